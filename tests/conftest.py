"""Launcher tests (``@pytest.mark.launchers``) need the Ray and submitit launchers, which
``pip install -e ".[dev]"`` installs: without them they are skipped with the install command."""

from __future__ import annotations

import importlib.util

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
