"""The fast tier (`pytest -m "not slow"`) leaves out exactly the tests conftest.SLOW_TESTS names;
a renamed or deleted test must leave the list too, or it would silently join the fast tier's
budget under another name."""
from __future__ import annotations

import ast

import pytest
from conftest import REPO, SLOW_TESTS, is_slow


@pytest.mark.parametrize("entry", SLOW_TESTS)
def test_every_slow_entry_names_a_test_that_exists(entry):
    module, _, func = entry.partition("::")
    path = REPO / module
    assert path.is_file(), entry
    names = {n.name for n in ast.walk(ast.parse(path.read_text())) if isinstance(n, ast.FunctionDef)}
    assert not func or func in names, entry


def test_is_slow_matches_modules_functions_and_parameters():
    entry = SLOW_TESTS[0]
    assert is_slow(entry) and is_slow(entry + "[a-1]")
    assert not is_slow(entry + "_other") and not is_slow("tests/test_no_such.py::test_x")
    assert len(set(SLOW_TESTS)) == len(SLOW_TESTS)
