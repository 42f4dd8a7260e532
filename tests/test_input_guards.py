"""Input guards of the Python API: the estimators and MinimizeEnv refuse what would give a NaN
gradient, a cryptic torch error or a silently wrong estimate, naming the key and the fix."""

from __future__ import annotations

import pytest
import torch
from _helpers import compose_config, own_stderr_lines, run_cli, sde_policy
from tensordict import TensorDict
from tensordict.nn import TensorDictSequential
from torchrl.envs import Compose, InitTracker, StepCounter, TransformedEnv

from sde_torchrl import (
    ENACEstimator,
    GPOMDPEstimator,
    LinearActor,
    MinimizeEnv,
    ReinforceEstimator,
    SDEActor,
    SDEParams,
    make_minimize_env,
    nonfinite_policy,
)
from sde_torchrl.collectors.rollout import collect_episodes
from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.schemas.train import validate
from sde_torchrl.objectives.estimators import (
    EpisodesError,
    MissingEpisodesKeyError,
    NonFiniteEpisodesError,
    enac_gradient,
)
from sde_torchrl.utils.checks import ArgumentError, NonFiniteInputError

ESTIMATORS = [ReinforceEstimator, ENACEstimator]
RUNS, EPISODES, LENGTH = 2, 6, 4


def _policy(runs=RUNS):
    return sde_policy(LinearActor(1, 1, init=-2.0, runs=runs), 1, 1, runs=runs)[0]


def _env(policy, length=LENGTH, runs=RUNS, episodes=EPISODES):
    env = make_minimize_env(length, episodes=episodes, runs=runs, x0=2.0, x0_spread=1.0)
    return env.append_transform(policy.sde.make_tensordict_primer())


def _episodes(policy, fast=True):
    torch.manual_seed(0)
    return collect_episodes(_env(policy), policy, LENGTH, fast=fast)


# ------------------------------------------------------------------------------ non-finite input


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
@pytest.mark.parametrize("key", ["observation", "action", ("next", "reward")])
@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_non_finite_input_names_the_key_the_episodes_and_the_fix(estimator_cls, key, bad, capfd):
    policy = _policy()
    episodes = _episodes(policy)
    episodes.get(key)[1, 2, 3] = bad
    episodes.get(key)[1, 4, 0] = bad
    with pytest.raises(NonFiniteEpisodesError) as info:
        estimator_cls(policy)(episodes)
    message = str(info.value)
    assert message.startswith(f"episodes key {key!r}: NaN/inf in run 1 episode 2, run 1 episode 4;"), message
    assert 'with sde_torchrl.nonfinite_policy("guarded"):' in message and info.value.key == key
    assert isinstance(info.value, NonFiniteInputError) and isinstance(info.value, ValueError)
    assert "MKL" not in capfd.readouterr().out  # ENAC never reached lstsq


def test_non_finite_features_are_named_by_their_key():
    policy = _policy()
    estimator = ReinforceEstimator(policy)
    estimator.set_keys(features="my_features")
    episodes = _episodes(policy)
    episodes["my_features"] = episodes["observation"].clone()
    episodes["my_features"][0, 5, 1] = float("-inf")
    with pytest.raises(NonFiniteEpisodesError, match=r"^episodes key 'my_features': NaN/inf in run 0 episode 5;"):
        estimator(episodes)


def test_without_runs_the_message_names_episodes_only():
    policy = _policy(runs=None)
    torch.manual_seed(0)
    episodes = collect_episodes(_env(policy, runs=None), policy, LENGTH)
    episodes["observation"][3, 1] = float("nan")
    with pytest.raises(NonFiniteEpisodesError, match=r"^episodes key 'observation': NaN/inf in episode 3;"):
        ReinforceEstimator(policy)(episodes)


