"""The map layer's manoeuvres and routes: which lane drives a (junction, entry road, exit road)
manoeuvre (one rule shared by the env's routes, the scenario tools and the OpenSCENARIO export),
every manoeuvre a map allows, and few routes that together cover them (used by the route-coverage
suites and the multi-agent env, so neither layer imports the other)."""
from __future__ import annotations

import math
from typing import Any, Callable, Iterable, Mapping, Sequence, TypeGuard, Union, cast

from .config import (DRIVE_DEFAULTS, KINK_RADIUS_M, MAX_TURN_DEG, MIN_UTURN_RADIUS_M, RAMP_MANOEUVRES, TURN_WINDOW_M,
                     TURNAROUND_DEG, TURNAROUND_RADIUS_M, TIGHT_BEND_RADIUS_M, VEHICLE_LENGTH_M)
from .extract_ramps import ExtractedRamp, extract_ramps
from .model import HDMap, Lane, interior_lane

Manoeuvre = tuple[str, str, str]  # (junction id, entry road id, exit road id)
Route = tuple[Manoeuvre, ...]  # manoeuvres in driving order (Scenario.route, the env's `route`)
# the env's lane-level route, {"lanes": [ids]} or {"from_lane": a, "to_lane": b}: a suite drives a ramp
# joined through a direct link (no junction, so no manoeuvre) on one (`ramp_routes`)
LaneRoute = Mapping[str, Any]
AnyRoute = Union[Route, LaneRoute]

DEFAULT_ROUTE_JUNCTIONS = 4  # longest route coverage_routes builds (junctions)
END_ROOM_M = 25.0  # a route ends on an exit road at least this long before the next junction where it can:
# the env's goal lies 15 m into it, and an ego at speed reaching a goal closer to a junction runs into it


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


def manoeuvres(m: HDMap) -> list[Manoeuvre]:
    """Every (junction id, entry road id, exit road id) some junction lane of `m` drives, in
    junction order, then entry and exit road order."""
    out: dict[Manoeuvre, None] = {}
    for jid in m.junctions:
        found = set()
        for ln in m.lanes_by_junction.get(jid, []):
            found.update(_lane_manoeuvres(m, ln))
        for mv in sorted(found):
            out[mv] = None
    return list(out)

def tight_uturn(ln: Lane, radius: float = MIN_UTURN_RADIUS_M) -> bool:
    """A U-turn lane tighter than a car turns: the circle through its centreline's first, middle
    and last points has a radius under `radius` (Apollo's topo_creator rule for U-turn lanes), or
    it kinks somewhere (`sharpest_radius` under KINK_RADIUS_M: U-turns a reader joined from
    pieces through a junction's interior, with right-angle kinks between them). SUMO's
    turnaround connections (radius ~1 m) are such lanes; no car drives them."""
    if ln.turn != "uturn":
        return False
    if len(ln.centerline) < 3 or sharpest_radius(ln) < KINK_RADIUS_M:
        return True
    return end_circle_radius(ln.centerline) < radius


