"""Where along its route the rules can stop a road user, for rows at once: the one scan of the
rules' stop distance (`TrafficRules.stop_distance`). A row's scan runs over its window lanes
(`TrafficCore.W`) within LOOKAHEAD_M, up to the first road after its next junction entry with
room to wait on it (`rules.room_to_wait`), however many short lanes lie before a line and however
many junctions follow each other with less road between them. On each lane scanned it notes what
can stop the row there, in the order the rules ask it: a road lane across a junction lane
(`TrafficRules.crossing_held`), a junction entry (its line: `may_enter`), a mid-block crossing's
light (`midblock_stop`), a crosswalk with people on it (`pedestrian_blocking`). The rules walk a
row's stops in order (`TrafficRules._rule_stop`); the batched core settles the rows whose first
stop is a signal that holds them in arrays (`TrafficCore._rule_stops`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import LOOKAHEAD_M
from ..rules import CROSSED, ENTRY, MIDBLOCK, PEOPLE, room_to_wait

if TYPE_CHECKING:
    from ..core import TrafficCore

@dataclass(frozen=True)
class Scan:
    """The scan of `rows`: per row and window place, the lane (`lanes`), the distance from the
    row's centre to its start (`D`: negative on the current lane, summed lane by lane as
    `RouteFollower.upcoming` does) and what on it can stop the row (`what`: bits, 0 on lanes
    holding nothing or not scanned)."""

    rows: np.ndarray
    lanes: np.ndarray
    D: np.ndarray
    what: np.ndarray

    def stops(self, r: int) -> list[tuple[int, int, float, int]]:
        """(lane, the lane before it (-1 for the current lane), distance, what) of each place that
        can stop the `r`-th row, in route order."""
        ks = self.what[r].nonzero()[0]
        before = np.where(ks > 0, self.lanes[r, np.maximum(ks - 1, 0)], -1)
        return list(zip(self.lanes[r, ks].tolist(), before.tolist(), self.D[r, ks].tolist(), self.what[r, ks].tolist()))


def scan(core: "TrafficCore", rows: np.ndarray) -> Scan:
    """The scan of driven `rows` (row indices; their windows up to date)."""
    t = core.table
    W = core.W[rows]
    n, K = W.shape
    lanes = np.maximum(W, 0)
    valid = W >= 0
    length = t.length[lanes]
    s = core.s[rows]
    D = np.empty((n, K))
    D[:, 0] = -s
    if K > 1:  # the current lane's rest, then each lane's length, added one by one
        D[:, 1:] = np.cumsum(np.column_stack([length[:, 0] - s, length[:, 1:-1]]), axis=1)
    live = valid & (D <= LOOKAHEAD_M)
    live[:, 0] = valid[:, 0]
    junction = t.junction[lanes] & live
    # the scan ends after the first road lane after a junction lane whose road since that
    # junction lane (this lane included), less its line's setback, holds the row waiting
    entered = np.zeros((n, K), dtype=bool)
    entered[:, 2:] = np.logical_or.accumulate(junction[:, 1:-1], axis=1)
    road = np.where(junction, 0.0, length)
    road[:, 0] = 0.0
    since = np.cumsum(road, axis=1)
    at_junction = np.maximum.accumulate(np.where(junction, np.arange(K), 0), axis=1)
    room = since - since[np.arange(n)[:, None], at_junction]
    end = live & ~junction & entered & room_to_wait(room - t.line_setback[lanes], core.length[rows][:, None])
    end[:, 0] = False
    scanned = live & (np.cumsum(end, axis=1) - end == 0)
    what = np.zeros((n, K), dtype=np.int8)
    what[:, 1:] |= np.where(t.crossed[lanes[:, 1:]], CROSSED, 0).astype(np.int8)
    what[:, 1:] |= np.where(junction[:, 1:] & ~junction[:, :-1], ENTRY, 0).astype(np.int8)
    what |= np.where(t.midblock[lanes], MIDBLOCK, 0).astype(np.int8)
    busy = busy_lanes(core)
    if busy:
        key = core.env[rows][:, None] * len(t.length) + lanes
        what |= np.where(np.isin(key, busy), PEOPLE, 0).astype(np.int8)
    what[~scanned] = 0
    return Scan(rows, lanes, D, what)


def busy_lanes(core: "TrafficCore") -> list[int]:
    """Keys (slot * lanes + lane) of the lanes across a crosswalk that has people on it, in any
    slot."""
    t = core.table
    nl = len(t.length)
    return [road.slot * nl + k for road in core.roads if road is not None
            for cw, people in road.control.pedestrians.items() if people for k in t.crosswalk_lanes.get(cw, ())]
