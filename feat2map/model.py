"""The HD map model: the one value every reader produces and every writer consumes.

Coordinates are metres in a local frame (x east, y north); `HDMap.origin` is the absolute
(UTM) position of the local origin. Polylines are tuples of (x, y) points.
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from functools import cached_property
from typing import Any, Iterable, Mapping

import numpy as np

from .bezier import Bezier, Point
from .config import MIDBLOCK_LINE_REACH_M, MIN_ARM_LENGTH_M
from .features import JunctionFeature

Polyline = tuple[Point, ...]
TURNS = ("none", "left", "right", "uturn")
BOUNDARY_TYPES = ("solid_white", "dotted_white", "solid_yellow", "dotted_yellow", "curb", "virtual")


def as_polyline(points: Any) -> Polyline:
    a = np.asarray(points, dtype=float)
    if a.ndim == 2 and a.shape[1] == 2:  # the common case, twice as fast
        return tuple(zip(a[:, 0].tolist(), a[:, 1].tolist()))
    return tuple(map(tuple, a.tolist()))


@dataclass(frozen=True)
class Lane:
    """A lane: centreline in driving direction, boundaries, links and attributes."""

    id: str
    road_id: str
    centerline: Polyline
    left_boundary: Polyline
    right_boundary: Polyline
    width: float
    speed_limit: float
    predecessors: tuple[str, ...] = ()
    successors: tuple[str, ...] = ()
    left_neighbors: tuple[str, ...] = ()  # same direction
    right_neighbors: tuple[str, ...] = ()
    left_reverse_neighbors: tuple[str, ...] = ()  # opposite direction, across the left boundary
    turn: str = "none"
    junction_id: str | None = None
    left_boundary_type: str = "solid_white"
    right_boundary_type: str = "solid_white"
    # the lane as one cubic Bézier between its end poses: its exact geometry for junction lanes;
    # generated road lanes are true offsets of their road's Bézier with the same end poses
    bezier: Bezier | None = None

    @cached_property
    def points(self) -> np.ndarray:
        return np.asarray(self.centerline, dtype=float)

    @cached_property
    def length(self) -> float:
        return float(np.hypot(*np.diff(self.points, axis=0).T).sum())

    @property
    def start(self) -> Point:
        return self.centerline[0]

    @property
    def end(self) -> Point:
        return self.centerline[-1]

    def heading_at_start(self) -> float:
        """Exact tangent direction for Bézier lanes, first segment's direction otherwise."""
        if self.bezier is not None:
            return float(self.bezier.heading(0.0))
        (x0, y0), (x1, y1) = self.centerline[0], self.centerline[1]
        return math.atan2(y1 - y0, x1 - x0)

    def heading_at_end(self) -> float:
        if self.bezier is not None:
            return float(self.bezier.heading(1.0))
        (x0, y0), (x1, y1) = self.centerline[-2], self.centerline[-1]
        return math.atan2(y1 - y0, x1 - x0)


def line_end(ln: Lane) -> tuple[Point, Point, float]:
    """Where a governed lane meets its control's stop line: (right border point, left border point,
    travel heading) at a road lane's end, or at the start of a junction lane a control names for
    itself (`incoming_lanes`: its predecessors lie in another junction, so its line is its entry)."""
    if ln.junction_id is not None:
        return ln.right_boundary[0], ln.left_boundary[0], ln.heading_at_start()
    return ln.right_boundary[-1], ln.left_boundary[-1], ln.heading_at_end()


def stop_line_across(lanes: Mapping[str, Lane], lane_ids: Iterable[str]) -> Polyline | None:
    """A control's stop line across the lanes it governs where they meet it (`line_end`), from
    the rightmost border to the leftmost in their mean travel direction, whatever order the lanes
    are listed in; None when none of them is in `lanes`."""
    ends = [line_end(lanes[x]) for x in lane_ids if x in lanes]
    if not ends:
        return None
    h = math.atan2(sum(math.sin(e[2]) for e in ends), sum(math.cos(e[2]) for e in ends))
    pts = [p for e in ends for p in e[:2]]
    lateral = [-math.sin(h) * px + math.cos(h) * py for px, py in pts]  # leftwards of the travel direction
    return as_polyline([pts[int(np.argmin(lateral))], pts[int(np.argmax(lateral))]])


