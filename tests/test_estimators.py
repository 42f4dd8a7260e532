"""Episodic estimators: per-episode scores (eq. 9) via torch.func against a per-episode
autograd loop, REINFORCE's optimal baseline against its formula, ENAC against the natural
gradient of a problem whose Fisher matrix is known, and the update θ ← θ + α g (eq. 1)."""

from __future__ import annotations

import pytest
import torch
from _helpers import sde_policy
from tensordict import TensorDict
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.modules import ProbabilisticActor

from sde_torchrl import (
    ENACEstimator,
    GPOMDPEstimator,
    LinearActor,
    MLPActor,
    ReinforceEstimator,
    SDEParams,
    episode_returns,
    episode_scores,
    make_minimize_env,
    make_sde_actor,
)
from sde_torchrl.objectives.base import rescale_largest_entry
from sde_torchrl.objectives.estimators import (
    EpisodeLogLikelihood,
    enac_gradient,
    flatten_scores,
    reinforce_gradient,
)


def _policy(actor_kind="linear", runs=None, sharing="element", gaussian=None):
    actor = (LinearActor(2, 2, bias=True, runs=runs, init=[-1.0, 0.0]) if actor_kind == "linear"
             else MLPActor(2, 2, hidden=[3], runs=runs, init=[-1.0, 0.0]))
    return sde_policy(actor, 2, 2, runs=runs, sharing=sharing, gaussian_init_param=gaussian)[0]


def _episodes(policy, runs=None, episodes=3, length=4):
    torch.manual_seed(0)
    env = make_minimize_env(length, dim=2, episodes=episodes, runs=runs, x0=2.0, x0_spread=1.0)
    env.append_transform(policy.sde.make_tensordict_primer())
    with torch.no_grad():
        return env.rollout(length, policy)


@pytest.mark.parametrize("actor_kind", ["linear", "mlp"])
@pytest.mark.parametrize("runs", [None, 2])
@pytest.mark.parametrize("gaussian", [None, -1.0])
def test_torch_func_scores_equal_a_per_episode_autograd_loop(actor_kind, runs, gaussian):
    torch.manual_seed(0)
    policy = _policy(actor_kind, runs, gaussian=gaussian)
    episodes = _episodes(policy, runs)
    log_lik = EpisodeLogLikelihood(policy)
    scores = episode_scores(log_lik, episodes)
    params = dict((n, p) for n, p in log_lik.named_parameters())
    assert set(scores) == set(params)
    for n in range(episodes.batch_size[-2]):
        loglik = log_lik(episodes[..., n, :])  # [*runs]: one autograd pass per (run, episode)
        for r in range(1 if runs is None else runs):
            target = loglik if runs is None else loglik[r]
            grads = torch.autograd.grad(target, list(params.values()), retain_graph=True)
            for name, g in zip(params, grads, strict=True):
                if runs is None:
                    torch.testing.assert_close(scores[name][n], g, rtol=1e-5, atol=1e-6)
                else:  # run r's score lives in slice r of the stacked parameter, nowhere else
                    torch.testing.assert_close(scores[name][r, n], g[r], rtol=1e-5, atol=1e-6)
                    assert g[1 - r].abs().sum() == 0


def test_scores_sum_per_step_likelihood_terms():
    """ψ_n = Σ_t ∇ log π(u_t|x_t) (eq. 9): the score of an episode is the sum of its steps'."""
    policy = _policy()
    episodes = _episodes(policy, episodes=1, length=3)
    log_lik = EpisodeLogLikelihood(policy)
    total = flatten_scores(episode_scores(log_lik, episodes), 0)[0]
    per_step = sum(
        flatten_scores(episode_scores(log_lik, episodes[:, t : t + 1]), 0)[0] for t in range(3)
    )
    torch.testing.assert_close(total, per_step, rtol=1e-5, atol=1e-5)


