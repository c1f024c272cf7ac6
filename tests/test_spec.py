"""Custom maps from hand-written specs (issue 6): the example specs build into valid maps whose
re-extracted features are the spec's, every unbuildable spec fails naming its element, random
valid junction specs build, the CLI path writes everything or nothing, and the mega junction drives."""
from __future__ import annotations

import json
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from feat2map.formats import native
from feat2map.cli import main
from feat2map.config import GenerationConfig, MIN_STUB_LENGTH_M
from feat2map.construct import junction_radius
from feat2map.extract import extract_junctions
from feat2map.features import FeatureSpace
from feat2map.invariants import check_map, feature_mismatch
from feat2map.spec import SpecError, build_spec, load_spec, parse_spec, spec_schema

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples"
SPECS = sorted(EXAMPLES.glob("*.yaml"))


@pytest.fixture(scope="module")
def example_maps():
    return {p.stem: (load_spec(p), build_spec(load_spec(p))) for p in SPECS}


def test_the_papers_examples_are_shipped():
    assert {"mega_junction", "one_way_t", "road_circle", "multi_lane"} <= {p.stem for p in SPECS}


@pytest.mark.parametrize("name", [p.stem for p in SPECS])
def test_every_example_builds_and_passes_the_invariants(example_maps, name):
    spec, m = example_maps[name]
    assert check_map(m) == []
    assert len(m.junctions) == len(spec.junctions)
    # re-extracting returns the spec's features: n, control, crosswalk, angles, road types, lanes
    got = {e.id: e.feature for e in extract_junctions(m)}
    for i, j in enumerate(spec.junctions):
        want = j.feature.normalized()
        assert feature_mismatch(got[f"J{i}"], want) == [], (name, i)
        assert sorted(got[f"J{i}"].road_types) == sorted(j.feature.road_types)
        if j.cell is not None:
            assert m.junctions[f"J{i}"].cell == j.cell


@pytest.mark.parametrize("name", [p.stem for p in SPECS])
def test_every_example_passes_the_apollo_validator(example_maps, tmp_path, name):
    from feat2map.formats.apollo.validate import validate_apollo
    from feat2map.formats.apollo import write_apollo

    write_apollo(example_maps[name][1], tmp_path / "apollo")
    assert [str(p) for p in validate_apollo(tmp_path / "apollo")] == []


def test_mega_junction_is_the_papers(example_maps):
    spec, m = example_maps["mega_junction"]
    f = spec.junctions[0].feature
    assert (f.n_roads, f.control, f.crosswalk) == (5, "signal", True)
    assert [a % 360 for a in f.rotation] == [0, 72, 144, 216, 288]
    assert len(m.signals) == 5 and len(m.crosswalks) == 5
    # drawn as written: the socket at 0 degrees points East
    arms = extract_junctions(m)[0].arms
    assert sorted(round(a.angle_deg % 360, 6) for a in arms) == pytest.approx([0, 72, 144, 216, 288], abs=1e-6)


def test_one_way_t_keeps_direction_and_controls_only_entries(example_maps):
    spec, m = example_maps["one_way_t"]
    assert spec.junctions[0].feature.road_types == ("in", "out", "in-out")  # from East, counter-clockwise
    j = m.junctions["J0"]
    by_angle = {}
    for e in extract_junctions(m)[0].arms:
        by_angle[round(e.angle_deg) % 360] = (e.lanes_in, e.lanes_out)
    assert by_angle == {0: (1, 0), 90: (0, 1), 180: (1, 1)}  # drawn as written
    for ln in m.junction_lanes("J0"):  # junction lanes only from incoming to outgoing lanes
        pred, succ = m.lanes[ln.predecessors[0]], m.lanes[ln.successors[0]]
        assert pred.junction_id is None and succ.junction_id is None
    entering = {lid for s in m.stop_signs.values() for lid in s.lane_ids}
    incoming = {m.lanes[ln.predecessors[0]].id for ln in m.junction_lanes("J0")}
    assert entering == incoming and len(m.stop_signs) == 2  # no stop sign on the out road
    assert len(j.socket_roads) == 3


