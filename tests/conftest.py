"""Launcher tests (``@pytest.mark.launchers``) need extras and a cluster: they are skipped unless
their file is named on the command line or ``-m`` selects them."""

from __future__ import annotations

import pytest


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    if "launchers" in (config.option.markexpr or "") or any("test_launchers" in a for a in config.args):
        return
    skip = pytest.mark.skip(reason="distributed launchers: run `python -m pytest tests/test_launchers.py`")
    for item in items:
        if item.get_closest_marker("launchers"):
            item.add_marker(skip)
