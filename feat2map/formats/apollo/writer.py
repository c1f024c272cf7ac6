"""Apollo 7-9 export: base_map, sim_map and routing_map from the map model.

`to_apollo` turns an `HDMap` into an `apollo.hdmap.Map` message (absolute UTM coordinates,
every lane CITY_DRIVING with curves, lengths, widths, links, boundary types; roads with one
section; junctions, signals, stop signs, yield signs, crosswalks; overlaps listed on both sides).
`sim_map.to_sim_map` downsamples it as Apollo's `sim_map_generator` does,
`routing` builds the routing graph, and `write_apollo` writes
the six files Apollo loads from `modules/map/data/<name>/`, all or nothing.
"""
from __future__ import annotations

import math
from pathlib import Path
from typing import Any, Iterable, Mapping, Sequence

import numpy as np
from shapely import STRtree
from shapely.geometry import LineString, Polygon

from ... import __version__, atomic
from .. import FORMATS
from . import schema as aps
from .geometry import (arc_lengths, distance_samples, exact_end_centerline, polygon_range, road_edges,
                       stop_line_range, trimmed_tapers, usable_boundaries, widened_boundaries, without_point_lanes)
from .sim_map import to_sim_map
from ..base import header_date
from ..lane_ends import closed_seams
from ..geo import check_origin, utm_projection
from ...config import (APOLLO_GENERATED_MARK, APOLLO_MIN_HALF_WIDTH_M, APOLLO_SIGNAL_HEAD_SIZE_M, APOLLO_SIGNAL_HEIGHT_M,
                       APOLLO_STOP_LINE_OVERLAP_M, APOLLO_WIDEN_MARGIN_M, APPROACH_SPLIT_DEG, UTM_ORIGIN, UTM_ZONE)
from ...errors import Feat2MapError
from ...model import HDMap, Lane, Polyline, line_end, stop_line_across
from ...validation import refuse_nonfinite

FILES = ("base_map", "sim_map", "routing_map")
BOUNDARY_TYPE = {
    "solid_white": aps.LaneBoundaryType.SOLID_WHITE, "dotted_white": aps.LaneBoundaryType.DOTTED_WHITE,
    "solid_yellow": aps.LaneBoundaryType.SOLID_YELLOW, "dotted_yellow": aps.LaneBoundaryType.DOTTED_YELLOW,
    "curb": aps.LaneBoundaryType.CURB, "virtual": aps.LaneBoundaryType.UNKNOWN,
}
TURN = {"none": aps.Lane.NO_TURN, "left": aps.Lane.LEFT_TURN, "right": aps.Lane.RIGHT_TURN,
        "uturn": aps.Lane.U_TURN}


def stop_sign_types(m: HDMap) -> dict[str | None, int]:
    """Apollo's StopType per junction: ALL_WAY when stop signs govern every lane entering it,
    else ONE_WAY .. FOUR_WAY by the number of its stop signs."""
    governed: dict[str | None, set[str]] = {}
    count: dict[str | None, int] = {}
    for s in m.stop_signs.values():
        governed.setdefault(s.junction_id, set()).update(s.lane_ids)
        count[s.junction_id] = count.get(s.junction_id, 0) + 1
    ways = (aps.StopSign.ONE_WAY, aps.StopSign.TWO_WAY, aps.StopSign.THREE_WAY, aps.StopSign.FOUR_WAY)
    out = {}
    for jid, lanes in governed.items():
        entering = {p for ln in m.lanes_by_junction.get(jid, []) for p in ln.predecessors
                    if p in m.lanes and m.lanes[p].junction_id != jid} if jid is not None else set()
        out[jid] = aps.StopSign.ALL_WAY if entering and entering <= lanes else ways[min(count[jid], 4) - 1]
    return out


# --- Apollo messages ----------------------------------------------------------------------

class _Ids:
    """Apollo ids unique across every element kind: model ids where free, else kind-prefixed."""

    def __init__(self) -> None:
        self.used: set[str] = set()
        self.of: dict[tuple[str, str], str] = {}

    def claim(self, kind: str, model_id: str | None, wanted: str) -> str:
        out = wanted
        if out in self.used or not out:
            out = f"{kind}_{wanted}"
            k = 1
            while out in self.used:
                out = f"{kind}_{wanted}_{k}"
                k += 1
        self.used.add(out)
        if model_id is not None:
            self.of[(kind, model_id)] = out
        return out