def test_road_circle_is_closed_and_strongly_connected(example_maps):
    spec, m = example_maps["road_circle"]
    chain = spec.chains[0]
    assert chain.closed and not m.junctions
    assert (chain.lanes_forward, chain.lanes_backward) == (2, 0)
    assert not m.entry_lanes and not m.exit_lanes  # no entries: a loop, lane changes across the dotted line
    for r in m.roads.values():
        a, b = (m.lanes[i] for i in r.right_lanes)
        assert a.right_boundary_type == b.left_boundary_type == "dotted_white"
    for ln in m.lanes.values():
        assert len(ln.successors) == 1 and len(ln.predecessors) == 1
    centre = np.array([0.0, 0.0])
    r = np.concatenate([np.hypot(*(ln.points - centre).T) for ln in m.lanes.values()])
    assert 40 - 3.5 - 1.5 < r.min() and r.max() < 40 + 3.5 + 1.5  # a ring, about 40 m round the origin


def test_multi_lane_connections_do_not_cross_and_neighbours_are_linked(example_maps):
    _, m = example_maps["multi_lane"]
    for r in m.roads.values():
        for ids in (r.right_lanes, r.left_lanes):
            for a, b in zip(ids, ids[1:]):
                la, lb = m.lanes[a], m.lanes[b]
                assert la.right_neighbors == (b,) and lb.left_neighbors == (a,)
                assert la.right_boundary_type == "dotted_white" and lb.left_boundary_type == "dotted_white"
    # at every approach, connections to one exit keep the lanes' order (they do not cross)
    from shapely.geometry import LineString

    for jid in m.junctions:
        lanes = m.junction_lanes(jid)
        for a in lanes:
            for b in lanes:
                same = (m.lanes[a.successors[0]].road_id == m.lanes[b.successors[0]].road_id
                        and m.lanes[a.predecessors[0]].road_id == m.lanes[b.predecessors[0]].road_id)
                if a.id < b.id and same and a.predecessors != b.predecessors and a.successors != b.successors:
                    assert not LineString(a.centerline).crosses(LineString(b.centerline)), (a.id, b.id)
    # every lane of a two-lane road is used: both entry lanes lead somewhere, both exit lanes are fed
    j0 = m.junctions["J0"]
    for rid in j0.socket_roads:
        for lid in m.roads[rid].lane_ids:
            assert m.lanes[lid].successors or m.lanes[lid].predecessors


def test_json_specs_and_schema_are_equivalent(tmp_path):
    doc = yaml.safe_load((EXAMPLES / "one_way_t.yaml").read_text())
    p = tmp_path / "t.json"
    p.write_text(json.dumps(doc))
    assert load_spec(p).junctions == load_spec(EXAMPLES / "one_way_t.yaml").junctions
    from jsonschema import Draft202012Validator

    Draft202012Validator.check_schema(spec_schema())
    for path in SPECS:
        Draft202012Validator(spec_schema()).validate(yaml.safe_load(path.read_text()))


def J(*sockets, **kw):
    return {"junctions": [{"sockets": list(sockets), **kw}]}


def CHAIN(start, *roads, **kw):
    return {"chains": [{"start": {"point": list(start[:2]), "heading": start[2]},
                        "roads": [{"end": list(r[:2]), "heading": r[2]} for r in roads], **kw}]}


