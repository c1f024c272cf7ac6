"""Failure classes found driving a real Baidu-style Apollo map (issue 21 item 5), each on a map
the test makes itself: merges registered as conflicts whatever the junction ids say; narrow lanes
on a bend (2.66 m lanes: a car's corners swing out of its lane there) are a narrow passage; an
unprotected entry held by a steady stream with the right of way takes its lane after PATIENCE_S
where the vehicles it relies on can still stop for its reservation; same-direction road lanes that
converge along a road (a taper merge, Highway101GLE's lane_92 and lane_93) zip.

Every fixture is a generated map changed the way the real map is drawn."""
from __future__ import annotations

import dataclasses
from pathlib import Path

import gymnasium as gym
import numpy as np
import pytest

import feat2map
from feat2map.config import STOP_POINT_M, STOP_ZONE_M
from feat2map.envs.network import MapNetwork, merge_pairs, unregistered_merges
from feat2map.formats import native
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.scenario import Scenario, make_env


def _drive(path: Path, route, spawns, duration: float = 40.0, config: dict | None = None):
    """Drive the ego with the baseline planner along `route`; `spawns` are (time, lane path, s
    before the first lane's end, speed) traffic cars added during the drive (and removed at the
    end of their path). Returns
    (outcome, env, planner): 'collision', 'completed' or 'timeout'."""
    sc = Scenario("fixture", str(path), route, seed=0, duration=duration)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False, **(config or {})})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    planner = BaselinePlanner()
    planner.reset(env)
    todo = sorted(spawns, key=lambda x: x[0])
    f = u.config["policy_frequency"]
    outcome = "timeout"
    for k in range(int(duration * f)):
        while todo and k >= todo[0][0] * f:
            _, path_, back, speed = todo.pop(0)
            u.road.spawn(path_[0], u.net.lane_of[path_[0]].length - back, speed, list(path_))
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        done = [v for v in u.road.vehicles if v is not u.vehicle and getattr(v, "finished", False)]
        if done:  # cars at the end of their route leave (they would park there)
            u.road.vehicles = [v for v in u.road.vehicles if v not in done]
        if info["collision"]:
            outcome = "collision"
            break
        if term or trunc:
            outcome = "completed" if u.route_completed() else "timeout"
            break
    env.close()
    return outcome, env, planner


def _in(m, jid: str, road: str) -> str:
    return next(ln.id for ln in m.lanes.values() if ln.road_id == road and ln.junction_id is None
                and any(m.lanes[s].junction_id == jid for s in ln.successors))


def _out(m, jid: str, road: str) -> str:
    return next(ln.id for ln in m.lanes.values() if ln.road_id == road and ln.junction_id is None
                and any(m.lanes[p].junction_id == jid for p in ln.predecessors))


def _path(m, jid: str, entry: str, exit_: str) -> str:
    return next(ln.id for ln in m.lanes.values() if ln.junction_id is not None
                and m.lanes[ln.predecessors[0]].road_id == entry and m.lanes[ln.successors[0]].road_id == exit_)


# ---- merges ------------------------------------------------------------------------------------

