"""The result pages under docs/ are what their scripts write from the committed run outputs:
regenerated here, they must come out the same (numbers are never copied by hand).

Same means what a page shows, on any machine: its ``.md`` as text (it prints rounded numbers), its
JSON parsed, every number to :data:`REL_TOL` (the writer rounds floats to
:data:`analysis.figures.PAGE_DIGITS` significant digits; a simulated float's last bits differ
between machines and can move the last digit kept) and everything else exactly.

Every generated page and JSON whose runs are committed is here; Table 1's page is checked against
the committed ``table1.json`` its script writes from the runs (30 runs per job, no run directory
committed); the cup arm's (``docs/study/ballcatch/cup/``, an older format, no runs committed) is not.
"""

from __future__ import annotations

import doctest
import json
import math
import shutil
from typing import Any

import pytest
from _helpers import REPO

from analysis import figures
from analysis.benchmarks.gsde_table import cli as gsde_table
from analysis.paper import (
    ballcatch_checked,
    ballcatch_controllers,
    ballcatch_finger_probe,
    ballcatch_reevaluation,
    fig5,
    fig6,
    table1,
)
from analysis.selection import ballcatch_tuning, learner_search

BALLCATCH = REPO / "docs" / "study" / "ballcatch"
RECORDS = REPO / "results" / "ballcatch"  # the committed run records the pages are written from
#: A number on a page's JSON matches within one unit of the last significant digit written...
REL_TOL = 10.0 ** (1 - figures.PAGE_DIGITS)
#: ...or, for a value that is zero but for rounding, to this (no page shows a digit near it).
ABS_TOL = 1e-12


def differences(written: Any, committed: Any, where: str = "") -> list[str]:
    """Where two parsed JSON values differ: numbers (not booleans) beyond :data:`REL_TOL` (NaN
    matches NaN), anything else not exactly equal (keys, strings, ``None``, booleans, lengths, and
    an integer against a float); ``[]`` when they are the same."""
    if isinstance(written, dict) and isinstance(committed, dict):
        found = [f"{where}/{key}: {'missing' if key in committed else 'not committed'}"
                 for key in written.keys() ^ committed.keys()]
        return found + [d for key in written.keys() & committed.keys()
                        for d in differences(written[key], committed[key], f"{where}/{key}")]
    if isinstance(written, list) and isinstance(committed, list):
        if len(written) != len(committed):
            return [f"{where}: {len(written)} items written, {len(committed)} committed"]
        return [d for i, (a, b) in enumerate(zip(written, committed, strict=True))
                for d in differences(a, b, f"{where}[{i}]")]
    if type(written) is type(committed) is float:
        same = (math.isnan(written) and math.isnan(committed)) or \
            math.isclose(written, committed, rel_tol=REL_TOL, abs_tol=ABS_TOL)
    else:
        same = type(written) is type(committed) and written == committed
    return [] if same else [f"{where or '/'}: {written!r} written, {committed!r} committed"]


def sde_against_rex(script, name: str) -> tuple:
    """The page ``script`` (fig5 or fig6) writes into ``docs/study/ballcatch/<name>`` from the sweep pair
    ``runs/<name>/{sde,rex}``."""
    page = script.__name__.rsplit(".", 1)[-1]
    return (script, [str(RECORDS / "runs" / name / explorer) for explorer in ("sde", "rex")], BALLCATCH / name,
            (f"{page}.md", f"{page}.json"))


