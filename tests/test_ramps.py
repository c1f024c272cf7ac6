"""Motorway ramps: the junction feature's per-socket `ramp` and `ramp_length`, the map feature's
`ramp` values and their sampling, spec requests, construction (acceleration and deceleration
lanes beside the main lanes), exports and extraction, on maps generated here; old feature files
and specs (no `ramp`) give the same bytes as before."""
from __future__ import annotations

import json
import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml
from conftest import ROUND_TRIPS, corpus_map, export_problems, numpy_avx512, round_trip, sha256_text

from feat2map.config import (JUNCTION_SPEED_LIMIT_MPS, MAX_MOTORWAY_LANES, MOTORWAY_SPEED_LIMIT_MPS, RAMP_ANGLE_RANGE_DEG,
                             RAMP_LANE_M, RAMP_SPEED_LIMIT_MPS, SPEED_LIMIT_MPS, GenerationConfig)
from feat2map.errors import ConfigError, FeatureError
from feat2map.extract import extract_junctions, map_feature
from feat2map.features import PAPER_SF_FEATURE_SPACE, FeatureSpace, JunctionFeature, Socket, ramp_angle, ramp_junction
from feat2map.formats import native, write_map
from feat2map.generate import generate, generate_from_features
from feat2map.invariants import check_map, feature_mismatch
from feat2map.model import HDMap
from feat2map.spec import SpecError, build_spec, load_spec, parse_spec

REPO = Path(__file__).resolve().parents[1]
SPACE = replace(PAPER_SF_FEATURE_SPACE, ramp=("none", "on", "off", "both"))
SPACE_LANES = replace(SPACE, motorway_lanes=(1, 2))  # ramp junctions on one- and two-lane motorways
# sha256 of the native JSON of maps whose inputs name no ramp, recorded with the code before ramps
# existed: such inputs must keep giving these bytes
PAPER_SEED0_SHA = "a374afe338eaccdd5e249e518121927e73c1788b428a82240fec5fdeec7da902"
FILTER_SPEC_SHA = "85343e462a3393fdbc271661e81694ddd23d1f46b5d2dfcde649c13f7de2b44b"
# (NumPy's AVX-512 kernels round a few coordinates of this map differently: `numpy_avx512`)
MEGA_SPEC_SHA = {False: "a741b31e954a6fb284632eec05a387f367c0c28ba4680feb9bf769737d3e5c71",
                 True: "5146d15a3d70a35ed8a3464b2f1cad422ceddf5a71b061a520cbcde9052fb013"}[numpy_avx512()]


@pytest.fixture(scope="module")
def sampled() -> HDMap:
    return generate(SPACE, seed=0)


@pytest.fixture(scope="module")
def sampled_lanes() -> HDMap:
    return generate(SPACE_LANES, seed=0)


@pytest.fixture(scope="module")
def spec_map() -> HDMap:
    return build_spec(load_spec(REPO / "examples" / "ramps.yaml"), seed=0)


def ramp_lanes(m: HDMap) -> dict[str, list[str]]:
    """Junction lanes from an on-ramp ("on") and into an off-ramp ("off"), by the ramp roads' ends."""
    ramps = {s for j in m.junctions.values() if j.feature is not None and j.feature.has_ramp
             for s, sock in zip(j.socket_roads, j.feature.sockets) if sock.ramp != "none"}
    out: dict[str, list[str]] = {"on": [], "off": []}
    for ln in m.lanes.values():
        if ln.junction_id is None:
            continue
        if any(m.lanes[p].road_id in ramps for p in ln.predecessors):
            out["on"].append(ln.id)
        if any(m.lanes[s].road_id in ramps for s in ln.successors):
            out["off"].append(ln.id)
    return out


# ------------------------------------------------------------------------------ feature model

