"""Launcher tests (``@pytest.mark.launchers``) need the Ray and submitit launchers, which
``pip install -e ".[dev]"`` installs: without them they are skipped with the install command.

``addopts`` runs the tests on pytest-xdist workers, one per core (``-n auto --dist loadgroup``); a
run given only files or test ids (``python -m pytest tests/test_sde.py``) runs in this process
instead, without the workers' start-up (several seconds each imports torch).

The study's tests (``tests/study/``, marked ``study`` by their conftest) are left out by
``addopts``' ``-m``; a run whose ``-m`` can select none of them does not even collect (import)
that folder, so the library's loop imports nothing from ``analysis/`` or ``docs/``. A run given
only paths under ``tests/study/`` and no ``-m`` runs those tests (but the ``e2e`` and ``slow``
ones)."""

from __future__ import annotations

import importlib.util
import itertools
import os
import re
from pathlib import Path

import pytest

LAUNCHER_MODULES = ("hydra_plugins.hydra_ray_launcher", "hydra_plugins.hydra_submitit_launcher", "ray")
STUDY = Path(__file__).resolve().parent / "study"
#: The selection of a run given only study paths without ``-m``: addopts' less ``not study``.
STUDY_ONLY = "not slow and not e2e"


def _installed(module: str) -> bool:
    try:
        return importlib.util.find_spec(module) is not None
    except ModuleNotFoundError:  # the parent package is missing
        return False


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    missing = [m for m in LAUNCHER_MODULES if not _installed(m)]
    if not missing:
        return
    skip = pytest.mark.skip(reason=f"needs {', '.join(missing)}: pip install -e '.[dev]'")
    for item in items:
        if item.get_closest_marker("launchers"):
            item.add_marker(skip)


def pytest_xdist_auto_num_workers(config: pytest.Config) -> int | None:
    """``-n auto``: no workers for a run given only files or test ids; otherwise (the whole
    suite, a folder, ``-k``/``-m`` on the whole suite) xdist's own count, one worker per core,
    or ``PYTEST_XDIST_AUTO_NUM_WORKERS``. An explicit ``-n 2`` or ``-n 0`` wins over both."""
    if os.environ.get("PYTEST_XDIST_AUTO_NUM_WORKERS"):
        return None
    given = config.args if config.args_source == pytest.Config.ArgsSource.ARGS else []
    if given and all("::" in arg or not Path(config.invocation_params.dir, arg).is_dir() for arg in given):
        return 0
    return None


def _given_paths(config: pytest.Config) -> list[Path]:
    """The files or folders given on the command line (test ids without their ``::`` part)."""
    given = config.args if config.args_source == pytest.Config.ArgsSource.ARGS else []
    return [Path(config.invocation_params.dir, arg.split("::")[0]).resolve() for arg in given]


def pytest_configure(config: pytest.Config) -> None:
    """A run given only paths under ``tests/study/`` and no ``-m`` of its own runs those tests."""
    if hasattr(config, "workerinput"):  # an xdist worker: the controller's options, already settled
        return
    given = _given_paths(config)
    own_mark = any(arg.startswith("-m") or arg.startswith("--m") for arg in config.invocation_params.args
                   if isinstance(arg, str))
    if given and not own_mark and all(path == STUDY or STUDY in path.parents for path in given):
        config.option.markexpr = STUDY_ONLY


def _may_select_study(expression: str) -> bool:
    """Whether the ``-m`` expression selects a test marked ``study`` for some set of its other
    marks (an expression this cannot read counts as selecting one)."""
    if not expression.strip():
        return True
    tokens = re.findall(r"\(|\)|[^\s()]+", expression)
    names = sorted({token for token in tokens if token not in ("(", ")", "and", "or", "not")})
    if not all(name.isidentifier() for name in names):
        return True
    others = [name for name in names if name != "study"]
    for values in itertools.product((False, True), repeat=len(others)):
        marks = {**dict(zip(others, values, strict=True)), "study": True}
        try:
            if eval(" ".join(str(marks.get(t, t)) for t in tokens), {"__builtins__": {}}):  # noqa: S307
                return True
        except SyntaxError:
            return True
    return False


def pytest_ignore_collect(collection_path: Path, config: pytest.Config) -> bool | None:
    """``tests/study/`` is not collected by a run that would deselect all of it (the default run)."""
    if collection_path.resolve() == STUDY and not _may_select_study(config.option.markexpr or ""):
        return True
    return None
