"""Checks that an Apollo map folder loads, routes and plans in Apollo 7-9.

`validate_apollo(path)` takes a map folder (base_map, sim_map, routing_map as .bin/.txt) or a
single map file and returns every `Problem` found: lane completeness (CITY_DRIVING, curves,
lengths, speed, turn, direction, samples, boundary types), symmetric links and neighbours,
road sections, junction/crosswalk polygons, signals and stop signs, overlaps (both sides,
s ranges, at the stop line, whole junction lanes, crosswalks over centrelines), ids unique
across kinds, references, the UTM header, sim_map/routing_map consistency with the base map,
`.txt` == `.bin`, and reachability over the routing graph when every road is two-way. A
file named sim_map is checked by sim_map rules (`validate_map`).
"""
from __future__ import annotations

import math
import re
from collections import Counter, deque
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
import shapely
from shapely import STRtree
from shapely.geometry import LineString, Point, Polygon

from . import schema as aps
from ..base import Problem
from .reader import base_map_file
from .routing import build_routing_graph
from ...config import (APOLLO_GENERATED_MARK, APOLLO_MIN_HALF_WIDTH_M, APOLLO_STOP_LINE_OVERLAP_M, UTM_EASTING,
                      UTM_NORTHING)
from ...errors import MapFormatError
from ...invariants import AREA_EPS_M2, unreached_exits
from ...validation import unusable_numbers

LENGTH_TOL_M = 0.05  # recorded lengths vs. the polyline's; endpoints of linked lanes
LINK_TOL_M = 0.1  # successor starts where its predecessor ends
SAMPLE_END_TOL_M = 0.5  # width samples reach s = 0 and s = length
STOP_LINE_TOL_M = 1.0  # an overlap's s range lies this close to where the stop line crosses the lane
CROSSWALK_TOL_M = 0.5  # crosswalk overlap ranges vs. the polygon's cover of the centreline
COST_TOL = 1e-6
MAX_SPEED_MPS = 50.0  # a larger "speed limit" is likely km/h or mph

_INFO_KIND = {"lane_overlap_info": "lane", "signal_overlap_info": "signal", "stop_sign_overlap_info": "stop_sign",
              "crosswalk_overlap_info": "crosswalk", "junction_overlap_info": "junction",
              "yield_sign_overlap_info": "yield", "clear_area_overlap_info": "clear_area",
              "speed_bump_overlap_info": "speed_bump", "parking_space_overlap_info": "parking_space",
              "pnc_junction_overlap_info": "pnc_junction", "rsu_overlap_info": "rsu"}
_KINDS = ("lane", "road", "junction", "signal", "stop_sign", "crosswalk", "overlap", "yield", "clear_area",
          "speed_bump", "parking_space", "pnc_junction", "rsu")


# --- loading --------------------------------------------------------------------------------

def _read(path: Path) -> bytes:
    try:
        return path.read_bytes()
    except OSError as exc:
        raise MapFormatError(f"cannot read ({exc.strerror})", str(path)) from None


def _pair(folder: Path, name: str, parse: Any) -> tuple[Any | None, list[Problem]]:
    """The message in folder/name.bin (else .txt); a problem when both exist and differ."""
    found = {ext: folder / f"{name}.{ext}" for ext in ("bin", "txt") if (folder / f"{name}.{ext}").is_file()}
    if not found:
        return None, []
    if "bin" not in found:
        return parse(_read(found["txt"]), str(found["txt"])), []
    msg = parse(_read(found["bin"]), str(found["bin"]))
    if "txt" not in found:
        return msg, []
    txt = _read(found["txt"])
    # fast path: the text is exactly what protobuf prints for the binary message (our writer);
    # otherwise (other tools' formatting) parse it and compare messages
    if txt.rstrip(b"\n") != str(msg).encode("utf-8").rstrip(b"\n") and parse(txt, str(found["txt"])) != msg:
        return msg, [Problem(f"file {name}", f"{name}.txt and {name}.bin hold different messages")]
    return msg, []


def load_base_map(path: str | Path) -> Any:
    """The base map of a map folder (base_map.bin, else .txt), or the map in a single file."""
    path = base_map_file(path)
    return aps.parse_map(_read(path), str(path))


def is_sim_map_file(path: str | Path) -> bool:
    """Apollo's name for the sim_map_generator output: sim_map.bin / sim_map.txt."""
    return Path(path).stem == "sim_map"


