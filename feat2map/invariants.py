"""Geometric and topological invariants every generated map must satisfy.

Each check returns a list of problems (strings naming the element); empty means it holds.
Used by the tests and available to users as a sanity check of their own maps.
"""
from __future__ import annotations

import math
from collections import deque
from typing import Callable, Iterable, Iterator, Sequence

from shapely import STRtree
from shapely.geometry import Polygon
from shapely.ops import unary_union

from .angles import wrap_degrees
from .config import ENDPOINT_TOLERANCE_M
from .features import JunctionFeature
from .model import HDMap

AREA_EPS_M2 = 0.05
RAMP_LENGTH_TOL_M = 0.05  # a ramp junction's measured ramp_length (between its main mouths) may be this far off


def _road_polygons(m: HDMap) -> dict[str, Polygon]:
    out = {}
    for r in m.roads.values():
        if r.kind == "junction":
            continue
        parts = [Polygon(ln.left_boundary + tuple(reversed(ln.right_boundary))).buffer(0)
                 for ln in (m.lanes[i] for i in r.lane_ids)]
        out[r.id] = unary_union(parts)
    return out


def overlapping_roads(m: HDMap) -> list[str]:
    """No two roads (outside junction areas) share area; no two junction areas overlap."""
    problems = []
    junctions = {jid: Polygon(j.polygon) for jid, j in m.junctions.items()}
    jl = list(junctions)
    jtree = STRtree([junctions[j] for j in jl])
    for a, jid in enumerate(jl):
        for b in jtree.query(junctions[jid], predicate="intersects"):
            if b > a and junctions[jid].intersection(junctions[jl[b]]).area > AREA_EPS_M2:
                problems.append(f"junctions {jid} and {jl[b]} overlap")
    all_junctions = unary_union(list(junctions.values())).buffer(0.01)
    roads = {rid: poly.difference(all_junctions) for rid, poly in _road_polygons(m).items()}
    ids = list(roads)
    tree = STRtree([roads[r] for r in ids])
    for a, rid in enumerate(ids):
        for b in tree.query(roads[rid], predicate="intersects"):
            if b > a and roads[rid].intersection(roads[ids[b]]).area > AREA_EPS_M2:
                problems.append(f"roads {rid} and {ids[b]} overlap outside junctions")
    return problems


def overlapping_crosswalks(m: HDMap) -> list[str]:
    """No two crosswalks share area."""
    polys = {c.id: Polygon(c.polygon) for c in m.crosswalks.values()}
    ids = list(polys)
    tree = STRtree([polys[i] for i in ids])
    return [f"crosswalks {a} and {ids[b]} overlap" for k, a in enumerate(ids)
            for b in tree.query(polys[a], predicate="intersects")
            if b > k and polys[a].intersection(polys[ids[b]]).area > AREA_EPS_M2]


def broken_lanes(m: HDMap) -> list[str]:
    """Every lane has >= 2 points and meets its successors within 1 cm, links symmetric."""
    problems = []
    for ln in m.lanes.values():
        if len(ln.centerline) < 2:
            problems.append(f"lane {ln.id} has fewer than 2 points")
            continue
        for s in ln.successors:
            succ = m.lanes[s]
            if math.dist(ln.end, succ.start) > ENDPOINT_TOLERANCE_M:
                problems.append(f"lane {ln.id} ends {math.dist(ln.end, succ.start):.3f} m from successor {s}")
            if ln.id not in succ.predecessors:
                problems.append(f"lane {ln.id} -> {s} is not mirrored in {s}.predecessors")
        for p in ln.predecessors:
            if ln.id not in m.lanes[p].successors:
                problems.append(f"lane {p} -> {ln.id} is not mirrored in {p}.successors")
    return problems


def dead_ends(m: HDMap) -> list[str]:
    """No road lane stops at a junction without a way through it (or starts at one without a
    way in): one-way roads can leave an approach with no exit but its own socket, and such a
    lane would otherwise pass for one of the map's exits. Needs the roads' end junctions."""
    problems = []
    for r in m.roads.values():
        if r.kind == "junction":
            continue
        for ids, (frm, to) in ((r.right_lanes, (r.start_junction, r.end_junction)),
                               (r.left_lanes, (r.end_junction, r.start_junction))):
            for lid in ids:
                ln = m.lanes[lid]
                if to is not None and not ln.successors:
                    problems.append(f"lane {lid} is a dead end at junction {to}: no junction lane leads on")
                if frm is not None and not ln.predecessors:
                    problems.append(f"lane {lid} leaves junction {frm} but no junction lane leads into it")
    return problems


def lane_changes(lane) -> tuple[str, ...]:
    """Same-direction neighbours reachable by a lane change (across a dotted boundary)."""
    left = lane.left_neighbors if lane.left_boundary_type.startswith("dotted") else ()
    right = lane.right_neighbors if lane.right_boundary_type.startswith("dotted") else ()
    return left + right


