"""Stop-sign order as row arrays: the queue a road user is in (`TrafficCore.stop_junction`, the
number of the junction whose stop sign it stopped at, -1 none) and its place in it (`stop_seq`,
the order of joining). One program joins and leaves the queues of every slot after a frame
(`update`); the rules read a slot's queues as lists of its vehicles, first come first served
(`queues`, what `TrafficControl.stop_queue` hands out); whose turn it is (`turns`) is one
program for every queued road user asked, the rules' `stop_queue_allows` one of them.
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ...config import STOP_ZONE_M
from ..network import LINE_STOP_SIGN
from ..rules import has_stopped
from . import entries, passages

if TYPE_CHECKING:
    from ..core import TrafficCore

ZONE_MARGIN_M = 1.0  # rows this much further from a stop sign's line than STOP_ZONE_M are asked too (a superset)


def update(core: "TrafficCore", rows: np.ndarray) -> None:
    """Bring the stop-sign queues of the road users in `rows` (a mask over the core's rows) up
    to date after a frame: a queued one leaves on entering a lane of its junction; then one that
    has stopped (`rules.has_stopped`) before a stop sign's line (`TrafficRules.waiting_line`)
    and is in no queue joins that junction's queue, in row order (its road's vehicles' order)."""
    stopped = rows & has_stopped(core.speed)
    if not core.queued and not stopped.any():  # (nobody to leave or join)
        return
    lane = core.where_lanes()
    if core.queued:
        queued = (rows & (core.stop_junction >= 0)).nonzero()[0]
        on = lane[queued]
        left = queued[(on < 0) | (core.table.lane_junction[np.maximum(on, 0)] == core.stop_junction[queued])]
        if len(left):
            core.stop_junction[left] = -1
            core.queue_version[core.env[left]] += 1
            core.queued -= len(left)
    joins = []
    number = core.table.junction_number
    for i in candidates(core, stopped & (core.stop_junction < 0), lane).tolist():
        sl, _ = core.roads[core.env[i]].control.waiting_line(core.objs[i], core.net.lane_ids[lane[i]])
        if sl is not None and sl.kind == "stop":
            joins.append((i, number[sl.junction_id]))
    if joins:
        new, junction = np.array(joins, dtype=np.int64).T
        core.stop_junction[new] = junction
        core.stop_seq[new] = core.stop_count + np.arange(len(new))
        core.stop_count += len(new)
        core.queued += len(new)
        core.queue_version[core.env[new]] += 1


def candidates(core: "TrafficCore", rows: np.ndarray, lane: np.ndarray) -> np.ndarray:
    """The rows of `rows` (a mask) on the map's lanes that may stand before a stop sign's line,
    for the rules to ask (`waiting_line`): a driven row whose window's first stop sign's line
    (`TrafficCore.stop_at`: on the lanes its route runs on for LOOKAHEAD_M) lies at most
    STOP_ZONE_M (and ZONE_MARGIN_M) ahead of it, or behind it; a row located off its route lane
    (`lane`, per row) on a lane with a stop sign's line; every row whose window is to be rebuilt
    (its route position moved this frame: `TrafficCore.dirty`) and every external road user. A
    superset: the rules decide."""
    on = rows & (lane >= 0)
    near = core.stop_at - core.s <= STOP_ZONE_M + ZONE_MARGIN_M
    off_route = (lane != core.lane) & (core.table.line_kind[lane] == LINE_STOP_SIGN)
    ask = on & (near | off_route | ~core.driven)
    if core.dirty:
        dirty = np.zeros(len(rows), dtype=bool)
        dirty[[i for i in core.dirty if i < len(rows)]] = True
        ask |= on & dirty
    return ask.nonzero()[0]


def queues(core: "TrafficCore", slot: int) -> dict[Any, list]:
    """A slot's stop-sign queues: {junction id: its vehicles in the order they joined}, made
    again only after a join, a leave or rows coming or going (read-only: the rows are the state)."""
    version = int(core.queue_version[slot])
    held = core.queue_views.get(slot)
    if held is not None and held[0] == version:
        return held[1]
    rows = core.slot_rows(slot)
    rows = rows[core.stop_junction[rows] >= 0]
    rows = rows[np.argsort(core.stop_seq[rows], kind="stable")]
    out: dict[Any, list] = {}
    ids = core.table.junction_ids
    for i, j in zip(rows.tolist(), core.stop_junction[rows].tolist()):
        out.setdefault(ids[j], []).append(core.objs[i])
    core.queue_views[slot] = (version, out)
    return out


def turns(core: "TrafficCore", rows: np.ndarray, j_lane: np.ndarray) -> np.ndarray:
    """Per row of `rows`, whether its turn has come at the stop sign before its next junction
    lane `j_lane` (lane indices), first come first served: it is in the queue of that lane's
    junction, and no road user earlier in the queue drives into a lane conflicting with it and may
    take it (one the box rule holds back, `TrafficRules.box_clear`, or one waiting for a narrow
    passage lets later ones go; one whose lane in the junction is unknown holds them). Stop-sign
    order's one place: the rules' `stop_queue_allows` asks it of one road user, the core
    (`_entry_answers`) of every row at a stop sign's junction entry at once."""
    t = core.table
    et = entries.entry_table(core.net, t)
    nl, nj = len(t.length), len(t.junction_ids)
    junction = t.lane_junction[j_lane]
    allowed = core.stop_junction[rows] == junction
    ask = allowed.nonzero()[0]
    key = core.env[rows[ask]] * nj + junction[ask]
    queued = (core.stop_junction >= 0).nonzero()[0]
    m = core.stop_count + 1  # (slot, junction, place in the queue) as one sortable number
    place = (core.env[queued] * nj + core.stop_junction[queued]) * m + core.stop_seq[queued]
    order = np.argsort(place)
    queued, place = queued[order], place[order]
    # (asking row, a road user earlier in its queue) pairs
    q, e = entries.expand_ranges(np.searchsorted(place, key * m),
                                 np.searchsorted(place, key * m + core.stop_seq[rows[ask]]))
    p, other = ask[q], queued[e]
    lane = lanes_in(core, other, junction[p])
    takes = (lane < 0) | entries.conflicting(et, nl, j_lane[p], np.maximum(lane, 0))
    k = (takes & (lane >= 0) & (~et.simple[np.maximum(lane, 0)]
                                | (core.length[other] > entries.BOX_LENGTH_M))).nonzero()[0]
    for x, o, lid in zip(k.tolist(), other[k].tolist(), lane[k].tolist()):  # a box to keep clear
        takes[x] = core.roads[core.env[o]].control.box_clear(core.objs[o], core.net.lane_ids[lid])
    if core.net.passages:  # one waiting for a narrow passage lets later ones go
        takes &= ~np.isin(other, passages.waiting_rows(core))
    allowed[p[takes]] = False
    return allowed


def lanes_in(core: "TrafficCore", rows: np.ndarray, junction: np.ndarray) -> np.ndarray:
    """Per row of `rows`, the lane of junction `junction` (numbers) it drives into next (lane
    indices, -1 none): the first one on its route from the lane before its route position on,
    since a route follower moves on in the last metre of its lane (Shalun's sim_map r008: a car
    later in J_1's stop queue took a lane merging with the ego's as the ego crossed its line).
    Read from the lane before and its window, else (beyond the window, a window to be rebuilt,
    a road user that is no driven row) from its route."""
    t = core.table
    driven = core.driven[rows]
    before = np.array([core.routes[o][k - 1] if d and k > 0 else -1 for o, k, d in
                       zip(rows.tolist(), core.route_pos[rows].tolist(), driven.tolist())], dtype=np.int64)
    W = np.hstack([before[:, None], core.W[rows]])
    in_j = (W >= 0) & (t.lane_junction[np.maximum(W, 0)] == junction[:, None])
    lane = np.where(in_j.any(axis=1), W[np.arange(len(rows)), np.argmax(in_j, axis=1)], -1)
    look = ~driven | (lane < 0)
    if core.dirty:
        look |= np.isin(rows, list(core.dirty))
    for x in look.nonzero()[0].tolist():
        lane[x] = _lane_on_route(core, core.objs[int(rows[x])], int(junction[x]))
    return lane


def _lane_on_route(core: "TrafficCore", obj: Any, junction: int) -> int:
    """`lanes_in` of one road user, read from its route (-1 none, or no route)."""
    route = getattr(obj, "lane_route", None)
    if route is None:
        return -1
    t = core.table
    for lid in route[max(obj.route_pos - 1, 0):]:
        k = t.index.get(lid, -1)
        if k >= 0 and t.lane_junction[k] == junction:
            return k
    return -1
