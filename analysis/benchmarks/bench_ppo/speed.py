"""How fast one PPO iteration runs (``speed``) and where its time goes (``phases``): each variant
trained for a few iterations in a fresh process of its own, on one thread."""

from __future__ import annotations

import numpy as np
import torch

from analysis.benchmarks.bench_ppo.build import ZOO
from analysis.benchmarks.bench_ppo.timing import TIMER
from analysis.benchmarks.bench_ppo.train import train_sb3, train_torchrl

#: ``+compile``: the update compiled; ``+compile+policy``: the collector's policy forward as well.
SPEED_VARIANTS = ("plain", "plain+compile", "plain+compile+policy", "sde", "sde+compile", "sde+compile+policy", "sb3",
                  "sb3_gauss")


def iteration_seconds(variant: str, rollouts: int) -> float:
    """Median wall time of one training iteration of ``variant``, the first iteration left out."""
    torch.set_num_threads(1)
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    method, *options = variant.split("+")
    if method.startswith("sb3"):
        result = train_sb3(0, rollouts * frames, use_sde=method == "sb3", evaluate=False)
    else:
        result = train_torchrl(method, 0, rollouts * frames, compile_update="compile" in options, evaluate=False,
                               compile_policy="policy" in options)
    return float(np.median(np.diff(result["iteration_ends_s"])))


def speed(variants: list[str], rollouts: int) -> str:
    """Env steps per second of one training iteration (collect ``n_envs × n_steps``, then update).

    Each variant (``sde``, ``sde+compile``, ``sde+compile+policy``, the same for ``plain``, ``sb3``,
    ``sb3_gauss``) trains ``rollouts`` iterations on one thread in a fresh process of its own (in
    one process, whatever runs later runs slower), one variant after the other, in the order
    given (a variant may come twice); the first iteration (warm-up, compilation) is left out and
    the median of the others is reported. With ``sb3`` among them, each variant's speed is also
    given as a ratio to SB3 gSDE's (the median of its entries, if it came more than once).
    """
    import multiprocessing

    seconds = []
    for variant in variants:
        with multiprocessing.get_context("spawn").Pool(1) as pool:
            seconds.append(pool.apply(iteration_seconds, (variant, rollouts)))
    return speed_table(variants, seconds, rollouts - 1)


def speed_table(variants: list[str], seconds: list[float], timed: int) -> str:
    """The ``speed`` table: seconds per iteration, env steps per second and, with ``sb3`` among
    the variants, the ratio to SB3 gSDE's speed (its median over its entries).

    Examples:
        >>> print(speed_table(["sb3", "sde", "sb3"], [4.0, 5.0, 6.0], 5).splitlines()[3])
        | sde | 5.00 | 1638 | 1.00 | 5 |
    """
    frames = ZOO["n_envs"] * ZOO["n_steps"]
    reference = [s for v, s in zip(variants, seconds, strict=True) if v == "sb3"]
    sb3 = float(np.median(reference)) if reference else None
    lines = ["| variant | median s / iteration | env steps / s | × SB3 gSDE's env steps / s | iterations timed |",
             "| --- | --- | --- | --- | --- |"]
    for variant, s in zip(variants, seconds, strict=True):
        ratio = f"{sb3 / s:.2f}" if sb3 else "-"
        lines.append(f"| {variant} | {s:.2f} | {frames / s:.0f} | {ratio} | {timed} |")
    return "\n".join(lines) + "\n"


def iteration_phases(variant: str, rollouts: int) -> dict[str, float]:
    """Seconds per iteration of each phase of ``variant``'s training, the first iteration left out."""
    with TIMER.on() as timed:
        seconds = iteration_seconds(variant, rollouts)
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
