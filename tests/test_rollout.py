"""The tensor-stepping rollout produces exactly the episodes TorchRL's env.rollout produces."""

from __future__ import annotations

import pytest
import torch
from tensordict.nn import TensorDictModule, TensorDictSequential
from torchrl.envs import RewardScaling, TransformedEnv
from torchrl.envs.utils import ExplorationType, set_exploration_type

from sde_torchrl import (
    LinearActor,
    MinimizeEnv,
    MLPActor,
    SDEParams,
    make_minimize_env,
    make_sde_actor,
    nonfinite_policy,
)
from sde_torchrl.collectors.rollout import (
    collect_episodes,
    episode_matrix,
    linear_episode_env,
    linear_episode_rollout,
    noise_primer,
    parameter_rollout,
    parameter_step_env,
    tensor_rollout,
    tensor_step_env,
)
from sde_torchrl.envs.ballcatch import make_ballcatch_env
from sde_torchrl.envs.ballcatch.models import ARM_MODELS, SCRIPTED_WEIGHTS
from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.utils.checks import ArgumentError, NonFiniteInputError
from sde_torchrl.utils.rng import RunStreams


def _setup(schedule, every_n=None, actor="linear", squash=False, gaussian=None):
    runs, dim = 2, 2
    actor_module = (LinearActor(dim, dim, runs=runs, init=[-1.0, 0.0]) if actor == "linear"
                    else MLPActor(dim, dim, hidden=[3], runs=runs, init=[-1.0, 0.0]))
    actor_module.module.reset_parameters(RunStreams(0, runs, "init"))
    sde = SDEParams(dim, dim, schedule=schedule, every_n=every_n, runs=runs, gaussian_init_param=gaussian)
    sde.streams = RunStreams(0, runs, "explore")
    env = make_minimize_env(6, dim=dim, episodes=3, runs=runs, x0_spread=1.0, seed=4)
    env.append_transform(sde.make_tensordict_primer())
    return env, make_sde_actor(actor_module, sde, squash=squash, low=-1.0, high=1.0)


def _fast(collect, env, policy, steps):
    """``collect`` (a fast path) on ``env``'s base env with ``env``'s noise primer."""
    return collect(env.base_env, policy, steps, noise_primer(env))


@pytest.mark.parametrize("schedule, every_n, actor, squash, gaussian", [
    ("episode", None, "linear", False, None),
    ("step", None, "linear", False, None),
    ("every_n", 2, "mlp", False, None),
    ("episode", None, "mlp", True, -1.0),
])
def test_tensor_rollout_equals_env_rollout(schedule, every_n, actor, squash, gaussian):
    env, policy = _setup(schedule, every_n, actor, squash, gaussian)
    with torch.no_grad():
        reference = env.rollout(6, policy, break_when_any_done=False)
    env2, policy2 = _setup(schedule, every_n, actor, squash, gaussian)
    base = tensor_step_env(env2, policy2)
    assert base is env2.base_env
    with torch.no_grad():
        fast = _fast(tensor_rollout, env2, policy2, 6)
    assert fast.batch_size == reference.batch_size == (2, 3, 6)
    keys = ["observation", "loc", "action_log_prob", "action", "sde_noise", "is_init",
            ("next", "observation"), ("next", "reward"), ("next", "truncated")]
    keys += ["action_sample"] if squash else []
    keys += ["sde_gaussian_noise"] if gaussian is not None else []
    for key in keys:
        torch.testing.assert_close(fast[key], reference[key], msg=lambda m, key=key: f"{key}: {m}")


