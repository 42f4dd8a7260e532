"""Resuming on PyBullet: a PPO, A2C or SAC job on ``HopperBulletEnv-v0`` stopped and resumed with
fresh envs (as a new process has) writes the numbers of the uninterrupted job, every column of
``metrics.csv`` and the final evaluation; and an episode's rewards do not depend on what its env
did before, which is what that rests on."""

from __future__ import annotations

import pytest
import torch
from _helpers import compose_config, read_rows
from tensordict import TensorDict

from sde_torchrl.config.schemas.train import validate
from sde_torchrl.jobs.checkpoint import env_streams, load_checkpoint

pytest.importorskip("pybullet_envs_gymnasium")

HOPPER = "pybullet_envs_gymnasium:HopperBulletEnv-v0"
TINY = ("updates=4", "eval_period=2", "eval_episodes=2", "checkpoint_period=1", "actor.hidden=[16]", "logger=none",
        "algorithm.compile=false")
#: Episodes as long as a rollout (PPO, A2C) or a round (SAC), and too short for the hopper to fall:
#: at every checkpoint the training envs have just been reset. The evaluation after the resume is
#: the first of the resumed job's evaluation env.
JOBS = {
    "ppo": ("+experiment=ppo_hopper_bullet", "env.episode_length=8", "algorithm.n_envs=2", "algorithm.n_steps=8",
            "algorithm.batch_size=16", "algorithm.n_epochs=1"),
    "a2c": ("+experiment=a2c_hopper_bullet", "env.episode_length=8", "algorithm.n_envs=2", "algorithm.n_steps=8"),
    "sac": ("+experiment=sac_hopper_bullet", "env.episode_length=4", "algorithm.train_freq=4",
            "algorithm.learning_starts=4", "algorithm.gradient_steps=1", "algorithm.batch_size=8",
            "algorithm.rounds_per_update=2", "algorithm.buffer_size=32"),
}


class Stop(RuntimeError):
    """Stands in for the end of a process: raised from inside the training loop."""


def build(algorithm: str):
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer
    from sde_torchrl.config.build_sac import build_sac_trainer

    conf = validate(compose_config(*JOBS[algorithm], *TINY))
    return (build_sac_trainer if algorithm == "sac" else build_onpolicy_trainer)(conf)


def train(trainer, run_dir, stop_at: int | None = None) -> dict:
    """The job in ``run_dir``; with ``stop_at``, stopped as update ``stop_at`` starts."""
    if stop_at is not None:
        update = trainer.update

        def stopping(k):
            if k == stop_at:
                raise Stop(f"stopped at update {k}")
            return update(k)

        trainer.update = stopping
    try:
        return trainer.train(run_dir, checkpoint_period=1)
    finally:
        trainer.close()


@pytest.mark.e2e
@pytest.mark.parametrize("algorithm", list(JOBS))
def test_a_stopped_and_resumed_bullet_job_equals_an_uninterrupted_one(tmp_path, algorithm):
    reference = train(build(algorithm), tmp_path / "ref")
    with pytest.raises(Stop):
        train(build(algorithm), tmp_path / "resumed", stop_at=2)
    assert load_checkpoint(tmp_path / "resumed" / "checkpoint.pt")["updates"] == 2
    torch.manual_seed(1234)  # a new process: the checkpoint must not need the generators' state
    resumed = train(build(algorithm), tmp_path / "resumed")

    assert read_rows(tmp_path / "resumed") == read_rows(tmp_path / "ref")  # every column, the differing ones named
    assert (tmp_path / "resumed" / "metrics.csv").read_bytes() == (tmp_path / "ref" / "metrics.csv").read_bytes()
    assert resumed["final_eval_return"] == reference["final_eval_return"]
    resumed.pop("wall_s"), reference.pop("wall_s")
    assert resumed == reference


def hopper_actions(steps: int, envs: int) -> torch.Tensor:
    return torch.rand(steps, envs, 3, generator=torch.Generator().manual_seed(0)) * 2 - 1


def test_a_vector_env_episode_does_not_depend_on_the_env_s_past():
    """Fresh envs replaying an episode that has just begun (the state a checkpoint records) then
    get its rewards, as the envs that ran episodes before it do."""
    from sde_torchrl.envs.vector import GymVectorEnv

    actions = hopper_actions(12, 2)
    used = GymVectorEnv(HOPPER, n_envs=2, episode_length=6)
    used.reset()
    for action in actions[:6]:  # a whole episode: both envs are reset at its end
        used.step_and_maybe_reset(TensorDict({"action": action}, [2]))
    fresh = GymVectorEnv(HOPPER, n_envs=2, episode_length=6)
    fresh.restore_replay(used.replay_state())
    for action in actions[6:]:
        step = TensorDict({"action": action}, [2])
        assert torch.equal(used.step(step.clone())["next", "reward"], fresh.step(step.clone())["next", "reward"])
    for env in (used, fresh):
        env.close()


def test_a_runs_env_episode_does_not_depend_on_the_env_s_past():
    """The episodic jobs' env: a fresh one whose streams are where a used one's are gets the
    used one's next episodes, rewards included."""
    from sde_torchrl.envs.gym import GymRunsEnv

    actions = hopper_actions(10, 2).reshape(10, 1, 2, 3)
    used = GymRunsEnv(HOPPER, episodes=2)
    used.reset()
    for action in actions[:5]:
        used.step(TensorDict({"action": action}, [1, 2]))
    fresh = GymRunsEnv(HOPPER, episodes=2)
    env_streams(fresh).load_state_dict(env_streams(used).state_dict())
    assert torch.equal(used.reset()["observation"], fresh.reset()["observation"])
    for action in actions[5:]:
        step = TensorDict({"action": action}, [1, 2])
        assert torch.equal(used.step(step.clone())["next", "reward"], fresh.step(step.clone())["next", "reward"])
    for env in (used, fresh):
        env.close()
