"""Narrow passages (envs.network.Passage, envs.rules): road lanes of opposite directions closer
than a car width plus margin (autonomous_stuff's one-lane two-way roads, 0.5 m apart; GoMentum's
lane_61/lane_62, 2.1 m apart where a road splits) are driven one direction at a time, first come
first served, by traffic and by the baseline planner; the map the test makes is a two-junction
map whose link road narrows to a one-lane bridge (lanes 1 m wide, centrelines 1 m apart).
Generated maps have no such lanes, so nothing changes on them."""
from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

import feat2map
from conftest import as_another_tools

from feat2map.config import STOP_POINT_M
from feat2map.envs.network import PASSAGE_DISTANCE_M, MapNetwork
from feat2map.formats import read_map
from feat2map.scenarios.rollout import run_suite
from feat2map.scenarios.routes import build_suite
from feat2map.scenarios.scenario import Scenario, make_env

BRIDGE_WIDTH_M, TAPER_M = 1.0, 12.0


def _narrow(src: Path, dst: Path, road_id: str, width: float, taper: float) -> None:
    """Road `road_id` of an exported OpenDRIVE map narrowed from its lane width to `width` over
    `taper` metres at both ends (`_narrow_near`)."""
    from lxml import etree

    road = next(r for r in etree.parse(str(src)).getroot().findall("road") if r.get("id") == road_id)
    length = float(road.get("length"))
    _narrow_near(src, dst, road_id, [(0.0, None), (taper, width), (length - taper, width), (length, None)])


@pytest.fixture(scope="module")
def bridge(tmp_path_factory) -> Path:
    """Two 4-way stop junctions joined by road 3 (61 m), narrowed to a one-lane bridge."""
    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("bridge")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "stop", False)
    write_opendrive(feat2map.generate_from_features([four, four], seed=0), d / "twin.xodr")
    _narrow(d / "twin.xodr", d / "bridge.xodr", "3", BRIDGE_WIDTH_M, TAPER_M)
    return d / "bridge.xodr"


def _coincident(m, road_id: str):
    """`m` with road `road_id`'s two opposite lanes drawn on one centre line, the one reversed
    (Baidu-style one-lane two-way roads: lanes `2765` and `2765dup1`), and the junction lanes
    at its ends bent (linearly along their length) to meet it."""
    import dataclasses

    from feat2map.model import as_polyline

    road = m.roads[road_id]
    a, b = m.lanes[road.right_lanes[0]], m.lanes[road.left_lanes[0]]
    mid = (a.points + b.points[::-1]) / 2
    u = np.gradient(mid, axis=0)
    u /= np.hypot(*u.T)[:, None]
    n = np.stack([-u[:, 1], u[:, 0]], axis=1) * a.width / 2
    lanes = dict(m.lanes)
    for ln, c, side in ((a, mid, n), (b, mid[::-1], -n[::-1])):
        lanes[ln.id] = dataclasses.replace(ln, centerline=as_polyline(c), left_boundary=as_polyline(c + side),
                                           right_boundary=as_polyline(c - side), bezier=None)

    def bend(ln, to, at_end: bool):
        p = ln.points
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
        w = (s / s[-1] if at_end else 1 - s / s[-1])[:, None] * (np.asarray(to) - p[-1 if at_end else 0])
        moved = [as_polyline(np.asarray(q) + w) if len(q) == len(p) else q
                 for q in (ln.centerline, ln.left_boundary, ln.right_boundary)]
        return dataclasses.replace(ln, centerline=moved[0], left_boundary=moved[1], right_boundary=moved[2],
                                   bezier=None)

    for ln in (a, b):
        new = lanes[ln.id]
        for x in ln.predecessors:
            lanes[x] = bend(lanes[x], new.centerline[0], True)
        for x in ln.successors:
            lanes[x] = bend(lanes[x], new.centerline[-1], False)
    return dataclasses.replace(m, lanes=lanes)


@pytest.fixture(scope="module")
def one_lane(tmp_path_factory) -> Path:
    """Two 4-way stop junctions whose link road R2 is one lane used both ways, drawn as two
    lanes with identical reversed centre lines (native map)."""
    from feat2map.formats import native

    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "stop", False)
    path = tmp_path_factory.mktemp("one_lane") / "one_lane.json"
    native.save(_coincident(feat2map.generate_from_features([four, four], seed=0), "R2"), path)
    return path


