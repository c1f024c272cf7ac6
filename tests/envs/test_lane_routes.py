"""Lane-level routes in MapEnv: maps without junctions (the closed road circle of
examples/road_circle.yaml) are driven on sampled lane walks, and any map on explicit lane routes
({"lanes": [...]} or {"from_lane", "to_lane"}); bad lane routes fail naming the element."""
from __future__ import annotations

import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env
from hypothesis import given, settings
from hypothesis import strategies as st

import feat2map
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver
from feat2map.envs.routes import sample_lane_walk
from feat2map.envs.network import MapNetwork
from feat2map.errors import Feat2MapError
from feat2map.spec import build_spec, load_spec

REPO = Path(__file__).resolve().parents[2]
DRIVE = {"action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 60, "traffic_vehicles": 4}


@pytest.fixture(scope="module")
def ring():
    """The closed one-way two-lane road circle: twelve chain roads, no junctions."""
    m = build_spec(load_spec(REPO / "examples" / "road_circle.yaml"))
    assert not m.junctions and not any(ln.junction_id for ln in m.lanes.values())
    return m


@pytest.fixture(scope="module")
def grid():
    """A small generated map: one signalized 4-way junction."""
    return feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False)], seed=0)


def lap_length(m) -> float:
    return sum(m.lanes[f"C0_{k}_0"].length for k in range(12))


def drive(m, config, seed=0):
    """Drive the scripted driver to the end of the episode; (env, final info, summed progress)."""
    env = gym.make("feat2map/MapFile-v0", config={"map": m, **DRIVE, **config})
    env.reset(seed=seed)
    driver = ScriptedDriver(env)
    progress = 0.0
    while True:
        _, _, term, trunc, info = env.step(driver.act())
        progress += info["rewards"]["progress"]
        if term or trunc:
            return env, info, progress


def route_driven_m(env) -> float:
    """Metres the ego drives on its route: from its start to the goal in the last lane."""
    u = env.unwrapped
    first, last = u.net.lane_of[u.route_lanes[0]], u.net.lane_of[u.route_lanes[-1]]
    middle = sum(u.net.lane_of[x].length for x in u.route_lanes[1:-1])
    return min(u.config["ego_start_distance"], first.length) + middle + u.goal_s(last)


def test_ring_sampled_lap_is_driven(ring):
    """With no route given, the ring is driven on a sampled lane walk of at least a lap: it loops
    (its lanes repeat), and the scripted driver completes it in traffic without incident; no
    junction-related info is reported."""
    lap = lap_length(ring)
    env, info, progress = drive(ring, {"route_length": lap})
    lanes = env.unwrapped.route_lanes
    assert len(lanes) > len(set(lanes)), "a lap-length walk round the ring revisits its start lane"
    assert all(b in ring.lanes[a].successors for a, b in zip(lanes, lanes[1:]))
    assert route_driven_m(env) >= lap
    assert info["route_completed"] and info["route_progress"] == pytest.approx(1.0)
    assert not info["collision"] and not info["off_road"]
    assert progress == pytest.approx(1.0, abs=0.02)
    assert info["junction"] == "" and info["manoeuvre"] == "" and info["control_ahead"] == ""  # "" for none
    assert info["junction_feature"]["n_roads"] == -1 and info["signal_states"] == {}
    assert info["distance_to_stop_line"] == np.inf
    assert info["violations"] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}
    assert len(env.unwrapped.road.vehicles) > 1, "traffic is spawned on the ring"
    assert set(env.unwrapped._spawn_lanes) == set(ring.lanes), "in both ring lanes, beside the route too"
    env.close()


def test_ring_lap_from_lane_to_itself_and_render(ring):
    """from_lane == to_lane goes once round the loop; the frame shows the route and lane markings
    that follow the ring."""
    env = gym.make("feat2map/MapFile-v0", render_mode="rgb_array",
                   config={"map": ring, "route": {"from_lane": "C0_3_1", "to_lane": "C0_3_1"},
                           "traffic_vehicles": 2, "scaling": 2.0})
    _, info = env.reset(seed=1)
    lanes = env.unwrapped.route_lanes
    assert lanes == [f"C0_{(3 + k) % 12}_1" for k in range(13)]
    assert info["lane_id"] == "C0_3_1" and info["junction"] == ""
    frame = env.render()
    assert frame.shape == (600, 600, 3)
    route_px = np.all(frame == np.array([60, 140, 255], dtype=np.uint8), axis=-1)  # render.ROUTE_RGB
    assert route_px.sum() > 100, "the ego route is drawn"
    # lane markings follow the curve: none inside the ring's inner edge (straight chords would cut in)
    surf = env.unwrapped.viewer.sim_surface
    cx, cy = surf.pos2pix(0.0, 0.0)
    inner = min(np.hypot(*np.asarray(b).T).min() for ln in ring.lanes.values()
                for b in (ln.left_boundary, ln.right_boundary))
    white = np.all(frame >= 235, axis=-1)
    ys, xs = np.nonzero(white)
    r_px = np.hypot(xs - cx, ys - cy)
    assert white.sum() > 200 and (r_px < (inner - 0.5) * surf.scaling).sum() == 0
    env.close()


