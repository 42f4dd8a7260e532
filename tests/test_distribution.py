"""The SDE distribution (eqs. 17-22) and the policy built for TorchRL's losses: the log-prob against
the closed form and ``torch.distributions``, reparameterised gradients against finite differences,
the noise schedule across partial resets, the wiring errors, and short real runs of ``ClipPPOLoss``,
``A2CLoss`` and ``SACLoss`` on Pendulum through TorchRL's ``Collector``."""

from __future__ import annotations

import doctest
import math
import re
from pathlib import Path

import pytest
import torch
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torch import distributions as D
from torch import nn
from torchrl.collectors import Collector
from torchrl.data import Unbounded
from torchrl.envs import Compose, GymEnv, InitTracker, ParallelEnv, SerialEnv, StepCounter, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type
from torchrl.modules import MLP, ValueOperator
from torchrl.modules.distributions.utils import has_analytic_entropy
from torchrl.objectives import A2CLoss, ClipPPOLoss, SACLoss
from torchrl.objectives.sac import compute_rsample_log_prob
from torchrl.objectives.value import GAE

import sde_torchrl.modules.distribution
import sde_torchrl.modules.sde_actor
from sde_torchrl.modules.distribution import (
    SDENormal,
    TanhSDENormal,
    gaussian_log_prob,
    noise_matrix,
    sde_sample,
    sde_sample_and_log_prob,
    sde_variance,
)
from sde_torchrl.modules.noise import SDENoisePrimer
from sde_torchrl.modules.sde import SDEParams, expln
from sde_torchrl.modules.sde_actor import action_bounds, make_sde_actor
from sde_torchrl.utils.rng import RunStreams

README = Path(__file__).resolve().parents[1] / "README.md"
A, S = 2, 3


def _params(batch=(4,), dtype=torch.float64, seed=0):
    g = torch.Generator().manual_seed(seed)
    loc = torch.randn(*batch, A, generator=g, dtype=dtype)
    sigma_hat = torch.rand(*batch, A, S, generator=g, dtype=dtype) + 0.1
    x = torch.randn(*batch, S, generator=g, dtype=dtype)
    noise = torch.randn(*batch, A, S, generator=g, dtype=dtype)
    return loc, sigma_hat, x, noise


# ----------------------------------------------------------------------------- the distribution

@pytest.mark.parametrize("gaussian", [False, True])
def test_log_prob_matches_eq_20_and_torch_normal(gaussian):
    loc, sigma_hat, x, noise = _params()
    gauss = torch.full((A,), 0.3, dtype=torch.float64) if gaussian else None
    dist = SDENormal(loc, sigma_hat, x, noise, gauss)
    u = loc + torch.randn_like(loc)
    # eq. 20, written out element by element
    var = torch.stack([
        torch.stack([sum((x[b, i] * sigma_hat[b, j, i]) ** 2 for i in range(S)) + (0.09 if gaussian else 0.0)
                     for j in range(A)]) for b in range(4)])
    closed = (-(u - loc) ** 2 / (2 * var) - 0.5 * torch.log(2 * math.pi * var)).sum(-1)
    torch.testing.assert_close(dist.log_prob(u), closed)
    normal = D.Normal(loc, var.sqrt())
    torch.testing.assert_close(dist.log_prob(u), normal.log_prob(u).sum(-1))
    torch.testing.assert_close(dist.entropy(), normal.entropy().sum(-1))
    torch.testing.assert_close(dist.stddev, var.sqrt())


def test_log_prob_gradient_matches_eqs_14_and_21():
    loc, sigma_hat, x, _ = _params(batch=())
    loc.requires_grad_(True)
    sigma_hat.requires_grad_(True)
    u = torch.tensor([0.4, -0.7], dtype=torch.float64)
    g_loc, g_sigma = torch.autograd.grad(SDENormal(loc, sigma_hat, x).log_prob(u), (loc, sigma_hat))
    var = (x.square() * sigma_hat.square()).sum(-1).detach()
    diff = u - loc.detach()
    torch.testing.assert_close(g_loc, diff / var)  # eq. 14 with dμ/dθ = identity
    # eq. 21: ((u_j - μ_j)² / σ_j² - 1) / σ_j² · x_i² σ̂_ji
    expected = ((diff.square() / var - 1) / var).unsqueeze(-1) * x.square() * sigma_hat.detach()
    torch.testing.assert_close(g_sigma, expected)


