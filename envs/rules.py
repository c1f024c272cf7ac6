"""Every traffic rule of the environments, in one place: the env's traffic, its judge of the ego
and the baseline planner (scenarios/planner.py) all ask this module.

- the IDM car-following law and MOBIL's lane-change criteria, for one vehicle and for the
  arrays core's rows at once; their constants and the rules' (what counts as a stop, how far
  ahead vehicles look, when a vehicle commits to a junction, how pedestrians are yielded to) are
  named in feat2map/config.py (env layer);
- `TrafficRules`: the questions traffic and planners ask of the traffic control state (the
  signal's state, where the rules make a vehicle stop, whether it may enter a junction lane,
  whether a turn is protected, who is heading into a conflicting lane, who may drive into a
  narrow passage, where opposite lanes are too close to pass: one direction at a time, first
  come first served, a vehicle claiming passages that follow each other together).
  The questions are pure. `control.TrafficControl` holds that state (signal plans, reservations,
  pedestrians; the stop-sign queues and the passages' holders and waiters are arrays of the
  core, `sim.stop_signs` and `sim.passages`, `stop_queue` and `passage_state` their views),
  inherits these questions and is the one place that writes it (a road user's claims, `claim`;
  the bookkeeping after a frame, `update`); `env.unwrapped.rules` is that object;
- `EgoJudge`: the ego's violations (red light, stop sign, pedestrian yield) and leaving the road.

Stop lines are measured along the route: `TrafficRules.line_ahead` gives the distance from a vehicle's
centre to the next stop line across lane boundaries, so a short last lane before the line (real
maps have 0.01-2.4 m lanes there) changes neither where a vehicle stops nor whether its stop
counts.

Vehicles are any objects with the route-follower interface (`vehicles.RouteFollower`):
`lane_route`, `route_pos`, `speed`, `LENGTH`, `reserved`, `upcoming()`, `s_on(lane)`; the ego
provides it directly, traffic through the arrays core's lightweight views. The laws the arrays
core applies to all rows at once (IDM, MOBIL's eligibility, who is in the way) are written once
here for scalars and arrays alike.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any, Callable, Iterable, Mapping, Sequence

import numpy as np

from ..config import (AMBER_BRAKE_MPS2, AMBER_CAP_MARGIN_M, AMBER_STOP_MARGIN_M, BLOCKED_NEAR_M, COMMIT_DISTANCE_M,
                      COMMIT_TIME_S, IDM_ACC, IDM_BRAKE, IDM_DELTA, IDM_GAP_M, IDM_MIN_GAP_M, IDM_RANGE_MPS2,
                      IDM_STOP_GAP_M, IDM_STOP_MARGIN_M, IDM_TIME_GAP_S, LEADER_LATERAL_M, MOBIL_GAIN_MPS2,
                      MOBIL_MIN_ROOM_M, MOBIL_MIN_SPEED_MPS, MOBIL_POLITENESS, MOBIL_SAFE_BRAKE_MPS2, OFF_ROAD_END_M,
                      OFF_ROAD_LATERAL_M, PASSAGE_HORIZON_M, PEDESTRIAN_IN_PATH_M,
                      PEDESTRIAN_YIELD_SPEED_MPS, PEDESTRIAN_YIELD_STRETCH_M, PRIORITY_HORIZON_S, PRIORITY_MARGIN_M,
                      SPAWN_BRAKE_MPS2, SPAWN_MARGIN_M, STOPPED_SPEED_MPS, STOP_POINT_M, STOP_ZONE_M)

from .sim import passages
from .sweep import clear_stop, swept_head

if TYPE_CHECKING:
    from ..model import Lane
    from .network import MapNetwork, StopLine
    from .reservations import Reservations

RULES = ("signal", "stop", "pedestrian", "conflict")  # what planners may ignore on purpose
VIOLATIONS = ("red_light", "stop_sign", "pedestrian_yield")
# every kind a judge counts: the ego's VIOLATIONS, then the two only agents are judged on
# (`multi_agent.AgentJudge`); the columns of `TrafficCore.violations` and `new_violations`
JUDGED = (*VIOLATIONS, "not_yielding", "stop_order")


def violation_names(counts: Sequence[int]) -> list[str]:
    """Violations named from their counts of each kind of JUDGED: the kinds in JUDGED order, each
    repeated by its count (what a judge's `new` and an info's "new_violations" give)."""
    return [kind for kind, n in zip(JUDGED, counts) for _ in range(n)]
SIGNAL_STATES = ("green", "amber", "red")  # the codes of the signal states' one program (`control.signal_timing`)
TURN_NAMES = {"none": "straight", "left": "left", "right": "right", "uturn": "uturn"}


def manoeuvre_name(ln: "Lane", ramps: Mapping[str, str]) -> str:
    """The manoeuvre junction lane `ln` drives: a ramp's "merge" / "diverge" (`ramps`: the map's
    `MapNetwork.ramp_moves`), else its turn's TURN_NAMES name."""
    return ramps.get(ln.id) or TURN_NAMES.get(ln.turn, ln.turn)


def idm_free(v, v0):
    """IDM's free-road term 1 - (v / v0)^delta (its acceleration without leaders is IDM_ACC times
    this); scalars or arrays."""
    return 1.0 - (v / v0) ** IDM_DELTA


def idm_behind(free, v, v_lead, gap, jam_gap):
    """IDM's acceleration behind one leader (`gap`: bumper to bumper, `jam_gap`: IDM_GAP_M
    behind a vehicle, IDM_STOP_GAP_M before a stop point) given the free term `free`; scalars or
    arrays (then elementwise, as the arrays core takes it for all (follower, leader) pairs)."""
    s_star = jam_gap + v * IDM_TIME_GAP_S + v * (v - v_lead) / (2 * math.sqrt(IDM_ACC * IDM_BRAKE))
    return IDM_ACC * (free - (_larger(s_star, 0.0) / _larger(gap, IDM_MIN_GAP_M)) ** 2)


def stop_gap(distance, length, margin: float = IDM_STOP_MARGIN_M):
    """The gap IDM keeps to a stop point `distance` ahead of a vehicle's centre: its front bumper
    halts `margin` short of it (a stop point is a standing leader)."""
    return distance - length / 2 - margin


def idm_clip(acc):
    """An IDM acceleration within IDM_RANGE_MPS2 (a float, or an array elementwise)."""
    lo, hi = IDM_RANGE_MPS2
    if isinstance(acc, np.ndarray):
        return np.minimum(np.maximum(acc, lo), hi)
    return min(max(float(acc), lo), hi)


def _larger(x, lo: float):
    return np.maximum(x, lo) if isinstance(x, np.ndarray) else max(x, lo)


def idm_accelerations(v, v0, follower, gap, v_lead, jam_gap) -> np.ndarray:
    """IDM's acceleration of each of a batch of vehicles (arrays: speed `v`, desired speed `v0`)
    behind its leaders, given as pairs (`follower` index, bumper `gap`, leader speed `v_lead`,
    `jam_gap`: IDM_GAP_M behind a road user, IDM_STOP_GAP_M before a stop point, a standing
    leader at `stop_gap`): the least over its pairs, clipped. IDM's one composition: traffic's
    rows (`TrafficCore._idm`) and one vehicle (`idm`, a batch of one)."""
    v = np.maximum(v, 0.0)
    free = idm_free(v, v0)
    acc = IDM_ACC * free
    if len(follower):
        np.minimum.at(acc, follower, idm_behind(free[follower], v[follower], v_lead, gap, jam_gap))
    return idm_clip(acc)