def test_coincident_opposite_lanes_are_one_passage(one_lane):
    """Opposite lanes at distance 0 from end to end are a passage over their whole length (their
    direction was read backwards at s = 0 and the pair dropped: both directions drove in)."""
    m = read_map(one_lane)
    net = MapNetwork.from_map(m)
    a, b = m.roads["R2"].lane_ids
    assert m.lanes[a].centerline == m.lanes[b].centerline[::-1]
    assert set(net.passages) == {a, b}
    pa, pb = net.passages[a], net.passages[b]
    assert pa.group == pb.group and {pa.side, pb.side} == {0, 1}
    for x in (a, b):
        assert net.passages[x].s0 == 0.0 and net.passages[x].s1 == pytest.approx(net.lane_of[x].length)
    from feat2map.envs.network import unguarded_coincident_lanes

    assert unguarded_coincident_lanes(net) == []
    net.passages.clear()  # the load-time check names the pair when no passage guards it
    assert unguarded_coincident_lanes(net) == [f"road lanes {min(a, b)} and {max(a, b)} coincide in opposite "
                                               "directions but are no narrow passage"]


def test_coincident_lanes_drive_clean_with_traffic(one_lane):
    """Every manoeuvre's route of the one-lane map drives with 6 traffic cars without a failure
    (head-on collisions on the shared lane before)."""
    suite = build_suite(one_lane, traffic_vehicles=6)
    assert suite.scenarios
    result = run_suite(suite, "baseline", workers=1, progress=False, record_failure_gif=False)
    assert [f"{o.name}: {o.outcome}: {o.message}" for o in result.failures("any")] == []


def test_generated_maps_have_no_passages():
    """Opposite lanes of generated roads are a lane width apart: no passage, so the rules (and
    the PPO example's behaviour) are those of before on every generated map."""
    maps = [feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=s) for s in range(3)]
    maps.append(feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 72, 144, 216, 288], "signal", True)],
                                                seed=0))
    for m in maps:
        net = MapNetwork.from_map(m)
        assert net.passages == {}
        assert any(ln.junction_id is None for ln in m.lanes.values())


def test_one_lane_bridge_is_one_passage(bridge):
    """Both lanes of the narrowed road form one passage, one lane a side, over the stretch where
    their centrelines are closer than PASSAGE_DISTANCE_M (plus half a car at each end)."""
    m = read_map(bridge)
    net = MapNetwork.from_map(m)
    link = [ln.id for ln in m.lanes.values() if ln.road_id == "3"]
    assert len(link) == 2 and set(net.passages) == set(link)
    a, b = (net.passages[x] for x in link)
    assert a.group == b.group and {a.side, b.side} == {0, 1}
    for x in link:
        p = net.passages[x]
        assert 30.0 < p.s1 - p.s0 <= net.lane_of[x].length + 1e-6
    assert BRIDGE_WIDTH_M < PASSAGE_DISTANCE_M


def _through(m, jid: str, entry: str, exit_: str) -> str:
    return next(ln.id for ln in m.lanes_by_junction[jid] if m.lanes[ln.predecessors[0]].road_id == entry
                and m.lanes[ln.successors[0]].road_id == exit_)


def test_oncoming_car_waits_until_the_ego_has_crossed(bridge):
    """The ego drives west to east over the bridge; a traffic car heading into it from the east
    waits before it (outside the junction) until the ego is off it: the two are never on the
    bridge together and nobody collides. Without the rule they met head-on."""
    m = read_map(bridge)
    sc = Scenario("bridge", str(bridge), (("1", "1", "3"), ("2", "3", "6")), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    net = u.net
    west_east = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id in u.vehicle.lane_route)
    east_west = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id != west_east)
    j = next(ln for ln in m.lanes.values() if ln.junction_id is not None and east_west in ln.successors)
    route = [j.predecessors[0], j.id, east_west]
    car = u.road.spawn(route[0], net.lane_of[route[0]].length - 40.0, 8.0, route)
    from feat2map.scenarios.planner import BaselinePlanner

    planner = BaselinePlanner()
    planner.reset(env)
    together = waited = False
    for _ in range(int(60 * u.config["policy_frequency"])):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        ego_on = net.id_of.get(u.vehicle.lane_index) == west_east
        car_on = net.id_of.get(car.lane_index) == east_west
        assert not info["collision"], f"collision at t={info['time']:.1f} s"
        together |= ego_on and car_on
        waited |= ego_on and car.speed < 0.5 and m.lanes[net.id_of.get(car.lane_index)].junction_id is None
        if term or trunc:
            break
    env.close()
    assert u.route_completed()
    assert not together and waited and not car.crashed


