"""What the PPO and SAC benchmarks against Stable-Baselines3 share: the gymnasium env by its id, a
run's record written whole with the versions it ran on, and variants timed in fresh processes
with their speed table.
"""

from __future__ import annotations

import importlib
import json
import os
import platform
from collections.abc import Callable, Sequence
from pathlib import Path

import numpy as np


def gym_make(env_id: str, **kwargs):
    """``gymnasium.make(env_id, **kwargs)``, pybullet's envs registered first for a ``...Bullet...`` id."""
    import gymnasium as gym

    if "Bullet" in env_id:
        import pybullet_envs_gymnasium  # noqa: F401  (registers the Bullet envs)
    return gym.make(env_id, **kwargs)


def versions(*libraries: str) -> dict[str, str]:
    """The versions a run ran on: torch's, torchrl's, those of ``libraries`` (module names), python's."""
    found = {name: importlib.import_module(name).__version__ for name in ("torch", "torchrl", *libraries)}
    return {**found, "python": platform.python_version()}


def write_run(path: Path, result: dict) -> Path:
    """Write a run's record as JSON, whole or not at all (a temporary file, then renamed); returns ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.tmp")
    tmp.write_text(json.dumps(result))
    os.replace(tmp, path)
    return path


def in_fresh_processes(timing: Callable[[str, int], tuple[float, float, float]], variants: Sequence[str],
                       length: int, repeats: int) -> dict[str, list[tuple[float, float, float]]]:
    """``timing(variant, length)`` of each variant, each call in a fresh spawned process of its
    own (in one process, whatever runs later runs slower), one variant after the other in the
    order given, the whole list ``repeats`` times over: per variant, one result per process.

    Examples:
        >>> in_fresh_processes(max, [], 3, 2)
        {}
    """
    import multiprocessing

    seconds: dict[str, list[tuple[float, float, float]]] = {variant: [] for variant in variants}
    for _ in range(repeats):
        for variant in variants:
            with multiprocessing.get_context("spawn").Pool(1) as pool:
                seconds[variant].append(pool.apply(timing, (variant, length)))
    return seconds


def speed_table(seconds: dict[str, list[tuple[float, float, float]]], steps: int, timed: int, unit: str) -> str:
    """A speed table from each variant's ``(wall, CPU, collection)`` seconds per ``unit`` (an
    iteration, a round), one triple per process (collection ``nan`` where not recorded): the
    medians, the update's share (wall minus collection), env steps per second and per CPU second
    and, with ``sb3`` among the variants, the ratio of SB3's seconds per unit to the variant's
    (ratio of the means over processes, 95 % bootstrap interval when both have several).

    Args:
        seconds: per variant, one ``(wall, CPU, collection)`` triple per process.
        steps: env steps per ``unit``.
        timed: units timed per process.
        unit: what one triple times.

    Examples:
        >>> table = speed_table({"sb3": [(4.0, 4.0, float("nan"))], "job": [(2.0, 2.0, 1.0)]}, 32, 9, "round")
        >>> print(table.splitlines()[3])
        | job | 1 | 2.00 | 1.00 | 1.00 | 16 | 16 | 2.00 | 2.00 | 9 |
    """
    from sde_torchrl.utils.intervals import bootstrap_interval

    sb3 = np.asarray(seconds.get("sb3", []), dtype=float).reshape(-1, 3)
    lines = [f"| variant | processes | median s / {unit} | collection s | update s | env steps / s "
             "| env steps / CPU s | × SB3's env steps / s | × SB3's env steps / CPU s "
             f"| {unit}s timed per process |",
             "| --- | --- | --- | --- | --- | --- | --- | --- | --- | --- |"]
    for variant, triples in seconds.items():
        own = np.asarray(triples, dtype=float)
        wall, cpu, collect = np.median(own[:, 0]), np.median(own[:, 1]), np.median(own[:, 2])
        phases = "- | -" if np.isnan(collect) else f"{collect:.2f} | {wall - collect:.2f}"
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
        lines.append(f"| {variant} | {len(own)} | {wall:.2f} | {phases} | {steps / wall:.0f} | {steps / cpu:.0f} "
                     f"| {ratios[0]} | {ratios[1]} | {timed} |")
    return "\n".join(lines) + "\n"
