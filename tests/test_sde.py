"""SDE's parameters and policy: expln (23, 24), the action distribution (20, 22), the likelihood's
gradients against the paper's closed forms (14)-(16), (21) and finite differences, the noise
schedule (episode / step / every_n) across full and partial resets, and that the policy's action
and log-probability are ``SDENormal``'s (one implementation)."""

from __future__ import annotations

import math

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule
from torchrl.envs.utils import ExplorationType, set_exploration_type, step_mdp

from sde_torchrl import (
    LinearActor,
    SDENormal,
    SDEParams,
    TanhSDENormal,
    expln,
    expln_inverse,
    make_minimize_env,
    make_sde_actor,
)

SHARINGS = ("element", "action", "single", "feature")


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

def _sde(sharing="element", dtype=torch.float64, **kwargs):
    sde = SDEParams(2, 3, sharing=sharing, **kwargs).to(dtype)
    with torch.no_grad():  # distinct σ̂ per entry, so sharing mistakes cannot cancel out
        p = sde.sigma_param
        p.copy_(torch.linspace(-2.5, 0.7, p.numel(), dtype=dtype).reshape(p.shape))
    return sde


def _mean_policy(sde, squash=False):
    """The SDE policy whose controller mean is the input's ``mean``: the distribution alone."""
    actor = TensorDictModule(lambda mean: mean, in_keys=["mean"], out_keys=["loc"])
    return make_sde_actor(actor, sde, squash=squash, low=-1.0, high=1.0)


def _step(loc, x, sde, noise=None):
    batch = loc.shape[:-1]
    td = TensorDict({"mean": loc, "observation": x,
                     "sde_noise": torch.randn(*batch, 2, 3, dtype=loc.dtype) if noise is None else noise}, batch)
    if sde.has_gaussian:
        td["sde_gaussian_noise"] = torch.randn(*batch, 2, dtype=loc.dtype)
    return td


@pytest.mark.parametrize("sharing", SHARINGS)
def test_scale_is_eq_20(sharing):
    sde = _sde(sharing)
    x = torch.tensor([[0.5, -2.0, 1.5], [3.0, 0.0, -0.1]], dtype=torch.float64)
    sigma_hat = expln(sde.sigma_param).expand(2, 3)
    expected = torch.stack([
        torch.sqrt(sum((x[b, i] * sigma_hat[j, i]) ** 2 for i in range(3))) for b in range(2) for j in range(2)
    ]).reshape(2, 2)
    torch.testing.assert_close(sde.scale(x), expected)


def test_scale_adds_gaussian_part_eq_22():
    sde = _sde(gaussian_init_param=-1.0)
    x = torch.tensor([[0.5, -2.0, 1.5]], dtype=torch.float64)
    expected = torch.sqrt(_sde().scale(x).square() + math.exp(-1.0) ** 2)
    torch.testing.assert_close(sde.scale(x), expected)


@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_actions_follow_the_stated_distribution(gaussian):
    """Over fresh noise draws, u ~ N(loc, scale²) (eq. 20; with eq. 22's part if enabled)."""
    torch.manual_seed(0)
    sde = _sde(gaussian_init_param=gaussian)
    n = 40_000
    x = torch.tensor([0.5, -2.0, 1.5], dtype=torch.float64).expand(n, 3)
    loc = torch.tensor([1.0, -1.0], dtype=torch.float64).expand(n, 2)
    out = _mean_policy(sde)(_step(loc, x, sde))
    torch.testing.assert_close(out["action"].mean(0), loc[0], atol=0.05, rtol=0)
    torch.testing.assert_close(out["action"].std(0), sde.scale(x[:1])[0], rtol=0.03, atol=0)


def test_squashed_policy_keeps_the_sample_and_scores_the_action_by_change_of_variables():
    """``action = tanh(u)``; ``sde.log_prob`` is the Gaussian density of ``u`` (eqs. 13, 20, what the
    estimators score); ``action_log_prob`` is the density of the action, ``- Σ log(1 - tanh² u)``."""
    torch.manual_seed(1)
    sde = _sde()
    loc, x = torch.randn(5, 2, dtype=torch.float64), torch.randn(5, 3, dtype=torch.float64)
    out = _mean_policy(sde, squash=True)(_step(loc, x, sde))
    sample = out["action_sample"]
    gaussian = torch.distributions.Normal(loc, sde.scale(x)).log_prob(sample).sum(-1)
    torch.testing.assert_close(sde.log_prob(loc, x, sample), gaussian)
    torch.testing.assert_close(out["action"], torch.tanh(sample))
    torch.testing.assert_close(out["action_log_prob"], gaussian - torch.log1p(-torch.tanh(sample) ** 2).sum(-1))


