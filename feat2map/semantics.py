"""Load-time semantic checks of a map: what must hold for a map to be driven and exported
safely, beyond the values `validation.validate_model` checks.

Every reader runs `check_map` on the map it returns (each problem a one-line warning naming the
file and element; `feat2map validate` reports them), and the env asserts `assert_sound` at reset.
The checks are a list (`CHECKS`) of small functions `(HDMap) -> Iterable[Finding]`; add one by
appending it. A `Finding` is `fatal` when the map cannot be driven safely (the env refuses it).

`drop_dangling` is the readers' repair step after their own transforms: a control or link that
names an element the map does not hold loses that reference (one warning naming both), never a
traceback further on.
"""
from __future__ import annotations

import warnings
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING, Any, Callable, Iterable, Sequence

from .config import (BRIDGE_AHEAD_M, BRIDGE_ASIDE_M, BRIDGE_TAIL_M, ENDPOINT_TOLERANCE_M, FOLD_BACK_M, FOLD_LOCATE_WINDOW,
                     FOLD_LOOP_SPAN, JUNCTION_SPEED_LIMIT_MPS, LANE_END_SNAP_M, LANE_LINK_GAP_M, LINK_REVERSAL_DEG,
                     PLAUSIBLE_SPEED_MPS, SPEED_LIMIT_MPS, TOUCHING_LINK_DEG)
from .errors import Feat2MapError, RepairWarning
from .model import HDMap, Lane, as_polyline, incoming_lanes, stop_line_across

if TYPE_CHECKING:
    import numpy as np

CONTROL_TABLES = ("signals", "stop_signs", "yield_signs")
_LINKS = ("predecessors", "successors", "left_neighbors", "right_neighbors", "left_reverse_neighbors")


@dataclass(frozen=True)
class Finding:
    """One semantic problem: the element (kind and id), what is wrong, and whether the map
    cannot be driven safely with it."""

    element: str
    message: str
    fatal: bool = False

    def __str__(self) -> str:
        return f"{self.element}: {self.message}"


# ------------------------------------------------------------------------------- checks

def dangling_references(m: HDMap) -> Iterable[Finding]:
    """Every id an element refers to exists (lanes, roads, junctions, controls' lanes)."""
    for ln in m.lanes.values():
        if ln.road_id not in m.roads:
            yield Finding(f"lane {ln.id}", f"refers to unknown road {ln.road_id}", True)
        if ln.junction_id is not None and ln.junction_id not in m.junctions:
            yield Finding(f"lane {ln.id}", f"refers to unknown junction {ln.junction_id}", True)
        for f in _LINKS:
            for x in getattr(ln, f):
                if x not in m.lanes:
                    yield Finding(f"lane {ln.id}", f"{f} names unknown lane {x}", True)
    for r in m.roads.values():
        for x in r.lane_ids:
            if x not in m.lanes:
                yield Finding(f"road {r.id}", f"lists unknown lane {x}", True)
    for kind in (*CONTROL_TABLES, "crosswalks"):
        for s in getattr(m, kind).values():
            for x in getattr(s, "lane_ids", ()):
                if x not in m.lanes:
                    yield Finding(f"{kind[:-1]} {s.id}", f"governs unknown lane {x}", True)
            if s.junction_id is not None and s.junction_id not in m.junctions:
                yield Finding(f"{kind[:-1]} {s.id}", f"refers to unknown junction {s.junction_id}", True)


APPROACH_LINKS = 3  # a governed lane may reach its junction through this many road lanes (SVL: the lane before)


def _leads_into(m: HDMap, lid: str, jid: str) -> bool:
    """Lane `lid` is an approach of junction `jid`: a lane of `jid` itself (a junction lane a
    control names for itself: its predecessors lie in another junction, `incoming_lanes`), or a
    road lane reaching `jid` through at most APPROACH_LINKS road lanes."""
    if m.lanes[lid].junction_id == jid:
        return True
    frontier, seen = [lid], {lid}
    for _ in range(APPROACH_LINKS):
        nxt = []
        for x in frontier:
            for y in m.lanes[x].successors:
                if y not in m.lanes or y in seen:
                    continue
                if m.lanes[y].junction_id == jid:
                    return True
                if m.lanes[y].junction_id is None:
                    seen.add(y)
                    nxt.append(y)
        frontier = nxt
    return False


