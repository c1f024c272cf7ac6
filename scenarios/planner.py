"""The baseline planner under test: a state machine of scenarios and stages like Apollo's
planning, driving a MapEnv's ego through the env's action interface, and the `Policy`
protocol any planner (a callable, an SB3 model) plugs into.

Scenarios and their stages (the paper's Section V abbreviations):

| scenario | selected when | stages |
|---|---|---|
| LANE_FOLLOW | no junction within SELECT_DISTANCE_M | LF |
| STOP_SIGN_UNPROTECTED | next stop line is a stop sign | S_PS -> S_S -> S_C -> S_I |
| TRAFFIC_LIGHT_PROTECTED | signal; straight, right on green, or a protected left | T_A -> T_C |
| TRAFFIC_LIGHT_UNPROTECTED_LEFT_TURN | signal; left/U-turn whose conflicts share our phase | L_A -> (L_C ->) L_I |
| TRAFFIC_LIGHT_UNPROTECTED_RIGHT_TURN | signal red at selection; right turn (right on red) | R_S -> R_C -> R_I |
| BARE_INTERSECTION_UNPROTECTED | junction without signal or stop sign | B_A -> B_I |
| RAMP_MERGE | bare; from an on-ramp onto its main road | M_A -> (M_G ->) M_I |
| RAMP_DIVERGE | bare; from the main road onto an off-ramp | D_A -> D_I |

Stages: S_PS pre-stop; S_S, R_S stop; S_C, L_C, R_C creep; T_A, L_A, B_A, M_A, D_A approach;
M_G wait for a gap; S_I, T_C, L_I, R_I, B_I intersection cruise, M_I merge along the acceleration
lane, D_I leave along the deceleration lane (R_S goes straight to R_I when the light turns green
first). A ramp (`MapNetwork.ramp_moves`) is approached at its own lane's speed, with no
slowing to a bare junction's; a merge held at its mouth by main-road traffic waits for a gap (M_G);
a diverge slows to the off-ramp's speed before the gore.

Every scenario ends back in LF when the ego leaves the junction. Longitudinal control is IDM
towards the lane speed limit, behind leaders (`leader_gaps`) and before the stop point the
rules impose (`rule_stop_distance`: signals, stop-sign arrival order, pedestrians,
conflicting junction traffic); stages add full stops, creeping and speed caps. Steering
follows the route (the env's lane keeping under a longitudinal-only ContinuousAction).

Every traffic rule the planner applies comes from the env's rules module (`env.unwrapped.rules`,
feat2map.envs.rules): which control governs the next stop line and its state, whether a turn is
protected, where the rules make the ego stop, who is heading into a conflicting lane, and what
counts as a full stop (distances to stop lines are measured along the route). Those questions
are pure; what the ego takes (its junction lanes, its place at narrow passages) it takes through
the env's claims (`claim`, `claim_passages`, `give_up`), the update traffic's claims go through.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, ClassVar, Iterable, Protocol, runtime_checkable

import numpy as np

from ..config import CONFLICT_DISTANCE_M, CURVE_BEHIND_M, IDM_ACC, RAMP_MANOEUVRES, STOP_POINT_M
from ..envs.driver import DRIVER_ACTION_CONFIG
from ..envs.lanes import curve_speeds
from ..envs.rules import (RULES, amber_speed_cap, braking_distance, can_stop_before, has_stopped, idm,
                          in_stop_zone)

SELECT_DISTANCE_M = 40.0  # junction scenarios are selected this far before the stop line
CREEP_TRIGGER_M = 12.0  # an unprotected left creeps when held by traffic this close to the line
CREEP_SPEED_MPS = 2.0
CREEP_GAIN = 1.5  # [1/s] speed error -> acceleration while creeping or capping speed
STOP_DURATION_S = 1.0  # full stop held at stop signs and before a right turn on red
BARE_APPROACH_M = 20.0  # bare junctions are approached at the junction speed limit from here
HOLD_BRAKE_MPS2 = -3.0
CURVE_LOOKAHEAD_M = 50.0
AMBER_LOOKAHEAD_M = 100.0  # a green signal's line is approached at a speed no amber can catch in its dilemma zone from here
APPROACH_STAGES = ("T_A", "L_A", "L_C")  # the stages before a signal's line that may meet its amber
GAP_ACCEL_MPS2 = 1.5  # the ego's assumed acceleration when judging whether it clears a conflict in time
GAP_MARGIN_S = 2.0  # a creeping turn goes when every conflicting vehicle arrives this much after it clears
CROSS_TRAFFIC_MARGIN_M = 5.0  # a right turn on red waits for vehicles this far (plus 3 s) from a conflict
PATIENCE_S = 15.0  # held at the line by traffic this long, an unprotected entry takes its lane when the rules allow it

LANE_FOLLOW = "LANE_FOLLOW"
STOP_SIGN = "STOP_SIGN_UNPROTECTED"
TL_PROTECTED = "TRAFFIC_LIGHT_PROTECTED"
TL_LEFT = "TRAFFIC_LIGHT_UNPROTECTED_LEFT_TURN"
TL_RIGHT = "TRAFFIC_LIGHT_UNPROTECTED_RIGHT_TURN"
BARE = "BARE_INTERSECTION_UNPROTECTED"
RAMP_MERGE = "RAMP_MERGE"
RAMP_DIVERGE = "RAMP_DIVERGE"
SCENARIO_STAGES: dict[str, tuple[str, ...]] = {
    LANE_FOLLOW: ("LF",),
    STOP_SIGN: ("S_PS", "S_S", "S_C", "S_I"),
    TL_PROTECTED: ("T_A", "T_C"),
    TL_LEFT: ("L_A", "L_C", "L_I"),
    TL_RIGHT: ("R_S", "R_C", "R_I"),
    BARE: ("B_A", "B_I"),
    RAMP_MERGE: ("M_A", "M_G", "M_I"),
    RAMP_DIVERGE: ("D_A", "D_I"),
}
STAGE_NAMES: dict[str, str] = {  # what each stage code means (reports explain the codes they show)
    "LF": "lane follow", "S_PS": "stop sign: pre-stop", "S_S": "stop sign: stop", "S_C": "stop sign: creep",
    "S_I": "stop sign: intersection cruise", "T_A": "signal, protected: approach",
    "T_C": "signal, protected: intersection cruise", "L_A": "signal, unprotected left: approach",
    "L_C": "signal, unprotected left: creep", "L_I": "signal, unprotected left: intersection cruise",
    "R_S": "signal, right turn on red: stop", "R_C": "signal, right turn on red: creep",
    "R_I": "signal, right turn: intersection cruise", "B_A": "bare junction: approach",
    "B_I": "bare junction: intersection cruise", "M_A": "ramp merge: approach", "M_G": "ramp merge: wait for a gap",
    "M_I": "ramp merge: acceleration lane", "D_A": "ramp diverge: approach", "D_I": "ramp diverge: deceleration lane",
}
CRUISE_STAGE = {STOP_SIGN: "S_I", TL_PROTECTED: "T_C", TL_LEFT: "L_I", TL_RIGHT: "R_I", BARE: "B_I", RAMP_MERGE: "M_I",
                RAMP_DIVERGE: "D_I"}
RAMP_SCENARIOS = {RAMP_MANOEUVRES["on"]: ("M_A", RAMP_MERGE), RAMP_MANOEUVRES["off"]: ("D_A", RAMP_DIVERGE)}
HELD_STAGES = ("B_A", "L_C", "M_A", "M_G")  # stages that count the time held at the line by traffic (PATIENCE_S)


@runtime_checkable
class Policy(Protocol):
    """Anything that drives an env: reset once per episode, then one action per step."""

    def reset(self, env: Any) -> None: ...

    def act(self, obs: Any, info: dict) -> Any: ...


@dataclass(frozen=True)
class StageEvent:
    """A scenario selection or stage transition of the planner at env step `step`."""

    step: int
    time: float
    junction: str | None
    scenario: str
    stage: str


class BaselinePlanner:
    """Apollo-like rule-based planner (see module docstring); implements `Policy`.

    `ignore` breaks chosen rules on purpose ("signal", "stop", "pedestrian", "conflict"),
    e.g. `BaselinePlanner(ignore={"signal"})` runs red lights: the deliberately broken planner.
    """

    action_config: ClassVar[dict] = dict(DRIVER_ACTION_CONFIG)

    def __init__(self, ignore: Iterable[str] = ()) -> None:
        self.ignore = frozenset(ignore)
        unknown = self.ignore - set(RULES)
        if unknown:
            raise ValueError(f"unknown rule(s) to ignore: {sorted(unknown)}; expected a subset of {RULES}")
        self.env: Any = None
        self.events: list[StageEvent] = []
        self.scenario = LANE_FOLLOW
        self.stage = "LF"

    # ---- Policy --------------------------------------------------------------------------
    def reset(self, env: Any) -> None:
        if not hasattr(env.unwrapped.action_type, "acceleration_range"):
            raise TypeError(f"BaselinePlanner drives a ContinuousAction ego (BaselinePlanner.action_config), "
                            f"the env has {type(env.unwrapped.action_type).__name__}")
        self.env = env.unwrapped
        self.events = []
        self.scenario, self.stage = LANE_FOLLOW, "LF"
        self.junction: str | None = None
        self.j_lane: str | None = None
        self.in_lane: str | None = None
        self.stage_since = 0.0
        self.go = False  # the unprotected left's gap acceptance lets it past the line (re-taken each step)
        self.full_stop = False  # stopped at the selected junction's line (right on red needs it)
        self.held = 0.0  # seconds held at the selected junction's line by traffic (PATIENCE_S)
        self._zones: dict[tuple[str, str], tuple[float, float, float, float]] = {}
        self._steps = 0
        self._log()

    def act(self, obs: Any, info: dict) -> np.ndarray:
        if self.env is None:
            raise RuntimeError("BaselinePlanner.act before reset(env)")
        with self.env.road.core.asking():  # (nothing moves while it decides: the rules read the rows once)
            self._update_stage()
            a = self._acceleration()
        self._steps += 1
        lo, hi = self.env.action_type.acceleration_range
        a = float(np.clip(a, lo, hi))
        return np.array([2 * (a - lo) / (hi - lo) - 1], dtype=np.float32)

    def stage_path(self) -> tuple[str, ...]:
        """Stages in the order visited, e.g. ("LF", "S_PS", "S_S", "S_C", "S_I", "LF")."""
        return tuple(e.stage for e in self.events)

    def scenario_path(self) -> tuple[str, ...]:
        """Scenarios in the order selected (consecutive repeats merged)."""
        out: list[str] = []
        for e in self.events:
            if not out or out[-1] != e.scenario:
                out.append(e.scenario)
        return tuple(out)

    # ---- state machine -------------------------------------------------------------------
    def _log(self) -> None:
        env = self.env
        self.events.append(StageEvent(self._steps, float(env.time), self.junction, self.scenario, self.stage))

    def _go(self, stage: str, scenario: str | None = None) -> None:
        self.scenario = scenario or self.scenario
        self.stage = stage
        self.stage_since = float(self.env.time)
        self.go = False
        if scenario is not None:
            self.full_stop = False
            self.held = 0.0
        if scenario == LANE_FOLLOW:
            self.junction = self.j_lane = self.in_lane = None
        self._log()

    def _update_stage(self) -> None:
        for _ in range(4):  # a few transitions may chain within one decision
            before = self.stage
            self._transition()
            if self.stage == before:
                return

    def _transition(self) -> None:
        env = self.env
        ego, m = env.vehicle, env.net.hdmap
        here = env.net.id_of.get(ego.lane_index)
        in_junction = here in m.lanes and m.lanes[here].junction_id is not None
        if self.stage == "LF":
            _, in_lane, j_lane, d = env.rules.line_ahead(ego)
            if j_lane is not None and not in_junction and d <= SELECT_DISTANCE_M:
                self._select(in_lane, j_lane)
            return
        passed = self.j_lane in ego.lane_route[:ego.route_pos]
        if self.stage == CRUISE_STAGE.get(self.scenario):
            if passed and not in_junction:
                self._go("LF", LANE_FOLLOW)
            return
        if (in_junction and m.lanes[here].junction_id == self.junction) or passed or \
                ego.lane_route[ego.route_pos] == self.j_lane:
            self._go(CRUISE_STAGE[self.scenario])
            return
        d = self._line_distance()
        t_stage = float(env.time) - self.stage_since
        stopped = has_stopped(ego.speed)
        held = stopped and d <= CREEP_TRIGGER_M and self.stage in HELD_STAGES and self._held_by_traffic()
        if held:
            self.held += 1.0 / float(env.config["policy_frequency"])
        if stopped and self._in_stop_zone():
            self.full_stop = True
        if self.stage == "S_PS" and stopped and self._in_stop_zone():
            self._go("S_S")
        elif self.stage == "S_S" and t_stage >= STOP_DURATION_S and self._line_free():
            self._go("S_C")
        elif self.stage == "L_A" and d <= CREEP_TRIGGER_M and (self._held_by_traffic() or not self._decide(d)):
            self._go("L_C")  # held by the rules, or by its own gap acceptance
        elif self.stage == "R_S" and self.full_stop and t_stage >= STOP_DURATION_S and self._signal_state() != "green":
            self._go("R_C")  # (a light turning green in R_S lets the ego on: R_S -> R_I, as in Apollo)
        elif self.stage == "M_A" and held:
            self._go("M_G")  # main-road traffic holds the merge at its mouth

    def _select(self, in_lane: str, j_lane: str) -> None:
        env = self.env
        m = env.net.hdmap
        self.in_lane, self.j_lane = in_lane, j_lane
        self.junction = m.lanes[j_lane].junction_id
        sl = env.rules.control_at(in_lane)
        turn = m.lanes[j_lane].turn
        if sl is None:
            ramp = self.env.net.ramp_moves.get(j_lane)
            self._go(*RAMP_SCENARIOS.get(ramp, ("B_A", BARE)))
        elif sl.kind == "stop":
            self._go("S_PS", STOP_SIGN)
        elif turn in ("left", "uturn") and not env.rules.protected(in_lane, j_lane):
            self._go("L_A", TL_LEFT)
        elif turn == "right" and self._signal_state() == "red" and self._right_on_red():
            self._go("R_S", TL_RIGHT)
        else:
            self._go("T_A", TL_PROTECTED)

    # ---- perception helpers -----------------------------------------------------------------
    def _line_distance(self) -> float:
        """Metres along the route from the ego centre to the selected junction's stop line
        (its entry where bare)."""
        env = self.env
        return env.rules.line_distance(env.vehicle, self.j_lane)

    def _in_stop_zone(self) -> bool:
        return self.env.rules.control_at(self.in_lane) is not None and in_stop_zone(self._line_distance())

    def _signal_state(self) -> str | None:
        return self.env.rules.signal_at(self.in_lane)

    def _right_on_red(self) -> bool:
        return self.env.rules.right_turn_on_red()

    def _rule_ignore(self) -> frozenset[str]:
        if self.stage == "R_C" and self._right_on_red() and self.full_stop:
            return self.ignore | {"signal"}
        return self.ignore

    def _line_free(self) -> bool:
        """The rules let the ego past the stop line now (probe, without reserving)."""
        stop = self.env.rule_stop_distance(self._rule_ignore())
        return stop > self._line_distance() + 0.5

    def _held_by_traffic(self) -> bool:
        """Conflicting traffic, not the signal or a pedestrian, holds the ego at the line."""
        env = self.env
        stop = env.rule_stop_distance(self.ignore)
        if stop == math.inf:
            return False
        return env.rule_stop_distance(self.ignore | {"conflict"}) > stop + 0.5

    def _cross_traffic_near(self) -> bool:
        """Vehicles about to enter a lane conflicting with ours (whatever their priority): a
        right turn on red yields to every approach that has green."""
        env = self.env
        return env.rules.cross_traffic_near(env.vehicle, self.j_lane, CROSS_TRAFFIC_MARGIN_M)

    def _zone(self, mine: str, other: str) -> tuple[float, float, float, float]:
        """(start, end) along `mine` and along `other` of where the two junction lanes come
        within CONFLICT_DISTANCE_M of each other (cached per pair)."""
        key = (mine, other)
        if key not in self._zones:
            a, b = self.env.net.lane_of[mine], self.env.net.lane_of[other]
            d = np.hypot(*(a.points[:, None, :] - b.points[None, :, :]).transpose(2, 0, 1))
            close = d < CONFLICT_DISTANCE_M
            if not close.any():
                i = np.unravel_index(np.argmin(d), d.shape)
                close = np.zeros_like(close)
                close[i] = True
            ia, ib = np.nonzero(close.any(axis=1))[0], np.nonzero(close.any(axis=0))[0]
            self._zones[key] = (float(a.cum[ia[0]]), float(a.cum[ia[-1]]), float(b.cum[ib[0]]), float(b.cum[ib[-1]]))
        return self._zones[key]

    def _gap_ok(self, yielding: bool = False) -> bool:
        """Gap acceptance of the unprotected left (scenarios/README.md), per conflict zone of our
        junction lane: every vehicle heading through it either leaves it GAP_MARGIN_S before we
        can arrive (at its current speed) or arrives GAP_MARGIN_S after we have left (it
        accelerating up to its lane's speed limit). With `yielding`, vehicles that would wait for
        our reservation (`TrafficRules.yields_to_reservation`) are left out."""
        assert self.j_lane is not None  # a scenario that checks gaps has selected its junction lane
        env = self.env
        ego, net = env.vehicle, env.net
        v_me = max(ego.speed, 0.0)
        here = net.id_of.get(ego.lane_index)
        before = self._line_distance() if here != self.j_lane else -ego.lane_s
        half = ego.LENGTH / 2
        v_turn = max(float(self._curve_speeds(self.j_lane)[1].min()), 1.0)  # the turn's comfortable speed
        for c in net.conflicts.get(self.j_lane, ()):
            m0, m1, c0, c1 = self._zone(self.j_lane, c)
            t_me_in = _travel_time(before + m0 - 2 * half, v_me, IDM_ACC)
            t_me_out = _travel_time(before + m1 + 2 * half, v_me, GAP_ACCEL_MPS2, v_turn)
            # (distance of the vehicle centre to the zone start, vehicle)
            through = [(d + c0, v) for d, v in env.rules.traffic_towards(c, exclude=ego)]
            for d_in, v in through:
                d_out = d_in + (c1 - c0) + v.LENGTH
                if d_out <= 0:
                    continue  # already through
                if yielding and env.rules.yields_to_reservation(v, c):
                    continue
                sp = max(float(getattr(v, "speed", 0.0)), 0.0)
                # it may speed up, to its lane's speed limit (IDM's target), not beyond
                lane = net.lane_of.get(net.id_of.get(getattr(v, "lane_index", None)))
                t_in = _travel_time(d_in - v.LENGTH / 2, sp, IDM_ACC, max(sp, lane.speed_limit if lane else sp))
                t_out = d_out / sp if sp > 0.1 else math.inf
                if not (t_in >= t_me_out + GAP_MARGIN_S or t_out + GAP_MARGIN_S <= t_me_in):
                    return False
        return True

    def _deciding(self) -> bool:
        """The unprotected left is within its decision distance of the line: CREEP_TRIGGER_M, or
        farther when the ego needs more than that to stop comfortably."""
        ego = self.env.vehicle
        return self._line_distance() <= max(CREEP_TRIGGER_M, braking_distance(max(ego.speed, 0.0), ego.LENGTH))

    def _decide(self, d_line: float) -> bool:
        """The unprotected left's go decision at `d_line` from the line (`self.go`): the signal
        and pedestrians let it past and `_gap_ok` finds a gap; a decision to go stands once the
        ego's front can no longer stop comfortably before the line. A standing ego always re-takes
        it (a go held by an amber 3 m before the line stood through the red and sent the ego
        across the oncoming traffic at the next green: four_way_crossing r009)."""
        ego = self.env.vehicle
        if not (self.go and not can_stop_before(d_line, ego.speed, ego.LENGTH)):
            free = self.env.rule_stop_distance(self.ignore | {"conflict"}) > d_line + 0.5
            self.go = free and (self._gap_ok() or self._forces())
            if not self.go:  # a reservation made while it meant to go would hold up the traffic it now waits for
                self.env.give_up(self.j_lane)
        return self.go

    def _forces(self) -> bool:
        """After PATIENCE_S held at the line by traffic, the unprotected entry takes its lane by
        reserving it when the gap acceptance finds a gap among the vehicles that would not wait
        for that reservation (those inside the junction, holding their lane, or too close to stop
        comfortably): a steady stream with the right of way (an entry into a bare junction's
        busy exit, an unprotected left at a signal waiting 70 s: issue 21) is then a decision,
        not a timeout; everyone it relies on waiting does so by the rules."""
        return "conflict" not in self.ignore and self.held >= PATIENCE_S and \
            self.env.rules.box_clear(self.env.vehicle, self.j_lane) and self._gap_ok(yielding=True)

    def _curve_speeds(self, lane_id: str) -> tuple[np.ndarray, np.ndarray]:
        """(s, comfortable speed) at the vertices of a lane (`lanes.curve_speeds`, traffic's rule too)."""
        lane = self.env.net.lane_of[lane_id]
        return lane.cum, curve_speeds(lane)

    def _curve_acceleration(self) -> float:
        """Deceleration that brings the ego to each upcoming curve at its comfortable speed
        (inf when no curve ahead is slower than the ego)."""
        ego = self.env.vehicle
        v = max(ego.speed, 0.0)
        a = math.inf
        for _, lid, d, s_own in ego.upcoming(CURVE_LOOKAHEAD_M):
            s, speed = self._curve_speeds(lid)
            x = s - s_own if s_own is not None else s + d
            ahead = (x >= -CURVE_BEHIND_M) & (x <= CURVE_LOOKAHEAD_M) & (speed < v)
            if ahead.any():
                need = (v * v - speed[ahead] ** 2) / (2 * np.maximum(x[ahead], 1.0))
                a = min(a, -float(need.max()))
        return a

    def _amber_acceleration(self) -> float:
        """Deceleration that keeps the ego, approaching a green signal, out of its dilemma zone
        (`rules.amber_speed_cap`): wherever an amber beginning there would leave it too slow to
        cross before red, given the turn's curve speed it slows to behind the line, it is slow
        enough to stop instead (inf when no such point ahead is slower than the ego). The amber
        decision (`rules.stops_at_amber`) then stays right for a planner that brakes for its turn."""
        env = self.env
        if "signal" in self.ignore:
            return math.inf
        if self.stage == "LF":  # (the junction is selected SELECT_DISTANCE_M before its line: too late)
            sl, _, j_lane, d = env.rules.line_ahead(env.vehicle, AMBER_LOOKAHEAD_M)
            if sl is None or sl.kind != "signal" or env.rules.signal_state(sl.control_id) != "green":
                return math.inf
        elif self.stage in APPROACH_STAGES and self._signal_state() == "green":
            j_lane, d = self.j_lane, self._line_distance()
        else:
            return math.inf
        if j_lane is None or not 0.0 < d <= AMBER_LOOKAHEAD_M:
            return math.inf
        v = max(env.vehicle.speed, 0.0)
        v_line = min(float(self._curve_speeds(j_lane)[1].min()), env.net.lane_of[j_lane].speed_limit)
        amber = float(env.config["signal_amber"]) - 1.0 / float(env.config["policy_frequency"])  # decided a step late
        x = np.arange(d, 0.0, -1.0)
        cap = amber_speed_cap(x, v, v_line, amber)
        ahead = cap < v
        if not ahead.any():
            return math.inf
        need = (v * v - cap[ahead] ** 2) / (2 * np.maximum(d - x[ahead], 1.0))
        return -float(need.max())

    # ---- control ---------------------------------------------------------------------------
    def _acceleration(self) -> float:
        return min(self._rule_acceleration(), self._curve_acceleration(), self._amber_acceleration())

    def _rule_acceleration(self) -> float:
        env = self.env
        ego = env.vehicle
        stage = self.stage
        if stage == "R_C" and self._right_on_red() and self._signal_state() == "red" and \
                (not self.full_stop or self._cross_traffic_near()):
            stop = self._line_distance() - 1.0
        elif stage in ("L_A", "L_C") and "conflict" not in self.ignore and self._deciding():
            # the unprotected left's gap acceptance (scenarios/README.md): past the line only when
            # the signal and pedestrians allow and its own prediction finds a gap in the oncoming
            # and crossing traffic (the env's conflict rule, which also waits for vehicles already
            # past the conflict, is then overruled and the junction lane reserved); re-taken every
            # step until the ego can no longer stop before the line
            d_line = self._line_distance()
            env.claim_passages()  # queue for the narrow passages ahead while deciding (first come first served)
            if self._decide(d_line):
                return idm(ego, env.leader_gaps(), env.claim(self.ignore | {"conflict"}))
            stop = min(env.rule_stop_distance(self.ignore), d_line - STOP_POINT_M)
        elif stage in ("B_A", "M_G") and self._forces():
            stop = env.claim(self.ignore | {"conflict"})  # reserves its lane
        else:
            stop = env.claim(self._rule_ignore())
        a = idm(ego, env.leader_gaps(), stop)
        v = max(ego.speed, 0.0)
        if stage == "S_S" or (stage == "R_S" and self._in_stop_zone() and self._signal_state() != "green"):
            return min(a, HOLD_BRAKE_MPS2) if v > 0 else min(a, 0.0)
        if stage in ("S_C", "L_C", "R_C") and self._line_distance() <= CREEP_TRIGGER_M:
            return min(a, CREEP_GAIN * (CREEP_SPEED_MPS - v))
        if stage in ("B_A", "D_A") and self._line_distance() <= BARE_APPROACH_M:
            v_j = env.net.lane_of[self.j_lane].speed_limit
            return min(a, CREEP_GAIN * (v_j - v))
        return a


def _travel_time(distance: float, speed: float, accel: float, v_max: float = math.inf) -> float:
    """Seconds to cover `distance` from `speed`, accelerating at `accel` up to `v_max` (0 if behind)."""
    if distance <= 0:
        return 0.0
    speed = min(speed, v_max)
    d_acc = (v_max * v_max - speed * speed) / (2 * accel) if v_max < math.inf else math.inf
    if distance <= d_acc:
        return (-speed + math.sqrt(speed * speed + 2 * accel * distance)) / accel
    return (v_max - speed) / accel + (distance - d_acc) / v_max


class CallablePolicy:
    """A Policy from a plain function `obs -> action` or `(obs, info) -> action`, told apart
    by its signature (two or more positional parameters, or *args: it gets `info` too)."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn
        self.with_info = takes_info(fn)

    def reset(self, env: Any) -> None:
        return None

    def act(self, obs: Any, info: dict) -> Any:
        return self.fn(obs, info) if self.with_info else self.fn(obs)


def takes_info(fn: Callable[..., Any]) -> bool:
    """Whether a policy callable takes `(obs, info)` rather than `(obs)`."""
    import inspect

    try:
        params = inspect.signature(fn).parameters.values()
    except (TypeError, ValueError):  # no signature (some builtins): the documented minimum
        return False
    positional = [p for p in params if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
    return len(positional) >= 2 or any(p.kind == p.VAR_POSITIONAL for p in params)


class ModelPolicy:
    """A Policy from a Stable-Baselines3-style model: `model.predict(obs, deterministic=True)`."""

    def __init__(self, model: Any, deterministic: bool = True) -> None:
        self.model = model
        self.deterministic = deterministic

    def reset(self, env: Any) -> None:
        return None

    def act(self, obs: Any, info: dict) -> Any:
        action, _ = self.model.predict(obs, deterministic=self.deterministic)
        return action


def as_policy(obj: Any) -> Policy:
    """A Policy from a Policy (returned as is), an SB3-style model (`.predict`), or a callable
    obs -> action; anything else is a TypeError."""
    if hasattr(obj, "act") and hasattr(obj, "reset"):
        return obj
    if hasattr(obj, "predict"):
        return ModelPolicy(obj)
    if callable(obj):
        return CallablePolicy(obj)
    raise TypeError(f"cannot use {type(obj).__name__} as a policy: expected a Policy, a model with "
                    f".predict, or a callable obs -> action or (obs, info) -> action")
