"""analysis/benchmarks/bench_ballcatch.py: one JSON line with the ball-catching env's step rates and
their ratios to the raw simulator."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest
from _helpers import REPO


@pytest.mark.parametrize("model", ["cup", "pybrain"])
@pytest.mark.e2e
def test_benchmark_prints_one_json_line_with_its_figures(model):
    result = subprocess.run([sys.executable, "-m", "analysis.benchmarks.bench_ballcatch", "--worlds", "2",
                             "--steps", "5", "--repeats", "1", "--model", model],
                            cwd=REPO, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    figures = json.loads(result.stdout.strip().splitlines()[-1])
    assert figures["worlds"] == 2 and figures["raw_steps_per_s"] > 0 and figures["model"] == model
    # the ratios are printed to 3 decimals (abs=1e-3), the rates to 1: the ratios agree with the rates
    assert figures["ratio"] == pytest.approx(figures["env_steps_per_s"] / figures["raw_steps_per_s"],
                                             rel=1e-2, abs=1e-3)
    assert figures["rex_ratio"] == pytest.approx(figures["rex_env_steps_per_s"] / figures["rex_raw_steps_per_s"],
                                                 rel=1e-2, abs=1e-3)
    # the stricter of the two replay orders is the denominator
    assert figures["raw_steps_per_s"] == max(figures["raw_episode_order_steps_per_s"],
                                             figures["raw_lockstep_steps_per_s"])
    assert figures["step_ratio"] == pytest.approx(
        figures["step_env_steps_per_s"] / figures["raw_lockstep_steps_per_s"], rel=1e-2, abs=1e-3)