def governed_lanes_are_approaches(m: HDMap) -> Iterable[Finding]:
    """A control of a junction governs lanes that lead into that junction (its approaches,
    through at most APPROACH_LINKS road lanes: SVL maps give signals the lane before), or its own
    lanes where their predecessors lie in another junction (GoMentum's back-to-back junctions)."""
    for kind in CONTROL_TABLES:
        for s in getattr(m, kind).values():
            if s.junction_id is None:
                continue
            for lid in incoming_lanes(m.lanes, s.lane_ids):
                if not _leads_into(m, lid, s.junction_id):
                    yield Finding(f"{kind[:-1]} {s.id}", f"governs lane {lid}, which is not an approach of "
                                                         f"junction {s.junction_id}")


def conflict_free_phases(m: HDMap) -> Iterable[Finding]:
    """No two signals whose paths conflict are green together in the phase plan (paired and
    single), and every group the map declares can switch together."""
    from .phases import declared_group_conflicts, junction_phases, phase_conflicts

    for paired in (True, False):
        for jid, a, b, why in phase_conflicts(m, junction_phases(m, paired), paired):
            yield Finding(f"junction {jid}", f"signals {a} and {b} are green together in the "
                                             f"{'paired' if paired else 'single'} plan: {why}", True)
    from .phases import signal_self_conflicts

    for sid, a, b, why in signal_self_conflicts(m):
        yield Finding(f"signal {sid}", f"governs roads {a} and {b} whose paths conflict ({why}): one light cannot "
                                       "keep them apart")
    clashes: dict[str, list[tuple[str, str, str]]] = {}
    for gid, a, b, why in declared_group_conflicts(m):
        clashes.setdefault(gid, []).append((a, b, why))
    for gid, found in clashes.items():
        a, b, why = found[0]
        more = f" ({len(found) - 1} more such pairs)" if len(found) > 1 else ""
        yield Finding(f"signal group {gid}", f"the map switches signals {a} and {b} together, but {why}{more} "
                                              "(the phase plan keeps them apart)")


def links_meet(m: HDMap) -> Iterable[Finding]:
    """A lane and its successor meet: the successor starts within LANE_LINK_GAP_M of its end."""
    for a, b, gap in _far_links(m):
        yield Finding(f"lane {a}", f"successor {b} starts {gap:.1f} m from its end")


def _far_links(m: HDMap) -> list[tuple[str, str, float]]:
    import math

    return [(ln.id, s, d) for ln in m.lanes.values() for s in ln.successors if s in m.lanes
            and (d := math.dist(ln.end, m.lanes[s].start)) > LANE_LINK_GAP_M]


def _reversing_links(m: HDMap) -> list[tuple[str, str, float]]:
    """Links (lane, successor, degrees) whose successor starts heading more than
    LINK_REVERSAL_DEG away from the lane's end heading: no car turns round at a point
    (osm2xodr links a road to the opposite carriageway beyond a junction)."""
    import math

    return [(ln.id, s, d) for ln in m.lanes.values() for s in ln.successors if s in m.lanes
            and (d := abs(math.degrees(math.remainder(m.lanes[s].heading_at_start() - ln.heading_at_end(),
                                                      math.tau)))) > LINK_REVERSAL_DEG]


CHECKS: list[Callable[[HDMap], Iterable[Finding]]] = [
    dangling_references,
    links_meet,
    governed_lanes_are_approaches,
    conflict_free_phases,
]


def findings(m: HDMap) -> list[Finding]:
    """Every problem every check finds, in check order."""
    return [f for check in CHECKS for f in check(m)]


def check_map(m: HDMap, where: str = "map") -> HDMap:
    """Warn (one line each, naming `where` and the element) about every finding; returns `m`."""
    for f in findings(m):
        warnings.warn(f"{where}: {f}", stacklevel=2)
    return m


def assert_sound(m: HDMap, where: str = "map") -> None:
    """Raise Feat2MapError naming the first fatal finding (the env's check at reset)."""
    bad = [f for f in findings(m) if f.fatal]
    if bad:
        more = f" (and {len(bad) - 1} more)" if len(bad) > 1 else ""
        raise Feat2MapError(f"{bad[0]}{more}", where)