def test_rsample_uses_the_carried_noise_and_is_reparameterised():
    loc, sigma_hat, x, noise = _params()
    dist = SDENormal(loc, sigma_hat, x, noise)
    torch.testing.assert_close(dist.rsample(), loc + ((sigma_hat * noise) @ x.unsqueeze(-1)).squeeze(-1))
    assert not SDENormal(loc.requires_grad_(), sigma_hat, x, noise).sample().requires_grad

    def sample(loc, sigma_hat, gauss):
        torch.manual_seed(3)  # the eq. 22 part is drawn at every call
        return SDENormal(loc, sigma_hat, x, noise, gauss).rsample()

    gauss = torch.full((4, A), 0.2, dtype=torch.float64)
    inputs = (loc.detach().requires_grad_(), sigma_hat.requires_grad_(), gauss.requires_grad_())
    assert torch.autograd.gradcheck(sample, inputs)  # autograd against finite differences


def test_log_prob_gradients_match_finite_differences():
    loc, sigma_hat, x, _ = _params()
    u = torch.randn_like(loc)
    inputs = (loc.requires_grad_(), sigma_hat.requires_grad_())
    assert torch.autograd.gradcheck(lambda m, s: SDENormal(m, s, x).log_prob(u), inputs)
    assert torch.autograd.gradcheck(lambda m, s: TanhSDENormal(m, s, x, low=-2.0, high=3.0).log_prob(
        torch.tanh(u)), inputs)


def test_fresh_samples_have_the_eq_20_variance_and_mean_is_loc():
    loc, sigma_hat, x, noise = _params(batch=(2,))
    gauss = torch.tensor([0.5, 0.1], dtype=torch.float64)
    dist = SDENormal(loc, sigma_hat, x, noise, gauss)
    torch.manual_seed(0)
    samples = dist.sample((40_000,))
    assert samples.shape == (40_000, 2, A)
    torch.testing.assert_close(samples.var(0), sde_variance(sigma_hat, x, gauss), rtol=0.05, atol=0)
    torch.testing.assert_close(samples.mean(0), loc, atol=0.05, rtol=0)
    for value in (dist.mean, dist.mode, dist.deterministic_sample):
        torch.testing.assert_close(value, loc)


def test_shared_sigma_broadcasts_like_the_full_matrix():
    loc, _, x, noise = _params()
    shared = torch.full((A, 1), 0.4, dtype=torch.float64)
    full = SDENormal(loc, shared.expand(4, A, S), x, noise)
    dist = SDENormal(loc, shared, x, noise)
    torch.testing.assert_close(dist.log_prob(loc + 0.1), full.log_prob(loc + 0.1))
    torch.testing.assert_close(dist.rsample(), full.rsample())


def test_batch_shapes_that_do_not_broadcast_are_named():
    loc, sigma_hat, x, _ = _params()
    with pytest.raises(ValueError, match=re.escape("noise (5, 2, 3)")):
        SDENormal(loc, sigma_hat, x, torch.zeros(5, A, S))
    with pytest.raises(ValueError, match=re.escape("features (5, 3)")):
        SDENormal(loc, sigma_hat, torch.zeros(5, S))


def test_wrong_matrix_shape_names_expected_and_got():
    loc, _, x, _ = _params()
    expected = "sigma_hat has shape (4, 3, 2); expected [..., A, S] = [..., 2, 3]"
    with pytest.raises(ValueError, match=re.escape(expected)):
        SDENormal(loc, torch.ones(4, 3, 2), x)


def test_tanh_variant_scores_with_the_log_det_and_stays_in_bounds():
    loc, sigma_hat, x, noise = _params()
    low, high = torch.tensor([-2.0, 0.0], dtype=torch.float64), torch.tensor([2.0, 1.0], dtype=torch.float64)
    dist = TanhSDENormal(loc, sigma_hat, x, noise, low=low, high=high)
    reference = D.TransformedDistribution(
        D.Independent(D.Normal(loc, dist.scale), 1),
        [D.TanhTransform(), D.AffineTransform((high + low) / 2, (high - low) / 2, event_dim=1)])
    action = dist.rsample()
    assert ((action > low) & (action < high)).all()
    torch.testing.assert_close(dist.log_prob(action), reference.log_prob(action))
    sample, log_prob = dist.rsample_and_log_prob()
    torch.testing.assert_close(sample, action)
    torch.testing.assert_close(log_prob, dist.log_prob(action))
    torch.testing.assert_close(dist.deterministic_sample, (high + low) / 2 + (high - low) / 2 * torch.tanh(loc))
    assert not has_analytic_entropy(dist)  # TorchRL falls back to sampling
    with pytest.raises(ValueError, match="high > low"):
        TanhSDENormal(loc, sigma_hat, x, low=1.0, high=1.0)


