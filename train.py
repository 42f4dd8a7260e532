"""Train policies with state-dependent exploration: ``python train.py +experiment=minimize``.

Hydra composes ``conf/config.yaml`` with the groups ``env``, ``actor``, ``explorer``,
``estimator``, ``logger`` and an optional ``+experiment``; each job writes ``metrics.csv``,
``summary.json`` and ``checkpoint.pt`` into its run directory, and resumes from the checkpoint
when started again in the same directory (``hydra.run.dir=...``).

Errors are reported in one line on stderr, and the exit code says which kind:

- 1: the job failed (a non-finite value, any exception);
- 2: a config error (``error: <key>=<value>: <what is allowed>``), or a checkpoint written
  under another config;
- 3: the run directory is in use by another live process (``<dir> is in use by another process
  (pid N)``); nothing in it was changed;
- 4: a file of the run directory is damaged (``checkpoint.pt``, ``metrics.csv``,
  ``summary.json``): the line names the file, what is wrong and the least destructive remedy;
  nothing was resumed from it;
- 0 also for a run directory that holds a finished job of the same config: a finished job is
  final, so the job says so in one line (``<dir> holds a finished job (...)``) and changes no
  file there (not ``.hydra/``, not ``train.log``); to train it again, remove the directory;
- 130: interrupted by Ctrl-C, with a checkpoint; 143 (SIGTERM, how schedulers preempt) and 140
  (SIGUSR2, submitit's signal before a time limit, outside submitit) likewise: the job finishes
  its update, checkpoints, names the signal and the update, and the same command resumes it.
  Under submitit (``hydra/launcher=slurm``) SIGUSR2 checkpoints and then lets submitit requeue.

A job holds its run directory (:mod:`sde_torchrl.jobs.lock`) from before anything is written there
(Hydra's ``.hydra/`` files included, which is why this script writes them) to its end. A failed
job also leaves ``error.txt`` (message and traceback) in its run directory; in a multirun the
other jobs go on, and the exit code is the failures' common code (1 if they differ).
``SDE_TORCHRL_DEBUG=1`` (or ``HYDRA_FULL_ERROR=1``) shows full tracebacks instead.
"""

from __future__ import annotations

import errno
import logging
import os
import shlex
import signal
import sys
import traceback
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.core.utils import JobStatus
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

# Light imports only (no torch): a job locks its run directory before importing torch.
from sde_torchrl.config.errors import describe_error
from sde_torchrl.config.help import register_help_resolver
from sde_torchrl.config.registration import register_resolvers
from sde_torchrl.config.schemas.train import TrainConf, validate
from sde_torchrl.jobs.lock import RunDirectoryInUse, hold_run_directory
from sde_torchrl.trainers.interrupt import TrainingInterrupted, stop_requested
from sde_torchrl.trainers.progress import progress_wanted
from sde_torchrl.trainers.sweep_stop import handle_in_parent, in_worker, job_started
from sde_torchrl.utils.files import DamagedFileError, FileWriteError, write_atomically

log = logging.getLogger("train")
register_resolvers()
register_help_resolver()

EXIT_FAILED, EXIT_CONFIG, EXIT_IN_USE, EXIT_DAMAGED, EXIT_INTERRUPTED = 1, 2, 3, 4, 130


@dataclass
class JobFailure:
    """A job that raised: where, with which overrides, the one-line message and its exit code."""

    out_dir: str
    overrides: list[str]
    message: str
    code: int
    multirun: bool
    error_file: bool = True


#: Failures of this process's jobs, reported once the (multi)run is over.
FAILURES: list[JobFailure] = []
#: The override that resumes this process's job (its run directory, or its sweep's), shell-quoted.
RESUME: dict[str, str] = {}
#: This process's jobs found finished in their directories: one line each, reported at the end
#: (not logged: the log file is in the run directory, which is left as it was).
FINISHED: list[str] = []
#: What each finished job of a multirun reports for the lines comparing its methods.
RESULTS: list[dict[str, Any]] = []
#: Jobs of this process stopped by a signal with a checkpoint (in a sweep's worker: reported to the parent).
INTERRUPTED: list[dict[str, Any]] = []
#: Full tracebacks wanted: read once at start-up (``cli`` then sets ``HYDRA_FULL_ERROR`` itself).
DEBUG = False


