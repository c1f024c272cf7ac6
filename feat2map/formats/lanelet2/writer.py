"""Write an HDMap as a Lanelet2 map (OSM XML) for Autoware, with `map_projector_info.yaml`.

Lanelets: one per lane (subtype road; junction lanes tagged with Autoware's `turn_direction`)
and one per crosswalk (subtype crosswalk, for pedestrians). Neighbouring lanes share one
boundary linestring (the opposite lane's too), and lanes that follow each other share their end
points, which is how Lanelet2 finds lane changes and successors. Boundary types follow the
model's markings: line_thin solid/dashed (white or yellow), curbstone, virtual inside junctions.

Regulatory elements: a traffic_light per signal (the light, its stop line as ref_line),
referenced by the lanes it governs; an all_way_stop per junction whose every approach has a
stop sign (yield: the approach lanes, one stop line each, refers: the signs), else a
right_of_way per stop sign (its lanes yield to the unsigned approaches); at a junction without
signals or stop signs, a right_of_way per approach with left turns: its left-turning junction
lanes yield to the straight and right-turning lanes of the other approaches, at the approach's
entry line (the env's rule).

Coordinates: nodes carry lat/lon (WGS84) of the map's UTM position, plus Autoware's
`local_x`/`local_y`/`ele` tags. Beside the .osm goes Autoware's `map_projector_info.yaml`
(projector_type LocalCartesianUTM, map_origin = the map's (0, 0)), so Autoware and Lanelet2's
`UtmProjector(Origin(lat, lon))` both give back the map's local metres. Element ids are
assigned in map order, so the same map gives the same bytes.
"""
from __future__ import annotations

import math
import re
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np

from ... import atomic
from ...config import (APOLLO_SIGNAL_HEAD_SIZE_M, APOLLO_SIGNAL_HEIGHT_M, LANELET2_MERGE_M, STOP_SIGN_HEIGHT_M,
                       STOP_SIGN_SIZE_M, UTM_ZONE)
from ...errors import Feat2MapError
from ...model import Crosswalk, HDMap, Lane, incoming_lanes
from ..geo import utm_origin, utm_to_latlon
from ..lane_ends import between, lane_ends

PROJECTOR_INFO = "map_projector_info.yaml"  # Autoware reads it from the map folder
TAG = "feat2map:"  # our own tags: lane, road, junction, from/to (a junction lane's entry/exit roads), crosswalk
STOP_SIGN_SUBTYPE = "usR1-1"  # MUTCD stop sign (Lanelet2: ISO country code + sign number)
YIELD_SIGN_SUBTYPE = "usR1-2"  # MUTCD yield sign
TURN_DIRECTION = {"none": "straight", "left": "left", "right": "right", "uturn": "left"}
ROUND_TRIP_M = 1e-3  # lat/lon round trip error allowed for near lane ends; unlinked ends this close are one node
END_CLEAR_M = 2 * LANELET2_MERGE_M  # a bound's inner points keep this far from lane ends and each other: clear of
# LANELET2_MERGE_M after the lat/lon round trip
_LINES = {"solid_white": {"type": "line_thin", "subtype": "solid", "color": "white"},
          "dotted_white": {"type": "line_thin", "subtype": "dashed", "color": "white"},
          "solid_yellow": {"type": "line_thin", "subtype": "solid", "color": "yellow"},
          "dotted_yellow": {"type": "line_thin", "subtype": "dashed", "color": "yellow"},
          "curb": {"type": "curbstone", "subtype": "high"},
          "virtual": {"type": "virtual"}}


