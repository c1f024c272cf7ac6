"""One source of truth: imports point down the layers (formats -> model; envs -> map layer;
scenarios on top), and each rule the layers share is written once (or, where a copy remains
in a module that is being reworked, kept equal to the one place by these tests)."""
from __future__ import annotations

import ast
import math
from pathlib import Path

import numpy as np
import pytest

REPO = Path(__file__).resolve().parents[1]
# modules of the map layer allowed to import a layer above it: the package's __init__ registers
# the Gymnasium envs (by string entry points), the command line dispatches to every layer
ALLOWED_UP = {"feat2map/__init__.py", "feat2map/cli.py", "feat2map/cli_scenarios.py"}


def _imports(path: Path) -> list[tuple[int, str]]:
    """(line, absolute dotted name) of every import in the module at `path`."""
    package = ".".join(("feat2map",) + path.relative_to(REPO).with_suffix("").parts[1:-1])
    layer = {"feat2map": "feat2map", "envs": "feat2map.envs", "scenarios": "feat2map.scenarios"}[
        path.relative_to(REPO).parts[0]]
    package = layer + package[len("feat2map"):]
    out = []
    for node in ast.walk(ast.parse(path.read_text())):
        if isinstance(node, ast.Import):
            out += [(node.lineno, a.name) for a in node.names]
        elif isinstance(node, ast.ImportFrom):
            base = package.split(".")
            if node.level:
                base = base[:len(base) - node.level + 1]
                name = ".".join(base + ([node.module] if node.module else []))
            else:
                name = node.module or ""
            out += [(node.lineno, f"{name}.{a.name}") for a in node.names]
    return out


def _up_imports(folder: str, above: tuple[str, ...]) -> list[str]:
    found = []
    for path in sorted((REPO / folder).rglob("*.py")):
        if str(path.relative_to(REPO)) in ALLOWED_UP:
            continue
        for line, name in _imports(path):
            if any(name == a or name.startswith(a + ".") for a in above):
                found.append(f"{path.relative_to(REPO)}:{line} imports {name}")
    return found


def test_the_map_layer_and_the_formats_never_import_envs_or_scenarios():
    assert _up_imports("feat2map", ("feat2map.envs", "feat2map.scenarios")) == []


def test_envs_never_import_scenarios():
    assert _up_imports("envs", ("feat2map.scenarios",)) == []


def test_the_import_scan_sees_relative_imports(tmp_path):
    """The scan resolves `from ...envs import x` inside feat2map/formats/<name>/ (else the two
    tests above could not fail)."""
    names = [n for _, n in _imports(REPO / "feat2map" / "formats" / "openscenario" / "writer.py")]
    assert "feat2map.routes.manoeuvre_lane" in names and "feat2map.config.DRIVE_DEFAULTS" in names


# the env wing's adapters: the batched env and the multi-agent env step their envs through the
# envs' public protocol (`MapEnv.begin_step`, `step_values`, `AgentView.reward_terms`, ...)
ADAPTERS = ("envs/vector.py", "envs/multi_agent.py")


def _private_reaches(source: str) -> list[str]:
    """`x._name` of every object `x` other than `self` and `cls` in `source` (dunders aside)."""
    found = []
    for node in ast.walk(ast.parse(source)):
        if isinstance(node, ast.Attribute) and node.attr.startswith("_") and not node.attr.startswith("__") \
                and not (isinstance(node.value, ast.Name) and node.value.id in ("self", "cls")):
            found.append((node.lineno, node.col_offset, ast.unparse(node)))
    return [f"{line}: {text}" for line, _, text in sorted(found)]


def test_the_adapters_reach_no_private_member_of_another_object():
    found = [f"{p}:{hit}" for p in ADAPTERS for hit in _private_reaches((REPO / p).read_text())]
    assert found == []


