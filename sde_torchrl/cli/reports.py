"""What each job of one command reports to the command's process, and how it gets there.

A job (:class:`~sde_torchrl.cli.job.Job`) may run in the command's process (a single run,
Hydra's basic launcher) or in another one (joblib's workers, submitit's tasks, Ray's workers), so
its report is a small JSON file: :class:`Reports` names where it goes. The
command (:func:`~sde_torchrl.cli.main.cli`) makes a fresh directory for each invocation; a single
run's job writes there; a sweep's jobs write under the sweep's own directory
(``<hydra.sweep.dir>/.job_reports/<that directory's name>/``), which every launcher's jobs share
with the command as they share their run directories, even on other machines. The sweep's
directory is recorded at multirun start by :class:`~sde_torchrl.cli.callbacks.SweepStart` (a Hydra
callback, in the command's process), found through :data:`REPORTS_ENV`. The command reads every
report once Hydra returns, then removes them.
"""

from __future__ import annotations

import json
import secrets
import shutil
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from sde_torchrl.utils.files import write_atomically

#: Environment variable naming the invocation's reports directory (set by the command for its callback).
REPORTS_ENV = "SDE_TORCHRL_REPORTS"
#: The folder of a sweep's directory that holds its jobs' reports while the command runs.
SWEEP_REPORTS = ".job_reports"
#: The file, in the invocation's directory, that records the sweep's directory.
SWEEP_RECORD = "sweep.json"


@dataclass
class JobFailure:
    """A job that raised: where, with which overrides, the one-line message and its exit code."""

    out_dir: str
    overrides: list[str]
    message: str
    code: int
    multirun: bool
    error_file: bool = True


@dataclass
class JobReport:
    """What one job tells the command: its failure, the line of a finished job it found, its
    interruption by a signal (in a sweep's worker), its result for the comparison lines.

    Examples:
        >>> report = JobReport(finished="runs/0 holds a finished job")
        >>> JobReport.from_dict(json.loads(json.dumps(report.to_dict()))) == report
        True
        >>> JobReport().empty
        True
    """

    failure: JobFailure | None = None
    finished: str | None = None
    interrupted: dict[str, Any] | None = None
    result: dict[str, Any] | None = None

    @property
    def empty(self) -> bool:
        return self == JobReport()

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)

    @classmethod
    def from_dict(cls, fields: dict[str, Any]) -> JobReport:
        failure = fields.get("failure")
        return cls(failure=JobFailure(**failure) if failure else None, finished=fields.get("finished"),
                   interrupted=fields.get("interrupted"), result=fields.get("result"))


@dataclass(frozen=True)
class Sweep:
    """A multirun's directory as composed (``hydra.sweep.dir``) and the directory it is relative to."""

    directory: str
    cwd: str

    @property
    def path(self) -> Path:
        return Path(self.cwd, self.directory)


@dataclass(frozen=True)
class Reports:
    """The reports of one invocation of the command: ``directory`` is its own (:meth:`fresh`, made
    at the first report, so that a command killed before leaves nothing); its name tells this
    invocation's reports apart in a sweep's directory.

    Examples:
        >>> reports = Reports.fresh()
        >>> reports.post(JobReport(finished="runs/a holds a finished job"), "run")
        >>> reports.collect()
        [JobReport(failure=None, finished='runs/a holds a finished job', interrupted=None, result=None)]
        >>> reports.remove()
        >>> reports.directory.exists()
        False
    """

    directory: Path

    @classmethod
    def fresh(cls) -> Reports:
        """A new invocation's reports, in the temporary directory (``sde-train-<random>``)."""
        return cls(Path(tempfile.gettempdir(), f"sde-train-{secrets.token_hex(8)}"))

    def sweep_reports(self, sweep: Sweep) -> Path:
        """Where the jobs of ``sweep`` write their reports."""
        return sweep.path / SWEEP_REPORTS / self.directory.name

    def post(self, report: JobReport, name: str, sweep: Sweep | None = None) -> None:
        """Writes a job's ``report`` as ``<name>.json``: into the sweep's reports for a job of
        ``sweep``, else into :attr:`directory`. A job that runs again (requeued) replaces its report."""
        if report.empty:
            return
        target = self.directory if sweep is None else self.sweep_reports(sweep)
        target.mkdir(mode=0o700, parents=True, exist_ok=True)
        write_atomically(target / f"{name}.json", lambda f: f.write(json.dumps(report.to_dict()).encode()))

    def note_sweep(self, sweep: Sweep) -> None:
        """Records the sweep's directory (at multirun start, in the command's process)."""
        self.directory.mkdir(mode=0o700, parents=True, exist_ok=True)
        write_atomically(self.directory / SWEEP_RECORD, lambda f: f.write(json.dumps(asdict(sweep)).encode()))

    def sweep(self) -> Sweep | None:
        """The sweep this invocation ran (:meth:`note_sweep`), if it ran one."""
        record = self.directory / SWEEP_RECORD
        return Sweep(**json.loads(record.read_text())) if record.is_file() else None

    def collect(self) -> list[JobReport]:
        """Every report posted, in job order (a sweep's jobs by their number)."""
        sweep = self.sweep()
        folders = [self.directory] + ([self.sweep_reports(sweep)] if sweep is not None else [])
        paths = [path for folder in folders for path in sorted(folder.glob("*.json")) if path.name != SWEEP_RECORD]
        return [JobReport.from_dict(json.loads(path.read_text())) for path in paths]

    def remove(self) -> None:
        """Removes the reports: this invocation's directory, and its folder in the sweep's directory."""
        sweep = self.sweep()
        if sweep is not None:
            shutil.rmtree(self.sweep_reports(sweep), ignore_errors=True)
            try:
                (sweep.path / SWEEP_REPORTS).rmdir()  # unless another command's reports are there
            except OSError:
                pass
        shutil.rmtree(self.directory, ignore_errors=True)
