"""The one runner of the analysis scripts' training jobs: a pool of worker processes.

:func:`run_train_jobs` runs jobs of ``train.py``'s config (``table1.py``, ``ballcatch_tuning.py``),
longest first: a job whose run directory holds a finished run
(:func:`sde_torchrl.jobs.run_dir.read_finished_run`) is skipped, any other starts or resumes from
its checkpoint, and a failed job is reported by name with its one-line error while the others go
on. A job runs one of two ways, with the same bookkeeping:

- in the worker process (``command=False``): the composed config through
  :func:`sde_torchrl.config.build.run_job`, as ``train.py`` runs it, without starting an
  interpreter and importing torch per job (Table 1's 34 short jobs);
- as the command ``python train.py OVERRIDES hydra.run.dir=RUN_DIR`` (``command=True``), which
  also writes Hydra's ``.hydra/`` files and, for a failed job, ``error.txt``.

:class:`JobPool` is the pool itself, for jobs that are not ``train.py`` runs
(``learner_search.py``'s candidate jobs, which stop at the first failure).

Examples:
    >>> job = TrainJob("sde", ("+experiment=minimize", "explorer=sde"), Path("runs/sde"), cost=15)
    >>> command_line(job)[-1]
    'hydra.run.dir=runs/sde'
"""

from __future__ import annotations

import functools
import gc
import logging
import subprocess
import sys
import time
from collections.abc import Callable, Hashable, Sequence
from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
from dataclasses import dataclass
from pathlib import Path
from typing import Any

REPO = Path(__file__).resolve().parents[1]

log = logging.getLogger("runner")


@dataclass(frozen=True)
class TrainJob:
    """One ``train.py`` job.

    Attributes:
        name: how the logs name it.
        overrides: its config overrides, as for ``train.py``.
        run_dir: its run directory.
        cost: its expected cost: the pool starts the most expensive jobs first.
    """

    name: str
    overrides: tuple[str, ...]
    run_dir: Path
    cost: float = 0.0


@dataclass(frozen=True)
class Failure:
    """A job that failed, and its one-line error."""

    job: TrainJob
    message: str


class JobPool:
    """``workers`` worker processes, for one or several batches of jobs (:meth:`run`)."""

    def __init__(self, workers: int) -> None:
        if workers < 1:
            raise ValueError(f"workers={workers}: a positive integer")
        self._pool = ProcessPoolExecutor(max_workers=workers)

    def __enter__(self) -> JobPool:
        return self

    def __exit__(self, *exc: Any) -> None:
        self._pool.shutdown()

    def run(self, function: Callable[..., Any], tasks: dict[Hashable, tuple], stop: Callable[[Any], bool] | None = None,
            done: Callable[[Hashable, Any], None] | None = None) -> dict[Hashable, Any]:
        """Runs ``function(*arguments)`` for every ``key → arguments`` of ``tasks``.

        Args:
            function: a module-level function (it is sent to the worker processes).
            tasks: key → the function's arguments, in the order they are submitted.
            stop: with a result for which it is true, the tasks not yet started are cancelled;
                those started finish and their results are kept.
            done: called with each key and its result as the result arrives.

        Returns:
            key → result, in the order the results arrived (after a stop, the started tasks'
            results follow in the order they were submitted).

        Raises:
            Exception: whatever ``function`` raised, once its result is collected.
        """
        pending = {self._pool.submit(function, *arguments): key for key, arguments in tasks.items()}
        results: dict[Hashable, Any] = {}
        stopped = False
        while pending and not stopped:
            finished, _ = wait(pending, return_when=FIRST_COMPLETED)
            for future in finished:
                key = pending.pop(future)
                results[key] = future.result()
                if done is not None:
                    done(key, results[key])
                stopped = stopped or (stop is not None and stop(results[key]))
        for future in pending:
            future.cancel()
        for future, key in pending.items():  # started before the stop: let them finish
            if not future.cancelled():
                results[key] = future.result()
        return results


def is_finished(run_dir: Path) -> bool:
    """Whether ``run_dir`` holds a finished run, read as the analysis reads it; an unfinished,
    missing or damaged one is not (running the job again finishes or repairs it)."""
    if not (run_dir / "summary.json").exists():  # not run yet: no need to import torch before the pool forks
        return False
    from sde_torchrl.jobs.run_dir import UnfinishedRunError, read_finished_run
    from sde_torchrl.utils.files import DamagedFileError

    try:
        read_finished_run(run_dir)
    except (UnfinishedRunError, DamagedFileError, FileNotFoundError):
        return False
    return True


