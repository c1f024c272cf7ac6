"""CommonRoad export, read back and checked with commonroad-io (its schema and its reader)."""
from __future__ import annotations

import numpy as np
import pytest
from conftest import SKIP_COMMONROAD_IO, shared_map, shared_map_params

from feat2map.errors import Feat2MapError
from feat2map.formats.commonroad import check_commonroad, lanelet_ids, write_commonroad
from feat2map.formats.commonroad.writer import commonroad_io
from feat2map.formats.commonroad.validate import lanelet_index, reachable
from feat2map.model import midblock_controls
from feat2map.scenarios.routes import manoeuvres

try:
    commonroad_io()  # where scripts/setup.sh puts it (off sys.path, see commonroad_io)
except Feat2MapError:
    pytest.skip(SKIP_COMMONROAD_IO, allow_module_level=True)


@pytest.fixture(scope="module")
def exported(ecosystem_map, tmp_path_factory):
    name, m = ecosystem_map
    path = tmp_path_factory.mktemp(f"cr-{name}") / f"{name}.xml"
    write_commonroad(m, path)
    return m, path, check_commonroad(path)


def _approaches(m) -> int:
    return len({(ln.junction_id, m.lanes[p].road_id) for ln in m.lanes.values() if ln.junction_id
                for p in ln.predecessors if m.lanes[p].junction_id is None})


def test_commonroad_io_reads_it_and_counts_match(exported):
    m, _, report = exported
    assert report.problems == []
    ends = sum((not ln.junction_id and not ln.successors) + (not ln.junction_id and not ln.predecessors)
               for ln in m.lanes.values())  # a continuation lanelet past every exit, before every entry
    assert report.counts == {"lanelets": len(m.lanes) + len(m.crosswalks) + ends, "crosswalks": len(m.crosswalks),
                             "intersections": len(m.junctions), "incomings": _approaches(m),
                             "traffic_lights": len(m.signals) - len(midblock_controls(m)),  # mid-lane: left out
                             "traffic_signs": len(m.stop_signs)}
    assert len(report.routes) == sum(1 for ln in m.lanes.values() if ln.junction_id)


def test_every_manoeuvre_is_reachable_in_the_lanelet_network(exported):
    """From the entry road's lanelets through the junction's to the exit road's, on
    commonroad-io's successor and adjacency lists as read from the file."""
    m, _, report = exported
    lls = lanelet_index(report.scenario.lanelet_network)
    ids = lanelet_ids(m)
    road = {}
    for lid, ln in m.lanes.items():
        road.setdefault(ln.road_id, set()).add(ids[lid])
    junction = {jid: {ids[ln.id] for ln in m.junction_lanes(jid)} for jid in m.junctions}
    moves = manoeuvres(m)
    assert moves
    for jid, entry, exit_ in moves:
        allowed = road[entry] | junction[jid] | road[exit_]
        assert reachable(lls, road[entry], road[exit_], allowed), (jid, entry, exit_)
    assert not reachable(lls, road[moves[0][2]], road[moves[0][1]], road[moves[0][1]] | road[moves[0][2]])


def test_intersections_controls_and_stop_lines_follow_the_map(exported):
    m, _, report = exported
    net = report.scenario.lanelet_network
    ids = lanelet_ids(m)
    lane_of = {v: k for k, v in ids.items()}
    turns = {"outgoing_right": {"right"}, "outgoing_straight": {"none"}, "outgoing_left": {"left", "uturn"}}
    for inter in net.intersections:
        for inc in inter.incomings:
            for key, allowed in turns.items():
                assert {m.lanes[lane_of[x]].turn for x in getattr(inc, key) or ()} <= allowed
    signed = {lid for s in m.stop_signs.values() for lid in s.lane_ids}
    lit = {lid for s in m.signals.values() if s.id not in midblock_controls(m) for lid in s.lane_ids}
    for ll in net.lanelets:
        lane = lane_of.get(ll.lanelet_id)
        if lane is None:  # a crosswalk, or a continuation past an exit / before an entry
            assert {t.value for t in ll.lanelet_type} == {"crosswalk"} or len(ll.successor) + len(ll.predecessor) == 1
            continue
        assert bool(ll.traffic_signs) == (lane in signed) and bool(ll.traffic_lights) == (lane in lit)
        assert (ll.stop_line is not None) == (lane in signed | lit)