@pytest.fixture(scope="module")
def overlapping_t(tmp_path_factory) -> Path:
    """A bare T (legs east R0, north R1, west R2) whose straight path west -> east belongs to a
    second junction element over the same area (Baidu-style overlapping junction polygons): the
    left turn north -> east merges into the lane that straight traffic enters."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "bare", False)], seed=0)
    straight = _path(m, "J0", "R2", "R0")
    lanes, roads = dict(m.lanes), dict(m.roads)
    lanes[straight] = dataclasses.replace(lanes[straight], junction_id="J0b")
    rid = lanes[straight].road_id
    roads[rid] = dataclasses.replace(roads[rid], junction_id="J0b")
    junctions = {**m.junctions, "J0b": dataclasses.replace(m.junctions["J0"], id="J0b")}
    path = tmp_path_factory.mktemp("merge") / "overlapping_t.json"
    native.save(dataclasses.replace(m, lanes=lanes, roads=roads, junctions=junctions), path)
    return path


def test_merges_are_conflicts_whatever_the_junction_ids(overlapping_t):
    m = native.load(overlapping_t)
    net = MapNetwork.from_map(m)
    left, straight = _path(m, "J0", "R1", "R0"), _path(m, "J0b", "R2", "R0")
    assert (min(left, straight), max(left, straight)) in merge_pairs(m)
    assert straight in net.conflicts[left] and left in net.conflicts[straight]
    assert unregistered_merges(net) == []
    # a diverge (two paths from one lane) is no merge
    assert all(not set(m.lanes[a].predecessors) & set(m.lanes[b].predecessors) for a, b in merge_pairs(m))


@pytest.mark.parametrize("t_spawn, back", [(3.0, 20.0), (4.0, 10.0), (5.0, 10.0)])
def test_left_turn_waits_for_straight_traffic_entering_its_exit(overlapping_t, t_spawn, back):
    """The ego turns left north -> east at the bare T while a car drives west -> east at 10 m/s
    into the same exit lane: nobody collides (the two entered together before: no conflict
    was registered between lanes of different junction elements)."""
    m = native.load(overlapping_t)
    car = [_in(m, "J0b", "R2"), _path(m, "J0b", "R2", "R0"), _out(m, "J0", "R0")]
    outcome, *_ = _drive(overlapping_t, (("J0", "R1", "R0"),), [(t_spawn, car, back, 10.0)])
    assert outcome == "completed"


# ---- narrow lanes on a bend --------------------------------------------------------------------

@pytest.fixture(scope="module")
def narrow(tmp_path_factory) -> Path:
    """The San Francisco feature space, seed 1, with 2.66 m lanes (the real map's width): road R1
    bends at a 10.7 m radius before J0."""
    from feat2map.config import GenerationConfig

    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1, config=GenerationConfig(lane_width=2.66))
    path = tmp_path_factory.mktemp("narrow") / "narrow.json"
    native.save(m, path)
    return path


def test_swing_grows_with_curvature():
    from feat2map.envs.network import VEHICLE_LENGTH_M, VEHICLE_WIDTH_M, swing

    k = np.array([0.0, 0.01, 0.05, 0.1, 0.2])
    w = swing(k)
    assert w[0] == 0.0 and np.all(np.diff(w) > 0)
    r = 1 / 0.1
    assert w[3] == pytest.approx(np.hypot(r + VEHICLE_WIDTH_M / 2, VEHICLE_LENGTH_M / 2) - r - VEHICLE_WIDTH_M / 2)


def test_narrow_lanes_on_a_bend_are_a_passage(narrow):
    """R1's opposite lanes are 2.66 m apart everywhere: more than a car width plus margin (no
    passage on its straight part), less once both cars swing on the bend before J0."""
    m = native.load(narrow)
    net = MapNetwork.from_map(m)
    assert set(net.passages) == {"R1_0", "R1_1"}
    toward_j0 = net.passages["R1_1"]
    assert toward_j0.s1 > net.lane_of["R1_1"].length - 2.0 and toward_j0.s0 > 40.0  # the bend, to J0
    assert MapNetwork.from_map(feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1)).passages == {}


@pytest.mark.parametrize("t_spawn, back", [(35.0, 20.0), (36.0, 40.0), (39.0, 20.0)])
def test_oncoming_car_on_the_bend_waits_for_the_ego(narrow, t_spawn, back):
    """The ego drives R1 towards J0 (a left turn there) while a car turns out of J0 into R1 at
    10 m/s: the two never meet on the bend (their corners clipped there before)."""
    car = ["R2_1", "J0_c5_0", "R1_0", "J1_c2_0", "R4_0"]
    outcome, *_ = _drive(narrow, (("J1", "R3", "R1"), ("J0", "R1", "R0")), [(t_spawn, car, back, 10.0)],
                         duration=150.0)
    assert outcome == "completed"


# ---- an unprotected entry into a steady stream ------------------------------------------------

@pytest.mark.parametrize("headway", [5.4, 5.8])
def test_entry_into_a_steady_stream_decides_instead_of_waiting_forever(overlapping_t, headway):
    """The ego turns left at the bare T into the exit that a car enters every `headway` seconds
    at 12 m/s (traffic with the right of way). It waited to the end of the drive before; now,
    held PATIENCE_S, it reserves its lane when the cars it relies on can still stop for that,
    and nobody collides."""
    from feat2map.scenarios.planner import PATIENCE_S

    m = native.load(overlapping_t)
    car = [_in(m, "J0b", "R2"), _path(m, "J0b", "R2", "R0"), _out(m, "J0", "R0")]
    spawns = [(k * headway, car, 40.0, 12.0) for k in range(int(90 / headway))]
    outcome, env, planner = _drive(overlapping_t, (("J0", "R1", "R0"),), spawns, duration=90.0)
    assert outcome == "completed"
    entered = next(e.time for e in planner.events if e.stage == "B_I")
    assert entered >= PATIENCE_S


# ---- stop-sign queue: a route position that moved on ------------------------------------------

def test_queue_member_that_moved_on_still_wants_its_lane_in_this_junction(tmp_path):
    """A route follower moves its route position onto the junction lane in the last metre before
    it; the stop-sign queue still reads that lane as the one it wants in this junction (it read
    the next junction's: a car later in the queue took a lane merging with the ego's as the ego
    crossed its line, Shalun's sim_map r008). Read alike from a row's window, from its route while
    its window is to be rebuilt, and for a road user that is no driven row."""
    from types import SimpleNamespace

    from feat2map.envs.sim.stop_signs import _lane_on_route, lanes_in

    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "stop", False)
    m = feat2map.generate_from_features([four, four], seed=0)
    j0 = next(ln for ln in m.lanes.values() if ln.junction_id == "J0" and ln.successors[0] in m.roads["R2"].lane_ids)
    link = j0.successors[0]
    j1 = next(x for x in m.lanes[link].successors if m.lanes[x].junction_id == "J1")
    route = [j0.predecessors[0], j0.id, link, j1]
    path = tmp_path / "two.json"
    native.save(m, path)
    env = make_env(Scenario("two", str(path), (("J0", "R0", "R2"),), seed=0, duration=10.0),
                   config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    core = u.road.core
    t = core.table
    v = u.road.spawn(route[0], 1.0, 0.0, route)
    J0 = np.array([t.junction_number["J0"]])
    for pos, want in ((0, j0.id), (1, j0.id), (2, j0.id), (3, None)):
        v.route_pos = pos
        stale = lanes_in(core, np.array([v.row]), J0)  # its window to be rebuilt: read from its route
        core.refresh_windows()
        fresh = lanes_in(core, np.array([v.row]), J0)
        assert [t.index.get(want, -1)] == stale.tolist() == fresh.tolist(), pos
    other = SimpleNamespace(lane_route=route, route_pos=1)  # a road user user code drives
    assert _lane_on_route(core, other, int(J0[0])) == t.index[j0.id]
    env.close()


# ---- an approach lane shorter than a car after another junction (netconvert) -------------------

def _cut(poly, s: float):
    """A polyline split at arc length `s`: (before, after), sharing the cut point."""
    p = np.asarray(poly, dtype=float)
    cum = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    s = s / cum[-1] * cum[-1]
    k = int(np.searchsorted(cum, s, side="right")) - 1
    t = (s - cum[k]) / max(cum[k + 1] - cum[k], 1e-12)
    q = p[k] + t * (p[k + 1] - p[k])
    return [tuple(x) for x in np.vstack([p[:k + 1], q])], [tuple(x) for x in np.vstack([q, p[k + 1:]])]


@pytest.fixture(scope="module")
def short_approach(tmp_path_factory) -> Path:
    """Two junctions (J0 bare, J1 signalled) joined by road R: the last 10 m of R's lanes towards
    J1 become a junction lane of a two-arm junction JX and a 0.2 m road lane before J1's stop
    line, the way netconvert writes them (its lane-count changes are junctions)."""
    return _short_approach_map(tmp_path_factory.mktemp("short") / "short_approach.json", 10.0)


@pytest.fixture(scope="module")
def tight_approach(tmp_path_factory) -> Path:
    """`short_approach` with a 3.8 m junction lane in JX, as in SUMO's durlacher-tor (junction
    163's 3.8 m lane, then the 0.2 m lane before junction 9's line)."""
    return _short_approach_map(tmp_path_factory.mktemp("tight") / "tight_approach.json", 4.0)


def _short_approach_map(path: Path, jx_length: float, jx: str = "JX", control: str = "signal") -> Path:
    """The two-junction map of `short_approach` with the last `jx_length` metres of R's lanes
    towards J1 made a junction lane of junction `jx` (less 0.2 m; JX, a junction of its own, or
    J1: one element drawn over both) and a 0.2 m road lane; J1's `control` a signal or stop signs."""
    from shapely.geometry import LineString

    from feat2map.model import as_polyline

    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False),
                                         feat2map.JunctionFeature.make([0, 90, 180], control, False)], seed=0)
    (conn,) = [r for r in m.roads.values() if r.kind == "connection"]
    lanes = dict(m.lanes)
    shapes = []
    for lid in conn.lane_ids:
        ln = lanes[lid]
        if not any(m.lanes[s].junction_id == "J1" for s in ln.successors):
            continue
        pieces = {}
        for f in ("centerline", "left_boundary", "right_boundary"):
            total = LineString(getattr(ln, f)).length
            road, rest = _cut(getattr(ln, f), total * (1 - jx_length / ln.length))
            inner, last = _cut(rest, LineString(rest).length - total * 0.2 / ln.length)
            pieces[f] = (road, inner, last)
        r, a = f"{lid}_r", f"{lid}_jx"
        lanes[r] = dataclasses.replace(ln, id=r, successors=(a,), left_neighbors=(), right_neighbors=(),
                                       left_reverse_neighbors=(), **{f: as_polyline(p[0]) for f, p in pieces.items()})
        lanes[a] = dataclasses.replace(ln, id=a, junction_id=jx, predecessors=(r,), successors=(lid,),
                                       left_neighbors=(), right_neighbors=(), left_reverse_neighbors=(),
                                       **{f: as_polyline(p[1]) for f, p in pieces.items()})
        lanes[lid] = dataclasses.replace(ln, predecessors=(a,), **{f: as_polyline(p[2]) for f, p in pieces.items()})
        for p in ln.predecessors:
            lanes[p] = dataclasses.replace(lanes[p], successors=tuple(r if x == lid else x for x in lanes[p].successors))
        parts = {"centerline": (pieces["centerline"][1],)}
        shapes.append(LineString(parts["centerline"][0]).buffer(2.0))
    from shapely.ops import unary_union

    poly = unary_union(shapes).convex_hull
    junctions = dict(m.junctions)
    if jx not in junctions:
        junctions[jx] = feat2map.model.Junction(jx, as_polyline(poly.exterior.coords[:-1]))
    native.save(dataclasses.replace(m, lanes=lanes, junctions=junctions), path)
    return path


