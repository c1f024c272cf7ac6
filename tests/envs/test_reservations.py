"""Junction reservations and the road lanes drawn across junction lanes: traffic heading into a
road lane that crosses a junction lane waits for whoever holds that junction lane (osm2xodr
scheck-in r077)."""
from __future__ import annotations

import dataclasses
import math
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.config import STOP_POINT_M
from feat2map.envs.core import LaneTable
from feat2map.envs.sim import passages
from feat2map.formats import native
from feat2map.scenarios.scenario import Scenario, make_env


def _crossed_map(path: Path) -> Path:
    """A generated bare four-way whose straight J0_c1_0 (ending at (19.5, -1.75)) is crossed
    0.5 m before its end by RX_0, a road lane of a road of its own running north along x = 19
    (scheck-in's `w669252633_0_0_-1` across `j_26026265_c55_0_-1`), fed by the 30 m road lane
    RY_0 before it: traffic reaches RX_0 from a road lane, through no junction entry."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)], seed=0)
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731

    def lane(lid: str, y0: float, y1: float, predecessors: tuple = (), successors: tuple = ()):
        pts = np.stack([np.full(8, 19.0), np.linspace(y0, y1, 8)], 1)
        return dataclasses.replace(m.lanes["R2_0"], id=lid, road_id=lid[:2], centerline=tup(pts),
                                   left_boundary=tup(pts - (1.75, 0)), right_boundary=tup(pts + (1.75, 0)),
                                   predecessors=predecessors, successors=successors, left_neighbors=(),
                                   right_neighbors=(), left_reverse_neighbors=(), bezier=None)

    def road(rid: str, lid: str):
        return dataclasses.replace(m.roads["R2"], id=rid, right_lanes=(lid,), left_lanes=(), reference=None,
                                   start_junction=None, end_junction=None)

    lanes = {**m.lanes, "RY_0": lane("RY_0", -44.0, -14.0, successors=("RX_0",)),
             "RX_0": lane("RX_0", -14.0, 0.0, predecessors=("RY_0",))}
    m = dataclasses.replace(m, lanes=lanes, roads={**m.roads, "RY": road("RY", "RY_0"), "RX": road("RX", "RX_0")})
    native.save(m, path)
    return path


@pytest.fixture(scope="module")
def crossed(tmp_path_factory) -> Path:
    return _crossed_map(tmp_path_factory.mktemp("crossed") / "crossed.json")


def _env(path: Path):
    sc = Scenario("crossed", str(path), (("J0", "R3", "R1"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    return env


def passage_arrays(core) -> tuple[bytes, ...]:
    """The narrow passages' state of every row (`sim.passages`), to compare."""
    return tuple(getattr(core, name).tobytes() for name in passages.ARRAYS)


def _parked(env) -> None:
    """One step with the ego standing still (the rules' state brought up to date)."""
    env.step(np.zeros(env.action_space.shape, dtype=np.float32))


def test_traffic_into_a_road_lane_across_a_held_junction_lane_waits_at_its_start(crossed):
    """A car on RY_0 heading into RX_0 waits at RX_0's start while J0_c1_0, which RX_0 crosses,
    is occupied by someone else, and drives on while it is free (fails without the rule: no
    junction entry lies ahead of it, nothing stopped it, and it drove into the car leaving
    J0_c1_0: scheck-in r077). The traffic core hands such rows to the rules."""
    env = _env(crossed)
    u = env.unwrapped
    net, ctl = u.net, u.control
    assert "RX_0" in net.conflicts["J0_c1_0"]
    car = u.road.spawn("RY_0", 20.0, 0.0, ["RY_0", "RX_0"])
    _parked(env)
    assert ctl.stop_distance(car) == math.inf  # J0_c1_0 is free
    c1 = net.hdmap.lanes["J0_c1_0"]
    u.road.spawn("J0_c1_0", 4.0, 0.0, ["J0_c1_0", c1.successors[0]])  # stands in J0_c1_0
    _parked(env)
    d = net.lane_of["RY_0"].length - car.s_on("RY_0")
    assert ctl.stop_distance(car) == pytest.approx(d - STOP_POINT_M)
    for _ in range(20):  # 2-4 s, driven by the batched traffic core: it stays before RX_0
        _parked(env)
    assert net.id_of[car.lane_index] == "RY_0"
    assert set(np.asarray(net.lane_ids)[LaneTable(net).crossed]) == {"RX_0"}  # the core's table of such lanes
    env.close()



