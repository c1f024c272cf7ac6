"""Write an HDMap as ASAM OpenDRIVE 1.8 (.xodr); 1.7, 1.6 and 1.4 on request (`VERSIONS`) for
readers that want an older revision. Each is valid against its official schema (the schemas
asam-qc-opendrive ships) and passes that checker's semantic and geometry checks.

Every road's reference line is its cubic Bézier written as ONE `paramPoly3` with
pRange="normalized" and the Bézier's exact power-basis coefficients (no sampling); a road
without a Bézier falls back to a polyline of `line` geometries along its innermost lane
edge. Lanes: right lanes (negative ids) drive along the reference, left lanes against it;
the divider's lateral offset is the `laneOffset`. Each junction lane is its own connecting
road, listed in its `<junction>` with a connection and lane link; roads that split or merge
outside junctions meet in a direct junction (1.7 on). Signals and stop signs
sit at the end of the incoming lanes they govern, with one `<controller>` per traffic light;
crosswalks are `object type="crosswalk"` with local outlines. The geoReference is the UTM
zone of feat2map.config written as a transverse Mercator whose false origin puts the
file's (local) coordinates at the map's absolute UTM position. The output depends on the map
only (the header date is SOURCE_DATE_EPOCH or none), so the same map gives the same bytes.

What differs by revision: crosswalk outlines are `fillType="paint"` from 1.8 on (earlier
schemas have no value for paint, so they omit it); 1.4 has no road `rule` and wants integer
road-type speeds, so its road types carry none (lane speeds stay).
"""
from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ... import atomic
from ...angles import wrap_angle
from ...bezier import Bezier
from ...config import (OPENDRIVE_JOINT_TANGENT_M, OPENDRIVE_NEIGHBOURS_CODE, OPENDRIVE_TURN_CODE, OPENDRIVE_VENDOR,
                      OPENDRIVE_VERSIONS, UTM_ZONE)
from ...errors import Feat2MapError, MapFormatError
from ...model import HDMap, Lane, Polyline, Road, midblock_controls
from ..base import header_date
from ..lane_ends import closed_seams
from ..geo import local_tmerc, utm_origin

VERSIONS = OPENDRIVE_VERSIONS
STRAIGHT_RUN_TOL_RAD = 1e-6  # polyline segments turning less than this form one line geometry
WIDTH_PROFILE_TOL_M = 0.01  # a lane's written width follows its boundaries within this (linear pieces)
TRAFFIC_LIGHT_TYPE = "1000001"  # OpenDRIVE country code "OpenDRIVE": 3-light traffic signal
STOP_SIGN_TYPE = "206"
YIELD_SIGN_TYPE = "205"
_GL_X, _GL_W = np.polynomial.legendre.leggauss(16)
_ROAD_MARKS = {"solid_white": ("solid", "white"), "dotted_white": ("broken", "white"),
               "solid_yellow": ("solid", "yellow"), "dotted_yellow": ("broken", "yellow"),
               "curb": ("curb", "standard"), "virtual": ("none", "standard")}


def junction_ids(m: HDMap) -> dict[str, str]:
    """OpenDRIVE ids of the map's junctions: their own where every one is a distinct whole number
    (a map read from OpenDRIVE keeps its junction ids through a round trip), else 1, 2, ... in
    map order (readers such as CARLA's and netconvert's want whole numbers; the model id is
    written as the junction's `name`)."""
    own = list(m.junctions)
    if own and all(re.fullmatch(r"0|[1-9][0-9]*", j) for j in own):
        return {j: j for j in own}
    return {jid: str(i + 1) for i, jid in enumerate(own)}


def bezier_length(b: Bezier, pieces: int = 16) -> float:
    """Arc length by Gauss-Legendre quadrature (16 nodes on each of `pieces` sub-intervals)."""
    edges = np.linspace(0.0, 1.0, pieces + 1)
    mid, half = 0.5 * (edges[1:] + edges[:-1]), 0.5 * np.diff(edges)
    t = (mid[:, None] + half[:, None] * _GL_X[None, :]).ravel()
    d = b.derivative(t)
    speed = np.hypot(d[:, 0], d[:, 1]).reshape(pieces, -1)
    return float((speed * _GL_W[None, :]).sum(axis=1) @ half)


def param_poly3(b: Bezier) -> tuple[float, float, float, dict[str, float]]:
    """(x, y, hdg, coefficients) of the paramPoly3 (normalized p) equal to the Bézier B(p).

    With power coefficients a0..a3 (B = a0 + a1 p + a2 p^2 + a3 p^3) and the start heading h,
    the local curve is R(-h) (B(p) - a0): aU = aV = bV = 0 and the rest rotated exactly.
    """
    a = b._power
    d = a[1] if np.hypot(*a[1]) > 1e-12 else a[2] if np.hypot(*a[2]) > 1e-12 else a[3]
    h = math.atan2(d[1], d[0])
    c, s = math.cos(h), math.sin(h)
    coef = {}
    for k, name in enumerate("abcd"):
        u, v = (0.0, 0.0) if k == 0 else (c * a[k][0] + s * a[k][1], -s * a[k][0] + c * a[k][1])
        coef[f"{name}U"], coef[f"{name}V"] = u, v
    coef["bV"] = 0.0 if abs(coef["bV"]) < 1e-9 * max(1.0, abs(coef["bU"])) else coef["bV"]
    return float(a[0][0]), float(a[0][1]), h, coef