def test_the_private_member_scan_sees_methods_fields_and_class_attributes():
    src = "env._end_step(a)\nview._last_rewards = r\ntype(env)._info is MapEnv._info\nself._own = self._views[a]._x\n"
    assert _private_reaches(src) == ["1: env._end_step", "2: view._last_rewards", "3: type(env)._info",
                                     "3: MapEnv._info", "4: self._views[a]._x"]


def test_the_env_defaults_are_the_drive_defaults():
    """The OpenSCENARIO export and the scenario tools model the env's drive from DRIVE_DEFAULTS."""
    from feat2map.config import DRIVE_DEFAULTS
    from feat2map.envs.map_env import MapEnv

    cfg = MapEnv.default_config()
    assert {k: cfg[k] for k in DRIVE_DEFAULTS} == dict(DRIVE_DEFAULTS)


def _constants(path: Path) -> dict[str, int]:
    """UPPER_CASE names a module assigns at its top level, with their lines."""
    out = {}
    for node in ast.parse(path.read_text()).body:
        targets = node.targets if isinstance(node, ast.Assign) else [node.target] if isinstance(node, ast.AnnAssign) else []
        for t in targets:
            out.update({n.id: node.lineno for n in ast.walk(t) if isinstance(n, ast.Name) and n.id.isupper()})
    return out


def test_every_map_layer_constant_is_named_once():
    """A constant of feat2map/config.py (map layer: MAX_LEGS, UTURN_THRESHOLD_DEG, ...; env layer:
    LOOKAHEAD_M, IDM_ACC, ...) is assigned nowhere else in the package: every module imports it."""
    config = REPO / "feat2map" / "config.py"
    named = _constants(config)
    assert {"MAX_LEGS", "UTURN_THRESHOLD_DEG", "STRAIGHT_TOLERANCE_DEG", "LOOKAHEAD_M", "IDM_ACC",
            "CONFLICT_DISTANCE_M"} <= set(named)
    again = [f"{p.relative_to(REPO)}:{line} {name}" for folder in ("feat2map", "envs", "scenarios")
             for p in sorted((REPO / folder).rglob("*.py")) if p != config
             for name, line in _constants(p).items() if name in named]
    assert again == []


def test_the_constant_scan_sees_assignments(tmp_path):
    """The scan finds plain, annotated and tuple assignments (else the test above could not fail)."""
    f = tmp_path / "m.py"
    f.write_text("MAX_LEGS = 8\nA: int = 1\nB, C = 1, 2\nlower = 3\ndef f():\n    D = 4\n")
    assert set(_constants(f)) == {"MAX_LEGS", "A", "B", "C"}


def test_the_env_drives_the_map_layers_lane_for_every_manoeuvre(sf_default_map):
    """envs.routes.manoeuvres_to_lanes picks the junction lane feat2map.routes.manoeuvre_lane names."""
    from feat2map.envs.routes import manoeuvres_to_lanes
    from feat2map.envs.network import MapNetwork
    from feat2map.routes import manoeuvre_lane
    from feat2map.scenarios.routes import manoeuvres, pick_lane

    m = sf_default_map
    net = MapNetwork.from_map(m)
    moves = manoeuvres(m)
    assert len(moves) > 50
    for mv in moves:
        lane = manoeuvre_lane(m, mv)
        assert lane is not None and pick_lane(m, mv) is lane
        assert manoeuvres_to_lanes(net, [mv])[1] == lane.id, mv
    assert manoeuvre_lane(m, ("J0", "no such road", "R1")) is None


