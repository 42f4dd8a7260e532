"""How fast one PPO iteration runs (``speed``) and where its time goes (``phases``): each variant
trained for a few iterations in a fresh process of its own, on one thread."""

from __future__ import annotations

import numpy as np
import torch

from analysis.benchmarks import common
from analysis.benchmarks.bench_ppo.iterations import job_config, train_job, train_raw, train_sb3
from analysis.benchmarks.bench_ppo.timing import TIMER

#: ``job``: ``python train.py +experiment=ppo_halfcheetah_bullet``'s own trainer as shipped (compiled
#: loss, fused Adam), ``job+eager`` with ``algorithm.compile=false``; ``sb3``: SB3's PPO with gSDE at the
#: job's settings, ``sb3_gauss`` with its plain Gaussian (the job's ``explorer=gaussian``).
#: ``raw``: the same env steps through one raw gymnasium env with random actions, the physical
#: limit a collection is measured against (no policy, no update).
SPEED_VARIANTS = ("job", "job+eager", "sb3", "sb3_gauss", "raw")
#: Each variant's overrides of the experiment.
OVERRIDES = {"job": (), "job+eager": ("algorithm.compile=false",), "sb3": (), "sb3_gauss": ("explorer=gaussian",),
             "raw": ()}


def iteration_frames() -> int:
    """Env steps of one iteration of the experiment: ``n_envs × n_steps``."""
    algorithm = job_config().algorithm
    return algorithm.n_envs * algorithm.n_steps


def iteration_seconds(variant: str, rollouts: int) -> tuple[float, float, float]:
    """Median wall and CPU time of one training iteration of ``variant`` and the median wall time
    of its collection, the first iteration left out."""
    torch.set_num_threads(1)
    if variant == "raw":
        result = train_raw(rollouts, iteration_frames())
    else:
        result = (train_sb3 if variant.startswith("sb3") else train_job)(rollouts, OVERRIDES[variant])
    collect = result["collect_s"][1:]
    return (float(np.median(np.diff(result["iteration_ends_s"]))),
            float(np.median(np.diff(result["iteration_cpu_ends_s"]))),
            float(np.median(collect)) if collect else float("nan"))


def speed(variants: list[str], rollouts: int, repeats: int = 1) -> str:
    """Env steps per second (wall and CPU) of one training iteration (collect ``n_envs × n_steps``,
    then update), with each variant's ratio to SB3 gSDE's.

    Each variant (:data:`SPEED_VARIANTS`) trains ``rollouts`` iterations on one thread in a fresh
    process of its own (in one process, whatever runs later runs slower), one variant after the
    other in the order given, the whole list ``repeats`` times over; the first iteration of a
    process (warm-up, compilation) is left out and the median of the others is the process's
    figure. With ``sb3`` among them, each variant's speed is also given as a ratio to SB3 gSDE's,
    with a 95 % bootstrap interval over the processes when there are several.
    """
    seconds = common.in_fresh_processes(iteration_seconds, variants, rollouts, repeats)
    raw = seconds.pop("raw", None)
    table = speed_table(seconds, rollouts - 1, iteration_frames()) if seconds else ""
    return table if raw is None else table + "\n" + raw_table(seconds, raw)


def raw_table(seconds: dict[str, list[tuple[float, float, float]]], raw: list[tuple[float, float, float]]) -> str:
    """Each variant's collection of one iteration against the same env steps through one raw
    gymnasium env with random actions (medians over processes).

    Examples:
        >>> print(raw_table({"job": [(5.0, 5.0, 2.6)]}, [(2.0, 2.0, 2.0)]).splitlines()[2])
        | job | 2.60 | 2.00 | 1.30 |
    """
    limit = float(np.median([collect for _, _, collect in raw]))
    lines = ["| variant | collection s | raw gymnasium s | collection ÷ raw |", "| --- | --- | --- | --- |"]
    for variant, triples in seconds.items():
        collect = float(np.median([c for _, _, c in triples]))
        lines.append(f"| {variant} | {collect:.2f} | {limit:.2f} | {collect / limit:.2f} |")
    return "\n".join(lines) + "\n"


def speed_table(seconds: dict[str, list[tuple[float, float, float]]], timed: int, frames: int) -> str:
    """The ``speed`` table (:func:`analysis.benchmarks.common.speed_table`) of PPO iterations of
    ``frames`` env steps.

    Examples:
        >>> table = speed_table({"sb3": [(4.0, 4.0, 2.0), (6.0, 5.0, 3.0)],
        ...                      "job": [(5.0, 5.0, 2.0), (5.0, 4.5, 2.0)]}, 5, 8192)
        >>> print(table.splitlines()[3])
        | job | 2 | 5.00 | 2.00 | 3.00 | 1638 | 1725 | 1.00 [0.80, 1.20] | 0.95 [0.80, 1.11] | 5 |
    """
    return common.speed_table(seconds, frames, timed, "iteration")


def iteration_phases(variant: str, rollouts: int) -> dict[str, float]:
    """Seconds per iteration of each phase of ``variant``'s training, the first iteration left out."""
    with TIMER.on() as timed:
        seconds, _, _ = iteration_seconds(variant, rollouts)
    return {"iteration": seconds, **{phase: total / (rollouts - 1) for phase, total in timed.items()}}


def phases(variants: list[str], rollouts: int) -> str:
    """Where one iteration's time goes: collection (and pybullet's share of it), GAE and the update
    (and its parts), in seconds per iteration, each variant in a fresh process on one thread.

    SB3 computes GAE inside its collection; its "loss forward" is the policy's
    ``evaluate_actions`` (actor and critic); the job's compiled update is timed whole. The timers
    themselves cost a few microseconds per call.
    """
    import multiprocessing

    table = {}
    for variant in variants:
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            table[variant] = pool.apply(iteration_phases, (variant, rollouts))
    rows = ["iteration", "collect", "collect: pybullet step", "collect: policy forward", "collect: env transforms",
            "GAE", "update", "update: loss forward", "update: backward", "update: clip + Adam step"]
    lines = [f"| seconds per iteration | {' | '.join(variants)} |", f"| --- |{' --- |' * len(variants)}"]
    for row in rows:
        cells = [f"{table[v][row]:.2f}" if row in table[v] else "-" for v in variants]
        lines.append(f"| {row} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"
