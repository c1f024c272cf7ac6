"""Fixed-time signal phases of a junction: which of its signals show green together.

One rule for every user of the map's signals (the env's phase plans, the CommonRoad and
OpenSCENARIO exports' light cycles, the scenario durations), conflict-free by construction for
any leg geometry:

- the signals of one approach (their governed lanes on one road, or lane neighbours) always
  share a phase; so do the signals of a group the map declares (an OpenDRIVE `<controller>`,
  `HDMap.meta["signal_groups"]`) when that group's own paths do not conflict (one that does is
  reported by `declared_group_conflicts` and split into its approaches);
- two units share a phase only when none of their junction paths conflict: two junction lanes
  conflict when their centrelines cross or they end in the same exit lane (a merge);
- `paired` plans let left turns and U-turns of *opposed* units go permissive (they yield through
  the env's conflict table, as at any junction with permitted lefts): two units are opposed when
  both have a straight path and no straight path of one conflicts with one of the other;
- units are placed first-fit in the order of their first signal id; `single` plans give each
  unit a phase of its own (every manoeuvre protected).

Signals that govern no lane with a path into their junction have nothing to compare: they are
grouped by the direction they face (`group_phases`, a heuristic used only where the map tells
nothing else) and given phases of their own.

A phase is green, then amber, then all-red, phases in turn, the first phase green from time 0
(`timeline`). The lights of mid-block crossings (outside junctions) share one plan, which ends
with an empty phase for the people crossing (`junction_phases`).
"""
from __future__ import annotations

import math
from typing import Iterable, Mapping

from .angles import wrap_angle
from .config import SIGNAL_ALL_RED_S, SIGNAL_AMBER_S, SIGNAL_GREEN_S, SIGNAL_OPPOSITE_DEG, SIGNAL_SAME_APPROACH_DEG
from .model import HDMap, Signal, incoming_lanes, midblock_controls

Phases = tuple[tuple[str, ...], ...]
PERMISSIVE_TURNS = ("left", "uturn")  # turns that yield to opposed traffic in a paired plan


def group_phases(signals: Iterable[Signal], paired: bool,
                 travel: Mapping[str, float] | None = None) -> Phases:
    """Phases of signals by direction alone (the heuristic for signals without paths): signals
    whose traffic travels within `SIGNAL_SAME_APPROACH_DEG` of one direction share a phase; when
    `paired`, opposite directions share one too. `travel` gives each signal's direction of travel
    (from the lanes it governs); without it, the direction is opposite the way the signal faces."""
    sigs = sorted(signals, key=lambda g: g.id)
    travel = travel or {}
    heading = {g.id: travel.get(g.id, g.heading + math.pi) for g in sigs}

    def apart(a: float, b: float) -> float:  # angle between two directions, 0..pi
        return abs(wrap_angle(a - b))

    approaches: list[list[str]] = []
    for g in sigs:
        same = next((a for a in approaches
                     if apart(heading[a[0]], heading[g.id]) < math.radians(SIGNAL_SAME_APPROACH_DEG)), None)
        if same is None:
            approaches.append([g.id])
        else:
            same.append(g.id)
    if not paired:
        return tuple(tuple(a) for a in approaches)
    phases, used = [], set()
    for i, a in enumerate(approaches):
        if i in used:
            continue
        used.add(i)
        group = list(a)
        for j, b in enumerate(approaches):
            if j not in used and apart(heading[a[0]], heading[b[0]]) > math.radians(SIGNAL_OPPOSITE_DEG):
                group += b
                used.add(j)
                break
        phases.append(tuple(group))
    return tuple(phases)


def travel_headings(hdmap: HDMap, signals: Iterable[Signal]) -> dict[str, float]:
    """Direction of travel (map frame) at the end of the first lane each signal governs."""
    out = {}
    for g in signals:
        lane = next((hdmap.lanes[l] for l in g.lane_ids if l in hdmap.lanes), None)
        if lane is not None and len(lane.centerline) >= 2:
            (x0, y0), (x1, y1) = lane.centerline[-2][:2], lane.centerline[-1][:2]
            out[g.id] = math.atan2(y1 - y0, x1 - x0)
    return out


# ---------------------------------------------------------------------------- path conflicts

def signal_paths(m: HDMap, sig: Signal) -> tuple[str, ...]:
    """The junction lanes traffic stopped by `sig` drives next: the successors, in its junction,
    of the incoming lanes it governs."""
    out: dict[str, None] = {}
    for lid in incoming_lanes(m.lanes, sig.lane_ids):
        for s in m.lanes[lid].successors:
            ln = m.lanes.get(s)
            if ln is not None and ln.junction_id is not None and (sig.junction_id is None or ln.junction_id == sig.junction_id):
                out[s] = None
    return tuple(out)