def debug_mode() -> bool:
    """Full tracebacks wanted (``SDE_TORCHRL_DEBUG=1`` or ``HYDRA_FULL_ERROR=1``)?"""
    return any(os.environ.get(name, "") not in ("", "0") for name in ("SDE_TORCHRL_DEBUG", "HYDRA_FULL_ERROR"))


def one_line(error: BaseException) -> tuple[str, int]:
    """The error as one line, and its exit code."""
    described = describe_error(error)
    if described is not None:
        return described, EXIT_CONFIG
    if _is_foreign_checkpoint(error):
        return str(error), EXIT_CONFIG
    unusable = unusable_run_directory(error)
    if unusable is not None:
        return unusable, EXIT_CONFIG
    if isinstance(error, FileWriteError):  # a full device, the file-size limit: the file and the cause
        return str(error), EXIT_FAILED
    if isinstance(error, (RunDirectoryInUse, DamagedFileError)):
        return str(error), EXIT_IN_USE if isinstance(error, RunDirectoryInUse) else EXIT_DAMAGED
    text = " ".join(str(error).split()) or type(error).__name__
    return (text if type(error).__name__ in text else f"{type(error).__name__}: {text}"), EXIT_FAILED


def unusable_run_directory(error: BaseException) -> str | None:
    """The one line for a run directory that cannot be made (Hydra makes it before :func:`main`):
    a file of that name, a symbolic link to nothing (dangling, or a loop), a path below a file,
    or a name longer than its file system allows (``ENAMETOOLONG``).

    Examples:
        >>> import tempfile
        >>> link = Path(tempfile.mkdtemp(), "run")
        >>> link.symlink_to(link.with_name("gone"))
        >>> unusable_run_directory(FileExistsError(17, "File exists", str(link)))  # doctest: +ELLIPSIS
        '.../run is a symbolic link to nothing (dangling, or a loop): give the job another hydra.run.dir ...'
        >>> print(unusable_run_directory(OSError(36, "File name too long", "/tmp/" + "x" * 300)))  # doctest: +ELLIPSIS
        /tmp/xxx...x: a name of 300 bytes, over its file system's limit of 255 bytes per name: give the job ...
    """
    name = getattr(error, "filename", None)
    another = "give the job another hydra.run.dir (hydra.sweep.dir for a sweep)"
    if isinstance(error, OSError) and error.errno == errno.ENAMETOOLONG and name:
        return f"{name}: {_too_long(Path(name))}: {another}"
    if not isinstance(error, (FileExistsError, NotADirectoryError)) or not name:
        return None
    path = Path(name)
    if path.is_symlink() and not path.exists():
        return f"{path} is a symbolic link to nothing (dangling, or a loop): {another}, or remove the link"
    if path.is_file():
        return f"{path} is a file, not a run directory: {another}"
    above = next((parent for parent in path.parents if parent.is_file()), None)
    if above is not None:
        return f"{path} is below a file ({above}), not in a directory: {another}"
    return None


def _too_long(path: Path) -> str:
    """What makes ``path`` too long, in words: its longest name beyond the file system's limit
    per name (``NAME_MAX``, 255 bytes on most), or else the whole path beyond ``PATH_MAX``."""
    existing = next((parent for parent in path.parents if os.path.isdir(parent)), Path("/"))  # False if too long
    limits = {}
    for limit, default in (("PC_NAME_MAX", 255), ("PC_PATH_MAX", 4096)):
        try:
            limits[limit] = os.pathconf(existing, limit)
        except (OSError, ValueError, AttributeError):  # not known here: the usual value
            limits[limit] = default
    longest = max((len(os.fsencode(part)) for part in path.parts), default=0)
    if longest > limits["PC_NAME_MAX"]:
        return f"a name of {longest} bytes, over its file system's limit of {limits['PC_NAME_MAX']} bytes per name"
    return f"a path of {len(os.fsencode(str(path)))} bytes, over the limit of {limits['PC_PATH_MAX']} bytes per path"


def _is_foreign_checkpoint(error: BaseException) -> bool:
    """The run directory holds another config's checkpoint (a sweep relaunched with other values)."""
    checkpoint = sys.modules.get("sde_torchrl.jobs.checkpoint")  # not imported: not its error
    return checkpoint is not None and isinstance(error, checkpoint.CheckpointMismatchError)