@pytest.mark.parametrize("schedule, actor", [("episode", "linear"), ("step", "linear"), ("step", "mlp")])
def test_one_draw_of_every_steps_noise_gives_the_step_by_step_episodes_bit_for_bit(schedule, actor, monkeypatch):
    """Tensor stepping draws every step's ξ at once where the primer can; the episodes, and where
    the streams stand after them, are those of drawing step by step, bit for bit."""
    results = []
    for one_draw in (True, False):
        env, policy = _setup(schedule, actor=actor)
        primer = noise_primer(env)
        if not one_draw:
            monkeypatch.setattr(primer, "episode_noise", lambda *args, **kwargs: None)
        else:
            assert primer.episode_noise((2, 3), 6) is not None
            env, policy = _setup(schedule, actor=actor)  # that look drew: start again
            primer = noise_primer(env)
        with torch.no_grad():
            episodes = _fast(tensor_rollout, env, policy, 6)
        results.append((episodes, primer.streams.normal((2, 5)), env.base_env._streams.normal((2, 5))))
    (batched, *batched_next), (stepped, *stepped_next) = results
    assert set(batched.keys(True, True)) == set(stepped.keys(True, True))
    for key in stepped.keys(True, True):
        assert torch.equal(batched[key], stepped[key]), key
    for got, want in zip(batched_next, stepped_next, strict=True):
        assert torch.equal(got, want)


def test_tensor_rollout_is_deterministic_under_deterministic_exploration():
    env, policy = _setup("episode")
    with torch.no_grad(), set_exploration_type(ExplorationType.DETERMINISTIC):
        fast = _fast(tensor_rollout, env, policy, 6)
    torch.testing.assert_close(fast["action"], policy.actor(fast.select("observation"))["loc"])


def test_envs_or_policies_it_cannot_reproduce_fall_back():
    env, policy = _setup("episode")
    assert tensor_step_env(env, policy.actor) is None  # not an SDE policy
    other = make_sde_actor(TensorDictModule(policy.actor_modules[0].module, ["observation"], ["loc"]),
                           SDEParams(2, 2, runs=2, noise_key="other_noise"))
    assert tensor_step_env(env, other) is None  # the env's primer draws another key
    env.append_transform(RewardScaling(loc=0.0, scale=2.0))  # a transform that must run
    assert tensor_step_env(env, policy) is None


def test_tensor_rollout_equals_env_rollout_on_the_ball_catching_worlds():
    from torchrl.envs import Compose as _Compose
    from torchrl.envs import InitTracker, TransformedEnv

    from sde_torchrl import BatchedBallCatchEnv

    def setup():
        torch.manual_seed(0)
        sde = SDEParams(4, 3)
        sde.streams = RunStreams(0, 3, "explore")
        env = TransformedEnv(BatchedBallCatchEnv(num_worlds=3, seed=5),
                             _Compose(InitTracker(), sde.make_tensordict_primer()))
        return env, make_sde_actor(LinearActor(3, 4, init=[-0.5, 0.5]), sde, squash=True, low=-1.0, high=1.0)

    env, policy = setup()
    with torch.no_grad():
        reference = env.rollout(40, policy, break_when_any_done=False)
    env2, policy2 = setup()
    base = tensor_step_env(env2, policy2)
    assert base is env2.base_env
    with torch.no_grad():
        fast = _fast(tensor_rollout, env2, policy2, 40)
    for key in ["observation", "action", "sde_noise", ("next", "observation"), ("next", "reward")]:
        torch.testing.assert_close(fast[key], reference[key], msg=lambda m, key=key: f"{key}: {m}")
    env.close()
    env2.close()


# ---------------------------------------------- whole episodes of fixed linear maps (fast path)
def _catching_setup(schedule="episode", bias=False, gaussian=None, runs=2, worlds=2, steps=120, every_n=None,
                    observation="raw"):
    """The paper's controller (the cup arm's scripted weights) with SDE (or REX, ``schedule="step"``)
    on ``[runs, worlds]`` worlds of the cup arm, whose contact timings these tests know; with the
    scaled observation, the weights that make the same map of the ball position."""
    env = make_ballcatch_env(worlds, runs=runs, episode_length=steps, model="cup", observation=observation)
    features = env.base_env.feature_dim
    weights = torch.as_tensor(SCRIPTED_WEIGHTS, dtype=torch.float64)
    if observation == "scaled":  # W [(x - c) / h, 1] = S x
        low, high = torch.tensor(ARM_MODELS["cup"].workspace, dtype=torch.float64).unbind(-1)
        weights = torch.cat([weights * (high - low) / 2, (weights @ ((low + high) / 2)).unsqueeze(-1)], -1)
    actor = LinearActor(features, 4, bias=bias, runs=runs)
    with torch.no_grad():
        actor.module.weight.copy_(weights.float())
    sde = SDEParams(4, features, schedule=schedule, every_n=every_n, init_param=-2.0, runs=runs,
                    gaussian_init_param=gaussian)
    sde.streams = RunStreams(0, runs, "explore")
    env.set_seed(3)
    env.append_transform(sde.make_tensordict_primer())
    return env, make_sde_actor(actor, sde, squash=True, low=-1.0, high=1.0)


