"""The narrow passages' state as row arrays of the core: per row and passage group
(`network.Passage.group`), the sides it holds (`pass_hold`, bit 1 << side), the side it waits
from (`pass_wait`, -1 none) and since when (`pass_since`, its slot's clock), and the sides before
which it took a place to wait (`pass_room`, bits). The rules read a slot's holders, waiters and
places here (`TrafficRules.passage_allows`, `room_taken`, `waits_for`); `TrafficControl` takes
them (`enrol`) and lets them go (`TrafficControl._update_passages`). A road user that leaves the
road lets go of everything with its row.
"""
from __future__ import annotations

import math
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core import TrafficCore
    from ..network import MapNetwork

# the arrays (rows x passage groups) and a new row's value in each
ARRAYS = {"pass_hold": 0, "pass_wait": -1, "pass_since": math.inf, "pass_room": 0}


def groups(net: "MapNetwork") -> int:
    """How many passage groups `net` has (they are numbered from 0)."""
    return 1 + max((p.group for p in net.passages.values()), default=-1)


def holders(core: "TrafficCore", slot: int, group: int, side: int) -> np.ndarray:
    """The rows of `slot` that hold passage `group` from `side`."""
    rows = core.slot_rows(slot)
    return rows[(core.pass_hold[rows, group] >> side) & 1 == 1]


def holds(core: "TrafficCore", r: int, group: int, side: int) -> bool:
    """Whether row `r` (-1: none) holds passage `group` from `side`."""
    return r >= 0 and bool((core.pass_hold[r, group] >> side) & 1)


def waiters(core: "TrafficCore", slot: int, group: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, the side each waits from, since when) of the rows of `slot` waiting for passage `group`."""
    rows = core.slot_rows(slot)
    rows = rows[core.pass_wait[rows, group] >= 0]
    return rows, core.pass_wait[rows, group], core.pass_since[rows, group]


def places(core: "TrafficCore", slot: int, group: int, side: int) -> np.ndarray:
    """The rows of `slot` that took a place to wait before passage `group` from `side`."""
    rows = core.slot_rows(slot)
    return rows[(core.pass_room[rows, group] >> side) & 1 == 1]


def enrol(core: "TrafficCore", r: int, chain: list[tuple[int, int]], ok: bool, room: tuple[int, int] | None,
          t: float) -> None:
    """Row `r` takes its place at the passages of `chain` ((group, side) pairs) at clock `t`:
    allowed (`ok`), among the holders of all and the place to wait before passage `room`; else
    among the waiters of all (keeping an earlier wait's time), standing in the room before the first."""
    for group, side in chain:
        if ok:
            core.pass_hold[r, group] |= 1 << side
            core.pass_wait[r, group] = -1
        elif core.pass_wait[r, group] < 0:
            core.pass_wait[r, group] = side
            core.pass_since[r, group] = t
    taken = room if ok else chain[0]
    if taken is not None:
        core.pass_room[r, taken[0]] |= 1 << taken[1]


def taken(core: "TrafficCore", group: int) -> bool:
    """Whether a row of any slot holds or waits for passage `group` (most passages, most frames:
    nobody)."""
    return bool(core.pass_hold[:, group].any()) or int(core.pass_wait[:, group].max(initial=-1)) >= 0


def users(core: "TrafficCore", slot: int) -> np.ndarray:
    """The rows of `slot` that hold, wait for or took a place before any passage."""
    if not (core.pass_hold.any() or core.pass_room.any()) and int(core.pass_wait.max(initial=-1)) < 0:
        return np.zeros(0, dtype=np.int64)
    rows = core.slot_rows(slot)
    return rows[(core.pass_hold[rows] | core.pass_room[rows]).any(axis=1) | (core.pass_wait[rows] >= 0).any(axis=1)]
