"""The junction-entry question for many road users at once: whether each may drive past its
line into its next junction lane now (`rules.TrafficRules.may_enter`'s conflict rule,
`junction_clear`), answered for every row of every slot with a few array operations against the
state the frame began with (the rules' questions are pure: `control.TrafficControl.claim` is
where a road user takes a lane, after every row has asked). `TrafficCore._entry_answers` asks it
of the rows whose first stop is a junction entry; an entry the arrays cannot answer exactly (a
yield sign, a junction lane chained to the next, a box to keep clear, a stop sign's queue, a
narrow passage) is asked of the rules one row at a time.

A junction lane is clear for a road user while no lane conflicting with it is occupied (a road
user located on it, or its reservation held by another) and no road user heading into a
conflicting lane of higher priority from an approach that may go (not held by a stop sign or a
red signal) reaches the end of its approach lane within PRIORITY_HORIZON_S at its speed plus
PRIORITY_MARGIN_M.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Callable

import numpy as np

from ...config import PRIORITY_HORIZON_S, PRIORITY_MARGIN_M
from ..rules import line_setback, room_to_wait

if TYPE_CHECKING:
    from ..core import LaneTable
    from ..network import MapNetwork

BOX_LENGTH_M = 30.0  # a body at most this long waits on a road with no box before it (`boxed`)


@dataclass(frozen=True)
class EntryTable:
    """Per lane (CSR over the network's lane indices): its conflicting lanes, whether each has
    the higher priority, each lane's predecessors, and whether the arrays answer an entry into it
    (`simple`)."""

    conf_ptr: np.ndarray
    conf_lane: np.ndarray
    conf_higher: np.ndarray
    pred_ptr: np.ndarray
    pred_lane: np.ndarray
    simple: np.ndarray
    conf_key: np.ndarray  # lane * lanes + conflicting lane of every conflict, sorted


def entry_table(net: "MapNetwork", table: "LaneTable") -> EntryTable:
    """The network's `EntryTable`, built once per network."""
    return net.memo(("entry_table",), lambda: _build(net, table))


def _build(net: "MapNetwork", table: "LaneTable") -> EntryTable:
    ids, index, lanes = net.lane_ids, table.index, net.hdmap.lanes
    conf_ptr, conf_lane, conf_higher, pred_ptr, pred_lane = [0], [], [], [0], []
    for lid in ids:
        mine = net.lane_of[lid].priority
        for c in net.conflicts.get(lid, ()):
            conf_lane.append(index[c])
            conf_higher.append(net.lane_of[c].priority > mine)
        conf_ptr.append(len(conf_lane))
        pred_lane += [index[p] for p in lanes[lid].predecessors if p in index]
        pred_ptr.append(len(pred_lane))
    simple = np.array([lanes[lid].junction_id is not None and lid not in net.yield_entries
                       and not _chains(net, lid) and not _boxed(net, lid) for lid in ids], dtype=bool)
    as_int = lambda a: np.array(a, dtype=np.int64)  # noqa: E731
    owner = np.repeat(np.arange(len(ids)), np.diff(conf_ptr))
    return EntryTable(as_int(conf_ptr), as_int(conf_lane), np.array(conf_higher, dtype=bool), as_int(pred_ptr),
                      as_int(pred_lane), simple, np.sort(owner * len(ids) + as_int(conf_lane)))


def _chains(net: "MapNetwork", lid: str) -> bool:
    """Whether a route through junction lane `lid` may chain a next lane to it
    (`TrafficRules.junction_chain`: a lane of the same junction, or a road lane crossing one)."""
    lanes, jid = net.hdmap.lanes, net.hdmap.lanes[lid].junction_id
    for s in lanes[lid].successors:
        if s not in lanes:
            continue
        if lanes[s].junction_id == jid or (lanes[s].junction_id is None and
                                           any(lanes[c].junction_id == jid for c in net.conflicts.get(s, ()))):
            return True
    return False


def _boxed(net: "MapNetwork", lid: str) -> bool:
    """Whether a route through junction lane `lid` may meet the next junction with less road
    between them than a BOX_LENGTH_M body waits on (`TrafficRules.box_clear` then asks that
    junction's lane too): any way on from `lid` through road lanes and lanes of its own junction,
    each lane followed while the road so far could still be that short."""
    lanes, jid = net.hdmap.lanes, net.hdmap.lanes[lid].junction_id
    back = max(net.setbacks.values(), default=0.0)
    least = {lid: 0.0}  # the least road before each lane reached
    stack = [lid]
    while stack:
        here = stack.pop()
        room = least[here]
        for s in lanes[here].successors:
            if s not in lanes or s not in net.lane_of:
                continue
            j = lanes[s].junction_id
            if j is not None and j != jid:
                if not room_to_wait(room - line_setback(net, here), BOX_LENGTH_M):
                    return True
                continue
            more = room + (net.lane_of[s].length if j is None else 0.0)
            if more < least.get(s, math.inf) and not room_to_wait(more - back, BOX_LENGTH_M):
                least[s] = more
                stack.append(s)
    return False


def junction_clear(core, rows: np.ndarray, j: np.ndarray, held_key: np.ndarray, held_row: np.ndarray,
                   held_at: Callable[[np.ndarray, np.ndarray], np.ndarray]) -> np.ndarray:
    """Per row of `rows`, `TrafficRules.junction_clear` of its junction lane `j` (lane indices)
    with the rows of its slot as they are now (`TrafficCore.where_lanes`: the rules' buckets), the
    reservations at keys `held_key` (slot * lanes + lane, sorted) held by rows `held_row` (-2: a
    road user no longer a row) and `held_at(slots, lanes)`: whether an approach is held (a stop
    sign, a red signal). The rows' slots hold no road user the arrays cannot place (`placed`)."""
    et = entry_table(core.net, core.table)
    nl = len(core.table.length)
    slot = core.env[rows]
    at = core.where_lanes()
    # (asking row, conflicting lane) pairs: a road user located on it, or its reservation held by another
    q, e = _expand(et.conf_ptr, j)
    c = et.conf_lane[e]
    key = slot[q] * nl + c
    located = (at >= 0).nonzero()[0]
    blocked = _count(np.sort(core.env[located] * nl + at[located]), key) > (at[rows[q]] == c)
    if len(held_key):
        k = np.searchsorted(held_key, key).clip(max=len(held_key) - 1)
        blocked |= (held_key[k] == key) & (held_row[k] != rows[q])
    # (asking row, higher-priority conflicting lane, its approach) triples: a road user about to enter
    high = et.conf_higher[e].nonzero()[0]
    h, f = _expand(et.pred_ptr, c[high])
    hq, hc, p = q[high][h], c[high][h], et.pred_lane[f]
    go = ~held_at(slot[hq], p)
    if go.any():
        hq, hc, p = hq[go], hc[go], p[go]
        near, keys = _about(core, at, nl)
        hk = (slot[hq] * nl + p) * nl + hc
        me = rows[hq]
        nxt = _next_two(core.W)
        own = near[me] & (at[me] == p) & ((nxt[me, 0] == hc) | (nxt[me, 1] == hc))  # (it is no other)
        clear_of = _count(keys, hk) <= own
    else:
        hq, clear_of = hq[:0], np.ones(0, dtype=bool)
    clear = np.ones(len(rows), dtype=bool)
    clear[q[blocked]] = False
    clear[hq[~clear_of]] = False
    return clear


def placed(core) -> np.ndarray:
    """Per slot, whether the arrays place every road user the rules would ask about: each driven
    row on its route lane (a controlled row located off it is where the rules project it) and no
    external road user that follows a route."""
    ok = np.ones(len(core.roads), dtype=bool)
    off = core.driven & (core.where_lanes() != core.lane)
    ok[core.env[off]] = False
    for i in core._external:
        if getattr(core.objs[i], "lane_route", None) is not None:
            ok[core.env[i]] = False
    return ok


def _about(core, at: np.ndarray, nl: int) -> tuple[np.ndarray, np.ndarray]:
    """(per row: near the end of its lane, the sorted keys (slot, lane, next lane) of the driven
    rows near the end of the lane they are on that drive into `next lane` next (either of their
    next two route lanes, `rules.enters_next`): `TrafficRules.about_to_enter`'s road users."""
    d = core.table.length[np.maximum(at, 0)] - core.s
    near = core.driven & (at >= 0) & (d < PRIORITY_HORIZON_S * np.maximum(core.speed, 0.0) + PRIORITY_MARGIN_M)
    r = near.nonzero()[0]
    base = (core.env[r] * nl + at[r]) * nl
    nxt = _next_two(core.W)[r]
    keys = np.concatenate([base + nxt[:, 0], (base + nxt[:, 1])[nxt[:, 1] >= 0]])
    return near, np.sort(keys)


def _next_two(W: np.ndarray) -> np.ndarray:
    """The first two columns of window lanes `W` (route position and the next; -1 none)."""
    return W[:, :2] if W.shape[1] >= 2 else np.hstack([W, np.full((len(W), 1), -1, dtype=W.dtype)])


def _expand(ptr: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, entry) of every CSR entry of the items `idx` (`ptr`'s rows), grouped by owner."""
    return expand_ranges(ptr[idx], ptr[idx + 1])


def expand_ranges(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index) of every index in [start[k], end[k]) for each k, grouped by owner."""
    cnt = end - start
    owner = np.repeat(np.arange(len(start)), cnt)
    return owner, np.repeat(start - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))


def conflicting(et: EntryTable, nl: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pair, whether junction lane `b` conflicts with `a` (`MapNetwork.conflicts`; lane indices)."""
    return _count(et.conf_key, a * nl + b) > 0


def _count(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """How often each of `keys` occurs in `sorted_keys`."""
    return np.searchsorted(sorted_keys, keys, side="right") - np.searchsorted(sorted_keys, keys, side="left")
