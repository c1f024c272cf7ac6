"""Junction feature extraction from any HD map model (paper Sec. III-C).

Arms: the junction's mouths (one per road lane feeding or leaving it) are grouped into arms
by lane neighbour links and by direction and position (not by road ids, which real maps cut
into pieces). A socket runs from the junction centre (where the arms' centre lines meet; the
paper's polygon centroid on request) to the mean of its arm's mouth points. Control is
`signal` if a signal names the junction (or, naming none, governs a lane entering it), else
`stop` if a stop sign does, else `bare` (yield signs leave a junction bare); a crosswalk counts
when it lies in or touches the junction area or is linked to the junction by the reader.

Filter lanes (`extract_filters`): a junction lane turning right whose road lane before it also
continues, as a road lane, to the junction's other entries within FILTER_LEAD_MAX_M (it leaves
its approach before the core), or one behind a yield sign in a signalised junction; its control
is `signal` when a light governs the lane before it, else `yield`, with an island when kerbs
line its left. Leaving early, it is no mouth of the junction: the arms are measured without it
and the socket whose direction its start lies in records it (`Socket.filter`); a signal that
governs only such lanes controls no junction.

Mid-block crosswalks (`extract_midblock`): a crosswalk that no reader linked to a junction,
crosses road lanes and touches neither a junction area nor a junction lane is a crossing between
junctions; `signal` when a light guards it (`model.midblock_crossing`), else `bare`.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass, replace
from typing import Iterable, Iterator, Mapping, Sequence

import numpy as np
from shapely import STRtree
from shapely.geometry import Polygon

from .angles import positive_degrees, turn_name, wrap_degrees
from .config import (ARM_CENTRE_EXACT_M, ARM_CLUSTER_DEG, ARM_MAX_DEPTH_M, ARM_MAX_WIDTH_M, ARM_NEAR_M, ARM_TIE_M,
                     ARM_PROBE_M, ARM_SAME_POINT_M, FILTER_LEAD_MAX_M, LEG_MERGE_DEG, MIN_LEG_SEPARATION_DEG)
from .errors import FeatureError
from .features import FeatureSpace, JunctionFeature, MidblockFeature, Socket, normalize_rotation, ramp_normalization
from .model import HDMap, Lane, incoming_lanes, interior_lane, midblock_controls


@dataclass(frozen=True)
class Arm:
    angle_deg: float  # absolute socket angle
    point: tuple[float, float]
    lanes_in: int
    lanes_out: int


@dataclass(frozen=True)
class ExtractedJunction:
    """One junction's measured feature; `arms` in absolute angles, in feature (normalized) order."""

    map_name: str
    id: str
    feature: JunctionFeature
    center: tuple[float, float]
    arms: tuple[Arm, ...]

    def to_dict(self) -> dict:
        out = {"map": self.map_name, "id": self.id, "n_roads": self.feature.n_roads,
               "rotation": [round(a, 4) for a in self.feature.rotation], "control": self.feature.control,
               "crosswalk": self.feature.crosswalk, "lanes_in": [s.lanes_in for s in self.feature.sockets],
               "lanes_out": [s.lanes_out for s in self.feature.sockets]}
        if self.feature.has_filter:
            out.update(filter=list(self.feature.filters), island=[s.island for s in self.feature.sockets])
        return out


@dataclass(frozen=True)
class SkippedJunction:
    """A junction element that gives no feature, and why (still counted in map statistics)."""

    map_name: str
    id: str
    n_arms: int
    control: str
    crosswalk: bool
    reason: str

    def to_dict(self) -> dict:
        return {"map": self.map_name, "id": self.id, "n_arms": self.n_arms, "control": self.control,
                "crosswalk": self.crosswalk, "reason": self.reason}


@dataclass(frozen=True)
class _ArmEnds:
    point: np.ndarray  # mean of the arm's mouth points
    direction: np.ndarray  # unit vector out of the junction: mean road tangent at the mouth
    far_direction: np.ndarray  # unit vector towards the road ARM_PROBE_M out
    lanes_in: int
    lanes_out: int
    mouths: frozenset[str] = frozenset()  # the road lanes of its mouths (`_link_arm`)


class _UnionFind:
    def __init__(self, n: int) -> None:
        self.parent = list(range(n))

    def find(self, i: int) -> int:
        while self.parent[i] != i:
            self.parent[i] = self.parent[self.parent[i]]
            i = self.parent[i]
        return i

    def union(self, i: int, k: int) -> None:
        self.parent[self.find(i)] = self.find(k)