FOUR_WAY = [0, 90, 180, 270]
INVALID = [
    ("negative lanes", J({"angle": 0, "lanes_in": -1}, 90, 180), "junctions[0].sockets[0].lanes_in: must be >= 0"),
    ("two legs", J(0, 180), "junctions[0].sockets: needs at least 3 entries"),
    ("nine legs", J(*range(0, 360, 40)), "junctions[0].sockets: takes at most 8 entries"),
    ("unknown control", J(*FOUR_WAY, control="yield"), "junctions[0].control: must be one of bare, signal, stop"),
    ("unknown field", J(*FOUR_WAY, colour="red"), "junctions[0].colour: unknown field"),
    ("unknown road type", J({"angle": 0, "type": "both"}, 90, 180), "junctions[0].sockets[0].type: must be one of"),
    ("angle not a number", J("east", 90, 180), "junctions[0].sockets[0]: must be an object (mapping) or a number"),
    ("legs too close", J(0, 10, 180), "junctions[0].sockets[1]: 10 deg from sockets[0], closer than the minimum"),
    ("same direction", J(0, 360, 180), "junctions[0].sockets[1]: same direction"),
    ("no exit", J({"angle": 0, "type": "in"}, {"angle": 120, "type": "in"}, {"angle": 240, "type": "in"}),
     "junctions[0]: needs a socket where traffic enters"),
    ("type and lanes_in", J({"angle": 0, "type": "in", "lanes_in": 2}, 90, 180),
     "junctions[0].sockets[0]: give either type/lanes or lanes_in/lanes_out"),
    ("no lanes", J({"angle": 0, "lanes_in": 0, "lanes_out": 0}, 90, 180), "junctions[0].sockets[0]: a socket needs"),
    ("lanes do not fit", J(*[{"angle": a, "lanes": 4} for a in range(0, 360, 45)]),
     "junctions[0]: legs too close to fit their lanes"),
    ("cell taken", {"junctions": [{"sockets": FOUR_WAY, "cell": [0, 0]}, {"sockets": FOUR_WAY, "cell": [0, 0]}]},
     "junctions[1].cell: cell [0, 0] is already taken by junctions[0]"),
    ("one-way dead end", J({"angle": 0}, {"angle": 120, "type": "in"}, {"angle": 240, "type": "in"}),
     "junctions[0]: socket 0 has incoming lanes but no other socket has outgoing ones: they would be dead ends"),
    ("one-way trap", {"junctions": [
        {"cell": [0, 0], "sockets": [0, {"angle": 90, "type": "in"}, {"angle": 180, "type": "in"}]},
        {"cell": [1, 0], "sockets": [{"angle": 0, "type": "in"}, {"angle": 90, "type": "in"}, 180]}]},
     "junctions[0]: socket 0 has incoming lanes but no other socket has outgoing ones"),
    ("pinned apart", {"junctions": [{"cell": [0, 0], "sockets": FOUR_WAY}, {"cell": [3, 0], "sockets": FOUR_WAY}]},
     "junctions[1]: pinned to cell (3, 0), where no road connects it to junctions[0]"),
    ("facing out and out", {"junctions": [
        {"cell": [0, 0], "sockets": [{"angle": 0, "type": "out"}, {"angle": 90, "type": "out"},
                                     {"angle": 180, "type": "in"}, {"angle": 270, "type": "in"}]},
        {"cell": [1, 0], "sockets": FOUR_WAY}]},
     "junctions[1]: no quarter turn at cell (1, 0) makes the sockets facing its neighbours direction-compatible"),
    ("chain crosses itself", CHAIN((0, 0, 0), (60, 0, 0), (80, 20, 90), (60, 40, 180), (40, -30, 270)),
     "chains[0].roads[3]: crosses or overlaps roads[0] of the same chain"),
    ("road backs up on itself", CHAIN((0, 0, 0), (10, 0, 180)), "chains[0].roads[0]: the road crosses itself"),
    ("bend too tight", CHAIN((0, 0, 0), (5, 5, 90), lanes_forward=2, lanes_backward=2),
     "chains[0].roads[0]: bends with a"),
    ("closed with a kink", CHAIN((0, 0, 0), (50, 0, 0), (50, 50, 90), (0, 0, 180)),
     "chains[0].roads[2]: ends at the chain's start but heading 180 deg"),
    ("zero-length road", CHAIN((0, 0, 0), (0, 0.5, 0)), "chains[0].roads[0]: road shorter than 1 m"),
    ("chain without lanes", CHAIN((0, 0, 0), (50, 0, 0), lanes_forward=0, lanes_backward=0),
     "chains[0]: a chain needs at least one lane"),
    ("chains overlap", {"chains": CHAIN((0, 0, 0), (50, 0, 0))["chains"] + CHAIN((25, -25, 90), (25, 25, 90))["chains"]},
     "chains[1]: overlaps chains[0]"),
    ("chain over the grid", {**J(*FOUR_WAY), **CHAIN((-60, 0, 0), (60, 0, 0))},
     "chains[0].roads[0]: overlaps"),
    ("empty", {}, "a spec needs at least one junction or chain"),
    ("wrong version", {"version": 2, **J(*FOUR_WAY)}, "version: must be 1"),
    ("bad config", {"config": {"grid_gap": -5}, **J(*FOUR_WAY)}, "config.grid_gap: must be > 0"),
]


@pytest.mark.parametrize("doc,message", [c[1:] for c in INVALID], ids=[c[0] for c in INVALID])
def test_invalid_specs_fail_naming_the_element(tmp_path, doc, message):
    p = tmp_path / "bad.yaml"
    p.write_text(yaml.safe_dump(doc))
    with pytest.raises(SpecError) as err:
        build_spec(load_spec(p))
    text = str(err.value)
    assert text.startswith(f"{p}: "), text
    assert message in text, text
    assert "\n" not in text


