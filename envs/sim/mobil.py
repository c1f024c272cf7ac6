"""MOBIL's lane changes of traffic as one program (docs/architecture.md, "traffic"): the rows due
(every MOBIL_PERIOD_S, on a road lane with a same-direction neighbour across a dashed line, room
and speed enough: `TrafficCore._mobil`) ask every such neighbour at once, against the state the
frame began with; the changes taken are then applied in row order, each to the first neighbour
that accepts.

A neighbour lane is taken when the car's acceleration behind the road users ahead on it (IDM,
`rules.idm_accelerations`) beats its acceleration behind its own leaders by MOBIL_GAIN_MPS2 plus
MOBIL_POLITENESS times what the new follower loses, that follower need not brake harder than
MOBIL_SAFE_BRAKE_MPS2, both keep MOBIL_MIN_GAP_M, the neighbour runs beside the car already, and
a route from it to the destination road is at most MOBIL_DETOUR_M longer than the car's
(`MapNetwork.lane_route_within`). The road users on a lane are those its slot's rows locate
there (a controlled row on its located lane), each measured along the neighbour from its place
(`lanes.project_rows`: `PolylineLane.local_coordinates`' arithmetic).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

from ...config import IDM_GAP_M, MOBIL_DETOUR_M, MOBIL_MIN_GAP_M
from ...invariants import lane_changes
from ..lanes import project_rows
from ..rules import idm_accelerations, may_change_lane, mobil_accepts, mobil_safe
from ..vehicles import RouteFollower
from .join import same_key_pairs

if TYPE_CHECKING:
    from ..core import TrafficCore


def decide(core: "TrafficCore", rows: np.ndarray, fi: np.ndarray, gap: np.ndarray,
           v_lead: np.ndarray) -> list[tuple[int, int, tuple[str, ...]]]:
    """The lane changes traffic `rows` (row indices, ascending) take: (row, neighbour lane int, the
    route from it), in row order, given their leaders on their own lanes ((follower row, bumper
    gap, leader speed), `TrafficCore._leaders`)."""
    t, net = core.table, core.net
    m = net.hdmap
    lane = core.lane[rows]
    xy = np.stack([core.x[rows], core.y[rows]], axis=1)
    s_own = _along(core, lane, xy[:, 0], xy[:, 1])
    ok = may_change_lane(t.junction[lane], t.length[lane] - s_own, core.speed[rows])
    rows, lane, xy = rows[ok], lane[ok], xy[ok]
    if not len(rows):
        return []
    # the pairs (row, neighbour lane) with a route to the destination road short enough
    ids = net.lane_ids
    pr, pn, paths = [], [], []
    for k, (i, ln) in enumerate(zip(rows.tolist(), lane.tolist())):
        route, pos = core.route_ids[i], int(core.route_pos[i])
        limit = sum(net.lane_of[x].length for x in route[pos:]) + MOBIL_DETOUR_M
        goal = m.lanes[route[-1]]
        for n in lane_changes(m.lanes[ids[ln]]):  # only across a dashed line
            if n not in m.lanes:
                continue
            found = [f[0] for g in (goal.id,) + goal.left_neighbors + goal.right_neighbors  # any lane of the
                     if g in m.lanes and (f := net.lane_route_within(n, g, limit))]  # destination road will do
            if found:
                pr.append(k)
                pn.append(t.index[n])
                paths.append(min(found, key=len))  # (the fewest lanes)
    if not pr:
        return []
    p_row, p_lane = np.array(pr, dtype=np.int64), np.array(pn, dtype=np.int64)
    me = rows[p_row]
    sn = _along(core, p_lane, xy[p_row, 0], xy[p_row, 1])
    beside = (sn >= 0.0) & (sn <= t.length[p_lane])  # not onto a lane that opens along the road ahead
    # the road users on each pair's neighbour lane (of the car's slot), measured along it
    where = core.where_lanes()
    on = (where >= 0).nonzero()[0]
    nl = len(t.length)
    a, b = same_key_pairs(core.env[me] * nl + p_lane, core.env[on] * nl + where[on])
    o = on[b]
    so = _along(core, p_lane[a], core.x[o], core.y[o])
    length, speed = core.length[me], core.speed[me]
    ahead = so >= sn[a]
    g_ahead = so - sn[a] - length[a]
    fine = beside & (np.bincount(a[ahead & (g_ahead < MOBIL_MIN_GAP_M)], minlength=len(pr)) == 0)
    v0 = t.speed_limit[lane]  # (towards its own lane's limit, as on its own lane)
    mine = np.isin(fi, rows)  # (its leaders on its own lane)
    a_cur = idm_accelerations(core.speed[rows], v0, np.searchsorted(rows, fi[mine]), gap[mine], v_lead[mine],
                              np.full(int(mine.sum()), IDM_GAP_M))
    ah = ahead.nonzero()[0]
    a_new = idm_accelerations(speed, v0[p_row], a[ah], g_ahead[ah], core.speed[o[ah]], np.full(len(ah), IDM_GAP_M))
    # the new follower: the nearest behind (the first in row order of equals)
    loss = np.zeros(len(pr))
    bh = (~ahead).nonzero()[0]
    if len(bh):
        by = bh[np.lexsort((o[bh], -so[bh], a[bh]))]  # by pair, the nearest behind first, then row order
        first = by[np.r_[True, a[by][1:] != a[by][:-1]]]
        p, f = a[first], o[first]
        g_f = sn[p] - so[first] - length[p]
        follows = np.array([isinstance(core.objs[x], RouteFollower) for x in f.tolist()], dtype=bool)
        v0_f = np.array([t.speed_limit[core.routes[x][core.route_pos[x]]] if ok else 1.0  # (its route lane's)
                         for x, ok in zip(f.tolist(), follows.tolist())])
        each = np.arange(len(p))
        a_f = idm_accelerations(core.speed[f], v0_f, each, g_f, speed[p], np.full(len(p), IDM_GAP_M))
        a_free = idm_accelerations(core.speed[f], v0_f, each[:0], g_f[:0], g_f[:0], g_f[:0])
        fine[p] &= (g_f >= MOBIL_MIN_GAP_M) & follows & mobil_safe(a_f)
        loss[p] = np.maximum(0.0, a_free - a_f)
    takes = fine & mobil_accepts(a_cur[p_row], a_new, loss)
    out, seen = [], set()
    for j in takes.nonzero()[0].tolist():  # the first neighbour that accepts
        if pr[j] not in seen:
            seen.add(pr[j])
            out.append((int(me[j]), pn[j], paths[j]))
    return out


def _along(core: "TrafficCore", lanes: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """Arc length of each point (x, y) along its lane (`lanes.project_rows`, one point a lane)."""
    if not len(lanes):
        return np.zeros(0)
    return project_rows(core.net.segment_table(), lanes, x[:, None], y[:, None], lateral=False)[0][:, 0]