def _probe(m: HDMap, ln: Lane, outward_from_start: bool, jid: str | None) -> np.ndarray:
    """A point ARM_PROBE_M out along the road attached to a junction lane end (through
    short road pieces, stopping at other junctions), or the lane's own tangent if none."""
    if outward_from_start:
        start = np.asarray(ln.start)
        nxt = [m.lanes[p] for p in ln.predecessors if m.lanes[p].junction_id != jid]
    else:
        start = np.asarray(ln.end)
        nxt = [m.lanes[s] for s in ln.successors if m.lanes[s].junction_id != jid]
    if not nxt or nxt[0].junction_id is not None:  # no road, or straight into another junction
        if nxt:
            h = nxt[0].heading_at_end() + math.pi if outward_from_start else nxt[0].heading_at_start()
        else:
            h = ln.heading_at_start() + math.pi if outward_from_start else ln.heading_at_end()
        return start + ARM_PROBE_M * np.array([math.cos(h), math.sin(h)])
    left = ARM_PROBE_M
    cur = nxt[0]
    pts: list[np.ndarray] = []
    for _ in range(50):  # bounded walk through short pieces
        seg = cur.points[::-1] if outward_from_start else cur.points
        d = np.hypot(*np.diff(seg, axis=0).T)
        cum = np.concatenate([[0.0], np.cumsum(d)])
        if cum[-1] >= left:
            k = int(np.searchsorted(cum, left))
            t = (left - cum[k - 1]) / max(d[k - 1], 1e-12)
            return seg[k - 1] + t * (seg[k] - seg[k - 1])
        left -= cum[-1]
        pts.append(seg[-1])
        links = cur.predecessors if outward_from_start else cur.successors
        more = [m.lanes[x] for x in links if m.lanes[x].junction_id is None]
        if not more:
            break
        cur = more[0]
    end = pts[-1] if pts else start
    if np.hypot(*(end - start)) < 1e-6:
        h = ln.heading_at_start() + math.pi if outward_from_start else ln.heading_at_end()
        return start + ARM_PROBE_M * np.array([math.cos(h), math.sin(h)])
    return end


def _arms(m: HDMap, jid: str, lanes: Sequence[Lane]) -> list[_ArmEnds]:
    """The junction's arms (`_group_arms`), as every junction is measured first."""
    return _group_arms(m, jid, lanes)


