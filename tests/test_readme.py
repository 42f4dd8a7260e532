"""The README is a front door that stays true: short, its examples and quick start run as written,
and its results table is what ``docs/readme_results.py`` writes from the committed result files."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

from docs import readme_results

README = Path(__file__).resolve().parents[1] / "README.md"
REPO = README.parent

# scripts run from a temporary folder import this checkout's package, not another installed copy
CHECKOUT_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}


def _example() -> str:
    text = README.read_text()
    block = re.search(r"<!-- example:start -->\s*```python\n(.*?)```\s*<!-- example:end -->", text, re.S)
    assert block, "README example markers not found"
    return block.group(1)


def test_readme_is_at_most_250_lines():
    assert len(README.read_text().splitlines()) <= 250


def test_readme_example_is_short():
    assert len(_example().strip().splitlines()) <= 25


def test_readme_example_runs(tmp_path):
    script = tmp_path / "example.py"
    script.write_text(_example())
    result = subprocess.run([sys.executable, str(script)], capture_output=True, text=True, timeout=300,
                            env=CHECKOUT_ENV)
    assert result.returncode == 0, result.stderr[-2000:]
    returns = [float(m) for m in re.findall(r"update \d: mean return (-?\d+\.\d+)", result.stdout)]
    assert len(returns) == 3 and all(-17 < r < 0 for r in returns), result.stdout


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


def _quick_start() -> list[str]:
    section = README.read_text().split("## Quick start", 1)[1].split("\n## ", 1)[0]
    block = re.search(r"```bash\n(.*?)```", section, re.S)
    assert block, "no bash block in the README's quick start"
    return block.group(1).strip().splitlines()


def test_quick_start_is_two_commands_the_training_one_and_the_tests():
    commands = _quick_start()
    assert len(commands) == 2
    assert commands[0].endswith("python train.py +experiment=ballcatch") and "pip install -e \".[dev]\"" in commands[0]
    assert commands[1].endswith("python -m pytest")


@pytest.mark.e2e
def test_quick_start_training_command_runs(tmp_path):
    """The quick start's training command as written, cut to 2 updates of one run (the full job is minutes)."""
    command = shlex.split(_quick_start()[0].split("&&")[-1])
    assert command[:2] == ["python", "train.py"]
    short = ["runs=1", "updates=2", "episode_queue=2", "eval_period=1", "final_episodes=2",
             f"hydra.run.dir={tmp_path / 'run'}"]
    result = subprocess.run([sys.executable, *command[1:], *short], cwd=REPO, capture_output=True, text=True,
                            timeout=600)
    assert result.returncode == 0, result.stderr[-2000:]
    assert (tmp_path / "run" / "summary.json").exists() and (tmp_path / "run" / "best_policy.pt").exists()
    assert "of 1 run, on 2 fresh balls each: the best policy catches in" in result.stdout + result.stderr


def _github_anchor(heading: str) -> str:
    """The anchor GitHub gives a Markdown heading: lower case, punctuation dropped, spaces as hyphens."""
    return re.sub(r"[^\w\- ]", "", heading.strip().lower()).replace(" ", "-")


def test_every_relative_link_of_the_readme_reaches_its_file_and_heading():
    """A reader following a link from the front door lands on the file, and on the heading it names."""
    broken = []
    for target in re.findall(r"\]\(([^)#:]+\.md|[^):]+\.md#[^)]+)\)", README.read_text()):
        path, _, anchor = target.partition("#")
        page = REPO / path
        if not page.is_file():
            broken.append(target)
        elif anchor:
            headings = re.findall(r"^#+ (.+)$", page.read_text(), re.M)
            if anchor not in {_github_anchor(h) for h in headings}:
                broken.append(target)
    assert not broken, f"links from README.md that reach no file or heading: {broken}"