@pytest.mark.parametrize(("schedule", "observation"), [("episode", "raw"), ("step", "raw"), ("episode", "scaled")])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_linear_episode_rollout_gives_the_tensor_rollout_episodes(mode, schedule, observation):
    # The worlds run the same physics under the same release jitter and noise (one ξ per episode
    # for SDE, one per step for REX); only the controller's float64 arithmetic differs (float32
    # on the step path), so the episodes agree to rounding until contacts amplify it (the ball
    # reaches the hand after ~95 steps).
    steps, before_contact = 120, 60
    env, policy = _catching_setup(schedule, observation=observation)
    env2, policy2 = _catching_setup(schedule, observation=observation)
    base = linear_episode_env(env2, policy2)
    assert base is env2.base_env
    with torch.no_grad(), set_exploration_type(mode):
        assert tensor_step_env(env, policy) is env.base_env
        reference = _fast(tensor_rollout, env, policy, steps)
        fast = _fast(linear_episode_rollout, env2, policy2, steps)
    assert set(fast.keys(True, True)) == set(reference.keys(True, True))
    assert ("sde_noise" in fast.keys()) == (mode == ExplorationType.RANDOM)
    for key in ["is_init", ("next", "done"), ("next", "truncated"), "sde_noise", "observation"]:
        if key in reference.keys(True, True):
            torch.testing.assert_close(fast[key][..., :before_contact, :], reference[key][..., :before_contact, :],
                                       rtol=0, atol=0, msg=lambda m, key=key: f"{key}: {m}")
    for key in ["loc", "action_sample", "action", ("next", "observation"), ("next", "reward")]:
        torch.testing.assert_close(fast[key][..., :before_contact, :], reference[key][..., :before_contact, :],
                                   rtol=1e-4, atol=1e-4, msg=lambda m, key=key: f"{key}: {m}")
    torch.testing.assert_close(fast["action_log_prob"][..., :before_contact],
                               reference["action_log_prob"][..., :before_contact], rtol=1e-4, atol=1e-4)
    torch.testing.assert_close(fast["next", "reward"].mean((-1, -2)), reference["next", "reward"].mean((-1, -2)),
                               rtol=0, atol=0.02)
    env.close()
    env2.close()


def test_linear_episodes_freeze_a_dropped_ball_as_the_step_path_does():
    env, _ = _catching_setup(steps=200)
    env2, _ = _catching_setup(steps=200)  # the same release jitter
    with torch.no_grad():
        reference = env.rollout(200, lambda td: td.set("action", torch.zeros(2, 2, 4)), break_when_any_done=False)
    observations, samples, rewards = env2.base_env.linear_episodes(torch.zeros(2, 2, 4, 3), 200)
    assert samples.abs().max() == 0
    torch.testing.assert_close(observations[..., 1:, :], reference["next", "observation"])
    torch.testing.assert_close(rewards, reference["next", "reward"])
    grounded = observations[..., 1:, 2] < ARM_MODELS["cup"].ground_z  # after step t
    assert grounded[..., -1].all()  # zero torques drop the ball
    first = grounded.float().argmax(-1)
    for r in range(2):
        for w in range(2):
            t = int(first[r, w])
            assert 50 < t < 190 and (rewards[r, w, t:] == -3.0).all()
            assert (observations[r, w, t + 1:] == observations[r, w, -1]).all()  # frozen
    env.close()
    env2.close()


