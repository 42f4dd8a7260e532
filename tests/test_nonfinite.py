"""The one non-finite policy (sde_torchrl.utils.nonfinite): "raise" by default for direct use,
"guarded" inside the trainer, whose guard names the update; set in one place, restored after it.

A non-finite stop of PPO, A2C or SAC shows the offending values and advises settings the job has;
a NaN that a gymnasium env returns after finite actions is reported as the env's, with its step."""

from __future__ import annotations

import threading

import gymnasium
import numpy as np
import pytest
import torch
from _helpers import build, compose_config, sde_policy
from tensordict.nn import TensorDictSequential

import sde_torchrl
from sde_torchrl import LinearActor, MinimizeEnv, PGPEEstimator, ReinforceEstimator, make_minimize_env
from sde_torchrl.collectors.rollout import collect_episodes
from sde_torchrl.envs.gym_checks import EnvOutputError
from sde_torchrl.modules.pgpe import ParameterExplorer
from sde_torchrl.objectives.base import NonFiniteEpisodesError
from sde_torchrl.trainers.guard import NonFiniteError
from sde_torchrl.utils.checks import ArgumentError, NonFiniteInputError
from sde_torchrl.utils.nonfinite import check_finite, current_nonfinite_policy, nonfinite_policy

GUARDED = 'with sde_torchrl.nonfinite_policy("guarded"):'


def _sde_episodes(runs=2, episodes=4, length=5):
    policy = sde_policy(LinearActor(1, 1, init=-2.0, runs=runs), 1, 1, runs=runs)[0]
    env = make_minimize_env(length, episodes=episodes, runs=runs).append_transform(
        policy.sde.make_tensordict_primer())
    torch.manual_seed(0)
    return policy, collect_episodes(env, policy, length)


def _pgpe_episodes(runs=2, episodes=4, length=5):
    actor = LinearActor(1, 1, init=-2.0, runs=runs)
    explorer = ParameterExplorer(actor, runs=runs)
    policy = TensorDictSequential(actor, explorer)
    env = make_minimize_env(length, episodes=episodes, runs=runs).append_transform(explorer.make_tensordict_primer())
    torch.manual_seed(0)
    return policy, collect_episodes(env, policy, length)


# ------------------------------------------------------------------------------ the default: raise


def test_the_default_is_raise():
    assert current_nonfinite_policy() == "raise"
    assert sde_torchrl.nonfinite_policy is nonfinite_policy  # the public name


def test_check_finite_names_the_tensor_the_entries_and_the_fix():
    value = torch.zeros(2, 3, 4)
    value[1, 2, 0] = float("inf")
    with pytest.raises(NonFiniteInputError, match=r"^my tensor: NaN/inf in run 1 episode 2; do this$"):
        check_finite("my tensor", value, ("run", "episode"), "do this")
    with pytest.raises(NonFiniteInputError, match=r"^my tensor: NaN/inf in the batch; do this$"):
        check_finite("my tensor", value, (), "do this")
    check_finite("integers", torch.arange(3), ("episode",))  # finite by their type
    check_finite("finite", torch.ones(2, 3), ("run", "episode"))


@pytest.mark.parametrize("bad", [float("nan"), float("inf")])
def test_an_estimator_called_directly_raises_naming_the_tensor_and_the_fix(bad):
    policy, episodes = _sde_episodes()
    episodes["observation"][1, 3, 2] = bad
    with pytest.raises(NonFiniteEpisodesError) as info:
        ReinforceEstimator(policy)(episodes)
    message = str(info.value)
    assert message.startswith("episodes key 'observation': NaN/inf in run 1 episode 3;"), message
    assert GUARDED in message and info.value.key == "observation"


def test_pgpe_called_directly_raises_naming_the_tensor_and_the_fix():
    policy, episodes = _pgpe_episodes()
    episodes["next", "reward"][0, 2, 1] = float("nan")
    with pytest.raises(NonFiniteEpisodesError) as info:
        PGPEEstimator(policy)(episodes)
    message = str(info.value)
    assert message.startswith("episodes key ('next', 'reward'): NaN/inf in run 0 episode 2;"), message
    assert GUARDED in message and info.value.key == ("next", "reward")


