"""The result pages under docs/ are what their scripts write from the committed run outputs:
regenerated here, they must come out identical (numbers are never copied by hand).

Every generated page and JSON whose runs are committed is here; Table 1's page is checked against
the committed ``table1.json`` its script writes from the runs (30 runs per job, no run directory
committed); the cup arm's (``docs/ballcatch/cup/``, an older format, no runs committed) is not.
"""

from __future__ import annotations

import json
import shutil

import pytest
from _helpers import REPO

from analysis.benchmarks.gsde_table import cli as gsde_table
from analysis.paper import ballcatch_controllers, ballcatch_finger_probe, fig5, fig6, table1
from analysis.selection import ballcatch_tuning, learner_search

BALLCATCH = REPO / "docs" / "ballcatch"
RECORDS = REPO / "results" / "ballcatch"  # the committed run records the pages are written from


def sde_against_rex(script, name: str) -> tuple:
    """The page ``script`` (fig5 or fig6) writes into ``docs/ballcatch/<name>`` from the sweep pair
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
}


@pytest.mark.parametrize("page", list(PAGES))
def test_a_result_page_is_what_its_script_writes_from_the_committed_runs(tmp_path, page):
    script, arguments, folder, files = PAGES[page]
    if script is learner_search:  # its runs are its record
        shutil.copy(folder / "learner_search.json", tmp_path)
    assert script.main([*arguments, "--out", str(tmp_path)]) == 0
    for name in files:
        written = (tmp_path / name).read_bytes()
        assert written == (folder / name).read_bytes(), f"{folder / name} differs from its script's"


def test_table1_page_is_what_its_script_writes_from_the_committed_results(tmp_path):
    """Table 1's run directories are not committed (about 32 jobs of 30 runs); ``table1.json``, which
    ``table1.py`` writes from them, is their record: the page must be what the script's writer makes
    of it, so no figure on it is typed by hand."""
    results = json.loads((REPO / "docs" / "table1" / "table1.json").read_text())
    table1.write_markdown(results["rows"], results["mlp2d"], tmp_path / "table1.md", results.get("wall_s"))
    assert (tmp_path / "table1.md").read_bytes() == (REPO / "docs" / "table1" / "table1.md").read_bytes()
