"""Route construction for the envs: the lane route a vehicle drives and where on it it starts.

A route is a list of lane ids along lane successors. The ego's (and each agent's) comes from the
config: an explicit lane route (`lane_route_from_config`), a route of junction manoeuvres
(`manoeuvres_to_lanes`: the map layer's `feat2map.routes.manoeuvre_lane` per manoeuvre, joined
by Dijkstra), or one sampled (`sample_route` through junctions, `sample_lane_walk` on maps
without them); traffic walks at random (`random_walk`). `start_place` puts a vehicle on its
route: `ego_start_distance` before the first junction, slow enough to stop before the first
stop line.
"""
from __future__ import annotations

import math
from typing import Any, Mapping, Sequence

import numpy as np

from ..errors import Feat2MapError
from ..routes import extend_to_goal, manoeuvre_lane, road_neighbour, trapped_lanes
from .network import MapNetwork
from ..config import ROUTE_SAMPLE_TRIES, SPAWN_BRAKE_MPS2, SPAWN_MARGIN_M, TRAFFIC_END_ROOM_M
from .rules import braking_distance, enters_junction, line_setback



def route_from_config(net: MapNetwork, spec: Any) -> tuple[list[str], bool]:
    """(lane route, whether a manoeuvre route that `start_place` may extend) of an explicit
    route: a lane-level route ({"lanes": ...} or {"from_lane", "to_lane"}) or a sequence of
    (junction, entry road, exit road) manoeuvres."""
    if isinstance(spec, Mapping):
        return lane_route_from_config(net, spec), False
    return manoeuvres_to_lanes(net, spec), True


def sample_config_route(net: MapNetwork, rng: np.random.Generator, config: Mapping[str, Any]) -> tuple[list[str], bool]:
    """(lane route, whether a manoeuvre route) sampled as the config says: through up to
    `route_junctions` junctions, or a lane walk of `route_length` metres where that is 0 or the
    map has no junction."""
    c = config
    if int(c["route_junctions"]) <= 0 or not net.hdmap.junctions:
        return sample_lane_walk(net, rng, float(c["route_length"]), float(c["ego_start_distance"]),
                                float(c["goal_distance"])), False
    for _ in range(ROUTE_SAMPLE_TRIES):
        r = sample_route(net, rng, int(c["route_junctions"]))
        if r:
            return r, True
    raise Feat2MapError("no route through a junction could be sampled", "map")


def ego_route(net: MapNetwork, rng: np.random.Generator, config: Mapping[str, Any]) -> tuple[list[str], bool]:
    """The ego's lane route from the config's `route` (explicit) or sampled, and whether it may
    be extended over neighbouring road lanes (a route of junction manoeuvres, not a lane route
    given or walked lane by lane)."""
    spec = config["route"]
    if isinstance(spec, Mapping) or spec:
        return route_from_config(net, spec)
    return sample_config_route(net, rng, config)


def extend_route(net: MapNetwork, route: list[str], start_distance: float, goal_distance: float,
                 min_room: float = 0.0) -> list[str]:
    """A manoeuvre route extended over road lanes (never into a junction) where its ends are
    short: predecessors before the first lane until `start_distance` fits before the first
    lane's end, successors after the last until the goal `goal_distance` into it fits. Where
    the road before the first junction is shorter than `min_room` (netconvert's 0.2 m approach
    lanes right after another junction: a car started there stands across the stop line), the
    route starts before that other junction instead, through one of its junction lanes (straight
    on where one is, never a U-turn)."""
    m = net.hdmap
    route = list(route)
    room = net.lane_of[route[0]].length
    while room < start_distance:
        prev = road_neighbour(m, route[0], m.lanes[route[0]].predecessors, set(route))
        if prev is None and room < min_room and len(route) > 1:
            through = sorted((j for j in m.lanes[route[0]].predecessors if j in m.lanes and j not in route
                              and m.lanes[j].junction_id is not None and m.lanes[j].turn != "uturn"),
                             key=lambda j: (m.lanes[j].turn != "none", j))  # straight on, never a U-turn
            before = road_neighbour(m, through[0], m.lanes[through[0]].predecessors, set(route)) if through else None
            if before is not None:
                route[:0] = [before, through[0]]
                room = net.lane_of[before].length
                continue
        if prev is None:
            break
        route.insert(0, prev)
        room += net.lane_of[prev].length
    return extend_to_goal(m, route, goal_distance, lambda lid: net.lane_of[lid].length)