def test_bridge_map_drives_clean_with_traffic(bridge):
    """Every manoeuvre's route of the bridge map drives with 6 traffic cars without a failure."""
    suite = build_suite(bridge, traffic_vehicles=6)
    assert suite.scenarios
    result = run_suite(suite, "baseline", workers=1, progress=False, record_failure_gif=False)
    assert [f"{o.name}: {o.outcome}: {o.message}" for o in result.failures("any")] == []


def test_driver_views_pedestrian_feature_is_not_a_passage_wait(bridge):
    """DriverView's `pedestrian` feature asks the rules for pedestrians only: an oncoming car
    holding the bridge makes the ego wait (the rules' stop distance is finite), the feature stays 0."""
    from feat2map.envs.driver_view import DRIVER_VIEW_FEATURES

    m = read_map(bridge)
    sc = Scenario("bridge", str(bridge), (("1", "1", "3"), ("2", "3", "6")), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False, "pedestrian_rate": 0.0,
                               "observation": {"type": "DriverView"}})
    env.reset(seed=0)
    u = env.unwrapped
    west_east = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id in u.vehicle.lane_route)
    east_west = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id != west_east)
    u.road.spawn(east_west, 1.0, 0.0, [east_west])  # holds the bridge, standing on it
    waited = False
    for _ in range(40):
        obs, *_ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        if u.control.passage_stop(u.vehicle) < math.inf:
            waited = True
            assert obs[DRIVER_VIEW_FEATURES.index("pedestrian")] == 1.0  # 1: none within its scale
    env.close()
    assert waited


@pytest.fixture(scope="module")
def two_narrow(tmp_path_factory) -> Path:
    """One bare 4-way junction whose legs 1 and 2 narrow to 1.6 m lanes (12 m tapers): each is a
    narrow passage ending 4.3 m before the junction, too little road to wait on at either side
    of it alone, 8.5 m across it (the converter maps' 2.0-2.5 m roads meeting at a junction)."""
    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("two_narrow")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    write_opendrive(feat2map.generate_from_features([four], seed=0), d / "one.xodr")
    _narrow(d / "one.xodr", d / "n1.xodr", "1", 1.6, TAPER_M)
    _narrow(d / "n1.xodr", d / "two_narrow.xodr", "2", 1.6, TAPER_M)
    return d / "two_narrow.xodr"


