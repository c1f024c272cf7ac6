"""Filter lanes (slip lanes): the junction feature's per-socket `filter`/`island`, the map
feature's `filter` values and their sampling, spec requests, construction, exports and
extraction, on maps generated here; old feature files and specs (no `filter`) give the same
bytes as before."""
from __future__ import annotations

import json
import math
from pathlib import Path

import pytest
from conftest import ROUND_TRIPS, export_problems, numpy_avx512, round_trip, sha256_text
from shapely.geometry import LineString, Polygon

from feat2map.cli import main
from feat2map.config import FILTER_DIVERGE_M
from feat2map.errors import FeatureError
from feat2map.extract import extract_filters, extract_junctions, map_feature
from feat2map.features import PAPER_SF_FEATURE_SPACE, FeatureSpace, JunctionFeature, Socket, with_filter
from feat2map.formats import native, write_map
from feat2map.generate import generate
from feat2map.invariants import check_map, feature_mismatch
from feat2map.model import HDMap
from feat2map.spec import SpecError, build_spec, load_spec, parse_spec

REPO = Path(__file__).resolve().parents[1]
SPACE = FeatureSpace(PAPER_SF_FEATURE_SPACE.road_counts, PAPER_SF_FEATURE_SPACE.controls,
                     PAPER_SF_FEATURE_SPACE.crosswalks, PAPER_SF_FEATURE_SPACE.rotation_ranges,
                     filter=("none", "yield", "signal"))
# sha256 of the native JSON of maps whose inputs name no filter lane, recorded with the code before
# filter lanes existed: such inputs must keep giving these bytes
# (NumPy's AVX-512 kernels round a few coordinates of this map differently: `numpy_avx512`)
PAPER_SEED2_SHA = {False: "d9e850d854e74e7e92b8a443d705f66abf97e76aa70e0831a6f3764cbb3d1e37",
                   True: "6c9feb482057307de76f1d15e8ab43604e87e5caede14bff20534588c52adba2"}[numpy_avx512()]
MIDBLOCK_SPEC_SHA = "cc153b50ad7121299cb97ec7bae27168e19266628dae618d483ac5653a7ef789"
MULTI_LANE_SPEC_SHA = "c3c2b1b6284233a6722dd645b22650ccdc57ca2725da5915b50f7048b2413eb8"


@pytest.fixture(scope="module")
def sampled() -> HDMap:
    return generate(SPACE, seed=0)


@pytest.fixture(scope="module")
def spec_map() -> HDMap:
    return build_spec(load_spec(REPO / "examples" / "filter_lanes.yaml"), seed=0)


def filter_lanes(m: HDMap):
    return [ln for ln in m.lanes.values() if ln.junction_id is not None and "_f" in ln.road_id]


# ------------------------------------------------------------------------------ feature model

def test_old_feature_files_and_specs_give_the_bytes_they_always_did(monkeypatch):
    old = json.loads(PAPER_SF_FEATURE_SPACE.to_json())
    assert "filter" not in old
    space = FeatureSpace.from_dict(old)
    assert space.filter == ("none",) and space == PAPER_SF_FEATURE_SPACE
    assert sha256_text(native.dumps(generate(space, seed=2))) == PAPER_SEED2_SHA
    monkeypatch.chdir(REPO)  # the map records the spec's path as given
    assert sha256_text(native.dumps(build_spec(load_spec("examples/midblock.yaml"), seed=0))) == MIDBLOCK_SPEC_SHA
    assert sha256_text(native.dumps(build_spec(load_spec("examples/multi_lane.yaml"), seed=0))) == MULTI_LANE_SPEC_SHA
    f = JunctionFeature.make([0, 90, 180, 270], "signal")
    assert "filter" not in f.to_dict() and JunctionFeature.from_dict(f.to_dict()) == f


def test_filter_values_round_trip_and_bad_ones_are_named():
    assert SPACE.filter_controls == ("yield", "signal")
    assert FeatureSpace.from_json(SPACE.to_json()) == SPACE
    with pytest.raises(FeatureError, match="filter.*slip"):
        FeatureSpace.from_dict({**SPACE.to_dict(), "filter": ["slip"]}, "f.json")
    f = with_filter(JunctionFeature.make([0, 90, 180, 270], "signal"), "yield")
    assert f.filters.count("yield") == 1 and JunctionFeature.from_dict(f.to_dict()) == f
    assert f.normalized().filters.count("yield") == 1
    with pytest.raises(FeatureError, match="right turn"):  # 0 -> 200 deg is no right turn
        JunctionFeature((Socket(0, filter="yield"), Socket(200), Socket(270)))
    assert PAPER_SF_FEATURE_SPACE.merge(SPACE).filter == ("none", "yield", "signal")


# ------------------------------------------------------------------------------ generation