def test_episode_returns_are_mean_rewards():
    rewards = torch.arange(24, dtype=torch.float32).reshape(2, 3, 4, 1)
    td = TensorDict({"next": {"reward": rewards}}, [2, 3, 4])
    torch.testing.assert_close(episode_returns(td), rewards.squeeze(-1).mean(-1))


def test_optimal_baseline_matches_its_formula():
    torch.manual_seed(0)
    scores = torch.randn(2, 7, 5, dtype=torch.float64)
    scores[1, :, 3] = 0.0  # a parameter without score: baseline 0, gradient 0
    returns = torch.randn(2, 7, dtype=torch.float64)
    gradient, baseline = reinforce_gradient(scores, returns)
    for r in range(2):
        for k in range(5):
            psi, ret = scores[r, :, k], returns[r]
            denom = (psi**2).sum()
            b = (psi**2 * ret).sum() / denom if denom > 0 else torch.tensor(0.0, dtype=torch.float64)
            torch.testing.assert_close(baseline[r, k], b)
            torch.testing.assert_close(gradient[r, k], (psi * (ret - b)).mean())
    assert baseline[1, 3] == 0 and gradient[1, 3] == 0


def _bandit_episodes(theta, sigma, target, n, generator):
    """One-step episodes of u ~ N(θ, σ²) with x = 1 and reward -(u - c)²."""
    u = theta + sigma * torch.randn(n, 1, 2, generator=generator)
    return TensorDict({
        "observation": torch.ones(n, 1, 1), "action": u,
        "next": {"reward": -(u - target).square().sum(-1, keepdim=True)},
    }, [n, 1])


def _bandit_policy(theta, sigma):
    actor = LinearActor(1, 2, init=0.0)
    actor.module.weight.data = theta.reshape(2, 1).clone()
    return sde_policy(actor, 2, 1, init_param=float(torch.log(torch.tensor(sigma))), learn_sigma=False)[0]


def test_reinforce_is_unbiased_on_a_gaussian_bandit():
    """J(θ) = -‖θ - c‖² - 2σ², so ∇J = -2(θ - c)."""
    theta, target, sigma = torch.tensor([0.5, -1.0]), torch.tensor([1.5, 0.0]), 0.3
    episodes = _bandit_episodes(theta, sigma, target, 200_000, torch.Generator().manual_seed(0))
    out = ReinforceEstimator(_bandit_policy(theta, sigma))(episodes)
    torch.testing.assert_close(out["gradient"], -2 * (theta - target), rtol=0.03, atol=0.02)


def test_enac_equals_the_natural_gradient_on_a_gaussian_bandit():
    """Fisher F = I/σ² for the mean of N(θ, σ²I): natural gradient F⁻¹∇J = -2σ²(θ - c)."""
    theta, target, sigma = torch.tensor([0.5, -1.0]), torch.tensor([1.5, 0.0]), 0.3
    episodes = _bandit_episodes(theta, sigma, target, 200_000, torch.Generator().manual_seed(1))
    out = ENACEstimator(_bandit_policy(theta, sigma))(episodes)
    torch.testing.assert_close(out["gradient"], -2 * sigma**2 * (theta - target), rtol=0.03, atol=2e-3)
    assert int(out["rank"]) == 3
    # J fits the average return J(θ) = -‖θ - c‖² - 2σ² (the ψ² term is uncorrelated with ψ).
    torch.testing.assert_close(out["J"], -(theta - target).square().sum() - 2 * sigma**2, rtol=0.02, atol=0)


def test_enac_equals_the_closed_form_least_squares_solution():
    torch.manual_seed(0)
    scores = torch.randn(3, 20, 4, dtype=torch.float64)
    returns = torch.randn(3, 20, dtype=torch.float64)
    w, J, rank, cond = enac_gradient(scores, returns)
    for r in range(3):
        X = torch.cat([scores[r], torch.ones(20, 1, dtype=torch.float64)], -1)
        solution = torch.linalg.solve(X.T @ X, X.T @ returns[r])
        torch.testing.assert_close(w[r], solution[:4])
        torch.testing.assert_close(J[r], solution[4])
    assert rank.tolist() == [5, 5, 5] and torch.isfinite(cond).all()


