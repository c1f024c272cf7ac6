"""Fixed-time signal phases of a junction: which of its signals show green together.

One rule for every user of the map's signals (the env's phase plans, the CommonRoad export's
light cycles): signals of one approach always share a phase; paired phases give opposite
approaches green together. A phase is green, then amber, then all-red, phases in turn, the
first phase green from time 0 (`timeline`).
"""
from __future__ import annotations

import math
from typing import Iterable, Mapping

from .config import SIGNAL_ALL_RED_S, SIGNAL_AMBER_S, SIGNAL_GREEN_S, SIGNAL_OPPOSITE_DEG, SIGNAL_SAME_APPROACH_DEG
from .model import HDMap, Signal


def group_phases(signals: Iterable[Signal], paired: bool,
                 travel: Mapping[str, float] | None = None) -> tuple[tuple[str, ...], ...]:
    """Phases of one junction's signals. Signals of one approach (traffic travelling within
    `SIGNAL_SAME_APPROACH_DEG` of the same direction: real maps have a head per lane) always
    share a phase; when `paired`, opposite approaches share one too. `travel` gives each signal's
    direction of travel (from the lanes it governs); without it, the direction is opposite the
    way the signal faces."""
    sigs = sorted(signals, key=lambda g: g.id)
    travel = travel or {}
    heading = {g.id: travel.get(g.id, g.heading + math.pi) for g in sigs}

    def apart(a: float, b: float) -> float:  # angle between two directions, 0..pi
        return abs((a - b + math.pi) % (2 * math.pi) - math.pi)

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


def junction_phases(m: HDMap, paired: bool = True) -> dict[str | None, tuple[tuple[str, ...], ...]]:
    """The phases of every junction's signals (signals outside junctions under key None)."""
    by_junction: dict[str | None, list[Signal]] = {}
    for s in m.signals.values():
        by_junction.setdefault(s.junction_id, []).append(s)
    return {jid: group_phases(sigs, paired, travel_headings(m, sigs)) for jid, sigs in by_junction.items()}


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
