"""HDMap -> highway-env road network, with a grid-hash lane index, lane-graph routing and the
tables traffic control needs (stop lines, junction conflicts, crosswalk crossings, narrow
passages).

highway-env's frame has y pointing down: every point is flipped (x, y) -> (x, -y) here, so
right-hand traffic renders as right-hand traffic. Lane groups (the same-direction lanes of one
road) are one highway-env edge, lane 0 nearest the divider, so LANE_LEFT/LANE_RIGHT work;
graph nodes are lane-end classes joined through lane successors.
"""
from __future__ import annotations

import ctypes
import gc
import heapq
import math
from dataclasses import dataclass, field, replace
from typing import Any, Iterable, Iterator, Mapping

import numpy as np
from highway_env.road.lane import LineType
from highway_env.road.road import LaneIndex, RoadNetwork
import shapely
import shapely.ops
from shapely import STRtree
from shapely.geometry import LineString, Point, Polygon

from ..angles import wrap_angle
from ..config import (CONFLICT_DISTANCE_M, CONVERGE_MAX_ANGLE_DEG, CROSSING_CLEARANCE_M, CURVE_CHORD_M,
                      FOOTPRINT_STEP_M, LANE_ROUTES_KEPT, MERGE_REACH_M, PASSAGE_DISTANCE_M, PASSAGE_STEP_M,
                      ROUTE_SEARCH_SLACK_M, TRACKING_MARGIN_M,
                      VEHICLE_LENGTH_M, VEHICLE_WIDTH_M)
from ..errors import Feat2MapError
from ..extract_ramps import ramp_moves
from ..model import HDMap, Lane, incoming_lanes, midblock_controls
from .lanes import PolylineLane, project_rows, segment_table
from .sweep import stretches, turn_setbacks

GRID_CELL_M = 8.0
_LINE = {"solid_white": LineType.CONTINUOUS_LINE, "solid_yellow": LineType.CONTINUOUS_LINE,
         "curb": LineType.CONTINUOUS_LINE, "dotted_white": LineType.STRIPED,
         "dotted_yellow": LineType.STRIPED, "virtual": LineType.NONE}
_PRIORITY = {"none": 2, "right": 2, "left": 1, "uturn": 0}


def _clear_of_crossings(ln, cl: LineString, road_lanes: "RoadLanes") -> float:
    """s on the incoming lane `ln` (centreline `cl`) at which a vehicle waiting at its line stands
    clear of every road lane of another road its centreline crosses (the crossing less half that
    lane's width and CROSSING_CLEARANCE_M); inf when it crosses none. GoMentum's lane_79 crosses
    lane_78, an exit of J_13, 2 m before its stop line: a car waiting there stood in the path of
    the right turn into lane_78."""
    roads, lines, tree = road_lanes
    linked = {ln.id, *ln.predecessors, *ln.successors}
    best = math.inf
    for k in tree.query(cl, predicate="intersects").tolist():
        other = roads[k]
        if other.road_id == ln.road_id or other.id in linked or set(other.predecessors) & set(ln.predecessors) \
                or set(other.successors) & set(ln.successors):
            continue
        inter = cl.intersection(lines[k])
        for g in getattr(inter, "geoms", [inter]):
            for p in g.coords:
                best = min(best, cl.project(Point(p)) - other.width / 2 - CROSSING_CLEARANCE_M)
    return max(best, 0.0)


def _clear_of_paths_over(ln, cl: LineString, m, s_line: float) -> float:
    """s on the incoming lane `ln` (centreline `cl`) at which a vehicle waiting at its line stands
    clear of the junction's lanes from other approaches that run over `ln` itself (within its half
    width) where a car waiting at `s_line` stands (its length before the line): where such a lane
    comes onto `ln` there, less half its width and CROSSING_CLEARANCE_M; inf when none does.
    osm2xodr draws a cluster's paths over the last metre of an approach (scheck-in's
    `j_14959944_c98` passes 0.9 m from the centre of `w268002703_2_0_-1` at its line): the car
    waiting there stood in their way. Only the lanes of the junctions `ln` leads into are looked
    at (`HDMap.lanes_by_junction`)."""
    own = set(ln.successors)
    jids = {m.lanes[s].junction_id for s in own if s in m.lanes} - {None}
    best = math.inf
    area = cl.buffer(ln.width / 2, cap_style="flat")
    for other in (o for j in sorted(jids) for o in m.lanes_by_junction.get(j, ())):
        if other.id in own or other.id in ln.predecessors or not other.predecessors \
                or ln.id in other.successors or set(other.predecessors) & (own | {ln.id} | set(ln.predecessors)):
            continue  # its own paths, the paths leading into it (a cluster's element around a short road), and
            # paths no lane leads into: no one drives them (CommonRoad's Guetersloh 21_0_1 starts on 36_0_-1's end)
        line = LineString(other.centerline)
        if not line.intersects(area):
            continue
        inter = line.intersection(area)
        for g in getattr(inter, "geoms", [inter]):
            for p in getattr(g, "coords", []):
                s = cl.project(Point(p))
                if s >= s_line - VEHICLE_LENGTH_M:
                    best = min(best, s - other.width / 2 - CROSSING_CLEARANCE_M)
    return max(best, 0.0)


RoadLanes = tuple[list, list[LineString], STRtree]  # road lanes (outside junctions), centrelines, their STRtree


def _road_lanes(hdmap) -> RoadLanes:
    """The map's road lanes, their centrelines and an STRtree over them: built once per network
    for the stop lines' crossing clearances and the narrow passages."""
    roads = [ln for ln in hdmap.lanes.values() if ln.junction_id is None]
    lines = [LineString(ln.centerline) for ln in roads]
    return roads, lines, STRtree(lines)


def _tangent(line: LineString, s: float) -> np.ndarray:
    """Chord of `line` over the metre around arc length `s`, kept on the line (shapely reads a
    negative distance from the far end: at s = 0 the chord pointed backwards, so lanes that
    coincide with an opposite lane from their start, Baidu-style `2765`/`2765dup1`, read as the
    same direction and their passage was missed)."""
    a, b = (np.asarray(line.interpolate(min(max(s + d, 0.0), line.length)).coords[0]) for d in (-0.5, 0.5))
    return b - a