def test_old_feature_files_and_specs_give_the_bytes_they_always_did(monkeypatch):
    old = json.loads(PAPER_SF_FEATURE_SPACE.to_json())
    assert "ramp" not in old
    space = FeatureSpace.from_dict(old)
    assert space.ramp == ("none",) and space == PAPER_SF_FEATURE_SPACE
    assert sha256_text(native.dumps(generate(space, seed=0))) == PAPER_SEED0_SHA
    monkeypatch.chdir(REPO)  # the map records the spec's path as given
    assert sha256_text(native.dumps(build_spec(load_spec("examples/filter_lanes.yaml"), seed=0))) == FILTER_SPEC_SHA
    assert sha256_text(native.dumps(build_spec(load_spec("examples/mega_junction.yaml"), seed=0))) == MEGA_SPEC_SHA
    f = JunctionFeature.make([0, 90, 180, 270], "signal")
    assert "ramp" not in f.to_dict() and "ramp_length" not in f.to_dict() and JunctionFeature.from_dict(f.to_dict()) == f


def test_ramp_values_round_trip_and_bad_ones_are_named():
    assert SPACE.ramp_kinds == ("on", "off", "both")
    assert FeatureSpace.from_json(SPACE.to_json()) == SPACE
    with pytest.raises(FeatureError, match="ramp.*slip"):
        FeatureSpace.from_dict({**SPACE.to_dict(), "ramp": ["slip"]}, "f.json")
    f = ramp_junction("both", 12.0, main_lanes=2)
    assert f.ramp_value == "both" and f.ramp_length == RAMP_LANE_M
    assert JunctionFeature.from_dict(f.to_dict()) == f
    assert f.to_dict()["ramp"] == ["off", "none", "none", "on"]
    n = f.normalized()
    assert sorted(n.ramps) == sorted(f.ramps) and n.normalized() == n
    assert [round(ramp_angle(n, i), 6) for i, s in enumerate(n.sockets) if s.ramp != "none"] == [12.0, 12.0]
    assert PAPER_SF_FEATURE_SPACE.merge(SPACE).ramp == ("none", "on", "off", "both")
    # a map feature of ramp junctions only: no junction combinations, the ramp values
    only = FeatureSpace.from_features([ramp_junction("on", 12.0)])
    assert only.road_counts == () and only.ramp == ("none", "on")
    assert FeatureSpace.from_json(only.to_json()) == only


@pytest.mark.parametrize("sockets, message", [
    ((Socket(0), Socket(180), Socket(192, 1, 1, ramp="on")), "on-ramp is one-way in"),
    ((Socket(0), Socket(180), Socket(183, 1, 0, ramp="on")), "3.00 degrees from its main leg"),
    ((Socket(0), Socket(120), Socket(132, 1, 0, ramp="on")), "off straight on"),
    ((Socket(0), Socket(90), Socket(180), Socket(192, 1, 0, ramp="on")), "two main legs"),
    ((Socket(-12, 1, 0, ramp="off"), Socket(0), Socket(180)), "off-ramp is one-way out"),
])
def test_bad_ramp_junctions_are_named(sockets, message):
    with pytest.raises(FeatureError, match=message):
        JunctionFeature(sockets)


def test_a_ramp_junction_is_bare_without_crosswalks():
    with pytest.raises(FeatureError, match="bare"):
        JunctionFeature((Socket(0), Socket(180), Socket(192, 1, 0, ramp="on")), "signal")


# ------------------------------------------------------------------------------ generation

def test_sampling_covers_every_ramp_value(sampled):
    ramps = [j.feature for j in sampled.junctions.values() if j.feature.has_ramp]
    assert len(sampled.junctions) == 8 + 3  # the paper's 8 combinations and one ramp junction per ramp value
    assert sorted(f.ramp_value for f in ramps) == ["both", "off", "on"]
    for f in ramps:
        angles = [ramp_angle(f, i) for i, s in enumerate(f.sockets) if s.ramp != "none"]
        assert all(RAMP_ANGLE_RANGE_DEG[0] <= a <= RAMP_ANGLE_RANGE_DEG[1] for a in angles)
    assert check_map(sampled) == []
    assert sha256_text(native.dumps(generate(SPACE, seed=0))) == sha256_text(native.dumps(sampled))  # seeded
    lanes = ramp_lanes(sampled)
    assert len(lanes["on"]) == 3 and len(lanes["off"]) == 3  # "both": the on-ramp's lane also goes on to the off-ramp


