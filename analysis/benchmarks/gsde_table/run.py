"""``run``: train the table's cells on both sides into one folder, a few runs at a time.

The folder::

    <out>/table.json                       the fraction of the budget and the overrides
    <out>/ours/<algo>_<env>_<noise>_seed<k>/   train.py's run directory (metrics.csv, summary.json, ...)
    <out>/sb3/<algo>_<env>_<noise>_seed<k>.json        the SB3 run's record, written whole
    <out>/sb3/<algo>_<env>_<noise>_seed<k>.error.txt   a failed SB3 run's error (no record)

A folder holds runs of one fraction and one set of overrides: :func:`open_folder` refuses another
(:class:`FolderMismatch`). A finished run (ours: a finished run directory; SB3: its record) is
skipped; an unfinished one of ours resumes from its checkpoint, an SB3 one starts again.
"""

from __future__ import annotations

import json
import logging
import time
import traceback
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from analysis.benchmarks.common import versions, write_run
from analysis.benchmarks.gsde_table.cells import Cell, compose_cell
from analysis.benchmarks.gsde_table.sb3 import sb3_settings, train_sb3
from analysis.runner import JobPool, TrainJob, is_finished, run_train_job

log = logging.getLogger("gsde_table")

#: The folder's record of what its runs are.
MANIFEST = "table.json"
#: Rough cost of an env step by algorithm, to start the longest runs first (SAC: 8 gradient steps per 8 env steps).
STEP_COST = {"ppo": 1.0, "a2c": 1.0, "sac": 4.0}


class FolderMismatch(RuntimeError):
    """A folder that holds runs of another fraction or other overrides than those asked for."""


def open_folder(out: Path, fraction: float, overrides: Sequence[str]) -> dict[str, Any]:
    """The folder's manifest, written on first use; refuses a folder of another fraction or overrides.

    Args:
        out: the folder.
        fraction: the fraction of the experiments' budget of this run.
        overrides: the overrides of this run (both sides).

    Returns:
        The manifest: ``{"fraction", "overrides"}``.

    Raises:
        FolderMismatch: ``out`` holds runs at another fraction or with other overrides.

    Examples:
        >>> import tempfile
        >>> folder = Path(tempfile.mkdtemp())
        >>> open_folder(folder, 0.01, ["eval_episodes=2"])
        {'fraction': 0.01, 'overrides': ['eval_episodes=2']}
        >>> open_folder(folder, 0.05, ["eval_episodes=2"])  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        analysis.benchmarks.gsde_table.run.FolderMismatch: ... holds runs at --fraction 0.01 ...
    """
    wanted = {"fraction": float(fraction), "overrides": list(overrides)}
    path = out / MANIFEST
    if path.exists():
        held = json.loads(path.read_text())
        if held != wanted:
            def describe(m: dict) -> str:
                return f"--fraction {m['fraction']:g} with overrides [{', '.join(m['overrides'])}]"
            raise FolderMismatch(
                f"{out} holds runs at {describe(held)}; this run asks for {describe(wanted)}: runs of two budgets "
                f"or settings do not make one table. Give --out another folder, or run again with "
                f"{describe(held)} to add to this one")
        return held
    out.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(wanted, indent=1) + "\n")
    return wanted


def ours_dir(out: Path, cell: Cell) -> Path:
    """Our run directory of ``cell``."""
    return out / "ours" / cell.name


def sb3_record(out: Path, cell: Cell) -> Path:
    """The SB3 record of ``cell``; its error file is :func:`sb3_error`."""
    return out / "sb3" / f"{cell.name}.json"


def sb3_error(out: Path, cell: Cell) -> Path:
    """Where a failed SB3 run of ``cell`` leaves its error."""
    return out / "sb3" / f"{cell.name}.error.txt"


