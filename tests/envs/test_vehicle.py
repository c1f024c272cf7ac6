"""The controlled vehicle (envs/sim/vehicle.py) of the ego and of the multi-agent env's agents: a
kinematic bicycle about the rear axle with the config's body. Its motion is exact on arcs, the
same over arrays as over floats, configurable, and its body fits the junction turns the
generator makes (highway-env's 5 m-wheelbase bicycle swept 0.83 m past a lane's edge in the
default map's tightest turn)."""
from __future__ import annotations

import math
import os

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.config import DRIVE_DEFAULTS
from feat2map.envs import parallel_env
from feat2map.envs.sim.vehicle import FLOATS, VehicleModel, integrate, keeping_steering, pursuit_steering
from feat2map.errors import Feat2MapError
from feat2map.routes import manoeuvres

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
J = feat2map.JunctionFeature.make
MODEL = VehicleModel.of()


def test_the_rear_axle_runs_on_the_arc_of_its_steering():
    x, y, h, v = 0.0, 0.0, 0.3, 6.0
    steer = 0.25
    radius = MODEL.wheelbase / math.tan(steer)
    rx, ry = x - MODEL.rear_offset * math.cos(h), y - MODEL.rear_offset * math.sin(h)
    cx, cy = rx - radius * math.sin(h), ry + radius * math.cos(h)  # the turn's centre, left of the rear axle
    for _ in range(300):
        x, y, h, v = integrate(x, y, h, v, steer, 0.0, 1 / 15, MODEL.wheelbase, MODEL.rear_offset, FLOATS)
        rx, ry = x - MODEL.rear_offset * math.cos(h), y - MODEL.rear_offset * math.sin(h)
        assert math.hypot(rx - cx, ry - cy) == pytest.approx(radius, abs=1e-6)
    assert v == 6.0


def test_arrays_and_floats_move_alike():
    """The bicycle and lane keeping over floats (`FLOATS`: one road user) give bit for bit what
    they give over arrays (every row of the core): a single env's ego moves as the same ego in a
    batch (libm's tan, asin and atan differ from numpy's in the last bit for some arguments)."""
    rng = np.random.default_rng(3)
    n = 20_000
    x, y, h = rng.uniform(-50, 50, n), rng.uniform(-50, 50, n), rng.uniform(-3, 3, n)
    v, steer, acc = rng.uniform(0, 20, n), rng.uniform(-0.6, 0.6, n), rng.uniform(-5, 3, n)
    ahead, lat = rng.uniform(-3, 3, n), rng.uniform(-2, 2, n)
    batch = integrate(x, y, h, v, steer, acc, 0.1, MODEL.wheelbase, MODEL.rear_offset)
    keep = keeping_steering(ahead, lat, h, v, MODEL.wheelbase, MODEL.max_steering)
    for k in range(n):
        one = integrate(x[k], y[k], h[k], v[k], steer[k], acc[k], 0.1, MODEL.wheelbase, MODEL.rear_offset, FLOATS)
        assert [b[k] for b in batch] == list(one), k
        assert keep[k] == keeping_steering(float(ahead[k]), float(lat[k]), float(h[k]), float(v[k]), MODEL.wheelbase,
                                           MODEL.max_steering, FLOATS), k


def test_pure_pursuit_holds_the_arc_it_is_on():
    """On a circle through the target, pure pursuit steers exactly that circle's curvature."""
    radius, h = 12.0, 0.0
    rx, ry = -MODEL.rear_offset, 0.0  # rear axle at the origin's left, heading east; centre (rx, ry + radius)
    a = 0.6  # the target 0.6 rad round the circle
    tx, ty = rx + radius * math.sin(a), ry + radius - radius * math.cos(a)
    steer = pursuit_steering(0.0, 0.0, h, tx, ty, MODEL)
    assert math.tan(steer) / MODEL.wheelbase == pytest.approx(1 / radius)


def test_the_vehicle_config_merges_and_is_checked():
    env = gym.make("feat2map/JunctionGrid-v0", config={"features": [J([0, 90, 180], "bare", False).to_dict()],
                                                        "traffic_vehicles": 0, "vehicle": {"length": 4.2, "width": 1.7}})
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    assert (ego.LENGTH, ego.WIDTH, ego.model.wheelbase) == (4.2, 1.7, DRIVE_DEFAULTS["vehicle"]["wheelbase"])
    assert ego.diagonal == pytest.approx(math.hypot(4.2, 1.7))
    env.close()
    for bad, where in (({"wheelbase": 5.0}, "config.vehicle"), ({"wheel_base": 2.0}, "config.vehicle.wheel_base"),
                       ({"max_steering": 2.0}, "config.vehicle.max_steering"), ({"width": -1}, "config.vehicle.width")):
        with pytest.raises(Feat2MapError, match=where.replace(".", r"\.")):
            gym.make("feat2map/JunctionGrid-v0", config={"vehicle": bad})


