"""The `DriverView` observation: what a driver perceives of the traffic rules and the traffic
that matters for the next junction of the route, as one flat vector in [0, 1].

Not the answer ("you may go now") but its ingredients, each from the rules module
(`env.unwrapped.rules`, the ego's judge): the ego's speed; the distance along the route to the
next stop line (finely near the line, coarsely further out), the time to reach it, and whether
the ego is in the zone where a stop counts; the control and the ego's manoeuvre there (a turn,
or a ramp's merge or diverge); the
signal's colour, time to change and whether the movement is protected; whether the ego has made
its full stop at the stop sign ahead (the judge's own rule) and how many vehicles that arrived
before it want a conflicting lane; the junction traffic in conflict with the ego's path (a
conflicting lane occupied or reserved; time to arrival, distance and speed of the nearest
vehicle with priority over the ego's movement, and of the nearest one without); a pedestrian in
or entering the path; the leader's gap and speed. Features are DRIVER_VIEW_FEATURES, in that
order; a distance or time without anything to measure reads 1 (far)."""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Sequence

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.observation import ObservationType

from ..config import (DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS, DRIVER_VIEW_CONFLICT_DISTANCE_M, DRIVER_VIEW_CONFLICT_TIME_S,
                      DRIVER_VIEW_LEADER_SCALE_M, DRIVER_VIEW_LINE_FAR_M, DRIVER_VIEW_LINE_NEAR_M,
                      DRIVER_VIEW_PEDESTRIAN_SCALE_M, DRIVER_VIEW_QUEUE_SCALE, DRIVER_VIEW_SIGNAL_SCALE_S,
                      DRIVER_VIEW_SPEED_SCALE_MPS)
from .reservations import NONE
from .rules import PEOPLE, SIGNAL_STATES, enters_next, in_stop_zone, manoeuvre_name
from .sim import crossings, rule_scan
from .sim.entries import entry_table, expand_ranges, next_two
from .sim.stop_signs import lanes_in

DRIVER_VIEW_FEATURES = (
    # (the scales x of "/ x" below are feat2map.config's DRIVER_VIEW_* constants)
    "speed",  # ego speed / SPEED_SCALE_MPS
    "line_near", "line_far",  # distance to the next stop line (junction entry) / LINE_NEAR_M, / LINE_FAR_M
    "line_time",  # time to reach that line at the current speed / CONFLICT_TIME_S
    "in_stop_zone",  # the ego centre within STOP_ZONE_M before that line
    "in_junction",
    "signal", "stop", "bare",  # control of the junction entry ahead (or just crossed); all 0 past the junction
    "left", "straight", "right", "merge", "diverge",  # the ego's manoeuvre there (rules.manoeuvre_name)
    "green", "amber", "red", "signal_change",  # the signal's colour, time to its next change / SIGNAL_SCALE_S
    "protected",  # a signalized movement no conflicting movement can have green with
    "stop_made",  # the full stop at the stop sign ahead is made (rules.EgoJudge)
    "queue_ahead",  # vehicles stopped before the ego at the stop signs that want a conflicting lane / QUEUE_SCALE
    "conflict_occupied",  # another vehicle is in or has reserved a junction lane that conflicts with the ego's
    "priority_time", "priority_distance", "priority_speed",  # nearest vehicle with priority heading into a conflict
    "other_time", "other_distance", "other_speed",  # ... and the nearest one without priority over the ego
    "pedestrian",  # distance to where a pedestrian in or entering the path makes the ego stop / PEDESTRIAN_SCALE_M
    "leader_gap", "leader_speed",  # bumper gap / LEADER_SCALE_M and speed of the nearest road user ahead
)
ARRAY_MIN_EGOS = 4  # egos with a junction ahead: fewer ask the rules of their conflicting traffic one by one


class DriverViewObservation(ObservationType):
    """DRIVER_VIEW_FEATURES of the ego of a MapEnv (see the module docstring): `driver_views`,
    a batch of one."""

    def space(self) -> spaces.Space:
        return spaces.Box(0.0, 1.0, (len(DRIVER_VIEW_FEATURES),), dtype=np.float32)

    def observe(self) -> np.ndarray:
        return driver_views([self.env])[0]