class _Frame:
    """Local model metres -> absolute UTM metres."""

    def __init__(self, origin: tuple[float, float]) -> None:
        self.ox, self.oy = float(origin[0]), float(origin[1])

    def fill_points(self, field: Any, points: Iterable[Sequence[float]], z: float | None = None) -> None:
        for p in points:
            q = field.add()
            q.x = p[0] + self.ox
            q.y = p[1] + self.oy
            if z is not None:
                q.z = z

    def fill_curve(self, curve: Any, points: Polyline) -> float:
        """One line segment with s, start position, heading and length; returns the length."""
        pts = np.asarray(points, dtype=float)
        length = float(arc_lengths(pts)[-1])
        seg = curve.segment.add()
        self.fill_points(seg.line_segment.point, pts)
        seg.s = 0.0
        seg.start_position.x = pts[0, 0] + self.ox
        seg.start_position.y = pts[0, 1] + self.oy
        seg.heading = math.atan2(pts[1, 1] - pts[0, 1], pts[1, 0] - pts[0, 0])
        seg.length = length
        return length


def approach_groups(lanes: Mapping[str, Lane], lane_ids: Iterable[str]) -> list[list[str]]:
    """The governed lanes grouped by approach: lanes whose headings at the stop line (`line_end`)
    are within APPROACH_SPLIT_DEG of a group's first lane are one approach (in listed order)."""
    groups: list[list[str]] = []
    for x in lane_ids:
        if x not in lanes:
            continue
        h = line_end(lanes[x])[2]
        for g in groups:
            if math.cos(h - line_end(lanes[g[0]])[2]) > math.cos(math.radians(APPROACH_SPLIT_DEG)):
                g.append(x)
                break
        else:
            groups.append([x])
    return groups


def _lanes_at_line(m: HDMap, centres: Mapping[str, Polyline], x: str, line: Polyline,
                   junction_id: str | None) -> list[str]:
    """The lanes a control's overlaps name for its governed lane `x`: `x` where its stop line
    meets it (within APOLLO_STOP_LINE_OVERLAP_M), else the successors in the control's junction
    that the line meets (San Francisco's SVL map draws some lines a few metres into the junction,
    past the road lane's end, and ties them to those junction lanes), else `x`."""
    stop = LineString(line)
    if stop.distance(LineString(centres[x])) <= APOLLO_STOP_LINE_OVERLAP_M:
        return [x]
    ahead = [y for y in m.lanes[x].successors if junction_id is not None and y in m.lanes
             and m.lanes[y].junction_id == junction_id
             and stop.distance(LineString(centres[y])) <= APOLLO_STOP_LINE_OVERLAP_M]
    return ahead or [x]


def _add_stop_line(msg: Any, frame: _Frame, line: Polyline) -> None:
    """One stop line (Apollo's `stop_line` is a repeated Curve on signals and stop signs)."""
    frame.fill_curve(msg.stop_line.add(), line)


def _signal_boundary(position: tuple[float, float], heading: float) -> list[tuple[float, float, float]]:
    """The light head's face: a vertical rectangle at the pole, facing `heading`."""
    w, h = APOLLO_SIGNAL_HEAD_SIZE_M
    nx, ny = -math.sin(heading) * w / 2, math.cos(heading) * w / 2
    x, y = position
    z0, z1 = APOLLO_SIGNAL_HEIGHT_M - h / 2, APOLLO_SIGNAL_HEIGHT_M + h / 2
    return [(x - nx, y - ny, z1), (x + nx, y + ny, z1), (x + nx, y + ny, z0), (x - nx, y - ny, z0)]