PAGES = {  # page → (script, its arguments before --out, the folder the page is in, the files it writes)
    "fig5": (fig5, [str(RECORDS / "runs" / "fig5")], BALLCATCH, ("fig5.md", "fig5.json")),
    "fig6": (fig6, [str(RECORDS / "runs" / "fig6")], BALLCATCH, ("fig6.md", "fig6.json")),
    "methods": (fig5, [str(RECORDS / "runs" / "fig5"), str(RECORDS / "runs" / "methods"), "--estimator", "all"],
                BALLCATCH, ("methods.md", "methods.json")),
    "fig5_selected": sde_against_rex(fig5, "fig5_selected"),
    "fig5_seed3": sde_against_rex(fig5, "fig5_seed3"),
    "fig6_selected": sde_against_rex(fig6, "fig6_selected"),
    "fig6_seed3": (fig6, [str(RECORDS / "runs" / "fig6_seed3" / "sde"),
                          str(RECORDS / "runs" / "fig6_selected" / "rex")],
                   BALLCATCH / "fig6_seed3", ("fig6.md", "fig6.json")),
    "fig6_seed6": (fig6, [str(RECORDS / "runs" / "fig6_seed6" / "sde"),
                          str(RECORDS / "runs" / "fig6_selected" / "rex")],
                   BALLCATCH / "fig6_seed6", ("fig6.md", "fig6.json")),
    "methods_selected": (fig5, [*(str(RECORDS / "runs" / folder) for folder in
                                    ("fig5_selected/sde", "fig5_selected/rex", "methods_selected/gpomdp",
                                     "methods_selected/pgpe")),
                                  "--estimator", "all"],
                         BALLCATCH / "methods_selected", ("methods.md", "methods.json")),
    "methods_seed3": (fig5, [str(RECORDS / "runs" / "fig5_seed3" / "sde"),
                             str(RECORDS / "runs" / "methods_seed3" / "gpomdp"), "--estimator", "all"],
                      BALLCATCH / "methods_seed3", ("methods.md", "methods.json")),
    "methods_seed6": (fig5, [str(RECORDS / "runs" / "fig5_seed3" / "sde"),
                             str(RECORDS / "runs" / "methods_seed6" / "gpomdp"), "--estimator", "all"],
                      BALLCATCH / "methods_seed6", ("methods.md", "methods.json")),
    "methods_seed4": (fig5, [str(RECORDS / "runs" / "fig5_seed3" / "sde"),
                             str(RECORDS / "runs" / "methods_seed4" / "pgpe"), "--estimator", "all"],
                      BALLCATCH / "methods_seed4", ("methods.md", "methods.json")),
    "score_probe": (fig5, [*(str(RECORDS / "runs" / "score_probe" / m) for m in ("sde", "pgpe")), "--estimator",
                             "all"], BALLCATCH / "score_probe", ("methods.md", "methods.json")),
    "held_training": sde_against_rex(fig5, "held_training"),
    "strong_fingers": sde_against_rex(fig5, "strong_fingers"),
    "checked": (ballcatch_checked, [str(RECORDS / "runs" / "checked" / explorer) for explorer in ("sde", "rex")],
                BALLCATCH / "checked", ("checked.md", "checked.json")),
    "selected/fig5": (fig5, [str(RECORDS / "runs" / "selected" / "heldout_4242")], BALLCATCH / "selected",
                      ("fig5.md", "fig5.json")),
    "controllers": (ballcatch_controllers, [f"{label}={RECORDS / 'runs' / path}" for label, path in (
        ("REINFORCE + SDE, Fig. 5", "fig5_seed3/sde"), ("REINFORCE + REX, Fig. 5", "fig5_seed3/rex"),
        ("ENAC + SDE, Fig. 6, earlier learner", "fig6_seed3/sde"), ("ENAC + SDE, Fig. 6", "fig6_seed6/sde"))],
        BALLCATCH, ("controllers.md", "controllers.json")),
    # each job's finger_probe.json is its record (the simulation is not run again)
    "finger_probe": (ballcatch_finger_probe, [str(RECORDS / "runs" / "fig5_seed3" / "sde")], BALLCATCH,
                     ("finger_probe.md", "finger_probe.json")),
    "tuning": (ballcatch_tuning, ["report", str(RECORDS / "tuning")], BALLCATCH, ("tuning.md", "tuning.json")),
    "ppo": (gsde_table, ["report", str(REPO / "results" / "ppo" / "f025")], REPO / "docs" / "ppo",
            ("gsde_table.md", "gsde_table.json")),
    "sac": (gsde_table, ["report", str(REPO / "results" / "sac" / "mountaincar")], REPO / "docs" / "sac",
            ("gsde_table.md", "gsde_table.json")),
    "gsde_table": (gsde_table, ["report", str(REPO / "results" / "gsde_table" / "f002")], REPO / "docs" / "gsde_table",
                   ("gsde_table.md", "gsde_table.json")),
    # every candidate is recorded: --resume runs none of them and rewrites the page from the record
    "learner_search": (learner_search, ["--resume", "--workers", "1"], REPO / "docs" / "table1",
                       ("learner_search.md", "learner_search.json")),
    # from each job's re-evaluations in both arms (the simulation is not run again)
    "reevaluation": (ballcatch_reevaluation, [str(RECORDS / "runs" / "fig5_selected")], BALLCATCH,
                     ("reevaluation.md", "reevaluation.json")),
}