def _group_arms(m: HDMap, jid: str, lanes: Sequence[Lane], ramps: bool = False) -> list[_ArmEnds]:
    """Arms from the junction's mouths: one per road lane that feeds or leaves it.

    Each mouth gets two outward directions: towards a point ARM_PROBE_M out along its road
    (robust to lanes that bend at the mouth) and the road's tangent at the mouth (robust to
    short curved road pieces). Two mouths are one arm when their road lanes are neighbours,
    or their tangents agree within ARM_CLUSTER_DEG and they are within ARM_NEAR_M, or their
    far directions agree within ARM_CLUSTER_DEG and they lie side by side (ARM_MAX_WIDTH_M
    across, ARM_MAX_DEPTH_M along the arm): divided roads and one-way pairs count once. Mouths
    that all enter (or all leave) merge only when their tangents agree within LEG_MERGE_DEG
    (the leg rule: legs at least MIN_LEG_SEPARATION_DEG apart, one-way ones too, stay apart).
    Two mouths that a junction lane joins (other than a U-turn) are never one arm: merges
    go strongest evidence first (neighbour links, then nearest pairs) and skip any merge
    that would put such a pair into one arm, so legs a few degrees apart stay apart. With
    `ramps` (`_ramp_junction`, for junctions that are skipped without), the mouths of a merge or
    a diverge between legs stay apart too (`_merging_mouths`).
    """
    # one end per lane outside (its incoming or outgoing road lane), else per point (points
    # within ARM_SAME_POINT_M are one: rounding coordinates would split them by where they lie)
    ends: dict[tuple, tuple[np.ndarray, np.ndarray, float, str, str | None]] = {}
    loose: list[tuple[tuple[float, float], tuple]] = []

    def point_key(p: tuple[float, float]) -> tuple:
        for q, key in loose:
            if math.dist(p, q) <= ARM_SAME_POINT_M:
                return key
        key = ("point", len(loose))
        loose.append((p, key))
        return key

    for ln in lanes:
        if any(interior_lane(m.lanes, m.lanes[x]) for x in ln.predecessors + ln.successors):
            continue  # a path through a piece of the junction (a centimetre road): no mouth
        if not any(m.lanes[p].junction_id == jid for p in ln.predecessors):
            outside = [m.lanes[p] for p in ln.predecessors]
            key = ("in", outside[0].id) if outside else point_key(ln.start)
            if key not in ends:
                tangent = (outside[0].heading_at_end() if outside else ln.heading_at_start()) + math.pi
                mouth = outside[0].end if outside else ln.start
                ends[key] = (np.asarray(mouth, dtype=float), _probe(m, ln, True, jid), tangent, "in",
                             outside[0].id if outside else None)
        if not any(m.lanes[s].junction_id == jid for s in ln.successors):
            outside = [m.lanes[s] for s in ln.successors]
            key = ("out", outside[0].id) if outside else point_key(ln.end)
            if key not in ends:
                tangent = outside[0].heading_at_start() if outside else ln.heading_at_end()
                mouth = outside[0].start if outside else ln.end
                ends[key] = (np.asarray(mouth, dtype=float), _probe(m, ln, False, jid), tangent, "out",
                             outside[0].id if outside else None)
    if not ends:
        return []
    ext = [v[4] for v in ends.values()]
    linked: list[set[str | None]] = []
    for lid in ext:
        ext_lane = m.lanes.get(lid) if lid else None
        linked.append(set(ext_lane.left_neighbors + ext_lane.right_neighbors + ext_lane.left_reverse_neighbors)
                      if ext_lane else set())
    pts = np.array([v[0] for v in ends.values()])
    dirs = np.array([v[1] - v[0] for v in ends.values()])
    dirs /= np.maximum(np.hypot(*dirs.T), 1e-12)[:, None]
    tangents = np.array([(math.cos(v[2]), math.sin(v[2])) for v in ends.values()])
    kinds = [v[3] for v in ends.values()]
    cos_tol = math.cos(math.radians(ARM_CLUSTER_DEG))
    # all pairs at once: offsets, distances, and along/across components in the mean direction
    d = pts[None, :, :] - pts[:, None, :]
    dist = np.hypot(d[..., 0], d[..., 1])
    mean = dirs[:, None, :] + dirs[None, :, :]
    mean /= np.maximum(np.hypot(mean[..., 0], mean[..., 1]), 1e-12)[..., None]
    across = np.abs(mean[..., 0] * d[..., 1] - mean[..., 1] * d[..., 0])
    along = np.abs((mean * d).sum(axis=-1))
    same = ((tangents @ tangents.T >= cos_tol) & (dist < ARM_NEAR_M - ARM_TIE_M)) | (  # adjacent, same local direction
        (dirs @ dirs.T >= cos_tol) & (across < ARM_MAX_WIDTH_M - ARM_TIE_M) & (along < ARM_MAX_DEPTH_M - ARM_TIE_M))
    entering = np.array([k == "in" for k in kinds])  # the leg rule: all-in or all-out mouths need close tangents
    same &= (entering[:, None] != entering[None, :]) | (tangents @ tangents.T >= math.cos(math.radians(LEG_MERGE_DEG)))
    same |= dist <= ARM_SAME_POINT_M  # mouths at one point are one leg whatever their tangents (thinned sim_map curves)
    index = {key: i for i, key in enumerate(ends)}
    merging = _merging_mouths(m, jid, lanes, index, tangents) if ramps else set()
    apart = _joined_mouths(m, jid, lanes, index) | merging
    cos_leg = math.cos(math.radians(LEG_MERGE_DEG))
    for i in {i for i, _ in merging}:  # a ramp's mouth is no lane of another road whose direction differs
        for k in range(len(pts)):
            if kinds[k] != kinds[i] and float(tangents[i] @ tangents[k]) < cos_leg \
                    and ext[k] not in linked[i] and ext[i] not in linked[k]:
                apart |= {(i, k), (k, i)}
    pairs = [(0.0, i, k) for i in range(len(pts)) for k in range(i + 1, len(pts)) if ext[k] in linked[i]]
    pairs += sorted((float(dist[i, k]), int(i), int(k)) for i, k in zip(*np.nonzero(np.triu(same, 1))))
    members = {i: {i} for i in range(len(pts))}
    uf = _UnionFind(len(pts))
    for _, i, k in pairs:
        a, b = uf.find(i), uf.find(k)
        if a == b or any((x, y) in apart for x in members[a] for y in members[b]):
            continue
        uf.union(a, b)
        members[b] |= members.pop(a)
    groups = {root: sorted(idx) for root, idx in members.items()}
    arms = []
    for idx in groups.values():
        t, f = tangents[idx].sum(axis=0), dirs[idx].sum(axis=0)
        arms.append(_ArmEnds(pts[idx].mean(axis=0), t / max(float(np.hypot(*t)), 1e-12),
                             f / max(float(np.hypot(*f)), 1e-12),
                             sum(kinds[i] == "in" for i in idx), sum(kinds[i] == "out" for i in idx),
                             frozenset(x for i in idx if (x := ext[i]) is not None)))
    return arms


def _joined_mouths(m: HDMap, jid: str, lanes: Sequence[Lane], index: dict[tuple, int]) -> set[tuple[int, int]]:
    """Pairs of mouth indices (both orders) that one junction lane joins, U-turns (labelled, or
    into the lane's own reverse neighbour) excepted: geometry cannot tell a U-turn from a
    turn between legs a few degrees apart."""
    apart: set[tuple[int, int]] = set()
    for ln in lanes:
        ins = [p for p in ln.predecessors if m.lanes[p].junction_id != jid]
        outs = [s for s in ln.successors if m.lanes[s].junction_id != jid]
        if not ins or not outs or ln.turn == "uturn" or outs[0] in m.lanes[ins[0]].left_reverse_neighbors:
            continue
        i, k = index.get(("in", ins[0])), index.get(("out", outs[0]))
        if i is not None and k is not None and i != k:
            apart |= {(i, k), (k, i)}
    return apart