def validate_apollo(path: str | Path, progress: bool = False, sim: bool | None = None) -> list[Problem]:
    """Every problem of the Apollo map folder (or single map file) at `path`; `progress`
    shows a tqdm bar over the checks. A single file is checked by sim_map rules when `sim`
    says so, by default when it is named sim_map (`validate_map`).

    Raises MapFormatError for a missing path, a folder without base_map, or files that are
    not Apollo maps (corrupt, truncated).
    """
    path = Path(path)
    if path.is_file():
        sim = is_sim_map_file(path) if sim is None else sim
        found = validate_map(aps.parse_map(_read(path), str(path)), progress=progress, sim=sim)
        return found if sim else found + reader_problems(path)
    if not path.is_dir():
        raise MapFormatError("no such map folder or file", str(path))
    base, problems = _pair(path, "base_map", aps.parse_map)
    if base is None:
        raise MapFormatError("no base_map.bin or base_map.txt in this folder", str(path))
    sim, p_sim = _pair(path, "sim_map", aps.parse_map)
    graph, p_graph = _pair(path, "routing_map", aps.parse_graph)
    problems += p_sim + p_graph
    problems += validate_map(base, graph, progress=progress)
    if sim is None:
        problems.append(Problem("file sim_map", "missing sim_map.bin/.txt (Dreamview shows no map without it)"))
    else:
        problems += check_sim_map(base, sim)
    if graph is None:
        problems.append(Problem("file routing_map", "missing routing_map.bin/.txt (routing cannot start)"))
    else:
        problems += check_routing_map(base, graph)
    return problems + reader_problems(path)


def reader_problems(path: Path) -> list[Problem]:
    """What feat2map's reader skips or its load-time semantic checks (feat2map.semantics) find
    in the base map at `path`, one Problem each."""
    import warnings

    from ...errors import Feat2MapError, RepairWarning
    from .reader import base_map_file, read_apollo

    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            read_apollo(path)
        except Feat2MapError as exc:
            return [Problem(base_map_file(path).name, f"feat2map reader: {exc}")]
    return [Problem(base_map_file(path).name, f"feat2map reader: {w.message}", warning=issubclass(w.category, RepairWarning))
            for w in caught]


# --- helpers --------------------------------------------------------------------------------

def _xy(points: Iterable[Any]) -> np.ndarray:
    return np.asarray([(p.x, p.y) for p in points], dtype=float).reshape(-1, 2)


def _curve_points(curve: Any) -> np.ndarray:
    return np.concatenate([_xy(seg.line_segment.point) for seg in curve.segment] or [np.zeros((0, 2))])


def _unset_points(m: Any) -> list[Problem]:
    """Elements with a point whose x or y is missing: Apollo's PointENU defaults a missing
    coordinate to NaN, which the text check cannot see (unset fields are not written)."""
    out = []
    for kind in _KINDS:
        fields = getattr(m, kind)
        if not fields:
            continue
        names = fields[0].DESCRIPTOR.fields_by_name
        for e in fields:
            pieces = [_xy(e.polygon.point)] if "polygon" in names else []
            if kind == "lane":
                pieces += [_curve_points(c) for c in (e.central_curve, e.left_boundary.curve, e.right_boundary.curve)]
            if "stop_line" in names:
                pieces += [_curve_points(c) for c in e.stop_line]
            if not all(np.isfinite(p).all() for p in pieces):
                out.append(Problem(f"{kind} {e.id.id}", "a point has no x or y (a missing coordinate reads as NaN)"))
    return out


def _polyline_length(pts: np.ndarray) -> float:
    return float(np.hypot(*np.diff(pts, axis=0).T).sum()) if len(pts) > 1 else 0.0


def _distinct(pts: np.ndarray) -> int:
    """Number of distinct points (to 0.1 mm), counted up to 3 (all the checks need)."""
    if len(pts) < 2:
        return len(pts)
    d0 = np.abs(pts - pts[0]).max(axis=1) > 1e-4
    if not d0.any():
        return 1
    second = pts[int(np.argmax(d0))]
    d1 = np.abs(pts - second).max(axis=1) > 1e-4
    return 3 if (d0 & d1).any() else 2


class _Index:
    """Elements by kind and id, for references."""

    def __init__(self, m: Any) -> None:
        self.by_kind: dict[str, dict[str, Any]] = {}
        for kind in _KINDS:
            self.by_kind[kind] = {e.id.id: e for e in getattr(m, kind)}
        self.lanes = self.by_kind["lane"]


# --- the base map ---------------------------------------------------------------------------

def validate_map(m: Any, graph: Any | None = None, progress: bool = False, sim: bool = False) -> list[Problem]:
    """Every problem of one Apollo `Map` (reachability over `graph`, else the graph Apollo
    would build from `m`).

    `sim`: check it by sim_map rules. Apollo's sim_map_generator clears every width and road
    sample and thins the curves' points but keeps the base map's segment lengths and overlap s
    ranges, so a sim_map needs no samples, a segment length may exceed its thinned polyline's
    (never fall short of it: thinning only shortens), and crosswalk overlaps are not measured
    against the thinned centrelines. Everything else is checked as for a base map."""
    from tqdm import tqdm

    bad = [Problem(element, f"unusable number {value} (text line {line}): NaN, infinite or >= 1e9")
           for value, element, line in unusable_numbers(str(m))]
    bad += _unset_points(m)
    if bad:  # the geometric checks below need finite coordinates
        return bad
    idx = _Index(m)
    checks = [("header", lambda: _header(m) + _ids(m)), ("lanes", lambda: _lanes(m, idx, sim)),
              ("roads", lambda: _roads(m, idx) + _areas(m)), ("signals", lambda: _controls(m, idx)),
              ("overlaps", lambda: _overlaps(m, idx) + ([] if sim else _crosswalk_cover(m, idx))),
              ("conflicts", lambda: _conflicts(m, idx) + _dead_ends(m, idx) if _generated(m) else []),
              ("reachability", lambda: reachability(m, graph if graph is not None else build_routing_graph(m)))]
    problems: list[Problem] = []
    with tqdm(checks, desc="validate", unit="check", disable=None if progress else True) as bar:
        for name, check in bar:
            bar.set_postfix_str(name)
            problems += check()
    return problems


