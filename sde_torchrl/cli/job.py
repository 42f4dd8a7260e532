"""One job of the command: Hydra's task function, run wherever the launcher runs it.

:class:`Job` holds the job's run directory (:mod:`sde_torchrl.jobs.lock`) before it writes
anything there (Hydra's ``.hydra/`` files included, :func:`save_hydra_config`) and before torch is
imported; leaves a finished job's directory as it is; trains (or resumes) the job; and posts what
the command reports at the end (:class:`~sde_torchrl.cli.reports.JobReport`: a failure, with
``error.txt`` in the run directory; a finished job's line; an interruption in a sweep's worker; the
result for the comparison lines), so that one failed job does not stop a sweep.
"""

from __future__ import annotations

import logging
import traceback
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig, OmegaConf

from sde_torchrl.cli.errors import is_foreign_checkpoint, one_line
from sde_torchrl.cli.outcome import interrupted_entry, resume_override
from sde_torchrl.cli.reports import JobFailure, JobReport, Reports, Sweep
from sde_torchrl.config.registration import register_resolvers
from sde_torchrl.config.schemas.train import TrainConf, validate
from sde_torchrl.jobs.lock import hold_run_directory
from sde_torchrl.trainers.interrupt import TrainingInterrupted, stop_requested
from sde_torchrl.trainers.progress import progress_wanted
from sde_torchrl.trainers.sweep_stop import in_worker, job_started
from sde_torchrl.utils.files import write_atomically

log = logging.getLogger("train")


@dataclass(frozen=True)
class Job:
    """Hydra's task function: trains (or resumes) one job and posts its report to ``reports``.

    A launcher that runs jobs in other processes pickles this object with the config, so each
    job knows where its report goes. ``debug``: a single run's failure is raised (full traceback)
    instead of reported in one line.
    """

    reports: Reports
    debug: bool = False

    def __call__(self, cfg: DictConfig) -> None:
        register_resolvers()  # in a launcher's worker too
        hydra_cfg = HydraConfig.get()
        multirun = hydra_cfg.mode == RunMode.MULTIRUN
        sweep = Sweep(str(hydra_cfg.sweep.dir), str(hydra_cfg.runtime.cwd)) if multirun else None
        resume = resume_override(hydra_cfg.sweep.dir if multirun else hydra_cfg.runtime.output_dir, multirun)
        try:
            report = self.run(cfg, hydra_cfg, multirun)
        except TrainingInterrupted as stop:
            if not in_worker():  # this process reports it (the command)
                raise
            report = JobReport(interrupted=interrupted_entry(stop, resume))  # a sweep's worker: to the command
        self.reports.post(report, f"{hydra_cfg.job.num:06d}" if multirun else "run", sweep)

    def run(self, cfg: DictConfig, hydra_cfg: Any, multirun: bool) -> JobReport:
        """The job, and what it reports."""
        out_dir = hydra_cfg.runtime.output_dir
        overrides = list(hydra_cfg.overrides.task)
        job_started()  # in a joblib worker: a stop signal checkpoints the job and starts no other
        if stop_requested() is not None:  # the sweep was stopped before this job: it does not start
            return JobReport()
        with ExitStack() as stack:
            try:
                stack.enter_context(hold_run_directory(out_dir))
            except Exception as error:  # noqa: BLE001 - in use (or not writable): nothing is written there
                message, code = one_line(error)
                return JobReport(failure=JobFailure(out_dir, overrides, message, code, multirun, error_file=False))
            # A directory with a summary holds a finished job (or, rarely, one about to resume from an
            # older checkpoint): leave its files as they are, train.log included, unless it trains.
            finished = Path(out_dir, "summary.json").exists()
            if finished:
                stack.enter_context(log_file_suspended(out_dir))
            elif not Path(out_dir, "checkpoint.pt").exists():  # a resumed job keeps its first session's
                save_hydra_config(cfg, out_dir)
            try:
                conf = validate(cfg)  # the job's config, once: a bad value fails here, before importing torch
                line = finished_line(conf, out_dir) if finished else None
                if line is not None:
                    return JobReport(finished=line)
                from sde_torchrl.config.build import run_job  # torch: imported once the run directory is ours

                summary = run_job(conf, out_dir, dict(hydra_cfg.runtime.choices),
                                  progress=progress_wanted(conf.progress, multirun))
            except Exception as error:  # noqa: BLE001 - every failure is recorded, then reported
                message, code = one_line(error)
                if finished or is_foreign_checkpoint(error):  # a finished job's, or another's: leave it as it is
                    return JobReport(failure=JobFailure(out_dir, overrides, message, code, multirun, error_file=False))
                failure = JobFailure(out_dir, overrides, message, code, multirun)
                try:
                    Path(out_dir, "error.txt").write_text(f"{message}\n\n{traceback.format_exc()}")
                except OSError:  # a full disk: the message still reaches stderr
                    Path(out_dir, "error.txt").unlink(missing_ok=True)
                    failure.error_file = False
                log.error("job failed: %s (details in %s)", message, Path(out_dir, "error.txt"))
                if self.debug and not multirun:
                    raise
                return JobReport(failure=failure)
        from sde_torchrl.trainers.comparison import job_result
        from sde_torchrl.trainers.summary import final_lines

        for line in final_lines(summary):
            log.info(line)
        return JobReport(result=job_result(overrides, summary)) if multirun else JobReport()


def save_hydra_config(cfg: DictConfig, out_dir: str) -> None:
    """Writes what Hydra writes into ``<run dir>/.hydra`` (``config.yaml``, ``hydra.yaml``,
    ``overrides.yaml``): the config tree's ``config.yaml`` sets ``hydra.output_subdir`` to null so
    that they are written here, by the process that holds the run directory."""
    hydra_node = HydraConfig.instance().cfg
    target = Path(out_dir, ".hydra")
    target.mkdir(exist_ok=True)
    for name, node in (("config.yaml", cfg), ("hydra.yaml", hydra_node),
                       ("overrides.yaml", hydra_node.hydra.overrides.task)):
        write_atomically(target / name, lambda f, node=node: f.write(OmegaConf.to_yaml(node).encode()))


def finished_line(conf: TrainConf, out_dir: str) -> str | None:
    """The line of this config's finished job if ``out_dir`` holds one, checked as the job checks
    it (:meth:`~sde_torchrl.jobs.run_dir.RunDirectory.check_job`, here before anything is built);
    nothing is changed.

    Raises:
        CheckpointMismatchError: it holds a job of another config.
        DamagedFileError: it holds no checkpoint and its files disagree, or a damaged checkpoint.
    """
    from sde_torchrl.jobs.checkpoint import result_config  # torch: the run directory is ours
    from sde_torchrl.jobs.run_dir import RunDirectory
    from sde_torchrl.trainers.job import finished_line as line_of

    done = RunDirectory(out_dir, result_config(conf.resolved())).check_job()
    return None if done is None else line_of(done)


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
