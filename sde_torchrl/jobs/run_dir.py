"""A job's run directory: which files it holds, and how each is written and checked.

- ``.lock``: held by the one process working in the directory (:mod:`sde_torchrl.jobs.lock`);
- ``metrics.csv``: one row per (run, update), flushed as written (:class:`MetricsFile`), its
  columns declared in :mod:`sde_torchrl.jobs.metrics`; read back by :func:`read_metrics`;
- ``summary.json``: strict JSON (no NaN or infinity), written atomically at the end;
- ``job_config.json``: the config the rows were written under, with its digest
  (:meth:`RunDirectory.check_job`, the one check that a directory holds this job);
- ``checkpoint.pt`` and the one before it, ``checkpoint.prev.pt``: see :mod:`sde_torchrl.jobs.checkpoint`;
- ``error.txt``: only for a failed job;
- ``*/scalars/*.csv``: the TorchRL CSV logger's curves, cut back on resume.

A finished job is final (:class:`RunDirectory` says what that means; :func:`check_finished` is
the one check that its files agree). :func:`read_finished_run` and :func:`finished_runs` are the
one reader of finished jobs, the analysis scripts' way in.
"""

from __future__ import annotations

import csv
import hashlib
import io
import json
import logging
import math
import os
from collections.abc import Mapping, Sequence
from contextlib import AbstractContextManager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from sde_torchrl.jobs.checkpoint import (
    CHECKPOINT,
    PREVIOUS,
    CheckpointMismatchError,
    config_differences,
    load_checkpoint,
    read_checkpoint,
    result_config,
)
from sde_torchrl.jobs.lock import LOCK, held_by, hold_run_directory, make_run_directory
from sde_torchrl.jobs.metrics import (  # noqa: F401 - the metrics names this module has offered, re-exported
    EXPLORATION_FIELDS,
    METRIC_FIELDS,
    REQUIRED_FIELDS,
    MetricRow,
    MetricsFormatError,
    csv_lines,
    metric_rows,
    parse_metrics,
    recorded_rows,
    update_statistics,
)
from sde_torchrl.jobs.sweeps import listed_jobs, sweeps_under
from sde_torchrl.utils.files import DamagedFileError, as_disk_full, write_atomically, write_json_atomic

log = logging.getLogger(__name__)

#: The files a job writes into its run directory, its job record ``job_config.json`` first: a
#: directory holding any of them is a job's (:func:`job_directories`), whatever state it is in.
JOB_FILES = ("job_config.json", LOCK, "metrics.csv", "summary.json", CHECKPOINT, "error.txt")
#: ``summary.json``'s entries that its own digest (``sha256``) leaves out: the digest itself, and
#: the training time, which adds up the sessions of a resumed job.
UNDIGESTED = ("sha256", "wall_s")


def episodes_after(update: int, episodes_per_update: int, episode_queue: int = 0) -> int:
    """Episodes each run has collected by the end of update ``update`` (0-based): an episode
    queue is filled first.

    Examples:
        >>> episodes_after(0, 5), episodes_after(2, 5), episodes_after(0, 1, episode_queue=20)
        (5, 15, 20)
    """
    return (update + 1) * episodes_per_update + max(episode_queue - episodes_per_update, 0)


def read_metrics(path: str | os.PathLike) -> list[MetricRow]:
    """Reads ``metrics.csv`` into typed rows, in file order (update by update, runs within an
    update): the one parser of the file :class:`MetricsFile` writes
    (:func:`~sde_torchrl.jobs.metrics.parse_metrics`).

    Args:
        path: the CSV file.

    Returns:
        One :class:`~sde_torchrl.jobs.metrics.MetricRow` per line after the header.

    Raises:
        FileNotFoundError: there is no such file.
        MetricsFormatError: its columns are not the metrics' (an unknown, missing or repeated one).

    Examples:
        >>> import tempfile
        >>> import torch
        >>> path = Path(tempfile.mkdtemp()) / "metrics.csv"
        >>> stats = update_statistics(0, 0, 5, {"return_mean": torch.tensor([-1.5, -2.0]),
        ...     "grad_norm": torch.tensor([0.5, 0.25]), "exploration": torch.tensor([[0.125, 0.25], [0.5, 0.75],
        ...                                                                          [1.0, 2.0]])}, None)
        >>> _ = path.write_bytes(b"".join(csv_lines(metric_rows(stats))))
        >>> [(row.run, row.return_mean, row.eval_return, row.sigma_max) for row in read_metrics(path)]
        [(0, -1.5, None, 0.5), (1, -2.0, None, 0.75)]
    """
    with open(path, newline="") as f:
        return parse_metrics(csv.reader(f), str(path))


def read_metrics_text(text: str) -> list[MetricRow]:
    """:func:`read_metrics` of the file's text.

    Examples:
        >>> [row.return_mean for row in read_metrics_text("run,update,episodes,return_mean,eval_return\\r\\n"
        ...                                               "0,0,5,-1.5,\\r\\n")]
        [-1.5]
    """
    return parse_metrics(csv.reader(io.StringIO(text, newline="")))