def test_overflowing_scores_raise_naming_the_parameter():
    policy, episodes = _sde_episodes()
    episodes["action"][0, 1, 2] = 3e38  # finite, but its squared deviation is not
    with pytest.raises(NonFiniteEpisodesError, match=r"^scores of parameter .*: NaN/inf in run 0 episode 1;") as info:
        ReinforceEstimator(policy)(episodes)
    assert GUARDED in str(info.value) and info.value.key == "scores"


def test_minimize_env_raises_naming_the_action_and_the_fix():
    env = MinimizeEnv(episodes=3, runs=2)
    x = env.initial_state()
    u = torch.zeros_like(x)
    u[0, 1] = float("nan")
    expected = r"^action: NaN/inf in run 0 episode 1; the policy produced them"
    with pytest.raises(NonFiniteInputError, match=expected) as info:
        env.transition(x, u)
    assert GUARDED in str(info.value)


# ------------------------------------------------------------------------------ guarded


def test_guarded_lets_every_layer_through():
    policy, episodes = _sde_episodes()
    episodes["observation"][1, 3, 2] = float("nan")
    with nonfinite_policy("guarded"):
        gradient = ReinforceEstimator(policy)(episodes)["gradient"]
    assert torch.isnan(gradient[1]).all() and torch.isfinite(gradient[0]).all()
    pgpe_policy, pgpe_episodes = _pgpe_episodes()
    pgpe_episodes["next", "reward"][0, 2, 1] = float("nan")
    with nonfinite_policy("guarded"):
        gradient = PGPEEstimator(pgpe_policy)(pgpe_episodes)["gradient"]
    assert torch.isnan(gradient[0]).all() and torch.isfinite(gradient[1]).all()
    env = MinimizeEnv(episodes=3, runs=2)
    x = env.initial_state()
    with nonfinite_policy("guarded"):
        x_next, reward = env.transition(x, torch.full_like(x, float("nan")))
    assert torch.isnan(x_next).all() and torch.isnan(reward).all()


def _poison_parameters_before(trainer, at: int) -> None:
    """Sets the actor's weight to NaN before the rollout of update ``at``: the env steps NaN actions."""
    collect, calls = trainer.collect, []

    def poisoned():
        if len(calls) == at:
            with torch.no_grad():
                next(trainer.policy.parameters()).fill_(float("nan"))
        calls.append(1)
        return collect()

    trainer.collect = poisoned


def test_the_trainers_rollout_is_guarded_so_its_guard_names_the_update(tmp_path):
    trainer = build("runs=2", "updates=5", "episodes_per_update=4")
    _poison_parameters_before(trainer, at=2)
    with pytest.raises(NonFiniteError) as info:  # not the env's NonFiniteInputError
        trainer.train(tmp_path)
    assert (info.value.update, info.value.what) == (2, "return")
    assert current_nonfinite_policy() == "raise"  # the trainer's blocks are left


def test_the_trainers_update_is_guarded_so_its_guard_names_the_update(tmp_path):
    trainer = build("runs=2", "updates=5", "episodes_per_update=4", "estimator.max_grad_norm=null")
    collect, calls = trainer.collect, []

    def poisoned():  # a NaN observation: finite returns, so the estimator is the first to see it
        episodes = collect()
        if len(calls) == 3:
            episodes["observation"][1, 0, 2] = float("nan")
        calls.append(1)
        return episodes

    trainer.collect = poisoned
    with pytest.raises(NonFiniteError) as info:  # not the estimator's NonFiniteEpisodesError
        trainer.train(tmp_path)
    assert (info.value.update, info.value.what, info.value.runs) == (3, "score", [1])
    assert current_nonfinite_policy() == "raise"


