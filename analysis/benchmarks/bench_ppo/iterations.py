"""Timed PPO iterations of both sides: ``python train.py +experiment=ppo_halfcheetah_bullet``'s own
trainer (:func:`train_job`) and Stable-Baselines3's PPO built from the config that experiment
composes (:func:`train_sb3`, through :mod:`analysis.benchmarks.gsde_table.sb3`), each iteration's
end in wall and CPU seconds and each rollout's collection time, split into phases while
:data:`~analysis.benchmarks.bench_ppo.timing.TIMER` is on."""

from __future__ import annotations

import time
from collections.abc import Callable
from contextlib import nullcontext
from typing import Any

from analysis.benchmarks.bench_ppo.timing import TIMER, sb3_update_timed
from analysis.benchmarks.gsde_table.sb3 import model_from_config

#: The experiment both sides run.
EXPERIMENT = "ppo_halfcheetah_bullet"


def job_config(overrides: tuple[str, ...] = ()):
    """The checked config of ``train.py +experiment=ppo_halfcheetah_bullet OVERRIDES`` (no logger)."""
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    return validate(compose([f"+experiment={EXPERIMENT}", "logger=none", *overrides]))


def train_job(rollouts: int, overrides: tuple[str, ...] = ()) -> dict[str, list[float]]:
    """``rollouts`` updates of the job's own trainer (its collector, checks and update; no
    evaluation or files), each update's end in wall and CPU seconds and each rollout's
    collection time."""
    from sde_torchrl.config.build_onpolicy import build_onpolicy_trainer

    trainer = build_onpolicy_trainer(job_config(overrides))
    collect_s: list[float] = []
    rollout = trainer.collector.rollout

    def timed_rollout():
        begin = time.perf_counter()
        batch = rollout()
        collect_s.append(time.perf_counter() - begin)
        return batch

    trainer.collector.rollout = timed_rollout
    restore = _time_job_phases(trainer) if TIMER.active else (lambda: None)
    ends, cpu_ends, start, cpu_start = [], [], time.perf_counter(), time.process_time()
    try:
        for k in range(rollouts):
            trainer.update(k)
            ends.append(time.perf_counter() - start)
            cpu_ends.append(time.process_time() - cpu_start)
            if k == 0:
                TIMER.restart()  # the first iteration (warm-up, compilation) is not timed
    finally:
        restore()
    trainer.close()
    return {"iteration_ends_s": ends, "iteration_cpu_ends_s": cpu_ends, "collect_s": collect_s}


def train_raw(rollouts: int, frames: int) -> dict[str, list[float]]:
    """The physical limit of a collection: ``frames`` steps of one raw gymnasium env of the
    experiment with uniformly random actions (drawn beforehand, seeded), reset at each episode's
    end, ``rollouts`` times; each time's seconds (wall, CPU) as an iteration and its collection."""
    import gymnasium
    import numpy as np

    from sde_torchrl.envs.vector import first_reset

    env = gymnasium.make(job_config().env.id)
    first_reset([env])
    env.reset(seed=1)
    space, rng = env.action_space, np.random.default_rng(0)
    ends, cpu_ends, collect_s, start, cpu_start = [], [], [], time.perf_counter(), time.process_time()
    for _ in range(rollouts):
        actions = rng.uniform(space.low, space.high, size=(frames, *space.shape)).astype(space.dtype)
        begin = time.perf_counter()
        for action in actions:
            _, _, terminated, truncated, _ = env.step(action)
            if terminated or truncated:
                env.reset()
        collect_s.append(time.perf_counter() - begin)
        ends.append(time.perf_counter() - start)
        cpu_ends.append(time.process_time() - cpu_start)
    env.close()
    return {"iteration_ends_s": ends, "iteration_cpu_ends_s": cpu_ends, "collect_s": collect_s}


def _time_job_phases(trainer) -> Callable[[], None]:
    """Times the job's phases under ``phases``' names: its collection and, within it, pybullet's
    step, the policy's forward and the env's transforms (on the tensor path: the normaliser and
    the noise schedule); GAE; the update (compiled: timed whole). Returns what puts the
    collector module's policy maker back."""
    from sde_torchrl.collectors import steps

    timed = TIMER.wrap
    collector = trainer.collector
    collector.rollout = timed("collect", collector.rollout)
    for env in collector.env.base_env.envs:
        env.step = timed("collect: pybullet step", env.step)
    on_tensors = steps.tensor_policy
    if collector.fused is not None:
        steps.tensor_policy = lambda policy: timed("collect: policy forward", on_tensors(policy))
        for part, methods in ((collector.fused.normalizer, ("observe", "normalize")),
                              (collector.fused.primer, ("step_noise", "reset_noise"))):
            for name in methods if part is not None else ():
                setattr(part, name, timed("collect: env transforms", getattr(part, name)))
    else:
        collector.policy = timed("collect: policy forward", collector.policy)
        for transform in collector.env.transform:
            transform._step = timed("collect: env transforms", transform._step)
    trainer.advantage = timed("GAE", trainer.advantage)
    trainer.update_step = timed("update", trainer.update_step)
    return lambda: setattr(steps, "tensor_policy", on_tensors)


def train_sb3(rollouts: int, overrides: tuple[str, ...] = ()) -> dict[str, Any]:
    """``rollouts`` iterations of SB3's PPO with the settings of the job's config
    (:func:`~analysis.benchmarks.gsde_table.sb3.sb3_settings`; ``("explorer=gaussian",)`` for its
    plain Gaussian), each iteration's end in wall and CPU seconds and each rollout's collection
    time (GAE included: SB3 computes it at the end of the rollout)."""
    settings, model, env = model_from_config(job_config(overrides), "bench_ppo")
    from stable_baselines3.common.callbacks import BaseCallback

    if TIMER.active:  # pybullet's step, inside SB3's vectorised env
        for inner in env.venv.envs if hasattr(env, "venv") else env.envs:
            inner.step = TIMER.wrap("collect: pybullet step", inner.step)
    iteration_ends: list[float] = []
    cpu_ends: list[float] = []
    collect_s: list[float] = []

    class Iterations(BaseCallback):
        def _on_rollout_start(self) -> None:  # the previous iteration's update has ended
            self.collect_start = time.perf_counter()
            if self.num_timesteps:
                iteration_ends.append(time.perf_counter() - start)
                cpu_ends.append(time.process_time() - cpu_start)
                TIMER.mark("update")
                if len(iteration_ends) == 1:
                    TIMER.restart()  # the first iteration is not timed
            TIMER.mark(None)

        def _on_rollout_end(self) -> None:
            collect_s.append(time.perf_counter() - self.collect_start)
            TIMER.mark("collect")

        def _on_step(self) -> bool:
            return True

    frames = settings["env"]["n_envs"] * settings["kwargs"]["n_steps"]
    start, cpu_start = time.perf_counter(), time.process_time()
    with sb3_update_timed(model) if TIMER.active else nullcontext():
        model.learn(total_timesteps=rollouts * frames, callback=Iterations())
    TIMER.mark("update")  # the last iteration's update
    iteration_ends.append(time.perf_counter() - start)
    cpu_ends.append(time.process_time() - cpu_start)
    env.close()
    return {"iteration_ends_s": iteration_ends, "iteration_cpu_ends_s": cpu_ends, "collect_s": collect_s}
