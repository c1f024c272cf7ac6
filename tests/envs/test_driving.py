"""Driving behaviour in the feat2map environments: a scripted driver completes routes through
every junction control without violations, running a red light is caught, traffic stops at red
and at stop signs, pedestrians cross and are yielded to; and a frame is rendered for review."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver
from feat2map.envs.rules import STOP_ZONE_M
from feat2map.envs.vehicles import Pedestrian, TrafficVehicle

J = feat2map.JunctionFeature.make
FOUR = [0, 90, 180, 270]
DRIVE = {"action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 80}


def drive(features, route, ignore=(), seed=0, **config):
    env = gym.make("feat2map/JunctionGrid-v0",
                   config={"features": [f.to_dict() for f in features], "route": route, **DRIVE, **config})
    env.reset(seed=seed)
    driver = ScriptedDriver(env, ignore)
    while True:
        _, _, term, trunc, info = env.step(driver.act())
        if term or trunc:
            return env, info


def manoeuvre(m, jid, turn):
    """(junction, entry road, exit road) of a `turn` at `jid` entering from its first socket."""
    lanes = [ln for ln in m.lanes_by_junction[jid] if ln.turn == turn]
    lanes.sort(key=lambda ln: ln.id)
    ln = lanes[0]
    return (jid, m.lanes[ln.predecessors[0]].road_id, m.lanes[ln.successors[0]].road_id)


CASES = [("signal", True, "left"), ("signal", False, "none"), ("stop", True, "right"),
         ("stop", False, "left"), ("bare", True, "none"), ("bare", False, "right")]


@pytest.mark.parametrize("control,crosswalk,turn", CASES)
def test_scripted_driver_completes_routes_without_violations(control, crosswalk, turn):
    feats = [J(FOUR, control, crosswalk)]
    m = feat2map.generate_from_features(feats, seed=0)
    route = [manoeuvre(m, "J0", turn)]
    env, info = drive(feats, route, traffic_vehicles=6, pedestrian_rate=6.0)
    assert info["route_completed"], info
    assert info["violations"] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}
    assert not info["collision"] and not info["off_road"]
    assert info["route_progress"] == pytest.approx(1.0, abs=0.05)


def test_multi_junction_route_and_info():
    feats = [J(FOUR, "signal", True), J(FOUR, "stop", False), J([0, 90, 180], "bare", True)]
    env = gym.make("feat2map/JunctionGrid-v0", config={"features": [f.to_dict() for f in feats], **DRIVE,
                                                         "route_junctions": 3, "traffic_vehicles": 6})
    seen = set()
    for seed in range(3):
        env.reset(seed=seed)
        driver = ScriptedDriver(env)
        while True:
            _, _, term, trunc, info = env.step(driver.act())
            if info["junction"]:
                seen.add(info["junction_feature"]["control"])
                assert info["manoeuvre"] in ("left", "straight", "right")
            if term or trunc:
                break
        assert info["route_completed"] and sum(info["violations"].values()) == 0, info
    assert seen  # info names the junctions on the way


def test_running_the_red_light_is_a_violation():
    feats = [J(FOUR, "signal", False)]
    m = feat2map.generate_from_features(feats, seed=0)
    mostly_red = {"signal_green": 1.0, "signal_amber": 0.5, "signal_all_red": 40.0, "traffic_vehicles": 0}
    _, info = drive(feats, [manoeuvre(m, "J0", "none")], ignore={"signal"}, **mostly_red)
    assert info["violations"]["red_light"] == 1
    _, info = drive(feats, [manoeuvre(m, "J0", "none")], duration=20, **mostly_red)
    assert info["violations"]["red_light"] == 0 and not info["route_completed"]  # waits at the red


def _watch_traffic(features, seconds, **config):
    """Per-frame record of traffic vehicles entering junctions: (stop-line kind, state, stopped)."""
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in features], "action": DRIVER_ACTION_CONFIG,
        "policy_frequency": 15, "duration": seconds, **config})
    env.reset(seed=0)
    u = env.unwrapped
    brake = np.array([-1.0], dtype=np.float32)  # the ego waits where it starts; traffic flows
    prev, stopped, entries, waiting_at_red = {}, {}, [], 0
    for _ in range(int(seconds * 15)):
        env.step(brake)
        net = u.net
        for v in u.road.vehicles:
            if not isinstance(v, TrafficVehicle):
                continue
            lid = net.id_of.get(v.lane_index)
            sl = net.stop_lines.get(lid)
            if sl is not None and 0 <= sl.s - v.lane_s <= STOP_ZONE_M and v.speed < 0.3:
                stopped[id(v)] = lid
                if sl.kind == "signal" and u.control.signal_state(sl.control_id) == "red":
                    waiting_at_red += 1
            p = prev.get(id(v))
            if p is not None and p != lid and net.hdmap.lanes[lid].junction_id is not None:
                psl = net.stop_lines.get(p)
                if psl is not None:
                    state = u.control.signal_state(psl.control_id) if psl.kind == "signal" else None
                    entries.append((psl.kind, state, stopped.get(id(v)) == p, v.reserved == lid))
            prev[id(v)] = lid
    return u, entries, waiting_at_red


def test_traffic_stops_at_red_and_at_stop_signs():
    feats = [J(FOUR, "signal", False), J(FOUR, "stop", False)]
    _, entries, waiting_at_red = _watch_traffic(feats, 50, traffic_vehicles=12, route_junctions=2)
    signal = [e for e in entries if e[0] == "signal"]
    stop = [e for e in entries if e[0] == "stop"]
    assert waiting_at_red > 0, "no traffic vehicle was seen waiting at a red light"
    assert signal and stop, entries
    # nobody enters on red without having committed (reserved) before the light changed
    assert all(state != "red" or committed for _, state, _, committed in signal), signal
    assert sum(state == "red" for _, state, _, _ in signal) <= 1
    assert all(was_stopped for _, _, was_stopped, _ in stop), stop  # full stop at every stop sign


def test_pedestrians_cross_and_are_yielded_to():
    feats = [J(FOUR, "bare", True)]
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], **DRIVE, "pedestrian_rate": 30.0, "traffic_vehicles": 8,
        "duration": 40})
    env.reset(seed=0)
    u = env.unwrapped
    driver = ScriptedDriver(env)
    seen, finished, yielding = set(), set(), 0
    for _ in range(900):  # until enough people have crossed (how soon depends on the traffic drawn)
        _, _, term, trunc, info = env.step(driver.act())
        peds = [o for o in u.road.objects if isinstance(o, Pedestrian)]
        for p in peds:
            seen.add(id(p))
            assert not p.hit, "a vehicle hit a pedestrian"
            if p.remaining < 0.5:
                finished.add(id(p))
        for v in u.road.vehicles:
            d = u.control.stop_distance(v, ignore=frozenset({"signal", "stop", "conflict"}))
            if d < 15 and v.speed < 2.0:
                yielding += 1
        assert info["violations"]["pedestrian_yield"] == 0 and not info["collision"]
        if term or trunc:
            env.reset()
        if len(seen) >= 5 and len(finished) >= 3 and yielding > 0:
            break
    assert len(seen) >= 5 and len(finished) >= 3
    assert yielding > 0, "no vehicle was seen yielding to a pedestrian"


def test_render_junction_frame():
    feats = [J(FOUR, "signal", True), J(FOUR, "stop", True)]
    m = feat2map.generate_from_features(feats, seed=0)
    a, b = m.junctions["J0"], m.junctions["J1"]
    assert abs(a.cell[0] - b.cell[0]) + abs(a.cell[1] - b.cell[1]) == 1  # neighbours
    env = gym.make("feat2map/JunctionGrid-v0", render_mode="rgb_array", config={
        "features": [f.to_dict() for f in feats], "centering_position": [0.3, 0.5],
        "screen_width": 900, "screen_height": 520, "scaling": 3.6, "pedestrian_rate": 60.0,
        "traffic_vehicles": 8, **DRIVE})
    env.reset(seed=2)
    u = env.unwrapped
    driver = ScriptedDriver(env)
    for k in range(80):  # 3 s at least, until someone walks (they step out where no car is near)
        env.step(driver.act())
        if k >= 15 and any(isinstance(o, Pedestrian) for o in u.road.objects):
            break
    frame = env.render()
    assert frame.shape == (520, 900, 3)
    colours = {tuple(c) for c in frame.reshape(-1, 3)[::7]}
    assert (240, 240, 240) in colours  # crosswalk stripes / stop lines
    assert any(c in colours for c in [(30, 220, 60), (255, 190, 0), (230, 30, 30)])  # a signal head
    assert (200, 0, 0) in colours  # a stop sign
    assert any(isinstance(o, Pedestrian) for o in u.road.objects)
    # docs/env_frame.png is this frame, drawn by scripts/make_docs_pictures.py (tests write nothing in the repo)


def test_traffic_changes_lane_by_mobil_behind_a_slow_leader():
    feats = [J(FOUR, "bare", False, lanes=2), J(FOUR, "bare", False, lanes=2)]
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], "traffic_vehicles": 0, **DRIVE})
    env.reset(seed=0)
    u = env.unwrapped
    m, net = u.net.hdmap, u.net
    road = next(r for r in m.roads.values() if r.kind == "connection" and len(r.right_lanes) == 2)
    lane_id, other = road.right_lanes
    lane = net.lane_of[lane_id]

    def length(path):
        return sum(net.lane_of[x].length for x in path)

    def reach(a, g):
        ln = m.lanes[g]
        return [net.lane_route(a, x) for x in (g,) + ln.left_neighbors + ln.right_neighbors if net.lane_route(a, x)]

    goal = next(g for g in m.lanes if m.lanes[g].junction_id is None and m.lanes[g].road_id != road.id
                and net.lane_route(lane_id, g) and reach(other, g)
                and min(length(p) for p in reach(other, g)) <= length(net.lane_route(lane_id, g)) + 3.0)

    def spawn(s, speed, lid=lane_id):
        ln = net.lane_of[lid]
        v = TrafficVehicle(u.road, ln.position(s, 0.0), ln.heading_at(s), speed)
        v.init_route(min(reach(lid, goal), key=length))
        u.road.vehicles.append(v)
        return v

    spawn(35.0, 0.0)  # the leader
    follower = spawn(10.0, 8.0)
    u.control.update(u.road, 0.0)
    assert lane.length > 60
    before = list(follower.lane_route)
    gaps = follower.leader_gaps()  # the standing leader, 25 m ahead centre to centre
    assert [(round(g, 6), v) for g, v in gaps] == [(round(25.0 - follower.LENGTH, 6), 0.0)]
    u.road.act()  # (MOBIL: a new car is due at once)
    assert getattr(follower, "lane_changes", 0) == 1
    assert follower.lane_route[0] == other and net.id_of[follower.target_lane_index] == other
    assert m.lanes[follower.lane_route[-1]].road_id == m.lanes[goal].road_id
    assert all(b in m.lanes[a].successors for a, b in zip(follower.lane_route, follower.lane_route[1:]))
    # an unsafe gap on the target lane (a fast car right behind) forbids the change
    u.road.vehicles.remove(follower)
    follower2 = spawn(10.0, 8.0)
    spawn(4.0, 12.0, other)
    u.control.update(u.road, 0.0)
    u.road.act()
    assert not getattr(follower2, "lane_changes", 0) and follower2.lane_route[0] == lane_id
    assert before[0] == lane_id


def test_left_turn_yields_to_oncoming_straight_traffic():
    feats = [J(FOUR, "bare", False)]
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], "traffic_vehicles": 0, **DRIVE})
    env.reset(seed=0)
    u = env.unwrapped
    m, net = u.net.hdmap, u.net
    left = next(ln for ln in m.lanes_by_junction["J0"] if ln.turn == "left")
    oncoming = next(ln for ln in m.lanes_by_junction["J0"] if ln.turn == "none" and ln.id in net.conflicts[left.id]
                    and net.lane_of[ln.id].priority > net.lane_of[left.id].priority)
    u.road.vehicles = [u.vehicle]

    def spawn(in_lane, j_lane, d, speed):
        ln = net.lane_of[in_lane]
        v = TrafficVehicle(u.road, ln.position(ln.length - d, 0.0), ln.heading_at(ln.length - d), speed)
        v.init_route([in_lane, j_lane])
        u.road.vehicles.append(v)
        return v

    turner = spawn(left.predecessors[0], left.id, 3.0, 0.0)
    u.control.update(u.road, 0.0)
    assert u.control.junction_clear(left.id, turner)
    straight = spawn(oncoming.predecessors[0], oncoming.id, 15.0, 8.0)
    u.control.update(u.road, 0.0)
    assert not u.control.junction_clear(left.id, turner)  # priority traffic 2 s away
    assert u.control.junction_clear(oncoming.id, straight)  # the straight one does not wait


@pytest.mark.parametrize("turn", ["left", "right"])
def test_route_steering_acts_every_frame_between_decisions(turn):
    """Longitudinal-only ContinuousAction at 1 decision per second: the lane-keeping assist
    steers every simulation frame, so the ego stays near its lane centre through a turn
    (steering held over a decision period drifted 2-3 m out and left the road)."""
    feats = [J(FOUR, "bare", False)]
    m = feat2map.generate_from_features(feats, seed=0)
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], "route": [manoeuvre(m, "J0", turn)], "action": DRIVER_ACTION_CONFIG,
        "policy_frequency": 1, "traffic_vehicles": 0, "pedestrian_rate": 0.0})
    env.reset(seed=0)
    lo, hi = DRIVER_ACTION_CONFIG["acceleration_range"]
    gentle = np.array([2 * (1.0 - lo) / (hi - lo) - 1], dtype=np.float32)  # +1 m/s2
    worst = 0.0
    while True:
        _, _, term, trunc, info = env.step(gentle)
        worst = max(worst, abs(env.unwrapped.vehicle.lane_lat))
        if term or trunc:
            break
    assert info["route_completed"] and not info["off_road"], info
    assert worst < 1.0


def test_a_vehicle_in_the_last_metre_before_the_junction_is_about_to_enter():
    """Route followers move their route position onto the junction lane in the last metre of
    the approach, while still located on it: they must still count as about to enter (a
    left-turner claimed its lane in front of the ego going straight at 10 m/s, then collided)."""
    feats = [J(FOUR, "bare", False)]
    m = feat2map.generate_from_features(feats, seed=0)
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], "route": [manoeuvre(m, "J0", "none")], "traffic_vehicles": 0, **DRIVE})
    env.reset(seed=0)
    u = env.unwrapped
    net, ego = u.net, u.vehicle
    straight = next(l for l in ego.lane_route if m.lanes[l].junction_id)
    left = next(l for l in sorted(net.conflicts[straight]) if m.lanes[l].turn == "left")
    approach = net.lane_of[ego.lane_route[0]]
    s = approach.length - 0.5
    ego.position, ego.heading, ego.speed = approach.position(s, 0.0), approach.heading_at(s), 10.0
    ego.on_state_update()
    ego.follow_road()
    assert ego.lane_route[ego.route_pos] == straight and net.id_of[ego.lane_index] == ego.lane_route[0]
    ln = net.lane_of[m.lanes[left].predecessors[0]]
    turner = TrafficVehicle(u.road, ln.position(ln.length - 3.0, 0.0), ln.heading_at(ln.length - 3.0), 0.0)
    turner.init_route([m.lanes[left].predecessors[0], left])
    u.road.vehicles.append(turner)
    u.control.update(u.road, 0.0)
    assert not u.control.junction_clear(left, turner)  # (the ego is on its approach: about to enter, not on it)
    assert any(v is ego for _, v in u.control.traffic_towards(straight))
