"""The result pages under docs/ are what their scripts write from the committed run outputs:
regenerated here, they must come out identical (numbers are never copied by hand)."""

from __future__ import annotations

import pytest
from _helpers import REPO, load_script

BALLCATCH = REPO / "docs" / "ballcatch"
PAGES = {  # page stem → (script, its arguments before --out, the folder the page is in)
    "fig5": ("fig5", [str(BALLCATCH / "runs" / "fig5")], BALLCATCH),
    "fig6": ("fig5", [str(BALLCATCH / "runs" / "fig6"), "--estimator", "enac"], BALLCATCH),
    "methods": ("fig5", [str(BALLCATCH / "runs" / "fig5"), str(BALLCATCH / "runs" / "methods"), "--estimator", "all"],
                BALLCATCH),
    "selected/fig5": ("fig5", [str(BALLCATCH / "runs" / "selected" / "heldout_4242")], BALLCATCH / "selected"),
    "tuning": ("ballcatch_tuning", ["report", str(BALLCATCH / "tuning")], BALLCATCH),
}


@pytest.mark.parametrize("page", list(PAGES))
def test_a_result_page_is_what_its_script_writes_from_the_committed_runs(tmp_path, page):
    script, arguments, folder = PAGES[page]
    assert load_script(script).main([*arguments, "--out", str(tmp_path)]) == 0
    stem = page.rsplit("/", 1)[-1]
    for suffix in (".md", ".json"):
        written = (tmp_path / f"{stem}{suffix}").read_text()
        assert written == (folder / f"{stem}{suffix}").read_text(), f"{folder / stem}{suffix} differs from its script's"