def test_no_start_across_the_stop_line_of_a_short_approach(short_approach):
    """A route from R at J1 started the ego on the 0.2 m lane, its front across J1's red line:
    a red-light violation at t=0.2 s (netconvert maps). It starts before JX instead."""
    m = native.load(short_approach)
    (conn,) = [r for r in m.roads.values() if r.kind == "connection"]
    sc = Scenario("fixture", str(short_approach), (("J1", conn.id, next(
        m.lanes[s].road_id for ln in m.lanes_by_junction["J1"] for s in ln.successors
        if any(m.lanes[p].road_id == conn.id for p in ln.predecessors))),), seed=0, duration=40.0)
    env = make_env(sc, config={"traffic_vehicles": 0})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    route = u.vehicle.lane_route
    assert m.lanes[route[1]].junction_id == "JX" and route[0].endswith("_r")
    planner = BaselinePlanner()
    planner.reset(env)
    for _ in range(40):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        if term or trunc:
            break
    assert info["violations"]["red_light"] == 0
    env.close()


def _through_jx_scenario(path: Path) -> Scenario:
    m = native.load(path)
    (conn,) = [r for r in m.roads.values() if r.kind == "connection"]
    exit_ = next(m.lanes[s].road_id for ln in m.lanes_by_junction["J1"] for s in ln.successors
                 if any(m.lanes[p].road_id == conn.id for p in ln.predecessors))
    return Scenario("fixture", str(path), (("J1", conn.id, exit_),), seed=0, duration=40.0)