def test_light_cycles_are_the_envs_phase_plan(sf_default_map, tmp_path):
    """Each light's cycle is the env's default fixed-time plan (offset 0), step by step."""
    from feat2map.config import COMMONROAD_DT_S
    from feat2map.envs.map_env import MapEnv
    from feat2map.envs.control import PhasePlan
    from feat2map.phases import junction_phases

    m = sf_default_map
    path = tmp_path / "m1.xml"
    write_commonroad(m, path)
    net = check_commonroad(path).scenario.lanelet_network
    ids = lanelet_ids(m)
    light_of = {}
    for ll in net.lanelets:
        for t in ll.traffic_lights:
            light_of[t] = ll.lanelet_id
    lights = {next(s.id for s in m.signals.values() if ids[s.lane_ids[0]] == light_of[t.traffic_light_id]): t
              for t in net.traffic_lights}
    cfg = MapEnv.default_config()
    names = {"green": "green", "amber": "yellow", "red": "red"}
    for phases in junction_phases(m).values():
        plan = PhasePlan(phases, cfg["signal_green"], cfg["signal_amber"], cfg["signal_all_red"], 0.0)
        for sid in (s for p in phases for s in p):
            steps = [el.state.value for el in lights[sid].traffic_light_cycle.cycle_elements for _ in range(el.duration)]
            assert len(steps) == round(plan.cycle / COMMONROAD_DT_S)
            assert steps == [names[plan.state(sid, (k + 0.5) * COMMONROAD_DT_S)] for k in range(len(steps))]


def test_checker_finds_broken_files(sf_default_map, tmp_path):
    """A schema violation, a dropped successor link, and two crossing approaches green at once."""
    from lxml import etree

    path = tmp_path / "m1.xml"
    write_commonroad(sf_default_map, path)
    doc = etree.parse(str(path))
    doc.getroot().set("date", "today")
    succ = next(el for el in doc.iter("successor") if el.getparent().tag == "lanelet")
    succ.getparent().remove(succ)
    for cycle in list(doc.iter("cycle"))[:4]:  # the first junction's lights: all green, always
        for el in cycle.findall("cycleElement"):
            el.find("color").text = "green"
    doc.write(str(path))
    messages = " | ".join(str(p) for p in check_commonroad(path).problems)
    assert "CommonRoad schema" in messages
    assert "does not name it as successor" in messages
    assert "green together on crossing approaches" in messages


def test_lights_green_together_are_a_problem_only_where_their_movements_meet():
    """SVL's 2019 San Francisco map gives a T-junction's stem (right turn only) and the main
    road's approach whose left turn enters the stem one phase: the approaches are 90 degrees
    apart but their paths neither cross nor merge (the env's conflict table keeps them
    together). The checker flagged them ("green together on crossing approaches", 2 of the
    map's junctions); it now looks at the movements: crossing centre lines or one lanelet both
    lead into."""
    from types import SimpleNamespace as NS

    from feat2map.formats.commonroad.validate import _movements_meet

    def move(points, succ):
        return NS(center_vertices=np.asarray(points, dtype=float), successor=[succ])

    # stem from the south (x = 2, heading north) turning right into the east road's far lane;
    # the main road from the east (y = 2, heading west) turning left into the stem's out lane
    stem_right = move([(2, -10), (2, -4), (10, -2)], 1)
    main_left = move([(10, 2), (0, 2), (-2, -10)], 2)
    main_straight = move([(10, 2), (-10, 2)], 3)
    stem_left = move([(2, -10), (2, 0), (-10, 2)], 4)
    assert not _movements_meet([stem_right], [main_left, main_straight])
    assert _movements_meet([stem_left], [main_straight])  # crossing centre lines
    assert _movements_meet([move([(0, -9), (9, 0)], 7)], [move([(9, 9), (9.5, 0.5)], 7)])  # a merge


def test_cli_export_and_validate(tmp_path, capsys):
    from feat2map.cli import main

    assert main(["generate", "--spec", "examples/mega_junction.yaml", "--out", str(tmp_path / "g"), "--no-apollo",
                 "--no-picture", "--quiet", "--commonroad"]) == 0
    out = tmp_path / "mega.xml"
    assert main(["export", "commonroad", str(tmp_path / "g" / "map.json"), "--out", str(out)]) == 0
    assert out.read_bytes() == (tmp_path / "g" / "commonroad.xml").read_bytes()
    assert main(["validate", str(out)]) == 0
    assert "0 problems" in capsys.readouterr().out