def start_place(net: MapNetwork, route: list[str], extend: bool, start_distance: float, goal_distance: float,
                speed: float, length: float) -> tuple[list[str], float, float]:
    """(route, s on its first lane, speed) of a vehicle starting `start_distance` before the end
    of its route's first lane (a manoeuvre route, `extend`: walking back over the road lanes
    before a short first lane, the route extended at both ends), at most at the speed whose
    braking distance fits before the first stop line. The ego's start (MapEnv) and the agents'
    (multi_agent) both come from here."""
    if extend:
        route = extend_route(net, route, start_distance, goal_distance, length / 2)
    s0 = max(0.0, route_start_s(net, route, start_distance) if extend else net.lane_of[route[0]].length - start_distance)
    d_line = first_line_distance(net, route, s0)
    if d_line < braking_distance(speed, length):
        speed = fitting_speed(d_line, length)
    return route, s0, speed


def route_start_s(net: MapNetwork, route: list[str], start_distance: float) -> float:
    """s on the route's first lane of the point `start_distance` before the end of the first
    lane that is not an extension (the approach): with lanes prepended, it walks back over them."""
    m = net.hdmap
    first_junction = next((k for k, l in enumerate(route) if m.lanes[l].junction_id is not None), len(route))
    k = max(first_junction - 1, 0)
    remaining = start_distance
    while k > 0 and remaining > net.lane_of[route[k]].length:
        remaining -= net.lane_of[route[k]].length
        k -= 1
    if k > 0:  # the start falls on a later lane: drop the lanes before it
        del route[:k]
    return net.lane_of[route[0]].length - remaining


def first_line_distance(net: MapNetwork, route: Sequence[str], s0: float) -> float:
    """Distance along `route` from s0 on its first lane to the first junction entry's stop line
    (the entry itself when bare; inf without a junction)."""
    m = net.hdmap
    d = -s0
    for k, lid in enumerate(route):
        if k and enters_junction(m.lanes, route[k - 1], lid):
            return d - line_setback(net, route[k - 1])
        d += net.lane_of[lid].length
    return math.inf


def fitting_speed(distance: float, length: float) -> float:
    """The highest speed whose braking distance fits in `distance` (0 when none does)."""
    room = distance - length / 2 - SPAWN_MARGIN_M
    return math.sqrt(2 * SPAWN_BRAKE_MPS2 * room) if room > 0 else 0.0


def manoeuvres_to_lanes(net: MapNetwork, spec: Sequence[Sequence[str]]) -> list[str]:
    """Explicit route -> lane ids: per (junction, entry road, exit road) a junction lane, joined
    by Dijkstra; starts on the first entry road's lane, ends on the last exit road's lane. The
    junction lane of a manoeuvre is the map layer's (`feat2map.routes.manoeuvre_lane`)."""
    m = net.hdmap
    picks = []
    for i, item in enumerate(spec):
        jid, entry, exit_ = (str(x) for x in item)
        pick = manoeuvre_lane(m, (jid, entry, exit_))
        if pick is None:
            raise Feat2MapError(f"no lane of junction {jid} leads from road {entry} to road {exit_}", f"route[{i}]")
        picks.append(pick)
    lanes = [next(p for p in picks[0].predecessors if m.lanes[p].road_id == str(spec[0][1])), picks[0].id]
    for i, ln in enumerate(picks[1:], 1):
        best: list[str] = []
        for pred in ln.predecessors:
            path = net.lane_route(lanes[-1], pred)
            if path and (not best or len(path) < len(best)):
                best = path
        if not best:
            raise Feat2MapError(f"junction {ln.junction_id} is not reachable from the previous manoeuvre", f"route[{i}]")
        lanes += best[1:] + [ln.id]
    lanes.append(next(s for s in picks[-1].successors if m.lanes[s].road_id == str(spec[-1][2])))
    return lanes


def lane_route_from_config(net: MapNetwork, spec: Mapping[str, Any]) -> list[str]:
    """Explicit lane-level route: {"lanes": [ids]} (each lane a successor of the one before), or
    {"from_lane": a, "to_lane": b} (shortest by Dijkstra; a == b goes once round a loop, e.g. a
    lap of a ring road). Errors name the config element."""
    m = net.hdmap
    keys = set(spec)
    if keys == {"lanes"}:
        raw = spec["lanes"]
        if isinstance(raw, (str, bytes)) or not isinstance(raw, Sequence) or len(raw) < 2:
            raise Feat2MapError("needs a list of at least 2 lane ids (the ego starts on the first and "
                                "finishes in the last)", "route.lanes")
        lanes = [str(x) for x in raw]
        for i, lid in enumerate(lanes):
            if lid not in m.lanes:
                raise Feat2MapError(f"unknown lane {lid!r}", f"route.lanes[{i}]")
            if i and lid not in m.lanes[lanes[i - 1]].successors:
                succ = ", ".join(m.lanes[lanes[i - 1]].successors) or "none"
                raise Feat2MapError(f"lane {lid} does not follow lane {lanes[i - 1]} (its successors: {succ})",
                                    f"route.lanes[{i}]")
        return lanes
    if keys == {"from_lane", "to_lane"}:
        a, b = str(spec["from_lane"]), str(spec["to_lane"])
        for key, lid in (("from_lane", a), ("to_lane", b)):
            if lid not in m.lanes:
                raise Feat2MapError(f"unknown lane {lid!r}", f"route.{key}")
        if a != b:
            path = net.lane_route(a, b)
        else:  # round a loop back to the start lane: the shortest cycle through it
            loops = [[a] + p for p in (net.lane_route(s, a) for s in m.lanes[a].successors if s in m.lanes) if p]
            path = min(loops, key=lambda p: sum(net.lane_of[x].length for x in p), default=[])
        if not path:
            raise Feat2MapError(f"lane {b} cannot be reached from lane {a} along lane successors", "route.to_lane")
        return path
    raise Feat2MapError(f"expected {{'lanes': [...]}} or {{'from_lane': ..., 'to_lane': ...}}, got keys "
                        f"{sorted(map(str, keys))}", "route")


