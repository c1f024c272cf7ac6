"""The ego's vehicle (envs/sim/vehicle.py): a kinematic bicycle about the rear axle with the
config's body. Its motion is exact on arcs, the same over arrays as over floats, configurable,
and its body fits the junction turns the generator makes (highway-env's 5 m-wheelbase bicycle
swept 0.83 m past a lane's edge in the default map's tightest turn)."""
from __future__ import annotations

import math
import os

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.config import DRIVE_DEFAULTS
from feat2map.envs.sim.vehicle import VehicleModel, integrate, pursuit_steering
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
        x, y, h, v = integrate(x, y, h, v, steer, 0.0, 1 / 15, MODEL.wheelbase, MODEL.rear_offset, math)
        rx, ry = x - MODEL.rear_offset * math.cos(h), y - MODEL.rear_offset * math.sin(h)
        assert math.hypot(rx - cx, ry - cy) == pytest.approx(radius, abs=1e-6)
    assert v == 6.0


def test_arrays_and_floats_move_alike():
    rng = np.random.default_rng(3)
    x, y, h = rng.uniform(-50, 50, 40), rng.uniform(-50, 50, 40), rng.uniform(-3, 3, 40)
    v, steer, acc = rng.uniform(0, 20, 40), rng.uniform(-0.6, 0.6, 40), rng.uniform(-5, 3, 40)
    batch = integrate(x, y, h, v, steer, acc, 0.1, MODEL.wheelbase, MODEL.rear_offset)
    for k in range(40):
        one = integrate(x[k], y[k], h[k], v[k], steer[k], acc[k], 0.1, MODEL.wheelbase, MODEL.rear_offset, math)
        assert np.allclose([b[k] for b in batch], one, rtol=0, atol=1e-12)


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