def _red_offset(sc: Scenario) -> float:
    """A `signal_offsets` value for J1 that holds the ego's approach red from t = 0 for a slot:
    the phase after the approach's own is on."""
    env = make_env(sc, config={"traffic_vehicles": 0})
    env.reset(seed=0)
    u = env.unwrapped
    sl, _, _, _ = u.control.line_ahead(u.vehicle)
    if sl is None:  # the ego starts before JX, whose bare entry comes first: J1's line is after it
        route = u.vehicle.lane_route
        sl = next(u.net.stop_lines[a] for a, b in zip(route, route[1:])
                  if b in u.net.lane_of and u.net.hdmap.lanes[b].junction_id == "J1")
    plan = u.control.plans[sl.control_id]
    env.close()
    slot = plan.green + plan.amber + plan.all_red
    return ((plan.phase_of(sl.control_id) + 1) % len(plan.phases)) * slot


def test_the_line_after_a_junction_and_a_short_lane_is_seen_from_before_the_junction(tight_approach):
    """SUMO's durlacher-tor r014/r015: junction 163's 3.8 m lane, a 0.2 m lane, then junction 9's
    red line. The rules' scan ended at the first road lane after the next junction entry, so J1's
    line came into view 4 m ahead, inside JX, too late to stop: a red-light violation. The scan
    now runs on across road too short to wait on: from before JX, J1's red is a stop."""
    sc = _through_jx_scenario(tight_approach)
    env = make_env(sc, config={"traffic_vehicles": 0, "signal_offsets": {"J1": _red_offset(sc)}})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    ego = u.vehicle
    m = u.net.hdmap
    assert m.lanes[ego.lane_route[ego.route_pos]].junction_id is None and m.lanes[ego.lane_route[1]].junction_id == "JX"
    j1 = next(x for x in ego.lane_route if m.lanes[x].junction_id == "J1")
    d_j1 = u.control.line_distance(ego, j1)
    stop = u.control.stop_distance(ego)
    assert stop == pytest.approx(d_j1 - STOP_POINT_M)  # J1's red line holds it, seen from before JX
    planner = BaselinePlanner()
    planner.reset(env)
    for _ in range(int(14 * u.config["policy_frequency"])):  # J1 is red all along
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        assert not (term or trunc)
    assert info["violations"]["red_light"] == 0
    assert ego.speed < 0.5 and 0.0 <= u.control.line_distance(ego, j1) < 3.0 + ego.LENGTH  # waiting at J1's line
    env.close()


def _walked_stops(u, v) -> list[tuple[str, str | None, float, int]]:
    """What a walk along `v`'s route (`RouteFollower.upcoming`) finds can stop it, lane by lane,
    up to the first road after a junction entry with room to wait: the test's own reading of the
    rules' scan, against which `sim.rule_scan` is held."""
    from feat2map.envs.rules import (CROSSED, ENTRY, MIDBLOCK, PEOPLE, crossed_lanes, enters_junction, line_setback,
                                     room_to_wait)

    net, m = u.net, u.net.hdmap
    out = []
    entered, room = False, 0.0
    for k, lid, d, s_own in v.upcoming():
        people = any(u.control.pedestrians.get(cw) for cw, _, _ in net.crossings.get(lid, ()))
        what = (MIDBLOCK if lid in net.midblock_lines else 0) | (PEOPLE if people else 0)
        if s_own is None:
            what |= (CROSSED if crossed_lanes(net, lid) else 0) | \
                (ENTRY if enters_junction(m.lanes, v.lane_route[k - 1], lid) else 0)
        if what:
            out.append((lid, None if s_own is not None else v.lane_route[k - 1], d, what))
        if s_own is not None:
            continue
        if m.lanes[lid].junction_id is not None:
            entered, room = True, 0.0
        elif entered:
            room += net.lane_of[lid].length
            if room_to_wait(room - line_setback(net, lid), v.LENGTH):
                break
    return out


@pytest.mark.parametrize("where", ["tight", "grid"])
def test_the_rules_scan_finds_every_stop_along_the_route(where, tight_approach):
    """`sim.rule_scan` (the one scan of the rules' stop distance) finds, for every road user at
    once, what a walk along its route finds: junction entries (two in a row from before JX of
    `tight_approach`: the 0.2 m road between JX and J1 holds no car), crosswalks with people on
    them and nothing past the first road with room to wait (on a 64 m grid the next junction's
    entry lies within LOOKAHEAD_M beyond it), however the road users stand."""
    from feat2map.envs.rules import ENTRY

    if where == "tight":
        sc = _through_jx_scenario(tight_approach)
        env = make_env(sc, config={"traffic_vehicles": 0})
        env.reset(seed=0)
        u = env.unwrapped
        route = list(u.vehicle.lane_route)
        for k in range(len(route) - 1):
            for s in np.linspace(0.0, u.net.lane_of[route[k]].length, 7):
                u.road.spawn(route[k], float(s), 0.0, route[k:])
        u.control.update(u.road, 0.0)
        frames = 1
    else:
        J = feat2map.JunctionFeature.make
        feats = [J([0, 90, 180, 270], "signal", True), J([0, 90, 180, 270], "stop", True),
                 J([0, 90, 180], "bare", True), J([0, 90, 180, 270], "bare", False)]
        env = gym.make("feat2map/JunctionGrid-v0", config={  # junctions close enough to see two at once
            "features": [f.to_dict() for f in feats], "traffic_vehicles": 30, "pedestrian_rate": 60.0,
            "policy_frequency": 5, "generation": {"grid_gap": 64.0}})
        env.reset(seed=3)
        u = env.unwrapped
        frames = 40
    core, ids = u.road.core, u.net.lane_ids
    seen = 0
    for _ in range(frames):
        for v in u.road.vehicles:
            got = [(ids[lane], ids[prev] if prev >= 0 else None, d, what) for lane, prev, d, what in
                   core.rule_scan_of(v)[0].stops(0)]
            want = _walked_stops(u, v)
            assert [g[:2] + g[3:] for g in got] == [w[:2] + w[3:] for w in want], v
            assert [g[2] for g in got] == pytest.approx([w[2] for w in want], abs=1e-9)
            seen += sum(1 for g in got if g[3] & ENTRY)
        if frames > 1:
            env.step(env.action_space.sample())
    assert seen > 0
    if where == "tight":  # from before JX, J1's entry is in the scan too
        ego = u.vehicle
        assert sum(1 for *_, what in core.rule_scan_of(ego)[0].stops(0) if what & ENTRY) == 2
    env.close()


