"""PGPE (``explorer=pgpe estimator=pgpe``): its formulas against loops, its estimates against the
closed-form gradient of ``J(μ, σ) = E_{θ ~ N(μ, σ²)}[R(θ)]`` on the 1-D task (plain and symmetric
sampling, with mutations that miss it), its relation to SDE's scores, runs stacked equal to
runs alone bit for bit, a bitwise resume, its config checks and the ball-catching env.

The closed form: on the 1-D task a controller ``u = θ x`` held for the episode has the expected
summed return ``R(θ)`` of :func:`~sde_torchrl.envs.minimize.expected_linear_return`, a polynomial
of degree ``2T`` in ``θ``; Gauss-Hermite quadrature with ``T + 1`` or more nodes gives
``J(μ, σ) = E_ξ[R(μ + σ ξ)]`` exactly, and autograd its gradient.
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest
import torch
from _helpers import build, compose_config, crash_at, read_rows, run_cli, sde_policy
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential

import sde_torchrl.modules.pgpe
import sde_torchrl.objectives.pgpe
from sde_torchrl import LinearActor, MLPActor, SDEParams, make_minimize_env, make_sde_actor
from sde_torchrl.collectors.rollout import collect_episodes
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.envs.minimize import expected_linear_return
from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.objectives.estimators import EpisodeLogLikelihood, EpisodesError, episode_scores
from sde_torchrl.objectives.pgpe import PGPEEstimator, parameter_scores, pgpe_gradient, symmetric_pgpe_gradient
from sde_torchrl.utils.checks import ArgumentError
from sde_torchrl.utils.rng import RunStreams

X0, STEP, NOISE, THETA0, LENGTH = 2.0, 0.1, 0.5, -2.0, 15
PGPE = ("explorer=pgpe", "estimator=pgpe")


@pytest.mark.parametrize("module", [sde_torchrl.modules.pgpe, sde_torchrl.objectives.pgpe])
def test_doctests(module):
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


# ------------------------------------------------------------------------------ the formulas


def test_gradients_equal_the_formulas_written_as_loops():
    torch.manual_seed(0)
    runs, n, k = 2, 6, 3
    eps, returns = torch.randn(runs, n, k, dtype=torch.float64), torch.randn(runs, n, dtype=torch.float64)
    sigma = torch.rand(runs, k, dtype=torch.float64) + 0.1
    g_mu, g_sigma, b = pgpe_gradient(eps, returns, sigma)
    sym_mu, sym_sigma, sym_b = symmetric_pgpe_gradient(eps[:, :3], returns[:, :3], returns[:, 3:], sigma)
    weighted = pgpe_gradient(eps, returns, sigma, variance_weighted=True)
    for r in range(runs):
        base = sum(returns[r].tolist()) / n
        mid = [(returns[r, j] + returns[r, 3 + j]) / 2 for j in range(3)]
        for i in range(k):
            s = float(sigma[r, i])
            mu_i = sum((returns[r, j] - base) * eps[r, j, i] for j in range(n)) / n / s**2
            sigma_i = sum((returns[r, j] - base) * (eps[r, j, i] ** 2 - s**2) for j in range(n)) / n / s**3
            assert float(g_mu[r, i]) == pytest.approx(float(mu_i), rel=1e-10)
            assert float(g_sigma[r, i]) == pytest.approx(float(sigma_i), rel=1e-10)
            assert float(weighted[0][r, i]) == pytest.approx(float(mu_i) * s**2, rel=1e-10)  # α_i = α σ_i²
            assert float(weighted[1][r, i]) == pytest.approx(float(sigma_i) * s**2, rel=1e-10)
            sym_mu_i = sum(eps[r, j, i] * (returns[r, j] - returns[r, 3 + j]) / 2 for j in range(3)) / 3 / s**2
            sym_sigma_i = sum((mid[j] - sum(mid) / 3) * (eps[r, j, i] ** 2 - s**2) for j in range(3)) / 3 / s**3
            assert float(sym_mu[r, i]) == pytest.approx(float(sym_mu_i), rel=1e-10)
            assert float(sym_sigma[r, i]) == pytest.approx(float(sym_sigma_i), rel=1e-10)
        assert float(b[r]) == pytest.approx(base) and float(sym_b[r]) == pytest.approx(float(sum(mid) / 3))


def test_scores_are_autograd_of_the_gaussian_log_density():
    torch.manual_seed(1)
    mu, sigma, theta = torch.randn(4, dtype=torch.float64), torch.rand(4, dtype=torch.float64) + 0.2, torch.randn(4)
    mu.requires_grad_(), sigma.requires_grad_()
    log_p = torch.distributions.Normal(mu, sigma).log_prob(theta.double()).sum()
    expected = torch.autograd.grad(log_p, (mu, sigma))
    scores = parameter_scores((theta.double() - mu).detach().unsqueeze(0), sigma.detach())
    for got, want in zip(scores, expected, strict=True):
        torch.testing.assert_close(got[0], want)


@pytest.mark.parametrize("actor", ["linear", "mlp"])
def test_explorer_acts_with_the_drawn_parameters_and_draws_once_per_episode(actor):
    torch.manual_seed(0)
    runs, n = 2, 4
    controller = (LinearActor(2, 2, bias=True, runs=runs) if actor == "linear"
                  else MLPActor(2, 2, hidden=[3], runs=runs))
    explorer = ParameterExplorer(controller, runs=runs)
    explorer.streams = RunStreams(0, runs, "explore")
    env = make_minimize_env(5, dim=2, episodes=n, runs=runs, x0=2.0, x0_spread=1.0)
    policy = TensorDictSequential(controller, explorer)
    episodes = collect_episodes(env.append_transform(explorer.make_tensordict_primer()), policy, 5)
    theta = episodes["pgpe_parameters"]
    assert (theta == theta[:, :, :1]).all()  # one draw per episode
    torch.testing.assert_close(theta[:, 0::2, 0] + theta[:, 1::2, 0], 2 * explorer.mean().detach()[:, None].expand(
        runs, n // 2, -1), rtol=1e-5, atol=1e-6)  # symmetric pairs μ ± ε
    for r in range(runs):  # the action is the network's output under θ, per episode
        for e in range(n):
            params = dict(zip(explorer.parameter_names, theta[r, e, 0].split(
                [s.numel() for s in explorer.parameter_shapes]), strict=True))
            single = {name: torch.stack([p.reshape(s)] * runs) for (name, p), s in
                      zip(params.items(), explorer.parameter_shapes, strict=True)}
            out = torch.func.functional_call(controller.module, single, (episodes["observation"][:, e],))[r]
            torch.testing.assert_close(episodes["action"][r, e], out, rtol=1e-5, atol=1e-5)


def test_noise_is_kept_until_an_episode_starts():
    actor = LinearActor(2, 1)
    explorer = ParameterExplorer(actor, symmetric=False)
    td = actor(TensorDict({"observation": torch.randn(3, 2)}, [3]))
    first = explorer(td.clone())["pgpe_noise"]
    kept = explorer(actor(TensorDict({"observation": torch.randn(3, 2), "pgpe_noise": first}, [3])))
    assert torch.equal(kept["pgpe_noise"], first)  # no is_init: the episode goes on
    is_init = torch.tensor([[True], [False], [False]])
    step = TensorDict({"observation": torch.randn(3, 2), "pgpe_noise": first, "is_init": is_init}, [3])
    redrawn = explorer(actor(step))["pgpe_noise"]
    assert not torch.equal(redrawn[0], first[0]) and torch.equal(redrawn[1:], first[1:])


def test_plain_sampling_draws_independently_and_evaluation_draws_nothing():
    actor = LinearActor(1, 1, init=-2.0, runs=2)
    explorer = ParameterExplorer(actor, symmetric=False, runs=2)
    explorer.streams = RunStreams(0, 2, "explore")
    env = make_minimize_env(3, episodes=4, runs=2).append_transform(explorer.make_tensordict_primer())
    policy = TensorDictSequential(actor, explorer)
    theta = collect_episodes(env, policy, 3)["pgpe_parameters"][..., 0, 0]
    assert not torch.allclose(theta[:, 0::2] + theta[:, 1::2], torch.full((2, 2), -4.0))
    state = explorer.streams.state_dict()
    from torchrl.envs.utils import ExplorationType, set_exploration_type

    with set_exploration_type(ExplorationType.DETERMINISTIC):
        evaluation = collect_episodes(env, policy, 3)
    assert (evaluation["pgpe_parameters"] == -2.0).all() and torch.equal(evaluation["action"], evaluation["loc"])
    assert torch.equal(explorer.streams.state_dict()["buffer"], state["buffer"])


# --------------------------------------------------------- closed form on the 1-D task


def closed_form(mu: float, sigma: float) -> torch.Tensor:
    """``(∂J/∂μ, ∂J/∂σ)`` of ``J(μ, σ) = E_ξ[R(μ + σ ξ)]``, summed return, noise-free reward."""
    z, w = np.polynomial.hermite_e.hermegauss(40)
    nodes, weights = torch.tensor(z), torch.tensor(w / w.sum())
    m = torch.tensor(mu, dtype=torch.float64, requires_grad=True)
    s = torch.tensor(sigma, dtype=torch.float64, requires_grad=True)
    returns = expected_linear_return(m + s * nodes, LENGTH, X0, STEP, NOISE, "noise_free", "sum")
    return torch.stack(torch.autograd.grad((weights * returns).sum(), (m, s)))


RUNS, SIGMA = 20_000, 0.3


def estimates(symmetric: bool, episodes: int, variance_weighted: bool = False, seed: int = 0) -> torch.Tensor:
    """Per-run PGPE gradients ``[RUNS, 2]`` (μ, σ) at ``μ = θ0``, ``σ = SIGMA``, on fresh episodes."""
    torch.manual_seed(seed)
    actor = LinearActor(1, 1, init=THETA0, runs=RUNS)
    explorer = ParameterExplorer(actor, symmetric=symmetric, init_param=float(np.log(SIGMA)), runs=RUNS)
    explorer.streams = RunStreams(seed, RUNS, "explore")
    env = make_minimize_env(LENGTH, episodes=episodes, runs=RUNS, x0=X0, step_size=STEP, noise_std=NOISE,
                            reward_state="noise_free", seed=seed)
    policy = TensorDictSequential(actor, explorer)
    episodes_td = collect_episodes(env.append_transform(explorer.make_tensordict_primer()), policy, LENGTH)
    estimator = PGPEEstimator(policy, episode_return="sum", variance_weighted=variance_weighted)
    return estimator(episodes_td)["gradient"].double()


def assert_matches(samples: torch.Tensor, expected: torch.Tensor, z: float = 4.0) -> None:
    mean, standard_error = samples.mean(0), samples.std(0) / len(samples) ** 0.5
    assert ((mean - expected).abs() < z * standard_error).all(), (mean, expected, standard_error)


def assert_misses(samples: torch.Tensor, expected: torch.Tensor, z: float = 8.0) -> None:
    mean, standard_error = samples.mean(0), samples.std(0) / len(samples) ** 0.5
    assert ((mean - expected).abs() > z * standard_error).any(), (mean, expected, standard_error)


@pytest.mark.e2e
def test_plain_sampling_matches_the_closed_form_and_a_missing_baseline_does_not(monkeypatch):
    """Two draws per update: the batch-mean baseline holds each return with weight 1/2, so the
    expected estimate is (N − 1)/N = 1/2 of the gradient; without it, the full gradient."""
    expected = closed_form(THETA0, SIGMA)
    samples = estimates(symmetric=False, episodes=2)
    assert_matches(samples, expected / 2)
    assert_misses(samples, expected)  # the factor is there, and the test can see it
    assert_misses(-samples, expected / 2)  # a wrong sign
    monkeypatch.setattr(sde_torchrl.objectives.pgpe, "batch_mean_baseline", lambda r: torch.zeros_like(r[..., 0]))
    no_baseline = estimates(symmetric=False, episodes=2)
    assert_misses(no_baseline, expected / 2)
    assert_matches(no_baseline, expected, z=5.0)  # unbiased without a baseline, but far noisier
    assert (no_baseline.std(0) > 2 * samples.std(0)).all()


@pytest.mark.e2e
def test_symmetric_sampling_matches_the_closed_form():
    """Pairs μ ± ε: the μ-estimate needs no baseline (unbiased, no (N − 1)/N factor); the
    σ-estimate's baseline is the mean over the P = 2 pairs: 1/2 of ∂J/∂σ. Plain sampling on the
    same 4 episodes: 3/4 of both."""
    expected = closed_form(THETA0, SIGMA)
    symmetric = estimates(symmetric=True, episodes=4)
    assert_matches(symmetric, expected * torch.tensor([1.0, 0.5], dtype=torch.float64))
    assert_misses(symmetric, expected * 0.5)
    plain = estimates(symmetric=False, episodes=4, seed=1)
    assert_matches(plain, expected * 0.75)
    assert_misses(plain, expected * torch.tensor([1.0, 0.5], dtype=torch.float64))


@pytest.mark.e2e
def test_variance_weighting_is_the_papers_step_not_the_gradient():
    expected = closed_form(THETA0, SIGMA)
    weighted = estimates(symmetric=True, episodes=4, variance_weighted=True)
    assert_matches(weighted, SIGMA**2 * expected * torch.tensor([1.0, 0.5], dtype=torch.float64))
    assert_misses(weighted, expected * torch.tensor([1.0, 0.5], dtype=torch.float64))


def test_on_the_linear_1d_task_sdes_scores_are_t_times_pgpes():
    """The same exploration, ``(θ + σ ξ) x`` for the episode, scored twice: SDE's per-step
    likelihood (eq. 20) counts the one draw ``ξ`` at each of the T steps, PGPE once."""
    policy, sde = sde_policy(LinearActor(1, 1, init=THETA0, runs=2), 1, 1, runs=2)
    sde.streams = RunStreams(0, 2, "explore")
    env = make_minimize_env(LENGTH, episodes=5, runs=2, x0=X0, reward_state="noise_free")
    episodes = collect_episodes(env.append_transform(sde.make_tensordict_primer()), policy, LENGTH)
    scores = episode_scores(EpisodeLogLikelihood(policy), episodes)
    xi, sigma = episodes["sde_noise"][..., 0, :, 0], sde.sde_sigma.detach()[..., 0]  # [2, 5, 1], [2, 1]
    mu_score, sigma_score = parameter_scores(sigma.unsqueeze(-2) * xi, sigma)
    torch.testing.assert_close(scores["actor.module.0.module.weight"][..., 0], LENGTH * mu_score, rtol=1e-4,
                               atol=1e-4)
    # σ̂ = exp(p): SDE's score of p is σ̂ times its score of σ̂
    torch.testing.assert_close(scores["sde.sigma_param"][..., 0], LENGTH * sigma.unsqueeze(-2) * sigma_score,
                               rtol=1e-4, atol=1e-4)


# ------------------------------------------------------------------- the harness


def test_runs_stacked_equal_runs_alone_bit_for_bit(tmp_path):
    budget = (*PGPE, "updates=8", "episodes_per_update=4", "eval_period=4", "seed=3")
    batched = build("runs=3", *budget).train(tmp_path / "batched")
    single = build("runs=1", "first_run=1", *budget).train(tmp_path / "single")
    run1 = [row for row in read_rows(tmp_path / "batched") if row["run"] == "1"]
    assert run1 == read_rows(tmp_path / "single") and len(run1) == 8
    for name, values in single["final_parameters"].items():
        assert values[0] == batched["final_parameters"][name][1]


@pytest.mark.parametrize("overrides", [(), ("explorer.symmetric=false", "episode_queue=8")])
def test_resume_after_crash_equals_uninterrupted(tmp_path, overrides):
    budget = (*PGPE, "runs=2", "updates=12", "episodes_per_update=4", "eval_period=5", *overrides)
    reference = build(*budget).train(tmp_path / "ref", checkpoint_period=4)
    crashed = build(*budget)
    crash_at(crashed, 10)
    with pytest.raises(Exception, match="crash at 10"):
        crashed.train(tmp_path / "resumed", checkpoint_period=4)
    torch.manual_seed(1234)
    resumed = build(*budget).train(tmp_path / "resumed", checkpoint_period=4)
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    reference.pop("wall_s"), resumed.pop("wall_s")
    assert resumed == reference and "module.1.sigma" in resumed["final_parameters"]


def test_the_guard_names_a_non_finite_sigma(tmp_path):
    from sde_torchrl.trainers.guard import NonFiniteError

    trainer = build(*PGPE, "runs=2", "updates=3")
    with torch.no_grad():
        trainer.policy.module[1].sigma[1] = float("nan")
    with pytest.raises(NonFiniteError, match="in run 1: .*") as caught:
        trainer.train(tmp_path)
    assert caught.value.runs == [1]


@pytest.mark.parametrize("overrides, message", [
    (("explorer=pgpe",), "estimator=ReinforceEstimator: explorer=pgpe and estimator=pgpe go together"),
    (("estimator=pgpe",), "explorer=SDEParams: explorer=pgpe and estimator=pgpe go together"),
    ((*PGPE, "episodes_per_update=5"), "episodes_per_update=5: an even number"),
    ((*PGPE, "episodes_per_update=2"), "episodes_per_update=2: at least 2 parameter draws"),
    ((*PGPE, "explorer.symmetric=false", "episodes_per_update=1"), "episodes_per_update=1: at least 2"),
])
def test_config_refuses_what_pgpe_cannot_learn_from(overrides, message):
    with pytest.raises(ArgumentError, match=message):
        validate(compose_config("+experiment=minimize", *overrides))


def test_estimator_refuses_other_policies_and_mixed_rows():
    actor = LinearActor(1, 1, init=-2.0)
    with pytest.raises(TypeError, match=r"^policy: got SDEActor\(TensorDictSequential, .*\); expected "
                                        r"TensorDictSequential\(actor, ParameterExplorer\(actor\)\)"):
        PGPEEstimator(make_sde_actor(actor, SDEParams(1, 1)))
    explorer = ParameterExplorer(actor)
    env = make_minimize_env(4, episodes=4).append_transform(explorer.make_tensordict_primer())
    policy = TensorDictSequential(actor, explorer)
    episodes = collect_episodes(env, policy, 4).unsqueeze(0)
    with pytest.raises(EpisodesError, match="batch shape"):
        PGPEEstimator(policy)(episodes)
    episodes = episodes[0]
    episodes["pgpe_parameters"][1, 2] += 1.0
    with pytest.raises(EpisodesError, match="changes within a row"):
        PGPEEstimator(policy)(episodes)


def test_pgpe_composes_with_the_ball_catching_env(tmp_path):
    result = run_cli("+experiment=ballcatch_reinforce", *PGPE, "runs=2", "updates=2", "episodes_per_update=2",
                     "episode_queue=4", "env.episode_length=20", "eval_episodes=1", "logger=none", run_dir=tmp_path)
    assert result.returncode == 0, result.stderr[-2000:]
    rows = read_rows(tmp_path)
    assert len(rows) == 4 and all(np.isfinite(float(row["return_mean"])) for row in rows)