def idm(vehicle, gaps: Iterable[tuple[float, float]], stop_distance: float = math.inf,
        stop_margin: float = IDM_STOP_MARGIN_M) -> float:
    """IDM acceleration of one vehicle towards its lane's speed limit, behind leaders ((bumper
    gap, speed) pairs) and before a stop point (`stop_distance` from the vehicle centre; the
    front bumper halts `stop_margin` short of it): `idm_accelerations` for a batch of one."""
    net = vehicle.net
    v0 = max(net.lane_of[vehicle.lane_route[vehicle.route_pos]].speed_limit, 1.0)
    pairs = [(g, vl, IDM_GAP_M) for g, vl in gaps]
    if stop_distance < math.inf:
        pairs.append((stop_gap(stop_distance, vehicle.LENGTH, stop_margin), 0.0, IDM_STOP_GAP_M))
    gap, v_lead, jam = np.array(pairs, dtype=float).reshape(-1, 3).T
    return float(idm_accelerations(np.array([float(vehicle.speed)]), np.array([v0]),
                                   np.zeros(len(pairs), dtype=np.int64), gap, v_lead, jam)[0])


def in_the_way(s, lateral, lane_width, lane_length, length, reach=0.0):
    """Whether a road user at (s, lateral) on a lane ahead is in the way of a vehicle `length`
    long on it: its centre, less `reach` (`body_reach`: how much farther its body sticks out
    sideways than a body aligned with the lane), within LEADER_LATERAL_M beyond the lane's half
    width, and not more than a vehicle length off either end (scalars or arrays)."""
    return (abs(lateral) - reach <= lane_width / 2 + LEADER_LATERAL_M) & (s >= -length) & (s <= lane_length + length)


def body_reach(width, length, angle):
    """How much farther across a lane a `width` x `length` body reaches at `angle` to the lane
    than aligned with it: its corners lie W/2 |cos a| + L/2 |sin a| from its centre across the
    lane instead of W/2. 0 along the lane; a 4.8 x 1.9 m car reaches 0.6 m farther at 0.27 rad,
    1.3 m at 0.66 rad (scalars or arrays)."""
    return width / 2 * (np.abs(np.cos(angle)) - 1.0) + length / 2 * np.abs(np.sin(angle))


def may_change_lane(in_junction, room, speed):
    """MOBIL's eligibility: a lane change is considered only on a road lane (not in a junction),
    at least MOBIL_MIN_ROOM_M before the lane's end and at MOBIL_MIN_SPEED_MPS or faster
    (scalars or arrays)."""
    return np.logical_not(in_junction) & (room >= MOBIL_MIN_ROOM_M) & (speed >= MOBIL_MIN_SPEED_MPS)


def mobil_safe(a_follower: Any) -> Any:
    """MOBIL's safety criterion: the new follower need not brake harder than MOBIL_SAFE_BRAKE_MPS2
    (floats or arrays)."""
    return a_follower >= -MOBIL_SAFE_BRAKE_MPS2


def mobil_accepts(a_current: Any, a_new: Any, follower_loss: Any) -> Any:
    """MOBIL's incentive criterion: the own acceleration gain, less MOBIL_POLITENESS times the
    new follower's loss, exceeds MOBIL_GAIN_MPS2 (floats or arrays)."""
    return a_new - a_current - MOBIL_POLITENESS * follower_loss > MOBIL_GAIN_MPS2


def has_stopped(speed):
    """A road user at most STOPPED_SPEED_MPS fast has stopped (a full stop at a stop sign, a place
    in a stop-sign queue, an agent's wait); a float, or an array elementwise."""
    return speed <= STOPPED_SPEED_MPS


def pedestrian_in_path(lateral, lane_width):
    """A pedestrian `lateral` metres off a lane's centre is in the path of its vehicles (within
    PEDESTRIAN_IN_PATH_M beyond the lane's half width); floats or arrays (elementwise)."""
    return abs(lateral) < lane_width / 2 + PEDESTRIAN_IN_PATH_M


def on_yield_stretch(s, s0, s1):
    """A road user at `s` along a lane is on the stretch s0..s1 where it crosses a crosswalk,
    widened by PEDESTRIAN_YIELD_STRETCH_M each way (where the judge looks for a pedestrian not
    yielded to); floats or arrays (elementwise)."""
    return (s0 - PEDESTRIAN_YIELD_STRETCH_M <= s) & (s <= s1 + PEDESTRIAN_YIELD_STRETCH_M)


def stops_at_amber(distance, speed):
    """At amber a vehicle stays when it can stop before the line (else it goes through); floats
    or arrays (elementwise)."""
    return distance > speed ** 2 / (2 * AMBER_BRAKE_MPS2) + AMBER_STOP_MARGIN_M


def held_at_signal(red, amber, distance, speed):
    """The signal rule at a line `distance` ahead: red holds a vehicle, amber holds one that can
    stop (`stops_at_amber`); bools and floats, or arrays (elementwise: the batched core's rows)."""
    return red | (amber & stops_at_amber(distance, speed))


def amber_arrival_speed(distance, line_speed: float, amber_s: float):
    """The lowest speed at `distance` (float or array) before a signal's line from which a
    vehicle that goes at amber onset crosses the line before red: holding its speed, or slowing
    steadily to `line_speed` at the line (a turn's curve speed behind it) once faster than that."""
    d = np.asarray(distance, dtype=float)
    hold = d / amber_s
    return np.where(hold <= line_speed, hold, 2 * d / amber_s - line_speed)


def amber_speed_cap(distance, speed: float, line_speed: float, amber_s: float):
    """The highest speed a vehicle now at `speed` may have at `distance` (float or array) before a
    signal's line while it is green, so that an amber beginning there never finds it in the
    dilemma zone: where it would be too slow to cross before red (`amber_arrival_speed`,
    slowing to `line_speed` for the turn behind the line) it must be slow enough that
    `stops_at_amber` stops it (plus AMBER_CAP_MARGIN_M); inf where its speed crosses in time or
    where it is too near the line to stop at all.
    (The go at amber assumed the speed held to the line while a turn was slowed for behind it:
    SVL San Francisco 2019, 20 m/s on every lane, crossed 0.05-0.6 s after red.)"""
    d = np.asarray(distance, dtype=float)
    room = d - AMBER_STOP_MARGIN_M - AMBER_CAP_MARGIN_M
    stop = np.sqrt(2 * AMBER_BRAKE_MPS2 * np.maximum(room, 0.0))
    # (nearer than the stop rule's own metre and the margin no speed stops: no cap, or a car
    # creeping up to the line on green would be held there)
    return np.where((room > 0) & (speed < amber_arrival_speed(d, line_speed, amber_s)), stop, math.inf)


def in_stop_zone(distance_to_line):
    """Where a stop at a line counts (centre before the line, within STOP_ZONE_M); a float, or an
    array elementwise."""
    return (0.0 <= distance_to_line) & (distance_to_line <= STOP_ZONE_M)


def commits(distance, speed):
    """A vehicle allowed into a junction reserves its lane this close to the line: within
    COMMIT_DISTANCE_M, or COMMIT_TIME_S at its speed; floats, or arrays (elementwise: the batched
    core's rows)."""
    return (distance < COMMIT_DISTANCE_M) | (distance < COMMIT_TIME_S * speed)


def braking_distance(speed: float, length: float) -> float:
    """Distance from a vehicle's centre it needs to stop comfortably before a line."""
    return speed ** 2 / (2 * SPAWN_BRAKE_MPS2) + length / 2 + SPAWN_MARGIN_M


def can_stop_before(distance: float, speed: float, length: float) -> bool:
    """Whether a vehicle whose centre is `distance` before a line can still stop comfortably with
    its front before it (a standing vehicle can, unless its front is past the line)."""
    return distance - length / 2 >= max(speed, 0.0) ** 2 / (2 * SPAWN_BRAKE_MPS2)


def enters_junction(lanes: Mapping[str, Any], before: str, lane: str) -> bool:
    """Whether driving from lane `before` into lane `lane` (map lanes by id) is a junction entry:
    `lane` is a junction lane and `before` is not (the incoming lane, whose stop line governs it)."""
    return lanes[lane].junction_id is not None and lanes[before].junction_id is None


