"""The documentation site is checked like code.

- The site builds with Sphinx, warnings as errors (the command of the README and .ci/run), and
  every name of ``sde_torchrl.__all__`` has its entry on the API page, with a docstring. The
  build is an ``e2e`` test; ``.ci/run``, which has just built the site with that command, gives
  it to the test in ``SDE_TORCHRL_BUILT_SITE`` so that it is built once.
- The ``python`` blocks of each page under ``docs/guide``, ``docs/reproduce`` and ``docs/study/chosen`` run as
  written, in order, one process per page; a ``text`` block right after a ``python`` block is that block's
  expected output, compared exactly.
- The ``console`` blocks' ``$ python -m sde_torchrl...`` commands print what the page shows.
"""

from __future__ import annotations

import inspect
import os
import re
import shlex
import subprocess
import sys
import time
from pathlib import Path

import pytest

import sde_torchrl

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs"
PAGES = sorted([*DOCS.glob("guide/*.md"), *DOCS.glob("reproduce/*.md"), *DOCS.glob("study/chosen/*.md")])
BUILD = [sys.executable, "-m", "sphinx", "-W", "--keep-going", "-b", "html", "-q", "docs"]
# blocks run from a temporary folder import this checkout's package, not another installed copy
CHECKOUT_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(REPO), os.environ.get("PYTHONPATH")]))}
FENCE = re.compile(r"^```(\w*)[^\n]*\n(.*?)^```\s*$", re.S | re.M)


#: A site the README's command has just built (``.ci/run`` sets it to ``docs/_build/html``): checked as it is,
#: not built a second time. Unset, the fixture builds the site itself, warnings as errors.
BUILT_SITE = "SDE_TORCHRL_BUILT_SITE"


def _pages_and_conf() -> list[Path]:
    """Files every build reads (the guide, reproduction and selection pages, the front page, the configuration):
    one changed since a build leaves the site older than it."""
    return [*PAGES, *DOCS.glob("*.md"), DOCS / "conf.py"]


@pytest.fixture(scope="module")
def site(tmp_path_factory) -> Path:
    if os.environ.get(BUILT_SITE):
        out = Path(os.environ[BUILT_SITE])
        assert (out / "index.html").is_file() and (out / "api" / "index.html").is_file(), \
            f"{BUILT_SITE}={out} holds no built site: build it with the README's command first"
        built = max(p.stat().st_mtime for p in out.rglob("*") if p.is_file())
        newer = [str(p.relative_to(REPO)) for p in _pages_and_conf() if p.stat().st_mtime > built]
        assert not newer, f"the site at {out} is older than {newer[:5]}: build it again with the README's command"
        return out
    out = tmp_path_factory.mktemp("site")
    start = time.perf_counter()
    result = subprocess.run([*BUILD, str(out), "-d", str(out / ".doctrees")], cwd=REPO, capture_output=True,
                            text=True, timeout=600)
    assert result.returncode == 0, f"the docs do not build without warnings:\n{result.stderr[-4000:]}"
    print(f"site built in {time.perf_counter() - start:.0f} s")
    return out


def test_the_readme_and_ci_build_the_site_with_this_command():
    command = "python -m sphinx -W --keep-going -b html docs docs/_build/html"
    assert command in (REPO / "README.md").read_text()
    assert command in (REPO / ".ci" / "run").read_text()


def test_ci_gives_the_site_it_built_to_the_tests():
    """.ci/run builds the site once, warnings as errors, and the site checks below read that build."""
    ci = (REPO / ".ci" / "run").read_text()
    assert f'{BUILT_SITE}="$repo/docs/_build/html"' in ci and "-m 'e2e and not slow'" in ci


@pytest.mark.e2e  # it builds the site (or checks the one .ci/run built: SDE_TORCHRL_BUILT_SITE)
def test_every_public_name_has_an_api_entry(site):
    page = (site / "api" / "index.html").read_text()
    missing = [name for name in sde_torchrl.__all__ if f'id="sde_torchrl.{name}"' not in page]
    assert not missing, f"names of sde_torchrl.__all__ without an entry on the API page: {missing}"


def test_every_public_name_has_a_docstring():
    bare = [name for name in sde_torchrl.__all__ if not inspect.getdoc(getattr(sde_torchrl, name))]
    assert not bare, f"public names without a docstring (their API entry would be empty): {bare}"