def test_the_stop_sign_queues_ask_the_rules_of_every_road_user_before_a_stop_sign_line(tmp_path):
    """`sim.stop_signs.candidates` (whom the stop-sign queues' update asks `waiting_line`) holds
    every road user that `TrafficRules.waiting_line` puts before a stop sign's line, wherever it
    stands along a route to J1's stop sign: on its own lane's line, and from the lane before the
    0.2 m last lane and inside JX before it (the line ahead along its route); stopped there, each
    joins J1's queue in the order it stopped."""
    from feat2map.envs.sim import stop_signs

    sc = _through_jx_scenario(_short_approach_map(tmp_path / "stop.json", 4.0, control="stop"))
    env = make_env(sc, config={"traffic_vehicles": 0})
    env.reset(seed=0)
    u = env.unwrapped
    core, route = u.road.core, list(u.vehicle.lane_route)
    m = u.net.hdmap
    j1 = next(k for k, x in enumerate(route) if m.lanes[x].junction_id == "J1")
    for k in range(j1 - 3, j1):
        for s in np.linspace(0.0, u.net.lane_of[route[k]].length, 12):
            u.road.spawn(route[k], float(s), 0.0, route[k:])
    for lid, sl in u.net.stop_lines.items():  # and about each line of J1 (either end of the zone)
        for s in np.clip(sl.s + np.linspace(-STOP_ZONE_M - 1.0, 1.0, 33), 0.0, u.net.lane_of[lid].length):
            u.road.spawn(lid, float(s), 0.0, [lid, m.lanes[lid].successors[0]])
    core.sync([u.road])
    core.refresh_windows()  # (a row whose window is stale is asked whatever it holds)
    lane = core.where_lanes()
    rows = core.rows(u.road)
    waiting = []
    for i in rows.tolist():
        sl, _ = u.control.waiting_line(core.objs[i], u.net.lane_ids[lane[i]])
        if sl is not None and sl.kind == "stop":
            waiting.append(i)
    asked = set(stop_signs.candidates(core, np.isin(np.arange(len(lane)), rows), lane).tolist())
    assert set(waiting) <= asked
    assert any(u.net.lane_ids[lane[i]] not in u.net.stop_lines for i in waiting)  # (a line ahead on the route)
    far = [i for i in rows.tolist() if u.control.line_ahead(core.objs[i])[3] > STOP_ZONE_M + stop_signs.ZONE_MARGIN_M
           + 0.1]  # ... but not those further from their next line than the zone and its margin
    assert far and asked.isdisjoint(far)
    u.control.update(u.road, 0.0)  # every spawned car stands: those before the line join J1's queue
    queue = u.control.stop_queue["J1"]
    assert sorted(v._row for v in queue) == sorted(waiting) and [v._row for v in queue] == sorted(waiting)
    assert core.queued == len(waiting) == (core.stop_junction >= 0).sum()
    u.road.vehicles.remove(queue[0])  # one leaves the road: the queue and the count follow
    u.control.update(u.road, 0.0)
    assert u.control.stop_queue["J1"] == queue[1:] and core.queued == len(waiting) - 1
    env.close()


def test_a_car_queued_behind_is_no_conflict(tmp_path):
    """osm2xodr's karl-wilhelm r039: junctions drawn as one element (j_25420935), two of its lanes
    joined by a 4.9 m road. The footprints of cars on the two lanes overlap across the road, so
    they were conflicts: a car waiting on the road at its red line could never enter the next
    lane while the car queued behind it stood in the first (three cars locked up). A junction
    lane that follows another through less than two cars of road is one stream with it."""
    path = _short_approach_map(tmp_path / "cluster.json", 4.0, jx="J1")
    m = native.load(path)
    first = next(ln for ln in m.lanes.values() if ln.id.endswith("_jx"))
    short = first.successors[0]
    nxt = next(s for s in m.lanes[short].successors)
    assert m.lanes[nxt].junction_id == first.junction_id == "J1"
    net = MapNetwork.from_map(m)
    assert nxt not in net.conflicts[first.id] and first.id not in net.conflicts[nxt]
    sc = _through_jx_scenario(path)
    env = make_env(sc, config={"traffic_vehicles": 0, "route": {"lanes": [first.predecessors[0], first.id, short, nxt]},
                               "ego_start_distance": 3.0})
    env.reset(seed=0)
    u = env.unwrapped
    u.road.spawn(first.id, 1.0, 0.0, [first.id, short, nxt])  # queued behind a car waiting at J1's line
    u.control.update(u.road, 0.0)
    assert u.control.junction_clear(nxt, u.vehicle)  # the car behind holds the leader at the line no longer
    env.close()