class PathConflicts:
    """Which junction lanes of one map conflict (cross or merge), computed on demand and kept."""

    def __init__(self, m: HDMap) -> None:
        self.m = m
        self._lines: dict[str, object] = {}
        self._pairs: dict[tuple[str, str], bool] = {}

    def _line(self, lid: str):
        from shapely.geometry import LineString

        if lid not in self._lines:
            self._lines[lid] = LineString(self.m.lanes[lid].centerline)
        return self._lines[lid]

    def conflict(self, a: str, b: str) -> bool:
        """Paths `a` and `b` conflict: they merge into one lane or their centrelines cross;
        paths from one lane (a diverge) never do."""
        if a == b:
            return False
        key = (a, b) if a < b else (b, a)
        hit = self._pairs.get(key)
        if hit is None:
            la, lb = self.m.lanes[a], self.m.lanes[b]
            if set(la.predecessors) & set(lb.predecessors):
                hit = False
            else:
                hit = bool(set(la.successors) & set(lb.successors)) or self._line(a).intersects(self._line(b))
            self._pairs[key] = hit
        return hit


def _opposed(pc: PathConflicts, a: tuple[str, ...], b: tuple[str, ...]) -> bool:
    straight = lambda ps: [p for p in ps if pc.m.lanes[p].turn == "none"]  # noqa: E731
    sa, sb = straight(a), straight(b)
    return bool(sa and sb) and not any(pc.conflict(p, q) for p in sa for q in sb)


def units_conflict(pc: PathConflicts, a: tuple[str, ...], b: tuple[str, ...], paired: bool) -> tuple[str, str] | None:
    """The first pair of conflicting paths of two units (paths tuples), or None. In a `paired`
    plan the left turns and U-turns of opposed units are permissive and not counted."""
    permissive = paired and _opposed(pc, a, b)
    for p in a:
        for q in b:
            if permissive and (pc.m.lanes[p].turn in PERMISSIVE_TURNS or pc.m.lanes[q].turn in PERMISSIVE_TURNS):
                continue
            if pc.conflict(p, q):
                return p, q
    return None