@pytest.mark.parametrize("page", list(PAGES))
def test_a_result_page_is_what_its_script_writes_from_the_committed_runs(tmp_path, page):
    script, arguments, folder, files = PAGES[page]
    if script is learner_search:  # its runs are its record
        shutil.copy(folder / "learner_search.json", tmp_path)
    assert script.main([*arguments, "--out", str(tmp_path)]) == 0
    for name in files:
        written, committed = (tmp_path / name).read_text(), (folder / name).read_text()
        if name.endswith(".md"):
            assert written == committed, f"{folder / name} differs from its script's"
            continue
        found = differences(json.loads(written), json.loads(committed))
        assert not found, f"{folder / name} differs from its script's: " + "; ".join(found[:5])
        assert json.dumps(figures.rounded(json.loads(committed))) == json.dumps(json.loads(committed)), \
            f"{folder / name}: floats beyond {figures.PAGE_DIGITS} significant digits: rewrite it with its script"


def test_two_page_jsons_differ_beyond_a_digit_moved_by_the_last_bits():
    """The comparison lets through what two machines' last bits can do to a rounded number, and
    nothing more: a number beyond the tolerance, a key, a string, a count or a type that changed."""
    page = {"closing": {"level": -0.0908582, "runs": 3, "label": "catch", "ok": True, "low": None},
            "returns": [-1.02345, 0.0, float("nan")]}
    assert differences(page, json.loads(json.dumps(page))) == []
    assert differences(-0.09085822555217142, -0.0908582255521714) == []  # the fresh clone's failure
    assert differences({"x": -0.0908582}, {"x": -0.0908583}) == []  # one unit in the sixth digit
    assert differences({"x": 1e-17}, {"x": 0.0}) == []
    changed = {"closing": {"level": -0.0908592, "runs": 3, "label": "catch", "ok": True, "low": None},
               "returns": [-1.02345, 0.0, float("nan")]}
    assert differences(changed, page) == ["/closing/level: -0.0908592 written, -0.0908582 committed"]
    for i, other in enumerate((-1.0235, 1e-9, 0.5)):  # 5e-5 relative; 1e-9 against zero; a number against NaN
        returns = [*page["returns"]]
        returns[i] = other
        assert [d.split(":")[0] for d in differences({**page, "returns": returns}, page)] == [f"/returns[{i}]"]
    for key, value in (("runs", 4), ("runs", 3.0), ("label", "good catch"), ("ok", 1), ("low", 0.0)):
        assert differences({**page, "closing": {**page["closing"], key: value}}, page) != [], (key, value)
    renamed = {"closing": page["closing"], "return": page["returns"]}
    assert sorted(differences(renamed, page)) == ["/return: not committed", "/returns: missing"]
    assert differences({**page, "returns": page["returns"][:2]}, page) == ["/returns: 2 items written, 3 committed"]


def test_the_page_json_writer_rounds_as_its_examples_say():
    result = doctest.testmod(figures, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.attempted > 0 and result.failed == 0


def test_table1_page_is_what_its_script_writes_from_the_committed_results(tmp_path):
    """Table 1's run directories are not committed (about 32 jobs of 30 runs); ``table1.json``, which
    ``table1.py`` writes from them, is their record: the page must be what the script's writer makes
    of it, so no figure on it is typed by hand."""
    results = json.loads((REPO / "docs" / "table1" / "table1.json").read_text())
    table1.write_markdown(results["rows"], results["mlp2d"], tmp_path / "table1.md", results.get("wall_s"))
    assert (tmp_path / "table1.md").read_text() == (REPO / "docs" / "table1" / "table1.md").read_text()