def _reach(m: HDMap, starts: Sequence[str], forward: bool = True) -> set[str]:
    """Lanes reachable from any of `starts` by following links and lane changes (or backwards)."""
    seen = set(starts)
    todo = deque(starts)
    while todo:
        lane = m.lanes[todo.popleft()]
        for nxt in (lane.successors if forward else lane.predecessors) + lane_changes(lane):
            if nxt not in seen:
                seen.add(nxt)
                todo.append(nxt)
    return seen


def exits_reached(nodes: Iterable[str], nexts: Callable[[str], Sequence[str]], exits: Sequence[str]
                  ) -> dict[str, int]:
    """Per node reachable from `nodes` (along `nexts`), the exits it reaches (itself included) as
    a bit set, bit i for exits[i]. Tarjan's strongly connected components come out sinks first,
    so each one's set is its own exits joined with the sets of the components it links to: one
    pass over the links, a word-parallel OR each, instead of a search of the graph per entry."""
    bit = {x: 1 << i for i, x in enumerate(exits)}
    index: dict[str, int] = {}
    low: dict[str, int] = {}
    reached: dict[str, int] = {}
    stack: list[str] = []
    on_stack: set[str] = set()

    def visit(lid: str) -> None:
        index[lid] = low[lid] = len(index)
        stack.append(lid)
        on_stack.add(lid)
        work.append((lid, iter(nexts(lid))))

    for root in nodes:
        if root in index:
            continue
        work: list[tuple[str, Iterator[str]]] = []
        visit(root)
        while work:
            v, todo = work[-1]
            for w in todo:
                if w not in index:
                    visit(w)
                    break
                if w in on_stack:
                    low[v] = min(low[v], index[w])
            else:
                work.pop()
                if work:
                    low[work[-1][0]] = min(low[work[-1][0]], low[v])
                if low[v] == index[v]:
                    comp = {v}
                    while stack[-1] != v:
                        comp.add(stack.pop())
                    stack.pop()
                    on_stack -= comp
                    bits = 0
                    for c in comp:
                        bits |= bit.get(c, 0)
                        for w in nexts(c):
                            if w not in comp:
                                bits |= reached[w]
                    reached.update(dict.fromkeys(comp, bits))
    return reached


def unreached_exits(entries: Sequence[str], exits: Sequence[str], nexts: Callable[[str], Sequence[str]],
                    road_of: Callable[[str], object]) -> list[tuple[str, str]]:
    """(entry, exit) pairs where the exit is not reachable from the entry along `nexts`, leaving
    out the exits on the entry's own road (reaching those needs a U-turn); in entry, then exit order."""
    reached = exits_reached(entries, nexts, exits)
    everything = (1 << len(exits)) - 1
    own: dict[object, int] = {}  # per road, its exits
    for i, x in enumerate(exits):
        own[road_of(x)] = own.get(road_of(x), 0) | 1 << i
    out = []
    for e in entries:
        road = road_of(e)
        need = everything & ~own.get(road, 0)
        if reached[e] & need != need:
            out += [(e, x) for i, x in enumerate(exits) if not reached[e] >> i & 1 and road_of(x) != road]
    return out


def two_way(m: HDMap, lane_ids) -> bool:
    """Every road (outside junctions) carrying these lanes has lanes in both directions."""
    roads = {m.lanes[i].road_id for i in lane_ids}
    return all(m.roads[r].kind == "junction" or (m.roads[r].right_lanes and m.roads[r].left_lanes) for r in roads)


def _components(m: HDMap) -> list[list[str]]:
    """Weakly connected groups of lanes (successor links and lane changes, either way)."""
    parent = {lid: lid for lid in m.lanes}

    def find(x: str) -> str:
        while parent[x] != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for ln in m.lanes.values():
        for o in ln.successors + lane_changes(ln):
            parent[find(o)] = find(ln.id)
    groups: dict[str, list[str]] = {}
    for lid in m.lanes:
        groups.setdefault(find(lid), []).append(lid)
    return list(groups.values())


def connectivity(m: HDMap) -> list[str]:
    """Routes exist: every lane lies on an entry-to-exit route; when all roads are two-way,
    entries also reach every exit (other than their own stub's); a part without entries
    (a closed road chain) is strongly connected.

    With two-way roads and no U-turns, "every lane from every entry" is impossible on a
    tree-shaped layout (a lane heading back towards an entry needs a U-turn to be reached
    from it), so the route-level property above is what full junction connectivity gives.
    One-way roads legitimately keep some exits from some entries (a one-way street leads away
    from them), so for them only the per-lane route property holds. Hand-written road chains
    that touch no junction are separate networks: each is checked on its own, while all
    junction lanes and the roads linked to them form one network.
    """
    if not m.lanes:
        return []
    junction_part: list[str] = []
    parts: list[list[str]] = []
    for comp in _components(m):
        if any(m.lanes[i].junction_id is not None for i in comp):
            junction_part += comp
        else:
            parts.append(comp)
    if junction_part:
        parts.insert(0, junction_part)
    problems = []
    for part in parts:
        problems += _part_connectivity(m, part)
    return problems


