"""Traffic control devices and their state during an episode: fixed-time signal phase plans
(phases grouped by the map library's `feat2map.phases`, shared with the exports), junction
reservations, narrow passages and crosswalk pedestrians (the stop-sign queues and the narrow
passages' holders and waiters are arrays of the core: `sim.stop_signs`, `sim.passages`).
`TrafficControl` inherits the rules' questions (`rules.TrafficRules`, pure) that traffic, the
ego's judge and planners ask of it, and is the one place that writes that state: what a road
user takes (`claim`: its reservations and its place at narrow passages) and the bookkeeping
after every simulation frame (`update`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any, Sequence

import numpy as np

from ..config import STOP_POINT_M
from ..phases import junction_phases
from .network import MapNetwork
from .reservations import LEFT_HOLDER
from .rules import SIGNAL_STATES, Claims, TrafficRules, beyond, commits, enters_next
from .sim import passages, pedestrians, stop_signs
from .vehicles import Pedestrian


@dataclass(frozen=True)
class PhasePlan:
    """Fixed-time plan of one signalized junction: each phase (a group of approaches) green in
    turn, then amber, then all-red. Paired phases give opposite approaches green together, with
    left turns unprotected (they yield through the conflict table); single phases protect all."""

    phases: tuple[tuple[str, ...], ...]  # signal ids per phase
    green: float
    amber: float
    all_red: float
    offset: float

    @cached_property
    def cycle(self) -> float:
        return len(self.phases) * (self.green + self.amber + self.all_red)

    @cached_property
    def _phase(self) -> dict[str, int]:
        return {sid: i for i, p in enumerate(self.phases) for sid in p}

    def phase_of(self, signal_id: str) -> int:
        return self._phase[signal_id]

    def state(self, signal_id: str, t: float) -> str:
        """The signal's state at time `t` (`signal_timing` of it alone)."""
        return SIGNAL_STATES[int(signal_timing(np.array([t]), self.column(signal_id)[:, None])[0][0])]

    def time_to_change(self, signal_id: str, t: float) -> float:
        """Seconds from time `t` until the signal's state changes (`signal_timing` of it alone)."""
        return float(signal_timing(np.array([t]), self.column(signal_id)[:, None])[1][0])

    def column(self, signal_id: str) -> np.ndarray:
        """(offset, cycle, start of the signal's phase in the cycle, green, green + amber): the
        signal's column of `signal_arrays`."""
        slot = self.green + self.amber + self.all_red
        return np.array((self.offset, self.cycle, self.phase_of(signal_id) * slot, self.green, self.green + self.amber))


def signal_arrays(control: "TrafficControl", signal_ids: list[str]) -> np.ndarray:
    """[5, signals] (offset, cycle, start of the signal's phase in the cycle, green, green +
    amber) of `signal_ids` under `control`'s plans (a signal without a plan: always green), so
    that `signal_timing` gives the states of many signals at once; built once per control (episode)."""
    held = control._signal_arrays
    if held is not None and held[0] is signal_ids:
        return held[1]
    out = no_plans(len(signal_ids))
    for k, sid in enumerate(signal_ids):
        plan = control.plans.get(sid)
        if plan is not None:
            out[:, k] = plan.column(sid)
    control._signal_arrays = (signal_ids, out)
    return out


def no_plans(n: int) -> np.ndarray:
    """`signal_arrays` of `n` signals without a plan: green for ever (a cycle of 1 s, all of it
    green, never changing)."""
    out = np.zeros((5, n))
    out[1] = 1.0
    out[3] = out[4] = np.inf
    return out