def _scaled(value: np.ndarray, scale: float) -> np.ndarray:
    """`value / scale` clipped to [0, 1], elementwise (`_unit`'s arithmetic)."""
    return np.minimum(np.maximum(value / scale, 0.0), 1.0)


def _unit(x: float) -> float:
    """`x` clipped to [0, 1]."""
    return min(max(x, 0.0), 1.0)


@dataclass(frozen=True)
class _LaneFacts:
    """Per lane of a network (its lane ints): its priority at a junction (`PolylineLane.priority`),
    its manoeuvre's feature column (-1: none, a U-turn), and each (junction lane, conflicting
    lane) pair's place in the junction lane's conflicts (`MapNetwork.conflicts`' order) by key
    lane * lanes + conflicting lane (sorted keys, their places)."""

    priority: np.ndarray
    turn: np.ndarray
    conf_key: np.ndarray
    conf_place: np.ndarray


def _lane_facts(net: Any, core: Any) -> _LaneFacts:
    def build() -> _LaneFacts:
        et, ids, m = entry_table(net, core.table), net.lane_ids, net.hdmap
        turn = [_F.get(manoeuvre_name(m.lanes[lid], net.ramp_moves), -1) if m.lanes[lid].junction_id else -1
                for lid in ids]
        owner = np.repeat(np.arange(len(ids)), np.diff(et.conf_ptr))
        key = owner * len(ids) + et.conf_lane
        order = np.argsort(key, kind="stable")
        return _LaneFacts(np.array([net.lane_of[lid].priority for lid in ids]), np.array(turn),
                          key[order], (np.arange(len(key)) - et.conf_ptr[owner])[order])
    return net.memo(("driver view lanes",), build)


def driver_views(envs: Sequence[Any]) -> list[np.ndarray]:
    """DRIVER_VIEW_FEATURES of the ego of each of `envs` (MapEnvs, unwrapped, or the multi-agent
    env's agent views, whose egos are rows of one core), one float32 array each. What the rules
    answer for every ego is asked once for all (the conflicting traffic, the pedestrians ahead, the
    signals, the leaders); a junction's stop sign (the full stop made, the queue) is asked of the
    egos before one."""
    core = envs[0].road.core
    egos = [e.vehicle for e in envs]
    core.sync(list({id(e.road): e.road for e in envs}.values()))
    core.refresh_windows()
    net, table = core.net, core.table
    ids = net.lane_ids
    n = len(envs)
    rows = np.array([v.row for v in egos], dtype=np.int64)
    slots = core.env[rows]
    out = np.zeros((n, len(DRIVER_VIEW_FEATURES)))
    out[:, _FAR_COLUMNS] = 1.0
    facts = _lane_facts(net, core)
    # per ego, its route's next junction lane, the line before it and its control (a few list reads an ego)
    j = np.full(n, -1, dtype=np.int64)
    sig_k, sig_q, plan_q = [], [], []
    junction = table.junction
    for q, (env, r, v) in enumerate(zip(envs, rows.tolist(), core.speed[rows].tolist())):
        row = out[q]
        row[_F["speed"]] = _unit(v / DRIVER_VIEW_SPEED_SCALE_MPS)
        route, pos = core.routes[r], int(core.route_pos[r])
        k = next((x for x in range(pos, len(route)) if junction[route[x]]), -1)
        if k < 0:
            continue
        j[q] = route[k]
        in_lane = ids[route[k - 1]] if k > 0 else None
        d = 0.0
        if k != pos:
            d = max(env.rules.line_distance(egos[q], ids[route[k]]), 0.0)
            row[_F["in_stop_zone"]] = float(in_stop_zone(d))
        else:
            row[_F["in_junction"]] = 1.0
        row[_F["line_near"]] = _unit(d / DRIVER_VIEW_LINE_NEAR_M)
        row[_F["line_far"]] = _unit(d / DRIVER_VIEW_LINE_FAR_M)
        row[_F["line_time"]] = _unit(d / max(v, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS) / DRIVER_VIEW_CONFLICT_TIME_S)
        if facts.turn[route[k]] >= 0:
            row[facts.turn[route[k]]] = 1.0
        sl = net.stop_lines.get(in_lane) if in_lane else None
        row[_F["signal" if sl is not None and sl.kind == "signal" else "stop" if sl is not None else "bare"]] = 1.0
        if sl is not None and sl.kind == "signal":
            g = table.signal_index.get(sl.control_id)
            if g is None:  # (no plan: green, no change)
                row[_F["green"]] = 1.0
                row[_F["signal_change"]] = float(sl.control_id in env.rules.plans)
            else:
                sig_q.append(q)
                sig_k.append(g)
                plan_q.append(sl.control_id in env.rules.plans)
            row[_F["protected"]] = float(env.rules.protected(in_lane, ids[route[k]]))
        if sl is not None and sl.kind == "stop" and k != pos:
            row[_F["stop_made"]] = float(env.judge.stopped_before(in_lane))
            row[_F["queue_ahead"]] = _unit(_queue_ahead(env.rules, egos[q], ids[route[k]]) / DRIVER_VIEW_QUEUE_SCALE)
    has = j >= 0
    if sig_q:
        sq, sk = np.array(sig_q), np.array(sig_k)
        codes = core.signal_codes()[slots[sq], sk]
        out[sq, np.array([_F[SIGNAL_STATES[c]] for c in codes.tolist()])] = 1.0
        pq = sq[np.array(plan_q)]
        if len(pq):
            waits = core.signal_waits_of(slots[pq], sk[np.array(plan_q)])
            out[pq, _F["signal_change"]] = _scaled(waits, DRIVER_VIEW_SIGNAL_SCALE_S)
    if has.sum() >= ARRAY_MIN_EGOS:
        _conflicts(envs, core, facts, has.nonzero()[0], rows, slots, j, out)
    else:
        for q in has.nonzero()[0].tolist():
            conflicts_asked(envs[q].rules, egos[q], ids[j[q]], out[q])
    _pedestrians(envs, core, rows, slots, out)
    _leaders(core, rows, out)
    return list(out.astype(np.float32))