def _header(m: Any) -> list[Problem]:
    out = []
    proj = m.header.projection.proj
    zone = re.search(r"\+zone=(\d+)", proj)
    if not proj.startswith("+proj=utm") or zone is None or not 1 <= int(zone.group(1)) <= 60:
        out.append(Problem("header", f"projection must be '+proj=utm +zone=N ...', got {proj!r}"))
    pts = [p for ln in m.lane[:50] for seg in ln.central_curve.segment for p in seg.line_segment.point[:1]]
    if pts and not all(UTM_EASTING[0] <= p.x <= UTM_EASTING[1] and UTM_NORTHING[0] <= p.y <= UTM_NORTHING[1]
                       for p in pts):
        out.append(Problem("header", "lane coordinates are not absolute UTM metres (easting 1e5..9e5, "
                                     "northing 0..1e7)"))
    return out


def _ids(m: Any) -> list[Problem]:
    out = []
    seen: dict[str, str] = {}
    for kind in _KINDS:
        for e in getattr(m, kind):
            i = e.id.id
            if not i:
                out.append(Problem(f"{kind} (no id)", "element has an empty id"))
                continue
            if i in seen:
                out.append(Problem(f"{kind} {i}", f"id is also used by a {seen[i]}"))
            else:
                seen[i] = kind
    return out


def _check_curve(name: str, curve: Any, where: str, sim: bool = False) -> list[Problem]:
    out = []
    if not curve.segment:
        return [Problem(where, f"{name} has no segment")]
    for k, seg in enumerate(curve.segment):
        pts = _xy(seg.line_segment.point)
        if not seg.HasField("line_segment") or _distinct(pts) < 2:
            out.append(Problem(where, f"{name} segment {k} needs a line segment of >= 2 distinct points"))
            continue
        if not seg.HasField("length"):
            out.append(Problem(where, f"{name} segment {k} has no length"))
        elif (_polyline_length(pts) - seg.length if sim else abs(seg.length - _polyline_length(pts))) > \
                LENGTH_TOL_M + 1e-3 * seg.length:
            out.append(Problem(where, f"{name} segment {k} length {seg.length:.3f} != its polyline's "
                                      f"{_polyline_length(pts):.3f}"))
    return out


def _check_samples(name: str, samples: Any, length: float, where: str, min_width: float) -> list[Problem]:
    if not samples:
        return [Problem(where, f"no {name}")]
    s = [x.s for x in samples]
    out = []
    if abs(s[0]) > SAMPLE_END_TOL_M or abs(s[-1] - length) > SAMPLE_END_TOL_M or any(b < a for a, b in zip(s, s[1:])):
        out.append(Problem(where, f"{name} must run from s=0 to s=length ({length:.2f}) in order, "
                                  f"got {s[0]:.2f}..{s[-1]:.2f}"))
    low = min(x.width for x in samples)
    if low < min_width:
        out.append(Problem(where, f"{name} width {low:.3f} m is below {min_width} m"))
    return out


