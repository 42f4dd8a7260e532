"""How fast one PPO iteration runs (``speed``) and where its time goes (``phases``): each variant
trained for a few iterations in a fresh process of its own, on one thread."""

from __future__ import annotations

import numpy as np
import torch

from analysis.benchmarks import common
from analysis.benchmarks.bench_ppo.build import ZOO
from analysis.benchmarks.bench_ppo.timing import TIMER
from analysis.benchmarks.bench_ppo.train import train_job, train_sb3, train_torchrl

#: ``job``: ``python train.py +experiment=ppo_halfcheetah_bullet``'s own trainer as shipped (compiled
#: loss, fused Adam), ``job+eager`` with ``algorithm.compile=false``; the others: this benchmark's
#: TorchRL loop (``+compile``: the update compiled; ``+compile+policy``: the collector's policy
#: forward as well) and SB3.
SPEED_VARIANTS = ("job", "job+eager", "plain", "plain+compile", "plain+compile+policy", "sde", "sde+compile",
                  "sde+compile+policy", "sb3", "sb3_gauss")


def iteration_seconds(variant: str, rollouts: int) -> tuple[float, float, float]:
    """Median wall and CPU time of one training iteration of ``variant`` and the median wall time
    of its collection (``nan`` where not recorded), the first iteration left out."""
    torch.set_num_threads(1)
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    method, *options = variant.split("+")
    if method == "job":
        result = train_job(rollouts, ("algorithm.compile=false",) if "eager" in options else ())
    elif method.startswith("sb3"):
        result = train_sb3(0, rollouts * frames, use_sde=method == "sb3", evaluate=False)
    else:
        result = train_torchrl(method, 0, rollouts * frames, compile_update="compile" in options, evaluate=False,
                               compile_policy="policy" in options)
    collect = result.get("collect_s", [])[1:]
    return (float(np.median(np.diff(result["iteration_ends_s"]))),
            float(np.median(np.diff(result["iteration_cpu_ends_s"]))),
            float(np.median(collect)) if collect else float("nan"))


def speed(variants: list[str], rollouts: int, repeats: int = 1) -> str:
    """Env steps per second (wall and CPU) of one training iteration (collect ``n_envs × n_steps``,
    then update), with each variant's ratio to SB3 gSDE's.

    Each variant (``job``, ``job+eager``, ``sde``, ``sde+compile``, ``sde+compile+policy``, the
    same for ``plain``, ``sb3``, ``sb3_gauss``) trains ``rollouts`` iterations on one thread in a
    fresh process of its own (in one process, whatever runs later runs slower), one variant after
    the other in the order given, the whole list ``repeats`` times over; the first iteration of a
    process (warm-up, compilation) is left out and the median of the others is the process's
    figure. With ``sb3`` among them, each variant's speed is also given as a ratio to SB3 gSDE's,
    with a 95 % bootstrap interval over the processes when there are several.
    """
    seconds = common.in_fresh_processes(iteration_seconds, variants, rollouts, repeats)
    return speed_table(seconds, rollouts - 1)


def speed_table(seconds: dict[str, list[tuple[float, float, float]]], timed: int) -> str:
    """The ``speed`` table (:func:`analysis.benchmarks.common.speed_table`) of PPO iterations.

    Examples:
        >>> table = speed_table({"sb3": [(4.0, 4.0, 2.0), (6.0, 5.0, 3.0)],
        ...                      "sde": [(5.0, 5.0, 2.0), (5.0, 4.5, 2.0)]}, 5)
        >>> print(table.splitlines()[3])
        | sde | 2 | 5.00 | 2.00 | 3.00 | 1638 | 1725 | 1.00 [0.80, 1.20] | 0.95 [0.80, 1.11] | 5 |
    """
    return common.speed_table(seconds, ZOO["n_envs"] * ZOO["n_steps"], timed, "iteration")


def iteration_phases(variant: str, rollouts: int) -> dict[str, float]:
    """Seconds per iteration of each phase of ``variant``'s training, the first iteration left out."""
    with TIMER.on() as timed:
        seconds, _, _ = iteration_seconds(variant, rollouts)
    return {"iteration": seconds, **{phase: total / (rollouts - 1) for phase, total in timed.items()}}


def phases(variants: list[str], rollouts: int) -> str:
    """Where one iteration's time goes: collection (and pybullet's share of it), GAE and the update
    (and its parts), in seconds per iteration, each variant in a fresh process on one thread.

    SB3 computes GAE inside its collection; its "loss forward" is the policy's
    ``evaluate_actions`` (actor and critic), ours ``ClipPPOLoss``'s whole forward; a compiled
    update is timed whole. The timers themselves cost a few microseconds per call.
    """
    import multiprocessing

    table = {}
    for variant in variants:
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            table[variant] = pool.apply(iteration_phases, (variant, rollouts))
    rows = ["iteration", "collect", "collect: pybullet step", "collect: policy forward", "collect: env transforms",
            "GAE", "update", "update: minibatch indexing",
            "update: loss forward", "update: backward", "update: clip + Adam step"]
    lines = [f"| seconds per iteration | {' | '.join(variants)} |", f"| --- |{' --- |' * len(variants)}"]
    for row in rows:
        cells = [f"{table[v][row]:.2f}" if row in table[v] else "-" for v in variants]
        lines.append(f"| {row} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"
