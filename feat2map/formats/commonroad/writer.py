"""Write an HDMap as a CommonRoad scenario (XML, format 2020a) with commonroad-io's own writer.

The lanelet network: one lanelet per lane (left, centre and right vertices taken at one set of
arc-length fractions that keeps every vertex of the lane's lines, and of its adjacent lanes',
which need the same count; junction lanes typed `intersection`), adjacency from the model's
neighbours (opposite lanes as `opposite`) where the two lanes share their border: CommonRoad's
adjacent lanelets have one common border, and its tools build the road from that
(commonroad-drivability-checker's road boundary takes a lane section's outermost borders and
only the end points of the borders inside it). Neighbours whose common border starts and ends
at one point (`lane_ends`) and whose two drawings of it lie within `COMMONROAD_SHARED_BORDER_M`
get one border, their mean (maps read from Apollo draw each lane's borders apart); neighbours
apart (a median between opposite lanes) or starting or ending elsewhere are not adjacent. One
crosswalk lanelet per crosswalk for pedestrians (mid-block ones too). Controls: a stop line on
every lane a signal or stop sign governs (a CommonRoad light governs the end of its lanelet, so
the lights of a mid-block crossing, which stand mid-lane before the junction's own control, are
left out); stop signs as traffic signs (Zamunda/German 206, yield signs 205, the catalogue
CommonRoad's schema holds, in a ZAM scenario: CommonRoad's country code for synthetic maps);
traffic lights with the fixed-time cycle of `feat2map.phases` (the env's default plan at offset
0: paired phases, green/amber/all-red from config). Intersections: per junction, one incoming
per entry road, its junction lanelets split into right, straight and left (U-turns count as
left).

The location is the map's (0, 0) in WGS84, and its geoReference a transverse Mercator whose
false origin makes the file's coordinates the map's local metres. commonroad-io stamps the
file with today's date; the writer sets SOURCE_DATE_EPOCH's date instead, else a fixed one
(the schema requires a date), so the same map gives the same bytes. commonroad-io is imported
from its XML modules only: its protobuf modules need protobuf 3.20, which the Apollo format
cannot use.
"""
from __future__ import annotations

import contextlib
import logging
import math
import tempfile
import warnings
from pathlib import Path
from typing import Iterable, Iterator, Mapping

import numpy as np

from ... import __version__, atomic
from ...angles import turn_name, wrap_angle
from ...commonroad_io import install
from ...config import (COMMONROAD_CONTINUATION_M, COMMONROAD_DATE, COMMONROAD_DT_S, COMMONROAD_HORIZON_S,
                       COMMONROAD_SHARED_BORDER_M, COMMONROAD_VERTEX_STEP_M, STRAIGHT_TOLERANCE_DEG, UTM_ZONE,
                       UTURN_THRESHOLD_DEG)
from ...errors import Feat2MapError
from ...model import HDMap, Lane, Polyline, incoming_lanes, midblock_controls
from ...phases import junction_phases, timeline
from ..base import header_date
from ..geo import local_tmerc, utm_origin, utm_to_latlon
from ..lane_ends import between, lane_ends

COUNTRY = "ZAM"
MAP_NAME = "Feat2map"
_MARKS = {"solid_white": "SOLID", "dotted_white": "DASHED", "solid_yellow": "SOLID", "dotted_yellow": "DASHED",
          "curb": "CURB", "virtual": "NO_MARKING"}
_STATES = {"green": "GREEN", "amber": "YELLOW", "red": "RED"}
_TURNS = {"right": "outgoing_right", "none": "outgoing_straight", "left": "outgoing_left", "uturn": "outgoing_left"}
# heading change [deg, left positive] each CommonRoad turn set allows (U-turns are listed as left);
# the writer lists a junction lanelet by its declared turn only when its geometry agrees
TURN_SETS = {"outgoing_right": lambda d: d < 0, "outgoing_straight": lambda d: abs(d) <= 2 * STRAIGHT_TOLERANCE_DEG,
             "outgoing_left": lambda d: d > 0 or abs(d) > UTURN_THRESHOLD_DEG}


