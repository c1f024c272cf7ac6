"""The traffic rules as the rules word them, for one road user, read from a slot's lane buckets
and queue lists: the specifications the rules' one array program each is held to
(tests/envs/test_entries.py, tests/envs/test_passages.py, tests/envs/test_pedestrians.py,
tests/envs/test_mobil.py, tests/envs/test_judge.py), and the DriverView observation as it words
its features (tests/envs/test_driver_view.py)."""
from __future__ import annotations

import math
from collections import Counter

import numpy as np

from feat2map.config import (DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS, DRIVER_VIEW_CONFLICT_TIME_S, DRIVER_VIEW_LEADER_SCALE_M,
                             DRIVER_VIEW_LINE_FAR_M, DRIVER_VIEW_LINE_NEAR_M, DRIVER_VIEW_PEDESTRIAN_SCALE_M,
                             DRIVER_VIEW_QUEUE_SCALE, DRIVER_VIEW_SIGNAL_SCALE_S, DRIVER_VIEW_SPEED_SCALE_MPS, MOBIL_DETOUR_M,
                             MOBIL_MIN_GAP_M, OFF_ROAD_END_M, OFF_ROAD_LATERAL_M,
                             PEDESTRIAN_CORRIDOR_M, PEDESTRIAN_YIELD_SPEED_MPS, PRIORITY_HORIZON_S, PRIORITY_MARGIN_M)
from feat2map.envs import task
from feat2map.envs.driver_view import DRIVER_VIEW_FEATURES, _queue_ahead, conflicts_asked
from feat2map.envs.rules import (enters_next, has_stopped, idm, in_stop_zone, manoeuvre_name, may_change_lane,
                                 mobil_accepts, mobil_safe, on_yield_stretch, pedestrian_in_path)
from feat2map.envs.vehicles import RouteFollower
from feat2map.invariants import lane_changes

CROSS_MARGIN_M = 2.5  # a margin other than PRIORITY_MARGIN_M for the cross-traffic test


def clear_as_worded(ctl, lane: str, vehicle, priority: bool = True, margin: float = PRIORITY_MARGIN_M,
                    why: Counter | None = None) -> bool:
    """The conflict rule: junction lane `lane` is clear for `vehicle` (None: nobody) while no
    lane conflicting with it is occupied (a road user on it other than `vehicle`) or reserved by
    another, and no road user other than `vehicle` heading into a conflicting lane of higher
    priority next (its next two route lanes) from an approach that may go (no stop sign, no red)
    reaches the end of its lane within PRIORITY_HORIZON_S at its speed plus `margin`, unless it
    waits for a narrow passage `vehicle` holds. With `priority` False (`cross_traffic_near`),
    every conflicting lane and every approach count. `why` counts what decided each refusal,
    and the passage waiters passed over."""
    net = ctl.net
    why = Counter() if why is None else why
    mine = net.lane_of[lane].priority
    for c in net.conflicts.get(lane, ()):
        holder = ctl.reservations.get(c)
        if holder is not None and holder is not vehicle:
            why["reserved"] += 1
            return False
        if any(v is not vehicle for v in ctl.buckets.get(c, ())):
            why["occupied"] += 1
            return False
        if priority and net.lane_of[c].priority <= mine:
            continue
        for p in net.hdmap.lanes[c].predecessors:
            approach = net.lane_of.get(p)
            if approach is None or priority and ctl._held(p):
                continue
            for v in ctl.buckets.get(p, ()):
                if v is vehicle or not enters_next(v, c):
                    continue
                if approach.length - v.s_on(p) >= PRIORITY_HORIZON_S * max(v.speed, 0.0) + margin:
                    continue
                if ctl.waits_for(v, vehicle):
                    why["passage waiter"] += 1
                    continue
                why["coming"] += 1
                why["coming, added by user code"] += getattr(v, "_core", None) is None
                return False
    return True