def _lanes(m: Any, idx: _Index, sim: bool = False) -> list[Problem]:
    out: list[Problem] = []
    in_sections = Counter(lid.id for road in m.road for sec in road.section for lid in sec.lane_id)
    lanes = idx.lanes
    for ln in m.lane:
        w = f"lane {ln.id.id}"
        if not ln.HasField("type"):
            out.append(Problem(w, "type not set (the default NONE drops the lane from routing)"))
        elif ln.type != aps.Lane.CITY_DRIVING:
            out.append(Problem(w, f"type {aps.Lane.LaneType.Name(ln.type)} is not CITY_DRIVING (no routing)"))
        out += _check_curve("central_curve", ln.central_curve, w, sim)
        for side in ("left_boundary", "right_boundary"):
            b = getattr(ln, side)
            if not ln.HasField(side):
                out.append(Problem(w, f"no {side}"))
                continue
            out += _check_curve(f"{side} curve", b.curve, w, sim)
            if not b.HasField("length") or b.length <= 0:
                out.append(Problem(w, f"{side} length not set"))
            if not b.boundary_type:
                out.append(Problem(w, f"{side} has no boundary_type"))
            for bt in b.boundary_type:
                if not bt.types:
                    out.append(Problem(w, f"{side} boundary_type at s={bt.s:g} has empty types"))
        centre_len = sum(seg.length for seg in ln.central_curve.segment)
        if not ln.HasField("length"):
            out.append(Problem(w, "length not set"))
        elif abs(ln.length - centre_len) > LENGTH_TOL_M + 1e-3 * centre_len:
            out.append(Problem(w, f"length {ln.length:.3f} != central curve length {centre_len:.3f}"))
        if not ln.HasField("speed_limit") or not 0 < ln.speed_limit <= MAX_SPEED_MPS:
            out.append(Problem(w, f"speed_limit must be set in m/s (0, {MAX_SPEED_MPS:g}], got "
                                  f"{ln.speed_limit if ln.HasField('speed_limit') else 'none'}"))
        if not ln.HasField("turn"):
            out.append(Problem(w, "turn not set"))
        if not ln.HasField("direction"):
            out.append(Problem(w, "direction not set"))
        length = ln.length if ln.HasField("length") else centre_len
        for name, low in (("left_sample", APOLLO_MIN_HALF_WIDTH_M), ("right_sample", APOLLO_MIN_HALF_WIDTH_M),
                          ("left_road_sample", 0.0), ("right_road_sample", 0.0)):
            if not (sim and not getattr(ln, name)):  # sim_map_generator clears them
                out += _check_samples(name, getattr(ln, name), length, w, low)
        if in_sections[ln.id.id] != 1:
            out.append(Problem(w, f"listed in {in_sections[ln.id.id]} road sections (must be exactly 1)"))
        out += _links(ln, lanes, w)
        if ln.HasField("junction_id") and ln.junction_id.id not in idx.by_kind["junction"]:
            out.append(Problem(w, f"junction_id {ln.junction_id.id} does not exist"))
        for o in ln.overlap_id:
            if o.id not in idx.by_kind["overlap"]:
                out.append(Problem(w, f"overlap_id {o.id} does not exist"))
    return out


def _links(ln: Any, lanes: dict[str, Any], w: str) -> list[Problem]:
    out = []
    end = _curve_points(ln.central_curve)
    mirror = {"predecessor_id": "successor_id", "successor_id": "predecessor_id",
              "left_neighbor_forward_lane_id": "right_neighbor_forward_lane_id",
              "right_neighbor_forward_lane_id": "left_neighbor_forward_lane_id",
              "left_neighbor_reverse_lane_id": "left_neighbor_reverse_lane_id",
              "right_neighbor_reverse_lane_id": "right_neighbor_reverse_lane_id"}
    for field, back in mirror.items():
        for ref in getattr(ln, field):
            other = lanes.get(ref.id)
            if other is None:
                out.append(Problem(w, f"{field} {ref.id} does not exist"))
                continue
            if ln.id.id not in {x.id for x in getattr(other, back)}:
                out.append(Problem(w, f"{field} {ref.id} does not list it back in {back}"))
            if field in ("successor_id", "predecessor_id") and len(end):
                o = _curve_points(other.central_curve)
                if len(o):
                    a, b = (end[-1], o[0]) if field == "successor_id" else (end[0], o[-1])
                    gap = math.dist(a, b)
                    if gap > LINK_TOL_M:
                        out.append(Problem(w, f"{field} {ref.id} does not meet it ({gap:.2f} m apart)"))
    return out


def _roads(m: Any, idx: _Index) -> list[Problem]:
    out = []
    junction_lanes = _junction_lanes(m, idx)
    for road in m.road:
        w = f"road {road.id.id}"
        if not road.section:
            out.append(Problem(w, "has no section"))
        ids = [lid.id for sec in road.section for lid in sec.lane_id]
        for lid in ids:
            if lid not in idx.lanes:
                out.append(Problem(w, f"section lane {lid} does not exist"))
        if road.HasField("junction_id"):
            if road.junction_id.id not in idx.by_kind["junction"]:
                out.append(Problem(w, f"junction_id {road.junction_id.id} does not exist"))
        elif ids and all(lid in junction_lanes for lid in ids):
            out.append(Problem(w, f"lies inside junction {junction_lanes[ids[0]]} but has no junction_id"))
    return out


def _junction_lanes(m: Any, idx: _Index) -> dict[str, str]:
    """Lane id -> junction id for lanes inside a junction: junction_id, or a junction overlap
    covering the whole lane."""
    out = {ln.id.id: ln.junction_id.id for ln in m.lane if ln.HasField("junction_id")}
    for ov in m.overlap:
        kinds = {o.WhichOneof("overlap_info"): o for o in ov.object}
        lane, junction = kinds.get("lane_overlap_info"), kinds.get("junction_overlap_info")
        if lane is None or junction is None or lane.id.id not in idx.lanes:
            continue
        info = lane.lane_overlap_info
        if info.start_s <= LENGTH_TOL_M and info.end_s >= idx.lanes[lane.id.id].length - LENGTH_TOL_M:
            out.setdefault(lane.id.id, junction.id.id)
    return out


def _generated(m: Any) -> bool:
    """A map feat2map generated (not converted) also keeps feat2map's own promises (invariants.
    check_map): no roads crossing without a junction, no overlapping crosswalks, no lane ending
    at a junction without a way on. Apollo does not need them, and real maps break them."""
    return m.header.generation == APOLLO_GENERATED_MARK