def test_enac_survives_rank_deficiency_and_reports_it():
    scores = torch.randn(2, 3, 6)  # 3 episodes, 6 parameters: rank at most 3 < 7
    scores[1, :, 2] = 0.0
    w, J, rank, cond = enac_gradient(scores, torch.randn(2, 3))
    assert torch.isfinite(w).all() and torch.isfinite(J).all()
    assert rank.tolist() == [3, 3]
    assert (cond > 1e6).all() or not torch.isfinite(cond).all()


@pytest.mark.parametrize("estimator_cls", [ReinforceEstimator, ENACEstimator])
def test_sgd_step_on_the_loss_is_plain_gradient_ascent(estimator_cls):
    """loss_objective = -g·θ: SGD(lr=α) on it gives θ ← θ + α g (eq. 1), per stacked run."""
    policy = _policy(runs=2)
    episodes = _episodes(policy, runs=2, episodes=6)
    estimator = estimator_cls(policy)
    before = torch.cat([p.detach().flatten(1) for p in estimator.learnable_parameters().values()], -1)
    out = estimator(episodes)
    optimizer = torch.optim.SGD(policy.parameters(), lr=0.05)
    optimizer.zero_grad()
    out["loss_objective"].backward()
    optimizer.step()
    after = torch.cat([p.detach().flatten(1) for p in estimator.learnable_parameters().values()], -1)
    assert out["gradient"].shape == before.shape and out["gradient"].abs().sum() > 0
    torch.testing.assert_close(after, before + 0.05 * out["gradient"])


def test_loss_output_keys_and_set_keys():
    policy = _policy()
    episodes = _episodes(policy)
    episodes["next", "cost"] = -episodes["next", "reward"]
    estimator = ReinforceEstimator(policy)
    out = estimator(episodes)
    assert {"loss_objective", "return_mean", "gradient", "baseline", "score_norm"} <= set(out.keys())
    estimator.set_keys(reward=("next", "cost"))
    torch.testing.assert_close(estimator(episodes)["return_mean"], -out["return_mean"])


@pytest.mark.parametrize("estimator_cls", [ReinforceEstimator, ENACEstimator])
def test_set_keys_renames_the_keys_the_estimator_reads(estimator_cls):
    policy = _policy(runs=2)
    episodes = _episodes(policy, runs=2, episodes=6)
    expected = estimator_cls(policy)(episodes)["gradient"]
    estimator = estimator_cls(policy)
    assert estimator.in_keys == ["observation", "action", ("next", "reward")]

    renamed = episodes.clone()
    renamed.rename_key_(("next", "reward"), "my_reward")
    estimator.set_keys(reward="my_reward")
    assert estimator.in_keys == ["observation", "action", "my_reward"]
    torch.testing.assert_close(estimator(renamed)["gradient"], expected, rtol=0, atol=0)

    renamed.rename_key_("action", "my_sample")
    renamed["my_features"] = renamed["observation"]
    estimator.set_keys(action_sample="my_sample", features="my_features")
    assert estimator.in_keys == ["observation", "my_features", "my_sample", "my_reward"]
    torch.testing.assert_close(estimator(renamed)["gradient"], expected, rtol=0, atol=0)
    with pytest.raises(KeyError, match="my_features"):
        estimator(renamed.exclude("my_features"))

    estimator.set_keys(reward=None, action_sample=None, features=None)  # back to the defaults
    assert estimator.in_keys == ["observation", "action", ("next", "reward")]
    torch.testing.assert_close(estimator(episodes)["gradient"], expected, rtol=0, atol=0)


def test_policy_without_explorer_is_rejected():
    with pytest.raises(TypeError, match=r"got TensorDictSequential; expected make_sde_actor\(actor, SDEParams"):
        ReinforceEstimator(TensorDictSequential(LinearActor(2, 2)))