def first_come_first_served(ctl, vehicle, j_lane: str) -> bool:
    """Stop-sign order as the rules word it, for one road user, from the slot's queue as lists:
    it is queued at the junction of `j_lane`, and no earlier road user in the queue (other than
    one waiting for a narrow passage) drives into a lane conflicting with `j_lane` (its lane in
    the junction: the first on its route from the lane before its route position on; unknown
    holds) that the box rule lets it take."""
    net = ctl.net
    jid = net.hdmap.lanes[j_lane].junction_id
    queue = ctl.stop_queue.get(jid, [])
    if vehicle not in queue:
        return False
    for other in queue[:queue.index(vehicle)]:
        if any(other in ctl.passage_state(ps.group)[1] for ps in net.passages.values()):
            continue
        route = other.lane_route
        lane = next((x for x in route[max(other.route_pos - 1, 0):] if net.hdmap.lanes[x].junction_id == jid), None)
        if lane is None or lane in net.conflicts.get(j_lane, ()) and ctl.box_clear(other, lane):
            return False
    return True


def yield_as_worded(ctl, lane_id: str, s_from: float) -> float | None:
    """The pedestrian yield rule: on `lane_id`, a road user stops a metre before a crosswalk
    across it that begins beyond `s_from` (half a metre behind counts) where a pedestrian on it,
    within 2 m of the crossing along the lane, is in the lane's path or walks towards the lane
    within PEDESTRIAN_CORRIDOR_M of its edge (the nearest such crosswalk; None: none)."""
    lane = ctl.net.lane_of[lane_id]
    best = None
    for cw, s0, s1 in ctl.net.crossings.get(lane_id, ()):
        if s0 < s_from - 0.5:
            continue
        for p in ctl.pedestrians.get(cw, ()):
            sp, rp = lane.local_coordinates(p.position)
            if not s0 - 2.0 <= sp <= s1 + 2.0:
                continue
            h = lane.heading_at(sp)
            towards = rp * (p.direction[0] * -math.sin(h) + p.direction[1] * math.cos(h)) < 0
            if pedestrian_in_path(rp, lane.width) or (towards and abs(rp) < lane.width / 2 + PEDESTRIAN_CORRIDOR_M):
                best = s0 - 1.0 if best is None else min(best, s0 - 1.0)
    return best


def junction_lanes_ahead(net, vehicle) -> list[str]:
    """The junction lanes on a road user's route from the lane before its route position on."""
    route = getattr(vehicle, "lane_route", None) or []
    lanes = net.hdmap.lanes
    return [x for x in route[max(vehicle.route_pos - 1, 0):] if x in lanes and lanes[x].junction_id is not None]


def check_conflict_questions(core, rng: np.random.Generator, why: Counter) -> None:
    """Every road user of every slot (and nobody), asked `TrafficCore.lanes_clear` about each
    junction lane ahead on its route and two others, with priority and as cross traffic: the
    answers are `clear_as_worded`'s; one question about several lanes is clear when each is, and
    every slot's questions asked at once (`entries.junction_clear`) answer the same."""
    from feat2map.envs.reservations import NONE
    from feat2map.envs.sim import entries

    net = core.net
    every = [x for x in net.lane_ids if net.hdmap.lanes[x].junction_id is not None]
    batch = []
    for slot in range(len(core.roads)):
        ctl = core.roads[slot].control
        rows = core.slot_rows(slot).tolist()
        for i, v in zip(rows + [NONE], [core.objs[i] for i in rows] + [None]):
            lanes = (junction_lanes_ahead(net, v) if v is not None else []) + list(rng.choice(every, 2))
            for lane in lanes:
                for priority, margin in ((True, PRIORITY_MARGIN_M), (False, CROSS_MARGIN_M)):
                    want = clear_as_worded(ctl, lane, v, priority, margin, why)
                    got = bool(core.lanes_clear(slot, v, [lane], priority, margin)[0])
                    assert got == want, (slot, lane, v, priority)
                    why["clear" if want else "refused"] += 1
                    if priority:
                        batch.append((slot, i, core.table.index[lane], want))
            if lanes:
                assert bool(core.lanes_clear(slot, v, lanes).all()) == all(clear_as_worded(ctl, x, v) for x in lanes)
    why["off its route lane"] += int((core.controlled & (core.where_lanes() != core.lane)).sum())
    slots, me, j, want = (np.array(x) for x in zip(*batch))
    got = entries.junction_clear(core, slots, me, j)
    assert got.tolist() == want.tolist()


