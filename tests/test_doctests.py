"""Every docstring example in the package runs as written (Google-style ``Examples:`` blocks)."""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest

import sde_torchrl

MODULES = sorted(name for _, name, _ in pkgutil.walk_packages(sde_torchrl.__path__, "sde_torchrl.")
                 if not name.endswith("__main__"))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
