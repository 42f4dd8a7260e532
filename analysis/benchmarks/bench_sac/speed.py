"""How fast SAC's rounds run (``speed``): ``python train.py +experiment=sac_mountaincar``'s own
trainer against SB3 SAC with gSDE at the same zoo settings, each in a fresh process on one thread.

A round is SB3's unit of SAC training at these settings: ``train_freq`` env steps collected, then
``gradient_steps`` gradient steps (32 and 32 on MountainCarContinuous).
"""

from __future__ import annotations

import time

import numpy as np
import torch

from analysis.benchmarks import common
from analysis.benchmarks.bench_sac.build import ZOO
from analysis.benchmarks.bench_sac.train import train_sb3

#: ``job``: the experiment as shipped (compiled losses, fused Adam); ``job+eager``: with
#: ``algorithm.compile=false``; ``sb3``: SB3 SAC with gSDE.
SPEED_VARIANTS = ("job", "job+eager", "sb3")
#: Rounds left out at the start of a process (warm-up, compilation).
WARM_UP = 3


def job_rounds(rounds: int, overrides: tuple[str, ...] = ()) -> list[tuple[float, float]]:
    """The end of each of ``rounds`` rounds of the SAC job's own trainer (one round an update), in
    wall and CPU seconds from its start."""
    from sde_torchrl.config.build_sac import build_sac_trainer
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    conf = validate(compose(["+experiment=sac_mountaincar", "logger=none", "algorithm.rounds_per_update=1",
                             f"updates={rounds}", *overrides]))
    trainer = build_sac_trainer(conf)
    ends, start, cpu_start = [], time.perf_counter(), time.process_time()
    for k in range(rounds):
        trainer.update(k)
        ends.append((time.perf_counter() - start, time.process_time() - cpu_start))
    trainer.close()
    return ends


def round_seconds(variant: str, rounds: int) -> tuple[float, float, float]:
    """Median wall and CPU seconds of one round of ``variant`` after :data:`WARM_UP` rounds (no
    collection split: ``nan``)."""
    torch.set_num_threads(1)
    zoo = ZOO["mountaincar"]
    if variant == "sb3":
        ends = train_sb3("mountaincar", 0, rounds * zoo["train_freq"], eval_episodes=0)["round_starts"]
    else:
        ends = job_rounds(rounds, ("algorithm.compile=false",) if variant == "job+eager" else ())
    per_round = np.diff(np.asarray(ends, dtype=float)[WARM_UP:], axis=0)
    return float(np.median(per_round[:, 0])), float(np.median(per_round[:, 1])), float("nan")


def speed(variants: list[str], rounds: int, repeats: int = 1) -> str:
    """Env steps per second (wall and CPU) of SAC's rounds, each variant's ratio to SB3's.

    Each variant trains ``rounds`` rounds on one thread in a fresh process of its own, one variant
    after the other in the order given, the whole list ``repeats`` times over; the median round
    after :data:`WARM_UP` is the process's figure (:func:`analysis.benchmarks.common.speed_table`).
    """
    seconds = common.in_fresh_processes(round_seconds, variants, rounds, repeats)
    return common.speed_table(seconds, ZOO["mountaincar"]["train_freq"], rounds - WARM_UP - 1, "round")