def assert_ramps_join_the_rightmost(m: HDMap) -> dict[str, list[str]]:
    """Each ramp's lane runs the acceleration or deceleration lane's length beside the main lanes
    and joins (leaves) its carriageway's rightmost lane, which a main lane also feeds (also goes
    on); returns `ramp_lanes(m)`."""
    lanes = ramp_lanes(m)
    for lid in lanes["on"] + lanes["off"]:
        ln = m.lanes[lid]
        assert ln.turn == "none"  # a ramp's lane bends by the ramp angle only
        # as long as the acceleration or deceleration lane: between the main sockets, 75 m apart (an
        # on-ramp's lane going on to an off-ramp bows out to them, the more beside a two-lane road)
        assert RAMP_LANE_M <= ln.length <= RAMP_LANE_M * 1.03
    for lid in lanes["on"]:  # it joins the carriageway's rightmost lane, which the main lane also feeds
        (dst,) = m.lanes[lid].successors
        road = m.roads[m.lanes[dst].road_id]
        side = road.right_lanes if dst in road.right_lanes else road.left_lanes
        assert dst == side[-1] and len(m.lanes[dst].predecessors) == 2
    for lid in lanes["off"]:  # it leaves the carriageway's rightmost lane, which also goes on
        (src,) = m.lanes[lid].predecessors
        road = m.roads[m.lanes[src].road_id]
        side = road.right_lanes if src in road.right_lanes else road.left_lanes
        assert src == side[-1] and len(m.lanes[src].successors) == 2
    return lanes


def test_sampled_ramp_junctions_take_their_main_roads_lanes_from_the_space(sampled_lanes):
    """A map feature's `motorway_lanes` (1 and 2 here): one ramp junction per ramp value and lane
    count, its main legs that many lanes per direction, its ramps steep enough to clear the wider
    road within RAMP_LANE_M; the two-lane ones make a motorway of their own (no town junction has
    two-lane legs), driven at the motorway's speed between them; seeded."""
    from itertools import product

    from feat2map.ramps import min_ramp_angle

    ramps = [j.feature for j in sampled_lanes.junctions.values() if j.feature.has_ramp]
    mains = [{(s.lanes_in, s.lanes_out) for s in f.sockets if s.ramp == "none"} for f in ramps]
    assert all(len(m) == 1 and len(next(iter(m))) == 2 and len(set(next(iter(m)))) == 1 for m in mains)
    got = sorted((f.ramp_value, next(iter(m))[0]) for f, m in zip(ramps, mains))
    assert got == sorted(product(("on", "off", "both"), (1, 2)))
    least = min_ramp_angle(2, RAMP_LANE_M, GenerationConfig())
    assert RAMP_ANGLE_RANGE_DEG[0] < least < RAMP_ANGLE_RANGE_DEG[1]
    for f, m in zip(ramps, mains):
        lo = least if next(iter(m))[0] == 2 else RAMP_ANGLE_RANGE_DEG[0]
        assert all(lo <= ramp_angle(f, i) <= RAMP_ANGLE_RANGE_DEG[1] for i, s in enumerate(f.sockets) if s.ramp != "none")
    assert check_map(sampled_lanes) == []
    assert len(assert_ramps_join_the_rightmost(sampled_lanes)["on"]) == 2 * 3  # "both": on to its off-ramp too
    wide = [r for r in sampled_lanes.roads.values() if r.kind == "connection" and len(r.lane_ids) == 4]
    assert len(wide) == 2 and all(sampled_lanes.lanes[x].speed_limit == MOTORWAY_SPEED_LIMIT_MPS
                                  for r in wide for x in r.lane_ids)
    assert sha256_text(native.dumps(generate(SPACE_LANES, seed=0))) == sha256_text(native.dumps(sampled_lanes))
    assert FeatureSpace.from_json(SPACE_LANES.to_json()) == SPACE_LANES
    assert json.loads(SPACE_LANES.to_json())["motorway_lanes"] == [1, 2] and "motorway_lanes" not in SPACE.to_dict()
    with pytest.raises(FeatureError, match="motorway_lanes.*1 to 3"):
        FeatureSpace.from_dict({**SPACE.to_dict(), "motorway_lanes": [0, 2]}, "f.json")
    widest = FeatureSpace((), (), (), {}, ramp=("none", "on", "off", "both"), motorway_lanes=(MAX_MOTORWAY_LANES,))
    assert check_map(generate(widest, seed=0)) == []  # its ramps steeper than the range, still ramps