def test_tanh_variant_scores_the_exact_pre_squash_sample_when_saturated():
    loc = torch.full((1, 1), 12.0)  # tanh(12) rounds to 1 in float32
    dist = TanhSDENormal(loc, torch.full((1, 1), 0.1), torch.ones(1, 1), torch.zeros(1, 1, 1))
    action, log_prob = dist.rsample_and_log_prob()
    assert torch.isfinite(log_prob).all() and torch.isfinite(dist.log_prob(action)).all()
    pre = loc.double()
    log_det = 2 * (math.log(2) - pre - nn.functional.softplus(-2 * pre))  # log(1 - tanh²), stable
    exact = D.Normal(pre, 0.1).log_prob(pre).sum(-1) - log_det.sum(-1)
    torch.testing.assert_close(log_prob.double(), exact, rtol=1e-5, atol=1e-5)


def test_compile_traces_the_distribution_without_graph_breaks():
    loc, sigma_hat, x, noise = _params(dtype=torch.float32)

    def step(loc, sigma_hat, x, noise):
        dist = SDENormal(loc, sigma_hat, x, noise)
        action = dist.rsample()
        return action, dist.log_prob(action), dist.entropy()

    compiled = torch.compile(step, backend="aot_eager", fullgraph=True)
    for got, want in zip(compiled(loc, sigma_hat, x, noise), step(loc, sigma_hat, x, noise), strict=True):
        torch.testing.assert_close(got, want)


# ----------------------------------------------------------------------------- the module and the schedule

def _linear_actor(in_features=3, out_features=1, out_key="loc"):
    return TensorDictModule(nn.Linear(in_features, out_features), in_keys=["observation"], out_keys=[out_key])


def _pendulum(sde=None, max_steps=20):
    transforms = [StepCounter(max_steps=max_steps), InitTracker()]
    if sde is not None:
        transforms.append(sde.make_tensordict_primer())
    return TransformedEnv(GymEnv("Pendulum-v1"), Compose(*transforms))


def _two_pendulums(sde):
    """Two envs with episodes of 3 and 5 steps: partial resets inside one rollout."""
    def make(n):
        return lambda: TransformedEnv(GymEnv("Pendulum-v1"), StepCounter(max_steps=n))
    return TransformedEnv(SerialEnv(2, [make(3), make(5)]), Compose(InitTracker(), sde.make_tensordict_primer()))


@pytest.mark.parametrize(("schedule", "every_n"), [("episode", None), ("step", None), ("every_n", 2)])
def test_noise_schedule_across_partial_resets(schedule, every_n):
    torch.manual_seed(0)
    sde = SDEParams(1, 3, schedule=schedule, every_n=every_n)
    env = _two_pendulums(sde)
    td = env.rollout(12, make_sde_actor(_linear_actor(), sde), break_when_any_done=False)
    noise = td["sde_noise"][..., 0, 0]  # [env, time]
    is_init = td["is_init"].squeeze(-1)
    for e in range(2):
        changed = noise[e, 1:] != noise[e, :-1]
        starts = is_init[e, 1:]
        assert changed[starts].all()  # every reset, partial included, draws anew
        age = torch.cumsum(torch.ones_like(is_init[e], dtype=torch.long), 0)
        for t in range(1, 12):
            if starts[t - 1]:
                age[t:] -= age[t - 1]  # steps since this episode began, 0 at its first step
        age = age - 1
        expected = {"episode": starts, "step": torch.ones_like(starts),
                    "every_n": starts | (age[1:] % 2 == 0)}[schedule]
        assert torch.equal(changed, expected)


@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_sde_params_log_prob_is_the_distributions(gaussian):
    """SDEParams.log_prob (SDESigma's, what the episodic estimators score) gives the log-prob
    the policy stored and its distribution recomputes: one likelihood for both paths."""
    torch.manual_seed(2)
    sde = SDEParams(1, 3, gaussian_init_param=gaussian)
    policy = make_sde_actor(_linear_actor(), sde)
    td = _pendulum(sde).rollout(10, policy)
    torch.testing.assert_close(sde.log_prob(td["loc"], td["observation"], td["action"]), td["action_log_prob"])
    torch.testing.assert_close(sde.scale(td["observation"]), policy.get_dist(td.clone()).stddev)