def to_apollo(m: HDMap, *, zone: int = UTM_ZONE, origin: tuple[float, float] | None = None) -> Any:
    """The Apollo `Map` of `m`. `origin` is the UTM position of the model's (0, 0); by default
    `m.origin` when set, else `config.UTM_ORIGIN`."""
    if not isinstance(zone, int) or isinstance(zone, bool) or not 1 <= zone <= 60:
        raise Feat2MapError(f"UTM zone must be an integer 1..60, got {zone!r}", "apollo export")
    if origin is None:
        origin = m.origin if any(m.origin) else UTM_ORIGIN  # checked (two numbers) just below
    origin = check_origin(origin, "apollo export: origin")
    m = widened_boundaries(usable_boundaries(trimmed_tapers(closed_seams(without_point_lanes(m)))))
    frame = _Frame(origin)
    ids = _Ids()
    out = aps.Map()
    _header(out.header, m, zone)

    # junctions claim their ids first: where an OpenDRIVE map's road and junction share an id, the
    # junction keeps it (extraction, suites and reports name junctions), the road takes road_<id>
    for kind, table in (("junction", m.junctions), ("lane", m.lanes), ("road", m.roads), ("signal", m.signals),
                        ("stop_sign", m.stop_signs), ("yield_sign", m.yield_signs), ("crosswalk", m.crosswalks)):
        for key in table:
            ids.claim(kind, key, key)
    lid = {k: ids.of[("lane", k)] for k in m.lanes}

    centres = {ln.id: exact_end_centerline(ln) for ln in m.lanes.values()}  # as exported
    lanes: dict[str, Any] = {}
    for ln in m.lanes.values():
        lanes[ln.id] = _lane(out.lane.add(), m, ln, centres[ln.id], frame, lid, ids)
    for r in m.roads.values():
        road = out.road.add()
        road.id.id = ids.of[("road", r.id)]
        road.type = aps.Road.CITY_ROAD
        jid = r.junction_id or next((m.lanes[x].junction_id for x in r.lane_ids if x in m.lanes
                                     and m.lanes[x].junction_id), None)
        if jid is not None and jid in m.junctions:
            road.junction_id.id = ids.of[("junction", jid)]
        sec = road.section.add()
        sec.id.id = ids.claim("section", None, f"{road.id.id}_section")
        for x in r.lane_ids:
            if x in m.lanes:
                sec.lane_id.add(id=lid[x])
        _section_boundary(sec, m, r, frame)
    junctions: dict[str, Any] = {}
    for j in m.junctions.values():
        msg = junctions[j.id] = out.junction.add()
        msg.id.id = ids.of[("junction", j.id)]
        frame.fill_points(msg.polygon.point, j.polygon)

    overlaps = _Overlaps(out, ids)

    def control_overlaps(msg: Any, c: Any, info: str) -> None:
        """Stop lines, and overlaps with the incoming lanes at their line and with the junction:
        one line per approach when a control governs lanes of several (a RoadRunner light
        referenced from two opposite roads), where the model's one line runs between them."""
        groups = approach_groups(m.lanes, c.lane_ids)
        lines = [c.stop_line] if len(groups) < 2 else [stop_line_across(m.lanes, g) or c.stop_line for g in groups]
        line_of = {x: line for g, line in zip(groups, lines) for x in g} if len(groups) > 1 else {}
        for line in lines:
            _add_stop_line(msg, frame, line)
        for x in c.lane_ids:
            if x in m.lanes:
                line = line_of.get(x, c.stop_line)
                for y in _lanes_at_line(m, centres, x, line, c.junction_id):
                    overlaps.add(lanes[y], "lane_overlap_info", stop_line_range(centres[y], line), msg, info)
        if c.junction_id in junctions:
            overlaps.add(junctions[c.junction_id], "junction_overlap_info", None, msg, info)

    for s in m.signals.values():
        msg = out.signal.add()
        msg.id.id = ids.of[("signal", s.id)]
        msg.type = aps.Signal.MIX_3_VERTICAL
        for bx, by, bz in _signal_boundary(s.position, s.heading):
            p = msg.boundary.point.add()
            p.x, p.y, p.z = bx + frame.ox, by + frame.oy, bz
        _, h = APOLLO_SIGNAL_HEAD_SIZE_M
        for k, dz in enumerate((h / 3, 0.0, -h / 3)):  # red, yellow, green from the top
            sub = msg.subsignal.add()
            sub.id.id = str(k)
            sub.type = aps.Subsignal.CIRCLE
            sub.location.x, sub.location.y = s.position[0] + frame.ox, s.position[1] + frame.oy
            sub.location.z = APOLLO_SIGNAL_HEIGHT_M + dz
        control_overlaps(msg, s, "signal_overlap_info")
    stop_types = stop_sign_types(m)
    for stop in m.stop_signs.values():
        msg = out.stop_sign.add()
        msg.id.id = ids.of[("stop_sign", stop.id)]
        msg.type = stop_types.get(stop.junction_id, aps.StopSign.UNKNOWN)
        control_overlaps(msg, stop, "stop_sign_overlap_info")
    for yld in m.yield_signs.values():
        msg = getattr(out, "yield").add()
        msg.id.id = ids.of[("yield_sign", yld.id)]
        control_overlaps(msg, yld, "yield_sign_overlap_info")
    for ln in m.lanes.values():
        if ln.junction_id in junctions:
            overlaps.add(lanes[ln.id], "lane_overlap_info", (0.0, lanes[ln.id].length),
                         junctions[ln.junction_id], "junction_overlap_info")
    if m.crosswalks:
        lane_list = list(m.lanes.values())
        tree = STRtree([LineString(centres[ln.id]) for ln in lane_list])
        for c in m.crosswalks.values():
            msg = out.crosswalk.add()
            msg.id.id = ids.of[("crosswalk", c.id)]
            frame.fill_points(msg.polygon.point, c.polygon)
            for k in sorted(tree.query(Polygon(c.polygon), predicate="intersects")):
                ln = lane_list[k]
                rng = polygon_range(centres[ln.id], c.polygon)
                if rng is not None:
                    overlaps.add(lanes[ln.id], "lane_overlap_info", rng, msg, "crosswalk_overlap_info")
    return out


