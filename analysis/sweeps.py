"""How the analysis scripts read sweeps: every finished job under the directories they are given
(:func:`~sde_torchrl.jobs.run_dir.finished_runs`: each job's files checked, and each sweep's
job list, from its ``multirun.yaml``, held against the jobs that ran), or, for a job that is not
finished or never started, a refusal in one line on stderr (``error: ...``) and exit code 2,
without a traceback: a table or a figure is never made from a sweep with a job missing."""

from __future__ import annotations

import os
import sys
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    from sde_torchrl.jobs.run_dir import FinishedRun

#: The exit code of a refused sweep (as argparse's for a bad argument).
EXIT_REFUSED = 2


def finished_jobs(*directories: str | os.PathLike) -> list[FinishedRun]:
    """Every finished job under ``directories`` (sweeps, shards of one, or run directories).

    Raises:
        SystemExit: with :data:`EXIT_REFUSED`, once the refusal's line is on stderr: a job under
            ``directories`` is not finished, never started, or has damaged files.
    """
    from sde_torchrl.jobs.run_dir import finished_runs  # torch: only once the arguments are read
    from sde_torchrl.utils.files import DamagedFileError

    try:
        return finished_runs(*directories)
    except DamagedFileError as error:  # UnfinishedRunError too
        print(f"error: {error}", file=sys.stderr)
        raise SystemExit(EXIT_REFUSED) from None