def turn_deg(centre: np.ndarray) -> float:
    """Heading change [deg, left positive] from the first to the last segment of a centreline."""
    c = np.asarray(centre, dtype=float)
    h0 = math.atan2(c[1][1] - c[0][1], c[1][0] - c[0][0])
    h1 = math.atan2(c[-1][1] - c[-2][1], c[-1][0] - c[-2][0])
    return math.degrees(wrap_angle(h1 - h0))


def turn_set(declared: str, centre: np.ndarray) -> str:
    """The CommonRoad turn set of a junction lanelet: its declared turn's when the geometry
    agrees, else the one its heading change gives (maps declare turns their geometry does not
    make, e.g. a "left" lane that runs straight)."""
    key = _TURNS.get(declared, "outgoing_straight")
    d = turn_deg(centre)
    if TURN_SETS[key](d):
        return key
    return _TURNS[turn_name(d)]


def mutual_adjacency(lanes: Mapping[str, Lane]) -> dict[str, dict[str, tuple[str, bool]]]:
    """{lane: {"left"/"right": (other lane, same direction)}} from the model's neighbour lists,
    mutual by construction: a pair is kept only when each side is still free on both lanes
    (same direction: my left is your right; opposite: my left is your left), in map order. Real
    maps list neighbours one-sidedly or several per side; CommonRoad needs each adjacency
    stated back."""
    adj: dict[str, dict[str, tuple[str, bool]]] = {lid: {} for lid in lanes}
    proposals = []
    for lid, ln in lanes.items():
        proposals += [(lid, "left", o, True) for o in ln.left_neighbors]
        proposals += [(lid, "right", o, True) for o in ln.right_neighbors]
        proposals += [(lid, "left", o, False) for o in ln.left_reverse_neighbors]
    for lid, side, other, same in proposals:
        if other == lid or other not in lanes:
            continue
        back = ("right" if side == "left" else "left") if same else side
        if side in adj[lid] or back in adj[other]:
            continue
        adj[lid][side] = (other, same)
        adj[other][back] = (lid, same)
    return adj


def _partner_side(side: str, same: bool) -> str:
    """The side of a neighbour that faces my `side` (same direction: my left is its right;
    opposite: my left is its left)."""
    return ("right" if side == "left" else "left") if same else side


def shared_borders(lanes: Mapping[str, Lane], adj: Mapping[str, Mapping[str, tuple[str, bool]]],
                   ends: Mapping[tuple[str, str, str], tuple[float, float]],
                   tol: float = COMMONROAD_SHARED_BORDER_M) -> dict[str, dict[str, tuple[str, bool]]]:
    """The adjacency of `adj` (`mutual_adjacency`) that CommonRoad can state: pairs whose common
    border starts and ends at one point (`ends`, `lane_ends`) and whose two drawings of it lie
    within `tol` of each other. The others do not share a border (a median between them, or one
    lane starting or ending elsewhere) and are left out, both ways."""
    from shapely.geometry import LineString

    out: dict[str, dict[str, tuple[str, bool]]] = {lid: {} for lid in adj}
    for lid, sides in adj.items():
        for side, (other, same) in sides.items():
            oside = _partner_side(side, same)
            o_at = {"start": "start", "end": "end"} if same else {"start": "end", "end": "start"}
            if any(ends[(lid, side, at)] != ends[(other, oside, o_at[at])] for at in ("start", "end")):
                continue
            mine, theirs = (LineString(np.asarray(lanes[x].left_boundary if k == "left" else lanes[x].right_boundary,
                                                  dtype=float)[:, :2]) for x, k in ((lid, side), (other, oside)))
            if mine.hausdorff_distance(theirs) <= tol:  # GEOS: each line's vertices to the other line
                out[lid][side] = (other, same)
    return out