@pytest.mark.parametrize("squash", [False, True])
def test_deterministic_exploration_returns_the_mean(squash):
    sde = _sde()
    loc, x = torch.randn(4, 2, dtype=torch.float64), torch.randn(4, 3, dtype=torch.float64)
    policy = _mean_policy(sde, squash)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        action = policy(TensorDict({"mean": loc, "observation": x}, [4]))["action"]  # no noise needed
    torch.testing.assert_close(action, torch.tanh(loc) if squash else loc)
    assert not torch.equal(policy(_step(loc, x, sde))["action"], action)  # exploration is on otherwise


def test_action_is_loc_plus_theta_hat_x():
    """(18): u = (Θ + Θ̂) x for a linear controller, with Θ̂ = σ̂ ⊙ ξ."""
    sde = SDEParams(2, 3, init_param=-1.0)
    x, noise, loc = torch.randn(4, 3), torch.randn(4, 2, 3), torch.randn(4, 2)
    td = _mean_policy(sde)(TensorDict({"mean": loc, "observation": x, "sde_noise": noise}, [4]))
    theta_hat = math.exp(-1.0) * noise
    torch.testing.assert_close(td["action"], loc + (theta_hat @ x.unsqueeze(-1)).squeeze(-1))


# ------------------------------------------------- gradients: closed forms (14)-(16), (21)

def _linear_policy(sharing, gaussian=None):
    actor = LinearActor(3, 2, init=[-1.0, 1.0]).double()
    return actor, _sde(sharing, gaussian_init_param=gaussian)


def _log_prob(actor, sde, x, u):
    return sde.log_prob(actor(TensorDict({"observation": x}, x.shape[:-1]))["loc"], x, u)


def _sample(actor, sde, x):
    torch.manual_seed(3)
    with torch.no_grad():
        td = TensorDict({"observation": x, "sde_noise": torch.randn(*x.shape[:-1], 2, 3, dtype=x.dtype)},
                        x.shape[:-1])
        if sde.has_gaussian:
            td["sde_gaussian_noise"] = torch.randn(*x.shape[:-1], 2, dtype=x.dtype)
        return make_sde_actor(actor, sde)(td)["action"]


@pytest.mark.parametrize("sharing", SHARINGS)
def test_autograd_matches_closed_forms_16_and_21_with_expln_factor(sharing):
    actor, sde = _linear_policy(sharing)
    x = torch.tensor([0.7, -1.2, 2.0], dtype=torch.float64)
    u = _sample(actor, sde, x)
    logp = _log_prob(actor, sde, x, u)
    d_theta, d_p = torch.autograd.grad(logp, [actor.module.weight, sde.sigma_param])

    with torch.no_grad():
        mu = actor.module.weight @ x
        p = sde.sigma_param
        sigma_hat = expln(p).expand(2, 3)
        var = (x.square() * sigma_hat.square()).sum(-1)
        diff = u - mu
        closed_16 = (diff / var).unsqueeze(-1) * x  # eq. 16
        per_element_21 = ((diff.square() - var) / var.square()).unsqueeze(-1) * x.square() * sigma_hat  # eq. 21
        if sharing == "element":
            d_sigma_hat = per_element_21
        elif sharing == "action":
            d_sigma_hat = per_element_21.sum(-1, keepdim=True)
        elif sharing == "feature":  # one σ̂ per feature, shared over the actions (SB3's full_std=False)
            d_sigma_hat = per_element_21.sum(0, keepdim=True)
        else:
            d_sigma_hat = per_element_21.sum().reshape(1, 1)
        expln_prime = torch.where(p <= 0, torch.exp(p), 1 / (p + 1))  # eq. 24
    torch.testing.assert_close(d_theta, closed_16)
    torch.testing.assert_close(d_p, d_sigma_hat * expln_prime)