class _Osm:
    """Nodes, ways and relations under one id counter. Lane ends are nodes by exact position
    (`lane_ends` places linked ends at one); other points closer than `LANELET2_MERGE_M` to an
    existing node at their height are that node (stop lines end on lane bounds)."""

    def __init__(self) -> None:
        self.next_id = 1
        self.nodes: dict[int, tuple[float, float, float]] = {}
        self.ways: dict[int, tuple[list[int], dict[str, str]]] = {}
        self.relations: dict[int, tuple[list[tuple[str, int, str]], dict[str, str]]] = {}
        self._grid: dict[tuple[int, int, float], list[int]] = {}  # (cell x, cell y, height) -> nodes
        self._ends: dict[tuple[float, float], int] = {}
        self._reserved: dict[tuple[int, int], list[tuple[float, float]]] = {}  # every lane end, by cell
        self._end_cells: dict[tuple[int, int], int] = {}  # end nodes by millimetre cell

    def reserve_ends(self, points: Iterable[tuple[float, float]]) -> None:
        """Register every lane end before any way is written: a bound's inner point near another
        lane's end (an end tangent sample beside where a new lane opens) is dropped, not made a
        node 5 cm from that end's node (lanelet2_validation: points too close)."""
        r = END_CLEAR_M
        for x, y in points:
            self._reserved.setdefault((math.floor(x / r), math.floor(y / r)), []).append((float(x), float(y)))

    def _near_end(self, p: tuple[float, float]) -> bool:
        """Whether `p` lies within END_CLEAR_M of a lane end (`reserve_ends`)."""
        r = END_CLEAR_M
        cx, cy = math.floor(p[0] / r), math.floor(p[1] / r)
        return any(math.dist(p, q) < r for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                   for q in self._reserved.get((cx + dx, cy + dy), ()))

    def _id(self) -> int:
        self.next_id += 1
        return self.next_id - 1

    def _new(self, x: float, y: float, z: float) -> int:
        nid = self._id()
        self.nodes[nid] = (float(x), float(y), float(z))
        cell = (math.floor(x / LANELET2_MERGE_M), math.floor(y / LANELET2_MERGE_M), z)
        self._grid.setdefault(cell, []).append(nid)
        return nid

    def node(self, x: float, y: float, z: float = 0.0) -> int:
        """The node at height z within `LANELET2_MERGE_M` of (x, y) (the nearest), else a new node."""
        cx, cy = math.floor(x / LANELET2_MERGE_M), math.floor(y / LANELET2_MERGE_M)
        near = [(math.hypot(self.nodes[n][0] - x, self.nodes[n][1] - y), n)
                for dx in (-1, 0, 1) for dy in (-1, 0, 1) for n in self._grid.get((cx + dx, cy + dy, z), ())]
        best = min(near, default=None)
        if best is not None and best[0] < LANELET2_MERGE_M:
            return best[1]
        return self._new(x, y, z)

    def end_node(self, x: float, y: float) -> int:
        """The node of a lane end at exactly (x, y)."""
        key = (float(x), float(y))
        if key not in self._ends:  # unlinked ends at one place (within float noise) are one node too
            cell = (round(x / ROUND_TRIP_M), round(y / ROUND_TRIP_M))
            same = [self._end_cells[(cell[0] + dx, cell[1] + dy)] for dx in (-1, 0, 1) for dy in (-1, 0, 1)
                    if (cell[0] + dx, cell[1] + dy) in self._end_cells]
            self._ends[key] = next((n for n in same if math.hypot(self.nodes[n][0] - x, self.nodes[n][1] - y)
                                    < ROUND_TRIP_M), None) or self._new(x, y, 0.0)
            self._end_cells.setdefault(cell, self._ends[key])
        return self._ends[key]

    def way(self, points: Sequence[Sequence[float] | np.ndarray], tags: dict[str, str], z: float = 0.0,
            lane_ends: bool = False) -> int:
        """A linestring through `points`; with `lane_ends`, its first and last point are lane
        ends and a point within END_CLEAR_M (twice `LANELET2_MERGE_M`) of the one before, of the
        end or of any lane's end (`reserve_ends`) is dropped (end tangent samples, joints of lanes
        read from other formats)."""
        pts = [(float(p[0]), float(p[1])) for p in points]
        if lane_ends and len(pts) > 2:  # keep points END_CLEAR_M apart
            kept = [pts[0]]
            for p in pts[1:-1]:
                if math.dist(p, kept[-1]) >= END_CLEAR_M and math.dist(p, pts[-1]) >= END_CLEAR_M \
                        and not self._near_end(p):
                    kept.append(p)
            pts = kept + [pts[-1]]
        ids: list[int] = []
        for k, (x, y) in enumerate(pts):
            nid = self.end_node(x, y) if lane_ends and k in (0, len(pts) - 1) else self.node(x, y, z)
            if not ids or ids[-1] != nid:
                ids.append(nid)
        wid = self._id()
        self.ways[wid] = (ids, dict(tags))
        return wid

    def relation(self, members: list[tuple[str, int, str]], tags: dict[str, str]) -> int:
        rid = self._id()
        self.relations[rid] = (members, dict(tags))
        return rid

    def ends(self, wid: int) -> tuple[int, int]:
        ids = self.ways[wid][0]
        return ids[0], ids[-1]