def test_a_line_just_past_the_goal_is_no_part_of_the_drive(tight_approach):
    """osm2xodr's karl-wilhelm r027: a route ending on a 4.9 m road before a red line puts the
    goal 1 m before the line; at 12 m/s the ego passed both within one policy step, and the
    frame after the goal was judged a red-light violation. The drive ends at the goal: frames
    after it are not judged. Here the route ends on the 0.2 m lane before J1's red line (its
    goal is the lane itself), so the ego, seeing no line on its route, drives on into J1."""
    sc = _through_jx_scenario(tight_approach)
    m = native.load(tight_approach)
    jx = next(ln for ln in m.lanes.values() if ln.junction_id == "JX")
    lanes = [jx.predecessors[0], jx.id, jx.successors[0]]
    env = make_env(sc, config={"traffic_vehicles": 0, "signal_offsets": {"J1": _red_offset(sc)},
                               "route": {"lanes": lanes}, "ego_start_distance": 20.0})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    planner = BaselinePlanner()
    planner.reset(env)
    for _ in range(int(20 * u.config["policy_frequency"])):
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        if term or trunc:
            break
    assert u.route_completed() and info["violations"]["red_light"] == 0
    assert m.lanes[u.net.id_of[u.vehicle.lane_index]].junction_id == "J1"  # it did cross the line, after the goal
    env.close()


# ---- a taper merge along a road ----------------------------------------------------------------

@pytest.fixture(scope="module")
def taper(tmp_path_factory) -> Path:
    """A bare 4-way junction with two lanes a direction whose exit east (R2) is a 60 m taper: the
    outer lane R2_1 converges onto the inner lane R2_0 and both end in one point (Highway101GLE's
    road_17 draws its merge so, without a junction or a link between the lanes)."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False, lanes=2)],
                                        seed=0)

    def along(ln, pts):
        d = np.gradient(pts, axis=0)
        d /= np.hypot(*d.T)[:, None]
        n = np.stack([-d[:, 1], d[:, 0]], 1) * ln.width / 2
        tup = lambda a: tuple(map(tuple, a))  # noqa: E731
        return dataclasses.replace(ln, centerline=tup(pts), left_boundary=tup(pts + n), right_boundary=tup(pts - n),
                                   bezier=None)

    x = np.linspace(19.5, 79.5, 31)
    lanes = dict(m.lanes)
    lanes["R2_0"] = along(m.lanes["R2_0"], np.stack([x, np.full_like(x, -1.75)], 1))
    lanes["R2_1"] = along(m.lanes["R2_1"], np.stack([x, -5.25 + 3.5 * (x - 19.5) / 60.0], 1))
    path = tmp_path_factory.mktemp("taper") / "taper.json"
    native.save(dataclasses.replace(m, lanes=lanes), path)
    return path


def test_converging_lanes_zip_until_they_meet(taper):
    """The taper's lanes are registered as converging, each with the end of its zip (where the
    centrelines are last closer than a car width: the common end point); lanes 3.5 m apart that
    never converge are not."""
    from feat2map.envs.network import converging_pairs

    m = native.load(taper)
    net = MapNetwork.from_map(m)
    assert converging_pairs(m) == [("R2_0", "R2_1")]
    assert set(net.merges) == {"R2_0", "R2_1"}
    assert net.merges["R2_0"]["R2_1"] == pytest.approx(net.lane_of["R2_0"].length, abs=1.0)
    plain = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False, lanes=2)],
                                            seed=0)
    assert MapNetwork.from_map(plain).merges == {}


def test_lanes_that_cross_steeply_do_not_zip(taper):
    """A road lane passing over another of the same general direction at a steep angle (Town04's
    bridges: 89.5 deg, which zipped and stopped traffic under the bridge) is no converging lane;
    the same lanes at the taper's 3.3 deg are."""
    from feat2map.envs.network import converging_pairs

    m = native.load(taper)
    ln = m.lanes["R2_1"]
    x = np.linspace(30.0, 60.0, 16)
    steep = np.stack([x, -1.75 + 1.2 * (x - 45.0)], 1)  # 50 deg to R2_0, crossing it at x = 45
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731
    crossing = dataclasses.replace(ln, centerline=tup(steep), left_boundary=tup(steep + (0.0, 1.75)),
                                   right_boundary=tup(steep - (0.0, 1.75)), bezier=None)
    assert converging_pairs(m) == [("R2_0", "R2_1")]
    assert converging_pairs(dataclasses.replace(m, lanes={**m.lanes, "R2_1": crossing})) == []


@pytest.mark.parametrize("t_spawn, s0, speed", [(8.0, 0.0, 10.0), (8.0, 0.0, 14.0), (8.0, 5.0, 10.0), (7.0, 0.0, 14.0)])
def test_car_beside_the_ego_in_a_taper_merge_zips(taper, t_spawn, s0, speed):
    """The ego goes straight west -> east into the tapering lane R2_1 and a car drives R2_0 beside
    or just behind it: they zip, nobody collides (the car drove into the ego where the lanes came
    closer than a car width: road lanes had no merge rule)."""
    outcome, *_ = _drive(taper, (("J0", "R0", "R2"),), [(t_spawn, ["R2_0"], 60.0 - s0, speed)], duration=40.0,
                         config={"goal_distance": 100.0})
    assert outcome == "completed"


# ---- a traffic route that would end on a short road between junctions ----------------------------

