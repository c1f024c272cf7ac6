"""Scenario files and route coverage: schema validation errors name file and element, suites
round-trip through YAML and JSON, every manoeuvre of generated maps is covered by
`coverage_routes`, routes are drivable by the env, and make_env applies the scenario."""
from __future__ import annotations

import json
import os
import pickle
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import pytest

from conftest import SHARED_MAPS, SHARED_MAPS_MISSING
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import feat2map
from feat2map.formats import native
from feat2map.envs.routes import manoeuvres_to_lanes
from feat2map.envs.network import MapNetwork
from feat2map.scenarios.routes import (BASE_DURATION_S, ROUTE_SPEED_MPS, SECONDS_PER_JUNCTION, SIGNAL_CROSSING_S,
                                       START_AND_GOAL_M, build_suite, coverage_routes, manoeuvres, pick_lane,
                                       render_routes, route_coverage, route_duration, route_length, signal_cycle,
                                       signal_cycles, successor_graph)
from feat2map.scenarios.scenario import (Scenario, ScenarioError, Suite, load_suite, make_env, save_suite,
                                         suite_from_dict)

J = feat2map.JunctionFeature.make
REPO = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def m1():
    return feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)


@pytest.fixture()
def map_file(tmp_path, m1):
    p = tmp_path / "maps" / "m1.json"
    native.save(m1, p)
    return p


def write(path: Path, data) -> Path:
    path.write_text(yaml.safe_dump(data) if path.suffix != ".json" else json.dumps(data))
    return path


def suite_doc(map_name="maps/m1.json", **overrides):
    sc = {"name": "a", "map": map_name, "route": [["J0", "R0", "R1"]], "seed": 3, **overrides}
    return {"version": 1, "name": "s", "scenarios": [sc]}


# ---- file format --------------------------------------------------------------------------
def test_suite_round_trip_yaml_and_json(tmp_path, map_file):
    src = write(tmp_path / "suite.yaml", {**suite_doc(), "defaults": {"traffic_vehicles": 4, "duration": 30}})
    suite = load_suite(src)
    sc = suite.scenarios[0]
    assert sc.map == str(map_file.resolve()) and sc.route == (("J0", "R0", "R1"),)
    assert sc.traffic_vehicles == 4 and sc.duration == 30.0 and sc.seed == 3  # defaults merged
    for name in ("out/again.yaml", "again.json"):
        save_suite(suite, tmp_path / name)
        back = load_suite(tmp_path / name)
        assert back.scenarios == suite.scenarios and back.name == suite.name
    raw = yaml.safe_load((tmp_path / "out" / "again.yaml").read_text())
    assert raw["scenarios"][0]["map"] == "../maps/m1.json"  # written relative to the suite file


def test_scenario_dict_round_trip():
    sc = Scenario("x", "m.json", (("J1", "R2", "R3"), ("J2", "R3", "R4")), 5, 2.5, {"J1": 4.0}, 7, 42.0)
    assert Scenario.from_dict(sc.to_dict(), "x") == sc
    assert Scenario.from_dict(json.loads(json.dumps(sc.to_dict())), "x") == sc
    assert hash(sc) == hash(Scenario.from_dict(sc.to_dict(), "x"))
    assert pickle.loads(pickle.dumps(sc)) == sc  # travels to worker processes
    with pytest.raises(TypeError, match="read-only"):
        sc.signal_offsets["J1"] = 0.0  # type: ignore[index]


@pytest.mark.parametrize("mutate,element", [
    (lambda d: d["scenarios"][0].pop("route"), "scenarios[0]"),
    (lambda d: d["scenarios"][0].update(route=[["J0", "R0"]]), "scenarios[0].route[0]"),
    (lambda d: d["scenarios"][0].update(seed=-1), "scenarios[0].seed"),
    (lambda d: d["scenarios"][0].update(traffic_vehicles="many"), "scenarios[0].traffic_vehicles"),
    (lambda d: d["scenarios"][0].update(duration=0), "scenarios[0].duration"),
    (lambda d: d["scenarios"][0].update(pedestrian_rate=-2), "scenarios[0].pedestrian_rate"),
    (lambda d: d["scenarios"][0].update(signal_offsets={"J0": "soon"}), "scenarios[0].signal_offsets.J0"),
    (lambda d: d["scenarios"][0].update(colour="red"), "scenarios[0]"),
    (lambda d: d.pop("name"), "suite.yaml"),
    (lambda d: d.update(version=2), "version"),
    (lambda d: d["scenarios"].append(dict(d["scenarios"][0])), "scenarios[1].name"),
])
def test_schema_errors_name_file_and_element(tmp_path, map_file, mutate, element):
    doc = suite_doc()
    mutate(doc)
    path = write(tmp_path / "suite.yaml", doc)
    with pytest.raises(ScenarioError) as err:
        load_suite(path)
    assert str(path) in err.value.where and element in err.value.where, err.value.where
    assert "\n" not in str(err.value)