def run_sb3(cell: Cell, settings: dict[str, Any], fraction: float, overrides: Sequence[str], out: Path) -> str | None:
    """Train the SB3 side of ``cell`` (on one thread) and write its record; a failure writes the
    error file instead (and no record) and returns its one line."""
    import torch

    torch.set_num_threads(1)  # one core per run, as ours (train.py's threads=1)
    error = sb3_error(out, cell)
    try:
        result = train_sb3(settings, cell.seed)
    except Exception as exc:  # noqa: BLE001 - recorded by name, the other runs go on
        error.parent.mkdir(parents=True, exist_ok=True)
        error.write_text(f"{cell.name}: {type(exc).__name__}: {exc}\n\n{traceback.format_exc()}")
        return f"{type(exc).__name__}: {' '.join(str(exc).split())} (see {error})"
    libraries = ("stable_baselines3", "sb3_contrib") if settings["env"]["time_feature"] else ("stable_baselines3",)
    result.update(algorithm=cell.algorithm, env=cell.env, noise=cell.noise, seed=cell.seed, fraction=fraction,
                  overrides=list(overrides), settings=settings, versions=versions(*libraries))
    write_run(sb3_record(out, cell), result)
    error.unlink(missing_ok=True)
    return None


def run_ours(job: TrainJob) -> str | None:
    """Train our side of a cell with the ``train.py`` command (its checkpoints removed once finished)."""
    return run_train_job(job, command=True, keep_checkpoints=False)


def run_table(cells: Sequence[Cell], fraction: float, overrides: Sequence[str], out: Path,
              workers: int) -> tuple[int, int, list[str]]:
    """Train every cell on both sides, skipping finished runs, ``workers`` runs at a time.

    Every cell's config is composed and mapped to SB3 first, so that a setting SB3 cannot run
    stops the command before any training.

    Args:
        cells: the cells.
        fraction: the fraction of the experiments' budget (both sides).
        overrides: ``train.py`` overrides of every cell (both sides).
        out: the folder (:func:`open_folder`).
        workers: runs at a time.

    Returns:
        ``(done, total, failures)``: the runs finished (before or now) of the ``2 × len(cells)``,
        and each failed run's one line.

    Raises:
        FolderMismatch: ``out`` holds runs of another fraction or other overrides.
        UnmappableSetting: a cell's config has a setting SB3 cannot run.
    """
    out = out.resolve()  # train.py runs from the repository
    open_folder(out, fraction, overrides)
    tasks: dict[tuple[str, Cell], tuple] = {}
    costs: dict[tuple[str, Cell], float] = {}
    for cell in cells:
        conf, cell_overrides = compose_cell(cell, fraction, overrides)
        settings = sb3_settings(conf)
        cost = settings["total_timesteps"] * STEP_COST[cell.algorithm]
        job = TrainJob(cell.name, tuple(cell_overrides), ours_dir(out, cell), cost)
        if not is_finished(job.run_dir):
            tasks[("ours", cell)], costs[("ours", cell)] = (job,), cost
        if not sb3_record(out, cell).exists():
            tasks[("sb3", cell)], costs[("sb3", cell)] = (cell, settings, fraction, tuple(overrides), out), cost
    total = 2 * len(cells)
    log.info("%d of %d runs to train (%d finished already), %d at a time", len(tasks), total, total - len(tasks),
             workers)
    start, failures = time.perf_counter(), []

    def done(key, message: str | None) -> None:
        side, cell = key
        if message is None:
            log.info("finished %s %s after %.0f s", side, cell.name, time.perf_counter() - start)
        else:
            failures.append(f"{side} {cell.name}: {message}")
            log.error("failed %s %s: %s", side, cell.name, message)

    ordered = dict(sorted(tasks.items(), key=lambda item: costs[item[0]], reverse=True))
    if ordered:
        with JobPool(workers) as pool:
            pool.run(_run_task, {key: (key[0], *args) for key, args in ordered.items()}, done=done)
    return total - len(failures), total, failures


def _run_task(side: str, *args) -> str | None:
    """One run of either side, in a worker process."""
    return run_ours(*args) if side == "ours" else run_sb3(*args)
