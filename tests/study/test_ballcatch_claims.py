"""The ball-catching comparisons of the paper (Fig. 5 and 6) on the full budget: 100 runs each of
SDE and REX, with REINFORCE and with ENAC, on the PyBrain arm; the claims are the README's (from
the first 50-run shard of each). Slow (the README gives the sweep times):
``python -m pytest -m slow tests/study/test_ballcatch_claims.py``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from _helpers import run_cli

from analysis.paper import fig5


def _sweep(tmp_path: Path, experiment: str, estimator: str) -> dict:
    result = run_cli(f"+experiment={experiment}", run_dir=tmp_path / "sweep", multirun=True, timeout=4 * 3600)
    assert result.returncode == 0, result.stderr[-3000:]
    assert fig5.main([str(tmp_path / "sweep"), "--out", str(tmp_path / "out"), "--estimator", estimator]) == 0
    name = fig5.FIGURE[estimator]
    return json.loads((tmp_path / "out" / f"{name}.json").read_text())


@pytest.mark.slow
def test_reinforce_sde_reaches_every_level_up_to_a_catch_more_often_than_rex(tmp_path):
    """README, Fig. 5: significantly more SDE runs than REX runs reach R ≥ -2, -1.5 and -1.1."""
    result = _sweep(tmp_path, "ballcatch_paper_sweep", "reinforce")
    assert result["explorers"]["sde"]["runs"] == result["explorers"]["rex"]["runs"] == 100
    for level in ("-2.0", "-1.5", "-1.1"):
        assert result["sde_minus_rex"]["best"][level]["significant"], level
        assert result["sde_minus_rex"]["best"][level]["estimate"] > 0, level


@pytest.mark.slow
def test_enac_sde_catches_more_often_than_rex(tmp_path):
    result = _sweep(tmp_path, "ballcatch_enac_paper_sweep", "enac")
    explorers = result["explorers"]
    assert explorers["sde"]["runs"] == explorers["rex"]["runs"] == 100
    assert explorers["sde"]["best"]["-1.1"] > explorers["rex"]["best"]["-1.1"]