def _curvature(line: LineString, s: np.ndarray) -> np.ndarray:
    """|curvature| [1/m] of `line` at arc lengths `s`: the turn between the chords CURVE_CHORD_M
    long either side (kept on the line), over the distance between their midpoints, so polyline
    kinks of read maps do not read as sharp bends."""
    c = CURVE_CHORD_M
    p = [np.asarray(shapely.get_coordinates(shapely.line_interpolate_point(line, np.clip(s + d, 0.0, line.length))))
         for d in (-c, 0.0, c)]
    d1, d2 = p[1] - p[0], p[2] - p[1]
    n1, n2 = np.hypot(*d1.T), np.hypot(*d2.T)
    h1, h2 = np.arctan2(d1[:, 1], d1[:, 0]), np.arctan2(d2[:, 1], d2[:, 0])
    both = (n1 > 1e-6) & (n2 > 1e-6)  # at a lane end one chord is empty: no turn measured there
    turn = np.where(both, np.abs(wrap_angle(h2 - h1)), 0.0)
    return turn / np.maximum((n1 + n2) / 2, 1e-6)


def swing(curvature):
    """How far [m] a car (VEHICLE_LENGTH_M x VEHICLE_WIDTH_M) whose centre follows a bend of this
    curvature sweeps beyond its width: its outer corners reach sqrt((R + W/2)^2 + (L/2)^2) from
    the bend's centre (0 on a straight)."""
    k = np.asarray(curvature, dtype=float)
    hl, hw = VEHICLE_LENGTH_M / 2, VEHICLE_WIDTH_M / 2
    return hl * hl * k / (np.sqrt((1 + k * hw) ** 2 + (k * hl) ** 2) + 1 + k * hw)


def _one_stream(m: HDMap, a: Lane, b: Lane) -> bool:
    """Whether junction lane `b` follows junction lane `a` through road lanes shorter together
    than two cars: a car on `b` is the leader of one leaving `a`, never in its way across a path
    (osm2xodr draws a cluster of junctions as one element; the footprints of two of its lanes
    joined by a 4.9 m road overlap, and a car waiting on the road for its light waited for the
    car queued behind it: karl-wilhelm r039)."""
    frontier, room = [(s, 0.0) for s in a.successors], 2 * VEHICLE_LENGTH_M
    while frontier:
        lid, d = frontier.pop()
        ln = m.lanes.get(lid)
        if ln is None or ln.junction_id is not None:
            continue
        d += ln.length
        if d >= room:
            continue
        if b.id in ln.successors:
            return True
        frontier += [(x, d) for x in ln.successors]
    return False


def _exit_lanes(m: HDMap, ln: Lane) -> set[str]:
    """The lanes junction lane `ln` ends in (`merge_pairs`): its successors, and the road lanes
    that road pieces adding up to less than MERGE_REACH_M lead on to."""
    out = set(ln.successors)
    frontier = [(x, 0.0) for x in ln.successors]
    while frontier:
        x, d = frontier.pop()
        piece = m.lanes.get(x)
        if piece is None or piece.junction_id is not None or d + piece.length >= MERGE_REACH_M:
            continue
        for y in piece.successors:
            if y in m.lanes and m.lanes[y].junction_id is None and y not in out:
                out.add(y)
                frontier.append((y, d + piece.length))
    return out


def merge_pairs(m: HDMap) -> list[tuple[str, str]]:
    """Pairs of junction lanes from different approaches that end in one lane (a merge: a left
    turn into the lane straight traffic enters): conflicts like crossings (issue 21). They are
    registered from the links, not only from how close the centrelines come, so a merge counts
    where a map's junction lanes end apart on a wide exit lane or carry different junction ids
    (overlapping junction polygons). Paths from one lane (a diverge) never merge. A lane also
    ends in the road lanes it reaches through road pieces shorter than MERGE_REACH_M: a
    signalised filter lane joins its exit road just after the piece that the junction's own lanes
    run on, and the two streams met there side by side (a highway-and-city map, r010)."""
    into: dict[str, list] = {}
    for ln in m.lanes.values():
        if ln.junction_id is not None:
            for x in _exit_lanes(m, ln):
                into.setdefault(x, []).append(ln)
    out: set[tuple[str, str]] = set()
    for group in into.values():
        for i, a in enumerate(group):
            for b in group[i + 1:]:
                if a.id != b.id and not set(a.predecessors) & set(b.predecessors):
                    out.add((min(a.id, b.id), max(a.id, b.id)))
    return sorted(out)


def converging_pairs(m: HDMap, road_lanes: "RoadLanes | None" = None) -> list[tuple[str, str]]:
    """Pairs of road lanes of one direction (not linked to each other) whose centrelines come
    closer than CONFLICT_DISTANCE_M (a car width and a margin): a taper merge along a road
    (Highway101GLE's lane_92 and lane_93 of road_17 converge over 148 m into one point), a lane
    opening or closing beside another, a diverge. Vehicles on them cannot drive side by side
    there: they zip (`MapNetwork.merges`). Found from the geometry, since such maps declare no
    merge outside junctions; lanes that meet only head to tail, and lanes that come close at more
    than CONVERGE_MAX_ANGLE_DEG (a road over another), are left out."""
    roads, lines, tree = road_lanes if road_lanes is not None else _road_lanes(m)
    out: set[tuple[str, str]] = set()
    if not lines:
        return []
    left, right = tree.query(lines, predicate="dwithin", distance=CONFLICT_DISTANCE_M)
    for i, j in zip(left.tolist(), right.tolist()):
        a, b = roads[i], roads[j]
        if i >= j or b.id in {*a.predecessors, *a.successors}:
            continue
        la, lb = lines[i], lines[j]
        pa, pb = shapely.ops.nearest_points(la, lb)
        sa, sb = la.project(pa), lb.project(pb)
        ta, tb = _tangent(la, sa), _tangent(lb, sb)
        cos = float(np.dot(ta, tb)) / max(float(np.linalg.norm(ta) * np.linalg.norm(tb)), 1e-12)
        if cos <= 0.0:
            continue  # opposite directions: a narrow passage
        if cos < math.cos(math.radians(CONVERGE_MAX_ANGLE_DEG)):
            continue  # lanes that come close at a steep angle cross (Town04's bridges), they do not zip
        if (sa >= la.length - 1e-6 and sb <= 1e-6) or (sb >= lb.length - 1e-6 and sa <= 1e-6):
            continue  # head to tail
        out.add((min(a.id, b.id), max(a.id, b.id)))
    return sorted(out)