_F = {name: k for k, name in enumerate(DRIVER_VIEW_FEATURES)}
_FAR_COLUMNS = [_F[k] for k in ("line_near", "line_far", "line_time", "priority_time", "priority_distance", "other_time",
                                 "other_distance", "pedestrian", "leader_gap")]  # 1 (far) without anything to measure


def _queue_ahead(rules, ego, j_lane: str) -> int:
    """Vehicles that stopped at the junction's stop signs before the ego (all of the queue while
    the ego has not stopped) and want a junction lane in conflict with `j_lane` (their lane in the
    junction as the stop-sign order reads it, `sim.stop_signs.lanes_in`; none known counts)."""
    jid = rules.net.hdmap.lanes[j_lane].junction_id
    queue = rules.stop_queue.get(jid, [])
    ahead = queue[:queue.index(ego)] if ego in queue else queue
    if not ahead:
        return 0
    core = rules.road.core
    rows = np.array([core.row_of(v) for v in ahead])
    lanes = lanes_in(core, rows, np.full(len(rows), core.table.junction_number[jid]))
    conflicts, ids = rules.net.conflicts.get(j_lane, frozenset()), rules.net.lane_ids
    return sum(k < 0 or ids[k] in conflicts for k in lanes.tolist())


def conflicts_asked(rules, ego, j_lane: str, row: np.ndarray) -> None:
    """`_conflicts` of one ego, asked of its rules one question at a time (`occupied`,
    `traffic_towards`), into its row of features: what the program costs more than for a few egos."""
    net = rules.net
    mine = net.lane_of[j_lane].priority
    nearest = {"priority": (math.inf, 0.0, 0.0), "other": (math.inf, 0.0, 0.0)}
    for c in net.conflicts.get(j_lane, ()):
        if rules.occupied(c, ego):
            row[_F["conflict_occupied"]] = 1.0
        group = "priority" if net.lane_of[c].priority >= mine else "other"
        for d, v in rules.traffic_towards(c, exclude=ego):
            speed = max(float(v.speed), 0.0)
            t = max(d, 0.0) / max(speed, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS)
            if t < nearest[group][0]:
                nearest[group] = (t, max(d, 0.0), speed)
    for group, (t, d, speed) in nearest.items():
        if t < math.inf:
            row[_F[f"{group}_time"]] = _unit(t / DRIVER_VIEW_CONFLICT_TIME_S)
            row[_F[f"{group}_distance"]] = _unit(d / DRIVER_VIEW_CONFLICT_DISTANCE_M)
            row[_F[f"{group}_speed"]] = _unit(speed / DRIVER_VIEW_SPEED_SCALE_MPS)