def _in_junction(m: Any, idx: _Index) -> dict[str, str]:
    """Lane id -> junction id: junction lanes and the lanes of junction roads."""
    out = _junction_lanes(m, idx)
    for r in m.road:
        if r.junction_id.id:
            out.update((x.id, r.junction_id.id) for sec in r.section for x in sec.lane_id if x.id not in out)
    return out


def _conflicts(m: Any, idx: _Index) -> list[Problem]:
    """Roads that cross without a junction (as check_map sees them): a lane outside
    junctions sharing area, outside every junction polygon, with a lane it is not linked to
    (neighbours, predecessors, successors, or lanes that split from or merge into the same
    lane); and junctions or crosswalks that share area."""
    inside = _in_junction(m, idx)
    links: dict[str, set[str]] = {}
    for ln in m.lane:
        lid = ln.id.id
        group = {x.id for f in ("predecessor_id", "successor_id", "left_neighbor_forward_lane_id",
                                "right_neighbor_forward_lane_id", "left_neighbor_reverse_lane_id",
                                "right_neighbor_reverse_lane_id") for x in getattr(ln, f)}
        links.setdefault(lid, set()).update(group)
        for f in ("predecessor_id", "successor_id"):  # siblings: they split from / merge into one lane
            sib = [x.id for x in getattr(ln, f)]
            for other in (idx.lanes.get(x) for x in sib):
                if other is not None:
                    back = "successor_id" if f == "predecessor_id" else "predecessor_id"
                    links[lid].update(x.id for x in getattr(other, back))
    junctions = [Polygon(_xy(j.polygon.point)).buffer(0.01) for j in m.junction if _distinct(_xy(j.polygon.point)) >= 3]
    cover = STRtree(junctions)  # a lane loses the area of the junctions it touches, not a union of all
    ids, polys = [], []
    for ln in m.lane:
        left, right = _curve_points(ln.left_boundary.curve), _curve_points(ln.right_boundary.curve)
        if ln.id.id in inside or len(left) < 2 or len(right) < 2:
            continue
        poly = Polygon(np.vstack([left, right[::-1]])).buffer(0)
        near = cover.query(poly, predicate="intersects")
        if len(near):
            poly = poly.difference(shapely.union_all([junctions[i] for i in near]))
        if not poly.is_empty:
            ids.append(ln.id.id)
            polys.append(poly)
    out = []
    pairs = STRtree(polys).query(polys, predicate="intersects") if polys else ((), ())
    for a, b in zip(*pairs):
        if a < b and ids[b] not in links.get(ids[a], ()) and ids[a] not in links.get(ids[b], ()) \
                and polys[a].intersection(polys[b]).area > AREA_EPS_M2:
            out.append(Problem(f"lane {ids[a]}", f"shares area with lane {ids[b]} outside any junction "
                                                 "(roads cross without a junction)"))
    for kind in ("junction", "crosswalk"):  # areas of one kind never share area
        areas = [(e.id.id, Polygon(_xy(e.polygon.point)).buffer(0)) for e in getattr(m, kind)
                 if _distinct(_xy(e.polygon.point)) >= 3]
        shapes = [p for _, p in areas]
        for a, b in zip(*(STRtree(shapes).query(shapes, predicate="intersects") if shapes else ((), ()))):
            if a < b and shapes[a].intersection(shapes[b]).area > AREA_EPS_M2:
                out.append(Problem(f"{kind} {areas[a][0]}", f"shares area with {kind} {areas[b][0]}"))
    return out


def _dead_ends(m: Any, idx: _Index) -> list[Problem]:
    """Lanes outside junctions that end at a junction with nothing to drive on to (or start at
    one with nothing leading in): such a lane would otherwise pass for a map exit (entry)."""
    inside = _in_junction(m, idx)
    polys = [(j.id.id, Polygon(_xy(j.polygon.point)).buffer(0)) for j in m.junction
             if _distinct(_xy(j.polygon.point)) >= 3]
    if not polys:
        return []
    tree = STRtree([p for _, p in polys])
    out = []
    for ln in m.lane:
        if ln.id.id in inside or (ln.successor_id and ln.predecessor_id):
            continue
        pts = _curve_points(ln.central_curve)
        if len(pts) < 2:
            continue
        for field, end, what in (("successor_id", pts[-1], "ends at junction {} with no lane leading on"),
                                 ("predecessor_id", pts[0], "starts at junction {} with no lane leading in")):
            if getattr(ln, field):
                continue
            near = tree.query(Point(end), predicate="dwithin", distance=LINK_TOL_M)
            if len(near):
                out.append(Problem(f"lane {ln.id.id}", what.format(polys[int(near[0])][0])))
    return out


def _areas(m: Any) -> list[Problem]:
    out = []
    for kind in ("junction", "crosswalk"):
        for e in getattr(m, kind):
            if _distinct(_xy(e.polygon.point)) < 3:
                out.append(Problem(f"{kind} {e.id.id}", "polygon needs >= 3 distinct points"))
    return out


