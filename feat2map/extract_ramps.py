"""Motorway ramps in any map: where a ramp's road joins a main road (an on-ramp) or leaves it
(an off-ramp), inside a junction or not.

Maps model ramps in different ways: feat2map's ramp junctions merge a ramp's lane into the
main road's rightmost lane inside the junction; ASAM's motorway example joins the ramp's lane
to the main road as an added lane in a short junction, and the added lane (the acceleration
lane) runs on beside the main lanes until it ends; OpenDRIVE direct junctions link the lanes of
two roads to one road without a junction area. All of them are one pattern on the lane graph:
the lanes of one direction of a road are fed (an on-ramp) by exactly two other roads, directly
or through junction lanes, or feed (an off-ramp) exactly two, one running on straight at its
mouth (the main road, within RAMP_MIN_ANGLE_DEG of the road's direction; it may bend further
on) and one coming in from (going off
to) the right, one-way, RAMP_MIN_ANGLE_DEG to RAMP_MAX_ANGLE_DEG off it at its mouth. Where the
ramp's lane meets the main road parallel (an added lane), the angle is the largest heading
difference along the ramp within RAMP_PROBE_M of the mouth, at least RAMP_MIN_ANGLE_DEG (a
loop ramp turns further). The length
is the ramp's junction lane's plus its added lanes' beside the main lanes.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Iterator, Sequence

import numpy as np

from .angles import wrap_degrees
from .config import RAMP_MANOEUVRES, RAMP_MAX_ANGLE_DEG, RAMP_MIN_ANGLE_DEG, RAMP_PROBE_M
from .model import HDMap, Lane

MAX_WALK = 200  # lanes followed at most along a ramp's path or its added lanes


@dataclass(frozen=True)
class ExtractedRamp:
    """One ramp: `kind` "on" or "off", the `road` the ramp's and the main road's lanes feed (on)
    or leave (off), the `ramp_road` and `main_road` on its other side, the `junction` whose lanes
    join them (None for a direct link), its angle off the main road, its acceleration or
    deceleration lanes' length and its `links`: each lane path across the mouth from a ramp lane
    (on) or a lane of `road` (off) to the lane after it, in driving order (the junction lane
    between them where there is one), so routes can drive the ramp."""

    map_name: str
    kind: str
    road: str
    ramp_road: str
    main_road: str
    junction: str | None
    angle_deg: float
    length_m: float
    links: tuple[tuple[str, ...], ...] = ()

    def to_dict(self) -> dict:
        return {"map": self.map_name, "kind": self.kind, "road": self.road, "ramp_road": self.ramp_road,
                "main_road": self.main_road, "junction": self.junction, "angle_deg": round(self.angle_deg, 2),
                "length_m": round(self.length_m, 2)}


def _directions(m: HDMap) -> Iterator[tuple[str, list[Lane]]]:
    """(road id, its road lanes of one direction of travel), for every road outside junctions."""
    for rid in m.roads:
        if _junction_road(m, rid):
            continue
        road = m.roads[rid]
        groups = [road.right_lanes, road.left_lanes] if (road.right_lanes or road.left_lanes) else [road.lane_ids]
        for ids in groups:
            lanes = [m.lanes[x] for x in ids if x in m.lanes and m.lanes[x].junction_id is None]
            if lanes:
                yield rid, lanes


def _junction_road(m: HDMap, rid: str) -> bool:
    """Road `rid` is a piece of a junction (a junction's road, even where its lanes lost their
    junction): no main road and no ramp."""
    road = m.roads.get(rid)
    return road is not None and (road.kind == "junction" or road.junction_id is not None)


def _links(m: HDMap, lane: Lane, forward: bool) -> list[tuple[Lane, Lane | None]]:
    """The road lanes after (`forward`) or before a road lane, each with the junction lane between
    them (None for a direct link)."""
    out: list[tuple[Lane, Lane | None]] = []
    for x in (lane.successors if forward else lane.predecessors):
        nxt = m.lanes[x]
        if nxt.junction_id is None:
            out.append((nxt, None))
            continue
        for y in (nxt.successors if forward else nxt.predecessors):
            if m.lanes[y].junction_id is None:
                out.append((m.lanes[y], nxt))
    return out


def _path_headings(m: HDMap, first: Sequence[Lane], forward: bool) -> Iterator[tuple[float, float]]:
    """(distance from the mouth, heading of travel) along a path of lanes leaving the mouth
    (`forward`: downstream from its start, else upstream from its end), through later lanes."""
    done = 0.0
    lanes = list(first)
    for _ in range(MAX_WALK):
        if not lanes:
            return
        ln = lanes[0]
        pts = ln.points if forward else ln.points[::-1]
        for a, b in zip(pts[:-1], pts[1:]):
            d = b - a if forward else a - b
            step = float(np.hypot(*d))
            if step > 1e-9:
                yield done, math.degrees(math.atan2(d[1], d[0]))
            done += step
        links = ln.successors if forward else ln.predecessors
        lanes = [m.lanes[x] for x in links[:1]]


def _deviation(m: HDMap, path: Sequence[Lane], reference_deg: float, forward: bool) -> tuple[float, bool]:
    """The heading of the path at its mouth relative to `reference_deg` and True, or, when that is
    under RAMP_MIN_ANGLE_DEG (a lane joining parallel), the largest such difference within
    RAMP_PROBE_M and False."""
    best = 0.0
    for dist, heading in _path_headings(m, path, forward):
        dev = wrap_degrees(heading - reference_deg)
        if dist == 0.0 and abs(dev) >= RAMP_MIN_ANGLE_DEG:
            return dev, True
        if dist > RAMP_PROBE_M:
            break
        if abs(dev) > abs(best):
            best = dev
    return best, False


def _added_length(m: HDMap, lanes: Sequence[Lane], others: set[str], forward: bool) -> float:
    """How far the ramp's own lanes (`lanes`, none of them one the main road also feeds: `others`)
    run on beside the main lanes (lanes with a left neighbour), downstream or upstream."""
    total = 0.0
    for ln in lanes:
        cur: Lane | None = ln
        run = 0.0
        for _ in range(MAX_WALK):
            if cur is None or cur.id in others or cur.junction_id is not None or not cur.left_neighbors:
                break
            run += cur.length
            links = cur.successors if forward else cur.predecessors
            cur = m.lanes[links[0]] if len(links) == 1 else None
        total = max(total, run)
    return total


def _one_way(m: HDMap, rid: str, lane: Lane) -> bool:
    """All lanes of road `rid` travel the way `lane` does (a ramp's road is one-way)."""
    h = lane.heading_at_end()
    return all(abs(wrap_degrees(math.degrees(m.lanes[x].heading_at_end() - h))) < 90.0
               for x in m.roads[rid].lane_ids if x in m.lanes)


def extract_ramps(m: HDMap, map_name: str = "map") -> list[ExtractedRamp]:
    """The on-ramps and off-ramps of a map (see the module docstring), in road order."""
    out: list[ExtractedRamp] = []
    for rid, lanes in _directions(m):
        for kind, forward in (("on", False), ("off", True)):
            found = _ramp_at(m, map_name, rid, lanes, kind, forward)
            if found is not None:
                out.append(found)
    return out


def _ramp_at(m: HDMap, map_name: str, rid: str, lanes: Sequence[Lane], kind: str,
             forward: bool) -> ExtractedRamp | None:
    """The ramp whose lanes and the main road's feed (`kind` "on": `forward` False, upstream of
    road `rid`'s `lanes`) or leave (off: downstream) one road, if they make one."""
    sides: dict[str, list[tuple[Lane, Lane | None, Lane]]] = {}
    for ln in lanes:
        for other, via in _links(m, ln, forward):
            if other.road_id != rid and not _junction_road(m, other.road_id):
                sides.setdefault(other.road_id, []).append((other, via, ln))
    if len(sides) != 2:
        return None
    ref = math.degrees(lanes[0].heading_at_end() if forward else lanes[0].heading_at_start())
    dev, at_mouth = {}, {}
    for side, links in sides.items():  # at the road's mouth, before any junction lane
        dev[side], at_mouth[side] = _deviation(m, [links[0][0]], ref, forward)
    # the main road runs on straight at its mouth (it may bend further on); of two, the straighter along
    main, ramp = sorted(sides, key=lambda s: (at_mouth[s], abs(dev[s])))
    angle = dev[ramp] if kind == "on" else -dev[ramp]  # from the right: turned left joining, right leaving
    if at_mouth[main] or angle < RAMP_MIN_ANGLE_DEG or (at_mouth[ramp] and angle > RAMP_MAX_ANGLE_DEG):
        return None
    ramp_lane = sides[ramp][0][0]
    if not _one_way(m, ramp, ramp_lane):
        return None
    through = [v for _, v, _ in sides[ramp] if v is not None]  # its junction lanes
    junction = through[0].junction_id if through else None
    mine = [t for _, _, t in sides[ramp]]
    theirs = {t.id for _, _, t in sides[main]}
    length = max((v.length for v in through), default=0.0) + _added_length(m, mine, theirs, not forward)
    return ExtractedRamp(map_name, kind, rid, ramp, main, junction, abs(angle), length, _paths(sides[ramp], forward))


def _paths(links: Sequence[tuple[Lane, Lane | None, Lane]], forward: bool) -> tuple[tuple[str, ...], ...]:
    """The lane paths (ramp side, junction lane or none, road side) of a ramp's links in driving
    order: downstream (`forward`, an off-ramp) from the road's lane, else from the ramp's."""
    out = []
    for other, via, mine in links:
        path = [mine.id, *([via.id] if via is not None else []), other.id]
        out.append(tuple(path if forward else path[::-1]))
    return tuple(out)


def ramp_moves(m: HDMap) -> dict[str, str]:
    """The junction lanes that drive a ramp (`extract_ramps`), lane id -> "merge" (from an
    on-ramp onto its main road) or "diverge" (from the main road onto an off-ramp): what a
    planner selects its ramp scenarios by. Ramps through a direct link have no such lane."""
    return {path[1]: RAMP_MANOEUVRES[r.kind] for r in extract_ramps(m) for path in r.links if len(path) == 3}
