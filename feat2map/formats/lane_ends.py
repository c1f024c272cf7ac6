"""Where linked lanes meet, for the formats whose lanes must share their end points (Lanelet2
finds successors by shared points; CommonRoad checkers want a lanelet to start where its
predecessor ends). Generated maps meet within 1 cm; maps read from other formats can leave
gaps of a decimetre or more between linked lanes, which the export closes.

Each lane has four end points (left/right boundary, start/end). The points of linked lanes (a
predecessor's end and its successor's start, on each side; the ends of a boundary two
neighbours share) that lie within `LANE_END_SNAP_M` are one point; every group of such points
is placed at its first member's position, in map order.
"""
from __future__ import annotations

from dataclasses import replace
from typing import Sequence

from ..config import ENDPOINT_TOLERANCE_M, LANE_END_SNAP_M
from ..model import HDMap, Point

End = tuple[str, str, str]  # (lane id, "left"/"right", "start"/"end")


def _point(m: HDMap, end: End) -> Point:
    ln = m.lanes[end[0]]
    line = ln.left_boundary if end[1] == "left" else ln.right_boundary
    p = line[0] if end[2] == "start" else line[-1]
    return (float(p[0]), float(p[1]))


def lane_ends(m: HDMap, lanes=None) -> dict[End, Point]:
    """The shared position of every lane end of `lanes` (default: every lane with two-point
    boundaries): linked ends closer than `LANE_END_SNAP_M` share one (see the module docstring)."""
    ids = [lid for lid, ln in m.lanes.items() if len(ln.left_boundary) >= 2 and len(ln.right_boundary) >= 2] \
        if lanes is None else list(lanes)
    keep = set(ids)
    parent: dict[End, End] = {}

    def find(e: End) -> End:
        root = e
        while parent.get(root, root) != root:
            root = parent[root]
        while e != root:
            parent[e], e = root, parent.get(e, e)
        return root

    order = {lid: i for i, lid in enumerate(ids)}

    def join(a: End, b: End) -> None:
        (ax, ay), (bx, by) = _point(m, a), _point(m, b)
        if (ax - bx) ** 2 + (ay - by) ** 2 <= LANE_END_SNAP_M ** 2:
            ra, rb = find(a), find(b)
            if ra != rb:  # the earlier lane in map order (then start before end) leads the group
                first, second = sorted((ra, rb), key=lambda e: (order[e[0]], e[2] != "start", e[1]))
                parent[second] = first

    for lid in ids:
        ln = m.lanes[lid]
        for s in (x for x in ln.successors if x in keep):
            for side in ("left", "right"):
                join((lid, side, "end"), (s, side, "start"))
        for n in (x for x in ln.left_neighbors if x in keep):  # one boundary: my left, its right
            for at in ("start", "end"):
                join((lid, "left", at), (n, "right", at))
        for r in (x for x in ln.left_reverse_neighbors if x in keep):  # one boundary, run the other way
            join((lid, "left", "start"), (r, "left", "end"))
            join((lid, "left", "end"), (r, "left", "start"))
    return {(lid, side, at): _point(m, find((lid, side, at)))
            for lid in ids for side in ("left", "right") for at in ("start", "end")}


def between(line: Sequence[Sequence[float]], start: tuple[float, float], end: tuple[float, float]) -> list:
    """The inner points of a boundary `line` whose ends moved to `start` and `end` (`lane_ends`),
    without those the moved ends passed: where a predecessor's end lies along a short inner
    kerb beyond its first inner point, keeping that point would make the bound's first segment
    run backwards (Lanelet2's loader, `geometry::align`, then inverts the bound and loses the
    lanelet's links; a CommonRoad lanelet's border folds back on itself)."""
    from shapely.geometry import LineString, Point

    if len(line) < 3:
        return []
    own = LineString([(float(p[0]), float(p[1])) for p in line])
    s0, s1 = own.project(Point(start)), own.project(Point(end))
    return [p for p in line[1:-1] if s0 < own.project(Point(float(p[0]), float(p[1]))) < s1]


def closed_seams(m: HDMap, tol: float = ENDPOINT_TOLERANCE_M) -> HDMap:
    """`m` with the seams between linked lanes closed, for the formats whose checks want a lane to
    start where its predecessor ends (Apollo: centre lines within 0.1 m; OpenDRIVE: borders at the
    contact point). Where a lane's centre line ends more than `tol` and at most `LANE_END_SNAP_M`
    from its successor's start (CommonRoad's OpenDRIVE converter leaves 0.1 m seams, SVL maps up
    to 0.5 m), the lane with one link across the seam (the predecessor with one successor, else
    the successor with one predecessor) is bent over its last (first) metres to meet the other
    (`semantics.bent`). Seams where both lanes fan out stay; `m` itself when nothing changes."""
    from ..semantics import bent

    lanes = dict(m.lanes)
    moved: set[tuple[str, str]] = set()
    for lid in m.lanes:
        for sid in m.lanes[lid].successors:
            a, b = lanes[lid], lanes.get(sid)
            if b is None or len(a.centerline) < 2 or len(b.centerline) < 2:
                continue
            gap = (b.start[0] - a.end[0], b.start[1] - a.end[1])
            if not tol < (gap[0] ** 2 + gap[1] ** 2) ** 0.5 <= LANE_END_SNAP_M:
                continue
            if len(a.successors) == 1 and (lid, "end") not in moved:
                lanes[lid] = bent(a, gap, "end")
                moved.add((lid, "end"))
            elif len(b.predecessors) == 1 and (sid, "start") not in moved:
                lanes[sid] = bent(b, (-gap[0], -gap[1]), "start")
                moved.add((sid, "start"))
    return replace(m, lanes=lanes) if moved else m
