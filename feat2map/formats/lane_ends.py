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

from ..config import LANE_END_SNAP_M
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