def test_traffic_route_never_ends_on_a_short_road_between_junctions(monkeypatch):
    """Traffic walks through up to its number of junctions, and on through the next where the
    road after the last is shorter than TRAFFIC_END_ROOM_M (Town07's 0.7 m road between junctions
    515 and 703: a car whose route ended there drove on past its end, blind to the ego in 703,
    and rear-ended it). Here the 50 m road between J0 and J1 counts as short."""
    from feat2map.envs import routes

    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)
    m = feat2map.generate_from_features([four, four], seed=0)
    net = MapNetwork.from_map(m)
    link = [ln.id for ln in m.lanes.values() if ln.junction_id is None
            and any(m.lanes[p].junction_id == "J0" for p in ln.predecessors)
            and any(m.lanes[s].junction_id == "J1" for s in ln.successors)]
    assert link
    monkeypatch.setattr(routes, "TRAFFIC_END_ROOM_M", max(net.lane_of[x].length for x in link) + 1.0, raising=False)
    starts = [ln.id for ln in m.lanes.values() if ln.junction_id is None
              and any(m.lanes[s].junction_id == "J0" for s in ln.successors)]
    rng = np.random.default_rng(0)
    ends = set()
    for _ in range(200):
        path = routes.random_walk(net, rng, starts[int(rng.integers(len(starts)))], 1)
        ends.add(path[-1])
        assert path[-1] not in link
    assert any(m.lanes[x].junction_id == "J1" for x in {p for x in ends for p in m.lanes[x].predecessors})


# ---- lanes after a junction entry: chained junction lanes, junction lanes across road lanes --------

_LINK_FIELDS = ("predecessors", "successors", "left_neighbors", "right_neighbors", "left_reverse_neighbors")


def _along(ln, pts, **changes):
    """Lane `ln` redrawn along the points `pts` (boundaries half its width either side)."""
    pts = np.asarray(pts, dtype=float)
    d = np.gradient(pts, axis=0)
    d /= np.hypot(*d.T)[:, None]
    n = np.stack([-d[:, 1], d[:, 0]], 1) * ln.width / 2
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731
    return dataclasses.replace(ln, centerline=tup(pts), left_boundary=tup(pts + n), right_boundary=tup(pts - n),
                               bezier=None, **changes)


def _drive_lanes(path: Path, lanes: list[str], car: list[str], t_spawn: float, back: float, speed: float,
                 duration: float = 40.0) -> str:
    """Drive the ego with the baseline planner along the lane route `lanes` while a car spawned
    at `t_spawn`, `back` metres before the end of its first lane, drives `car`."""
    sc = Scenario("fixture", str(path), (), seed=0, duration=duration)
    env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False, "route": {"lanes": lanes},
                               "goal_distance": 60.0})
    obs, info = env.reset(seed=0)
    u = env.unwrapped
    planner = BaselinePlanner()
    planner.reset(env)
    f = u.config["policy_frequency"]
    try:
        for k in range(int(duration * f)):
            if k == int(t_spawn * f):
                u.road.spawn(car[0], u.net.lane_of[car[0]].length - back, speed, list(car))
            obs, _, term, trunc, info = env.step(planner.act(obs, info))
            if info["collision"]:
                return "collision"
            if term or trunc:
                return "completed" if u.route_completed() else "timeout"
        return "timeout"
    finally:
        env.close()


def _two_lane_four_way():
    return feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False, lanes=2)],
                                           seed=0)


@pytest.fixture(scope="module")
def runs_out(tmp_path_factory) -> Path:
    """The bare two-lane 4-way whose straight lane west -> east (J0_c3_0) runs on out of the
    junction to the map's edge (it takes the place of R2_0), while the exit lane beside it (R2_1,
    entered by the right turn J0_c6_0 from the south) swings across it 10-20 m past the junction
    (USA_Lanker's 35.5 m junction lane 41_0_-1 across the road lane 47_0_-1)."""
    m = _two_lane_four_way()
    lanes = {k: v for k, v in m.lanes.items() if k != "R2_0"}
    x = np.linspace(-19.5, 48.5, 35)
    lanes["J0_c3_0"] = _along(m.lanes["J0_c3_0"], np.stack([x, np.full_like(x, -1.75)], 1))
    t = np.linspace(0.0, 1.0, 12)
    swing = [(19.5 + u, -5.25) for u in np.linspace(0.0, 8.5, 6)] + \
        [(28.0 + 12.0 * u, -5.25 + 7.0 * (3 - 2 * u) * u * u) for u in t[1:]] + [(40.0 + u, 1.75) for u in (3.0, 8.5)]
    lanes["R2_1"] = _along(m.lanes["R2_1"], swing)
    lanes = {k: dataclasses.replace(v, **{f: tuple(x for x in getattr(v, f) if x != "R2_0") for f in _LINK_FIELDS})
             for k, v in lanes.items()}
    roads = {**m.roads, "R2": dataclasses.replace(m.roads["R2"], right_lanes=("R2_1",))}
    path = tmp_path_factory.mktemp("runs_out") / "runs_out.json"
    native.save(dataclasses.replace(m, lanes=lanes, roads=roads), path)
    return path


