"""The ball-catching comparisons of the paper (Fig. 5 and 6) on the full budget: 100 runs each of
SDE and REX, with REINFORCE and with ENAC. Slow (the README gives the sweep times):
``python -m pytest -m slow tests/test_ballcatch_claims.py``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _helpers import load_script, run_cli

fig5 = load_script("fig5")


def _sweep(tmp_path: Path, experiment: str, estimator: str) -> dict:
    result = run_cli(f"+experiment={experiment}", run_dir=tmp_path / "sweep", multirun=True, timeout=3 * 3600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert fig5.main([str(tmp_path / "sweep"), "--out", str(tmp_path / "out"), "--estimator", estimator]) == 0
    name = fig5.FIGURE[estimator]
    return json.loads((tmp_path / "out" / f"{name}.json").read_text())["explorers"]


@pytest.mark.slow
def test_reinforce_sde_catches_far_more_often_than_rex(tmp_path):
    explorers = _sweep(tmp_path, "ballcatch_sweep", "reinforce")
    sde, rex = explorers["sde"], explorers["rex"]
    assert sde["runs"] == rex["runs"] == 100
    assert sde["best"]["-1.0"] >= 3 * rex["best"]["-1.0"] and sde["best"]["-1.0"] > 0
    assert sde["best"]["-1.1"] >= 80


@pytest.mark.slow
def test_enac_sde_catches_more_often_than_rex(tmp_path):
    explorers = _sweep(tmp_path, "ballcatch_enac_sweep", "enac")
    assert explorers["sde"]["runs"] == explorers["rex"]["runs"] == 100
    assert explorers["sde"]["best"]["-1.1"] > explorers["rex"]["best"]["-1.1"]