def test_finite_input_whose_scores_overflow_names_the_parameter():
    policy = _policy()
    episodes = _episodes(policy)
    episodes["action"][0, 1, 2] = 3e38  # finite, but its squared deviation is not
    with pytest.raises(NonFiniteEpisodesError) as info:
        ReinforceEstimator(policy)(episodes)
    assert str(info.value).startswith("scores of parameter ") and "run 0 episode 1;" in str(info.value)
    assert "max_grad_norm" in str(info.value) and info.value.key == "scores"


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_guarded_policy_gives_nan_for_the_runs_concerned_only(estimator_cls, capfd):
    policy = _policy()
    episodes = _episodes(policy)
    clean = estimator_cls(policy)(episodes)["gradient"]
    episodes["observation"][1, 2, 3] = float("nan")
    with nonfinite_policy("guarded"):
        gradient = estimator_cls(policy)(episodes)["gradient"]
    assert torch.isnan(gradient[1]).all()
    if estimator_cls is ENACEstimator:  # runs are solved independently
        torch.testing.assert_close(gradient[0], clean[0], rtol=0, atol=0)
    else:  # REINFORCE's scores of run 0 do not see run 1
        assert torch.isfinite(gradient[0]).all()
    captured = capfd.readouterr()
    assert "MKL" not in captured.out + captured.err and "INTERNAL ASSERT" not in captured.out + captured.err


def test_enac_gradient_never_hands_nan_to_lstsq(capfd):
    scores = torch.randn(3, 8, 2)
    returns = torch.randn(3, 8)
    reference = enac_gradient(scores, returns)
    scores[1, 4, 0] = float("nan")
    returns[2, 0] = float("inf")
    w, average, rank, condition = enac_gradient(scores, returns)
    assert torch.isnan(w[1:]).all() and torch.isnan(average[1:]).all() and torch.isnan(condition[1:]).all()
    assert rank.tolist() == [3, 0, 0]
    torch.testing.assert_close(w[0], reference[0][0], rtol=0, atol=0)
    captured = capfd.readouterr()
    assert "MKL" not in captured.out + captured.err


# ------------------------------------------------------------------------------ shapes, keys, dtypes


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
@pytest.mark.parametrize("index, shape", [((slice(None), slice(0, 0)), (2, 0, 4)),
                                          ((Ellipsis, slice(0, 0)), (2, 6, 0)),
                                          ((0, 0), (4,))])
def test_empty_or_flat_batch_names_the_shape_and_what_is_expected(estimator_cls, index, shape):
    policy = _policy()
    episodes = _episodes(policy)[index]
    with pytest.raises(EpisodesError, match=rf"batch shape \({', '.join(map(str, shape))},?\); the estimators need "
                                            r"\[\*runs, N, T\] with N >= 1 episodes of T >= 1 steps"):
        estimator_cls(policy)(episodes)


def test_a_tensor_instead_of_episodes_is_named():
    policy = _policy()
    with pytest.raises(TypeError, match=r"episodes: got Tensor; expected a TensorDict shaped \[\*runs, N, T\]"):
        ReinforceEstimator(policy)(torch.zeros(2, 6, 4))


def test_missing_key_names_the_key_and_set_keys():
    policy = _policy()
    with pytest.raises(MissingEpisodesKeyError) as info:
        ReinforceEstimator(policy)(_episodes(policy).exclude("action"))
    assert str(info.value).startswith("episodes lack key 'action'; the estimator reads ")
    assert "set_keys" in str(info.value) and isinstance(info.value, KeyError)


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_float64_observation_with_a_float32_policy_names_both_dtypes_and_the_fix(estimator_cls):
    policy = _policy()
    episodes = _episodes(policy)
    episodes["observation"] = episodes["observation"].double()
    with pytest.raises(EpisodesError) as info:
        estimator_cls(policy)(episodes)
    message = str(info.value)
    assert message.startswith("episodes key 'observation' is torch.float64 but the policy's parameters are "
                              "torch.float32;"), message
    assert "DoubleToFloat" in message and "policy.to(torch.float64)" in message and info.value.key == "observation"


def test_features_beyond_the_actor_inputs_are_converted_like_the_explorer_does():
    policy = _policy()
    episodes = _episodes(policy)
    expected = ReinforceEstimator(policy)(episodes)["gradient"]
    estimator = ReinforceEstimator(policy)
    estimator.set_keys(features="my_features")
    episodes["my_features"] = episodes["observation"].double()
    torch.testing.assert_close(estimator(episodes)["gradient"], expected, rtol=0, atol=0)


def test_a_float64_policy_takes_float64_episodes():
    policy = _policy()
    episodes = _episodes(policy).apply(lambda t: t.double() if t.is_floating_point() else t)
    gradient = ReinforceEstimator(policy.double())(episodes)["gradient"]
    assert gradient.dtype == torch.float64 and torch.isfinite(gradient).all()


