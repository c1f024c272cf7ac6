"""A controlled row's task is row arrays of the core (envs/task.py): its route metres and its
goal are found again only when its route or route position changed, they move with the row when
other rows go, and the reward's progress terms of an episode add up to the route driven."""
from __future__ import annotations

import math

import gymnasium as gym
import numpy as np

import feat2map
from feat2map.envs import task

N = 4
J = feat2map.JunctionFeature.make
# two lanes a direction, and the ego changes lanes (its route is planned again: `TrafficCore.reroute`)
TWO_LANES = {"features": [J([0, 90, 180, 270], c, False, lanes=2).to_dict() for c in ("signal", "bare")],
             "action": {"type": "DiscreteMetaAction", "lateral": True, "longitudinal": True}}


def walked(ego) -> float:
    """The route metres of a road user, walked lane by lane: the lanes behind its route position
    and its place on its route lane, within the lane."""
    lanes = ego.road.network.lane_of
    route, pos = ego.lane_route, ego.route_pos
    return sum(lanes[x].length for x in route[:pos]) + min(max(ego.route_s(), 0.0), lanes[route[pos]].length)


def at_goal(env) -> bool:
    """Whether the ego stands on its route's last lane at least its goal into it."""
    ego = env.vehicle
    route = ego.lane_route
    return ego.route_pos == len(route) - 1 and ego.route_s() >= env.goal_s(env.net.lane_of[route[-1]])


def test_route_metres_and_arrival_follow_lane_changes_and_rows_that_come_and_go():
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=N, vectorization_mode="vector_entry_point",
                        config={"traffic_vehicles": 8, "route_junctions": 2, **TWO_LANES})
    envs.reset(seed=5)
    rng = np.random.default_rng(0)
    subs = envs.unwrapped.envs
    core = subs[0].road.core
    moved = rerouted = arrived = 0
    for _ in range(160):
        before = [e.vehicle.row for e in subs]
        versions = core.route_ver[before].copy()
        _, _, te, tr, info = envs.step(rng.integers(0, 5, N))
        rows = np.array([e.vehicle.row for e in subs])
        moved += int((rows != before).sum())
        rerouted += int((core.route_ver[rows] != versions).sum())
        assert task.route_done(core, rows).tolist() == [walked(e.vehicle) for e in subs]
        done = task.completed(core, rows).tolist()
        assert done == [at_goal(e) for e in subs]
        arrived += sum(done)
    assert moved and rerouted and arrived  # rows moved, routes changed, egos arrived: each was looked at
    # a route user code sets, the ego at the same route position on it: what lies behind differs
    ego = next(e.vehicle for e in subs if e.vehicle.route_pos >= 1)
    route, pos, lanes = list(ego.lane_route), ego.route_pos, ego.road.network.lane_of
    other = next(x for x in lanes if abs(lanes[x].length - lanes[route[0]].length) > 1.0)
    ego.lane_route = [other, *route[1:]]
    ego.route_pos = pos
    assert task.route_done(core, np.array([ego.row]))[0] == walked(ego)


def test_an_episodes_progress_terms_add_up_to_the_route_driven():
    env = gym.make("feat2map/JunctionGrid-v0", config={"traffic_vehicles": 4, "route_junctions": 1})
    env.reset(seed=2)
    u = env.unwrapped
    core, row = u.road.core, u.vehicle.row
    start, goal = core.progress[row], core.goal[row]  # the route metres at the start, and to the goal
    assert start == walked(u.vehicle) and 0 <= start < goal
    total, steps = 0.0, 0
    while True:
        _, _, te, tr, info = env.step(1)  # IDLE: the ego drives its route to the goal
        total += info["rewards"]["progress"]
        steps += 1
        if te or tr:
            break
    assert steps > 10 and info["route_completed"] and not info["crashed"]
    now = walked(u.vehicle)
    assert core.progress[u.vehicle.row] == now >= goal
    assert math.isclose(total, (now - start) / goal, rel_tol=1e-9)
    assert info["route_progress"] == 1.0