def save_hydra_config(cfg: DictConfig, out_dir: str) -> None:
    """Writes what Hydra writes into ``<run dir>/.hydra`` (``config.yaml``, ``hydra.yaml``,
    ``overrides.yaml``): ``conf/config.yaml`` sets ``hydra.output_subdir`` to null so that they
    are written here, by the process that holds the run directory."""
    hydra_node = HydraConfig.instance().cfg
    target = Path(out_dir, ".hydra")
    target.mkdir(exist_ok=True)
    for name, node in (("config.yaml", cfg), ("hydra.yaml", hydra_node),
                       ("overrides.yaml", hydra_node.hydra.overrides.task)):
        write_atomically(target / name, lambda f, node=node: f.write(OmegaConf.to_yaml(node).encode()))


def report_finished(conf: TrainConf, out_dir: str) -> bool:
    """Whether ``out_dir`` holds this config's finished job, checked as the job checks it
    (:meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`, here before anything is built);
    if so, its line is recorded for the end and nothing is changed.

    Raises:
        CheckpointMismatchError: it holds a job of another config.
        DamagedFileError: it holds no checkpoint and its files disagree, or a damaged checkpoint.
    """
    from sde_torchrl.jobs.checkpoint import result_config  # torch: the run directory is ours
    from sde_torchrl.jobs.run_dir import RunDirectory
    from sde_torchrl.trainers.trainer import finished_line

    done = RunDirectory(out_dir, result_config(conf.resolved())).check_job()
    if done is None:
        return False
    FINISHED.append(finished_line(done))
    return True


@contextmanager
def log_file_suspended(out_dir: str) -> Iterator[None]:
    """Hydra's log file handlers that write into ``out_dir`` (``train.log``) detached for the
    ``with`` block: what the job logs goes to the console only."""
    root = logging.getLogger()
    inside = [handler for handler in root.handlers if isinstance(handler, logging.FileHandler)
              and Path(handler.baseFilename).resolve().parent == Path(out_dir).resolve()]
    for handler in inside:
        root.removeHandler(handler)
    try:
        yield
    finally:
        for handler in inside:
            root.addHandler(handler)


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> dict[str, Any] | None:
    """Trains (or resumes) one job; a failure is recorded in ``error.txt`` and reported once
    the run or sweep is over, so that one failed job does not stop a sweep.

    Returns:
        What the sweep's parent process reports for the job (:func:`job_report`): a launcher
        that runs the job in another process (joblib, submitit, Ray) hands it back to the parent.
    """
    failures, finished, interrupted, results = len(FAILURES), len(FINISHED), len(INTERRUPTED), len(RESULTS)
    try:
        job(cfg)
    except TrainingInterrupted as stop:
        if not in_worker():  # this process reports it (train.py's cli)
            raise
        INTERRUPTED.append(interrupted_job(stop))  # a sweep's worker: reported to the parent
    return job_report(FAILURES[failures:], FINISHED[finished:], INTERRUPTED[interrupted:], RESULTS[results:])


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


def job_report(failures: list[JobFailure], finished: list[str], interrupted: list[dict[str, Any]] | None = None,
               results: list[dict[str, Any]] | None = None) -> dict[str, Any] | None:
    """A job's failure, finished line and interruption as plain data, sent between processes.

    Examples:
        >>> job_report([JobFailure("runs/0", ["lr=1e38"], "NonFiniteError: ...", 1, True)], [])["failures"][0]["code"]
        1
    """
    if not failures and not finished and not interrupted and not results:
        return None
    return {"failures": [asdict(failure) for failure in failures], "finished": list(finished),
            "interrupted": list(interrupted or []), "results": list(results or [])}


def interrupted_job(stop: TrainingInterrupted) -> dict[str, Any]:
    """What the sweep's parent reports for a job a signal stopped in a worker (:func:`interrupted_line`).

    Examples:
        >>> import signal
        >>> interrupted_job(TrainingInterrupted(3, Path("runs/0"), signal.SIGTERM))["updates_done"]
        3
    """
    return {"signal": stop.signal_name, "code": stop.exit_code, "updates_done": stop.updates_done,
            "out_dir": str(stop.out_dir), "resume": RESUME.get("override") or resume_override(str(stop.out_dir), False)}