class RunDirectory:
    """The files of one job, and the one check that they are this job's (:meth:`check_job`).

    On resume, the rows of ``metrics.csv`` up to the checkpoint must be exactly those the
    checkpoint recorded (:meth:`check_metrics`), and a missing file is rebuilt from the
    checkpoint. ``job_config.json`` makes a rerun with another config refused before the first
    checkpoint as after it; it is checked wherever it is read
    (:func:`read_job_config`), and rows without it are refused, never overwritten.

    A finished job is final: ``summary.json`` records the SHA-256 of ``metrics.csv`` and of its
    own entries, and :func:`check_finished` is the one check that its files agree (the job runs
    it before doing anything in a directory that holds a summary, the reader before reading
    one). Those two files are its result; its checkpoint decides nothing: one that is damaged,
    unfinished or of another job is named in one line and left alone, and the job is never
    trained again from it (only when the summary and the rows disagree does a finished
    checkpoint rebuild them). A rerun of the same config finds it finished and changes nothing;
    another config is refused; :meth:`start_new_job` refuses to remove or retrain a finished
    job: starting over means removing the directory. A directory without a summary or a
    checkpoint starts a new job: :meth:`start_new_job` removes the outputs of an earlier,
    unfinished or failed job there, so that no stale file is mistaken for this job's.

    Args:
        path: the directory (created if missing).
        config: the job's result config (:func:`~sde_torchrl.jobs.checkpoint.result_config`):
            what :meth:`start_new_job` records in ``job_config.json`` and a checkpoint stores,
            and what :meth:`check_job` holds the recorded one against; ``None``: no record, no check.

    Examples:
        >>> import tempfile
        >>> run_dir = RunDirectory(tempfile.mkdtemp(), {"seed": 1})
        >>> run_dir.checkpoint.name, run_dir.has_checkpoint(), run_dir.check_job()
        ('checkpoint.pt', False, None)
    """

    def __init__(self, path: str | os.PathLike, config: dict[str, Any] | None = None) -> None:
        self.path = make_run_directory(path)
        self.config = config
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

    def check_job(self) -> FinishedRun | None:
        """Whether the directory may hold this job (:attr:`config`): the one "same job?" check,
        made before anything is built or changed. What the directory holds decides which record
        counts and how a refusal reads:

        - a finished job (:meth:`_finished_job`): the config its ``job_config.json`` or its
          summary records; its checkpoint, whatever state it is in, decides nothing;
        - else a ``checkpoint.pt`` (the job resumes from it): the config it stores, which
          ``job_config.json`` must record too (a missing one is written again from it, with a
          warning);
        - else rows in ``metrics.csv``: the config ``job_config.json`` records (rows without it
          are refused, for a job with a config).

        Returns:
            The finished job, which is final (nothing is to be done); ``None``: the job starts, or
            resumes from its checkpoint.

        Raises:
            CheckpointMismatchError: the directory holds a job of another config (nothing is
                changed), or a checkpoint of another format.
            UnfinishedRunError: it holds a summary, its files disagree, and there is no finished
                checkpoint to rebuild them from.
            DamagedFileError: ``summary.json`` is not valid JSON (and there is no finished
                checkpoint), ``checkpoint.pt`` is damaged, or ``job_config.json`` is damaged,
                disagrees with the checkpoint or, beside rows, is missing.

        Examples:
            >>> import tempfile
            >>> path = tempfile.mkdtemp()
            >>> RunDirectory(path, {"lr": 0.1}).start_new_job()
            >>> with open(Path(path) / "metrics.csv", "w") as f:
            ...     _ = f.write("run,update\\n0,0\\n")
            >>> RunDirectory(path, {"lr": 0.2}).check_job()  # doctest: +ELLIPSIS
            Traceback (most recent call last):
            ...
            sde_torchrl.jobs.checkpoint.CheckpointMismatchError: ... of a job with another config (lr: 0.1 -> 0.2); ...
        """
        done = self._finished_job()
        if done is not None:
            recorded, refusal = self.recorded_config(done), self._finished_refusal
        elif self.has_checkpoint():
            recorded, refusal = read_checkpoint(self.checkpoint).get("config"), self._checkpoint_refusal
        elif self._holds_rows():
            recorded, refusal = self._rows_config(), self._rows_refusal
        else:
            recorded, refusal = None, self._rows_refusal
        if self.config is not None and recorded is not None:
            diff = config_differences(recorded, self.config)
            if diff:
                raise CheckpointMismatchError(refusal(diff))
        if done is None and self.has_checkpoint():
            self._match_job_config(recorded)
        return done

    def _holds_rows(self) -> bool:
        """Whether ``metrics.csv`` holds a row (a line after its header)."""
        return self.metrics.exists() and len(self.metrics.read_bytes().splitlines()) > 1

    def _rows_config(self) -> dict[str, Any] | None:
        """The config ``metrics.csv``'s rows were written under (``job_config.json``), checked.

        Raises:
            DamagedFileError: ``job_config.json`` is damaged, or missing while this job has a
                config to hold the rows against (they are kept, not overwritten).
        """
        if self.job_config.exists():
            return read_job_config(self.job_config)
        if self.config is None:
            return None
        rows = len(self.metrics.read_bytes().splitlines()) - 1
        raise DamagedFileError(self.job_config, (
            f"it is missing, and {self.metrics.name} holds {rows} row{'s' if rows > 1 else ''} written under the "
            "config it recorded, which cannot be told from another config's"), (
            f"the rows were left unchanged: restore {self.job_config.name} from where the directory was copied, or "
            f"move {self.metrics.name} elsewhere (mv {self.metrics} ...) to start this job over in this directory"))

    def _match_job_config(self, saved: dict[str, Any] | None) -> None:
        """Holds ``job_config.json`` against the config a checkpoint stores (``saved``): a missing
        one is written again from it, with a warning.

        Raises:
            DamagedFileError: ``job_config.json`` is damaged, or records another config.
        """
        if saved is None:
            return
        if not self.job_config.exists():
            log.warning("%s was missing: written again from the config %s records", self.job_config, CHECKPOINT)
            write_job_config(self.job_config, saved)
            return
        diff = config_differences(read_job_config(self.job_config), saved)
        if diff:
            raise DamagedFileError(self.job_config, f"it records another config than {CHECKPOINT} "
                                                    f"({'; '.join(diff[:3])})", _job_config_remedy(self.path))

    def _finished_refusal(self, diff: list[str]) -> str:
        more = ("; a finished job is not trained further in its directory: to train for other updates, "
                "give the job another directory" if {d.split(":")[0] for d in diff} == {"updates"} else "")
        return (f"{self.path} holds a finished job of another config ({'; '.join(diff[:5])}); it was left "
                f"unchanged: rerun with the same overrides, or give this job another directory (hydra.run.dir, "
                f"or hydra.sweep.dir for a sweep){more}")

    def _checkpoint_refusal(self, diff: list[str]) -> str:
        return (f"{self.checkpoint} was written by another config ({'; '.join(diff[:5])}); it was left unchanged: "
                "resume with the same overrides, or give this job another directory (hydra.run.dir, "
                "or hydra.sweep.dir for a sweep), or delete the checkpoint")

    def _rows_refusal(self, diff: list[str]) -> str:
        return (f"{self.path} holds the rows of a job with another config ({'; '.join(diff[:5])}); they were left "
                "unchanged: rerun with the same overrides, or give this job another directory (hydra.run.dir, "
                "or hydra.sweep.dir for a sweep), or delete its metrics.csv")

    def start_new_job(self) -> None:
        """Removes an earlier, unfinished job's metrics, error file and TorchRL CSV logger files
        (no checkpoint: nothing resumes; the logger would otherwise append to the old rows), and
        records :attr:`config` in ``job_config.json``. Rows of an earlier job of another config
        are refused before (:meth:`check_job`).

        Raises:
            FinishedRunError: the directory holds a finished job (its ``summary.json``): a finished
                job's files are never removed.
        """
        if self.summary.exists():
            raise FinishedRunError(self.path, "a new job would remove its files")
        previous = self.path / PREVIOUS  # another job's: never a remedy for this one
        for stale in (self.metrics, self.summary, self.error, previous, *self._logger_csv_files()):
            stale.unlink(missing_ok=True)
        if self.config is not None:
            write_job_config(self.job_config, self.config)

    def clear_error(self) -> None:
        """Removes the error file of a failed session (the job is resumed)."""
        self.error.unlink(missing_ok=True)

    def write_summary(self, summary: dict[str, Any]) -> dict[str, Any]:
        """Writes ``summary.json`` atomically, with the SHA-256 of ``metrics.csv`` as it is now
        (``metrics_sha256``) and of its own entries (``sha256``, :func:`summary_digest`), which
        :func:`check_finished` verifies.

        Returns:
            The summary written.

        Raises:
            ValueError: a value is NaN or infinite (JSON has neither): nothing is written.
        """
        where = _non_finite(summary)
        if where is not None:
            raise ValueError(f"{self.summary} not written: {where} is not a finite number")
        summary = {key: value for key, value in summary.items() if key not in ("metrics_sha256", "sha256")}
        summary["metrics_sha256"] = hashlib.sha256(self.metrics.read_bytes()).hexdigest()
        summary["sha256"] = summary_digest(summary)
        write_json_atomic(self.summary, summary)
        return summary

    def _finished_job(self) -> FinishedRun | None:
        """The finished job this directory holds, its files checked (:func:`check_finished`), if any.

        A directory with a summary held a finished job: its summary and ``metrics.csv``, which
        agree with their digests, are its result, and nothing makes it train again. Only when
        they do not agree may a finished ``checkpoint.pt`` rebuild them.

        Returns:
            The finished job, when its files agree; ``None`` when there is no ``summary.json``,
            or when they disagree and a finished ``checkpoint.pt`` decides (``metrics.csv`` is
            checked against it, the summary rewritten from it).

        Raises:
            UnfinishedRunError: its files disagree, and no finished checkpoint can rebuild them.
            DamagedFileError: ``summary.json`` is not valid JSON and no finished checkpoint can
                rebuild it, or ``job_config.json`` is damaged or records another config.
        """
        if not self.summary.exists():
            return None
        try:
            return check_finished(self.path, live=False)
        except DamagedFileError as error:  # UnfinishedRunError too
            if error.path != self.job_config and _checkpoint_is_finished(self.checkpoint):
                return None
            raise

    def recorded_config(self, job: FinishedRun) -> dict[str, Any] | None:
        """The result config a finished job ran with: its ``job_config.json``, else its summary's
        ``config`` label; ``None`` if neither records one.

        Raises:
            DamagedFileError: ``job_config.json`` is damaged.
        """
        if self.job_config.exists():
            return read_job_config(self.job_config)
        return result_config(job.summary.get("config"))

    def check_metrics(self, rows: Sequence[MetricRow], finished: bool) -> None:
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

    def open_metrics(self, rows: Sequence[MetricRow]) -> MetricsFile:
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
        return sorted(self.path.glob("*/scalars/**/*.csv"))  # a namespaced key ("train/...") is a subfolder