@pytest.fixture(scope="module")
def signal_cross(tmp_path_factory) -> Path:
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False)], seed=0)
    path = tmp_path_factory.mktemp("signal_cross") / "cross.json"
    native.save(m, path)
    return path


def test_a_follower_past_the_line_takes_over_its_leaders_reservation(signal_cross):
    """A car that followed its leader past the line into the leader's reserved left turn claimed
    nothing (the lane was taken); when the leader gives the lane up, the follower, no longer
    able to stop, holds it, so cross traffic's `junction_clear` sees it. Without the hand-over
    the lane stood unreserved while the follower was still short of it, and the ego reserved a
    crossing straight lane into its path (GoMentum base_map r002). A follower that can still
    stop takes nothing: it asks `may_enter` as usual."""
    sc = Scenario("cross", str(signal_cross), (("J0", "R3", "R1"),), seed=0, duration=30.0)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, ctl, m = u.net, u.control, u.net.hdmap
    left = next(lid for lid, ln in sorted(m.lanes.items()) if ln.turn == "left" and ln.junction_id == "J0"
                and not lid.startswith(("J0_c3", "J0_c1")))  # not across the ego's way in
    approach, exit_ = m.lanes[left].predecessors[0], m.lanes[left].successors[0]
    length = net.lane_of[approach].length
    line = length - net.setbacks.get(approach, 0.0)
    leader = u.road.spawn(left, 2.0, 5.0, [left, exit_])
    near = u.road.spawn(approach, line + 1.0, 8.0, [approach, left, exit_])  # past its line at 8 m/s
    far = u.road.spawn(approach, line - 40.0, 8.0, [approach, left, exit_])  # can still stop
    ctl.reservations[left] = leader
    u.road.vehicles.remove(leader)  # the leader is gone: its reservation is given up
    ctl.update(u.road, 0.0)
    assert ctl.reservations.get(left) is near
    assert all(ctl.reservations.get(x) is not far for x in ctl.reservations)
    env.close()


