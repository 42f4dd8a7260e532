"""The study's sweeps (``analysis/conf/experiment/*_sweep.yaml``) on the cluster launchers: each
shard asks for what it is estimated to use, as the library's experiments do
(``tests/test_launchers.py``). Skipped without the launchers that ``pip install -e ".[dev]"``
installs (``tests/conftest.py``)."""

from __future__ import annotations

import pytest
from _helpers import REPO
from test_launchers import requests_cover_the_estimates

pytestmark = pytest.mark.launchers

#: The study's sweeps (analysis/conf/experiment/, on Hydra's search path in a clone).
SWEEPS = sorted(p.stem for p in (REPO / "analysis" / "conf" / "experiment").glob("*sweep.yaml"))


@pytest.mark.parametrize("launcher", ["slurm", "ray_cluster"])
@pytest.mark.parametrize("sweep", SWEEPS)
def test_every_sweep_requests_what_its_shards_are_estimated_to_use(sweep, launcher):
    """Each sweep composed with each cluster launcher asks, per shard, for at least the memory
    and the time that shard is estimated to need (sde_torchrl/jobs/resources.py)."""
    requests_cover_the_estimates([f"+experiment={sweep}"], launcher)