class UnfinishedRunError(DamagedFileError):
    """A run directory that does not hold a finished job: running, interrupted, failed, or
    with files that disagree with each other (a job refuses such a directory as it refuses a
    damaged file: ``train.py`` exits 4).

    Examples:
        >>> str(UnfinishedRunError("runs/3", "it has no summary.json", "run its command again"))
        'runs/3 is not a finished run: it has no summary.json; run its command again'
    """

    def __init__(self, path: str | os.PathLike, problem: str, remedy: str) -> None:
        super().__init__(path, problem, remedy)
        self.args = (f"{path} is not a finished run: {problem}; {remedy}",)

    def __str__(self) -> str:
        return self.args[0]


class FinishedRunError(CheckpointMismatchError):
    """A run directory that holds a finished job, which a job would have to remove or train
    again: a finished job is final (``train.py`` exits 2, nothing is changed).

    Examples:
        >>> str(FinishedRunError("runs/3", "a new job would remove its files")).split(";")[0]
        'runs/3 holds a finished job: a new job would remove its files'
    """

    def __init__(self, path: str | os.PathLike, problem: str) -> None:
        self.path = Path(path)
        super().__init__(f"{path} holds a finished job: {problem}; it was left unchanged: give this job another "
                         "directory (hydra.run.dir, or hydra.sweep.dir for a sweep), or remove that one to start over")


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