def commonroad_io():
    """commonroad-io's scenario modules, or a clear error without the package. commonroad-io
    pins protobuf 3.20 (Apollo's maps need a newer one) and feat2map uses only its XML modules:
    scripts/setup.sh installs it --no-deps into <venv>/commonroad-io, outside site-packages, so
    the environment stays consistent (`pip check`); `import feat2map` puts that folder on sys.path
    (feat2map.commonroad_io.install)."""
    install()
    try:
        from commonroad.common.writer import file_writer_xml  # noqa: F401
        import commonroad.scenario.intersection  # noqa: F401
    except ImportError:
        raise Feat2MapError("CommonRoad export needs commonroad-io (pip install --no-deps commonroad-io "
                            "commonroad-vehicle-models iso3166 omegaconf rtree; see scripts/setup.sh)",
                            "commonroad") from None
    import commonroad

    return commonroad


@contextlib.contextmanager
def quiet_commonroad() -> Iterator[None]:
    """commonroad-io logs a format note per intersection incoming; keep the CLI quiet."""
    log = logging.getLogger("commonroad")
    level = log.level
    log.setLevel(logging.ERROR)
    try:
        yield
    finally:
        log.setLevel(level)


def _arc(line: Polyline) -> tuple[np.ndarray, np.ndarray]:
    """A polyline's points (x, y) and their arc length from its start."""
    pts = np.asarray(line, dtype=float)[:, :2]
    return pts, np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])


def resample_at(line: Polyline, fractions: np.ndarray) -> np.ndarray:
    """The points of a polyline at `fractions` (0 to 1) of its arc length, ends exact."""
    pts, s = _arc(line)
    if s[-1] <= 0:
        return np.repeat(pts[:1], len(fractions), axis=0)
    t = np.asarray(fractions, dtype=float) * s[-1]
    out = np.column_stack([np.interp(t, s, pts[:, 0]), np.interp(t, s, pts[:, 1])])
    out[0], out[-1] = pts[0], pts[-1]
    return out


def vertex_fractions(lines: Iterable[Polyline], min_step_m: float = COMMONROAD_VERTEX_STEP_M) -> np.ndarray:
    """Where the vertices of `lines` lie, as fractions (0 to 1) of each one's arc length, merged:
    the lines resampled at these keep every vertex of theirs (a sparse lane's borders at equal
    steps cut its bends: up to 0.7 m off a junction lane's inner border in Apollo's cube_town), but
    for those within `min_step_m` (along the longest line) of one kept before."""
    fr, longest = [np.array([0.0, 1.0])], 0.0
    for line in lines:
        _, s = _arc(line)
        if s[-1] > 0:
            fr.append(s / s[-1])
            longest = max(longest, float(s[-1]))
    merged = np.unique(np.concatenate(fr))
    step = min_step_m / longest if longest > 0 else 1.0
    keep = [0.0]
    for f in merged[1:-1]:
        if f - keep[-1] >= step and 1.0 - f >= step:
            keep.append(float(f))
    return np.array(keep + [1.0])


def lanelet_ids(m: HDMap) -> dict[str, int]:
    """The CommonRoad lanelet id of each lane written (lanes with two-point boundaries): 1, 2, ...
    in map order."""
    lanes = [lid for lid, ln in m.lanes.items() if len(ln.left_boundary) >= 2 and len(ln.right_boundary) >= 2]
    return {lid: i + 1 for i, lid in enumerate(lanes)}


class _Ids:
    """CommonRoad ids: positive integers, one space for every element, given in map order."""

    def __init__(self) -> None:
        self.next = 1
        self.of: dict[tuple[str, str], int] = {}

    def __call__(self, kind: str, key: str) -> int:
        if (kind, key) not in self.of:
            self.of[(kind, key)] = self.next
            self.next += 1
        return self.of[(kind, key)]