def _through(m: HDMap, jid: str, lanes: Sequence[Lane]) -> Iterator[tuple[str, str]]:
    """(road lane before, road lane after) of each junction lane with road lanes on both sides."""
    for ln in lanes:
        ins = [p for p in ln.predecessors if m.lanes[p].junction_id != jid]
        outs = [x for x in ln.successors if m.lanes[x].junction_id != jid]
        if ins and outs:
            yield ins[0], outs[0]


def _merging_mouths(m: HDMap, jid: str, lanes: Sequence[Lane], index: dict[tuple, int],
                    tangents: np.ndarray) -> set[tuple[int, int]]:
    """Pairs of mouth indices (both orders) of a merge or a diverge between legs: entering mouths
    whose junction lanes lead into one carriageway (an on-ramp joining the main road's rightmost
    lane, or a motorway link its added lanes), or leaving mouths fed from one (an off-ramp or a
    link), with tangents more than LEG_MERGE_DEG apart (the
    leg rule; the lanes of one approach run parallel). Such mouths are separate legs: without
    this, a ramp a few degrees off its main road joins the main road's arm through the main
    road's lanes of the other direction (`_arms` also keeps them apart from the mouths of the other
    kind whose directions differ as much)."""
    into: dict[tuple, set[int]] = {}
    for src, dst in _through(m, jid, lanes):
        i, k = index.get(("in", src)), index.get(("out", dst))
        if i is not None and k is not None:
            into.setdefault(("out", _carriageway(m, dst)), set()).add(i)
            into.setdefault(("in", _carriageway(m, src)), set()).add(k)
    cos_leg = math.cos(math.radians(LEG_MERGE_DEG))
    apart: set[tuple[int, int]] = set()
    for group in into.values():
        for i in group:
            for k in group:
                if i != k and float(tangents[i] @ tangents[k]) < cos_leg:
                    apart.add((i, k))
    return apart


def _carriageway(m: HDMap, lane_id: str) -> tuple[str, bool]:
    """The road of a road lane and whether the lane runs along its reference line: its carriageway."""
    return m.lanes[lane_id].road_id, lane_id not in m.roads[m.lanes[lane_id].road_id].left_lanes


def _link_arm(m: HDMap, jid: str, lanes: Sequence[Lane], arm: _ArmEnds) -> bool:
    """Whether an arm's lanes go on through the junction one to one, as a motorway link's do
    (`Socket.link`): the road lanes its junction lanes lead into (entering) or come from (leaving)
    meet no junction lane of another arm."""
    pairs = [(src, dst) if arm.lanes_in else (dst, src) for src, dst in _through(m, jid, lanes)]
    far = {other for near, other in pairs if near in arm.mouths}
    if any(other in far and near not in arm.mouths for near, other in pairs):
        return False
    return bool(far)


def _meeting_point(lines: Sequence[tuple[np.ndarray, np.ndarray]]) -> tuple[np.ndarray, float] | None:
    """Least-squares meeting point of lines (point, unit direction) and the largest distance
    of a line from it; None when the lines are (nearly) parallel."""
    a, rhs = np.zeros((2, 2)), np.zeros(2)
    normals = [np.array([-u[1], u[0]]) for _, u in lines]
    for (p, _), n in zip(lines, normals):
        a += np.outer(n, n)
        rhs += n * (n @ p)
    if len(lines) < 2 or np.linalg.cond(a) > 1e4:
        return None
    c = np.linalg.solve(a, rhs)
    return c, max(abs(float(n @ (c - p))) for (p, _), n in zip(lines, normals))


def arms_centre(arms: Sequence[_ArmEnds], polygon: Polygon) -> np.ndarray:
    """Where the arms' centre lines meet, or the polygon's centroid when they are (nearly)
    parallel or meet far outside the junction area.

    When the road tangents at the junction mouths meet in one point (generated maps: roads
    leave along their sockets) that point is exact; otherwise (real roads bend at the mouth)
    the least-squares point of the tangent lines and the lines towards the roads ARM_PROBE_M
    out is used."""
    centroid = np.array(polygon.centroid.coords[0])
    near = _meeting_point([(a.point, a.direction) for a in arms])
    if near is not None and near[1] <= ARM_CENTRE_EXACT_M:
        c = near[0]
    else:
        both = _meeting_point([(a.point, u) for a in arms for u in (a.direction, a.far_direction)])
        if both is None:
            return centroid
        c = both[0]
    reach = max(float(np.hypot(*(arm.point - centroid))) for arm in arms)
    return c if float(np.hypot(*(c - centroid))) <= 0.5 * reach else centroid


