"""Traffic slows for curves as the baseline planner does: its desired speed is limited by the
lateral acceleration on its path ahead (`lanes.curve_speeds`, one rule for both), looked up per
lane from a table built once per network (`LaneTable.curve_q`, `TrafficCore.curve_limit`).
Without it an osm2xodr car took a 7.9 m, 120-degree junction lane at 12.7 m/s (docs/realmaps.md,
"Traffic slows for curves")."""
from __future__ import annotations

import math
import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.config import CURVE_BEHIND_M, CURVE_BRAKE_MPS2, CURVE_MIN_SPEED_MPS, LATERAL_ACCEL_MPS2, LOOKAHEAD_M
from feat2map.envs.core import LaneTable
from feat2map.envs.lanes import PolylineLane, curve_speeds
from feat2map.scenarios.planner import BaselinePlanner

J = feat2map.JunctionFeature.make


@pytest.fixture(scope="module")
def four_way():
    """A generated bare four-way junction (right turns of about 11 m radius, junction limit
    8.9 m/s), no traffic of its own."""
    env = gym.make("feat2map/JunctionGrid-v0",
                   config={"features": [J([0, 90, 180, 270], "bare", False).to_dict()], "traffic_vehicles": 0})
    env.reset(seed=0)
    yield env.unwrapped
    env.close()


@pytest.mark.parametrize("radius", [4.0, 10.0, 40.0])
def test_curve_speed_of_an_arc_is_sqrt_of_lateral_acceleration_times_radius(radius):
    t = np.linspace(0.0, math.pi / 2, max(8, int(radius * math.pi / 2)))
    lane = PolylineLane(np.stack([radius * np.cos(t), radius * np.sin(t)], axis=1), lane_id="arc")
    v = curve_speeds(lane)
    want = max(math.sqrt(LATERAL_ACCEL_MPS2 * radius), CURVE_MIN_SPEED_MPS)
    np.testing.assert_allclose(v, want, rtol=0.03)
    straight = PolylineLane(np.array([[0.0, 0.0], [5.0, 0.0], [30.0, 0.0]]), lane_id="straight")
    assert curve_speeds(straight).min() > 100.0
    assert curve_speeds(lane) is v  # computed once per lane


def test_planner_and_traffic_read_the_same_curve_speeds(four_way):
    """One source of truth: the planner's curve speeds are the lane's `curve_speeds`."""
    planner = BaselinePlanner()
    planner.env = four_way
    lid = "J0_c0_0"
    s, v = planner._curve_speeds(lid)
    lane = four_way.net.lane_of[lid]
    assert s is lane.cum and v is curve_speeds(lane)


def _brute_force_limit(core, i: int) -> float:
    """The desired-speed cap of row i from every vertex of its window, one by one."""
    best = math.inf
    s = float(core.s[i])
    for k in range(core.W.shape[1]):
        lane = int(core.W[i, k])
        if lane < 0 or core.C[i, k] - s > LOOKAHEAD_M:
            continue
        ln = core.net._lanes[lane]
        for sv, vc in zip(ln.cum, curve_speeds(ln)):
            x = core.C[i, k] + sv - s
            if k == 0 and x < -CURVE_BEHIND_M:
                continue
            best = min(best, vc * vc + 2 * CURVE_BRAKE_MPS2 * x)
    return math.sqrt(max(best, CURVE_MIN_SPEED_MPS ** 2))


def test_curve_limit_is_the_brute_force_minimum_over_the_window():
    env = gym.make("feat2map/JunctionGrid-v0", config={"features": [J([0, 90, 180, 270], "signal", True).to_dict(),
                                                                    J([0, 120, 240], "stop", False).to_dict()],
                                                       "traffic_vehicles": 14})
    env.reset(seed=2)
    core = env.unwrapped.road.core
    checked = 0
    for _ in range(12):
        env.step(1)
        core.refresh_windows()  # as `accelerations` does before it asks
        limit = core.curve_limit()
        for i in np.nonzero(core.driven)[0].tolist():
            assert limit[i] == pytest.approx(_brute_force_limit(core, i), rel=1e-9)
            checked += 1
    env.close()
    assert checked > 50
    assert isinstance(core.table, LaneTable)


def test_traffic_takes_a_junction_turn_at_its_curve_speed(four_way):
    """A car entering a right turn at about 9 m/s (its road's limit is 11.2 m/s, the junction's
    8.9 m/s) brakes to the turn's curve speed (5.3 m/s): never more than 0.5 m/s above it where
    the turn is tightest (IDM follows its lowered desired speed with a lag) (fails without the rule: the car keeps 8.9 m/s)."""
    u = four_way
    net = u.net
    turn = "J0_c0_0"  # R0_1 -> R1_0
    lane = net.lane_of[turn]
    v_c = curve_speeds(lane)
    core = u.road.core
    car = core.add_traffic(u.road, "R0_1", 0.0, 8.9, ["R0_1", turn, "R1_0"])
    tight = lane.cum[v_c < v_c.min() + 0.2]
    seen = []
    for _ in range(150):
        u.road.act()
        u.road.step(1 / u.config["simulation_frequency"])
        if net.id_of.get(car.lane_index) == turn:
            s = car.lane_s
            if tight.min() <= s <= tight.max():
                seen.append(car.speed)
        elif seen:
            break
    assert seen, "the car never reached the tight part of the turn"
    assert max(seen) <= v_c.min() + 0.5