def line_across_at(lanes: Mapping[str, Lane], lane_ids: Iterable[str], point: Point) -> Polyline | None:
    """A stop line across lanes `lane_ids` where `point` (a control's pole beside them) lies
    along them, from the rightmost border to the leftmost (None when none is in `lanes`)."""
    from shapely.geometry import LineString
    from shapely.geometry import Point as At

    pts: list[tuple[float, float]] = []
    heads = []
    for lid in lane_ids:
        ln = lanes.get(lid)
        if ln is None or len(ln.centerline) < 2:
            continue
        cl = LineString(ln.centerline)
        s = cl.project(At(point))
        a, b = cl.interpolate(max(s - 0.5, 0.0)), cl.interpolate(min(s + 0.5, cl.length))
        heads.append(math.atan2(b.y - a.y, b.x - a.x))
        c = cl.interpolate(s)
        for side in (ln.left_boundary, ln.right_boundary):
            edge = LineString(side) if len(side) >= 2 else cl
            q = edge.interpolate(edge.project(c))
            pts.append((q.x, q.y))
    if not pts:
        return None
    h = math.atan2(sum(map(math.sin, heads)), sum(map(math.cos, heads)))
    lateral = [-math.sin(h) * px + math.cos(h) * py for px, py in pts]
    return as_polyline([pts[int(np.argmin(lateral))], pts[int(np.argmax(lateral))]])


def incoming_lanes(lanes: Mapping[str, Lane], lane_ids: Iterable[str]) -> tuple[str, ...]:
    """The road lanes a control governs, in the model's convention (`Signal.lane_ids`): a
    junction lane named instead (Apollo's overlaps tie controls to the junction lanes behind
    the stop line) stands for its predecessors outside the junction; unknown ids are dropped."""
    out: dict[str, None] = {}
    for lid in lane_ids:
        ln = lanes.get(lid)
        if ln is None:
            continue
        preds = [p for p in ln.predecessors if p in lanes and lanes[p].junction_id is None]
        out.update((x, None) for x in (preds if ln.junction_id is not None and preds else [lid]))
    return tuple(out)


def interior_lane(lanes: Mapping[str, Lane], ln: Lane) -> bool:
    """A road lane shorter than MIN_ARM_LENGTH_M whose predecessors and successors all lie in
    one junction: a piece of that junction (a junction split into elements joined by a
    centimetre road), neither an arm nor where a route starts or ends."""
    if ln.junction_id is not None or ln.length >= MIN_ARM_LENGTH_M or not ln.predecessors or not ln.successors:
        return False
    ends = {lanes[x].junction_id for x in ln.predecessors + ln.successors if x in lanes}
    return len(ends) == 1 and None not in ends


@dataclass(frozen=True)
class Road:
    """A road: its lanes, reference line and the junctions at its ends.

    `right_lanes` drive along the reference line, `left_lanes` against it, both listed from
    the centre divider outwards; `lane_offset` is the divider's lateral offset (left positive).
    `kind` is "connection" (junction to junction), "stub" (open end), "junction" (inside a
    junction, one lane) or "chain" (hand-written road).
    """

    id: str
    kind: str
    right_lanes: tuple[str, ...] = ()
    left_lanes: tuple[str, ...] = ()
    reference: Bezier | None = None
    lane_offset: float = 0.0
    junction_id: str | None = None
    start_junction: str | None = None
    end_junction: str | None = None

    @property
    def lane_ids(self) -> tuple[str, ...]:
        return self.right_lanes + self.left_lanes