def _behind(arm: _ArmEnds, c: np.ndarray) -> bool:
    """Whether the arm's mouth lies behind `c`, both along its road's tangent and towards its road."""
    off = arm.point - c
    return float(off @ arm.direction) < 0.0 and float(off @ arm.far_direction) < 0.0


def _socket_arms(ends: Sequence[_ArmEnds], c: np.ndarray, by_road: bool) -> list[Arm]:
    """Arms with socket angles from the centre `c` to each mouth, or (`by_road`) each arm's own
    road direction at its mouth. The latter is for a junction whose centre lies behind a mouth
    and whose angles from it break the leg rule: a road running straight through a merge or
    diverge has its in and out arms on one line, which a ramp's line meets beyond both mouths,
    so both arms of the through road get one angle from there while their roads leave 180
    degrees apart."""
    return [Arm(round(math.degrees(math.atan2(*((a.direction if by_road else a.point - c)[::-1]))), 9),  # no noise
                (float(a.point[0]), float(a.point[1])), a.lanes_in, a.lanes_out) for a in ends]


def _angles_and_gap(arms: Sequence[Arm]) -> tuple[list[float], float]:
    """The arms' angles in [0, 360) sorted, and the smallest gap between neighbours."""
    raw = sorted(positive_degrees(a.angle_deg) for a in arms)
    return raw, min(positive_degrees(raw[(i + 1) % len(raw)] - raw[i]) for i in range(len(raw)))


def _junction_controls(m: HDMap, ignore: Iterable[str] = ()) -> dict[str, set[str]]:
    """Junction id -> control kinds: a signal or stop sign counts for the junction it names;
    one that names none, for the junctions its lanes lead into (the readers name a control's
    junction from the same two sources, so neither leaks into a neighbour); a signal guarding a
    mid-block crosswalk (`midblock_controls`) or in `ignore` (a filter lane's) controls no junction."""
    out: dict[str, set[str]] = {}
    skip = set(midblock_controls(m)) | set(ignore)
    for kind, items in (("signal", m.signals), ("stop", m.stop_signs)):
        for s in items.values():
            if kind == "signal" and s.id in skip:
                continue
            if s.junction_id:
                out.setdefault(s.junction_id, set()).add(kind)
                continue
            for lid in s.lane_ids:
                ln = m.lanes.get(lid)
                if ln is None:
                    continue
                for nxt in ln.successors:
                    jid = m.lanes[nxt].junction_id
                    if jid and jid != ln.junction_id:
                        out.setdefault(jid, set()).add(kind)
    return out