def _conflicts(envs, core, facts: _LaneFacts, asked: np.ndarray, rows: np.ndarray, slots: np.ndarray,
               j: np.ndarray, out: np.ndarray) -> None:
    """Junction traffic in conflict with each asking ego's junction lane `j` (`asked`: the egos
    with one), one program for them all (`conflicts_asked` asks the rules of one): a conflicting
    lane occupied (a road user other than the ego located on it, or its reservation held by
    another), and the nearest road user heading into a conflicting lane (on it, or on an
    approach allowed to go and driving into it next, `rules.enters_next`, unless it waits for a
    narrow passage the ego holds) with priority over the ego's movement (its lane's priority at
    least the ego's) and without: by time to reach the lane at its speed (at least
    DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS), the first in the rules' order (the conflicting
    lanes in `MapNetwork.conflicts` order, each the road users on it, then those on each
    approach, in row order) where times tie."""
    et = entry_table(core.net, core.table)
    nl = len(core.table.length)
    me, sl, jl = rows[asked], slots[asked], j[asked]
    # who is on which lane: keys slot * lanes + lane of every located row (of the one slot asked, or
    # of all), sorted, rows in order
    one = bool((sl == sl[0]).all())
    every = core.slot_rows(int(sl[0])) if one else np.arange(len(core.objs))
    at = core.where_lanes(every)
    on = (at >= 0).nonzero()[0]
    keys = core.env[every[on]] * nl + at[on]
    order = np.argsort(keys, kind="stable")
    keys, on = keys[order], every[on[order]]
    # the questions: (ego, conflicting lane) pairs, the road users on the lane; (ego, conflicting
    # lane, approach) triples, those on an approach that may go
    q, e = expand_ranges(et.conf_ptr[jl], et.conf_ptr[jl + 1])
    c = et.conf_lane[e]
    holder = core.res[sl[q], c]
    key = sl[q] * nl + c
    lo, hi = np.searchsorted(keys, key), np.searchsorted(keys, key, side="right")
    occupied = (hi - lo > (core.where_lanes(me[q]) == c)) | ((holder != NONE) & (holder != me[q]))
    out[asked[np.unique(q[occupied])], _F["conflict_occupied"]] = 1.0
    hq, f = expand_ranges(et.cross_ptr[jl], et.cross_ptr[jl + 1])
    hc, p = et.cross_lane[f], et.cross_from[f]
    go = ~core.approach_held(sl[hq], p)
    hq, f, hc, p = hq[go], f[go], hc[go], p[go]
    ask_q = np.concatenate([q, hq])
    ask_c = np.concatenate([c, hc])  # the conflicting lane
    ask_lane = np.concatenate([c, p])  # the lane its road users are on
    ask_place = np.concatenate([e - et.conf_ptr[jl[q]],  # the rules' order: the conflicting lane's place,
                                facts.conf_place[np.searchsorted(facts.conf_key, jl[hq] * nl + hc)]])
    ask_sub = np.concatenate([np.full(len(q), -1), f - et.cross_ptr[jl[hq]]])  # then on it (-1), then each approach
    key = sl[ask_q] * nl + ask_lane
    t_k, m_k = expand_ranges(np.searchsorted(keys, key), np.searchsorted(keys, key, side="right"))
    row = on[m_k]
    keep = row != me[ask_q[t_k]]
    t_k, row = t_k[keep], row[keep]
    if not len(row):
        return
    cq, cc, lane, place, sub = ask_q[t_k], ask_c[t_k], ask_lane[t_k], ask_place[t_k], ask_sub[t_k]
    approach = sub >= 0
    dist, speed, enters = _comer_places(core, cc, row, lane, approach)
    ok = ~approach | enters
    if core.net.passages:  # one waiting for a narrow passage the ego holds comes no nearer
        for x in (ok & approach).nonzero()[0].tolist():
            env = envs[asked[cq[x]]]
            ok[x] = not env.rules.waits_for(core.objs[row[x]], env.vehicle)
    if not ok.all():
        cq, cc, row, place, sub, dist, speed = (a[ok] for a in (cq, cc, row, place, sub, dist, speed))
        if not len(row):
            return
    speed = np.maximum(speed, 0.0)
    dist = np.maximum(dist, 0.0)
    t = dist / np.maximum(speed, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS)
    other = facts.priority[cc] < facts.priority[jl[cq]]
    pick = np.lexsort((row, sub, place, t, other, cq))
    group = (cq * 2 + other)[pick]
    first = pick[np.flatnonzero(np.r_[True, group[1:] != group[:-1]])]
    for x, k, o in zip(first.tolist(), asked[cq[first]].tolist(), other[first].tolist()):
        name = "other" if o else "priority"
        out[k, _F[f"{name}_time"]] = _unit(float(t[x]) / DRIVER_VIEW_CONFLICT_TIME_S)
        out[k, _F[f"{name}_distance"]] = _unit(float(dist[x]) / DRIVER_VIEW_CONFLICT_DISTANCE_M)
        out[k, _F[f"{name}_speed"]] = _unit(float(speed[x]) / DRIVER_VIEW_SPEED_SCALE_MPS)


