"""How fast one PPO iteration runs (``speed``) and where its time goes (``phases``): each variant
trained for a few iterations in a fresh process of its own, on one thread."""

from __future__ import annotations

import numpy as np
import torch

from analysis.benchmarks.bench_ppo.build import ZOO
from analysis.benchmarks.bench_ppo.timing import TIMER
from analysis.benchmarks.bench_ppo.train import train_job, train_sb3, train_torchrl

#: ``job``: ``python train.py +experiment=ppo_halfcheetah_bullet``'s own trainer as shipped (compiled
#: loss, fused Adam), ``job+eager`` with ``algorithm.compile=false``; the others: this benchmark's
#: TorchRL loop (``+compile``: the update compiled; ``+compile+policy``: the collector's policy
#: forward as well) and SB3.
SPEED_VARIANTS = ("job", "job+eager", "plain", "plain+compile", "plain+compile+policy", "sde", "sde+compile",
                  "sde+compile+policy", "sb3", "sb3_gauss")


def iteration_seconds(variant: str, rollouts: int) -> tuple[float, float]:
    """Median wall and CPU time of one training iteration of ``variant``, the first iteration
    left out."""
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
    return (float(np.median(np.diff(result["iteration_ends_s"]))),
            float(np.median(np.diff(result["iteration_cpu_ends_s"]))))


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
    import multiprocessing

    seconds: dict[str, list[tuple[float, float]]] = {variant: [] for variant in variants}
    for _ in range(repeats):
        for variant in variants:
            with multiprocessing.get_context("spawn").Pool(1) as pool:
                seconds[variant].append(pool.apply(iteration_seconds, (variant, rollouts)))
    return speed_table(seconds, rollouts - 1)


def speed_table(seconds: dict[str, list[tuple[float, float]]], timed: int) -> str:
    """The ``speed`` table from each variant's ``(wall, CPU)`` seconds per iteration, one pair per
    process: the medians, env steps per second and per CPU second and, with ``sb3`` among the
    variants, the ratio of SB3's seconds per iteration to the variant's (ratio of the means over
    processes, bootstrap interval when both have several).

    Examples:
        >>> table = speed_table({"sb3": [(4.0, 4.0), (6.0, 5.0)], "sde": [(5.0, 5.0), (5.0, 4.5)]}, 5)
        >>> print(table.splitlines()[3])
        | sde | 2 | 5.00 | 1638 | 1725 | 1.00 [0.80, 1.20] | 0.95 [0.80, 1.11] | 5 |
    """
    from sde_torchrl.utils.intervals import bootstrap_interval

    frames = ZOO["n_envs"] * ZOO["n_steps"]
    sb3 = np.asarray(seconds.get("sb3", []), dtype=float).reshape(-1, 2)
    lines = ["| variant | processes | median s / iteration | env steps / s | env steps / CPU s "
             "| × SB3 gSDE's env steps / s | × SB3 gSDE's env steps / CPU s | iterations timed per process |",
             "| --- | --- | --- | --- | --- | --- | --- | --- |"]
    for variant, pairs in seconds.items():
        own = np.asarray(pairs, dtype=float)
        wall, cpu = np.median(own[:, 0]), np.median(own[:, 1])
        ratios = []
        for column in (0, 1):
            if not len(sb3):
                ratios.append("-")
                continue
            ratio = sb3[:, column].mean() / own[:, column].mean()
            if len(sb3) > 1 and len(own) > 1:
                _, low, high = bootstrap_interval((sb3[:, column], own[:, column]),
                                                  statistic=lambda a, b: a.mean(-1) / b.mean(-1))
                ratios.append(f"{ratio:.2f} [{low:.2f}, {high:.2f}]")
            else:
                ratios.append(f"{ratio:.2f}")
        lines.append(f"| {variant} | {len(own)} | {wall:.2f} | {frames / wall:.0f} | {frames / cpu:.0f} "
                     f"| {ratios[0]} | {ratios[1]} | {timed} |")
    return "\n".join(lines) + "\n"


def iteration_phases(variant: str, rollouts: int) -> dict[str, float]:
    """Seconds per iteration of each phase of ``variant``'s training, the first iteration left out."""
    with TIMER.on() as timed:
        seconds, _ = iteration_seconds(variant, rollouts)
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
    rows = ["iteration", "collect", "collect: pybullet step", "GAE", "update", "update: minibatch indexing",
            "update: loss forward", "update: backward", "update: clip + Adam step"]
    lines = [f"| seconds per iteration | {' | '.join(variants)} |", f"| --- |{' --- |' * len(variants)}"]
    for row in rows:
        cells = [f"{table[v][row]:.2f}" if row in table[v] else "-" for v in variants]
        lines.append(f"| {row} | {' | '.join(cells)} |")
    return "\n".join(lines) + "\n"