@pytest.mark.parametrize("gaussian", [False, True])
def test_sde_sample_is_loc_plus_theta_hat_x(gaussian):
    loc, sigma_hat, x, noise = _params()
    expected = loc + torch.einsum("bas,bs->ba", sigma_hat * noise, x)
    scale = eps = None
    if gaussian:
        scale, eps = torch.full((A,), 0.3, dtype=torch.float64), torch.randn(4, A, dtype=torch.float64)
        expected = expected + scale * eps
    torch.testing.assert_close(sde_sample(loc, sigma_hat, noise, x, scale, eps), expected)  # eqs. 17-19, 22
    torch.testing.assert_close(noise_matrix(sigma_hat, noise), sigma_hat * noise)  # eq. 18


def test_run_stacked_variance_equals_the_broadcast_one():
    sigma_hat, x = torch.rand(2, A, S, dtype=torch.float64), torch.randn(2, 7, S, dtype=torch.float64)
    gauss = torch.rand(2, 1, A, dtype=torch.float64)
    stacked = sde_variance(sigma_hat, x, gauss, run_dims=1)  # one matrix product per run
    torch.testing.assert_close(stacked, sde_variance(sigma_hat[:, None], x, gauss))
    assert sde_variance(torch.zeros(A, S), torch.zeros(S)).min() > 0  # floored: a finite likelihood at x = 0


def test_variance_of_a_sigma_hat_expanded_to_the_batch_is_the_per_row_sum_and_its_gradient():
    """σ_j² = Σ_i (x_i σ̂_ji)² (eq. 20) for σ̂ written as SDEParams writes it: one matrix expanded to the batch."""
    p = torch.randn(A, S, dtype=torch.float64, requires_grad=True)
    x = torch.randn(6, S, dtype=torch.float64)
    variance = sde_variance(p.exp().expand(6, A, S), x)
    per_row = torch.stack([(p.exp().square() * x[n].square()).sum(-1) for n in range(6)])
    torch.testing.assert_close(variance, per_row)
    (grad,) = torch.autograd.grad(variance.sum(), p)
    torch.testing.assert_close(grad, 2 * p.exp().square() * x.square().sum(0))  # d/dp Σ_n Σ_i x_ni² e^(2p)
    materialised = sde_variance(p.exp().expand(6, A, S).clone(), x)
    torch.testing.assert_close(materialised, per_row)


def test_compact_broadcast_cuts_only_expanded_dimensions():
    from sde_torchrl.utils.shapes import compact_broadcast

    base = torch.randn(1, A, S)
    assert compact_broadcast(base.expand(3, 4, A, S), 2).shape == (1, 1, A, S)
    dense = torch.randn(3, A, S)
    assert torch.equal(compact_broadcast(dense, 2), dense)
    assert compact_broadcast(dense.unsqueeze(1).expand(3, 5, A, S), 2).shape == (3, 1, A, S)


def test_stored_noise_reproduces_the_taken_action_and_log_prob():
    torch.manual_seed(1)
    sde = SDEParams(1, 3, gaussian_init_param=None)
    policy = make_sde_actor(_linear_actor(), sde)
    td = _pendulum(sde).rollout(10, policy)
    dist = policy.get_dist(td.clone())
    torch.testing.assert_close(dist.rsample(), td["action"])
    torch.testing.assert_close(dist.log_prob(td["action"]), td["action_log_prob"])


@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_a_sampling_step_writes_what_the_distribution_gives_bit_for_bit(gaussian):
    """The unsquashed policy samples without building its distribution (eqs. 17-22): the action
    is the distribution's ``rsample`` with the carried noise and its log-probability the
    distribution's, exactly, with and without eq. (22)'s Gaussian part."""
    torch.manual_seed(2)
    sde = SDEParams(2, 3, gaussian_init_param=gaussian)
    policy = make_sde_actor(_linear_actor(out_features=2), sde)
    primer = sde.make_tensordict_primer()
    td = TensorDict({"observation": torch.randn(7, 3), **dict(zip(
        ("sde_noise", "sde_gaussian_noise"), [t for t in primer.draw((7,)) if t is not None], strict=False))}, [7])
    with set_exploration_type(ExplorationType.RANDOM):
        out = policy(td.clone())
    dist = policy.get_dist(td.clone())
    assert torch.equal(out["action"], dist.rsample())
    assert torch.equal(out["action_log_prob"], dist.log_prob(out["action"]))
    with pytest.raises(ValueError, match="noise has shape"):
        sde_sample_and_log_prob(out["loc"], out["sde_sigma_hat"], torch.randn(7, 3), torch.randn(7, 3, 3))