def _f(x: float) -> str:
    if not math.isfinite(x):  # never written as a made-up value
        raise Feat2MapError(f"refusing to write a non-finite number ({x}) to OpenDRIVE", "map")
    return repr(float(x))


class _Ref:
    """A road's reference line in the file: geometry elements, length, and sampled points."""

    widths: list[tuple[float, float, float]] | None = None  # (s, a, b) width pieces; None: ln.width throughout
    width_samples: tuple[np.ndarray, np.ndarray] | None = None  # (s, width) a one-lane polyline road writes

    def __init__(self, road: Road, m: HDMap) -> None:
        self.geoms: list[tuple[float, float, float, float, str, dict[str, float]]] = []
        if road.reference is not None:
            x, y, h, coef = param_poly3(road.reference)
            self.length = bezier_length(road.reference)
            self.geoms.append((0.0, x, y, h, "paramPoly3", coef))
            t = np.linspace(0.0, 1.0, 257)
            self.pts = road.reference.point(t)
            dense = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(self.pts, axis=0).T))])
            self.s = dense * (self.length / dense[-1]) if dense[-1] > 0 else dense
            self.heads = road.reference.heading(t)
            self.divider = _divider_offset(road, m)
        else:
            self._from_lanes(road, m)

    def _from_lanes(self, road: Road, m: HDMap) -> None:
        """Fallback for a one-lane road without a Bézier: its centreline as a polyline of
        lines, with the divider half a lane to the left (lane -1 along, lane 1 against)."""
        if len(road.lane_ids) != 1:
            raise MapFormatError("a road without a reference curve must have exactly one lane", f"road {road.id}")
        ln = m.lanes[road.lane_ids[0]]
        pts = np.asarray(ln.centerline, dtype=float)
        if road.left_lanes:
            pts = pts[::-1]
        seg = np.diff(pts, axis=0)
        keep = np.concatenate([[True], np.hypot(seg[:, 0], seg[:, 1]) > 1e-6])
        raw = pts[keep]
        joined = _joint_tangents(ln, m)
        pts = _merge_straight_runs(joined[::-1] if road.left_lanes else joined)
        seg = np.diff(pts, axis=0)
        ln_len = np.hypot(seg[:, 0], seg[:, 1])
        if len(ln_len) == 0:
            raise MapFormatError("lane geometry has no length", f"lane {ln.id}")
        heads = np.arctan2(seg[:, 1], seg[:, 0])
        s = np.concatenate([[0.0], np.cumsum(ln_len)])
        for i in range(len(ln_len)):
            self.geoms.append((float(s[i]), float(pts[i, 0]), float(pts[i, 1]), float(heads[i]), "line", {}))
        self.length = float(s[-1])
        self.pts, self.s = pts, s
        self.heads = np.append(heads, heads[-1])
        self.divider = ln.width / 2 if road.right_lanes else -ln.width / 2
        samples = _width_samples(ln, raw, keep, bool(road.left_lanes), self.length)
        if samples is not None and float(np.max(np.abs(samples[1] - ln.width))) > WIDTH_PROFILE_TOL_M:
            self.width_samples = samples
            self.widths = _width_pieces(*samples)
        elif samples is not None:  # within the tolerance of ln.width: one constant record
            self.width_samples = (samples[0], np.full(len(samples[0]), ln.width))

    def set_end_widths(self, start: float, end: float) -> None:
        """Make the written width `start` (`end`) at the reference's start (end), so a lane's
        borders meet those of the lane it continues (ASAM's
        lane_smoothness.contact_point_no_horizontal_gaps)."""
        assert self.width_samples is not None
        s, w = self.width_samples
        if abs(w[0] - start) <= 1e-9 and abs(w[-1] - end) <= 1e-9:
            return
        w = w.copy()
        w[0], w[-1] = start, end
        self.widths = _width_pieces(s, w)

    def project(self, p) -> tuple[float, float]:
        """(s, t) of a point: nearest sampled reference point, lateral offset along its normal."""
        d = np.hypot(self.pts[:, 0] - p[0], self.pts[:, 1] - p[1])
        i = int(np.argmin(d))
        h = self.heads[i]
        t = -(p[0] - self.pts[i, 0]) * math.sin(h) + (p[1] - self.pts[i, 1]) * math.cos(h)
        return float(self.s[i]), float(t)

    def heading_at(self, s: float) -> float:
        return float(np.interp(s, self.s, np.unwrap(self.heads)))


def _end_heading(points: Polyline, at_start: bool) -> float:
    """Heading of a polyline's first (last) chord."""
    p = np.asarray(points, dtype=float)
    a, b = (p[0], p[1]) if at_start else (p[-2], p[-1])
    return math.atan2(b[1] - a[1], b[0] - a[0])


def _merge_into(ln: Lane, m: HDMap) -> Lane | None:
    """The lane whose start `ln`'s end is aligned to: its first successor (the one its road links
    to) where that successor has other predecessors too (a merge: it keeps its own start)."""
    nxt = m.lanes.get(ln.successors[0]) if ln.successors else None
    return nxt if nxt is not None and len(nxt.predecessors) > 1 and len(nxt.centerline) >= 2 else None