def _meets(lanes: Mapping[str, Any], ln, rd) -> bool:
    """Whether road lane `rd` meets junction lane `ln` where lanes join at a junction's edge: it
    links to a lane of `ln`'s junction, lies on the road of one of `ln`'s own links, or shares a
    successor or predecessor with it (a merge or a split, not a crossing)."""
    links = (*rd.predecessors, *rd.successors)
    return any(x in lanes and lanes[x].junction_id == ln.junction_id for x in links) \
        or rd.road_id in {lanes[x].road_id for x in (*ln.predecessors, *ln.successors) if x in lanes} \
        or bool(set(rd.successors) & set(ln.successors) or set(rd.predecessors) & set(ln.predecessors))


def road_crossings(jl: list, lines: list[LineString], road_lanes: "RoadLanes",
                   lanes: Mapping[str, Any] | None = None) -> list[tuple[str, str]]:
    """(junction lane, road lane) pairs whose centrelines cross, at least CROSSING_CLEARANCE_M
    from either lane's ends where the road lane meets the junction lane (`_meets`: lanes joining
    at the junction's edge touch there), else (`lanes`, the map's lanes, given) from the ends of
    one of them (ends that touch are where lanes join, declared or not): a junction lane that
    runs out of its junction across a road lane (USA_Lanker's 35.5 m 41_0_-1 across 47_0_-1, a
    road lane just after the junction), or a road lane of another road
    that osm2xodr draws across a junction lane's last metre (scheck-in's `w669252633_0_0_-1`
    across `j_26026265_c55_0_-1`, 0.9 m before its end: r078). They conflict like two junction
    lanes, and a vehicle entering the junction towards that road lane claims it with its
    junction lanes (`TrafficRules.junction_chain`)."""
    roads, rlines, tree = road_lanes
    out: list[tuple[str, str]] = []
    if not rlines or not lines:
        return out
    a_idx, b_idx = tree.query(lines, predicate="crosses")
    for i, k in zip(a_idx.tolist(), b_idx.tolist()):
        ln, rd = jl[i], roads[k]
        if rd.id in {*ln.predecessors, *ln.successors}:
            continue
        inter = lines[i].intersection(rlines[k])
        for p in shapely.get_coordinates(inter):
            pt = Point(p)
            sa, sb = lines[i].project(pt), rlines[k].project(pt)
            c = CROSSING_CLEARANCE_M
            mid_a, mid_b = c <= sa <= lines[i].length - c, c <= sb <= rlines[k].length - c
            if (mid_a and mid_b) or ((mid_a or mid_b) and lanes is not None and not _meets(lanes, ln, rd)):
                out.append((ln.id, rd.id))
                break
    return out


def unregistered_merges(net: "MapNetwork") -> list[str]:
    """Load-time check: every merge (`merge_pairs`) is a conflict in the network's table, like a
    crossing; one line per pair that is not (empty when sound)."""
    return [f"junction lanes {a} and {b} merge into one lane but are no conflict"
            for a, b in merge_pairs(net.hdmap) if b not in net.conflicts.get(a, ())]


def unguarded_coincident_lanes(net: "MapNetwork", tolerance: float = 0.1) -> list[str]:
    """Load-time check: road lanes of opposite directions whose centre lines coincide (within
    `tolerance` metres, Baidu-style `2765`/`2765dup1`) are both in one narrow passage (one
    direction at a time); one line per pair that is not (empty when sound)."""
    roads, lines, tree = _road_lanes(net.hdmap)
    out: list[str] = []
    if not lines:
        return out
    left, right = tree.query(lines, predicate="dwithin", distance=tolerance)
    for i, j in zip(left.tolist(), right.tolist()):
        a, b = roads[i], roads[j]
        if i >= j or lines[i].hausdorff_distance(lines[j].reverse()) > tolerance:
            continue
        pa, pb = net.passages.get(a.id), net.passages.get(b.id)
        if pa is None or pb is None or pa.group != pb.group or pa.side == pb.side:
            x, y = sorted((a.id, b.id))
            out.append(f"road lanes {x} and {y} coincide in opposite directions but are no narrow passage")
    return out


def flip(points) -> np.ndarray:
    """Map frame (y north) -> highway-env frame (y down)."""
    p = np.asarray(points, dtype=float).reshape(-1, 2).copy()
    p[:, 1] *= -1.0
    return p


LINE_SIGNAL, LINE_STOP_SIGN = 1, 2  # a stop line's kind as a number (0: none; `core.LaneTable.line_kind`)


class LaneSet(frozenset):
    """A frozenset of lane ids that iterates in their sorted order: a walk over it (the rules', an
    observation's) takes equals in the same order in every process, whatever its string hashes."""

    __slots__ = ("_order",)
    _order: tuple[str, ...]

    def __new__(cls, items: Iterable[str] = ()) -> "LaneSet":
        self = super().__new__(cls, items)
        self._order = tuple(sorted(frozenset.__iter__(self)))
        return self

    def __iter__(self) -> Iterator[str]:
        return iter(self._order)


@dataclass(frozen=True)
class StopLine:
    """A controlled stop line on one lane: `s` along the lane (metres), kind signal/stop."""

    kind: str
    control_id: str
    junction_id: str | None
    s: float


@dataclass(frozen=True)
class Passage:
    """Where a road lane runs closer than PASSAGE_DISTANCE_M to a road lane of the opposite
    direction (one-lane two-way roads: autonomous_stuff's opposite lanes 0.5 m apart; a road
    splitting into two one-way roads: GoMentum's lane_61 and lane_62 2.1 m apart): vehicles
    of the two directions cannot pass each other there. `group` numbers the passage (the lanes
    linked by such pairs), `side` is the lane's direction in it (0 or 1), [s0, s1] its stretch
    of the lane."""

    group: int
    side: int
    s0: float
    s1: float


