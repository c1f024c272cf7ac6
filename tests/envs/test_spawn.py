"""Spawn placement and stop lines on maps with short lanes before a junction (issue 13): real maps
have 0.01-2 m entry lanes and 2.4 m last lanes before a stop line. The fixtures split a generated
map's approach lanes so that their last metres become a lane of their own."""
from __future__ import annotations

import math
import os
from dataclasses import replace

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver
from feat2map.envs.routes import first_line_distance
from feat2map.envs.rules import SPAWN_BRAKE_MPS2, braking_distance
from feat2map.envs.vehicles import TrafficVehicle
from feat2map.model import HDMap, as_polyline
from feat2map.scenarios.planner import BaselinePlanner

J = feat2map.JunctionFeature.make
FOUR = [0, 90, 180, 270]
DRIVE = {"action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 60}


def _cut(points: np.ndarray, at: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """A polyline split at the point nearest `at` (that point ends the first part, starts the second)."""
    seg = np.diff(points, axis=0)
    t = np.clip(np.einsum("ij,ij->i", at - points[:-1], seg) / np.maximum(np.einsum("ij,ij->i", seg, seg), 1e-12), 0, 1)
    near = points[:-1] + t[:, None] * seg
    i = int(np.argmin(np.hypot(*(near - at).T)))
    p = near[i]
    return np.vstack([points[:i + 1], p]), np.vstack([p, points[i + 1:]])


def split_entries(m: HDMap, tail_m: float) -> HDMap:
    """Every road lane entering a junction split in two: its last `tail_m` metres become lane
    `<id>_e` (same road, not in the road's lane groups, as read maps' short lanes are), which the
    junction lanes and the lane's signal or stop sign now name."""
    lanes = dict(m.lanes)
    renamed: dict[str, str] = {}
    for ln in m.lanes.values():
        if ln.junction_id is not None or not any(m.lanes[s].junction_id for s in ln.successors if s in m.lanes):
            continue
        pts = ln.points
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
        s = cum[-1] - tail_m
        k = int(np.searchsorted(cum, s) - 1)
        at = pts[k] + (s - cum[k]) / (cum[k + 1] - cum[k]) * (pts[k + 1] - pts[k])
        head_c, tail_c = _cut(pts, at[None, :])
        head_l, tail_l = _cut(np.asarray(ln.left_boundary), at[None, :])
        head_r, tail_r = _cut(np.asarray(ln.right_boundary), at[None, :])
        tid = f"{ln.id}_e"
        renamed[ln.id] = tid
        lanes[ln.id] = replace(ln, centerline=as_polyline(head_c), left_boundary=as_polyline(head_l),
                               right_boundary=as_polyline(head_r), successors=(tid,), bezier=None)
        lanes[tid] = replace(ln, id=tid, centerline=as_polyline(tail_c), left_boundary=as_polyline(tail_l),
                             right_boundary=as_polyline(tail_r), predecessors=(ln.id,), left_neighbors=(),
                             right_neighbors=(), left_reverse_neighbors=(), bezier=None)
    for lid, ln in list(lanes.items()):
        if ln.junction_id is not None:
            lanes[lid] = replace(ln, predecessors=tuple(renamed.get(p, p) for p in ln.predecessors))
    signals = {k: replace(g, lane_ids=tuple(renamed.get(l, l) for l in g.lane_ids)) for k, g in m.signals.items()}
    stops = {k: replace(g, lane_ids=tuple(renamed.get(l, l) for l in g.lane_ids)) for k, g in m.stop_signs.items()}
    return replace(m, lanes=lanes, signals=signals, stop_signs=stops)


@pytest.fixture(scope="module")
def base_map():
    return feat2map.generate_from_features([J(FOUR, "stop", False), J(FOUR, "signal", False)], seed=0)


@pytest.mark.parametrize("tail_m", [0.01, 0.5, 2.0])
def test_ego_and_traffic_start_a_braking_distance_before_the_first_line(base_map, tail_m):
    """Sampled routes start on the short entry lane: the ego walks back over the lane before it
    (the route starts on a road lane, never in a junction) and starts `ego_start_distance` before
    the line; every traffic vehicle starts at least its braking distance before its first line."""
    m = split_entries(base_map, tail_m)
    assert min(ln.length for ln in m.lanes.values()) == pytest.approx(tail_m, abs=1e-6)
    env = gym.make("feat2map/MapFile-v0", config={"map": m, "traffic_vehicles": 10, **DRIVE})
    u = env.unwrapped
    for seed in range(4):
        _, info = env.reset(seed=seed)
        ego, net = u.vehicle, u.net
        route = ego.lane_route
        assert m.lanes[route[0]].junction_id is None and m.lanes[route[-1]].junction_id is None
        assert not route[0].endswith("_e")  # walked back over the lane before the short entry lane
        s0 = net.lane_of[route[0]].local_coordinates(ego.position)[0]
        d = first_line_distance(net, route, s0)
        if d < u.config["ego_start_distance"] - 1e-6:  # only where the road begins (a map's open end)
            assert s0 == pytest.approx(0.0, abs=1e-6) and not m.lanes[route[0]].predecessors
        assert d == pytest.approx(min(u.config["ego_start_distance"], d), abs=1e-6) and d > 10.0
        assert info["distance_to_stop_line"] == pytest.approx(d, abs=1e-6)
        for v in u.road.vehicles:
            if isinstance(v, TrafficVehicle):
                lane = net.lane_of[v.lane_route[0]]
                d_v = first_line_distance(net, v.lane_route, lane.local_coordinates(v.position)[0])
                assert d_v >= braking_distance(v.speed, v.LENGTH) - 1e-6
                assert m.lanes[v.lane_route[0]].junction_id is None
        _, _, _, _, info = env.step(np.array([0.0], dtype=np.float32))
        assert not info["new_violations"]
    env.close()


def test_too_short_a_road_starts_the_ego_slower(base_map):
    """Where the road before the first line is shorter than the braking distance (here a start
    distance of 3 m), the ego starts slow enough to stop before the line."""
    env = gym.make("feat2map/MapFile-v0", config={"map": base_map, "traffic_vehicles": 0, "ego_start_distance": 3.0,
                                                   "ego_initial_speed": 10.0, **DRIVE})
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    assert ego.speed < 10.0 and 3.0 >= ego.speed ** 2 / (2 * SPAWN_BRAKE_MPS2) + ego.LENGTH / 2
    env.close()


def _drive(env, policy_factory, seed):
    obs, info = env.reset(seed=seed)
    policy = policy_factory(env)
    while True:
        obs, _, term, trunc, info = env.step(policy(obs, info))
        if term or trunc:
            return info


@pytest.mark.parametrize("who", ["driver", "planner"])
def test_a_short_last_lane_before_a_stop_line_is_driven(base_map, who):
    """With a 2.4 m last lane before the stop sign, vehicles stop on the lane before it: the stop
    counts (measured along the route) and they go on; the ego's route completes without
    violations and every traffic vehicle that entered the stop junction had stopped first."""
    m = split_entries(base_map, 2.4)
    stop_in = next(l for s in m.stop_signs.values() for l in s.lane_ids)
    jl = next(s for s in m.lanes[stop_in].successors)
    route = {"lanes": [m.lanes[stop_in].predecessors[0], stop_in, jl, m.lanes[jl].successors[0]]}
    config = {"map": m, "route": route, "traffic_vehicles": 6, "pedestrian_rate": 0.0, **DRIVE}
    if who == "planner":
        config.update(action=dict(BaselinePlanner.action_config))
    env = gym.make("feat2map/MapFile-v0", config=config)
    u = env.unwrapped
    if who == "driver":
        def factory(e):
            d = ScriptedDriver(e)
            return lambda obs, info: d.act()
    else:
        def factory(e):
            p = BaselinePlanner()
            p.reset(e)
            return p.act
    for seed in range(2):
        info = _drive(env, factory, seed)
        assert info["route_completed"] and not info["collision"], info
        assert info["violations"] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}
    assert u.control.stop_queue is not None
    env.close()


def _through_a_stop(m):
    """An env on `m` without traffic, reset, whose route goes from the lane before a stop-sign
    entry lane through its junction; and that route."""
    stop_in = next(l for s in m.stop_signs.values() for l in s.lane_ids)
    jl = m.lanes[stop_in].successors[0]
    route = {"lanes": [m.lanes[stop_in].predecessors[0], stop_in, jl, m.lanes[jl].successors[0]]}
    env = gym.make("feat2map/MapFile-v0", config={"map": m, "route": route, "traffic_vehicles": 0, **DRIVE})
    env.reset(seed=0)
    return env, route


def test_running_a_stop_over_a_lane_too_short_to_be_seen_is_caught(base_map):
    """A 1 cm entry lane is driven over within a frame (the ego is never located on it): entering
    the junction from the lane before it still judges that lane's stop sign."""
    env, _ = _through_a_stop(split_entries(base_map, 0.01))
    driver = ScriptedDriver(env, ignore={"stop"})
    while True:
        _, _, term, trunc, info = env.step(driver.act())
        if term or trunc:
            break
    assert info["violations"]["stop_sign"] == 1 and info["route_completed"]
    assert math.isinf(info["distance_to_stop_line"])
    env.close()


def test_a_stop_on_the_lane_before_a_short_last_lane_is_a_full_stop(base_map):
    """The judge counts the stop the driver makes on the lane before a 2.4 m last lane (the
    stop line 4 m ahead, along the route) as the stop sign's full stop."""
    env, route = _through_a_stop(split_entries(base_map, 2.4))
    u = env.unwrapped
    driver = ScriptedDriver(env)
    seen = False
    for _ in range(100):
        _, _, term, trunc, info = env.step(driver.act())
        on_lane_before = info["lane_id"] == route["lanes"][0]
        if on_lane_before and u.vehicle.speed <= 0.3 and info["distance_to_stop_line"] <= 6.0:
            assert u.judge.stopped_before(route["lanes"][1]) and not u.judge.stopped_before(route["lanes"][0])
            seen = True
        if term or trunc:
            break
    assert seen and info["route_completed"] and info["violations"]["stop_sign"] == 0
    env.close()


# ---- dead ends: traffic is never routed where it cannot leave --------------------------------

def _dead_end_map() -> HDMap:
    """A bare T junction whose south stub R1 ends in a one-arm junction D whose only way on is a
    U-turn of 1.75 m radius (undrivable: no car turns that tightly): a car sent down R1_0 (or the
    junction lanes into it) could never leave."""
    from feat2map.model import Junction, Road

    m = feat2map.generate_from_features([J([0, 90, 180], "bare", False)], seed=0)
    (x0, y0), (x1, y1) = m.lanes["R1_0"].end, m.lanes["R1_1"].start
    cx, cy, r = (x0 + x1) / 2, (y0 + y1) / 2, math.dist((x0, y0), (x1, y1)) / 2
    a = np.linspace(math.pi, 2 * math.pi, 13)

    def arc(radius: float):
        return as_polyline(np.column_stack([cx + radius * np.cos(a), cy + radius * np.sin(a)]))
    turn = replace(m.lanes["R1_0"], id="T_uturn", road_id="T", centerline=arc(r), left_boundary=arc(0.5),
                   right_boundary=arc(2 * r), predecessors=("R1_0",), successors=("R1_1",), left_neighbors=(),
                   right_neighbors=(), left_reverse_neighbors=(), turn="uturn", junction_id="D",
                   left_boundary_type="virtual", right_boundary_type="virtual", bezier=None)
    lanes = {**m.lanes, "T_uturn": turn, "R1_0": replace(m.lanes["R1_0"], successors=("T_uturn",)),
             "R1_1": replace(m.lanes["R1_1"], predecessors=("T_uturn",))}
    roads = {**m.roads, "T": Road("T", "junction", ("T_uturn",), junction_id="D", start_junction="D", end_junction="D"),
             "R1": replace(m.roads["R1"], kind="connection", end_junction="D")}
    box = as_polyline([(cx - 5, cy - 5), (cx + 5, cy - 5), (cx + 5, cy + 1), (cx - 5, cy + 1)])
    return replace(m, lanes=lanes, roads=roads, junctions={**m.junctions, "D": Junction("D", box)})


def test_traffic_is_never_routed_into_a_dead_end():
    """The lanes that lead only into the undrivable U-turn are trapped; traffic neither spawns on
    them nor turns into them (two cars stood in such a stub for good, and the ego waited behind)."""
    from feat2map.routes import trapped_lanes, undrivable

    m = _dead_end_map()
    assert undrivable(m.lanes["T_uturn"])
    into = {x for x in m.lanes["R1_0"].predecessors}
    assert trapped_lanes(m) == {"T_uturn", "R1_0", *into} and into
    env = gym.make("feat2map/MapFile-v0", config={"map": m, "traffic_vehicles": 8, "route": [["J0", "R0", "R2"]],
                                                  **DRIVE})
    u = env.unwrapped
    for seed in range(3):
        env.reset(seed=seed)
        assert not {"R1_0", *into} & set(u._spawn_lanes)
        for _ in range(10):
            env.step(np.array([0.0], dtype=np.float32))
            for v in u.road.vehicles:
                if isinstance(v, TrafficVehicle):
                    assert not {"R1_0", "T_uturn", *into} & set(v.lane_route), v.lane_route
    env.close()