def test_linear_episodes_reject_bad_matrices():
    env, _ = _catching_setup()
    with pytest.raises(ValueError, match=r"matrices must have shape \(2, 2, 4, 3\)"):
        env.base_env.linear_episodes(torch.zeros(2, 4, 3), 10)
    bad = torch.zeros(2, 2, 4, 3)
    bad[0, 1, 2, 0] = float("nan")
    with pytest.raises(ValueError, match=r"non-finite values in worlds \[1\]"):
        env.base_env.linear_episodes(bad, 10)
    with pytest.raises(ValueError, match="steps must be >= 1"):
        env.base_env.linear_episodes(torch.zeros(2, 2, 4, 3), 0)
    env.close()


@pytest.mark.parametrize("setup, usable", [
    (dict(), True),
    (dict(bias=True), False),
    (dict(schedule="step"), True),
    (dict(schedule="every_n", every_n=5), False),
    (dict(gaussian=-1.0), False),
    (dict(schedule="step", gaussian=-1.0), False),
])
def test_linear_episode_path_needs_a_bias_free_linear_map_fixed_per_episode(setup, usable):
    env, policy = _catching_setup(**setup)
    assert (linear_episode_env(env, policy) is env.base_env) == usable
    env.close()


class _StepsOnly(MinimizeEnv):
    """The minimisation task without its whole-episode method: an env that only steps tensors."""

    linear_episodes = None  # a protocol's method set to None is absent to isinstance


def test_linear_episode_path_needs_an_env_that_runs_linear_episodes():
    env, policy = _setup("episode")
    assert linear_episode_env(env, policy) is env.base_env
    stepped = TransformedEnv(_StepsOnly(episodes=3, dim=2, runs=2), env.transform.clone())
    assert tensor_step_env(stepped, policy) is stepped.base_env
    assert linear_episode_env(stepped, policy) is None


@pytest.mark.parametrize("squash", [False, True])
@pytest.mark.parametrize("schedule", ["episode", "step"])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_linear_minimize_episodes_are_the_tensor_rollout_episodes(mode, schedule, squash):
    # Tensor stepping acts with Θ x + Θ̂ x, the whole-episode path with (Θ + Θ̂) x: float32
    # rounding apart; the random draws (start jitter, state noise, ξ) are the same numbers.
    env, policy = _setup(schedule, squash=squash)
    env2, policy2 = _setup(schedule, squash=squash)
    assert linear_episode_env(env2, policy2) is env2.base_env
    with torch.no_grad(), set_exploration_type(mode):
        reference = _fast(tensor_rollout, env, policy, 6)
        fast = _fast(linear_episode_rollout, env2, policy2, 6)
    assert set(fast.keys(True, True)) == set(reference.keys(True, True))
    for key in ["is_init", ("next", "done"), ("next", "truncated"), "sde_noise"]:
        if key in reference.keys(True, True):
            assert torch.equal(fast[key], reference[key]), key
    for key in fast.keys(True, True):
        torch.testing.assert_close(fast[key], reference[key], msg=lambda m, key=key: f"{key}: {m}")
    for streams, twin in ((policy.sde.streams, policy2.sde.streams), (env.base_env._streams, env2.base_env._streams)):
        assert torch.equal(streams.normal((2, 5)), twin.normal((2, 5)))  # both paths leave the streams alike


@pytest.mark.parametrize("reward_state", ["noisy", "noise_free"])
def test_linear_minimize_episodes_follow_the_transition(reward_state):
    """Per-step maps: each step is ``transition`` under ``u_t = M_t x_t``, the draws in its order."""
    kwargs = dict(episodes=3, dim=2, runs=2, x0_spread=1.0, seed=5, reward_state=reward_state)
    env, env2 = MinimizeEnv(**kwargs), MinimizeEnv(**kwargs)
    maps = 0.3 * torch.randn(2, 3, 4, 2, 2)
    states, samples, rewards = env.linear_episodes(maps, 4, squash=False)
    x = env2.initial_state()
    for t in range(4):
        u = (x.unsqueeze(-2) @ maps[..., t, :, :].transpose(-1, -2)).squeeze(-2)
        x_next, reward = env2.transition(x, u)
        for got, expected in ((states[..., t, :], x), (samples[..., t, :], u), (rewards[..., t, :], reward),
                              (states[..., t + 1, :], x_next)):
            assert torch.equal(got, expected)
        x = x_next