@dataclass(frozen=True)
class Junction:
    """A junction area; `feature` is what it was built from (None for maps read from files)."""

    id: str
    polygon: Polyline
    feature: JunctionFeature | None = None
    cell: tuple[int, int] | None = None
    socket_roads: tuple[str, ...] = ()  # per socket of `feature`: the road attached there

    @cached_property
    def center(self) -> Point:
        from shapely.geometry import Polygon

        c = Polygon(self.polygon).centroid
        return (c.x, c.y)


@dataclass(frozen=True)
class Signal:
    """A traffic light: stop line across the incoming lanes, pole position and facing heading."""

    id: str
    junction_id: str | None
    stop_line: Polyline
    position: Point
    heading: float  # direction the light faces (towards the traffic it controls), radians
    lane_ids: tuple[str, ...] = ()  # incoming lanes it governs


@dataclass(frozen=True)
class TrafficSign:
    """A sign on the right of its road, facing the traffic: the line it guards, its pole, the
    incoming lanes it governs."""

    id: str
    junction_id: str | None
    stop_line: Polyline
    position: Point
    heading: float
    lane_ids: tuple[str, ...] = ()


@dataclass(frozen=True)
class StopSign(TrafficSign):
    """A stop sign: traffic on its lanes stops at the line."""


@dataclass(frozen=True)
class YieldSign(TrafficSign):
    """A yield (give-way) sign. Not a stop sign: traffic on its lanes gives way without
    stopping, so the junction stays `bare` in its feature (bare with priority: the signed
    approaches are the minor ones; see docs/extraction.md)."""


def signal_precedence(lanes: Mapping[str, Lane], signals: Mapping[str, Signal],
                      signs: Mapping[str, TrafficSign], crosswalks: Iterable["Crosswalk"] = ()) -> dict:
    """`signs` (stop or yield signs) without the lanes a signal governs: a signal governs where
    both exist (a sign under a light is for when the light is dark). A sign left with no lane
    is dropped; one that governed no lane to begin with is kept as it is. Signals guarding a
    mid-block crossing (`midblock_crossing` with `crosswalks`) do not count: they are not the
    junction's."""
    walks = list(crosswalks)
    lit = {x for g in signals.values() if g.junction_id is not None or midblock_crossing(lanes, walks, g) is None
           for x in incoming_lanes(lanes, g.lane_ids)}
    out = {}
    for k, s in signs.items():
        mine = incoming_lanes(lanes, s.lane_ids)
        keep = tuple(x for x in mine if x not in lit)
        if keep or not mine:
            out[k] = s if keep == mine else replace(s, lane_ids=keep)
    return out


@dataclass(frozen=True)
class Crosswalk:
    id: str
    junction_id: str | None
    polygon: Polyline

    def sides(self) -> tuple[Polyline, Polyline] | None:
        """The long sides of the polygon's minimum rectangle, pointing one way, the right one
        on the right of the left one: where pedestrians walk between (None if degenerate)."""
        from shapely.geometry import Polygon

        if len(self.polygon) < 3:
            return None
        c = np.asarray(Polygon(self.polygon).minimum_rotated_rectangle.exterior.coords[:4], dtype=float)
        if len(c) < 4:
            return None
        if np.hypot(*(c[1] - c[0])) < np.hypot(*(c[2] - c[1])):
            c = np.roll(c, -1, axis=0)
        a, b, cc, d = c  # a->b and d->c are the long sides
        if (b - a)[0] * (d - a)[1] - (b - a)[1] * (d - a)[0] > 0:  # d->c must lie on the right of a->b
            a, b, cc, d = d, cc, b, a
        return as_polyline([a, b]), as_polyline([d, cc])