def _comer_places(core, cand_c, cand_row, cand_lane, approach):
    """(distance to the conflicting lane's start, speed, whether it drives into the conflicting
    lane next) of each candidate road user: on the lane `-s`, on an approach its length less `s`
    (`s` where it is on that lane: a row's on its route lane, else its object's projection), a
    driven row's next two route lanes from its window, an external road user's from its object."""
    ids, length = core.net.lane_ids, core.table.length
    s = core.s[cand_row].copy()
    speed = core.speed[cand_row].copy()
    nxt = next_two(core.W[cand_row])
    driven = core.driven[cand_row]
    enters = (nxt == cand_c[:, None]).any(axis=1) & driven
    for x in ((core.lane[cand_row] != cand_lane) | ~driven).nonzero()[0].tolist():
        o = core.objs[cand_row[x]]
        s[x] = o.s_on(ids[cand_lane[x]])
        if not driven[x]:
            speed[x] = o.speed
            enters[x] = enters_next(o, ids[cand_c[x]])
    dist = np.where(approach, length[cand_lane] - s, -s)
    return dist, speed, enters


def _pedestrians(envs, core, rows: np.ndarray, slots: np.ndarray, out: np.ndarray) -> None:
    """Where a pedestrian in or entering each ego's path makes it stop (`TrafficRules.stop_distance`
    with every other rule left out): the first crosswalk with people along its route scan
    (`sim.rule_scan`) at which `sim.crossings.blocking` holds it, one question for every such
    crosswalk of every ego at once; out of the swept paths (`clear_of_sweeps`) on a map with them."""
    sc = rule_scan.scan(core, rows)
    q, k = ((sc.what & PEOPLE) != 0).nonzero()  # (ego, window place), in route order
    if not len(q):
        return
    dist = sc.D[q, k]
    at = crossings.blocking(core, slots[q], sc.lanes[q, k], np.where(k == 0, -dist, 0.0))
    stop = dist + at
    found = np.isfinite(stop)
    q, stop = q[found], stop[found]
    q, first = np.unique(q, return_index=True)
    stop = stop[first]
    if core.net.swept:
        stop = np.array([envs[x].rules.clear_of_sweeps(envs[x].vehicle, float(v)) for x, v in zip(q.tolist(), stop.tolist())])
    out[q, _F["pedestrian"]] = _scaled(stop, DRIVER_VIEW_PEDESTRIAN_SCALE_M)


def _leaders(core, rows: np.ndarray, out: np.ndarray) -> None:
    """The nearest road user ahead of each ego (`TrafficCore.leader_gaps`: the least bumper gap,
    then the least speed) and its speed."""
    driven = core.driven[rows]
    if not driven.any():
        return
    fr, gap, speed = core.leaders_of(rows[driven])
    nearest: dict[int, tuple[float, float]] = {}
    for f, pair in zip(fr.tolist(), zip(gap.tolist(), speed.tolist())):
        if f not in nearest or pair < nearest[f]:
            nearest[f] = pair
    place = {r: q for q, r in enumerate(rows.tolist())}
    for f, (g, v) in nearest.items():
        out[place[f], _F["leader_gap"]] = _unit(g / DRIVER_VIEW_LEADER_SCALE_M)
        out[place[f], _F["leader_speed"]] = _unit(v / DRIVER_VIEW_SPEED_SCALE_MPS)