def _start_aligned_to(ln: Lane, m: HDMap) -> Lane | None:
    """The lane whose written end `ln`'s start is aligned to: its first predecessor (the one its
    road links to), unless some predecessor's end is aligned to `ln` itself (a merge: `ln` keeps
    its own start). Where a lane fans out into lanes that others merge into too (GoMentum's
    back-to-back junctions), its end is aligned to its first successor only; the others start
    along that written end, which every predecessor they share ends on too."""
    prev = m.lanes.get(ln.predecessors[0]) if ln.predecessors else None
    if prev is None or len(prev.centerline) < 2:
        return None
    merged = (_merge_into(m.lanes[p], m) for p in ln.predecessors if p in m.lanes)
    return None if any(x is not None and x.id == ln.id for x in merged) else prev


def _deduplicated(ln: Lane) -> np.ndarray:
    """`ln`'s centreline without repeated points."""
    pts = np.asarray(ln.centerline, dtype=float)
    seg = np.diff(pts, axis=0)
    return pts[np.concatenate([[True], np.hypot(seg[:, 0], seg[:, 1]) > 1e-6])]


def _tail_heading(ln: Lane, m: HDMap, d: float = OPENDRIVE_JOINT_TANGENT_M) -> float | None:
    """The heading `_joint_tangents` gives `ln`'s last chord where it aligns it (None: its own)."""
    pts = _deduplicated(ln)
    nxt = _merge_into(ln, m)
    if nxt is None or len(pts) < 2 or np.hypot(*(pts[-1] - pts[-2])) <= 2 * d:
        return None
    return _end_heading(nxt.centerline, at_start=True)


def _joint_tangents(ln: Lane, m: HDMap, d: float = OPENDRIVE_JOINT_TANGENT_M) -> np.ndarray:
    """`ln`'s centreline (driving direction, repeated points dropped) starting with a chord of
    length `d` along its predecessor's end heading as written (`_start_aligned_to`), and ending with one along
    its first successor's start heading where that successor has other predecessors (it keeps its
    own start). A polyline road's lane borders at an end lie across its first (last) chord, so
    linked roads whose end chords differ by a few milliradians left centimetre gaps between their
    borders; each joint is aligned on one side only, to its neighbour's unchanged chord."""
    pts = _deduplicated(ln)
    if len(pts) < 2:
        return pts
    chords = np.hypot(*np.diff(pts, axis=0).T)
    head, tail = pts[:1], pts[-1:]
    prev = _start_aligned_to(ln, m)
    if prev is not None and chords[0] > 2 * d:
        h = _tail_heading(prev, m, d)
        h = _end_heading(prev.centerline, at_start=False) if h is None else h
        head = np.array([pts[0], pts[0] + d * np.array([math.cos(h), math.sin(h)])])
    h = _tail_heading(ln, m, d)
    if h is not None:
        tail = np.array([pts[-1] - d * np.array([math.cos(h), math.sin(h)]), pts[-1]])
    return np.concatenate([head, pts[1:-1], tail])


def _merge_straight_runs(pts: np.ndarray, tol_rad: float = STRAIGHT_RUN_TOL_RAD) -> np.ndarray:
    """`pts` without the inner points of straight runs (segments within `tol_rad` of the run's
    first heading): one `line` per run, not a chain of collinear ones (ASAM's
    performance.avoid_redundant_info)."""
    while len(pts) >= 3:  # again on the result: merged chords can end up within the tolerance of each other
        heads = np.arctan2(*np.diff(pts, axis=0).T[::-1])
        keep, run = [0], heads[0]
        for i in range(1, len(heads)):
            if abs(wrap_angle(heads[i] - run)) > tol_rad:
                keep.append(i)
                run = heads[i]
        if len(keep) + 1 == len(pts):
            break
        pts = pts[keep + [len(pts) - 1]]
    return pts


def _width_samples(ln: Lane, pts: np.ndarray, keep: np.ndarray, reverse: bool,
                   length: float) -> tuple[np.ndarray, np.ndarray] | None:
    """(s, width) of a lane along its centreline `pts` (in the written direction: reversed when
    `reverse`, the points `keep` selects), s scaled to the written `length`; at the two ends the
    width between the boundaries' end points, the cross-section the linked lanes share (the
    distance to a coarse boundary's first chord, slanted against the centreline's, falls short).
    None where the lane has no usable boundaries."""
    from shapely import LineString, distance, points

    if len(pts) < 2 or len(ln.left_boundary) < 2 or len(ln.right_boundary) < 2:
        return None
    left, right = np.asarray(ln.left_boundary, dtype=float), np.asarray(ln.right_boundary, dtype=float)
    if len(left) == len(right) == len(keep):  # boundaries sampled with the centreline: the exact widths
        w = np.hypot(*(left - right).T)
        w = (w[::-1] if reverse else w)[keep]
    else:
        p = points(pts)
        w = distance(LineString(left), p) + distance(LineString(right), p)
        ends = np.hypot(*(left[[0, -1]] - right[[0, -1]]).T)  # in driving direction
        w[0], w[-1] = ends[::-1] if reverse else ends
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])
    if s[-1] <= 0:
        return None
    return s * (length / s[-1]), w


