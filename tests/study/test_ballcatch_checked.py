"""The headline learner's page (``analysis/paper/ballcatch_checked.py``): counts read off the
jobs' final checks, and a sweep without them refused; the film of a job's best policy
(``analysis/paper/ballcatch_best_film.py``)."""

from __future__ import annotations

import json

import pytest
from _helpers import compose_config, run_cli

from analysis.paper import ballcatch_best_film, ballcatch_checked
from sde_torchrl.config.build import run_job
from sde_torchrl.config.schemas.train import validate

#: Ball-catching jobs run as processes (train.py), as a user runs them: the end-to-end tests.
pytestmark = pytest.mark.e2e

TINY = ("+experiment=ballcatch", "runs=2", "updates=2", "eval_period=1", "episode_queue=2", "env.episode_length=40",
        "final_episodes=2", "logger=none")


@pytest.fixture(scope="module")
def sweeps(tmp_path_factory):
    root = tmp_path_factory.mktemp("checked")
    for explorer in ("sde", "rex"):
        result = run_cli(*TINY, f"explorer={explorer}", run_dir=root / explorer / "0")
        assert result.returncode == 0, result.stderr[-2000:]
    return root


def test_the_page_counts_what_the_jobs_final_checks_found(sweeps, tmp_path):
    assert ballcatch_checked.main([str(sweeps / "sde"), str(sweeps / "rex"), "--out", str(tmp_path)]) == 0
    page = json.loads((tmp_path / "checked.json").read_text())
    for explorer in ("sde", "rex"):
        summary = json.loads((sweeps / explorer / "0" / "summary.json").read_text())
        counts = page["explorers"][explorer]["counts"]["catch"]
        assert counts["best_checked"] == sum(level in ("catch", "good catch") for level in summary["best_check_level"])
        assert counts["final"] == sum(level in ("catch", "good catch") for level in summary["final_eval_level"])
        assert page["explorers"][explorer]["runs"] == 2
        episodes = page["explorers"][explorer]["best_policy_episodes"]
        assert sum(episodes.values()) == 2 * 2  # 2 runs × 2 fresh balls
        assert (sweeps / explorer / "0" / "best_policy.gif").stat().st_size > 0  # the best run's best policy, filmed
    page = (tmp_path / "checked.md").read_text()
    assert "| best policy: a catch on the fresh balls |" in page and "| last evaluation: a good catch |" in page


def test_a_sweep_without_final_checks_is_refused_in_one_line(sweeps, tmp_path, capsys):
    run_job(validate(compose_config(*TINY, "final_episodes=0")), str(tmp_path / "old" / "0"),
            {"experiment": "ballcatch", "explorer": "sde", "env": "ballcatch"})
    with pytest.raises(SystemExit) as refused:
        ballcatch_checked.main([str(tmp_path / "old"), str(sweeps / "rex"), "--out", str(tmp_path / "out")])
    assert refused.value.code == 2
    assert capsys.readouterr().err.splitlines()[-1].startswith(f"error: {tmp_path / 'old' / '0'} has no final check")


def test_the_best_run_s_best_policy_is_filmed_from_its_job(sweeps, tmp_path, capsys):
    out = tmp_path / "best.gif"
    assert ballcatch_best_film.main([str(sweeps / "sde"), "--out", str(out)]) == 0
    found = json.loads(capsys.readouterr().out.splitlines()[-1])
    summary = json.loads((sweeps / "sde" / "0" / "summary.json").read_text())
    best = max(range(2), key=lambda r: summary["best_check_return"][r])
    assert found["run"] == best and found["best_update"] == summary["best_update"][best]
    assert out.read_bytes()[:6] == b"GIF89a"