def loaded(m: HDMap, where: str = "map") -> HDMap:
    """A reader's last step: links a lane leading nowhere leaves out added (`link_touching_ends`),
    links between lanes that do not meet dropped (`drop_far_links`),
    short gaps between linked lanes bridged (`bridge_gaps`), linked ends turned against each other
    closed (`turned_link_ends`), dangling references dropped
    (`drop_dangling`), values checked (`validation.validate_model`), implausible speeds replaced
    (`plausible_speeds`), governed lanes that are no approach dropped (`drop_non_approaches`),
    boundaries that fold back on themselves unfolded (`unfolded_boundaries`), signals over
    conflicting approaches split (`split_conflicting_signals`), semantic findings warned
    (`check_map`)."""
    from .validation import validate_model

    m = drop_far_links(link_touching_ends(m, where), where)
    m = validate_model(drop_dangling(turned_link_ends(bridge_gaps(m, where), where), where), where)
    m = unfolded_boundaries(drop_non_approaches(plausible_speeds(m, where), where), where)
    return check_map(split_conflicting_signals(m, where), where)


# ------------------------------------------------------------------------------- repair

def link_touching_ends(m: HDMap, where: str = "map") -> HDMap:
    """`m` with the links a lane without successor leaves out: it leads into every lane that starts
    where it ends (within ENDPOINT_TOLERANCE_M, heading within TOUCHING_LINK_DEG), one warning
    naming them. SVL's Borregas Ave leaves two right-turn lanes unlinked from their junction
    lanes (routing reached no exit from them, their lights governed lanes leading nowhere),
    GoMentum six lanes of back-to-back junctions."""
    import math

    import shapely

    ids = [x for x, ln in m.lanes.items() if len(ln.centerline) >= 2]
    open_ends = [x for x in ids if not m.lanes[x].successors]
    if not open_ends:
        return m
    tree = shapely.STRtree(shapely.points([m.lanes[x].start[:2] for x in ids]))
    cos_max = math.cos(math.radians(TOUCHING_LINK_DEG))
    added: list[tuple[str, str]] = []
    for a in open_ends:
        ln = m.lanes[a]
        near = sorted(int(k) for k in tree.query(shapely.Point(ln.end[:2]), predicate="dwithin",
                                                 distance=ENDPOINT_TOLERANCE_M))
        added += [(a, ids[k]) for k in near if ids[k] != a
                  and math.cos(m.lanes[ids[k]].heading_at_start() - ln.heading_at_end()) >= cos_max]
    if not added:
        return m
    lanes = dict(m.lanes)
    for a, b in added:
        lanes[a] = replace(lanes[a], successors=lanes[a].successors + (b,))
        lanes[b] = replace(lanes[b], predecessors=lanes[b].predecessors + (a,))
    shown = ", ".join(f"{a} -> {b}" for a, b in added[:5]) + (f" and {len(added) - 5} more" if len(added) > 5 else "")
    warnings.warn(f"{where}: {len(added)} missing link(s) added where a lane without successor ends exactly where "
                  f"another starts ({shown})", stacklevel=3)
    return replace(m, lanes=lanes)


def plausible_speeds(m: HDMap, where: str = "map") -> HDMap:
    """`m` with every lane speed limit outside PLAUSIBLE_SPEED_MPS replaced by the default a map
    that declares none gets (SPEED_LIMIT_MPS, JUNCTION_SPEED_LIMIT_MPS in junctions), with one
    warning naming the file and the lanes: a converter that wrote `<speed max="2.68016"
    unit="mph"/>` on every lane made cars crawl at 1.2 m/s and every scenario time out."""
    lo, hi = PLAUSIBLE_SPEED_MPS
    bad = [ln for ln in m.lanes.values() if not lo <= ln.speed_limit <= hi]
    if not bad:
        return m
    speeds = sorted({round(ln.speed_limit, 2) for ln in bad})
    shown = ", ".join(f"{x:g}" for x in speeds[:5]) + (", ..." if len(speeds) > 5 else "")
    names = ", ".join(ln.id for ln in bad[:3]) + (", ..." if len(bad) > 3 else "")
    warnings.warn(f"{where}: {len(bad)} of {len(m.lanes)} lanes (lanes {names}) declare speed limits outside "
                  f"{lo:g}-{hi:g} m/s ({shown} m/s), implausible for a driving lane: read as {SPEED_LIMIT_MPS:g} m/s "
                  f"({JUNCTION_SPEED_LIMIT_MPS:g} in junctions)", stacklevel=3)
    lanes = dict(m.lanes)
    for ln in bad:
        lanes[ln.id] = replace(ln, speed_limit=JUNCTION_SPEED_LIMIT_MPS if ln.junction_id else SPEED_LIMIT_MPS)
    return replace(m, lanes=lanes)