class _Writer:
    def __init__(self, m: HDMap) -> None:
        self.m = m
        self.osm = _Osm()
        self.bound: dict[tuple[str, str], int] = {}  # (lane id, "left"/"right") -> way
        self.lanelet: dict[str, int] = {}  # lane id -> lanelet relation
        self.ends = lane_ends(m)  # where linked lanes meet: one node each
        self.osm.reserve_ends(self.ends.values())

    # -- lanelets ----------------------------------------------------------------------------
    def build(self) -> None:
        for lid in dict.fromkeys(lid for lid, _, _ in self.ends):  # lanes with two-point bounds, map order
            self._lane(self.m.lanes[lid])
        for cw in self.m.crosswalks.values():
            self._crosswalk(cw)
        for s in self.m.signals.values():
            self._traffic_light(s)
        self._stop_junctions()
        self._yield_signs()
        self._bare_junctions()

    def _lane(self, ln: Lane) -> None:
        m = self.m
        tags = {"type": "lanelet", "subtype": "road", "location": "urban", "one_way": "yes",
                "speed_limit": f"{ln.speed_limit * 3.6:.2f}".rstrip("0").rstrip("."),
                TAG + "lane": ln.id, TAG + "road": ln.road_id}
        if ln.junction_id is not None:
            tags["turn_direction"] = TURN_DIRECTION.get(ln.turn, "straight")
            tags[TAG + "junction"] = ln.junction_id
            for key, links in (("from", ln.predecessors), ("to", ln.successors)):
                roads = dict.fromkeys(m.lanes[x].road_id for x in links if x in m.lanes and m.lanes[x].junction_id is None)
                if roads:
                    tags[TAG + key] = ";".join(roads)
        members = [("way", self._boundary(ln, "left"), "left"), ("way", self._boundary(ln, "right"), "right")]
        self.lanelet[ln.id] = self.osm.relation(members, tags)

    def _boundary(self, ln: Lane, side: str) -> int:
        """The way of a lane's boundary: its neighbour's across that boundary when the two lie on
        one line (same-direction neighbours share left/right, opposite lanes their left bounds)."""
        start, end = self.ends[(ln.id, side, "start")], self.ends[(ln.id, side, "end")]
        pts = [start, *between(ln.left_boundary if side == "left" else ln.right_boundary, start, end), end]
        if side == "left":
            partners = [(n, "right") for n in ln.left_neighbors] + [(n, "left") for n in ln.left_reverse_neighbors]
        else:
            partners = [(n, "left") for n in ln.right_neighbors]
        for other, other_side in partners:
            wid = self.bound.get((other, other_side))
            if wid is not None and _same_ends(self.osm, wid, pts):
                self.bound[(ln.id, side)] = wid
                return wid
        kind = ln.left_boundary_type if side == "left" else ln.right_boundary_type
        wid = self.osm.way(pts, _LINES.get(kind, _LINES["solid_white"]), lane_ends=True)
        self.bound[(ln.id, side)] = wid
        return wid

    def _crosswalk(self, cw: Crosswalk) -> None:
        sides = cw.sides()
        if sides is None:
            return
        line = {"type": "pedestrian_marking"}
        members = [("way", self.osm.way(sides[0], line), "left"), ("way", self.osm.way(sides[1], line), "right")]
        tags = {"type": "lanelet", "subtype": "crosswalk", "location": "urban", "one_way": "no",
                "participant:pedestrian": "yes", TAG + "crosswalk": cw.id}
        if cw.junction_id is not None:
            tags[TAG + "junction"] = cw.junction_id
        self.osm.relation(members, tags)

    # -- regulatory elements -------------------------------------------------------------------
    def _refer(self, lane_ids: Iterable[str], regelem: int) -> None:
        for lid in dict.fromkeys(lane_ids):
            self.osm.relations[self.lanelet[lid]][0].append(("relation", regelem, "regulatory_element"))

    def _governed(self, lane_ids: Iterable[str]) -> list[str]:
        return [lid for lid in incoming_lanes(self.m.lanes, lane_ids) if lid in self.lanelet]

    def _head(self, position, heading: float, width: float, z: float, tags: dict[str, str]) -> int:
        """A light or sign as Lanelet2 draws it: a line from its left to its right edge as the
        approaching driver sees it, at the height of its lower edge."""
        left = heading - math.pi / 2  # the driver faces heading + pi; their left is heading - pi/2
        u = np.array([math.cos(left), math.sin(left)]) * width / 2
        p = np.asarray(position[:2], dtype=float)
        return self.osm.way([p + u, p - u], tags, z=z)

    def _traffic_light(self, s) -> None:
        lanes = self._governed(s.lane_ids)
        if not lanes or len(s.stop_line) < 2:
            return
        w, h = APOLLO_SIGNAL_HEAD_SIZE_M
        light = self._head(s.position, s.heading, w, APOLLO_SIGNAL_HEIGHT_M - h / 2,
                           {"type": "traffic_light", "subtype": "red_yellow_green", "height": f"{h:g}"})
        line = self.osm.way(s.stop_line, {"type": "stop_line"})
        reg = self.osm.relation([("way", light, "refers"), ("way", line, "ref_line")],
                                {"type": "regulatory_element", "subtype": "traffic_light", TAG + "signal": s.id})
        self._refer(lanes, reg)

    def _sign(self, s) -> int:
        return self._head(s.position, s.heading, STOP_SIGN_SIZE_M, STOP_SIGN_HEIGHT_M,
                          {"type": "traffic_sign", "subtype": STOP_SIGN_SUBTYPE, "height": f"{STOP_SIGN_SIZE_M:g}"})

    def _approaches(self, jid: str | None) -> dict[str, list[str]]:
        """Entry road -> its lanes into junction `jid` that have lanelets."""
        if jid is None:
            return {}
        out = {road: [x for x in lanes if x in self.lanelet] for road, lanes in self.m.approaches(jid).items()}
        return {road: lanes for road, lanes in out.items() if lanes}

    def _stop_junctions(self) -> None:
        by_junction: dict[str | None, list] = {}
        for s in self.m.stop_signs.values():
            by_junction.setdefault(s.junction_id, []).append(s)
        for jid, signs in by_junction.items():
            approach = [lid for lanes in self._approaches(jid).values() for lid in lanes]
            signed = {s.id: self._governed(s.lane_ids) for s in signs}
            stopped = {lid for lanes in signed.values() for lid in lanes}
            if approach and set(approach) <= stopped:  # every approach stops: an all-way stop
                yield_lanes = list(dict.fromkeys(lid for s in signs for lid in signed[s.id]))
                members = [("relation", self.lanelet[lid], "yield") for lid in yield_lanes]
                members += [("way", self._lane_end_line(lid, {"type": "stop_line"}), "ref_line") for lid in yield_lanes]
                members += [("way", self._sign(s), "refers") for s in signs]
                reg = self.osm.relation(members, {"type": "regulatory_element", "subtype": "all_way_stop",
                                                  TAG + "junction": str(jid)})
                self._refer(yield_lanes, reg)
                continue
            free = [lid for lid in approach if lid not in stopped]
            for s in signs:
                if not signed[s.id] or len(s.stop_line) < 2:
                    continue
                line = self.osm.way(s.stop_line, {"type": "stop_line"})
                if free:  # its lanes yield to the approaches without a sign
                    members = [("relation", self.lanelet[lid], "right_of_way") for lid in free]
                    members += [("relation", self.lanelet[lid], "yield") for lid in signed[s.id]]
                    members += [("way", line, "ref_line")]
                    reg = self.osm.relation(members, {"type": "regulatory_element", "subtype": "right_of_way",
                                                      TAG + "stop_sign": s.id})
                    self._refer(free + signed[s.id], reg)
                else:  # no junction to yield at: the sign and its line
                    reg = self.osm.relation([("way", self._sign(s), "refers"), ("way", line, "ref_line")],
                                            {"type": "regulatory_element", "subtype": "traffic_sign",
                                             TAG + "stop_sign": s.id})
                    self._refer(signed[s.id], reg)

    def _yield_signs(self) -> None:
        """A yield sign (a filter lane's): a `right_of_way` element whose yielding lanelets are
        the junction lanes after its lanes and whose right-of-way lanelets are the other lanes
        merging into the same lanes (the exit road's, that the junction's core feeds), its stop
        line as ref_line; a `traffic_sign` element with its line where nothing merges."""
        lanes = self.m.lanes
        for s in self.m.yield_signs.values():
            governed = self._governed(s.lane_ids)
            after = [x for lid in governed for x in lanes[lid].successors if x in self.lanelet]
            prio = list(dict.fromkeys(p for x in after for nxt in lanes[x].successors if nxt in lanes
                                      for p in lanes[nxt].predecessors if p != x and p in self.lanelet))
            if not governed or len(s.stop_line) < 2:
                continue
            line = self.osm.way(s.stop_line, {"type": "stop_line"})
            if after and prio:
                members = [("relation", self.lanelet[lid], "right_of_way") for lid in prio]
                members += [("relation", self.lanelet[lid], "yield") for lid in after]
                members += [("way", line, "ref_line")]
                reg = self.osm.relation(members, {"type": "regulatory_element", "subtype": "right_of_way",
                                                  TAG + "yield_sign": s.id})
                self._refer(prio + after, reg)
                continue
            head = self._head(s.position, s.heading, STOP_SIGN_SIZE_M, STOP_SIGN_HEIGHT_M,
                              {"type": "traffic_sign", "subtype": YIELD_SIGN_SUBTYPE, "height": f"{STOP_SIGN_SIZE_M:g}"})
            reg = self.osm.relation([("way", head, "refers"), ("way", line, "ref_line")],
                                    {"type": "regulatory_element", "subtype": "traffic_sign", TAG + "yield_sign": s.id})
            self._refer(governed, reg)

    def _bare_junctions(self) -> None:
        controlled = {s.junction_id for s in self.m.signals.values()} | {s.junction_id for s in self.m.stop_signs.values()}
        for jid in self.m.junctions:
            if jid in controlled:
                continue
            approaches = self._approaches(jid)
            by_entry: dict[str, list[Lane]] = {}
            for ln in self.m.lanes_by_junction.get(jid, []):
                if ln.id not in self.lanelet:
                    continue
                for p in dict.fromkeys(self.m.lanes[x].road_id for x in ln.predecessors if x in self.m.lanes):
                    if p in approaches:
                        by_entry.setdefault(p, []).append(ln)
            for road, lanes in by_entry.items():
                yields = [ln.id for ln in lanes if ln.turn in ("left", "uturn")]
                prio = [ln.id for r, other in by_entry.items() if r != road for ln in other if ln.turn in ("none", "right")]
                if not yields or not prio:
                    continue
                line = self._entry_line(approaches[road])
                members = [("relation", self.lanelet[lid], "right_of_way") for lid in prio]
                members += [("relation", self.lanelet[lid], "yield") for lid in yields]
                members += [("way", line, "ref_line")]
                reg = self.osm.relation(members, {"type": "regulatory_element", "subtype": "right_of_way",
                                                  TAG + "junction": jid, TAG + "approach": road})
                self._refer(prio + yields, reg)

    def _lane_end_line(self, lane_id: str, tags: dict[str, str]) -> int:
        """A line across the end of a lane: from its right to its left boundary's last node."""
        return self.osm.way([self.ends[(lane_id, "right", "end")], self.ends[(lane_id, "left", "end")]], tags,
                            lane_ends=True)

    def _entry_line(self, lane_ids: Sequence[str]) -> int:
        """A virtual line across the ends of an approach's lanes (where its traffic enters the junction)."""
        lanes = [self.m.lanes[lid] for lid in lane_ids]
        h = lanes[0].heading_at_end()
        left = np.array([-math.sin(h), math.cos(h)])
        ends = [np.asarray(self.ends[(ln.id, side, "end")]) for ln in lanes for side in ("left", "right")]
        side = [float(e @ left) for e in ends]
        return self.osm.way([ends[int(np.argmin(side))], ends[int(np.argmax(side))]], {"type": "virtual"}, lane_ends=True)