@pytest.mark.parametrize("squash", [False, True])
def test_deterministic_exploration_acts_with_loc_and_needs_no_noise(squash):
    sde = SDEParams(1, 3)
    policy = make_sde_actor(_linear_actor(), sde, squash=squash, low=-2.0, high=2.0)
    td = TensorDict({"observation": torch.randn(5, 3)}, [5])
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        out = policy(td)
    torch.testing.assert_close(out["action"], 2 * torch.tanh(out["loc"]) if squash else out["loc"])


def test_resets_redraw_without_init_tracker():
    torch.manual_seed(0)
    sde = SDEParams(1, 3)
    env = TransformedEnv(GymEnv("Pendulum-v1"), Compose(StepCounter(max_steps=3), sde.make_tensordict_primer()))
    td = env.rollout(9, make_sde_actor(_linear_actor(), sde), break_when_any_done=False)
    noise, starts = td["sde_noise"][..., 0, 0], td["step_count"].squeeze(-1) == 0
    assert torch.equal(noise[1:] != noise[:-1], starts[1:])


def test_dtype_follows_the_policy():
    sde = SDEParams(1, 3).double()
    env = _pendulum(sde)
    assert env.reset()["sde_noise"].dtype == torch.float64


def test_stacked_runs_write_their_own_sigma():
    sde = SDEParams(2, 3, runs=2, sharing="single")
    with torch.no_grad():
        sde.sigma_param[1] = 0.0
    td = TensorDict({"loc": torch.zeros(2, 5, 2), "observation": torch.ones(2, 5, 3),
                     "sde_noise": torch.zeros(2, 5, 2, 3)}, [2, 5])
    sigma = sde(td)["sde_sigma_hat"]
    assert sigma.shape == (2, 5, 2, 3)
    torch.testing.assert_close(sigma[:, 0, 0, 0], torch.tensor([math.exp(-2), 1.0]))


def test_stacked_runs_draw_from_their_own_streams():
    sde = SDEParams(1, 3, runs=2)
    sde.streams = RunStreams(seed=7, runs=2, stream="explore")
    env = TransformedEnv(SerialEnv(2, lambda: GymEnv("Pendulum-v1")), sde.make_tensordict_primer())
    torch.testing.assert_close(env.reset()["sde_noise"], RunStreams(seed=7, runs=2, stream="explore").normal((2, 1, 3)))


def test_gaussian_part_is_learnable_and_written():
    sde = SDEParams(1, 3, gaussian_init_param=0.0)
    policy = make_sde_actor(_linear_actor(), sde)
    td = _pendulum(sde).rollout(4, policy)
    torch.testing.assert_close(td["sde_gaussian_scale"], torch.ones(4, 1))
    policy.get_dist(td.clone()).log_prob(td["action"]).sum().backward()
    assert sde.gaussian_param.grad.abs().sum() > 0


def test_keys_are_configurable():
    torch.manual_seed(0)
    sde = SDEParams(1, 3, loc_key="mean", feature_key="features", noise_key=("sde", "xi"), sigma_key=("sde", "sigma"))
    actor = TensorDictModule(nn.Linear(3, 1), in_keys=["observation"], out_keys=["mean"])
    copy = TensorDictModule(lambda obs: obs.clone(), in_keys=["observation"], out_keys=["features"])
    env = TransformedEnv(GymEnv("Pendulum-v1"), Compose(StepCounter(max_steps=3), sde.make_tensordict_primer()))
    policy = make_sde_actor(TensorDictSequential(actor, copy), sde, action_key="action")
    td = env.rollout(5, policy, break_when_any_done=False)
    assert td["sde", "xi"].shape == (5, 1, 3) and td["sde", "sigma"].shape == (5, 1, 3)
    expected = td["mean"] + ((td["sde", "sigma"] * td["sde", "xi"]) @ td["features"].unsqueeze(-1)).squeeze(-1)
    torch.testing.assert_close(td["action"], expected)


