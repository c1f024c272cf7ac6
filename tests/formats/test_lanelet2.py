"""Lanelet2 export, checked by the lanelet2 wheel (Lanelet2's loader and routing graph)."""
from __future__ import annotations

import copy
import math
from collections import Counter

import pytest
from conftest import SKIP_LANELET2
import yaml

from feat2map.formats.lanelet2 import PROJECTOR_INFO, check_lanelet2, write_lanelet2
from feat2map.scenarios.routes import manoeuvres

lanelet2 = pytest.importorskip("lanelet2", reason=SKIP_LANELET2)
from lanelet2.io import Origin  # noqa: E402
from lanelet2.projection import UtmProjector  # noqa: E402


@pytest.fixture(scope="module")
def exported(ecosystem_map, tmp_path_factory):
    name, m = ecosystem_map
    path = tmp_path_factory.mktemp(f"ll2-{name}") / "lanelet2_map.osm"
    write_lanelet2(m, path)
    return m, path, check_lanelet2(path)


def _load(path):
    o = yaml.safe_load((path.parent / PROJECTOR_INFO).read_text())["map_origin"]
    lmap, errors = lanelet2.io.loadRobust(str(path), UtmProjector(Origin(o["latitude"], o["longitude"])))
    assert errors == []
    rules = lanelet2.traffic_rules.create(lanelet2.traffic_rules.Locations.Germany,
                                          lanelet2.traffic_rules.Participants.Vehicle)
    return lmap, lanelet2.routing.RoutingGraph(lmap, rules)


def _lane(ll) -> str | None:
    return str(ll.attributes["feat2map:lane"]) if "feat2map:lane" in ll.attributes else None


def _expected_right_of_way(m) -> int:
    """Approaches of uncontrolled junctions with a left turn, where another approach goes straight or right."""
    controlled = {s.junction_id for s in m.signals.values()} | {s.junction_id for s in m.stop_signs.values()}
    n = 0
    for jid in m.junctions:
        if jid in controlled:
            continue
        turns: dict[str, set[str]] = {}
        for ln in m.junction_lanes(jid):
            for p in ln.predecessors:
                turns.setdefault(m.lanes[p].road_id, set()).add(ln.turn)
        for road, mine in turns.items():
            others = set().union(*(t for r, t in turns.items() if r != road))
            n += bool(mine & {"left", "uturn"}) and bool(others & {"none", "right"})
    return n


def test_wheel_loads_routes_every_manoeuvre_and_counts_match(exported):
    m, _, report = exported
    assert report.problems == []
    assert report.lanelets == Counter({"road": len(m.lanes), "crosswalk": len(m.crosswalks)}) - Counter()
    stop_junctions = {s.junction_id for s in m.stop_signs.values()}
    expected = Counter(traffic_light=len(m.signals), all_way_stop=len(stop_junctions),
                       right_of_way=_expected_right_of_way(m))
    assert report.regulatory_elements == expected - Counter()
    assert report.routes == set(manoeuvres(m)) and report.routes


def test_routing_graph_has_the_model_lane_graph(exported):
    """Successors come from shared end points, lane changes from shared bounds: the routing
    graph's relations are exactly the model's links."""
    m, path, _ = exported
    lmap, graph = _load(path)
    by_lane = {_lane(ll): ll for ll in lmap.laneletLayer if _lane(ll)}
    assert set(by_lane) == set(m.lanes)
    for lid, ll in by_lane.items():
        ln = m.lanes[lid]
        assert {_lane(x) for x in graph.following(ll)} == set(ln.successors)
        besides = {_lane(x) for x in (graph.left(ll), graph.adjacentLeft(ll)) if x is not None}
        assert besides == set(ln.left_neighbors)
        for other in ln.left_reverse_neighbors:  # opposite lanes share their left bound
            assert by_lane[other].leftBound.id == ll.leftBound.id
    changes = [ll for ll in by_lane.values() if graph.left(ll) is not None or graph.right(ll) is not None]
    dashed = [ln for ln in m.lanes.values() if ln.left_neighbors and ln.left_boundary_type.startswith("dotted")]
    assert len(changes) >= len(dashed)  # a dashed line between neighbours allows the lane change


def test_regulatory_elements_name_the_controlled_lanes(exported):
    m, path, _ = exported
    lmap, _ = _load(path)
    lanes = {ll.id: _lane(ll) for ll in lmap.laneletLayer}
    governed: dict[str, set[str]] = {}
    for ll in lmap.laneletLayer:
        for re in ll.regulatoryElements:
            key = str(re.attributes["feat2map:signal"]) if "feat2map:signal" in re.attributes else re.id
            governed.setdefault(key, set()).add(lanes[ll.id])
    for s in m.signals.values():
        assert governed[s.id] == set(s.lane_ids)
    for re in lmap.regulatoryElementLayer:
        subtype = re.attributes["subtype"]
        if subtype == "traffic_light":
            stop = re.stopLine
            assert stop is not None and stop.attributes["type"] == "stop_line"
        elif subtype == "all_way_stop":
            assert {lanes[x.id] for x in re.lanelets()} == {x for s in m.stop_signs.values()
                                                           if s.junction_id == re.attributes["feat2map:junction"]
                                                           for x in s.lane_ids}
        elif subtype == "right_of_way":  # left turns yield to straight and right turns
            assert {m.lanes[lanes[x.id]].turn for x in re.yieldLanelets()} <= {"left", "uturn"}
            assert {m.lanes[lanes[x.id]].turn for x in re.rightOfWayLanelets()} <= {"none", "right"}
    crosswalks = [ll for ll in lmap.laneletLayer if ll.attributes["subtype"] == "crosswalk"]
    assert len(crosswalks) == len(m.crosswalks)