@pytest.mark.parametrize("content,message", [
    ("junctions: [\n", "not valid YAML (line"), ("", "empty spec"), ("- 1\n- 2\n", "must be an object"),
])
def test_unreadable_spec_files(tmp_path, content, message):
    p = tmp_path / "broken.yaml"
    p.write_text(content)
    with pytest.raises(SpecError, match=message.replace("(", r"\(")):
        load_spec(p)
    with pytest.raises(SpecError, match="cannot read"):
        load_spec(tmp_path / "missing.yaml")


@st.composite
def junction_specs(draw):
    n = draw(st.integers(3, 6))
    base = draw(st.floats(-180, 180))
    step = 360.0 / n
    angles = [base + i * step + draw(st.floats(-step / 2 + 20, step / 2 - 20)) for i in range(n)]  # legs >= 40 deg apart
    types = draw(st.lists(st.sampled_from(["in", "out", "in-out"]), min_size=n, max_size=n))
    lanes = draw(st.lists(st.integers(1, 2), min_size=n, max_size=n))
    # routes exist: every entering socket has another socket to leave by, and vice versa
    ins = [i for i, t in enumerate(types) if t != "out"]
    outs = [i for i, t in enumerate(types) if t != "in"]
    assume(all(any(o != i for o in outs) for i in ins) and all(any(i != o for i in ins) for o in outs))
    return {"control": draw(st.sampled_from(["bare", "signal", "stop"])), "crosswalk": draw(st.booleans()),
            "sockets": [{"angle": round(a, 3), "type": t, "lanes": k} for a, t, k in zip(angles, types, lanes)]}


@settings(max_examples=20, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much])
@given(junction_specs())
def test_random_valid_junction_specs_build_and_round_trip(junction):
    cfg = GenerationConfig()
    spec = parse_spec({"junctions": [junction]}, "random.yaml")
    f = spec.junctions[0].feature
    assume(junction_radius(f, cfg) <= cfg.grid_gap / 2 - MIN_STUB_LENGTH_M - cfg.junction_margin)
    m = build_spec(spec)
    assert check_map(m) == []
    got = extract_junctions(m)[0].feature
    assert feature_mismatch(got, f.normalized()) == []
    # signals / stop signs exactly on the entering sockets
    n_entries = sum(1 for s in f.sockets if s.lanes_in)
    assert len(m.signals) + len(m.stop_signs) == (n_entries if f.control != "bare" else 0)
    # lane counts flow through: per road, the lanes in each direction are the socket's
    total = sum(s.lanes_in + s.lanes_out for s in f.sockets)
    assert sum(len(m.roads[r].lane_ids) for r in m.junctions["J0"].socket_roads) == total