def _crossing(a: Sequence[float], b: Sequence[float], c: Sequence[float], d: Sequence[float]) -> float | None:
    """Where segment a-b crosses segment c-d, as the fraction along a-b (None if they do not)."""
    rx, ry, sx, sy = b[0] - a[0], b[1] - a[1], d[0] - c[0], d[1] - c[1]
    den = rx * sy - ry * sx
    if den == 0.0:
        return None
    qx, qy = c[0] - a[0], c[1] - a[1]
    t, u = (qx * sy - qy * sx) / den, (qx * ry - qy * rx) / den
    return t if 0.0 <= t <= 1.0 and 0.0 <= u <= 1.0 else None


def along(points: Sequence[Sequence[float]], centre: Sequence[Sequence[float]],
          window: float = FOLD_LOCATE_WINDOW) -> list[float]:
    """Each of a boundary's `points` located along the `centre` line (metres from its start): the
    nearest place on the stretch of the centre line within `window` (a fraction of its length) of
    the point's own fraction along the boundary. A U-turn's centre line passes its own start again
    near its end, and the nearest place on the whole line put the boundary's last points at its
    start (so `unfold` dropped all of GoMentum's lane_75's inner border but its ends)."""
    import numpy as np

    p, c = np.asarray(points, dtype=float)[:, :2], np.asarray(centre, dtype=float)[:, :2]
    if len(c) < 2:
        return [0.0] * len(p)
    seg = np.diff(c, axis=0)
    length = np.hypot(seg[:, 0], seg[:, 1])
    cum = np.concatenate([[0.0], np.cumsum(length)])
    own = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    frac = own / own[-1] if own[-1] > 0 else np.zeros(len(p))
    lo, hi = (frac - window) * cum[-1], (frac + window) * cum[-1]  # per point, metres along the centre
    safe = np.where(length > 0, length, 1.0)
    d = p[:, None, :] - c[None, :-1, :]
    t = (d * seg[None]).sum(axis=2) / safe ** 2
    t_lo, t_hi = (lo[:, None] - cum[None, :-1]) / safe, (hi[:, None] - cum[None, :-1]) / safe
    allowed = (t_lo <= 1.0) & (t_hi >= 0.0)
    t = np.clip(t, np.maximum(t_lo, 0.0), np.minimum(t_hi, 1.0))
    t = np.where(length[None] > 0, np.clip(t, 0.0, 1.0), 0.0)
    gap = np.hypot(*(d - t[..., None] * seg[None]).transpose(2, 0, 1))
    best = np.argmin(np.where(allowed, gap, np.inf), axis=1)
    rows = np.arange(len(p))
    return (cum[best] + t[rows, best] * length[best]).tolist()


def unfold(line: Sequence[Sequence[float]], centre: Sequence[Sequence[float]]) -> list[tuple[float, ...]] | None:
    """`line` (a boundary of the lane whose centre line is `centre`) without its folds, or None
    when it has none: inner points more than FOLD_BACK_M behind the point kept before them
    (along the centre line, `along`) are dropped, and loops where what is left still crosses
    itself are cut at the crossing (each segment jumps to the crossing with the last later segment
    it meets). A crossing of segments further apart along the centre line than FOLD_LOOP_SPAN of
    its length is no fold: a U-turn's inner border crosses itself where the lane's ends meet, and
    cutting there left GoMentum's lane_75 a 1 m stub that Lanelet2's loader turned round."""
    from shapely.geometry import LineString

    if len(line) < 3:
        return None
    pts = [tuple(float(v) for v in p) for p in line]
    s = along(pts, centre)
    kept = [0]
    for i in range(1, len(pts) - 1):
        if s[i] >= s[kept[-1]] - FOLD_BACK_M:
            kept.append(i)
    while len(kept) > 1 and s[kept[-1]] > s[-1] + FOLD_BACK_M:
        kept.pop()
    pts2, s2 = [pts[i] for i in kept] + [pts[-1]], [s[i] for i in kept] + [s[-1]]
    if LineString([p[:2] for p in pts2]).is_simple:
        return pts2 if len(pts2) < len(pts) else None
    span = FOLD_LOOP_SPAN * LineString([p[:2] for p in centre]).length
    cur, out, i, n = pts2[0], [pts2[0]], 0, len(pts2)
    while i < n - 1:
        nxt = pts2[i + 1]
        for j in range(n - 2, i + 1, -1):
            t = _crossing(cur, nxt, pts2[j], pts2[j + 1]) if s2[j] - s2[i + 1] <= span else None
            if t is not None:
                cur = tuple(a + t * (b - a) for a, b in zip(cur, nxt))
                out.append(cur)
                i = j
                break
        else:
            out.append(nxt)
            cur, i = nxt, i + 1
    return out if out != pts else None


