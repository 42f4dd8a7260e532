"""The study's tests: the reproduction of the paper with the library (``analysis/``, the committed
runs under ``results/``, the pages the scripts write under ``docs/``, the benchmarks, the README's
results table). Every test in this folder is marked ``study``: the library's fast loop
(``python -m pytest``) leaves them out; ``python -m pytest -m study tests/study`` runs them (those
also marked ``e2e`` or ``slow`` run with ``-m e2e`` or ``-m slow``, as everywhere)."""

from __future__ import annotations

from pathlib import Path

import pytest

STUDY = Path(__file__).resolve().parent


@pytest.hookimpl(tryfirst=True)  # before ``-m`` deselects by mark
def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    for item in items:
        if STUDY in Path(item.path).resolve().parents:
            item.add_marker(pytest.mark.study)