def summary_digest(summary: Mapping[str, Any]) -> str:
    """SHA-256 of ``summary.json``'s entries but :data:`UNDIGESTED` (:func:`record_digest`):
    what its ``sha256`` entry records, so that an edited summary is found.

    Examples:
        >>> summary_digest({"runs": 2, "wall_s": 1.5}) == summary_digest({"wall_s": 9.0, "runs": 2})
        True
        >>> summary_digest({"runs": 2}) == summary_digest({"runs": 3})
        False
    """
    return record_digest(summary, UNDIGESTED)


def record_digest(entries: Mapping[str, Any], left_out: Sequence[str] = ("sha256",)) -> str:
    """SHA-256 of a JSON record's entries but ``left_out``, as canonical JSON (sorted keys): the
    digest ``summary.json`` and ``job_config.json`` carry under ``sha256``.

    Examples:
        >>> record_digest({"seed": 1, "lr": 0.1}) == record_digest({"lr": 0.1, "seed": 1, "sha256": "x"})
        True
    """
    kept = {key: value for key, value in entries.items() if key not in left_out}
    text = json.dumps(kept, sort_keys=True, allow_nan=False, separators=(",", ":"))
    return hashlib.sha256(text.encode()).hexdigest()


def write_job_config(path: str | os.PathLike, config: Mapping[str, Any]) -> None:
    """Writes ``job_config.json``: the result config and its digest (``sha256``,
    :func:`record_digest`), atomically."""
    write_json_atomic(path, {**config, "sha256": record_digest(config)})