def test_ramp_lanes_run_beside_the_main_lanes_and_join_the_rightmost(spec_map):
    assert check_map(spec_map) == []
    feats = {jid: j.feature for jid, j in spec_map.junctions.items()}
    assert feats["J0"].ramp_value == "off" and feats["J1"].ramp_value == "both" and not feats["J2"].has_ramp
    lanes = assert_ramps_join_the_rightmost(spec_map)
    assert len(lanes["on"]) == 1 and len(lanes["off"]) == 2
    ramp_roads = [r for r in spec_map.roads.values() if r.kind == "stub" and len(r.lane_ids) == 1]
    assert len(ramp_roads) == 3 and all(r.reference.length >= 10.0 for r in ramp_roads)


def test_the_main_road_connects_to_city_junctions_lane_for_lane(spec_map):
    j2 = spec_map.junctions["J2"]
    west = spec_map.roads[j2.socket_roads[2]]
    assert len(west.right_lanes) == len(west.left_lanes) == 2


@pytest.mark.parametrize("change, path, message", [
    ({"ramp_length": 40}, "junctions[0].ramp_length", "too short"),
    ({"ramp_length": 120}, "junctions[0].ramp_length", "grid_gap >= 143"),
    ({"sockets": [{"angle": -15, "type": "in", "ramp": {"kind": "off"}}, {"angle": 0, "lanes": 2},
                  {"angle": 180, "lanes": 2}]}, "junctions[0].sockets[0].ramp", "one-way out"),
    ({"sockets": [{"angle": 0, "lanes": 2}, {"angle": 180, "lanes": 2},
                  {"angle": 200, "type": "in", "ramp": {"kind": "on"}},
                  {"angle": 204, "type": "in"}]}, "junctions[0].sockets[3]", "4 deg from sockets\\[2\\]"),
    ({"sockets": [{"angle": -15, "type": "out", "ramp": {"kind": "off"}, "filter": {}}, {"angle": 0, "lanes": 2},
                  {"angle": 180, "lanes": 2}]}, "junctions[0].sockets[0].filter", "no filter lane"),
])
def test_bad_ramp_requests_name_their_element(change, path, message):
    doc = {"junctions": [{"sockets": [{"angle": -15, "type": "out", "ramp": {"kind": "off"}}, {"angle": 0, "lanes": 2},
                                      {"angle": 180, "lanes": 2}], **change}]}
    with pytest.raises(SpecError, match=message) as err:
        build_spec(parse_spec(doc, "s.yaml"))
    assert f"s.yaml: {path}" in str(err.value)


def test_an_unquoted_yaml_off_is_named_with_the_hint():
    doc = yaml.safe_load("junctions:\n  - sockets: [{angle: -15, type: out, ramp: {kind: off}}, 0, 180]\n")
    with pytest.raises(SpecError, match="quote it") as err:
        parse_spec(doc, "s.yaml")
    assert "s.yaml: junctions[0].sockets[0].ramp.kind" in str(err.value)


def test_generate_from_ramps_alone_and_from_a_spec_with_a_space(tmp_path):
    m = generate_from_features([ramp_junction("both", 15.0, main_lanes=2)], 0)
    assert check_map(m) == []
    m = build_spec(load_spec(REPO / "examples" / "ramps.yaml"), seed=0, space=SPACE)
    assert sum(j.feature.has_ramp for j in m.junctions.values()) == 2 + 3 and check_map(m) == []


