"""How fast SAC's rounds run (``speed``): ``python train.py +experiment=sac_mountaincar``'s own
trainer against SB3 SAC with gSDE built from the same config, each in a fresh process on one
thread (:mod:`.rounds`)."""

from __future__ import annotations

import numpy as np
import torch

from analysis.benchmarks import common
from analysis.benchmarks.bench_sac.rounds import job_config, job_rounds, sb3_rounds

#: ``job``: the experiment as shipped (compiled losses, fused Adam); ``job+eager``: with
#: ``algorithm.compile=false``; ``sb3``: SB3 SAC with gSDE at the job's settings, ``sb3_gauss`` with
#: its plain Gaussian (the job's ``explorer=gaussian``).
SPEED_VARIANTS = ("job", "job+eager", "sb3", "sb3_gauss")
#: Each variant's overrides of the experiment.
OVERRIDES = {"job": (), "job+eager": ("algorithm.compile=false",), "sb3": (), "sb3_gauss": ("explorer=gaussian",)}
#: Rounds left out at the start of a process (warm-up, compilation).
WARM_UP = 3


def round_seconds(variant: str, rounds: int) -> tuple[float, float, float]:
    """Median wall and CPU seconds of one round of ``variant`` after :data:`WARM_UP` rounds (no
    collection split: ``nan``)."""
    torch.set_num_threads(1)
    train = sb3_rounds if variant.startswith("sb3") else job_rounds
    per_round = np.diff(np.asarray(train(rounds, OVERRIDES[variant]), dtype=float)[WARM_UP:], axis=0)
    return float(np.median(per_round[:, 0])), float(np.median(per_round[:, 1])), float("nan")


def speed(variants: list[str], rounds: int, repeats: int = 1) -> str:
    """Env steps per second (wall and CPU) of SAC's rounds, each variant's ratio to SB3's.

    Each variant trains ``rounds`` rounds on one thread in a fresh process of its own, one variant
    after the other in the order given, the whole list ``repeats`` times over; the median round
    after :data:`WARM_UP` is the process's figure (:func:`analysis.benchmarks.common.speed_table`).
    """
    seconds = common.in_fresh_processes(round_seconds, variants, rounds, repeats)
    return common.speed_table(seconds, job_config().algorithm.train_freq, rounds - WARM_UP - 1, "round")
