"""A road user's body, not only its centre, decides whether it is in the way (`rules.in_the_way`
with `rules.body_reach`): traffic turning off a lane behind a car that stands on the lane
diverging from it waits where that car's body, at an angle to the turn, sticks into its path
(CommonRoad's reactive planner's sf-r022: a car on the diverging lane accelerated into the ego's
turned body, whose centre lay 2.9-3.6 m from its lane), and passes where it does not."""
from __future__ import annotations

import math
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import numpy as np
import pytest

import feat2map
from feat2map.envs.rules import body_reach, in_the_way
from feat2map.formats import native
from feat2map.scenarios.scenario import Scenario, make_env

STRAIGHT, RIGHT = "J0_c10_0", "J0_c9_0"  # from R3_1: straight on, and the right turn diverging from it


def test_body_reach_is_zero_along_the_lane_and_grows_with_the_angle():
    assert body_reach(1.9, 4.8, 0.0) == 0.0 and body_reach(1.9, 4.8, math.pi) == pytest.approx(0.0, abs=1e-12)
    assert body_reach(1.9, 4.8, 0.27) == pytest.approx(body_reach(1.9, 4.8, -0.27))
    assert body_reach(1.9, 4.8, 0.66) == pytest.approx(0.95 * (math.cos(0.66) - 1) + 2.4 * math.sin(0.66))
    assert body_reach(1.9, 4.8, math.pi / 2) == pytest.approx(2.4 - 0.95)
    corner = math.atan2(4.8, 1.9)  # the diagonal across the lane: the farthest a corner reaches
    reach = body_reach(1.9, 4.8, np.linspace(0.0, corner, 50))  # arrays too
    assert np.all(np.diff(reach) > 0) and reach[-1] == pytest.approx(math.hypot(1.9, 4.8) / 2 - 0.95)
    assert not in_the_way(10.0, 3.0, 3.5, 30.0, 4.8) and in_the_way(10.0, 3.0, 3.5, 30.0, 4.8, reach=0.3)


@pytest.fixture(scope="module")
def four_way(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("reach") / "m.json"
    native.save(feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)],
                                                seed=0), path)
    return path


def _drive_past(path: Path, s: float, turn: float) -> tuple[float, bool]:
    """A car starting at 6 m/s on the right turn; the ego standing on the straight lane at `s`,
    turned `turn` off it. (How far the car got along its turn in 8 s, whether anyone crashed.)"""
    env = make_env(Scenario("reach", str(path), (("J0", "R3", "R1"),), seed=0, duration=30.0),
                   config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    lane = u.net.lane_of[STRAIGHT]
    ego = u.vehicle
    ego.position, ego.heading, ego.speed = np.array(lane.position(s, 0.0)), lane.heading_at(s) + turn, 0.0
    car = u.road.spawn(RIGHT, 0.5, 6.0, [RIGHT, "R0_0"])
    still = np.zeros(env.action_space.shape, dtype=np.float32)
    for _ in range(40):
        env.step(still)
        if car.crashed or ego.crashed:
            break
    got = (float(car.lane_s) if u.net.id_of.get(car.lane_index) == RIGHT else math.inf, car.crashed or ego.crashed)
    env.close()
    return got


@pytest.mark.parametrize("s,turn", [(13.0, 0.0), (14.0, -0.27), (15.0, -0.27)])
def test_a_car_waits_behind_a_body_that_sticks_into_its_turn(four_way, s, turn):
    """The ego's centre lies 3.0-4.1 m from the turn's centreline, yet its body reaches into it:
    the car stops behind it (before the body rule, in the first two it drove into the ego)."""
    along, crashed = _drive_past(four_way, s, turn)
    assert not crashed and along < 8.0, (along, crashed)


@pytest.mark.parametrize("s,turn", [(15.0, 0.0), (14.0, 0.27)])
def test_a_car_passes_a_body_clear_of_its_turn(four_way, s, turn):
    along, crashed = _drive_past(four_way, s, turn)
    assert not crashed and along == math.inf  # it left its turn for R0_0
