"""The SDE explorer: expln (23, 24), the action distribution (20, 22), the likelihood's
gradients against the paper's closed forms (14)-(16), (21) and finite differences, and the
noise schedule (episode / step / every_n) across full and partial resets; and that the explorer is
the same SDE as the distribution form (shared ``SDESigma`` parameters, ``SDENormal``'s numbers)."""

from __future__ import annotations

import doctest
import math
import warnings

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

import sde_torchrl.modules.exploration
from sde_torchrl import (
    LinearActor,
    SDENormal,
    SDEParams,
    StateDependentExplorer,
    expln,
    expln_inverse,
    make_minimize_env,
)
from sde_torchrl.modules.exploration import SDESigma

SHARINGS = ("element", "action", "single")


# ----------------------------------------------------------------------------- expln (23, 24)

def test_expln_values_match_eq_23():
    p = torch.tensor([-3.0, -2.0, 0.0, 0.5, 4.0], dtype=torch.float64)
    expected = torch.tensor([math.exp(-3), math.exp(-2), 1.0, math.log(1.5) + 1, math.log(5) + 1],
                            dtype=torch.float64)
    torch.testing.assert_close(expln(p), expected)


def test_expln_and_its_derivative_are_continuous_at_zero():
    eps = 1e-7
    p = torch.tensor([-eps, 0.0, eps], dtype=torch.float64, requires_grad=True)
    value = expln(p)
    (derivative,) = torch.autograd.grad(value.sum(), p)
    torch.testing.assert_close(value, torch.ones(3, dtype=torch.float64), atol=2e-7, rtol=0)
    # eq. 24: exp(p) below zero, 1/(p+1) above: both 1 at zero.
    torch.testing.assert_close(derivative, torch.ones(3, dtype=torch.float64), atol=2e-7, rtol=0)


def test_expln_derivative_matches_eq_24_on_both_branches():
    p = torch.tensor([-1.5, 2.0], dtype=torch.float64, requires_grad=True)
    (derivative,) = torch.autograd.grad(expln(p).sum(), p)
    torch.testing.assert_close(derivative, torch.tensor([math.exp(-1.5), 1 / 3.0], dtype=torch.float64))


def test_expln_has_no_nan_gradient_far_out():
    p = torch.tensor([-50.0, -1.5, 1e6], requires_grad=True)
    (derivative,) = torch.autograd.grad(expln(p).sum(), p)
    assert torch.isfinite(derivative).all()
    assert (expln(p) > 0).all()


@pytest.mark.parametrize("sigma", [1e-3, 0.135, 1.0, 1.7, 25.0])
def test_expln_inverse_round_trips(sigma):
    p = expln_inverse(torch.tensor(sigma, dtype=torch.float64))
    torch.testing.assert_close(expln(p), torch.tensor(sigma, dtype=torch.float64))


@pytest.mark.parametrize("bad", [0.0, -1.0, float("nan"), float("inf")])
def test_expln_inverse_rejects_non_positive_or_non_finite(bad):
    with pytest.raises(ValueError, match="sigma"):
        expln_inverse(bad)


# ----------------------------------------------------------------- distribution (20, 22)

def _explorer(sharing="element", dtype=torch.float64, **kwargs):
    explorer = StateDependentExplorer(2, 3, sharing=sharing, **kwargs).to(dtype)
    with torch.no_grad():  # distinct σ̂ per entry, so sharing mistakes cannot cancel out
        p = explorer.sigma_param
        p.copy_(torch.linspace(-2.5, 0.7, p.numel(), dtype=dtype).reshape(p.shape))
    return explorer


@pytest.mark.parametrize("sharing", SHARINGS)
def test_scale_is_eq_20(sharing):
    explorer = _explorer(sharing)
    x = torch.tensor([[0.5, -2.0, 1.5], [3.0, 0.0, -0.1]], dtype=torch.float64)
    sigma_hat = expln(explorer.sigma_param).expand(2, 3)
    expected = torch.stack([
        torch.sqrt(sum((x[b, i] * sigma_hat[j, i]) ** 2 for i in range(3))) for b in range(2) for j in range(2)
    ]).reshape(2, 2)
    torch.testing.assert_close(explorer.scale(x), expected)