def _width_pieces(s: np.ndarray, w: np.ndarray) -> list[tuple[float, float, float]]:
    """Linear pieces (s, width at s, slope) through the samples within WIDTH_PROFILE_TOL_M, ending
    exactly on the first and last sample."""
    breaks, i = [0], 0
    while i < len(s) - 1:
        j = i + 1
        while j + 1 < len(s):  # extend the piece while every point inside stays within the tolerance
            k = np.arange(i + 1, j + 1)
            line = w[i] + (w[j + 1] - w[i]) * (s[k] - s[i]) / max(s[j + 1] - s[i], 1e-12)
            if np.max(np.abs(line - w[k])) > WIDTH_PROFILE_TOL_M:
                break
            j += 1
        breaks.append(j)
        i = j
    return [(float(s[a]), float(w[a]), float((w[b] - w[a]) / max(s[b] - s[a], 1e-12)))
            for a, b in zip(breaks, breaks[1:])]


def _divider_offset(road: Road, m: HDMap) -> float:
    """Lateral offset (left positive) of the divider from the reference, from the lane positions."""
    b = road.reference
    assert b is not None
    if road.right_lanes:  # innermost right lane starts at the reference start
        ln = m.lanes[road.right_lanes[0]]
        p, h, sign = np.asarray(ln.start), float(b.heading(0.0)), 1.0
        q = b.p0
    elif road.left_lanes:  # innermost left lane ends at the reference start
        ln = m.lanes[road.left_lanes[0]]
        p, h, sign = np.asarray(ln.end), float(b.heading(0.0)), -1.0
        q = b.p0
    else:
        return 0.0
    lateral = -(p[0] - q[0]) * math.sin(h) + (p[1] - q[1]) * math.cos(h)
    return float(lateral + sign * ln.width / 2)