def unfolded_boundaries(m: HDMap, where: str = "map") -> HDMap:
    """`m` with every lane boundary's folds removed (`unfold`), with one warning naming the
    lanes: a lane wider than twice its inner border's turn radius folds that border back on
    itself (SVL CubeTown's right turns: a loop and a spike), so Lanelet2's loader inverted the
    bound and the turn lost its links, and the env's lane outline had a loop."""

    fixed: dict[str, Lane] = {}
    for ln in m.lanes.values():
        left, right = unfold(ln.left_boundary, ln.centerline), unfold(ln.right_boundary, ln.centerline)
        if left is not None or right is not None:
            fixed[ln.id] = replace(ln, left_boundary=ln.left_boundary if left is None else as_polyline(left),
                                   right_boundary=ln.right_boundary if right is None else as_polyline(right))
    if not fixed:
        return m
    shown = ", ".join(list(fixed)[:3]) + (" ..." if len(fixed) > 3 else "")
    warnings.warn(f"{where}: {len(fixed)} lane(s) with a boundary that folds back on itself (a border tighter than "
                  f"the lane's width): the folds dropped ({shown})", RepairWarning, stacklevel=3)
    return replace(m, lanes={**m.lanes, **fixed})


def drop_non_approaches(m: HDMap, where: str = "map") -> HDMap:
    """`m` without the lanes a control governs that are no approach of its junction (the
    `governed_lanes_are_approaches` finding), one warning per control naming them: the control's
    stop line is redrawn across the lanes it keeps, and a control left with none is dropped (a
    stop line drawn across both directions of a road made GoMentum's stop sign govern the lane
    leaving its junction too; every export then carried it)."""
    tables: dict[str, Any] = {}
    for kind in CONTROL_TABLES:
        table = getattr(m, kind)
        out = dict(table)
        for sid, s in table.items():
            if s.junction_id is None:
                continue
            keep = tuple(x for x in s.lane_ids if any(_leads_into(m, y, s.junction_id)
                                                      for y in incoming_lanes(m.lanes, (x,))))
            if keep == tuple(s.lane_ids):
                continue
            gone = ", ".join(x for x in s.lane_ids if x not in keep)
            what = f"dropped from it (it keeps {', '.join(keep)})" if keep else "dropped with it (it governs no other)"
            warnings.warn(f"{where}: {kind[:-1]} {sid}: governs lane(s) {gone}, which are not approaches of junction "
                          f"{s.junction_id}: {what}", stacklevel=3)
            if keep:
                out[sid] = replace(s, lane_ids=keep, stop_line=stop_line_across(m.lanes, keep) or s.stop_line)
            else:
                del out[sid]
            tables[kind] = out
    return replace(m, **tables) if tables else m


def split_conflicting_signals(m: HDMap, where: str = "map") -> HDMap:
    """`m` with every signal that governs approaches whose paths conflict split into one signal
    per group of approaches that do not (ids `<id>`, `<id>~2`, ...; groups the map declares get
    the new ids too), one warning each: one light cannot keep crossing traffic apart, and the
    phase plans must (a CARLA town's references give one light a right turn and the road it
    merges into)."""
    from .phases import PathConflicts, units_conflict

    pc = PathConflicts(m)
    signals: dict = {}
    renamed: dict[str, list[str]] = {}
    for sid, sig in m.signals.items():
        by_road: dict[str, list[str]] = {}
        for lid in sig.lane_ids:
            if lid in m.lanes:
                by_road.setdefault(m.lanes[lid].road_id, []).append(lid)
        paths = {r: tuple(x for lid in incoming_lanes(m.lanes, ids) for x in m.lanes[lid].successors
                          if x in m.lanes and m.lanes[x].junction_id is not None) for r, ids in by_road.items()}
        parts: list[list[str]] = []
        for road in by_road:
            home = next((p for p in parts if all(units_conflict(pc, paths[road], paths[q], True) is None for q in p)), None)
            if home is None:
                parts.append([road])
            else:
                home.append(road)
        if len(parts) < 2:
            signals[sid] = sig
            continue
        ids = [sid] + [f"{sid}~{k}" for k in range(2, len(parts) + 1)]
        for new, part in zip(ids, parts):
            keep = tuple(x for x in sig.lane_ids if x in m.lanes and m.lanes[x].road_id in part)
            signals[new] = replace(sig, id=new, lane_ids=keep, stop_line=stop_line_across(m.lanes, keep) or sig.stop_line)
        renamed[sid] = ids
        warnings.warn(f"{where}: signal {sid}: governs approaches whose paths conflict (roads "
                      f"{' / '.join(', '.join(p) for p in parts)}): split into signals {', '.join(ids)}", stacklevel=3)
    if not renamed:
        return m
    meta = dict(m.meta)
    groups = meta.get("signal_groups")
    if isinstance(groups, dict):
        meta["signal_groups"] = {g: [y for x in ids for y in renamed.get(x, [x])] for g, ids in groups.items()}
    return replace(m, signals=signals, meta=meta)


