"""A job's run directory: which files it holds, and how each is written and checked.

- ``.lock``: held by the one process working in the directory (:mod:`sde_torchrl.jobs.lock`);
- ``metrics.csv``: one row per (run, update), flushed as written (:class:`MetricsFile`); on
  resume, its rows up to the checkpoint must be exactly those the checkpoint recorded
  (:meth:`RunDirectory.check_metrics`), and a missing one is rebuilt from the checkpoint;
- ``summary.json``: strict JSON (no NaN or infinity), written atomically at the end;
- ``job_config.json``: the config the rows were written under, so that a rerun with another
  config is refused before the first checkpoint as after it;
- ``checkpoint.pt`` and the one before it, ``checkpoint.prev.pt``: see :mod:`sde_torchrl.jobs.checkpoint`;
- ``error.txt``: only for a failed job (written by ``train.py``);
- ``*/scalars/*.csv``: the TorchRL CSV logger's curves, cut back on resume.

A directory without a checkpoint starts a new job: :meth:`RunDirectory.start_new_job` removes
the outputs of an earlier, unfinished or failed job there, so that no stale file is mistaken
for this job's.

Read back, beside the writer: :func:`read_metrics` is the one parser of ``metrics.csv`` (typed
:class:`MetricRow` rows), and :func:`read_finished_run` / :func:`finished_runs` the one reader of
a finished job (summary, config and rows), which refuses a directory a live job holds or whose
files disagree; the analysis scripts read run directories through them only.
"""

from __future__ import annotations

import csv
import io
import json
import logging
import math
import os
from collections.abc import Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

import torch

from sde_torchrl.jobs.checkpoint import (
    CHECKPOINT,
    PREVIOUS,
    CheckpointMismatchError,
    config_differences,
    load_checkpoint,
)
from sde_torchrl.jobs.lock import held_by, hold_run_directory, make_run_directory
from sde_torchrl.utils.files import DamagedFileError, as_disk_full, write_atomically, write_json_atomic

log = logging.getLogger(__name__)

#: The exploration state after each update (:func:`~sde_torchrl.trainers.summary.exploration_state`).
EXPLORATION_FIELDS = ("sigma_min", "sigma_max", "weight_max")
METRIC_FIELDS = ("run", "update", "episodes", "return_mean", "eval_return", "grad_norm", *EXPLORATION_FIELDS)


def metric_rows(
    first_run: int, update: int, episodes: int, return_mean: torch.Tensor,
    eval_return: torch.Tensor | None, grad_norm: torch.Tensor, exploration: torch.Tensor,
) -> list[dict[str, Any]]:
    """The ``metrics.csv`` rows of one update, one per run.

    Args:
        first_run: global index of the job's first run.
        update: the update (0-based).
        episodes: episodes each run has collected by its end.
        return_mean: mean exploratory return per run ``[runs]``.
        eval_return: mean deterministic return per run, or ``None`` (not evaluated).
        grad_norm: gradient norm per run ``[runs]``.
        exploration: the :data:`EXPLORATION_FIELDS` per run after the update, ``[3, runs]``.

    Examples:
        >>> metric_rows(2, 0, 10, torch.tensor([-1.5]), None, torch.tensor([0.25]),
        ...             torch.tensor([[0.125], [0.5], [2.0]]))  # doctest: +NORMALIZE_WHITESPACE
        [{'run': 2, 'update': 0, 'episodes': 10, 'return_mean': -1.5, 'eval_return': '', 'grad_norm': 0.25,
          'sigma_min': 0.125, 'sigma_max': 0.5, 'weight_max': 2.0}]
    """
    return [{
        "run": first_run + r, "update": update, "episodes": episodes,
        "return_mean": float(return_mean[r]),
        "eval_return": "" if eval_return is None else float(eval_return[r]),
        "grad_norm": float(grad_norm[r]),
        **{name: float(exploration[i, r]) for i, name in enumerate(EXPLORATION_FIELDS)},
    } for r in range(len(return_mean))]