def command_line(job: TrainJob) -> list[str]:
    """``python train.py OVERRIDES hydra.run.dir=RUN_DIR``, run from the repository."""
    return [sys.executable, "train.py", *job.overrides, f"hydra.run.dir={job.run_dir}"]


def run_train_jobs(jobs: Sequence[TrainJob], workers: int, command: bool = False,
                   keep_checkpoints: bool = True) -> list[Failure]:
    """Runs the jobs that are not finished yet on ``workers`` processes, the most expensive first.

    Args:
        jobs: the jobs; those whose run directory holds a finished run are skipped.
        workers: worker processes.
        command: run each job as the ``train.py`` command (:func:`command_line`) rather than in
            the worker process.
        keep_checkpoints: ``False`` deletes a job's checkpoints once it has finished (run
            directories that are committed without them).

    Returns:
        The failed jobs, each with its one-line error (also logged); the others went on.
    """
    start = time.perf_counter()
    todo = []
    for job in jobs:
        if is_finished(job.run_dir):
            log.info("finished already: %s", job.name)
        else:
            todo.append(job)
    todo.sort(key=lambda job: job.cost, reverse=True)

    def report(job: TrainJob, message: str | None) -> None:
        if message is None:
            log.info("finished %s after %.0f s", job.name, time.perf_counter() - start)
        else:
            log.error("failed %s: %s", job.name, message)

    run = _run_command if command else _run_in_process
    with JobPool(workers) as pool:
        results = pool.run(run, {job: (job, keep_checkpoints) for job in todo}, done=report)
    failures = [Failure(job, message) for job, message in results.items() if message is not None]
    if failures:
        log.error("%d of %d jobs failed: %s", len(failures), len(todo), ", ".join(f.job.name for f in failures))
    return failures


def run_train_job(job: TrainJob, command: bool = False, keep_checkpoints: bool = True) -> str | None:
    """Trains (or resumes) one job in this process, or as the ``train.py`` command (``command``),
    for a pool of one's own (:class:`JobPool`) that also runs other kinds of jobs; its one-line
    error, or ``None`` once it has finished."""
    return (_run_command if command else _run_in_process)(job, keep_checkpoints)


def _run_in_process(job: TrainJob, keep_checkpoints: bool) -> str | None:
    """Trains (or resumes) ``job`` in this worker process; its one-line error, or ``None``."""
    import torch
    from omegaconf import open_dict

    from sde_torchrl.config.build import run_job
    from sde_torchrl.config.compose import compose
    from sde_torchrl.config.schemas.train import validate

    torch.set_num_threads(1)  # one core per worker: the pool is the parallelism
    _freeze_imports()
    try:
        cfg = compose(list(job.overrides), return_hydra_config=True)
        choices = dict(cfg.hydra.runtime.choices)  # the labels train.py gives its summaries
        with open_dict(cfg):
            del cfg["hydra"]
        run_job(validate(cfg), str(job.run_dir), choices)
    except Exception as error:  # noqa: BLE001 - reported by name, the other jobs go on
        text = " ".join(str(error).split())
        return text if type(error).__name__ in text else f"{type(error).__name__}: {text}"
    _finish(job, keep_checkpoints)
    return None


@functools.cache
def _freeze_imports() -> None:
    """Once per worker process: the objects alive so far (the modules of torch, TorchRL and Hydra
    just imported) are left out of every later garbage collection (:func:`gc.freeze`), which
    then walks only what the jobs make; a job's updates trigger many."""
    gc.freeze()


def _run_command(job: TrainJob, keep_checkpoints: bool) -> str | None:
    """Trains (or resumes) ``job`` with the ``train.py`` command; its error line, or ``None``."""
    result = subprocess.run(command_line(job), cwd=REPO, capture_output=True, text=True)
    if result.returncode != 0:
        lines = [line for line in result.stderr.splitlines() if line.startswith("error:")] or \
            result.stderr.strip().splitlines()[-1:] or [""]
        error_file = job.run_dir / "error.txt"
        see = f" (see {error_file})" if error_file.exists() else ""
        return f"exit {result.returncode}: {lines[-1].removeprefix('error: ')}{see}"
    _finish(job, keep_checkpoints)
    return None


def _finish(job: TrainJob, keep_checkpoints: bool) -> None:
    if not keep_checkpoints:
        for checkpoint in job.run_dir.glob("checkpoint*.pt"):
            checkpoint.unlink()
