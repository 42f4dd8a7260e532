"""Every docstring example in the package runs as written (Google-style ``Examples:`` blocks).

Each module's examples start from one seed, so their random inputs do not depend on which tests
ran before them in the same worker; what they print must still hold for any seed.
"""

from __future__ import annotations

import doctest
import importlib
import pkgutil

import pytest
import torch

import sde_torchrl

MODULES = sorted(name for _, name, _ in pkgutil.walk_packages(sde_torchrl.__path__, "sde_torchrl.")
                 if not name.endswith("__main__"))


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples_run(name):
    module = importlib.import_module(name)
    torch.manual_seed(0)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
