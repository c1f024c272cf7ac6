"""The model's boundary: every map a reader returns passes `validate_model` before any work is
done on it, and every writer refuses non-finite output (`refuse_nonfinite`).

`validate_model` checks every element's values (types, finite coordinates within
`Limits.max_coordinate_m`, widths and speeds in range, polylines and polygons with enough
points, enums), its references (ids that exist, no lane its own successor or predecessor) and
the map's size (`Limits.max_lanes`, `Limits.max_points`); the first problem is raised as a
`MapFormatError` naming the file and element, quoting at most a short snippet of the value.
"""
from __future__ import annotations

import math
import re
from typing import Any, Iterable

import numpy as np

from .bezier import Bezier
from .config import limits
from .errors import Feat2MapError, MapFormatError, snippet
from .features import JunctionFeature
from .model import BOUNDARY_TYPES, TURNS, HDMap

ROAD_KINDS = ("connection", "stub", "junction", "chain")
CONTROL_KINDS = ("signals", "stop_signs", "yield_signs")  # HDMap fields of elements with a stop line and lanes
_LINKS = ("predecessors", "successors", "left_neighbors", "right_neighbors", "left_reverse_neighbors")


def _bad(where: str, element: str, message: str) -> MapFormatError:
    return MapFormatError(message, f"{where}: {element}")


def _is_number(value: Any) -> bool:
    return isinstance(value, (int, float, np.floating, np.integer)) and not isinstance(value, bool) \
        and math.isfinite(value)


def _number(value: Any, where: str, element: str, field: str, lo: float | None = None,
            hi: float | None = None) -> None:
    if not _is_number(value) or (lo is not None and value < lo) or (hi is not None and value > hi):
        span = "" if lo is None and hi is None else f" in [{lo if lo is not None else '-inf'}, " \
                                                    f"{hi if hi is not None else 'inf'}]"
        raise _bad(where, element, f"{field} must be a finite number{span}, got {snippet(value)}")


def _ids(value: Any, where: str, element: str, field: str) -> None:
    if not isinstance(value, tuple) or not all(isinstance(x, str) and x for x in value):
        raise _bad(where, element, f"{field} must be a list of ids, got {snippet(value)}")


def _opt_id(value: Any, where: str, element: str, field: str) -> None:
    if value is not None and not (isinstance(value, str) and value):
        raise _bad(where, element, f"{field} must be an id or null, got {snippet(value)}")


class _Points:
    """Polylines and polygons collected as arrays, checked in bulk (finite, within range)."""

    def __init__(self, where: str) -> None:
        self.where = where
        self.arrays: list[tuple[str, str, np.ndarray]] = []
        self.count = 0

    def add(self, value: Any, element: str, field: str, min_points: int) -> None:
        try:
            arr = np.asarray(value, dtype=float)
        except (TypeError, ValueError):
            arr = None
        if arr is None or arr.ndim != 2 or arr.shape[1] != 2 or len(arr) < min_points:
            raise _bad(self.where, element, f"{field} must be a list of at least {min_points} [x, y] points, "
                                            f"got {snippet(value)}")
        self.arrays.append((element, field, arr))
        self.count += len(arr)
        if self.count > limits().max_points:
            limits().check("max_points", self.count, "the number of points")

    def point(self, value: Any, element: str, field: str) -> None:
        self.add((value,) if isinstance(value, tuple) else value, element, field, 1)

    def check(self) -> None:
        if not self.arrays:
            return
        cap = limits().max_coordinate_m
        allpts = np.concatenate([a for _, _, a in self.arrays])
        if np.isfinite(allpts).all() and float(np.abs(allpts).max()) <= cap:
            return
        for element, field, arr in self.arrays:
            bad = ~np.isfinite(arr).all(axis=1) | (np.abs(np.nan_to_num(arr, nan=0.0, posinf=np.inf)) > cap).any(axis=1)
            if bad.any():
                k = int(np.argmax(bad))
                raise _bad(self.where, element, f"{field} point {k} is {snippet(tuple(arr[k].tolist()))}: "
                                                f"coordinates must be finite and within +-{cap:g} m "
                                                f"(limit max_coordinate_m)")