def test_the_rules_questions_take_nothing_and_a_claim_takes_what_they_allow(signal_cross):
    """The rules' questions are pure: asking a car's stop distance, whether it may enter, or its
    wait for a passage, in any order and with any rule ignored, leaves the reservations as they
    were and gives the same answers again. Its claim (what traffic does every frame, and an ego
    through `EgoTask.claim`) answers what the question answered and takes it: within commit
    distance of its line on green it reserves its junction lane (with the lanes chained after it);
    on red the question holds it at the line and keeps the reservation, the claim gives it up."""
    env = make_env(Scenario("cross", str(signal_cross), (("J0", "R3", "R1"),), seed=0, duration=30.0),
                   config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    net, ctl, m = u.net, u.control, u.net.hdmap
    approach = next(lid for lid, sl in sorted(net.stop_lines.items())
                    if sl.kind == "signal" and ctl.signal_at(lid) == "green" and not lid.startswith("R3"))
    lane = next(s for s in sorted(m.lanes[approach].successors) if m.lanes[s].turn == "none")
    line = net.lane_of[approach].length - net.setbacks.get(approach, 0.0)
    car = u.road.spawn(approach, line - 6.0, 5.0, [approach, lane, m.lanes[lane].successors[0]])
    ctl.update(u.road, 0.0)

    def state():
        return dict(ctl.reservations), car.reserved, passage_arrays(u.road.core)

    before = state()
    answers = [ctl.stop_distance(car, ignore=frozenset(ig)) for ig in ((), ("conflict",), ("signal", "stop"))]
    assert ctl.may_enter(car, approach, lane, line - car.s_on(approach)) and ctl.passage_stop(car) == math.inf
    assert answers == [math.inf] * 3 and state() == before and lane not in ctl.reservations
    assert [ctl.stop_distance(car, ignore=frozenset(ig)) for ig in ((), ("conflict",), ("signal", "stop"))] == answers
    assert ctl.claim(car) == answers[0]
    assert ctl.reservations.get(lane) is car and car.reserved == lane
    held = dict(ctl.reservations)
    plan = ctl.plans[net.stop_lines[approach].control_id]
    ctl.t = next(t for t in np.arange(0.0, plan.cycle, 0.5) if plan.state(net.stop_lines[approach].control_id, t) == "red")
    d_line = line - car.s_on(approach)
    assert not ctl.may_enter(car, approach, lane, d_line)
    assert ctl.stop_distance(car) == pytest.approx(d_line - STOP_POINT_M)  # held at the line
    assert dict(ctl.reservations) == held and car.reserved == lane  # ... and the question kept the reservation
    assert ctl.claim(car) == pytest.approx(d_line - STOP_POINT_M)
    assert lane not in ctl.reservations and car.reserved is None  # the claim gave it up
    env.close()


def test_asking_every_road_user_every_question_changes_nothing_in_busy_traffic(signal_cross):
    """Over 60 steps of a signalized cross with traffic, every question asked of every road user
    (its stop distance with each rule ignored in turn and all at once, may it enter its next junction lane, its
    wait for a passage, what holds it there) leaves the rules' state as it was: reservations,
    passage holders, waiters and rooms, and each road user's reserved lane; the frames between
    the steps, where traffic claims, do change it (the check can tell)."""
    from feat2map.envs.rules import RULES

    env = make_env(Scenario("cross", str(signal_cross), (("J0", "R3", "R1"),), seed=0, duration=30.0),
                   config={"traffic_vehicles": 10})
    env.reset(seed=0)
    u = env.unwrapped
    ctl = u.control

    def state():
        return (dict(ctl.reservations), [getattr(v, "reserved", None) for v in u.road.vehicles],
                passage_arrays(u.road.core))

    asks = [(), *((r,) for r in RULES), RULES]  # each rule ignored, and all of them (a claim would take a lane now)
    moved, last = 0, state()
    for _ in range(60):
        _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, dtype=np.float32))
        if terminated or truncated:
            break
        before = state()
        moved += before != last
        users = [v for v in u.road.vehicles if hasattr(v, "lane_route")]
        for v in users:
            answers = [ctl.stop_distance(v, ignore=frozenset(ig)) for ig in asks]
            ctl.passage_stop(v)
            _, in_lane, j_lane, d = ctl.line_ahead(v)
            if j_lane is not None:
                ctl.may_enter(v, in_lane, j_lane, d)
                ctl.may_enter(v, in_lane, j_lane, d, ignore=frozenset(RULES))
                ctl.junction_clear(j_lane, v)
            assert [ctl.stop_distance(v, ignore=frozenset(ig)) for ig in asks] == answers
        assert state() == before
        last = before
    assert moved > 0
    env.close()