def midblock_crossing(lanes: Mapping[str, Lane], crosswalks: Iterable[Crosswalk], control: Signal | TrafficSign
                      ) -> tuple[str, str, float] | None:
    """(crosswalk, lane, s of the line on it) when `control` guards a mid-block crossing: its
    stop line crosses one of its road lanes at s and a crosswalk outside junctions crosses that
    lane within MIDBLOCK_LINE_REACH_M beyond it, with as much lane again beyond the crosswalk (a
    crosswalk at the end of a junction's approach is that junction's); None otherwise. Readers
    leave such a control without a junction, extraction does not count it for the junction its
    lanes lead into, and the envs stop traffic at its line on the lane."""
    from shapely.geometry import LineString, Point, Polygon

    walks = [c for c in crosswalks if c.junction_id is None and len(c.polygon) >= 3]
    if not walks or len(control.stop_line) < 2:
        return None
    line = LineString(control.stop_line)
    for lid in control.lane_ids:
        ln = lanes.get(lid)
        if ln is None or ln.junction_id is not None or len(ln.centerline) < 2:
            continue
        cl = LineString(ln.centerline)
        hit = line.intersection(cl)
        if hit.is_empty:
            continue
        at = cl.project(hit.representative_point())
        for c in walks:
            cross = cl.intersection(Polygon(c.polygon))
            if cross.is_empty:
                continue
            along = [cl.project(Point(p)) for g in getattr(cross, "geoms", [cross]) for p in g.coords]
            if 0.0 < min(along) - at <= MIDBLOCK_LINE_REACH_M and max(along) <= cl.length - MIDBLOCK_LINE_REACH_M:
                return c.id, lid, float(at)
    return None


def midblock_controls(m: "HDMap") -> dict[str, tuple[str, str, float]]:
    """Signal id -> `midblock_crossing` of every signal outside junctions that guards one."""
    if not any(c.junction_id is None for c in m.crosswalks.values()):
        return {}
    out = {}
    for sig in m.signals.values():
        if sig.junction_id is None:
            hit = midblock_crossing(m.lanes, m.crosswalks.values(), sig)
            if hit is not None:
                out[sig.id] = hit
    return out


@dataclass(frozen=True)
class HDMap:
    """A whole HD map. Element dicts are keyed by id and kept in insertion order."""

    lanes: Mapping[str, Lane]
    roads: Mapping[str, Road]
    junctions: Mapping[str, Junction]
    signals: Mapping[str, Signal] = field(default_factory=dict)
    stop_signs: Mapping[str, StopSign] = field(default_factory=dict)
    crosswalks: Mapping[str, Crosswalk] = field(default_factory=dict)
    origin: Point = (0.0, 0.0)
    meta: Mapping[str, Any] = field(default_factory=dict)
    yield_signs: Mapping[str, YieldSign] = field(default_factory=dict)

    def junction_lanes(self, junction_id: str) -> list[Lane]:
        return [ln for ln in self.lanes.values() if ln.junction_id == junction_id]

    @cached_property
    def lanes_by_junction(self) -> dict[str | None, list[Lane]]:
        out: dict[str | None, list[Lane]] = {}
        for ln in self.lanes.values():
            out.setdefault(ln.junction_id, []).append(ln)
        return out

    def approaches(self, junction_id: str) -> dict[str, list[str]]:
        """Entry road -> its lanes that lead into the junction (road lanes preceding one of the
        junction's lanes), in the order the junction's lanes name them."""
        out: dict[str, dict[str, None]] = {}
        for ln in self.lanes_by_junction.get(junction_id, []):
            for p in ln.predecessors:
                pl = self.lanes.get(p)
                if pl is not None and pl.junction_id is None:
                    out.setdefault(pl.road_id, {})[p] = None
        return {road: list(lanes) for road, lanes in out.items()}

    @property
    def entry_lanes(self) -> list[Lane]:
        """Lanes with no predecessor: where traffic enters the map."""
        return [ln for ln in self.lanes.values() if not ln.predecessors]

    @property
    def exit_lanes(self) -> list[Lane]:
        return [ln for ln in self.lanes.values() if not ln.successors]

    def bounds(self) -> tuple[float, float, float, float]:
        pts = np.concatenate([ln.points for ln in self.lanes.values()])
        return float(pts[:, 0].min()), float(pts[:, 1].min()), float(pts[:, 0].max()), float(pts[:, 1].max())
