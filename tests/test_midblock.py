"""Mid-block crosswalks (crossings on a road between two junctions): the map feature's `midblock`
values, their sampling, spec requests, construction, exports and extraction, on maps generated
here; old feature files and specs (no `midblock`) give the same bytes as before."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from conftest import ROUND_TRIPS, export_problems, read_shared_map, round_trip, sha256_text
from shapely.geometry import Polygon

from feat2map.cli import main
from feat2map.config import CROSSWALK_WIDTH_M, MIDBLOCK_POSITION_RANGE
from feat2map.errors import FeatureError
from feat2map.extract import extract_junctions, extract_midblock, map_feature
from feat2map.features import PAPER_SF_FEATURE_SPACE, FeatureSpace, MidblockFeature
from feat2map.formats import native, write_map
from feat2map.generate import generate
from feat2map.invariants import check_map
from feat2map.model import HDMap, midblock_controls
from feat2map.phases import junction_phases
from feat2map.spec import SpecError, build_spec, load_spec, parse_spec

REPO = Path(__file__).resolve().parents[1]
SPACE = FeatureSpace(PAPER_SF_FEATURE_SPACE.road_counts, PAPER_SF_FEATURE_SPACE.controls,
                     PAPER_SF_FEATURE_SPACE.crosswalks, PAPER_SF_FEATURE_SPACE.rotation_ranges,
                     ("none", "bare", "signal"))
# sha256 of the native JSON of maps whose inputs name no mid-block crosswalk, recorded with the
# code before mid-block crosswalks existed: such inputs must keep giving these bytes
PAPER_SEED1_SHA = "7b222c7b491ed12086adbe11f3c23e815a03eab6140270c657a917bbbb03589a"
MULTI_LANE_SPEC_SHA = "c3c2b1b6284233a6722dd645b22650ccdc57ca2725da5915b50f7048b2413eb8"
PAPER_SPACE_JSON_SHA = "9f68374b69230c40b582ec0d385e9a0cc2dde740fc60a029638b7bf3e674b1b9"


@pytest.fixture(scope="module")
def sampled() -> HDMap:
    return generate(SPACE, seed=3)


@pytest.fixture(scope="module")
def spec_map() -> HDMap:
    return build_spec(load_spec(REPO / "examples" / "midblock.yaml"), seed=0)


def midblock_walks(m: HDMap):
    return [c for c in m.crosswalks.values() if c.junction_id is None]


# ------------------------------------------------------------------------------ feature model

def test_an_old_feature_file_reads_and_generates_the_bytes_it_always_did():
    old = json.loads(PAPER_SF_FEATURE_SPACE.to_json())
    assert "midblock" not in old  # what feature files written before mid-block crosswalks hold
    space = FeatureSpace.from_dict(old)
    assert space.midblock == ("none",) and space == PAPER_SF_FEATURE_SPACE
    assert sha256_text(space.to_json()) == PAPER_SPACE_JSON_SHA
    assert sha256_text(native.dumps(generate(space, seed=1))) == PAPER_SEED1_SHA


def test_an_old_spec_builds_the_bytes_it_always_did(monkeypatch):
    monkeypatch.chdir(REPO)  # the map records the spec's path as given
    assert sha256_text(native.dumps(build_spec(load_spec("examples/multi_lane.yaml"), seed=0))) == MULTI_LANE_SPEC_SHA


def test_midblock_values_round_trip_and_bad_ones_are_named():
    assert SPACE.midblock_controls == ("bare", "signal")
    assert FeatureSpace.from_json(SPACE.to_json()) == SPACE
    assert FeatureSpace.from_dict(SPACE.to_dict()).to_dict()["midblock"] == ["none", "bare", "signal"]
    bad = {**SPACE.to_dict(), "midblock": ["zebra"]}
    with pytest.raises(FeatureError, match="midblock.*zebra"):
        FeatureSpace.from_dict(bad, "f.json")
    with pytest.raises(FeatureError, match="strictly between 0 and 1"):
        MidblockFeature("bare", 1.0)
    merged = PAPER_SF_FEATURE_SPACE.merge(SPACE)
    assert merged.midblock == ("none", "bare", "signal")


# ------------------------------------------------------------------------------ generation

def test_sampling_places_one_crosswalk_per_value_on_roads_between_junctions(sampled):
    walks = midblock_walks(sampled)
    assert len(walks) == 2  # "bare" and "signal", samples_per_combination 1
    assert len(sampled.junctions) == 8  # the junction combinations are unchanged
    mids = midblock_controls(sampled)
    assert len(mids) == 2 and {cw for cw, _, _ in mids.values()} == {walks[1].id}
    for c in walks:
        road = sampled.roads[c.id[:-len("_cw")]]
        assert road.kind == "connection"
        poly = Polygon(c.polygon)
        across = [ln for ln in sampled.lanes.values() if ln.road_id == road.id]
        assert len(across) == len(road.lane_ids)
        from shapely.geometry import LineString
        for ln in across:
            crossed = LineString(ln.centerline).intersection(poly)
            assert math.isclose(crossed.length, CROSSWALK_WIDTH_M, abs_tol=0.2), (c.id, crossed.length)
    assert check_map(sampled) == []
    assert sha256_text(native.dumps(generate(SPACE, seed=3))) == sha256_text(native.dumps(sampled))  # seeded


def test_signalised_midblock_lights_face_their_traffic_and_have_a_pedestrian_phase(sampled):
    lights = [s for s in sampled.signals.values() if s.junction_id is None]
    assert len(lights) == 2
    for s in lights:
        ln = sampled.lanes[s.lane_ids[0]]
        travel = math.atan2(ln.end[1] - ln.start[1], ln.end[0] - ln.start[0])
        assert abs(math.remainder(s.heading - travel - math.pi, 2 * math.pi)) < 0.5  # facing the traffic
    plan = junction_phases(sampled)[None]
    assert plan[-1] == () and {x for ph in plan for x in ph} == {s.id for s in lights}


def test_a_spec_asks_for_crosswalks_on_given_roads(spec_map):
    walks = {c.id: c for c in midblock_walks(spec_map)}
    assert set(walks) == {"R0_cw", "R4_cw"}
    found = {e.id: e for e in extract_midblock(spec_map)}
    assert found["R0_cw"].feature.control == "signal" and found["R0_cw"].feature.position == pytest.approx(0.4, abs=0.01)
    assert found["R4_cw"].feature.control == "bare"
    assert check_map(spec_map) == []


@pytest.mark.parametrize("socket, message", [
    ("{angle: 90, midblock: {control: bare}}", "ends in a stub"),
    ("{angle: 0, midblock: {control: zebra}}", "junctions\\[0\\].sockets\\[0\\].midblock"),
    ("{angle: 0, midblock: {position: 0.02}}", "does not fit"),
])
def test_bad_midblock_requests_name_their_socket(tmp_path, socket, message):
    import yaml

    doc = yaml.safe_load(f"""