def drop_far_links(m: HDMap, where: str = "map") -> HDMap:
    """`m` without successor/predecessor links between lanes whose ends lie more than
    LANE_LINK_GAP_M apart (converters that link the roads on both sides of a junction past its
    connecting roads: routes jumped across the junction), with one warning for them all; and
    without links that reverse (`_reversing_links`), with one more warning."""
    far = _far_links(m)
    rev = [x for x in _reversing_links(m) if x[:2] not in {f[:2] for f in far}]
    if not far and not rev:
        return m
    cut: dict[str, dict[str, set[str]]] = {}
    for a, b, _ in far + rev:
        cut.setdefault(a, {}).setdefault("successors", set()).add(b)
        cut.setdefault(b, {}).setdefault("predecessors", set()).add(a)
    lanes = dict(m.lanes)
    for lid, fields in cut.items():
        ln = lanes[lid]
        kept: dict[str, Any] = {f: tuple(x for x in getattr(ln, f) if x not in gone) for f, gone in fields.items()}
        lanes[lid] = replace(ln, **kept)
    if far:
        shown = ", ".join(f"{a} -> {b} ({d:.0f} m)" for a, b, d in sorted(far, key=lambda x: -x[2])[:3])
        warnings.warn(f"{where}: {len(far)} lane link(s) between ends more than {LANE_LINK_GAP_M:g} m apart dropped "
                      f"(largest: {shown})", stacklevel=3)
    if rev:
        shown = ", ".join(f"{a} -> {b} ({d:.0f} deg)" for a, b, d in sorted(rev, key=lambda x: -x[2])[:3])
        warnings.warn(f"{where}: {len(rev)} lane link(s) whose successor starts heading more than "
                      f"{LINK_REVERSAL_DEG:g} degrees away dropped (largest: {shown})", stacklevel=3)
    return replace(m, lanes=lanes)


def bent(ln: Lane, gap: Sequence[float] | np.ndarray, at: str = "end", tail: float = BRIDGE_TAIL_M) -> Lane:
    """`ln` with its last (`at`="end") or first ("start") `tail` metres moved by `gap` (dx, dy),
    centre line and boundaries, smoothly from nothing to all of it (smoothstep: no kink where the
    bend begins), so that end lands where a linked lane's end is."""
    return replace(ln, centerline=_bent_line(ln.centerline, gap, at, tail),
                   left_boundary=_bent_line(ln.left_boundary, gap, at, tail),
                   right_boundary=_bent_line(ln.right_boundary, gap, at, tail), bezier=None)


def _bent_line(poly: Sequence[Sequence[float]], gap: Sequence[float] | np.ndarray, at: str, tail: float) -> tuple:
    """`poly` with its last (first) `tail` metres moved by `gap`, smoothly from nothing to all of it."""
    import numpy as np

    p = np.asarray(poly, dtype=float)[:, :2]
    s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(p, axis=0).T))])
    t = min(tail, s[-1]) or 1.0
    u = np.clip((s - (s[-1] - t)) / t if at == "end" else (t - s) / t, 0.0, 1.0)
    w = u * u * (3 - 2 * u)
    return tuple(map(tuple, p + w[:, None] * np.asarray(gap, dtype=float)))


def _line_onto(poly: Sequence[Sequence[float]], target: Sequence[float], at: str, tail: float) -> tuple:
    """`poly` ending (`at`="end", else starting) at `target`: cut where `target` lies alongside it
    when that is short of its end (a bend alone would fold it back; the points in the last
    BRIDGE_AHEAD_M before the cut go too, so the new end's heading is a chord's, not a wiggle's),
    then its last (first) `tail` metres bent onto `target`."""
    import shapely
    from shapely.geometry import LineString

    pts = [tuple(float(v) for v in q[:2]) for q in poly]
    if at == "start":
        pts.reverse()
    line = LineString(pts)
    cut = float(shapely.line_locate_point(line, shapely.Point(target[:2])))
    if cut < line.length - FOLD_BACK_M:
        s = shapely.line_locate_point(line, shapely.points(pts)).tolist()
        pts = [q for q, d in zip(pts, s) if d < cut - BRIDGE_AHEAD_M] + [tuple(line.interpolate(cut).coords[0])]
        if len(pts) < 2:
            pts = [pts[0], pts[0]]
    end = pts[-1]
    out = list(_bent_line(pts, (target[0] - end[0], target[1] - end[1]), "end", tail))
    if at == "start":
        out.reverse()
    return tuple(out)