def crossed_lanes(net: "MapNetwork", lane_id: str) -> list[str]:
    """The junction lanes that road lane `lane_id` crosses (`network.road_crossings`: a road
    lane of another road drawn across a junction lane, as osm2xodr draws scheck-in's
    `w669252633_0_0_-1` across `j_26026265_c55_0_-1`); empty for a junction lane."""
    lanes = net.hdmap.lanes
    if lanes[lane_id].junction_id is not None:
        return []
    return [c for c in net.conflicts.get(lane_id, ()) if lanes[c].junction_id is not None]


def line_setback(net: "MapNetwork", in_lane: str) -> float:
    """How far before the end of incoming lane `in_lane` vehicles wait to enter the junction
    (`MapNetwork.setbacks`: its stop line, or at a bare entry the point clear of the junction's
    paths drawn over the approach; 0 where the entry itself is the line): a distance to a junction
    entry less this is the distance to its line."""
    return net.setbacks.get(in_lane, 0.0)


def line_plan(net: "MapNetwork", route: Sequence[str], pos: int) -> tuple:
    """The next junction entry of `route` from route position `pos`: (the lengths of the lanes
    between the current one and the entry, the entry's `line_setback`, (stop line or None,
    incoming lane, junction lane)), or (None,) when no entry is ahead; a bare entry's line is
    the junction lane's start. Found once per route position (`TrafficRules.line_ahead`)."""
    lanes, lane_of = net.hdmap.lanes, net.lane_of
    lengths: list[float] = []
    for k in range(pos + 1, len(route)):
        lid = route[k]
        if enters_junction(lanes, route[k - 1], lid):
            in_lane = route[k - 1]
            return tuple(lengths), line_setback(net, in_lane), (net.stop_lines.get(in_lane), in_lane, lid)
        lengths.append(lane_of[lid].length)
    return (None,)


def route_memo(vehicle: Any, key: Any, make: Callable[[], Any]) -> Any:
    """`make()`: a fact of `vehicle`'s route from its route position on (the next junction entry,
    a junction lane's chain, ...), worked out once per route position: the facts are held on the
    vehicle by `key` and forgotten when its route or position changes."""
    route, pos = vehicle.lane_route, vehicle.route_pos
    held = vehicle.__dict__.get("_route_memo")
    if held is None or held[0] is not route or held[1] != pos:
        held = vehicle._route_memo = (route, pos, {})
    facts = held[2]
    if key not in facts:
        facts[key] = make()
    return facts[key]


# what can stop a road user on a lane of its route (`sim.rule_scan`, bits): a road lane across a
# junction lane, a junction entry, a mid-block crossing's light, a crosswalk with people on it
CROSSED, ENTRY, MIDBLOCK, PEOPLE = 1, 2, 4, 8


def room_to_wait(room: float | np.ndarray, length: float | np.ndarray) -> bool | np.ndarray:
    """Whether `room` metres of road up to where a vehicle waits (the next junction's stop line, a
    narrow passage) hold one `length` long waiting there; else it would wait inside the junction
    or passage before (back-to-back junctions, passages). Floats or arrays (elementwise)."""
    return room >= length + STOP_POINT_M