def _same_ends(osm: _Osm, wid: int, pts) -> bool:
    """Do the way's end nodes lie at the ends of `pts` (either way round)?"""
    a, b = (np.asarray(osm.nodes[n][:2]) for n in osm.ends(wid))
    p, q = np.asarray(pts[0][:2], dtype=float), np.asarray(pts[-1][:2], dtype=float)
    tol = LANELET2_MERGE_M
    return bool((np.hypot(*(a - p)) < tol and np.hypot(*(b - q)) < tol)
                or (np.hypot(*(a - q)) < tol and np.hypot(*(b - p)) < tol))


def _xml(osm: _Osm, zone: int, origin: tuple[float, float]) -> bytes:
    from lxml import etree

    root = etree.Element("osm", version="0.6", generator="feat2map")
    ids = list(osm.nodes)
    xyz = np.array([osm.nodes[i] for i in ids], dtype=float).reshape(-1, 3)
    lat, lon = utm_to_latlon(zone, origin[0] + xyz[:, 0], origin[1] + xyz[:, 1])
    for k, nid in enumerate(ids):
        el = etree.SubElement(root, "node", id=str(nid), visible="true", version="1",
                              lat=f"{lat[k]:.11f}", lon=f"{lon[k]:.11f}")
        for key, v in (("ele", xyz[k, 2]), ("local_x", xyz[k, 0]), ("local_y", xyz[k, 1])):
            etree.SubElement(el, "tag", k=key, v=f"{v:.4f}")
    for wid, (nodes, tags) in osm.ways.items():
        el = etree.SubElement(root, "way", id=str(wid), visible="true", version="1")
        for nid in nodes:
            etree.SubElement(el, "nd", ref=str(nid))
        for key, v in tags.items():
            etree.SubElement(el, "tag", k=key, v=v)
    for rid, (members, tags) in osm.relations.items():
        el = etree.SubElement(root, "relation", id=str(rid), visible="true", version="1")
        for kind, ref, role in members:
            etree.SubElement(el, "member", type=kind, ref=str(ref), role=role)
        for key, v in tags.items():
            etree.SubElement(el, "tag", k=key, v=v)
    return etree.tostring(root, xml_declaration=True, encoding="UTF-8", pretty_print=True)