def _end_gaps(a: Lane, b: Lane) -> list[tuple[float, float]]:
    """From `a`'s end to its successor `b`'s start: the (dx, dy) of the centre line, the left and
    the right boundary."""
    return [(float(q[0][0] - p[-1][0]), float(q[0][1] - p[-1][1]))
            for p, q in ((a.centerline, b.centerline), (a.left_boundary, b.left_boundary),
                         (a.right_boundary, b.right_boundary))]


def _onto(ln: Lane, other: Lane, at: str) -> Lane:
    """`ln` with its end (`at`="end") on `other`'s start, or its start on `other`'s end, line by
    line (`_line_onto`)."""
    i = 0 if at == "end" else -1

    def line(f: str) -> Any:
        return as_polyline(_line_onto(getattr(ln, f), getattr(other, f)[i], at, BRIDGE_TAIL_M))
    return replace(ln, centerline=line("centerline"), left_boundary=line("left_boundary"),
                   right_boundary=line("right_boundary"), bezier=None)


def turned_link_ends(m: HDMap, where: str = "map") -> HDMap:
    """`m` with every link whose lane ends turned against its successor's start (a boundary's ends
    more than LANE_END_SNAP_M apart, all three lines within LANE_LINK_GAP_M) closed: the lane with
    one link across it (the predecessor with one successor, else the successor with one
    predecessor) has each line's last (first) BRIDGE_TAIL_M metres bent onto the other lane's
    (`_line_onto`: a line whose new end lies alongside it is cut there first); one RepairWarning
    names the largest. SVL's Borregas Ave joins 8-11 m wide junction lanes to their roads with
    15-25 degree kinks in the reference line, so a side missed its successor's by up to 5 m: the
    exports' per-side snap (LANE_END_SNAP_M) left them apart, Lanelet2 found no route through the
    turn and Apollo refused the link."""
    import numpy as np

    lanes = dict(m.lanes)
    moved: set[tuple[str, str]] = set()
    shown: list[tuple[float, str, str]] = []
    for lid in m.lanes:
        for sid in m.lanes[lid].successors:
            a, b = lanes[lid], lanes.get(sid)
            if b is None or min(len(x) for x in (a.centerline, a.left_boundary, a.right_boundary, b.centerline,
                                                  b.left_boundary, b.right_boundary)) < 2:
                continue
            gaps = _end_gaps(a, b)
            dist = [float(np.hypot(*g)) for g in gaps]
            if max(dist[1:]) <= LANE_END_SNAP_M or max(dist) > LANE_LINK_GAP_M:
                continue
            if len(a.successors) == 1 and (lid, "end") not in moved:
                lanes[lid] = _onto(a, b, "end")
                moved.add((lid, "end"))
            elif len(b.predecessors) == 1 and (sid, "start") not in moved:
                lanes[sid] = _onto(b, a, "start")
                moved.add((sid, "start"))
            else:
                continue
            shown.append((max(dist), lid, sid))
    if not shown:
        return m
    top = ", ".join(f"{a} -> {b} ({d:.1f} m)" for d, a, b in sorted(shown, reverse=True)[:3])
    warnings.warn(f"{where}: {len(shown)} lane link(s) whose ends are turned against each other (a side more than "
                  f"{LANE_END_SNAP_M:g} m from its successor's) closed: each lane's last {BRIDGE_TAIL_M:g} m bent onto "
                  f"its successor's start, or the successor's first onto the lane's end (largest: {top})", RepairWarning,
                  stacklevel=3)
    return replace(m, lanes=lanes)


