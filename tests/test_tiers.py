"""The fast tier (`pytest -m "not slow"`) leaves out exactly the tests conftest.SLOW_TESTS names;
a renamed or deleted test must leave the list too, or it would silently join the fast tier's
budget under another name. Every skip in tests/ says how to get what it misses."""
from __future__ import annotations

import ast
import re

import pytest
import conftest
from conftest import REPO, SHARED_MAPS_MISSING, SKIP_REASONS, SLOW_TESTS, is_slow

# a remedy: the setup command that installs what is missing, or the variable that turns the test on
REMEDY = re.compile(r"bash (scripts|adapters/\w+)/\w+\.sh|FEAT2MAP_[A-Z_]+=")


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


def _skip_reasons(tree: ast.AST) -> list[tuple[int, ast.expr | None]]:
    """(line, reason expression) of every pytest.skip(...), pytest.importorskip(...),
    pytest.mark.skip(...) and pytest.mark.skipif(...) call in `tree` (None: no reason given)."""
    out: list[tuple[int, ast.expr | None]] = []
    for node in ast.walk(tree):
        if not (isinstance(node, ast.Call) and isinstance(node.func, ast.Attribute)):
            continue
        name = node.func.attr
        if name not in ("skip", "importorskip", "skipif"):
            continue
        kw = {k.arg: k.value for k in node.keywords}
        if name == "skip":
            out.append((node.lineno, kw.get("reason", node.args[0] if node.args else None)))
        else:
            out.append((node.lineno, kw.get("reason")))
    return out


def _text(expr: ast.expr) -> str:
    """The text of a reason: a conftest constant's value, or a (formatted) string's literal parts."""
    if isinstance(expr, ast.Name) and hasattr(conftest, expr.id):
        return str(getattr(conftest, expr.id))
    return " ".join(n.value for n in ast.walk(expr) if isinstance(n, ast.Constant) and isinstance(n.value, str))


def test_every_skip_reason_names_a_remedy():
    bad = []
    for path in sorted((REPO / "tests").rglob("*.py")):
        for line, expr in _skip_reasons(ast.parse(path.read_text())):
            if expr is None or not REMEDY.search(_text(expr)):
                bad.append(f"{path.relative_to(REPO)}:{line}")
    assert not bad, f"skips without a remedy (a setup command or variable): {bad}"


def test_the_skip_reasons_name_their_setup_command():
    assert all(REMEDY.search(r) for r in SKIP_REASONS)
    assert "../shared/maps/SOURCES.md" in SHARED_MAPS_MISSING and "docs/realmaps.md" in SHARED_MAPS_MISSING
    assert "FEAT2MAP_SHARED_MAPS=" in SHARED_MAPS_MISSING