# ------------------------------------------------------------------------------ one episode per row


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_rows_holding_a_reset_are_refused_naming_row_and_step(estimator_cls):
    policy = _policy()
    torch.manual_seed(0)
    episodes = _env(policy).rollout(2 * LENGTH, policy, break_when_any_done=False)  # two episodes per row
    with pytest.raises(EpisodesError) as info:
        estimator_cls(policy)(episodes)
    message = str(info.value)
    assert message.startswith("episodes row run 0 episode 0 holds more than one episode: a new episode starts at "
                              f"step {LENGTH} of {2 * LENGTH} ('is_init' is set there)"), message
    assert "break_when_any_done=False" in message and "StepCounter(T)" in message and "collect_episodes" in message
    with pytest.raises(EpisodesError, match=rf"an episode ends at step {LENGTH - 1} of {2 * LENGTH} "
                                            r"\(\('next', 'done'\) is set there\)"):
        estimator_cls(policy)(episodes.exclude("is_init"))


def test_a_reset_in_a_later_row_names_that_row():
    policy = _policy()
    episodes = _episodes(policy)
    episodes["is_init"][1, 3, 2] = True
    with pytest.raises(EpisodesError, match=r"row run 1 episode 3 holds more than one episode: a new episode starts "
                                            r"at step 2 of 4"):
        ReinforceEstimator(policy)(episodes)


@pytest.mark.parametrize("fast", [True, False])
def test_fixed_horizon_collections_pass(fast):
    """What the trainer collects: ``is_init`` only at step 0, done/truncated only at the last step."""
    policy = _policy()
    episodes = _episodes(policy, fast=fast)
    assert episodes["is_init"][..., 0, :].all() and not episodes["is_init"][..., 1:, :].any()
    assert episodes["next", "done"][..., -1, :].all() and not episodes["next", "done"][..., :-1, :].any()
    assert torch.isfinite(ReinforceEstimator(policy)(episodes)["gradient"]).all()


def test_gym_episodes_held_absorbing_pass():
    """An episode that ends early is held until T (sde_torchrl.envs.gym): not a reset inside the row."""
    from sde_torchrl.envs.gym import GymRunsEnv

    policy, sde = sde_policy(LinearActor(2, 1), 1, 2)
    base = GymRunsEnv("MountainCarContinuous-v0", episodes=3, runs=1, gym_kwargs={"max_episode_steps": 5})
    env = TransformedEnv(base, Compose(StepCounter(10), InitTracker(), sde.make_tensordict_primer()))
    with torch.no_grad():
        episodes = env.rollout(10, policy, break_when_any_done=False)
    assert bool((episodes["next", "reward"][..., 5:, :] == 0).all())  # held after the time limit
    assert not episodes["next", "done"][..., :-1, :].any() and not episodes["is_init"][..., 1:, :].any()
    ReinforceEstimator(policy)(episodes)


# ------------------------------------------------------------------------------ wiring


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_sde_params_instead_of_the_policy_names_the_expected_form(estimator_cls):
    with pytest.raises(TypeError, match=r"^policy: got SDEParams; expected "
                                        r"make_sde_actor\(actor, SDEParams\(\.\.\.\)\), an SDEActor$"):
        estimator_cls(SDEParams(1, 1))


def _sde_actor_over(*modules):
    """An SDEActor over other modules than (actor, SDEParams), bypassing make_sde_actor's checks."""
    sde = SDEParams(1, 1)
    return SDEActor(TensorDictSequential(*[sde if m is SDEParams else m for m in modules]), sde)


@pytest.mark.parametrize("policy, given", [
    (LinearActor(1, 1), "got LinearActor; expected make_sde_actor"),
    (TensorDictSequential(LinearActor(1, 1), SDEParams(1, 1)), "got TensorDictSequential; expected make_sde_actor"),
    (_sde_actor_over(SDEParams), r"an SDEActor over TensorDictSequential\(SDEParams\); expected an actor, then "
                                 r"SDEParams: build it with make_sde_actor\(actor, sde\)"),
    (_sde_actor_over(SDEParams, LinearActor(1, 1)), r"an SDEActor over TensorDictSequential\(SDEParams, "
                                                    r"LinearActor\); expected an actor, then SDEParams"),
])
def test_other_wrong_policies_name_what_was_given(policy, given):
    with pytest.raises(TypeError, match=rf"^policy: {given}"):
        ReinforceEstimator(policy)


# ------------------------------------------------------------------------------ MinimizeEnv