def _bezier(value: Any, points: _Points, element: str, field: str) -> None:
    if value is None:
        return
    if not isinstance(value, Bezier):
        raise _bad(points.where, element, f"{field} must be 4 control points, got {snippet(value)}")
    points.add((value.p0, value.p1, value.p2, value.p3), element, field, 4)


def validate_model(m: HDMap, where: str = "map") -> HDMap:
    """Check every value of `m` (see the module docstring); returns `m`, raises MapFormatError."""
    lim = limits()
    lim.check("max_lanes", len(m.lanes), "the number of lanes")
    pts = _Points(where)
    for kind in ("lanes", "roads", "junctions", "signals", "stop_signs", "yield_signs", "crosswalks"):
        items = getattr(m, kind)
        for key, el in items.items():
            if getattr(el, "id", None) != key or not isinstance(key, str) or not key:
                raise _bad(where, f"{kind} {snippet(key)}", "element id missing or not the key it is stored under")
    for lid, ln in m.lanes.items():
        e = f"lane {lid}"
        pts.add(ln.centerline, e, "centerline", 2)
        pts.add(ln.left_boundary, e, "left_boundary", 2)
        pts.add(ln.right_boundary, e, "right_boundary", 2)
        _bezier(ln.bezier, pts, e, "bezier")
        _number(ln.width, where, e, "width", 0.0, lim.max_lane_width_m)
        _number(ln.speed_limit, where, e, "speed_limit", 0.0, 1000.0)
        if not isinstance(ln.road_id, str) or not ln.road_id:
            raise _bad(where, e, f"road_id must be an id, got {snippet(ln.road_id)}")
        _opt_id(ln.junction_id, where, e, "junction_id")
        for field in _LINKS:
            _ids(getattr(ln, field), where, e, field)
        for field in ("predecessors", "successors"):
            if lid in getattr(ln, field):
                raise _bad(where, e, f"the lane is its own {field[:-1]}")
        if ln.turn not in TURNS:
            raise _bad(where, e, f"turn must be one of {', '.join(TURNS)}, got {snippet(ln.turn)}")
        for field in ("left_boundary_type", "right_boundary_type"):
            if getattr(ln, field) not in BOUNDARY_TYPES:
                raise _bad(where, e, f"{field} must be one of {', '.join(BOUNDARY_TYPES)}, "
                                     f"got {snippet(getattr(ln, field))}")
    for rid, r in m.roads.items():
        e = f"road {rid}"
        if r.kind not in ROAD_KINDS:
            raise _bad(where, e, f"kind must be one of {', '.join(ROAD_KINDS)}, got {snippet(r.kind)}")
        _ids(r.right_lanes, where, e, "right_lanes")
        _ids(r.left_lanes, where, e, "left_lanes")
        _bezier(r.reference, pts, e, "reference")
        _number(r.lane_offset, where, e, "lane_offset", -lim.max_lane_width_m * 100, lim.max_lane_width_m * 100)
        for field in ("junction_id", "start_junction", "end_junction"):
            _opt_id(getattr(r, field), where, e, field)
    for jid, j in m.junctions.items():
        e = f"junction {jid}"
        pts.add(j.polygon, e, "polygon", 3)
        if j.feature is not None and not isinstance(j.feature, JunctionFeature):
            raise _bad(where, e, f"feature must be a junction feature, got {snippet(j.feature)}")
        if j.cell is not None and not (isinstance(j.cell, tuple) and len(j.cell) == 2 and all(
                isinstance(c, int) and not isinstance(c, bool) for c in j.cell)):
            raise _bad(where, e, f"cell must be [x, y] integers, got {snippet(j.cell)}")
        _ids(j.socket_roads, where, e, "socket_roads")
    for kind in CONTROL_KINDS:
        for sid, s in getattr(m, kind).items():
            e = f"{kind[:-1]} {sid}"
            pts.add(s.stop_line, e, "stop_line", 2)
            pts.point(s.position, e, "position")
            _number(s.heading, where, e, "heading")
            _ids(s.lane_ids, where, e, "lane_ids")
            _opt_id(s.junction_id, where, e, "junction_id")
    for cid, c in m.crosswalks.items():
        e = f"crosswalk {cid}"
        pts.add(c.polygon, e, "polygon", 3)
        _opt_id(c.junction_id, where, e, "junction_id")
    pts.point(m.origin, "map", "origin")
    pts.check()
    check_references(m, where)
    return m


