"""Apollo HD map reader (`base_map` / `sim_map`, binary or text) into the feat2map model.

Apollo stores relations in two places: lane links (predecessor/successor/neighbour ids) and
overlaps (pairs of objects: signal-lane, junction-lane, crosswalk-lane ...). Real maps rely
on the second: lanes carry no `junction_id` (membership comes from `road.junction_id`; junction-
lane overlaps also name approach lanes in Baidu-style maps, so they count only where roads say
nothing), signals, stop signs and yield signs overlap the incoming lanes or the junction's own
lanes (and usually the junction), and many crosswalks have no id and no overlaps (they are
linked to junctions geometrically). A signal governs where a sign shares its lanes.
Coordinates are UTM metres; a whole-metre origin is subtracted and kept in `HDMap.origin`. A map in
local metres (outside UTM's ranges) keeps its frame and origin (0, 0), as OpenDRIVE files do.
"""
from __future__ import annotations

import math
import warnings
from pathlib import Path
from typing import Any, Iterable

import numpy as np
from shapely import STRtree
from shapely.geometry import MultiPoint, Polygon
from shapely.geometry.polygon import orient

from . import schema as aps
from ...config import (APOLLO_CROSSWALK_LINK_M, APOLLO_JUNCTION_COVER_M, APOLLO_KMH_SPEED_MPS, UTM_EASTING,
                       UTM_NORTHING, limits)
from ...errors import LimitError, MapFormatError
from ...model import (Crosswalk, HDMap, Junction, Lane, Road, Signal, StopSign, YieldSign, as_polyline,
                      incoming_lanes, signal_precedence)
from ...semantics import loaded

# overlap kind -> (the Map field listing the elements, the model class)
_CONTROL_FIELDS = {"signal": ("signal", Signal), "stop_sign": ("stop_sign", StopSign),
                   "yield_sign": ("yield", YieldSign)}
_TURNS = {aps.Lane.NO_TURN: "none", aps.Lane.LEFT_TURN: "left", aps.Lane.RIGHT_TURN: "right",
          aps.Lane.U_TURN: "uturn"}
# lanes that are not for cars: read and checked, but not part of the driving network
_NON_DRIVING = {aps.Lane.BIKING, aps.Lane.SIDEWALK, aps.Lane.PARKING, aps.Lane.SHOULDER}
_BOUNDARY = {
    aps.LaneBoundaryType.DOTTED_WHITE: "dotted_white",
    aps.LaneBoundaryType.SOLID_WHITE: "solid_white",
    aps.LaneBoundaryType.DOTTED_YELLOW: "dotted_yellow",
    aps.LaneBoundaryType.SOLID_YELLOW: "solid_yellow",
    aps.LaneBoundaryType.DOUBLE_YELLOW: "solid_yellow",
    aps.LaneBoundaryType.CURB: "curb",
    aps.LaneBoundaryType.UNKNOWN: "virtual",
}


def _curve_points(curve: Any) -> np.ndarray:
    """All (x, y) points of an Apollo Curve, segments joined, repeated joints dropped."""
    pts: list[tuple[float, float]] = []
    for seg in curve.segment:
        for p in seg.line_segment.point:
            xy = (p.x, p.y)
            if not pts or xy != pts[-1]:
                pts.append(xy)
    return np.array(pts, dtype=float).reshape(-1, 2)


def _polygon_points(poly: Any) -> np.ndarray:
    return np.array([(p.x, p.y) for p in poly.point], dtype=float).reshape(-1, 2)


def _boundary_type(boundary: Any) -> str:
    """The model's type of a lane boundary: the first type it declares, whether or not it is
    `virtual` (Baidu-style maps mark every boundary virtual and declare DOTTED_WHITE between
    lanes a car may change between); "virtual" only where it declares none (or UNKNOWN)."""
    for bt in boundary.boundary_type:
        for t in bt.types:
            return _BOUNDARY.get(t, "virtual")
    return "virtual"


def _sample_width(lane: Any) -> float | None:
    """Mean lane width from Apollo's left/right width samples (None when absent)."""
    if not lane.left_sample or not lane.right_sample:
        return None
    left = sum(s.width for s in lane.left_sample) / len(lane.left_sample)
    right = sum(s.width for s in lane.right_sample) / len(lane.right_sample)
    return float(left + right)


