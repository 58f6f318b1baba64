"""The examples in the packages' docstrings, run as doctests under the names users import them by
(armd.robots, ...): collected by path, they would be imported a second time under other names."""

from __future__ import annotations

import doctest
import importlib

import pytest

MODULES = ["armd.robots", "armd.robots.angles", "armd.solvers", "armd.planning", "armd.clients.client", "armd.errors"]


@pytest.mark.parametrize("name", MODULES)
def test_docstring_examples(name: str) -> None:
    module = importlib.import_module(name)
    result = doctest.testmod(module, optionflags=doctest.ELLIPSIS | doctest.NORMALIZE_WHITESPACE)
    assert result.failed == 0, f"{result.failed} of {result.attempted} examples failed in {name}"
