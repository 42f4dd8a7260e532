"""The README is a front door that stays true: short, its examples and quick start run as written,
its links reach their pages (its results table, written from the study's committed results, is
checked in ``tests/study/test_readme_results.py``)."""

from __future__ import annotations

import os
import re
import shlex
import subprocess
import sys
from pathlib import Path

import pytest

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