def test_sampling_covers_every_filter_value(sampled):
    assert len(sampled.junctions) == 24  # 8 combinations of the paper's values x 3 filter values
    values = sorted(v for j in sampled.junctions.values() for v in j.feature.filters if v != "none")
    assert values == ["signal"] * 8 + ["yield"] * 8
    assert len(filter_lanes(sampled)) == 16 and len(sampled.yield_signs) == 8
    assert check_map(sampled) == []
    assert sha256_text(native.dumps(generate(SPACE, seed=0))) == sha256_text(native.dumps(sampled))  # seeded


def test_a_filter_lane_leaves_before_the_core_and_joins_the_exit_after_it(spec_map):
    assert check_map(spec_map) == []
    lanes = {ln.id: ln for ln in filter_lanes(spec_map)}
    assert set(lanes) == {"J0_f2_0", "J0_f3_0", "J1_f1_0"}
    for ln in lanes.values():
        (src,), (dst,) = ln.predecessors, ln.successors
        before, after = spec_map.lanes[src], spec_map.lanes[dst]
        assert ln.turn == "right" and before.junction_id is None and after.junction_id is None
        # the lane before it also goes on, as a road lane FILTER_DIVERGE_M long, to the core's entry
        (on,) = [x for x in before.successors if spec_map.lanes[x].junction_id is None]
        assert math.isclose(spec_map.lanes[on].length, FILTER_DIVERGE_M, rel_tol=0.01)
        # outside the core: the centre line keeps clear of the hull of the core lanes' ends
        core = Polygon([p for x in spec_map.lanes.values() if x.junction_id == ln.junction_id and "_c" in x.road_id
                        for p in (x.start, x.end)]).convex_hull
        assert not LineString(ln.centerline).intersects(core.buffer(-1.0))
        assert ln.left_boundary_type == ("solid_white" if ln.id == "J0_f2_0" else "curb")  # island: kerbs
    assert set(spec_map.yield_signs) == {"J0_yield3", "J1_yield1"}
    assert spec_map.signals["J0_filter2"].lane_ids == lanes["J0_f2_0"].predecessors


def test_multi_lane_approaches_get_a_filter_lane_from_their_rightmost_lane():
    import yaml

    doc = yaml.safe_load("""
junctions:
  - cell: [0, 0]
    control: signal
    sockets:
      - {angle: 0, lanes: 2}
      - {angle: 90, lanes: 2, filter: {control: signal}}
      - {angle: 180, lanes: 2}
      - {angle: 270, lanes: 2, filter: {island: false}}
  - cell: [1, 0]
    sockets: [0, {angle: 180, lanes: 2, filter: {}}, 270]
""")
    m = build_spec(parse_spec(doc, "s.yaml"))
    assert check_map(m) == []
    found = sorted((f.junction, f.control, f.island) for f in extract_filters(m))
    assert found == [("J0", "signal", True), ("J0", "yield", False), ("J1", "yield", True)]
    for f in extract_filters(m):
        before = m.lanes[f.approach]
        road = m.roads[before.road_id]
        lanes = road.right_lanes if f.approach in road.right_lanes else road.left_lanes
        assert f.approach == lanes[-1]  # the rightmost of its direction (lanes listed from the divider)
        (through,) = [x for x in before.successors if m.lanes[x].junction_id is None]
        assert all(m.lanes[x].turn != "right" for x in m.lanes[through].successors)  # no second right turn


@pytest.mark.parametrize("socket, message", [
    ("{angle: 90, filter: {control: yield}}", "no incoming lanes"),
    ("{angle: 0, filter: {control: stop}}", "junctions\\[0\\].sockets\\[0\\].filter"),
])
def test_bad_filter_requests_name_their_socket(socket, message):
    import yaml

    doc = yaml.safe_load(f"junctions:\n  - sockets: [{socket}, 180, 270]\n")
    if "angle: 90" in socket:
        doc["junctions"][0]["sockets"] = [0, {"angle": 90, "type": "out", "filter": {}}, 180]
    with pytest.raises(SpecError, match=message) as err:
        build_spec(parse_spec(doc, "s.yaml"))
    assert "s.yaml" in str(err.value)


def test_a_filter_without_a_right_turn_is_named():
    doc = {"junctions": [{"sockets": [0, {"angle": 90, "filter": {}}, 270]}]}  # 90 -> 270: straight on
    with pytest.raises(SpecError, match="right turn") as err:
        build_spec(parse_spec(doc, "s.yaml"))
    assert r"junctions[0].sockets[1].filter" in str(err.value)


# ------------------------------------------------------------------------------ exports

@pytest.mark.parametrize("fmt, name", ROUND_TRIPS)
def test_filter_lanes_survive_a_round_trip(tmp_path, spec_map, fmt, name):
    back = round_trip(spec_map, tmp_path, fmt, name)
    found = sorted((f.control, f.island) for f in extract_filters(back))  # OpenDRIVE numbers the junctions
    assert found == [("signal", False), ("yield", True), ("yield", True)]
    assert len({f.junction for f in extract_filters(back)}) == 2
    got = [j.feature for j in extract_junctions(back)]  # OpenDRIVE numbers the junctions
    for want, j in zip(spec_map.junctions.values(), got):
        assert feature_mismatch(j, want.feature, angle_tol_deg=0.5) == []
    assert len(back.yield_signs) == 2  # the yield signs travel too