def _stop_lines(e: Any) -> list[Any]:
    return list(e.stop_line)


def _controls(m: Any, idx: _Index) -> list[Problem]:
    out = []
    overlaps = idx.by_kind["overlap"]
    for kind in ("signal", "stop_sign"):
        for e in getattr(m, kind):
            w = f"{kind} {e.id.id}"
            if kind == "signal":
                if len(e.boundary.point) < 4:
                    out.append(Problem(w, f"boundary has {len(e.boundary.point)} points (>= 4 needed)"))
                if not e.subsignal:
                    out.append(Problem(w, "has no subsignal"))
                for sub in e.subsignal:
                    if not (sub.id.id and sub.HasField("type") and sub.HasField("location")):
                        out.append(Problem(w, f"subsignal {sub.id.id or '?'} needs id, type and location"))
            lines = _stop_lines(e)
            if not lines:
                out.append(Problem(w, "has no stop_line"))
            for c in lines:
                if _distinct(_curve_points(c)) < 2:
                    out.append(Problem(w, "stop_line needs >= 2 distinct points"))
            geoms = [LineString(p) for c in lines if _distinct(p := _curve_points(c)) >= 2]
            lane_objs = []
            for o in e.overlap_id:
                ov = overlaps.get(o.id)
                if ov is None:
                    out.append(Problem(w, f"overlap_id {o.id} does not exist"))
                    continue
                lane_objs += [x for x in ov.object if x.WhichOneof("overlap_info") == "lane_overlap_info"]
            if not lane_objs:
                out.append(Problem(w, "overlaps no lane (planning ignores it)"))
            for x in lane_objs:
                lane = idx.lanes.get(x.id.id)
                if lane is None or not geoms:
                    continue
                pts = _curve_points(lane.central_curve)
                if _distinct(pts) < 2:
                    continue
                line = LineString(pts)
                info = x.lane_overlap_info
                mid = line.interpolate((info.start_s + info.end_s) / 2)
                d = min(g.distance(mid) for g in geoms)
                if d > STOP_LINE_TOL_M + APOLLO_STOP_LINE_OVERLAP_M + (info.end_s - info.start_s) / 2:
                    out.append(Problem(w, f"overlap with lane {x.id.id} is {d:.1f} m from the stop line"))
    return out


def _overlaps(m: Any, idx: _Index) -> list[Problem]:
    out = []
    for ov in m.overlap:
        w = f"overlap {ov.id.id}"
        if len(ov.object) != 2:
            out.append(Problem(w, f"has {len(ov.object)} objects (must be 2)"))
        for o in ov.object:
            info = o.WhichOneof("overlap_info")
            if info is None:
                out.append(Problem(w, f"object {o.id.id} has no overlap info"))
                continue
            kind = _INFO_KIND[info]
            e = idx.by_kind[kind].get(o.id.id)
            if e is None:
                out.append(Problem(w, f"{kind} {o.id.id} does not exist"))
                continue
            if ov.id.id not in {x.id for x in e.overlap_id}:
                out.append(Problem(w, f"{kind} {o.id.id} does not list it in overlap_id"))
            if kind == "lane":
                li = o.lane_overlap_info
                if not (li.HasField("start_s") and li.HasField("end_s")):
                    out.append(Problem(w, f"lane {o.id.id}: start_s/end_s not set"))
                elif not -LENGTH_TOL_M <= li.start_s <= li.end_s <= e.length + LENGTH_TOL_M:
                    out.append(Problem(w, f"lane {o.id.id}: s range {li.start_s:.2f}..{li.end_s:.2f} is not "
                                          f"within 0..{e.length:.2f}"))
    for kind in ("junction", "crosswalk", "signal", "stop_sign"):
        for e in getattr(m, kind):
            for o in e.overlap_id:
                ov = idx.by_kind["overlap"].get(o.id)
                if ov is not None and e.id.id not in {x.id.id for x in ov.object}:
                    out.append(Problem(f"{kind} {e.id.id}", f"lists overlap {o.id} which does not include it"))
    # junction lanes overlap their junction over the whole lane
    cover = {(lane, j): rng for j, lane, rng in _lane_ranges(m, "junction_overlap_info")}
    for ln in m.lane:
        if not ln.HasField("junction_id"):
            continue
        rng = cover.get((ln.id.id, ln.junction_id.id))
        if rng is None:
            out.append(Problem(f"lane {ln.id.id}", f"no overlap with its junction {ln.junction_id.id}"))
        elif rng[0] > LENGTH_TOL_M or rng[1] < ln.length - LENGTH_TOL_M:
            out.append(Problem(f"lane {ln.id.id}", f"junction overlap covers {rng[0]:.2f}..{rng[1]:.2f}, "
                                                   f"not the whole lane (0..{ln.length:.2f})"))
    return out