def test_scale_adds_gaussian_part_eq_22():
    explorer = _explorer(gaussian_init_param=-1.0)
    x = torch.tensor([[0.5, -2.0, 1.5]], dtype=torch.float64)
    sde_only = _explorer().scale(x)
    expected = torch.sqrt(sde_only.square() + math.exp(-1.0) ** 2)
    torch.testing.assert_close(explorer.scale(x), expected)


@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_actions_follow_the_stated_distribution(gaussian):
    """Over fresh noise draws, u ~ N(loc, scale²) (eq. 20; with eq. 22's part if enabled)."""
    torch.manual_seed(0)
    explorer = _explorer(schedule="step", gaussian_init_param=gaussian)
    n = 40_000
    x = torch.tensor([0.5, -2.0, 1.5], dtype=torch.float64).expand(n, 3)
    loc = torch.tensor([1.0, -1.0], dtype=torch.float64).expand(n, 2)
    out = explorer(TensorDict({"loc": loc, "observation": x}, [n]))
    torch.testing.assert_close(out["action"].mean(0), loc[0], atol=0.05, rtol=0)
    torch.testing.assert_close(out["action"].std(0), out["scale"][0], rtol=0.03, atol=0)


def test_log_prob_is_gaussian_density_of_pre_squash_sample():
    torch.manual_seed(1)
    explorer = _explorer(squash=True)
    td = TensorDict({"loc": torch.randn(5, 2, dtype=torch.float64),
                     "observation": torch.randn(5, 3, dtype=torch.float64)}, [5])
    out = explorer(td)
    expected = torch.distributions.Normal(out["loc"], out["scale"]).log_prob(out["action_sample"]).sum(-1)
    torch.testing.assert_close(out["action_log_prob"], expected)
    torch.testing.assert_close(out["action"], torch.tanh(out["action_sample"]))


@pytest.mark.parametrize("squash", [False, True])
def test_deterministic_exploration_returns_the_mean(squash):
    explorer = _explorer(squash=squash)
    loc = torch.randn(4, 2, dtype=torch.float64)
    td = TensorDict({"loc": loc, "observation": torch.randn(4, 3, dtype=torch.float64)}, [4])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = explorer(td.clone())["action"]
    torch.testing.assert_close(action, torch.tanh(loc) if squash else loc)
    assert not torch.equal(explorer(td)["action"], action)  # exploration is on otherwise


# ------------------------------------------------- gradients: closed forms (14)-(16), (21)

def _linear_policy(sharing, gaussian=None):
    actor = LinearActor(3, 2, init=[-1.0, 1.0]).double()
    return actor, _explorer(sharing, gaussian_init_param=gaussian)


def _log_prob(actor, explorer, x, u):
    return explorer.log_prob(actor(TensorDict({"observation": x}, x.shape[:-1]))["loc"], x, u)


def _sample(actor, explorer, x):
    torch.manual_seed(3)
    with torch.no_grad():
        td = actor(TensorDict({"observation": x}, x.shape[:-1]))
        return explorer(td)["action_sample"]


@pytest.mark.parametrize("sharing", SHARINGS)
def test_autograd_matches_closed_forms_16_and_21_with_expln_factor(sharing):
    actor, explorer = _linear_policy(sharing)
    x = torch.tensor([0.7, -1.2, 2.0], dtype=torch.float64)
    u = _sample(actor, explorer, x)
    logp = _log_prob(actor, explorer, x, u)
    d_theta, d_p = torch.autograd.grad(logp, [actor.module.weight, explorer.sigma_param])

    with torch.no_grad():
        mu = actor.module.weight @ x
        p = explorer.sigma_param
        sigma_hat = expln(p).expand(2, 3)
        var = (x.square() * sigma_hat.square()).sum(-1)
        diff = u - mu
        closed_16 = (diff / var).unsqueeze(-1) * x  # eq. 16
        per_element_21 = ((diff.square() - var) / var.square()).unsqueeze(-1) * x.square() * sigma_hat  # eq. 21
        if sharing == "element":
            d_sigma_hat = per_element_21
        elif sharing == "action":
            d_sigma_hat = per_element_21.sum(-1, keepdim=True)
        else:
            d_sigma_hat = per_element_21.sum().reshape(1, 1)
        expln_prime = torch.where(p <= 0, torch.exp(p), 1 / (p + 1))  # eq. 24
    torch.testing.assert_close(d_theta, closed_16)
    torch.testing.assert_close(d_p, d_sigma_hat * expln_prime)


