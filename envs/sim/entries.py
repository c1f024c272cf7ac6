"""The conflict rule at a junction entry, one program for every question: whether junction lane
`j` is clear for a road user (`rules.TrafficRules.junction_clear`, and with every conflicting
lane and approach `cross_traffic_near`), for many questions of many slots at once or one road
user's (`TrafficCore.lanes_clear`, what the rules ask), against the state as it is (a frame's
questions see the state the frame began with: the rules' questions are pure,
`control.TrafficControl.claim` is where a road user takes a lane, after every row has asked).
`TrafficCore._entry_answers` asks it of the rows whose first stop is a junction entry; an entry
whose other rules the arrays do not answer (a yield sign, a junction lane chained to the next, a
box to keep clear, a narrow passage) is asked of the rules one row at a time, which ask it here.

A junction lane is clear for a road user while no lane conflicting with it is occupied (a road
user located on it, or its reservation held by another) and no road user heading into a
conflicting lane of higher priority from an approach that may go (not held by a stop sign or a
red signal) reaches the end of the lane it is on within PRIORITY_HORIZON_S at its speed plus
PRIORITY_MARGIN_M, unless it waits for a narrow passage the asking road user holds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import PRIORITY_HORIZON_S, PRIORITY_MARGIN_M
from ..reservations import NONE
from ..rules import line_setback, room_to_wait

if TYPE_CHECKING:
    from ..core import LaneTable
    from ..network import MapNetwork

BOX_LENGTH_M = 30.0  # a body at most this long waits on a road with no box before it (`boxed`)


@dataclass(frozen=True)
class EntryTable:
    """Per lane (CSR over the network's lane indices): its conflicting lanes; the (conflicting
    lane, one of its approaches) pairs of the conflicting lanes of higher priority (`come`) and of
    every conflicting lane (`cross`), where road users about to enter count; and whether the
    arrays answer an entry into it (`simple`)."""

    conf_ptr: np.ndarray
    conf_lane: np.ndarray
    come_ptr: np.ndarray
    come_lane: np.ndarray
    come_from: np.ndarray
    cross_ptr: np.ndarray
    cross_lane: np.ndarray
    cross_from: np.ndarray
    simple: np.ndarray
    conf_key: np.ndarray  # lane * lanes + conflicting lane of every conflict, sorted


def entry_table(net: "MapNetwork", table: "LaneTable") -> EntryTable:
    """The network's `EntryTable`, built once per network."""
    return net.memo(("entry_table",), lambda: _build(net, table))


def _build(net: "MapNetwork", table: "LaneTable") -> EntryTable:
    ids, index, lanes = net.lane_ids, table.index, net.hdmap.lanes
    conf: list[list[int]] = []
    come: list[list[tuple[int, int]]] = []
    cross: list[list[tuple[int, int]]] = []
    for lid in ids:
        mine = net.lane_of[lid].priority
        conf.append([index[c] for c in net.conflicts.get(lid, ())])
        cross.append([(index[c], index[p]) for c in net.conflicts.get(lid, ()) for p in lanes[c].predecessors
                      if p in index])
        come.append([(c, p) for c, p in cross[-1] if net.lane_of[ids[c]].priority > mine])
    simple = np.array([lanes[lid].junction_id is not None and lid not in net.yield_entries
                       and not _chains(net, lid) and not _boxed(net, lid) for lid in ids], dtype=bool)
    conf_ptr, conf_lane = _csr(conf)
    come_ptr, come_pairs = _csr(come)
    cross_ptr, cross_pairs = _csr(cross)
    owner = np.repeat(np.arange(len(ids)), np.diff(conf_ptr))
    come_lane, come_from = come_pairs.reshape(-1, 2).T
    cross_lane, cross_from = cross_pairs.reshape(-1, 2).T
    return EntryTable(conf_ptr, conf_lane, come_ptr, come_lane, come_from, cross_ptr, cross_lane, cross_from, simple,
                      np.sort(owner * len(ids) + conf_lane))