def mobil_as_worded(ctl, car, gaps: list[tuple[float, float]]) -> tuple[str, tuple[str, ...]] | None:
    """MOBIL for one car, from its road's lane buckets: the first same-direction neighbour across
    a dashed line (in `lane_changes` order) that runs beside it and has a route to the
    destination road at most MOBIL_DETOUR_M longer than its own, where its IDM acceleration behind
    every road user ahead on it (none closer than MOBIL_MIN_GAP_M) beats that behind its own
    leaders `gaps` ((bumper gap, speed) pairs) by MOBIL_GAIN_MPS2 plus MOBIL_POLITENESS times the
    new follower's loss, the new follower (the nearest behind, MOBIL_MIN_GAP_M away, a route
    follower) braking no harder than MOBIL_SAFE_BRAKE_MPS2: (that lane, its route), else None;
    nothing when the car may not change lanes here (in a junction, near its lane's end, slow)."""
    net, m = ctl.net, ctl.net.hdmap
    lid = car.lane_route[car.route_pos]
    ln, lane = m.lanes[lid], net.lane_of[lid]
    s, _ = lane.local_coordinates(car.position)
    if not may_change_lane(ln.junction_id is not None, lane.length - s, car.speed):
        return None
    limit = sum(net.lane_of[x].length for x in car.lane_route[car.route_pos:]) + MOBIL_DETOUR_M
    a_cur = idm(car, gaps)
    goal = m.lanes[car.lane_route[-1]]
    for n in lane_changes(ln):
        if n not in m.lanes:
            continue
        paths = [f[0] for g in (goal.id,) + goal.left_neighbors + goal.right_neighbors
                 if g in m.lanes and (f := net.lane_route_within(n, g, limit))]
        nl = net.lane_of[n]
        sn, _ = nl.local_coordinates(car.position)
        if not paths or not 0.0 <= sn <= nl.length:
            continue
        ahead, behind = [], None
        for o in ctl.buckets.get(n, ()):
            so, _ = nl.local_coordinates(o.position)
            if so >= sn:
                ahead.append((so - sn - car.LENGTH, float(o.speed)))
            elif behind is None or so > behind[0]:
                behind = (so, o)
        if any(g < MOBIL_MIN_GAP_M for g, _ in ahead):
            continue
        loss = 0.0
        if behind is not None:
            so, f = behind
            gap = sn - so - car.LENGTH
            if gap < MOBIL_MIN_GAP_M or not isinstance(f, RouteFollower):
                continue
            a_f = idm(f, [(gap, car.speed)])
            if not mobil_safe(a_f):
                continue
            loss = max(0.0, idm(f, []) - a_f)
        if mobil_accepts(a_cur, idm(car, ahead), loss):
            return n, min(paths, key=len)
    return None