def test_linear_minimize_episodes_refuse_bad_input():
    env = MinimizeEnv(episodes=3, dim=2, runs=2)
    with pytest.raises(ValueError, match=r"matrices must have shape \(2, 3, 2, 2\) or \(2, 3, 4, 2, 2\)"):
        env.linear_episodes(torch.zeros(2, 3, 2), 4)
    with pytest.raises(ArgumentError, match="steps"):
        env.linear_episodes(torch.zeros(2, 3, 2, 2), 0)
    diverged = torch.zeros(2, 3, 4, 2, 2)
    diverged[1, 2, 3] = float("nan")
    with pytest.raises(NonFiniteInputError, match="action: NaN/inf in run 1 episode 2 step 3"):
        env.linear_episodes(diverged, 4)
    with nonfinite_policy("guarded"):
        states, _, rewards = env.linear_episodes(diverged, 4)
    assert states[1, 2, -1].isnan().all() and rewards[1, 2, -1].isnan().all() and rewards[0].isfinite().all()


@pytest.mark.parametrize("schedule", ["episode", "step"])
def test_episode_matrix_is_theta_plus_sigma_noise_and_draws_like_the_primer(schedule):
    """The maps use the noise the env's primer gives an episode of ``steps`` steps (a draw at the
    reset, one after each step but the last) and leave the streams where ``env.rollout`` does."""
    runs, steps = 2, 5
    env, policy = _catching_setup(schedule, runs=runs, worlds=3, steps=steps)
    sde, primer = policy.sde, noise_primer(env)
    weight = policy.actor_modules[0].module.weight.detach()
    matrix, noise = episode_matrix(primer, sde, weight, torch.Size([runs, 3]), steps)
    after_matrix = sde.streams.normal((runs, 7))

    sde.streams.load_state_dict(RunStreams(0, runs, "explore").state_dict())
    with torch.no_grad():
        episodes = env.rollout(steps, policy, break_when_any_done=False)
    expected = episodes["sde_noise"][:, :, 0] if schedule == "episode" else episodes["sde_noise"]
    torch.testing.assert_close(noise, expected, rtol=0, atol=0)  # [runs, 3, (steps,) 4, 3]
    torch.testing.assert_close(sde.streams.normal((runs, 7)), after_matrix, rtol=0, atol=0)
    sigma = sde.sde_sigma.detach()[:, None]
    theta = weight[:, None]
    if schedule == "step":
        sigma, theta = sigma[:, None], theta[:, None]
    torch.testing.assert_close(matrix, theta + sigma * noise)
    with set_exploration_type(ExplorationType.DETERMINISTIC):
        deterministic, none = episode_matrix(primer, sde, weight, torch.Size([runs, 3]), steps)
    assert none is None and torch.equal(deterministic, weight[:, None].expand(runs, 3, 4, 3))
    env.close()


def test_per_step_maps_run_like_one_map_per_episode():
    """The same map given once per step gives the episodes of one map per episode, bit for bit."""
    env, _ = _catching_setup(steps=150)
    env2, _ = _catching_setup(steps=150)
    matrices = torch.as_tensor(SCRIPTED_WEIGHTS, dtype=torch.float32) + 0.1 * torch.randn(2, 2, 4, 3)
    per_episode = env.base_env.linear_episodes(matrices, 150)
    per_step = env2.base_env.linear_episodes(matrices.unsqueeze(2).expand(2, 2, 150, 4, 3), 150)
    for expected, got in zip(per_episode, per_step, strict=True):
        assert torch.equal(got, expected)
    with pytest.raises(ValueError, match=r"or \(2, 2, 10, 4, 3\), got \(2, 2, 9, 4, 3\)"):
        env.base_env.linear_episodes(torch.zeros(2, 2, 9, 4, 3), 10)
    bad = torch.zeros(2, 2, 10, 4, 3)
    bad[1, 0, 7, 3, 2] = float("inf")
    with pytest.raises(ValueError, match=r"non-finite values in worlds \[2\]"):
        env.base_env.linear_episodes(bad, 10)
    env.close()
    env2.close()


