"""How the command ends: the lines it prints once Hydra returns (finished jobs, the comparison of a
multirun's methods, each failure, each job a signal stopped, the override that resumes) and the
exit code, from the jobs' reports (:mod:`sde_torchrl.cli.reports`).

Part of :mod:`sde_torchrl.cli`; the exit codes and one-line errors are :mod:`sde_torchrl.cli.errors`'.
"""

from __future__ import annotations

import shlex
import signal
import sys
from typing import Any, TextIO

from sde_torchrl.cli.errors import EXIT_FAILED
from sde_torchrl.cli.reports import JobFailure, JobReport
from sde_torchrl.trainers.interrupt import TrainingInterrupted


def resume_override(directory: str, multirun: bool) -> str:
    """The override that names the directory a job resumes in, quoted for the shell (a path with
    spaces pastes back as one argument): the sweep's directory for a job of a multirun.

    Examples:
        >>> resume_override("runs/a b", multirun=False)
        "'hydra.run.dir=runs/a b'"
        >>> resume_override("runs/sweep", multirun=True)
        'hydra.sweep.dir=runs/sweep'
    """
    return shlex.quote(f"hydra.{'sweep' if multirun else 'run'}.dir={directory}")


def interrupted_entry(stop: TrainingInterrupted, resume: str) -> dict[str, Any]:
    """What a job a signal stopped in a sweep's worker reports (:func:`interrupted_line`).

    Examples:
        >>> from pathlib import Path
        >>> interrupted_entry(TrainingInterrupted(3, Path("runs/0"), signal.SIGTERM), "hydra.sweep.dir=runs")["code"]
        143
    """
    return {"signal": stop.signal_name, "code": stop.exit_code, "updates_done": stop.updates_done,
            "out_dir": str(stop.out_dir), "resume": resume}


def interrupted_line(entry: dict[str, Any]) -> str:
    """The line for a job stopped by a signal, with the override that resumes it.

    Examples:
        >>> interrupted_line({"signal": "SIGTERM", "updates_done": 3, "out_dir": "runs/0",
        ...                   "resume": "hydra.sweep.dir=runs"})  # doctest: +ELLIPSIS
        'interrupted by SIGTERM: checkpoint after update 3 in runs/0; run the same command with hydra.sweep.dir=...'
    """
    return (f"interrupted by {entry['signal']}: checkpoint after update {entry['updates_done']} in "
            f"{shlex.quote(entry['out_dir'])}; run the same command with {entry['resume']} to resume")


def report(reports: list[JobReport], stopped: int | None, resume: str | None, *, out: TextIO | None = None,
           err: TextIO | None = None) -> int:
    """Prints the end of a (multi)run from its jobs' ``reports`` and returns the exit code:
    finished jobs' lines and, for several finished jobs of a multirun, one comparison line per
    method (stdout); then a stopped sweep's lines (:func:`report_stopped`, for ``stopped``, the
    signal the command's process kept, or a job a signal stopped), or each failure's line (stderr).

    Examples:
        >>> import io
        >>> failed = JobReport(failure=JobFailure("runs/0", ["lr=1e38"], "NonFiniteError: ...", 1, True))
        >>> err = io.StringIO()
        >>> report([failed], None, None, out=io.StringIO(), err=err)
        1
        >>> print(err.getvalue(), end="")
        error: NonFiniteError: ... (job lr=1e38, see runs/0/error.txt)
    """
    out, err = out or sys.stdout, err or sys.stderr
    failures = [job.failure for job in reports if job.failure is not None]
    interrupted = [job.interrupted for job in reports if job.interrupted is not None]
    results = [job.result for job in reports if job.result is not None]
    for job in reports:
        if job.finished is not None:
            out.write(f"{job.finished}\n")
    if len(results) > 1:
        from sde_torchrl.trainers.comparison import comparison_lines

        for line in comparison_lines(results):
            out.write(f"{line}\n")
    if interrupted or stopped is not None:
        return report_stopped(stopped, failures, interrupted, resume, err=err)
    if not failures:
        return 0
    for failure in failures:
        see = f", see {failure.out_dir}/error.txt" if failure.error_file else ""
        where = f" (job {' '.join(failure.overrides)}{see})" if failure.multirun else ""
        err.write(f"error: {failure.message}{where}\n")
    codes = {failure.code for failure in failures}
    return codes.pop() if len(codes) == 1 else EXIT_FAILED


def report_stopped(signum: int | None, failures: list[JobFailure], interrupted: list[dict[str, Any]],
                   resume: str | None, *, err: TextIO | None = None) -> int:
    """Reports a sweep stopped by a signal: each failure, each stopped job's line (its checkpoint and
    the resume override), and returns the signal's exit code (143 for SIGTERM). ``resume``: the
    override that runs the sweep's jobs not started, if known.

    Examples:
        >>> import io
        >>> err = io.StringIO()
        >>> report_stopped(signal.SIGTERM, [], [], "hydra.sweep.dir=runs", err=err)
        143
        >>> print(err.getvalue(), end="")  # doctest: +ELLIPSIS
        interrupted by SIGTERM while no job was training: ...; run the same command with hydra.sweep.dir=runs ...
    """
    err = err or sys.stderr
    for failure in failures:
        err.write(f"error: {failure.message} (job {' '.join(failure.overrides)})\n")
    for entry in interrupted:
        err.write(f"{interrupted_line(entry)}\n")
    name = signal.Signals(signum).name if signum is not None else interrupted[0]["signal"]
    if not interrupted:
        how = f"run the same command with {resume}" if resume else "run the same command"
        err.write(f"interrupted by {name} while no job was training: the jobs not started did not start; "
                  f"{how} to run them\n")
    return 128 + (signum if signum is not None else interrupted[0]["code"] - 128)
