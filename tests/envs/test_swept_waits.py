"""Waits beside the swept path of turning cars (envs/sweep.py): on a narrow two-way road a car
waiting at the junction's line (or before a passage) stands out of the path the ego's lane
keeping actually sweeps when it turns into the opposite lane (SUMO durlacher-tor r025: the ego
turning out of junction 33 clipped a car standing at the opposite bare entry; digitaf r110/r125:
the ego running wide through a 90-degree kink clipped a car waiting before the passage).

The map the tests make: one generated bare 4-way junction whose road 1 keeps 2.6 m lanes for
10 m at the junction (two cars pass there, straight) and narrows to 1.6 m lanes beyond (a
passage), its lanes shifted 1.5 m sideways, so the junction lanes bend to meet them (the
converters' jogs at a junction's mouth); road 2 narrows to 1.6 m lanes from the junction."""
from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import shapely

import feat2map
from conftest import as_another_tools

from feat2map.config import IDM_STOP_GAP_M, IDM_STOP_MARGIN_M
from feat2map.envs.network import MapNetwork
from feat2map.envs.sim import passages
from feat2map.envs.rules import room_to_wait
from feat2map.envs.sweep import footprints
from feat2map.formats import read_map
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.scenario import Scenario, make_env

INBOUND, OUTBOUND, FAR = "1_0_1", "1_0_-1", "2_0_1"  # road 1 towards / away from the junction; road 2 towards it


def _widths(road, parts) -> None:
    """Every lane of an OpenDRIVE `road` element gets these (sOffset, a, c, d) cubic widths."""
    from lxml import etree

    for lane in road.findall("lanes/laneSection/*/lane"):
        old = lane.find("width")
        if old is None:
            continue
        at = lane.index(old)
        lane.remove(old)
        for k, (s, a, c, d) in enumerate(parts):
            lane.insert(at + k, etree.Element("width", sOffset=repr(s), a=repr(a), b="0.0", c=repr(c), d=repr(d)))


def _taper(w0: float, w1: float, s0: float, s1: float) -> list[tuple[float, float, float, float]]:
    """Width w0 up to s0, a cubic (zero slope at both joints) to w1 at s1, then w1."""
    n, dw = s1 - s0, w1 - w0
    return [(0.0, w0, 0.0, 0.0), (s0, w0, 3 * dw / n ** 2, -2 * dw / n ** 3), (s1, w1, 0.0, 0.0)]


@pytest.fixture(scope="module")
def jogged(tmp_path_factory) -> Path:
    from lxml import etree

    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("jogged")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    write_opendrive(feat2map.generate_from_features([four], seed=0), d / "four.xodr")
    root = as_another_tools(etree.parse(str(d / "four.xodr")).getroot())
    roads = {r.get("id"): r for r in root.findall("road")}
    _widths(roads["1"], _taper(2.6, 1.6, 10.0, 16.0))
    roads["1"].find("lanes/laneOffset").set("a", "-1.5")
    _widths(roads["2"], _taper(3.5, 1.6, 0.0, 4.0))
    (d / "jogged.xodr").write_bytes(etree.tostring(root))
    return d / "jogged.xodr"


def _least_room(length: float) -> float:
    """The least road [m] a car `length` long can wait on (`rules.room_to_wait`), to 0.1 m."""
    return next(r / 10 for r in range(200) if room_to_wait(r / 10, length))