def _boundary_width(centre: np.ndarray, left: np.ndarray, right: np.ndarray) -> float:
    """Mean distance between boundaries, measured at the boundary points nearest the centreline."""
    if len(left) == 0 or len(right) == 0:
        return 0.0
    mid = centre[len(centre) // 2]
    dl = np.hypot(*(left - mid).T).min()
    dr = np.hypot(*(right - mid).T).min()
    return float(dl + dr)



class _Reader:
    """One conversion: protobuf `Map` -> HDMap, with `where` naming the file in errors."""

    def __init__(self, pb: Any, where: str) -> None:
        self.pb = pb
        self.where = where

    def err(self, what: str, message: str) -> MapFormatError:
        return MapFormatError(message, f"{self.where}: {what}")

    def points(self, pts: np.ndarray, what: str) -> np.ndarray:
        """`pts` when finite and within the limit max_coordinate_m (checked before any geometry)."""
        cap = limits().max_coordinate_m
        if not np.isfinite(pts).all() or (len(pts) and float(np.abs(pts).max()) > cap):
            raise self.err(what, f"coordinates not finite or beyond the limit max_coordinate_m={cap:g}")
        return pts

    def warn(self, what: str, message: str) -> None:
        warnings.warn(f"{self.where}: {what}: {message}", stacklevel=3)

    # -- overlaps ----------------------------------------------------------------------------
    def _overlap_pairs(self, known: dict[str, set[str]]) -> dict[tuple[str, str], list[tuple[str, str, Any]]]:
        """(kind_a, kind_b) -> [(id_a, id_b, (object_a, object_b))] for every two-object overlap,
        kinds sorted; ids are checked against the elements the map defines."""
        pairs: dict[tuple[str, str], list[tuple[str, str, Any]]] = {}
        for ov in self.pb.overlap:
            objs: list[tuple[str, str, Any]] = []
            for obj in ov.object:
                kind = obj.WhichOneof("overlap_info")
                if kind is None:
                    raise self.err(f"overlap {ov.id.id!r}", f"object {obj.id.id!r} has no overlap info")
                kind = kind.removesuffix("_overlap_info")
                if not obj.id.id:  # SVL-era maps: a broken object, not a broken map
                    self.warn(f"overlap {ov.id.id!r}", f"holds a {kind} with an empty id, skipped")
                    objs = []
                    break
                if kind in known and obj.id.id not in known[kind]:
                    raise self.err(f"overlap {ov.id.id!r}", f"refers to unknown {kind} {obj.id.id!r}")
                objs.append((kind, obj.id.id, obj))
            objs.sort(key=lambda o: o[0])
            for i in range(len(objs)):
                for k in range(i + 1, len(objs)):
                    a, b = objs[i], objs[k]
                    pairs.setdefault((a[0], b[0]), []).append((a[1], b[1], (a[2], b[2])))
        return pairs

    def _membership(self, pairs, raw: dict[str, dict[str, np.ndarray]], lane_road: dict[str, str],
                    road_junction: dict[str, str | None], junction_ids: set[str]) -> dict[str, str]:
        """Lane id -> junction id for the lanes inside a junction.

        A lane's own `junction_id` says it; else its road's `junction_id` (a road without one is
        an ordinary road: Baidu-style maps draw junction polygons over the approach lanes, and
        their junction-lane overlaps name those road lanes too). Only lanes of maps whose roads
        name no junction at all, or lanes outside every road, fall back to junction-lane
        overlaps, and then only to an overlap that covers the whole lane."""
        roads_tell = any(road_junction.values())
        out: dict[str, str] = {}
        for jid, lid, (_, info) in pairs.get(("junction", "lane"), []):
            if roads_tell and lid in lane_road:
                continue
            li = info.lane_overlap_info
            length = float(np.hypot(*np.diff(raw[lid]["c"], axis=0).T).sum())
            if li.start_s <= APOLLO_JUNCTION_COVER_M and li.end_s >= length - APOLLO_JUNCTION_COVER_M:
                out.setdefault(lid, jid)
        for lid, rid in lane_road.items():
            if road_junction.get(rid):
                out[lid] = road_junction[rid]  # type: ignore[assignment]
        for ln in self.pb.lane:
            if ln.junction_id.id:
                if ln.junction_id.id not in junction_ids:
                    raise self.err(f"lane {ln.id.id!r}", f"junction_id {ln.junction_id.id!r} is unknown")
                out[ln.id.id] = ln.junction_id.id
        return out

    # -- main --------------------------------------------------------------------------------
    def read(self) -> HDMap:
        pb = self.pb
        if not pb.lane:
            raise self.err("map", "no lanes")
        raw: dict[str, dict[str, np.ndarray]] = {}
        for i, ln in enumerate(pb.lane):
            lid = ln.id.id
            if not lid:
                raise self.err(f"lane #{i}", "lane without id")
            if lid in raw:
                raise self.err(f"lane {lid!r}", "duplicate lane id")
            centre = _curve_points(ln.central_curve)
            if len(centre) < 2:
                raise self.err(f"lane {lid!r}", "central_curve has fewer than 2 points")
            raw[lid] = {"c": self.points(centre, f"lane {lid!r} central_curve"),
                        "l": self.points(_curve_points(ln.left_boundary.curve), f"lane {lid!r} left_boundary"),
                        "r": self.points(_curve_points(ln.right_boundary.curve), f"lane {lid!r} right_boundary")}
        allpts = np.vstack([r["c"] for r in raw.values()])
        lo, hi = allpts.min(axis=0), allpts.max(axis=0)
        absolute = (UTM_EASTING[0] <= lo[0] <= hi[0] <= UTM_EASTING[1]
                    and UTM_NORTHING[0] <= lo[1] <= hi[1] <= UTM_NORTHING[1])
        # absolute UTM: a whole-metre origin taken off; local metres (x from -400 to 200 under
        # `utm zone 0`): the map's own frame, placed at the export's origin as OpenDRIVE files are
        origin = (float(np.floor(lo[0])), float(np.floor(lo[1]))) if absolute else (0.0, 0.0)
        o = np.array(origin)

        # roads and junction membership
        lane_road: dict[str, str] = {}
        road_junction: dict[str, str | None] = {}
        road_lane_ids: dict[str, list[str]] = {}
        junction_ids = {j.id.id for j in pb.junction}
        for r in pb.road:
            rid = r.id.id
            jid = r.junction_id.id or None
            if jid is not None and jid not in junction_ids:
                raise self.err(f"road {rid!r}", f"junction_id {jid!r} is not a junction of this map")
            road_junction[rid] = jid
            ids = road_lane_ids.setdefault(rid, [])
            for sec in r.section:
                for lid in sec.lane_id:
                    if lid.id not in raw:
                        raise self.err(f"road {rid!r}", f"section lists unknown lane {lid.id!r}")
                    lane_road.setdefault(lid.id, rid)
                    ids.append(lid.id)
        known = {"lane": set(raw), "junction": junction_ids, "signal": {s.id.id for s in pb.signal},
                 "stop_sign": {s.id.id for s in pb.stop_sign}, "yield_sign": {s.id.id for s in getattr(pb, "yield")}}
        pairs = self._overlap_pairs(known)
        lane_junction = self._membership(pairs, raw, lane_road, road_junction, junction_ids)

        # junctions (polygon from the map, or the hull of its lanes)
        junctions: dict[str, Junction] = {}
        for j in pb.junction:
            jid = j.id.id
            pts = self.points(_polygon_points(j.polygon), f"junction {jid!r} polygon") - o
            # real maps draw self-touching outlines: kept as drawn, only an empty area is replaced
            if len(pts) < 3 or Polygon(pts).buffer(0).area <= 0:
                member = [raw[lid][k] - o for lid, jj in lane_junction.items() if jj == jid for k in ("l", "r", "c")]
                hull = MultiPoint(np.vstack(member)).convex_hull if member else None
                if hull is None or hull.geom_type != "Polygon":
                    self.warn(f"junction {jid!r}", "no usable polygon and no lanes, skipped")
                    continue
                self.warn(f"junction {jid!r}", "no polygon, using the hull of its lanes")
                pts = np.array(orient(hull, 1.0).exterior.coords[:-1])
            junctions[jid] = Junction(jid, as_polyline(pts))
        lane_junction = {lid: jid for lid, jid in lane_junction.items() if jid in junctions}

        # lanes (links to non-driving lanes are dropped with them)
        driving = {ln.id.id for ln in pb.lane if not (ln.HasField("type") and ln.type in _NON_DRIVING)}
        lanes: dict[str, Lane] = {}
        speeds = sorted(float(ln.speed_limit) for ln in pb.lane if ln.id.id in driving)
        unit = 1.0
        if speeds and speeds[len(speeds) // 2] > APOLLO_KMH_SPEED_MPS:  # converters writing km/h (60 = 60 km/h)
            unit = 1 / 3.6
            self.warn("map", f"median lane speed_limit {speeds[len(speeds) // 2]:g} m/s is implausible: read as km/h")
        for ln in pb.lane:
            lid = ln.id.id
            if lid not in driving:
                continue
            links: dict[str, Any] = {}  # Lane's link fields, passed as keywords
            for attr, field in (("predecessors", "predecessor_id"), ("successors", "successor_id"),
                                ("left_neighbors", "left_neighbor_forward_lane_id"),
                                ("right_neighbors", "right_neighbor_forward_lane_id"),
                                ("left_reverse_neighbors", "left_neighbor_reverse_lane_id")):
                link_ids = tuple(dict.fromkeys(x.id for x in getattr(ln, field)))
                bad = [x for x in link_ids if x not in raw]
                if bad:
                    raise self.err(f"lane {lid!r}", f"{field} refers to unknown lane {bad[0]!r}")
                links[attr] = tuple(x for x in link_ids if x in driving)
            r = raw[lid]
            centre, left, right = r["c"] - o, r["l"] - o, r["r"] - o
            bad = [x.width for x in list(ln.left_sample) + list(ln.right_sample) if not x.width >= 0.0]
            if bad:  # the mean width would hide it
                raise self.err(f"lane {lid!r}", f"width sample {bad[0]:g} m is negative or not a number")
            width = _sample_width(ln) or _boundary_width(centre, left, right)
            lanes[lid] = Lane(
                lid, lane_road.get(lid, lid), as_polyline(centre),
                as_polyline(left if len(left) >= 2 else centre), as_polyline(right if len(right) >= 2 else centre),
                width, float(ln.speed_limit) * unit, turn=_TURNS.get(ln.turn, "none"),
                junction_id=lane_junction.get(lid),
                left_boundary_type=_boundary_type(ln.left_boundary),
                right_boundary_type=_boundary_type(ln.right_boundary), **links)

        roads = self._roads(lanes, road_lane_ids, road_junction)
        signals = self._controls(pairs, lanes, junctions, "signal", o)
        stops = signal_precedence(lanes, signals, self._controls(pairs, lanes, junctions, "stop_sign", o))
        yields = signal_precedence(lanes, signals, self._controls(pairs, lanes, junctions, "yield_sign", o))
        crosswalks = self._crosswalks(pairs, lanes, junctions, o)
        header = pb.header
        meta = {"source": self.where, "format": "apollo",
                "projection": header.projection.proj,
                "version": header.version.decode("utf-8", "replace"),
                "vendor": header.vendor.decode("utf-8", "replace"),
                "district": header.district.decode("utf-8", "replace"),
                "non_driving_lanes": len(raw) - len(driving)}
        return HDMap(lanes, roads, junctions, signals, stops, crosswalks, origin=origin, meta=meta,
                     yield_signs=yields)

    def _roads(self, lanes: dict[str, Lane], road_lane_ids: dict[str, list[str]],
               road_junction: dict[str, str | None]) -> dict[str, Road]:
        """Roads with lanes split by direction: `right_lanes` along the first lane, `left_lanes`
        against it; end junctions from the lanes' links."""
        roads: dict[str, Road] = {}
        for rid, ids in road_lane_ids.items():
            ids = [x for x in dict.fromkeys(ids) if x in lanes]
            if not ids:
                continue
            ref = lanes[ids[0]]
            d0 = np.subtract(ref.end, ref.start)
            right = [x for x in ids if np.dot(np.subtract(lanes[x].end, lanes[x].start), d0) >= 0]
            left = [x for x in ids if x not in right]
            jid = road_junction.get(rid)
            start_j = next((lanes[p].junction_id for x in right for p in lanes[x].predecessors
                            if lanes[p].junction_id), None)
            end_j = next((lanes[s].junction_id for x in right for s in lanes[x].successors
                          if lanes[s].junction_id), None)
            kind = "junction" if jid else "chain"
            roads[rid] = Road(rid, kind, tuple(right), tuple(left), None, 0.0, jid,
                              jid or start_j, jid or end_j)
        for lid, ln in lanes.items():  # lanes outside any road get a road of their own
            if ln.road_id not in roads:
                roads[ln.road_id] = Road(ln.road_id, "junction" if ln.junction_id else "chain", (lid,),
                                         junction_id=ln.junction_id)
        return roads

    def _controls(self, pairs, lanes: dict[str, Lane], junctions: dict[str, Junction], kind: str,
                  o: np.ndarray) -> dict:
        """Signals, stop signs or yield signs with the incoming lanes they overlap and their junction."""
        governed: dict[str, list[str]] = {}
        for lid, sid, (obj, _) in pairs.get(("lane", kind), []):
            ln = lanes.get(lid)
            if ln is not None and ln.junction_id is not None and obj.lane_overlap_info.start_s > ln.length / 2:
                continue  # a line at a junction lane's end is that junction's exit: not its approaches' control
            governed.setdefault(sid, []).append(lid)
        named: dict[str, list[str]] = {}
        for jid, sid, _ in pairs.get(("junction", kind), []):
            if jid in junctions:  # not one skipped for lack of a polygon
                named.setdefault(sid, []).append(jid)
        items = getattr(self.pb, _CONTROL_FIELDS[kind][0])
        out: dict = {}
        for i, el in enumerate(items):
            sid = el.id.id
            if not sid:
                self.warn(f"{kind} #{i}", "empty id, skipped")
                continue
            line = next((self.points(p, f"{kind} {sid!r} stop_line") for p in (_curve_points(c) for c in el.stop_line)
                         if len(p) >= 2), None)
            if not governed.get(sid) and line is not None:  # the map ties it to no lane: its stop line tells
                governed[sid] = self._crossed_lanes(lanes, line - o)
            lane_ids = incoming_lanes(lanes, governed.get(sid, []))
            # its junction: the one its lanes lie in or lead into (junction overlaps of Baidu-style maps may
            # name a neighbour whose polygon reaches the stop line), preferring one it overlaps
            ahead = [j for x in governed.get(sid, []) if x in lanes for j in (
                [lanes[x].junction_id] if lanes[x].junction_id else [lanes[s].junction_id for s in lanes[x].successors])
                if j]
            jid = next((j for j in ahead if j in named.get(sid, ())), None) or next(
                iter(ahead + named.get(sid, [])), None)
            if line is None:
                if not lane_ids:
                    self.warn(f"{kind} {sid!r}", "no stop line and no lanes, skipped")
                    continue
                ends = np.array([lanes[x].end for x in lane_ids])
                line_local = np.vstack([ends.min(axis=0), ends.max(axis=0)])
            else:
                line_local = line - o
            pos = self._position(el, kind, o, line_local)
            heading = self._facing(lane_ids, lanes, line_local)
            cls = _CONTROL_FIELDS[kind][1]
            out[sid] = cls(sid, jid, as_polyline(line_local), pos, heading, lane_ids)
        return out

    def _crossed_lanes(self, lanes: dict[str, Lane], line: np.ndarray) -> list[str]:
        """The heuristic for a control whose overlaps name no lane (maps converted from other
        formats): the lanes its stop line crosses that enter a junction (road lanes whose
        successors lie in one, crossed in their second half; junction lanes crossed in their
        first half)."""
        from shapely.geometry import LineString

        if not hasattr(self, "_lane_tree"):
            self._lane_ids = list(lanes)
            self._lane_lines = [LineString(lanes[x].centerline) for x in self._lane_ids]
            self._lane_tree = STRtree(self._lane_lines)
        stop = LineString(line)
        out = []
        for k in self._lane_tree.query(stop, predicate="intersects"):
            ln = lanes[self._lane_ids[int(k)]]
            at = self._lane_lines[int(k)].project(stop.intersection(self._lane_lines[int(k)]).representative_point())
            if ln.junction_id is None and at >= ln.length / 2 and any(
                    lanes[x].junction_id for x in ln.successors if x in lanes):
                out.append(ln.id)
            elif ln.junction_id is not None and at <= ln.length / 2:
                out.append(ln.id)
        return out

    @staticmethod
    def _position(el: Any, kind: str, o: np.ndarray, line: np.ndarray) -> tuple[float, float]:
        if kind == "signal" and len(el.boundary.point) >= 1:
            pts = _polygon_points(el.boundary) - o
            if np.isfinite(pts).all():
                return (float(pts[:, 0].mean()), float(pts[:, 1].mean()))
        m = line.mean(axis=0)
        return (float(m[0]), float(m[1]))

    @staticmethod
    def _facing(lane_ids: Iterable[str], lanes: dict[str, Lane], line: np.ndarray) -> float:
        """The direction the control faces: against the traffic on its lanes at the stop line."""
        mid = line.mean(axis=0)
        for lid in lane_ids:
            pts = lanes[lid].points
            k = int(np.argmin(np.hypot(*(pts - mid).T)))
            a, b = pts[max(k - 1, 0)], pts[min(k + 1, len(pts) - 1)]
            return math.atan2(a[1] - b[1], a[0] - b[0])
        d = line[-1] - line[0]
        return math.atan2(-d[0], d[1])

    def _crosswalks(self, pairs, lanes: dict[str, Lane], junctions: dict[str, Junction],
                    o: np.ndarray) -> dict[str, Crosswalk]:
        """Crosswalks linked to a junction through the junction lanes they overlap, else
        geometrically (the nearest junction polygon within APOLLO_CROSSWALK_LINK_M); empty ids
        get a stable made-up one."""
        lanes_of: dict[str, list[str]] = {}
        for cid, lid, _ in pairs.get(("crosswalk", "lane"), []):
            lanes_of.setdefault(cid, []).append(lid)
        jids = list(junctions)
        polys = [Polygon(junctions[j].polygon) for j in jids]
        tree = STRtree(polys) if polys else None
        out: dict[str, Crosswalk] = {}
        for i, c in enumerate(self.pb.crosswalk):
            cid = c.id.id or f"crosswalk_unnamed_{i}"
            if cid in out:
                cid = f"{cid}_{i}"
            pts = self.points(_polygon_points(c.polygon), f"crosswalk {cid!r} polygon") - o
            if len(pts) < 3:
                self.warn(f"crosswalk {cid!r}", "polygon has fewer than 3 points, skipped")
                continue
            # a junction lane it overlaps; road lanes at a junction mouth do not tell which end
            jid = next((lanes[lid].junction_id for lid in (lanes_of.get(c.id.id, []) if c.id.id else [])
                        if lid in lanes and lanes[lid].junction_id), None)
            if jid is None and tree is not None:
                poly = Polygon(pts).buffer(0)
                near = tree.query(poly, predicate="dwithin", distance=APOLLO_CROSSWALK_LINK_M)
                if len(near):
                    jid = jids[int(min(near, key=lambda k: polys[k].distance(poly)))]
            out[cid] = Crosswalk(cid, jid, as_polyline(pts))
        return out


def base_map_file(path: str | Path) -> Path:
    """`path` itself for a file; for a map folder its base_map.bin, else base_map.txt."""
    path = Path(path)
    if path.is_dir():
        for name in ("base_map.bin", "base_map.txt"):
            if (path / name).is_file():
                return path / name
        raise MapFormatError("no base_map.bin or base_map.txt in this folder", str(path))
    if not path.exists():
        raise MapFormatError("no such map folder or file", str(path))
    return path


def read_apollo(path: str | Path) -> HDMap:
    """Read an Apollo HD map (binary or text protobuf, Apollo 5-9): a file, or a map folder's
    base_map, into an HDMap."""
    path = base_map_file(path)
    try:
        limits().check("max_file_bytes", path.stat().st_size, "the file size (bytes)")
        data = path.read_bytes()
    except OSError as exc:
        raise MapFormatError(f"cannot read ({exc.strerror})", str(path)) from None
    except LimitError as exc:
        raise LimitError(exc.message, str(path)) from None
    pb = aps.parse_map(data, str(path))
    return loaded(_Reader(pb, str(path)).read(), str(path))


def read_apollo_bytes(data: bytes, where: str = "<bytes>") -> HDMap:
    """Like `read_apollo`, from the file's content."""
    return loaded(_Reader(aps.parse_map(data, where), where).read(), where)
