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
