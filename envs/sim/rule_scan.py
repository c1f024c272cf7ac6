"""Where along its route the rules can stop a road user, for rows at once: the one scan of the
rules' stop distance (`TrafficRules.stop_distance`). A row's scan runs over its window lanes
(`TrafficCore.W`) within LOOKAHEAD_M, up to the first road after its next junction entry with
room to wait on it (`rules.room_to_wait`), however many short lanes lie before a line and however
many junctions follow each other with less road between them. On each lane scanned it notes what
can stop the row there, in the order the rules ask it: a road lane across a junction lane
(`TrafficRules.crossing_held`), a junction entry (its line: `may_enter`), a mid-block crossing's
light (`midblock_stop`), a crosswalk with people on it (`pedestrian_blocking`). The rules walk a
row's stops in order (`TrafficRules._rule_stop`); the batched core answers in arrays the rows
whose first stop a program settles (`TrafficCore._rule_stops`: a signal that holds them, a
junction entry, a crosswalk with people).
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np

from ...config import LOOKAHEAD_M
from ..rules import CROSSED, ENTRY, MIDBLOCK, PEOPLE, room_to_wait
from .join import member

if TYPE_CHECKING:
    from ..core import TrafficCore

IS_ANY_COMPARISONS = 8  # `is_any` compares value by value up to this many values (more: a binary search)


@dataclass
class Scan:
    """A scan of rows: per row and window place, the lane (`lanes`, -1 past the route's end),
    the distance from the row's centre to its start (`D`: negative on the current lane) and what
    on it can stop the row (`what`: bits, 0 on lanes holding nothing or not scanned). `index`
    lists the stops for `TrafficRules._rule_stop` to walk."""

    lanes: np.ndarray
    D: np.ndarray
    what: np.ndarray
    # the stops of the rows indexed, flat in row and route order: the `r`-th row's are
    # `first[r]` up to `end[r]`: lane, the lane before it (-1 for the current lane), distance,
    # what; `state[r]`: the signal's state at its first stop's line where known (None: the
    # rules look). Flat lists, so that no object is made per row.
    lane: list = field(default_factory=list)
    prev: list = field(default_factory=list)
    dist: list = field(default_factory=list)
    bits: list = field(default_factory=list)
    first: list = field(default_factory=list)
    end: list = field(default_factory=list)
    state: list = field(default_factory=list)

    def index(self, asked: np.ndarray | None = None) -> "Scan":
        """List the stops of the rows `asked` (a mask over the scan's rows; default every row)."""
        what = self.what if asked is None else np.where(asked[:, None], self.what, 0)
        r_i, k_i = what.nonzero()  # row by row, in route order
        self.lane = self.lanes[r_i, k_i].tolist()
        self.prev = np.where(k_i > 0, self.lanes[r_i, np.maximum(k_i - 1, 0)], -1).tolist()
        self.dist = self.D[r_i, k_i].tolist()
        self.bits = what[r_i, k_i].tolist()
        places = np.arange(len(self.what))
        self.first = np.searchsorted(r_i, places).tolist()
        self.end = np.searchsorted(r_i, places, side="right").tolist()
        self.state = [None] * len(self.what)
        return self

    def stops(self, r: int) -> list[tuple[int, int, float, int]]:
        """The `r`-th row's stops as (lane, lane before, distance, what) (indexed)."""
        k = slice(self.first[r], self.end[r])
        return list(zip(self.lane[k], self.prev[k], self.dist[k], self.bits[k]))


def along(table, lanes: list[int], length: float) -> list[int]:
    """What of a window's scan holds while the route position does (`TrafficCore.
    refresh_windows`, once per window): per window lane what can stop a road user `length` long
    there (a crosswalk's people aside), up to the last lane the scan reaches, the first road lane
    after a junction lane whose road since that junction lane (itself included), less its line's
    setback, holds the road user waiting (`rules.room_to_wait`); nothing beyond."""
    junction, crossed, midblock = table.junction, table.crossed, table.midblock
    what = [MIDBLOCK if midblock[lanes[0]] else 0]
    entered, room = False, 0.0  # past a junction lane; road since the last one
    for k in range(1, len(lanes)):
        lane = lanes[k]
        j = junction[lane]
        what.append((CROSSED if crossed[lane] else 0) | (ENTRY if j and not junction[lanes[k - 1]] else 0) |
                    (MIDBLOCK if midblock[lane] else 0))
        if j:
            entered, room = True, 0.0
        elif entered:
            room += table.length[lane]
            if room_to_wait(room - table.line_setback[lane], length):
                break
    return what


def scan(core: "TrafficCore", rows: np.ndarray | None = None) -> Scan:
    """The scan of driven `rows` (row indices, default every row; their windows up to date):
    the window's stops (`along`) within LOOKAHEAD_M of each row, and the crosswalks with people
    on them now."""
    if rows is None:
        W, C, s, env, what, reach = core.W, core.C, core.s, core.env, core.scan_what, core.scan_len
    else:
        W, C, s, env, what, reach = (core.W[rows], core.C[rows], core.s[rows], core.env[rows], core.scan_what[rows],
                                     core.scan_len[rows])
    D = C - s[:, None]
    # within LOOKAHEAD_M (the current lane, at D = -s, always) and up to where `along` stops
    scanned = (D <= LOOKAHEAD_M) & (np.arange(W.shape[1]) < reach[:, None])
    what = what * scanned
    busy = busy_lanes(core)
    if busy:
        key = env[:, None] * len(core.table.length) + W
        what |= np.where(scanned & (W >= 0) & is_any(key, busy), PEOPLE, 0).astype(np.int8)
    return Scan(W, D, what)


def busy_lanes(core: "TrafficCore") -> list[int]:
    """Keys (slot * lanes + lane) of the lanes across a crosswalk that has people on it, in any
    slot: the (slot, crosswalk) pairs of the walker rows (`TrafficCore.add_walker`)."""
    if not len(core.p_env):
        return []
    t, ids = core.table, core.crosswalks.ids
    nl, ncw = len(t.length), len(ids)
    pairs = set((core.p_env * ncw + core.p_cw).tolist())  # (a few walkers a slot: no sort)
    return [q * nl + k for q, c in map(lambda p: divmod(p, ncw), pairs) for k in t.crosswalk_lanes.get(ids[c], ())]


def is_any(keys: np.ndarray, few: list[int]) -> np.ndarray:
    """`np.isin(keys, few)`: for a short list `few` a comparison per value, else a binary search
    in them (`join.member`)."""
    if len(few) > IS_ANY_COMPARISONS:
        return member(keys, few)
    hit = keys == few[0]
    for k in few[1:]:
        hit |= keys == k
    return hit
