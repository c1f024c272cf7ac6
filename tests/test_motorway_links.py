"""Motorway-to-motorway junctions: ramps that are motorway links (`Socket.link`), whose
carriageway gains the link's lanes (on) or drops them into it (off) lane for lane. The feature
model and its errors, the map feature's "link-" values and their sampling, spec requests,
construction (one-to-one lane connectivity, no merge), extraction, round trips and exports."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from conftest import ROUND_TRIPS, export_problems, round_trip

from feat2map.errors import FeatureError
from feat2map.extract import extract_junctions, map_feature
from feat2map.features import (PAPER_SF_FEATURE_SPACE, RAMP_VALUES, FeatureSpace, JunctionFeature, Socket,
                               ramp_carriageway, ramp_junction)
from feat2map.generate import generate, generate_from_features
from feat2map.invariants import check_map, feature_mismatch
from feat2map.model import HDMap
from feat2map.spec import SpecError, build_spec, load_spec, parse_spec

REPO = Path(__file__).resolve().parents[1]
LINKS = ("link-on", "link-off", "link-both")
SPACE = replace(PAPER_SF_FEATURE_SPACE, ramp=("none", *LINKS))


@pytest.fixture(scope="module")
def sampled() -> HDMap:
    return generate(SPACE, seed=0)


@pytest.fixture(scope="module")
def spec_map() -> HDMap:
    return build_spec(load_spec(REPO / "examples" / "motorway_links.yaml"), seed=0)


def link_sockets(m: HDMap) -> list[tuple[str, int]]:
    """(junction id, socket) of every motorway link of a map."""
    return [(jid, i) for jid, j in m.junctions.items() if j.feature is not None
            for i, s in enumerate(j.feature.sockets) if s.link]


def junction_lanes(m: HDMap, jid: str, src_road: str, dst_road: str) -> list[tuple[str, str]]:
    """(road lane before, road lane after) of the junction lanes of `jid` from one road to another."""
    return [(ln.predecessors[0], ln.successors[0]) for ln in m.lanes.values() if ln.junction_id == jid
            and m.lanes[ln.predecessors[0]].road_id == src_road and m.lanes[ln.successors[0]].road_id == dst_road]


# ------------------------------------------------------------------------------ feature model

def test_link_values_and_features_round_trip():
    assert RAMP_VALUES[-3:] == LINKS and SPACE.ramp_kinds == LINKS
    assert FeatureSpace.from_json(SPACE.to_json()) == SPACE
    for kind in LINKS:
        f = ramp_junction(kind, 12.0, main_lanes=2, ramp_lanes=2)
        assert f.ramp_value == kind and f.has_link
        assert JunctionFeature.from_dict(f.to_dict()) == f and f.to_dict()["link"] == [s.link for s in f.sockets]
        n = f.normalized()
        assert n.ramp_value == kind and n.normalized() == n
    f = ramp_junction("link-both", 12.0, main_lanes=2, ramp_lanes=1)
    assert [(s.lanes_in, s.lanes_out, s.ramp, s.link) for s in f.sockets] == [
        (3, 3, "none", False), (0, 1, "off", True), (2, 2, "none", False), (1, 0, "on", True)]
    assert ramp_carriageway(f, 3) == (2, 0) and ramp_carriageway(f, 1) == (0, 2)  # on: west -> east; off: east -> west
    assert "link" not in ramp_junction("both", 12.0).to_dict()  # plain ramps write what they always did


@pytest.mark.parametrize("sockets, message", [
    ((Socket(0, 2, 2), Socket(180, 2, 2), Socket(195, 1, 0, ramp="on", link=True)),
     "socket 2: the lanes of a motorway link \\(on-ramp\\) do not add up: the carriageway leaves at socket 0 with "
     "2 lane\\(s\\), not the 2 entering at socket 1 plus the link's 1"),
    ((Socket(0, 2, 2), Socket(165, 0, 1, ramp="off", link=True), Socket(180, 2, 2)),
     "socket 1: the lanes of a motorway link \\(off-ramp\\) do not add up"),
    ((Socket(0, 2, 2), Socket(165, 0, 1, ramp="off", link=True), Socket(180, 1, 1),
      Socket(195, 1, 0, ramp="on")), "all motorway links .* or none are"),
    ((Socket(-15, 0, 1, ramp="off", link=True), Socket(0, 2, 2), Socket(180, 2, 2),
      Socket(195, 1, 0, ramp="on", link=True)), "a motorway link's carriageway has no other ramp"),
    ((Socket(0, 1, 1, link=True), Socket(90), Socket(180)), "socket 0: link .* true only on a ramp"),
])
def test_impossible_links_are_named(sockets, message):
    with pytest.raises(FeatureError, match=message):
        JunctionFeature(sockets)


@pytest.mark.parametrize("socket, path, message", [
    ({"angle": 195, "type": "in", "lanes": 2, "ramp": {"kind": "on", "link": True}},
     "junctions[0].sockets[3].ramp", "do not add up"),
    ({"angle": 195, "type": "in", "ramp": {"kind": "on", "link": "yes"}},
     "junctions[0].sockets[3].ramp.link", "must be true or false"),
])
def test_bad_link_requests_name_their_element(socket, path, message):
    doc = {"junctions": [{"sockets": [{"angle": 0, "lanes": 2},
                                      {"angle": 165, "type": "out", "ramp": {"kind": "off", "link": True}},
                                      {"angle": 180, "lanes": 1}, socket]}]}
    with pytest.raises(SpecError, match=message) as err:
        build_spec(parse_spec(doc, "s.yaml"))
    assert f"s.yaml: {path}" in str(err.value)


# ------------------------------------------------------------------------------ construction

def check_one_to_one(m: HDMap) -> int:
    """Asserts every link junction's carriageways pair their lanes one to one (lane gain / lane
    drop: no junction lane shares its road lane before or after with another); returns how many
    link lanes it saw."""
    seen = 0
    for jid, i in link_sockets(m):
        j = m.junctions[jid]
        f = j.feature
        assert f is not None
        up, down = ramp_carriageway(f, i)
        roads = j.socket_roads
        main = junction_lanes(m, jid, roads[up], roads[down])
        if f.sockets[i].ramp == "on":
            link = junction_lanes(m, jid, roads[i], roads[down])
            fed, feeding = [d for _, d in link + main], [s for s, _ in main]
            assert len(link) == f.sockets[i].lanes_in and len(main) == f.sockets[up].lanes_in
            assert len(set(fed)) == len(fed) == f.sockets[down].lanes_out  # every downstream lane fed once
            assert len(set(feeding)) == len(feeding)
        else:
            link = junction_lanes(m, jid, roads[up], roads[i])
            fed, feeding = [d for _, d in main], [s for s, _ in link + main]
            assert len(link) == f.sockets[i].lanes_out and len(main) == f.sockets[down].lanes_out
            assert len(set(feeding)) == len(feeding) == f.sockets[up].lanes_in  # every upstream lane goes on once
            assert len(set(fed)) == len(fed)
        for src, dst in main + link:  # no merge, no split
            assert len(m.lanes[dst].predecessors) == 1 and len(m.lanes[src].successors) == 1
        for src, _ in main:  # main lanes run straight on
            (lid,) = m.lanes[src].successors
            assert m.lanes[lid].turn == "none"
        seen += len(link)
    return seen


def test_the_example_gains_and_drops_link_lanes_one_to_one(spec_map):
    assert check_map(spec_map) == []
    assert [j.feature.ramp_value for j in spec_map.junctions.values()] == ["link-both", "link-both"]
    assert check_one_to_one(spec_map) == 4
    for jid, i in link_sockets(spec_map):  # a link's lane runs beside the main lanes: as long as ramp_length
        j = spec_map.junctions[jid]
        link = j.socket_roads[i]
        lanes = [ln for ln in spec_map.lanes.values() if ln.junction_id == jid
                 and link in {spec_map.lanes[x].road_id for x in ln.predecessors + ln.successors}]
        assert len(lanes) == 1 and j.feature.ramp_length <= lanes[0].length <= j.feature.ramp_length * 1.02


def test_multi_lane_links_and_sampling_cover_every_link_value(sampled):
    m = generate_from_features([ramp_junction("link-both", 15.0, main_lanes=1, ramp_lanes=2)], 0)
    assert check_map(m) == [] and check_one_to_one(m) == 4
    links = [j.feature for j in sampled.junctions.values() if j.feature.has_ramp]
    assert sorted(f.ramp_value for f in links) == sorted(LINKS)
    assert check_map(sampled) == [] and check_one_to_one(sampled) == 4


# ------------------------------------------------------------------------------ extraction

def test_extraction_finds_links_and_records_them_in_the_feature(sampled, spec_map):
    for m in (sampled, spec_map):
        got = {e.id: e.feature for e in extract_junctions(m)}
        for jid, j in m.junctions.items():
            assert feature_mismatch(got[jid], j.feature) == [], jid
    assert map_feature(extract_junctions(sampled)).ramp == ("none", *LINKS)
    # a plain ramp with the same lane counts stays a ramp: its lane merges into the rightmost one
    plain = replace(ramp_junction("link-on", 12.0), sockets=tuple(replace(s, link=False)
                                                                  for s in ramp_junction("link-on", 12.0).sockets))
    (got,) = [e.feature for e in extract_junctions(generate_from_features([plain], 0))]
    assert got.ramp_value == "on" and not got.has_link


@pytest.mark.parametrize("fmt, name", ROUND_TRIPS)
def test_link_junctions_survive_a_round_trip(tmp_path, spec_map, fmt, name):
    back = round_trip(spec_map, tmp_path, fmt, name)
    got = [j.feature for j in extract_junctions(back)]
    assert len(got) == len(spec_map.junctions)
    for want, j in zip(spec_map.junctions.values(), got):
        assert feature_mismatch(j, want.feature) == []


# ------------------------------------------------------------------------------ exports

@pytest.mark.parametrize("fmt", ["apollo", "lanelet2", "commonroad", "opendrive"])
@pytest.mark.parametrize("which", ["spec_map", "sampled"])
def test_exports_with_links_validate(tmp_path, request, fmt, which):
    """Every export of the example and of a sampled map with every link value passes its
    ecosystem's own checks (the OpenDRIVE one: ASAM's qc_opendrive)."""
    problems = export_problems(request.getfixturevalue(which), fmt, tmp_path)
    assert problems == [], problems[:3]


def test_openscenario_routes_through_links_pass_asam_qc(tmp_path, spec_map):
    """The example's suite takes every link both ways, and its scenarios pass ASAM's OpenSCENARIO checks."""
    from conftest import SKIP_QC_OPENSCENARIO

    from feat2map.formats import native
    from feat2map.formats.asam_qc import OPENSCENARIO, find_bundle
    from feat2map.formats.openscenario import validate_openscenario, write_openscenario
    from feat2map.scenarios.routes import build_suite

    native.save(spec_map, tmp_path / "map.json")
    suite = build_suite(tmp_path / "map.json", traffic_vehicles=6, seed=0)
    links = {spec_map.junctions[jid].socket_roads[i] for jid, i in link_sockets(spec_map)}
    assert {r for sc in suite.scenarios for mv in sc.route for r in mv[1:] if r in links} == links
    files = write_openscenario(suite, tmp_path / "x")
    assert len(files) == len(suite.scenarios) == 4
    if find_bundle(OPENSCENARIO[0]) is None:
        pytest.skip(SKIP_QC_OPENSCENARIO)
    for f in files:
        assert validate_openscenario(f) == [], f.name


def test_the_extract_command_names_links(tmp_path, spec_map, capsys):
    from feat2map.cli import main
    from feat2map.formats import native

    native.save(spec_map, tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    assert "[-15.00, 0.00, 15.00, 180.00]  ramps: 0 link-off, 2 link-on (75.00 m)\n" in capsys.readouterr().out