def _lane_ranges(m: Any, info: str) -> list[tuple[str, str, tuple[float, float]]]:
    """(other object id, lane id, lane s range) of every overlap between a lane and an object
    whose overlap info is `info` (e.g. "junction_overlap_info")."""
    out = []
    for ov in m.overlap:
        kinds = {o.WhichOneof("overlap_info"): o for o in ov.object}
        if "lane_overlap_info" in kinds and info in kinds:
            li = kinds["lane_overlap_info"].lane_overlap_info
            out.append((kinds[info].id.id, kinds["lane_overlap_info"].id.id, (li.start_s, li.end_s)))
    return out


def _crosswalk_cover(m: Any, idx: _Index) -> list[Problem]:
    """Each crosswalk overlaps exactly the lanes whose centreline it covers, over that s range."""
    out: list[Problem] = []
    if not m.crosswalk:
        return out
    lanes = [ln for ln in m.lane if _distinct(_curve_points(ln.central_curve)) >= 2]
    lines = [LineString(_curve_points(ln.central_curve)) for ln in lanes]
    tree = STRtree(lines)
    ranges = {(cw, lane): rng for cw, lane, rng in _lane_ranges(m, "crosswalk_overlap_info")}
    for cw in m.crosswalk:
        pts = _xy(cw.polygon.point)
        if _distinct(pts) < 3:
            continue
        poly = Polygon(pts).buffer(0)
        for k in tree.query(poly, predicate="intersects"):
            inter = lines[k].intersection(poly)
            if inter.length <= CROSSWALK_TOL_M:
                continue
            ss = [lines[k].project(shapely.Point(c)) for c in shapely.get_coordinates(inter)]
            lid = lanes[k].id.id
            got = ranges.get((cw.id.id, lid))
            if got is None:
                out.append(Problem(f"crosswalk {cw.id.id}", f"covers lane {lid} at s {min(ss):.1f}..{max(ss):.1f} "
                                                             "without an overlap"))
            elif abs(got[0] - min(ss)) > CROSSWALK_TOL_M or abs(got[1] - max(ss)) > CROSSWALK_TOL_M:
                out.append(Problem(f"crosswalk {cw.id.id}", f"overlap with lane {lid} spans {got[0]:.1f}..{got[1]:.1f}"
                                                             f", the crosswalk covers {min(ss):.1f}..{max(ss):.1f}"))
    return out


# --- sim_map and routing_map ------------------------------------------------------------------

def check_sim_map(base: Any, sim: Any) -> list[Problem]:
    """sim_map has the base map's elements, lane curves of >= 2 points within the base's."""
    out = []
    for kind in ("lane", "road", "junction", "signal", "stop_sign", "crosswalk", "overlap"):
        a = [e.id.id for e in getattr(base, kind)]
        b = [e.id.id for e in getattr(sim, kind)]
        if sorted(a) != sorted(b):
            out.append(Problem("file sim_map", f"{kind} ids differ from base_map ({len(b)} vs {len(a)})"))
    base_lanes = {ln.id.id: ln for ln in base.lane}
    for ln in sim.lane:
        for name in ("central_curve", "left_boundary", "right_boundary"):
            curve = getattr(ln, name) if name == "central_curve" else getattr(ln, name).curve
            pts = _curve_points(curve)
            if _distinct(pts) < 2:
                out.append(Problem(f"sim_map lane {ln.id.id}", f"{name} has fewer than 2 distinct points"))
                continue
            base_ln = base_lanes.get(ln.id.id)
            if base_ln is not None:
                bc = getattr(base_ln, name) if name == "central_curve" else getattr(base_ln, name).curve
                bp = _curve_points(bc)
                if len(bp) and (math.dist(bp[0], pts[0]) > LENGTH_TOL_M or math.dist(bp[-1], pts[-1]) > LENGTH_TOL_M):
                    out.append(Problem(f"sim_map lane {ln.id.id}", f"{name} ends differ from base_map"))
    return out


def check_routing_map(base: Any, graph: Any) -> list[Problem]:
    """routing_map equals the graph topo_creator builds from base_map (nodes, edges, costs)."""
    want = build_routing_graph(base)
    out = []
    a = {n.lane_id: n for n in want.node}
    b = {n.lane_id: n for n in graph.node}
    for lid in sorted(a.keys() - b.keys())[:20]:
        out.append(Problem(f"routing_map node {lid}", "missing (lane is routable in base_map)"))
    for lid in sorted(b.keys() - a.keys())[:20]:
        out.append(Problem(f"routing_map node {lid}", "not a routable lane of base_map"))
    for lid in sorted(a.keys() & b.keys()):
        if abs(a[lid].cost - b[lid].cost) > COST_TOL * max(1.0, a[lid].cost) or a[lid].road_id != b[lid].road_id:
            out.append(Problem(f"routing_map node {lid}", f"cost/road {b[lid].cost:.3f}/{b[lid].road_id} != "
                                                          f"{a[lid].cost:.3f}/{a[lid].road_id} from base_map"))
    ea = {(e.from_lane_id, e.to_lane_id, e.direction_type): e.cost for e in want.edge}
    eb = {(e.from_lane_id, e.to_lane_id, e.direction_type): e.cost for e in graph.edge}
    for k in sorted(ea.keys() - eb.keys())[:20]:
        out.append(Problem(f"routing_map edge {k[0]}->{k[1]}", "missing"))
    for k in sorted(eb.keys() - ea.keys())[:20]:
        out.append(Problem(f"routing_map edge {k[0]}->{k[1]}", "not derivable from base_map"))
    for k in sorted(ea.keys() & eb.keys()):
        if not (ea[k] == eb[k] or abs(ea[k] - eb[k]) <= COST_TOL * max(1.0, abs(ea[k]))):
            out.append(Problem(f"routing_map edge {k[0]}->{k[1]}", f"cost {eb[k]} != {ea[k]}"))
    return out