def test_a_feature_space_of_ramps_alone_generates(tmp_path, capsys):
    from feat2map.cli import main

    doc = {"road_counts": [], "controls": [], "crosswalks": [], "rotation_ranges": {}, "ramp": ["none", "on", "both"]}
    (tmp_path / "f.json").write_text(json.dumps(doc))
    assert main(["generate", "--features", str(tmp_path / "f.json"), "--no-picture", "--no-apollo", "--quiet",
                 "--out", str(tmp_path / "g")]) == 0
    m = native.load(tmp_path / "g" / "map.json")
    assert sorted(j.feature.ramp_value for j in m.junctions.values()) == ["both", "on"] and check_map(m) == []
    with pytest.raises(FeatureError, match="must each be non-empty"):  # no junctions and no ramps
        FeatureSpace.from_dict({**doc, "ramp": ["none"]})


def lane_speeds(m: HDMap) -> dict[str, set[float]]:
    """The speed limits of the example's lanes by kind: the motorway (main roads and lanes straight
    on), ramp roads, acceleration and deceleration lanes, town roads and town junction lanes."""
    ramps = {s for j in m.junctions.values() if j.feature.has_ramp
             for s, sock in zip(j.socket_roads, j.feature.sockets) if sock.ramp != "none"}
    aux = ramp_lanes(m)
    out: dict[str, set[float]] = {}
    for ln in m.lanes.values():
        if ln.id in aux["on"] or ln.id in aux["off"]:
            kind = "acceleration" if ln.id in aux["on"] else "deceleration"
        elif ln.junction_id is not None:
            kind = "motorway" if m.junctions[ln.junction_id].feature.has_ramp else "town junction"
        elif ln.road_id in ramps:
            kind = "ramp"
        else:
            road = m.roads[ln.road_id]
            ends = [m.junctions[j].feature for j in (road.start_junction, road.end_junction) if j is not None]
            kind = "motorway" if all(f.has_ramp for f in ends) else "town"
        out.setdefault(kind, set()).add(ln.speed_limit)
    return out


def assert_same_speeds(back: HDMap, m: HDMap) -> None:
    """Every lane of `m` read back (`back`, another format: other ids, maybe another origin) with
    its speed limit: lanes matched by the middles of their centre lines, within 0.3 m."""
    def middles(x: HDMap) -> tuple[np.ndarray, list[float]]:
        mids = []
        for ln in x.lanes.values():
            pts = np.asarray(ln.centerline, dtype=float)
            cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
            mids.append([np.interp(cum[-1] / 2, cum, pts[:, k]) for k in (0, 1)])
        at = np.asarray(mids)
        return at - at.min(axis=0), [ln.speed_limit for ln in x.lanes.values()]

    (want_at, want), (got_at, got) = middles(m), middles(back)
    assert len(got) == len(want)
    for p, v in zip(want_at, want):
        k = int(np.argmin(np.hypot(*(got_at - p).T)))
        assert np.hypot(*(got_at[k] - p)) < 0.3 and got[k] == pytest.approx(v, abs=1e-3), (p, v, got[k])


def test_ramp_junctions_carry_motorway_and_ramp_speeds(spec_map):
    """The main carriageway and its acceleration lanes at the motorway's limit, the ramps and the
    deceleration lanes at the ramp's, the motorway's road into the town junction at the town's."""
    assert lane_speeds(spec_map) == {
        "motorway": {MOTORWAY_SPEED_LIMIT_MPS}, "acceleration": {MOTORWAY_SPEED_LIMIT_MPS},
        "deceleration": {RAMP_SPEED_LIMIT_MPS}, "ramp": {RAMP_SPEED_LIMIT_MPS}, "town": {SPEED_LIMIT_MPS},
        "town junction": {JUNCTION_SPEED_LIMIT_MPS}}
    assert JUNCTION_SPEED_LIMIT_MPS < SPEED_LIMIT_MPS < RAMP_SPEED_LIMIT_MPS < MOTORWAY_SPEED_LIMIT_MPS


