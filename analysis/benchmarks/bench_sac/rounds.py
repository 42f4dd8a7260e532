"""Timed SAC rounds of both sides: ``python train.py +experiment=sac_mountaincar``'s own trainer
(:func:`job_rounds`) and Stable-Baselines3's SAC built from the config that experiment composes
(:func:`sb3_rounds`, through :mod:`analysis.benchmarks.gsde_table.sb3`), each round's end in wall
and CPU seconds.

A round is SB3's unit of SAC training: ``train_freq`` env steps collected, then ``gradient_steps``
gradient steps (32 and 32 on MountainCarContinuous).
"""

from __future__ import annotations

import time

from analysis.benchmarks.gsde_table.sb3 import model_from_config

#: The experiment both sides run.
EXPERIMENT = "sac_mountaincar"


def job_config(overrides: tuple[str, ...] = (), experiment: str = EXPERIMENT):
    """The checked config of ``train.py +experiment=EXPERIMENT OVERRIDES`` (no logger)."""
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    return validate(compose([f"+experiment={experiment}", "logger=none", *overrides]))


def job_rounds(rounds: int, overrides: tuple[str, ...] = ()) -> list[tuple[float, float]]:
    """The end of each of ``rounds`` rounds of the job's own trainer (one round an update: its
    collection, checks and gradient steps; no evaluation or files), in wall and CPU seconds from
    its start."""
    from sde_torchrl.config.build_sac import build_sac_trainer

    trainer = build_sac_trainer(job_config(("algorithm.rounds_per_update=1", f"updates={rounds}", *overrides)))
    ends, start, cpu_start = [], time.perf_counter(), time.process_time()
    for k in range(rounds):
        trainer.update(k)
        ends.append((time.perf_counter() - start, time.process_time() - cpu_start))
    trainer.close()
    return ends


def sb3_rounds(rounds: int, overrides: tuple[str, ...] = ()) -> list[tuple[float, float]]:
    """The end of each of ``rounds`` rounds of SB3's SAC with the settings of the job's config
    (:func:`~analysis.benchmarks.gsde_table.sb3.sb3_settings`; ``("explorer=gaussian",)`` for its
    plain Gaussian), in wall and CPU seconds from its start (no evaluation)."""
    settings, model, env = model_from_config(job_config(overrides), "bench_sac")
    from stable_baselines3.common.callbacks import BaseCallback

    ends: list[tuple[float, float]] = []

    class Rounds(BaseCallback):
        def _on_rollout_start(self) -> None:  # the previous round's gradient steps have ended
            if self.num_timesteps:
                ends.append((time.perf_counter() - start, time.process_time() - cpu_start))

        def _on_step(self) -> bool:
            return True

    start, cpu_start = time.perf_counter(), time.process_time()
    model.learn(total_timesteps=rounds * settings["kwargs"]["train_freq"], callback=Rounds())
    ends.append((time.perf_counter() - start, time.process_time() - cpu_start))  # the last round's
    env.close()
    return ends