def test_unreadable_suites_and_missing_maps(tmp_path, map_file):
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: [unclosed\n")
    with pytest.raises(ScenarioError, match="not valid YAML") as err:
        load_suite(bad)
    assert err.value.where == str(bad)
    trunc = tmp_path / "t.json"
    trunc.write_text(json.dumps(suite_doc())[:40])
    with pytest.raises(ScenarioError, match="not valid JSON"):
        load_suite(trunc)
    with pytest.raises(ScenarioError, match="cannot read"):
        load_suite(tmp_path / "absent.yaml")
    with pytest.raises(ScenarioError, match="must be a mapping"):
        load_suite(write(tmp_path / "list.yaml", [1, 2]))
    missing = write(tmp_path / "m.yaml", suite_doc("nowhere.json"))
    with pytest.raises(ScenarioError, match="map file not found") as err:
        load_suite(missing)
    assert err.value.where.endswith("scenarios[0].map")


def test_save_is_atomic_and_validated(tmp_path):
    bad = Suite("s", (Scenario("a", "m.json", (("J0", "R0", "R1"),), seed=0, duration=-1.0),), tmp_path)
    target = tmp_path / "out.yaml"
    with pytest.raises(ScenarioError, match="duration"):
        save_suite(bad, target)
    assert not target.exists() and not list(tmp_path.glob(".out.yaml*"))


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(st.lists(st.tuples(st.text("JR0123", min_size=1, max_size=4), st.integers(0, 50), st.floats(0, 30),
                          st.integers(0, 10**6), st.floats(1, 600)), min_size=1, max_size=5, unique_by=lambda t: t[0]))
def test_any_valid_suite_round_trips(tmp_path, rows):
    suite = Suite("p", tuple(Scenario(n, "m.json", (("J0", n, "R9"),), t, p, {"J0": p}, s, d)
                             for n, t, p, s, d in rows), tmp_path)
    save_suite(suite, tmp_path / "p.yaml")
    back = suite_from_dict(yaml.safe_load((tmp_path / "p.yaml").read_text()), "p", tmp_path)
    assert [sc.to_dict() | {"map": ""} for sc in back.scenarios] == [sc.to_dict() | {"map": ""} for sc in suite.scenarios]
    assert all(Path(sc.map) == tmp_path / "m.json" for sc in back.scenarios)


# ---- route coverage -----------------------------------------------------------------------
def test_manoeuvres_are_every_junction_lane_movement(m1):
    moves = manoeuvres(m1)
    assert len(moves) == len(set(moves))
    lanes = [ln for ln in m1.lanes.values() if ln.junction_id is not None]
    assert {(ln.junction_id, m1.lanes[ln.predecessors[0]].road_id, m1.lanes[ln.successors[0]].road_id)
            for ln in lanes} == set(moves)
    assert {mv[0] for mv in moves} == set(m1.junctions)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_coverage_routes_cover_every_manoeuvre_and_are_drivable(seed):
    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=seed)
    routes = coverage_routes(m)
    assert route_coverage(m, routes) == 1.0
    assert set(manoeuvres(m)) <= {mv for r in routes for mv in r}
    assert len(routes) < len(manoeuvres(m))  # routes chain manoeuvres: fewer routes than manoeuvres
    net = MapNetwork.from_map(m)
    graph = successor_graph(m)
    for r in routes:
        assert 1 <= len(r) <= 4 and len({mv[0] for mv in r}) == len(r)
        assert all(b in graph[a] for a, b in zip(r, r[1:]))
        lanes = manoeuvres_to_lanes(net, r)  # the env accepts it ...
        assert m.lanes[lanes[0]].junction_id is None and m.lanes[lanes[-1]].junction_id is None  # road to road
        crossed = [m.lanes[l].junction_id for l in lanes if m.lanes[l].junction_id is not None]
        assert crossed == [mv[0] for mv in r]  # ... and crosses exactly the named junctions
        inner = sum(m.lanes[l].length for l in lanes[1:-1])
        assert route_length(m, r) == pytest.approx(inner + START_AND_GOAL_M)  # the env's lanes
        assert route_duration(m, r) > inner / 10.0


def test_durations_follow_the_speeds_the_ego_drives(m1):
    """A map whose lanes are limited to 4 m/s gets the time to drive its routes at 4 m/s (the
    durations assumed 8 m/s whatever the map declared: a 1.2-2.4 m/s map timed out at 97%);
    lanes at 8 m/s or faster keep the old budget."""
    from dataclasses import replace

    route = coverage_routes(m1)[0]
    assert min(ln.speed_limit for ln in m1.lanes.values()) >= ROUTE_SPEED_MPS  # M1 keeps its old durations
    slow = replace(m1, lanes={k: replace(v, speed_limit=4.0) for k, v in m1.lanes.items()})
    length = route_length(m1, route)
    assert route_duration(slow, route) - route_duration(m1, route) == pytest.approx(length / 4.0 - length / 8.0, abs=0.2)