# ------------------------------------------------------------------ parameter-exploring episodes
def _pgpe_setup(actor="linear", symmetric=True, squash=False, streams=True):
    """PGPE's policy and env as the trainer builds them: run-stacked, with the explorer's primer."""
    runs, dim = 2, 2
    actor_module = (LinearActor(dim, dim, bias=False, runs=runs, init=[-1.0, 0.0]) if actor == "linear"
                    else MLPActor(dim, dim, hidden=[3], runs=runs, init=[-1.0, 0.0]))
    actor_module.module.reset_parameters(RunStreams(0, runs, "init"))
    explorer = ParameterExplorer(actor_module, symmetric=symmetric, squash=squash, runs=runs, init_param=-0.5)
    explorer.streams = RunStreams(0, runs, "explore") if streams else None
    env = make_minimize_env(6, dim=dim, episodes=4, runs=runs, x0_spread=1.0, seed=4)
    env.append_transform(explorer.make_tensordict_primer())
    return env, TensorDictSequential(actor_module, explorer)


@pytest.mark.parametrize("actor, symmetric, squash", [
    ("linear", True, False), ("linear", False, True), ("mlp", True, False), ("mlp", False, True),
])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_parameter_rollout_equals_env_rollout(actor, symmetric, squash, mode):
    env, policy = _pgpe_setup(actor, symmetric, squash)
    env2, policy2 = _pgpe_setup(actor, symmetric, squash)
    assert parameter_step_env(env2, policy2) is env2.base_env
    with set_exploration_type(mode), torch.no_grad():
        for _ in range(2):  # the second collection starts where the first left the streams
            reference = env.rollout(6, policy, break_when_any_done=False)
            fast = parameter_rollout(env2.base_env, policy2, 6)
            assert fast.batch_size == reference.batch_size == (2, 4, 6)
            assert set(fast.keys(True, True)) <= set(reference.keys(True, True))
            expected = {"observation", "loc", "action", "action_sample", "pgpe_parameters", "is_init",
                        ("next", "observation"), ("next", "reward"), ("next", "done"), ("next", "truncated")}
            expected |= {"pgpe_noise"} if mode == ExplorationType.RANDOM else set()
            assert set(fast.keys(True, True)) == expected
            for key in fast.keys(True, True):  # bit for bit: the same draws and the same arithmetic
                assert torch.equal(fast[key], reference[key]), key
    theta = fast["pgpe_parameters"]
    if mode == ExplorationType.RANDOM:
        assert bool((theta[..., 1:, :] == theta[..., :1, :]).all())  # held for the whole episode
        assert not torch.equal(theta[:, 0, 0], theta[:, 1, 0])  # one draw per episode
    else:
        assert torch.equal(fast["action_sample"], fast["loc"])


def test_parameter_path_needs_pgpes_policy_and_an_init_tracker():
    env, policy = _pgpe_setup()
    assert parameter_step_env(env, policy) is env.base_env
    assert parameter_step_env(env, policy.module[0]) is None  # the actor alone: no exploration
    sde_env, sde_policy = _setup("episode")
    assert parameter_step_env(sde_env, sde_policy) is None  # SDE's policy has a path of its own
    env_global, policy_global = _pgpe_setup(streams=False)  # global generator: the primer draws from it first
    assert parameter_step_env(env_global, policy_global) is None
    untracked = TransformedEnv(env.base_env, policy.module[1].make_tensordict_primer())  # no is_init
    assert parameter_step_env(untracked, policy) is None
    env.append_transform(RewardScaling(loc=0.0, scale=2.0))  # a transform that must run
    assert parameter_step_env(env, policy) is None


def test_linear_episode_controller_is_the_explorers_controller_bit_for_bit():
    actor = LinearActor(3, 2, bias=False, runs=4, init=[-1.0, 1.0])
    explorer = ParameterExplorer(actor, runs=4)
    theta, x = torch.randn(4, 5, 6), torch.randn(4, 5, 3)
    assert torch.equal(explorer.episode_controller(theta)(x), explorer.controller(theta, [x]))
    explorer = ParameterExplorer(LinearActor(3, 2, bias=False), symmetric=False)  # unstacked
    theta, x = torch.randn(7, 6), torch.randn(7, 3)
    assert torch.equal(explorer.episode_controller(theta)(x), explorer.controller(theta, [x]))