def end_circle_radius(points: Sequence[Sequence[float]]) -> float:
    """Radius of the circle through a polyline's first, middle and last points (inf when they
    are collinear, 0 without points): how tightly a U-turn turns, as Apollo's topo_creator
    measures it."""
    if not len(points):
        return 0.0
    (x1, y1), (x2, y2), (x3, y3) = (tuple(points[i][:2]) for i in (0, len(points) // 2, -1))
    d = 2 * (x1 * (y2 - y3) + x2 * (y3 - y1) + x3 * (y1 - y2))
    if abs(d) < 1e-10:  # collinear: a wide U-turn
        return math.inf
    ux = ((x1**2 + y1**2) * (y2 - y3) + (x2**2 + y2**2) * (y3 - y1) + (x3**2 + y3**2) * (y1 - y2)) / d
    uy = ((x1**2 + y1**2) * (x3 - x2) + (x2**2 + y2**2) * (x1 - x3) + (x3**2 + y3**2) * (x2 - x1)) / d
    return math.hypot(x1 - ux, y1 - uy)


def sharpest_radius(ln: Lane, window: float = TURN_WINDOW_M) -> float:
    """The smallest radius [m] a car following the lane's centreline turns on: the heading change
    from each segment to the first one at least `window` metres further on (midpoint to
    midpoint: a kink counts over the stretch around it, a coarse polyline over its segments),
    as distance / change; inf for a straight lane."""
    _, radius = turn_radii(ln.centerline, window)
    return float(radius.min()) if len(radius) else math.inf


def turn_radii(points, window: float = TURN_WINDOW_M):
    """(arc length where each stretch of `sharpest_radius` begins, its radius [m]) along a
    polyline: empty arrays for fewer than two segments."""
    import numpy as np

    pts = np.asarray(points, dtype=float)[:, :2]
    seg = np.hypot(*np.diff(pts, axis=0).T)
    keep = seg > 1e-6
    if keep.sum() < 2:
        return np.zeros(0), np.zeros(0)
    d = np.diff(pts, axis=0)[keep]
    s = np.concatenate([[0.0], np.cumsum(seg[keep])])
    heading = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))  # heading of segment k, from s[k] to s[k + 1]
    mid = (s[:-1] + s[1:]) / 2
    k = np.arange(len(mid) - 1)
    j = np.maximum(np.searchsorted(mid, mid[:-1] + window, side="left"), k + 1).clip(max=len(mid) - 1)
    change = np.abs(heading[j] - heading[k])
    return s[:-1][k], (mid[j] - mid[k]) / np.maximum(change, 1e-12)


def first_tight_bend(points, radius: float = TIGHT_BEND_RADIUS_M) -> float:
    """Arc length [m] along a polyline where its first bend tighter than `radius` (a car's
    turning radius) begins; inf where it has none. No car follows the line past it."""
    at, radii = turn_radii(points)
    tight = radii < radius
    return float(at[tight][0]) if tight.any() else math.inf


def loops(ln: Lane, limit: float = MAX_TURN_DEG) -> bool:
    """A lane whose heading turns further than `limit` degrees from start to end (unwrapped: a
    U-turn turns 180): netconvert's internal lanes, joined by the reader into one junction lane,
    can run round a junction's interior more than once (up to 700 deg)."""
    import numpy as np

    pts = np.asarray(ln.centerline, dtype=float)[:, :2]
    d = np.diff(pts, axis=0)
    d = d[np.hypot(*d.T) > 1e-6]
    if len(d) < 2:
        return False
    h = np.unwrap(np.arctan2(d[:, 1], d[:, 0]))
    return bool(abs(math.degrees(h[-1] - h[0])) > limit)


def tight_turnaround(ln: Lane, radius: float = TURNAROUND_RADIUS_M) -> bool:
    """A junction lane that turns round (at least TURNAROUND_DEG from its start heading to its
    end heading, short of a U-turn's UTURN_THRESHOLD_DEG, so classed left or right) on a mean
    radius (length / turn) under `radius`: where osm2xodr ends a dual carriageway it joins the
    two one-way roads with a 7 m junction lane turning 154 degrees (radius 2.7 m); a car that
    took it left the road."""
    turn = abs(math.remainder(ln.heading_at_end() - ln.heading_at_start(), math.tau))
    return turn >= math.radians(TURNAROUND_DEG) and ln.length / turn < radius


def undrivable(ln: Lane) -> bool:
    """A junction lane no car drives: a `tight_uturn`, a `tight_turnaround` or a lane that
    `loops`."""
    return tight_uturn(ln) or tight_turnaround(ln) or loops(ln)


def trapped_lanes(m: HDMap) -> frozenset[str]:
    """Lanes a car cannot leave: every way on from them ends before a junction lane that is
    `undrivable` (a stub into a one-arm junction whose only way on is a tight turnaround: traffic
    routed in stood there for good). A lane without successors is the map's edge, where a car
    leaves, and a lane on a loop always has a way on: neither is trapped."""
    def blocked(x: str) -> bool:
        ln = m.lanes[x]
        return ln.junction_id is not None and undrivable(ln)
    onward = {lid: set(x for x in ln.successors if x in m.lanes) for lid, ln in m.lanes.items()}
    back: dict[str, list[str]] = {}
    for lid, nxt in onward.items():
        for x in nxt:
            back.setdefault(x, []).append(lid)
    open_ways = {lid: len(nxt) for lid, nxt in onward.items()}
    todo = [lid for lid in m.lanes if blocked(lid)]
    trapped = set(todo)
    while todo:  # backward: a lane is trapped once every way on from it is
        for p in back.get(todo.pop(), ()):
            open_ways[p] -= 1
            if open_ways[p] == 0 and p not in trapped:
                trapped.add(p)
                todo.append(p)
    return frozenset(trapped)


