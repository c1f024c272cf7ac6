"""Read OpenDRIVE 1.4 to 1.8 (.xodr) files into the feat2map map model: the 1.4 and 1.6 files
of CARLA, SVL, esmini and CommonRoad, and every revision the writer produces (1.4, 1.6, 1.7,
1.8; the header's revMinor is not checked: 1.4 `outline` and 1.5+ `outlines` both read).

Road reference lines (line, arc, spiral, poly3, paramPoly3) are evaluated in closed form or
by dense numeric integration; lanes are the reference shifted by the lane offset and the
cumulative lane widths. Only driving lanes become `Lane`s (other lanes still take width).
Lane links are collected as contacts between lane ends (inside a road, across road links and
across junction lane links) and turned into successor/predecessor links in driving direction
(right-hand traffic: negative lane ids drive along the reference, positive ones against it; a
road with `rule="LHT"` the other way round). Boundary types come from the `<roadMark>`s.
CARLA splits one intersection into several `<junction>` elements: junction elements whose
connecting lanes touch are merged into one `Junction`. Signals are mapped through the one
`SIGNAL_CODES` table and attached to the incoming lanes they govern.
"""
from __future__ import annotations

import math
import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from shapely.geometry import MultiPoint, Polygon
from shapely.geometry.polygon import orient

from ...angles import classify_turn, positive_angle, wrap_angle
from ...config import (EDGE_STUB_LENGTH_M, IMPLICIT_LANE_LINK_M, MIN_ARM_LENGTH_M, NEGATIVE_WIDTH_TOL_M,
                       OPENDRIVE_NEIGHBOURS_CODE, OPENDRIVE_TURN_CODE, OPENDRIVE_VENDOR, ROAD_CONTACT_M, SAMPLE_SPACING_M,
                       SPEED_LIMIT_MPS, UTURN_THRESHOLD_DEG, limits)
from ...errors import LimitError, MapFormatError, snippet
from ...model import (TURNS, Crosswalk, HDMap, Junction, Lane, Road, Signal, StopSign, YieldSign, as_polyline,
                      line_across_at, midblock_crossing, signal_precedence, stop_line_across)
from ...semantics import loaded, unfold

# OpenDRIVE signal type -> feat2map control kind, from the code tables the dialects use: the
# OpenDRIVE 1.5 country "OpenDRIVE" codes for lights (CARLA/VectorZero, SVL and esmini: 1000001
# light, 1000002 pedestrian light; RoadRunner 1000011 arrow lights, subtype 10 left / 20 right),
# the German StVO catalogue every dialect reuses for signs (206 stop, 205 yield), the US MUTCD
# (R1-1 stop, R1-2 yield), and the free-text types some converters write ("traffic_light",
# "give_way"). 1000003 is esmini's crosswalk road marking (SgRMCrosswalk), not a light.
SIGNAL_CODES: dict[str, str] = {
    "1000001": "signal", "1000002": "signal", "1000007": "signal",
    "1000008": "signal", "1000009": "signal", "1000010": "signal", "1000011": "signal",
    "1000012": "signal", "1000013": "signal", "1000014": "signal", "1000015": "signal",
    "1000016": "signal", "1000017": "signal", "1000018": "signal", "1000019": "signal",
    "1000020": "signal",
    "206": "stop", "R1-1": "stop",
    "205": "yield", "R1-2": "yield",
    "traffic_light": "signal", "trafficlight": "signal", "traffic_signals": "signal", "traffic_signal": "signal",
    "stop": "stop", "stop_sign": "stop", "give_way": "yield", "yield": "yield", "yield_sign": "yield",
}
# known codes that are no junction control (speed limits, stop lines, road markings, priority
# and direction signs, ...): ignored without a warning
NOT_CONTROLS = frozenset({
    "1000003", "274", "274.1", "274.2", "278", "282", "294", "301", "306", "307", "310", "311", "314", "331",
    "332", "333", "336", "350", "625", "626", "215", "209", "211", "214", "220", "222", "237", "239", "240",
    "241", "250", "251", "253", "254", "260", "267", "283", "286", "290", "325", "330", "101", "102", "103",
    "105", "108", "110", "112", "114", "120", "123", "125", "131", "133", "136", "138", "142", "151",
    "1000", "1004", "334", "406", "430", "436", "440", "449", "450", "451", "452", "531", "605",
    "R2-1", "R3-1", "R3-2", "R3-4", "R3-5", "R3-7", "R4-7", "R5-1", "R6-1", "W3-1", "W3-3",
    "speed", "maxspeed", "city_limit", "stop_line", "stopline", "holdingline", "crosswalk", "pedestrian_crossing",
    "roadmark",  # RoadRunner (2021) writes its stop lines as <signal name="StopLine" type="roadmark">
    "-1", "",
})
US_COUNTRIES = frozenset({"us", "usa"})  # 205/206 are German codes: not stop/yield under the MUTCD


def signal_kind(type_: str | None, country: str | None = None, dynamic: str | None = None) -> str | None:
    """The control kind ("signal", "stop", "yield") of a `<signal>` from its type code, country
    and `dynamic` flag, or None for no control. A light type marked dynamic="no" is no light
    (a sign or marking drawn with a light's code); a sign code marked dynamic="yes" stays a sign."""
    t, country = _code(type_, country)
    kind = SIGNAL_CODES.get(t) or SIGNAL_CODES.get(t.lower())
    if t in ("205", "206") and (country or "").strip().lower() in US_COUNTRIES:
        return None
    if kind == "signal" and (dynamic or "").strip().lower() == "no":
        return None
    return kind


def known_non_control(type_: str | None) -> bool:
    """Whether a signal type is in the code tables as something that is no junction control."""
    t, _ = _code(type_, None)
    return t in NOT_CONTROLS or t.lower() in NOT_CONTROLS


def _code(type_: str | None, country: str | None) -> tuple[str, str | None]:
    """(code, country) of a type as written: OSM-style "DE:206" carries its country, "DE:274[60]"
    its value; both come off."""
    t = re.sub(r"\[[^\]]*\]$", "", (type_ or "").strip())
    m = re.match(r"^([A-Za-z]{2,3}):(.+)$", t)
    if m:
        return m.group(2).strip(), m.group(1)
    return t, country


# A yield sign is not a stop sign: it becomes a `YieldSign` (its junction stays bare).
_CONTROL_CLASS = {"signal": Signal, "stop": StopSign, "yield": YieldSign}
# OpenDRIVE 1.4+ lane types cars drive, and 1.1-1.3's motorway entry/exit ("mwyEntry", "mwyExit":
# VIRES ROD still writes them)
DRIVING_TYPES = frozenset({"driving", "entry", "exit", "onramp", "offramp", "connectingramp", "mwyentry", "mwyexit"})
MIN_LANE_WIDTH_M = 0.3  # lanes never wider than this in a section are slivers, not lanes
JUNCTION_TOUCH_M = 0.1  # junction elements whose connecting lanes touch (this close) are one intersection
END_TANGENT_M = 0.05  # extra sample this close to each lane end, so polyline end headings are exact
SIGNAL_SEARCH_M = 40.0  # a signal governs incoming lanes ending within this distance
_MPH = 0.44704


@dataclass(frozen=True)
class _Geometry:
    s: float
    x: float
    y: float
    hdg: float
    length: float
    kind: str
    params: dict[str, float]


def _cumtrapz(y: np.ndarray, x: np.ndarray) -> np.ndarray:
    return np.concatenate([[0.0], np.cumsum(0.5 * (y[1:] + y[:-1]) * np.diff(x))])