@pytest.mark.parametrize("car_speed", [8.0, 5.0])
def test_two_narrow_roads_at_a_junction_do_not_lock(two_narrow, car_speed):
    """The ego drives from narrow road 1 through the junction into narrow road 2, a car the other
    way round. Each claims its way in and its way out together (no car can wait between them
    clear of both), so one waits before its road until the other is through. Claiming the way
    in alone, both drove into their roads and waited at the junction for each other's: locked
    for the whole minute (scheck-in r006, Testfeld_Karlsruhe r137/r144)."""
    m = read_map(two_narrow)
    net0 = MapNetwork.from_map(m)
    inbound = {r: next(x for x in net0.passages if m.lanes[x].road_id == r and m.lanes[x].successors)
               for r in ("1", "2")}
    outbound = {r: next(x for x in net0.passages if m.lanes[x].road_id == r and not m.lanes[x].successors)
                for r in ("1", "2")}
    for r in ("1", "2"):
        ps = net0.passages[inbound[r]]
        room = net0.lane_of[inbound[r]].length - ps.s1
        assert 2.0 < room < 5.0 + 1.0 <= 2 * room  # not room alone, room across the junction
    sc = Scenario("two_narrow", str(two_narrow), (("1", "1", "2"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    net = u.net
    j = next(ln.id for ln in m.lanes_by_junction["1"]
             if ln.predecessors[0] == inbound["2"] and ln.successors[0] == outbound["1"])
    car = u.road.spawn(inbound["2"], 0.0, car_speed, [inbound["2"], j, outbound["1"]])
    for lid in (inbound["1"], outbound["2"]):  # the ego, placed before road 1, holds both ways
        assert u.vehicle in u.control.passage_state(net.passages[lid].group)[0][net.passages[lid].side]
    from feat2map.scenarios.planner import BaselinePlanner

    planner = BaselinePlanner()
    planner.reset(env)
    for _ in range(int(60 * u.config["policy_frequency"])):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        assert not info["collision"], f"collision at t={info['time']:.1f} s"
        if term or trunc:
            break
    env.close()
    assert u.route_completed() and info["time"] < 30.0 and not car.crashed


def test_holder_lets_go_once_its_rear_is_out(bridge):
    """A car holds the bridge from before it until its rear has passed the bridge's end, and no
    longer (still on the same lane, waiting beyond the bridge, it held up the other direction for
    nothing: digitaf r025)."""
    m = read_map(bridge)
    sc = Scenario("bridge", str(bridge), (("1", "1", "3"), ("2", "3", "6")), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net = u.net
    west_east = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id in u.vehicle.lane_route)
    east_west = next(ln.id for ln in m.lanes.values() if ln.road_id == "3" and ln.id != west_east)
    ps = net.passages[east_west]
    car = u.road.spawn(east_west, 1.0, 8.0, [east_west])
    seen = {True: False, False: False}  # rear in the passage / past its end, on the bridge's lane
    for _ in range(int(20 * u.config["policy_frequency"])):
        env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        if net.id_of.get(car.lane_index) != east_west:
            break
        s = car.s_on(east_west)
        inside = s - car.LENGTH / 2 <= ps.s1
        assert (car in u.control.passage_state(ps.group)[0][ps.side]) == inside, (s, ps)
        seen[inside] = True
    env.close()
    assert seen[True] and seen[False]


def test_passage_wait_after_back_to_back_junctions_is_before_the_first(tmp_path):
    """A one-lane two-way road (R4, coincident lanes) leaves J1, whose approach is 0.2 m of road
    after the 4 m junction JX (`tight_approach` of test_real_classes). A car heading for R4 while
    a car holds it from the other side waits at JX's entry, not at J1's line: a car waiting there
    stands inside JX and blocks it (digitaf r033: a car waiting on a short road between two
    junctions for the passage beyond locked the junction behind it)."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from feat2map.formats import native
    from test_real_classes import _short_approach_map

    m = read_map(_short_approach_map(tmp_path / "tight.json", 4.0))
    native.save(_coincident(m, "R4"), tmp_path / "b2b.json")
    m = read_map(tmp_path / "b2b.json")
    sc = Scenario("b2b", str(tmp_path / "b2b.json"), (("J0", "R0", "R3"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    out = next(ln.id for ln in m.lanes_by_junction["J1"] if ln.predecessors[0] == "R2_0" and ln.successors[0] == "R4_0")
    back = next(ln.id for ln in m.lanes_by_junction["J1"] if ln.predecessors[0] == "R4_1")
    to_jx = u.net.lane_of["R2_0_r"].length
    car = u.road.spawn("R2_0_r", to_jx - 30.0, 0.0, ["R2_0_r", "R2_0_jx", "R2_0", out, "R4_0"])
    u.road.spawn("R4_1", 10.0, 0.0, ["R4_1", back])  # holds R4 from the other side
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))
    chain, wait = u.control.passage_ahead(car)
    assert chain == [(u.net.passages["R4_0"].group, u.net.passages["R4_0"].side)]
    assert 0.0 < wait <= to_jx - car.s_on("R2_0_r") - 1.0 + 1e-6  # before JX, not inside it
    assert u.control.passage_stop(car) == pytest.approx(wait)
    env.close()


def _narrow_near(src: Path, dst: Path, road_id: str, profile: list[tuple[float, float | None]]) -> None:
    """Road `road_id` of an exported OpenDRIVE map with lane widths through the points `profile`
    ((s, width), None: the lane's own width), cubic between them with zero slope at each."""
    from lxml import etree

    root = as_another_tools(etree.parse(str(src)).getroot())
    road = next(r for r in root.findall("road") if r.get("id") == road_id)
    for lane in road.findall("lanes/laneSection/*/lane"):
        old = lane.find("width")
        if old is None:
            continue
        w0 = float(old.get("a"))
        at = lane.index(old)
        lane.remove(old)
        pts = [(s, w0 if w is None else w) for s, w in profile]
        for k, (s, w) in enumerate(pts):
            t, dw = (pts[k + 1][0] - s, pts[k + 1][1] - w) if k + 1 < len(pts) else (1.0, 0.0)
            lane.insert(at + k, etree.Element("width", sOffset=repr(s), a=repr(w), b="0.0",
                                              c=repr(3 * dw / t ** 2), d=repr(-2 * dw / t ** 3)))
    dst.write_bytes(etree.tostring(root))


@pytest.fixture(scope="module")
def room_for_one(tmp_path_factory) -> Path:
    """One bare 4-way junction: road 1 narrows to 1.6 m lanes over its 10 m next to the junction
    (passage A, up to the junction's edge), road 2 from 8 m after the junction on (passage B):
    7.2 m of road between the junction and B, room to wait for one car (SUMO durlacher-tor's
    `3835_0_-1` into junction 33 and `3593_0_-1`, 7.4 m before the next passage)."""
    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("room_for_one")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    write_opendrive(feat2map.generate_from_features([four], seed=0), d / "one.xodr")
    _narrow_near(d / "one.xodr", d / "a.xodr", "1", [(0.0, 1.6), (10.0, 1.6), (14.0, None)])
    _narrow_near(d / "a.xodr", d / "room_for_one.xodr", "2", [(0.0, None), (8.0, None), (12.0, 1.6)])
    return d / "room_for_one.xodr"


def test_room_before_a_passage_is_taken_with_the_passage_before_it(room_for_one):
    """Two cars placed inside passage A both head through the junction into road 2, whose 7.2 m
    before passage B hold one waiting car; two cars come the other way out of B. The first car
    in A takes the place before B with A; the second must claim B too (all or nothing), and
    while B is held from the other side it may not be placed there (refused like a head-on
    spawn). Placed there before, it followed the first into the junction and stood in the way:
    nobody moved for the whole minute and the ego behind them timed out (SUMO durlacher-tor
    r024, r027, r029)."""
    from feat2map.envs.rules import places_to_wait

    m = read_map(room_for_one)
    sc = Scenario("room", str(room_for_one), (("1", "1", "2"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    net, ctl = u.net, u.control
    a_in, b_out = net.passages["1_0_1"], net.passages["2_0_-1"]
    assert a_in.s1 == pytest.approx(net.lane_of["1_0_1"].length) and a_in.s0 > 5.0  # A up to the junction
    assert places_to_wait(b_out.s0, 5.0) == 1  # room for one before B
    to_b = next(ln.id for ln in m.lanes_by_junction["1"] if ln.predecessors[0] == "1_0_1" and ln.successors[0] == "2_0_-1")
    back = next(ln.id for ln in m.lanes_by_junction["1"] if ln.predecessors[0] == "2_0_1" and ln.successors[0] == "1_0_-1")
    out_of_b = [u.road.spawn("2_0_1", s, 5.0, ["2_0_1", back, "1_0_-1"]) for s in (10.0, 2.0)]
    first = u.road.spawn("1_0_1", 21.0, 5.0, ["1_0_1", to_b, "2_0_-1"])
    assert all(ctl.passage_start(v) for v in [*out_of_b, first])
    assert first in ctl.passage_state(b_out.group)[2][b_out.side]
    second = u.road.spawn("1_0_1", 15.0, 5.0, ["1_0_1", to_b, "2_0_-1"])
    chain, _, room = ctl.passage_way(second, entered=True)
    assert chain == [(a_in.group, a_in.side), (b_out.group, b_out.side)] and room is None
    placed = ctl.passage_start(second)  # what the reset's traffic placement asks
    if not placed:
        u.road.vehicles.remove(second)
    from feat2map.scenarios.planner import BaselinePlanner

    planner = BaselinePlanner()
    planner.reset(env)
    ego, entered_early = u.vehicle, []
    for _ in range(int(60 * u.config["policy_frequency"])):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        assert not info["collision"], f"collision at t={info['time']:.1f} s"
        in_a = net.id_of.get(ego.lane_index) == "1_0_1" and ego.s_on("1_0_1") + ego.LENGTH / 2 > a_in.s0
        if in_a and ctl.passage_state(b_out.group)[0][1 - b_out.side]:
            entered_early.append(round(info["time"], 1))
        if term or trunc:
            break
    env.close()
    assert not placed
    assert not entered_early  # the ego, behind them, waits before A while B is held the other way
    assert u.route_completed() and info["time"] < 40.0


def _parked(env) -> None:
    """One step with the ego standing still (the rules' state brought up to date)."""
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))


def test_car_past_its_line_waits_for_a_passage_at_the_junctions_edge(tmp_path):
    """A car past its line but not yet in the junction (placed there at a route's start), heading
    through the junction into a passage with no room to wait before it, waits for the passage at
    the junction's edge, not in the junction at the passage's mouth: standing there it blocks
    the lanes the passage's holders leave by, and they wait for it (digitaf r114: the ego, its
    start lane's line behind it, waited 37 m into junction j_25760084 for the passage that a car
    held from the other side, which waited to enter that junction: nobody moved for 120 s). The
    map: `test_bare_setback`'s four-way whose right turn is drawn over R0_1's last metre (R0_1's
    wait point 3.8 m before its end), with R2 one lane used both ways."""
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    from feat2map.formats import native
    from test_bare_setback import _redrawn

    m, net0 = _redrawn("bare")
    native.save(_coincident(m, "R2"), tmp_path / "edge.json")
    m = read_map(tmp_path / "edge.json")
    sc = Scenario("edge", str(tmp_path / "edge.json"), (("J0", "R3", "R1"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, ctl = u.net, u.control
    into = next(ln.id for ln in m.lanes_by_junction["J0"] if ln.predecessors[0] == "R0_1" and ln.successors[0] == "R2_0")
    ps = net.passages["R2_0"]
    setback = net.setbacks["R0_1"]
    assert ps.s0 < 1.0 and setback > 3.0  # no room before the passage; R0_1 waits 3.8 m before its end
    to_junction = 2.0  # past the wait point, 2 m before the junction
    u.road.spawn("R2_1", 20.0, 0.0, ["R2_1"])  # holds the passage from the other side
    _parked(env)
    assert ctl.passage_state(ps.group)[0][1 - ps.side]
    car = u.road.spawn("R0_1", net.lane_of["R0_1"].length - to_junction, 0.0, ["R0_1", into, "R2_0"])
    chain, wait = ctl.passage_ahead(car)
    assert chain == [(ps.group, ps.side)]
    assert wait == pytest.approx(to_junction - STOP_POINT_M)  # at the junction's edge, not inside it
    assert ctl.passage_stop(car) == pytest.approx(wait)
    env.close()


def test_reservation_beyond_a_passage_wait_is_given_up(two_narrow):
    """A car that reserved its junction lane into a passage while the passage was free, and now
    waits for it at the junction's line, gives the reservation up: kept, it held back the
    passage's holder from the other side, whose way out of the passage crossed that lane, while
    the car waited for that holder (digitaf r025, junction j_1388683057)."""
    m = read_map(two_narrow)
    sc = Scenario("unreserve", str(two_narrow), (("1", "4", "1"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, ctl = u.net, u.control
    into = next(ln.id for ln in m.lanes_by_junction["1"] if ln.predecessors[0] == "3_0_1" and ln.successors[0] == "2_0_-1")
    ps = net.passages["2_0_-1"]
    u.road.spawn("2_0_1", 12.0, 0.0, ["2_0_1"])  # holds the passage from the other side
    _parked(env)
    assert ctl.passage_state(ps.group)[0][1 - ps.side]
    car = u.road.spawn("3_0_1", net.lane_of["3_0_1"].length - 8.0, 0.0, ["3_0_1", into, "2_0_-1"])
    ctl.reservations[into], car.reserved = car, into  # reserved while the passage was free
    wait = ctl.claim(car)  # what the traffic core asks every step
    assert wait < math.inf and wait == pytest.approx(ctl.passage_stop(car))  # it waits for the passage, at the line
    assert into not in ctl.reservations and car.reserved is None
    env.close()


@pytest.fixture(scope="module")
def bare_bridge(tmp_path_factory) -> Path:
    """Two bare 4-way junctions joined by road 3 (61 m), narrowed to 1 m lanes over its middle
    (from 20 m to 40 m): a passage with room to wait on road 3 between junction 1 and it."""
    from feat2map.formats.opendrive.writer import write_opendrive

    d = tmp_path_factory.mktemp("bare_bridge")
    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    write_opendrive(feat2map.generate_from_features([four, four], seed=0), d / "twin.xodr")
    _narrow_near(d / "twin.xodr", d / "bare_bridge.xodr", "3",
                 [(0.0, None), (15.0, None), (20.0, 1.0), (40.0, 1.0), (45.0, None)])
    return d / "bare_bridge.xodr"


def test_junction_before_a_far_passage_wait_is_reserved(bare_bridge):
    """A car whose wait for a passage lies on the road after a junction reserves its lane in
    that junction as it commits to it, as it would with no passage ahead: only lanes beyond the
    wait go unreserved. Reserving none, it drove into the junction unseen by the rules, a car
    from the other side reserved a lane conflicting with its own, and the two stood nose to nose
    in the junction (Testfeld_Karlsruhe r046, junction j_262852677)."""
    m = read_map(bare_bridge)
    sc = Scenario("far", str(bare_bridge), (("1", "2", "4"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, ctl = u.net, u.control
    ps = net.passages["3_0_-1"]
    assert 8.0 < ps.s0 < 20.0  # room to wait between junction 1 and the passage
    into = next(ln.id for ln in m.lanes_by_junction["1"] if ln.predecessors[0] == "1_0_1" and ln.successors[0] == "3_0_-1")
    u.road.spawn("3_0_1", 30.0, 0.0, ["3_0_1"])  # holds the passage from the other side
    _parked(env)
    assert ctl.passage_state(ps.group)[0][1 - ps.side]
    car = u.road.spawn("1_0_1", net.lane_of["1_0_1"].length - 4.0, 5.0, ["1_0_1", into, "3_0_-1"])
    wait = ctl.claim(car)  # what the traffic core asks every step
    assert wait == pytest.approx(ctl.passage_stop(car))
    assert net.lane_of["1_0_1"].length - car.s_on("1_0_1") + net.lane_of[into].length < wait < math.inf  # beyond junction 1
    assert ctl.reservations.get(into) is car and car.reserved == into
    env.close()


def test_the_conflict_rule_passes_over_road_users_waiting_for_a_passage_the_asker_holds(bridge):
    """The conflict rule (`TrafficCore.lanes_clear`) is as worded on the bridge map in busy
    traffic: a road user near its line that waits for the bridge someone holds is no traffic
    about to enter for that one (GoMentum r034)."""
    from collections import Counter

    from rule_specs import check_conflict_questions

    sc = Scenario("bridge", str(bridge), (("1", "1", "3"), ("2", "3", "6")), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 12})
    obs, info = env.reset(seed=0)
    from feat2map.scenarios.planner import BaselinePlanner

    planner = BaselinePlanner()
    planner.reset(env)
    rng, why = np.random.default_rng(0), Counter()
    for _ in range(300):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        check_conflict_questions(env.unwrapped.road.core, rng, why)
        if term or trunc:
            obs, info = env.reset(seed=int(rng.integers(100)))
            planner.reset(env)
    env.close()
    assert why["passage waiter"] > 0 and why["coming"] > 20, why


def test_passage_places_move_with_their_rows_and_go_with_a_road_user_that_leaves(bridge):
    """The passages' state is row arrays of the core (`sim.passages`): a holder's and a waiter's
    places stay theirs while rows before them leave and the rows move, and a road user that leaves
    the road lets go with its row at once: the car waiting on the other side may drive in before
    any frame's bookkeeping."""
    m = read_map(bridge)
    sc = Scenario("bridge", str(bridge), (("1", "1", "2"),), seed=0, duration=60.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, core, ctl = u.net, u.road.core, u.control
    bridge_lanes = [ln.id for ln in m.lanes.values() if ln.road_id == "3"]
    assert not set(bridge_lanes) & set(u.vehicle.lane_route)
    west_east, east_west = bridge_lanes
    ps = net.passages[west_east]
    j = next(ln for ln in m.lanes.values() if ln.junction_id is not None and east_west in ln.successors)
    fillers = [u.road.spawn(j.predecessors[0], 1.0 + 8.0 * k, 0.0, [j.predecessors[0]]) for k in range(2)]
    holder = u.road.spawn(west_east, ps.s0 + 10.0, 0.0, [west_east])
    line = net.lane_of[j.predecessors[0]].length
    waiter = u.road.spawn(j.predecessors[0], line - 8.0, 0.0, [j.predecessors[0], j.id, east_west])
    ctl.update(u.road, 0.0)
    assert ctl.passage_stop(waiter) < math.inf  # held by the holder from the other side
    ctl.claim(waiter)
    holders, waiters, _ = ctl.passage_state(ps.group)
    assert holders[ps.side] == [holder] and not holders[1 - ps.side]
    assert list(waiters) == [waiter] and waiters[waiter] == (1 - ps.side, 0.0)
    rows = (holder.row, waiter.row)
    for v in fillers:  # rows before theirs leave: theirs move, their places with them
        u.road.vehicles.remove(v)
    core.sync()
    assert (holder.row, waiter.row) == (rows[0] - 2, rows[1] - 2)
    holders, waiters, _ = ctl.passage_state(ps.group)
    assert holders[ps.side] == [holder] and list(waiters) == [waiter] and waiters[waiter] == (1 - ps.side, 0.0)
    assert ctl.passage_stop(waiter) < math.inf
    u.road.vehicles.remove(holder)  # the holder leaves the road
    core.sync()
    holders, waiters, _ = ctl.passage_state(ps.group)
    assert not holders[0] and not holders[1] and list(waiters) == [waiter]
    assert ctl.passage_stop(waiter) == math.inf
    env.close()


def test_driver_view_on_the_bridge_is_as_worded(bare_bridge, monkeypatch):
    """DriverView of a batch on a map with a narrow passage between bare junctions (its conflicting
    traffic asked whether it waits for a passage the ego holds) equals the rules' answers asked
    one question at a time (`rule_specs`)."""
    import gymnasium as gym
    from rule_specs import driver_view_as_worded

    from feat2map.envs.driver import DRIVER_ACTION_CONFIG
    from feat2map.envs.driver_view import driver_views
    from feat2map.envs.rules import TrafficRules

    answers: list[bool] = []
    waits_for = TrafficRules.waits_for

    def counted(self, v, other, depth=4) -> bool:
        answers.append(waits_for(self, v, other, depth))
        return answers[-1]

    monkeypatch.setattr(TrafficRules, "waits_for", counted)
    batch = gym.make_vec("feat2map/MapFile-v0", num_envs=3, config={
        "map_file": str(bare_bridge), "traffic_vehicles": 8, "observation": {"type": "DriverView"},
        "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 30.0})
    obs, _ = batch.reset(seed=0)
    rng = np.random.default_rng(0)
    asked = False  # whether the program asked if road users heading into a conflict wait for a passage
    for _ in range(100):
        envs = batch.unwrapped.envs
        n = len(answers)
        again = driver_views(envs)
        asked |= len(answers) > n
        for env, o, o2 in zip(envs, obs, again):
            assert np.array_equal(o, o2) and np.array_equal(o, driver_view_as_worded(env))
        obs, *_ = batch.step(rng.uniform(-1, 1, batch.action_space.shape).astype(np.float32))
    batch.close()
    assert asked