def test_outside_the_trainer_its_estimator_and_env_raise():
    trainer = build("runs=2", "updates=5", "episodes_per_update=4")
    episodes = trainer.collect()
    episodes["observation"][0, 1, 2] = float("nan")
    with pytest.raises(NonFiniteEpisodesError, match=r"^episodes key 'observation': NaN/inf in run 0 episode 1;"):
        trainer.estimator(episodes)
    x = trainer.env.base_env.initial_state()
    with pytest.raises(NonFiniteInputError, match=r"^action: NaN/inf in run 0 episode 0, run 0 episode 1"):
        trainer.env.base_env.transition(x, torch.full_like(x, float("nan")))


# ------------------------------------------------------------------------------ the context manager


def test_the_policy_is_restored_after_the_block_and_nests():
    with nonfinite_policy("guarded"):
        assert current_nonfinite_policy() == "guarded"
        with nonfinite_policy("raise"):
            assert current_nonfinite_policy() == "raise"
            with pytest.raises(NonFiniteInputError):
                check_finite("x", torch.tensor([float("nan")]))
        assert current_nonfinite_policy() == "guarded"
        check_finite("x", torch.tensor([float("nan")]))
    assert current_nonfinite_policy() == "raise"


def test_the_policy_is_restored_after_an_exception_in_the_block():
    with pytest.raises(KeyError), nonfinite_policy("guarded"):
        raise KeyError("inside")
    assert current_nonfinite_policy() == "raise"
    with nonfinite_policy("guarded"):
        with pytest.raises(RuntimeError), nonfinite_policy("raise"):
            raise RuntimeError("inside")
        assert current_nonfinite_policy() == "guarded"
    assert current_nonfinite_policy() == "raise"


def test_the_policy_is_restored_after_a_trainer_that_failed(tmp_path):
    trainer = build("runs=2", "updates=3", "lr=1e38")
    with pytest.raises(NonFiniteError):
        trainer.train(tmp_path)
    assert current_nonfinite_policy() == "raise"


def test_another_thread_keeps_its_own_policy():
    seen = []
    with nonfinite_policy("guarded"):
        thread = threading.Thread(target=lambda: seen.append(current_nonfinite_policy()))
        thread.start()
        thread.join()
    assert seen == ["raise"]


@pytest.mark.parametrize("policy", ["ignore", "Guarded", "", None, True, 1])
def test_an_unknown_policy_is_refused_before_the_block(policy):
    ran = []
    with pytest.raises(ArgumentError) as info, nonfinite_policy(policy):
        ran.append(1)
    message = str(info.value)
    assert message.startswith("nonfinite_policy=") and "raise" in message and "guarded" in message, message
    assert not ran and current_nonfinite_policy() == "raise"


# ------------------------------------------------------------------------------ PPO, A2C and SAC

#: A few steps of PPO or SAC on Pendulum-v1, no logger.
PPO = ("algorithm=ppo", "env=gym", "env.episode_length=10", "algorithm.n_steps=8", "algorithm.batch_size=4",
       "algorithm.n_epochs=1", "updates=2", "eval_episodes=1", "actor.hidden=[4]", "actor.init=null", "logger=none")
SAC = ("algorithm=sac", "env=gym", "env.episode_length=10", "algorithm.train_freq=4", "algorithm.gradient_steps=1",
       "algorithm.batch_size=4", "algorithm.learning_starts=4", "updates=3", "eval_episodes=1", "actor.hidden=[4]",
       "logger=none")


def _build_actor_critic(*overrides: str):
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.build_sac import build_sac_trainer
    from sde_torchrl.config.schemas.train import validate

    conf = validate(compose_config(*overrides))
    return (build_sac_trainer if conf.algorithm.__class__.__name__ == "SACConf" else build_onpolicy_trainer)(conf)


class _PoisonedStep:
    """The trainer's gradient step, after which two entries of the policy's first weight are NaN and inf."""

    def __init__(self, trainer) -> None:
        self.step, self.policy = trainer.update_step, trainer.policy

    def __call__(self, *args):
        out = self.step(*args)
        with torch.no_grad():
            weight = next(self.policy.parameters())
            weight.view(-1)[1], weight.view(-1)[2] = float("nan"), float("inf")
        return out

    def __getattr__(self, name):  # SAC's step also sets its round
        return getattr(self.step, name)