def to_scenario(m: HDMap, *, zone: int = UTM_ZONE, origin: tuple[float, float] | None = None):
    """The commonroad-io Scenario of `m` (its lanelet network; no obstacles) and its planning
    problem set."""
    commonroad_io()
    from commonroad.common.common_lanelet import LaneletType, LineMarking, RoadUser, StopLine
    from commonroad.common.common_scenario import GeoTransformation, Location, ScenarioID
    from commonroad.scenario.intersection import IncomingGroup, Intersection
    from commonroad.scenario.lanelet import Lanelet, LaneletNetwork
    from commonroad.scenario.scenario import Scenario
    from commonroad.scenario.traffic_light import (TrafficLight, TrafficLightCycle, TrafficLightCycleElement,
                                                   TrafficLightState)
    from commonroad.scenario.traffic_sign import TrafficSign, TrafficSignElement, TrafficSignIDZamunda

    o = utm_origin(m, zone, origin, "commonroad export")
    lat, lon = utm_to_latlon(zone, [o[0]], [o[1]])
    location = Location(geo_name_id=-999, gps_latitude=float(lat[0]), gps_longitude=float(lon[0]),
                        geo_transformation=GeoTransformation(geo_reference=local_tmerc(zone, o), x_translation=0.0,
                                                             y_translation=0.0, z_rotation=0.0, scaling=1.0))
    net = LaneletNetwork(location=location)
    ids = _Ids()
    for lid in lanelet_ids(m):
        ids("lane", lid)
    lanes = {lid: m.lanes[lid] for lid in lanelet_ids(m)}
    midblock = midblock_controls(m)  # a light stands at its lanelet's end: a mid-block crossing's has no place
    signals = {s.id: [x for x in incoming_lanes(m.lanes, s.lane_ids) if x in lanes] for s in m.signals.values()
               if s.id not in midblock}
    signs = {s.id: [x for x in incoming_lanes(m.lanes, s.lane_ids) if x in lanes] for s in m.stop_signs.values()}
    controls: dict[str, tuple[set[int], set[int]]] = {}  # lane -> (sign ids, light ids) at its end
    for sid, governed in signs.items():
        for lid in governed:
            controls.setdefault(lid, (set(), set()))[0].add(ids("sign", sid))
    for sid, governed in signals.items():
        for lid in governed:
            controls.setdefault(lid, (set(), set()))[1].add(ids("light", sid))
    yields = {s.id: [x for x in incoming_lanes(m.lanes, s.lane_ids) if x in lanes] for s in m.yield_signs.values()}
    for sid, governed in yields.items():  # a yield sign's line: where its lanes end (a filter lane's start)
        for lid in governed:
            controls.setdefault(lid, (set(), set()))[0].add(ids("sign", sid))

    ends = lane_ends(m, lanes)
    adj = shared_borders(lanes, mutual_adjacency(lanes), ends)
    borders = _borders(lanes, adj, ends)
    for lid, ln in lanes.items():
        left, right, centre = (borders[(lid, k)] for k in ("left", "right", "centre"))
        (adj_left, same_left), (adj_right, same_right) = (
            (ids("lane", adj[lid][k][0]), adj[lid][k][1]) if k in adj[lid] else (None, None) for k in ("left", "right"))
        stop = None
        if lid in controls:
            sign_ids, light_ids = controls[lid]
            stop = StopLine(right[-1].copy(), left[-1].copy(), LineMarking.SOLID, sign_ids, light_ids)
        net.add_lanelet(Lanelet(
            left, centre, right, ids("lane", lid),
            predecessor=[ids("lane", x) for x in ln.predecessors if x in lanes],
            successor=[ids("lane", x) for x in ln.successors if x in lanes],
            adjacent_left=adj_left, adjacent_left_same_direction=same_left,
            adjacent_right=adj_right, adjacent_right_same_direction=same_right,
            line_marking_left_vertices=LineMarking[_MARKS.get(ln.left_boundary_type, "UNKNOWN")],
            line_marking_right_vertices=LineMarking[_MARKS.get(ln.right_boundary_type, "UNKNOWN")],
            stop_line=stop, lanelet_type={LaneletType.INTERSECTION if ln.junction_id else LaneletType.URBAN},
            user_one_way={RoadUser.VEHICLE}), rtree=False)
    for cw in m.crosswalks.values():
        sides = cw.sides()
        if sides is not None:
            left, right = (np.asarray(x) for x in sides)
            net.add_lanelet(Lanelet(left, (left + right) / 2, right, ids("crosswalk", cw.id),
                                    lanelet_type={LaneletType.CROSSWALK}, user_bidirectional={RoadUser.PEDESTRIAN}),
                            rtree=False)
    _continuations(m, lanes, adj, ids, net)
    for s in m.stop_signs.values():
        if signs[s.id]:
            sign = TrafficSign(ids("sign", s.id), [TrafficSignElement(TrafficSignIDZamunda.STOP, [])],
                               {ids("lane", x) for x in signs[s.id]}, np.asarray(s.position[:2], dtype=float),
                               virtual=False)
            net.add_traffic_sign(sign, {ids("lane", x) for x in signs[s.id]})
    for y in m.yield_signs.values():  # a filter lane's (or any) yield sign: Zamunda 205 on the lanes it governs
        given_way = {ids("lane", x) for x in yields[y.id]}
        if given_way:
            sign = TrafficSign(ids("sign", y.id), [TrafficSignElement(TrafficSignIDZamunda.YIELD, [])], given_way,
                               np.asarray(y.position[:2], dtype=float), virtual=False)
            net.add_traffic_sign(sign, given_way)
    steps = round(1.0 / COMMONROAD_DT_S)
    for phases in junction_phases(m).values():
        for k, phase in enumerate(phases):
            cycle = [TrafficLightCycleElement(TrafficLightState[_STATES[state]], int(round(d * steps)))
                     for state, d in timeline(k, len(phases))]
            for sid in phase:
                if signals.get(sid):
                    light = TrafficLight(ids("light", sid), np.asarray(m.signals[sid].position[:2], dtype=float),
                                         TrafficLightCycle(cycle, time_offset=0, active=True), active=True)
                    net.add_traffic_light(light, {ids("lane", x) for x in signals[sid]})
    dead_ends = _dead_end_junction_lanes(m, lanes)
    for jid in m.junctions:
        incomings = _incomings(m, jid, lanes, net, ids, dead_ends)
        groups = []
        for road, (feeders, turns) in incomings.items():
            groups.append(IncomingGroup(ids("incoming", f"{jid}/{road}"), {ids("lane", x) for x in feeders},
                                        **{key: {ids("lane", x) for x in lids} for key, lids in turns.items()}))
        if groups:
            net.add_intersection(Intersection(ids("intersection", jid), groups))
    scenario = Scenario(COMMONROAD_DT_S, ScenarioID(country_id=COUNTRY, map_name=MAP_NAME, map_id=1))
    scenario.add_objects(net)
    return scenario, _planning_problems(m, lanes, ids, net)