def test_episodes_need_an_episode_and_a_time_dimension():
    policy = _policy()
    with pytest.raises(ValueError, match="episodes"):
        episode_scores(EpisodeLogLikelihood(policy), _episodes(policy)[0])


def test_max_grad_norm_rescales_each_run_separately():
    policy = _policy(runs=2)
    episodes = _episodes(policy, runs=2, episodes=6)
    free = ReinforceEstimator(policy)(episodes)
    norms = free["gradient"].norm(dim=-1)
    bound = float(norms.min() + norms.max()) / 2  # clips one run, leaves the other
    clipped = ReinforceEstimator(policy, max_grad_norm=bound)(episodes)
    small, large = int(norms.argmin()), int(norms.argmax())
    torch.testing.assert_close(clipped["gradient"][small], free["gradient"][small])
    torch.testing.assert_close(clipped["gradient"][large], free["gradient"][large] * bound / norms[large])
    torch.testing.assert_close(clipped["gradient_norm"], norms)
    with pytest.raises(ValueError, match="max_grad_norm"):
        ReinforceEstimator(policy, max_grad_norm=0.0)


def test_episode_returns_sum_or_mean_the_rewards():
    rewards = torch.arange(24, dtype=torch.float32).reshape(2, 3, 4, 1)
    td = TensorDict({"next": {"reward": rewards}}, [2, 3, 4])
    torch.testing.assert_close(episode_returns(td, kind="sum"), rewards.squeeze(-1).sum(-1))
    policy = _policy()
    assert ReinforceEstimator(policy, episode_return="sum").returns(td).equal(rewards.squeeze(-1).sum(-1))
    with pytest.raises(ValueError, match="episode_return"):
        ReinforceEstimator(policy, episode_return="total")


def _linear_closed_forms(actor, sde, episodes):
    """Per-episode closed forms on u = W x + Θ̂ x: eq. (14) for W, eq. (21) with expln' (24) for p."""
    weight = actor.module.weight.detach()
    sigma_hat = sde.sde_sigma.detach()  # p <= 0: expln'(p) = σ̂
    x, u = episodes["observation"], episodes["action"]
    mu = x @ weight.T
    variance = (x.square() @ sigma_hat.square().T)  # eq. (20), [N, T, A]
    d = (u - mu).unsqueeze(-1)  # [N, T, A, 1]
    xs = x.unsqueeze(-2)  # [N, T, 1, S]
    plain_w = (d / variance.unsqueeze(-1) * xs).sum(1)
    plain_p = (((d.square() - variance.unsqueeze(-1)) / variance.unsqueeze(-1).square()) * xs.square()
               * sigma_hat.square()).sum(1)
    return plain_w, plain_p, variance.unsqueeze(-1), d, xs, sigma_hat