def _corners(x: float, y: float, h: float, length: float, width: float) -> list[tuple[float, float]]:
    c, s = math.cos(h), math.sin(h)
    return [(x + a * c - b * s, y + a * s + b * c) for a in (-length / 2, length / 2) for b in (-width / 2, width / 2)]


@pytest.mark.parametrize("feature", [J([0, 90, 180, 270], "signal", True), J([0, 60, 180], "stop", False)],
                         ids=["cross", "sharp-y"])
def test_the_body_stays_inside_its_lane_through_every_turn(feature):
    """The ego on its own, lane keeping at 6 m/s through every manoeuvre of a junction: every
    corner of its body stays inside the junction lane's edges."""
    env = gym.make("feat2map/JunctionGrid-v0", config={
        "features": [feature.to_dict()], "traffic_vehicles": 0, "pedestrian_rate": 0, "policy_frequency": 5,
        "action": {"type": "ContinuousAction", "longitudinal": True, "lateral": False}, "offroad_terminal": False,
        "duration": 40})
    env.reset(seed=0)
    e = env.unwrapped
    m = e.net.hdmap
    moves = manoeuvres(m)
    assert len(moves) >= 6
    for mv in moves:
        e.config["route"] = [list(mv)]
        env.reset(seed=0)
        ego, inside, seen = e.vehicle, -math.inf, 0
        for _ in range(150):
            _, _, term, trunc, info = env.step(np.array([np.clip((6.0 - ego.speed) / 3, -1, 1)], dtype=np.float32))
            lid = ego.lane_route[ego.route_pos]
            if m.lanes[lid].junction_id is not None:
                lane = e.net.lane_of[lid]
                for p in _corners(ego.position[0], ego.position[1], ego.heading, ego.LENGTH, ego.WIDTH):
                    s, r = lane.local_coordinates(np.array(p))
                    if 0.0 < s < lane.length:
                        inside, seen = max(inside, abs(r) - lane.width / 2), seen + 1
            if term or trunc or info["route_completed"]:
                break
        assert info["route_completed"] and not info["crashed"], mv
        assert seen and inside < 0.0, f"{mv}: a corner {inside:.2f} m past the lane's edge"
    env.close()


# ---- the multi-agent env's agents: the same bicycle, batched over the agents (core.TrafficCore.drive)
def _agent_turns(feature, vehicle: dict | None = None) -> dict[tuple, tuple[dict, float, float]]:
    """Per manoeuvre of the junction, one agent alone at 6 m/s (TargetSpeed): (its last info, how
    far its body's corners reached past the junction lane's edges, its largest |lateral offset|
    there)."""
    env = parallel_env({"features": [feature.to_dict()], "agents": 1, "traffic_vehicles": 0, "pedestrian_rate": 0.0,
                        "policy_frequency": 5, "duration": 40.0, "vehicle": vehicle or {},
                        "action": {"type": "TargetSpeed", "target_speeds": [6.0]}})
    env.reset(seed=0)
    net = env.world.net
    m = net.hdmap
    out = {}
    for mv in manoeuvres(m):
        env.reset(seed=0, options={"config": {"agent_routes": [[list(mv)]]}})
        v, inside, lat, info = env.view("agent_0").vehicle, -math.inf, 0.0, {}
        while env.agents:
            info = env.step({"agent_0": 0})[4]["agent_0"]
            lid = v.lane_route[v.route_pos]
            if m.lanes[lid].junction_id is not None:
                lane = net.lane_of[lid]
                lat = max(lat, abs(v.lane_lat))
                for p in _corners(v.position[0], v.position[1], v.heading, v.LENGTH, v.WIDTH):
                    s, r = lane.local_coordinates(np.array(p))
                    if 0.0 < s < lane.length:
                        inside = max(inside, abs(r) - lane.width / 2)
        out[mv] = (info, inside, lat)
    env.close()
    return out