def _borders(lanes: Mapping[str, Lane], adj, ends) -> dict[tuple[str, str], np.ndarray]:
    """{(lane, "left"/"right"/"centre"): the lanelet's vertices}: each line with its ends where
    linked lanelets meet (`ends`; inner points the moved ends passed dropped, `between`), the
    lines of a group of adjacent lanes taken at the same fractions of their arc length, every
    vertex of theirs among them (`vertex_fractions`), and the border two adjacent lanes share
    written once, the mean of the two drawings (the same vertices on both lanelets, reversed for
    an opposite lane)."""
    lines: dict[tuple[str, str], Polyline] = {}  # each line with its ends where lanelets meet
    for lid, ln in lanes.items():
        for side, line in (("left", ln.left_boundary), ("right", ln.right_boundary)):
            lines[(lid, side)] = _with_ends(line, ends[(lid, side, "start")], ends[(lid, side, "end")])
        mid = {at: (float(ends[(lid, "left", at)][0] + ends[(lid, "right", at)][0]) / 2,
                    float(ends[(lid, "left", at)][1] + ends[(lid, "right", at)][1]) / 2) for at in ("start", "end")}
        lines[(lid, "centre")] = _with_ends(ln.centerline, mid["start"], mid["end"])
    fractions: dict[str, np.ndarray] = {}
    for flip in _adjacency_groups(lanes, adj):
        # an opposite lane runs the other way: its fractions count from the group's other end
        f = vertex_fractions([lines[(x, k)][::-1] if flip[x] else lines[(x, k)] for x in flip
                              for k in ("left", "right", "centre")])
        for x in flip:
            fractions[x] = (1.0 - f[::-1]) if flip[x] else f
    out: dict[tuple[str, str], np.ndarray] = {}
    order = {lid: k for k, lid in enumerate(lanes)}
    for lid in lanes:
        for k in ("left", "right", "centre"):
            out[(lid, k)] = resample_at(lines[(lid, k)], fractions[lid])
    for lid, sides in adj.items():
        for side, (other, same) in sides.items():
            oside = _partner_side(side, same)
            if order[lid] < order[other]:
                theirs = out[(other, oside)] if same else out[(other, oside)][::-1]
                mean = (out[(lid, side)] + theirs) / 2  # exact at the ends: both drawings end there
                out[(lid, side)] = mean
                out[(other, oside)] = mean.copy() if same else mean[::-1].copy()
    return out