junctions:
  - cell: [0, 0]
    sockets: [{socket}, 180, 270]
  - cell: [1, 0]
    sockets: [0, 90, 180]
""")
    if socket.startswith("{angle: 90"):
        doc["junctions"][0]["sockets"] = [0, yaml.safe_load(socket), 180]
    with pytest.raises(SpecError, match=message) as err:
        build_spec(parse_spec(doc, "s.yaml"))
    assert "s.yaml" in str(err.value)


# ------------------------------------------------------------------------------ exports

def positions(m: HDMap) -> list[float]:
    """The mid-block crosswalks' centres from the map's lower left corner (readers may move the
    local origin), flat: x0, y0, x1, y1, ... in x order."""
    x0, y0, _, _ = m.bounds()
    return [v for x, y in sorted(Polygon(c.polygon).centroid.coords[0] for c in midblock_walks(m))
            for v in (x - x0, y - y0)]


@pytest.mark.parametrize("fmt, name", ROUND_TRIPS)
def test_midblock_crosswalks_and_lights_survive_a_round_trip(tmp_path, sampled, fmt, name):
    back = round_trip(sampled, tmp_path, fmt, name)
    assert len(back.crosswalks) == len(sampled.crosswalks)
    assert positions(back) == pytest.approx(positions(sampled), abs=0.2)
    assert len(midblock_controls(back)) == 2
    assert sorted(s.junction_id is None for s in back.signals.values()) == \
        sorted(s.junction_id is None for s in sampled.signals.values())
    assert len(back.stop_signs) == len(sampled.stop_signs)  # a junction's signs stay under a mid-block light
    assert {e.feature.control for e in extract_midblock(back)} == {"bare", "signal"}
    assert sorted((j.feature.n_roads, j.feature.control) for j in extract_junctions(back)) == \
        sorted((j.feature.n_roads, j.feature.control) for j in sampled.junctions.values() if j.feature)


@pytest.mark.parametrize("fmt", ["apollo", "lanelet2", "commonroad"])
def test_exports_with_midblock_crosswalks_validate(tmp_path, sampled, fmt):
    problems = export_problems(sampled, fmt, tmp_path)
    assert problems == [], problems[:3]


def test_the_opendrive_export_passes_asam_qc(tmp_path, sampled):
    from conftest import SKIP_QC_OPENDRIVE

    from feat2map.formats.asam_qc import OPENDRIVE, find_bundle
    from feat2map.formats.opendrive import validate_opendrive

    if find_bundle(OPENDRIVE[0]) is None:
        pytest.skip(SKIP_QC_OPENDRIVE)
    write_map(sampled, tmp_path / "m.xodr", "opendrive")
    assert validate_opendrive(tmp_path / "m.xodr") == []


# ------------------------------------------------------------------------------ extraction

def test_extraction_counts_midblock_crosswalks(tmp_path, sampled, capsys):
    found = extract_midblock(sampled)
    assert sorted(e.feature.control for e in found) == ["bare", "signal"]
    for e in found:
        assert MIDBLOCK_POSITION_RANGE[0] - 0.05 <= e.feature.position <= MIDBLOCK_POSITION_RANGE[1] + 0.05
    assert extract_midblock(generate(PAPER_SF_FEATURE_SPACE, seed=3)) == []  # junction crosswalks are not
    assert map_feature(extract_junctions(sampled), found).midblock == ("none", "bare", "signal")
    native.save(sampled, tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    assert "2 mid-block crosswalks (1 signalised)" in capsys.readouterr().out
    assert main(["extract", str(tmp_path / "m.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["midblock_crosswalks"]) == 2 and doc["feature_space"]["midblock"] == ["none", "bare", "signal"]


@pytest.mark.real_maps
@pytest.mark.parametrize("rel, count", [("apollo/gomentum/base_map.bin", 7), ("apollo/gomentum/sim_map.txt", 7),
                                        ("apollo/san_francisco/base_map.bin", 0),
                                        ("opendrive/carla_town04/Town04.xodr", 0)])
def test_midblock_crosswalks_of_real_maps(rel, count):
    m = read_shared_map(rel)
    found = extract_midblock(m, rel)
    assert len(found) == count and all(e.feature.control == "bare" for e in found)
    assert midblock_controls(m) == {}  # no real light is taken for a mid-block one


def test_cli_generate_with_midblock_values(tmp_path, capsys):
    feats = tmp_path / "features.json"
    feats.write_text(SPACE.to_json())
    assert main(["generate", "--features", str(feats), "--seed", "3", "--out", str(tmp_path / "g"), "--quiet",
                 "--no-picture"]) == 0
    assert "16 crosswalks (2 outside junctions)" in capsys.readouterr().out
    assert FeatureSpace.load(tmp_path / "g" / "features.json") == SPACE
    assert native.dumps(native.load(tmp_path / "g" / "map.json")) == native.dumps(generate(SPACE, seed=3))


def test_openscenario_pedestrians_walk_the_midblock_crosswalks_a_route_passes(tmp_path, spec_map):
    from feat2map.formats.openscenario.writer import write_openscenario
    from feat2map.scenarios.routes import build_suite

    native.save(spec_map, tmp_path / "map.json")
    suite = build_suite(tmp_path / "map.json", pedestrian_rate=6.0, seed=0)
    through = [sc for sc in suite.scenarios if ("J1", "R0", "R4") in sc.route]  # drives R0 and its crossing
    assert through
    (xosc,) = write_openscenario(type(suite)(suite.name, (through[0],)), tmp_path / "x")
    assert 'name="pedestrian_R0_cw_' in xosc.read_text()