def approach_room(m: HDMap, mv: Sequence[str], enough: float = VEHICLE_LENGTH_M / 2) -> float:
    """Metres of road a car can stand on before manoeuvre `mv`'s junction: the longest chain of
    road lanes walking back from the approach lanes of its junction lane (inf where a junction
    lane leads into that chain: a route can start before that junction instead,
    `envs.routes.extend_route`). Stops counting at `enough`."""
    ln = manoeuvre_lane(m, mv)
    if ln is None:
        return 0.0
    best = 0.0
    stack: list[tuple[str, float, frozenset[str]]] = [(p, 0.0, frozenset()) for p in ln.predecessors
                                                      if p in m.lanes and m.lanes[p].road_id == mv[1]]
    while stack and best < enough:
        lid, done, seen = stack.pop()
        lane = m.lanes[lid]
        if lane.junction_id is not None:
            return math.inf
        done += lane.length
        best = max(best, done)
        stack += [(p, done, seen | {lid}) for p in lane.predecessors if p in m.lanes and p not in seen]
    return best


def edge_stub(m: HDMap, mv: Sequence[str]) -> bool:
    """A manoeuvre from an approach at the map's edge too short to hold a car before its junction
    (`approach_room` under half a car: osm2xodr's 1.1 m `w850595601_0_0_1` in Testfeld, a signal
    line at its end and nothing before it). A car can only start there with its body in the
    junction, inside the paths of the cars turning through it, and no road leads there: no car
    drives it."""
    return approach_room(m, mv) < VEHICLE_LENGTH_M / 2


def suite_manoeuvres(m: HDMap) -> list[Manoeuvre]:
    """The manoeuvres a route-coverage suite drives: `manoeuvres` without those whose junction
    lane is `undrivable` (left out: no car turns that tightly or loops) and the `edge_stub`s (no
    car stands before their junction); `build_suite` says how many."""
    return [mv for mv in manoeuvres(m) if (ln := manoeuvre_lane(m, mv)) is not None and not undrivable(ln)
            and not edge_stub(m, mv)]


def _lane_manoeuvres(m: HDMap, ln: Lane) -> set[Manoeuvre]:
    """The (junction, entry road, exit road) a junction lane drives: from a road lane to a road
    lane, neither of them a piece of a junction (`interior_lane`: no route starts or ends inside
    one)."""
    def roads(ids: Sequence[str]) -> set[str]:
        return {m.lanes[x].road_id for x in ids if x in m.lanes and m.lanes[x].junction_id is None
                and not interior_lane(m.lanes, m.lanes[x])}
    return {(str(ln.junction_id), e, x) for e in roads(ln.predecessors) for x in roads(ln.successors)}

def successor_graph(m: HDMap, moves: Sequence[Manoeuvre] | None = None) -> dict[Manoeuvre, list[Manoeuvre]]:
    """Manoeuvre -> manoeuvres that can follow it directly: from the env's lane for the first,
    road lanes only (successor links, no junction lane) lead to a predecessor of the env's lane
    for the second."""
    moves = list(moves if moves is not None else manoeuvres(m))
    picks = {mv: manoeuvre_lane(m, mv) for mv in moves}
    by_pred: dict[str, list[Manoeuvre]] = {}
    for mv, ln in picks.items():
        if ln is None:
            continue
        for p in ln.predecessors:
            if p in m.lanes and m.lanes[p].road_id == mv[1]:
                by_pred.setdefault(p, []).append(mv)
    graph: dict[Manoeuvre, list[Manoeuvre]] = {}
    for mv, ln in picks.items():
        nxt: dict[Manoeuvre, None] = {}
        if ln is not None:
            stack = [s for s in ln.successors if s in m.lanes and m.lanes[s].junction_id is None]
            seen = set(stack)
            while stack:
                lid = stack.pop()
                for follower in by_pred.get(lid, ()):
                    if follower[0] != mv[0]:
                        nxt[follower] = None
                for s in m.lanes[lid].successors:
                    if s in m.lanes and m.lanes[s].junction_id is None and s not in seen:
                        seen.add(s)
                        stack.append(s)
        graph[mv] = sorted(nxt)
    return graph

