"""Build the HD map geometry of placed junctions: sockets, roads, lanes, controls, crosswalks.

Every road and lane is one cubic Bézier (paper eqs. 1-2): lane end points are the road's
end points shifted along the normal of the end headings. Lanes of a road are centred on its
reference line, so an arm's socket (the reference end point) is the mean of its lane ends.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np
from shapely import STRtree
from shapely.geometry import MultiPoint, Polygon
from shapely.ops import unary_union
from shapely.geometry.polygon import orient

from .angles import classify_turn, positive_angle, positive_degrees, wrap_angle
from .bezier import Bezier, left_normal, unit
from .config import FILTER_DIVERGE_M, FILTER_HANDLE, MIN_STUB_LENGTH_M, GenerationConfig
from .features import JunctionFeature, MidblockFeature, filter_exit, ramp_angle
from .ramps import RampLane, ramp_fit, ramp_lane_speed, ramp_lanes, ramp_radius, ramp_socket_radius, socket_speed
from .invariants import AREA_EPS_M2
from .errors import CrossingRoadsError, LayoutError
from .layout import Placement
from .model import Crosswalk, HDMap, Junction, Lane, Road, Signal, StopSign, YieldSign, as_polyline


Pose = tuple[tuple[float, float], float]  # (point, heading in radians)


@dataclass(frozen=True)
class RoadChain:
    """Hand-written roads connected end to end (paper Sec. IV-RQ4): piece k runs from pose k
    to pose k+1, each one cubic Bézier; `closed` links the last piece back to the first."""

    id: str
    poses: tuple[Pose, ...]  # start pose, then each piece's end pose
    lanes_forward: int = 1  # lanes along the chain
    lanes_backward: int = 1  # lanes against it
    closed: bool = False

    @property
    def n_pieces(self) -> int:
        return len(self.poses) - 1


@dataclass(frozen=True)
class MidblockRequest:
    """A mid-block crosswalk to build: on the road at `socket` (junction index, socket index of
    its normalized feature), its position measured from that junction; `socket` None: on a road
    between junctions the layout draws (seeded). `name` labels it in errors."""

    feature: MidblockFeature
    socket: tuple[int, int] | None = None
    name: str = "mid-block crosswalk"


@dataclass(frozen=True)
class SocketGeometry:
    point: tuple[float, float]
    angle: float  # absolute outward direction, radians
    half_width: float


def junction_radius(feature: JunctionFeature, cfg: GenerationConfig) -> float:
    """Centre-to-socket distance: far enough that neighbouring legs' pavements (plus a margin,
    the crosswalks' overhang) do not overlap, plus room for a crosswalk and stop line. A ramp
    junction's main sockets lie half its `ramp_length` from the centre (`ramps.ramp_radius`)."""
    if feature.has_ramp:
        return ramp_radius(feature)
    n = feature.n_roads
    halves = [(s.lanes_in + s.lanes_out) * cfg.lane_width / 2 + cfg.junction_margin for s in feature.sockets]
    need = cfg.min_junction_radius
    for i in range(n):
        j = (i + 1) % n
        delta = math.radians(positive_degrees(feature.rotation[j] - feature.rotation[i]))
        if delta < math.pi - 1e-6:
            s, c = math.sin(delta), math.cos(delta)
            for near, far in ((i, j), (j, i)):
                # the socket corner of leg `far` facing leg `near` clears that leg's pavement from
                # this radius on; legs more than 90 deg apart also clear it once the corner lies
                # behind the centre as seen along `near` (nearly opposite legs of unequal widths:
                # their pavements point away from each other whatever the radius)
                clear = (halves[near] + halves[far] * c) / s
                need = max(need, clear if c >= 0 else min(clear, halves[far] * s / -c))
    return need + cfg.crosswalk_width + 2 * cfg.junction_margin


def socket_geometry(feature: JunctionFeature, center: np.ndarray, rotation_deg: float,
                    cfg: GenerationConfig) -> list[SocketGeometry]:
    r = junction_radius(feature, cfg)
    out = []
    for i, s in enumerate(feature.sockets):
        a = math.radians(s.angle + rotation_deg)
        p = center + (ramp_socket_radius(feature, i) if s.ramp != "none" else r) * unit(a)
        out.append(SocketGeometry((float(p[0]), float(p[1])), a, (s.lanes_in + s.lanes_out) * cfg.lane_width / 2))
    return out


