"""Where a car may stand beside a narrow road: the swept path of the cars that turn past it.

On a narrow two-way road (a `network.Passage`: opposite lanes too close to pass) the cars of
one direction turn onto the road out of a junction, or through a kink of the road itself, right
beside where the other direction waits (for the passage, or at the junction's line). A turning
car's body does not stay on its centreline: the lane keeping (highway-env's lateral P -> heading
P -> yaw rate law, `sim.vehicle.lane_keeping`) runs wide through a bend tighter
than it can take, and its body turns late, so its corners sweep over the other lane (digitaf's
`w134499576_0_0_1`, a 90-degree kink within 2 m: the ego's heading was 0.56 rad off its lane
4 m after it; SUMO's 2.0-2.5 m lanes at junction 33: the ego turning out of `4262_0_-1` clipped a
car standing at the bare entry of the opposite lane). Road design places stop lines behind the
swept path of a design vehicle; here the design vehicle is the env's own lane keeping, driven
along every path into and out of the opposite lanes at SWEEP_SPEEDS_MPS (`stretches`). A
waiting car's stop point moves back out of that path (`rules.TrafficRules.clear_of_sweeps`), and
where the path covers the first metres of the road after a junction, they are no room to wait
for the passage beyond (`swept_head`, in `rules.TrafficRules.passage_ahead`): the car waits at
the junction's line instead. Maps without passages (generated maps among them) have no such
stretch, so nothing changes there.
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import shapely
from shapely import STRtree

from ..config import (STOP_POINT_M, SWEEP_CLEARANCE_M, SWEEP_LEAD_M, SWEEP_SPEEDS_MPS, SWEEP_STEP_S,
                      TIGHT_BEND_RADIUS_M, VEHICLE_LENGTH_M, VEHICLE_WIDTH_M)
from ..routes import sharpest_radius
from .lanes import PolylineLane
from .sim.vehicle import FLOATS, VehicleModel, integrate, lane_keeping

if TYPE_CHECKING:
    from .network import MapNetwork

SAMPLE_M = 0.5  # standing places along a lane are tried this often


def footprints(poses: np.ndarray) -> np.ndarray:
    """Cars' rectangles (VEHICLE_LENGTH_M x VEHICLE_WIDTH_M) at poses [n, 3] (x, y, heading), as
    shapely polygons."""
    poses = np.asarray(poses, dtype=float).reshape(-1, 3)
    c, s = np.cos(poses[:, 2])[:, None], np.sin(poses[:, 2])[:, None]
    hl, hw = VEHICLE_LENGTH_M / 2, VEHICLE_WIDTH_M / 2
    a, b = np.array([-hl, hl, hl, -hl]), np.array([-hw, -hw, hw, hw])
    ring = np.stack([poses[:, :1] + a * c - b * s, poses[:, 1:2] + a * s + b * c], axis=-1)
    return shapely.polygons(ring)


def sweep(path: PolylineLane, speed: float, s_from: float = 0.0) -> list[tuple[float, float, float]]:
    """Poses (x, y, heading) of a car that starts on `path` at `s_from`, on its centre and
    heading, and keeps to it at a constant `speed` with the ego's lane keeping and bicycle (the
    default `VehicleModel`; one pose every SWEEP_STEP_S), until its centre reaches the path's end."""
    x, y = (float(c) for c in path.position(s_from, 0.0))
    h = path.heading_at(s_from)
    model = VehicleModel.of()
    poses = [(x, y, h)]
    for _ in range(int(4 * path.length / max(speed * SWEEP_STEP_S, 1e-3)) + 10):
        s, r = path.local_coordinates(np.array([x, y]))
        if s >= path.length - 1e-3:
            break
        steer = lane_keeping(path, s, r, h, speed, model)
        x, y, h, _ = integrate(x, y, h, speed, steer, 0.0, SWEEP_STEP_S, model.wheelbase, model.rear_offset, FLOATS)
        poses.append((x, y, h))
    return poses


def _joined(net: "MapNetwork", first: str, second: str, keep: float) -> PolylineLane:
    """One lane through `first` then `second` (network frame), cut `keep` metres into `second`."""
    a, b = net.lane_of[first], net.lane_of[second]
    pts = np.vstack([a.points, b.points[1:] if np.hypot(*(b.points[0] - a.points[-1])) < 1e-6 else b.points])
    lane = PolylineLane(pts, b.width)
    return PolylineLane(np.array([lane.position(s, 0.0) for s in _cut(lane, 0.0, a.length + keep)]), b.width)


def _cut(lane: PolylineLane, lo: float, hi: float) -> list[float]:
    """Arc lengths of `lane`'s vertices within [lo, hi], with lo and hi themselves."""
    lo, hi = max(lo, 0.0), min(hi, lane.length)
    return [lo, *[float(s) for s in lane.cum if lo < s < hi], hi]