def bridge_gaps(m: HDMap, where: str = "map") -> HDMap:
    """`m` with every lane whose only successor starts more than BRIDGE_AHEAD_M ahead of its end
    or more than BRIDGE_ASIDE_M to its side (and within LANE_LINK_GAP_M: `drop_far_links` drops
    the rest) bent to meet it: its last BRIDGE_TAIL_M metres (centre line and boundaries) move by
    the gap, smoothly from nothing to all of it, so a car following the lanes never leaves them
    (osm2xodr writes links between lanes 1-5 m apart: a stretch without lane, or a lane one over).
    One warning for them all; a lane with several successors is left as it is."""
    import math

    import numpy as np

    fixed: dict[str, Any] = {}
    shown: list[tuple[float, str, str]] = []
    for ln in m.lanes.values():
        if len(ln.successors) != 1 or ln.successors[0] not in m.lanes or len(ln.centerline) < 2:
            continue
        nxt = m.lanes[ln.successors[0]]
        gap = np.subtract(nxt.start[:2], ln.end[:2])
        dist = float(np.hypot(*gap))
        h = ln.heading_at_end()
        ahead, aside = gap[0] * math.cos(h) + gap[1] * math.sin(h), -gap[0] * math.sin(h) + gap[1] * math.cos(h)
        if dist > LANE_LINK_GAP_M or (ahead <= BRIDGE_AHEAD_M and abs(aside) <= BRIDGE_ASIDE_M):
            continue

        fixed[ln.id] = bent(ln, gap, "end")
        shown.append((dist, ln.id, nxt.id))
    if not fixed:
        return m
    top = ", ".join(f"{a} -> {b} ({d:.1f} m)" for d, a, b in sorted(shown, reverse=True)[:3])
    warnings.warn(f"{where}: {len(fixed)} lane link(s) between ends 1-{LANE_LINK_GAP_M:g} m apart bridged: each "
                  f"lane's last {BRIDGE_TAIL_M:g} m bent to meet its successor (largest: {top})", stacklevel=3)
    return replace(m, lanes={**m.lanes, **fixed})


def drop_dangling(m: HDMap, where: str = "map") -> HDMap:
    """`m` without references to elements it does not hold: links and controls' lanes that name
    unknown lanes lose them, junction ids that name unknown junctions become None; each with a
    one-line warning naming `where`, the element and the id. Returns `m` itself when clean."""
    def warn(element: str, msg: str) -> None:
        warnings.warn(f"{where}: {element}: {msg}, skipped", stacklevel=3)

    lanes = dict(m.lanes)
    changed = False
    for lid, ln in m.lanes.items():
        upd: dict[str, Any] = {}
        for f in _LINKS:
            ids = getattr(ln, f)
            keep = tuple(x for x in ids if x in m.lanes)
            if keep != ids:
                warn(f"lane {lid}", f"{f} names unknown lane(s) {', '.join(x for x in ids if x not in m.lanes)}")
                upd[f] = keep
        if ln.junction_id is not None and ln.junction_id not in m.junctions:
            warn(f"lane {lid}", f"unknown junction {ln.junction_id}")
            upd["junction_id"] = None
        if upd:
            lanes[lid] = replace(ln, **upd)
            changed = True
    tables: dict[str, Any] = {}
    for kind in (*CONTROL_TABLES, "crosswalks"):
        out = {}
        for sid, s in getattr(m, kind).items():
            upd = {}
            ids = getattr(s, "lane_ids", ())
            keep = tuple(x for x in ids if x in m.lanes)
            if keep != ids:
                warn(f"{kind[:-1]} {sid}", f"governs unknown lane(s) {', '.join(x for x in ids if x not in m.lanes)}")
                upd["lane_ids"] = keep
            if s.junction_id is not None and s.junction_id not in m.junctions:
                warn(f"{kind[:-1]} {sid}", f"unknown junction {s.junction_id}")
                upd["junction_id"] = None
            out[sid] = replace(s, **upd) if upd else s
            changed = changed or bool(upd)
        tables[kind] = out
    roads = dict(m.roads)
    for rid, r in m.roads.items():
        if any(x not in m.lanes for x in r.lane_ids):
            warn(f"road {rid}", f"lists unknown lane(s) {', '.join(x for x in r.lane_ids if x not in m.lanes)}")
            roads[rid] = replace(r, right_lanes=tuple(x for x in r.right_lanes if x in m.lanes),
                                 left_lanes=tuple(x for x in r.left_lanes if x in m.lanes))
            changed = True
    if not changed:
        return m
    return replace(m, lanes=lanes, roads=roads, **tables)


__all__ = ["CHECKS", "Finding", "assert_sound", "bridge_gaps", "check_map", "drop_dangling", "drop_far_links",
           "drop_non_approaches", "findings", "link_touching_ends", "loaded", "split_conflicting_signals", "turned_link_ends",
           "unfold", "unfolded_boundaries"]