def test_sampled_walk_on_a_junction_map_with_route_junctions_zero(grid):
    env = gym.make("feat2map/MapFile-v0", config={"map": grid, "route_junctions": 0, "route_length": 60.0})
    env.reset(seed=3)
    lanes = env.unwrapped.route_lanes
    assert all(b in grid.lanes[a].successors for a, b in zip(lanes, lanes[1:]))
    assert route_driven_m(env) >= 60.0 or not grid.lanes[lanes[-1]].successors
    env.close()


def test_explicit_lane_route_on_a_generated_map(grid):
    """{"lanes": [...]} through the junction's left turn is driven to the goal; info names the
    junction and manoeuvre on the way, and {"from_lane", "to_lane"} gives the same route."""
    jl = sorted((ln for ln in grid.junction_lanes("J0") if ln.turn == "left"), key=lambda ln: ln.id)[0]
    route = [jl.predecessors[0], jl.id, jl.successors[0]]
    env = gym.make("feat2map/MapFile-v0", config={"map": grid, "route": {"from_lane": route[0], "to_lane": route[-1]}})
    env.reset(seed=0)
    assert env.unwrapped.route_lanes[0] == route[0] and env.unwrapped.route_lanes[-1] == route[-1]
    env.close()
    env = gym.make("feat2map/MapFile-v0", config={"map": grid, "route": {"lanes": route}, **DRIVE})
    _, info = env.reset(seed=0)
    assert info["junction"] == "J0" and info["manoeuvre"] == "left" and info["control_ahead"] == "signal"
    assert env.unwrapped.route_lanes == route
    driver = ScriptedDriver(env)
    while True:
        _, _, term, trunc, info = env.step(driver.act())
        if term or trunc:
            break
    assert info["route_completed"] and not info["collision"] and not info["off_road"]
    assert info["violations"]["red_light"] == 0
    env.close()


@pytest.mark.parametrize("route, where, text", [
    ({"lanes": ["C0_0_0", "nope"]}, "route.lanes[1]", "unknown lane 'nope'"),
    ({"lanes": ["C0_0_0", "C0_1_0", "C0_3_0"]}, "route.lanes[2]", "lane C0_3_0 does not follow lane C0_1_0"),
    ({"lanes": ["C0_0_0", "C0_1_1"]}, "route.lanes[1]", "does not follow lane C0_0_0 (its successors: C0_1_0)"),
    ({"lanes": ["C0_0_0"]}, "route.lanes", "at least 2 lane ids"),
    ({"lanes": "C0_0_0"}, "route.lanes", "at least 2 lane ids"),
    ({"from_lane": "x", "to_lane": "C0_0_0"}, "route.from_lane", "unknown lane 'x'"),
    ({"from_lane": "C0_0_0", "to_lane": "C0_5_1"}, "route.to_lane", "cannot be reached from lane C0_0_0"),
    ({"from": "C0_0_0"}, "route", "expected"),
])
def test_bad_lane_routes_name_the_element(ring, route, where, text):
    with pytest.raises(Feat2MapError) as err:  # highway-env resets on construction
        gym.make("feat2map/MapFile-v0", config={"map": ring, "route": route}).reset(seed=0)
    assert err.value.where == where and text in err.value.message
    assert str(err.value).count("\n") == 0


def test_check_env_on_the_ring(ring):
    env = gym.make("feat2map/MapFile-v0", config={"map": ring, "traffic_vehicles": 3})
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