def check_references(m: HDMap, where: str = "map") -> None:
    """Every id an element refers to exists; raises MapFormatError naming the element."""
    def missing(ids: Iterable[str], table: Any) -> str | None:
        return next((x for x in ids if x not in table), None)

    def need(ids: Iterable[str], table: Any, what: str, element: str) -> None:
        x = missing(ids, table)
        if x is not None:
            raise _bad(where, element, f"unknown {what} id {snippet(x)}")

    for ln in m.lanes.values():
        need([ln.road_id], m.roads, "road", f"lane {ln.id}")
        need([ln.junction_id] if ln.junction_id is not None else [], m.junctions, "junction", f"lane {ln.id}")
        need((x for f in _LINKS for x in getattr(ln, f)), m.lanes, "lane", f"lane {ln.id}")
    for r in m.roads.values():
        need(r.lane_ids, m.lanes, "lane", f"road {r.id}")
    for kind in CONTROL_KINDS:
        for s in getattr(m, kind).values():
            need(s.lane_ids, m.lanes, "lane", f"{kind[:-1]} {s.id}")
    for kind in (*CONTROL_KINDS, "crosswalks"):
        for s in getattr(m, kind).values():
            need([s.junction_id] if s.junction_id is not None else [], m.junctions, "junction", f"{kind[:-1]} {s.id}")


# ------------------------------------------------------------------------------ writers

# protobuf text numbers that are NaN/inf, or at least 1e9 in size (no coordinate, length or width is):
# `x: nan`, `y: -inf`, `s: 1e+308`, `x: 12345678901.5`
_UNUSABLE_PROTO = re.compile(r"(?<=: )[-+]?(?:nan|inf|\d+(?:\.\d*)?e\+?0?(?:[1-9]\d+|9)|\d{10,}(?:\.\d*)?)\b", re.I)
_PROTO_ID = re.compile(r'\bid: "([^"]*)"')


def unusable_numbers(text: str, first: bool = False) -> list[tuple[str, str, int]]:
    """(value, element, line) of every NaN, infinite or absurdly large (>= 1e9) number in
    protobuf text; the element is the nearest id before it. Only the first with `first`."""
    out = []
    for hit in _UNUSABLE_PROTO.finditer(text):
        ids = list(_PROTO_ID.finditer(text, max(0, hit.start() - 4000), hit.start()))
        out.append((hit.group(0), f"element {snippet(ids[-1].group(1))}" if ids else "an element",
                    text.count("\n", 0, hit.start()) + 1))
        if first:
            break
    return out


def refuse_nonfinite(text: str, where: str) -> str:
    """`text` (protobuf text format, as writers produce it) if all its numbers are usable (see
    `unusable_numbers`), else a Feat2MapError naming the element and the output line."""
    bad = unusable_numbers(text, first=True)
    if not bad:
        return text
    value, element, line = bad[0]
    raise Feat2MapError(f"refusing to write the number {value} in {element} (output line {line}): the map holds "
                        "NaN, infinite or absurdly large numbers", where)