# --- reachability -----------------------------------------------------------------------------

def all_roads_two_way(m: Any) -> bool:
    """Every road outside junctions carries lanes in both directions."""
    lanes = {ln.id.id: ln for ln in m.lane}
    junction_roads = {r.id.id for r in m.road if r.HasField("junction_id")}
    for road in m.road:
        if road.id.id in junction_roads:
            continue
        members = [lanes[x.id] for sec in road.section for x in sec.lane_id if x.id in lanes]
        if not members or any(ln.HasField("junction_id") for ln in members):
            continue
        if any(ln.left_neighbor_reverse_lane_id or ln.right_neighbor_reverse_lane_id for ln in members):
            continue
        heads = []
        for ln in members:
            p = _curve_points(ln.central_curve)
            if len(p) >= 2:
                d = p[-1] - p[0]
                heads.append(d / (np.hypot(*d) or 1.0))
        if not any(float(a @ b) < 0 for a in heads for b in heads):
            return False
    return True


def _unreached_groups(pairs: list[tuple[str, str]]) -> list[Problem]:
    """One problem per set of exits that the same entries miss, not one per (entry, exit) pair:
    one broken link keeps every exit beyond it from every entry before it (a CommonRoad map read
    with its road links at the far end gave 1,156 lines for 44 causes)."""
    missed: dict[str, list[str]] = {}
    for e, x in pairs:
        missed.setdefault(e, []).append(x)
    by_exits: dict[tuple[str, ...], list[str]] = {}
    for e, xs in missed.items():
        by_exits.setdefault(tuple(xs), []).append(e)

    def few(ids: Sequence[str]) -> str:
        return ", ".join(ids[:3]) + (f" and {len(ids) - 3} more" if len(ids) > 3 else "")
    return [Problem(f"lane {xs[0]}", f"{len(xs)} exit lane(s) not reachable from {len(es)} entry lane(s): "
                                     f"exits {few(xs)}; entries {few(es)}") for xs, es in by_exits.items()]


def reachability(m: Any, graph: Any) -> list[Problem]:
    """When every road is two-way: over the routing graph, every exit is reachable from every
    entry (bar its own road's, which needs a U-turn), every lane from some entry, and every
    lane reaches some exit; a map without entries and exits must be strongly connected. Maps
    feat2map generated get the per-lane checks with one-way roads too (as check_map does).
    Entries are lanes without predecessors (the open ends of stub roads), exits lanes without
    successors; exits some entries miss are one problem per set of exits those entries miss."""
    two_way = all_roads_two_way(m)
    if not m.lane or not (two_way or _generated(m)):  # one-way roads: per lane only, generated maps only
        return []
    nodes = [n.lane_id for n in graph.node]
    fwd: dict[str, list[str]] = {n: [] for n in nodes}
    bwd: dict[str, list[str]] = {n: [] for n in nodes}
    for e in graph.edge:
        if e.from_lane_id in fwd and e.to_lane_id in fwd:
            fwd[e.from_lane_id].append(e.to_lane_id)
            bwd[e.to_lane_id].append(e.from_lane_id)
    lanes = {ln.id.id: ln for ln in m.lane}
    nodes = [n for n in nodes if n in lanes]  # a routing_map may name lanes the map lacks
    road_of = {x.id: r.id.id for r in m.road for s in r.section for x in s.lane_id}
    entries = [n for n in nodes if not lanes[n].predecessor_id]
    exits = [n for n in nodes if not lanes[n].successor_id]

    def reach(starts: list[str], adj: dict[str, list[str]]) -> set[str]:
        seen, todo = set(starts), deque(starts)
        while todo:
            for nxt in adj[todo.popleft()]:
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        return seen

    out = []
    if not entries and not exits:
        if nodes and (len(reach(nodes[:1], fwd)) != len(nodes) or len(reach(nodes[:1], bwd)) != len(nodes)):
            out.append(Problem("routing graph", "map without entries or exits is not strongly connected"))
        return out
    if two_way:
        out += _unreached_groups(unreached_exits(entries, exits, fwd.__getitem__, road_of.get))
    from_entries, to_exits = reach(entries, fwd), reach(exits, bwd)
    for n in nodes:
        if n not in from_entries:
            out.append(Problem(f"lane {n}", "not reachable from any map entry"))
        if n not in to_exits:
            out.append(Problem(f"lane {n}", "reaches no map exit"))
    return out
