"""Pages, the README and the code's docstrings and comments are written for users: none of them
names an entry of the project's tracker ("issue 22", "(#41)"); they say what the thing is instead.

Run records (``docs/*/runs/``, the job folders under ``results/ballcatch/tuning/``, logs and JSON) and
``CHANGELOG.md`` are left as they were committed and are not scanned.
"""

from __future__ import annotations

import re
from pathlib import Path

from _helpers import REPO

#: "issue 22", "Issues #3", "issue-7", "gh-12", "PR #5", "pull request 9", and a bare "#41" that is
#: not part of a word, a Markdown heading or a colour ("#000000" has more digits than a tracker's).
TRACKER_REFERENCE = re.compile(
    r"\bissues?[ -]?#?\d+\b|\bgh-\d+\b|\bPR ?#\d+\b|\bpull requests? #?\d+\b|(?<![\w&/#])#\d{1,4}\b(?![\w-])",
    re.IGNORECASE,
)

#: Files that name a tracker entry but are being edited elsewhere right now; their owner rewrites
#: them and empties this set. Every other file must have no tracker reference.
BEING_EDITED_ELSEWHERE: frozenset[str] = frozenset()


def scanned_files(root: Path = REPO) -> list[Path]:
    """The pages (``docs/**/*.md``; run records live under ``results/``), ``README.md``, the Python of ``sde_torchrl/``,
    ``analysis/``, ``train.py`` and the YAML of ``conf/`` and ``analysis/conf/``."""
    files = [path for path in sorted((root / "docs").rglob("*.md")) if "_build" not in path.parts]
    files.append(root / "README.md")
    for package in ("sde_torchrl", "analysis"):
        files += [path for path in sorted((root / package).rglob("*.py")) if "runs" not in path.parts]
    files.append(root / "train.py")
    files += sorted((root / "conf").rglob("*.yaml")) + sorted((root / "analysis" / "conf").rglob("*.yaml"))
    return files


def tracker_references(root: Path = REPO) -> list[str]:
    """``file:line: text`` for every tracker reference in :func:`scanned_files` outside the allow-list."""
    found = []
    for path in scanned_files(root):
        relative = path.relative_to(root).as_posix()
        if relative in BEING_EDITED_ELSEWHERE:
            continue
        for number, line in enumerate(path.read_text(encoding="utf-8").splitlines(), start=1):
            if TRACKER_REFERENCE.search(line):
                found.append(f"{relative}:{number}: {line.strip()}")
    return found


def test_the_pattern_finds_tracker_references_and_nothing_else():
    for line in ("(issue 22)", "Issue 38 item 8:", "issues #3 and 4", "see #41", "gh-12", "PR #5"):
        assert TRACKER_REFERENCE.search(line), line
    for line in ("# 1. Plan", "## 2. Results", "color='#000000'", "C#1x", "an issue with seeds",
                 "round 2", "&#8212;", "item 3"):
        assert not TRACKER_REFERENCE.search(line), line


def test_no_page_or_docstring_names_a_tracker_issue():
    found = tracker_references()
    assert not found, "say what the thing is instead of naming a tracker issue:\n" + "\n".join(found)


def test_the_allow_list_names_only_files_that_still_need_it():
    """An allow-listed file that no longer names a tracker issue leaves the list."""
    for relative in BEING_EDITED_ELSEWHERE:
        text = (REPO / relative).read_text(encoding="utf-8")
        assert TRACKER_REFERENCE.search(text), f"{relative} is clean: take it off BEING_EDITED_ELSEWHERE"