def signal_timing(t: np.ndarray, arrays: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(the states as codes of SIGNAL_STATES: 0 green, 1 amber, 2 red; the seconds until each
    changes) of signals at times `t` (columns of `signal_arrays`: their plans; broadcast
    together): the one program of a fixed-time plan, each phase green in turn, then amber, then
    all-red."""
    offset, cycle, start, green, amber_end = arrays
    into = ((t + offset) % cycle - start) % cycle  # (time into the signal's own phase)
    state = (into >= green).astype(np.int8) + (into >= amber_end)
    return state, np.where(into < green, green, np.where(into < amber_end, amber_end, cycle)) - into


def signal_tables(net: MapNetwork, paired: bool) -> tuple[dict, list]:
    """({junction: sorted signal ids}, [(junction, phases)] in junction order) of a network's
    signals (per network and phase mode: the same every episode)."""
    ids: dict[str | None, list[str]] = {}
    for sig in net.hdmap.signals.values():
        ids.setdefault(sig.junction_id, []).append(sig.id)
    phases = junction_phases(net.hdmap, paired)
    return {j: sorted(x) for j, x in ids.items()}, [(jid, phases[jid]) for jid in sorted(phases, key=str)]


def episode_key(rng: np.random.Generator) -> int:
    """The key of an episode's counter-based draws (`sim.random`): read from `rng`'s state, so
    that the episode's other draws (traffic) come out of `rng` as they would without it."""
    state = rng.bit_generator.state["state"]
    words = state.values() if isinstance(state, dict) else [state]
    return int(np.random.SeedSequence([int(w) for w in words]).generate_state(1, np.uint64)[0])


class TrafficControl(TrafficRules):
    """Signals, junction reservations, passages and crosswalk pedestrians of one episode."""

    _signal_arrays: tuple | None = None  # (signal ids, `signal_arrays` of them), made on first use

    def __init__(self, net: MapNetwork, rng: np.random.Generator, cfg: dict) -> None:
        self.net = net
        self._t = 0.0  # the clock until a road holds it (`t`)
        self._buckets: tuple[int, dict[str, list]] | None = None  # (the slot's `moves` they were made at, buckets)
        self.cfg = cfg
        self.plans: dict[str, PhasePlan] = {}
        self.signals_by_junction, grouped = net.memo(("phases", cfg["signal_phases"]),
                                                     lambda: signal_tables(net, cfg["signal_phases"] == "paired"))
        g, a, r = cfg["signal_green"], cfg["signal_amber"], cfg["signal_all_red"]
        fixed = cfg.get("signal_offsets") or {}  # by junction id, or by any of its signal ids
        for jid, phases in grouped:
            offset = float(rng.uniform(0, len(phases) * (g + a + r)))
            key = next((k for k in [jid, *self.signals_by_junction[jid]] if k is not None and str(k) in fixed), None)
            if key is not None:
                offset = float(fixed[str(key)])
            plan = PhasePlan(phases, g, a, r, offset)
            for phase in phases:
                for sid in phase:
                    self.plans[sid] = plan
        self.road: Any = None  # the road whose rows hold the stop-sign queues (`MapRoad` sets it)
        self.pedestrians: dict[str, list[Pedestrian]] = {}  # by crosswalk, the walkers' views (`sim.pedestrians`)
        self._active_crosswalks: list[str] = []
        self.key = episode_key(rng)  # of the episode's counter-based draws (`sim.random`)
        self._claims: Claims = []  # what the claim being made takes (`claim`)

    @property
    def t(self) -> float:
        """The rules' clock, seconds into the episode: its road's slot's in the core
        (`TrafficCore.clock`, which a frame advances for every slot at once)."""
        road = self.road
        return float(road.core.clock[road.slot]) if road is not None else self._t

    @t.setter
    def t(self, value: float) -> None:
        road = self.road
        if road is None:
            self._t = float(value)
        else:
            road.core.clock[road.slot] = value

    @property
    def active_crosswalks(self) -> list[str]:
        """The crosswalks pedestrians step out on (the route's junctions' and the mid-block ones
        it crosses); setting them starts their spawning in the road's core (`sim.pedestrians`)."""
        return self._active_crosswalks

    @active_crosswalks.setter
    def active_crosswalks(self, ids: list[str]) -> None:
        self._active_crosswalks = list(ids)
        cfg = self.cfg
        chance = float(cfg["pedestrian_rate"]) / 60.0 / float(cfg["simulation_frequency"])  # per crosswalk and frame
        self.road.core.set_crosswalks(self.road.slot, self._active_crosswalks, self.key, chance,
                                      int(cfg["pedestrians_per_crosswalk"]))

    # ---- claims: the one update of rule state -------------------------------------------
    def claim(self, vehicle, ignore: frozenset = frozenset(), scan: tuple | None = None) -> float:
        """The one update of rule state by one road user, from its place and speed (in a frame of
        traffic, each row whose answer takes something, in row order after every row has asked:
        `core.TrafficCore._rule_stops`; a controlled row when its driver claims,
        `map_env.EgoTask.claim`), in this order: its place at the narrow passages ahead
        (`claim_passages`); while it waits for one, the junction lane beyond that wait it gives up
        (`_unreserve_beyond`); then its walk along the route (`_rule_stop`): the junction lanes the
        rules let it enter, reserved within commit distance of their line, and on red the one it
        gives up. Returns its stop distance, as `stop_distance` (with `ignore` and `scan`) finds it
        on the way. A vehicle waiting for a passage reserves the junction lanes before that wait
        (unseen by the rules, it drove into a junction in which a car from the other side then
        took a lane conflicting with its own: Testfeld_Karlsruhe r046), and none beyond it."""
        passage = math.inf if "passage" in ignore else self.claim_passages(vehicle)
        if passage < math.inf:
            self._unreserve_beyond(vehicle, passage)
        claims = self._claims  # (one list, used again: no object per claim for the cyclic GC to count)
        stop = self._stop_within(vehicle, ignore, passage, scan, claims)
        self.apply(vehicle, claims)
        claims.clear()
        return stop

    def apply(self, vehicle, claims: Claims) -> None:
        """What a claim's walk recorded (`claims`, in its order), taken: reserve, or give up."""
        for op, j_lane, chain in claims:
            if op == "reserve":
                self._reserve(vehicle, j_lane, chain)
            else:
                self.release(vehicle, j_lane)

    def claim_passages(self, vehicle) -> float:
        """`passage_stop`, and `vehicle` takes its place at the passages ahead (as a holder or a
        waiter, `_enrol`) once within commit distance of its wait: first come first served."""
        nxt = self.passage_way(vehicle) if self.net.passages else None
        if nxt is None:
            return math.inf
        chain, wait, room = nxt
        ok = self.passage_allows(vehicle, chain)
        if commits(wait + STOP_POINT_M, vehicle.speed):
            self._enrol(vehicle, chain, ok, room)
        return math.inf if ok else wait

    def _enrol(self, vehicle, chain: list[tuple[int, int]], ok: bool, room: tuple[int, int] | None) -> None:
        """`vehicle` takes its place at the passages of `chain` (`sim.passages.enrol`): allowed
        (`ok`), among the holders of all and the place to wait before passage `room`
        (`passage_way`'s third item); else among the waiters of all, standing in the room before
        the first."""
        core = self.road.core
        r = core.user_row(vehicle)
        if r < 0:
            raise ValueError(f"{vehicle!r} is no road user of this road's rows: it cannot take a place at a passage")
        passages.enrol(core, r, chain, ok, room, self.t)

    def passage_start(self, vehicle) -> bool:
        """Whether a vehicle just placed on the road (the ego at reset, traffic at a spawn) may
        be there: the passages it starts in or is about to enter, with those chained after them,
        are not held from the other direction; it then holds them."""
        nxt = self.passage_way(vehicle, entered=True) if self.net.passages else None
        if nxt is None or not commits(nxt[1] + STOP_POINT_M, vehicle.speed):
            return True
        ok = self.passage_allows(vehicle, nxt[0])
        if ok:
            self._enrol(vehicle, nxt[0], True, nxt[2])
        return ok

    def _unreserve_beyond(self, vehicle, wait: float) -> None:
        """Give up `vehicle`'s reservation of a junction lane that begins beyond its wait for a
        narrow passage (`wait` metres ahead): it will not enter that lane until the passage is its
        own, and the reservation kept the passage's holder, whose way out crossed that lane, from
        coming through (digitaf r025: a car reserved its lane into the passage while the passage
        was free, then waited before it: the holder from the other side waited for the lane)."""
        lane = getattr(vehicle, "reserved", None)
        holder = self.reservations.get(lane) if lane is not None else None
        if holder is None or holder is not vehicle:
            return
        for _k, lid, d, s_own in vehicle.upcoming(wait + vehicle.LENGTH):
            if lid == lane:
                if s_own is None and beyond(d, wait):
                    self.release(vehicle, lane)
                return

    def release(self, vehicle, j_lane: str) -> None:
        """Give up `vehicle`'s reservation of `j_lane` and the lanes chained after it in its
        junction (if it holds them): it will not enter now (one that holds nothing skips the
        chain)."""
        if self.reservations.held_by(vehicle):
            for x in self.junction_chain(vehicle, j_lane):
                if x in self.reservations and self.reservations[x] is vehicle:
                    del self.reservations[x]
        if vehicle.reserved == j_lane:
            vehicle.reserved = None

    def hand_over(self, j_lane: str) -> None:
        """A reservation of junction lane `j_lane` was given up: the road user that followed its
        holder past the line and can no longer stop before it takes it over (with its chain),
        nearest the lane first. It found the lane reserved when it committed, so it claimed
        nothing, and a lower-priority lane unreserved and not yet entered is invisible to cross
        traffic's `junction_clear`: GoMentum's base_map r002, a car behind its leader into a
        permissive left turn was hit by the ego going straight on the lane the leader's release
        let it reserve."""
        committed = []
        for p in self.net.hdmap.lanes[j_lane].predecessors:
            for v in self.buckets.get(p, ()):
                if enters_next(v, j_lane) and not self.can_still_stop(v, j_lane):
                    committed.append((self.line_distance(v, j_lane), v))
        if committed:
            _, v = min(committed, key=lambda dv: dv[0])
            self._reserve(v, j_lane, self.junction_chain(v, j_lane))

    def _reserve(self, vehicle, j_lane: str, chain: tuple[str, ...]) -> None:
        """`vehicle` reserves junction lane `j_lane` and `chain` (the lanes it holds keep their holders)."""
        for x in chain:
            self.reservations.setdefault(x, vehicle)
        vehicle.reserved = j_lane

    # ---- per-frame bookkeeping -------------------------------------------------------------
    def update(self, road, dt: float) -> None:
        """Advance the clock by `dt` and bring the state up to date with the road's vehicles, for
        this road alone (a reset's bookkeeping; `TrafficCore.step` does the same for all roads of
        a frame at once): take in what user code added or removed, the stop-sign queues, the
        pedestrians, the clock (`TrafficCore.tick`), then `bookkeeping`."""
        road.sync()
        core = road.core
        mine = np.arange(len(core.roads)) == road.slot
        stop_signs.update(core, mine[core.env])
        pedestrians.update(core, dt, mine)
        looks = core.release_looks(mine).get(road.slot, ())
        core.tick(mine, dt)
        self.bookkeeping(looks)

    def bookkeeping(self, looks: Sequence[str] = ()) -> None:
        """After a frame, the reservations of `looks` (`TrafficCore.release_looks`) released where
        their holder left the road or drove through the lane, a committed follower taking over
        (`hand_over`); the narrow passages' holders and waiters."""
        for lid in looks:
            v: Any = self.reservations.get(lid)
            left = v is LEFT_HOLDER
            if left or v is not None and self._passed(v, lid):
                del self.reservations[lid]
                if not left and v.reserved == lid:
                    v.reserved = None
                self.hand_over(lid)
        if self.net.passages:
            self._update_passages(self.buckets, set(map(id, self.road.vehicles)))

    def _passed(self, vehicle, lane: str) -> bool:
        """Whether `vehicle` has driven through `lane` (on its route before its place) and is no
        longer on it."""
        net = self.net
        on = lane in (net.id_of.get(vehicle.lane_index),
                      getattr(vehicle, "lane_route", [None])[getattr(vehicle, "route_pos", 0)])
        return hasattr(vehicle, "lane_route") and lane in vehicle.lane_route[:vehicle.route_pos] and not on

    @property
    def buckets(self) -> dict[str, list]:
        """The road users on each lane (what the rules' occupancy questions read), made from the
        road's rows when first asked after its rows moved, came or went (`TrafficCore.moves`):
        most frames of a batch, most slots ask none."""
        road = self.road
        at = int(road.core.moves[road.slot])
        held = self._buckets
        if held is None or held[0] != at:
            held = self._buckets = (at, road.core.buckets(road))
        return held[1]

    def _update_passages(self, buckets: dict, alive: set) -> None:
        """Road users within a narrow passage hold it from their side; holders and waiters whose
        route no longer leads into it let go (one that left the road let go with its row), and so
        do holders whose rear has passed the passage's end (one standing beyond it, at the
        junction after it, held it against the car waiting to come the other way: digitaf r025),
        and those that drove through it and out onto a road lane beyond it, where their route
        loops back into it, unless a new claim would hold it now (a car circling a block held the
        passage from behind the cars waiting for it: Testfeld_Karlsruhe r142; dropped as it came
        round again, its claim was lost to a car from the other side: digitaf r022). A place to
        wait before a passage (`sim.passages.places`) is given up on holding that passage or
        leaving its way. `alive`: the ids of the road's road users (one removed since the rows
        were last brought in line lets go too)."""
        net = self.net
        lanes = net.hdmap.lanes
        core = self.road.core
        for lid, users in buckets.items():
            ps = net.passages.get(lid)
            if ps is None:
                continue
            for v in users:
                s = v.s_on(lid)
                if ps.s0 - v.LENGTH / 2 <= s <= ps.s1 + v.LENGTH / 2:
                    passages.hold(core, core.user_row(v), ps.group, ps.side)

        def ahead(r: int, group: int, side: int) -> bool:  # the passage is on the rest of its route
            v = core.objs[r]
            if id(v) not in alive:
                return False
            route = getattr(v, "lane_route", None)
            if route is None:
                lid = net.id_of.get(getattr(v, "lane_index", None))
                ps = net.passages.get(lid) if lid is not None else None
                return ps is not None and ps.group == group
            here = route[v.route_pos]
            if lanes[here].junction_id is None and getattr(net.passages.get(here), "group", None) != group and \
                    any(getattr(net.passages.get(x), "group", None) == group and net.passages[x].side == side
                        for x in route[:v.route_pos]):
                # through it and out on the road beyond: it holds it again only as a new claim would
                # (near its wait for the loop back into it, and nobody from the other side first)
                nxt = self.passage_ahead(v, entered=True)
                return nxt is not None and (group, side) in nxt[0] and \
                    commits(nxt[1] + STOP_POINT_M, v.speed) and self.passage_allows(v, nxt[0])
            for k, lid in enumerate(route[v.route_pos:]):
                ps = net.passages.get(lid)
                if ps is not None and ps.group == group and ps.side == side and \
                        (k > 0 or v.s_on(lid) - v.LENGTH / 2 <= ps.s1):
                    return True  # not yet out of it: its rear has not passed the passage's end
            return False

        slot = self.road.slot
        gone = False  # whether anyone let go (the emptied places are dropped then)
        for g in passages.in_use(core, slot, "pe_hold"):
            for side in (0, 1):
                for r in [r for r in passages.holders(core, slot, g, side).tolist() if not ahead(r, g, side)]:
                    passages.let_go(core, r, g, "pe_hold", side)
                    gone = True
        for g in passages.in_use(core, slot, "pe_wait"):
            rows, sides, _ = passages.waiters(core, slot, g)
            for r in [r for r, side in zip(rows.tolist(), sides.tolist()) if not ahead(r, g, side)]:
                passages.let_go(core, r, g, "pe_wait")
                gone = True
        for g in passages.in_use(core, slot, "pe_room"):  # a place to wait is given up on holding or leaving the way
            for side in (0, 1):
                for r in [r for r in passages.places(core, slot, g, side).tolist()
                          if passages.holds(core, r, g, side) or not ahead(r, g, side)]:
                    passages.let_go(core, r, g, "pe_room", side)
                    gone = True
        if gone:
            passages.prune(core)