class _Writer:
    def __init__(self, m: HDMap, version: str = VERSIONS[0]) -> None:
        from lxml import etree

        if version not in VERSIONS:
            raise MapFormatError(f"unsupported OpenDRIVE version {version!r}: expected one of {', '.join(VERSIONS)}",
                                 "version")
        self.E = etree
        self.m = m = closed_seams(_filter_lanes_as_roads(m))  # linked lanes' borders meet at their contact points
        self.minor = int(version.split(".")[1])
        self.roads = export_roads(m)
        self.road_ids = {rid: str(i + 1) for i, rid in enumerate(self.roads)}
        self.junction_ids = junction_ids(m)
        self.refs = {rid: _Ref(r, m) for rid, r in self.roads.items()}
        self.odr_lane: dict[str, tuple[str, int]] = {}  # model lane -> (exported road, OpenDRIVE lane id)
        for rid, r in self.roads.items():
            for i, lid in enumerate(r.right_lanes):
                self.odr_lane[lid] = (rid, -(i + 1))
            for i, lid in enumerate(r.left_lanes):
                self.odr_lane[lid] = (rid, i + 1)
        missing = [lid for lid in m.lanes if lid not in self.odr_lane]
        if missing:
            raise MapFormatError(f"lane {missing[0]!r} belongs to no road's lane list", "map")
        self.direct = self._direct_junctions()
        self._meet_widths()

    def _meet_widths(self) -> None:
        """A one-lane polyline road's lane takes, at each end where `_joint_tangents` aligns it to
        a neighbour, that neighbour's written width: at its start its predecessor's end width (`_start_aligned_to`),
        at its end its first successor's start width where that successor has other predecessors.
        Linked lanes' borders then meet (ASAM's lane_smoothness.contact_point_no_horizontal_gaps);
        the source's cross-sections there can differ by decimetres (a coarse Apollo junction lane
        starts square to its own first chord, not to the lane it continues)."""
        def sampled(lid: str, at: str) -> float:  # the lane's width at its driving start/end as sampled
            ref = self.refs[self.odr_lane[lid][0]]
            if ref.width_samples is None:
                return self.m.lanes[lid].width
            return float(ref.width_samples[1][0 if self._lane_end(lid, at) == "start" else -1])

        def end_width(ln: Lane) -> float:  # the width written at the lane's driving end
            nxt = _merge_into(ln, self.m)
            return sampled(ln.id, "end") if nxt is None else sampled(nxt.id, "start")
        for rid, ref in self.refs.items():
            if ref.width_samples is None:
                continue
            ln = self.m.lanes[self.roads[rid].lane_ids[0]]
            prev = _start_aligned_to(ln, self.m)
            start = end_width(prev) if prev is not None else sampled(ln.id, "start")
            end = end_width(ln)
            ref.set_end_widths(*((end, start) if self.roads[rid].left_lanes else (start, end)))

    # -- helpers ------------------------------------------------------------------------------
    def sub(self, parent, tag: str, **attrs):
        el = self.E.SubElement(parent, tag)
        for k, v in attrs.items():
            el.set(k, v if isinstance(v, str) else _f(v))
        return el

    def _lane_end(self, lane_id: str, at: str) -> str:
        """'start' or 'end' of its road's reference where lane `lane_id` starts (at='start')/ends."""
        rid, odr = self.odr_lane[lane_id]
        along = odr < 0
        return ("start" if along else "end") if at == "start" else ("end" if along else "start")

    def _touching(self, road: Road, end: str) -> list[tuple[str, str]]:
        """(other lane, which of its ends touches here) for the lanes linked at the reference's
        `end` ('start'/'end') of `road`."""
        touching: list[tuple[str, str]] = []
        for lid in road.right_lanes:
            ln = self.m.lanes[lid]
            touching += [(x, "end") for x in ln.predecessors] if end == "start" else [(x, "start") for x in ln.successors]
        for lid in road.left_lanes:
            ln = self.m.lanes[lid]
            touching += [(x, "start") for x in ln.successors] if end == "start" else [(x, "end") for x in ln.predecessors]
        return touching

    def _direct_junctions(self) -> dict[tuple[str, str], str]:
        """(road, reference end) -> id of the direct junction written there: where more than two
        road ends outside junctions meet (a lane split or merge between roads), a road link would
        be ambiguous (ASAM's road.linkage.is_junction_needed), so they meet in a `type="direct"`
        junction (OpenDRIVE 1.7 on; older revisions have none and keep the road links)."""
        if self.minor < 7:
            return {}
        parent: dict[tuple[str, str], tuple[str, str]] = {}

        def find(e: tuple[str, str]) -> tuple[str, str]:
            while parent.setdefault(e, e) != e:
                parent[e] = parent[parent[e]]
                e = parent[e]
            return e
        ends = {(rid, end): self._touching(road, end) for rid, road in self.roads.items()
                if road.junction_id is None for end in ("start", "end")}
        # an end touching a junction lane links to that junction
        at_junction = {e for e, touching in ends.items() if any(self.m.lanes[x].junction_id for x, _ in touching)}
        for e, touching in ends.items():
            find(e)
            for other, at in touching:
                o = (self.odr_lane[other][0], self._lane_end(other, at))
                a, b = find(e), find(o)
                if a != b and e not in at_junction and o not in at_junction:
                    parent[max(a, b)] = min(a, b)
        groups: dict[tuple[str, str], list[tuple[str, str]]] = {}
        for e in parent:
            groups.setdefault(find(e), []).append(e)
        taken = [int(j) for j in self.junction_ids.values()]
        next_id = max(taken, default=0) + 1
        out: dict[tuple[str, str], str] = {}
        for group in groups.values():  # in road order: the same map gives the same ids
            if len(group) > 2:
                out.update({e: str(next_id) for e in group})
                next_id += 1
        return out

    def _road_link(self, rid: str, end: str):
        """(elementType, id, contactPoint) linked at road `rid`'s reference `end` ('start'/'end')."""
        road = self.roads[rid]
        touching = self._touching(road, end)
        if (rid, end) in self.direct:
            return ("junction", self.direct[(rid, end)], None)
        if road.junction_id is None:
            jids = [j for j in (self.m.lanes[x].junction_id for x, _ in touching) if j]
            fallback = road.start_junction if end == "start" else road.end_junction
            jid = jids[0] if jids else (fallback if fallback in self.junction_ids and not touching else None)
            if jid:
                return ("junction", self.junction_ids[jid], None)
        if not touching:
            return None
        other, at = touching[0]
        return ("road", self.road_ids[self.odr_lane[other][0]], self._lane_end(other, at))

    # -- document -----------------------------------------------------------------------------
    def build(self):
        m, E = self.m, self.E
        root = E.Element("OpenDRIVE")
        x0, y0, x1, y1 = m.bounds() if m.lanes else (0.0, 0.0, 0.0, 0.0)
        date = header_date()  # optional in OpenDRIVE; never the wall clock (same map, same bytes)
        header = self.sub(root, "header", revMajor="1", revMinor=str(self.minor), name="feat2map",
                          version="1.00", **({"date": date} if date else {}),
                          north=y1, south=y0, east=x1, west=x0, vendor=OPENDRIVE_VENDOR)
        geo = self.sub(header, "geoReference")
        geo.text = E.CDATA(geo_reference(m))
        signal_roads = self._place_signals()
        objects = self._place_crosswalks()
        for rid, road in self.roads.items():
            self._road(root, rid, road, signal_roads.get(rid, []), objects.get(rid, []))
        self._controllers(root)
        for jid in m.junctions:
            self._junction(root, jid)
        for djid in dict.fromkeys(self.direct.values()):
            self._direct_junction(root, djid)
        return root

    def _road(self, root, rid: str, road: Road, signals: list, objects: list) -> None:
        ref = self.refs[rid]
        jid = road.junction_id
        el = self.sub(root, "road", name=rid, length=ref.length, id=self.road_ids[rid],
                      junction=self.junction_ids[jid] if jid in self.junction_ids else "-1")
        if self.minor >= 5:
            el.set("rule", "RHT")
        link = self.sub(el, "link")
        for kind, end in (("predecessor", "start"), ("successor", "end")):
            lk = self._road_link(rid, end)
            if lk is not None:
                attrs = {"elementType": lk[0], "elementId": lk[1]}
                if lk[2]:
                    attrs["contactPoint"] = lk[2]
                self.sub(link, kind, **attrs)
        lanes = [self.m.lanes[x] for x in road.lane_ids]
        speed = max((ln.speed_limit for ln in lanes), default=0.0)
        typ = self.sub(el, "type", s=0.0, type="town")
        if speed > 0 and self.minor >= 5:
            self.sub(typ, "speed", max=speed, unit="m/s")
        pv = self.sub(el, "planView")
        for i, (s, x, y, h, kind, coef) in enumerate(ref.geoms):
            length = (ref.geoms[i + 1][0] if i + 1 < len(ref.geoms) else ref.length) - s
            g = self.sub(pv, "geometry", s=s, x=x, y=y, hdg=h, length=length)
            if kind == "paramPoly3":
                self.sub(g, "paramPoly3", **{k: coef[k] for k in ("aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV")},
                         pRange="normalized")
            else:
                self.sub(g, "line")
        self.sub(self.sub(el, "elevationProfile"), "elevation", s=0.0, a=0.0, b=0.0, c=0.0, d=0.0)
        self.sub(el, "lateralProfile")
        lanes_el = self.sub(el, "lanes")
        if ref.widths is None:
            self.sub(lanes_el, "laneOffset", s=0.0, a=ref.divider, b=0.0, c=0.0, d=0.0)
        else:  # a one-lane road of varying width: the divider stays half its width off the centreline
            sign = 1.0 if ref.divider >= 0 else -1.0
            for s, a, b in ref.widths:
                self.sub(lanes_el, "laneOffset", s=s, a=sign * a / 2, b=sign * b / 2, c=0.0, d=0.0)
        sec = self.sub(lanes_el, "laneSection", s=0.0)
        if road.left_lanes:
            left = self.sub(sec, "left")
            for lid in reversed(road.left_lanes):
                self._lane(left, lid)
        center = self.sub(sec, "center")
        c = self.sub(center, "lane", id="0", type="none", level="false")
        inner = lanes[0] if lanes else None
        mark = "solid_yellow" if road.right_lanes and road.left_lanes else (
            inner.left_boundary_type if inner else "solid_white")
        self._mark(c, mark)
        if road.right_lanes:
            right = self.sub(sec, "right")
            for lid in road.right_lanes:
                self._lane(right, lid)
        objs = self.sub(el, "objects")
        for obj in objects:
            objs.append(obj)
        sigs = self.sub(el, "signals")
        for s in signals:
            sigs.append(s)

    def _mark(self, lane_el, boundary: str) -> None:
        typ, colour = _ROAD_MARKS.get(boundary, ("solid", "standard"))
        self.sub(lane_el, "roadMark", sOffset=0.0, type=typ, weight="standard", color=colour, width=0.15,
                 laneChange="none" if typ == "solid" else "both")

    def _lane(self, parent, lid: str) -> None:
        ln = self.m.lanes[lid]
        odr = self.odr_lane[lid][1]
        el = self.sub(parent, "lane", id=str(odr), type="driving", level="false")
        link = self.sub(el, "link")
        # lane links name lanes of the linked road, so they exist only across road-road links
        # and inside junctions (connecting roads); an incoming road links to the junction itself
        rid = self.odr_lane[lid][0]
        # in the reference direction (the schema's order: predecessor, then successor); for a
        # left lane the driving successors are the reference predecessors
        along = (ln.predecessors, ln.successors) if odr < 0 else (ln.successors, ln.predecessors)
        for ref_kind, end, lanes in zip(("predecessor", "successor"), ("start", "end"), along):
            lk = self._road_link(rid, end)
            if lk is None or lk[0] != "road":
                continue
            for other in lanes:
                if self.road_ids[self.odr_lane[other][0]] == lk[1]:
                    self.sub(link, ref_kind, id=str(self.odr_lane[other][1]))
                    break
        widths = self.refs[self.odr_lane[lid][0]].widths
        for s, a, b in widths or [(0.0, ln.width, 0.0)]:
            self.sub(el, "width", sOffset=s, a=a, b=b, c=0.0, d=0.0)
        self._mark(el, ln.right_boundary_type)
        if ln.speed_limit > 0:
            self.sub(el, "speed", sOffset=0.0, max=ln.speed_limit, unit="m/s")
        if ln.junction_id is not None:  # the turn, which OpenDRIVE cannot say, for our reader (last: additional data)
            self.sub(el, "userData", code=OPENDRIVE_TURN_CODE, value=ln.turn)
        elsewhere = self._neighbours_elsewhere(ln, rid)
        if elsewhere:
            self.sub(el, "userData", code=OPENDRIVE_NEIGHBOURS_CODE, value=elsewhere)

    def _neighbours_elsewhere(self, ln: Lane, rid: str) -> str:
        """`left=ROAD:LANE,...;right=...;reverse=...`: the neighbours of road lane `ln` written as
        lanes of other roads (a map without reference lines writes each lane as its own road),
        for our reader; "" when none. Neighbours in the same road need no note."""
        if ln.junction_id is not None:
            return ""
        parts = []
        for kind, others in (("left", ln.left_neighbors), ("right", ln.right_neighbors),
                             ("reverse", ln.left_reverse_neighbors)):
            ends = [f"{self.road_ids[self.odr_lane[x][0]]}:{self.odr_lane[x][1]}" for x in others
                    if x in self.odr_lane and self.odr_lane[x][0] != rid]
            if ends:
                parts.append(f"{kind}={','.join(ends)}")
        return ";".join(parts)

    def _junction(self, root, jid: str) -> None:
        el = self.sub(root, "junction", id=self.junction_ids[jid], name=jid)
        n = 0
        for rid, road in self.roads.items():
            if road.junction_id != jid or not road.lane_ids:
                continue
            along = bool(road.right_lanes)
            first = self.m.lanes[road.lane_ids[0]]
            # incoming roads are ordinary roads (ASAM's junctions.connection.connect_road_no_incoming_road):
            # a connecting road fed straight from another junction's (adjacent Apollo junctions) is
            # linked to it by its road and lane links only
            feeders = [p for p in first.predecessors if self.m.lanes[p].junction_id is None]
            if not feeders:
                continue
            incoming = self.odr_lane[feeders[0]][0]
            conn = self.sub(el, "connection", id=str(n), incomingRoad=self.road_ids[incoming],
                            connectingRoad=self.road_ids[rid], contactPoint="start" if along else "end")
            n += 1
            for lid in road.lane_ids:
                for p in self.m.lanes[lid].predecessors:
                    if self.odr_lane[p][0] == incoming:
                        self.sub(conn, "laneLink", **{"from": str(self.odr_lane[p][1]), "to": str(self.odr_lane[lid][1])})
                        break
        for k, (cid, _) in enumerate(self.controllers.get(jid, [])):
            self.sub(el, "controller", id=cid, type="0", sequence=str(k))

    def _direct_junction(self, root, djid: str) -> None:
        """A direct junction: per pair (incoming road, linked road) one connection with the lane
        links from the incoming road's lanes that end there to the linked road's lanes they
        continue in (contactPoint: the linked road's end)."""
        el = self.sub(root, "junction", id=djid, type="direct")
        conns: dict[tuple[str, str], list[tuple[int, int]]] = {}
        for (rid, end), j in self.direct.items():
            if j != djid:
                continue
            for lid in self.roads[rid].lane_ids:
                if self._lane_end(lid, "end") != end:
                    continue
                for nxt in self.m.lanes[lid].successors:
                    other = self.odr_lane[nxt][0]
                    if self.direct.get((other, self._lane_end(nxt, "start"))) == djid:
                        conns.setdefault((rid, other), []).append((self.odr_lane[lid][1], self.odr_lane[nxt][1]))
        for n, ((inc, linked), pairs) in enumerate(conns.items()):
            contact = self._lane_end(next(x for x in self.roads[linked].lane_ids
                                          if self.odr_lane[x][1] == pairs[0][1]), "start")
            conn = self.sub(el, "connection", id=str(n), incomingRoad=self.road_ids[inc],
                            linkedRoad=self.road_ids[linked], contactPoint=contact)
            for a, b in pairs:
                self.sub(conn, "laneLink", **{"from": str(a), "to": str(b)})

    # -- signals, controllers, objects ----------------------------------------------------------
    def _signal_place(self, lane_ids, position, midblock: bool = False):
        """(model road, s, t, orientation, validity lanes) of a sign governing `lane_ids`: at the
        end of its lanes (their junction entry), or beside its pole for a light guarding a
        mid-block crossing (`midblock`)."""
        lanes = [lid for lid in lane_ids if lid in self.odr_lane and self.m.lanes[lid].junction_id is None]
        if lanes:
            rid = self.odr_lane[lanes[0]][0]
            ids = [self.odr_lane[x][1] for x in lanes if self.odr_lane[x][0] == rid]
            along = ids[0] < 0
            ref = self.refs[rid]
            if midblock:
                s, t = ref.project(position)
                return rid, s, t, "+" if along else "-", (min(ids), max(ids))
            s = ref.length if along else 0.0
            _, t = ref.project(position)
            h = ref.heading_at(s)
            p = ref.pts[-1] if along else ref.pts[0]
            t = -(position[0] - p[0]) * math.sin(h) + (position[1] - p[1]) * math.cos(h)
            return rid, s, t, "+" if along else "-", (min(ids), max(ids))
        best = None
        for rid, road in self.roads.items():
            if road.junction_id is not None:
                continue
            s, t = self.refs[rid].project(position)
            if best is None or abs(t) < abs(best[2]):
                best = (rid, s, t, "+", None)
        return best

    def _place_signals(self) -> dict[str, list]:
        out: dict[str, list] = {}
        self.controllers: dict[str, list[tuple[str, str]]] = {}
        next_id = 1
        midblock = midblock_controls(self.m)
        for kind, items in (("signal", self.m.signals), ("stop", self.m.stop_signs), ("yield", self.m.yield_signs)):
            for s in items.values():
                place = self._signal_place(s.lane_ids, s.position, kind == "signal" and s.id in midblock)
                if place is None:
                    continue
                rid, sv, tv, orient, valid = place
                sid = str(next_id)
                next_id += 1
                el = self.E.Element("signal")
                attrs = dict(s=sv, t=tv, id=sid, name=s.id, dynamic="yes" if kind == "signal" else "no",
                             orientation=orient, zOffset=0.0 if kind == "signal" else 2.0, country="OpenDRIVE",
                             type={"signal": TRAFFIC_LIGHT_TYPE, "stop": STOP_SIGN_TYPE, "yield": YIELD_SIGN_TYPE}[kind],
                             subtype="-1",
                             hOffset=0.0, pitch=0.0, roll=0.0, height=1.0 if kind == "signal" else 0.75,
                             width=0.5 if kind == "signal" else 0.75)
                for k, v in attrs.items():
                    el.set(k, v if isinstance(v, str) else _f(v))
                if valid is not None:
                    self.sub(el, "validity", fromLane=str(valid[0]), toLane=str(valid[1]))
                out.setdefault(rid, []).append(el)
                if kind == "signal" and s.junction_id in self.junction_ids:
                    self.controllers.setdefault(s.junction_id, []).append((f"{1000 + next_id}", sid))
        return out

    def _controllers(self, root) -> None:
        for jid, ctrls in self.controllers.items():
            for cid, sid in ctrls:
                c = self.sub(root, "controller", id=cid, name=f"{jid}_ctrl{sid}", sequence="0")
                self.sub(c, "control", signalId=sid, type="0")

    def _place_crosswalks(self) -> dict[str, list]:
        from shapely.geometry import Polygon

        out: dict[str, list] = {}
        for k, cw in enumerate(self.m.crosswalks.values()):
            if len(cw.polygon) < 3:
                continue
            c = Polygon(cw.polygon).centroid
            best = None
            for rid, road in self.roads.items():
                if road.junction_id is not None:
                    continue
                s, t = self.refs[rid].project((c.x, c.y))
                d = math.hypot(*(np.asarray((c.x, c.y)) - self.refs[rid].pts[np.argmin(np.abs(self.refs[rid].s - s))]))
                if best is None or d < best[0]:
                    best = (d, rid, s, t)
            if best is None:
                continue
            _, rid, s, t = best
            ref = self.refs[rid]
            h = ref.heading_at(s)
            i = int(np.argmin(np.abs(ref.s - s)))
            ox = ref.pts[i, 0] - t * math.sin(h)
            oy = ref.pts[i, 1] + t * math.cos(h)
            local = [((x - ox) * math.cos(h) + (y - oy) * math.sin(h), -(x - ox) * math.sin(h) + (y - oy) * math.cos(h))
                     for x, y in cw.polygon]
            us, vs = [p[0] for p in local], [p[1] for p in local]
            obj = self.E.Element("object")
            attrs = dict(id=str(k + 1), name=cw.id, type="crosswalk", s=s, t=t, zOffset=0.0, orientation="none",
                         hdg=0.0, pitch=0.0, roll=0.0, height=0.0, length=max(us) - min(us), width=max(vs) - min(vs))
            for key, v in attrs.items():
                obj.set(key, v if isinstance(v, str) else _f(v))
            if self.minor >= 5:  # 1.5 brought <outlines> and the outline's attributes
                ol = self.sub(self.sub(obj, "outlines"), "outline", id="0", outer="true", closed="true",
                              laneType="driving")
                if self.minor >= 8:
                    ol.set("fillType", "paint")
            else:
                ol = self.sub(obj, "outline")
            for j, (u, v) in enumerate(local):
                corner = self.sub(ol, "cornerLocal", u=u, v=v, z=0.0, height=0.0)
                if self.minor >= 5:
                    corner.set("id", str(j))
            out.setdefault(rid, []).append(obj)
        return out