# ------------------------------------------------------------------------------ the entry point
def _assert_same_episodes(got, expected):
    assert got.batch_size == expected.batch_size
    assert set(got.keys(True, True)) == set(expected.keys(True, True))
    for key in expected.keys(True, True):
        assert torch.equal(got[key], expected[key]), key


@pytest.mark.parametrize("schedule", ["episode", "step"])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_collect_episodes_steps_tensors_where_it_can(schedule, mode):
    env, policy = _setup(schedule, actor="mlp")
    env2, policy2 = _setup(schedule, actor="mlp")
    with set_exploration_type(mode):
        with torch.no_grad():
            reference = _fast(tensor_rollout, env, policy, 6)
        episodes = collect_episodes(env2, policy2, 6)
    _assert_same_episodes(episodes, reference)
    assert not episodes["loc"].requires_grad  # collected without a graph


@pytest.mark.parametrize("setup", [lambda: _setup("step"), lambda: _setup("step", actor="mlp"), lambda: _pgpe_setup(),
                                   lambda: _catching_setup("episode", steps=30)])
def test_episodes_of_a_fast_path_are_tensors_autograd_can_score(setup):
    """The fast paths run in inference mode; what they return, and the streams they leave, are
    ordinary tensors: the log-likelihood of the episodes has a gradient."""
    env, policy = setup()
    episodes = collect_episodes(env, policy, 6)
    assert not any(value.is_inference() for value in episodes.values(True, True))
    for streams in (noise_primer(env).streams if noise_primer(env) else None, env.base_env._streams):
        assert streams is None or not streams.normal((streams.runs, 1)).is_inference()
    parameter = next(p for p in policy.parameters() if p.requires_grad)
    (parameter.sum() * episodes["loc"].sum()).backward()
    assert parameter.grad is not None


@pytest.mark.parametrize("schedule", ["episode", "step"])
@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
@pytest.mark.parametrize("task", ["catching", "minimize"])
def test_collect_episodes_runs_linear_episodes_where_it_can(mode, schedule, task):
    def setup():
        return _catching_setup(schedule, steps=30) if task == "catching" else _setup(schedule)
    (env, policy), (env2, policy2) = setup(), setup()
    with set_exploration_type(mode):
        with torch.no_grad():
            reference = _fast(linear_episode_rollout, env, policy, 30)
        _assert_same_episodes(collect_episodes(env2, policy2, 30), reference)
    env.close()
    env2.close()


@pytest.mark.parametrize("mode", [ExplorationType.RANDOM, ExplorationType.DETERMINISTIC])
def test_collect_episodes_steps_pgpe_episodes_where_it_can(mode):
    env, policy = _pgpe_setup()
    env2, policy2 = _pgpe_setup()
    with set_exploration_type(mode):
        with torch.no_grad():
            reference = parameter_rollout(env.base_env, policy, 6)
        episodes = collect_episodes(env2, policy2, 6)
    _assert_same_episodes(episodes, reference)
    assert not episodes["pgpe_parameters"].requires_grad  # collected without a graph


@pytest.mark.parametrize("fast", [True, False])
def test_collect_episodes_falls_back_to_env_rollout(fast):
    env, policy = _setup("episode")
    env2, policy2 = _setup("episode")
    if fast:  # a transform that must run rules the fast paths out
        env.append_transform(RewardScaling(loc=0.0, scale=2.0))
        env2.append_transform(RewardScaling(loc=0.0, scale=2.0))
    with torch.no_grad():
        reference = env.rollout(6, policy, break_when_any_done=False)
    _assert_same_episodes(collect_episodes(env2, policy2, 6, fast=fast), reference)


def test_collect_episodes_needs_a_positive_length():
    env, policy = _setup("episode")
    with pytest.raises(ValueError, match="steps=0: a positive integer"):
        collect_episodes(env, policy, 0)
