"""Train policies with state-dependent exploration: ``python train.py +experiment=minimize``.

Hydra composes ``conf/config.yaml`` with the groups ``env``, ``actor``, ``explorer``,
``estimator``, ``logger`` and an optional ``+experiment``; each job writes ``metrics.csv``,
``summary.json`` and ``checkpoint.pt`` into its run directory, and resumes from the checkpoint
when started again in the same directory (``hydra.run.dir=...``).

Errors are reported in one line on stderr (``error: <key>=<value>: <what is allowed>`` for a
config error, exit code 2; exit code 1 for a failed job; 130 after Ctrl-C, with a checkpoint).
A failed job also leaves ``error.txt`` (message and traceback) in its run directory; in a
multirun the other jobs go on. ``SDE_TORCHRL_DEBUG=1`` (or ``HYDRA_FULL_ERROR=1``) shows full
tracebacks instead.
"""

from __future__ import annotations

import logging
import os
import sys
import traceback
from dataclasses import dataclass
from pathlib import Path

import hydra
from hydra.core.hydra_config import HydraConfig
from hydra.types import RunMode
from omegaconf import DictConfig

from sde_torchrl.build import register_resolvers, run_job
from sde_torchrl.checkpoint import CheckpointMismatchError
from sde_torchrl.config import describe_error
from sde_torchrl.interrupt import TrainingInterrupted
from sde_torchrl.progress import progress_wanted

log = logging.getLogger("train")
register_resolvers()

EXIT_FAILED, EXIT_CONFIG, EXIT_INTERRUPTED = 1, 2, 130


@dataclass
class JobFailure:
    """A job that raised: where, with which overrides, and the one-line message."""

    out_dir: str
    overrides: list[str]
    message: str
    config_error: bool
    multirun: bool


#: Failures of this process's jobs, reported once the (multi)run is over.
FAILURES: list[JobFailure] = []
#: Full tracebacks wanted: read once at start-up (``cli`` then sets ``HYDRA_FULL_ERROR`` itself).
DEBUG = False


def debug_mode() -> bool:
    """Full tracebacks wanted (``SDE_TORCHRL_DEBUG=1`` or ``HYDRA_FULL_ERROR=1``)?"""
    return any(os.environ.get(name, "") not in ("", "0") for name in ("SDE_TORCHRL_DEBUG", "HYDRA_FULL_ERROR"))


def one_line(error: BaseException) -> tuple[str, bool]:
    """The error as one line, and whether it is a config error."""
    described = describe_error(error)
    if described is not None:
        return described, True
    if isinstance(error, CheckpointMismatchError):
        return str(error), True
    text = " ".join(str(error).split()) or type(error).__name__
    return (text if type(error).__name__ in text else f"{type(error).__name__}: {text}"), False


@hydra.main(version_base="1.3", config_path="conf", config_name="config")
def main(cfg: DictConfig) -> None:
    """Trains (or resumes) one job; a failure is recorded in ``error.txt`` and reported once
    the run or sweep is over, so that one failed job does not stop a sweep."""
    hydra_cfg = HydraConfig.get()
    out_dir = hydra_cfg.runtime.output_dir
    multirun = hydra_cfg.mode == RunMode.MULTIRUN
    try:
        summary = run_job(cfg, out_dir, dict(hydra_cfg.runtime.choices),
                          progress=progress_wanted(cfg.get("progress"), multirun))
    except Exception as error:  # noqa: BLE001 - every failure is recorded, then reported
        message, config_error = one_line(error)
        Path(out_dir, "error.txt").write_text(f"{message}\n\n{traceback.format_exc()}")
        FAILURES.append(JobFailure(out_dir, list(hydra_cfg.overrides.task), message, config_error, multirun))
        log.error("job failed: %s (details in %s)", message, Path(out_dir, "error.txt"))
        if DEBUG and not multirun:
            raise
        return
    log.info("final return per run: %s", [round(r, 3) for r in summary["final_return"]])


def cli() -> int:
    """Runs :func:`main` and turns every failure into one line on stderr and an exit code."""
    global DEBUG
    debug = DEBUG = debug_mode()
    previous = os.environ.get("HYDRA_FULL_ERROR")
    os.environ["HYDRA_FULL_ERROR"] = "1"  # let errors through: one line from us, or the traceback
    try:
        main()
    except TrainingInterrupted as stop:
        sys.stderr.write(f"interrupted: checkpoint after update {stop.updates_done} in {stop.out_dir}; "
                         f"run the same command with hydra.run.dir={stop.out_dir} to resume\n")
        return EXIT_INTERRUPTED
    except KeyboardInterrupt:
        sys.stderr.write("interrupted\n")
        return EXIT_INTERRUPTED
    except Exception as error:  # noqa: BLE001 - composition errors (bad group option, type)
        if debug:
            raise
        message, config_error = one_line(error)
        sys.stderr.write(f"error: {message}\n")
        return EXIT_CONFIG if config_error else EXIT_FAILED
    finally:
        if previous is None:
            os.environ.pop("HYDRA_FULL_ERROR", None)
    if not FAILURES:
        return 0
    for failure in FAILURES:
        where = f" (job {' '.join(failure.overrides)}, see {failure.out_dir}/error.txt)" if failure.multirun else ""
        sys.stderr.write(f"error: {failure.message}{where}\n")
    return EXIT_CONFIG if all(f.config_error for f in FAILURES) else EXIT_FAILED


if __name__ == "__main__":
    sys.exit(cli())