def interrupted_line(entry: dict[str, Any]) -> str:
    """The line for a job stopped by a signal, with the override that resumes it.

    Examples:
        >>> interrupted_line({"signal": "SIGTERM", "updates_done": 3, "out_dir": "runs/0",
        ...                   "resume": "hydra.sweep.dir=runs"})  # doctest: +ELLIPSIS
        'interrupted by SIGTERM: checkpoint after update 3 in runs/0; run the same command with hydra.sweep.dir=...'
    """
    return (f"interrupted by {entry['signal']}: checkpoint after update {entry['updates_done']} in "
            f"{shlex.quote(entry['out_dir'])}; run the same command with {entry['resume']} to resume")


def gather_job_reports(sweep_returns: list[Any]) -> None:
    """Adds to :data:`FAILURES` and :data:`FINISHED` what the sweep's jobs reported
    (:func:`job_report`, their return values) and this process does not hold yet: the jobs a
    launcher ran in other processes."""
    seen = {(failure.out_dir, failure.message) for failure in FAILURES}
    for batch in sweep_returns:
        for job_return in batch:
            report = job_return._return_value if job_return.status == JobStatus.COMPLETED else None
            if not isinstance(report, dict):
                continue
            for failure in map(lambda fields: JobFailure(**fields), report.get("failures", [])):
                if (failure.out_dir, failure.message) not in seen:
                    seen.add((failure.out_dir, failure.message))
                    FAILURES.append(failure)
            FINISHED.extend(line for line in report.get("finished", []) if line not in FINISHED)
            INTERRUPTED.extend(entry for entry in report.get("interrupted", []) if entry not in INTERRUPTED)
            RESULTS.extend(entry for entry in report.get("results", []) if entry not in RESULTS)


@contextmanager
def sweep_returns_kept(into: list[Any]) -> Iterator[None]:
    """Keeps what a multirun's sweeper returns (each job's ``JobReturn``), which Hydra drops:
    the one way a job run by another process (joblib, submitit, Ray) reports back."""
    from hydra._internal.hydra import Hydra

    multirun = Hydra.multirun

    def keeping(self: Any, *args: Any, **kwargs: Any) -> Any:
        returned = multirun(self, *args, **kwargs)
        into.extend(returned or [])
        if HydraConfig.initialized():  # the sweep's directory, for the resume line of a stopped sweep
            RESUME.setdefault("sweep", resume_override(HydraConfig.get().sweep.dir, multirun=True))
        return returned

    Hydra.multirun = keeping
    try:
        yield
    finally:
        Hydra.multirun = multirun


def job(cfg: DictConfig) -> None:
    """One job (:func:`main`): its failure goes to :data:`FAILURES`, its finished line to :data:`FINISHED`."""
    hydra_cfg = HydraConfig.get()
    out_dir = hydra_cfg.runtime.output_dir
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    overrides = list(hydra_cfg.overrides.task)
    RESUME["override"] = resume_override(hydra_cfg.sweep.dir if multirun else out_dir, multirun)
    job_started()  # in a joblib worker: a stop signal checkpoints the job and starts no other
    if stop_requested() is not None:  # the sweep was stopped before this job: it does not start
        return
    with ExitStack() as stack:
        try:
            stack.enter_context(hold_run_directory(out_dir))
        except Exception as error:  # noqa: BLE001 - in use (or not writable): nothing is written there
            message, code = one_line(error)
            FAILURES.append(JobFailure(out_dir, overrides, message, code, multirun, error_file=False))
            return
        # A directory with a summary holds a finished job (or, rarely, one about to resume from an
        # older checkpoint): leave its files as they are, train.log included, unless it trains.
        finished = Path(out_dir, "summary.json").exists()
        if finished:
            stack.enter_context(log_file_suspended(out_dir))
        elif not Path(out_dir, "checkpoint.pt").exists():  # a resumed job keeps its first session's
            save_hydra_config(cfg, out_dir)
        try:
            conf = validate(cfg)  # the job's config, once: a bad value fails here, before importing torch
            if finished and report_finished(conf, out_dir):
                return
            from sde_torchrl.config.build import run_job  # torch: imported once the run directory is ours

            summary = run_job(conf, out_dir, dict(hydra_cfg.runtime.choices),
                              progress=progress_wanted(conf.progress, multirun))
        except Exception as error:  # noqa: BLE001 - every failure is recorded, then reported
            message, code = one_line(error)
            if finished or _is_foreign_checkpoint(error):  # a finished job's, or another's: leave it as it is
                FAILURES.append(JobFailure(out_dir, overrides, message, code, multirun, error_file=False))
                return
            try:
                Path(out_dir, "error.txt").write_text(f"{message}\n\n{traceback.format_exc()}")
            except OSError:  # a full disk: the message still reaches stderr
                Path(out_dir, "error.txt").unlink(missing_ok=True)
                FAILURES.append(JobFailure(out_dir, overrides, message, code, multirun, error_file=False))
            else:
                FAILURES.append(JobFailure(out_dir, overrides, message, code, multirun))
            log.error("job failed: %s (details in %s)", message, Path(out_dir, "error.txt"))
            if DEBUG and not multirun:
                raise
            return
    from sde_torchrl.trainers.comparison import job_result
    from sde_torchrl.trainers.summary import final_lines

    for line in final_lines(summary):
        log.info(line)
    if multirun:
        RESULTS.append(job_result(overrides, summary))


