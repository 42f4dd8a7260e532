"""Launcher tests (``@pytest.mark.launchers``) need the Ray and submitit launchers, which
``pip install -e ".[dev]"`` installs: without them they are skipped with the install command.

``addopts`` runs the tests on pytest-xdist workers, one per core (``-n auto --dist loadgroup``); a
run given only files or test ids (``python -m pytest tests/test_sde.py``) runs in this process
instead, without the workers' start-up (several seconds each imports torch)."""

from __future__ import annotations

import importlib.util
import os
from pathlib import Path

import pytest

LAUNCHER_MODULES = ("hydra_plugins.hydra_ray_launcher", "hydra_plugins.hydra_submitit_launcher", "ray")


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
