"""analysis/paper/table1.py: the sweep machinery on a tiny budget (fast), and the paper's claims on
the full budget (slow: ``python -m pytest -m slow tests/study/test_table1.py``)."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SETTINGS = {("noise", 0.5, 15), ("noise", 1.0, 15), ("noise", 1.5, 15), ("episode_length", 0.5, 5),
            ("episode_length", 0.5, 15), ("episode_length", 0.5, 30), ("episode_length", 0.5, 45),
            ("episode_length", 0.5, 60)}
OUTPUTS = ("table1.json", "table1.md", "fig2.png", "fig3_left.png", "fig3_right.png")


def _table1(out: Path, *args: str) -> dict:
    result = subprocess.run([sys.executable, "-m", "analysis.paper.table1", "--out", str(out), *args],
                            cwd=ROOT, capture_output=True, text=True, timeout=1800)
    assert result.returncode == 0, result.stderr[-3000:]
    return json.loads((out / "table1.json").read_text())


@pytest.mark.e2e
def test_tiny_sweep_writes_every_output_and_rereads_its_runs(tmp_path):
    table = _table1(tmp_path / "a", "runs=2", "updates=8", "episodes_per_update=4")
    assert {(r["sweep"], r["sigma_noise"], r["episode_length"]) for r in table["rows"]} == SETTINGS
    for row in table["rows"]:
        assert row["paper"]["rex_episodes"] > row["paper"]["sde_episodes"]
        assert row["r_lim"] == row["paper"]["r_lim"]  # the paper's R_lim, unchanged, on the authors' task
        for method in ("rex", "sde", "sde_gpomdp", "pgpe"):  # SDE + GPOMDP and PGPE: added, same harness
            assert row[f"{method}_spread"]["runs"] == 2
    assert table["mlp2d"]["runs"] == 2 and table["mlp2d"]["episodes"] == 32
    assert set(table["mlp2d"]["intervals"]) >= {"rex_plateau", "episodes_to_rex_plateau", "plateau_speedup"}
    assert len(list((tmp_path / "a" / "runs").glob("*estimator-gpomdp"))) == 8
    assert len(list((tmp_path / "a" / "runs").glob("*explorer-pgpe_estimator-pgpe"))) == 8
    for name in OUTPUTS:
        assert (tmp_path / "a" / name).stat().st_size > 0, name
    markdown = (tmp_path / "a" / "table1.md").read_text()
    assert markdown.count("\n| noise |") == 3 and markdown.count("\n| episode_length |") == 5
    assert set(table["checks"]) >= {"all_runs_converged", "settings_within_factor_2", "speedup_el60_over_el5"}
    summary = json.loads(next((tmp_path / "a" / "runs").rglob("summary.json")).read_text())
    assert summary["episode_return"] == "sum"

    again = _table1(tmp_path / "b", "--from", str(tmp_path / "a" / "runs"))
    assert again["rows"] == table["rows"] and again["mlp2d"] == table["mlp2d"]


def _summary(method: str, sweep: str, episodes: list) -> dict:
    estimator = {"sde_gpomdp": "gpomdp", "pgpe": "pgpe"}.get(method, "reinforce")
    explorer = method if method in ("rex", "pgpe") else "sde"
    return {"experiment": sweep, "explorer": explorer, "estimator": estimator,
            "config": {"env": {"noise_std": 0.5, "episode_length": 15}}, "settings": {"r_lim": -1.6},
            "episodes_to_threshold": episodes}


def test_cells_carry_bootstrap_intervals_and_significance(tmp_path):
    from analysis.paper import table1
    rex = [9000 + 100 * i for i in range(30)]  # mean 10,450: the paper's 9,950 lies outside its interval
    sde = [700 + 10 * i for i in range(29)] + [None]
    gpomdp = [1400 + 20 * i for i in range(30)]
    pgpe = [700 + 10 * i for i in range(28)] + [None, None]  # as fast as SDE: no significant difference
    rows = table1.table_rows([_summary("rex", "noise_sweep", rex), _summary("sde", "noise_sweep", sde),
                              _summary("sde_gpomdp", "noise_sweep", gpomdp), _summary("pgpe", "noise_sweep", pgpe)])
    (row,) = rows
    assert row["rex_episodes"] == 10450 and row["rex_ci"][0] < 10450 < row["rex_ci"][1]
    assert row["sde_spread"]["not_converged"] == 1 and row["sde_episodes"] == 840
    assert row["speedup_significant"] and row["paper_outside_ci"] == {"rex": True, "sde": True, "speedup": True}
    assert row["gpomdp_ratio"] < 1 and row["gpomdp_ratio_significant"]  # GPOMDP slower here, significantly
    assert row["pgpe_spread"]["not_converged"] == 2 and not row["pgpe_ratio_significant"]
    table1.write_markdown(rows, None, tmp_path / "table1.md")
    markdown = (tmp_path / "table1.md").read_text()
    low, high = (f"{x:,.0f}" for x in row["rex_ci"])
    assert f"| 10,450 [{low}, {high}] / 9,950 † |" in markdown
    assert "GPOMDP significantly faster in 0 of 1; significantly slower in 1 of 1 (σ 0.5)" in markdown
    assert "SDE significantly faster in 0 of 1; PGPE significantly faster in 0 of 1" in markdown
    assert "| 0 / 1 / 0 / 2 |" in markdown  # not converged REX / SDE / SDE + GPOMDP / PGPE


@pytest.fixture(scope="module")
def full_table(tmp_path_factory):
    return _table1(tmp_path_factory.mktemp("table1"))


def _rows(table: dict) -> dict:
    return {(r["sweep"], r["sigma_noise"], r["episode_length"]): r for r in table["rows"]}


@pytest.mark.slow
def test_full_table_sde_faster_everywhere_more_so_for_longer_episodes(full_table):
    rows = _rows(full_table)
    assert set(rows) == SETTINGS
    for setting, row in rows.items():
        assert row["sde_episodes"] < row["rex_episodes"], setting
    lengths = [rows[("episode_length", 0.5, n)]["speedup"] for n in (5, 15, 30, 45, 60)]
    assert lengths[-1] >= 3 * lengths[0]
    assert full_table["checks"]["settings_within_factor_2"] >= 6
    mlp = full_table["mlp2d"]
    assert mlp["plateau_speedup"] >= 5
    assert mlp["final_mean_return"]["sde"] > mlp["final_mean_return"]["rex"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="one REX run at EL 45 diverges to θ > 0, finite in float32 (README, Table 1)")
def test_full_table_every_run_converges(full_table):
    assert full_table["checks"]["all_runs_converged"]


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="the norm bound slows SDE at high noise: speed-up falls with noise (README)")
def test_full_table_speedup_grows_with_noise(full_table):
    assert full_table["checks"]["speedup_grows_with_noise"]