def csv_lines(rows: Sequence[dict[str, Any]]) -> list[bytes]:
    """The lines of a ``metrics.csv`` holding ``rows``, header first, byte for byte as
    :class:`MetricsFile` writes them.

    Examples:
        >>> lines = csv_lines(metric_rows(0, 3, 40, torch.tensor([-1.0]), torch.tensor([-0.5]), torch.tensor([2.0]),
        ...                               torch.tensor([[0.25], [0.5], [1.0]])))
        >>> for line in lines:
        ...     print(line.decode().rstrip())
        run,update,episodes,return_mean,eval_return,grad_norm,sigma_min,sigma_max,weight_max
        0,3,40,-1.0,-0.5,2.0,0.25,0.5,1.0
    """
    text = io.StringIO(newline="")
    writer = csv.DictWriter(text, fieldnames=METRIC_FIELDS)
    writer.writeheader()
    writer.writerows(rows)
    return text.getvalue().encode().splitlines(keepends=True)


class MetricRow(NamedTuple):
    """One ``metrics.csv`` row, typed: one run after one update (:data:`METRIC_FIELDS`).

    ``eval_return`` is ``None`` for an update without an evaluation; ``grad_norm`` and the
    exploration state (:data:`EXPLORATION_FIELDS`) are ``None`` in files written before they were
    recorded (their column is missing or empty).

    Examples:
        >>> row = MetricRow(run=0, update=3, episodes=40, return_mean=-1.0, eval_return=None)
        >>> row.eval_return is None, row.sigma_min is None
        (True, True)
    """

    run: int
    update: int
    episodes: int
    return_mean: float
    eval_return: float | None = None
    grad_norm: float | None = None
    sigma_min: float | None = None
    sigma_max: float | None = None
    weight_max: float | None = None


def read_metrics(path: str | os.PathLike) -> list[MetricRow]:
    """Reads ``metrics.csv`` into typed rows, in file order (update by update, runs within an
    update): the one parser of the file :class:`MetricsFile` writes.

    Args:
        path: the CSV file.

    Returns:
        One :class:`MetricRow` per line after the header.

    Raises:
        FileNotFoundError: there is no such file.

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "metrics.csv"
        >>> _ = path.write_bytes(b"".join(csv_lines(metric_rows(
        ...     0, 0, 5, torch.tensor([-1.5, -2.0]), None, torch.tensor([0.5, 0.25]),
        ...     torch.tensor([[0.125, 0.25], [0.5, 0.75], [1.0, 2.0]])))))
        >>> [(row.run, row.return_mean, row.eval_return, row.sigma_max) for row in read_metrics(path)]
        [(0, -1.5, None, 0.5), (1, -2.0, None, 0.75)]
    """
    def number(text: str | None) -> float | None:
        return float(text) if text else None

    with open(path, newline="") as f:
        return [MetricRow(int(row["run"]), int(row["update"]), int(row["episodes"]), float(row["return_mean"]),
                          *(number(row.get(name)) for name in METRIC_FIELDS[4:]))
                for row in csv.DictReader(f)]


