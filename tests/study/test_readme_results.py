"""The README's results table, and the results page's, are what ``docs/readme_results.py`` writes
from the committed result files: one measure a cell, a legend under it, at most the headline rows
in the README, no hand-typed result table outside the generated block."""

from __future__ import annotations

import re

from _helpers import REPO

from docs import readme_results

README = REPO / "README.md"


def test_readme_results_are_what_the_script_writes_from_the_committed_results():
    text = README.read_text()
    assert readme_results.replaced(text) == text, "README's results table differs: run python docs/readme_results.py"
    page = readme_results.RESULTS_PAGE.read_text()
    assert readme_results.replaced(page, readme_results.summary()) == page, \
        "the results page's table differs: run python docs/readme_results.py"


def test_the_readme_shows_at_most_eight_headline_results_and_the_page_has_them_all():
    def rows(text: str) -> list[str]:
        block = text[text.index(readme_results.START):text.index(readme_results.END)]
        return [line for line in block.splitlines() if line.startswith("| [")]

    headline, everything = rows(README.read_text()), rows(readme_results.RESULTS_PAGE.read_text())
    assert 0 < len(headline) <= readme_results.HEADLINE_ROWS
    assert len(everything) > len(headline)


def test_the_results_check_fails_on_a_changed_figure(monkeypatch, tmp_path):
    text = README.read_text()
    block = text[text.index(readme_results.START):text.index(readme_results.END)]
    changed = text.replace(block, block.replace("%", " %", 1))
    fake = tmp_path / "README.md"
    fake.write_text(changed)
    monkeypatch.setattr(readme_results, "README", fake)
    assert readme_results.main(["--check"]) == 1


def _packed_cells(block: str) -> list[str]:
    """The cells of the results table's rows that hold more than one measure: two intervals, a value
    and its interval, a list, a range or a spread."""
    rows = [line for line in block.splitlines() if line.startswith("| ") and "---" not in line][1:]
    cells = [cell.strip() for row in rows for cell in row.strip("|").split(" | ")]
    unlinked = {cell: re.sub(r"\[[^]]*\]\([^)]*\)", "", cell) for cell in cells}  # a link's text is no interval
    return [cell for cell, text in unlinked.items() if text.count("[") > 1 or re.search(r"\d.*\[|;| / |±| to \d", text)]


def test_each_cell_of_the_results_table_holds_one_measure_and_a_legend_follows():
    text = README.read_text()
    block = text[text.index(readme_results.START):text.index(readme_results.END)]
    assert not _packed_cells(block), _packed_cells(block)
    header = block.splitlines()[1]
    assert header == "| " + " | ".join(readme_results.HEADER) + " |"
    legend = block.split("\n\n", 1)[1].strip()
    assert legend == readme_results.LEGEND and "\n" not in legend, "no one-line legend under the results table"
    for column in ("methods", "first", "second", "paper", "interval"):
        assert column in legend, f"the legend does not say what {column!r} is"
    for packed in ("SDE 24 % [14, 37], REX 2 % [0, 10]", "24 % [14, 37]", "2256 ± 167 (5)", "4.7× to 20.4×"):
        assert _packed_cells(f"| a | b |\n| [x](p.md) | {packed} |\n") == [packed], packed
    assert _packed_cells("| a | b | c |\n| [Fig. 5](p.md) | 24 % | [14, 37] |\n") == []


def test_no_hand_typed_result_table_outside_the_generated_block():
    text = README.read_text()
    outside = text[:text.index(readme_results.START)] + text[text.index(readme_results.END):]
    assert not re.search(r"^\|.*\d+ %", outside, re.M), "a table of results outside <!-- results:start/end -->"