def test_motorway_and_ramp_speeds_are_configured_and_recorded_only_when_set(monkeypatch):
    cfg = GenerationConfig(motorway_speed_limit=30.0, ramp_speed_limit=20.0)
    monkeypatch.chdir(REPO)
    m = build_spec(load_spec("examples/ramps.yaml"), seed=0, config=cfg)
    speeds = lane_speeds(m)
    assert speeds["motorway"] == speeds["acceleration"] == {30.0} and speeds["ramp"] == speeds["deceleration"] == {20.0}
    assert m.meta["config"]["motorway_speed_limit"] == 30.0 and GenerationConfig.from_dict(m.meta["config"]) == cfg
    assert "motorway_speed_limit" not in GenerationConfig().to_dict()  # old maps' recorded config keeps its bytes
    with pytest.raises(ConfigError, match="ramp_speed_limit"):
        GenerationConfig(ramp_speed_limit=0.0)
    doc = {**yaml.safe_load((REPO / "examples" / "ramps.yaml").read_text()), "config": {"ramp_speed_limit": 200}}
    with pytest.raises(SpecError, match="r.yaml: config: config field 'ramp_speed_limit' must be between 0.1 and 100"):
        build_spec(parse_spec(doc, "r.yaml"))


# ------------------------------------------------------------------------------ exports

@pytest.mark.parametrize("fmt", ["apollo", "lanelet2", "commonroad", "opendrive"])
@pytest.mark.parametrize("which", ["spec_map", "sampled", "sampled_lanes"])
def test_exports_with_ramps_validate(tmp_path, request, fmt, which):
    """Every export of the example spec and of sampled maps with ramps (on one- and two-lane
    motorways) passes its ecosystem's own checks (the OpenDRIVE one: ASAM's qc_opendrive)."""
    problems = export_problems(request.getfixturevalue(which), fmt, tmp_path)
    assert problems == [], problems[:3]


@pytest.mark.parametrize("fmt, name", ROUND_TRIPS)
def test_ramp_junctions_survive_a_round_trip(tmp_path, spec_map, fmt, name):
    from feat2map.extract_ramps import extract_ramps

    back = round_trip(spec_map, tmp_path, fmt, name)
    got = [j.feature for j in extract_junctions(back)]  # OpenDRIVE numbers the junctions
    for want, j in zip(spec_map.junctions.values(), got):
        assert feature_mismatch(j, want.feature) == []
    assert sorted(r.kind for r in extract_ramps(back)) == ["off", "off", "on"]
    assert_same_speeds(back, spec_map)  # motorway, ramp and town speeds as written
    assert {MOTORWAY_SPEED_LIMIT_MPS, RAMP_SPEED_LIMIT_MPS} <= {round(ln.speed_limit, 2) for ln in back.lanes.values()}


def test_openscenario_routes_through_ramps_pass_asam_qc(tmp_path, spec_map):
    """The suite's scenarios that merge from an on-ramp or diverge onto an off-ramp pass ASAM's
    OpenSCENARIO checks."""
    from conftest import SKIP_QC_OPENSCENARIO

    from feat2map.formats.asam_qc import OPENSCENARIO, find_bundle
    from feat2map.formats.openscenario import validate_openscenario, write_openscenario
    from feat2map.scenarios.routes import build_suite

    native.save(spec_map, tmp_path / "map.json")
    suite = build_suite(tmp_path / "map.json", traffic_vehicles=6, seed=0)
    ramps = {r for j in spec_map.junctions.values() if j.feature.has_ramp
             for r, s in zip(j.socket_roads, j.feature.sockets) if s.ramp != "none"}
    taking = tuple(sc for sc in suite.scenarios if any(mv[1] in ramps or mv[2] in ramps for mv in sc.route))
    assert {r for sc in taking for mv in sc.route for r in mv[1:] if r in ramps} == ramps
    files = write_openscenario(type(suite)(suite.name, taking), tmp_path / "x")
    assert len(files) == len(taking) >= 3
    if find_bundle(OPENSCENARIO[0]) is None:
        pytest.skip(SKIP_QC_OPENSCENARIO)
    for f in files:
        assert validate_openscenario(f) == [], f.name