@pytest.mark.parametrize("kwargs, message", [
    ({"x0": float("nan")}, "x0=nan: a finite number or a list of dim=1 finite numbers"),
    ({"x0": float("inf")}, "x0=inf: a finite number"),
    ({"x0": [1.0, float("-inf")], "dim": 2}, r"x0=\[1.0, -inf\]: a finite number or a list of dim=2"),
    ({"x0": [1.0, 2.0, 3.0], "dim": 2}, r"x0=\[1.0, 2.0, 3.0\]: a finite number or a list of dim=2"),
    ({"step_size": float("nan")}, "step_size=nan: a finite number"),
    ({"step_size": float("inf")}, "step_size=inf: a finite number"),
    ({"noise_std": float("nan")}, "noise_std=nan: a finite number >= 0"),
    ({"noise_std": float("inf")}, "noise_std=inf: a finite number >= 0"),
])
def test_minimize_env_refuses_non_finite_parameters(kwargs, message):
    with pytest.raises(ArgumentError, match=f"^{message}"):
        MinimizeEnv(**kwargs)


@pytest.mark.parametrize("runs, entry", [(2, "run 1 episode 2"), (None, "episode 2")])
def test_minimize_env_refuses_non_finite_actions_naming_runs_and_episodes(runs, entry):
    env = MinimizeEnv(episodes=3, runs=runs)
    td = env.reset()
    td["action"] = torch.zeros(*env.batch_size, 1)
    td["action"][..., 2, :] = float("nan") if runs is None else 0.0
    if runs is not None:
        td["action"][1, 2] = float("inf")
    with pytest.raises(NonFiniteInputError, match=rf"^action: NaN/inf in {entry}; the policy produced them"):
        env.step(td)
    with pytest.raises(NonFiniteInputError, match=rf"^action: NaN/inf in {entry};"):
        env.transition(td["observation"], td["action"])
    with nonfinite_policy("guarded"):
        assert not torch.isfinite(env.step(td)["next", "observation"]).all()



@pytest.mark.parametrize("key, shape, expected", [
    ("action", (2, 6, 4), r"'action' has shape \(2, 6, 4\), expected \(2, 6, 4, 1\): .*action_dim=1"),
    ("observation", (2, 6, 4, 2), r"'observation' has shape \(2, 6, 4, 2\), expected \(2, 6, 4, 1\): .*feature_dim=1"),
])
def test_features_and_action_samples_must_fit_the_explorer(key, shape, expected):
    policy = _policy()
    episodes = _episodes(policy)
    episodes.set(key, torch.zeros(shape))
    with pytest.raises(EpisodesError, match=expected):
        ReinforceEstimator(policy)(episodes)


def test_an_action_sample_that_would_broadcast_is_refused():
    """A size-1 action dimension against action_dim=2 broadcast silently before the guard."""
    policy, _ = sde_policy(LinearActor(1, 2), 2, 1)
    episodes = TensorDict({"observation": torch.randn(4, 5, 1), "action": torch.randn(4, 5, 1),
                           ("next", "reward"): torch.randn(4, 5, 1)}, [4, 5])
    with pytest.raises(EpisodesError, match=r"'action' has shape \(4, 5, 1\), expected \(4, 5, 2\)"):
        ReinforceEstimator(policy)(episodes)


@pytest.mark.parametrize("estimator_cls", [*ESTIMATORS, GPOMDPEstimator])
def test_a_reward_that_is_not_one_number_per_step_is_refused(estimator_cls):
    """A reward with three terms per step would be summed into three times the gradient."""
    policy = _policy()
    episodes = _episodes(policy)
    episodes.set(("next", "reward"), episodes.get(("next", "reward")).expand(RUNS, EPISODES, LENGTH, 3).clone())
    with pytest.raises(EpisodesError, match=r"episodes key \('next', 'reward'\) has shape \(2, 6, 4, 3\), expected "
                                            r"\(2, 6, 4, 1\): one reward per step"):
        estimator_cls(policy)(episodes)


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_integer_observations_are_refused_with_the_fix(estimator_cls):
    policy = _policy()
    episodes = _episodes(policy)
    episodes.set("observation", episodes.get("observation").round().long())
    with pytest.raises(EpisodesError, match="episodes key 'observation' is torch.int64; the controller needs "
                                            "floating-point inputs"):
        estimator_cls(policy)(episodes)


