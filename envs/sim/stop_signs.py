"""Stop-sign order as row arrays: the queue a road user is in (`TrafficCore.stop_junction`, the
number of the junction whose stop sign it stopped at, -1 none) and its place in it (`stop_seq`,
the order of joining). One program joins and leaves the queues of every slot after a frame
(`update`); the rules read a slot's queues as lists of its vehicles, first come first served
(`queues`, what `TrafficControl.stop_queue` hands out and `TrafficRules.stop_queue_allows` asks).
"""
from __future__ import annotations

from typing import TYPE_CHECKING, Any

import numpy as np

from ..network import LINE_STOP_SIGN
from ..rules import has_stopped
from . import entries

if TYPE_CHECKING:
    from ..core import TrafficCore


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
    for the rules to ask (`waiting_line`): a stop sign's line on the lane a row is on (`lane`, per
    row) or on a lane of a driven row's window (the lanes its route runs on for LOOKAHEAD_M:
    `TrafficCore.stop_ahead`), every row whose window is to be rebuilt (its route position moved
    this frame: `TrafficCore.dirty`) and every external road user. A superset: the rules decide."""
    on = rows & (lane >= 0)
    ask = on & (core.stop_ahead | (core.table.line_kind[lane] == LINE_STOP_SIGN) | ~core.driven)
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


def turns(core: "TrafficCore", rows: np.ndarray, j_lane: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(allowed, known) per row of `rows` (each in the stop-sign queue of the junction of its
    next junction lane `j_lane`): `TrafficRules.stop_queue_allows`, no road user earlier in that
    queue drives into a lane conflicting with the row's (its lane in the junction: the first one
    on its route from the lane before its route position on). `known` is False where the arrays
    cannot say as the rules would (an earlier road user whose lane in the junction is beyond its
    window, whose route ran through the junction just before, or whose conflicting lane has a box
    to keep clear or a chain: `entries.EntryTable.simple`); the rules answer those. On a map
    with no narrow passages (a road user waiting for one lets later ones go)."""
    t = core.table
    et = entries.entry_table(core.net, t)
    nl, nj = len(t.length), len(t.junction_ids)
    junction = t.lane_junction[j_lane]
    key = core.env[rows] * nj + junction
    queued = (core.stop_junction >= 0).nonzero()[0]
    m = core.stop_count + 1  # (slot, junction, place in the queue) as one sortable number
    place = (core.env[queued] * nj + core.stop_junction[queued]) * m + core.stop_seq[queued]
    order = np.argsort(place)
    queued, place = queued[order], place[order]
    # (asking row, a road user earlier in its queue) pairs
    p, e = entries.expand_ranges(np.searchsorted(place, key * m), np.searchsorted(place, key * m + core.stop_seq[rows]))
    other = queued[e]
    j = junction[p]
    W = core.W[other]
    in_j = (W >= 0) & (t.lane_junction[np.maximum(W, 0)] == j[:, None])
    found = in_j.any(axis=1)
    lane = W[np.arange(len(other)), np.argmax(in_j, axis=1)]
    before = np.array([r[pos - 1] if pos > 0 else -1 for r, pos in
                       zip((core.routes[o] for o in other.tolist()), core.route_pos[other].tolist())], dtype=np.int64)
    came = (before >= 0) & (t.lane_junction[np.maximum(before, 0)] == j)
    conflict = found & entries.conflicting(et, nl, j_lane[p], np.maximum(lane, 0))
    unknown = ~found | came | (conflict & ~et.simple[np.maximum(lane, 0)])
    allowed, known = np.ones(len(rows), dtype=bool), np.ones(len(rows), dtype=bool)
    allowed[p[conflict]] = False
    known[p[unknown]] = False
    return allowed, known