class _Builder:
    """Accumulates map elements; lane ids are `<road>_<k>`."""

    def __init__(self, cfg: GenerationConfig) -> None:
        self.cfg = cfg
        self.lanes: dict[str, dict] = {}
        self.roads: dict[str, Road] = {}
        self.beziers: dict[str, Bezier] = {}
        self._references: dict[tuple[float, ...], Bezier] = {}

    def reference(self, start, h0: float, end, h1: float) -> Bezier:
        """`Bezier.from_poses`, one object per pose pair: a road's pavement, its reference and its
        lanes along it share one curve, so its arc-length table is computed once."""
        key = (float(start[0]), float(start[1]), float(h0), float(end[0]), float(end[1]), float(h1))
        b = self._references.get(key)
        if b is None:
            b = self._references[key] = Bezier.from_poses(start, h0, end, h1)
        return b

    def lane_curves(self, start, h0, end, h1, offset: float) -> tuple[Bezier, np.ndarray, np.ndarray, np.ndarray]:
        """A lane `offset` metres left of the reference Bézier start->end: its end-pose Bézier
        and its centre and (left, right) boundary polylines.

        The polylines are true offsets of the reference, so lanes keep their width on any bend
        (Béziers between offset end poses pinch on S-bends); the returned Bézier shares the
        centreline's end points and end tangents, which is what links and features use."""
        w = self.cfg.lane_width / 2
        reference = self.reference(start, h0, end, h1)
        centre = reference if offset == 0.0 else Bezier.from_poses(
            tuple(np.asarray(start) + offset * left_normal(h0)), h0, tuple(np.asarray(end) + offset * left_normal(h1)), h1)
        ts = reference.sample_params(self.cfg.sample_spacing)  # centre and boundaries share parameters
        pts, left, right = reference.offset_points(ts, (offset, offset + w, offset - w))
        pts[0], pts[-1] = centre.p0, centre.p3  # exactly the end poses the links were built on
        return centre, pts, left, right

    def add_lane(self, lane_id: str, road_id: str, centre: Bezier, pts, left, right, *, speed: float,
                 junction_id: str | None = None, turn: str = "none", ltype: str = "solid_white",
                 rtype: str = "solid_white") -> None:
        self.beziers[lane_id] = centre
        self.lanes[lane_id] = dict(
            id=lane_id, road_id=road_id, centerline=as_polyline(pts), left_boundary=as_polyline(left),
            right_boundary=as_polyline(right), width=self.cfg.lane_width, speed_limit=speed,
            predecessors=[], successors=[], left_neighbors=[], right_neighbors=[], left_reverse_neighbors=[],
            turn=turn, junction_id=junction_id, left_boundary_type=ltype, right_boundary_type=rtype, bezier=centre,
        )

    def add_road(self, road_id: str, kind: str, start, h0: float, end, h1: float, n_right: int, n_left: int,
                 start_junction: str | None, end_junction: str | None, speed: float | None = None) -> Road:
        """A road with `n_right` lanes along start->end and `n_left` against it, centred on the
        reference, its lanes' limit `speed` (default `speed_limit`, a town road)."""
        w = self.cfg.lane_width
        speed = self.cfg.speed_limit if speed is None else speed
        divider = (n_right - n_left) * w / 2  # left of the reference by this much
        right_ids: list[str] = []
        left_ids: list[str] = []
        for i in range(n_right):
            lid = f"{road_id}_{len(right_ids)}"
            off = divider - (i + 0.5) * w
            centre, pts, left, right = self.lane_curves(start, h0, end, h1, off)
            ltype = ("solid_yellow" if n_left else "solid_white") if i == 0 else "dotted_white"
            rtype = "dotted_white" if i < n_right - 1 else "solid_white"
            self.add_lane(lid, road_id, centre, pts, left, right, speed=speed, ltype=ltype, rtype=rtype)
            right_ids.append(lid)
        for i in range(n_left):
            lid = f"{road_id}_{n_right + i}"
            off = divider + (i + 0.5) * w
            # driving against the reference: from end to start, so "left" is the reference's right
            centre, pts, left, right = self.lane_curves(end, h1 + math.pi, start, h0 + math.pi, -off)
            ltype = ("solid_yellow" if n_right else "solid_white") if i == 0 else "dotted_white"
            rtype = "dotted_white" if i < n_left - 1 else "solid_white"
            self.add_lane(lid, road_id, centre, pts, left, right, speed=speed, ltype=ltype, rtype=rtype)
            left_ids.append(lid)
        for ids in (right_ids, left_ids):
            for a, b in zip(ids, ids[1:]):  # a is nearer the divider: left of b
                self.lanes[a]["right_neighbors"].append(b)
                self.lanes[b]["left_neighbors"].append(a)
        if right_ids and left_ids:
            self.lanes[right_ids[0]]["left_reverse_neighbors"].append(left_ids[0])
            self.lanes[left_ids[0]]["left_reverse_neighbors"].append(right_ids[0])
        road = Road(road_id, kind, tuple(right_ids), tuple(left_ids), self.reference(start, h0, end, h1),
                    divider, None, start_junction, end_junction)
        self.roads[road_id] = road
        return road

    def link(self, a: str, b: str) -> None:
        self.lanes[a]["successors"].append(b)
        self.lanes[b]["predecessors"].append(a)