def _with_ends(line: Polyline, start: tuple[float, float], end: tuple[float, float]) -> Polyline:
    """`line` from `start` to `end` (its ends where linked lanelets meet), without the inner
    points those moved ends passed (`between`)."""
    return (start, *((float(p[0]), float(p[1])) for p in between(line, start, end)), end)


def _adjacency_groups(lanes: Mapping[str, Lane], adj) -> list[dict[str, bool]]:
    """The lanes joined by adjacency, a group per set, each {lane: whether it runs against the
    group's first lane in map order} (crossing an opposite neighbour flips the direction)."""
    groups: list[dict[str, bool]] = []
    seen: set[str] = set()
    for lid in lanes:
        if lid in seen:
            continue
        flip = {lid: False}
        stack = [lid]
        while stack:
            x = stack.pop()
            for other, same in adj[x].values():
                if other not in flip:
                    flip[other] = flip[x] if same else not flip[x]
                    stack.append(other)
        seen.update(flip)
        groups.append(flip)
    return groups


def _continuations(m: HDMap, lanes, adj, ids: _Ids, net) -> None:
    """A straight lanelet of COMMONROAD_CONTINUATION_M past every map exit and before every map
    entry (no successor / predecessor), linked to it and adjacent like it: a planner's horizon
    (several seconds at speed) then never ends in a dead end at the map's edge. Adjacent
    continuations share their common border: the first written draws it, its neighbour takes it
    (lanes whose end headings differ would else fan apart). Ids follow every other element's."""
    from commonroad.common.common_lanelet import LaneletType, LineMarking, RoadUser
    from commonroad.scenario.lanelet import Lanelet

    ext: dict[tuple[str, str], int] = {}
    for lid, ln in lanes.items():
        if ln.junction_id is None and not any(x in lanes for x in ln.successors):
            ext[(lid, "end")] = ids("continuation", f"{lid}/end")
        if ln.junction_id is None and not any(x in lanes for x in ln.predecessors):
            ext[(lid, "start")] = ids("continuation", f"{lid}/start")
    drawn: dict[int, dict[str, np.ndarray]] = {}
    for (lid, at), cid in ext.items():
        parent = net.find_lanelet_by_id(ids("lane", lid))
        k, k0 = (-1, -2) if at == "end" else (0, 1)
        d = parent.center_vertices[k] - parent.center_vertices[k0]
        d = d / max(float(np.hypot(*d)), 1e-9)  # away from the lanelet, at either end
        steps = np.linspace(0.0, COMMONROAD_CONTINUATION_M, 11)[:, None] * d
        left, right = parent.left_vertices[k] + steps, parent.right_vertices[k] + steps
        if at == "start":  # drawn backwards from the entry: reverse so it drives into it
            left, right = left[::-1], right[::-1]
        sides = {}
        for side, (other, same) in adj[lid].items():  # the continuation beside mine, if any
            o_at = at if same else ("start" if at == "end" else "end")
            if (other, o_at) in ext:
                sides[side] = (ext[(other, o_at)], same)
        border = {"left": left, "right": right}
        for side, (other, same) in sides.items():  # a neighbour drawn already: its border is mine
            if other in drawn:
                theirs = drawn[other][_partner_side(side, same)]
                border[side] = theirs.copy() if same else theirs[::-1].copy()
        left, right = border["left"], border["right"]
        drawn[cid] = border
        lsides = sides.get("left", (None, None))
        rsides = sides.get("right", (None, None))
        net.add_lanelet(Lanelet(
            left, (left + right) / 2, right, cid,
            predecessor=[parent.lanelet_id] if at == "end" else [], successor=[parent.lanelet_id] if at == "start" else [],
            adjacent_left=lsides[0], adjacent_left_same_direction=lsides[1],
            adjacent_right=rsides[0], adjacent_right_same_direction=rsides[1],
            line_marking_left_vertices=LineMarking.UNKNOWN, line_marking_right_vertices=LineMarking.UNKNOWN,
            lanelet_type={LaneletType.URBAN}, user_one_way={RoadUser.VEHICLE}), rtree=False)
        if at == "end":
            parent.successor.append(cid)
        else:
            parent.predecessor.append(cid)