def stretches(net: "MapNetwork") -> dict[str, list[tuple[float, float]]]:
    """For each road lane of a narrow passage: the stretches [lo, hi] of centre positions where a
    car standing on it comes within SWEEP_CLEARANCE_M of a car driven by the lane keeping along a
    lane of the other direction of its passage group (one that comes within a car length of it):
    along that lane, and turning into it from every lane before it and out of it into every lane
    after it. A standing car stands on its lane's centre, along it, or, where it has just turned
    onto the lane, as the lane keeping brought it there (its body still turned). Inside the
    passage itself every place is such a place; what matters are the places beside it."""
    by_group: dict[int, list[str]] = {}
    for lid, ps in net.passages.items():
        by_group.setdefault(ps.group, []).append(lid)
    swept: dict[str, np.ndarray] = {}  # opposite lane -> footprints (made once per lane)
    driven: dict[str, tuple[list, list]] = {}
    out: dict[str, list[tuple[float, float]]] = {}
    reach = VEHICLE_LENGTH_M + VEHICLE_WIDTH_M
    for lid in sorted(net.passages):
        ps = net.passages[lid]
        lane = net.lane_of[lid]
        line = shapely.LineString(lane.points)
        parts = []
        for other in sorted(by_group[ps.group]):
            if net.passages[other].side == ps.side or \
                    shapely.LineString(net.lane_of[other].points).distance(line) > reach:
                continue
            if other not in swept:
                into, rest = _driven(net, other, driven)
                swept[other] = footprints(np.array(into + rest))
            parts.append(swept[other])
        if not parts:
            continue
        feet = np.concatenate(parts)
        feet = feet[shapely.distance(feet, line) < reach]
        if not len(feet):
            continue
        centres = np.arange(0.0, lane.length + 1e-9, SAMPLE_M)
        poses = [(*lane.position(c, 0.0), lane.heading_at(c)) for c in centres]
        at = list(range(len(centres)))
        for x, y, h in _driven(net, lid, driven)[0]:  # a car that stops right after a turn stands turned
            c = lane.local_coordinates(np.array([x, y]))[0]
            if 0.0 < c < lane.length:
                poses.append((x, y, h))
                at.append(min(int(round(c / SAMPLE_M)), len(centres) - 1))
        mine = footprints(np.array(poses))
        hit = np.zeros(len(centres), dtype=bool)
        touched = np.unique(STRtree(feet).query(mine, predicate="dwithin", distance=SWEEP_CLEARANCE_M)[0])
        hit[np.asarray(at)[touched]] = True
        spans: list[tuple[float, float]] = []
        for c, h in zip(centres.tolist(), hit.tolist()):
            if h:
                if spans and spans[-1][1] >= c - SAMPLE_M - 1e-9:
                    spans[-1] = (spans[-1][0], c)
                else:
                    spans.append((c, c))
        if spans:
            out[lid] = spans
    return out


def _driven(net: "MapNetwork", lid: str, memo: dict) -> tuple[list, list]:
    """(poses turning into road lane `lid` from each lane before it, poses along it and out of it
    into each lane after it) of the lane keeping at every speed of SWEEP_SPEEDS_MPS: into it from
    SWEEP_LEAD_M before it to SWEEP_LEAD_M into it, along it alone, and out of it from SWEEP_LEAD_M
    before its end to SWEEP_LEAD_M into the next lane. Made once per lane (`memo`)."""
    if lid in memo:
        return memo[lid]
    lanes, own = net.hdmap.lanes[lid], net.lane_of[lid]
    into = [(_joined(net, p, lid, SWEEP_LEAD_M), max(net.lane_of[p].length - SWEEP_LEAD_M, 0.0))
            for p in lanes.predecessors if p in net.lane_of]
    rest = [(own, 0.0)] + [(_joined(net, lid, n, SWEEP_LEAD_M), max(own.length - SWEEP_LEAD_M, 0.0))
                           for n in lanes.successors if n in net.lane_of]
    memo[lid] = tuple([pose for path, s0 in paths for speed in SWEEP_SPEEDS_MPS for pose in sweep(path, speed, s0)]
                      for paths in (into, rest))
    return memo[lid]


def clear_stop(spans: list[tuple[float, float]], centre: float) -> float:
    """How far [m] a car standing with its centre at `centre` on a lane with these swept `spans`
    must stand further back to be clear of them: to before the span it stands in, when the lane
    leaves room before it (a span from the lane's start gives no place: 0)."""
    for lo, hi in spans:
        if lo - SAMPLE_M <= centre <= hi + SAMPLE_M:
            return centre - (lo - SAMPLE_M) if lo > 0.0 else 0.0
    return 0.0


def swept_head(spans: list[tuple[float, float]] | None, length: float) -> float:
    """How much of a lane's start [m] a waiting car `length` long cannot use: up to its first place
    clear of a swept stretch that starts with the lane (the road right after a junction where the
    opposite direction turns out of the junction beside it); 0 when none does."""
    if not spans or spans[0][0] > 0.0:
        return 0.0
    return max(spans[0][1] + SAMPLE_M - length / 2, 0.0)