@pytest.mark.parametrize(("overrides", "remedy"), [
    (PPO, "(lower lr or set a smaller algorithm.max_grad_norm)"),
    (SAC, "(lower lr or set a larger algorithm.batch_size)"),
])
def test_an_actor_critic_stop_shows_the_values_and_a_remedy_of_its_own_settings(tmp_path, overrides, remedy):
    trainer = _build_actor_critic(*overrides)
    trainer.update_step = _PoisonedStep(trainer)
    with pytest.raises(NonFiniteError) as info:
        trainer.train(tmp_path)
    message = str(info.value)
    assert info.value.what == "parameter" and info.value.runs == [0], message
    assert " in run 0: [nan, inf] (2 of " in message and "entries, the first at [0, 1]);" in message, message
    assert message.endswith(remedy) and "estimator." not in message, message


class NaNEnv(gymnasium.Env):
    """Returns a NaN observation entry (or reward) at the third step of every episode, whatever the action."""

    observation_space = gymnasium.spaces.Box(-1.0, 1.0, (2,), np.float32)
    action_space = gymnasium.spaces.Box(-1.0, 1.0, (1,), np.float32)

    def __init__(self, bad: str = "observation") -> None:
        self.bad, self.t = bad, 0

    def reset(self, *, seed=None, options=None):
        super().reset(seed=seed)
        self.t = 0
        return np.zeros(2, np.float32), {}

    def step(self, action):
        self.t += 1
        observation, reward = np.full(2, 0.1, np.float32), -float(np.square(action).sum())
        if self.t == 3:
            if self.bad == "observation":
                observation[1] = np.nan
            else:
                reward = float("nan")
        return observation, reward, False, False, {}


gymnasium.register("NaNObservation-v0", entry_point=NaNEnv, max_episode_steps=20)
gymnasium.register("NaNReward-v0", entry_point=NaNEnv, max_episode_steps=20, kwargs={"bad": "reward"})
NAN_OBSERVATION, NAN_REWARD = f"{__name__}:NaNObservation-v0", f"{__name__}:NaNReward-v0"


@pytest.mark.parametrize(("env_id", "what"), [(NAN_OBSERVATION, "observation [0.1, nan]"),
                                              (NAN_REWARD, "reward [nan]")])
def test_a_nan_from_the_env_is_reported_as_the_env_s_with_its_step(tmp_path, env_id, what):
    from sde_torchrl.config.build import build_trainer

    trainer = build_trainer(compose_config("env=gym", f"env.id={env_id}", "env.episode_length=10", "updates=2",
                                           "episodes_per_update=2", "logger=none"))
    with pytest.raises(EnvOutputError) as info:  # not the guard's NonFiniteError, which would blame lr
        trainer.train(tmp_path)
    message = str(info.value)
    assert message.startswith(f"env {env_id} returned a non-finite {what} at step 3 of run 0 episode 0, after a "
                              "finite action: the env made it"), message
    assert "lr" not in message, message


@pytest.mark.parametrize("overrides", [PPO, SAC])
def test_a_nan_from_the_env_stops_ppo_and_sac_as_the_env_s_with_its_step(tmp_path, overrides):
    trainer = _build_actor_critic(*overrides, f"env.id={NAN_REWARD}")
    with pytest.raises(EnvOutputError, match=rf"^env {NAN_REWARD} returned a non-finite reward \[nan\] at step 3 of "
                                             r"env 0's episode \(seed \d+\), after a finite action"):
        trainer.train(tmp_path)


def test_a_nan_after_a_nan_action_is_left_to_the_guard():
    from sde_torchrl.envs.gym_checks import check_env_output

    check_env_output("any", "step 1", [float("nan")], float("nan"), action=[float("nan")])  # the policy's doing
    with pytest.raises(EnvOutputError, match=r"^env any returned a non-finite observation \[nan\] at the reset"):
        check_env_output("any", "the reset", [float("nan")])