def _local_curve(g: _Geometry, ds: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(u, v, heading offset) of one geometry at distances `ds` from its start, local frame."""
    p, L = g.params, g.length
    if g.kind == "line":
        return ds, np.zeros_like(ds), np.zeros_like(ds)
    if g.kind == "arc":
        k = p["curvature"]
        if abs(k) < 1e-12:
            return ds, np.zeros_like(ds), np.zeros_like(ds)
        return np.sin(k * ds) / k, (1.0 - np.cos(k * ds)) / k, k * ds
    if g.kind == "spiral":  # clothoid: curvature linear in s, position by numeric integration
        k0, k1 = p["curvStart"], p["curvEnd"]
        c = (k1 - k0) / L if L > 0 else 0.0
        n = max(16, int(math.ceil(L / 0.05)) + 1)
        grid = np.linspace(0.0, L, n)
        th = k0 * grid + 0.5 * c * grid * grid
        u, v = _cumtrapz(np.cos(th), grid), _cumtrapz(np.sin(th), grid)
        return np.interp(ds, grid, u), np.interp(ds, grid, v), k0 * ds + 0.5 * c * ds * ds
    n = max(64, int(math.ceil(L / 0.05)) + 1)
    if g.kind == "poly3":
        a, b, cc, d = (p[k] for k in "abcd")
        uu = np.linspace(0.0, L, n)  # arc length >= u, so u never exceeds the length
        vv = a + uu * (b + uu * (cc + uu * d))
        dv = b + uu * (2 * cc + 3 * d * uu)
        du = np.ones_like(uu)
    else:  # paramPoly3
        pmax = 1.0 if p.get("normalized", 1.0) else L
        t = np.linspace(0.0, pmax, n)
        uu = p["aU"] + t * (p["bU"] + t * (p["cU"] + t * p["dU"]))
        vv = p["aV"] + t * (p["bV"] + t * (p["cV"] + t * p["dV"]))
        du = p["bU"] + t * (2 * p["cU"] + 3 * p["dU"] * t)
        dv = p["bV"] + t * (2 * p["cV"] + 3 * p["dV"] * t)
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(uu), np.diff(vv)))])
    if g.kind != "poly3" and arc[-1] > 0:  # p is not arc length: stretch the table onto [0, L]
        arc = arc * (L / arc[-1])
    head = np.arctan2(dv, du)
    return np.interp(ds, arc, uu), np.interp(ds, arc, vv), np.interp(ds, arc, np.unwrap(head))


class _RefLine:
    """A road's reference line: position and heading at any s (vectorised)."""

    def __init__(self, geoms: list[_Geometry]) -> None:
        self.geoms = sorted(geoms, key=lambda g: g.s)
        self.starts = np.array([g.s for g in self.geoms])

    def eval(self, s: np.ndarray | list[float]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        s = np.atleast_1d(np.asarray(s, dtype=float))
        idx = np.clip(np.searchsorted(self.starts, s, side="right") - 1, 0, len(self.geoms) - 1)
        x, y, h = np.empty_like(s), np.empty_like(s), np.empty_like(s)
        for i in np.unique(idx):
            g = self.geoms[i]
            m = idx == i
            ds = np.clip(s[m] - g.s, 0.0, g.length)
            u, v, dh = _local_curve(g, ds)
            c, sn = math.cos(g.hdg), math.sin(g.hdg)
            x[m] = g.x + u * c - v * sn
            y[m] = g.y + u * sn + v * c
            h[m] = g.hdg + dh
        return x, y, h


def _poly(records: list[tuple[float, float, float, float, float]], s: np.ndarray,
          end: float = math.inf) -> np.ndarray:
    """Piecewise cubic a + b ds + c ds^2 + d ds^3, each record valid from its start s; at `end`
    (a lane section's end) the record before it still holds: one starting there is the next
    section's (CARLA jumps the lane offset at section ends; taking the next record at the last
    sample folded the lane back on itself)."""
    if not records:
        return np.zeros_like(s)
    starts = np.array([r[0] for r in records])
    idx = np.clip(np.searchsorted(starts, np.minimum(s + 1e-9, end - 1e-9), side="right") - 1, 0, len(records) - 1)
    rec = np.array(records)[idx]
    ds = s - rec[:, 0]
    return rec[:, 1] + ds * (rec[:, 2] + ds * (rec[:, 3] + ds * rec[:, 4]))


@dataclass
class _OdrLane:
    id: int
    type: str
    widths: list[tuple[float, float, float, float, float]]
    borders: list[tuple[float, float, float, float, float]]
    predecessor: int | None
    successor: int | None
    speed: float | None
    marks: list[tuple[float, str, str]] = field(default_factory=list)  # (sOffset, type, color) of its outer edge


@dataclass
class _Section:
    s0: float
    s1: float
    lanes: dict[int, _OdrLane]
    centre_marks: list[tuple[float, str, str]] = field(default_factory=list)  # the centre lane's (id 0)


@dataclass
class _OdrRoad:
    id: str
    length: float
    junction: str | None
    ref: _RefLine
    sections: list[_Section]
    lane_offset: list[tuple[float, float, float, float, float]]
    links: dict[str, tuple[str, str, str]]  # "predecessor"/"successor" -> (type, id, contactPoint)
    speed: float | None
    el: Any = field(repr=False, default=None)  # lxml element (lxml has no type stubs here)
    lht: bool = False  # rule="LHT": positive lane ids drive along the reference line

    def along(self, lane_id: int) -> bool:
        """Lane `lane_id` drives along the reference line (negative ids in right-hand traffic,
        positive ones in left-hand traffic)."""
        return (lane_id < 0) != self.lht


class _Ctx:
    """Error helpers that name the file and element."""

    def __init__(self, path: str) -> None:
        self.path = path

    def where(self, el, what: str | None = None) -> str:
        tag = what or f"<{el.tag}>"
        line = getattr(el, "sourceline", None)
        return f"{self.path}: {tag}" + (f" (line {line})" if line else "")

    def num(self, el, attr: str, default: float | None = None, what: str | None = None) -> float:
        raw = el.get(attr)
        if raw is None:
            if default is not None:
                return default
            raise MapFormatError(f"missing attribute '{attr}'", self.where(el, what))
        try:
            v = float(raw)
        except ValueError:
            raise MapFormatError(f"attribute '{attr}' is not a number: {snippet(raw)}", self.where(el, what)) from None
        if not math.isfinite(v):
            raise MapFormatError(f"attribute '{attr}' is not finite: {snippet(raw)}", self.where(el, what))
        return v

    def length(self, el, attr: str, what: str) -> float:
        """A length attribute: finite, >= 0 and within the limit max_road_length_m."""
        v = self.num(el, attr, what=what)
        if v < 0:
            raise MapFormatError(f"attribute '{attr}' is negative: {snippet(v)}", self.where(el, what))
        try:
            limits().check("max_road_length_m", v, f"attribute '{attr}'")
        except LimitError as exc:
            raise LimitError(exc.message, self.where(el, what)) from None
        return v


def _geometry(ctx: _Ctx, g, road_id: str) -> _Geometry:
    what = f"road {road_id} <geometry>"
    base = dict(s=ctx.num(g, "s", what=what), x=ctx.num(g, "x", what=what), y=ctx.num(g, "y", what=what),
                hdg=ctx.num(g, "hdg", what=what), length=ctx.length(g, "length", what=what))
    cap = limits().max_coordinate_m
    if max(abs(base["x"]), abs(base["y"]), abs(base["s"])) > cap:
        raise MapFormatError(f"x, y or s beyond the limit max_coordinate_m={cap:g}", ctx.where(g, what))
    for child in g:
        tag = child.tag if isinstance(child.tag, str) else ""
        w = f"road {road_id} <{tag}>"
        if tag == "line":
            return _Geometry(**base, kind="line", params={})
        if tag == "arc":
            return _Geometry(**base, kind="arc", params={"curvature": ctx.num(child, "curvature", what=w)})
        if tag == "spiral":
            return _Geometry(**base, kind="spiral", params={k: ctx.num(child, k, what=w) for k in ("curvStart", "curvEnd")})
        if tag == "poly3":
            return _Geometry(**base, kind="poly3", params={k: ctx.num(child, k, what=w) for k in "abcd"})
        if tag == "paramPoly3":
            params = {k: ctx.num(child, k, what=w) for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")}
            params["normalized"] = 0.0 if child.get("pRange", "normalized") == "arcLength" else 1.0
            return _Geometry(**base, kind="paramPoly3", params=params)
    raise MapFormatError("geometry without line/arc/spiral/poly3/paramPoly3", ctx.where(g, what))


def _records(ctx: _Ctx, els: Iterable, start: str, what: str) -> list[tuple[float, float, float, float, float]]:
    recs = [(ctx.num(e, start, what=what), ctx.num(e, "a", 0.0, what), ctx.num(e, "b", 0.0, what),
             ctx.num(e, "c", 0.0, what), ctx.num(e, "d", 0.0, what)) for e in els]
    return sorted(recs, key=lambda r: r[0])


def _speed(el) -> float | None:
    sp = el.find("speed") if el is not None else None
    if sp is None or sp.get("max") in (None, "no limit", "undefined"):
        return None
    try:
        v = float(sp.get("max"))
    except ValueError:
        return None
    unit = sp.get("unit", "m/s")
    return v * (_MPH if unit == "mph" else 1 / 3.6 if unit == "km/h" else 1.0)


def _marks(ln) -> list[tuple[float, str, str]]:
    """A lane's `<roadMark>` records (sOffset, type, color), lower case, in s order; an sOffset
    that is no number counts as 0."""
    out = []
    for rm in ln.findall("roadMark"):
        try:
            s0 = float(rm.get("sOffset", "0"))
        except ValueError:
            s0 = 0.0
        out.append((s0 if math.isfinite(s0) else 0.0, " ".join((rm.get("type") or "none").lower().split()),
                    (rm.get("color") or "standard").lower()))
    return sorted(out, key=lambda m: m[0])


def _mark_type(marks: list[tuple[float, str, str]], length: float, same_direction: bool, first: bool) -> str:
    """The model's boundary type of one lane side from the `<roadMark>`s of the line there:
    the record covering most of the section's `length`. A double type names its lines from the
    inside of the road out (the centre lane's from left to right), and the lane sees the line on
    its side (`first`: the lane lies on the side of the first-named line). A broken line, botts dots or no mark
    between same-direction lanes may be crossed (dotted); a solid line, a curb or grass may not;
    the road's edge without a mark is solid white. See docs/opendrive.md."""
    if not marks:
        return "dotted_white" if same_direction else "solid_white"
    spans = [(min(length, marks[i + 1][0] if i + 1 < len(marks) else length) - max(m[0], 0.0), m)
             for i, m in enumerate(marks)]
    _, (_, typ, colour) = max(spans, key=lambda x: x[0])
    parts = typ.split()
    line = (parts[0] if first else parts[-1]) if parts else "none"
    yellow = colour == "yellow"
    if line in ("broken", "botts") or (line == "none" and same_direction):
        return "dotted_yellow" if yellow else "dotted_white"
    if line in ("curb", "grass"):
        return "curb"
    return "solid_yellow" if yellow else "solid_white"


def _parse_road(ctx: _Ctx, r) -> _OdrRoad:
    rid = r.get("id")
    if rid is None:
        raise MapFormatError("road without id", ctx.where(r))
    what = f"road {rid}"
    length = ctx.length(r, "length", what=what)
    pv = r.find("planView")
    geoms = [_geometry(ctx, g, rid) for g in (pv.findall("geometry") if pv is not None else [])]
    if not geoms:
        raise MapFormatError("road without planView geometry", ctx.where(r, what))
    links: dict[str, tuple[str, str, str]] = {}
    link = r.find("link")
    for kind in ("predecessor", "successor"):
        e = link.find(kind) if link is not None else None
        if e is not None and e.get("elementId") is not None:
            links[kind] = (e.get("elementType", "road"), e.get("elementId"), e.get("contactPoint", ""))
    lanes_el = r.find("lanes")
    if lanes_el is None:
        raise MapFormatError("road without <lanes>", ctx.where(r, what))
    offset = _records(ctx, lanes_el.findall("laneOffset"), "s", f"{what} <laneOffset>")
    sec_els = lanes_el.findall("laneSection")
    if not sec_els:
        raise MapFormatError("road without <laneSection>", ctx.where(r, what))
    s_starts = [ctx.num(e, "s", what=f"{what} <laneSection>") for e in sec_els]
    order = np.argsort(s_starts, kind="stable")
    sections = []
    for k, i in enumerate(order):
        e = sec_els[i]
        s0 = s_starts[i]
        s1 = s_starts[order[k + 1]] if k + 1 < len(order) else length
        lanes: dict[int, _OdrLane] = {}
        for side in ("left", "right"):
            side_el = e.find(side)
            for ln in (side_el.findall("lane") if side_el is not None else []):
                w = f"{what} <lane id={ln.get('id')}>"
                lid = int(ctx.num(ln, "id", what=w))
                lk = ln.find("link")
                pred = lk.find("predecessor") if lk is not None else None
                succ = lk.find("successor") if lk is not None else None
                lanes[lid] = _OdrLane(
                    lid, (ln.get("type") or "none").lower(),
                    _records(ctx, ln.findall("width"), "sOffset", w), _records(ctx, ln.findall("border"), "sOffset", w),
                    int(ctx.num(pred, "id", what=w)) if pred is not None else None,
                    int(ctx.num(succ, "id", what=w)) if succ is not None else None,
                    _speed(ln), _marks(ln))
        centre = e.find("center")
        centre_lane = centre.find("lane") if centre is not None else None
        sections.append(_Section(s0, max(s1, s0), lanes, _marks(centre_lane) if centre_lane is not None else []))
    junction = r.get("junction", "-1")
    return _OdrRoad(rid, length, None if junction in ("-1", "") else junction, _RefLine(geoms), sections, offset,
                    links, _speed(r.find("type")), r, (r.get("rule") or "").strip().upper() == "LHT")


@dataclass
class _LaneGeom:
    key: tuple[str, int, int]  # (road, section index, lane id)
    centre: np.ndarray  # in driving direction
    left: np.ndarray
    right: np.ndarray
    width: float
    speed: float
    folded: bool = False  # samples were cut where the lane folds round a bend (see _unfolded)
    left_type: str = "solid_white"  # boundary types as its traffic sees them (from the roadMarks)
    right_type: str = "solid_white"


def _section_lanes(road: _OdrRoad, k: int, ctx: _Ctx) -> list[_LaneGeom]:
    """Sample every driving lane of one lane section; geometry that is not finite, lies beyond
    the limit max_coordinate_m or has lanes wider than max_lane_width_m is a MapFormatError."""
    sec = road.sections[k]
    n = max(2, int(math.ceil((sec.s1 - sec.s0) / SAMPLE_SPACING_M)) + 1)
    s = np.linspace(sec.s0, sec.s1, n)
    if sec.s1 - sec.s0 > 4 * END_TANGENT_M:  # short end segments: end headings are the true tangents
        s = np.concatenate([[s[0], s[0] + END_TANGENT_M], s[1:-1], [s[-1] - END_TANGENT_M, s[-1]]])
    x, y, h = road.ref.eval(s)
    lim = limits()
    off = _poly(road.lane_offset, s, sec.s1)
    if not (np.isfinite(x).all() and np.isfinite(y).all() and np.isfinite(h).all() and np.isfinite(off).all()
            and max(float(np.abs(x).max()), float(np.abs(y).max()), float(np.abs(off).max())) <= lim.max_coordinate_m):
        raise MapFormatError(f"reference line or lane offset is not finite or beyond the limit max_coordinate_m="
                             f"{lim.max_coordinate_m:g}", ctx.where(road.el, f"road {road.id}"))
    nx, ny = -np.sin(h), np.cos(h)
    ds = s - sec.s0
    out = []
    for side in (-1, 1):
        ids = sorted((i for i in sec.lanes if i * side > 0), key=abs)
        inner = off.copy()
        for i, lid in enumerate(ids):
            ln = sec.lanes[lid]
            if ln.widths or not ln.borders:
                w = _poly(ln.widths, ds, sec.s1 - sec.s0)
                low = min([float(w.min(initial=0.0))] + [r[1] for r in ln.widths])  # records shorter than a sample too
                if low < -NEGATIVE_WIDTH_TOL_M:
                    raise MapFormatError(f"lane {lid} width {low:g} m is negative", ctx.where(road.el, f"road {road.id}"))
                w = np.maximum(w, 0.0)
                outer = inner + side * w
            else:  # border records give the outer edge's t directly
                outer = off + _poly(ln.borders, ds, sec.s1 - sec.s0)
                w = np.abs(outer - inner)
            if not (np.isfinite(outer).all() and float(np.abs(w).max(initial=0.0)) <= lim.max_lane_width_m):
                raise MapFormatError(f"lane {lid} width is not finite or above the limit max_lane_width_m="
                                     f"{lim.max_lane_width_m:g}", ctx.where(road.el, f"road {road.id}"))
            if ln.type in DRIVING_TYPES and float(w.max()) >= MIN_LANE_WIDTH_M:
                mid = 0.5 * (inner + outer)
                keep = _unfolded(s, h, mid) if road.junction is None else np.arange(len(s))
                c, lft, rgt = (np.column_stack([x + t * nx, y + t * ny])[keep] for t in (mid, inner, outer))
                ltype, rtype = _side_types(sec, ids, i, side)  # (inner, outer): the centre on the left
                if road.lht:  # traffic keeps left: the side towards the centre is the driver's right
                    lft, rgt, ltype, rtype = rgt, lft, rtype, ltype
                if not road.along(lid):
                    c, lft, rgt = c[::-1], lft[::-1], rgt[::-1]
                out.append(_LaneGeom((road.id, k, lid), c, lft, rgt, float(w.mean()),
                                     ln.speed or road.speed or SPEED_LIMIT_MPS, len(keep) < len(s), ltype, rtype))
            inner = outer
    return out


def _side_types(sec: _Section, ids: list[int], i: int, side: int) -> tuple[str, str]:
    """(inner, outer) boundary types of lane `ids[i]` of one side of a section (`ids` ordered
    from the centre out): its outer line is its own roadMark, its inner line the roadMark of
    the lane inside it, or the centre lane's."""
    length = sec.s1 - sec.s0
    ln = sec.lanes[ids[i]]
    beyond = sec.lanes[ids[i + 1]] if i + 1 < len(ids) else None
    outer = _mark_type(ln.marks, length, beyond is not None and beyond.type in DRIVING_TYPES, True)
    if i > 0:
        prev = sec.lanes[ids[i - 1]]
        inner = _mark_type(prev.marks, length, prev.type in DRIVING_TYPES, False)
    else:
        inner = _mark_type(sec.centre_marks, length, False, side > 0)
    return inner, outer


def _unfolded(s: np.ndarray, h: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Indices of the samples of the offset curve ref(s) + t(s) normal(s) that move it forward:
    where t lies beyond the reference line's radius of curvature (1 - curvature * t < 0) the
    curve runs backwards and folds into a loop (osm2xodr: a lane 9 m to the side of a road that
    bends at a 5 m radius turns through 140 degrees in its first 5 m, and a car following it
    leaves the road). The progress along the reference line between two samples is the integral
    of (1 - curvature * t) ds = ds - t * dh, taken from the exact headings, so a fold shorter
    than the sample spacing counts too (osm2xodr rounds a road's last corner at a 1.2 m radius
    in 1.7 m; its 1.5 m-offset lane kept one sample inside the fold, a 168-degree spike). The
    two ends are kept (links meet there); a sample between them is kept when its progress is
    beyond every sample before it and short of every sample after it: the fold's loop is cut
    out and the lane turns its corner where its two sides cross."""
    if len(s) < 3:
        return np.arange(len(s))
    dh = np.diff(np.unwrap(h))
    step = np.diff(s) - 0.5 * (t[1:] + t[:-1]) * dh
    if step.min() > 0:
        return np.arange(len(s))
    progress = np.concatenate([[0.0], np.cumsum(step)])
    before = np.concatenate([[-np.inf], np.maximum.accumulate(progress)[:-1]])
    after = np.concatenate([np.minimum.accumulate(progress[::-1])[::-1][1:], [np.inf]])
    inner = (progress > before) & (progress < after) & (progress > progress[0]) & (progress < progress[-1])
    kept = np.flatnonzero(inner[1:-1]) + 1
    return np.concatenate([[0], kept, [len(s) - 1]]) if progress[-1] > progress[0] else np.array([0, len(s) - 1])


def _proj_origin(text: str | None) -> tuple[float, float]:
    """Absolute (UTM-like) position of the file's local origin from the geoReference string.

    A UTM zone written as tmerc with shifted false origin (our writer) gives the origin back
    exactly; a local tmerc around lat_0/lon_0 with +x_0/+y_0 (SVL) gives its false origin.
    """
    if not text:
        return (0.0, 0.0)
    vals = dict(re.findall(r"\+(\w+)=([^\s]+)", text))

    def f(k: str, d: float = 0.0) -> float:
        try:
            return float(vals.get(k, d))
        except ValueError:
            return d
    x0, y0 = f("x_0"), f("y_0")
    if vals.get("proj") == "utm":
        return (500000.0 - x0 if "x_0" in vals else 0.0, -y0 if "y_0" in vals else 0.0)
    if vals.get("proj") == "tmerc" and abs(f("k", 1.0) - 0.9996) < 1e-9 and f("lat_0") == 0.0 and x0 <= 0:
        return (500000.0 - x0, -y0)
    return (x0, y0)


def read_opendrive(path: str | Path) -> HDMap:
    """Read an OpenDRIVE file into an `HDMap`; MapFormatError names the file and element."""
    from lxml import etree

    path = Path(path)
    ctx = _Ctx(str(path))
    try:
        limits().check("max_file_bytes", path.stat().st_size, "the file size (bytes)")
        parser = etree.XMLParser(remove_comments=True, resolve_entities=False, no_network=True)
        tree = etree.parse(str(path), parser)
    except LimitError as exc:
        raise LimitError(exc.message, str(path)) from None
    except OSError as exc:
        raise MapFormatError(f"cannot read ({exc.strerror or type(exc).__name__})", str(path)) from None
    except etree.XMLSyntaxError as exc:
        where = "" if exc.msg and "line" in exc.msg else f", line {exc.lineno}"  # libxml2 names it mostly
        raise MapFormatError(f"malformed XML ({exc.msg or exc}{where})", str(path)) from None
    root = tree.getroot()
    if etree.QName(root).localname != "OpenDRIVE":
        raise MapFormatError(f"root element is <{root.tag}>, not <OpenDRIVE>", str(path))
    for el in root.iter():  # drop namespaces so plain tag names work for every dialect
        if isinstance(el.tag, str) and el.tag.startswith("{"):
            el.tag = etree.QName(el).localname
    header = root.find("header")
    geo = header.find("geoReference") if header is not None else None
    origin = _proj_origin(geo.text if geo is not None else None)
    roads: dict[str, _OdrRoad] = {}
    bad: list[MapFormatError] = []
    for r in root.findall("road"):
        try:
            road = _parse_road(ctx, r)
        except MapFormatError as exc:  # one bad road in an otherwise good map: warn and skip
            warnings.warn(f"skipping bad road: {exc}", stacklevel=2)
            bad.append(exc)
            continue
        if road.id in roads:
            raise MapFormatError(f"duplicate road id {road.id!r}", ctx.where(r))
        roads[road.id] = road
    if not roads:  # say why: a dialect without <planView> (point-set borders) is refused on every road
        first = f"{(bad[0].where or '').removeprefix(f'{ctx.path}: ')}: {bad[0].message}" if bad else ""
        why = f": all {len(bad)} unreadable (first: {first})" if bad else ""
        raise MapFormatError(f"no readable <road> elements{why}", str(path))
    return loaded(_Builder(ctx, root, roads, origin).build(), str(path))


class _Builder:
    def __init__(self, ctx: _Ctx, root, roads: dict[str, _OdrRoad], origin: tuple[float, float]) -> None:
        self.ctx, self.root, self.roads, self.origin = ctx, root, roads, origin
        self.geoms: dict[tuple[str, int, int], _LaneGeom] = {}
        for rid, road in list(roads.items()):
            try:
                with np.errstate(all="ignore"):  # overflow shows as non-finite geometry, checked there
                    sampled = [g for k in range(len(road.sections)) for g in _section_lanes(road, k, ctx)]
                for g in sampled:
                    self.geoms[g.key] = g
            except MapFormatError as exc:  # geometry that evaluates to nonsense: skip the road, like a bad road
                warnings.warn(f"skipping bad road: {exc}", stacklevel=3)
                self.geoms = {key: g for key, g in self.geoms.items() if key[0] != rid}
                del roads[rid]
        folded = [self.lane_id(key) for key, g in self.geoms.items() if g.folded]
        if folded:
            warnings.warn(f"{ctx.path}: {len(folded)} lane(s) fold round a bend tighter than their offset from the "
                          f"reference line; cut where they run backwards (first: lane {folded[0]})", stacklevel=3)
        if not roads:
            raise MapFormatError("no readable <road> elements", ctx.path)

    @staticmethod
    def lane_id(key: tuple[str, int, int]) -> str:
        return f"{key[0]}_{key[1]}_{key[2]}"

    # ---- topology -------------------------------------------------------------------------
    def _sec_at(self, road: _OdrRoad, end: str) -> int:
        return 0 if end == "low" else len(road.sections) - 1

    def _contacts(self) -> set[tuple[tuple, str, tuple, str]]:
        """Touching lane ends: ((road, sec, lane), 'low'|'high', (road, sec, lane), 'low'|'high')."""
        out = set()
        swapped: list[str] = []

        def add(a, ea, b, eb):
            if a in self.geoms and b in self.geoms and a != b:
                out.add((a, ea, b, eb))
        for road in self.roads.values():
            for k, sec in enumerate(road.sections):
                for lid, ln in sec.lanes.items():
                    if ln.successor is not None and k + 1 < len(road.sections):
                        add((road.id, k, lid), "high", (road.id, k + 1, ln.successor), "low")
                    if ln.predecessor is not None and k > 0:
                        add((road.id, k, lid), "low", (road.id, k - 1, ln.predecessor), "high")
            for kind, end in (("predecessor", "low"), ("successor", "high")):
                link = road.links.get(kind)
                if link is not None and link[0] == "road" and link[1] not in self.roads:
                    warnings.warn(f"{self.ctx.path}: road {road.id} <{kind}>: unknown road id {link[1]!r:.40}, "
                                  "link skipped", stacklevel=2)
                if link is None or link[0] != "road" or link[1] not in self.roads:
                    continue
                other = self.roads[link[1]]
                oend = self._contact_end(road, end, other, "high" if link[2] == "end" else "low", kind, swapped)
                k, ko = self._sec_at(road, end), self._sec_at(other, oend)
                targets = {lid: ln.successor if kind == "successor" else ln.predecessor
                           for lid, ln in road.sections[k].lanes.items()}
                if all(t is None for t in targets.values()):  # a road link without lane links
                    targets = self._implicit_targets(road, k, end, other, ko, oend)
                for lid, target in targets.items():
                    if target is not None:
                        add((road.id, k, lid), end, (other.id, ko, target), oend)
        for j in self.root.findall("junction"):
            for c in j.findall("connection"):
                # a direct junction (OpenDRIVE 1.7 `type="direct"`: a lane split or merge) links the
                # incoming road's lanes to the `linkedRoad`'s lanes themselves, with no connecting road
                other = c.get("connectingRoad") if c.get("connectingRoad") is not None else c.get("linkedRoad", "")
                inc, con = self.roads.get(c.get("incomingRoad", "")), self.roads.get(other)
                if inc is None or con is None:
                    if c.get("incomingRoad") is not None:
                        warnings.warn(f"{self.ctx.where(c, 'junction ' + str(j.get('id')) + ' <connection>')}: "
                                      "unknown road id, skipped", stacklevel=3)
                    continue
                cend = "high" if c.get("contactPoint") == "end" else "low"
                iend = self._incoming_end(inc, j.get("id"), con, cend)
                ki, kc = self._sec_at(inc, iend), self._sec_at(con, cend)
                for ll in c.findall("laneLink"):
                    try:
                        a, b = int(ll.get("from")), int(ll.get("to"))
                    except (TypeError, ValueError):
                        warnings.warn(f"{self.ctx.where(ll)}: bad laneLink, skipped", stacklevel=3)
                        continue
                    add((inc.id, ki, a), iend, (con.id, kc, b), cend)
        if swapped:
            shown = ", ".join(swapped[:5]) + (f" and {len(swapped) - 5} more" if len(swapped) > 5 else "")
            warnings.warn(f"{self.ctx.path}: {len(swapped)} road link(s) name the far end of the road they link to "
                          f"while its other end touches; read at the touching end ({shown})", stacklevel=3)
        return out

    def _ref_end(self, road: _OdrRoad, end: str) -> np.ndarray:
        """The reference line's point at `end` ('low': s = 0, 'high': s = length)."""
        x, y, _ = road.ref.eval([0.0 if end == "low" else road.length])
        return np.array([x[0], y[0]])

    def _contact_end(self, road: _OdrRoad, end: str, other: _OdrRoad, oend: str, kind: str,
                     swapped: list[str]) -> str:
        """The end of `other` that `road`'s link at `end` meets: the one its contactPoint names
        (`oend`), unless that end lies more than ROAD_CONTACT_M from `road`'s end while the other
        end lies within it. CommonRoad's OpenDRIVE export names the far end of 44 of 102 road links
        in ARG_Carcarana, and half its lanes then led nowhere; each one read otherwise is added
        to `swapped`."""
        here = self._ref_end(road, end)
        flip = "low" if oend == "high" else "high"
        if other.id == road.id or np.hypot(*(here - self._ref_end(other, oend))) <= ROAD_CONTACT_M:
            return oend
        if np.hypot(*(here - self._ref_end(other, flip))) <= ROAD_CONTACT_M:
            swapped.append(f"road {road.id} <{kind}> road {other.id}")
            return flip
        return oend

    def _implicit_targets(self, road: _OdrRoad, k: int, end: str, other: _OdrRoad, ko: int,
                          oend: str) -> dict[int, int | None]:
        """Lane targets of a road link that names no lane links (a connecting road whose lanes have
        no `<link>`): the other road's lane of the same id (the mirrored id where the roads meet
        head to head or tail to tail), where their ends lie within IMPLICIT_LANE_LINK_M."""
        flip = -1 if end == oend else 1
        out: dict[int, int | None] = {}
        for lid in road.sections[k].lanes:
            a, b = (road.id, k, lid), (other.id, ko, flip * lid)
            out[lid] = None
            if a in self.geoms and b in self.geoms:
                gap = np.hypot(*(self._end_point(a, end) - self._end_point(b, oend)))
                out[lid] = b[2] if gap <= IMPLICIT_LANE_LINK_M else None
        return out

    def _end_point(self, key: tuple[str, int, int], end: str) -> np.ndarray:
        """The centre point of lane `key` at its section's `end` ('low': its start s, 'high': its end s)."""
        c = self.geoms[key].centre
        return c[-1] if (end == "high") == self.roads[key[0]].along(key[2]) else c[0]

    def _incoming_end(self, inc: _OdrRoad, jid: str | None, con: _OdrRoad, cend: str) -> str:
        ends = [e for kind, e in (("predecessor", "low"), ("successor", "high"))
                if inc.links.get(kind, ("", "", ""))[:2] == ("junction", jid)]
        if len(ends) == 1:
            return ends[0]
        # unlinked or linked at both ends: the end nearest the connecting road's contact point
        cx, cy, _ = con.ref.eval([0.0 if cend == "low" else con.length])
        ix, iy, _ = inc.ref.eval([0.0, inc.length])
        d = np.hypot(ix - cx[0], iy - cy[0])
        return "low" if d[0] <= d[1] else "high"

    def _exit_end(self, key: tuple[str, int, int]) -> str:
        return "high" if self.roads[key[0]].along(key[2]) else "low"

    def _links(self) -> tuple[dict[str, list[str]], dict[str, list[str]]]:
        succ: dict[str, list[str]] = {}
        pred: dict[str, list[str]] = {}

        def link(a, b):
            la, lb = self.lane_id(a), self.lane_id(b)
            if lb not in succ.setdefault(la, []):
                succ[la].append(lb)
                pred.setdefault(lb, []).append(la)
        for a, ea, b, eb in sorted(self._contacts()):
            a_exit, b_exit = ea == self._exit_end(a), eb == self._exit_end(b)
            if a_exit and not b_exit:
                link(a, b)
            elif b_exit and not a_exit:
                link(b, a)
        return succ, pred

    # ---- junctions ------------------------------------------------------------------------
    @property
    def ours(self) -> bool:
        """Whether feat2map wrote this file (its header's vendor)."""
        header = self.root.find("header")
        return header is not None and header.get("vendor") == OPENDRIVE_VENDOR

    def _lane_notes(self, code: str, in_junction: bool) -> Iterable[tuple[str, str]]:
        """(piece lane id, value) of every lane's userData `code` in feat2map's own file, on the
        connecting roads (`in_junction`) or the other roads; nothing from other producers."""
        if not self.ours:
            return
        for rid, road in self.roads.items():
            if road.el is None or (road.junction is not None) != in_junction:
                continue
            for k, sec in enumerate(road.el.findall("lanes/laneSection")):
                for lane in sec.iter("lane"):
                    value = next((u.get("value") for u in lane.findall("userData") if u.get("code") == code), None)
                    if value is not None and (lane.get("id") or "").lstrip("-").isdigit():
                        yield self.lane_id((rid, k, int(lane.get("id")))), value

    def _declared_turns(self) -> dict[str, str]:
        """Lane id -> the turn feat2map's own file declares for a connecting road's lane
        (userData OPENDRIVE_TURN_CODE): OpenDRIVE has no turn, and geometry alone read the
        declared U-turns and straights of a round trip back as right and left turns."""
        return {lid: turn for lid, turn in self._lane_notes(OPENDRIVE_TURN_CODE, True) if turn in TURNS}

    def _junction_groups(self) -> dict[str, str]:
        """OpenDRIVE junction id -> merged junction id (elements whose lanes touch are one). A
        lane's area is taken with its borders' folds dropped (`unfold`, as the lanes are read):
        a fold's spike must not join two elements (a skewed merge lane, written back, spiked
        0.9 m past its end into the next element, 0.2 m on, and two junctions became one).
        feat2map's own files (header vendor) write one element per junction, named by the model's
        junction id: each is kept, under that id (a city's back-to-back junctions, GoMentum's 33,
        became 24 on re-reading its export, and ids J_0, ... came back as 1, ...)."""
        if self.ours:
            used = list(dict.fromkeys(r.junction for r in self.roads.values() if r.junction is not None))
            names = {j.get("id"): (j.get("name") or "").strip() for j in self.root.findall("junction")}
            named = [names.get(j) for j in used]
            if all(named) and len(set(named)) == len(named):
                return {j: str(n) for j, n in zip(used, named)}
            return {j: j for j in used}
        from shapely.ops import unary_union

        areas: dict[str, list[Any]] = {}
        for key, g in self.geoms.items():
            jid = self.roads[key[0]].junction
            if jid is None:
                continue
            centre = g.centre.tolist()
            left, right = (b if (u := unfold(b.tolist(), centre)) is None else np.asarray(u) for b in (g.left, g.right))
            poly = Polygon(np.vstack([left, right[::-1]])).buffer(0)
            areas.setdefault(jid, []).append(poly)
        shapes = {j: unary_union(p) for j, p in areas.items()}
        ids = list(shapes)
        parent = {j: j for j in ids}

        def find(j):
            while parent[j] != j:
                parent[j] = parent[parent[j]]
                j = parent[j]
            return j
        from shapely import STRtree

        tree = STRtree([shapes[j] for j in ids])
        for j in ids:
            for k in tree.query(shapes[j].buffer(JUNCTION_TOUCH_M), predicate="intersects"):
                a, b = find(j), find(ids[int(k)])
                if a != b:
                    parent[max(a, b, key=_id_key)] = min(a, b, key=_id_key)
        return {j: find(j) for j in ids}

    def _interior_roads(self, groups: dict[str, str]) -> dict[str, str]:
        """Ordinary roads shorter than MIN_ARM_LENGTH_M with both ends in one merged junction,
        road id -> that junction: pieces of the intersection, not arms (CARLA joins the
        elements of one intersection with centimetre roads). So are roads shorter than
        EDGE_STUB_LENGTH_M whose one end is a junction and whose other end is the map's edge
        (osm2xodr cuts OSM ways at the map's bounds 1.2 m past a junction): a car on one
        stands in the junction, so no route starts or ends there."""
        out = {}
        for r in self.roads.values():
            if r.junction is not None:
                continue
            if len(r.links) == 1 and r.length < EDGE_STUB_LENGTH_M:
                ((etype, eid, _),) = r.links.values()
                j = eid if etype == "junction" else self.roads[eid].junction if eid in self.roads else None
                if j is not None and groups.get(j) is not None:
                    out[r.id] = groups[j]
                continue
            if r.length >= MIN_ARM_LENGTH_M or len(r.links) != 2:
                continue
            ends = set()
            for etype, eid, _ in r.links.values():
                j = eid if etype == "junction" else self.roads[eid].junction if eid in self.roads else None
                ends.add(groups.get(j) if j is not None else None)
            only = next(iter(ends)) if len(ends) == 1 else None
            if only is not None:
                out[r.id] = only
        return out

    # ---- build ----------------------------------------------------------------------------
    def _chains(self, succ: dict[str, list[str]], pred: dict[str, list[str]]) -> list[list[tuple[str, int, int]]]:
        """Lane pieces of consecutive sections of one road joined one-to-one, in driving order."""
        keys = {self.lane_id(k): k for k in self.geoms}

        def nxt(lid: str) -> str | None:
            s = succ.get(lid, [])
            if len(s) == 1 and keys[s[0]][0] == keys[lid][0] and pred.get(s[0]) == [lid]:
                return s[0]
            return None
        has_prev = {n for lid in keys if (n := nxt(lid)) is not None}
        chains, seen = [], set()
        for lid in keys:
            if lid in has_prev or lid in seen:
                continue
            chain = [lid]
            while (n := nxt(chain[-1])) is not None and n not in seen and n not in chain:
                chain.append(n)
            seen.update(chain)
            chains.append([keys[c] for c in chain])
        for lid in keys:  # closed loops of pieces (ring roads): keep them as single pieces
            if lid not in seen:
                chains.append([keys[lid]])
        return chains

    def build(self) -> HDMap:
        piece_succ, piece_pred = self._links()
        groups = self._junction_groups()
        interior = self._interior_roads(groups)
        chains = self._chains(piece_succ, piece_pred)
        chain_of = {self.lane_id(k): self.lane_id(c[0]) for c in chains for k in c}
        self.chain_of = chain_of
        lanes: dict[str, Lane] = {}
        road_lanes: dict[str, tuple[list[str], list[str]]] = {}
        for chain in chains:
            lid = self.lane_id(chain[0])
            road_id = chain[0][0]
            parts = [self.geoms[k] for k in chain]

            def joined(attr: str, parts: list[_LaneGeom] = parts) -> np.ndarray:  # this chain's parts
                arrs = [getattr(g, attr) for g in parts]
                return np.vstack([arrs[0]] + [a[1:] for a in arrs[1:]])
            centre = joined("centre")
            seg = np.hypot(*np.diff(centre, axis=0).T)
            keep = np.concatenate([[True], seg > 1e-6])  # drop repeated points of empty sections
            if keep.sum() < 2:
                keep[-1] = True
            lens = [max(float(np.hypot(*np.diff(g.centre, axis=0).T).sum()), 1e-9) for g in parts]
            width = float(np.average([g.width for g in parts], weights=lens))
            odr_junction = self.roads[road_id].junction
            jid = groups.get(odr_junction) if odr_junction else interior.get(road_id)
            first, last = self.lane_id(chain[0]), self.lane_id(chain[-1])
            lanes[lid] = Lane(
                lid, road_id, as_polyline(centre[keep]), as_polyline(joined("left")[keep]),
                as_polyline(joined("right")[keep]), width, parts[0].speed,
                tuple(dict.fromkeys(chain_of[x] for x in piece_pred.get(first, ()))),
                tuple(dict.fromkeys(chain_of[x] for x in piece_succ.get(last, ()))),
                junction_id=jid, left_boundary_type="virtual" if jid else _longest(parts, "left_type"),
                right_boundary_type="virtual" if jid else _longest(parts, "right_type"))
            rl = road_lanes.setdefault(road_id, ([], []))
            (rl[0] if self.roads[road_id].along(chain[0][2]) else rl[1]).append(lid)
        self._neighbours(lanes, chain_of)
        self._declared_neighbours(lanes, chain_of)
        self.joined = _join_through(lanes, road_lanes, {lid for r in interior for g in road_lanes.get(r, ()) for lid in g})
        declared = self._declared_turns()
        for lid, ln in lanes.items():
            if ln.junction_id is not None:
                lanes[lid] = _replace(ln, turn=declared.get(lid) or _turn(ln, lanes))
        roads: dict[str, Road] = {}
        for rid, road in self.roads.items():
            right, left = road_lanes.get(rid, ([], []))
            if rid in road_lanes and not any(road_lanes[rid]):
                continue  # all its lanes were joined into junction lanes of other roads
            jid = groups.get(road.junction) if road.junction else interior.get(rid)
            ends = {}
            for kind in ("predecessor", "successor"):
                link = road.links.get(kind)
                if link and link[0] == "junction":
                    ends[kind] = groups.get(link[1], link[1] if link[1] in groups else None)
            kind = "junction" if jid else ("connection" if len(road.links) == 2 else "stub")
            roads[rid] = Road(rid, kind, tuple(right), tuple(left), None, 0.0, jid,
                              ends.get("predecessor", jid), ends.get("successor", jid))
        _filter_lanes_back(lanes, roads)
        junctions: dict[str, Junction] = {}
        members: dict[str, list[str]] = {}
        for odr, merged in groups.items():
            members.setdefault(merged, []).append(odr)
        for merged in sorted(members, key=_id_key):
            pts = np.array([p for ln in lanes.values() if ln.junction_id == merged
                            for p in ln.left_boundary + ln.right_boundary])
            meeting = self._centre(merged, lanes)
            if meeting is not None:  # centrally symmetric about the arms' meeting point
                pts = np.vstack([pts, 2 * meeting - pts])
            hull = MultiPoint(pts).convex_hull
            if hull.geom_type != "Polygon":
                warnings.warn(f"{self.ctx.path}: junction {merged}: degenerate area, skipped", stacklevel=2)
                continue
            junctions[merged] = Junction(merged, as_polyline(orient(hull, 1.0).exterior.coords[:-1]))
        for lid, ln in list(lanes.items()):  # drop links into skipped junctions' lanes
            if ln.junction_id is not None and ln.junction_id not in junctions:
                lanes[lid] = _replace(ln, junction_id=None)
        crosswalks = self._crosswalks(junctions)
        signals, stops, yields = self._signals(lanes, groups, junctions, list(crosswalks.values()))
        meta = {"source": self.ctx.path, "format": "opendrive",
                "junction_elements": {m: sorted(v, key=_id_key) for m, v in members.items()}}
        if self.signal_groups:
            meta["signal_groups"] = self.signal_groups
        return HDMap(lanes, roads, junctions, signals, stops, crosswalks, origin=self.origin, meta=meta,
                     yield_signs=yields)

    @staticmethod
    def _centre(merged: str, lanes: dict[str, Lane]) -> np.ndarray | None:
        """Least-squares meeting point of the lines along the lanes that enter and leave the
        junction, at their junction ends; None if they are (nearly) parallel. For feat2map's
        own maps (lanes centred on straight-in sockets) this is exactly the junction centre."""
        A, rhs = np.zeros((2, 2)), np.zeros(2)
        ends: dict[str, tuple[tuple[float, float], float]] = {}
        for ln in lanes.values():
            if ln.junction_id != merged:
                continue
            for p in ln.predecessors:
                if lanes[p].junction_id is None:
                    ends[p] = (lanes[p].end, lanes[p].heading_at_end())
            for q in ln.successors:
                if lanes[q].junction_id is None:
                    ends[q] = (lanes[q].start, lanes[q].heading_at_start())
        for (x, y), h in ends.values():
            n = np.array([-math.sin(h), math.cos(h)])
            A += np.outer(n, n)
            rhs += n * (n @ np.array([x, y]))
        if len(ends) < 2 or np.linalg.cond(A) > 1e6:
            return None
        return np.linalg.solve(A, rhs)

    def _neighbours(self, lanes: dict[str, Lane], chain_of: dict[str, str]) -> None:
        """Same-direction neighbours (ids differ by one on one side) and the reverse neighbour
        across the centre (left-hand traffic has it on the right, which the model does not hold)."""
        found: dict[str, dict[str, list[str]]] = {}
        for key in self.geoms:
            road, k, lid = key
            side = -1 if lid < 0 else 1
            out = -side if self.roads[road].lht else side  # lanes further out lie on the driver's right in RHT
            me = chain_of[self.lane_id(key)]
            centre = (road, k, -side) if abs(lid) == 1 and not self.roads[road].lht else None
            for attr, other in (("right_neighbors", (road, k, lid + out)), ("left_neighbors", (road, k, lid - out)),
                                ("left_reverse_neighbors", centre)):
                if other is not None and other[2] != 0 and other in self.geoms:
                    lst = found.setdefault(me, {}).setdefault(attr, [])
                    if chain_of[self.lane_id(other)] not in lst and chain_of[self.lane_id(other)] != me:
                        lst.append(chain_of[self.lane_id(other)])
        for target, upd in found.items():
            lanes[target] = _replace(lanes[target], **{k: tuple(v) for k, v in upd.items()})

    def _declared_neighbours(self, lanes: dict[str, Lane], chain_of: dict[str, str]) -> None:
        """Neighbours that feat2map's own file writes as lanes of other roads (userData
        OPENDRIVE_NEIGHBOURS_CODE, `left=ROAD:LANE,...;right=...;reverse=...`), added to those
        `_neighbours` finds: a real map's lanes are written one road each, and its approaches
        read back without their neighbours (lane changes, and arms: Shalun's J_15 split in two)."""
        attrs = {"left": "left_neighbors", "right": "right_neighbors", "reverse": "left_reverse_neighbors"}
        for piece, note in self._lane_notes(OPENDRIVE_NEIGHBOURS_CODE, False):
            me = chain_of.get(piece)
            if me is None or me not in lanes:
                continue
            for part in note.split(";"):
                kind, _, ends = part.partition("=")
                attr = attrs.get(kind.strip())
                if attr is None:
                    continue
                others = [chain_of.get(self.lane_id((r, 0, int(x)))) for r, _, x in (e.partition(":") for e in ends.split(","))
                          if x.lstrip("-").isdigit()]
                have = getattr(lanes[me], attr)
                add = tuple(o for o in others if o is not None and o in lanes and o != me and o not in have)
                if add:
                    lanes[me] = _replace(lanes[me], **{attr: have + add})

    def _pose(self, road: _OdrRoad, s: float, t: float) -> tuple[tuple[float, float], float]:
        s = min(max(s, 0.0), road.length)
        x, y, h = road.ref.eval([s])
        return (float(x[0] - t * math.sin(h[0])), float(y[0] + t * math.cos(h[0]))), float(h[0])

    def _resolve(self, ids: Iterable[str], lanes: dict[str, Lane], what: str) -> list[str]:
        """Lane ids as the built map holds them: a lane joined into junction lanes by
        `_join_through` stands for those; an id that resolves to nothing is skipped with a
        one-line warning naming `what` (never a KeyError further on)."""
        out: list[str] = []
        for lid in ids:
            todo, seen = [lid], set()
            found = []
            while todo:
                x = todo.pop()
                if x in seen:
                    continue
                seen.add(x)
                if x in lanes:
                    found.append(x)
                else:
                    todo += self.joined.get(x, [])
            if not found:
                warnings.warn(f"{what}: refers to lane {lid}, which the map does not hold, skipped", stacklevel=3)
            out += found
        return list(dict.fromkeys(out))

    def _signals(self, lanes: dict[str, Lane], groups: dict[str, str], junctions: dict[str, Junction],
                 crosswalks: list[Crosswalk]):
        """Signals, stop signs and yield signs, each attached to the incoming lanes it governs
        (the map's `orientation` and `validity` first); a signal governs where a sign shares its
        lanes (`signal_precedence`). Controllers that switch several signals together become
        `meta["signal_groups"]`. Unknown types are skipped with one warning per type. A light
        beside a mid-block crossing (`midblock_crossing`, its line across its lanes at its pole)
        belongs to no junction."""
        refs: dict[str, list[tuple[str, Any]]] = {}
        for r in self.roads.values():
            sig_el = r.el.find("signals")
            for sr in (sig_el.findall("signalReference") if sig_el is not None else []):
                if sr.get("id") is not None:
                    refs.setdefault(sr.get("id"), []).append((r.id, sr))
        incoming_ends = [ln for ln in lanes.values() if ln.junction_id is None
                         and any(lanes[s].junction_id for s in ln.successors)]
        ends = np.array([ln.end for ln in incoming_ends]) if incoming_ends else np.zeros((0, 2))
        made: dict[str, dict] = {kind: {} for kind in _CONTROL_CLASS}
        unknown: dict[tuple[str, str], int] = {}
        ident_of: dict[str, str] = {}
        seen: set[tuple] = set()  # (road, id, s, t, type, subtype, orientation) of the controls made
        twice: list[str] = []
        depends: dict[str, list[str]] = {}  # signal id -> the signals it controls (`<dependency>`)
        for r in self.roads.values():
            sig_el = r.el.find("signals")
            for s_el in (sig_el.findall("signal") if sig_el is not None else []):
                kind = signal_kind(s_el.get("type"), s_el.get("country"), s_el.get("dynamic"))
                sid = s_el.get("id")
                placed = (r.id, sid, *(s_el.get(a) for a in ("s", "t", "type", "subtype", "orientation")))
                if kind is not None and placed in seen:  # the same sign written twice (VIRES ROD does): one control
                    twice.append(f"road {r.id} <signal id={sid}>")
                    continue
                seen.add(placed)
                if sid is not None:
                    depends.setdefault(sid, []).extend(d.get("id") for d in s_el.findall("dependency") if d.get("id"))
                if kind is None:
                    if not known_non_control(s_el.get("type")):
                        key = ((s_el.get("type") or "").strip(), (s_el.get("country") or "").strip())
                        unknown[key] = unknown.get(key, 0) + 1
                    continue
                if sid is None:
                    continue
                try:
                    what = f"road {r.id} <signal id={sid}>"
                    pos, h = self._pose(r, self.ctx.num(s_el, "s", what=what), self.ctx.num(s_el, "t", 0.0, what=what))
                    _check_points([pos], self.ctx.where(s_el, what))
                except MapFormatError as exc:
                    warnings.warn(f"skipping bad signal: {exc}", stacklevel=2)
                    continue
                orientation = (s_el.get("orientation") or "+").strip()
                heading = positive_angle(h + (math.pi if orientation != "-" else 0.0))
                governed = self._governed(r, s_el, refs.get(sid, []), lanes)
                if not governed and len(ends):
                    d = np.hypot(ends[:, 0] - pos[0], ends[:, 1] - pos[1])
                    if orientation in ("+", "-"):  # only lanes whose traffic the signal faces
                        travel = heading + math.pi
                        facing = np.array([math.cos(ln.heading_at_end() - travel) > 0 for ln in incoming_ends])
                        d = np.where(facing, d, np.inf)
                    i = int(np.argmin(d))
                    if d[i] <= SIGNAL_SEARCH_M:
                        governed = [incoming_ends[i].id]
                jids = {j for j in (lanes[s].junction_id for g in governed for s in lanes[g].successors) if j}
                jid = sorted(jids, key=_id_key)[0] if jids else None
                line = self._stop_line(governed, lanes, pos)
                ident = sid if all(sid not in v for v in made.values()) else f"{r.id}_{sid}"
                made[kind][ident] = _CONTROL_CLASS[kind](ident, jid, line, pos, heading, tuple(governed))
                if kind == "signal" and crosswalks:  # a light beside a mid-block crossing: its line is there
                    there = line_across_at(lanes, governed, pos)
                    mid = _replace(made[kind][ident], junction_id=None, stop_line=there) if there else None
                    if mid is not None and midblock_crossing(lanes, crosswalks, mid):
                        made[kind][ident] = mid
                ident_of.setdefault(sid, ident)
        for (t, c), n in sorted(unknown.items()):
            static = SIGNAL_CODES.get(t) == "signal" or SIGNAL_CODES.get(t.lower()) == "signal"
            warnings.warn(f"{self.ctx.path}: {n} <signal> of type {t!r}" + (f" (country {c!r})" if c else "")
                          + (' marked dynamic="no": a sign or marking, not made a light' if static else
                             " not in the code tables: ignored, not made a control"), stacklevel=2)
        if twice:
            warnings.warn(f"{self.ctx.path}: {len(twice)} <signal> declared twice on its road with the same position "
                          f"and type (first: {twice[0]}): read once", stacklevel=2)
        signals = made["signal"]
        self.signal_groups = {**self._controller_groups(ident_of, signals),
                              **self._dependency_groups(depends, ident_of, signals)}
        return (signals, signal_precedence(lanes, signals, made["stop"], crosswalks),
                signal_precedence(lanes, signals, made["yield"], crosswalks))

    def _controller_groups(self, ident_of: dict[str, str], signals: dict) -> dict[str, list[str]]:
        """`<controller>` id -> the signals (lights) it switches together, where it holds two or more."""
        out: dict[str, list[str]] = {}
        for c in self.root.findall("controller"):
            ids = [ident_of[x] for x in (k.get("signalId") for k in c.findall("control"))
                   if x in ident_of and ident_of[x] in signals]
            ids = list(dict.fromkeys(ids))
            if len(ids) > 1 and c.get("id") is not None:
                out[f"controller {c.get('id')}"] = ids
        return out

    def _dependency_groups(self, depends: dict[str, list[str]], ident_of: dict[str, str],
                           signals: dict) -> dict[str, list[str]]:
        """`dependency <id>` -> a light and the lights it controls through its `<dependency>`
        elements (OpenDRIVE 1.6/1.7: the signal holding `<dependency id=X>` controls signal X,
        e.g. a light switching a secondary light): they switch together, like a controller's.
        A dependency on a signal the file does not hold is skipped with one warning; one on a
        sign (no light) switches nothing the env drives."""
        out: dict[str, list[str]] = {}
        for sid, deps in depends.items():
            missing = [x for x in deps if x not in depends]
            if missing:
                warnings.warn(f"{self.ctx.path}: <signal id={sid}>: <dependency> on unknown signal(s) "
                              f"{', '.join(missing)}, skipped", stacklevel=3)
            if sid not in ident_of or ident_of[sid] not in signals:
                continue
            ids = [ident_of[sid]] + [ident_of[x] for x in deps if x in ident_of and ident_of[x] in signals]
            ids = list(dict.fromkeys(ids))
            if len(ids) > 1:
                out[f"dependency {sid}"] = ids
        return out

    def _governed(self, road: _OdrRoad, s_el, refs: list, lanes: dict[str, Lane]) -> list[str]:
        """Incoming lanes a signal governs: via its placements on junction roads (the signal or
        its references), else the lanes of its own road of the direction it is valid for that
        enter a junction at their end (nearest the signal when it is valid for both)."""
        out: list[str] = []
        placements = [(road.id, s_el)] + refs
        what = self.ctx.where(s_el, f"road {road.id} <signal id={s_el.get('id')}>")
        for rid, el in placements:
            r = self.roads.get(rid)
            if r is None or r.junction is None:
                continue
            # junction lanes: govern their feeders
            for lid in self._resolve(self._valid_lanes(r, el, s_el).values(), lanes, what):
                out += [p for p in lanes[lid].predecessors if p in lanes and lanes[p].junction_id is None]
        if out:
            return list(dict.fromkeys(out))
        for rid, el in placements:
            r = self.roads.get(rid)
            if r is None or r.junction is not None:
                continue
            try:
                s = float(el.get("s", "0"))
            except ValueError:
                continue
            valid = self._valid_lanes(r, el, s_el)
            for end in sorted(("low", "high"), key=lambda e: abs(s - (0.0 if e == "low" else r.length))):
                sec = self._sec_at(r, end)
                keys = [(r.id, sec, lid) for lid in r.sections[sec].lanes
                        if (r.id, sec, lid) in self.geoms and self._exit_end((r.id, sec, lid)) == end]
                cands = self._resolve([self.chain_of[self.lane_id(k)] for k in keys if self.lane_id(k) in valid],
                                      lanes, what)
                cands = [c for c in cands if any(lanes[x].junction_id for x in lanes[c].successors if x in lanes)]
                if cands:
                    out += cands
                    break
        return list(dict.fromkeys(out))

    def _valid_lanes(self, road: _OdrRoad, el, signal_el=None) -> dict[str, str]:
        """Lane pieces (piece id -> chain id) a signal placement is valid for: the lanes its
        `<validity>` records name; without them (or only lane 0, the whole road), the lanes of
        the driving direction its `orientation` gives ("+": along the reference line, lanes
        with negative ids; "-": against it; "none": both). Declared lanes of the other
        direction than the orientation are dropped unless nothing else is left."""
        orientation = (el.get("orientation") or (signal_el.get("orientation") if signal_el is not None else None)
                       or "none").strip()
        side = -1 if orientation == "+" else 1 if orientation == "-" else 0
        side = -side if road.lht else side  # "+": the lanes driving along the reference line
        keys = [(road.id, k, lid) for k in range(len(road.sections)) for lid in road.sections[k].lanes
                if (road.id, k, lid) in self.geoms]
        keep: set[int] = set()
        for v in el.findall("validity"):
            try:
                a, b = sorted((int(v.get("fromLane")), int(v.get("toLane"))))
            except (TypeError, ValueError):
                continue
            keep |= set(range(a, b + 1))
        keep -= {0}
        if keep:
            declared = [k for k in keys if k[2] in keep]
            mine = [k for k in declared if side == 0 or k[2] * side > 0]
            keys = mine or declared
        elif side:
            keys = [k for k in keys if k[2] * side > 0]
        return {self.lane_id(k): self.chain_of[self.lane_id(k)] for k in keys}

    @staticmethod
    def _stop_line(governed: list[str], lanes: dict[str, Lane], pos) -> tuple:
        """Across the ends of the governed lanes (`stop_line_across`: in any listed order; a list
        such as 5, 4, 6 made a line of zero length)."""
        line = stop_line_across(lanes, governed)
        if line is not None:
            return line
        return as_polyline([pos, (pos[0] + 0.01, pos[1])])

    def _crosswalks(self, junctions: dict[str, Junction]) -> dict[str, Crosswalk]:
        polys = {jid: Polygon(j.polygon) for jid, j in junctions.items()}
        out: dict[str, Crosswalk] = {}
        for r in self.roads.values():
            obj_el = r.el.find("objects")
            for o in (obj_el.findall("object") if obj_el is not None else []):
                if (o.get("type") or "").lower() != "crosswalk":
                    continue
                oid = o.get("id") or f"{r.id}_cw{len(out)}"
                try:
                    poly = self._object_outline(r, o)
                    _check_points(poly, self.ctx.where(o, f"road {r.id} <object id={oid}>"))
                except MapFormatError as exc:
                    warnings.warn(f"skipping bad crosswalk: {exc}", stacklevel=2)
                    continue
                if len(poly) < 3:
                    warnings.warn(f"{self.ctx.where(o, f'road {r.id} <object id={oid}>')}: crosswalk without area, "
                                  "skipped", stacklevel=2)
                    continue
                shape = Polygon(poly).buffer(0)
                jid = next((j for j, p in polys.items() if p.intersects(shape)), None)
                ident = oid if oid not in out else f"{r.id}_{oid}"
                out[ident] = Crosswalk(ident, jid, as_polyline(poly))
        return out

    def _object_outline(self, r: _OdrRoad, o) -> list[tuple[float, float]]:
        what = f"road {r.id} <object id={o.get('id')}>"
        s, t = self.ctx.num(o, "s", what=what), self.ctx.num(o, "t", 0.0, what=what)
        (px, py), h = self._pose(r, s, t)
        h += self.ctx.num(o, "hdg", 0.0, what=what)
        outlines = o.findall("outline") + [x for os_ in o.findall("outlines") for x in os_.findall("outline")]
        for ol in outlines:
            local = ol.findall("cornerLocal")
            if local:
                c, sn = math.cos(h), math.sin(h)
                return [(px + self.ctx.num(k, "u", what=what) * c - self.ctx.num(k, "v", what=what) * sn,
                         py + self.ctx.num(k, "u", what=what) * sn + self.ctx.num(k, "v", what=what) * c) for k in local]
            road_pts = ol.findall("cornerRoad")
            if road_pts:
                return [self._pose(r, self.ctx.num(k, "s", what=what), self.ctx.num(k, "t", what=what))[0]
                        for k in road_pts]
        length, width = self.ctx.num(o, "length", 0.0, what=what), self.ctx.num(o, "width", 0.0, what=what)
        c, sn = math.cos(h), math.sin(h)
        return [(px + u * c - v * sn, py + u * sn + v * c)
                for u, v in ((-length / 2, -width / 2), (length / 2, -width / 2), (length / 2, width / 2),
                             (-length / 2, width / 2))] if length > 0 and width > 0 else []


def _join_through(lanes: dict[str, Lane], road_lanes: dict[str, tuple[list[str], list[str]]],
                  inner: set[str]) -> dict[str, list[str]]:
    """Replace every path junction lane -> interior lane -> junction lane by one junction lane
    (id `a+inner+b`, on a's road): a manoeuvre drives one junction lane from road to road. Only
    where the path is unambiguous (a leads into the interior lane alone, b comes from it alone);
    in place on `lanes` and the roads' lane lists. Returns removed lane -> the lanes it was
    joined into, so references to it (signals, validity records) can follow."""
    joined: dict[str, list[str]] = {}
    for mid in sorted(inner):
        ln = lanes.get(mid)
        if ln is None or not ln.predecessors or not ln.successors:
            continue
        ins = [lanes[p] for p in ln.predecessors]
        outs = [lanes[x] for x in ln.successors]
        if any(a.successors != (mid,) or a.junction_id != ln.junction_id for a in ins) or any(
                b.predecessors != (mid,) or b.junction_id != ln.junction_id for b in outs):
            continue
        for a in ins:
            for b in outs:
                parts = (a, ln, b)
                new = f"{a.id}+{mid}+{b.id}"
                cat = lambda attr, parts=parts: as_polyline(np.vstack(  # noqa: E731  (this join's parts)
                    [getattr(parts[0], attr)] + [getattr(x, attr)[1:] for x in parts[1:]]))
                lens = [max(x.length, 1e-9) for x in parts]
                for x in parts:
                    joined.setdefault(x.id, []).append(new)
                lanes[new] = Lane(new, a.road_id, cat("centerline"), cat("left_boundary"), cat("right_boundary"),
                                  float(np.average([x.width for x in parts], weights=lens)), a.speed_limit,
                                  a.predecessors, b.successors, junction_id=a.junction_id,
                                  left_boundary_type=a.left_boundary_type, right_boundary_type=a.right_boundary_type)
                for p in a.predecessors:
                    lanes[p] = _replace(lanes[p], successors=lanes[p].successors + (new,))
                for q in b.successors:
                    lanes[q] = _replace(lanes[q], predecessors=lanes[q].predecessors + (new,))
                group = road_lanes.setdefault(a.road_id, ([], []))
                (group[0] if a.id in group[0] else group[1]).append(new)
        gone = {mid} | {x.id for x in ins + outs}
        for k in gone:
            del lanes[k]
        for k, ln2 in list(lanes.items()):
            links = {f: tuple(x for x in getattr(ln2, f) if x not in gone) for f in
                     ("predecessors", "successors", "left_neighbors", "right_neighbors", "left_reverse_neighbors")}
            if any(links[f] != getattr(ln2, f) for f in links):
                lanes[k] = _replace(ln2, **links)
        for group in road_lanes.values():
            for side in group:
                side[:] = [x for x in side if x not in gone]
    return joined


def _check_points(points, where: str) -> None:
    """Points of a signal or object: finite and within the limit max_coordinate_m."""
    cap = limits().max_coordinate_m
    if any(not (math.isfinite(x) and math.isfinite(y) and abs(x) <= cap and abs(y) <= cap) for x, y in points):
        raise MapFormatError(f"position not finite or beyond the limit max_coordinate_m={cap:g}", where)


def _turn(ln: Lane, lanes: dict[str, Lane]) -> str:
    """left / right / uturn / none from the heading change along a junction lane (OpenDRIVE
    declares no turns); a U-turn also where the connection reverses direction between the road
    lanes it joins (the end of its predecessor to the start of its successor): SUMO's netconvert
    writes turnaround connections that turn 127 deg themselves and make up the rest with kinks at
    both ends."""
    turn = classify_turn(ln.heading_at_start(), ln.heading_at_end(), uturns=True)
    if turn == "uturn":
        return turn
    for p in ln.predecessors:
        for q in ln.successors:
            a, b = lanes.get(p), lanes.get(q)
            if a is None or b is None or a.junction_id is not None or b.junction_id is not None:
                continue
            if abs(math.degrees(wrap_angle(b.heading_at_start() - a.heading_at_end()))) >= UTURN_THRESHOLD_DEG:
                return "uturn"
    return turn


def _longest(parts: list[_LaneGeom], attr: str) -> str:
    """The boundary type `attr` of the longest of a lane's pieces (one type per lane side)."""
    return str(getattr(max(parts, key=lambda g: float(np.hypot(*np.diff(g.centre, axis=0).T).sum())), attr))


def _id_key(j: str) -> tuple[int, float, str]:
    try:
        return (0, float(j), j)
    except ValueError:
        return (1, 0.0, j)


def _replace(obj, **kw):
    from dataclasses import replace

    return replace(obj, **kw)


__all__ = ["read_opendrive", "SIGNAL_CODES", "signal_kind"]


def _filter_lanes_back(lanes: dict[str, Lane], roads: dict[str, Road]) -> None:
    """Filter lanes written as roads outside junctions (feat2map's export: between two direct
    junctions) back into their junction, in place: a road lane turning right whose one lane
    before it also goes on to junction J's entries, and whose one lane after it also comes out
    of J, within FILTER_LEAD_MAX_M (`extract.junctions_within`), becomes a lane of J."""
    from ...angles import turn_name, wrap_degrees
    from ...extract import junctions_within

    for lid, ln in list(lanes.items()):
        if ln.junction_id is not None or len(ln.predecessors) != 1 or len(ln.successors) != 1 \
                or len(ln.centerline) < 2 or turn_name(wrap_degrees(math.degrees(
                    ln.heading_at_end() - ln.heading_at_start()))) != "right":
            continue
        before, after = lanes.get(ln.predecessors[0]), lanes.get(ln.successors[0])
        if before is None or after is None or before.junction_id is not None or after.junction_id is not None:
            continue
        into = junctions_within(lanes, [x for x in before.successors if x != lid])
        out_of = junctions_within(lanes, [x for x in after.predecessors if x != lid], forward=False)
        common = sorted(into & out_of)
        if len(common) != 1:
            continue
        lanes[lid] = _replace(ln, junction_id=common[0], turn="right")
        road = roads.get(ln.road_id)
        if road is not None and road.lane_ids == (lid,):
            roads[road.id] = _replace(road, kind="junction", junction_id=common[0], start_junction=common[0],
                                      end_junction=common[0])