def read_job_config(path: str | os.PathLike) -> dict[str, Any]:
    """Reads ``job_config.json``, its digest checked; one without a digest is read as it is
    (the checkpoint or the summary it is held against then tells).

    Returns:
        The result config it records (its digest left out).

    Raises:
        DamagedFileError: it is not a JSON object, or does not match its digest; the remedy
            depends on what else the directory holds (:func:`_job_config_remedy`).

    Examples:
        >>> import tempfile
        >>> path = Path(tempfile.mkdtemp()) / "job_config.json"
        >>> write_job_config(path, {"seed": 1})
        >>> read_job_config(path)
        {'seed': 1}
        >>> _ = path.write_text(path.read_text().replace('"seed": 1', '"seed": 2'))
        >>> read_job_config(path)  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.utils.files.DamagedFileError: ...job_config.json is damaged: it does not match its digest ...
    """
    path = Path(path)
    remedy = _job_config_remedy(path.parent)
    try:
        record = json.loads(path.read_bytes(), parse_constant=_not_json)
    except ValueError as error:  # JSONDecodeError and UnicodeDecodeError are ValueErrors
        raise DamagedFileError(path, f"it is not valid JSON ({error})", remedy) from None
    if not isinstance(record, dict):
        raise DamagedFileError(path, f"it holds a JSON {type(record).__name__}, not an object", remedy)
    digest = record.pop("sha256", None)
    if digest is not None and digest != record_digest(record):
        raise DamagedFileError(path, "it does not match its digest (sha256): an entry was changed", remedy)
    return record


def _job_config_remedy(directory: Path) -> str:
    """The way out of a damaged ``job_config.json``, by what else the directory holds."""
    if (directory / "summary.json").exists():
        return ("restore it from where the directory was copied, or delete it: summary.json records the finished "
                "job's config too")
    if (directory / CHECKPOINT).exists():
        return f"delete it and run the job again: it is written again from the config its {CHECKPOINT} records"
    return ("restore it from where the directory was copied, or move metrics.csv elsewhere to start this job over "
            "in this directory: without it, its rows cannot be told from another config's")


def _not_json(constant: str) -> None:
    raise ValueError(f"{constant} is not JSON")


def check_finished(path: str | os.PathLike, *, live: bool = True) -> FinishedRun:
    """Checks that a run directory holds a finished job whose files agree, and reads it: the one
    check, run by the job on a directory that holds a summary (:meth:`RunDirectory.check_job`)
    and by the reader (:func:`read_finished_run`).

    - no live process holds it (``live``);
    - ``summary.json`` exists, is strict JSON and matches its own digest (``sha256``);
    - ``metrics.csv`` matches the digest the summary recorded (``metrics_sha256``), is byte for
      byte as the job writes it (header, columns, number format, line endings: implied by a
      digest that matches, as the job wrote those bytes; otherwise its rows are written again
      and compared), holds one row per
      run for each of the summary's ``updates_done`` updates in the job's order, and agrees with
      the summary's per-run returns, evaluations, episodes and env steps;
    - a ``job_config.json`` matches its digest and records the config the summary records.

    Those files are the finished job's result, and final. A kept ``checkpoint.pt`` is not part
    of it: one that is not the finished job's (damaged, of another format, at another update,
    of another config, or with other rows than ``metrics.csv``) is reported in one warning
    line and left as it is. Summaries written before the digests were recorded are checked
    without them.

    Args:
        path: the run directory.
        live: check that no live process holds it (the job itself holds it).

    Returns:
        The summary and the typed metrics rows.

    Raises:
        UnfinishedRunError: the job is running, did not finish, or its files disagree.
        DamagedFileError: ``summary.json`` is not valid JSON, or ``job_config.json`` is damaged
            or records another config.

    Examples:
        >>> import tempfile
        >>> check_finished(tempfile.mkdtemp())  # doctest: +ELLIPSIS
        Traceback (most recent call last):
        ...
        sde_torchrl.jobs.run_dir.UnfinishedRunError: ... is not a finished run: it has no summary.json; ...
    """
    path = Path(path)
    if live:
        holder = held_by(path)
        if holder is not None:
            raise UnfinishedRunError(path, f"a job is running in it (pid {holder})", "read it once that job has ended")
    if not (path / "summary.json").exists():
        raise UnfinishedRunError(path, "it has no summary.json",
                                 "run the job's command again to finish it (it resumes from its checkpoint)")
    checkpoint = path / CHECKPOINT
    try:
        summary = read_summary(path / "summary.json")
    except DamagedFileError as error:
        raise DamagedFileError(error.path, error.problem, _rebuild_remedy(checkpoint)) from None
    if not (path / "metrics.csv").exists():
        raise UnfinishedRunError(path, "it has no metrics.csv", _rebuild_remedy(checkpoint))
    data = (path / "metrics.csv").read_bytes()
    written = summary.get("metrics_sha256") == hashlib.sha256(data).hexdigest()  # the bytes the job wrote
    rows, problem = _parse_rows(data, rewrite=not written)
    for check in (_rows_problem, _summary_problem, _digest_problem):
        problem = problem or check(summary, data, rows)
    if problem is not None:
        raise UnfinishedRunError(path, problem, _rebuild_remedy(checkpoint))
    _check_job_config(path, summary)
    problem = _kept_checkpoint_problem(checkpoint, summary, data)
    if problem is not None:
        log.warning("%s was left as it is and is not used: %s; the job finished (its summary.json and metrics.csv "
                    "agree) and is final, so no checkpoint trains it again; remove this one to silence this line",
                    checkpoint, problem)
    return FinishedRun(path, summary, rows)