# ----------------------------------------------------------------------------- wiring mistakes

def test_missing_primer_says_what_to_add():
    sde = SDEParams(1, 3)
    with pytest.raises(KeyError, match=r"make_tensordict_primer\(\).*auto_register_policy_transforms=True"):
        _pendulum().rollout(3, make_sde_actor(_linear_actor(), sde))


def test_actor_writing_action_instead_of_loc_names_the_key():
    sde = SDEParams(1, 3)
    with pytest.raises(ValueError, match=r"the actor writes \['action'\] but SDEParams reads the mean from 'loc'"):
        make_sde_actor(_linear_actor(out_key="action"), sde)
    # built by hand (no make_sde_actor), the module itself names the missing key at the first call
    td = TensorDict({"action": torch.zeros(2, 1), "observation": torch.zeros(2, 3)}, [2])
    with pytest.raises(KeyError, match=r"SDEParams reads 'loc', which is missing .*out_keys=\['loc'\]"):
        sde(td)


def test_wrong_observation_shape_names_expected_and_got():
    sde = SDEParams(2, 3)
    td = TensorDict({"loc": torch.zeros(4, 2), "observation": torch.zeros(4, 2, 3), "sde_noise": torch.zeros(4, 2, 3)},
                    [4])
    with pytest.raises(ValueError, match=re.escape("'observation' has shape (4, 2, 3): expected (4, 3)")):
        sde(td)
    td["observation"] = torch.zeros(4, 5)
    with pytest.raises(ValueError, match=re.escape("'observation' has shape (4, 5): expected (4, 3)")):
        sde(td)


def test_action_bounds_come_from_the_env_spec():
    sde = SDEParams(1, 3)
    env = _pendulum(sde)
    low, high = action_bounds(env.action_spec)
    torch.testing.assert_close((low, high), (torch.tensor([-2.0]), torch.tensor([2.0])))
    policy = make_sde_actor(_linear_actor(), sde, squash=True, action_spec=env.action_spec)
    with torch.no_grad():
        policy.actor_modules[0].bias.fill_(30.0)  # saturate: the bound is 2, not tanh's 1
    td = env.rollout(5, policy)
    assert (td["action"] <= 2).all() and (td["action"] > 1.99).all()
    with pytest.raises(ValueError, match="has no bounds"):
        make_sde_actor(_linear_actor(), sde, squash=True, action_spec=Unbounded(shape=(1,)))
    with pytest.raises(ValueError, match="squash=True needs low= and high="):
        make_sde_actor(_linear_actor(), sde, squash=True)
    with pytest.raises(ValueError, match=re.escape("action spec has shape (1,), SDEParams action_dim=2")):
        make_sde_actor(_linear_actor(out_features=2), SDEParams(2, 3), action_spec=env.action_spec)


# ----------------------------------------------------------------------------- TorchRL's losses, real runs

def _collect(policy, env, frames=64, **kwargs):
    collector = Collector(env, policy, frames_per_batch=frames, total_frames=frames, **kwargs)
    batch = next(iter(collector))
    collector.shutdown()
    return batch


def _critic():
    return ValueOperator(MLP(in_features=3, out_features=1, num_cells=[16]), in_keys=["observation"])


def _policy_and_env(squash, **sde_kwargs):
    torch.manual_seed(0)
    sde = SDEParams(1, 3, **sde_kwargs)
    env = _pendulum(sde)
    policy = make_sde_actor(_linear_actor(), sde, squash=squash, action_spec=env.action_spec)
    return policy, sde, env


def _assert_grads(policy, sde):
    actor_weight = policy.actor_modules[0].weight
    assert actor_weight.grad is not None and actor_weight.grad.abs().sum() > 0  # θ
    assert sde.sigma_param.grad is not None and sde.sigma_param.grad.abs().sum() > 0  # σ̂