def test_exits_and_entries_continue_past_a_planners_horizon(exported):
    """Every map exit (entry) lanelet has a straight 100 m successor (predecessor), adjacent like
    it, so that a planner's horizon never ends in a dead end at the map's edge."""
    from feat2map.config import COMMONROAD_CONTINUATION_M

    m, _, report = exported
    lls = lanelet_index(report.scenario.lanelet_network)
    ids = lanelet_ids(m)
    for lid, ln in m.lanes.items():
        if ln.junction_id:
            continue
        ll = lls[ids[lid]]
        for own, linked, missing in ((ln.successors, ll.successor, "end"), (ln.predecessors, ll.predecessor, "start")):
            if own:
                assert all(x in {ids[o] for o in own} for x in linked)
                continue
            (cid,) = linked
            c = lls[cid]
            length = float(np.sum(np.hypot(*np.diff(c.center_vertices, axis=0).T)))
            assert abs(length - COMMONROAD_CONTINUATION_M) < 0.5
            assert (c.predecessor if missing == "end" else c.successor) == [ids[lid]]
            # it drives on in the lanelet's direction: straight, the same heading as where they meet
            d = np.diff(c.center_vertices, axis=0)
            h = np.arctan2(d[:, 1], d[:, 0])
            p = ll.center_vertices[[-2, -1]] if missing == "end" else ll.center_vertices[[0, 1]]
            hp = np.arctan2(*(p[1] - p[0])[::-1])
            assert np.all(np.abs((h - hp + np.pi) % (2 * np.pi) - np.pi) < 1e-3), lid


def test_one_planning_problem_per_manoeuvre_with_a_single_goal(exported):
    m, _, report = exported
    from commonroad.common.reader.file_reader_xml import XMLFileReader

    _, problems = XMLFileReader(str(exported[1])).open()
    pps = list(problems.planning_problem_dict.values())
    assert len(pps) == len(manoeuvres(m))
    for pp in pps:
        (goal,) = pp.goal.lanelets_of_goal_position.values()
        assert len(goal) == 1


def _validates_with_straight_listed(bad, straight: str, tmp_path) -> None:
    """`bad`'s CommonRoad export has no problem for feat2map's validator, and lists junction
    lane `straight` among its intersection's straight-on manoeuvres."""
    path = tmp_path / "bad.xml"
    write_commonroad(bad, path)
    report = check_commonroad(path)
    assert report.problems == []
    inc = {x for i in report.scenario.lanelet_network.intersections for g in i.incomings
           for x in g.outgoing_straight or ()}
    assert lanelet_ids(bad)[straight] in inc


def test_one_sided_neighbours_and_mislabelled_turns_still_validate(sf_default_map, tmp_path):
    """Issue 21 item 7 as a class: a map that lists a neighbour on one side only (or two on a side),
    and a junction lane declared "left" that runs straight, exports to a file feat2map's own
    CommonRoad validator accepts: adjacency is written mutual, turn sets follow the geometry."""
    import dataclasses

    m = sf_default_map
    lanes = dict(m.lanes)
    road = next(ln for ln in lanes.values() if ln.junction_id is None and ln.left_reverse_neighbors)
    other = next(ln for ln in lanes.values() if ln.junction_id is None and ln.road_id != road.road_id)
    lanes[road.id] = dataclasses.replace(road, left_neighbors=(other.id,), right_neighbors=(other.id,))
    straight = next(ln for ln in lanes.values() if ln.junction_id and ln.turn == "none")
    lanes[straight.id] = dataclasses.replace(straight, turn="left")
    _validates_with_straight_listed(dataclasses.replace(m, lanes=lanes), straight.id, tmp_path)