@dataclass(frozen=True)
class OpenDriveIds:
    """How `to_opendrive` names the map's elements: what scenarios on the export refer to."""

    lanes: dict[str, tuple[str, int]]  # model lane id -> (road id, OpenDRIVE lane id)
    road_length: dict[str, float]  # road id -> reference line length
    signals: dict[str, str]  # model signal / stop sign id -> signal id


def opendrive_ids(m: HDMap) -> OpenDriveIds:
    """The ids `to_opendrive(m)` gives lanes, roads and signals (any version)."""
    w = _Writer(m)
    placed = w._place_signals()
    return OpenDriveIds({lid: (w.road_ids[rid], odr) for lid, (rid, odr) in w.odr_lane.items()},
                        {w.road_ids[rid]: ref.length for rid, ref in w.refs.items()},
                        {el.get("name"): el.get("id") for els in placed.values() for el in els})


def _filter_lanes_as_roads(m: HDMap) -> HDMap:
    """`m` with its filter lanes that leave their approach before the core (`extract_filters`)
    as roads outside junctions: an OpenDRIVE road end links to one element, and where a filter
    lane leaves (joins) a road the piece on to the core (from it) meets that road's end too, so
    the three meet in a direct junction (the reader gives such lanes back to their junction)."""
    from dataclasses import replace

    from ...extract import extract_filters

    early = [f.id for f in extract_filters(m) if f.early]
    if not early:
        return m
    lanes, roads = dict(m.lanes), dict(m.roads)
    for lid in early:
        ln = lanes[lid]
        lanes[lid] = replace(ln, junction_id=None)
        road = roads[ln.road_id]
        roads[road.id] = replace(road, junction_id=None, start_junction=None, end_junction=None)
    return replace(m, lanes=lanes, roads=roads)