def projector_info(zone: int, origin: tuple[float, float]) -> bytes:
    """Autoware's map_projector_info.yaml: LocalCartesianUTM about the map's (0, 0)."""
    lat, lon = utm_to_latlon(zone, [origin[0]], [origin[1]])
    return (f"# the map's (0, 0): UTM zone {zone}N easting {origin[0]:.3f} northing {origin[1]:.3f}\n"
            "projector_type: LocalCartesianUTM\nvertical_datum: WGS84\nmap_origin:\n"
            f"  latitude: {lat[0]:.11f}\n  longitude: {lon[0]:.11f}\n  altitude: 0.0\n").encode()


_NUMBER = rb"-?\d+\.\d+"
# what `projector_info` writes, whatever the origin: a file like it was written by an earlier export
_OUR_PROJECTOR_INFO = re.compile(rb"# the map's \(0, 0\): UTM zone \d{1,2}N easting " + _NUMBER + rb" northing " + _NUMBER
                                 + rb"\nprojector_type: LocalCartesianUTM\nvertical_datum: WGS84\nmap_origin:\n"
                                 rb"  latitude: " + _NUMBER + rb"\n  longitude: " + _NUMBER + rb"\n  altitude: 0\.0\n")
_PROJECTOR_INFO_MAX_BYTES = 512  # ours is about 200 bytes