def test_a_turn_that_yields_at_a_signal_gets_two_cycles(m1):
    """A left turn at a signal yields to oncoming traffic in its green and may wait out a whole
    green's stream and the next red (four_way_crossing r009): its budget is two cycles, a
    straight or right turn's one."""
    moves = {}
    for mv in manoeuvres(m1):
        lane = pick_lane(m1, mv)
        if signal_cycle(m1, mv[0]) > 0 and lane is not None:
            moves.setdefault(lane.turn, mv)
    assert {"left", "none"} <= set(moves)
    for turn, mv in moves.items():
        cycles = 2 if turn in ("left", "uturn") else 1
        assert signal_cycles(m1, mv) == cycles
        expected = BASE_DURATION_S + max(SECONDS_PER_JUNCTION, cycles * signal_cycle(m1, mv[0]) + SIGNAL_CROSSING_S) \
            + route_length(m1, [mv]) / ROUTE_SPEED_MPS
        assert route_duration(m1, [mv]) == pytest.approx(expected, abs=0.06)
    assert route_duration(m1, [moves["left"]]) - route_length(m1, [moves["left"]]) / ROUTE_SPEED_MPS > \
        route_duration(m1, [moves["none"]]) - route_length(m1, [moves["none"]]) / ROUTE_SPEED_MPS


def test_coverage_is_deterministic_and_partial_coverage_is_measured(m1):
    routes = coverage_routes(m1)
    assert routes == coverage_routes(m1)
    assert route_coverage(m1, routes[:1]) == pytest.approx(len(set(routes[0])) / len(manoeuvres(m1)))
    assert route_coverage(m1, []) == 0.0
    single = coverage_routes(m1, max_junctions=1)
    assert len(single) == len(manoeuvres(m1)) and route_coverage(m1, single) == 1.0
    with pytest.raises(ValueError):
        coverage_routes(m1, max_junctions=0)


ANGLES = {3: [0, 100, 220], 4: [0, 90, 180, 270], 5: [0, 72, 144, 216, 288]}


@settings(max_examples=12, deadline=None)
@given(st.lists(st.tuples(st.sampled_from([3, 4, 5]), st.sampled_from(["signal", "stop", "bare"]), st.booleans()),
                min_size=1, max_size=4), st.integers(0, 50), st.integers(1, 4))
def test_coverage_routes_cover_any_generated_map(feats, seed, max_junctions):
    m = feat2map.generate_from_features([J(ANGLES[n], c, cw) for n, c, cw in feats], seed=seed)
    routes = coverage_routes(m, max_junctions)
    assert route_coverage(m, routes) == 1.0
    assert all(1 <= len(r) <= max_junctions for r in routes)
    graph = successor_graph(m)
    assert all(b in graph[a] for r in routes for a, b in zip(r, r[1:]))


def test_coverage_of_a_mega_junction_with_uturns():
    m = feat2map.generate_from_features([J([0, 72, 144, 216, 288], "bare", True)], seed=0,
                                        config=feat2map.GenerationConfig(uturns=True))
    routes = coverage_routes(m)
    assert route_coverage(m, routes) == 1.0
    assert any(ln.turn == "uturn" for ln in m.lanes.values())


def test_routes_do_not_end_just_before_another_junction_where_they_can_go_on():
    """Two junctions 23 m apart (a 62 m grid): a route whose last manoeuvre leaves onto that
    road goes on through the next junction when the length allows (the env's goal, 15 m into
    the road, put an ego at speed into the next junction, on red in Town06); with one junction
    per route there is no choice."""
    from feat2map.config import GenerationConfig
    from feat2map.scenarios.routes import END_ROOM_M, _exit_room

    m = feat2map.generate_from_features([J([0, 90, 180, 270], "bare", False), J([0, 90, 180], "bare", False)],
                                        seed=0, config=GenerationConfig(grid_gap=62.0))
    (short,) = [r for r in m.roads.values() if r.kind == "connection"]
    assert m.lanes[short.right_lanes[0]].length < END_ROOM_M
    ends_short = lambda routes: [r for r in routes if _exit_room(m, r[-1]) < END_ROOM_M]  # noqa: E731
    assert ends_short(coverage_routes(m, 1)) and not ends_short(coverage_routes(m, 2))
    assert route_coverage(m, coverage_routes(m, 2)) == 1.0


