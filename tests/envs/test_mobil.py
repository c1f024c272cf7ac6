"""MOBIL's lane changes as one program (`envs/sim/mobil.py`): on two-lane roads in busy batched
traffic, every car due asks at once, and each takes the neighbour lane, and the route from it,
that MOBIL as worded for that car alone gives (rule_specs.py); cars change lanes, and cars
refuse to."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.invariants import lane_changes
from feat2map.envs.sim import mobil
from rule_specs import mobil_as_worded

J = feat2map.JunctionFeature.make
TWO_LANES = {"features": [J([0, 90, 180, 270], "signal", True, lanes=2).to_dict(),
                          J([0, 120, 240], "bare", False, lanes=2).to_dict()],
             "traffic_vehicles": 32, "route_junctions": 2, "pedestrian_rate": 10.0, "duration": 20.0}


def test_every_car_due_takes_the_lane_change_mobil_gives_it_alone(monkeypatch):
    decide = mobil.decide
    seen = {"asked": 0, "changes": 0}

    def checked(c, rows, fi, gap, v_lead):
        got = decide(c, rows, fi, gap, v_lead)
        taken = {i: (c.net.lane_ids[n], tuple(path)) for i, n, path in got}
        for i in rows.tolist():  # (each car against the state the frame began with, before any change)
            gaps = [(g, v) for f, g, v in zip(fi.tolist(), gap.tolist(), v_lead.tolist()) if f == i]
            want = mobil_as_worded(c.roads[c.env[i]].control, c.objs[i], gaps)
            assert taken.get(i) == (None if want is None else (want[0], tuple(want[1]))), i
        seen["asked"] += len(rows)
        seen["changes"] += len(got)
        return got

    monkeypatch.setattr(mobil, "decide", checked)
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=8, vectorization_mode="vector_entry_point",
                        config=TWO_LANES)
    envs.reset(seed=3)
    for _ in range(120):
        envs.step(np.ones(8, dtype=np.int64))
    envs.close()
    assert seen["changes"] > 10 and seen["asked"] > 10 * seen["changes"], seen


@pytest.fixture
def road():
    """(the env, its map network, a road lane of the two-lane road between the junctions, the
    lane beside it across a dashed line), with no traffic."""
    env = gym.make("feat2map/JunctionGrid-v0", config={**TWO_LANES, "traffic_vehicles": 0, "pedestrian_rate": 0.0})
    env.reset(seed=0)
    u = env.unwrapped
    net, m = u.net, u.net.hdmap
    lane = next(ln for ln in m.lanes.values() if ln.junction_id is None and lane_changes(ln) and ln.successors
                and net.lane_of[ln.id].length > 60)
    yield u, net, lane, lane_changes(lane)[0]
    env.close()


def test_a_car_changes_onto_the_free_lane_beside_a_slow_leader(road):
    """A car behind a slow car on the two-lane road between the junctions moves to the free lane
    beside it, where its route goes on; the slow car keeps its lane."""
    u, net, lane, other = road
    slow = u.road.spawn(lane.id, 30.0, 2.0, [lane.id])
    car = u.road.spawn(lane.id, 5.0, 10.0, [lane.id])
    for _ in range(20):
        u.road.act()
        u.road.step(0.1)
    assert net.id_of[car.lane_index] == other and getattr(car, "lane_changes", 0) == 1
    assert net.id_of[slow.lane_index] == lane.id and not getattr(slow, "lane_changes", 0)


@pytest.mark.parametrize("behind", ["near", "far"])
def test_a_car_stays_where_its_new_follower_would_brake_hard(road, behind):
    """The same car with two cars coming up behind on the free lane, one at its speed, one faster:
    where the faster one is the nearer behind (close, it would brake harder than
    MOBIL_SAFE_BRAKE_MPS2 behind the car) the car stays; where it is farther back than the other,
    the other is the new follower and the car changes (the new follower is the nearest behind)."""
    u, net, lane, other = road
    u.road.spawn(lane.id, 40.0, 2.0, [lane.id])
    car = u.road.spawn(lane.id, 20.0, 8.0, [lane.id])
    u.road.spawn(other, 3.0, 8.0, [other])
    u.road.spawn(other, 12.0 if behind == "near" else 0.0, 13.0, [other])
    u.road.act()
    assert (net.id_of[car.lane_index] == lane.id) == (behind == "near")


def test_a_car_stays_where_its_gain_is_less_than_its_new_followers_loss_times_politeness(road):
    """A car 20 m behind a car at 6 m/s gains 1.6 m/s^2 on the free lane, but its new follower,
    9 m behind it there at its speed, would go from accelerating to braking at 2.8 m/s^2 (safe,
    but a loss of 5.4 m/s^2, of which MOBIL_POLITENESS counts): the car stays."""
    u, net, lane, other = road
    car = u.road.spawn(lane.id, 15.0, 8.0, [lane.id])
    u.road.spawn(lane.id, 15.0 + 20.0 + car.LENGTH, 6.0, [lane.id])
    u.road.spawn(other, 15.0 - 9.0 - car.LENGTH, 8.0, [other])
    u.road.act()
    assert net.id_of[car.lane_index] == lane.id