def export_roads(m: HDMap) -> dict[str, Road]:
    """The roads as written: roads with a Bézier reference as they are; every lane of a road
    without one (maps read from other formats) becomes its own one-lane road, so its
    geometry survives exactly. Roads without lanes are dropped."""
    from dataclasses import replace

    out: dict[str, Road] = {}
    for rid, road in m.roads.items():
        if not road.lane_ids:
            continue
        if road.reference is not None:
            out[rid] = road
            continue
        for lid in road.lane_ids:
            along = lid in road.right_lanes
            out[f"{rid}/{lid}" if len(road.lane_ids) > 1 else rid] = replace(
                road, right_lanes=(lid,) if along else (), left_lanes=() if along else (lid,))
    return out


def geo_reference(m: HDMap) -> str:
    """UTM zone `UTM_ZONE` with a shifted false origin: file coordinates are local metres."""
    return local_tmerc(UTM_ZONE, utm_origin(m, UTM_ZONE, None, "opendrive export"))


def to_opendrive(m: HDMap, version: str = VERSIONS[0]) -> bytes:
    """The OpenDRIVE document (revision `version`, one of VERSIONS) of `m`, as UTF-8 bytes."""
    from lxml import etree

    root = _Writer(m, version).build()
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def write_opendrive(m: HDMap, path: str | Path, version: str = VERSIONS[0]) -> None:
    """Write `m` to `path` atomically as OpenDRIVE `version`."""
    atomic.write_bytes(path, to_opendrive(m, version))
