"""Every tunable constant is named once, in feat2map/config.py: no module of the package (map
layer, envs, scenarios) assigns a module-level name that the config module defines (it imports it)."""
from __future__ import annotations

import ast
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGE = ["feat2map/**/*.py", "envs/*.py", "scenarios/*.py"]


def assigned(path: Path) -> dict[str, int]:
    """UPPER_CASE names a module assigns at its top level -> line."""
    out: dict[str, int] = {}
    for node in ast.parse(path.read_text(encoding="utf-8")).body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for t in targets:
            for n in [t] if isinstance(t, ast.Name) else getattr(t, "elts", []):
                if isinstance(n, ast.Name) and n.id.isupper():
                    out[n.id] = node.lineno
    return out


def test_config_constants_are_named_nowhere_else():
    config = REPO / "feat2map" / "config.py"
    names = assigned(config)
    assert {"LOOKAHEAD_M", "IDM_ACC", "MOBIL_GAIN_MPS2", "CONFLICT_DISTANCE_M", "MAX_LEGS"} <= set(names)
    again = [f"{p.relative_to(REPO)}:{line} {n}" for pattern in PACKAGE for p in sorted(REPO.glob(pattern))
             if p != config for n, line in assigned(p).items() if n in names]
    assert not again, "defined in feat2map/config.py and again in: " + ", ".join(again)


def test_the_scan_sees_a_second_definition(tmp_path):
    """(else the test above could not fail)"""
    p = tmp_path / "m.py"
    p.write_text("import x\nLOOKAHEAD_M = 60.0\nA, B = 1, 2\nlower = 3\n")
    assert assigned(p) == {"LOOKAHEAD_M": 2, "A": 3, "B": 3}