def cli() -> int:
    """Runs :func:`main` and turns every failure into one line on stderr and an exit code."""
    global DEBUG
    debug = DEBUG = debug_mode()
    previous = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # let errors through: one line from us, or the traceback
    sweep_returns: list[Any] = []
    if {"-m", "--multirun"} & set(sys.argv[1:]):
        handle_in_parent()  # a stop signal reaches the jobs joblib runs in other processes
    try:
        with sweep_returns_kept(sweep_returns):
            main()
    except TrainingInterrupted as stop:
        resume = RESUME.get("override") or resume_override(str(stop.out_dir), multirun=False)
        sys.stderr.write(f"interrupted by {stop.signal_name}: checkpoint after update {stop.updates_done} in "
                         f"{shlex.quote(str(stop.out_dir))}; run the same command with {resume} to resume\n")
        return stop.exit_code
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        return EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - composition errors (bad group option, type)
        if debug:
            raise
        message, code = one_line(error)
        sys.stderr.write(f"error: {message}\n")
        return code
    finally:
        if previous is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
    gather_job_reports(sweep_returns)
    for line in FINISHED:
        sys.stdout.write(f"{line}\n")
    if len(RESULTS) > 1:
        from sde_torchrl.trainers.comparison import comparison_lines

        for line in comparison_lines(RESULTS):
            sys.stdout.write(f"{line}\n")
    stopped = stop_requested()
    if INTERRUPTED or stopped is not None:
        return report_stopped(stopped)
    if not FAILURES:
        return 0
    for failure in FAILURES:
        see = f", see {failure.out_dir}/error.txt" if failure.error_file else ""
        where = f" (job {' '.join(failure.overrides)}{see})" if failure.multirun else ""
        sys.stderr.write(f"error: {failure.message}{where}\n")
    codes = {failure.code for failure in FAILURES}
    return codes.pop() if len(codes) == 1 else EXIT_FAILED


def report_stopped(signum: int | None) -> int:
    """Reports a sweep stopped by a signal: each failure, each stopped job's line (its checkpoint and
    the resume override), and returns the signal's exit code (143 for SIGTERM)."""
    for failure in FAILURES:
        sys.stderr.write(f"error: {failure.message} (job {' '.join(failure.overrides)})\n")
    for entry in INTERRUPTED:
        sys.stderr.write(f"{interrupted_line(entry)}\n")
    name = signal.Signals(signum).name if signum is not None else INTERRUPTED[0]["signal"]
    if not INTERRUPTED:
        resume = RESUME.get("sweep") or RESUME.get("override")
        how = f"run the same command with {resume}" if resume else "run the same command"
        sys.stderr.write(f"interrupted by {name} while no job was training: the jobs not started did not start; "
                         f"{how} to run them\n")
    return 128 + (signum if signum is not None else INTERRUPTED[0]["code"] - 128)


if __name__ == "__main__":
    sys.exit(cli())