def test_projector_origin_gives_back_the_map_coordinates(sf_default_map, tmp_path):
    """Autoware's LocalCartesianUTM (map_projector_info.yaml) and Lanelet2's UtmProjector about
    its origin give the map's local metres, for the default origin and a given one."""
    m = sf_default_map
    lane = next(iter(m.lanes.values()))
    for origin, zone in ((None, 10), ((500000.0, 5400000.0), 32)):
        path = tmp_path / f"{zone}" / "map.osm"
        write_lanelet2(m, path, origin=origin, zone=zone)
        info = yaml.safe_load((path.parent / PROJECTOR_INFO).read_text())
        assert info["projector_type"] == "LocalCartesianUTM" and info["vertical_datum"] == "WGS84"
        lmap, _ = _load(path)
        ll = next(x for x in lmap.laneletLayer if _lane(x) == lane.id)
        (x, y), p = lane.left_boundary[0], ll.leftBound[0]
        assert math.hypot(p.x - x, p.y - y) < 1e-3 or math.hypot(ll.leftBound[-1].x - x, ll.leftBound[-1].y - y) < 1e-3
    assert check_lanelet2(path).problems == []


def test_checker_finds_broken_maps(sf_default_map, tmp_path):
    """A junction lanelet not starting at its predecessor's end breaks its manoeuvre; a stop line
    dropped from a traffic light, or no projector file, are problems."""
    from lxml import etree

    path = tmp_path / "map.osm"
    write_lanelet2(sf_default_map, path)
    doc = etree.parse(str(path))
    junction = next(r for r in doc.iter("relation") if r.find("tag[@k='feat2map:junction']") is not None
                    and r.find("tag[@k='subtype']").get("v") == "road")
    left = junction.find("member[@role='left']").get("ref")
    nd = doc.find(f"way[@id='{left}']/nd")  # its first node is its predecessor's last: give it its own
    node = copy.deepcopy(doc.find(f"node[@id='{nd.get('ref')}']"))
    node.set("id", "999999")
    node.set("lat", str(float(node.get("lat")) + 2e-5))  # about 2 m north
    doc.getroot().insert(0, node)
    nd.set("ref", "999999")
    light = next(r for r in doc.iter("relation") if r.find("tag[@v='traffic_light']") is not None)
    light.remove(light.find("member[@role='ref_line']"))
    doc.write(str(path))
    messages = " | ".join(str(p) for p in check_lanelet2(path).problems)
    assert "is no route for vehicles" in messages
    assert "traffic light without its light or stop line" in messages
    (tmp_path / PROJECTOR_INFO).unlink()
    assert any(PROJECTOR_INFO in p.element for p in check_lanelet2(path).problems)


def test_cli_export_and_validate(tmp_path, capsys):
    from feat2map.cli import main

    assert main(["generate", "--spec", "examples/one_way_t.yaml", "--out", str(tmp_path / "g"), "--no-apollo",
                 "--no-picture", "--quiet", "--lanelet2"]) == 0
    assert (tmp_path / "g" / "lanelet2" / PROJECTOR_INFO).is_file()
    out = tmp_path / "x" / "one_way.osm"
    assert main(["export", "lanelet2", str(tmp_path / "g" / "map.json"), "--out", str(out), "--zone", "11"]) == 0
    assert main(["validate", str(out)]) == 0
    assert "0 problems" in capsys.readouterr().out


def test_what_lanelet2_rates_a_warning_is_shown_and_the_map_still_validates(tmp_path, capsys):
    """lanelet2_validation rates bound curvature over 0.5 1/m and points closer than 5 cm
    warnings, not errors: `feat2map validate` prints them as warnings and exits 0; an error
    (a broken manoeuvre) still fails it."""
    from lxml import etree

    from feat2map.cli import main

    assert main(["generate", "--spec", "examples/one_way_t.yaml", "--out", str(tmp_path / "g"), "--no-apollo",
                 "--no-picture", "--quiet", "--lanelet2"]) == 0
    path = next((tmp_path / "g" / "lanelet2").glob("*.osm"))
    doc = etree.parse(str(path))
    way = next(w for w in doc.iter("way") if len(w.findall("nd")) >= 3)
    nds = way.findall("nd")
    a, b = (doc.find(f"node[@id='{nd.get('ref')}']") for nd in nds[:2])
    kink = copy.deepcopy(b)  # a point 2 cm beside b, between a and b: a sharp zigzag, too close to b
    kink.set("id", "999998")
    kink.set("lat", str(float(b.get("lat")) + 2e-7))
    for tag in kink.findall("tag"):
        kink.remove(tag)
    doc.getroot().insert(0, kink)
    way.insert(list(way).index(nds[1]), etree.Element("nd", ref="999998"))
    doc.write(str(path))
    found = check_lanelet2(path).problems
    assert found and all(p.warning for p in found)
    assert {p.message.split(" ")[0] for p in found} >= {"closer"}
    capsys.readouterr()
    assert main(["validate", "--format", "lanelet2", str(path)]) == 0
    out = capsys.readouterr().out
    assert "warning: point 999998: closer than 0.05 m" in out and "0 problems, " in out
