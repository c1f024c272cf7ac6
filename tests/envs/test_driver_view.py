"""The DriverView observation (envs/driver_view.py): Gymnasium's checker, and each feature against
what the env and its rules say along real drives (stop line distance and zone, the full stop,
signal colour and time to change, the arrival queue, conflicting traffic, the leader)."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import feat2map
from feat2map.envs import driver_view as dv
from feat2map.envs import parallel_env
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver
from feat2map.envs.rules import STOP_ZONE_M
from feat2map.envs.vehicles import Pedestrian, TrafficVehicle
from conftest import REPO
from feat2map.spec import build_spec, load_spec
from rule_specs import driver_view_as_worded

J = feat2map.JunctionFeature.make
FOUR = [0, 90, 180, 270]
F = {name: i for i, name in enumerate(dv.DRIVER_VIEW_FEATURES)}


def make(control, traffic=0, pedestrians=0.0, turn=None, **config):
    feats = [J(FOUR, control, False)]
    route = None
    if turn is not None:
        m = feat2map.generate_from_features(feats, seed=0)
        ln = sorted((ln for ln in m.lanes_by_junction["J0"] if ln.turn == turn), key=lambda ln: ln.id)[0]
        route = [("J0", m.lanes[ln.predecessors[0]].road_id, m.lanes[ln.successors[0]].road_id)]
    return gym.make("feat2map/JunctionGrid-v0", config={
        "features": [f.to_dict() for f in feats], "observation": {"type": "DriverView"}, "action": DRIVER_ACTION_CONFIG,
        "policy_frequency": 5, "traffic_vehicles": traffic, "pedestrian_rate": pedestrians, "route": route,
        "route_junctions": 1, "duration": 60.0, **config})


def drive(env, seed=0):
    """(observation, info) pairs of a ScriptedDriver episode, the first from reset."""
    obs, info = env.reset(seed=seed)
    out = [(obs, info)]
    driver = ScriptedDriver(env)
    while True:
        obs, _, term, trunc, info = env.step(driver.act())
        out.append((obs, info))
        if term or trunc:
            return out


@pytest.mark.parametrize("control", ["signal", "stop", "bare"])
def test_checker_and_bounds(control):
    env = make(control, traffic=4, pedestrians=3.0)
    check_env(env.unwrapped, skip_render_check=True)
    assert env.observation_space.shape == (len(dv.DRIVER_VIEW_FEATURES),)
    for obs, _ in drive(env):
        assert env.observation_space.contains(obs)


def test_stop_sign_features_along_a_drive():
    """Distance and zone match info's stop-line distance; the control is a stop sign until the
    junction; stop_made turns on only after a stop inside the zone and the entry is no violation."""
    steps = drive(make("stop", turn="left"))
    obs, info = steps[-1]
    assert info["route_completed"] and info["violations"]["stop_sign"] == 0
    made = None
    for i, (obs, info) in enumerate(steps):
        d = info["distance_to_stop_line"]
        if info["lane_id"] and obs[F["in_junction"]] == 0 and obs[F["stop"]] == 1:
            assert obs[F["line_near"]] == pytest.approx(min(max(d, 0) / dv.DRIVER_VIEW_LINE_NEAR_M, 1), abs=1e-4)
            assert obs[F["line_far"]] == pytest.approx(min(max(d, 0) / dv.DRIVER_VIEW_LINE_FAR_M, 1), abs=1e-4)
            assert obs[F["in_stop_zone"]] == float(0 <= d <= STOP_ZONE_M)
            assert obs[F["left"]] == 1 and obs[F["straight"]] == obs[F["right"]] == 0
            if made is None and obs[F["stop_made"]]:
                made = i
    assert made is not None
    before = steps[made - 1][1]
    assert steps[made][1]["speed"] <= 0.3 + 1e-6 or before["speed"] <= 1.0
    assert 0 <= steps[made][1]["distance_to_stop_line"] <= STOP_ZONE_M
    assert all(obs[F["stop_made"]] == 0 for obs, _ in steps[:made])
    assert any(obs[F["in_junction"]] == 1 for obs, _ in steps)
    last = steps[-1][0]  # past the junction: no control, far line
    assert last[F["signal"]] == last[F["stop"]] == last[F["bare"]] == 0 and last[F["line_far"]] == 1


def test_signal_features_match_info():
    steps = drive(make("signal", turn="none"))
    seen = set()
    for obs, info in steps:
        if info["control_ahead"] != "signal":
            continue
        state = info["signal_state"]
        seen.add(state)
        assert [obs[F[s]] for s in ("green", "amber", "red")] == [float(state == s) for s in ("green", "amber", "red")]
        assert obs[F["signal_change"]] == pytest.approx(min(info["signal_time_to_change"] / dv.DRIVER_VIEW_SIGNAL_SCALE_S, 1),
                                                        abs=1e-4)
    assert "green" in seen and steps[-1][1]["violations"]["red_light"] == 0


def _spawn(u, in_lane, j_lane, d, speed):
    """A traffic vehicle `d` metres before the end of `in_lane`, routed into `j_lane`."""
    ln = u.net.lane_of[in_lane]
    v = TrafficVehicle(u.road, ln.position(ln.length - d, 0.0), ln.heading_at(ln.length - d), speed)
    v.init_route([in_lane, j_lane, *u.net.hdmap.lanes[j_lane].successors[:1]])
    u.road.vehicles.append(v)
    u.control.update(u.road, 0.0)
    return v


def _conflict(u, mine, turn, higher):
    """A junction lane of `turn` in conflict with `mine`, with higher (else lower) priority."""
    m, net = u.net.hdmap, u.net
    return next(l for l in sorted(net.conflicts[mine]) if m.lanes[l].turn == turn
                and (net.lane_of[l].priority > net.lane_of[mine].priority) == higher)


def test_conflicting_traffic_with_and_without_priority():
    """Ego turning left at a bare junction: an oncoming straight car is traffic with priority,
    seen with its time to arrival, distance and speed; going straight, a left-turner crossing
    its path is traffic without priority; a vehicle inside a conflicting lane occupies it."""
    env = make("bare", turn="left")
    env.reset(seed=0)
    u = env.unwrapped
    m = u.net.hdmap
    mine = next(l for l in u.vehicle.lane_route if m.lanes[l].junction_id)
    obs = u.observation_type.observe()
    assert obs[F["priority_time"]] == obs[F["other_time"]] == 1 and obs[F["conflict_occupied"]] == 0
    oncoming = _conflict(u, mine, "none", higher=True)
    _spawn(u, m.lanes[oncoming].predecessors[0], oncoming, 20.0, 8.0)
    obs = u.observation_type.observe()
    assert obs[F["priority_time"]] == pytest.approx(20.0 / 8.0 / dv.DRIVER_VIEW_CONFLICT_TIME_S, abs=0.02)
    assert obs[F["priority_distance"]] == pytest.approx(20.0 / dv.DRIVER_VIEW_CONFLICT_DISTANCE_M, abs=0.01)
    assert obs[F["priority_speed"]] == pytest.approx(8.0 / dv.DRIVER_VIEW_SPEED_SCALE_MPS, abs=0.01)
    assert obs[F["other_time"]] == 1 and obs[F["conflict_occupied"]] == 0
    ln = u.net.lane_of[oncoming]
    v = TrafficVehicle(u.road, ln.position(3.0, 0.0), ln.heading_at(3.0), 5.0)
    v.init_route([oncoming])
    u.road.vehicles.append(v)
    u.control.update(u.road, 0.0)
    assert u.observation_type.observe()[F["conflict_occupied"]] == 1

    env = make("bare", turn="none")
    env.reset(seed=0)
    u = env.unwrapped
    mine = next(l for l in u.vehicle.lane_route if m.lanes[l].junction_id)
    turner = _conflict(u, mine, "left", higher=False)
    _spawn(u, m.lanes[turner].predecessors[0], turner, 10.0, 5.0)
    obs = u.observation_type.observe()
    assert obs[F["other_time"]] == pytest.approx(10.0 / 5.0 / dv.DRIVER_VIEW_CONFLICT_TIME_S, abs=0.02)
    assert obs[F["priority_time"]] == 1


def test_stop_queue_counts_earlier_arrivals_with_conflicting_lanes():
    env = make("stop", turn="none")
    env.reset(seed=0)
    u = env.unwrapped
    m, net = u.net.hdmap, u.net
    mine = next(l for l in u.vehicle.lane_route if m.lanes[l].junction_id)
    crossing = next(l for l in sorted(net.conflicts[mine]) if m.lanes[l].turn == "none")
    assert u.observation_type.observe()[F["queue_ahead"]] == 0
    v = _spawn(u, m.lanes[crossing].predecessors[0], crossing, 4.0, 0.0)  # stopped in its zone
    assert v in u.control.stop_queue["J0"]
    assert u.observation_type.observe()[F["queue_ahead"]] == pytest.approx(1 / dv.DRIVER_VIEW_QUEUE_SCALE)


def test_leader_gap_and_speed():
    env = make("bare", turn="none")
    env.reset(seed=0)
    u = env.unwrapped
    ego = u.vehicle
    lane = u.net.lane_of[ego.lane_route[0]]
    s = ego.lane_s + 15.0
    v = TrafficVehicle(u.road, lane.position(s, 0.0), lane.heading_at(s), 3.0)
    v.init_route(ego.lane_route)
    u.road.vehicles.append(v)
    u.control.update(u.road, 0.0)
    obs = u.observation_type.observe()
    assert obs[F["leader_gap"]] == pytest.approx((15.0 - ego.LENGTH) / dv.DRIVER_VIEW_LEADER_SCALE_M, abs=0.02)
    assert obs[F["leader_speed"]] == pytest.approx(3.0 / dv.DRIVER_VIEW_SPEED_SCALE_MPS, abs=0.01)


def test_the_ego_and_traffic_read_their_leaders_from_one_program():
    """The ego's leaders (what DriverView, the planner and the judge read) are the traffic's
    (`TrafficCore._leaders` for the one row): a traffic car ahead and, behind it, a road user
    user code added (a highway-env vehicle the core does not drive) at its exact place, seen by
    the ego and the traffic car alike; the ego as a leader of a car behind it."""
    from highway_env.vehicle.kinematics import Vehicle

    env = make("bare", turn="none")
    env.reset(seed=0)
    u = env.unwrapped
    ego = u.vehicle
    lane = u.net.lane_of[ego.lane_route[0]]
    s = ego.lane_s
    car = TrafficVehicle(u.road, lane.position(s + 12.0, 0.0), lane.heading_at(s + 12.0), 3.0)
    car.init_route(ego.lane_route)
    other = Vehicle(u.road, lane.position(s + 30.0, 0.0), lane.heading_at(s + 30.0), 0.0)
    u.road.vehicles += [car, other]
    u.control.update(u.road, 0.0)
    assert flat(sorted(ego.leader_gaps())) == pytest.approx([12.0 - ego.LENGTH, 3.0, 30.0 - ego.LENGTH, 0.0], abs=1e-6)
    assert flat(car.leader_gaps()) == pytest.approx([18.0 - car.LENGTH, 0.0], abs=1e-6)
    assert u.road.core.leader_gaps(u.road.vehicles.index(car)) == car.leader_gaps()
    # the ego seen by a car behind it
    back = TrafficVehicle(u.road, lane.position(s - 10.0, 0.0), lane.heading_at(s - 10.0), 3.0)
    back.init_route(ego.lane_route)
    u.road.vehicles.append(back)
    u.control.update(u.road, 0.0)
    assert flat([min(back.leader_gaps())]) == pytest.approx([10.0 - back.LENGTH, ego.speed], abs=1e-6)


def flat(pairs: list) -> list[float]:
    return [x for pair in pairs for x in pair]


# busy junctions: a signal and a stop sign, both with crosswalks, queues, traffic in conflict
BUSY = {"features": [J(FOUR, "signal", True).to_dict(), J(FOUR, "stop", True).to_dict()], "traffic_vehicles": 14,
        "pedestrian_rate": 40.0, "route_junctions": 2, "duration": 12.0, "policy_frequency": 5,
        "simulation_frequency": 10, "observation": {"type": "DriverView"}, "action": DRIVER_ACTION_CONFIG}
FELT = ("priority_time", "other_time", "conflict_occupied", "pedestrian", "leader_gap", "queue_ahead", "stop_made",
        "signal_change", "protected", "in_stop_zone", "in_junction", "line_near")


def same_as_worded(pairs, seen: set) -> None:
    """Each (env, observation) pair's observation is DriverView as worded (`rule_specs`), bit for
    bit; `seen` collects the features that were away from their empty value."""
    for env, obs in pairs:
        want = driver_view_as_worded(env)
        assert obs.dtype == np.float32 and np.array_equal(obs, want), \
            {f: (a, b) for f, a, b in zip(dv.DRIVER_VIEW_FEATURES, obs.tolist(), want.tolist()) if a != b}
        seen.update(f for f in FELT if obs[F[f]] != (1.0 if f in ("priority_time", "other_time", "pedestrian",
                                                                    "leader_gap", "line_near") else 0.0))


def test_the_single_batched_and_multi_agent_envs_observe_driver_view_as_worded():
    """DriverView is one program over every ego asked (`driver_views`: a batch of one in the single
    env, the sub-envs of a batch, the agents of the multi-agent env); its features equal the
    rules' answers asked one question at a time, through busy drives with episode ends, and the
    drives reach every feature."""
    rng = np.random.default_rng(0)
    seen: set = set()
    env = gym.make("feat2map/JunctionGrid-v0", config={**BUSY, "duration": 40.0})
    for seed in range(3):
        obs, _ = env.reset(seed=seed)
        driver = ScriptedDriver(env) if seed != 1 else None
        for _ in range(200):
            same_as_worded([(env.unwrapped, obs)], seen)
            action = driver.act() if driver else rng.uniform(-1, 1, env.action_space.shape).astype(np.float32)
            obs, _, term, trunc, _ = env.step(action)
            if term or trunc:
                break
    midblock = {**{k: v for k, v in BUSY.items() if k != "features"}, "route_junctions": 3, "duration": 30.0,
                "map": build_spec(load_spec(REPO / "examples" / "midblock.yaml"))}  # crosswalks one after another
    for env_id, config in (("feat2map/JunctionGrid-v0", BUSY), ("feat2map/MapFile-v0", midblock)):
        batch = gym.make_vec(env_id, num_envs=4, config=config)
        obs, _ = batch.reset(seed=3)
        for _ in range(80):
            same_as_worded(zip(batch.unwrapped.envs, obs), seen)
            obs, *_ = batch.step(rng.uniform(-1, 1, batch.action_space.shape).astype(np.float32))
    marl = parallel_env({**BUSY, "agents": 6, "traffic_vehicles": 4, "duration": 20.0, "action": {"type": "TargetSpeed"},
                         "signal_phases": "single"})  # (every signalled movement protected)
    obs, _ = marl.reset(seed=0)
    for _ in range(100):
        same_as_worded([(marl.unwrapped._views[a], o) for a, o in obs.items()], seen)
        if not marl.agents:
            break
        obs, *_ = marl.step({a: marl.action_space(a).sample() for a in marl.agents})
    assert seen == set(FELT)


def test_the_pedestrian_feature_is_the_first_crosswalk_ahead_that_holds_the_ego(tmp_path):
    """With people standing on two crosswalks along the ego's route (a mid-block one on its road
    and one on the next junction's lane), DriverView's pedestrian distance is the first's; with
    people on the second alone, the second's: each as worded."""
    (tmp_path / "two.yaml").write_text(
        "junctions:\n"
        "  - {cell: [0, 0], crosswalk: true, sockets: [{angle: 0, midblock: {control: bare, position: 0.85}}, 90, 180, 270]}\n"
        "  - {cell: [1, 0], crosswalk: true, sockets: [0, 90, 180, 270]}\n")
    env = gym.make("feat2map/MapFile-v0", config={
        "map": build_spec(load_spec(tmp_path / "two.yaml")), "route_junctions": 2, "observation": {"type": "DriverView"},
        "traffic_vehicles": 0, "pedestrian_rate": 0.0, "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5})
    env.reset(seed=1)  # a route east over the mid-block crosswalk into the second junction
    u = env.unwrapped
    driver = ScriptedDriver(env)
    for _ in range(200):
        if u.vehicle.lane_route[u.vehicle.route_pos] == "R0_0" and u.vehicle.lane_s > 30.0:
            break
        env.step(driver.act())
    route, pos = u.vehicle.lane_route, u.vehicle.route_pos
    (lane_a, cw_a, s_a), (lane_b, cw_b, s_b) = [(lid, cw, (s0 + s1) / 2) for lid in route[pos:pos + 2]
                                                for cw, s0, s1 in u.net.crossings.get(lid, ())][:2]
    assert cw_a == "R0_cw" and u.net.hdmap.crosswalks[cw_b].junction_id is not None

    def stand(lid: str, cw: str, s: float) -> None:
        lane = u.net.lane_of[lid]
        Pedestrian(u.road, lane.position(s, 0.0), lane.position(s, 2.0), 0.0, cw)  # in the lane's middle

    stand(lane_b, cw_b, s_b)
    second = u.observation_type.observe()
    assert np.array_equal(second, driver_view_as_worded(u))
    stand(lane_a, cw_a, s_a)
    both = u.observation_type.observe()
    assert np.array_equal(both, driver_view_as_worded(u))
    assert both[F["pedestrian"]] < second[F["pedestrian"]] < 1.0