def sample_lane_walk(net: MapNetwork, rng: np.random.Generator, length: float, start_distance: float = math.inf,
                     goal_distance: float = 0.0, tries: int = 100, max_lanes: int = 10_000) -> list[str]:
    """A random walk along lane successors from a road lane, long enough that an ego starting
    `start_distance` before the end of its first lane and finishing `goal_distance` into its
    last (as MapEnv places them) drives >= `length` metres; a closed ring simply loops. Maps
    without junctions are driven on such routes. When no walk is that long (dead ends), the
    longest walk found."""
    m = net.hdmap
    starts = sorted(ln.id for ln in m.lanes.values()
                    if ln.junction_id is None and any(s in m.lanes for s in ln.successors))
    if not starts:
        raise Feat2MapError("no road lane with a successor to start a route on", "map")
    best: list[str] = []
    best_len = -math.inf
    for _ in range(tries):
        path = [starts[int(rng.integers(len(starts)))]]
        ahead = min(start_distance, net.lane_of[path[0]].length)  # ego start -> end of the last lane but one
        while len(path) < max_lanes:
            succ = [s for s in m.lanes[path[-1]].successors if s in m.lanes]
            if not succ:
                break
            path.append(succ[int(rng.integers(len(succ)))])
            last = net.lane_of[path[-1]].length
            driven = ahead + min(goal_distance, last - 1.0)
            if driven >= length:
                return path
            if driven > best_len:
                best, best_len = list(path), driven
            ahead += last
    return best


def traffic_traps(net: MapNetwork) -> frozenset[str]:
    """The lanes traffic is never routed onto or spawned on (`feat2map.routes.trapped_lanes`:
    no way on from them but an undrivable junction lane), once per network."""
    return net.memo("trapped lanes", lambda: trapped_lanes(net.hdmap))


def random_walk(net: MapNetwork, rng: np.random.Generator, start: str, junctions: int) -> list[str]:
    """A route from `start` through up to `junctions` junctions, choosing successors at random;
    through one more where the road after the last is shorter than TRAFFIC_END_ROOM_M (a route
    that ended on Town07's 0.7 m road between two junctions left its car driving on past its
    end, blind to the vehicles in the next junction: it rear-ended the ego there)."""
    m = net.hdmap
    trapped = traffic_traps(net)
    path = [start]
    count = 0
    room = 0.0  # road after the last junction lane of the path
    while True:
        succ = [s for s in m.lanes[path[-1]].successors if s in m.lanes and s not in trapped]  # never into a dead end
        if not succ or len(path) > 200:
            break
        nxt = succ[int(rng.integers(len(succ)))]
        entering = enters_junction(m.lanes, path[-1], nxt)
        if entering:
            if count >= junctions and room >= TRAFFIC_END_ROOM_M:
                break
            count += 1
        path.append(nxt)
        room = 0.0 if m.lanes[nxt].junction_id is not None else room + net.lane_of[nxt].length
    return path


def sample_route(net: MapNetwork, rng: np.random.Generator, junctions: int) -> list[str]:
    """A random route that starts on a lane entering a junction and crosses >= 1 junction."""
    m = net.hdmap
    starts = net.memo("route starts", lambda: [
        ln.id for ln in m.lanes.values() if ln.junction_id is None
        and any(m.lanes[s].junction_id is not None for s in ln.successors if s in m.lanes)])
    if not starts:
        return []
    start = starts[int(rng.integers(len(starts)))]
    path = random_walk(net, rng, start, max(1, junctions))
    if m.lanes[path[-1]].junction_id is not None or not any(m.lanes[l].junction_id for l in path):
        return []
    return path
