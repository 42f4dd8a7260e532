"""The training command, ``sde-train`` / ``python -m sde_torchrl`` / the clone's ``train.py``:
Hydra's entry point over the package's config tree, and every failure turned into one line on
stderr and an exit code.

:func:`cli` makes the invocation's reports directory (:class:`~sde_torchrl.cli.reports.Reports`),
hands Hydra the task function (:class:`~sde_torchrl.cli.job.Job`) that carries it to every job,
wherever the launcher runs it, and once Hydra returns prints what the jobs reported and exits
(:mod:`sde_torchrl.cli.outcome`). Exit codes (:mod:`sde_torchrl.cli.errors`):

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

In a multirun a failed job leaves ``error.txt`` and the other jobs go on; the exit code is the
failures' common code (1 if they differ). ``SDE_TORCHRL_DEBUG=1`` (or ``HYDRA_FULL_ERROR=1``)
shows full tracebacks instead. Light imports only (no torch): a job holds its run directory
before torch is imported.
"""

from __future__ import annotations

import os
import shlex
import sys

import hydra

from sde_torchrl.cli.errors import EXIT_INTERRUPTED, debug_mode, one_line
from sde_torchrl.cli.job import Job
from sde_torchrl.cli.outcome import report, resume_override
from sde_torchrl.cli.reports import REPORTS_ENV, Reports
from sde_torchrl.config.compose import CONF_DIR
from sde_torchrl.config.help import register_help_resolver
from sde_torchrl.config.registration import register_resolvers
from sde_torchrl.trainers.interrupt import TrainingInterrupted, stop_requested
from sde_torchrl.trainers.sweep_stop import handle_in_parent


def cli() -> int:
    """Runs the command (``sys.argv``: Hydra's overrides and flags) and returns its exit code."""
    register_resolvers()
    register_help_resolver()
    debug = debug_mode()
    previous = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # let errors through: one line from us, or the traceback
    if {"-m", "--multirun"} & set(sys.argv[1:]):
        handle_in_parent()  # a stop signal reaches the jobs joblib runs in other processes
    reports = Reports.fresh()
    outer = os.environ.get(REPORTS_ENV)
    os.environ[REPORTS_ENV] = str(reports.directory)  # for the callback at multirun start (callbacks.py)
    main = hydra.main(version_base="1.3", config_path=str(CONF_DIR), config_name="config")(Job(reports, debug))
    try:
        try:
            main()
        except TrainingInterrupted as stop:
            sweep = reports.sweep()
            resume = (resume_override(sweep.directory, multirun=True) if sweep is not None
                      else resume_override(str(stop.out_dir), multirun=False))
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
        sweep = reports.sweep()
        return report(reports.collect(), stop_requested(),
                      resume_override(sweep.directory, multirun=True) if sweep is not None else None)
    finally:
        if outer is None:
            os.environ.pop(REPORTS_ENV, None)
        else:
            os.environ[REPORTS_ENV] = outer
        reports.remove()