@pytest.mark.parametrize("estimator_cls", ESTIMATORS)
def test_episodes_of_another_runs_count_are_refused(estimator_cls):
    three = _policy(runs=3)
    episodes = collect_episodes(_env(three, runs=3), three, LENGTH)
    with pytest.raises(EpisodesError, match=r"episodes have batch shape \(3, 6, 4\), but the policy's parameters are "
                                            r"stacked over runs=2: expected \[2, N, T\]"):
        estimator_cls(_policy(runs=2))(episodes)


def test_pgpe_refuses_a_reward_with_terms_and_another_runs_count():
    from sde_torchrl import ParameterExplorer, PGPEEstimator

    actor = LinearActor(1, 1, init=-2.0, runs=RUNS)
    policy = TensorDictSequential(actor, ParameterExplorer(actor, runs=RUNS))
    env = make_minimize_env(LENGTH, episodes=EPISODES, runs=RUNS, x0=2.0)
    env.append_transform(policy.module[-1].make_tensordict_primer())
    episodes = collect_episodes(env, policy, LENGTH)
    PGPEEstimator(policy)(episodes)  # as collected: accepted
    bad = episodes.clone()
    bad.set(("next", "reward"), bad.get(("next", "reward")).expand(RUNS, EPISODES, LENGTH, 2).clone())
    with pytest.raises(EpisodesError, match="one reward per step"):
        PGPEEstimator(policy)(bad)
    with pytest.raises(EpisodesError, match="stacked over runs=2"):
        PGPEEstimator(policy)(episodes[:1])


# ------------------------------------------------------------------------------ PPO, A2C and SAC configs

#: A SAC job on Pendulum-v1 of 2 updates × 2 rounds × 8 env steps.
SAC = ("algorithm=sac", "env=gym", "updates=2", "algorithm.rounds_per_update=2", "algorithm.train_freq=8",
       "algorithm.batch_size=16", "algorithm.buffer_size=100")


def _refusal(*overrides: str) -> str:
    """The one line that refuses the config of ``overrides``."""
    with pytest.raises(Exception) as info:
        validate(compose_config(*overrides))
    return describe_error(info.value)


def test_sac_refuses_a_warm_up_as_long_as_the_job():
    """``learning_starts`` at or beyond the job's env steps would run to the end with grad_norm 0 in every row."""
    validate(compose_config(*SAC, "algorithm.learning_starts=24"))  # the last round takes gradient steps
    for starts in (32, 40):
        assert _refusal(*SAC, f"algorithm.learning_starts={starts}") == (
            f"algorithm.learning_starts={starts}: below the job's 32 env steps (updates × algorithm.rounds_per_update "
            "× algorithm.train_freq), or no gradient step is ever taken: lower it, or raise updates")


def test_sac_refuses_a_minibatch_larger_than_its_buffer():
    """As PPO refuses a minibatch larger than its rollout."""
    assert _refusal(*SAC, "algorithm.batch_size=101") == (
        "algorithm.batch_size=101: at most algorithm.buffer_size = 100 (a minibatch is drawn from the transitions "
        "the replay buffer keeps)")
    assert _refusal("+experiment=sac_hopper_bullet", "algorithm.batch_size=100000000").startswith(
        "algorithm.batch_size=100000000: at most algorithm.buffer_size = 300000")


@pytest.mark.parametrize("algorithm", ["ppo", "a2c", "sac"])
def test_the_algorithms_refuse_episodes_per_update(algorithm):
    """A top-level key of the episodic estimators that PPO, A2C and SAC do not read; its default
    (which the schema cannot tell from the same value set) is accepted."""
    validate(compose_config(f"algorithm={algorithm}", "env=gym", "episodes_per_update=10"))
    line = _refusal(f"algorithm={algorithm}", "env=gym", "episodes_per_update=3")
    assert line.startswith(f"episodes_per_update=3: 10 (its default) with algorithm={algorithm}: a setting of the "
                           f"episodic estimators, which algorithm={algorithm} does not read"), line


def test_a_warm_up_as_long_as_the_job_exits_2_in_one_line(tmp_path):
    result = run_cli(*SAC, "algorithm.learning_starts=32", run_dir=tmp_path / "run")
    lines = own_stderr_lines(result.stderr)
    assert result.returncode == 2 and lines == [
        "error: algorithm.learning_starts=32: below the job's 32 env steps (updates × algorithm.rounds_per_update "
        "× algorithm.train_freq), or no gradient step is ever taken: lower it, or raise updates"], result.stderr[-2000:]
    assert not (tmp_path / "run" / "metrics.csv").exists()