def test_autograd_matches_eq_15_for_the_gaussian_sigma():
    """With zero features the SDE part vanishes and σ_j is the Gaussian σ alone (eq. 15)."""
    actor, sde = _linear_policy("element", gaussian=-0.5)
    sde.gaussian_param.data = torch.tensor([-0.5, 0.3], dtype=torch.float64)
    x = torch.zeros(3, dtype=torch.float64)
    u = torch.tensor([0.4, -0.9], dtype=torch.float64)
    (d_q,) = torch.autograd.grad(_log_prob(actor, sde, x, u), [sde.gaussian_param])
    with torch.no_grad():
        q = sde.gaussian_param
        sigma = expln(q)
        closed_15 = (u.square() - sigma.square()) / sigma**3
        expln_prime = torch.where(q <= 0, torch.exp(q), 1 / (q + 1))
    torch.testing.assert_close(d_q, closed_15 * expln_prime)


def test_autograd_matches_eq_14_through_an_mlp():
    """(14): ∂log π/∂θ = Σ_k (u_k - μ_k)/σ_k² ∂μ_k/∂θ, with ∂μ/∂θ from the network alone."""
    from sde_torchrl import MLPActor

    torch.manual_seed(4)
    actor = MLPActor(3, 2, hidden=[4], init=[-1.0, 1.0]).double()
    sde = _sde("single")
    x = torch.tensor([0.7, -1.2, 2.0], dtype=torch.float64)
    u = _sample(actor, sde, x)
    params = list(actor.parameters())
    grads = torch.autograd.grad(_log_prob(actor, sde, x, u), params)
    with torch.no_grad():
        mu = actor(TensorDict({"observation": x}, []))["loc"]
        weight = (u - mu) / sde.scale(x).square()
    jac_rows = [torch.autograd.grad(actor(TensorDict({"observation": x}, []))["loc"][k], params)
                for k in range(2)]
    for i, g in enumerate(grads):
        torch.testing.assert_close(g, sum(weight[k] * jac_rows[k][i] for k in range(2)))


@pytest.mark.parametrize("sharing", SHARINGS)
@pytest.mark.parametrize("gaussian", [None, 0.4])
def test_autograd_matches_finite_differences(sharing, gaussian):
    actor, sde = _linear_policy(sharing, gaussian)
    actor.module.bias = None
    x = torch.tensor([[0.7, -1.2, 2.0], [-0.3, 0.5, 0.1]], dtype=torch.float64)
    u = _sample(actor, sde, x)
    params = [p for p in (*actor.parameters(), *sde.parameters())]
    grads = torch.autograd.grad(_log_prob(actor, sde, x, u).sum(), params)
    h = 1e-6
    for param, g in zip(params, grads, strict=True):
        numeric = torch.zeros_like(param)
        for idx in range(param.numel()):
            with torch.no_grad():
                flat = param.view(-1)
                flat[idx] += h
                up = _log_prob(actor, sde, x, u).sum()
                flat[idx] -= 2 * h
                down = _log_prob(actor, sde, x, u).sum()
                flat[idx] += h
            numeric.view(-1)[idx] = (up - down) / (2 * h)
        torch.testing.assert_close(g, numeric, rtol=1e-5, atol=1e-6)


# ---------------------------------------------------------------- the noise schedule

def _rollout(schedule, steps=12, episode_length=5, runs=None, every_n=None, episodes=3):
    torch.manual_seed(0)
    sde = SDEParams(1, 1, schedule=schedule, every_n=every_n, runs=runs)
    env = make_minimize_env(episode_length, episodes=episodes, runs=runs)
    env.append_transform(sde.make_tensordict_primer())
    policy = make_sde_actor(LinearActor(1, 1, init=-2.0, runs=runs), sde)
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


def test_every_schedule_draws_the_same_numbers_sde_keeps_the_first_rex_uses_each():
    """The primer draws one ξ per step from an episode's start whatever the schedule: SDE's
    episode noise is REX's first step's, and the streams end where they end for REX."""
    sde_td, rex_td = _rollout("episode", steps=5), _rollout("step", steps=5)
    assert torch.equal(sde_td["sde_noise"][:, 0], rex_td["sde_noise"][:, 0])
    assert torch.equal(_rollout_then_draw("episode"), _rollout_then_draw("step"))