def _approach_units(m: HDMap, sigs: list[Signal]) -> list[list[str]]:
    """Signal ids joined into approaches: signals whose governed lanes share a road or are lane
    neighbours (one approach of a map with a head per lane), in the order of first signal id."""
    parent = {g.id: g.id for g in sigs}

    def find(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    owner: dict[str, str] = {}
    for g in sigs:
        for lid in incoming_lanes(m.lanes, g.lane_ids):
            ln = m.lanes[lid]
            for key in (f"road:{ln.road_id}", f"lane:{lid}", *(f"lane:{x}" for x in ln.left_neighbors + ln.right_neighbors)):
                if key in owner:
                    a, b = find(owner[key]), find(g.id)
                    if a != b:
                        parent[max(a, b)] = min(a, b)
                else:
                    owner[key] = g.id
    groups: dict[str, list[str]] = {}
    for g in sigs:
        groups.setdefault(find(g.id), []).append(g.id)
    return sorted(groups.values(), key=lambda u: u[0])


def declared_groups(m: HDMap) -> list[tuple[str, tuple[str, ...]]]:
    """The signal groups the map declares (`meta["signal_groups"]`: group id -> signal ids that
    switch together), restricted to the map's signals."""
    raw = m.meta.get("signal_groups") if isinstance(m.meta, Mapping) else None
    if not isinstance(raw, Mapping):
        return []
    out = []
    for gid, ids in raw.items():
        ids = tuple(x for x in (ids if isinstance(ids, (list, tuple)) else ()) if x in m.signals)
        if len(ids) > 1:
            out.append((str(gid), ids))
    return out


def _unit_paths(m: HDMap, sids: Iterable[str]) -> list[tuple[list[str], tuple[str, ...]]]:
    """The approach units of signals `sids` with each unit's paths."""
    sigs = [m.signals[s] for s in sids if s in m.signals]
    return [(u, tuple(dict.fromkeys(p for s in u for p in signal_paths(m, m.signals[s]))))
            for u in _approach_units(m, sigs)]


def _unit_clashes(pc: PathConflicts, units: list[tuple[list[str], tuple[str, ...]]],
                  paired: bool) -> list[tuple[str, str, str]]:
    """(signal of one unit, signal of another, why) for every two units whose paths conflict."""
    out = []
    for i, (u, pu) in enumerate(units):
        for v, pv in units[i + 1:]:
            if m_junction(pc.m, u) != m_junction(pc.m, v):
                continue
            hit = units_conflict(pc, pu, pv, paired)
            if hit is not None:
                out.append((u[0], v[0], f"paths {hit[0]} and {hit[1]} conflict"))
    return out


def m_junction(m: HDMap, unit: list[str]) -> str | None:
    return m.signals[unit[0]].junction_id


def declared_group_conflicts(m: HDMap, pc: PathConflicts | None = None,
                             paired: bool = True) -> list[tuple[str, str, str, str]]:
    """(group id, signal a, signal b, why) for every declared group holding two approaches whose
    paths conflict (by the `paired` or single rules): the map says they switch together but
    they cannot."""
    pc = pc or PathConflicts(m)
    return [(gid, a, b, why) for gid, ids in declared_groups(m)
            for a, b, why in _unit_clashes(pc, _unit_paths(m, ids), paired)]


def signal_self_conflicts(m: HDMap, pc: PathConflicts | None = None) -> list[tuple[str, str, str, str]]:
    """(signal, road a, road b, why) for every signal that governs lanes of two roads whose paths
    conflict (paired rules): one light cannot keep them apart (a map may declare one light for
    two opposite approaches, which is fine; crossing ones are not)."""
    pc = pc or PathConflicts(m)
    out = []
    for sig in m.signals.values():
        by_road: dict[str, list[str]] = {}
        for lid in incoming_lanes(m.lanes, sig.lane_ids):
            by_road.setdefault(m.lanes[lid].road_id, []).extend(
                x for x in m.lanes[lid].successors if x in m.lanes and m.lanes[x].junction_id is not None)
        roads = sorted(by_road)
        for i, a in enumerate(roads):
            for b in roads[i + 1:]:
                hit = units_conflict(pc, tuple(by_road[a]), tuple(by_road[b]), True)
                if hit is not None:
                    out.append((sig.id, a, b, f"paths {hit[0]} and {hit[1]} conflict"))
    return out


def _junction_units(m: HDMap, sigs: list[Signal], pc: PathConflicts, paired: bool) -> list[list[str]]:
    units = _approach_units(m, sigs)
    bad = {g for g, *_ in declared_group_conflicts(m, pc, paired)}
    mine = {g.id for g in sigs}
    for gid, declared in declared_groups(m):
        ids = [x for x in declared if x in mine]
        if gid in bad or len(ids) < 2:
            continue
        hit = [u for u in units if set(u) & set(ids)]
        whole = [(u, tuple(dict.fromkeys(p for x in u for p in signal_paths(m, m.signals[x])))) for u in hit]
        if len(hit) > 1 and not any(units_conflict(pc, pu, pv, paired) is not None
                                    for i, (_, pu) in enumerate(whole) for _, pv in whole[i + 1:]):
            merged = sorted(x for u in hit for x in u)
            units = sorted([u for u in units if u not in hit] + [merged], key=lambda u: u[0])
    return units


def plan_junction(m: HDMap, sigs: Iterable[Signal], paired: bool, pc: PathConflicts | None = None) -> Phases:
    """The phases of one junction's signals (see the module docstring)."""
    sigs = sorted(sigs, key=lambda g: g.id)
    pc = pc or PathConflicts(m)
    by_id = {g.id: g for g in sigs}
    units = _junction_units(m, sigs, pc, paired)
    paths = {u[0]: tuple(dict.fromkeys(p for s in u for p in signal_paths(m, by_id[s]))) for u in units}
    blind = [s for u in units if not paths[u[0]] for s in u]
    phases: list[list[list[str]]] = []
    for u in units:
        if not paths[u[0]]:
            continue
        home = None
        if paired:
            home = next((ph for ph in phases if all(units_conflict(pc, paths[u[0]], paths[v[0]], True) is None
                                                    for v in ph)), None)
        if home is None:
            phases.append([u])
        else:
            home.append(u)
    out = [tuple(s for u in ph for s in u) for ph in phases]
    if blind:
        out += list(group_phases([by_id[s] for s in blind], False, travel_headings(m, [by_id[s] for s in blind])))
    return tuple(out)


def junction_phases(m: HDMap, paired: bool = True) -> dict[str | None, Phases]:
    """The phases of every junction's signals (signals outside junctions under key None). When
    lights of mid-block crossings are among the latter (`midblock_controls`), their plan ends
    with a pedestrian phase: one slot with every light red, while people cross."""
    by_junction: dict[str | None, list[Signal]] = {}
    for s in m.signals.values():
        by_junction.setdefault(s.junction_id, []).append(s)
    pc = PathConflicts(m)
    out = {jid: plan_junction(m, sigs, paired, pc) for jid, sigs in by_junction.items()}
    if None in out and midblock_controls(m):
        out[None] = out[None] + ((),)
    return out


def phase_conflicts(m: HDMap, phases: Mapping[str | None, Phases], paired: bool = True) -> list[tuple[str, str, str, str]]:
    """(junction, signal a, signal b, why) for every two approaches green together in a plan
    whose paths conflict (paired rules: permissive lefts of opposed approaches allowed)."""
    pc = PathConflicts(m)
    return [(str(jid), a, b, why) for jid, plan in phases.items() for ph in plan
            for a, b, why in _unit_clashes(pc, _unit_paths(m, ph), paired)]


def timeline(phase: int, n_phases: int, green: float = SIGNAL_GREEN_S, amber: float = SIGNAL_AMBER_S,
             all_red: float = SIGNAL_ALL_RED_S) -> list[tuple[str, float]]:
    """One cycle of a signal in phase `phase` of `n_phases`, from time 0: (state, seconds) with
    states green/amber/red, adjacent reds merged, zero durations dropped."""
    slot = green + amber + all_red
    out: list[tuple[str, float]] = []
    for state, d in (("red", phase * slot), ("green", green), ("amber", amber),
                     ("red", all_red + (n_phases - phase - 1) * slot)):
        if d <= 0:
            continue
        if out and out[-1][0] == state:
            out[-1] = (state, out[-1][1] + d)
        else:
            out.append((state, d))
    return out