def coverage_routes(m: HDMap, max_junctions: int = DEFAULT_ROUTE_JUNCTIONS,
                    moves: Iterable[Manoeuvre] | None = None) -> list[Route]:
    """Few routes that together cover every manoeuvre of `m` (or of `moves`) at least once.

    How: greedy set cover over the manoeuvre graph (`successor_graph`, built from the lane
    graph). While a manoeuvre is uncovered, take the first uncovered one (map order) as the
    anchor, search exhaustively backwards and forwards from it for the chains of at most
    `max_junctions` manoeuvres in total (never visiting a junction twice) that add the most
    uncovered manoeuvres (ties: an end with END_ROOM_M of road before the next junction, fewer
    junctions, then map order), and add that route. Each
    route is the locally best extension of its anchor, so the result is a small cover but not
    a minimum one (set cover is NP-hard). Manoeuvres the env cannot drive are skipped, and so
    are those no car drives (`suite_manoeuvres`), as targets and as links of a route. Covering
    every manoeuvre (`moves` None) with routes of 2 junctions or more, a road lane across a
    mid-block crosswalk that no route drives from junction to junction gets a route of its own
    (`_midblock_routes`).
    """
    if max_junctions < 1:
        raise ValueError("max_junctions must be at least 1")
    all_moves = suite_manoeuvres(m)
    targets = [mv for mv in (list(moves) if moves is not None else all_moves) if manoeuvre_lane(m, mv) is not None]
    graph = successor_graph(m, all_moves)
    preds: dict[Manoeuvre, list[Manoeuvre]] = {mv: [] for mv in graph}
    for mv, nxts in graph.items():
        for n in nxts:
            preds[n].append(mv)
    order = {mv: i for i, mv in enumerate(all_moves)}
    room = {mv: _exit_room(m, mv) for mv in graph}
    uncovered = set(targets)
    routes: list[Route] = []
    for anchor in targets:
        if anchor not in uncovered:
            continue
        best: tuple = ()
        best_key = None
        for back in _chains(preds, anchor, max_junctions - 1, {anchor[0]}):
            used = {anchor[0], *(mv[0] for mv in back)}
            for fwd in _chains(graph, anchor, max_junctions - 1 - len(back), used):
                route = tuple(reversed(back)) + (anchor,) + fwd
                gain = len(set(route) & uncovered)
                key = (-gain, room[route[-1]] < END_ROOM_M, len(route), [order[mv] for mv in route])
                if best_key is None or key < best_key:
                    best, best_key = route, key
        routes.append(best)
        uncovered -= set(best)
    if moves is None and max_junctions >= 2:
        routes += _midblock_routes(m, graph, routes, order)
    return routes


def midblock_lanes(m: HDMap) -> list[tuple[str, str]]:
    """(crosswalk, road lane) for every road lane that crosses a crosswalk outside junctions (a
    mid-block crossing), in map order."""
    from shapely import STRtree
    from shapely.geometry import LineString, Polygon

    walks = [c for c in m.crosswalks.values() if c.junction_id is None and len(c.polygon) >= 3]
    if not walks:
        return []
    road = [ln for ln in m.lanes.values() if ln.junction_id is None and len(ln.centerline) >= 2]
    tree = STRtree([LineString(ln.centerline) for ln in road])
    return [(c.id, road[k].id) for c in walks
            for k in sorted(tree.query(Polygon(c.polygon), predicate="intersects").tolist())]