@pytest.mark.parametrize("squash", [False, True])
def test_clip_ppo_loss(squash):
    policy, sde, env = _policy_and_env(squash, schedule="every_n", every_n=4)
    critic = _critic()
    batch = _collect(policy, env)
    GAE(gamma=0.99, lmbda=0.95, value_network=critic)(batch)
    loss = ClipPPOLoss(policy, critic)
    with torch.no_grad():
        recomputed = policy.get_dist(batch.clone()).log_prob(batch["action"])
    torch.testing.assert_close(recomputed, batch["action_log_prob"])
    log_weight = loss._log_weight(batch, batch.shape)[0]
    torch.testing.assert_close(log_weight.exp(), torch.ones_like(log_weight))  # ratio 1 on the first epoch
    stored_noise = batch["sde_noise"].clone()
    out = loss(batch)
    assert float(out["clip_fraction"]) == 0.0
    assert torch.equal(batch["sde_noise"], stored_noise)  # the replay draws nothing
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    _assert_grads(policy, sde)


@pytest.mark.parametrize("squash", [False, True])
def test_ppo_minibatches_may_leave_the_noise_out(squash):
    """The likelihood (eq. 20) does not read ξ: ClipPPOLoss gives the same losses and gradients
    on a batch without the stored noise, which saves gathering an A × S matrix per sample."""
    policy, sde, env = _policy_and_env(squash, schedule="every_n", every_n=4)
    critic = _critic()
    batch = _collect(policy, env)
    GAE(gamma=0.99, lmbda=0.95, value_network=critic)(batch)
    loss = ClipPPOLoss(policy, critic)
    grads = []
    for minibatch in (batch, batch.exclude(sde.noise_key, sde.age_key)):
        loss.zero_grad()
        out = loss(minibatch.clone())
        (out["loss_objective"] + out["loss_critic"]).backward()
        grads.append([out["loss_objective"].detach(),
                      *(p.grad.clone() for p in loss.parameters() if p.grad is not None)])
    assert len(grads[0]) == len(grads[1]) > 1
    for with_noise, without in zip(*grads, strict=True):
        torch.testing.assert_close(with_noise, without, rtol=0, atol=0)


def test_a2c_loss():
    policy, sde, env = _policy_and_env(False, gaussian_init_param=-1.0)
    critic = _critic()
    batch = _collect(policy, env)
    GAE(gamma=0.99, lmbda=0.95, value_network=critic)(batch)
    loss = A2CLoss(policy, critic)
    with torch.no_grad():
        recomputed = policy.get_dist(batch.clone()).log_prob(batch["action"])
    torch.testing.assert_close(recomputed, batch["action_log_prob"])
    out = loss(batch)
    (out["loss_objective"] + out["loss_critic"] + out["loss_entropy"]).backward()
    _assert_grads(policy, sde)
    assert sde.gaussian_param.grad.abs().sum() > 0


@pytest.mark.parametrize("squash", [False, True])
def test_sac_loss_samples_with_the_carried_noise(squash):
    policy, sde, env = _policy_and_env(squash)
    batch = _collect(policy, env)
    qvalue = ValueOperator(MLP(in_features=4, out_features=1, num_cells=[16]), in_keys=["observation", "action"])
    loss = SACLoss(policy, qvalue, action_spec=env.action_spec)
    # the actor loss's draw: get_dist on the stored batch, then a reparameterised sample
    action, log_prob = compute_rsample_log_prob(policy.get_dist(batch.clone()))
    torch.testing.assert_close(action, batch["action"])  # the carried ξ gives back the taken action
    torch.testing.assert_close(log_prob, batch["action_log_prob"])
    out = loss(batch)
    torch.testing.assert_close(out["entropy"], -batch["action_log_prob"].mean())
    out["loss_actor"].backward()
    _assert_grads(policy, sde)


def test_collector_registers_the_primer_itself():
    torch.manual_seed(0)
    sde = SDEParams(1, 3, schedule="step")
    env = _pendulum()  # no primer, no SDE noise in the specs
    batch = _collect(make_sde_actor(_linear_actor(), sde), env, frames=20, auto_register_policy_transforms=True)
    noise = batch["sde_noise"][..., 0, 0]
    assert (noise[1:] != noise[:-1]).all()  # redrawn every step: the schedule came along


def test_collector_without_auto_registration_needs_the_primer():
    sde = SDEParams(1, 3)
    batch = _collect(make_sde_actor(_linear_actor(), sde), _pendulum(sde, max_steps=8), frames=16,
                     auto_register_policy_transforms=False)
    noise = batch["sde_noise"][..., 0, 0]
    assert noise[:8].unique().numel() == 1 and noise[8:].unique().numel() == 1 and noise[0] != noise[8]
    with pytest.raises(KeyError, match="make_tensordict_primer"):
        _collect(make_sde_actor(_linear_actor(), sde), _pendulum(), frames=8, auto_register_policy_transforms=False)