def extract_junctions(m: HDMap, map_name: str = "map", centre: str = "arms", tie_tol_deg: float = 0.0,
                      skipped: list[SkippedJunction] | None = None) -> list[ExtractedJunction]:
    """The junction feature of every junction that has lanes and at least 3 arms.

    `centre` is where sockets start: "arms" (default) the meeting point of the arms' centre
    lines, which does not depend on how a map draws its junction polygon (Apollo T-junction
    polygons lean towards the stem), or "polygon", the paper's polygon centroid.
    `tie_tol_deg` is passed to `normalize_rotation` (0: the paper's exact largest gap).
    Junction elements with fewer than 3 arms (road bends, lane merges) are not junctions in
    the paper's sense; junctions that cannot give a valid feature are skipped with a warning.
    Both are appended to `skipped` when a list is given.
    """
    if centre not in ("arms", "polygon"):
        raise ValueError(f"centre must be 'arms' or 'polygon', got {centre!r}")
    by_junction = m.lanes_by_junction
    xw_polys = [Polygon(c.polygon) for c in m.crosswalks.values() if len(c.polygon) >= 3]
    xw_tree = STRtree(xw_polys) if xw_polys else None
    xw_junctions = {c.junction_id for c in m.crosswalks.values() if c.junction_id}
    filters = extract_filters(m, map_name)
    early = {f.id for f in filters if f.early}
    by_filter_junction: dict[str, list[ExtractedFilter]] = {}
    for f in filters:
        by_filter_junction.setdefault(f.junction, []).append(f)
    controls = _junction_controls(m, _filter_signals(m, filters))

    def skip(jid: str, poly: Polygon | None, control: str, n_arms: int, reason: str, warn: bool = True) -> None:
        if warn:
            warnings.warn(f"{map_name}: junction {jid}: {reason}, skipped", stacklevel=3)
        if skipped is not None:
            has_xw = jid in xw_junctions or (poly is not None and xw_tree is not None and len(
                xw_tree.query(poly, predicate="intersects")) > 0)
            skipped.append(SkippedJunction(map_name, jid, n_arms, control, has_xw, reason))

    out = []
    for jid, j in m.junctions.items():
        lanes = by_junction.get(jid, [])
        poly = Polygon(j.polygon) if len(j.polygon) >= 3 else None
        if poly is not None and not poly.is_valid:  # real maps draw self-touching outlines
            poly = poly.buffer(0)
        kinds = controls.get(jid, set())
        control = "signal" if "signal" in kinds else "stop" if "stop" in kinds else "bare"
        if not lanes or poly is None or poly.is_empty or poly.area <= 0:
            skip(jid, poly, control, 0, "no lanes or no valid polygon")
            continue
        mine = by_filter_junction.get(jid, [])
        if any(f.id in early for f in mine):
            lanes = [ln for ln in lanes if ln.id not in early]  # they leave before the core: no mouth
        ends = _arms(m, jid, lanes)
        crosswalk = jid in xw_junctions or (
            xw_tree is not None and len(xw_tree.query(poly, predicate="intersects")) > 0)
        if not (mine or crosswalk) and (len(ends) < 3 or _leg_gap(ends, poly, centre) < MIN_LEG_SEPARATION_DEG - 1e-9):
            ramp = _ramp_junction(m, jid, lanes, poly, control)  # skipped otherwise: a motorway's ramps?
            if ramp is not None:
                out.append(ExtractedJunction(map_name, jid, *ramp))
                continue
        if len(ends) < 3:
            skip(jid, poly, control, len(ends), f"{len(ends)} arm(s), not a junction of 3 or more roads", warn=False)
            continue
        c = arms_centre(ends, poly) if centre == "arms" else np.array(poly.centroid.coords[0])
        arms = _socket_arms(ends, c, by_road=False)
        raw, gap = _angles_and_gap(arms)
        if gap < MIN_LEG_SEPARATION_DEG - 1e-9 and any(_behind(a, c) for a in ends):
            arms = _socket_arms(ends, c, by_road=True)  # the centre lies beyond a mouth: see _socket_arms
            raw, gap = _angles_and_gap(arms)
        if gap < MIN_LEG_SEPARATION_DEG - 1e-9:  # the leg rule, before any ordering of equal angles
            skip(jid, poly, control, len(arms), f"sockets {gap:.2f} degrees apart, closer than the minimum separation "
                            f"{MIN_LEG_SEPARATION_DEG} degrees: {[round(a, 2) for a in raw]}")
            continue
        try:
            norm = normalize_rotation([a.angle_deg for a in arms], tie_tol_deg)
            arms = [arms[i] for i in norm.order]
            sockets = tuple(Socket(a, arm.lanes_in, arm.lanes_out) for a, arm in zip(norm.angles, arms))
            feature = JunctionFeature(sockets, control, crosswalk, MIN_LEG_SEPARATION_DEG)
            if mine:
                feature = _with_filters(feature, arms, c, mine, m)
        except FeatureError as exc:
            skip(jid, poly, control, len(arms), exc.message)
            continue
        out.append(ExtractedJunction(map_name, jid, feature, (float(c[0]), float(c[1])), tuple(arms)))
    return out


def _socket_angles(ends: Sequence[_ArmEnds], poly: Polygon, centre: str) -> tuple[list[Arm], np.ndarray, float]:
    """The arms with their socket angles as `extract_junctions` measures them, their centre and
    the smallest gap between neighbouring angles."""
    c = arms_centre(ends, poly) if centre == "arms" else np.array(poly.centroid.coords[0])
    arms = _socket_arms(ends, c, by_road=False)
    _, gap = _angles_and_gap(arms)
    if gap < MIN_LEG_SEPARATION_DEG - 1e-9 and any(_behind(a, c) for a in ends):
        arms = _socket_arms(ends, c, by_road=True)
        _, gap = _angles_and_gap(arms)
    return arms, c, gap


def _leg_gap(ends: Sequence[_ArmEnds], poly: Polygon, centre: str) -> float:
    return _socket_angles(ends, poly, centre)[2]


def _ramp_junction(m: HDMap, jid: str, lanes: Sequence[Lane], poly: Polygon, control: str
                   ) -> tuple[JunctionFeature, tuple[float, float], tuple[Arm, ...]] | None:
    """(feature, centre, arms) of a ramp junction (`ramp_feature`), measured with the mouths of a
    merge or diverge kept apart (`_arms` with `ramps`), or None when the junction makes none. Only
    a junction that is skipped without it (fewer than 3 arms, or arms closer than the leg rule)
    is taken as one, so every other junction measures as it always did."""
    ends = _group_arms(m, jid, lanes, ramps=True)
    if len(ends) < 3:
        return None
    arms, c, gap = _socket_angles(ends, poly, "arms")
    if gap >= MIN_LEG_SEPARATION_DEG - 1e-9:
        return None
    try:
        found = ramp_feature(arms, control, [_link_arm(m, jid, lanes, e) for e in ends])
    except FeatureError:
        return None
    return None if found is None else (found[0], (float(c[0]), float(c[1])), found[1])