def test_variance_weighted_scores_match_the_authors_closed_forms():
    """Weighted by σ_j² (constant): ∂/∂W_ji = Σ_t (u_j − μ_j) x_i, and the σ̂ score is eq. (21) × σ_j²."""
    actor = LinearActor(2, 2, bias=False, init=[-1.0, 0.0])
    policy, sde = sde_policy(actor, 2, 2)
    episodes = _episodes(policy, episodes=3, length=4)
    plain = episode_scores(EpisodeLogLikelihood(policy), episodes)
    weighted = episode_scores(EpisodeLogLikelihood(policy, variance_weighted=True), episodes)
    plain_w, plain_p, variance, d, xs, sigma_hat = _linear_closed_forms(actor, sde, episodes)
    names = list(plain)
    torch.testing.assert_close(plain[names[0]], plain_w, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(plain[names[1]], plain_p, rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(weighted[names[0]], (d * xs).sum(1), rtol=1e-4, atol=1e-4)
    expected_p = ((d.square() - variance) / variance * xs.square() * sigma_hat.square()).sum(1)
    torch.testing.assert_close(weighted[names[1]], expected_p, rtol=1e-4, atol=1e-4)
    assert not torch.allclose(weighted[names[0]], plain[names[0]], rtol=0.1)


def test_max_grad_entry_rescales_by_the_signed_largest_entry_per_run():
    policy = _policy(runs=2)
    episodes = _episodes(policy, runs=2, episodes=6)
    free = ReinforceEstimator(policy)(episodes)["gradient"]
    largest = free.max(-1).values
    bound = float(largest.min() + largest.max()) / 2  # rescales one run, leaves the other
    rescaled = ReinforceEstimator(policy, max_grad_entry=bound)(episodes)["gradient"]
    small, large = int(largest.argmin()), int(largest.argmax())
    torch.testing.assert_close(rescaled[small], free[small])
    torch.testing.assert_close(rescaled[large], free[large] * bound / largest[large])
    assert float(rescaled[large].max()) == pytest.approx(bound)
    negative = -torch.tensor([[5000.0, 1.0]])  # huge but negative entries: untouched (signed maximum)
    torch.testing.assert_close(rescale_largest_entry(negative, 1000.0), negative)
    with pytest.raises(ValueError, match="max_grad_entry"):
        ReinforceEstimator(policy, max_grad_entry=0.0)


def _squashed_twin(policy):
    """The squashed form (``TanhSDENormal`` onto [-1, 1]) of an unsquashed SDE policy, same parameters."""
    sde = policy.sde
    twin = SDEParams(sde.action_dim, sde.feature_dim, sharing=sde.sharing,
                     gaussian_init_param=-1.0 if sde.has_gaussian else None)
    twin.load_state_dict(sde.state_dict())
    return make_sde_actor(policy.actor_modules[0], twin, squash=True, low=-1.0, high=1.0)


@pytest.mark.parametrize("estimator_cls", [ReinforceEstimator, ENACEstimator, GPOMDPEstimator])
@pytest.mark.parametrize("variance_weighted", [False, True])
def test_squashed_policy_gives_the_unsquashed_policys_gradient(estimator_cls, variance_weighted):
    """The likelihood scores the pre-squash sample: the tanh Jacobian does not depend on the parameters."""
    torch.manual_seed(0)
    policy = _policy(gaussian=-1.0)
    with torch.no_grad():
        policy.sde.sigma_param.add_(0.3 * torch.randn_like(policy.sde.sigma_param))
    twin = _squashed_twin(policy)
    episodes = _episodes(policy, episodes=6)
    # the squashed policy reads the sample it took under "action_sample" and the squashed action under "action"
    as_taken = episodes.clone().set("action_sample", episodes["action"]).set("action", torch.tanh(episodes["action"]))
    expected = estimator_cls(policy, variance_weighted=variance_weighted)(episodes)["gradient"]
    got = estimator_cls(twin, variance_weighted=variance_weighted)(as_taken)["gradient"]
    assert twin.sample_key == "action_sample" and expected.abs().max() > 0
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)


def test_probabilistic_actor_policy_learns_from_its_own_rollouts():
    torch.manual_seed(0)
    sde = SDEParams(1, 1)
    policy = make_sde_actor(LinearActor(1, 1, init=-2.0), sde)
    env = make_minimize_env(5, episodes=8, x0=1.0).append_transform(sde.make_tensordict_primer())
    with torch.no_grad():
        episodes = env.rollout(5, policy, break_when_any_done=False)
    assert episodes["sde_noise"][:, 0].ne(episodes["sde_noise"][:, -1]).sum() == 0  # ξ held for the episode
    gradient = ReinforceEstimator(policy)(episodes)["gradient"]
    assert gradient.shape == (2,) and torch.isfinite(gradient).all() and gradient.abs().max() > 0


def test_foreign_probabilistic_policies_are_refused_with_the_fix():
    plain = ProbabilisticActor(TensorDictModule(torch.nn.Linear(2, 4), in_keys=["observation"], out_keys=["p"]),
                               in_keys=["p"], distribution_class=torch.distributions.Normal)
    with pytest.raises(TypeError, match="got ProbabilisticActor; expected make_sde_actor"):
        ReinforceEstimator(plain)