class RunDirectory:
    """The files of one job.

    Args:
        path: the directory (created if missing).

    Examples:
        >>> import tempfile
        >>> run_dir = RunDirectory(tempfile.mkdtemp())
        >>> run_dir.checkpoint.name, run_dir.has_checkpoint()
        ('checkpoint.pt', False)
    """

    def __init__(self, path: str | os.PathLike) -> None:
        self.path = make_run_directory(path)
        self.metrics = self.path / "metrics.csv"
        self.summary = self.path / "summary.json"
        self.error = self.path / "error.txt"
        self.checkpoint = self.path / CHECKPOINT
        self.job_config = self.path / "job_config.json"

    def has_checkpoint(self) -> bool:
        return self.checkpoint.exists()

    def lock(self) -> AbstractContextManager[None]:
        """Holds the directory for this process (:func:`~sde_torchrl.jobs.lock.hold_run_directory`).

        Raises:
            RunDirectoryInUse: another live process holds it.
        """
        return hold_run_directory(self.path)

    def start_new_job(self, config: dict[str, Any] | None = None) -> None:
        """Removes an earlier job's metrics, summary, error file and TorchRL CSV logger files
        (no checkpoint: nothing resumes; the logger would otherwise append to the old rows), and
        records ``config`` in ``job_config.json``.

        Rows of an earlier job whose recorded config differs are not removed: such a directory
        is refused as one with another config's checkpoint is.

        Raises:
            CheckpointMismatchError: ``metrics.csv`` holds rows of a job with another config.
        """
        if config is not None and self.job_config.exists() and self.metrics.exists() \
                and len(self.metrics.read_bytes().splitlines()) > 1:
            diff = config_differences(json.loads(self.job_config.read_text()), config)
            if diff:
                raise CheckpointMismatchError(
                    f"{self.path} holds the rows of a job with another config ({'; '.join(diff[:5])}); they were left "
                    "unchanged: rerun with the same overrides, or give this job another directory (hydra.run.dir, "
                    "or hydra.sweep.dir for a sweep), or delete its metrics.csv")
        previous = self.path / PREVIOUS  # another job's: never a remedy for this one
        for stale in (self.metrics, self.summary, self.error, previous, *self._logger_csv_files()):
            stale.unlink(missing_ok=True)
        if config is not None:
            write_json_atomic(self.job_config, config)

    def clear_error(self) -> None:
        """Removes the error file of a failed session (the job is resumed)."""
        self.error.unlink(missing_ok=True)

    def write_summary(self, summary: dict[str, Any]) -> None:
        """Writes ``summary.json`` atomically.

        Raises:
            ValueError: a value is NaN or infinite (JSON has neither): nothing is written.
        """
        where = _non_finite(summary)
        if where is not None:
            raise ValueError(f"{self.summary} not written: {where} is not a finite number")
        write_json_atomic(self.summary, summary)

    def check_metrics(self, rows: Sequence[dict[str, Any]], finished: bool) -> None:
        """Checks that ``metrics.csv`` begins with exactly ``rows`` (what the checkpoint recorded)
        and, for a finished job, holds nothing more; a missing file is rebuilt from ``rows``.

        Raises:
            DamagedFileError: a row differs or is cut short, rows are missing, or a finished job's
                file holds more (nothing is changed).
        """
        expected = csv_lines(rows)
        if not self.metrics.exists():
            log.warning("%s is missing: its %d rows are rebuilt from %s", self.metrics, len(rows), CHECKPOINT)
            write_atomically(self.metrics, lambda f: f.writelines(expected))
            return
        lines = self.metrics.read_bytes().splitlines(keepends=True)
        problem = _first_difference(lines, expected, rows)
        if problem is None and len(lines) < len(expected):
            problem = f"it holds {max(len(lines) - 1, 0)} of the {len(rows)} rows {CHECKPOINT} recorded"
        if problem is None and finished and len(lines) > len(expected):
            extra = len(lines) - len(expected)
            problem = f"it holds {extra} line{'s' if extra > 1 else ''} after the job's last update"
        if problem is not None:
            raise DamagedFileError(self.metrics, problem, (
                f"delete it and run the job again: its {len(rows)} rows (every update up to the "
                f"checkpoint) are rebuilt from {CHECKPOINT}, nothing is lost"))

    def open_metrics(self, rows: Sequence[dict[str, Any]]) -> MetricsFile:
        """``metrics.csv`` cut back to ``rows`` (checked by :meth:`check_metrics`) and continued."""
        return MetricsFile(self.metrics, csv_lines(rows))

    def truncate_logger_csv(self, max_step: int) -> None:
        """Drops the TorchRL CSV logger's rows logged after ``max_step`` (a resumed job logs them again)."""
        for path in self._logger_csv_files():
            lines = path.read_bytes().splitlines(keepends=True)
            kept = [line for line in lines if line.endswith(b"\n") and _step_of(line) <= max_step]
            if len(kept) != len(lines):
                write_atomically(path, lambda f, kept=kept: f.writelines(kept))

    def _logger_csv_files(self) -> list[Path]:
        return sorted(self.path.glob("*/scalars/*.csv"))


class UnfinishedRunError(ValueError):
    """A run directory that does not hold a finished job: running, interrupted, failed, or
    with files that disagree with each other.

    Examples:
        >>> str(UnfinishedRunError("runs/3", "it has no summary.json", "run its command again"))
        'runs/3 is not a finished run: it has no summary.json; run its command again'
    """

    def __init__(self, path: str | os.PathLike, problem: str, remedy: str) -> None:
        self.path, self.problem = Path(path), problem
        super().__init__(f"{path} is not a finished run: {problem}; {remedy}")