@pytest.mark.parametrize("fmt", ["apollo", "lanelet2", "commonroad"])
def test_exports_with_filter_lanes_validate(tmp_path, spec_map, fmt):
    problems = export_problems(spec_map, fmt, tmp_path)
    assert problems == [], problems[:3]


def test_the_opendrive_export_passes_asam_qc(tmp_path, spec_map):
    """A filter lane leaves a road where the piece on to the core starts: OpenDRIVE gets it as a
    road between two direct junctions (a road end links to one element), and ASAM's checker
    finds nothing."""
    from conftest import SKIP_QC_OPENDRIVE

    from feat2map.formats.asam_qc import OPENDRIVE, find_bundle
    from feat2map.formats.opendrive import validate_opendrive

    if find_bundle(OPENDRIVE[0]) is None:
        pytest.skip(SKIP_QC_OPENDRIVE)
    write_map(spec_map, tmp_path / "m.xodr", "opendrive")
    text = (tmp_path / "m.xodr").read_text()
    assert text.count('type="direct"') == 5 and text.count('type="205"') == 2  # one per road cut, one per sign
    assert validate_opendrive(tmp_path / "m.xodr") == []


def test_openscenario_routes_through_filter_lanes_pass_asam_qc(tmp_path, spec_map):
    """A suite's scenarios that take a filter lane route along it (in the OpenDRIVE file written
    beside them, a road between direct junctions) and pass ASAM's OpenSCENARIO checks."""
    from conftest import SKIP_QC_OPENSCENARIO

    from feat2map.formats.asam_qc import OPENSCENARIO, find_bundle
    from feat2map.formats.openscenario import validate_openscenario, write_openscenario
    from feat2map.scenarios.routes import build_suite

    native.save(spec_map, tmp_path / "map.json")
    suite = build_suite(tmp_path / "map.json", traffic_vehicles=6, seed=0)
    moves = {("J0", "R2", "R3"), ("J0", "R3", "R0"), ("J1", "R4", "R5")}
    taking = tuple(sc for sc in suite.scenarios if moves & {tuple(mv) for mv in sc.route})
    files = write_openscenario(type(suite)(suite.name, taking), tmp_path / "x")
    assert len(files) == len(taking) >= 2
    if find_bundle(OPENSCENARIO[0]) is None:
        pytest.skip(SKIP_QC_OPENSCENARIO)
    for f in files:
        assert validate_openscenario(f) == [], f.name


# ------------------------------------------------------------------------------ extraction

def test_extraction_finds_filter_lanes_and_records_them_in_the_feature(tmp_path, sampled, capsys):
    found = extract_filters(sampled)
    assert len(found) == 16 and all(f.early for f in found)
    assert sorted(f.control for f in found) == ["signal"] * 8 + ["yield"] * 8
    assert extract_filters(generate(PAPER_SF_FEATURE_SPACE, seed=2)) == []  # plain right turns are not
    space = map_feature(extract_junctions(sampled))
    assert space.filter == ("none", "yield", "signal")
    # a junction's control counts its core's lights only (a filter lane's light is its own)
    assert {j.feature.control for j in extract_junctions(sampled)} == {"signal", "stop"}
    native.save(sampled, tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    assert "16 filter lanes (8 signalised)" in capsys.readouterr().out
    assert main(["extract", str(tmp_path / "m.json"), "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert len(doc["filter_lanes"]) == 16 and doc["feature_space"]["filter"] == ["none", "yield", "signal"]


def test_the_junction_table_notes_filter_lanes_by_socket(tmp_path, spec_map, capsys):
    native.save(spec_map, tmp_path / "m.json")
    assert main(["extract", str(tmp_path / "m.json")]) == 0
    out = capsys.readouterr().out
    assert "[0.00, 90.00, 180.00, 270.00]  filter lanes: 2 signal (painted), 3 yield (island)\n" in out
    assert "[0.00, 90.00, 180.00]  filter lanes: 1 yield (island)\n" in out


@pytest.mark.real_maps
@pytest.mark.parametrize("rel", ["apollo/san_francisco/base_map.bin", "apollo/gomentum/base_map.bin",
                                 "opendrive/carla_town03/Town03.xodr", "opendrive/carla_town04/Town04.xodr"])
def test_real_maps_hold_no_filter_lanes(rel):
    """Their right turns all start at the junctions' entries under the junctions' own control (no
    road lane forks into one, no yield sign governs one): none is taken for a filter lane, and no
    OpenDRIVE road is given back to a junction as one."""
    from conftest import read_shared_map

    m = read_shared_map(rel)
    assert extract_filters(m, rel) == []
    assert not any(j.feature.has_filter for j in extract_junctions(m, rel))