def _ego_sweep(path: Path, entry: str) -> np.ndarray:
    """Footprints of the ego (the baseline planner, alone) driving from road `entry` through the
    junction into road 1, every policy step."""
    sc = Scenario("jogged", str(path), (("1", entry, "1"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    planner = BaselinePlanner()
    planner.reset(env)
    poses = []
    for _ in range(int(60 * u.config["policy_frequency"])):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        poses.append((*u.vehicle.position, u.vehicle.heading))
        if term or trunc:
            break
    env.close()
    assert u.route_completed()
    return footprints(np.array(poses))


def _waits_at(path: Path, with_sweeps: bool):
    """Footprint of a car that comes down road 1 towards road 2 while another car holds road 2's
    passage from the far side, where the rules make it come to rest (its stop point less the
    stop margin and jam gap, its centre half a car behind), with and without the swept
    stretches."""
    m = read_map(path)
    sc = Scenario("jogged", str(path), (("1", "3", "1"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net = u.net
    to_2 = next(ln.id for ln in m.lanes_by_junction["1"]
                if ln.predecessors[0] == INBOUND and ln.successors[0] == "2_0_-1")
    holder = u.road.spawn(FAR, 5.0, 0.0, [FAR])
    car = u.road.spawn(INBOUND, 10.0, 0.0, [INBOUND, to_2, "2_0_-1"])
    u.control.update(u.road, 0.0)
    ps = net.passages[FAR]
    assert holder in u.control.passage_state(ps.group)[0][ps.side]
    swept = net.swept
    try:
        if not with_sweeps:
            net.swept = {}  # the network is cached per map: put back below
        stop = u.control.stop_distance(car)
    finally:
        net.swept = swept
    env.close()
    assert stop < np.inf  # it waits for road 2's passage
    rest = car.s_on(INBOUND) + stop - IDM_STOP_MARGIN_M - IDM_STOP_GAP_M - car.LENGTH / 2
    lane = net.lane_of[INBOUND]
    return footprints(np.array([(*lane.position(rest, 0.0), lane.heading_at(rest))]))[0], rest


def test_jogged_mouth_has_a_swept_stretch(jogged):
    """Both lanes of road 1 are one passage (its narrow part), and the last metres of the lane
    towards the junction are swept by cars turning into the opposite lane out of the junction,
    past where a car waits at the bare entry."""
    net = MapNetwork.from_map(read_map(jogged))
    assert net.passages[INBOUND].group == net.passages[OUTBOUND].group
    length = net.lane_of[INBOUND].length
    spans = net.swept[INBOUND]
    assert any(lo > net.passages[INBOUND].s1 and hi >= length - 1.0 for lo, hi in spans), spans


@pytest.mark.parametrize("entry", ["2", "3", "4"])
def test_wait_at_the_mouth_is_out_of_the_turning_ego(jogged, entry):
    """The car waiting at road 1's line for road 2's passage stands clear of every footprint of the
    ego turning from road `entry` into road 1 (left, straight, right). At the line's usual
    stop point (no swept stretches) the ego's body runs over it."""
    ego = _ego_sweep(jogged, entry)
    moved, rest = _waits_at(jogged, with_sweeps=True)
    usual, usual_rest = _waits_at(jogged, with_sweeps=False)
    assert rest < usual_rest - 0.5
    assert float(shapely.distance(ego, usual).min()) == 0.0
    assert float(shapely.distance(ego, moved).min()) > 0.0


def test_generated_maps_have_no_swept_stretches():
    """No passage, no swept stretch: stop points on generated maps are where they were."""
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    net = MapNetwork.from_map(feat2map.generate_from_features([four, four], seed=0))
    assert not net.passages and not net.swept


def test_swept_room_after_the_junction_is_no_room(jogged):
    """Road 1's first metres after the junction leave room for one car before its passage, but
    cars turning out of road 1 into the junction sweep over them (the jog): a car heading into
    road 1 while its passage is held from the far side waits at the junction's line, not in that
    room standing turned beside the passage's traffic (SUMO durlacher-tor r025, then r024, r027,
    r029: a car waiting there, its body still turned, was clipped, or locked the junction)."""
    m = read_map(jogged)
    sc = Scenario("jogged", str(jogged), (("1", "3", "1"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net = u.net
    ps = net.passages[OUTBOUND]
    assert ps.s0 > _least_room(u.vehicle.LENGTH)  # room enough on a clear road
    from_3 = next(ln.id for ln in m.lanes_by_junction["1"]
                  if m.lanes[ln.predecessors[0]].road_id == "3" and ln.successors[0] == OUTBOUND)
    approach = m.lanes[from_3].predecessors[0]
    holder = u.road.spawn(INBOUND, 2.0, 0.0, [INBOUND])
    car = u.road.spawn(approach, 5.0, 0.0, [approach, from_3, OUTBOUND])
    u.control.update(u.road, 0.0)
    assert holder in u.control.passage_state(ps.group)[0][1 - ps.side]
    chain, wait = u.control.passage_ahead(car)
    line = u.control.line_distance(car, from_3)
    swept = net.swept
    try:
        net.swept = {}
        _, wait_unswept = u.control.passage_ahead(car)
    finally:
        net.swept = swept
    env.close()
    assert (ps.group, ps.side) in chain
    assert wait <= line  # before the junction
    assert wait_unswept > line + net.lane_of[from_3].length  # without the stretches: in the room after it


def test_holder_out_on_the_road_beyond_lets_go_though_its_route_loops_back(jogged):
    """A car that drove through road 2's passage and is out on a road beyond it lets go, though
    its route comes back into the passage later (a car circling a block held the passage from
    behind the cars waiting for it: Testfeld_Karlsruhe r142), unless it is as near its wait for
    the loop back in as a new claim and nobody waits on the other side before it (dropped there,
    its claim was lost to a car from the other side: digitaf r022); in the junction right after
    the passage, and before it, a holder keeps holding."""
    m = read_map(jogged)
    sc = Scenario("jogged", str(jogged), (("1", "3", "1"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, core = u.net, u.road.core
    ps = net.passages[FAR]
    j = next(ln.id for ln in m.lanes_by_junction["1"]
             if ln.predecessors[0] == FAR and m.lanes[ln.successors[0]].road_id == "3")
    road = m.lanes[j].successors[0]
    back = next(ln.id for ln in m.lanes_by_junction["1"] if m.lanes[ln.predecessors[0]].road_id == "3")
    loop = [FAR, j, road, back, FAR]

    def placed(route: list[str], pos: int, s: float):  # standing at s on the route's lane `pos`
        v = core.add_traffic(u.road, route[pos], s, 0.0, route)
        v.route_pos = pos
        return v

    end = net.lane_of[road].length
    far, near, inside, before = placed(loop, 2, 1.0), placed(loop, 2, end - 1.0), placed(loop, 1, 3.0), placed(loop, 0, 1.0)
    everyone = (far, near, inside, before)
    control = u.control
    for v in everyone:
        passages.hold(core, v.row, ps.group, ps.side)
    control._update_passages({}, {id(v) for v in u.road.vehicles})
    assert set(control.passage_state(ps.group)[0][ps.side]) == {near, inside, before}
    to_2 = next(ln.id for ln in m.lanes_by_junction["1"]
                if ln.predecessors[0] == INBOUND and ln.successors[0] == "2_0_-1")
    waiter = placed([INBOUND, to_2, "2_0_-1"], 0, 20.0)  # waits for the other side since t = 0
    passages.enrol(core, waiter.row, [(ps.group, 1 - ps.side)], False, None, 0.0)
    control._update_passages({}, {id(v) for v in u.road.vehicles})
    assert set(control.passage_state(ps.group)[0][ps.side]) == {inside, before}
    assert waiter in control.passage_state(ps.group)[1]
    env.close()