def test_autograd_matches_eq_15_for_the_gaussian_sigma():
    """With zero features the SDE part vanishes and σ_j is the Gaussian σ alone (eq. 15)."""
    actor, explorer = _linear_policy("element", gaussian=-0.5)
    explorer.gaussian_param.data = torch.tensor([-0.5, 0.3], dtype=torch.float64)
    x = torch.zeros(3, dtype=torch.float64)
    u = torch.tensor([0.4, -0.9], dtype=torch.float64)
    (d_q,) = torch.autograd.grad(_log_prob(actor, explorer, x, u), [explorer.gaussian_param])
    with torch.no_grad():
        q = explorer.gaussian_param
        sigma = expln(q)
        closed_15 = (u.square() - sigma.square()) / sigma**3
        expln_prime = torch.where(q <= 0, torch.exp(q), 1 / (q + 1))
    torch.testing.assert_close(d_q, closed_15 * expln_prime)


def test_autograd_matches_eq_14_through_an_mlp():
    """(14): ∂log π/∂θ = Σ_k (u_k - μ_k)/σ_k² ∂μ_k/∂θ, with ∂μ/∂θ from the network alone."""
    from sde_torchrl import MLPActor

    torch.manual_seed(4)
    actor = MLPActor(3, 2, hidden=[4], init=[-1.0, 1.0]).double()
    explorer = _explorer("single")
    x = torch.tensor([0.7, -1.2, 2.0], dtype=torch.float64)
    u = _sample(actor, explorer, x)
    params = list(actor.parameters())
    grads = torch.autograd.grad(_log_prob(actor, explorer, x, u), params)
    with torch.no_grad():
        mu = actor(TensorDict({"observation": x}, []))["loc"]
        weight = (u - mu) / explorer.scale(x).square()
    jac_rows = [torch.autograd.grad(actor(TensorDict({"observation": x}, []))["loc"][k], params)
                for k in range(2)]
    for i, g in enumerate(grads):
        torch.testing.assert_close(g, sum(weight[k] * jac_rows[k][i] for k in range(2)))