def road_lanes_between(m: HDMap, a: Manoeuvre, b: Manoeuvre) -> set[str]:
    """The road lanes a route drives from manoeuvre `a`'s junction lane to manoeuvre `b`'s."""
    def reach(starts: Iterable[str], forward: bool) -> set[str]:
        out: set[str] = set()
        stack = [x for x in starts if x in m.lanes and m.lanes[x].junction_id is None]
        while stack:
            lid = stack.pop()
            if lid in out:
                continue
            out.add(lid)
            nxt = m.lanes[lid].successors if forward else m.lanes[lid].predecessors
            stack += [x for x in nxt if x in m.lanes and m.lanes[x].junction_id is None]
        return out

    la, lb = manoeuvre_lane(m, a), manoeuvre_lane(m, b)
    if la is None or lb is None:
        return set()
    return reach(la.successors, True) & reach(lb.predecessors, False)


def _midblock_routes(m: HDMap, graph: dict[Manoeuvre, list[Manoeuvre]], routes: Sequence[Route],
                     order: dict[Manoeuvre, int]) -> list[Route]:
    """Two-manoeuvre routes, one per road lane across a mid-block crosswalk that no route of
    `routes` drives from junction to junction (a route that starts on that lane begins near its
    end, past the crossing): the first pair of consecutive manoeuvres, in map order, whose road
    between them holds the lane."""
    wanted = [lid for _, lid in midblock_lanes(m)]
    if not wanted:
        return []
    driven = {x for r in routes for a, b in zip(r, r[1:]) for x in road_lanes_between(m, a, b)}
    pairs = sorted(((a, b) for a, nxt in graph.items() for b in nxt), key=lambda p: (order[p[0]], order[p[1]]))
    out: list[Route] = []
    for lid in wanted:
        if lid in driven:
            continue
        for a, b in pairs:
            between = road_lanes_between(m, a, b)
            if lid in between:
                out.append((a, b))
                driven |= between
                break
    return out

def _exit_room(m: HDMap, mv: Manoeuvre) -> float:
    """Metres of road after the manoeuvre's junction lane before the next junction (inf where the
    road leaves the map): the longest chain of road lanes from the lane it leads into."""
    ln = manoeuvre_lane(m, mv)
    best = 0.0
    firsts = ln.successors if ln is not None else ()
    stack: list[tuple[str, float, frozenset[str]]] = [(s, 0.0, frozenset()) for s in firsts if s in m.lanes]
    while stack:
        lid, done, seen = stack.pop()
        lane = m.lanes[lid]
        if lane.junction_id is not None or lid in seen:
            best = max(best, done)
            continue
        nxt = [x for x in lane.successors if x in m.lanes]
        if not nxt:
            return math.inf
        stack += [(x, done + lane.length, seen | {lid}) for x in nxt]
    return best

def _chains(graph: dict[Manoeuvre, list[Manoeuvre]], start: Manoeuvre, depth: int,
            used: set[str]) -> list[tuple[Manoeuvre, ...]]:
    """Every chain of up to `depth` manoeuvres following `start` in `graph` (start excluded),
    through junctions not in `used`; the empty chain first."""
    out: list[tuple[Manoeuvre, ...]] = [()]
    if depth <= 0:
        return out
    for nxt in graph.get(start, ()):
        if nxt[0] in used:
            continue
        for tail in _chains(graph, nxt, depth - 1, used | {nxt[0]}):
            out.append((nxt,) + tail)
    return out


def is_lane_route(route: Any) -> TypeGuard[LaneRoute]:
    """A lane-level route ({"lanes": ...} or {"from_lane", "to_lane"}), not a route of manoeuvres."""
    return isinstance(route, Mapping)


def lane_route_ids(route: LaneRoute) -> list[str]:
    """The lane ids a lane-level route names: its lanes, or its first and last lane."""
    return [str(x) for x in route["lanes"]] if "lanes" in route else [str(route["from_lane"]), str(route["to_lane"])]


def road_neighbour(m: HDMap, lane_id: str, candidates: Sequence[str], exclude: set[str]) -> str | None:
    """The road lane (not in a junction, not in `exclude`) among `candidates` to extend a route
    with: one of the same road first, then the longest, ties by id."""
    road = m.lanes[lane_id].road_id
    cands = [c for c in candidates if c in m.lanes and m.lanes[c].junction_id is None and c not in exclude]
    if not cands:
        return None
    return min(cands, key=lambda c: (m.lanes[c].road_id != road, -m.lanes[c].length, c))