def _csr(rows: list[list]) -> tuple[np.ndarray, np.ndarray]:
    """(row pointers, the items of every row one after another) of lists of lane indices (or pairs)."""
    ptr = np.cumsum([0] + [len(r) for r in rows])
    return ptr.astype(np.int64), np.array([x for r in rows for x in r], dtype=np.int64).ravel()


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


def junction_clear(core, slots: np.ndarray, me: np.ndarray, j: np.ndarray, *, priority: bool = True,
                   margin: float = PRIORITY_MARGIN_M, one: int = NONE) -> np.ndarray:
    """Per question k, whether junction lane `j[k]` (a lane index) is clear for road user `me[k]`
    (a row; NONE: nobody) of slot `slots[k]`, with the road users of that slot as they are now
    (`TrafficCore.where_lanes`: the rules' buckets), its reservations (`TrafficCore.res`) and
    whether an approach is held (a stop sign, a red signal: `TrafficCore.approach_held`). With
    `priority` False, `TrafficRules.cross_traffic_near`'s test: every conflicting lane counts,
    from every approach, held or not. `one`: the slot of every question, where all are of one
    (only its rows are read), else NONE."""
    et = entry_table(core.net, core.table)
    nl = len(core.table.length)
    clear = np.ones(len(j), dtype=bool)
    if not len(j):
        return clear
    rows, at, located = core.asked(("located", one), lambda: _located(core, one, nl))
    # (question, conflicting lane) pairs: a road user located on it, or its reservation held by another
    q, e = _expand(et.conf_ptr, j)
    c = et.conf_lane[e]
    asker = me[q]
    holder = core.res[slots[q], c]
    mine = (asker >= 0) & (core.where_lanes(np.maximum(asker, 0)) == c)  # (the asker's own place)
    blocked = (_on(located, one, nl, slots[q], c) > mine) | ((holder != NONE) & (holder != asker))
    clear[q[blocked]] = False
    # (question, conflicting lane, its approach) triples: a road user about to enter the lane, from
    # an approach someone is on
    ptr, lane, approach = (et.come_ptr, et.come_lane, et.come_from) if priority else \
        (et.cross_ptr, et.cross_lane, et.cross_from)
    hq, f = _expand(ptr, j)
    someone = (_on(located, one, nl, slots[hq], approach[f]) > 0).nonzero()[0]
    if priority and len(someone):
        someone = someone[~core.approach_held(slots[hq[someone]], approach[f[someone]])]
    if not len(someone):
        return clear
    hq, hc, p = hq[someone], lane[f[someone]], approach[f[someone]]
    keys, who = core.asked(("comers", one, margin), lambda: _comers(core, rows, at, nl, margin))
    hk = (slots[hq] * nl + p) * nl + hc
    t, m = expand_ranges(np.searchsorted(keys, hk, side="left"), np.searchsorted(keys, hk, side="right"))
    asker, comer = me[hq[t]], who[m]
    keep = comer != asker
    if core.net.passages:  # one waiting for a narrow passage the asker holds comes no nearer
        for x in (keep & (asker >= 0)).nonzero()[0].tolist():
            keep[x] = not core.roads[core.env[comer[x]]].control.waits_for(core.objs[comer[x]], core.objs[asker[x]])
    clear[hq[t[keep]]] = False
    return clear


