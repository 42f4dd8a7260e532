"""analysis/benchmarks/time_split.py: one tiny whole training per side, each in a fresh process, its
time split into exclusive phases that add up to the process's wall time, written as JSON and Markdown
that agree."""

from __future__ import annotations

import json
import time

import pytest

from analysis.benchmarks import time_split


@pytest.mark.e2e
def test_a_tiny_training_splits_into_phases_that_add_up_to_each_process(tmp_path, capsys):
    pytest.importorskip("stable_baselines3")
    pytest.importorskip("pybullet_envs_gymnasium")
    argv = ["--algorithm", "a2c", "--env", "hopper", "--fraction", "0.0005", "--override", "eval_episodes=2",
            "--out", str(tmp_path), "--record", str(tmp_path)]
    start = time.time()
    assert time_split.main(argv) == 0
    elapsed = time.time() - start
    record = json.loads((tmp_path / "a2c_hopper_sde_seed0.json").read_text())
    page = (tmp_path / "a2c_hopper_sde_seed0.md").read_text()
    assert capsys.readouterr().out == page

    for side in ("ours", "sb3"):
        phases, wall = record[side]["phases"], record[side]["wall_s"]
        assert set(phases) <= set(time_split.ROWS) and min(phases.values()) >= 0
        assert sum(phases.values()) == pytest.approx(wall, rel=0.01, abs=0.05)  # exclusive phases: no double count
        assert all(phases.get(p, 0) > 0 for p in ("start-up and imports", "collection", "update", "evaluation", "exit"))
        assert record[side]["env_steps"] == 32 * 32  # 32 updates of 4 envs × 8 steps, both sides
    assert {"config composition", "checkpoint", "metric files"} <= set(record["ours"]["phases"])
    assert "checkpoint" not in record["sb3"]["phases"]
    assert record["ours"]["wall_s"] + record["sb3"]["wall_s"] < elapsed  # the processes ran one after the other

    rows = [line.strip("|").split("|") for line in page.splitlines() if line.startswith("| ") and "---" not in line]
    table = {cells[0].strip(): [c.strip() for c in cells[1:]] for cells in rows[1:]}
    assert list(table) == [p for p in time_split.ROWS if p in record["ours"]["phases"] or p in record["sb3"]["phases"]
                           ] + ["whole process"]
    for phase, (ours, sb3, ratio) in table.items():
        values = [record[s]["wall_s"] if phase == "whole process" else record[s]["phases"].get(phase)
                  for s in ("ours", "sb3")]
        assert [ours, sb3] == ["—" if v is None else f"{v:.2f}" for v in values]
        assert ratio == ("—" if None in values or not values[1] else f"{values[0] / values[1]:.2f}")
    assert f"`{record['command']}`" in page and f"torch {record['machine']['torch']}" in page
