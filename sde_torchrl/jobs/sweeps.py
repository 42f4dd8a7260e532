"""A sweep's job list, from the record Hydra writes into the sweep's directory.

A multirun (``python train.py -m ...``) writes ``multirun.yaml`` into its sweep directory before
it launches a job: its config, whose basic sweeper's ``params`` and the command's overrides
(``hydra.overrides.task``) give the jobs, expanded as Hydra expands them (a cartesian product,
a command-line value replacing a ``params`` one) and numbered in that order; job ``n`` runs in
the subdirectory ``n`` (``hydra.sweep.subdir``'s default). A job that never started (a sweep
stopped before it, or one of its directories removed) leaves no files there, but the record
still lists it, which is how the readers (:func:`~sde_torchrl.jobs.run_dir.finished_runs`)
refuse a sweep with a job missing.

A directory without ``multirun.yaml`` (a single run, a sweep laid out by hand or copied without
it) has no job list: its jobs are the directories holding a job's files. So has a sweep whose
record this module cannot expand (another sweeper, another ``subdir``): a warning says so.
No torch here.
"""

from __future__ import annotations

import logging
import os
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import yaml

from sde_torchrl.utils.files import DamagedFileError

log = logging.getLogger(__name__)

#: The record Hydra writes into a sweep's directory.
SWEEP_RECORD = "multirun.yaml"
#: The sweeper whose job lists :func:`listed_jobs` expands, and the job subdirectory it names.
BASIC_SWEEPER = "hydra._internal.core_plugins.basic_sweeper.BasicSweeper"
JOB_SUBDIR = "${hydra.job.num}"


@dataclass(frozen=True)
class SweepJob:
    """One job a sweep's record lists.

    Attributes:
        path: its run directory (``<sweep>/<num>``).
        num: its number in the sweep (Hydra's ``hydra.job.num``).
        swept: its overrides that differ between the sweep's jobs (all of them for a one-job sweep).
    """

    path: Path
    num: int
    swept: tuple[str, ...]


def listed_jobs(sweep: str | os.PathLike) -> list[SweepJob] | None:
    """The jobs the sweep in ``sweep`` lists (its ``multirun.yaml``), in job order.

    Returns:
        The jobs, or ``None`` when ``sweep`` has no ``multirun.yaml`` or its job list cannot be
        expanded here (a warning names why): its jobs are then found by their files only.

    Raises:
        DamagedFileError: ``multirun.yaml`` is not a YAML mapping with a ``hydra`` entry.

    Examples:
        >>> import tempfile
        >>> sweep = Path(tempfile.mkdtemp())
        >>> listed_jobs(sweep) is None
        True
        >>> _ = (sweep / SWEEP_RECORD).write_text(yaml.safe_dump({"hydra": {
        ...     "sweep": {"subdir": JOB_SUBDIR}, "sweeper": {"_target_": BASIC_SWEEPER, "params": {"seed": "0,1"}},
        ...     "overrides": {"task": ["+experiment=minimize", "lr=0.1,0.2"]}}}))
        >>> [(job.path.name, job.swept) for job in listed_jobs(sweep)]  # doctest: +NORMALIZE_WHITESPACE
        [('0', ('seed=0', 'lr=0.1')), ('1', ('seed=0', 'lr=0.2')), ('2', ('seed=1', 'lr=0.1')),
         ('3', ('seed=1', 'lr=0.2'))]
    """
    sweep = Path(sweep)
    record = sweep / SWEEP_RECORD
    if not record.is_file():
        return None
    hydra = _hydra_entry(record)
    sweeper, subdir = hydra.get("sweeper") or {}, (hydra.get("sweep") or {}).get("subdir")
    if sweeper.get("_target_") != BASIC_SWEEPER or subdir != JOB_SUBDIR:
        log.warning("%s: its jobs are found by their files only (a job that never started is not noticed): this "
                    "reader expands the job list of Hydra's basic sweeper with subdir %s, not of %s with subdir %s",
                    record, JOB_SUBDIR, sweeper.get("_target_"), subdir)
        return None
    try:
        jobs = _expanded(sweeper.get("params") or {}, (hydra.get("overrides") or {}).get("task") or [])
    except Exception as error:  # noqa: BLE001 - Hydra's parser errors: no job list, said so
        log.warning("%s: its jobs are found by their files only (a job that never started is not noticed): its "
                    "overrides cannot be expanded here (%s)", record, " ".join(str(error).split())[:200])
        return None
    common = set.intersection(*map(set, jobs)) if len(jobs) > 1 else set()
    return [SweepJob(sweep / str(num), num, tuple(o for o in job if o not in common)) for num, job in enumerate(jobs)]


def sweeps_under(directory: str | os.PathLike) -> list[Path]:
    """The sweep directories under ``directory`` (itself included): those holding a ``multirun.yaml``.

    Examples:
        >>> import tempfile
        >>> sweeps_under(tempfile.mkdtemp())
        []
    """
    return sorted(record.parent for record in Path(directory).rglob(SWEEP_RECORD) if record.is_file())


def _hydra_entry(record: Path) -> dict[str, Any]:
    """``multirun.yaml``'s ``hydra`` mapping (Hydra's interpolations left as text)."""
    remedy = ("restore it from where the sweep was copied, or remove it to read the sweep by the job directories "
              "it holds (a job that never started is then not noticed)")
    try:
        found = yaml.safe_load(record.read_text())
    except (yaml.YAMLError, UnicodeDecodeError) as error:
        raise DamagedFileError(record, f"it is not valid YAML ({' '.join(str(error).split())[:200]})", remedy) from None
    if not isinstance(found, dict) or not isinstance(found.get("hydra"), dict):
        raise DamagedFileError(record, "it holds no hydra entry", remedy)
    return found["hydra"]


def _expanded(params: dict[str, Any], task: list[str]) -> list[list[str]]:
    """Each job's overrides, as Hydra's basic sweeper expands ``params`` and the command's overrides."""
    from hydra._internal.core_plugins.basic_sweeper import BasicSweeper  # Hydra's own expansion, not a copy
    from hydra.core.override_parser.overrides_parser import OverridesParser

    overrides = OverridesParser.create().parse_overrides([*(f"{k}={v}" for k, v in params.items()), *task])
    return [job for batch in BasicSweeper.split_arguments(overrides, None) for job in batch]