class JudgeAsWorded:
    """A controlled road user's judge as the judge words it, checked after every frame, its
    verdicts and what it keeps in Python (`counts`, `off_road`, and sets of lane ids): the
    specification `sim.judge` is held to (tests/envs/test_judge.py). red_light: a signal's line
    crossed into the junction on red (a right turn on red after a full stop allowed where the
    config allows it) or a mid-block crossing's line crossed on red; stop_sign: entered without a
    full stop within the stop zone; pedestrian_yield: moving on a crosswalk's stretch with a
    pedestrian in its path; with `agent`, entering the junction lane the verdict noted before
    it (`multi_agent.AgentJudge.note`: the core's `v_*` of its row, read before the env's judge
    uses them) against that verdict."""

    def __init__(self, rules, ego, arrives: bool = False, agent: bool = False) -> None:
        self.rules, self.ego, self.arrives, self.agent = rules, ego, arrives, agent
        self.done = False
        self.counts: Counter = Counter()
        self.off_road = False
        self.lane = rules.net.id_of.get(ego.lane_index)
        self.lane_s = ego.lane_s
        self.stopped: set[str] = set()  # incoming lanes whose line it has stopped at
        self.crossed: set[str] = set()
        self.crossed_mid: set[tuple[str, str]] = set()  # (light, lane) of mid-block lines crossed on red
        self.ped_flags: set[tuple[str, str]] = set()

    def check(self) -> None:
        core = self.rules.road.core
        if self.done or (self.arrives and bool(task.completed(core, self.ego.row))):
            self.done = True
            return
        rules, ego = self.rules, self.ego
        net, m = rules.net, rules.net.hdmap
        lid = net.id_of[ego.lane_index]
        prev = self.lane
        reds = self.counts["red_light"]
        on_road = lid in m.lanes and m.lanes[lid].junction_id is None
        rtor = rules.right_turn_on_red()
        if has_stopped(ego.speed):
            sl, in_lane = rules.waiting_line(ego, lid)
            if sl is not None and in_lane is not None and (sl.kind == "stop" or rtor):
                self.stopped.add(in_lane)
        if on_road:  # stops and line crossings count until it is on another road lane
            if self.stopped - {lid}:
                self.stopped &= {lid, rules.line_ahead(ego)[1]}
            self.crossed &= {lid}
        if lid != prev and prev is not None and m.lanes[lid].junction_id is not None:
            entry = self._entry_lane(prev, lid)
            if entry not in self.crossed:  # flickering across the line is one crossing
                if m.lanes[entry].junction_id is None:
                    self.crossed.add(entry)
                psl = net.stop_lines.get(entry)
                if psl is not None and psl.kind == "signal" and rules.signal_state(psl.control_id) == "red" \
                        and not (rtor and entry in self.stopped and self._turn_after(entry) == "right"):
                    self.counts["red_light"] += 1
                if psl is not None and psl.kind == "stop" and entry not in self.stopped:
                    self.counts["stop_sign"] += 1
        s_before = self.lane_s if lid == prev else -math.inf
        for sid, s_line in net.midblock_lines.get(lid, ()):
            if s_before < s_line <= ego.lane_s and (sid, lid) not in self.crossed_mid \
                    and rules.signal_state(sid) == "red":
                self.crossed_mid.add((sid, lid))
                self.counts["red_light"] += 1
        self.lane, self.lane_s = lid, ego.lane_s
        due = [(k, cw) for k, (cw, s0, s1) in enumerate(net.crossings.get(lid, ()))
               if on_yield_stretch(ego.lane_s, s0, s1) and ego.speed > PEDESTRIAN_YIELD_SPEED_MPS
               and (lid, cw) not in self.ped_flags]
        if due:
            which, sp, rp = core.walkers_across(rules.road.slot, lid)
            near = pedestrian_in_path(rp, net.lane_of[lid].width) & (np.abs(sp - ego.lane_s) < ego.LENGTH)
            for k, cw in due:
                if (near & (which == k)).any():
                    self.ped_flags.add((lid, cw))
                    self.counts["pedestrian_yield"] += 1
        lane = net.get_lane(ego.lane_index)
        if abs(ego.lane_lat) > lane.width / 2 + OFF_ROAD_LATERAL_M or \
                ego.lane_s > lane.length + OFF_ROAD_END_M and not m.lanes[lid].successors:
            self.off_road = True
        if self.agent and lid != prev and m.lanes[lid].junction_id is not None and \
                (prev is None or m.lanes[prev].junction_id is None):
            i = ego.row  # the verdict noted for the lane it enters now, from a road lane
            noted = core.v_lane[i] >= 0 and net.lane_ids[core.v_lane[i]] == lid
            if noted and self.counts["red_light"] == reds:
                if not core.v_order[i]:
                    self.counts["stop_order"] += 1
                elif not core.v_clear[i]:
                    self.counts["not_yielding"] += 1

    def _entry_lane(self, prev: str, junction_lane: str) -> str:
        """The road lane it entered `junction_lane` from: its route lane before it, else `prev`."""
        route, pos = self.ego.lane_route, self.ego.route_pos
        m = self.rules.net.hdmap
        for k in range(min(pos + 1, len(route) - 1), 0, -1):
            if route[k] == junction_lane:
                before = route[k - 1]
                return before if m.lanes[before].junction_id is None else prev
        return prev

    def _turn_after(self, lane_id: str) -> str | None:
        """The turn of its route lane after `lane_id`: the latest occurrence at or before it."""
        route, pos = self.ego.lane_route, self.ego.route_pos
        k = next((i + 1 for i in range(min(pos, len(route) - 1), -1, -1) if route[i] == lane_id), len(route))
        return self.rules.net.hdmap.lanes[route[k]].turn if k < len(route) else None