def extend_to_goal(m: HDMap, path: list[str], goal: float, length: Callable[[str], float]) -> list[str]:
    """`path` with road lanes appended (`road_neighbour`) until its goal, `goal` metres into the
    last lane, fits in it (`length`: a lane's length as the caller measures it)."""
    while length(path[-1]) < goal + 1.0:
        nxt = road_neighbour(m, path[-1], m.lanes[path[-1]].successors, set(path))
        if nxt is None:
            break
        path.append(nxt)
    return path


def ramp_manoeuvre(ramp: ExtractedRamp) -> Manoeuvre | None:
    """The (junction, entry road, exit road) manoeuvre that takes `ramp`: from the ramp's road
    onto the road it joins (an on-ramp), from the road onto the ramp (an off-ramp); None for a
    ramp joined through a direct link, which no junction holds."""
    if ramp.junction is None:
        return None
    return (ramp.junction, ramp.ramp_road, ramp.road) if ramp.kind == "on" else (ramp.junction, ramp.road, ramp.ramp_road)


def ramp_lanes(m: HDMap, ramp: ExtractedRamp) -> list[str]:
    """The lanes a suite drives across a ramp's mouth: its first link (`ExtractedRamp.links`),
    with road lanes before it until the env's start (`ego_start_distance` before the end of
    the first lane) lies before the mouth, and after it until its goal (`goal_distance` in) fits
    in the last lane. [] for a ramp without links."""
    if not ramp.links:
        return []
    path = list(ramp.links[0])
    start, goal = float(DRIVE_DEFAULTS["ego_start_distance"]), float(DRIVE_DEFAULTS["goal_distance"])
    while m.lanes[path[0]].length < start:
        prev = road_neighbour(m, path[0], m.lanes[path[0]].predecessors, set(path))
        if prev is None:
            break
        path.insert(0, prev)
    return extend_to_goal(m, path, goal, lambda lid: m.lanes[lid].length)


def ramp_routes(m: HDMap, ramps: Sequence[ExtractedRamp] | None = None) -> list[tuple[str, LaneRoute]]:
    """(manoeuvre kind, lane route) for every ramp of `m` (`extract_ramps`, or `ramps`) joined
    through a direct link: its merge ("merge": from the on-ramp onto the road it joins) or
    diverge ("diverge": from the road onto the off-ramp), RAMP_MANOEUVRES. Ramps inside a
    junction are manoeuvres of it (`ramp_manoeuvre`) that `coverage_routes` already drives."""
    out: list[tuple[str, LaneRoute]] = []
    for r in extract_ramps(m) if ramps is None else ramps:
        lanes = ramp_lanes(m, r) if r.junction is None else []
        if len(lanes) >= 2:
            out.append((RAMP_MANOEUVRES[r.kind], {"lanes": lanes}))
    return out


def route_ramps(m: HDMap, route: AnyRoute, ramps: Sequence[ExtractedRamp] | None = None) -> list[str]:
    """The ramp manoeuvres (RAMP_MANOEUVRES: "merge", "diverge") a route drives, in driving
    order: its manoeuvres that take a ramp in a junction, or the links across a ramp's mouth
    its lanes follow."""
    ramps = extract_ramps(m) if ramps is None else ramps
    if is_lane_route(route):
        return _lane_route_ramps(lane_route_ids(route), ramps)
    kinds = {ramp_manoeuvre(r): RAMP_MANOEUVRES[r.kind] for r in ramps}
    return [kinds[mv] for mv in (cast(Manoeuvre, tuple(str(x) for x in item)) for item in route) if mv in kinds]


def _lane_route_ramps(lanes: Sequence[str], ramps: Sequence[ExtractedRamp]) -> list[str]:
    """`route_ramps` of a lane route: the ramps one of whose links its lanes follow, in order."""
    found: list[tuple[int, str]] = []
    for r in ramps:
        for link in r.links:
            at = next((i for i in range(len(lanes) - len(link) + 1) if tuple(lanes[i:i + len(link)]) == link), None)
            if at is not None:
                found.append((at, RAMP_MANOEUVRES[r.kind]))
                break
    return [kind for _, kind in sorted(found)]
