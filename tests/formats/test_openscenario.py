"""OpenSCENARIO export of scenario suites: every file passes asam-qc-openscenarioxml with every
check run; the files hold the suite's ego routes, traffic, pedestrians and signal plans against
the exported OpenDRIVE map; same suite, same bytes; nothing half-written on bad input."""
from __future__ import annotations

import math
from dataclasses import replace

import pytest
from lxml import etree

import feat2map
from feat2map.cli import main
from feat2map.errors import Feat2MapError
from feat2map.atomic import MANIFEST
from feat2map.formats import native
from feat2map.formats.asam_qc import OPENSCENARIO, find_bundle, run_bundle
from feat2map.formats.openscenario import validate_openscenario, write_openscenario
from feat2map.scenarios.routes import build_suite, pick_lane, signal_cycle
from feat2map.scenarios.scenario import Suite, save_suite

from conftest import REPO, SKIP_QC_OPENSCENARIO, shared_map

needs_checker = pytest.mark.skipif(find_bundle(OPENSCENARIO[0]) is None, reason=SKIP_QC_OPENSCENARIO)
ALL_CHECKS = 17  # checkers of asam-qc-openscenarioxml 1.0.0


def _suite(tmp_path, m, n: int = 3, **kw) -> Suite:
    path = tmp_path / "map.json"
    native.save(m, path)
    suite = build_suite(path, traffic_vehicles=3, pedestrian_rate=6.0, **kw)
    return Suite(suite.name, suite.scenarios[:n], suite.base_dir)


@pytest.fixture(scope="module")
def mega(tmp_path_factory):
    """The 5-leg signalized junction with crosswalks: 3 scenarios exported."""
    from feat2map.spec import build_spec, load_spec

    spec = load_spec(REPO / "examples" / "mega_junction.yaml")
    m = build_spec(spec, seed=0, config=spec.generation_config({}))
    tmp = tmp_path_factory.mktemp("mega")
    suite = _suite(tmp, m)
    out = tmp / "xosc"
    files = write_openscenario(suite, out)
    return m, suite, out, files


def _check(path):
    results = run_bundle(path, OPENSCENARIO)
    assert len(results) == ALL_CHECKS
    assert [str(p) for r in results for p in r.issues] == []
    assert {r.checker_id: r.summary for r in results if r.status != "completed"} == {}


@needs_checker
def test_mega_junction_suite_passes_every_check(mega):
    _, suite, out, files = mega
    assert sorted(p.name for p in out.iterdir()) == sorted([f.name for f in files] + ["map.xodr", MANIFEST])
    assert len(files) == len(suite.scenarios)
    for f in files:
        _check(f)


@needs_checker
def test_generated_map_suite_passes_every_check(tmp_path):
    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=5)
    for f in write_openscenario(_suite(tmp_path, m, n=2), tmp_path / "x"):
        _check(f)


@needs_checker
@pytest.mark.real_maps
def test_suite_on_a_map_from_real_features_passes_every_check(tmp_path):
    from feat2map.extract import extract_junctions, map_feature
    from feat2map.formats import read_map

    space = map_feature(extract_junctions(read_map(shared_map("opendrive/carla_town01/Town01.xodr"))))
    m = feat2map.generate(space, seed=3, config=feat2map.GenerationConfig(samples_per_combination=4))
    for f in write_openscenario(_suite(tmp_path, m, n=2), tmp_path / "x"):
        _check(f)