def test_the_agents_take_the_vehicle_config():
    env = parallel_env({"features": [J([0, 90, 180], "bare", False).to_dict()], "agents": 3, "traffic_vehicles": 2,
                        "vehicle": {"length": 4.2, "width": 1.7, "wheelbase": 2.6}})
    env.reset(seed=0)
    core = env.world.road.core
    assert env.agents
    for a in env.agents:
        v = env.view(a).vehicle
        i = v._row
        assert (v.LENGTH, v.WIDTH, v.model.wheelbase) == (4.2, 1.7, 2.6)
        assert v.diagonal == pytest.approx(math.hypot(4.2, 1.7))
        assert (core.length[i], core.width[i], core.wheelbase[i]) == (4.2, 1.7, 2.6)
        assert core.rear_offset[i] == VehicleModel.of({"length": 4.2, "wheelbase": 2.6}).rear_offset
    with pytest.raises(Feat2MapError, match=r"config\.vehicle\.wheel_base"):
        parallel_env({"vehicle": {"wheel_base": 2.0}})


@pytest.mark.parametrize("feature", [J([0, 90, 180, 270], "signal", True), J([0, 60, 180], "stop", False)],
                         ids=["cross", "sharp-y"])
def test_an_agents_body_stays_inside_its_lane_through_every_turn(feature):
    """As the ego's test above, for an agent: it steers the bicycle by lane keeping (off the
    lane's centre line in the turns, as a car is), and every corner stays inside the lane."""
    turns = _agent_turns(feature)
    assert len(turns) >= 6
    for mv, (info, inside, _) in turns.items():
        assert info["route_completed"] and not info["collision"] and not info["off_road"], mv
        assert inside < 0.0, f"{mv}: a corner {inside:.2f} m past the lane's edge"
    assert max(lat for *_, lat in turns.values()) > 0.1  # not the centre line: the bicycle's own path


def test_the_vehicle_config_changes_the_agents_turning():
    """A steering limit too small for the sharp Y's tight turns takes the agent wide, off the road."""
    feature = J([0, 60, 180], "stop", False)
    default, stiff = _agent_turns(feature), _agent_turns(feature, {"max_steering": 0.15})
    assert max(lat for *_, lat in default.values()) < 0.5
    wide = [mv for mv in stiff if stiff[mv][2] > default[mv][2] + 3.0]
    assert wide and all(stiff[mv][0]["off_road"] for mv in wide)


def test_an_agents_place_on_its_lane_is_the_lanes_own_projection():
    """`TrafficCore.drive` projects agents on their route lanes near where they were (a few
    segments, `LaneTable.project_near`): the values `PolylineLane.local_coordinates` finds over
    the whole lane, through every kind of turn."""
    feats = [J([0, 60, 180], "stop", False), J([0, 90, 180, 270], "signal", True)]
    env = parallel_env({"features": [f.to_dict() for f in feats], "agents": 12, "traffic_vehicles": 3,
                        "duration": 30.0})
    env.reset(seed=1)
    core, lanes = env.world.road.core, env.world.net._lanes
    rng = np.random.default_rng(0)
    checked = 0
    while env.agents:
        env.step({a: int(rng.integers(6)) for a in env.agents})
        for a in env.agents:
            i = env.view(a).vehicle._row
            s, r = lanes[core.lane[i]].local_coordinates(np.array([core.x[i], core.y[i]]))
            assert (core.s[i], core.lat[i]) == (pytest.approx(s, abs=1e-9), pytest.approx(r, abs=1e-9))
            checked += 1
    assert checked > 200


def test_a_tracker_steers_while_set_and_lane_keeping_resumes_after():
    """With a tracker the ego takes its steering every frame; once the tracker is taken away, an
    ego whose action has no lateral part is steered by lane keeping again."""
    from feat2map.envs.driver import DRIVER_ACTION_CONFIG

    env = gym.make("feat2map/JunctionGrid-v0", config={"action": DRIVER_ACTION_CONFIG, "traffic_vehicles": 0})
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    core, row = ego._core, ego._row
    assert ego.auto_steer and core.keeps[row]

    class Left:
        def command(self, position, heading, speed):
            return {"acceleration": 0.0, "steering": 0.2}

    ego.tracker = Left()
    env.step(np.array([0.0], dtype=np.float32))
    assert not core.keeps[row] and ego.action["steering"] == pytest.approx(0.2)
    ego.tracker = None
    assert core.keeps[row]
    env.step(np.array([0.0], dtype=np.float32))
    assert ego.action["steering"] != pytest.approx(0.2)  # lane keeping steers, not the tracker's held 0.2
    env.close()