def check_projector_target(path: str | Path) -> None:
    """Whether map_projector_info.yaml may be written beside `path`: absent, or one an earlier
    export wrote (`projector_info`'s form); else a Feat2MapError naming it, as Autoware reads
    the map's origin from it and a user's or Autoware's own file is never overwritten."""
    info = Path(path).parent / PROJECTOR_INFO
    if not info.exists() and not info.is_symlink():
        return
    head = b""
    if info.is_file() and not info.is_symlink():
        try:
            with info.open("rb") as fh:
                head = fh.read(_PROJECTOR_INFO_MAX_BYTES + 1)
        except OSError:
            head = b""
    if _OUR_PROJECTOR_INFO.fullmatch(head) is None:
        raise Feat2MapError("exists and is not one a feat2map lanelet2 export wrote: refusing to overwrite it "
                            "(Autoware reads the map's origin from it; the .osm goes beside it); move it or "
                            "write the .osm into another folder", str(info))


def to_lanelet2(m: HDMap, *, zone: int = UTM_ZONE, origin: tuple[float, float] | None = None) -> tuple[bytes, bytes]:
    """The Lanelet2 OSM document of `m` and its map_projector_info.yaml, as bytes."""
    o = utm_origin(m, zone, origin, "lanelet2 export")
    w = _Writer(m)
    w.build()
    return _xml(w.osm, zone, o), projector_info(zone, o)


def write_lanelet2(m: HDMap, path: str | Path, *, zone: int = UTM_ZONE,
                   origin: tuple[float, float] | None = None) -> None:
    """Write `m` to `path` (.osm) and map_projector_info.yaml beside it, each atomically; an
    existing map_projector_info.yaml that an earlier export did not write is refused first."""
    path = atomic.check_file_target(path)
    check_projector_target(path)
    osm, info = to_lanelet2(m, zone=zone, origin=origin)
    atomic.write_bytes(path.parent / PROJECTOR_INFO, info)
    atomic.write_bytes(path, osm)
