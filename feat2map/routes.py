"""The map layer's answer to "which lane drives this manoeuvre": one rule shared by the env's
routes, the scenario tools (route coverage, durations, pictures) and the OpenSCENARIO export,
so that all of them drive the same junction lane for a (junction, entry road, exit road)."""
from __future__ import annotations

from typing import Sequence

from .model import HDMap, Lane

Manoeuvre = tuple[str, str, str]  # (junction id, entry road id, exit road id)


def manoeuvre_lanes(m: HDMap, mv: Sequence[str]) -> list[Lane]:
    """Every junction lane of junction `mv[0]` with a predecessor on road `mv[1]` and a
    successor on road `mv[2]`, in map order."""
    jid, entry, exit_ = (str(x) for x in mv)
    return [ln for ln in m.lanes_by_junction.get(jid, [])
            if any(m.lanes[p].road_id == entry for p in ln.predecessors if p in m.lanes)
            and any(m.lanes[s].road_id == exit_ for s in ln.successors if s in m.lanes)]


def manoeuvre_lane(m: HDMap, mv: Sequence[str]) -> Lane | None:
    """The junction lane a route drives for manoeuvre `mv` (junction, entry road, exit road):
    the one with the smallest id among `manoeuvre_lanes`; None when the map has none."""
    return min(manoeuvre_lanes(m, mv), key=lambda ln: ln.id, default=None)