@pytest.mark.parametrize("sharing", SHARINGS)
@pytest.mark.parametrize("gaussian", [None, 0.4])
def test_autograd_matches_finite_differences(sharing, gaussian):
    actor, explorer = _linear_policy(sharing, gaussian)
    actor.module.bias = None
    x = torch.tensor([[0.7, -1.2, 2.0], [-0.3, 0.5, 0.1]], dtype=torch.float64)
    u = _sample(actor, explorer, x)
    params = [p for p in (*actor.parameters(), *explorer.parameters())]
    grads = torch.autograd.grad(_log_prob(actor, explorer, x, u).sum(), params)
    h = 1e-6
    for param, g in zip(params, grads, strict=True):
        numeric = torch.zeros_like(param)
        for idx in range(param.numel()):
            with torch.no_grad():
                flat = param.view(-1)
                flat[idx] += h
                up = _log_prob(actor, explorer, x, u).sum()
                flat[idx] -= 2 * h
                down = _log_prob(actor, explorer, x, u).sum()
                flat[idx] += h
            numeric.view(-1)[idx] = (up - down) / (2 * h)
        torch.testing.assert_close(g, numeric, rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------- the noise schedule

def _rollout(schedule, steps=12, episode_length=5, runs=None, every_n=None, episodes=3):
    torch.manual_seed(0)
    explorer = StateDependentExplorer(1, 1, schedule=schedule, every_n=every_n, runs=runs)
    env = make_minimize_env(episode_length, episodes=episodes, runs=runs)
    env.append_transform(explorer.make_tensordict_primer())
    policy = TensorDictSequential(LinearActor(1, 1, init=-2.0, runs=runs), explorer)
    with torch.no_grad():
        return env.rollout(steps, policy, break_when_any_done=False)


def _changes(noise):
    """Boolean [*, T-1]: where the noise differs from the previous step."""
    flat = noise.flatten(-2)
    return (flat[..., 1:, :] != flat[..., :-1, :]).any(-1)


def test_episode_schedule_holds_noise_and_redraws_exactly_at_resets():
    td = _rollout("episode")
    changes = _changes(td["sde_noise"])  # [episodes, T-1]
    is_init = td["is_init"].squeeze(-1)[..., 1:]
    assert torch.equal(changes, is_init)
    assert is_init[:, [4, 9]].all() and is_init.sum() == 2 * 3  # resets after 5 and 10 steps
    first = td["sde_noise"][:, 0].flatten()
    assert len(set(first.tolist())) == 3  # every batch element has its own draw


def test_episode_schedule_with_stacked_runs():
    td = _rollout("episode", runs=2)
    assert td.batch_size == (2, 3, 12)
    assert torch.equal(_changes(td["sde_noise"]), td["is_init"].squeeze(-1)[..., 1:])


def test_step_schedule_redraws_every_step():
    assert _changes(_rollout("step")["sde_noise"]).all()


@pytest.mark.parametrize("n", [2, 3])
def test_every_n_schedule_redraws_every_n_steps_and_at_resets(n):
    td = _rollout("every_n", every_n=n, steps=14, episode_length=7)
    step_in_episode = torch.arange(14) % 7
    expected = (step_in_episode % n == 0)[1:].expand(3, 13)
    assert torch.equal(_changes(td["sde_noise"]), expected)


def test_partial_reset_redraws_only_the_reset_elements():
    explorer = StateDependentExplorer(1, 1)
    env = make_minimize_env(50, episodes=4).append_transform(explorer.make_tensordict_primer())
    policy = TensorDictSequential(LinearActor(1, 1, init=-2.0), explorer)
    with torch.no_grad():
        td = policy(env.reset())
        before = td["sde_noise"].clone()
        td = step_mdp(env.step(td))
        td["_reset"] = torch.tensor([True, False, True, False]).unsqueeze(-1)
        td = policy(env.reset(td))
    changed = (td["sde_noise"] != before).flatten(1).any(-1)
    assert changed.tolist() == [True, False, True, False]


def test_is_init_mask_is_honoured_per_element_without_env():
    explorer = StateDependentExplorer(2, 3)
    noise = torch.randn(4, 2, 3)
    td = TensorDict({
        "loc": torch.zeros(4, 2), "observation": torch.ones(4, 3), "sde_noise": noise.clone(),
        "is_init": torch.tensor([[True], [False], [False], [True]]),
    }, [4])
    out = explorer(td)["sde_noise"]
    assert [not torch.equal(out[i], noise[i]) for i in range(4)] == [True, False, False, True]


def test_module_works_without_primer_and_keeps_its_noise():
    explorer = StateDependentExplorer(2, 3)
    td = explorer(TensorDict({"loc": torch.zeros(4, 2), "observation": torch.ones(4, 3)}, [4]))
    noise = td["sde_noise"].clone()
    assert noise.shape == (4, 2, 3)
    td = explorer(td)
    assert torch.equal(td["sde_noise"], noise)


def test_action_is_loc_plus_theta_hat_x():
    """(18): u = (Θ + Θ̂) x for a linear controller, with Θ̂ = σ̂ ⊙ ξ."""
    explorer = StateDependentExplorer(2, 3, init_param=-1.0)
    x = torch.randn(4, 3)
    noise = torch.randn(4, 2, 3)
    loc = torch.randn(4, 2)
    td = explorer(TensorDict({"loc": loc, "observation": x, "sde_noise": noise}, [4]))
    theta_hat = math.exp(-1.0) * noise
    torch.testing.assert_close(td["action"], loc + (theta_hat @ x.unsqueeze(-1)).squeeze(-1))


# -------------------------------------------------------------------------- bad input

@pytest.mark.parametrize("kwargs, match", [
    ({"schedule": "sometimes"}, "schedule"),
    ({"sharing": "per_state"}, "sharing"),
    ({"schedule": "every_n"}, "every_n"),
    ({"schedule": "every_n", "every_n": 0}, "every_n"),
    ({"every_n": 3}, "every_n"),
    ({"runs": 0}, "runs"),
])
def test_bad_options_are_rejected_by_name(kwargs, match):
    with pytest.raises(ValueError, match=match):
        StateDependentExplorer(2, 3, **kwargs)


def test_wrong_shapes_are_rejected_by_name():
    explorer = StateDependentExplorer(2, 3)
    with pytest.raises(ValueError, match="observation"):
        explorer(TensorDict({"loc": torch.zeros(4, 2), "observation": torch.ones(4, 5)}, [4]))
    with pytest.raises(ValueError, match="loc"):
        explorer(TensorDict({"loc": torch.zeros(4, 1), "observation": torch.ones(4, 3)}, [4]))


def test_carried_noise_without_is_init_warns_once():
    """A rollout that carries the noise but has no InitTracker would never redraw it: say so."""
    from tensordict import TensorDict

    explorer = StateDependentExplorer(action_dim=1, feature_dim=2)
    td = TensorDict({"loc": torch.zeros(3, 1), "observation": torch.ones(3, 2)}, [3])
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out = explorer(td)  # a first call without noise: nothing to say
    with pytest.warns(UserWarning, match="never redrawn.*InitTracker"):
        explorer(out.clone())
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        explorer(out.clone())  # once per explorer
        out["is_init"] = torch.zeros(3, 1, dtype=torch.bool)
        StateDependentExplorer(action_dim=1, feature_dim=2)(out.clone())  # with is_init: fine


# ------------------------------------------------------------- one implementation with SDENormal

def _explorer_and_step(sharing, runs, gaussian=None):
    torch.manual_seed(3)
    explorer = _explorer(sharing, runs=runs, gaussian_init_param=gaussian)
    if gaussian is not None:
        with torch.no_grad():
            explorer.gaussian_param.uniform_(-1.0, 0.5)
    batch = (5,) if runs is None else (runs, 5)
    td = TensorDict({"loc": torch.randn(*batch, 2, dtype=torch.float64),
                     "observation": torch.randn(*batch, 3, dtype=torch.float64),
                     "sde_noise": torch.randn(*batch, 2, 3, dtype=torch.float64),
                     "is_init": torch.zeros(*batch, 1, dtype=torch.bool)}, batch)
    return explorer, td


def _sde_normal(explorer, td):
    """The SDENormal that SDEParams, loaded with the explorer's state dict, parameterises."""
    sde = SDEParams(2, 3, sharing=explorer.sharing, runs=explorer.runs,
                    gaussian_init_param=0.0 if explorer.has_gaussian else None).double()
    sde.load_state_dict(explorer.state_dict())  # the same parameter names
    params = sde(td.clone())
    return SDENormal(params["loc"], params["sde_sigma_hat"], params["observation"], params["sde_noise"],
                     params.get("sde_gaussian_scale", None))


@pytest.mark.parametrize("runs", [None, 2])
@pytest.mark.parametrize("sharing", SHARINGS)
def test_explorer_acts_and_scores_as_sde_normal_with_the_same_parameters(sharing, runs):
    """Given the carried ξ, SDENormal takes the explorer's very action and scores it alike."""
    explorer, td = _explorer_and_step(sharing, runs)
    out = explorer(td.clone())
    dist = _sde_normal(explorer, td)
    assert torch.equal(out["sde_noise"], td["sde_noise"])  # held: no reset
    assert torch.equal(dist.rsample(), out["action_sample"])  # eqs. 17-19, one formula
    torch.testing.assert_close(dist.stddev, out["scale"])  # eq. 20
    torch.testing.assert_close(dist.log_prob(out["action_sample"]), out["action_log_prob"])  # eq. 13


@pytest.mark.parametrize("runs", [None, 2])
def test_gaussian_part_scores_as_sde_normal(runs):
    explorer, td = _explorer_and_step("action", runs, gaussian=-0.7)
    out = explorer(td.clone())
    dist = _sde_normal(explorer, td)
    torch.testing.assert_close(dist.stddev, out["scale"])  # eqs. 20, 22
    torch.testing.assert_close(dist.log_prob(out["action_sample"]), out["action_log_prob"])


def test_explorer_and_sde_params_share_the_sigma_module():
    explorer, sde = StateDependentExplorer(2, 3, runs=4), SDEParams(2, 3, runs=4)
    assert isinstance(explorer, SDESigma) and isinstance(sde, SDESigma)
    assert [name for name, _ in explorer.named_parameters()] == [name for name, _ in sde.named_parameters()]
    x = torch.randn(4, 6, 3)
    torch.testing.assert_close(explorer.scale(x), sde.scale(x))


def test_exploration_doctests():
    result = doctest.testmod(sde_torchrl.modules.exploration, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0