def test_vmap_under_default_randomness():
    torch.manual_seed(0)
    sde = SDEParams(1, 3)
    policy = make_sde_actor(_linear_actor(), sde)
    td = TensorDict({"observation": torch.randn(6, 3), "sde_noise": torch.randn(6, 1, 3)}, [6])
    batched = policy(td.clone())["action"]
    vmapped = torch.vmap(lambda t: policy(t))(td.clone())["action"]  # randomness="error": nothing is drawn
    torch.testing.assert_close(vmapped, batched)


def test_vmap_with_the_gaussian_part_needs_a_random_mode():
    sde = SDEParams(1, 3, gaussian_init_param=-1.0)
    policy = make_sde_actor(_linear_actor(), sde)
    td = TensorDict({"observation": torch.randn(6, 3), "sde_noise": torch.randn(6, 1, 3)}, [6])
    out = torch.vmap(lambda t: policy(t), randomness="different")(td)  # eq. 22's ε is i.i.d. per step
    assert out["action"].shape == (6, 1)


def test_compiled_policy_matches_eager():
    torch.manual_seed(0)
    sde = SDEParams(1, 3)
    policy = make_sde_actor(_linear_actor(), sde, squash=True, low=-2.0, high=2.0)
    td = TensorDict({"observation": torch.randn(6, 3), "sde_noise": torch.randn(6, 1, 3)}, [6])
    compiled = torch.compile(policy, backend="aot_eager")
    got, want = compiled(td.clone()), policy(td.clone())
    torch.testing.assert_close(got["action"], want["action"])
    torch.testing.assert_close(got["action_log_prob"], want["action_log_prob"])


@pytest.mark.e2e  # worker processes: spawned, each importing torch and the env
def test_parallel_env_with_the_primer_on_the_batched_env():
    torch.manual_seed(0)
    sde = SDEParams(1, 3)
    base = ParallelEnv(2, lambda: TransformedEnv(GymEnv("Pendulum-v1"), StepCounter(max_steps=4)))
    env = TransformedEnv(base, Compose(InitTracker(), sde.make_tensordict_primer()))
    try:
        td = env.rollout(8, make_sde_actor(_linear_actor(), sde), break_when_any_done=False)
    finally:
        env.close()
    noise = td["sde_noise"][..., 0, 0]
    assert noise[0, 0] != noise[1, 0]  # each worker its own ξ
    assert torch.equal(noise[:, 1:] != noise[:, :-1], td["is_init"].squeeze(-1)[:, 1:])


# ----------------------------------------------------------------------------- documentation

@pytest.mark.parametrize("module", [sde_torchrl.modules.distribution, sde_torchrl.modules.sde_actor])
def test_doctests(module):
    result = doctest.testmod(module, optionflags=doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_every_public_name_has_examples():
    for module in (sde_torchrl.modules.distribution, sde_torchrl.modules.sde_actor):
        for name in module.__all__ if hasattr(module, "__all__") else ():
            assert "Examples:" in getattr(module, name).__doc__, name
    for obj in (SDENormal, TanhSDENormal, gaussian_log_prob, noise_matrix, sde_sample, sde_variance, SDEParams,
                SDENoisePrimer, action_bounds, make_sde_actor):
        assert "Examples:" in obj.__doc__, obj.__name__


def test_docs_examples_run_as_written():
    section = re.search(r"<!-- losses:start -->(.*?)<!-- losses:end -->", README.read_text(), re.S)
    assert section, "README markers of the TorchRL-losses section not found"
    blocks = re.findall(r"```python\n(.*?)```", section.group(1), re.S)
    assert len(blocks) == 2, "expected the example and the explicit wiring in the README section"
    namespace: dict = {}
    for block in blocks:  # the second block rebuilds the first one's policy by hand
        exec(compile(block, str(README), "exec"), namespace)
    rebuilt = namespace["policy"]
    td = namespace["env"].reset()
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        torch.testing.assert_close(rebuilt(td.clone())["action"], namespace["loss"].actor_network(td.clone())["action"])


def test_sigma_hat_is_expln_of_the_parameter():
    sde = SDEParams(2, 3, init_param=0.5)
    torch.testing.assert_close(sde.sde_sigma, expln(torch.full((2, 3), 0.5)))