@dataclass(frozen=True)
class FinishedRun:
    """A finished job's outputs, read by :func:`read_finished_run`.

    Attributes:
        path: the run directory.
        summary: ``summary.json``.
        rows: ``metrics.csv``'s rows (:func:`read_metrics`), one per (update, run).

    Examples:
        >>> rows = [MetricRow(run, update, 10 * update, -float(run), -0.5 if update else None)
        ...         for update in range(2) for run in (4, 5)]
        >>> job = FinishedRun(Path("runs/0"), {"first_run": 4, "runs": 2, "config": {"seed": 1}}, rows)
        >>> job.series("eval_return"), job.config
        ({4: [(1, -0.5)], 5: [(1, -0.5)]}, {'seed': 1})
        >>> job.values("return_mean")
        {4: [-4.0, -4.0], 5: [-5.0, -5.0]}
    """

    path: Path
    summary: dict[str, Any]
    rows: list[MetricRow]

    @property
    def config(self) -> dict[str, Any]:
        """The resolved config the job ran with (the summary's ``config`` label; empty if none)."""
        return self.summary.get("config", {})

    def series(self, field: str) -> dict[int, list[tuple[int, float]]]:
        """One column per run: global run index → ``(update, value)`` in update order, the updates
        without a value (``None``: no evaluation, not recorded) left out; a run without any value
        is left out."""
        found: dict[int, list[tuple[int, float]]] = {}
        for row in self.rows:
            value = getattr(row, field)
            if value is not None:
                found.setdefault(row.run, []).append((row.update, value))
        return found

    def values(self, field: str) -> dict[int, list[float]]:
        """:meth:`series` without the updates: global run index → the column's values in update order."""
        return {run: [value for _, value in points] for run, points in self.series(field).items()}


def read_finished_run(path: str | os.PathLike) -> FinishedRun:
    """Reads a run directory that holds a finished job, after checking that its files agree:
    no live process holds it, ``summary.json`` exists, ``metrics.csv`` has one row per run for
    each of the summary's ``updates_done`` updates, and a ``checkpoint.pt`` (if kept) is the
    finished job's at that update. The one reader for analysis scripts: a directory mid-run, or
    left by an interrupted or failed job, is refused by name instead of read as a result.

    Args:
        path: the run directory.

    Returns:
        The summary and the typed metrics rows.

    Raises:
        UnfinishedRunError: the job is running, did not finish, or its files disagree.
        DamagedFileError: ``summary.json`` is not valid JSON, or ``checkpoint.pt`` is damaged.

    Examples:
        >>> import tempfile
        >>> read_finished_run(tempfile.mkdtemp())  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.jobs.run_dir.UnfinishedRunError: ... is not a finished run: it has no summary.json; ...
    """
    path = Path(path)
    again = "run the job's command again to finish it (it resumes from its checkpoint)"
    holder = held_by(path)
    if holder is not None:
        raise UnfinishedRunError(path, f"a job is running in it (pid {holder})", "read it once that job has ended")
    if not (path / "summary.json").exists():
        raise UnfinishedRunError(path, "it has no summary.json", again)
    summary = read_summary(path / "summary.json")
    rows = read_metrics(path / "metrics.csv")
    runs, updates = summary.get("runs"), summary.get("updates_done")
    if not isinstance(runs, int) or not isinstance(updates, int):
        raise UnfinishedRunError(path, "its summary.json names no runs and updates_done", again)
    if len(rows) != runs * updates or (rows and rows[-1].update != updates - 1):
        last = rows[-1].update if rows else "none"
        raise UnfinishedRunError(path, f"metrics.csv has {len(rows)} rows up to update {last}, summary.json says "
                                       f"{runs} runs × {updates} updates", again)
    if (path / CHECKPOINT).exists():
        loop = load_checkpoint(path / CHECKPOINT)["loop"]
        if loop.get("update") != updates or not loop.get("finished"):
            raise UnfinishedRunError(path, f"its {CHECKPOINT} is at update {loop.get('update')}"
                                           f"{'' if loop.get('finished') else ' (unfinished)'}, summary.json says "
                                           f"{updates}", again)
    return FinishedRun(path, summary, rows)


def finished_runs(*directories: str | os.PathLike) -> list[FinishedRun]:
    """Every run directory under ``directories`` (each one holding a ``metrics.csv``), read by
    :func:`read_finished_run`, directory by directory in path order: one that is not finished
    refuses the whole set, naming it, rather than giving results with a run missing or cut short.

    Args:
        directories: sweep or run directories (shards of one sweep may be given together).

    Raises:
        UnfinishedRunError: a run directory under ``directories`` is not finished.

    Examples:
        >>> import tempfile
        >>> finished_runs(tempfile.mkdtemp(), tempfile.mkdtemp())
        []
    """
    return [read_finished_run(metrics.parent) for directory in directories
            for metrics in sorted(Path(directory).rglob("metrics.csv"))]