# ---- the DriverView observation ---------------------------------------------------------------
_IGNORE_BUT_PEDESTRIANS = frozenset({"signal", "stop", "conflict", "passage"})
CONFLICT_FEATURES = ("conflict_occupied", "priority_time", "priority_distance", "priority_speed", "other_time",
                     "other_distance", "other_speed")


def _scaled_as_worded(value: float, scale: float) -> float:
    return min(max(value / scale, 0.0), 1.0)


def _next_junction_lane(ego) -> tuple[int, str | None]:
    """(route index, lane id) of the junction lane the ego is on or will enter next ((-1, None)
    past the route's last junction)."""
    lanes = ego.net.hdmap.lanes
    for k in range(ego.route_pos, len(ego.lane_route)):
        if lanes[ego.lane_route[k]].junction_id is not None:
            return k, ego.lane_route[k]
    return -1, None


def driver_view_as_worded(env) -> np.ndarray:
    """DRIVER_VIEW_FEATURES of `env`'s ego (a MapEnv, unwrapped, or an agent's view) as the
    observation words them, asked of the rules one question at a time (`driver_view.driver_views`
    is held to it)."""
    ego, rules = env.vehicle, env.rules
    net = rules.net
    m = net.hdmap
    out = dict.fromkeys(DRIVER_VIEW_FEATURES, 0.0)
    out["speed"] = _scaled_as_worded(ego.speed, DRIVER_VIEW_SPEED_SCALE_MPS)
    for key in ("line_near", "line_far", "line_time", "priority_time", "priority_distance", "other_time", "other_distance",
                "pedestrian", "leader_gap"):
        out[key] = 1.0
    k, j_lane = _next_junction_lane(ego)
    if j_lane is not None:
        in_junction = k == ego.route_pos
        in_lane = ego.lane_route[k - 1] if k > 0 else None
        sl = rules.control_at(in_lane)
        d = 0.0 if in_junction else max(rules.line_distance(ego, j_lane), 0.0)
        out.update(line_near=_scaled_as_worded(d, DRIVER_VIEW_LINE_NEAR_M), line_far=_scaled_as_worded(d, DRIVER_VIEW_LINE_FAR_M),
                   line_time=_scaled_as_worded(d / max(ego.speed, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS),
                                               DRIVER_VIEW_CONFLICT_TIME_S),
                   in_stop_zone=float(not in_junction and in_stop_zone(d)), in_junction=float(in_junction))
        out["signal" if sl is not None and sl.kind == "signal" else "stop" if sl is not None else "bare"] = 1.0
        turn = manoeuvre_name(m.lanes[j_lane], net.ramp_moves)
        if turn in out:  # a U-turn has no feature of its own
            out[turn] = 1.0
        if sl is not None and sl.kind == "signal":
            out[rules.signal_state(sl.control_id)] = 1.0
            if sl.control_id in rules.plans:
                out["signal_change"] = _scaled_as_worded(rules.signal_change(sl.control_id), DRIVER_VIEW_SIGNAL_SCALE_S)
            out["protected"] = float(rules.protected(in_lane, j_lane))
        if sl is not None and sl.kind == "stop" and not in_junction:
            out["stop_made"] = float(env.judge.stopped_before(in_lane))
            out["queue_ahead"] = _scaled_as_worded(_queue_ahead(rules, ego, j_lane), DRIVER_VIEW_QUEUE_SCALE)
        row = np.array([out[f] for f in DRIVER_VIEW_FEATURES])
        conflicts_asked(rules, ego, j_lane, row)  # (the rules' occupancy and traffic towards each lane)
        out.update({f: float(x) for f, x in zip(DRIVER_VIEW_FEATURES, row) if f in CONFLICT_FEATURES})
    ped = rules.stop_distance(ego, ignore=_IGNORE_BUT_PEDESTRIANS)
    if ped < math.inf:
        out["pedestrian"] = _scaled_as_worded(ped, DRIVER_VIEW_PEDESTRIAN_SCALE_M)
    gaps = ego.leader_gaps()
    if gaps:
        gap, speed = min(gaps)
        out.update(leader_gap=_scaled_as_worded(gap, DRIVER_VIEW_LEADER_SCALE_M),
                   leader_speed=_scaled_as_worded(speed, DRIVER_VIEW_SPEED_SCALE_MPS))
    return np.asarray([out[f] for f in DRIVER_VIEW_FEATURES], dtype=np.float32)