def _planning_problems(m: HDMap, lanes, ids: _Ids, net):
    """One planning problem per junction manoeuvre (junction, entry road, exit road), each with a
    single goal lanelet: from half-way along the lanelet into the junction lane, at rest, to the
    lanelet it leads to. A map without junctions gets one: from the first map entry lane to the
    exit lanes it leads to (or, in a closed network, to the lanes furthest from the first)."""
    from commonroad.planning.planning_problem import PlanningProblemSet

    problems, seen = [], set()
    for jid in m.junctions:
        for ln in m.lanes_by_junction[jid]:
            if ln.id not in lanes:
                continue
            for p in ln.predecessors:
                for s_ in ln.successors:
                    if p not in lanes or s_ not in lanes or m.lanes[p].junction_id or m.lanes[s_].junction_id:
                        continue
                    key = (jid, m.lanes[p].road_id, m.lanes[s_].road_id)
                    if key not in seen:
                        seen.add(key)
                        problems.append(_problem(p, [s_], ids, net, f"{jid}/{p}/{s_}"))
    if problems:
        return PlanningProblemSet(problems)
    return PlanningProblemSet([_whole_map_problem(m, lanes, ids, net)])


def _whole_map_problem(m: HDMap, lanes, ids: _Ids, net):
    """The one planning problem CommonRoad's schema asks for: from the first map entry lane to
    any map exit lane it leads to; in a closed network (no entries or exits), from the first lane
    to the lanes furthest from it (in links)."""
    for ln in m.entry_lanes:
        if ln.id not in lanes:
            continue
        seen, stack, exits = {ln.id}, [ln.id], set()
        while stack:
            cur = m.lanes[stack.pop()]
            if not cur.successors:
                exits.add(cur.id)
            for s in cur.successors:
                if s in lanes and s not in seen:
                    seen.add(s)
                    stack.append(s)
        exits.discard(ln.id)
        if exits:
            return _problem(ln.id, [x for x in lanes if x in exits], ids, net, ln.id)
    first = next(iter(lanes))
    level, seen, furthest = [first], {first}, [first]
    while level:
        furthest = level
        level = list(dict.fromkeys(s for x in level for s in m.lanes[x].successors if s in lanes and s not in seen))
        seen.update(level)
    return _problem(first, furthest, ids, net, first)


def _problem(start_lane: str, goal_lanes: list[str], ids: _Ids, net, key: str):
    """Start half-way along `start_lane` as written, between its lanelet's borders (a sparse real
    lane's centreline vertex at a sharp bend lies outside the lanelet its resampled borders make:
    a start there was on no lanelet), at rest; reach a goal lane within `COMMONROAD_HORIZON_S`."""
    from commonroad.common.util import Interval
    from commonroad.geometry.occupancy.occupancy_group import OccupancyGroup
    from commonroad.planning.goal import GoalRegion
    from commonroad.planning.planning_problem import PlanningProblem
    from commonroad.scenario.state import CustomState, InitialState

    ll = net.find_lanelet_by_id(ids("lane", start_lane))
    mid = (ll.left_vertices + ll.right_vertices) / 2
    k = (len(mid) - 1) // 2  # half-way along, between the borders
    (x0, y0), (x1, y1) = mid[k], mid[k + 1]
    start = InitialState(position=np.array([x0, y0], dtype=float), orientation=math.atan2(y1 - y0, x1 - x0),
                         velocity=0.0, acceleration=0.0, yaw_rate=0.0, slip_angle=0.0, time_step=0)
    horizon = int(round(COMMONROAD_HORIZON_S / COMMONROAD_DT_S))
    goal_ids = [ids("lane", x) for x in goal_lanes]
    area = OccupancyGroup(occupancies=tuple(net.find_lanelet_by_id(x).polygon for x in goal_ids))
    goal = GoalRegion([CustomState(time_step=Interval(0, horizon), position=area)], {0: goal_ids})
    return PlanningProblem(ids("planning", key), start, goal)


