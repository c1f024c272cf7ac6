"""Bends tighter than a car turns (`feat2map.config.TIGHT_BEND_RADIUS_M`): a car waiting at a
junction's entry stands clear of the swept path of such a junction turn (osm2xodr digitaf r178:
the ego left a 4.9 m left turn with its heading 29 degrees behind its lane and its corner swept
over the car waiting at the opposite lane's line), and a route's goal lies before its last
lane's first such bend (digitaf r214: a road at the map's edge whose lanes fold into one point).

The map the tests make: a generated signalled four-way whose right turn from R0 into R1 is
redrawn with a kink 2 m before the junction's mouth (radius 2.8 m over a wheelbase), as
osm2xodr draws turns; R1_1, R1's lane towards the junction, waits 3.5 m beside its exit."""
from __future__ import annotations

from dataclasses import replace
from types import SimpleNamespace

import numpy as np
import pytest
import shapely

import feat2map
from feat2map.config import STOP_POINT_M, SWEEP_CLEARANCE_M, SWEEP_SPEEDS_MPS, TIGHT_BEND_RADIUS_M, VEHICLE_LENGTH_M
from feat2map.envs.lanes import PolylineLane
from feat2map.envs.map_env import MapEnv
from feat2map.envs.network import MapNetwork
from feat2map.envs.sweep import _joined, footprints, sweep
from feat2map.routes import first_tight_bend, sharpest_radius

TURN, WAITER = "J0_c0_0", "R1_1"


def _dense(corners) -> tuple:
    pts = np.asarray(corners, dtype=float)
    seg = np.diff(pts, axis=0)
    out = [pts[0]] + [pts[i] + np.outer(np.linspace(0, 1, max(2, int(np.hypot(*seg[i]) / 0.5)))[1:], seg[i])
                      for i in range(len(seg))]
    return tuple(map(tuple, np.vstack(out)))


@pytest.fixture(scope="module")
def four():
    return feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False)], seed=1)


@pytest.fixture(scope="module")
def kinked(four):
    assert four.lanes[TURN].turn == "right" and four.lanes[TURN].successors == ("R1_0",)
    c = _dense([(-19.5, -1.7), (-12.0, -5.0), (-1.8, -17.5), (-1.8, -19.5)])
    lane = replace(four.lanes[TURN], centerline=c, left_boundary=c, right_boundary=c, bezier=None)
    assert sharpest_radius(lane) < TIGHT_BEND_RADIUS_M < sharpest_radius(four.lanes[TURN])
    return replace(four, lanes={**four.lanes, TURN: lane})


def _waiting(net, line: float) -> shapely.Polygon:
    lane = net.lane_of[WAITER]
    c = line - STOP_POINT_M - VEHICLE_LENGTH_M / 2
    return footprints(np.array([(*lane.position(c, 0.0), lane.heading_at(c))]))[0]


def test_the_wait_beside_a_tight_turns_exit_is_out_of_its_swept_path(four, kinked):
    """R1_1's signal line moves back until a car waiting at it is clear of the lane keeping's
    footprints leaving the kinked turn (at every sweep speed); at the line's old place the
    footprints run over it (fails without the rule)."""
    net = MapNetwork.from_map(kinked)
    old = MapNetwork.from_map(four)
    length = net.lane_of[WAITER].length
    assert old.stop_lines[WAITER].s == pytest.approx(length) and WAITER not in old.setbacks
    assert net.setbacks[WAITER] > 0.0 and net.stop_lines[WAITER].s == pytest.approx(length - net.setbacks[WAITER])
    assert net.max_line_setback == pytest.approx(net.setbacks[WAITER])
    assert {k for k, v in net.setbacks.items() if v > 1e-6} == {WAITER}  # nothing else moves
    path = _joined(net, TURN, "R1_0", 20.0)
    feet = footprints(np.array([p for v in SWEEP_SPEEDS_MPS for p in sweep(path, v)]))
    assert shapely.distance(feet, _waiting(net, length)).min() < SWEEP_CLEARANCE_M  # the old wait is swept
    assert shapely.distance(feet, _waiting(net, net.stop_lines[WAITER].s)).min() >= SWEEP_CLEARANCE_M


def test_generated_maps_have_no_tight_turns_to_wait_clear_of(four):
    """The generated junction's turns are wider than a car turns: no wait point moves."""
    net = MapNetwork.from_map(four)
    assert all(v < 1e-6 for v in net.setbacks.values())
    assert all(sl.s == pytest.approx(net.lane_of[lid].length) for lid, sl in net.stop_lines.items())


def test_the_goal_lies_before_the_last_lanes_first_tight_bend():
    """digitaf's `w648817642_1_0_-1`: 0.6 m east, then 75 degrees north at once, into the point
    where the road's three lanes end. The goal is where the tight bend begins, not 15 m in;
    a lane without a tight bend keeps its goal (fails without the rule)."""
    a = np.radians(75.0)
    kinked = PolylineLane(np.array(_dense([(0.0, 0.0), (0.6, 0.0), (0.6 + 8 * np.cos(a), 8 * np.sin(a))])), 1.6, lane_id="kinked")
    straight = PolylineLane(np.array([(0.0, 0.0), (30.0, 0.0)]), 3.5, lane_id="straight")
    assert first_tight_bend(kinked.points) < 0.6 and first_tight_bend(straight.points) == np.inf
    env = SimpleNamespace(config={"goal_distance": 15.0}, net=SimpleNamespace(memo=lambda key, build: build()))
    assert MapEnv.goal_s(env, kinked) == pytest.approx(max(first_tight_bend(kinked.points), 0.0))
    assert MapEnv.goal_s(env, straight) == 15.0