def read_summary(path: str | os.PathLike) -> dict[str, Any]:
    """Reads a job's ``summary.json`` as strict JSON.

    Raises:
        DamagedFileError: it is not a JSON object (cut short, overwritten, NaN or infinity in
            it); the remedy is to run the job again, which rewrites it from the checkpoint.

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "summary.json"
        >>> write_json_atomic(path, {"runs": 2})
        >>> read_summary(path)
        {'runs': 2}
    """
    path = Path(path)
    remedy = f"run the job's command again: a finished job rewrites {path.name} from its {CHECKPOINT}"

    def refuse(constant: str) -> None:
        raise ValueError(f"{constant} is not JSON")

    try:
        summary = json.loads(path.read_bytes(), parse_constant=refuse)
    except ValueError as error:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise DamagedFileError(path, f"it is not valid JSON ({error})", remedy) from None
    if not isinstance(summary, dict):
        raise DamagedFileError(path, f"it holds a JSON {type(summary).__name__}, not an object", remedy)
    return summary


def _first_difference(lines: list[bytes], expected: list[bytes], rows: Sequence[dict[str, Any]]) -> str | None:
    """What is wrong with the first line of ``lines`` that differs from ``expected``, if any."""
    for i, (have, want) in enumerate(zip(lines, expected, strict=False)):
        if have == want:
            continue
        if i == 0:
            return f"its header is not {','.join(METRIC_FIELDS)}"
        row = f"row {i} (run {rows[i - 1]['run']}, update {rows[i - 1]['update']})"
        if want.startswith(have):
            return f"{row} is cut short"
        return f"{row} differs from what {CHECKPOINT} recorded"
    return None


def _non_finite(value: Any, where: str = "") -> str | None:
    """The key path of the first NaN or infinite float in ``value`` (nested dicts and lists)."""
    if isinstance(value, float) and not math.isfinite(value):
        return f"{where} = {value}"
    items = value.items() if isinstance(value, dict) else enumerate(value) if isinstance(value, list) else ()
    for key, item in items:
        found = _non_finite(item, f"{where}.{key}" if isinstance(key, str) else f"{where}[{key}]")
        if found is not None:
            return found.lstrip(".")
    return None


def _step_of(line: bytes) -> float:
    try:
        return float(line.split(b",", 1)[0])
    except ValueError:
        return float("inf")


class MetricsFile:
    """``metrics.csv``, opened to continue after the lines ``kept`` (header first).

    Rows are flushed as they are written (a crash keeps every finished update); lines beyond
    ``kept`` (written after the checkpoint a job resumes from) are dropped first, by rewriting
    the kept lines byte for byte, atomically.

    Args:
        path: the CSV file.
        kept: its lines to keep (:func:`csv_lines`; a new job keeps just the header).

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "metrics.csv"
        >>> with MetricsFile(path, csv_lines([])) as metrics:
        ...     metrics.write(metric_rows(0, 0, 5, torch.tensor([-1.0]), None, torch.tensor([2.0]),
        ...                               torch.tensor([[0.5], [0.5], [1.0]])))
        >>> path.read_text().splitlines()[1]
        '0,0,5,-1.0,,2.0,0.5,0.5,1.0'
    """

    def __init__(self, path: Path, kept: list[bytes]) -> None:
        self.path, self.kept = path, kept
        self._file: Any = None
        self._writer: csv.DictWriter | None = None

    def __enter__(self) -> MetricsFile:
        if not self.path.exists() or self.path.stat().st_size != sum(map(len, self.kept)):
            write_atomically(self.path, lambda f: f.writelines(self.kept))
        self._file = open(self.path, "a", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=METRIC_FIELDS)
        return self

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Appends rows and flushes them to the OS.

        Raises:
            DiskFullError: the device is full (the rows after the last checkpoint are redone
                when the job resumes).
        """
        try:
            self._writer.writerows(rows)
            self._file.flush()
        except OSError as error:
            raise as_disk_full(self.path, error) from error

    def sync(self) -> None:
        """Makes the rows written so far durable (before a checkpoint refers to them)."""
        try:
            self._file.flush()
            os.fsync(self._file.fileno())
        except OSError as error:
            raise as_disk_full(self.path, error) from error

    def __exit__(self, *exc: Any) -> None:
        self._file.close()