def on_lane(width, length, s, r, lane_heading, heading):
    """Whether a road user at (s along, r beside) a lane of this width and length, heading
    `heading` where the lane heads `lane_heading`, is on that lane: within its width, at most
    0.5 m past either end, and no more than 60 degrees across it (no heading: any). Floats, or
    arrays of rows (`TrafficCore.locate`). The test `locate` puts to its hint lane."""
    on = (abs(r) <= width / 2) & (s >= -0.5) & (s <= length + 0.5)
    return on if heading is None else on & (abs(wrap_angle(lane_heading - heading)) < math.pi / 3)


@dataclass
class MapNetwork(RoadNetwork):
    """A `RoadNetwork` built from an HDMap, with O(1) lane lookups and lane-level routing."""

    hdmap: HDMap  # MapNetwork.from_map builds it
    lane_ids: list[str] = field(default_factory=list)  # integer lane number -> map lane id
    index_of: dict[str, LaneIndex] = field(default_factory=dict)  # map lane id -> highway-env index
    id_of: dict[LaneIndex, str] = field(default_factory=dict)
    lane_of: dict[str, PolylineLane] = field(default_factory=dict)
    stop_lines: dict[str, StopLine] = field(default_factory=dict)  # incoming lane id -> stop line
    setbacks: dict[str, float] = field(default_factory=dict)  # incoming lane -> how far before its end vehicles wait (> 0)
    conflicts: dict[str, LaneSet] = field(default_factory=dict)  # junction lane -> conflicting ones (+ road_crossings)
    crossings: dict[str, list[tuple[str, float, float]]] = field(default_factory=dict)  # lane -> (crosswalk, s0, s1)
    crosswalk_axes: dict[str, tuple[np.ndarray, np.ndarray, float]] = field(default_factory=dict)
    midblock_lines: dict[str, list[tuple[str, float]]] = field(default_factory=dict)  # road lane -> (light, s of its line)
    yield_entries: frozenset[str] = frozenset()  # filter lanes behind a yield sign (`rules.TrafficRules.yield_held`)
    max_line_setback: float = 0.0  # the farthest a wait point (`setbacks`) lies before its lane's end [m]
    passages: dict[str, "Passage"] = field(default_factory=dict)  # road lane -> its narrow passage zone
    merges: dict[str, dict[str, float]] = field(default_factory=dict)  # road lane -> {converging lane: zip end s}
    swept: dict[str, list[tuple[float, float]]] = field(default_factory=dict)  # passage lane -> `sweep.stretches`
    _memo: dict = field(default_factory=dict, repr=False, compare=False)

    def near_lanes(self, lane_id: str) -> frozenset[str]:
        """Lanes whose road users may be in the way of a vehicle on `lane_id`, besides its own:
        for a junction lane those it conflicts with and those diverging from its predecessors,
        for a road lane those converging with it (`merges`)."""
        def build() -> dict[str, frozenset[str]]:
            m = self.hdmap
            out = {}
            for lid, ln in m.lanes.items():
                if ln.junction_id is None:
                    near = set(self.merges.get(lid, ()))
                else:
                    near = set(self.conflicts.get(lid, ()))
                    for p in ln.predecessors:
                        if p in m.lanes:
                            near.update(x for x in m.lanes[p].successors if x != lid)
                out[lid] = frozenset(near)
            return out
        return self.memo("near lanes", build)[lane_id]

    def merge_ahead(self, lane_a: str, pos_a, lane_b: str, pos_b) -> bool:
        """Whether a road user at `pos_b` on `lane_b` is ahead of one at `pos_a` on `lane_a`, lanes
        that converge: both measured along the pair's reference lane (the smaller id), so that of
        two users side by side exactly one is the other's leader (each measuring along its own
        lane, both could brake for the other and stand there)."""
        ref = self.lane_of[min(lane_a, lane_b)]
        return ref.local_coordinates(pos_b)[0] > ref.local_coordinates(pos_a)[0]

    @property
    def ramp_moves(self) -> dict[str, str]:
        """Junction lane -> "merge" / "diverge" for the lanes that drive the map's ramps
        (`feat2map.extract_ramps.ramp_moves`), found once per map."""
        return self.memo("ramp_moves", lambda: ramp_moves(self.hdmap))

    def memo(self, key, build):
        """A value derived from the (immutable) network, built once: per-map tables that every
        reset would otherwise rebuild by scanning the whole map."""
        if key not in self._memo:
            self._memo[key] = build()
        return self._memo[key]

    def segment_table(self) -> tuple[np.ndarray, ...]:
        """The projection arrays of every lane (`lanes.segment_table`, what `lanes.project_rows`
        reads), built once."""
        return self.memo("segment table", lambda: segment_table(self._lanes))

    def __post_init__(self) -> None:
        self.graph: dict[str, dict[str, list]] = {}

    # ---- construction -------------------------------------------------------------------
    @classmethod
    def from_map(cls, m: HDMap) -> "MapNetwork":
        if not m.lanes:
            raise Feat2MapError("the map has no lanes", "map")
        net = cls(hdmap=m)
        parent: dict[str, str] = {}

        def find(x: str) -> str:
            while parent.setdefault(x, x) != x:
                parent[x] = parent[parent[x]]
                x = parent[x]
            return x

        def union(a: str, b: str) -> None:
            ra, rb = find(a), find(b)
            if ra != rb:
                parent[max(ra, rb)] = min(ra, rb)

        groups: list[list[str]] = []
        grouped: set[str] = set()
        for road in m.roads.values():
            for side in (road.right_lanes, road.left_lanes):
                g = [lid for lid in side if lid in m.lanes]
                if g:
                    groups.append(g)
                    grouped.update(g)
        groups += [[lid] for lid in m.lanes if lid not in grouped]
        for lane in m.lanes.values():
            for succ in lane.successors:
                if succ in m.lanes:
                    union(f"{lane.id}:e", f"{succ}:s")
        for g in groups:
            for lid in g[1:]:
                union(f"{g[0]}:s", f"{lid}:s")
                union(f"{g[0]}:e", f"{lid}:e")
        names: dict[str, str] = {}

        def node(x: str) -> str:
            r = find(x)
            return names.setdefault(r, f"n{len(names)}")

        for g in groups:
            a, b = node(f"{g[0]}:s"), node(f"{g[0]}:e")
            for lid in g:
                ln = m.lanes[lid]
                lane = PolylineLane(
                    flip(ln.centerline), ln.width,
                    (_LINE.get(ln.left_boundary_type, LineType.NONE), _LINE.get(ln.right_boundary_type, LineType.NONE)),
                    speed_limit=ln.speed_limit, priority=_PRIORITY.get(ln.turn, 1) if ln.junction_id else 3, lane_id=lid)
                lanes = net.graph.setdefault(a, {}).setdefault(b, [])
                idx = (a, b, len(lanes))
                lanes.append(lane)
                net.index_of[lid] = idx
                net.id_of[idx] = lid
                net.lane_of[lid] = lane
                net.lane_ids.append(lid)
        net._build_index()
        road_lanes = _road_lanes(m)
        net._build_controls(road_lanes)
        net._build_passages(road_lanes)
        if net.passages:
            net.swept = stretches(net)
        net._build_merges(road_lanes)
        problems = unregistered_merges(net) + unguarded_coincident_lanes(net)  # sound by construction: asserted
        if problems:
            raise Feat2MapError(problems[0] + (f" (and {len(problems) - 1} more)" if len(problems) > 1 else ""), "map")
        return net

    def _build_index(self) -> None:
        """Grid hash of lane segments: every segment's arrays once, each cell a view of the
        segment ids (and their lanes) near it, so the index stays small on big maps."""
        self._lanes = [self.lane_of[lid] for lid in self.lane_ids]
        self._indices = [self.index_of[lid] for lid in self.lane_ids]
        c = GRID_CELL_M
        lane_k = np.concatenate([np.full(len(ln.seg_len), k, dtype=np.int32) for k, ln in enumerate(self._lanes)])
        self._seg_a = np.concatenate([ln.a for ln in self._lanes])
        self._seg_u = np.concatenate([ln.u for ln in self._lanes])
        self._seg_len = np.concatenate([ln.seg_len for ln in self._lanes])
        self._seg_cum = np.concatenate([ln.cum[:-1] for ln in self._lanes])
        self._seg_h = np.concatenate([ln.seg_heading for ln in self._lanes])
        pad = np.concatenate([np.full(len(ln.seg_len), ln.width / 2 + 1.0) for ln in self._lanes])
        b = self._seg_a + self._seg_u * self._seg_len[:, None]
        lo = np.floor((np.minimum(self._seg_a, b) - pad[:, None]) / c).astype(np.int64)
        hi = np.floor((np.maximum(self._seg_a, b) + pad[:, None]) / c).astype(np.int64)
        span = (hi - lo + 1)
        count = span[:, 0] * span[:, 1]
        seg = np.repeat(np.arange(len(lane_k), dtype=np.int32), count)
        local = np.arange(count.sum()) - np.repeat(np.cumsum(count) - count, count)
        gx = lo[seg, 0] + local // span[seg, 1]
        gy = lo[seg, 1] + local % span[seg, 1]
        order = np.lexsort((seg, gy, gx))
        gx, gy, seg = gx[order], gy[order], seg[order]
        self._cell_seg = seg
        self._cell_lane = lane_k[seg]
        starts = np.concatenate([[0], np.nonzero((np.diff(gx) != 0) | (np.diff(gy) != 0))[0] + 1, [len(seg)]])
        self._cells = {(int(gx[i]), int(gy[i])): (self._cell_lane[i:j], self._cell_seg[i:j])
                       for i, j in zip(starts[:-1], starts[1:])}
        allpts = np.concatenate([ln.points for ln in self._lanes])
        self.extent = (*allpts.min(axis=0), *allpts.max(axis=0))

    def locate(self, position: np.ndarray, heading: float | None = None,
               hint: LaneIndex | None = None) -> tuple[LaneIndex, float, float]:
        """(lane index, s, lateral) of the lane nearest a position, preferring `hint` when on it."""
        x, y = float(position[0]), float(position[1])
        if hint is not None:
            lane = self.get_lane(hint)
            s, r = lane.local_coordinates(position)
            if on_lane(lane.width, lane.length, s, r, lane.heading_at(s) if heading is not None else None, heading):
                return hint, s, r
        key = (math.floor(x / GRID_CELL_M), math.floor(y / GRID_CELL_M))
        cell = self._cells.get(key)
        if cell is None:
            return self._far_locate(position, heading)
        ks, segs = cell
        a, u, ln, cum, h = self._seg_a[segs], self._seg_u[segs], self._seg_len[segs], self._seg_cum[segs], self._seg_h[segs]
        rx, ry = x - a[:, 0], y - a[:, 1]
        t = np.clip(rx * u[:, 0] + ry * u[:, 1], 0.0, ln)
        dx, dy = rx - t * u[:, 0], ry - t * u[:, 1]
        cost = np.sqrt(dx * dx + dy * dy)
        if heading is not None:
            cost = cost + np.abs(wrap_angle(h - heading))
        j = int(np.argmin(cost))
        k = int(ks[j])
        lat = u[j, 0] * ry[j] - u[j, 1] * rx[j]
        return self._indices[k], float(cum[j] + t[j]), float(lat)

    def locate_many(self, positions: list, headings: list, hints: list) -> list[tuple[LaneIndex, float, float]]:
        """`locate` of many road users at once (each with its hint lane): the projections on the
        hint lanes are one array program (`lanes.project_rows`, the same arithmetic); whoever is
        not on its hint lane is located alone."""
        out: list = [None] * len(positions)
        index = self.memo("lane object index", lambda: {id(ln): k for k, ln in enumerate(self._lanes)})
        lanes = [self.get_lane(h) if h is not None else None for h in hints]
        ks = [index.get(id(ln), -1) if ln is not None else -1 for ln in lanes]
        batch = [g for g, k in enumerate(ks) if k >= 0 and self._lanes[k] is lanes[g]]
        if batch:
            x = np.array([[float(positions[g][0])] for g in batch])
            y = np.array([[float(positions[g][1])] for g in batch])
            table = self.segment_table()
            s_all, r_all = project_rows(table, np.array([ks[g] for g in batch], dtype=np.int64), x, y)
            for g, s, r in zip(batch, s_all[:, 0].tolist(), r_all[:, 0].tolist()):
                lane, heading = lanes[g], headings[g]
                if lane is not None and on_lane(lane.width, lane.length, s, r,
                                                lane.heading_at(s) if heading is not None else None, heading):
                    out[g] = (hints[g], s, r)
        return [o if o is not None else self.locate(p, h, hint) for o, p, h, hint in zip(out, positions, headings, hints)]

    def _far_locate(self, position, heading):
        """`locate` of a place in no grid cell (off the map): the lane whose bounding box is
        nearest (the sum of the gaps along x and y; the first of equals), one array program over
        the lanes' boxes."""
        box = self.memo("lane boxes", lambda: np.array([lane.bbox for lane in self._lanes], dtype=float))
        x, y = float(position[0]), float(position[1])
        gap = np.maximum(np.maximum(box[:, 0] - x, 0.0), x - box[:, 2]) + \
            np.maximum(np.maximum(box[:, 1] - y, 0.0), y - box[:, 3])
        k = int(np.argmin(gap))
        s, r = self._lanes[k].local_coordinates(position)
        return self._indices[k], s, r

    def get_closest_lane_index(self, position: np.ndarray, heading: float | None = None) -> LaneIndex:
        return self.locate(position, heading)[0]

    def get_lane(self, index: LaneIndex) -> PolylineLane:
        _from, _to, _id = index
        if _id is None:
            _id = 0
        return self.graph[_from][_to][_id]

    # ---- controls and conflicts -----------------------------------------------------------
    def _footprints(self, lane_id: str) -> np.ndarray:
        """Corners (n, 4, 2) of a vehicle's rectangle (highway-env's, widened by TRACKING_MARGIN_M
        a side but kept inside its lane) every FOOTPRINT_STEP_M along a lane, in the map frame:
        together the area a vehicle driving the lane sweeps."""
        ln = self.hdmap.lanes[lane_id]
        pts = np.asarray([p[:2] for p in ln.centerline], dtype=float)
        seg = np.diff(pts, axis=0)
        cum = np.concatenate([[0.0], np.cumsum(np.hypot(seg[:, 0], seg[:, 1]))])
        s = np.linspace(0.0, cum[-1], max(2, int(math.ceil(cum[-1] / FOOTPRINT_STEP_M)) + 1))
        k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(seg) - 1)
        t = ((s - cum[k]) / np.maximum(cum[k + 1] - cum[k], 1e-9))[:, None]
        centre = pts[k] + t * seg[k]
        u = seg[k] / np.maximum(np.hypot(seg[k, 0], seg[k, 1]), 1e-9)[:, None]
        n = np.stack([-u[:, 1], u[:, 0]], axis=1)
        hl = VEHICLE_LENGTH_M / 2
        hw = min(VEHICLE_WIDTH_M / 2 + TRACKING_MARGIN_M, max(ln.width / 2 - 0.1, VEHICLE_WIDTH_M / 2))
        return np.stack([centre + a * hl * u + b * hw * n for a, b in ((1, 1), (1, -1), (-1, -1), (-1, 1))], axis=1)

    def _build_setbacks(self) -> None:
        """`setbacks`, the one source of every junction entry's wait point: a stop line's distance
        before its lane's end, and at a bare entry (no line) the same clearance a line gets from
        the junction's paths drawn over the approach (`_clear_of_paths_over`). osm2xodr draws a
        cluster's paths over bare approaches too: durlacher-tor's `j_14892149_c16` crosses
        `w656222580_0_0_-1` 0.8 m before its end, where a car waiting at the entry stood."""
        m = self.hdmap
        for lid, sl in self.stop_lines.items():
            if self.lane_of[lid].length - sl.s > 0.0:
                self.setbacks[lid] = self.lane_of[lid].length - sl.s
        bare = {p for jid, lanes in m.lanes_by_junction.items() if jid is not None for jl in lanes
                for p in jl.predecessors
                if p in m.lanes and m.lanes[p].junction_id is None and p not in self.stop_lines and p in self.lane_of}
        for lid in sorted(bare):
            ln, length = m.lanes[lid], self.lane_of[lid].length
            s = min(length, _clear_of_paths_over(ln, LineString(ln.centerline), m, length))
            if length - s > 0.0:
                self.setbacks[lid] = length - s
        for lid, back in turn_setbacks(self, self.setbacks, sorted(set(self.stop_lines) | bare)).items():
            self.setbacks[lid] = back  # out of the swept path of a turn tighter than a car turns
            if lid in self.stop_lines:
                self.stop_lines[lid] = replace(self.stop_lines[lid], s=self.lane_of[lid].length - back)
        self.max_line_setback = max(self.setbacks.values(), default=0.0)

    def _build_controls(self, road_lanes: RoadLanes) -> None:
        m = self.hdmap
        if m.yield_signs:  # filter lanes behind a yield sign give way at their entry
            from ..extract import extract_filters

            self.yield_entries = frozenset(f.id for f in extract_filters(m) if f.early and f.control == "yield")
        midblock = midblock_controls(m)  # lights of mid-block crossings: lines on their lanes, not junction entries
        for sid in midblock:
            sig = m.signals[sid]
            line = LineString(sig.stop_line)
            for lid in incoming_lanes(m.lanes, sig.lane_ids):
                cl = LineString(m.lanes[lid].centerline)
                if line.intersects(cl):
                    s = cl.project(line.intersection(cl).representative_point())
                    self.midblock_lines.setdefault(lid, []).append((sid, float(s)))
        for kind, table in (("signal", m.signals), ("stop", m.stop_signs)):
            for c in table.values():
                if c.id in midblock and kind == "signal":
                    continue
                line = LineString(c.stop_line) if len(c.stop_line) >= 2 else None
                for lid in incoming_lanes(m.lanes, c.lane_ids):
                    ln = m.lanes[lid]
                    cl = LineString(ln.centerline)
                    s = ln.length
                    if line is not None and line.intersects(cl):
                        inter = line.intersection(cl)
                        s = cl.project(inter.representative_point())
                    s = min(s, self.lane_of[lid].length, _clear_of_crossings(ln, cl, road_lanes))
                    s = min(s, _clear_of_paths_over(ln, cl, m, s))
                    self.stop_lines[lid] = StopLine(kind, c.id, c.junction_id, float(s))
        self._build_setbacks()
        # junction conflicts: different entry lanes whose paths cross, merge or pass too close
        jl = [ln for ln in m.lanes.values() if ln.junction_id is not None]
        lines = [LineString(ln.centerline) for ln in jl]
        conf: dict[str, set[str]] = {ln.id: set() for ln in jl}
        if lines:
            # two junction lanes conflict when their paths pass closer than a car width, or when the
            # footprints of vehicles driving them overlap (sharp turns side by side: the bodies
            # swing beyond their paths)
            tree = STRtree(lines)
            left, right = tree.query(lines, predicate="dwithin", distance=CONFLICT_DISTANCE_M)
            rects = [self._footprints(ln.id) for ln in jl]
            owner = np.repeat(np.arange(len(jl)), [len(r) for r in rects])
            boxes = shapely.polygons(np.concatenate(rects))
            bi, bj = STRtree(boxes).query(boxes, predicate="intersects")
            pairs = set(zip(left.tolist(), right.tolist())) | set(zip(owner[bi].tolist(), owner[bj].tolist()))
            for i, j in sorted(pairs):
                if i >= j:
                    continue
                a, b = jl[i], jl[j]
                if a.junction_id != b.junction_id or set(a.predecessors) & set(b.predecessors) or \
                        _one_stream(m, a, b) or _one_stream(m, b, a):
                    continue
                conf[a.id].add(b.id)
                conf[b.id].add(a.id)
        for a, b in merge_pairs(m):  # whatever their geometry or junction ids say
            conf[a].add(b)
            conf[b].add(a)
        for a, b in road_crossings(jl, lines, road_lanes, m.lanes):
            conf[a].add(b)
            conf.setdefault(b, set()).add(a)
        self.conflicts = {k: LaneSet(v) for k, v in conf.items()}
        # crosswalk crossings: junction lanes across any crosswalk, road lanes across those outside
        # junctions (mid-block crossings; a junction's crosswalks reach onto its approaches' ends)
        cws = list(m.crosswalks.values())
        if cws:
            polys = [Polygon(c.polygon) for c in cws]
            tree = STRtree(polys)
            road = [ln for ln in m.lanes.values() if ln.junction_id is None] \
                if any(c.junction_id is None for c in cws) else []
            for ln in jl + road:
                cl = LineString(ln.centerline)
                for ci in tree.query(cl, predicate="intersects").tolist():
                    if ln.junction_id is None and cws[ci].junction_id is not None:
                        continue
                    inter = cl.intersection(polys[ci])
                    if inter.is_empty:
                        continue
                    ss = [cl.project(Point(p)) for g in getattr(inter, "geoms", [inter]) for p in g.coords]
                    self.crossings.setdefault(ln.id, []).append((cws[ci].id, min(ss), max(ss)))
            for cw, poly in zip(cws, polys):
                rect = poly.minimum_rotated_rectangle
                pts = np.asarray(rect.exterior.coords[:4])
                e = [np.hypot(*(pts[(i + 1) % 4] - pts[i])) for i in range(4)]
                i = int(np.argmin(e[:2]))  # short side i and its opposite i+2
                a = (pts[i] + pts[(i + 1) % 4]) / 2
                b = (pts[(i + 2) % 4] + pts[(i + 3) % 4]) / 2
                self.crosswalk_axes[cw.id] = (flip(a)[0], flip(b)[0], float(e[i]))

    def _build_passages(self, road_lanes: RoadLanes) -> None:
        """`passages`: pairs of road lanes of opposite directions (not linked to each other) whose
        centrelines come closer than PASSAGE_DISTANCE_M plus both cars' `swing` on the bend
        there, found once through an STRtree; lanes linked by such pairs form one passage, its
        two sides coloured by direction. (2.66 m lanes on a 10.7 m bend: the cars' bodies
        overlapped where their paths stayed 2.66 m apart, issue 21.)"""
        roads, lines, tree = road_lanes
        if not lines:
            return
        samples = [np.linspace(0.0, ln.length, max(2, int(math.ceil(ln.length / PASSAGE_STEP_M)) + 1)) for ln in lines]
        swings = [swing(_curvature(ln, s)) for ln, s in zip(lines, samples)]
        most = np.array([float(w.max()) for w in swings])
        left, right = tree.query(lines, predicate="dwithin", distance=PASSAGE_DISTANCE_M + most + most.max())
        span: dict[str, list[float]] = {}
        edges: dict[str, set[str]] = {}
        for i, j in zip(left.tolist(), right.tolist()):
            a, b = roads[i], roads[j]
            if i == j or b.id in {*a.predecessors, *a.successors, *a.left_neighbors, *a.right_neighbors}:
                continue
            la, lb = lines[i], lines[j]
            if la.distance(lb) >= PASSAGE_DISTANCE_M + most[i] + most[j]:
                continue
            s = samples[i]
            pts = shapely.line_interpolate_point(la, s)
            on_b = shapely.line_locate_point(lb, pts)
            room = PASSAGE_DISTANCE_M + swings[i] + np.interp(on_b, samples[j], swings[j])
            near = shapely.distance(pts, lb) < room
            if not near.any():
                continue
            # opposite directions where they are close: the tangents point against each other
            k = int(np.argmax(near))
            if float(np.dot(_tangent(la, s[k]), _tangent(lb, lb.project(pts[k])))) >= 0.0:
                continue
            on_b = on_b[near]
            for lid, lo, hi in ((a.id, s[near].min(), s[near].max()), (b.id, on_b.min(), on_b.max())):
                old = span.get(lid)
                span[lid] = [float(lo), float(hi)] if old is None else [min(old[0], lo), max(old[1], hi)]
            edges.setdefault(a.id, set()).add(b.id)
            edges.setdefault(b.id, set()).add(a.id)
        side: dict[str, tuple[int, int]] = {}
        group = 0
        for start in sorted(span):
            if start in side:
                continue
            side[start] = (group, 0)
            stack = [start]
            while stack:
                x = stack.pop()
                for y in sorted(edges.get(x, ())):
                    if y not in side and y in span:
                        side[y] = (group, 1 - side[x][1])
                        stack.append(y)
            group += 1
        for lid, (g, k) in side.items():
            length = self.lane_of[lid].length
            s0, s1 = span[lid]
            self.passages[lid] = Passage(g, k, float(max(s0 - VEHICLE_LENGTH_M / 2, 0.0)),
                                         float(min(s1 + VEHICLE_LENGTH_M / 2, length)))

    def _build_merges(self, road_lanes: RoadLanes) -> None:
        """`merges`: for each lane of a `converging_pairs` pair, the other lane and the last s on
        this lane where their centrelines are closer than CONFLICT_DISTANCE_M (the end of the
        zip: past it the other lane's users are out of the way)."""
        roads, lines, _ = road_lanes
        line = {ln.id: cl for ln, cl in zip(roads, lines)}
        for a, b in converging_pairs(self.hdmap, road_lanes):
            for x, y in ((a, b), (b, a)):
                lx = line[x]
                s = np.linspace(0.0, lx.length, max(2, int(math.ceil(lx.length / PASSAGE_STEP_M)) + 1))
                close = shapely.distance(shapely.line_interpolate_point(lx, s), line[y]) < CONFLICT_DISTANCE_M
                end = float(s[np.nonzero(close)[0][-1]]) if close.any() else float(lx.length)
                self.merges.setdefault(x, {})[y] = end

    def zip_leader(self, lane_id: str, s_own: float | None, other_lane: str, so: float, pos, other_pos,
                   length: float) -> bool:
        """Whether a road user at `other_pos` on `other_lane`, a lane converging with `lane_id`
        (`merges`), is a leader of a vehicle `length` long at `s_own` on `lane_id` (None: the
        lane is ahead on its route) that sees it at `so` along `lane_id`: until the zip's end
        whatever the lateral offset (lanes 3.5 m apart converge within a few car lengths: a
        vehicle that waited until the other was within its lane's width had no room left to
        fall back), in one order for both (`merge_ahead`)."""
        end = self.merges[lane_id][other_lane]
        if not -length <= so <= end + length:
            return False
        if s_own is None:
            return True
        return s_own <= end and self.merge_ahead(lane_id, pos, other_lane, other_pos)

    # ---- routing ------------------------------------------------------------------------
    def lane_route(self, start: str, goal: str) -> list[str]:
        """Length-weighted Dijkstra over lane successors; [] when `goal` is unreachable (a new
        list each call; kept: `lane_route_within`)."""
        found = self.lane_route_within(start, goal, math.inf)
        return list(found[0]) if found else []

    def lane_route_within(self, start: str, goal: str, limit: float) -> tuple[tuple[str, ...], float] | None:
        """(`lane_route`, the sum of its lanes' lengths in route order, `start` included) where
        that sum is at most `limit`, else None; the search goes no farther than the limit (a lane
        change asks for a route no longer than the one it has: a search over a whole big map per
        candidate each MOBIL period is what this bound saves). Kept per (start, goal), up to
        LANE_ROUTES_KEPT of them: a route found is the shortest whatever the limit; none found
        is searched again under a higher limit."""
        routes = self.memo("lane routes", dict)
        key = (start, goal)
        held = routes.get(key)  # (path, its length, the limit searched under)
        if held is None or (not held[0] and held[2] < limit):
            if len(routes) >= LANE_ROUTES_KEPT:
                routes.clear()
            reach = limit - self.lane_of[start].length + ROUTE_SEARCH_SLACK_M  # (from the start lane's end)
            path = tuple(self._lane_route(start, goal, reach))
            held = routes[key] = (path, sum(self.lane_of[x].length for x in path) if path else math.inf, limit)
        return (held[0], held[1]) if held[0] and held[1] <= limit else None

    def _lane_route(self, start: str, goal: str, reach: float = math.inf) -> list[str]:
        """`lane_route`, searching only lanes that end within `reach` of the start lane's end (the
        same route where it ends within it: lanes farther never lead nearer)."""
        m = self.hdmap
        if start == goal:
            return [start]
        dist = {start: 0.0}
        prev: dict[str, str] = {}
        heap = [(0.0, start)]
        while heap:
            d, lid = heapq.heappop(heap)
            if lid == goal:
                path = [goal]
                while path[-1] != start:
                    path.append(prev[path[-1]])
                return path[::-1]
            if d > dist.get(lid, math.inf):
                continue
            for nxt in m.lanes[lid].successors:
                if nxt not in m.lanes:
                    continue
                nd = d + m.lanes[nxt].length
                if nd <= reach and nd < dist.get(nxt, math.inf):
                    dist[nxt] = nd
                    prev[nxt] = lid
                    heapq.heappush(heap, (nd, nxt))
        return []

    def shortest_path(self, start: str, goal: str) -> list[str]:
        """Node path over the lane graph (Dijkstra, never highway-env's path enumeration)."""
        starts = [lid for lid, idx in self.index_of.items() if idx[0] == start]
        goals = {lid for lid, idx in self.index_of.items() if idx[1] == goal}
        best: list[str] = []
        for s in starts[:4]:
            for g in goals:
                r = self.lane_route(s, g)
                if r and (not best or len(r) < len(best)):
                    best = r
        return [self.index_of[best[0]][0]] + [self.index_of[l][1] for l in best] if best else []


def release_memory() -> None:
    """Hand memory freed after a big build (a map, a network) back to the OS, where the C library
    allows it: the build's temporaries would otherwise stay in every env worker's resident set."""
    gc.collect()
    try:
        ctypes.CDLL("libc.so.6").malloc_trim(0)
    except (OSError, AttributeError):  # not glibc
        pass