def places_to_wait(room: float, length: float) -> int:
    """How many vehicles `length` long `room` metres of road before a narrow passage hold
    waiting there, one per length and stop margin (`room_to_wait` is whether it holds one)."""
    return int(room // (length + STOP_POINT_M))


def beyond(d: float, wait: float) -> bool:
    """Whether a junction lane starting `d` metres ahead of a vehicle's centre lies beyond its
    stop point `wait` metres ahead (a wait at the lane's line or at its edge, or before them)."""
    return d >= wait + STOP_POINT_M - 1e-6


def enters_next(vehicle, lane_id: str) -> bool:
    """Whether a road user located on the lane before `lane_id` drives into it next: its next
    route lane, or its current one when its route position has already moved on while it is
    still on the lane before (route followers move on in the last metre of a lane; missing
    them there let traffic claim a junction lane in conflict with one about to be entered)."""
    route = getattr(vehicle, "lane_route", None)
    if route is None:
        return False
    pos = vehicle.route_pos
    return lane_id in route[pos:pos + 2]


# What one road user's walk along its route takes and gives up, in route order
# (`control.TrafficControl.claim` applies it once the walk is done): ("reserve", junction lane,
# the lanes reserved with it) and ("release", junction lane, ()) on red. The walk's later stops
# read what it takes from it (`TrafficRules._holds`), as they would once applied.
Claims = list[tuple[str, str, tuple[str, ...]]]


class TrafficRules:
    """The rules' questions, answered from the traffic control state of `control.TrafficControl`
    (which inherits them): signals (`plans`, `t`), junction reservations, stop-sign queues,
    crosswalk pedestrians and the vehicles on each lane (`buckets`); `stop_queue` is a view of the
    rows (`sim.stop_signs`)."""

    net: "MapNetwork"
    t: float
    cfg: dict
    plans: dict
    road: Any  # the road whose rows hold the stop-sign queues (`MapRoad` sets it; None: none yet)
    reservations: "Reservations"  # {junction lane: holder}, a view of the core's arrays (`MapRoad` sets it)
    pedestrians: dict
    if TYPE_CHECKING:
        @property
        def buckets(self) -> dict[str, list]: ...  # the road users on each lane (`TrafficControl.buckets`)
    signals_by_junction: dict  # junction id -> its signal ids

    # (clock, signal states asked at it, junction states asked at it): `signal_state`, `signal_states`
    _states_at: tuple[float, dict[str, str], dict] = (math.nan, {}, {})
    _codes: tuple[float, Any] = (math.nan, None)  # (clock, every signal's state code at it)
    _waits: tuple[float, Any] = (math.nan, None)  # (clock, the seconds until each signal changes)

    @property
    def stop_queue(self) -> dict:
        """{junction id: the road users queued at its stop signs, first come first}: a view of the
        rows of the road these rules control (`road`; `sim.stop_signs`), empty without one."""
        road = self.road
        return road.core.stop_queues(road.slot) if road is not None else {}

    # ---- signals ----------------------------------------------------------------------
    def _states_now(self) -> tuple[float, dict[str, str], dict]:
        """The states asked at the current clock (a new clock forgets them)."""
        if self._states_at[0] != self.t:
            self._states_at = (self.t, {}, {})
        return self._states_at

    def signal_state(self, signal_id: str) -> str:
        """The state of a signal ("green" without a plan), read once per clock value from the
        states of every signal (`TrafficCore.signal_codes`, the one program of the phase plans): a
        plan's state is a function of `t` alone, and a frame's rule queries, judges and infos ask
        the same signals many times."""
        states = self._states_now()[1]
        state = states.get(signal_id)
        if state is None:
            road = self.road
            k = road.core.table.signal_index.get(signal_id)
            if k is not None and self._codes[0] != self.t:
                self._codes = (self.t, road.core.signal_codes(road.slot))
            state = states[signal_id] = "green" if k is None else SIGNAL_STATES[self._codes[1][k]]
        return state

    def signal_change(self, signal_id: str) -> float:
        """Seconds until a signal's state changes (inf without a plan): `TrafficCore.signal_waits`,
        once per clock value."""
        road = self.road
        k = road.core.table.signal_index.get(signal_id)
        if k is not None and self._waits[0] != self.t:
            self._waits = (self.t, road.core.signal_waits(road.slot))
        return math.inf if k is None else float(self._waits[1][k])

    def signal_states(self, junction_id: str | None = None) -> dict[str, str]:
        """States of one junction's signals (all signals when `junction_id` is None): a new dict,
        worked out once per clock value."""
        by_junction = self._states_now()[2]
        states = by_junction.get(junction_id)
        if states is None:
            ids = self.net.hdmap.signals if junction_id is None else self.signals_by_junction.get(junction_id, ())
            states = by_junction[junction_id] = {sid: self.signal_state(sid) for sid in ids}
        return dict(states)

    def control_at(self, in_lane: str | None) -> "StopLine | None":
        """The stop line (signal or stop sign) on an incoming lane, None at a bare entry."""
        return self.net.stop_lines.get(in_lane) if in_lane else None

    def signal_at(self, in_lane: str | None) -> str | None:
        """The state of the signal governing an incoming lane (None without a signal)."""
        sl = self.control_at(in_lane)
        return self.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None

    def protected(self, in_lane: str, junction_lane: str) -> bool:
        """A signalized movement is protected when no conflicting movement can have green with it
        (paired phases leave left turns unprotected; single phases protect every movement)."""
        net = self.net
        sl = net.stop_lines.get(in_lane)
        plan = self.plans.get(sl.control_id) if sl is not None else None
        if sl is None or plan is None:
            return False
        phase = plan.phases[plan.phase_of(sl.control_id)]
        for c in net.conflicts.get(junction_lane, ()):
            for p in net.hdmap.lanes[c].predecessors:
                other = net.stop_lines.get(p)
                if other is None or other.kind != "signal" or other.control_id in phase:
                    return False
        return True

    def right_turn_on_red(self) -> bool:
        return bool(self.cfg.get("right_turn_on_red", False))

    # ---- where a vehicle is --------------------------------------------------------------
    def line_ahead(self, vehicle, within: float = math.inf) -> tuple["StopLine | None", str | None, str | None, float]:
        """(stop line or None, incoming lane, junction lane, distance along the route from the
        vehicle's centre to the line) of a route follower's next junction entry, looking `within`
        metres ahead (beyond, or none: (None, None, None, inf)). The entry is found once per
        route position (`line_plan`, a `route_memo`); the distance is summed from the
        vehicle's place lane by lane, in `upcoming`'s order."""
        route, pos = vehicle.lane_route, vehicle.route_pos
        plan = route_memo(vehicle, "line plan", lambda: line_plan(self.net, route, pos))
        if plan[0] is None:
            return None, None, None, math.inf
        lengths, back, found = plan
        d = self.net.lane_of[route[pos]].length - vehicle.route_s()
        for length in lengths:
            d += length
        d -= back
        return (*found, d) if d <= within else (None, None, None, math.inf)

    def waiting_line(self, vehicle, lane_id: str | None) -> tuple["StopLine | None", str | None]:
        """(stop line, incoming lane) of the line a vehicle on `lane_id` stands before, its centre
        within STOP_ZONE_M of it along its route: its own lane's line, or the next line ahead from
        a lane before a short last lane or from a junction lane of the junction before (back-to-
        back junctions: Shalun's 3.5 m road from J_1 to J_14 leaves a car stopped at J_14's line
        inside J_1); (None, None) anywhere else."""
        net = self.net
        if lane_id is None or lane_id not in net.hdmap.lanes:
            return None, None
        sl = net.stop_lines.get(lane_id)
        if sl is not None and in_stop_zone(sl.s - getattr(vehicle, "lane_s", 0.0)):
            return sl, lane_id
        if not hasattr(vehicle, "lane_route"):
            return None, None
        sl, in_lane, _, d = self.line_ahead(vehicle, STOP_ZONE_M)
        return (sl, in_lane) if sl is not None and in_stop_zone(d) else (None, None)

    def line_distance(self, vehicle, junction_lane: str) -> float:
        """Distance along the vehicle's route from its centre to the stop line before
        `junction_lane` (the lane's start at a bare entry); 0 once that lane is behind."""
        net = self.net
        route = vehicle.lane_route
        for k, lid, d, s_own in vehicle.upcoming(math.inf):
            if lid == junction_lane:
                if s_own is not None:
                    return -s_own
                return d - line_setback(net, route[k - 1])
        return 0.0

    # ---- occupancy ----------------------------------------------------------------------
    def occupied(self, lane_id: str, by_other_than=None) -> bool:
        holder = self.reservations.get(lane_id)
        if holder is not None and holder is not by_other_than:
            return True
        return any(v is not by_other_than for v in self.buckets.get(lane_id, ()))

    def junction_clear(self, junction_lane: str, vehicle=None) -> bool:
        """No conflicting junction lane is occupied or reserved, and no vehicle with priority
        (straight/right over left turns) is about to enter one from an approach allowed to go."""
        return self.lanes_clear((junction_lane,), vehicle)

    def lanes_clear(self, lanes: Sequence[str], vehicle=None, priority: bool = True,
                    margin: float = PRIORITY_MARGIN_M) -> bool:
        """`junction_clear` of every junction lane of `lanes` for `vehicle` (None: nobody): the one
        program `sim.entries.junction_clear`, asked of one road user (`TrafficCore.lanes_clear`).
        With `priority` False, `cross_traffic_near`'s test with `margin`."""
        if not lanes:
            return True
        road = self.road
        return bool(road.core.lanes_clear(road.slot, vehicle, lanes, priority, margin).all())

    def box_clear(self, vehicle, junction_lane: str) -> bool:
        """Don't block the box: a vehicle whose wait at the next junction's line would leave it
        inside the junction of `junction_lane` (the road between them shorter than the vehicle
        and its stop margin: back-to-back junctions) enters only while its lane in the next
        junction is clear too; otherwise two cars, each waiting inside the junction the other
        needs, lock up (Shalun's J_5 and J_15, 2-4 m apart). A chain of such junctions is one
        box: its lanes in every junction up to the first road with room to wait must be clear
        (Town04's 1249, 870 and 483, 3.6 m and 1.5 m apart: a car waiting inside 1249 for 483
        and one waiting inside 483 for 1249 locked up)."""
        return self.lanes_clear(self.box_lanes(vehicle, junction_lane), vehicle)

    def box_lanes(self, vehicle, junction_lane: str) -> tuple[str, ...]:
        """`box_clear`'s lanes (a `route_memo` of the vehicle's)."""
        return route_memo(vehicle, ("box", junction_lane), lambda: self._box_lanes(vehicle, junction_lane))

    def _box_lanes(self, vehicle, junction_lane: str) -> tuple[str, ...]:
        """`box_clear`'s lanes after `junction_lane` on the vehicle's route: the first one in
        each junction up to the first road with room to wait."""
        net, lanes = self.net, self.net.hdmap.lanes
        route = vehicle.lane_route
        if junction_lane not in route[vehicle.route_pos:]:
            return ()
        k = route.index(junction_lane, vehicle.route_pos)
        jid = lanes[junction_lane].junction_id
        room = 0.0
        box = []
        for i in range(k + 1, len(route)):
            lane = lanes[route[i]]
            if lane.junction_id is None:
                room += net.lane_of[route[i]].length
            elif lane.junction_id != jid:
                room -= line_setback(net, route[i - 1])
                if room_to_wait(room, vehicle.LENGTH):
                    break
                box.append(route[i])
                jid, room = lane.junction_id, 0.0
        return tuple(box)

    def _held(self, approach: str) -> bool:
        """Traffic on an approach waits at its line: a stop sign or a red signal."""
        sl = self.net.stop_lines.get(approach)
        return sl is not None and (sl.kind == "stop" or self.signal_state(sl.control_id) == "red")

    def cross_traffic_near(self, vehicle, junction_lane: str, margin: float) -> bool:
        """A conflicting lane is occupied or reserved, or a vehicle (whatever its priority) is
        about to enter one: a right turn on red yields to every approach that has green."""
        return not self.lanes_clear((junction_lane,), vehicle, priority=False, margin=margin)

    def yields_to_reservation(self, other, lane_id: str) -> bool:
        """Whether road user `other`, heading into junction lane `lane_id` from the road lane
        before it, would wait if someone reserved a lane conflicting with it now: it holds no
        reservation of `lane_id` and can still stop comfortably before its line (every vehicle's
        `junction_clear` waits while a conflicting lane is occupied or reserved)."""
        net = self.net
        if self.reservations.get(lane_id) is other or not hasattr(other, "lane_route"):
            return False
        pos = other.route_pos
        route = other.lane_route
        k = route.index(lane_id, pos) if lane_id in route[pos:] else -1
        if k <= 0 or net.hdmap.lanes[route[k - 1]].junction_id is not None:
            return False
        return self.can_still_stop(other, lane_id)

    def can_still_stop(self, vehicle, lane_id: str) -> bool:
        """Whether `vehicle`, heading into junction lane `lane_id`, can still stop comfortably at
        its stop point before the lane's line (else it is committed: it goes)."""
        d = self.line_distance(vehicle, lane_id)
        return can_stop_before(d - STOP_POINT_M, max(vehicle.speed, 0.0), vehicle.LENGTH)

    def traffic_towards(self, lane_id: str, exclude=None) -> list[tuple[float, Any]]:
        """(distance from the vehicle centre to the start of `lane_id`, vehicle) of every road
        user on the lane (negative distances) or heading into it next from an approach allowed
        to go (stop signs and red signals hold theirs)."""
        net = self.net
        out = [(-v.s_on(lane_id), v) for v in self.buckets.get(lane_id, ()) if v is not exclude]
        for p in net.hdmap.lanes[lane_id].predecessors:
            if self._held(p):
                continue
            lane_p = net.lane_of.get(p)
            if lane_p is None:
                continue
            out += [(lane_p.length - v.s_on(p), v) for v in self.buckets.get(p, ())
                    if v is not exclude and enters_next(v, lane_id) and not self.waits_for(v, exclude)]
        return out

    def yield_held(self, vehicle, filter_lane: str) -> bool:
        """A filter lane behind a yield sign gives way: `vehicle` waits at its entry while a lane
        conflicting with it is taken or about to be (`cross_traffic_near`), or while a road user
        is on, or within PRIORITY_HORIZON_S (plus PRIORITY_MARGIN_M) of, a lane that merges with
        it (the exit road's lane that the junction's core feeds)."""
        if self.cross_traffic_near(vehicle, filter_lane, PRIORITY_MARGIN_M):
            return True
        lanes = self.net.hdmap.lanes
        for nxt in lanes[filter_lane].successors:
            for p in lanes[nxt].predecessors if nxt in lanes else ():
                if p == filter_lane or p not in self.net.lane_of:
                    continue
                for d, v in self.traffic_towards(p, exclude=vehicle):
                    if d < PRIORITY_HORIZON_S * max(float(getattr(v, "speed", 0.0)), 0.0) + PRIORITY_MARGIN_M:
                        return True
        return False

    def stop_queue_allows(self, vehicle, junction_lane: str) -> bool:
        """Arrival order: `vehicle` is in the queue of the junction of `junction_lane` and no
        earlier road user in it wants a conflicting lane and may take it: `sim.stop_signs.turns`
        (`TrafficCore.stop_turns`) asked of this one road user where one came before it (a road
        user not in the queue, or first in it, is answered from the queue's view: nearly every
        call of the single env, which asks without the core's arrays)."""
        queue = self.stop_queue.get(self.net.hdmap.lanes[junction_lane].junction_id, ())
        if vehicle not in queue:
            return False
        if queue[0] is vehicle:
            return True
        core = self.road.core
        return bool(core.stop_turns(np.array([core.row_of(vehicle)]), np.array([core.table.index[junction_lane]]))[0])

    def _holds_any(self, vehicle) -> bool:
        """Whether `vehicle` holds a junction reservation (what a release can give up)."""
        return getattr(vehicle, "reserved", None) is not None or self.reservations.held_by(vehicle)

    def _holds(self, vehicle, lane_id: str, claims: Claims | None) -> bool:
        """Whether `vehicle` holds the reservation of `lane_id`, or takes it in `claims` (a lane
        someone else holds is not taken)."""
        if self.reservations.get(lane_id) is vehicle:
            return True
        if not claims:
            return False
        return lane_id not in self.reservations and any(op == "reserve" and lane_id in chain for op, _, chain in claims)

    def may_enter(self, vehicle, in_lane: str, j_lane: str, d_line: float, ignore: frozenset = frozenset(),
                  state: str | None = None) -> bool:
        """Whether `vehicle` may drive past the stop line of `in_lane` into `j_lane` now (a pure
        question). A reservation skips the other checks but not the signal: a vehicle held at the
        line (e.g. by pedestrians) into amber stays there if it can stop. `state`: the signal's
        state when the caller knows it (the batched core)."""
        return self._may_enter(vehicle, in_lane, j_lane, d_line, ignore, state, None, False)

    def _may_enter(self, vehicle, in_lane: str, j_lane: str, d_line: float, ignore: frozenset,
                   state: str | None, claims: Claims | None, take: bool) -> bool:
        """`may_enter` asked by a claim's walk (`claims`, what it took so far); with `take`, what the
        answer takes is recorded there: within commit distance of the line it reserves `j_lane` with
        its chain, and on red it gives its reservation up."""
        sl = self.net.stop_lines.get(in_lane)
        if sl is not None and sl.kind == "signal" and "signal" not in ignore:
            state = state or self.signal_state(sl.control_id)
            if held_at_signal(state == "red", state == "amber", d_line, vehicle.speed):
                if take and claims is not None and state == "red" and self._holds_any(vehicle):
                    claims.append(("release", j_lane, ()))
                return False
        if self._holds(vehicle, j_lane, claims):
            return True
        if sl is not None and sl.kind == "stop" and "stop" not in ignore:
            if not self.stop_queue_allows(vehicle, j_lane):
                return False
        if j_lane in self.net.yield_entries and "conflict" not in ignore and self.yield_held(vehicle, j_lane):
            return False
        chain = self.junction_chain(vehicle, j_lane)
        if "conflict" not in ignore and not self.lanes_clear(chain + self.box_lanes(vehicle, j_lane), vehicle):
            return False
        if take and claims is not None and commits(d_line, vehicle.speed) and j_lane not in self.reservations:
            claims.append(("reserve", j_lane, chain))
        return True

    def junction_chain(self, vehicle, j_lane: str) -> tuple[str, ...]:
        """`j_lane` and the lanes that follow it on the vehicle's route in the same junction, or
        crossing one of its lanes (road lanes, `network.road_crossings`): a map may chain
        connecting lanes inside one junction (USA_Lanker's 26_0_-5 -> 53_0_-3 in junction 1) or
        let a junction lane run out across the road lane after another (41_0_-1 across 47_0_-1);
        entering the first is entering them all, so all must be clear and are reserved together
        (the later lanes' conflicts went unchecked: cars crossed the ego's reserved path). A
        `route_memo` of the vehicle's."""
        if not getattr(vehicle, "lane_route", None):
            return (j_lane,)
        return route_memo(vehicle, ("chain", j_lane), lambda: self._chain(vehicle, j_lane))

    def _chain(self, vehicle, j_lane: str) -> tuple[str, ...]:
        route = vehicle.lane_route
        if j_lane not in route[vehicle.route_pos:]:
            return (j_lane,)
        lanes, conflicts = self.net.hdmap.lanes, self.net.conflicts
        k = route.index(j_lane, vehicle.route_pos)
        jid = lanes[j_lane].junction_id
        chain = [j_lane]
        for lid in route[k + 1:]:
            if lid in chain:
                break
            if lanes[lid].junction_id is None:  # a road lane crossing a lane of this junction (`road_crossings`)
                if not any(lanes[c].junction_id == jid for c in conflicts.get(lid, ())):
                    break
            elif lanes[lid].junction_id != jid:
                break
            chain.append(lid)
        return tuple(chain)

    def crossing_held(self, vehicle, lane_id: str, d: float, claims: Claims | None = None) -> bool:
        """Whether `vehicle`, `d` metres before the start of road lane `lane_id`, waits there:
        the lane crosses a junction lane (`crossed_lanes`) that someone else occupies or has
        reserved, `vehicle` holds no reservation of `lane_id` (a vehicle entering through that
        junction claims the road lane with its junction lanes, `junction_chain`) and it can still
        stop comfortably before it. Nothing else gates such a road lane: no junction entry lies on
        it, so traffic on it drove through the reserved junction lane's path (scheck-in r077: v1 on
        `w669252633_0_0_-1` at 9-12 m/s into the ego's rear leaving `c55`). `claims`: what the
        walk asking it has taken so far."""
        if self._holds(vehicle, lane_id, claims):
            return False
        crossed = crossed_lanes(self.net, lane_id)
        return bool(crossed) and any(self.occupied(c, vehicle) for c in crossed) and \
            can_stop_before(d, vehicle.speed, vehicle.LENGTH)

    # ---- narrow passages -------------------------------------------------------------------
    def passage_ahead(self, vehicle, entered: bool = False) -> tuple[list[tuple[int, int]], float] | None:
        """(chain, wait) of `passage_way`: the passages to claim together and where to wait."""
        way = self.passage_way(vehicle, entered)
        return None if way is None else (way[0], way[1])

    def room_taken(self, group: int, side: int, vehicle=None) -> int:
        """How many road users other than `vehicle` took a place to wait before passage `group`
        from `side` (`sim.passages.places`)."""
        core = self.road.core
        rows = passages.places(core, self.road.slot, group, side)
        return len(rows) - int(vehicle is not None and core.user_row(vehicle) in rows)

    def passage_state(self, group: int) -> tuple[tuple[list, list], dict, tuple[list, list]]:
        """(holders from side 0 and from side 1, {waiter: (side, time it began to wait)}, the
        road users that took a place to wait before it from side 0 and from side 1) of passage
        `group`: a view of the core's places taken (`sim.passages`) for readers."""
        core, slot = self.road.core, self.road.slot
        objs = core.objs
        rows, sides, since = passages.waiters(core, slot, group)
        return (tuple([objs[r] for r in passages.holders(core, slot, group, k).tolist()] for k in (0, 1)),  # type: ignore[return-value]
                {objs[r]: (k, t) for r, k, t in zip(rows.tolist(), sides.tolist(), since.tolist())},
                tuple([objs[r] for r in passages.places(core, slot, group, k).tolist()] for k in (0, 1)))

    def passage_way(self, vehicle, entered: bool = False) -> \
            tuple[list[tuple[int, int]], float, tuple[int, int] | None] | None:
        """([(passage group, side)], distance from the vehicle centre to where it waits for them)
        of the next passages (`MapNetwork.passages`) on the vehicle's route that it neither holds
        nor has entered (with `entered`, from the one it is in): the first one and every one
        after it with no room to wait between (less than a vehicle length of road outside
        passages and junctions: holding one passage while waiting for the next locked up
        autonomous_stuff's one-lane roads that lead into each other). Room is counted on one side
        of a junction alone, no car waits across one (two narrow roads meeting at a junction,
        each car waiting at the line inside the passage it came through: scheck-in r006). None
        without a passage within PASSAGE_HORIZON_M. It waits before the first passage, or at the
        line of the junction before it when that wait would be inside the junction (a car
        standing at a junction exit blocks the box and stands beside the other direction's
        lane); after back-to-back junctions with no room to wait between, at the first one's
        line (digitaf r033). A vehicle already past that line but not yet in the junction (placed
        there at a route's start) waits at the junction's edge, never in the junction at the
        passage's mouth, where it stood in the way out of the passage (digitaf r114). The room
        before a passage that follows the chain is a counted
        resource, one place per vehicle length and stop margin (`places_to_wait`): the chain
        ends before it while a place is free (the third item, the (group, side) whose room the
        vehicle takes with the chain), else that passage joins the chain, all or nothing (two
        cars out of one passage into a room for one: the second waited inside the junction
        before it, in the way of the car that held the next passage, SUMO durlacher-tor r024). The
        first metres of a road after a junction that the other direction's turns sweep
        (`sweep.swept_head`) are no room (SUMO durlacher-tor r025: a car waiting there, its body
        still turned, was clipped)."""
        net = self.net
        lanes = net.hdmap.lanes
        route = vehicle.lane_route
        core = self.road.core
        skip: set[int] = set()
        chain: list[tuple[int, int]] = []
        taken: tuple[int, int] | None = None  # the passage whose room the chain ends before
        wait = room = 0.0
        opened = False  # the road after the chain holds a waiting car (counted if a passage follows)
        line = exit_d = None  # stop point of the junction entry ahead, start of the road after it
        for k, lid, d, s_own in vehicle.upcoming(PASSAGE_HORIZON_M):
            length = net.lane_of[lid].length
            junction = lanes[lid].junction_id is not None
            if s_own is None and enters_junction(lanes, route[k - 1], lid):
                at = d - line_setback(net, route[k - 1]) - STOP_POINT_M
                if at < 0.0:  # past its line, not yet in the junction: its edge is the last wait outside
                    at = max(d - STOP_POINT_M, 0.0)
                if line is None or line < 0.0 or exit_d is None or \
                        room_to_wait(at + STOP_POINT_M - exit_d, vehicle.LENGTH):
                    line = at  # else a junction right after the one before: wait before that one
                exit_d = None
            elif s_own is None and not junction and lanes[route[k - 1]].junction_id is not None:
                head = swept_head(net.swept.get(lid), vehicle.LENGTH)  # swept by the other direction's turns
                exit_d = d + head
                room -= head
            ps = net.passages.get(lid)
            if ps is not None and ps.group not in skip and (ps.group, ps.side) not in chain:
                start = d + ps.s0 if s_own is None else ps.s0 - s_own
                if not chain and not entered and (start - vehicle.LENGTH / 2 <= 0.0 or
                                                  passages.holds(core, core.user_row(vehicle), ps.group, ps.side)):
                    skip.add(ps.group)  # entered (or holding) it: the next passage counts
                    continue
                if chain and room_to_wait(room + ps.s0, vehicle.LENGTH) and \
                        self.room_taken(ps.group, ps.side, vehicle) < places_to_wait(room + ps.s0, vehicle.LENGTH):
                    taken = (ps.group, ps.side)  # a place to wait before it is free: take it
                    break
                if not chain:
                    wait = start - STOP_POINT_M
                    if line is not None and line >= 0.0 and exit_d is not None and \
                            not room_to_wait(start - exit_d, vehicle.LENGTH):
                        wait = line  # the wait before the passage would be inside the junction
                chain.append((ps.group, ps.side))
                room = 0.0 if ps.s1 >= length - 1e-6 else length - ps.s1
                opened = False
            elif chain and not junction:
                room += length  # room to wait: the chain ends here, unless a passage follows whose room is taken
                opened = opened or bool(room_to_wait(room, vehicle.LENGTH))
            elif chain and s_own is None and enters_junction(lanes, route[k - 1], lid):
                if opened or room_to_wait(room - line_setback(net, route[k - 1]), vehicle.LENGTH):
                    break  # room to wait at the junction's line clear of the passage behind
                room = 0.0  # no car waits across a junction: the road beyond must hold it alone
        return (chain, wait, taken) if chain else None

    def passage_allows(self, vehicle, chain: list[tuple[int, int]]) -> bool:
        """One direction at a time, first come first served: `vehicle` may drive into the passages
        of `chain` ((group, side) pairs) while no one holds one of them from the other side or
        waits there since before it (a pure question; `TrafficControl._enrol` takes the place it
        gives)."""
        core, slot = self.road.core, self.road.slot
        me = -2  # (looked up once needed)
        for group, side in chain:
            if not passages.taken(core, group):
                continue
            me = core.user_row(vehicle) if me == -2 else me
            if (passages.holders(core, slot, group, 1 - side) != me).any():
                return False
            rows, sides, since = passages.waiters(core, slot, group)
            own = since[rows == me]
            mine = own[0] if len(own) else math.inf
            first = rows[(sides != side) & (since < mine) & (rows != me)]
            if any(not self._held_against(w, group, side) for w in first.tolist()):
                return False
        return True

    def _held_against(self, w: int, group: int, side: int) -> bool:
        """Whether the road user of row `w` waits for another passage of its chain than `group`
        that a road user holds from the other direction whose own way leads through `group` from
        `side`: `w` cannot go before that one has come through, so its earlier wait on `group`
        must not hold back the cars coming through from `side` (a car waiting before passage A
        for A and the passage B after A's full room kept the car waiting at A's far end from
        going, whose queue held B: locked). Otherwise its wait holds, first come first served."""
        core, slot, net = self.road.core, self.road.slot, self.net
        for g, waits_from, _ in passages.waits(core, w):
            if g == group:
                continue
            for h in passages.holders(core, slot, g, 1 - waits_from).tolist():
                route = core.route_ids[h]
                if h == w or not route:
                    continue
                for lid in route[int(core.route_pos[h]):]:
                    ps = net.passages.get(lid)
                    if ps is not None and ps.group == group and ps.side == side:
                        return True
        return False

    def waits_for(self, vehicle, other, depth: int = 4) -> bool:
        """Whether `vehicle` waits for a narrow passage that `other` holds from the other
        direction, or that someone waiting for `other` in turn holds up (up to `depth` links):
        it stays where it is until `other` has left the passage (a car waiting at a junction at
        the far end of a one-lane road is no oncoming traffic for the one that holds the road:
        taking it for one locked both up, GoMentum r034)."""
        if other is None:
            return False
        core = self.road.core
        return self._waits_for(core.user_row(vehicle), core.user_row(other), depth)

    def _waits_for(self, r: int, other: int, depth: int) -> bool:
        """`waits_for` of rows (-1: none)."""
        if r < 0 or other < 0 or depth <= 0:
            return False
        core, slot = self.road.core, self.road.slot
        for g, side, since in passages.waits(core, r):
            rows, sides, t = passages.waiters(core, slot, g)
            blockers = np.concatenate([passages.holders(core, slot, g, 1 - side), rows[(sides != side) & (t < since)]])
            if (blockers == other).any() or \
                    any(self._waits_for(u, other, depth - 1) for u in blockers.tolist() if u != r):
                return True
        return False

    def passage_stop(self, vehicle) -> float:
        """Distance ahead of `vehicle` where it waits for the next narrow passage (inf: free)."""
        nxt = self.passage_way(vehicle) if self.net.passages else None
        return math.inf if nxt is None or self.passage_allows(vehicle, nxt[0]) else nxt[1]

    def midblock_ahead(self, vehicle, within: float = math.inf) -> tuple[str, float] | None:
        """(light, distance along the route from the vehicle's centre) of the next mid-block
        crossing's line ahead of a route follower within `within` metres, or None."""
        if not self.net.midblock_lines:
            return None
        for _k, lid, d, s_own in vehicle.upcoming(within):
            for sid, s in self.net.midblock_lines.get(lid, ()):
                ahead = s - s_own if s_own is not None else d + s
                if 0.0 < ahead <= within:
                    return sid, ahead
        return None

    def midblock_stop(self, vehicle, lane_id: str, d: float, ignore: frozenset = frozenset()) -> float:
        """Distance ahead of `vehicle` to stop at, STOP_POINT_M before the line of a mid-block
        crossing's light on road lane `lane_id` (its start `d` metres ahead of the vehicle's
        centre, negative once on it) that shows red, or amber where it can stop; inf when none
        holds it (lines behind the centre are passed)."""
        if "signal" in ignore:
            return math.inf
        for sid, s in self.net.midblock_lines.get(lane_id, ()):
            d_line = d + s
            if d_line <= 0.0:
                continue
            state = self.signal_state(sid)
            if held_at_signal(state == "red", state == "amber", d_line, vehicle.speed):
                return d_line - STOP_POINT_M
        return math.inf

    def pedestrian_blocking(self, lane_id: str, s_from: float) -> float | None:
        """s on `lane_id` to stop at for a pedestrian in the lane's path beyond `s_from`, or None
        (`sim.crossings.blocking`, the one program, asked through the road's core)."""
        road = self.road
        at = road.core.pedestrian_stop(road.slot, lane_id, s_from)
        return None if at == math.inf else at

    def stop_distance(self, vehicle, ignore: frozenset = frozenset(), scan: tuple | None = None) -> float:
        """Distance ahead of `vehicle` where traffic rules make it stop (inf when free to go):
        STOP_POINT_M before a stop line it may not pass (measured along the route), before a
        pedestrian's crosswalk, or before a narrow passage the other direction holds. A pure
        question: what it would take is `claim`'s. `ignore` names rules to leave out: "signal",
        "stop", "conflict", "pedestrian", "passage". `scan`: the vehicle's scan along its route
        when the caller made it (`_rule_stop`)."""
        passage = math.inf if "passage" in ignore else self.passage_stop(vehicle)
        return self._stop_within(vehicle, ignore, passage, scan)

    def ask(self, vehicle, scan: tuple, claims: Claims) -> float:
        """`stop_distance` as the traffic core asks it of a row (with its `scan`), recording in
        `claims` what the row's claim would take or give up at the junction entries on its way
        (`control.TrafficControl.claim`: the core claims for the rows that would, after every row
        has asked). Not of a row with a narrow passage ahead, which claims (its place at the
        passage is part of its claim: `TrafficCore._passages_ahead`)."""
        return self._stop_within(vehicle, frozenset(), math.inf, scan, claims)

    def _stop_within(self, vehicle, ignore: frozenset, passage: float, scan: tuple | None,
                     claims: Claims | None = None) -> float:
        """The stop distance of `vehicle` whose wait for a narrow passage lies `passage` metres
        ahead (inf: none): the first stop of its walk (`_rule_stop`) before that wait, out of the
        swept paths (`clear_of_sweeps`); `claims` records what the walk takes."""
        stop = min(passage, self._rule_stop(vehicle, ignore, passage, scan, claims))
        return self.clear_of_sweeps(vehicle, stop) if self.net.swept and stop < math.inf else stop

    def clear_of_sweeps(self, vehicle, stop: float) -> float:
        """A stop point `stop` metres ahead of `vehicle`, moved back so that the vehicle waits
        with its body out of the swept path of the cars turning past it on the opposite lanes of
        a narrow road (`sweep.stretches`: where road design puts a stop line on a narrow road,
        behind the turning design vehicle; digitaf r110, SUMO durlacher-tor r025). A stop sign's
        line keeps its place (a stop counts within STOP_ZONE_M of it)."""
        net = self.net
        at_rest = stop - IDM_STOP_MARGIN_M - vehicle.LENGTH / 2  # where its centre comes to rest
        for _k, lid, d, _s_own in vehicle.upcoming(max(at_rest, 0.0)):
            spans = net.swept.get(lid)
            if spans is None or not d <= at_rest <= d + net.lane_of[lid].length:
                continue
            back = clear_stop(spans, at_rest - d)
            if back > 0.0:
                sl, _, _, d_line = self.line_ahead(vehicle, stop + STOP_POINT_M + 1e-6)
                if sl is not None and sl.kind == "stop" and abs(d_line - STOP_POINT_M - stop) < 1e-6:
                    return stop
            return stop - back
        return stop

    def _rule_stop(self, vehicle, ignore: frozenset, before: float = math.inf, scan: tuple | None = None,
                   claims: Claims | None = None) -> float:
        """`stop_distance` without narrow passages: the vehicle's stops along its route in order
        (`sim.rule_scan`: a road lane across a junction lane, a junction entry's line, a
        mid-block crossing's light, a crosswalk with people on it), the first that holds it.
        `scan`: (an indexed `rule_scan.Scan`, the vehicle's place in it) when the caller scanned
        it (the signal's state at its first stop's line may be known there), else its road's
        core scans it. The scan runs up to the first road after the next junction entry with
        room to wait on it, however many short road lanes lie before a line (CARLA's 1.5 m and
        2.4 m roads) and however many junctions follow each other with less road between them:
        a line right after a junction is seen from before that junction (SUMO's 0.2 m approach
        lanes after a junction: the line came into view 4 m ahead, too late to stop for its
        red). `claims` (`claim`'s) records what the walk takes; junction lanes `beyond` the stop
        point `before` (a passage's wait) are checked but never reserved."""
        ids = self.net.lane_ids
        sc, r = scan if scan is not None else self.road.core.rule_scan_of(vehicle)
        lanes, prevs, dists, bits = sc.lane, sc.prev, sc.dist, sc.bits
        for k in range(sc.first[r], sc.end[r]):
            lane, prev, d, what = lanes[k], prevs[k], dists[k], bits[k]
            state = sc.state[r] if k == sc.first[r] else None
            lid = ids[lane]
            if prev < 0:  # the current lane: a mid-block light's line and pedestrians ahead of us on it
                s_own = -d
                stop = self.midblock_stop(vehicle, lid, d, ignore) if what & MIDBLOCK else math.inf
                ped = None if "pedestrian" in ignore or not what & PEOPLE else self.pedestrian_blocking(lid, s_own)
                if ped is not None:
                    stop = min(stop, ped - s_own)
                if stop < math.inf:
                    return stop
                continue
            if what & CROSSED and "conflict" not in ignore and self.crossing_held(vehicle, lid, d, claims):
                return d - STOP_POINT_M
            if what & ENTRY:
                in_lane = ids[prev]
                d_line = d - line_setback(self.net, in_lane)
                if not self._may_enter(vehicle, in_lane, lid, d_line, ignore, state, claims, not beyond(d, before)):
                    return d_line - STOP_POINT_M
            stop = self.midblock_stop(vehicle, lid, d, ignore) if what & MIDBLOCK else math.inf
            ped = None if "pedestrian" in ignore or not what & PEOPLE else self.pedestrian_blocking(lid, 0.0)
            if ped is not None:
                stop = min(stop, d + ped)
            if stop < math.inf:
                return stop
        return math.inf


def compliance_rules(right_turn_on_red: bool, blocked_after: float) -> dict[str, Any]:
    """What `EgoJudge` and the rollout judge, as numbers, for a planner in another process (the
    planner bridge's init, docs/planners.md): read from the constants the judge uses, so that the
    description follows the rules. `blocked_after` is the rollout's (0: never)."""
    return {
        "full_stop": {"speed_mps": STOPPED_SPEED_MPS, "zone_m": STOP_ZONE_M},
        "stop_sign": {"order": "first_come_first_served"},
        "signal": {"red": "violation", "amber": "allowed", "right_turn_on_red": bool(right_turn_on_red)},
        "amber": {"brake_mps2": AMBER_BRAKE_MPS2, "margin_m": AMBER_STOP_MARGIN_M},
        "stop_line": {"hold_m": STOP_POINT_M, "zone_m": STOP_ZONE_M},
        "pedestrian_yield": {"in_path_m": PEDESTRIAN_IN_PATH_M, "moving_mps": PEDESTRIAN_YIELD_SPEED_MPS,
                             "stretch_m": PEDESTRIAN_YIELD_STRETCH_M, "along": "ego_length"},
        "off_road": {"lateral_m": OFF_ROAD_LATERAL_M, "end_m": OFF_ROAD_END_M},
        "blocked": {"after_s": float(blocked_after), "near_m": BLOCKED_NEAR_M},
    }


class EgoJudge:
    """A controlled row's judge (`sim.judge`, the one program every env's judge is): its verdicts
    and what it keeps are the row's columns of the core; `check` judges the row alone (the envs
    judge every due row at once).

    red_light: the ego crossed a signal's stop line into the junction while red (amber is
    allowed; with `right_turn_on_red`, a right turn after a full stop is too), or a mid-block
    crossing's line on red; stop_sign: it
    entered without a stop (speed <= STOPPED_SPEED_MPS within STOP_ZONE_M of the line, along its
    route); pedestrian_yield: it moved on a crosswalk with a pedestrian in its path. With
    `arrives`, the drive ends at the goal: the judge stops there."""

    KINDS: tuple[str, ...] = VIOLATIONS  # the kinds it counts (`violations`' keys)
    AGENT = False  # whether it judges the agents' two violations too (`multi_agent.AgentJudge`)

    def __init__(self, rules: TrafficRules, ego, arrives: bool = False) -> None:
        self.rules = rules
        self.ego = ego
        self._core = rules.road.core
        self._held: tuple[list[int], list[int], bool] | None = None  # its verdicts once its row is gone (`let_go`)
        self._core.judge_start(ego.row, arrives, self.AGENT)

    def check(self) -> None:
        """Judge the row after a frame (`TrafficCore.judge`, a batch of one)."""
        self._core.judge(np.array([self.ego.row], dtype=np.int64))

    @property
    def done(self) -> bool:
        """Whether it no longer judges: the route is completed (with `arrives`)."""
        return bool(self._core.j_done[self.ego.row])

    def wait_reason(self, near: float = BLOCKED_NEAR_M) -> str:
        """What justifies the ego's standing where it stands, in words ("" when nothing does): a red
        or amber signal at its next stop line (however far); the rules holding it within `near`
        metres (`stop_distance`: its turn at a stop sign it stands at, conflicting traffic, a
        pedestrian, a narrow passage; a stop sign it has not reached does not hold it); a road
        user within `near` metres ahead in its path (`leader_gaps`: a queue). Read-only; the
        rollouts' blocked early end (scenarios/rollout.py) asks it while the ego stands."""
        rules, ego = self.rules, self.ego
        sl = rules.line_ahead(ego)[0]
        state = rules.signal_state(sl.control_id) if sl is not None and sl.kind == "signal" else None
        if state in ("red", "amber"):
            return f"{state} signal"
        at_line = rules.waiting_line(ego, rules.net.id_of.get(ego.lane_index))[0] is not None
        if rules.stop_distance(ego, ignore=frozenset() if at_line else frozenset({"stop"})) <= near:
            return "held by the rules"
        if any(gap <= near for gap, _ in ego.leader_gaps()):
            return "road user ahead"
        return ""

    def stopped_before(self, in_lane: str | None) -> bool:
        """Whether the ego has made its full stop at the line of `in_lane` (it counts until the
        ego is on another road lane)."""
        k = self._core.table.index.get(in_lane, -1) if in_lane is not None else -1
        return k >= 0 and bool((self._core.j_stop[self.ego.row] == k).any())

    # ---- its verdicts: the row's columns of the core (`violations`, `new_violations`, `off_road`)
    @property
    def violations(self) -> dict[str, int]:
        """{kind: count} of this episode's violations (a new dict)."""
        counts = self._held[0] if self._held else self._core.violations[self.ego.row, :len(self.KINDS)].tolist()
        return dict(zip(self.KINDS, counts))

    @property
    def new(self) -> list[str]:
        """The violations of this policy step (`violation_names`)."""
        return violation_names(self._held[1] if self._held else self._core.new_violations[self.ego.row].tolist())

    @property
    def off_road(self) -> bool:
        """Whether it has left the road this episode."""
        return self._held[2] if self._held else bool(self._core.off_road[self.ego.row])

    def let_go(self) -> None:
        """Keep the verdicts here: the road user's row is about to leave the core."""
        i = self.ego.row
        self._held = (self._core.violations[i, :len(self.KINDS)].tolist(), self._core.new_violations[i].tolist(),
                      bool(self._core.off_road[i]))