@pytest.mark.parametrize("a", [0.0, 1.0, -1.0, math.pi, -math.pi, 3 * math.pi, -7.5, 1e6, 2 * math.pi - 1e-12])
def test_wrap_angle_gives_the_inline_formulas_bits(a):
    from feat2map.angles import wrap_angle, wrap_degrees

    w = wrap_angle(a)
    assert w == (a + math.pi) % (2 * math.pi) - math.pi and -math.pi <= w < math.pi
    assert math.isclose(math.cos(w), math.cos(a), abs_tol=1e-6) and math.isclose(math.sin(w), math.sin(a), abs_tol=1e-6)
    d = wrap_degrees(math.degrees(a))
    assert d == (math.degrees(a) + 180.0) % 360.0 - 180.0 and -180.0 <= d < 180.0
    arr = np.array([a, -a, 0.5 * a])
    assert np.array_equal(wrap_angle(arr), (arr + np.pi) % (2 * np.pi) - np.pi)


def test_one_uturn_threshold():
    """A turn sharper than any left a real map has (150 deg) but short of a U-turn (180)."""
    from feat2map.config import STRAIGHT_TOLERANCE_DEG, UTURN_THRESHOLD_DEG

    assert 150.0 < UTURN_THRESHOLD_DEG < 180.0 and UTURN_THRESHOLD_DEG > STRAIGHT_TOLERANCE_DEG


@pytest.mark.parametrize("change, plain, with_uturns", [
    (0.0, "none", "none"), (29.0, "none", "none"), (-29.0, "none", "none"), (31.0, "left", "left"),
    (-31.0, "right", "right"), (150.0, "left", "left"), (-150.0, "right", "right"), (-179.0, "right", "uturn")])
def test_one_turn_rule(change, plain, with_uturns):
    """`angles.classify_turn` is the turn of the generator, the OpenDRIVE reader (U-turns from
    config.UTURN_THRESHOLD_DEG on) and the CommonRoad export's fallback turn set."""
    from feat2map.angles import classify_turn, turn_name
    from feat2map.config import UTURN_THRESHOLD_DEG
    from feat2map.formats.commonroad.writer import turn_set
    from feat2map.formats.opendrive.reader import _turn
    from feat2map.model import Lane

    h0 = 0.3
    h1 = h0 + math.radians(change)
    assert classify_turn(h0, h1) == turn_name(change) == plain
    assert classify_turn(h0, h1, uturns=True) == with_uturns
    assert turn_name(30.0) == turn_name(-30.0) == "none"  # straight up to STRAIGHT_TOLERANCE_DEG included
    for at, turn in ((UTURN_THRESHOLD_DEG, "uturn"), (UTURN_THRESHOLD_DEG - 0.5, "left")):
        assert turn_name(at, uturns=True) == turn and turn_name(-at, uturns=True) == turn.replace("left", "right")
    # a junction lane of an OpenDRIVE map: two segments, heading h0 then h1
    mid = (10 * math.cos(h0), 10 * math.sin(h0))
    end = (mid[0] + 10 * math.cos(h1), mid[1] + 10 * math.sin(h1))
    lane = Lane("l", "r", ((0.0, 0.0), mid, end), (), (), 3.5, 10.0)
    assert _turn(lane, {}) == with_uturns
    # CommonRoad: a lane declared straight whose geometry is not lists under its geometry's turn
    if abs(change) > 60.0:
        assert turn_set("none", np.array(lane.centerline)) == {"left": "outgoing_left", "right": "outgoing_right"}[plain]


@pytest.mark.parametrize("a", [0.0, 1.0, -1.0, math.pi, -math.pi, 3 * math.pi, -7.5, 1e6, 2 * math.pi - 1e-12, -1e-300])
def test_positive_wraps_give_the_inline_formulas_bits(a):
    from feat2map.angles import positive_angle, positive_degrees

    assert positive_angle(a) == a % (2 * math.pi) and 0.0 <= positive_angle(a) <= 2 * math.pi  # -1e-300: 2 pi
    d = math.degrees(a)
    assert positive_degrees(d) == d % 360.0 and 0.0 <= positive_degrees(d) <= 360.0
    arr = np.array([a, -a, 0.5 * a])
    assert np.array_equal(positive_angle(arr), arr % (2 * np.pi))