def test_reservations_are_the_cores_arrays_and_each_slot_reads_them_as_a_mapping():
    """A slot's reservations (`TrafficControl.reservations`) are a view of the core's arrays:
    a mapping in the order they were taken (taking a held lane again keeps its place), the
    holders' rows in `res[slot, lane]`; rows going renumber the holders, one that left
    the road holds as `LEFT` until its slot's next update releases it, and a slot's new episode
    starts with nothing reserved while the other slots keep theirs."""
    from feat2map.envs.reservations import LEFT, LEFT_HOLDER, NONE

    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=3, vectorization_mode="vector_entry_point",
                        config={"traffic_vehicles": 6})
    envs.reset(seed=1)
    c = envs.unwrapped.core
    junction_lanes = [lid for lid in c.net.lane_ids if c.net.hdmap.lanes[lid].junction_id is not None]
    nl = len(c.net.lane_ids)
    held = {}
    for slot in range(3):
        road, ctl = c.roads[slot], c.roads[slot].control
        cars = road.vehicles[1:4]
        lanes = junction_lanes[3 * slot:3 * slot + 3][::-1]  # taken out of lane order
        for car, lane in zip(cars, lanes):
            ctl.reservations[lane] = car
        ctl.reservations[lanes[0]] = cars[2]  # taken again: a new holder, the same place in the order
        assert ctl.reservations.setdefault(lanes[1], cars[0]) is cars[1]
        assert list(ctl.reservations) == lanes and len(ctl.reservations) == 3
        assert [ctl.reservations[x] for x in lanes] == [cars[2], cars[1], cars[2]]
        assert lanes[0] in ctl.reservations and junction_lanes[-1] not in ctl.reservations
        assert ctl.reservations.held_by(cars[2]) and not ctl.reservations.held_by(cars[0])
        held[slot] = (lanes, cars)
    slot_of, lane_of = np.nonzero(c.res != NONE)
    assert sorted(zip((slot_of * nl + lane_of).tolist(), c.res[slot_of, lane_of].tolist())) == sorted(
        (slot * nl + c.table.index[x], ctl_car._row) for slot, (lanes, cars) in held.items()
        for x, ctl_car in zip(lanes, (cars[2], cars[1], cars[2])))
    # slot 0's cars[2] leaves the road: slot 1's and 2's rows move down, their holders with them
    lanes0, cars0 = held[0]
    c.roads[0].vehicles.remove(cars0[2])
    c.sync()
    ctl0 = c.roads[0].control
    assert ctl0.reservations[lanes0[0]] is LEFT_HOLDER and ctl0.reservations[lanes0[1]] is cars0[1]
    for slot in (1, 2):
        lanes, cars = held[slot]
        res = c.roads[slot].control.reservations
        assert [res[x] for x in lanes] == [cars[2], cars[1], cars[2]]
        assert res.held_by(cars[2]) and res.held_by(cars[1]) and not res.held_by(cars[0])  # (counts moved along)
    res2 = c.roads[2].control.reservations
    del res2[held[2][0][1]]
    assert not res2.held_by(held[2][1][1]) and res2.held_by(held[2][1][2])
    res2[held[2][0][1]] = held[2][1][1]
    assert c.res[0, c.table.index[lanes0[0]]] == LEFT
    ctl0.update(c.roads[0], 0.0)  # the holder that left lets go
    assert list(ctl0.reservations) == [lanes0[1]]
    envs.unwrapped.envs[1].reset(seed=5)  # slot 1's new episode
    assert not c.roads[1].control.reservations
    lanes, cars = held[2]
    assert list(c.roads[2].control.reservations) == [lanes[0], lanes[2], lanes[1]]  # (given up and taken again: last)
    envs.close()


def test_looking_only_at_reservations_whose_holder_moved_releases_what_looking_at_all_does(monkeypatch):
    """A frame's releases look only at the reservations taken since the last look, held by a road
    user that left, or whose holder's route, route position or lane changed (`release_looks`):
    in busy batched traffic every slot then holds, step by step, exactly what it holds when every
    reservation is looked at every frame."""
    from feat2map.envs.core import TrafficCore

    looks = TrafficCore.release_looks

    def run(look_at_all: bool) -> list:
        if look_at_all:
            def every(core, slots):
                looks(core, slots)  # (its bookkeeping, as in the other run)
                return {s: list(core.roads[s].control.reservations) for s in np.nonzero(slots)[0].tolist()}
            monkeypatch.setattr(TrafficCore, "release_looks", every)
        envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=8, vectorization_mode="vector_entry_point",
                            config={"traffic_vehicles": 14, "policy_frequency": 5, "duration": 1e9})
        envs.reset(seed=6)
        c = envs.unwrapped.core
        out = []
        for _ in range(120):
            envs.step(np.ones(8, dtype=np.int64))
            out.append([sorted((lid, getattr(v, "_row", -2)) for lid, v in road.control.reservations.items())
                        for road in c.roads])
        envs.close()
        monkeypatch.undo()
        return out

    looked, every = run(False), run(True)
    assert sum(len(held) for step in every for held in step) > 500
    assert looked == every