def _rollout_then_draw(schedule):
    _rollout(schedule, steps=5)
    return torch.randn(3)


def test_partial_reset_redraws_only_the_reset_elements():
    sde = SDEParams(1, 1)
    env = make_minimize_env(50, episodes=4).append_transform(sde.make_tensordict_primer())
    policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
    with torch.no_grad():
        td = policy(env.reset())
        before = td["sde_noise"].clone()
        td = step_mdp(env.step(td))
        td["_reset"] = torch.tensor([True, False, True, False]).unsqueeze(-1)
        td = policy(env.reset(td))
    changed = (td["sde_noise"] != before).flatten(1).any(-1)
    assert changed.tolist() == [True, False, True, False]


def test_deterministic_exploration_draws_nothing():
    from sde_torchrl.utils.rng import RunStreams

    sde = SDEParams(1, 1, runs=2)
    sde.streams = RunStreams(seed=0, runs=2, stream="explore")
    env = make_minimize_env(5, episodes=3, runs=2).append_transform(sde.make_tensordict_primer())
    state = sde.streams.state_dict()
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        env.rollout(5, make_sde_actor(LinearActor(1, 1, runs=2), sde), break_when_any_done=False)
    assert torch.equal(sde.streams.state_dict()["buffer"], state["buffer"])
    assert all(torch.equal(a, b) for a, b in zip(sde.streams.state_dict()["generators"], state["generators"],
                                                 strict=True))


def test_policy_without_noise_says_to_add_the_primer():
    policy = make_sde_actor(LinearActor(3, 2), SDEParams(2, 3))
    with pytest.raises(KeyError, match="make_tensordict_primer"):
        policy(TensorDict({"observation": torch.ones(4, 3)}, [4]))


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
        SDEParams(2, 3, **kwargs)


def test_wrong_shapes_are_rejected_by_name():
    sde = SDEParams(2, 3)
    noise = torch.zeros(4, 2, 3)
    with pytest.raises(ValueError, match="observation"):
        sde(TensorDict({"loc": torch.zeros(4, 2), "observation": torch.ones(4, 5), "sde_noise": noise}, [4]))
    with pytest.raises(ValueError, match="loc"):
        sde(TensorDict({"loc": torch.zeros(4, 1), "observation": torch.ones(4, 3), "sde_noise": noise}, [4]))


# -------------------------------------------------------- one implementation: SDENormal's numbers

@pytest.mark.parametrize("squash", [False, True])
@pytest.mark.parametrize("gaussian", [None, -0.7])
@pytest.mark.parametrize("runs", [None, 2])
@pytest.mark.parametrize("sharing", SHARINGS)
def test_policy_acts_and_scores_as_sde_normal(sharing, runs, gaussian, squash):
    """Given the carried ξ (and ε), the policy's action is SDENormal's sample (eqs. 17-19, 22),
    its log-probability the distribution's, and ``sde.log_prob`` of the sample eq. 13 with eq. 20."""
    torch.manual_seed(3)
    sde = _sde(sharing, runs=runs, gaussian_init_param=gaussian)
    batch = (5,) if runs is None else (runs, 5)
    loc, x = torch.randn(*batch, 2, dtype=torch.float64), torch.randn(*batch, 3, dtype=torch.float64)
    td = _step(loc, x, sde)
    out = _mean_policy(sde, squash)(td.clone())
    cls = TanhSDENormal if squash else SDENormal
    dist = cls(loc, out["sde_sigma_hat"], x, td["sde_noise"], out.get("sde_gaussian_scale", None),
               td.get("sde_gaussian_noise", None))
    sample = SDENormal.rsample(dist)
    assert torch.equal(out["action_sample" if squash else "action"], sample)
    torch.testing.assert_close(out["action_log_prob"], dist.log_prob(out["action"]))
    plain = SDENormal(loc, out["sde_sigma_hat"], x, gaussian_scale=out.get("sde_gaussian_scale", None))
    torch.testing.assert_close(sde.log_prob(loc, x, sample), plain.log_prob(sample))
    torch.testing.assert_close(plain.stddev, sde.scale(x))
