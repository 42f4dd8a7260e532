"""REINFORCE + SDE's scores on the ball-catching controller are Θ̂ S (analysis/paper/ballcatch_scores.py)."""

from __future__ import annotations

import json

from _helpers import REPO

from analysis.paper import ballcatch_scores as scores


def test_the_scores_of_the_trainers_own_episodes_are_the_noise_times_the_state_moment():
    measured = scores.measure(3, seed=1)
    assert measured["identity_max_relative_error"] < 1e-4
    eigenvalues = measured["eigenvalues"]
    assert eigenvalues == sorted(eigenvalues) and eigenvalues[0] > 0
    assert measured["condition_all"] >= measured["condition_top_two"] >= 1.0
    assert measured["condition_after_scaling"] >= 1.0


def test_scores_page_is_what_its_script_writes_from_its_record(tmp_path):
    """``scores.json`` is the record of the measurement (100 episodes, about a minute); the page is
    what the script's writer makes of it, no number typed by hand."""
    folder = REPO / "docs" / "study" / "ballcatch"
    scores.write_markdown(json.loads((folder / "scores.json").read_text()), tmp_path / "scores.md")
    assert (tmp_path / "scores.md").read_bytes() == (folder / "scores.md").read_bytes()