def _header(h: Any, m: HDMap, zone: int) -> None:
    h.version = f"feat2map {__version__}".encode()
    date = header_date()
    if date is not None:
        h.date = date.encode()
    h.projection.proj = utm_projection(zone)
    h.district = b"feat2map"
    h.vendor = b"feat2map"
    if m.meta.get("generator"):  # generated, not converted: the validator holds it to check_map's rules too
        h.generation = APOLLO_GENERATED_MARK
    h.rev_major = b"1"
    h.rev_minor = b"0"


def _lane(msg: Any, m: HDMap, ln: Lane, centre: Polyline, frame: _Frame, lid: dict[str, str], ids: _Ids) -> Any:
    msg.id.id = lid[ln.id]
    msg.type = aps.Lane.CITY_DRIVING
    msg.direction = aps.Lane.FORWARD
    msg.turn = TURN.get(ln.turn, aps.Lane.NO_TURN)
    msg.speed_limit = float(ln.speed_limit)
    msg.length = frame.fill_curve(msg.central_curve, centre)
    for side, pts, kind in (("left", ln.left_boundary, ln.left_boundary_type),
                            ("right", ln.right_boundary, ln.right_boundary_type)):
        b = getattr(msg, f"{side}_boundary")
        b.length = frame.fill_curve(b.curve, pts)
        b.virtual = kind == "virtual" or ln.junction_id is not None  # no painted line in a junction
        bt = b.boundary_type.add()
        bt.s = 0.0
        bt.types.append(BOUNDARY_TYPE.get(kind, aps.LaneBoundaryType.UNKNOWN))
    for field, refs in (("predecessor_id", ln.predecessors), ("successor_id", ln.successors),
                        ("left_neighbor_forward_lane_id", ln.left_neighbors),
                        ("right_neighbor_forward_lane_id", ln.right_neighbors),
                        ("left_neighbor_reverse_lane_id", ln.left_reverse_neighbors)):
        for x in refs:
            if x in lid:
                getattr(msg, field).add(id=lid[x])
    if ln.junction_id is not None and ln.junction_id in m.junctions:
        msg.junction_id.id = ids.of[("junction", ln.junction_id)]
    for field, edge in (("left_sample", ln.left_boundary), ("right_sample", ln.right_boundary)):
        _samples(getattr(msg, field), centre, edge, msg.length, APOLLO_MIN_HALF_WIDTH_M + APOLLO_WIDEN_MARGIN_M)
    left, right = road_edges(m, ln)
    _samples(msg.left_road_sample, centre, left, msg.length)
    _samples(msg.right_road_sample, centre, right, msg.length)
    return msg


def _samples(field: Any, centerline: Polyline, edge: Polyline, length: float, floor: float = 0.0) -> None:
    """Width samples from `centerline` to `edge`, at least `floor`: a side widened for Apollo
    (widened_boundaries) that still measures narrower, because offsetting it round a bend tighter
    than the offset folds it back, is written at the floor Apollo holds (its warning named it)."""
    for s, w in distance_samples(centerline, edge):
        field.add(s=min(s, length), width=max(w, floor))