def ramp_feature(arms: Sequence[Arm], control: str, links: Sequence[bool] = ()
                 ) -> tuple[JunctionFeature, tuple[Arm, ...]] | None:
    """The ramp junction feature of arms closer than the leg rule allows (None when they make
    none): each pair of neighbouring arms closer than MIN_LEG_SEPARATION_DEG is a main leg and a
    ramp, an on-ramp when the counter-clockwise one only enters, an off-ramp when the clockwise one
    only leaves (right-hand traffic); `ramp_length` is the distance between the main legs'
    mouths. `links` (per arm): its lanes go on one to one (`_link_arm`); when every ramp's do,
    the ramps are motorway links (`Socket.link`). A FeatureError when the result breaks the ramp
    junction rules (`JunctionFeature`)."""
    order = sorted(range(len(arms)), key=lambda i: positive_degrees(arms[i].angle_deg))
    ordered = [arms[i] for i in order]
    n = len(ordered)
    angles = [positive_degrees(a.angle_deg) for a in ordered]
    kinds = ["none"] * n
    for i in range(n):
        k = (i + 1) % n
        if positive_degrees(angles[k] - angles[i]) >= MIN_LEG_SEPARATION_DEG - 1e-9:
            continue
        if ordered[k].lanes_out == 0 and kinds[k] == "none":
            kinds[k] = "on"
        elif ordered[i].lanes_in == 0 and kinds[i] == "none":
            kinds[i] = "off"
        else:
            return None
    mains = [a for a, kind in zip(ordered, kinds) if kind == "none"]
    if len(mains) != 2:
        return None
    unwrapped = [angles[0] + positive_degrees(a - angles[0]) for a in angles]
    link = bool(links) and all(links[i] for i, kind in zip(order, kinds) if kind != "none")
    sockets = tuple(Socket(a, arm.lanes_in, arm.lanes_out, ramp=kind, link=link and kind != "none")
                    for a, arm, kind in zip(unwrapped, ordered, kinds))
    length = round(math.dist(mains[0].point, mains[1].point), 2)
    feature = JunctionFeature(sockets, control, False, MIN_LEG_SEPARATION_DEG, length)
    norm = ramp_normalization(feature)
    return feature.normalized(), tuple(ordered[i] for i in norm.order)


@dataclass(frozen=True)
class ExtractedFilter:
    """One filter lane: the junction lane `id` of `junction`, the road lane before it
    (`approach`), its `control` ("yield" or "signal"), `island` (kerbs on its left) and whether
    it leaves its approach before the core's entries (`early`; else it is a yield-sign right
    turn of a signalised junction)."""

    map_name: str
    id: str
    junction: str
    approach: str
    control: str
    island: bool
    early: bool

    def to_dict(self) -> dict:
        return {"map": self.map_name, "id": self.id, "junction": self.junction, "approach": self.approach,
                "control": self.control, "island": self.island, "early": self.early}


def junctions_within(lanes: Mapping[str, Lane], starts: Iterable[str], forward: bool = True,
                     limit: float = FILTER_LEAD_MAX_M) -> set[str]:
    """The junctions whose lanes road lanes from `starts` on lead into (`forward`; else come out
    of) within `limit` metres of road (the start lanes' lengths counted)."""
    stack = [(x, 0.0) for x in starts]
    seen: set[str] = set()
    out: set[str] = set()
    while stack:
        lid, run = stack.pop()
        ln = lanes.get(lid)
        if ln is None or lid in seen or ln.junction_id is not None:
            continue
        seen.add(lid)
        run += ln.length
        for nxt in ln.successors if forward else ln.predecessors:
            jid = lanes[nxt].junction_id if nxt in lanes else None
            if jid is not None:
                out.add(jid)
            elif run < limit:
                stack.append((nxt, run))
    return out


def extract_filters(m: HDMap, map_name: str = "map") -> list[ExtractedFilter]:
    """The filter lanes of every junction (see the module docstring), in map order."""
    governed: dict[str, set[str]] = {}  # road lane -> control kinds on it
    for kind, items in (("signal", m.signals), ("yield", m.yield_signs)):
        for s in items.values():
            for lid in incoming_lanes(m.lanes, s.lane_ids):
                governed.setdefault(lid, set()).add(kind)
    out = []
    for jid, lanes in m.lanes_by_junction.items():
        if jid is None:
            continue
        entries = {p for ln in lanes for p in ln.predecessors if p in m.lanes and m.lanes[p].junction_id is None}
        signalised = any("signal" in governed.get(p, ()) for p in entries)
        for ln in lanes:
            ins = [p for p in ln.predecessors if p in m.lanes and m.lanes[p].junction_id is None]
            if len(ins) != 1 or len(ln.centerline) < 2 or \
                    turn_name(wrap_degrees(math.degrees(ln.heading_at_end() - ln.heading_at_start()))) != "right":
                continue
            p = m.lanes[ins[0]]
            early = jid in junctions_within(m.lanes, [x for x in p.successors
                                                      if x in m.lanes and m.lanes[x].junction_id is None])
            kinds = governed.get(p.id, set())
            if not early and not ("yield" in kinds and signalised and "signal" not in kinds):
                continue
            out.append(ExtractedFilter(map_name, ln.id, jid, p.id, "signal" if "signal" in kinds else "yield",
                                       ln.left_boundary_type == "curb", early))
    return out