def test_lanelet2_writes_motorway_and_ramp_speeds(tmp_path, spec_map):
    import xml.etree.ElementTree as ET

    from feat2map.formats.lanelet2.writer import TAG

    write_map(spec_map, tmp_path / "m.osm", "lanelet2")
    kmh = {}
    for rel in ET.parse(tmp_path / "m.osm").getroot().iter("relation"):
        tags = {t.get("k"): t.get("v") for t in rel.iter("tag")}
        if tags.get("type") == "lanelet" and TAG + "lane" in tags:
            kmh[tags[TAG + "lane"]] = float(tags["speed_limit"])
    assert kmh.keys() == spec_map.lanes.keys()
    for lid, ln in spec_map.lanes.items():
        assert kmh[lid] == pytest.approx(ln.speed_limit * 3.6, abs=0.01), lid
    assert {round(v / 3.6, 2) for v in kmh.values()} >= {MOTORWAY_SPEED_LIMIT_MPS, RAMP_SPEED_LIMIT_MPS}


# ------------------------------------------------------------------------------ extraction

def test_extraction_finds_ramp_junctions_and_records_them_in_the_feature(sampled, spec_map):
    got = {e.id: e.feature for e in extract_junctions(sampled)}
    for jid, j in sampled.junctions.items():
        assert feature_mismatch(got[jid], j.feature) == [], jid
    assert map_feature(extract_junctions(sampled)).ramp == ("none", "on", "off", "both")
    got = {e.id: e.feature for e in extract_junctions(spec_map)}
    assert math.isclose(got["J1"].ramp_length, RAMP_LANE_M, abs_tol=0.01)
    assert got["J1"].ramps.count("on") == 1 and got["J1"].ramps.count("off") == 1


def test_extract_ramps_finds_every_generated_ramp(spec_map, sampled):
    from feat2map.extract_ramps import extract_ramps

    found = extract_ramps(spec_map)
    assert sorted(r.kind for r in found) == ["off", "off", "on"]
    assert {r.junction for r in found} == {"J0", "J1"}
    assert all(math.isclose(r.angle_deg, 15.0, abs_tol=1e-6) for r in found)
    assert all(RAMP_LANE_M <= r.length_m <= RAMP_LANE_M * 1.02 for r in found)  # the ramp lane, inside the junction
    found = extract_ramps(sampled)
    assert sorted(r.kind for r in found) == ["off", "off", "on", "on"]  # "on", "off" and "both"
    angles = {round(ramp_angle(j.feature, i), 4) for j in sampled.junctions.values()
              for i, s in enumerate(j.feature.sockets) if s.ramp != "none"}
    assert {round(r.angle_deg, 4) for r in found} == angles
    assert extract_ramps(generate(PAPER_SF_FEATURE_SPACE, seed=0)) == []  # city junctions hold none


def test_the_extract_command_lists_ramps(tmp_path, spec_map, capsys):
    from feat2map.cli import main

    native.save(spec_map, tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "[-15.00, 0.00, 15.00, 180.00]  ramps: 0 off, 2 on (75.00 m)\n" in out
    assert "  on-ramp R4 -> R5 at junction J1: 15.00 deg, 75.41 m (main road R1)\n" in out
    assert "3 ramps (1 on, 2 off)" in out
    assert main(["extract", str(tmp_path / "m.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["ramps"]) == 3 and doc["feature_space"]["ramp"] == ["none", "off", "both"]


@pytest.mark.real_maps
@pytest.mark.parametrize("rel, on, off", [
    ("asam_examples/UC_Motorway-Exit-Entry.xodr", 2, 2),  # ramp lanes joining as added lanes in 5 m junctions
    ("asam_qc/Ex_Entry_Exit.xodr", 1, 1),  # direct junctions
    ("roadrunner_2020/DR_CHN_Merging_ZS_partial_v02.xodr", 0, 0),  # lane drops within a road: no ramp road
    ("roadrunner_2020/DR_DEU_Merging_MT_v01_shifted.xodr", 0, 0),
])
def test_ramps_of_public_motorway_maps(rel, on, off):
    """Public motorway maps (not in the repository: a corpus folder beside it, docs/realmaps.md)
    declare their exits and entries as direct junctions or short junctions where a ramp's lane
    becomes an added lane; extraction finds each as a ramp."""
    import warnings

    from feat2map.extract_ramps import extract_ramps
    from feat2map.formats import read_map

    path = corpus_map(rel)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        found = extract_ramps(read_map(path), rel)
    assert (sum(r.kind == "on" for r in found), sum(r.kind == "off" for r in found)) == (on, off)