def _dead_end_junction_lanes(m: HDMap, lanes) -> set[str]:
    """Junction lanes that lead nowhere (no successor written): no manoeuvre (CommonRoad's
    turn sets list movements through the intersection), so they are left out of the incomings,
    with one warning naming them (Autonomous Stuff's junction 4 has three lanes ending at an arm
    without a road)."""
    out = [x for x, ln in lanes.items() if ln.junction_id is not None and not any(s in lanes for s in ln.successors)]
    if out:
        shown = ", ".join(out[:5]) + (f" and {len(out) - 5} more" if len(out) > 5 else "")
        warnings.warn(f"{m.meta.get('source', 'map')}: {len(out)} junction lane(s) lead nowhere ({shown}): written "
                      "as lanelets, not listed as intersection manoeuvres in the CommonRoad export", stacklevel=3)
    return set(out)


def _incomings(m: HDMap, jid: str, lanes, net, ids: "_Ids",
               dead_ends: set[str]) -> dict[str, tuple[list[str], dict[str, list[str]]]]:
    """Entry road -> (its lanes into junction `jid`, junction lanes from them by CommonRoad turn:
    `turn_set` of the lanelet as a reader sees it, its centre midway between its borders;
    `dead_ends` left out)."""
    out: dict[str, tuple[list[str], dict[str, list[str]]]] = {}
    for road, feeders in m.approaches(jid).items():
        feeders = [x for x in feeders if x in lanes]
        turns: dict[str, list[str]] = {}
        for ln in m.lanes_by_junction[jid]:
            if ln.id in lanes and any(p in feeders for p in ln.predecessors) and ln.id not in dead_ends:
                ll = net.find_lanelet_by_id(ids("lane", ln.id))  # the file holds its borders, not our centre line
                turns.setdefault(turn_set(ln.turn, (ll.left_vertices + ll.right_vertices) / 2), []).append(ln.id)
        if feeders:
            out[road] = (feeders, turns)
    return out


def to_commonroad(m: HDMap, *, zone: int = UTM_ZONE, origin: tuple[float, float] | None = None) -> bytes:
    """The CommonRoad XML of `m`, written by commonroad-io's XMLFileWriter, with a fixed date."""
    scenario, problems = to_scenario(m, zone=zone, origin=origin)
    from commonroad.common.writer.file_writer_interface import OverwriteExistingFile
    from commonroad.common.writer.file_writer_xml import XMLFileWriter
    from lxml import etree

    writer = XMLFileWriter(scenario, problems, author="feat2map", affiliation="feat2map",
                           source=f"feat2map {__version__}", tags=set())
    with tempfile.TemporaryDirectory(prefix="feat2map-cr-") as tmp, quiet_commonroad():
        out = Path(tmp) / "scenario.xml"
        writer.write_to_file(str(out), OverwriteExistingFile.ALWAYS)
        root = etree.parse(str(out)).getroot()
    root.set("date", (header_date() or COMMONROAD_DATE)[:10])
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def write_commonroad(m: HDMap, path: str | Path, *, zone: int = UTM_ZONE,
                     origin: tuple[float, float] | None = None) -> None:
    """Write `m` to `path` (.xml) atomically."""
    atomic.write_bytes(path, to_commonroad(m, zone=zone, origin=origin))