def turn_setbacks(net: "MapNetwork", setbacks: dict[str, float], waits: list[str]) -> dict[str, float]:
    """Wait points of junction entries moved back out of the swept path of junction turns tighter
    than a car turns: incoming lane -> its new setback (how far before its end cars wait), only
    where it grows. osm2xodr's turns of 3-5 m radius (digitaf's `j_360700741_c305_0_-1`, a left
    turn of 4.9 m radius onto the 16 m `w798909041_0_0_-1`): the lane keeping leaves such a turn
    with its heading up to 30 degrees behind its lane, and its front corner swept over the car
    waiting at the opposite lane's line 2.8 m away (digitaf r178). The design vehicle (`sweep`, at
    SWEEP_SPEEDS_MPS) drives every path into and out of each junction lane whose `sharpest_radius`
    is under TIGHT_BEND_RADIUS_M and that passes within reach of a wait; a car waiting at an
    entry stands clear of those footprints by SWEEP_CLEARANCE_M, its own paths and those of the
    cars behind it left out. Only tight turns are driven, and only those near a wait, so the cost
    stays with the maps that have them (generated maps have none)."""
    m = net.hdmap
    tight = [ln for ln in m.lanes.values() if ln.junction_id is not None and ln.id in net.lane_of
             and sharpest_radius(ln) < TIGHT_BEND_RADIUS_M]
    if not tight or not waits:
        return {}
    reach = VEHICLE_LENGTH_M + VEHICLE_WIDTH_M
    look = 3 * VEHICLE_LENGTH_M  # a wait may move back this far
    spots = []  # (lane id, first and last centre position a waiting car may take)
    for lid in waits:
        lane = net.lane_of[lid]
        line = lane.length - setbacks.get(lid, 0.0)
        hi = line - STOP_POINT_M - VEHICLE_LENGTH_M / 2
        if hi > 0.0:
            spots.append((lid, max(hi - look, 0.0), hi))
    if not spots:
        return {}
    areas = [shapely.LineString([net.lane_of[lid].position(c, 0.0) for c in _cut(net.lane_of[lid], lo, hi)])
             if hi - lo > 1e-6 else shapely.Point(net.lane_of[lid].position(hi, 0.0)) for lid, lo, hi in spots]
    tree = STRtree(areas)
    near: dict[str, set[int]] = {}
    for ln in tight:
        ends = [ln.centerline[0], *ln.centerline, *[net.lane_of[n].position(min(SWEEP_LEAD_M, net.lane_of[n].length), 0.0)
                                                    for n in ln.successors if n in net.lane_of]]
        path = shapely.LineString(np.asarray(ends, dtype=float)[:, :2])
        hits = tree.query(path, predicate="dwithin", distance=reach)
        if len(hits):
            near[ln.id] = {int(i) for i in hits}
    out: dict[str, float] = {}
    if not near:
        return out
    feet: dict[int, list] = {}
    for jid, idx in near.items():
        ln = m.lanes[jid]
        paths = [((p, jid), _joined(net, p, jid, net.lane_of[jid].length), max(net.lane_of[p].length - SWEEP_LEAD_M, 0.0))
                 for p in ln.predecessors if p in net.lane_of]
        paths += [((jid, n), _joined(net, jid, n, SWEEP_LEAD_M), 0.0) for n in ln.successors if n in net.lane_of]
        for ids, path, s0 in paths:
            # a wait's own paths, and those of the cars behind it, are left out
            others = [i for i in idx if not {spots[i][0], *m.lanes[spots[i][0]].predecessors,
                                             *m.lanes[spots[i][0]].successors} & set(ids)]
            if not others:
                continue
            prints = footprints(np.array([pose for speed in SWEEP_SPEEDS_MPS for pose in sweep(path, speed, s0)]))
            for i in others:
                feet.setdefault(i, []).append(prints)
    for i, parts in feet.items():
        lid, lo, hi = spots[i]
        lane = net.lane_of[lid]
        every = np.concatenate(parts)
        centres = np.arange(hi, lo - 1e-9, -SAMPLE_M)
        mine = footprints(np.array([(*lane.position(c, 0.0), lane.heading_at(c)) for c in centres]))
        hit = np.zeros(len(centres), dtype=bool)
        hit[np.unique(STRtree(every).query(mine, predicate="dwithin", distance=SWEEP_CLEARANCE_M)[0])] = True
        if not hit[0]:
            continue
        clear = np.flatnonzero(~hit)
        if not len(clear):
            continue  # no place clear of the sweep within reach: the wait keeps its place
        c = float(centres[clear[0]])
        out[lid] = lane.length - (c + VEHICLE_LENGTH_M / 2 + STOP_POINT_M)
    return out