def _filter_signals(m: HDMap, filters: Sequence[ExtractedFilter]) -> set[str]:
    """The signals that govern only the lanes before filter lanes that leave early (their own lights)."""
    before = {f.approach for f in filters if f.early}
    if not before:
        return set()
    return {s.id for s in m.signals.values()
            if (lanes := incoming_lanes(m.lanes, s.lane_ids)) and set(lanes) <= before}


def _with_filters(feature: JunctionFeature, arms: Sequence[Arm], centre: np.ndarray,
                  filters: Sequence[ExtractedFilter], m: HDMap) -> JunctionFeature:
    """`feature` (sockets in `arms`' order) with each filter lane on the socket whose direction
    from `centre` its start lies closest to; the feature without them when that makes no valid
    feature (a filter lane must turn right into the next socket)."""
    sockets = list(feature.sockets)
    for f in filters:
        x, y = np.asarray(m.lanes[f.id].start) - centre
        at = math.degrees(math.atan2(y, x))
        k = min(range(len(arms)), key=lambda i: abs(wrap_degrees(arms[i].angle_deg - at)))
        sockets[k] = replace(sockets[k], filter=f.control, island=f.island)
    try:
        return JunctionFeature(tuple(sockets), feature.control, feature.crosswalk, feature.min_separation_deg)
    except FeatureError:
        return feature


@dataclass(frozen=True)
class ExtractedMidblock:
    """One mid-block crosswalk: its feature (`position`: its centre's fraction along `lane`, the
    first road lane it crosses) and the road lanes it crosses."""

    map_name: str
    id: str
    feature: MidblockFeature
    lane: str
    lanes: tuple[str, ...]

    def to_dict(self) -> dict:
        return {"map": self.map_name, "id": self.id, "control": self.feature.control,
                "position": round(self.feature.position, 4), "lane": self.lane, "lanes": list(self.lanes)}


def extract_midblock(m: HDMap, map_name: str = "map") -> list[ExtractedMidblock]:
    """The crosswalks between junctions (see the module docstring), in map order."""
    from shapely.geometry import LineString, Point

    walks = [c for c in m.crosswalks.values() if c.junction_id is None and len(c.polygon) >= 3]
    if not walks:
        return []
    junctions = [Polygon(j.polygon).buffer(0) for j in m.junctions.values() if len(j.polygon) >= 3]
    jtree = STRtree(junctions) if junctions else None
    ids = list(m.lanes)
    lines = [LineString(m.lanes[x].centerline) for x in ids]
    tree = STRtree(lines)
    guarded = {cw for cw, _, _ in midblock_controls(m).values()}
    out = []
    for c in walks:
        poly = Polygon(c.polygon).buffer(0)
        if poly.is_empty or (jtree is not None and len(jtree.query(poly, predicate="intersects"))):
            continue
        crossed = [ids[k] for k in sorted(tree.query(poly, predicate="intersects").tolist())]
        if not crossed or any(m.lanes[x].junction_id is not None for x in crossed):
            continue
        lane = crossed[0]
        line = lines[ids.index(lane)]
        at = line.project(Point(poly.centroid.coords[0])) / max(line.length, 1e-9)
        feature = MidblockFeature("signal" if c.id in guarded else "bare", min(max(at, 1e-6), 1 - 1e-6))
        out.append(ExtractedMidblock(map_name, c.id, feature, lane, tuple(crossed)))
    return out


def map_feature(junctions: Iterable[ExtractedJunction | JunctionFeature],
                midblock: Iterable[ExtractedMidblock | MidblockFeature] = (), ramps: Iterable[str] = ()) -> FeatureSpace:
    """The map feature of one or several maps: union of discrete values, per-n angle ranges, the
    mid-block crosswalk values seen and the ramp values (ramp junctions', and `ramps`: the kinds
    of ramps found outside them)."""
    return FeatureSpace.from_features((j.feature if isinstance(j, ExtractedJunction) else j for j in junctions),
                                      (c.feature if isinstance(c, ExtractedMidblock) else c for c in midblock),
                                      ramps)