@st.composite
def network_specs(draw):
    """2-4 junctions with random road types and lane counts, some pinned to random cells."""
    junctions = []
    cells = draw(st.lists(st.tuples(st.integers(0, 2), st.integers(0, 1)), min_size=4, max_size=4, unique=True))
    for i in range(draw(st.integers(2, 4))):
        n = draw(st.sampled_from([3, 4]))
        sockets = []
        for a in range(n):
            s = {"angle": a * 360 // n}
            if draw(st.booleans()):
                s["lanes_in"], s["lanes_out"] = draw(st.sampled_from([(1, 1), (2, 2), (1, 0), (0, 1), (2, 1), (0, 2)]))
            sockets.append(s)
        j = {"control": draw(st.sampled_from(["bare", "signal", "stop"])), "sockets": sockets}
        if draw(st.booleans()):
            j["cell"] = list(cells[i])
        junctions.append(j)
    return {"junctions": junctions}


@settings(max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(network_specs(), st.integers(0, 3))
def test_random_networks_build_valid_maps_or_fail_naming_an_element(doc, seed):
    try:
        m = build_spec(parse_spec(doc, "net.yaml"), seed=seed)
    except SpecError as exc:
        assert str(exc).startswith("net.yaml: ") and "\n" not in str(exc)
        return
    assert check_map(m) == []
    for i, j in enumerate(doc["junctions"]):
        if "cell" in j:
            assert m.junctions[f"J{i}"].cell == tuple(j["cell"])


def test_spec_junctions_on_top_of_a_feature_space():
    space = FeatureSpace((3,), ("stop",), (False,), {3: ((-10, 10), (80, 100), (170, 190))})
    spec = load_spec(EXAMPLES / "mega_junction.yaml")
    m = build_spec(spec, seed=3, space=space)
    assert check_map(m) == []
    feats = [m.junctions[f"J{i}"].feature for i in range(len(m.junctions))]
    assert feats[0].n_roads == 5 and feats[0].control == "signal"  # spec junctions come first
    assert [(f.n_roads, f.control) for f in feats[1:]] == [(3, "stop")]
    assert m.meta["feature_space"] == space.to_dict()


def test_cli_generate_from_spec_writes_the_sampled_pipelines_outputs(tmp_path, capsys):
    out = tmp_path / "mega"
    assert main(["generate", "--spec", str(EXAMPLES / "mega_junction.yaml"), "--out", str(out), "--quiet"]) == 0
    assert {"map.json", "features.json", "map.png", "junctions.png", "apollo"} <= {p.name for p in out.iterdir()}
    m = native.load(out / "map.json")
    assert check_map(m) == [] and len(m.junctions) == 1
    space = FeatureSpace.from_json((out / "features.json").read_text())
    assert space.road_counts == (5,) and space.controls == ("signal",)
    # mixed use: spec junctions on top of the features extracted from a map
    mixed = tmp_path / "mixed"
    assert main(["generate", "--from-maps", str(out / "map.json"), "--spec", str(EXAMPLES / "one_way_t.yaml"),
                 "--out", str(mixed), "--quiet", "--no-picture"]) == 0
    m2 = native.load(mixed / "map.json")
    assert check_map(m2) == []
    assert sorted(j.feature.n_roads for j in m2.junctions.values()) == [3, 5]


@pytest.mark.real_maps
def test_cli_spec_on_top_of_a_real_maps_features(tmp_path):
    from conftest import shared_map

    real = shared_map("apollo/borregas_ave/base_map.bin")
    out = tmp_path / "mixed"
    assert main(["generate", "--from-maps", str(real), "--spec", str(EXAMPLES / "one_way_t.yaml"), "--out", str(out),
                 "--quiet", "--no-picture", "--no-apollo"]) == 0
    m = native.load(out / "map.json")
    assert check_map(m) == []
    want = load_spec(EXAMPLES / "one_way_t.yaml").junctions[0].feature.normalized()
    assert feature_mismatch(m.junctions["J0"].feature, want) == []  # the spec junction comes first
    assert len(m.junctions) > 1 and "feature_space" in m.meta


@pytest.mark.parametrize("args,message", [
    (["--spec", "{dir}/bad.yaml"], "bad.yaml: junctions[0].sockets[1]: same direction"),
    (["--spec", "{dir}/nope.yaml"], "nope.yaml: cannot read"),
    (["--spec", str(EXAMPLES / "mega_junction.yaml"), "--grid-gap", "60"], "junctions[0]: legs too close"),
])
def test_cli_bad_specs_exit_2_and_write_nothing(tmp_path, capsys, args, message):
    (tmp_path / "bad.yaml").write_text(yaml.safe_dump(J(0, 360, 180)))
    out = tmp_path / "out"
    code = main(["generate", *[a.format(dir=tmp_path) for a in args], "--out", str(out), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2
    assert message in err and err.count("\n") == 1 and "Traceback" not in err
    assert not out.exists()
    assert [p.name for p in tmp_path.iterdir() if p.name not in {"bad.yaml"}] == []


@pytest.mark.parametrize("name", ["mega_junction", "multi_lane"])
def test_spec_maps_drive_in_the_env(example_maps, name):
    """The mega junction (a left turn through the signal) and the multi-lane/one-way pair
    (a sampled route through both junctions) are driven to the goal without violations."""
    import gymnasium as gym

    from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver

    _, m = example_maps[name]
    route = None
    if name == "mega_junction":
        lane = next(ln for ln in m.junction_lanes("J0") if ln.turn == "left")
        route = [("J0", m.lanes[lane.predecessors[0]].road_id, m.lanes[lane.successors[0]].road_id)]
    env = gym.make("feat2map/MapFile-v0", config={"map": m, "route": route, "route_junctions": 2,
                                                    "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5,
                                                    "duration": 60, "traffic_vehicles": 3})
    env.reset(seed=0)
    driver = ScriptedDriver(env)
    for _ in range(400):
        _, _, term, trunc, info = env.step(driver.act())
        if term or trunc:
            break
    env.close()
    assert info["route_completed"], info
    assert info["violations"] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}
    assert not info["collision"] and not info["off_road"]
    assert info["route_progress"] == pytest.approx(1.0, abs=0.05)
