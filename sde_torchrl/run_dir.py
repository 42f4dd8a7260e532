"""A job's run directory: which files it holds, and how each is written.

- ``metrics.csv``: one row per (run, update), flushed as written (:class:`MetricsFile`);
- ``summary.json``: written atomically at the end;
- ``checkpoint.pt``: see :mod:`sde_torchrl.checkpoint`;
- ``error.txt``: only for a failed job (written by ``train.py``);
- ``*/scalars/*.csv``: the TorchRL CSV logger's curves, cut back on resume.

A directory without a checkpoint starts a new job: :meth:`RunDirectory.start_new_job` removes
the outputs of an earlier, unfinished or failed job there, so that no stale file is mistaken
for this job's.
"""

from __future__ import annotations

import csv
import os
from pathlib import Path
from typing import Any

from sde_torchrl.checkpoint import CHECKPOINT, CheckpointMismatchError
from sde_torchrl.files import write_atomically, write_json_atomic

METRIC_FIELDS = ("run", "update", "episodes", "return_mean", "eval_return", "grad_norm")


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
        self.path = Path(path)
        self.path.mkdir(parents=True, exist_ok=True)
        self.metrics = self.path / "metrics.csv"
        self.summary = self.path / "summary.json"
        self.error = self.path / "error.txt"
        self.checkpoint = self.path / CHECKPOINT

    def has_checkpoint(self) -> bool:
        return self.checkpoint.exists()

    def start_new_job(self) -> None:
        """Removes an earlier job's metrics, summary and error file (no checkpoint: nothing resumes)."""
        for stale in (self.metrics, self.summary, self.error):
            stale.unlink(missing_ok=True)

    def clear_error(self) -> None:
        """Removes the error file of a failed session (the job is resumed)."""
        self.error.unlink(missing_ok=True)

    def write_summary(self, summary: dict[str, Any]) -> None:
        write_json_atomic(self.summary, summary)

    def open_metrics(self, keep_rows: int) -> MetricsFile:
        """``metrics.csv`` continued after its first ``keep_rows`` data rows (0: a new file)."""
        return MetricsFile(self.metrics, keep_rows)

    def truncate_logger_csv(self, max_step: int) -> None:
        """Drops the TorchRL CSV logger's rows logged after ``max_step`` (a resumed job logs them again)."""
        for path in self.path.glob("*/scalars/*.csv"):
            lines = path.read_bytes().splitlines(keepends=True)
            kept = [line for line in lines if line.endswith(b"\n") and _step_of(line) <= max_step]
            if len(kept) != len(lines):
                write_atomically(path, lambda f, kept=kept: f.writelines(kept))


def _step_of(line: bytes) -> float:
    try:
        return float(line.split(b",", 1)[0])
    except ValueError:
        return float("inf")


class MetricsFile:
    """``metrics.csv``, opened to continue after its first ``keep_rows`` data rows.

    Rows are flushed as they are written (a crash keeps every finished update); rows beyond
    ``keep_rows`` (written after the checkpoint a job resumes from) are dropped first, by
    rewriting the kept lines byte for byte, atomically.

    Args:
        path: the CSV file.
        keep_rows: data rows to keep from an existing file (0 starts a new file).
    """

    def __init__(self, path: Path, keep_rows: int = 0) -> None:
        self.path, self.keep_rows = path, keep_rows
        self._file: Any = None
        self._writer: csv.DictWriter | None = None

    def __enter__(self) -> MetricsFile:
        if self.keep_rows:
            self._cut()
        self._file = open(self.path, "a" if self.keep_rows else "w", newline="")
        self._writer = csv.DictWriter(self._file, fieldnames=METRIC_FIELDS)
        if not self.keep_rows:
            self._writer.writeheader()
        return self

    def _cut(self) -> None:
        lines = self.path.read_bytes().splitlines(keepends=True) if self.path.exists() else []
        kept = lines[: 1 + self.keep_rows]
        if len(kept) < 1 + self.keep_rows or not all(line.endswith(b"\n") for line in kept):
            raise CheckpointMismatchError(
                f"{self.path} holds fewer rows ({max(len(lines) - 1, 0)}) than the checkpoint "
                f"needs ({self.keep_rows}); delete the checkpoint to start over"
            )
        write_atomically(self.path, lambda f: f.writelines(kept))

    def write(self, rows: list[dict[str, Any]]) -> None:
        """Appends rows and flushes them to the OS."""
        self._writer.writerows(rows)
        self._file.flush()

    def sync(self) -> None:
        """Makes the rows written so far durable (before a checkpoint refers to them)."""
        self._file.flush()
        os.fsync(self._file.fileno())

    def __exit__(self, *exc: Any) -> None:
        self._file.close()