def test_files_hold_the_suite(mega):
    """Ego route (entry lane, one waypoint per manoeuvre on its junction lane, goal), traffic
    count, pedestrians on the route's crosswalks, one controller per signalized junction whose
    phases cover its cycle and name signals of the exported map."""
    m, suite, out, files = mega
    xodr = etree.parse(str(out / "map.xodr")).getroot()
    signal_ids = {s.get("id") for s in xodr.iter("signal") if s.get("dynamic") == "yes"}
    road_of = {r.get("name"): r.get("id") for r in xodr.findall("road")}
    for sc, f in zip(suite.scenarios, files):
        root = etree.parse(str(f)).getroot()
        assert root.find("RoadNetwork/LogicFile").get("filepath") == "map.xodr"
        waypoints = root.findall(".//Private[@entityRef='ego']//AssignRouteAction/Route/Waypoint")
        assert len(waypoints) == len(sc.route) + 2
        for mv, wp in zip(sc.route, waypoints[1:-1]):
            assert wp.find("Position/LanePosition").get("roadId") == road_of[pick_lane(m, mv).road_id]
        names = [o.get("name") for o in root.findall("Entities/ScenarioObject")]
        assert sum(n.startswith("traffic_") for n in names) == sc.traffic_vehicles
        peds = [n for n in names if n.startswith("pedestrian_")]
        assert peds and len(root.findall(".//Story/Act/ManeuverGroup")) == len(peds)
        for c in root.findall("RoadNetwork/TrafficSignals/TrafficSignalController"):
            total = sum(float(p.get("duration")) for p in c.findall("Phase"))
            assert total == pytest.approx(signal_cycle(m, c.get("name").split()[-1]), abs=1e-5)  # the env's plan
            assert {s.get("trafficSignalId") for s in c.iter("TrafficSignalState")} <= signal_ids
        assert len(root.findall("RoadNetwork/TrafficSignals/TrafficSignalController")) == 1


def test_pedestrians_walk_across_their_crosswalk(mega):
    from shapely.geometry import Point, Polygon

    m, _, _, files = mega
    polys = [Polygon(c.polygon).buffer(0.5) for c in m.crosswalks.values()]
    root = etree.parse(str(files[0])).getroot()
    for line in root.iter("Polyline"):
        ends = [(float(w.get("x")), float(w.get("y"))) for w in line.iter("WorldPosition")]
        assert len(ends) == 2 and math.dist(*ends) > 3.0
        assert any(p.contains(Point(ends[0])) and p.contains(Point(ends[1])) for p in polys)


def test_a_fixed_signal_offset_starts_the_cycle_there(tmp_path, mega):
    m, suite, _, _ = mega
    jid = next(iter(m.junctions))
    sc = replace(suite.scenarios[0], signal_offsets={jid: 0.0})
    f = write_openscenario(Suite("fixed", (sc,), suite.base_dir), tmp_path / "x")[0]
    phases = etree.parse(str(f)).getroot().findall(".//TrafficSignalController/Phase")
    assert [(p.get("name"), float(p.get("duration"))) for p in phases[:3]] == [
        ("phase1_green", 12.0), ("phase1_amber", 3.0), ("phase1_all_red", 2.0)]


def test_same_suite_same_bytes(tmp_path, mega):
    _, suite, out, files = mega
    again = write_openscenario(suite, tmp_path / "again")
    for a, b in zip(files, again):
        assert a.read_bytes() == b.read_bytes()
    assert (out / "map.xodr").read_bytes() == (tmp_path / "again" / "map.xodr").read_bytes()


def test_a_bad_route_writes_nothing(tmp_path, mega):
    _, suite, _, _ = mega
    bad = replace(suite.scenarios[1], route=(("J0", "R0", "nowhere"),))
    out = tmp_path / "out"
    with pytest.raises(Feat2MapError, match=r"route\[0\]"):
        write_openscenario(Suite("bad", (suite.scenarios[0], bad), suite.base_dir), out)
    assert not out.exists() or not any(out.iterdir())


@needs_checker
def test_cli_export_and_validate(tmp_path, capsys, mega):
    _, suite, _, _ = mega
    path = tmp_path / "suite.yaml"
    save_suite(Suite(suite.name, suite.scenarios[:1], suite.base_dir), path)
    out = tmp_path / "xosc"
    assert main(["export", "openscenario", str(path), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert printed.endswith(": 1 scenario\n") and "1 scenarios" not in printed, printed
    xosc = next(out.glob("*.xosc"))
    assert main(["validate", str(xosc)]) == 0
    root = etree.parse(str(xosc)).getroot()  # an action for an entity that does not exist
    root.find(".//Private").set("entityRef", "nobody")
    broken = out / "broken.xosc"
    broken.write_bytes(etree.tostring(root))
    problems = validate_openscenario(broken)
    assert problems and any("nobody" in p.message or "entity" in p.message for p in problems)
    assert main(["validate", str(broken)]) == 1