def _rebuild_remedy(checkpoint: Path) -> str:
    """The way out of a finished job's files that disagree: a finished checkpoint rebuilds them."""
    if _checkpoint_is_finished(checkpoint):
        return (f"run the job's command again: it checks metrics.csv against its {CHECKPOINT} and rewrites "
                "summary.json from it")
    without = f"without a {CHECKPOINT}" if not checkpoint.exists() else f"its {CHECKPOINT} is not the finished one:"
    return (f"{without} nothing can rebuild them: restore the directory from where it was copied (a committed one: "
            "git checkout -- DIRECTORY), or remove it to train the job again from the start")


def _check_job_config(path: Path, summary: dict[str, Any]) -> None:
    """A finished job's ``job_config.json``, if any, intact and of the config its summary records.

    Raises:
        DamagedFileError: it is damaged, or records another config.
    """
    record = path / "job_config.json"
    if not record.exists():
        return
    config = read_job_config(record)
    if "config" in summary:
        diff = config_differences(config, result_config(summary["config"]))
        if diff:
            raise DamagedFileError(record, f"it records another config than summary.json ({'; '.join(diff[:3])})",
                                   _job_config_remedy(path))


def read_finished_run(path: str | os.PathLike) -> FinishedRun:
    """Reads a run directory that holds a finished job, after checking that its files agree
    (:func:`check_finished`, what the job itself checks) and that no live process holds it. The
    one reader for analysis scripts: a directory mid-run, or left by an interrupted or failed
    job, or whose files were changed, is refused by name instead of read as a result.

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
    return check_finished(path, live=True)


def job_directories(directory: str | os.PathLike) -> list[Path]:
    """The run directories under ``directory`` (itself included), in path order: every directory
    holding a file only a job writes (:data:`JOB_FILES`: its job record, its lock, ...), so that a
    job killed before its first row, or live, or with its ``metrics.csv`` deleted, is found.

    A sweep's own record (``multirun.yaml``, :func:`~sde_torchrl.jobs.sweeps.listed_jobs`) lists
    its jobs: one that never started (its directory missing, or holding no job's file) is
    refused by name. A directory without that record is read by the job directories it holds.

    Raises:
        UnfinishedRunError: a sweep under ``directory`` lists a job that never started.
        DamagedFileError: a sweep's ``multirun.yaml`` cannot be read.

    Examples:
        >>> import tempfile
        >>> sweep = Path(tempfile.mkdtemp())
        >>> for job in ("0", "1"):
        ...     (sweep / job).mkdir()
        >>> _ = (sweep / "1" / "job_config.json").write_text("{}")
        >>> [p.name for p in job_directories(sweep)]
        ['1']
    """
    found, not_started = _jobs_under(Path(directory))
    if not_started:
        raise not_started[0]
    return found


def _jobs_under(directory: Path) -> tuple[list[Path], list[UnfinishedRunError]]:
    """The run directories under ``directory`` (:func:`job_directories`), and a refusal for each
    job a sweep's record lists that never started."""
    found = {path.parent for name in JOB_FILES for path in directory.rglob(name) if path.is_file()}
    not_started = []
    for sweep in sweeps_under(directory):
        jobs = listed_jobs(sweep) or []
        for job in jobs:
            if job.path not in found:
                state = "holds none of a job's files" if job.path.is_dir() else "is missing"
                not_started.append(UnfinishedRunError(job.path, (
                    f"job {job.num} of the {len(jobs)} its sweep lists ({' '.join(job.swept)}) never started: its "
                    f"directory {state}"), f"run the sweep's command again with hydra.sweep.dir={sweep} to run it "
                                           "(its finished jobs are left as they are)"))
    return sorted(found), not_started


def finished_runs(*directories: str | os.PathLike, finished_only: bool = False) -> list[FinishedRun]:
    """Every run directory under ``directories`` (:func:`job_directories`), read by
    :func:`read_finished_run`, directory by directory in path order: a job that is not finished
    (killed, live, failed, with files that disagree, or, listed by its sweep's record, never
    started) refuses the whole set, naming it, rather than giving results with a run missing
    or cut short, unless ``finished_only``. Jobs are found by the files a job writes
    (:data:`JOB_FILES`), so that a job killed before its first row is named, not skipped, and by
    the sweep's own job list (:mod:`sde_torchrl.jobs.sweeps`), so that a job that never started
    is named too.

    Args:
        directories: sweep or run directories (shards of one sweep may be given together).
        finished_only: leave out, with a warning naming each, the jobs that are not finished,
            instead of refusing the set (an explicit choice: the results then miss those jobs).

    Raises:
        UnfinishedRunError: a job under ``directories`` is not finished, or never started.
        DamagedFileError: one holds a damaged ``summary.json`` or ``job_config.json``, or a
            sweep's ``multirun.yaml`` cannot be read.

    Examples:
        >>> import tempfile
        >>> finished_runs(tempfile.mkdtemp(), tempfile.mkdtemp())
        []
    """
    found = []
    for directory in map(Path, directories):
        run_dirs, not_started = _jobs_under(directory)
        for error in not_started:
            if not finished_only:
                raise error
            log.warning("left out (finished_only): %s", error)
        for run_dir in run_dirs:
            try:
                found.append(read_finished_run(run_dir))
            except DamagedFileError as error:  # UnfinishedRunError too
                if not finished_only:
                    raise
                log.warning("left out (finished_only): %s", error)
    return found


def _parse_rows(data: bytes, rewrite: bool) -> tuple[list[MetricRow], str | None]:
    """``metrics.csv``'s rows, and what is wrong with its bytes: not as the job writes them
    (with ``rewrite``, its rows written again and compared; without, only its header is checked)."""
    try:
        text = data.decode()
        header = next(csv.reader(io.StringIO(text, newline="")), [])
        rows = read_metrics_text(text)
    except (ValueError, KeyError, TypeError, csv.Error) as error:  # MetricsFormatError is a ValueError
        return [], f"metrics.csv cannot be read ({type(error).__name__}: {error})"
    if tuple(header) != METRIC_FIELDS[:len(header)] or len(header) < len(REQUIRED_FIELDS):
        return rows, f"metrics.csv's header is not {','.join(METRIC_FIELDS)}"
    if not rewrite:
        return rows, None
    expected = csv_lines(rows, fields=tuple(header))
    lines = data.splitlines(keepends=True)
    for i, (have, want) in enumerate(zip(lines, expected, strict=False)):
        if have != want:
            return rows, f"metrics.csv's line {i + 1} is not as the job writes it ({have[:80]!r})"
    if len(lines) != len(expected):
        return rows, f"metrics.csv has {len(lines)} lines where its rows make {len(expected)}"
    return rows, None


def _digest_problem(summary: dict[str, Any], data: bytes, rows: list[MetricRow]) -> str | None:
    """The summary's own digest, and the one it recorded of ``metrics.csv``, if any."""
    if "sha256" in summary and summary["sha256"] != summary_digest(summary):
        return "summary.json does not match its digest (sha256): an entry was changed"
    if "metrics_sha256" in summary and summary["metrics_sha256"] != hashlib.sha256(data).hexdigest():
        return "metrics.csv does not match the digest summary.json recorded (metrics_sha256): it was changed"
    return None


def _rows_problem(summary: dict[str, Any], data: bytes, rows: list[MetricRow]) -> str | None:
    """One row per run for each update, in the job's order, with the episodes of that update."""
    runs, updates, first = summary.get("runs"), summary.get("updates_done"), summary.get("first_run", 0)
    if not isinstance(runs, int) or not isinstance(updates, int) or not isinstance(first, int):
        return "its summary.json names no runs and updates_done"
    if len(rows) != runs * updates or (rows and rows[-1].update != updates - 1):
        last = rows[-1].update if rows else "none"
        return (f"metrics.csv has {len(rows)} rows up to update {last}, summary.json says {runs} runs × {updates} "
                "updates")
    episodes = _episodes(summary)
    for i, row in enumerate(rows):
        run, update = first + i % runs, i // runs
        if (row.run, row.update) != (run, update):
            return f"metrics.csv's row {i + 1} is run {row.run}, update {row.update}, not run {run}, update {update}"
        if episodes is not None and row.episodes != episodes(update):
            return f"metrics.csv's row {i + 1} (run {run}, update {update}) counts {row.episodes} episodes, " \
                   f"not {episodes(update)}"
    return None


def _summary_problem(summary: dict[str, Any], data: bytes, rows: list[MetricRow]) -> str | None:
    """The summary's per-run numbers against the rows they were computed from."""
    runs, updates = summary["runs"], summary["updates_done"]
    if not rows:
        return "metrics.csv has no rows"
    first, last = rows[:runs], rows[-runs:]
    derived = {"initial_return": [row.return_mean for row in first], "final_return": [row.return_mean for row in last],
               "final_eval_return": [row.eval_return for row in last]}
    settings, episodes = summary.get("settings") or {}, _episodes(summary)
    if episodes is not None and "episode_length" in settings:
        derived["env_steps"] = episodes(updates - 1) * settings["episode_length"] * runs
    if episodes is not None and settings.get("r_lim") is not None:
        derived["episodes_to_threshold"] = [
            next((episodes(row.update) for row in rows[r::runs] if row.return_mean > settings["r_lim"]), None)
            for r in range(runs)]
    for key, value in derived.items():
        if key in summary and summary[key] != value:
            return f"summary.json's {key} is not what metrics.csv's rows give"
    return None


def _kept_checkpoint_problem(checkpoint: Path, summary: dict[str, Any], data: bytes) -> str | None:
    """What makes a kept checkpoint not the finished job's (:func:`_checkpoint_problem`), a
    damaged one included; ``None`` without one."""
    if not checkpoint.exists():
        return None
    try:
        return _checkpoint_problem(checkpoint, summary, data)
    except DamagedFileError as error:
        return f"it is damaged ({error.problem})"
    except CheckpointMismatchError:
        return "it has a checkpoint format this version does not read"


def _checkpoint_problem(checkpoint: Path, summary: dict[str, Any], data: bytes) -> str | None:
    """A checkpoint against the summary and the rows: the finished job's, of its config."""
    saved = load_checkpoint(checkpoint)
    loop, updates = saved.get("loop"), summary["updates_done"]
    if not isinstance(loop, dict):
        return "it holds no training loop record"
    if loop.get("update") != updates or not loop.get("finished"):
        return (f"it is at update {loop.get('update')}{'' if loop.get('finished') else ' (unfinished)'}, "
                f"summary.json says {updates}")
    if saved.get("config") is not None and "config" in summary:
        diff = config_differences(saved["config"], result_config(summary["config"]))
        if diff:
            return f"it was written by another config than summary.json's ({'; '.join(diff[:3])})"
    episodes = _episodes(summary)
    if episodes is None:
        return None
    expected = csv_lines(recorded_rows(loop, summary.get("first_run", 0), episodes))
    lines = data.splitlines(keepends=True)
    problem = _first_difference(lines, expected, recorded_rows(loop, summary.get("first_run", 0), episodes))
    if problem is None and len(lines) != len(expected):
        problem = f"metrics.csv holds {len(lines) - 1} rows, it recorded {len(expected) - 1}"
    return None if problem is None else f"metrics.csv disagrees with it: {problem}"


def _checkpoint_is_finished(checkpoint: Path) -> bool:
    """Whether ``checkpoint`` is an intact checkpoint of a finished job (``False`` without one)."""
    try:
        return bool(load_checkpoint(checkpoint)["loop"].get("finished"))
    except (OSError, DamagedFileError, CheckpointMismatchError, KeyError, AttributeError):
        return False


def _episodes(summary: dict[str, Any]) -> Any:
    """Update → episodes each run has collected by its end, from the summary's settings (``None``
    without them)."""
    settings = summary.get("settings") or {}
    per_update = settings.get("episodes_per_update")
    if not isinstance(per_update, int):
        return None
    queue = settings.get("episode_queue") or 0
    return lambda update: episodes_after(update, per_update, queue)


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


def _first_difference(lines: list[bytes], expected: list[bytes], rows: Sequence[MetricRow]) -> str | None:
    """What is wrong with the first line of ``lines`` that differs from ``expected``, if any."""
    for i, (have, want) in enumerate(zip(lines, expected, strict=False)):
        if have == want:
            continue
        if i == 0:
            return f"its header is not {','.join(METRIC_FIELDS)}"
        row = f"row {i} (run {rows[i - 1].run}, update {rows[i - 1].update})"
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
        >>> import torch
        >>> path = Path(tempfile.mkdtemp()) / "metrics.csv"
        >>> with MetricsFile(path, csv_lines([])) as metrics:
        ...     metrics.write(metric_rows(update_statistics(0, 0, 5, {
        ...         "return_mean": torch.tensor([-1.0]), "grad_norm": torch.tensor([2.0]),
        ...         "exploration": torch.tensor([[0.5], [0.5], [1.0]])}, None)))
        >>> path.read_text().splitlines()[1]
        '0,0,5,-1.0,,2.0,0.5,0.5,1.0'
    """

    def __init__(self, path: Path, kept: list[bytes]) -> None:
        self.path, self.kept = path, kept
        self._file: Any = None
        self._writer: Any = None

    def __enter__(self) -> MetricsFile:
        if not self.path.exists() or self.path.stat().st_size != sum(map(len, self.kept)):
            write_atomically(self.path, lambda f: f.writelines(self.kept))
        self._file = open(self.path, "a", newline="")
        self._writer = csv.writer(self._file)  # rows are MetricRows, in METRIC_FIELDS order; None is an empty cell
        return self

    def write(self, rows: list[MetricRow]) -> None:
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
        """Closes the file; a failure to close (rows still buffered after a full disk) never
        replaces the error in flight, and is itself a :class:`DiskFullError` naming the file."""
        try:
            self._file.close()
        except OSError as error:
            if exc[0] is None:
                raise as_disk_full(self.path, error) from error
            # the error in flight (a DiskFullError naming this file) is re-raised as it is