def test_build_suite_of_a_map_file(map_file, m1, tmp_path):
    suite = build_suite(map_file, seed=10, traffic_vehicles=3, pedestrian_rate=2.0)
    assert route_coverage(m1, [sc.route for sc in suite.scenarios]) == 1.0
    assert [sc.seed for sc in suite.scenarios] == list(range(10, 10 + len(suite.scenarios)))
    assert all(sc.traffic_vehicles == 3 and sc.duration > 20 for sc in suite.scenarios)
    save_suite(suite, tmp_path / "cov.yaml")
    assert load_suite(tmp_path / "cov.yaml").scenarios == suite.scenarios


def test_build_suite_of_a_real_opendrive_map():
    maps = sorted((SHARED_MAPS / "opendrive").rglob("*.xodr")) if SHARED_MAPS.is_dir() else []
    if not maps:
        pytest.skip(SHARED_MAPS_MISSING)
    path = min(maps, key=lambda p: p.stat().st_size)
    suite = build_suite(path)
    from feat2map.readers import read_map

    assert route_coverage(read_map(path), [sc.route for sc in suite.scenarios]) == 1.0


# ---- env --------------------------------------------------------------------------------
def test_make_env_applies_the_scenario(map_file, m1):
    route = coverage_routes(m1)[0]
    sig = next(s for s in m1.signals.values())
    sc = Scenario("e", str(map_file), route, traffic_vehicles=3, pedestrian_rate=1.0,
                  signal_offsets={sig.junction_id: 7.5}, seed=2, duration=12.0)
    env = make_env(sc)
    env.reset(seed=sc.seed)
    u = env.unwrapped
    assert u.config["duration"] == 12.0 and u.config["traffic_vehicles"] == 3
    assert u.control.plans[sig.id].offset == 7.5
    crossed = [m1.lanes[l].junction_id for l in u.route_lanes if m1.lanes[l].junction_id]
    assert crossed == [mv[0] for mv in route]
    bad = Scenario("b", str(map_file), (("J0", "R0", "R0"),))
    with pytest.raises(feat2map.errors.Feat2MapError, match="no lane of junction J0") as err:
        make_env(bad).reset(seed=0)
    assert err.value.where == "route[0]"


# ---- the CI suite -------------------------------------------------------------------------
def same_numbers(a, b, tol: float = 1e-6) -> bool:
    """Equal JSON documents up to float rounding (generator arithmetic may change last digits)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(same_numbers(a[k], b[k], tol) for k in a)
    if isinstance(a, list):
        return isinstance(b, list) and len(a) == len(b) and all(same_numbers(x, y, tol) for x, y in zip(a, b))
    if isinstance(a, float) or isinstance(b, float):
        return isinstance(a, (int, float)) and isinstance(b, (int, float)) and abs(a - b) <= tol
    return a == b


def test_ci_suite_is_valid_current_and_touches_every_junction_type(tmp_path):
    from feat2map.scenarios import make_ci_suite

    suite = load_suite(REPO / "scenarios" / "ci_suite.yaml")
    m = native.load(REPO / "scenarios" / "ci_map.json")
    assert make_ci_suite.main(["--out-dir", str(tmp_path)]) == 0  # the script regenerates the same files
    stale = "stale: regenerate with .venv/bin/python scenarios/make_ci_suite.py --picture"
    assert same_numbers(json.loads((tmp_path / "ci_map.json").read_text()),
                        json.loads((REPO / "scenarios" / "ci_map.json").read_text())), f"ci_map.json {stale}"
    assert (tmp_path / "ci_suite.yaml").read_text() == (REPO / "scenarios" / "ci_suite.yaml").read_text(), \
        f"ci_suite.yaml {stale}"
    types = {(j.feature.n_roads, j.feature.control, j.feature.crosswalk) for j in m.junctions.values()}
    assert {c for _, c, _ in types} == {"signal", "stop", "bare"} and len(types) == len(m.junctions) == 6
    routes = [sc.route for sc in suite.scenarios]
    assert {mv[0] for r in routes for mv in r} == set(m.junctions)
    keys = set().union(*(make_ci_suite.behaviour_keys(m, r) for r in routes))
    turns = {(c, t) for kind, *rest in keys if kind == "turn" for c, t in [rest]}
    assert turns == {(c, t) for c in ("signal", "stop", "bare") for t in ("left", "straight", "right")}
    net = MapNetwork.from_map(m)
    for r in routes:
        manoeuvres_to_lanes(net, r)


def test_render_routes_png_and_svg(tmp_path, m1):
    routes = coverage_routes(m1)[:3]
    render_routes(m1, routes, tmp_path / "r.png", names=["a", "b", "c"])
    render_routes(m1, routes[:1], tmp_path / "r.svg")
    assert (tmp_path / "r.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    svg = (tmp_path / "r.svg").read_text()
    assert svg.lstrip().startswith("<?xml") and " → ".join(f"{j}:{e}>{x}" for j, e, x in routes[0]).replace(">", "&gt;") in svg
