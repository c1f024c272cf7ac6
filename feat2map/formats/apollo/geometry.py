"""Geometry the Apollo export needs, computed on the map model (local metres): arc lengths,
half-width and road-edge samples, stop-line and crosswalk s ranges on centrelines, exact end
tangents, repaired degenerate and too narrow boundaries, and a lane's carriageway edges."""
from __future__ import annotations

import dataclasses
import math
import warnings
from typing import Any

import numpy as np
import shapely
import shapely.ops
from shapely.geometry import LineString, Polygon

from ...config import (APOLLO_END_TANGENT_M, APOLLO_MIN_HALF_WIDTH_M, APOLLO_WIDEN_MARGIN_M, APOLLO_SAMPLE_WINDOW_M,
                       APOLLO_STOP_LINE_OVERLAP_M)
from ...errors import Feat2MapError
from ...model import HDMap, Lane, Polyline, as_polyline
from ...validation import CONTROL_KINDS
from ...semantics import unfold


def arc_lengths(points: np.ndarray) -> np.ndarray:
    """Cumulative length along a polyline, starting at 0."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(points, axis=0).T))])


def distance_samples(centerline: Polyline, edge: Polyline, window: float = APOLLO_SAMPLE_WINDOW_M
                     ) -> list[tuple[float, float]]:
    """(s, local distance from the centreline point at s to `edge`) at every centreline vertex.

    Only the part of `edge` within `window` metres of the same relative position counts, so a
    curve that bends back near itself (a hairpin) does not pinch the measured width.
    """
    pts = np.asarray(centerline, dtype=float)
    e = np.asarray(edge, dtype=float)
    s = arc_lengths(pts)
    se = arc_lengths(e)
    a, b = e[:-1], e[1:]
    ab = b - a
    ap = pts[:, None, :] - a[None, :, :]
    t = np.clip(np.einsum("nmk,mk->nm", ap, ab) / np.maximum(np.einsum("mk,mk->m", ab, ab), 1e-18), 0.0, 1.0)
    d = np.hypot(*(ap - t[..., None] * ab[None]).transpose(2, 0, 1))
    here = s / max(s[-1], 1e-12) * se[-1]  # the same relative position on the edge
    near = (se[None, 1:] >= here[:, None] - window) & (se[None, :-1] <= here[:, None] + window)
    d = np.where(near, d, np.inf).min(axis=1)
    return list(zip(s.tolist(), d.tolist()))


def stop_line_range(centerline: Polyline, stop_line: Polyline, half: float = APOLLO_STOP_LINE_OVERLAP_M
                    ) -> tuple[float, float]:
    """s range on a lane around where the stop line meets its centreline, clamped to the lane."""
    line = LineString(centerline)
    a = shapely.get_coordinates(shapely.shortest_line(line, LineString(stop_line)))[0]
    s = line.project(shapely.Point(a))
    return max(0.0, s - half), min(line.length, s + half)


def polygon_range(centerline: Polyline, polygon: Polyline) -> tuple[float, float] | None:
    """s range of the centreline covered by `polygon`, or None when they do not meet."""
    line = LineString(centerline)
    inter = line.intersection(Polygon(polygon))
    if inter.is_empty or inter.length <= 0.0:
        return None
    ss = [line.project(shapely.Point(c)) for c in shapely.get_coordinates(inter)]
    return min(ss), max(ss)


def exact_end_centerline(ln: Lane, step: float = APOLLO_END_TANGENT_M) -> Polyline:
    """The centreline with a point `step` metres inside each end taken from the lane's exact
    Bézier, so the first and last chords follow the true end tangents (Apollo, and any reader,
    takes a lane's end headings from them); unchanged for lanes without a Bézier."""
    pts = ln.centerline
    bz = ln.bezier
    if bz is None or len(pts) < 2 or bz.length <= 4 * step:
        return pts
    if math.dist(pts[0], bz.p0) > 1e-6 or math.dist(pts[-1], bz.p3) > 1e-6:
        return pts
    eps = step / bz.length
    if math.dist(pts[0], pts[1]) <= 2 * step or math.dist(pts[-2], pts[-1]) <= 2 * step:
        return pts
    a, b = ((float(p[0]), float(p[1])) for p in bz.point(np.array([eps, 1.0 - eps])))
    return (pts[0], a) + tuple(pts[1:-1]) + (b, pts[-1])


def offset_polyline(points: Polyline, d: float | np.ndarray) -> Polyline:
    """`points` shifted `d` metres (one value, or one per point) to the left along vertex normals
    (central differences)."""
    p = np.asarray(points, dtype=float)
    t = np.gradient(p, axis=0)
    t /= np.maximum(np.hypot(t[:, 0], t[:, 1]), 1e-12)[:, None]
    return as_polyline(p + np.reshape(d, (-1, 1)) * np.column_stack([-t[:, 1], t[:, 0]]))


def widened_boundaries(m: HDMap, half: float = APOLLO_MIN_HALF_WIDTH_M) -> HDMap:
    """`m` with every lane side that comes nearer its centreline than `half` somewhere rebuilt as
    the centreline offset by the distance measured at each vertex, at least `half` (plus
    APOLLO_WIDEN_MARGIN_M; unfolded where that folds it round a tighter bend: `semantics.unfold`), and
    one warning per map naming the lanes. Apollo refuses narrower width samples, and converters
    leave them: a geometry loop's 0.117 m-wide sample, a taper closing to 1.001 m at a linked
    end, a fold-cut connection's boundary 0.15 m from its centre (Bézier lanes are exact)."""
    fixed: dict[str, Lane] = {}
    narrowest: list[tuple[float, str]] = []
    for ln in m.lanes.values():
        if ln.bezier is not None or len(ln.centerline) < 2:
            continue
        sides: dict[str, Any] = {}
        for name, sign in (("left_boundary", 1.0), ("right_boundary", -1.0)):
            w = np.array([d for _, d in distance_samples(ln.centerline, getattr(ln, name))])
            w = np.where(np.isfinite(w), w, ln.width / 2)
            if w.min() < half:
                narrowest.append((float(w.min()), ln.id))
                side = offset_polyline(ln.centerline, sign * np.maximum(w, half + APOLLO_WIDEN_MARGIN_M))
                sides[name] = unfold(side, ln.centerline) or side  # round a bend tighter than `half` it folds
        if sides:
            fixed[ln.id] = dataclasses.replace(ln, **sides)
    if not fixed:
        return m
    w0, first = min(narrowest)
    warnings.warn(f"{m.meta.get('source', 'map')}: {len(fixed)} lane(s) narrower than Apollo holds ({half:g} m a side; "
                  f"first: lane {first}, {w0:.3f} m): those sides widened to {half:g} m in the Apollo export",
                  stacklevel=3)
    return dataclasses.replace(m, lanes={k: fixed.get(k, ln) for k, ln in m.lanes.items()})


def _usable(points: Polyline) -> bool:
    """At least two points more than 1 mm apart (the validator counts 0.1 mm as distinct)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    return len(p) >= 2 and bool((np.abs(p - p[0]).max(axis=1) > 1e-3).any())


def without_point_lanes(m: HDMap) -> HDMap:
    """`m` without lanes whose centreline is shorter than Apollo can hold (no two points 1 mm
    apart: CARLA's micrometre road pieces): each is spliced out, its predecessors linked
    straight to its successors (they meet where it was), and every reference to it dropped."""
    gone = {lid for lid, ln in m.lanes.items() if not _usable(ln.centerline)}
    if not gone:
        return m

    def through(ids: tuple[str, ...], attr: str) -> tuple[str, ...]:
        out: dict[str, None] = {}
        todo, seen = list(ids), set()
        while todo:
            x = todo.pop(0)
            if x in gone:
                if x not in seen:
                    seen.add(x)
                    todo += list(getattr(m.lanes[x], attr))
            else:
                out[x] = None
        return tuple(out)

    lanes = {}
    for lid, ln in m.lanes.items():
        if lid in gone:
            continue
        drop: dict[str, Any] = {f: tuple(x for x in getattr(ln, f) if x not in gone)
                for f in ("left_neighbors", "right_neighbors", "left_reverse_neighbors")}
        lanes[lid] = dataclasses.replace(ln, predecessors=through(ln.predecessors, "predecessors"),
                                         successors=through(ln.successors, "successors"), **drop)
    roads = {rid: dataclasses.replace(r, right_lanes=tuple(x for x in r.right_lanes if x not in gone),
                                      left_lanes=tuple(x for x in r.left_lanes if x not in gone))
             for rid, r in m.roads.items()}
    controls: dict[str, Any] = {kind: {k: dataclasses.replace(c, lane_ids=tuple(x for x in c.lane_ids if x not in gone))
                       for k, c in getattr(m, kind).items()} for kind in CONTROL_KINDS}
    return dataclasses.replace(m, lanes=lanes, roads=roads, **controls)


def trimmed_tapers(m: HDMap, half: float = APOLLO_MIN_HALF_WIDTH_M) -> HDMap:
    """`m` with every lane that opens from (or closes to) less than a car's width at a free end
    (no predecessor at its start, no successor at its end: an exit lane or turn pocket growing
    from 0 m, an acceleration lane tapering away) starting (ending) where both its half widths
    reach `half`. Apollo wants every width sample at least half a car wide, and no car drives
    the sliver (traffic enters such a lane by a lane change, further along). Linked ends, lanes
    never that wide and lanes with a Bézier (generated: exact, full width) stay as they are."""
    cut: dict[str, Lane] = {}
    for ln in m.lanes.values():
        if ln.bezier is not None or len(ln.centerline) < 3:
            continue
        s_l, w_l = zip(*distance_samples(ln.centerline, ln.left_boundary))
        _, w_r = zip(*distance_samples(ln.centerline, ln.right_boundary))
        wide = np.minimum(np.asarray(w_l), np.asarray(w_r)) >= half + 1e-3
        if wide.all() or not wide.any():
            continue
        first = int(np.argmax(wide)) if not ln.predecessors else 0
        last = len(wide) - 1 - int(np.argmax(wide[::-1])) if not ln.successors else len(wide) - 1
        if (first, last) == (0, len(wide) - 1) or last - first < 1:
            continue
        line = LineString(ln.centerline)
        a, b = s_l[first], s_l[last]
        pieces: dict[str, Any] = {}
        for name in ("left_boundary", "right_boundary"):
            edge = LineString(getattr(ln, name))
            lo = edge.project(shapely.Point(ln.centerline[first]))
            hi = edge.project(shapely.Point(ln.centerline[last]))
            pieces[name] = as_polyline(shapely.get_coordinates(shapely.ops.substring(edge, lo, hi)))
        centre = as_polyline(shapely.get_coordinates(shapely.ops.substring(line, a, b)))
        if not all(_usable(x) for x in (centre, *pieces.values())):
            continue
        cut[ln.id] = dataclasses.replace(ln, centerline=centre, **pieces)
    if not cut:
        return m
    return dataclasses.replace(m, lanes={k: cut.get(k, ln) for k, ln in m.lanes.items()})


def usable_boundaries(m: HDMap) -> HDMap:
    """`m` with every degenerate lane boundary (fewer than 2 distinct points: the inner side of
    a tight U-turn collapses to its pivot) replaced by the centreline offset by half the lane
    width. Raises Feat2MapError naming the lane when a centreline or repair is degenerate."""
    fixed = {}
    for ln in m.lanes.values():
        if not _usable(ln.centerline):
            raise Feat2MapError("centerline needs 2 or more distinct points", f"lane {ln.id}")
        sides: dict[str, Any] = {}
        for name, sign in (("left_boundary", 1.0), ("right_boundary", -1.0)):
            if not _usable(getattr(ln, name)):
                sides[name] = offset_polyline(ln.centerline, sign * ln.width / 2)
                if not _usable(sides[name]):
                    raise Feat2MapError(f"{name} needs 2 or more distinct points", f"lane {ln.id}")
        if sides:
            fixed[ln.id] = dataclasses.replace(ln, **sides)
    if not fixed:
        return m
    return dataclasses.replace(m, lanes={k: fixed.get(k, ln) for k, ln in m.lanes.items()})


def road_edges(m: HDMap, lane: Lane) -> tuple[Polyline, Polyline]:
    """(left, right) edge of the carriageway around `lane`, each in the lane's direction.

    Left: across same-direction left neighbours, then the reverse lanes beyond the divider to
    the outermost one's right boundary; right: the outermost right neighbour's right boundary.
    """
    def walk(lid: str, attr: str) -> Lane:
        seen = {lid}
        cur = m.lanes[lid]
        while (nxt := [n for n in getattr(cur, attr) if n in m.lanes and n not in seen]):
            seen.add(nxt[0])
            cur = m.lanes[nxt[0]]
        return cur

    right = walk(lane.id, "right_neighbors").right_boundary
    leftmost = walk(lane.id, "left_neighbors")
    reverse = [n for n in leftmost.left_reverse_neighbors if n in m.lanes]
    if reverse:
        left = tuple(reversed(walk(reverse[0], "right_neighbors").right_boundary))
    else:
        left = leftmost.left_boundary
    return left, right