def _section_boundary(sec: Any, m: HDMap, r: Any, frame: _Frame) -> None:
    """Outer polygon of a section: its left and right edges along the road's first lane."""
    first = next((m.lanes[x] for x in r.lane_ids if x in m.lanes), None)
    if first is None:
        return
    left, right = road_edges(m, first)
    for kind, pts in ((aps.BoundaryEdge.LEFT_BOUNDARY, left), (aps.BoundaryEdge.RIGHT_BOUNDARY, right)):
        edge = sec.boundary.outer_polygon.edge.add()
        edge.type = kind
        frame.fill_curve(edge.curve, pts)


class _Overlaps:
    """Overlap messages with two objects, each object listing the overlap's id."""

    def __init__(self, out: Any, ids: _Ids) -> None:
        self.out, self.ids = out, ids

    def add(self, a: Any, a_info: str, a_range: tuple[float, float] | None, b: Any, b_info: str) -> None:
        ov = self.out.overlap.add()
        ov.id.id = self.ids.claim("overlap", None, f"overlap_{b.id.id}_{a.id.id}")
        for obj, info, rng in ((a, a_info, a_range), (b, b_info, None)):
            o = ov.object.add()
            o.id.id = obj.id.id
            getattr(o, info).SetInParent()
            if rng is not None:
                getattr(o, info).start_s, getattr(o, info).end_s = float(rng[0]), float(rng[1])
            obj.overlap_id.add(id=ov.id.id)


# --- files --------------------------------------------------------------------------------

def text_of(msg: Any) -> str:
    """Protobuf text format of `msg` from protobuf's C encoder (about twice as fast as
    `text_format`; doubles in round-trip precision, enums by name), newline-terminated."""
    text = str(msg)
    return text if text.endswith("\n") or not text else text + "\n"


def refuse_invalid(base: Any, graph: Any, out_dir: str | Path, skipped: int = 0) -> None:
    """Before anything is written, the lanes of every map must pass `feat2map validate`'s lane
    checks (links that exist, are listed back and meet, lengths, types): an input edited into
    a broken map (a junction-lane cycle, a self-link, a zero-length lane) is refused with its
    first problem named, instead of written for validate to reject. A map feat2map generated
    (its header says so), and a map whose reading `skipped` broken elements (links to a missing
    road), is held to every rule validate applies; converted real maps keep their own flaws of
    routing and signals (validate reports them). The refusal leads with the first problem."""
    from .validate import _Index, _lanes, validate_map

    whole = skipped > 0 or base.header.generation == APOLLO_GENERATED_MARK
    problems = validate_map(base, graph) if whole else _lanes(base, _Index(base), False)
    if problems:
        why = f"; every rule applies: reading skipped {skipped} broken element(s)" if skipped else ""
        raise Feat2MapError(f"refusing to export a map that would not validate: {problems[0]} "
                            f"({len(problems)} problem(s){why})", str(out_dir))


def write_apollo(m: HDMap, out_dir: str | Path, *, zone: int = UTM_ZONE,
                 origin: tuple[float, float] | None = None, progress: bool = False) -> None:
    """Write base_map, sim_map and routing_map (.txt and .bin each) into `out_dir`, all or
    nothing; `progress` shows a tqdm bar over the stages (big maps take a while)."""
    from tqdm import tqdm

    from .routing import build_routing_graph

    with tqdm(total=6, desc="apollo export", unit="step", disable=None if progress else True) as bar:
        bar.set_postfix_str("base_map")
        base = to_apollo(m, zone=zone, origin=origin)
        bar.update()
        bar.set_postfix_str("sim_map")
        messages = {"base_map": base, "sim_map": to_sim_map(base)}
        bar.update()
        bar.set_postfix_str("routing_map")
        messages["routing_map"] = build_routing_graph(base)
        bar.update()
        refuse_invalid(base, messages["routing_map"], out_dir, skipped=int(m.meta.get("skipped_on_read", 0)))
        texts = {name: refuse_nonfinite(text_of(msg), f"{out_dir}: {name}") for name, msg in messages.items()}
        try:
            with atomic.staged_dir(out_dir, FORMATS["apollo"].markers) as tmp:
                for name, msg in messages.items():
                    bar.set_postfix_str(f"{name}.bin/.txt")
                    atomic.write_bytes(tmp / f"{name}.bin", msg.SerializeToString())
                    atomic.write_text(tmp / f"{name}.txt", texts[name])
                    bar.update()
        except OSError as exc:
            raise Feat2MapError(f"cannot write the Apollo map ({exc.strerror or exc})", str(out_dir)) from None