def _part_connectivity(m: HDMap, part: list[str]) -> list[str]:
    problems = []
    entries = [i for i in part if not m.lanes[i].predecessors]
    exits = [i for i in part if not m.lanes[i].successors]
    if not entries and not exits:
        first = part[0]
        fwd, bwd = _reach(m, [first]), _reach(m, [first], forward=False)
        if len(fwd) != len(part) or len(bwd) != len(part):
            problems.append(f"network of lane {first} without entries is not strongly connected")
        return problems
    if two_way(m, part):
        unreached = unreached_exits(entries, exits, lambda lid: m.lanes[lid].successors + lane_changes(m.lanes[lid]),
                                    lambda lid: m.lanes[lid].road_id)
        problems += [f"exit lane {x} is not reachable from entry lane {e}" for e, x in unreached]
    from_entries, to_exits = _reach(m, entries), _reach(m, exits, forward=False)
    for lid in part:
        if lid not in from_entries:
            problems.append(f"lane {lid} is unreachable from every entry")
        if lid not in to_exits:
            problems.append(f"lane {lid} reaches no exit")
    return problems


def unrealized_features(m: HDMap, angle_tol_deg: float = 0.01) -> list[str]:
    """Re-measure every junction's feature from the geometry and compare with the recorded one."""
    from .extract import extract_junctions

    problems = []
    measured = {e.id: e.feature for e in extract_junctions(m)}
    for jid, j in m.junctions.items():
        want, got = j.feature, measured.get(jid)
        if want is None:
            continue
        if got is None:
            problems.append(f"junction {jid}: no feature could be measured")
            continue
        if (got.n_roads, got.control, got.crosswalk) != (want.n_roads, want.control, want.crosswalk):
            problems.append(f"junction {jid}: measured n/control/crosswalk {(got.n_roads, got.control, got.crosswalk)}"
                            f" != {(want.n_roads, want.control, want.crosswalk)}")
            continue
        problems += [f"junction {jid}: {p}" for p in feature_mismatch(got, want, angle_tol_deg)]
    return problems


def _circ(a: float, b: float) -> float:
    """Absolute angular difference in degrees, in [0, 180]."""
    return abs(wrap_degrees(a - b))


def feature_mismatch(got: JunctionFeature, want: JunctionFeature, angle_tol_deg: float = 0.01) -> list[str]:
    """Why two junction features differ ([] when they are the same feature).

    Normalization breaks ties between equally good socket orders (equal largest gaps) by
    position, so the same junction, turned by one of its symmetries (a quarter turn, a third of
    a turn, ...), may list its sockets from another start. The features match when they have
    the same socket directions and some cyclic re-listing of `got`, turned by one common angle,
    has `want`'s lanes, filter lanes and ramps (motorway links too) socket by socket."""
    if (got.n_roads, got.control, got.crosswalk) != (want.n_roads, want.control, want.crosswalk):
        return [f"measured n/control/crosswalk {(got.n_roads, got.control, got.crosswalk)}"
                f" != {(want.n_roads, want.control, want.crosswalk)}"]
    n = want.n_roads
    off = max(min(_circ(w, g) for g in got.rotation) for w in want.rotation)
    out = [f"socket angles off by {off:.4f} deg"] if off > angle_tol_deg else []
    want_lanes = [(w.lanes_in, w.lanes_out) for w in want.sockets]
    want_filters = [(w.filter, w.island) if w.filter != "none" else ("none",) for w in want.sockets]
    lanes_match = False
    for k in range(n):
        sock = [got.sockets[(i + k) % n] for i in range(n)]
        turn = sock[0].angle - want.sockets[0].angle
        if max(_circ(g.angle - turn, w.angle) for g, w in zip(sock, want.sockets)) <= max(angle_tol_deg, off) \
                and [(g.lanes_in, g.lanes_out) for g in sock] == want_lanes:
            lanes_match = True
            if [(g.filter, g.island) if g.filter != "none" else ("none",) for g in sock] != want_filters:
                continue
            if [(g.ramp, g.link) for g in sock] != [(w.ramp, w.link) for w in want.sockets]:
                return out + ["ramps per socket differ"]
            if want.has_ramp and abs(got.ramp_length - want.ramp_length) > RAMP_LENGTH_TOL_M:
                return out + [f"ramp_length {got.ramp_length:g} m != {want.ramp_length:g} m"]
            return out
    return out + ["filter lanes per socket differ" if lanes_match else "lanes per socket differ"]


def check_map(m: HDMap) -> list[str]:
    """All invariants at once."""
    return (overlapping_roads(m) + overlapping_crosswalks(m) + broken_lanes(m) + dead_ends(m) + connectivity(m)
            + unrealized_features(m))