def lane_pairs(p: int, exits: Sequence[tuple[int, int, str]]) -> list[tuple[int, int, int]]:
    """Lane-level connections at one approach: (in lane, exit index, out lane), lanes right to left.

    Exits are sorted from the sharpest right to the sharpest left and split over the incoming
    lanes in that order, like lane-use arrows: lane i serves the exits whose share of the
    [0, 1] interval overlaps lane i's share. Within one exit, its c serving lanes and its q
    lanes are joined by a monotone map (out lane j from serving lane floor(j c / q) when
    q >= c, serving lane k to out lane floor(k q / c) otherwise). Monotone maps never cross,
    and every incoming lane and every lane of every exit gets at least one connection.
    """
    n_exits = len(exits)
    out = []
    for e, (_, q, _) in enumerate(exits):
        lanes = [i for i in range(p) if i * n_exits < (e + 1) * p and e * p < (i + 1) * n_exits]
        c = len(lanes)
        if q >= c:
            out += [(lanes[j * c // q], e, j) for j in range(q)]
        else:
            out += [(i, e, k * q // c) for k, i in enumerate(lanes)]
    return out


def chain_road_id(chain: RoadChain, k: int) -> str:
    return f"{chain.id}_{k}"


def _build_chain(b: _Builder, chain: RoadChain) -> None:
    """One road per piece; forward lanes link piece k -> k+1, backward lanes k+1 -> k (lane i
    to lane i: the lane count is constant along a chain); a closed chain also links last/first."""
    roads = []
    for k in range(chain.n_pieces):
        (p0, h0), (p1, h1) = chain.poses[k], chain.poses[k + 1]
        roads.append(b.add_road(chain_road_id(chain, k), "chain", p0, h0, p1, h1,
                                chain.lanes_forward, chain.lanes_backward, None, None))
    pairs = list(zip(roads, roads[1:])) + ([(roads[-1], roads[0])] if chain.closed else [])
    for a, c in pairs:
        for x, y in zip(a.right_lanes, c.right_lanes):
            b.link(x, y)
        for x, y in zip(c.left_lanes, a.left_lanes):
            b.link(x, y)


def assign_midblock(placements: Sequence[Placement], requests: Sequence[MidblockRequest],
                    rng: np.random.Generator) -> dict[tuple[int, int], MidblockRequest]:
    """(junction, socket) -> the request built on its road: the asked-for sockets as they are,
    the others on distinct roads between junctions drawn by `rng` (measured from the road's
    start). A socket ending in a stub, two crossings on one road or more crossings than roads
    is a LayoutError naming the request."""
    out: dict[tuple[int, int], MidblockRequest] = {}
    taken: set[tuple[int, int]] = set()

    def road_of(j: int, s: int) -> tuple[int, int]:  # a road by its start socket (the smaller end)
        ln = placements[j].links[s]
        return min((j, s), (ln.junction, ln.socket)) if ln is not None else (j, s)

    for r in requests:
        if r.socket is None:
            continue
        j, s = r.socket
        if placements[j].links[s] is None:
            raise LayoutError("its road ends in a stub at the map's edge: a mid-block crosswalk lies on a road "
                              "between two junctions (pin the junctions next to each other with cell)", r.name)
        if road_of(j, s) in taken:
            raise LayoutError("its road already has a mid-block crosswalk (one per road)", r.name)
        taken.add(road_of(j, s))
        out[(j, s)] = r
    free = [(j, s) for j, p in enumerate(placements) for s, ln in enumerate(p.links)
            if ln is not None and (j, s) < (ln.junction, ln.socket) and (j, s) not in taken
            and not p.feature.has_ramp and not placements[ln.junction].feature.has_ramp]  # no crossing on a motorway
    drawn = [r for r in requests if r.socket is None]
    if len(drawn) > len(free):
        raise LayoutError(f"{len(drawn)} mid-block crosswalks to place but {len(free)} free roads between junctions "
                          "(one per road: ask for fewer, or more junctions)", drawn[0].name)
    for r, k in zip(drawn, rng.permutation(len(free))[:len(drawn)].tolist()):
        out[free[k]] = r
    return out


def build_map(placements: Sequence[Placement], cfg: GenerationConfig, meta: dict | None = None,
              chains: Sequence[RoadChain] = (), progress: bool = False,
              midblock: dict[tuple[int, int], MidblockRequest] | None = None) -> HDMap:
    """Instantiate every placed junction, its roads, lanes, controls and crosswalks, the
    mid-block crosswalks (`assign_midblock`'s) and the hand-written road chains (which keep
    their absolute coordinates); `progress` shows a bar over the junctions (twice: their roads,
    then their lanes), on a terminal only."""
    from tqdm import tqdm

    with tqdm(total=2 * len(placements), desc="build", unit="junction", unit_scale=0.5, leave=False,
              disable=None if progress and len(placements) > 1 else True) as bar:
        return _build_map(placements, cfg, meta, chains, bar.update, midblock or {})


def _build_map(placements: Sequence[Placement], cfg: GenerationConfig, meta: dict | None,
               chains: Sequence[RoadChain], tick, midblock: dict[tuple[int, int], MidblockRequest]) -> HDMap:
    b = _Builder(cfg)
    for chain in chains:
        _build_chain(b, chain)
    sockets: list[list[SocketGeometry]] = []
    centers = [tuple(np.array(p.cell, dtype=float) * cfg.grid_gap) for p in placements]
    for j, p in enumerate(placements):
        r = junction_radius(p.feature, cfg)
        room = cfg.grid_gap / 2 - MIN_STUB_LENGTH_M - cfg.junction_margin
        if p.feature.has_ramp and (why := ramp_fit(p.feature, cfg, room)):
            raise LayoutError(why, f"junction J{j}")
        if r > room:
            need = 2 * (r + MIN_STUB_LENGTH_M + cfg.junction_margin)
            raise LayoutError(
                f"legs {list(p.feature.rotation)} are too close for their lanes: the junction needs a "
                f"{r:.1f} m radius, a {cfg.grid_gap:g} m grid leaves {room:.1f} m (use grid_gap >= {need:.0f})",
                f"junction J{j}")
        center = np.array(p.cell, dtype=float) * cfg.grid_gap
        sockets.append(socket_geometry(p.feature, center, p.rotation_deg, cfg))

    # the pavement of every road between junctions, so that no stub is laid across one
    connections = [pavement(b.reference(sockets[j][s].point, sockets[j][s].angle,
                                              sockets[ln.junction][ln.socket].point,
                                              sockets[ln.junction][ln.socket].angle + math.pi),
                            sockets[j][s].half_width + cfg.junction_margin, cfg)
                   for j, p in enumerate(placements) for s, ln in enumerate(p.links)
                   if ln is not None and (ln.junction, ln.socket) > (j, s)]
    owners = [{j, ln.junction} for j, p in enumerate(placements) for s, ln in enumerate(p.links)
              if ln is not None and (ln.junction, ln.socket) > (j, s)]
    junction_polys = [_junction_polygon(np.asarray(c), socks, not p.feature.has_ramp)
                      for c, socks, p in zip(centers, sockets, placements)]
    _check_uncrossed(connections, junction_polys, cfg)
    connection_tree = STRtree(connections)
    # roads: incoming / outgoing lanes per (junction, socket), each listed right to left
    incoming: dict[tuple[int, int], list[str]] = {}
    outgoing: dict[tuple[int, int], list[str]] = {}
    socket_road: dict[tuple[int, int], str] = {}  # the road (piece) at the socket
    main_road: dict[tuple[int, int], str] = {}  # the same road's longest piece (a filter lane splits it)
    cuts = {(j, s) for j, p in enumerate(placements) for a in range(p.feature.n_roads)
            if p.feature.sockets[a].filter != "none"
            for s in (a, filter_exit(p.feature, a)) if s is not None}  # roads split for a filter lane
    n_roads = 0
    for j, p in enumerate(placements):
        tick()
        for s, link in enumerate(p.links):
            if link is not None and (link.junction, link.socket) < (j, s):
                continue
            sock = p.feature.sockets[s]
            g = sockets[j][s]
            rid = f"R{n_roads}"
            n_roads += 1
            cut_start = (j, s) in cuts
            if link is None:
                along, tree = 1.0, connection_tree
                if sock.ramp != "none":  # it runs beside its own main road's, diverging: checked by its ramp angle
                    along = math.cos(math.radians(ramp_angle(p.feature, s)))
                    tree = STRtree([c for c, o in zip(connections, owners) if j not in o])
                length = _stub_length(g, centers[j], tree, cfg, f"junction J{j}", along)
                end = tuple(np.asarray(g.point) + length * unit(g.angle))
                road, main, last = _add_road_split(b, rid, "stub", g.point, g.angle, end, g.angle, sock.lanes_out,
                                                   sock.lanes_in, f"J{j}", None, cut_start, False,
                                                   socket_speed(p.feature, s, cfg))
            else:
                o = sockets[link.junction][link.socket]
                cut_end = (link.junction, link.socket) in cuts
                speed = min(socket_speed(p.feature, s, cfg),
                            socket_speed(placements[link.junction].feature, link.socket, cfg))  # the lower end's
                road, main, last = _add_road_split(b, rid, "connection", g.point, g.angle, o.point, o.angle + math.pi,
                                                   sock.lanes_out, sock.lanes_in, f"J{j}", f"J{link.junction}",
                                                   cut_start, cut_end, speed)
                incoming[(link.junction, link.socket)] = list(reversed(last.right_lanes))
                outgoing[(link.junction, link.socket)] = list(reversed(last.left_lanes))
                socket_road[(link.junction, link.socket)] = last.id
                main_road[(link.junction, link.socket)] = main.id
            incoming[(j, s)] = list(reversed(road.left_lanes))
            outgoing[(j, s)] = list(reversed(road.right_lanes))
            socket_road[(j, s)] = road.id
            main_road[(j, s)] = main.id

    junctions: dict[str, Junction] = {}
    signals: dict[str, Signal] = {}
    stops: dict[str, StopSign] = {}
    yields: dict[str, YieldSign] = {}
    crosswalks: dict[str, Crosswalk] = {}
    for j, p in enumerate(placements):
        tick()
        jid = f"J{j}"
        f = p.feature
        poly = junction_polys[j]
        n_conn = 0
        for a in range(f.n_roads):
            ins = incoming[(j, a)]
            if not ins:
                continue
            if f.has_ramp:
                continue  # ramp junctions: below
            entry_heading = sockets[j][a].angle + math.pi
            slip = filter_exit(f, a) if f.sockets[a].filter != "none" else None
            exits = []
            for c in range(f.n_roads):
                if not outgoing[(j, c)] or (c == a and not cfg.uturns) or c == slip:
                    continue
                turn = "uturn" if c == a else classify_turn(entry_heading, sockets[j][c].angle)
                delta = wrap_angle(sockets[j][c].angle - entry_heading)
                exits.append((c, len(outgoing[(j, c)]), turn, delta if c != a else math.pi))
            exits.sort(key=lambda e: e[3])
            for i, e, k in lane_pairs(len(ins), [x[:3] for x in exits]):
                c, _, turn, _ = exits[e]
                src, dst = ins[i], outgoing[(j, c)][k]
                rid = f"{jid}_c{n_conn}"
                n_conn += 1
                s_pt, d_pt = b.lanes[src]["centerline"][-1], b.lanes[dst]["centerline"][0]
                h0 = float(b.beziers[src].heading(1.0))
                h1 = float(b.beziers[dst].heading(0.0))
                centre, pts, left, right = b.lane_curves(s_pt, h0, d_pt, h1, 0.0)
                lid = f"{rid}_0"
                b.add_lane(lid, rid, centre, pts, left, right, speed=cfg.junction_speed_limit, junction_id=jid,
                           turn=turn, ltype="virtual", rtype="virtual")
                b.roads[rid] = Road(rid, "junction", (lid,), (), centre, 0.0, jid, jid, jid)
                b.link(src, lid)
                b.link(lid, dst)
        if f.has_ramp:
            for lane in ramp_lanes(f, incoming, outgoing, j):
                _ramp_lane(b, jid, f"{jid}_c{n_conn}", lane, cfg)
                n_conn += 1
        for a in range(f.n_roads):
            into = filter_exit(f, a) if f.sockets[a].filter != "none" else None
            if into is not None:
                poly = _filter_lane(b, jid, a, f.sockets[a], incoming[(j, a)][0], outgoing[(j, into)][0], poly, cfg,
                                    signals, yields)
        for a in range(f.n_roads):
            ins = incoming[(j, a)]
            if not ins or f.control == "bare":
                continue
            line, pos, heading = _stop_line(b, ins, cfg)
            if f.control == "signal":
                sid = f"{jid}_signal{a}"
                signals[sid] = Signal(sid, jid, line, pos, heading, tuple(ins))
            else:
                sid = f"{jid}_stop{a}"
                stops[sid] = StopSign(sid, jid, line, pos, heading, tuple(ins))
        if f.crosswalk:
            for a, g in enumerate(sockets[j]):
                cid = f"{jid}_cw{a}"
                crosswalks[cid] = Crosswalk(cid, jid, _crosswalk_polygon(g, poly, cfg))
        junctions[jid] = Junction(jid, as_polyline(poly.exterior.coords[:-1]), f, p.cell,
                                  tuple(socket_road[(j, s)] for s in range(f.n_roads)))
    for (j, s), req in sorted(midblock.items()):
        road = b.roads[main_road[(j, s)]]
        ln = placements[j].links[s]
        from_start = ln is None or (j, s) < (ln.junction, ln.socket)
        _midblock(b, road, req, from_start, cfg, crosswalks, signals)

    lanes = {}
    for lid, d in b.lanes.items():
        for key in ("predecessors", "successors", "left_neighbors", "right_neighbors", "left_reverse_neighbors"):
            d[key] = tuple(d[key])
        lanes[lid] = Lane(**d)
    roads = dict(sorted(b.roads.items(), key=lambda kv: (kv[1].kind == "junction", kv[0])))
    if yields:
        return HDMap(lanes, roads, junctions, signals, stops, crosswalks, meta=dict(meta or {}), yield_signs=yields)
    return HDMap(lanes, roads, junctions, signals, stops, crosswalks, meta=dict(meta or {}))


def _add_road_split(b: _Builder, rid: str, kind: str, start, h0: float, end, h1: float, n_right: int, n_left: int,
                    start_junction: str | None, end_junction: str | None, cut_start: bool, cut_end: bool,
                    speed: float) -> tuple[Road, Road, Road]:
    """A road from `start` to `end` as `_Builder.add_road` makes it, split FILTER_DIVERGE_M from
    the end(s) where a filter lane leaves or joins it (`cut_start`, `cut_end`; on a road too short
    for that, as far as leaves a quarter of FILTER_DIVERGE_M between the cuts, but at least half
    FILTER_DIVERGE_M, else a LayoutError naming the road): (the piece at the start, the
    longest piece, the piece at the end), the same road three times when nothing is cut. The
    pieces' lanes link end to start; a cut piece at a junction is `<rid>a` (start) or `<rid>b`.
    Every piece's lanes have the limit `speed`."""
    if not cut_start and not cut_end:
        road = b.add_road(rid, kind, start, h0, end, h1, n_right, n_left, start_junction, end_junction, speed)
        return road, road, road
    ref = b.reference(start, h0, end, h1)
    length = ref.length
    reach = min(FILTER_DIVERGE_M, (length - FILTER_DIVERGE_M / 4) / (cut_start + cut_end))
    if reach < FILTER_DIVERGE_M / 2:
        raise LayoutError(f"a {length:.1f} m road is too short for a filter lane leaving it {FILTER_DIVERGE_M / 2:g} to "
                          f"{FILTER_DIVERGE_M:g} m before its junction (raise stub_length or grid_gap)", f"road {rid}")
    poses = [(tuple(start), h0)]
    for cut, s in ((cut_start, reach), (cut_end, length - reach)):
        if cut:
            t = ref.param_at(s)
            pt = ref.point(t)
            poses.append(((float(pt[0]), float(pt[1])), float(ref.heading(t))))
    poses.append((tuple(end), h1))
    names = ([f"{rid}a"] if cut_start else []) + [rid] + ([f"{rid}b"] if cut_end else [])
    pieces = []
    for k, name in enumerate(names):
        (p0, a0), (p1, a1) = poses[k], poses[k + 1]
        pieces.append(b.add_road(name, kind, p0, a0, p1, a1, n_right, n_left,
                                 start_junction if k == 0 else None, end_junction if k == len(names) - 1 else None,
                                 speed))
    for x, y in zip(pieces, pieces[1:]):
        for u, v in zip(x.right_lanes, y.right_lanes):
            b.link(u, v)
        for u, v in zip(y.left_lanes, x.left_lanes):
            b.link(u, v)
    main = pieces[1] if cut_start else pieces[0]
    return pieces[0], main, pieces[-1]


def _filter_lane(b: _Builder, jid: str, a: int, sock, approach: str, exit_lane: str, poly: Polygon,
                 cfg: GenerationConfig, signals: dict[str, Signal], yields: dict[str, YieldSign]) -> Polygon:
    """The filter lane of approach `a`: a junction lane `<jid>_f<a>_0` from the end of the lane
    before the approach's rightmost lane (`approach`; the roads were split FILTER_DIVERGE_M from
    the junction) to the start of the lane after the exit's rightmost lane (`exit_lane`), typed a
    right turn, kerbs on its left with an island (else a solid line), a solid line on its right;
    a yield sign or a light of its own on the lane before it. Returns the junction polygon grown
    by the lane and the island or painted area between it and the core (the hull of both, less
    the two road pieces beside it)."""
    src = b.lanes[approach]["predecessors"][0]
    dst = b.lanes[exit_lane]["successors"][0]
    p0, p3 = np.asarray(b.lanes[src]["centerline"][-1]), np.asarray(b.lanes[dst]["centerline"][0])
    h0, h1 = float(b.beziers[src].heading(1.0)), float(b.beziers[dst].heading(0.0))
    d0, d1 = unit(h0), unit(h1)
    r = p3 - p0  # where the lines meet: u d0 + v d1 = r (Cramer's rule)
    det = d0[0] * d1[1] - d0[1] * d1[0]
    u = (r[0] * d1[1] - r[1] * d1[0]) / det if abs(det) > 1e-9 else -1.0
    v = (d0[0] * r[1] - d0[1] * r[0]) / det if abs(det) > 1e-9 else -1.0
    if u > 0 and v > 0:
        centre = Bezier((float(p0[0]), float(p0[1])), tuple(p0 + FILTER_HANDLE * u * d0),
                        tuple(p3 - FILTER_HANDLE * v * d1), (float(p3[0]), float(p3[1])))
    else:
        centre = Bezier.from_poses(tuple(p0), h0, tuple(p3), h1)
    w = cfg.lane_width / 2
    pts, left, right = centre.offset_points(centre.sample_params(cfg.sample_spacing), (0.0, w, -w))
    pts[0], pts[-1] = centre.p0, centre.p3
    rid = f"{jid}_f{a}"
    lid = f"{rid}_0"
    b.add_lane(lid, rid, centre, pts, left, right, speed=cfg.junction_speed_limit, junction_id=jid, turn="right",
               ltype="curb" if sock.island else "solid_white", rtype="solid_white")
    b.roads[rid] = Road(rid, "junction", (lid,), (), centre, 0.0, jid, jid, jid)
    b.link(src, lid)
    b.link(lid, dst)
    line, pos, heading = _stop_line(b, [src], cfg)
    if sock.filter == "signal":
        sid = f"{jid}_filter{a}"
        signals[sid] = Signal(sid, jid, line, pos, heading, (src,))
    else:
        sid = f"{jid}_yield{a}"
        yields[sid] = YieldSign(sid, jid, line, pos, heading, (src,))
    lane = Polygon(np.concatenate([left, right[::-1]])).buffer(0)
    pieces = [Polygon(list(d["left_boundary"]) + list(reversed(d["right_boundary"]))).buffer(0)
              for r in (b.lanes[approach]["road_id"], b.lanes[exit_lane]["road_id"]) for x in b.roads[r].lane_ids
              for d in (b.lanes[x],)]
    grown = unary_union([poly, lane]).convex_hull.difference(unary_union(pieces))
    merged = unary_union([grown, poly])
    if merged.geom_type != "Polygon":  # slivers the pieces cut off
        merged = max(getattr(merged, "geoms", [merged]), key=lambda g: g.area)
    return orient(Polygon(merged.exterior.coords), 1.0)


def _ramp_lane(b: _Builder, jid: str, rid: str, lane: RampLane, cfg: GenerationConfig) -> None:
    """A junction lane `<rid>_0` from the end of road lane `lane.src` to the start of `lane.dst`:
    a cubic Bezier whose handles are `lane.shape` (start, end) fractions of the distance between
    its ends along their headings (a ramp's lane turns onto the main road's line early and runs
    beside its lanes, or runs beside them and turns off late), its turn classed by its heading
    change, its limit `ramps.ramp_lane_speed`'s."""
    src, dst, shape = lane.src, lane.dst, lane.shape
    p0, p3 = np.asarray(b.lanes[src]["centerline"][-1]), np.asarray(b.lanes[dst]["centerline"][0])
    h0, h1 = float(b.beziers[src].heading(1.0)), float(b.beziers[dst].heading(0.0))
    dist = float(np.hypot(*(p3 - p0)))
    centre = Bezier((float(p0[0]), float(p0[1])), tuple(p0 + shape[0] * dist * unit(h0)),
                    tuple(p3 - shape[1] * dist * unit(h1)), (float(p3[0]), float(p3[1])))
    w = cfg.lane_width / 2
    pts, left, right = centre.offset_points(centre.sample_params(cfg.sample_spacing), (0.0, w, -w))
    pts[0], pts[-1] = centre.p0, centre.p3
    lid = f"{rid}_0"
    b.add_lane(lid, rid, centre, pts, left, right, speed=ramp_lane_speed(lane, cfg), junction_id=jid,
               turn=classify_turn(h0, h1), ltype="virtual", rtype="virtual")
    b.roads[rid] = Road(rid, "junction", (lid,), (), centre, 0.0, jid, jid, jid)
    b.link(src, lid)
    b.link(lid, dst)


def _midblock(b: _Builder, road: Road, req: MidblockRequest, from_start: bool, cfg: GenerationConfig,
              crosswalks: dict[str, Crosswalk], signals: dict[str, Signal]) -> None:
    """A crosswalk `crosswalk_width` wide across all lanes of `road` (and `junction_margin`
    beyond its edges, as at junctions), centred `req.feature.position` of the road's length from
    the asking junction; for a signalised one a light per direction of travel, its stop line
    `junction_margin` before the crossing and its pole on the right, facing the traffic."""
    ref = road.reference
    assert ref is not None
    length = ref.length
    centre = length * (req.feature.position if from_start else 1.0 - req.feature.position)
    half = cfg.crosswalk_width / 2
    reach = half + (2 * cfg.junction_margin if req.feature.control == "signal" else cfg.junction_margin)
    if not reach <= centre <= length - reach:
        raise LayoutError(f"at {req.feature.position:g} of a {length:.1f} m road it does not fit: its strip"
                          f"{' and stop lines' if req.feature.control == 'signal' else ''} need {reach:.2f} m "
                          "of road on each side of its centre", req.name)
    w = cfg.lane_width
    n_right, n_left = len(road.right_lanes), len(road.left_lanes)
    right_edge, left_edge = road.lane_offset - n_right * w, road.lane_offset + n_left * w
    t0, t1 = ref.param_at(centre - half), ref.param_at(centre + half)
    margin = cfg.junction_margin
    (a0, a1), (b0, b1) = (ref.offset_points(np.array([t]), (right_edge - margin, left_edge + margin)) for t in (t0, t1))
    cid = f"{road.id}_cw"
    crosswalks[cid] = Crosswalk(cid, None, as_polyline([a0[0], b0[0], b1[0], a1[0]]))
    if req.feature.control != "signal":
        return
    # along the reference (right lanes) the line lies before the strip's start, against it after its end
    for k, (lanes, at, edge, inner, turn) in enumerate((
            (road.right_lanes, centre - half - margin, right_edge, road.lane_offset, 0.0),
            (road.left_lanes, centre + half + margin, left_edge, road.lane_offset, math.pi))):
        if not lanes:
            continue
        t = ref.param_at(at)
        outer, mid, pole = ref.offset_points(np.array([t]), (edge, inner, edge + math.copysign(margin, edge - inner)))
        sid = f"{road.id}_signal{k}"
        heading = positive_angle(float(ref.heading(t)) + turn + math.pi)
        signals[sid] = Signal(sid, None, as_polyline([outer[0], mid[0]]), (float(pole[0][0]), float(pole[0][1])),
                              heading, tuple(reversed(lanes)))


def pavement(reference: Bezier, half_width: float, cfg: GenerationConfig) -> Polygon:
    """The area a road takes: its reference line widened by `half_width` on each side."""
    ts = reference.sample_params(cfg.sample_spacing)
    left, right = reference.offset_points(ts, (half_width, -half_width))
    return Polygon(np.concatenate([left, right[::-1]])).buffer(0)


def _stub_length(g: SocketGeometry, center, connections: STRtree, cfg: GenerationConfig,
                 where: str, along: float = 1.0) -> float:
    """A stub ends short of the half-way line (facing stubs never meet) and short of every road
    between junctions that sweeps across its way (a connection leaving a socket far from its
    grid direction; `connections`: an STRtree of their pavements); a stub that would keep less than
    MIN_STUB_LENGTH_M is a LayoutError. `along`: the cosine of the stub's angle to the grid
    direction whose half-way line bounds it (a ramp's, to its main road; 1 for other sockets)."""
    reach = cfg.grid_gap / 2 - cfg.junction_margin - math.dist(g.point, center) * along
    length = min(cfg.stub_length, reach / along)
    p, u = np.asarray(g.point), unit(g.angle)
    hw = g.half_width + cfg.junction_margin
    n = left_normal(g.angle)
    way = Polygon([tuple(p + hw * n), tuple(p + length * u + hw * n), tuple(p + length * u - hw * n),
                   tuple(p - hw * n)])
    for road in connections.geometries.take(connections.query(way, predicate="intersects")):
        hit = way.intersection(road)
        if hit.area > 1e-6:
            pts = np.concatenate([np.asarray(part.exterior.coords) for part in getattr(hit, "geoms", [hit])
                                  if part.geom_type == "Polygon"])
            length = min(length, float(((pts - p) @ u).min()) - cfg.junction_margin)
    if length < MIN_STUB_LENGTH_M:
        raise CrossingRoadsError(f"the leg at {positive_degrees(math.degrees(g.angle)):.1f} deg would run into a road between "
                                 f"junctions within {MIN_STUB_LENGTH_M:g} m (raise grid_gap or spread the legs)", where)
    return length


def _check_uncrossed(connections: Sequence[Polygon], junctions: Sequence[Polygon], cfg: GenerationConfig) -> None:
    """Roads between junctions share no area outside the junctions (their margins aside): a
    socket far from the grid direction it serves can sweep its road across a neighbour's."""
    if len(connections) < 2:
        return
    inside = [j.buffer(cfg.junction_margin) for j in junctions]
    near = STRtree(inside)
    roads = []
    for c in connections:  # each road minus the junctions it touches (the union of all is quadratic)
        road = c.buffer(-cfg.junction_margin)
        hits = near.query(road, predicate="intersects")
        roads.append(road.difference(unary_union([inside[i] for i in hits])) if len(hits) else road)
    tree = STRtree(roads)
    for a, b in zip(*tree.query(roads, predicate="intersects")):
        if a < b and roads[a].intersection(roads[b]).area > AREA_EPS_M2:
            raise CrossingRoadsError("two roads between junctions would cross outside the junctions "
                                     "(spread the legs or pin the junctions elsewhere)", "layout")


def _junction_polygon(center: np.ndarray, socks: Sequence[SocketGeometry], symmetric: bool = True) -> Polygon:
    """Centrally symmetric hull of the legs' pavement corners: its centroid is the junction centre
    (`symmetric` False, a ramp junction's: their hull, the ramps on one side only)."""
    pts = []
    for g in socks:
        p = np.asarray(g.point)
        for side in (-1.0, 1.0):
            q = p + side * g.half_width * left_normal(g.angle)
            pts.append(q)
            if symmetric:
                pts.append(2 * center - q)
    hull = MultiPoint([tuple(q) for q in pts]).convex_hull
    return orient(hull, 1.0)


def _stop_line(b: _Builder, ins: list[str], cfg: GenerationConfig):
    """Stop line across the incoming lanes at their ends (the socket), pole on the right."""
    w = cfg.lane_width / 2
    right_lane, left_lane = b.lanes[ins[0]], b.lanes[ins[-1]]
    h = float(b.beziers[ins[0]].heading(1.0))
    n_right = -left_normal(h)
    p_right = np.asarray(right_lane["centerline"][-1]) + w * n_right
    p_left = np.asarray(left_lane["centerline"][-1]) - w * n_right
    pos = p_right + cfg.junction_margin * n_right
    return as_polyline([p_right, p_left]), (float(pos[0]), float(pos[1])), positive_angle(h + math.pi)


def _crosswalk_polygon(g: SocketGeometry, junction: Polygon, cfg: GenerationConfig):
    """A strip across the whole leg just inside the socket, clipped to the junction area."""
    d = unit(g.angle)
    nrm = left_normal(g.angle)
    p = np.asarray(g.point)
    near = p - (cfg.junction_margin + cfg.crosswalk_width) * d
    far = p - cfg.junction_margin * d
    hw = g.half_width + cfg.junction_margin
    strip = Polygon([tuple(near - hw * nrm), tuple(far - hw * nrm), tuple(far + hw * nrm), tuple(near + hw * nrm)])
    clipped = strip.intersection(junction)
    return as_polyline(clipped.exterior.coords[:-1])