def test_a_junction_lane_across_a_road_lane_conflicts(runs_out):
    """The crossing is a conflict both ways (`network.road_crossings`); road lanes that meet
    their junction lanes at their ends cross none of them."""
    from feat2map.envs.network import road_crossings

    m = native.load(runs_out)
    net = MapNetwork.from_map(m)
    assert "R2_1" in net.conflicts["J0_c3_0"] and net.conflicts["R2_1"] == frozenset({"J0_c3_0"})
    assert all(m.lanes[k].junction_id is not None for k in net.conflicts if k != "R2_1")
    jl = [ln for ln in m.lanes.values() if ln.junction_id is not None]
    from shapely.geometry import LineString

    from feat2map.envs.network import _road_lanes
    assert road_crossings(jl, [LineString(ln.centerline) for ln in jl], _road_lanes(m)) == [("J0_c3_0", "R2_1")]


@pytest.mark.parametrize("t_spawn, back", [(4.0, 10.0), (4.0, 20.0), (3.5, 10.0)])
def test_right_turn_into_a_road_lane_across_the_egos_path_waits(runs_out, t_spawn, back):
    """The ego drives J0_c3_0 west -> east out of the junction while a car turns right from the
    south into R2_1, which crosses the ego's lane past the junction: the car's entry claims R2_1
    with its junction lane, nobody collides (the car crossed into the ego: no conflict between a
    junction lane and a road lane was registered)."""
    car = ["R1_3", "J0_c6_0", "R2_1"]
    assert _drive_lanes(runs_out, ["R0_2", "J0_c3_0"], car, t_spawn, back, 10.0) == "completed"


@pytest.fixture(scope="module")
def chained(tmp_path_factory) -> Path:
    """The bare two-lane 4-way whose left turn north -> east (J0_c22_0) is drawn as two junction
    lanes in a row (J0_c22_0 -> J0_c22_0b, on two connecting roads of J0: USA_Lanker's
    26_0_-5 -> 53_0_-3 in junction 1); only the second crosses the straight lane west -> east."""
    m = _two_lane_four_way()
    ln = m.lanes["J0_c22_0"]
    k = int(np.nonzero(ln.points[:, 1] < 5.0)[0][0])
    lanes, roads = dict(m.lanes), dict(m.roads)
    lanes["J0_c22_0"] = _along(ln, ln.points[:k + 1], successors=("J0_c22_0b",))
    lanes["J0_c22_0b"] = _along(ln, ln.points[k:], id="J0_c22_0b", road_id="J0_c22b", predecessors=("J0_c22_0",))
    lanes["R2_1"] = dataclasses.replace(m.lanes["R2_1"], predecessors=tuple(
        "J0_c22_0b" if x == "J0_c22_0" else x for x in m.lanes["R2_1"].predecessors))
    roads["J0_c22b"] = dataclasses.replace(m.roads["J0_c22"], id="J0_c22b", right_lanes=("J0_c22_0b",), reference=None)
    path = tmp_path_factory.mktemp("chained") / "chained.json"
    native.save(dataclasses.replace(m, lanes=lanes, roads=roads), path)
    return path


def test_chained_junction_lanes_are_entered_together(chained):
    """Entering J0 on the first lane of the chain is entering both (`junction_chain`)."""
    from types import SimpleNamespace

    from feat2map.envs.rules import TrafficRules

    net = MapNetwork.from_map(native.load(chained))
    assert "J0_c3_0" not in net.conflicts["J0_c22_0"] and "J0_c3_0" in net.conflicts["J0_c22_0b"]
    rules = TrafficRules()
    rules.net = net
    car = SimpleNamespace(lane_route=["R3_2", "J0_c22_0", "J0_c22_0b", "R2_1"], route_pos=0)
    assert rules.junction_chain(car, "J0_c22_0") == ("J0_c22_0", "J0_c22_0b")


@pytest.mark.parametrize("t_spawn, back", [(1.5, 20.0), (1.5, 30.0), (2.0, 20.0), (2.5, 10.0), (3.0, 10.0)])
def test_a_car_on_chained_junction_lanes_yields_to_the_ego(chained, t_spawn, back):
    """The ego goes straight west -> east while a car turns left north -> east on the chained
    lanes: nobody collides (the car checked only its first lane's conflicts and crossed the
    ego's reserved path on the second)."""
    car = ["R3_2", "J0_c22_0", "J0_c22_0b", "R2_1"]
    assert _drive_lanes(chained, ["R0_2", "J0_c3_0", "R2_0"], car, t_spawn, back, 10.0) == "completed"


# ---- a lane drawn with a cusp -------------------------------------------------------------------

def test_a_lane_folding_back_at_a_cusp_loses_the_fold():
    """The inner lane of a curve tighter than its offset from the reference line is drawn with a
    cusp: north, back 0.4 m, then east (Issue295a's 995_0_-1 at its apex). The env's lane drops
    the fold (the ego tracking it lost the lane there and drove straight on), keeping the ends; a
    turn drawn with long segments is kept as drawn."""
    from feat2map.envs.lanes import PolylineLane

    cusp = [(0.0, 0.0), (0.0, 4.0), (0.0, 5.0), (0.02, 5.1), (-0.3, 4.9), (0.6, 4.8), (3.0, 4.4), (8.0, 3.6)]
    lane = PolylineLane(np.array(cusp), 3.5, lane_id="cusp")
    turn = np.cos(np.diff(lane.seg_heading))
    assert np.all(turn > -0.5)
    assert tuple(lane.points[0]) == cusp[0] and tuple(lane.points[-1]) == cusp[-1]
    s = [lane.local_coordinates(np.array(p))[0] for p in lane.points]
    assert np.all(np.diff(s) > 0)
    hairpin = [(0.0, 0.0), (0.0, 10.0), (3.0, 0.0)]
    assert len(PolylineLane(np.array(hairpin), 3.5, lane_id="hairpin").points) == 3