def test_turn_sets_follow_the_lanelet_as_read_not_our_centre_line(sf_default_map, tmp_path):
    """A CommonRoad file holds a lanelet's borders; a reader's centre line lies midway between
    them. A junction lane whose own centre line lies off that midline (SUMO's WBeaverAve: a
    U-turn whose centre turns 180 degrees and whose borders' midline 168) is listed by the turn
    a reader sees, so the file validates."""
    import dataclasses

    m = sf_default_map
    lanes = dict(m.lanes)
    straight = next(ln for ln in lanes.values() if ln.junction_id and ln.turn == "none")
    c = np.asarray(straight.centerline, dtype=float)
    d = (c[-1] - c[0]) / np.hypot(*(c[-1] - c[0]))
    off = c.copy()
    off[1:-1] += 1.0 * np.array([-d[1], d[0]])  # the centre line 1 m off its borders' midline between its ends
    lanes[straight.id] = dataclasses.replace(straight, centerline=tuple(map(tuple, off)))
    _validates_with_straight_listed(dataclasses.replace(m, lanes=lanes), straight.id, tmp_path)


def test_commonroad_ios_file_reader_imports_next_to_feat2map(sf_default_map, tmp_path):
    """`from commonroad.common.file_reader import CommonRoadFileReader` works once feat2map is
    imported (its protobuf modules need protobuf 3.20; feat2map stands in for them), reads our
    XML, and Apollo's protobuf still works in the same process."""
    import subprocess
    import sys

    path = tmp_path / "m1.xml"
    write_commonroad(sf_default_map, path)
    code = ("import feat2map, logging; logging.getLogger('commonroad').setLevel(logging.ERROR)\n"
            "from commonroad.common.file_reader import CommonRoadFileReader\n"
            "from commonroad.common.file_writer import CommonRoadFileWriter\n"
            f"sc, pp = CommonRoadFileReader({str(path)!r}).open()\n"
            "from feat2map.formats.apollo.schema import parse_map\n"
            "print(len(sc.lanelet_network.lanelets), len(pp.planning_problem_dict))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr[-800:]
    n, problems = map(int, out.stdout.split())
    assert n > len(sf_default_map.lanes) and problems == len(manoeuvres(sf_default_map))


def test_a_planning_problem_starts_on_its_lanelet_as_written(tmp_path):
    """San Francisco's and GoMentum's sparse lanes turn at a vertex: the model's centreline point
    half-way along lay outside the lanelet written from the resampled borders ('its goal
    lanelets ... are not reachable from its start (on lanelets [])'). The start is taken between
    the written borders."""
    from feat2map.model import HDMap, Lane, Road

    def lane(lid, centre, left, right, **links):
        return Lane(lid, "r", tuple(centre), tuple(left), tuple(right), 3.5, 10.0, **links)

    bend = lane("a", [(0, 0), (10, 0), (10, 40), (10, 41)], [(0, 1.75), (8.25, 1.75), (8.25, 40), (8.25, 41)],
                [(0, -1.75), (11.75, -1.75), (11.75, 40), (11.75, 41)], successors=("b",))
    on = lane("b", [(10, 41), (10, 60)], [(8.25, 41), (8.25, 60)], [(11.75, 41), (11.75, 60)], predecessors=("a",))
    m = HDMap({"a": bend, "b": on}, {"r": Road("r", "chain", ("a", "b"))}, {})
    path = tmp_path / "bend.xml"
    write_commonroad(m, path)
    report = check_commonroad(path)
    assert report.problems == []


def test_adjacent_lanelets_share_their_border_and_lanes_apart_are_not_adjacent(tmp_path):
    """Apollo maps draw each lane's borders apart: cube_town's opposite lanes lie 3.3 m apart (a
    median) yet name each other as neighbours, other neighbours' common border is drawn twice,
    up to a metre apart. CommonRoad's road boundary (commonroad-drivability-checker) takes a lane
    section's road from its outermost borders and the ends of the borders inside it, so such
    lanelets written adjacent made a road that cut corners off the lanelets at their ends. Now
    adjacent lanelets share one border (the mean of the two drawings) and lanes apart are not
    adjacent; the checker flags a pair that does not share its border."""
    import xml.etree.ElementTree as ET

    from feat2map.model import HDMap, Lane, Road

    def lane(lid, y_left, y_right, x0=0.0, x1=40.0, bow=0.0, **nb):
        xs = np.linspace(x0, x1, 5)
        arc = bow * np.sin(np.pi * (xs - x0) / (x1 - x0))  # a border drawn off the neighbour's mid-way
        left = [(x, y_left + a) for x, a in zip(xs, arc)]
        right = [(x, y_right) for x in xs]
        centre = [(x, (y_left + y_right) / 2) for x in xs]
        return Lane(lid, "r", tuple(centre), tuple(left), tuple(right), 3.5, 10.0, **nb)

    def backwards(ln):
        return Lane(ln.id, "r", ln.centerline[::-1], ln.right_boundary[::-1], ln.left_boundary[::-1], 3.5, 10.0,
                    left_reverse_neighbors=ln.left_reverse_neighbors)

    lanes = {"a": lane("a", 3.5, 0.0, bow=0.4, left_neighbors=("b",)),  # b's right border runs straight
             "b": lane("b", 7.0, 3.5, right_neighbors=("a",), left_reverse_neighbors=("c",)),
             "c": backwards(lane("c", 13.8, 10.3, left_reverse_neighbors=("b",)))}  # 3.3 m beyond b: a median
    m = HDMap(lanes, {"r": Road("r", "chain", tuple(lanes))}, {})
    path = tmp_path / "apart.xml"
    write_commonroad(m, path)
    report = check_commonroad(path)
    assert [str(p) for p in report.problems] == []
    lls, ids = lanelet_index(report.scenario.lanelet_network), lanelet_ids(m)
    a, b, c = (lls[ids[x]] for x in "abc")
    assert (a.adj_left, a.adj_left_same_direction, b.adj_right) == (b.lanelet_id, True, a.lanelet_id)
    np.testing.assert_array_equal(a.left_vertices, b.right_vertices)  # one border, written once
    assert 3.65 < a.left_vertices[2][1] < 3.85  # mid-way: the mean of 3.9 (a's drawing) and 3.5 (b's)
    assert b.adj_left is None and c.adj_left is None  # not adjacent: they share no border

    # a file whose adjacent lanelets keep two drawings of their border is flagged
    tree = ET.parse(path)
    for ll in tree.getroot().iter("lanelet"):
        if ll.get("id") == str(a.lanelet_id):
            ll.find("leftBound").findall("point")[2].find("y").text = "4.5"
    tree.write(tmp_path / "bad.xml")
    assert any("does not share its border" in str(p) for p in check_commonroad(tmp_path / "bad.xml").problems)


def test_a_sparse_lanes_vertices_are_its_lanelets(tmp_path):
    """Apollo's junction lanes have five points a border: resampled at equal steps, the bends
    were cut up to 0.7 m (cube_town), a lanelet that was not the lane. Every vertex of a lane's
    borders is now a vertex of its lanelet (within 1 cm: vertices closer are one), its
    neighbour's too (one vertex count for both)."""
    from feat2map.model import HDMap, Lane, Road

    def arc(r, n, phase=0.0):  # a quarter turn, its points bunched at the start
        t = (np.linspace(0, 1, n) ** 2 + phase * np.sin(np.linspace(0, np.pi, n))) * np.pi / 2
        return [(r * np.sin(a), r - r * np.cos(a)) for a in t]

    inner = Lane("in", "r", tuple(arc(12.0, 7)), tuple(arc(10.25, 5)), tuple(arc(13.75, 6, 0.1)), 3.5, 10.0,
                 right_neighbors=("out",))
    outer = Lane("out", "r", tuple(arc(15.5, 9)), tuple(arc(13.75, 6, 0.1)), tuple(arc(17.25, 4)), 3.5, 10.0,
                 left_neighbors=("in",))
    m = HDMap({"in": inner, "out": outer}, {"r": Road("r", "chain", ("in", "out"))}, {})
    path = tmp_path / "sparse.xml"
    write_commonroad(m, path)
    report = check_commonroad(path)
    assert [str(p) for p in report.problems] == []
    lls, ids = lanelet_index(report.scenario.lanelet_network), lanelet_ids(m)
    for lane, side in ((inner, "left"), (outer, "right")):  # the outer borders, as the lanes draw them
        ll = lls[ids[lane.id]]
        written = ll.left_vertices if side == "left" else ll.right_vertices
        drawn = np.asarray(lane.left_boundary if side == "left" else lane.right_boundary)
        assert max(np.hypot(*(written - p).T).min() for p in drawn) < 0.01  # COMMONROAD_VERTEX_STEP_M
    assert lls[ids["in"]].adj_right == ids["out"]
    np.testing.assert_array_equal(lls[ids["in"]].right_vertices, lls[ids["out"]].left_vertices)


def test_a_junction_lane_leading_nowhere_is_no_manoeuvre(tmp_path):
    """Autonomous Stuff's junction 4 has three lanes that end at an arm without a road: listed as
    manoeuvres of their incomings, each was 'not reachable ... to a lanelet past it'. They are
    written as lanelets and left out of the intersection, one warning naming them."""
    import warnings
    from dataclasses import replace

    import feat2map
    from feat2map.features import JunctionFeature

    m = feat2map.generate_from_features([JunctionFeature.make([0, 90, 180, 270], "signal", False)], seed=0)
    dead = next(ln for ln in m.lanes.values() if ln.junction_id is not None)
    lanes = {k: replace(ln, predecessors=tuple(p for p in ln.predecessors if p != dead.id)) for k, ln in m.lanes.items()}
    lanes[dead.id] = replace(dead, successors=())
    path = tmp_path / "dead.xml"
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        write_commonroad(replace(m, lanes=lanes), path)
    assert [str(w.message) for w in caught if "lead nowhere" in str(w.message)] == [
        f"map: 1 junction lane(s) lead nowhere ({dead.id}): written as lanelets, not listed as intersection "
        "manoeuvres in the CommonRoad export"]
    report = check_commonroad(path)
    assert report.problems == []
    assert lanelet_ids(m)[dead.id] in lanelet_index(report.scenario.lanelet_network)


def test_opposed_approaches_left_turns_are_permissive_however_skewed():
    """San Francisco's junction 90 pairs two approaches 128 degrees apart (a skewed crossing):
    their straights do not meet, so feat2map's paired plan lets their left turns go permissive.
    The checker took them for crossing approaches ('green together on crossing approaches');
    like the plan, it now leaves opposed approaches' left turns out, and nothing else."""
    from types import SimpleNamespace as NS

    from feat2map.formats.commonroad.validate import _movements_meet, _unprotected

    def move(lid, points):
        return NS(lanelet_id=lid, center_vertices=np.asarray(points, dtype=float), successor=[100 + lid])

    # right-hand traffic: northbound at x = 2, southbound at x = -2, each turning left across the other
    north = [move(1, [(2, -10), (2, 10)]), move(2, [(2, -10), (2, 0), (-10, 2)])]
    south = [move(3, [(-2, 10), (-2, -10)]), move(4, [(-2, 10), (-2, 0), (10, -2)])]
    west = [move(5, [(10, 2), (-10, 2)])]  # westbound straight: crosses both
    turn_of = {1: "outgoing_straight", 2: "outgoing_left", 3: "outgoing_straight", 4: "outgoing_left",
               5: "outgoing_straight"}
    assert _movements_meet(north, south)
    assert not _movements_meet(*_unprotected(north, south, turn_of))
    assert _movements_meet(*_unprotected(north, west, turn_of))  # not opposed: every movement counts
    assert _movements_meet(*_unprotected(north, [move(3, [(-2, 10), (-2, -10)]), move(6, [(-2, 10), (10, -2)])],
                                         {**turn_of, 6: "outgoing_right"}))  # a right turn across is no left


@pytest.mark.real_maps
@pytest.mark.parametrize("rel", shared_map_params("apollo/autonomous_stuff/base_map.bin", "apollo/gomentum/*",
                                                  "apollo/san_francisco/base_map.bin", "apollo/cube_town/base_map.bin",
                                                  "apollo/borregas_ave/base_map.bin", "apollo/shalun/base_map.bin"))
def test_real_apollo_maps_commonroad_exports_validate_clean(rel, tmp_path):
    """Autonomous Stuff's dead-end junction lanes, GoMentum's unlinked back-to-back junction
    lanes, San Francisco's sparse bends and skewed opposed lights, cube_town's opposite lanes
    across a median and every map's neighbours drawing their common border twice (adjacent
    lanelets share one border): each export validates clean."""
    import warnings

    from feat2map.formats import read_map

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the source's flaws, each repaired with its warning
        write_commonroad(read_map(shared_map(rel)), tmp_path / "map.xml")
    assert [str(p) for p in check_commonroad(tmp_path / "map.xml").problems] == []
