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

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.observation import ObservationType

from ..config import (DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS, DRIVER_VIEW_CONFLICT_DISTANCE_M, DRIVER_VIEW_CONFLICT_TIME_S,
                      DRIVER_VIEW_LEADER_SCALE_M, DRIVER_VIEW_LINE_FAR_M, DRIVER_VIEW_LINE_NEAR_M,
                      DRIVER_VIEW_PEDESTRIAN_SCALE_M, DRIVER_VIEW_QUEUE_SCALE, DRIVER_VIEW_SIGNAL_SCALE_S,
                      DRIVER_VIEW_SPEED_SCALE_MPS)
from .rules import in_stop_zone, manoeuvre_name
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
_IGNORE_BUT_PEDESTRIANS = frozenset({"signal", "stop", "conflict", "passage"})


def _scaled(value: float, scale: float) -> float:
    return min(max(value / scale, 0.0), 1.0)


class DriverViewObservation(ObservationType):
    """DRIVER_VIEW_FEATURES of the ego of a MapEnv (see the module docstring)."""

    def space(self) -> spaces.Space:
        return spaces.Box(0.0, 1.0, (len(DRIVER_VIEW_FEATURES),), dtype=np.float32)

    def observe(self) -> np.ndarray:
        return np.asarray(driver_view(self.env), dtype=np.float32)


def next_junction_lane(ego) -> tuple[int, str | None]:
    """(route index, lane id) of the junction lane the ego is on or will enter next ((-1, None)
    past the route's last junction)."""
    lanes = ego.net.hdmap.lanes
    for k in range(ego.route_pos, len(ego.lane_route)):
        if lanes[ego.lane_route[k]].junction_id is not None:
            return k, ego.lane_route[k]
    return -1, None


def driver_view(env) -> list[float]:
    """DRIVER_VIEW_FEATURES of `env`'s ego (a MapEnv, unwrapped)."""
    ego, rules = env.vehicle, env.rules
    net = rules.net
    m = net.hdmap
    out = dict.fromkeys(DRIVER_VIEW_FEATURES, 0.0)
    out["speed"] = _scaled(ego.speed, DRIVER_VIEW_SPEED_SCALE_MPS)
    for key in ("line_near", "line_far", "line_time", "priority_time", "priority_distance", "other_time", "other_distance",
                "pedestrian", "leader_gap"):
        out[key] = 1.0
    k, j_lane = next_junction_lane(ego)
    if j_lane is not None:
        in_junction = k == ego.route_pos
        in_lane = ego.lane_route[k - 1] if k > 0 else None
        sl = rules.control_at(in_lane)
        d = 0.0 if in_junction else max(rules.line_distance(ego, j_lane), 0.0)
        out.update(line_near=_scaled(d, DRIVER_VIEW_LINE_NEAR_M), line_far=_scaled(d, DRIVER_VIEW_LINE_FAR_M),
                   line_time=_scaled(d / max(ego.speed, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS), DRIVER_VIEW_CONFLICT_TIME_S),
                   in_stop_zone=float(not in_junction and in_stop_zone(d)), in_junction=float(in_junction))
        out["signal" if sl is not None and sl.kind == "signal" else "stop" if sl is not None else "bare"] = 1.0
        turn = manoeuvre_name(m.lanes[j_lane], net.ramp_moves)
        if turn in out:  # a U-turn has no feature of its own
            out[turn] = 1.0
        if sl is not None and sl.kind == "signal":
            out[rules.signal_state(sl.control_id)] = 1.0
            if sl.control_id in rules.plans:
                out["signal_change"] = _scaled(rules.signal_change(sl.control_id), DRIVER_VIEW_SIGNAL_SCALE_S)
            out["protected"] = float(rules.protected(in_lane, j_lane))
        if sl is not None and sl.kind == "stop" and not in_junction:
            out["stop_made"] = float(env.judge.stopped_before(in_lane))
            out["queue_ahead"] = _scaled(_queue_ahead(rules, ego, j_lane), DRIVER_VIEW_QUEUE_SCALE)
        _conflicts(rules, ego, j_lane, out)
    ped = rules.stop_distance(ego, ignore=_IGNORE_BUT_PEDESTRIANS)
    if ped < math.inf:
        out["pedestrian"] = _scaled(ped, DRIVER_VIEW_PEDESTRIAN_SCALE_M)
    gaps = ego.leader_gaps()
    if gaps:
        gap, speed = min(gaps)
        out.update(leader_gap=_scaled(gap, DRIVER_VIEW_LEADER_SCALE_M),
                   leader_speed=_scaled(speed, DRIVER_VIEW_SPEED_SCALE_MPS))
    return [out[f] for f in DRIVER_VIEW_FEATURES]


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


def _conflicts(rules, ego, j_lane: str, out: dict) -> None:
    """Junction traffic in conflict with `j_lane`: occupancy, and the nearest vehicle heading
    into a conflicting lane with priority over the ego's movement (at least its lane priority)
    and without."""
    net = rules.net
    mine = net.lane_of[j_lane].priority
    nearest = {"priority": (math.inf, 0.0, 0.0), "other": (math.inf, 0.0, 0.0)}
    for c in net.conflicts.get(j_lane, ()):
        if rules.occupied(c, ego):
            out["conflict_occupied"] = 1.0
        group = "priority" if net.lane_of[c].priority >= mine else "other"
        for d, v in rules.traffic_towards(c, exclude=ego):
            speed = max(float(v.speed), 0.0)
            t = max(d, 0.0) / max(speed, DRIVER_VIEW_ARRIVAL_MIN_SPEED_MPS)
            if t < nearest[group][0]:
                nearest[group] = (t, max(d, 0.0), speed)
    for group, (t, d, speed) in nearest.items():
        if t < math.inf:
            out.update({f"{group}_time": _scaled(t, DRIVER_VIEW_CONFLICT_TIME_S),
                        f"{group}_distance": _scaled(d, DRIVER_VIEW_CONFLICT_DISTANCE_M),
                        f"{group}_speed": _scaled(speed, DRIVER_VIEW_SPEED_SCALE_MPS)})