def test_the_api_page_is_generated_from_all_not_typed():
    """The page's source holds the placeholder line the site's extension (``docs/_ext/public_api.py``)
    replaces with an entry for each name of ``__all__``, and no entry typed by hand; the entries
    themselves are checked on the built page (above)."""
    source = (DOCS / "api" / "index.md").read_text()
    assert "\n<!-- public-api -->\n" in source
    assert "<!-- public-api -->" in (DOCS / "_ext" / "public_api.py").read_text()
    assert not [name for name in sde_torchrl.__all__ if f"sde_torchrl.{name}" in source]


def blocks(page: Path) -> list[tuple[str, str, int, int]]:
    """``(language, text, start, end)`` of every fenced block of ``page``, in order."""
    return [(m.group(1), m.group(2), m.start(), m.end()) for m in FENCE.finditer(page.read_text())]


def python_blocks(page: Path) -> list[tuple[str, str | None]]:
    """The page's ``python`` blocks, each with the ``text`` block that directly follows it, if any."""
    source, items, found = page.read_text(), blocks(page), []
    for i, (language, text, _, end) in enumerate(items):
        if language == "python":
            after = items[i + 1] if i + 1 < len(items) else None
            adjacent = after is not None and after[0] == "text" and not source[end:after[2]].strip()
            found.append((text, after[1] if adjacent else None))
    return found


RUNNER = """
import contextlib, io, json, sys
blocks = json.loads(sys.stdin.read())
namespace = {"__name__": "__main__"}
outputs = []
for number, code in enumerate(blocks):
    buffer = io.StringIO()
    with contextlib.redirect_stdout(buffer):
        exec(compile(code, f"<block {number + 1}>", "exec"), namespace)
    outputs.append(buffer.getvalue())
print(json.dumps(outputs))
"""


@pytest.mark.parametrize("page", [p for p in PAGES if python_blocks(p)], ids=lambda p: p.relative_to(DOCS).as_posix())
def test_the_python_blocks_of_a_page_run_as_written(page, tmp_path):
    import json

    found = python_blocks(page)
    result = subprocess.run([sys.executable, "-c", RUNNER], input=json.dumps([code for code, _ in found]),
                            capture_output=True, text=True, cwd=tmp_path, timeout=600, env=CHECKOUT_ENV)
    assert result.returncode == 0, f"{page.name}: a python block failed:\n{result.stderr[-3000:]}"
    outputs = json.loads(result.stdout.strip().splitlines()[-1])
    for (code, expected), output in zip(found, outputs, strict=True):
        if expected is not None:
            assert output == expected, f"{page.name}: the block\n{code}\nprints\n{output}\nnot the page's\n{expected}"


def console_commands(page: Path) -> list[tuple[str, str]]:
    """``(command, the output the page shows)`` of each ``$ python -m sde_torchrl`` line of a console block."""
    found = []
    for language, text, _, _ in blocks(page):
        if language != "console":
            continue
        for command, output in re.findall(r"^\$ (python -m sde_torchrl[^\n]*)\n((?:(?!\$ )[^\n]*\n)*)", text, re.M):
            found.append((command, output))
    return found


CONSOLE = [(page, command, output) for page in PAGES for command, output in console_commands(page)]


@pytest.mark.parametrize(("page", "command", "output"), CONSOLE, ids=[c for _, c, _ in CONSOLE])
@pytest.mark.e2e
def test_a_console_command_of_the_docs_prints_what_the_page_shows(page, command, output, tmp_path):
    assert "--video" not in command, "a checked command must not write into the repository"
    argv = shlex.split(command)
    result = subprocess.run([sys.executable, *argv[1:]], capture_output=True, text=True, cwd=tmp_path, timeout=600,
                            env=CHECKOUT_ENV)
    assert result.returncode == 0, result.stderr[-2000:]
    assert result.stdout == output, f"{page.name}: `{command}` prints\n{result.stdout}\nnot\n{output}"


def test_the_docs_pages_have_examples_to_check():
    assert CONSOLE, "no console command found: the extraction is broken"
    assert sum(len(python_blocks(page)) for page in PAGES) >= 3, "python blocks not found: the extraction is broken"
    assert any(expected for page in PAGES for _, expected in python_blocks(page)), "no expected output found"