@settings(max_examples=25, deadline=None)
@given(length=st.floats(1.0, 1500.0), seed=st.integers(0, 2**16), start=st.floats(0.0, 60.0), goal=st.floats(0.0, 30.0))
def test_lane_walk_on_the_ring_is_connected_and_long_enough(ring_net, length, seed, start, goal):
    m = ring_net.hdmap
    path = sample_lane_walk(ring_net, np.random.default_rng(seed), length, start, goal)
    assert len(path) >= 2
    assert all(b in m.lanes[a].successors for a, b in zip(path, path[1:]))
    lens = [ring_net.lane_of[x].length for x in path]
    driven = min(start, lens[0]) + sum(lens[1:-1]) + min(goal, lens[-1] - 1.0)
    assert driven >= length
    if len(path) > 2:  # it stops at the first lane that makes it long enough
        assert min(start, lens[0]) + sum(lens[1:-2]) + min(goal, lens[-2] - 1.0) < length


def test_lane_walk_on_an_open_chain_is_the_longest_possible():
    """A one-way open chain ends in a dead end: the walk takes the whole chain."""
    spec = feat2map.spec.parse_spec({"version": 1, "chains": [{
        "name": "line", "lanes_forward": 1, "lanes_backward": 0, "start": {"point": [0, 0], "heading": 0},
        "roads": [{"end": [30, 0], "heading": 0}, {"end": [60, 0], "heading": 0}]}]})
    net = MapNetwork.from_map(build_spec(spec))
    path = sample_lane_walk(net, np.random.default_rng(0), 1000.0)
    assert path == ["C0_0_0", "C0_1_0"]


@pytest.fixture(scope="module")
def ring_net(ring):
    return MapNetwork.from_map(ring)


@pytest.mark.parametrize("allowed", [True, False])
def test_right_turn_on_red_after_a_stop_on_a_lane_route(grid, allowed):
    """On a lane route, a right turn past a red signal after a full stop is legal only with
    `right_turn_on_red` (the turn after the stop line is looked up on the ego's lane route)."""
    jl = sorted((ln for ln in grid.junction_lanes("J0") if ln.turn == "right"), key=lambda ln: ln.id)[0]
    route = [jl.predecessors[0], jl.id, jl.successors[0]]
    env = gym.make("feat2map/MapFile-v0", config={
        "map": grid, "route": {"lanes": route}, **DRIVE, "traffic_vehicles": 0, "pedestrian_rate": 0.0,
        "signal_green": 200.0, "right_turn_on_red": allowed})
    env.reset(seed=0)
    u = env.unwrapped
    sid = u.net.stop_lines[route[0]].control_id
    plan = u.control.plans[sid]  # fix the offset so that this approach stays red for a minute
    offset = next(o for o in range(int(plan.cycle)) if all(
        replace(plan, offset=float(o)).state(sid, t) == "red" for t in range(60)))
    u.configure({"signal_offsets": {"J0": float(offset)}})
    env.reset(seed=0)
    lawful, rogue = ScriptedDriver(env), ScriptedDriver(env, ignore={"signal"})
    stopped = False
    for _ in range(300):
        driver = rogue if stopped else lawful
        _, _, term, trunc, info = env.step(driver.act())
        stopped = stopped or (u.vehicle.speed < 0.1 and info["distance_to_stop_line"] < 8.0)
        if term or trunc:
            break
    assert stopped and info["route_completed"] and info["signal_state"] == ""
    assert u.control.signal_state(sid) == "red"
    assert info["violations"]["red_light"] == (0 if allowed else 1)
    env.close()


def test_lane_change_on_the_ring_keeps_the_lap(ring):
    """With lateral actions, a lane change onto the other ring lane (whose lanes never merge back)
    moves the rest of the lap beside itself instead of losing the route: the lap still completes."""
    env = gym.make("feat2map/MapFile-v0", config={
        "map": ring, "route": {"from_lane": "C0_0_0", "to_lane": "C0_0_0"}, "traffic_vehicles": 0,
        "action": {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": True}, "duration": 80})
    env.reset(seed=0)
    u = env.unwrapped
    act = {name: k for k, name in u.action_type.actions.items()}
    for i in range(80):
        _, _, term, trunc, info = env.step(act["LANE_RIGHT"] if i == 3 else act["FASTER"] if i < 3 else act["IDLE"])
        if term or trunc:
            break
    assert info["route_completed"] and not info["off_road"]
    assert u.route_lanes[:1] == ["C0_0_0"] and u.route_lanes[-1] == "C0_0_1" and len(u.route_lanes) == 13
    env.close()
