"""analysis/benchmarks/bench_table1.py: one JSON line with each cell's costs per update."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from _helpers import REPO


@pytest.mark.e2e  # a benchmark script, as a user runs it
def test_prints_one_json_line_with_every_cells_costs():
    result = subprocess.run([sys.executable, "-m", "analysis.benchmarks.bench_table1", "--lengths", "5",
                             "--explorers", "rex", "sde", "--updates", "2", "--repeats", "1"],
                            cwd=REPO, capture_output=True, text=True, timeout=300, check=True)
    lines = result.stdout.strip().splitlines()
    assert len(lines) == 1
    cells = json.loads(lines[0])["cells"]
    assert set(cells) == {"rex_el5", "sde_el5"}
    for cell in cells.values():
        assert cell["collect_ms"] > 0 and cell["update_ms"] > 0
        assert cell["steps_per_update"] == 30 * 10 * 5  # the sweep's 30 runs × 10 episodes × EL


def test_a_cell_it_does_not_know_is_refused():
    from analysis.benchmarks import bench_table1

    with pytest.raises(SystemExit):
        bench_table1.main(["--explorers", "pgpe"])