def _located(core, slot: int, nl: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(the rows of `slot` (NONE: of every slot), the lane each is on (`TrafficCore.where_lanes`),
    and where they are for `_on`: how many are on each lane (one slot), else the sorted keys
    slot * lanes + lane of those on a lane)."""
    rows = core.slot_rows(slot) if slot != NONE else np.arange(len(core.objs))
    at = core.where_lanes(rows)
    on = at >= 0
    if slot != NONE:
        return rows, at, np.bincount(at[on], minlength=nl)
    return rows, at, np.sort(core.env[rows[on]] * nl + at[on])


def _on(located: np.ndarray, one: int, nl: int, slots: np.ndarray, lanes: np.ndarray) -> np.ndarray:
    """How many road users are on each lane of `lanes` in slot `slots` (`_located`'s last item)."""
    return located[lanes] if one != NONE else _count(located, slots * nl + lanes)


def _comers(core, rows: np.ndarray, at: np.ndarray, nl: int, margin: float) -> tuple[np.ndarray, np.ndarray]:
    """(sorted keys (slot, lane, next lane), their rows) of the road users among `rows` (located on
    lanes `at`) that follow a route, drive into `next lane` next (either of their next two route
    lanes, `rules.enters_next`) and reach the end of the lane they are on within
    PRIORITY_HORIZON_S at their speed plus `margin`: road users about to enter a lane. A driven
    row is read from its row (a controlled one where it is located, `at_s`; a window to be
    rebuilt from its route), an external road user from its object."""
    ids = core.net.lane_ids
    driven = core.driven[rows]
    follows = driven & (at >= 0)
    nxt = next_two(core.W)[rows]
    s, speed = np.where(core.controlled[rows], core.at_s[rows], core.s[rows]), core.speed[rows]
    if core.dirty or core._external:
        speed = speed.copy()
        for x in (np.isin(rows, list(core.dirty)) & driven).nonzero()[0].tolist() if core.dirty else ():
            i = int(rows[x])
            nxt[x] = _two(core.routes[i][core.route_pos[i]:core.route_pos[i] + 2])
        for x in (~driven & (at >= 0)).nonzero()[0].tolist():
            o = core.objs[rows[x]]
            route = getattr(o, "lane_route", None)
            if route:
                follows[x] = True
                nxt[x] = _two([core.table.index.get(lid, -1) for lid in route[o.route_pos:o.route_pos + 2]])
                s[x], speed[x] = o.s_on(ids[at[x]]), o.speed
    d = core.table.length[np.maximum(at, 0)] - s
    near = (follows & (d < PRIORITY_HORIZON_S * np.maximum(speed, 0.0) + margin)).nonzero()[0]
    base = (core.env[rows[near]] * nl + at[near]) * nl
    nxt = nxt[near]
    real = (nxt >= 0).T.ravel()
    keys = np.concatenate([base + nxt[:, 0], base + nxt[:, 1]])[real]
    who = np.concatenate([rows[near], rows[near]])[real]
    order = np.argsort(keys, kind="stable")
    return keys[order], who[order]


def _two(lanes: list[int]) -> list[int]:
    """Route lanes as a row of `next_two` (-1 padded)."""
    return (list(lanes) + [-1, -1])[:2]


def next_two(W: np.ndarray) -> np.ndarray:
    """The first two columns of window lanes `W` (route position and the next; -1 none)."""
    return W[:, :2] if W.shape[1] >= 2 else np.hstack([W, np.full((len(W), 1), -1, dtype=W.dtype)])


def _expand(ptr: np.ndarray, idx: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, entry) of every CSR entry of the items `idx` (`ptr`'s rows), grouped by owner."""
    return expand_ranges(ptr[idx], ptr[idx + 1])


def expand_ranges(start: np.ndarray, end: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(owner, index) of every index in [start[k], end[k]) for each k, grouped by owner."""
    if len(start) == 1:  # (one range: the same, in two operations)
        idx = np.arange(start[0], end[0])
        return np.zeros(len(idx), dtype=np.int64), idx
    cnt = end - start
    owner = np.repeat(np.arange(len(start)), cnt)
    return owner, np.repeat(start - (np.cumsum(cnt) - cnt), cnt) + np.arange(int(cnt.sum()))


def conflicting(et: EntryTable, nl: int, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Per pair, whether junction lane `b` conflicts with `a` (`MapNetwork.conflicts`; lane indices)."""
    return _count(et.conf_key, a * nl + b) > 0


def _count(sorted_keys: np.ndarray, keys: np.ndarray) -> np.ndarray:
    """How often each of `keys` occurs in `sorted_keys`."""
    return np.searchsorted(sorted_keys, keys, side="right") - np.searchsorted(sorted_keys, keys, side="left")
