"""The narrow passages' state as arrays of the core: a table of places, one entry per (row,
passage group) in use (`network.Passage.group`), with the sides the row holds (`pe_hold`, bit
1 << side), the side it waits from (`pe_wait`, -1 none) and since when (`pe_since`, its slot's
clock), and the sides before which it took a place to wait (`pe_room`, bits). The table holds
only the places taken (a few per road user near a passage), so it costs nothing on maps without
passages and little on maps with thousands of them. The rules read a slot's holders, waiters and
places here (`TrafficRules.passage_allows`, `room_taken`, `waits_for`); `TrafficControl` takes
them (`enrol`, `hold`) and lets them go (`let_go`, in `TrafficControl._update_passages`). A road
user that leaves the road lets go of everything with its row (`keep_rows`).
"""
from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from ..core import TrafficCore

# the table's columns, and a new entry's value in each
ARRAYS = {"pe_row": -1, "pe_group": -1, "pe_hold": 0, "pe_wait": -1, "pe_since": np.inf, "pe_room": 0}


def _find(core: "TrafficCore", r: int, group: int) -> int:
    """The entry of row `r` at passage `group` (-1: none)."""
    k = ((core.pe_row == r) & (core.pe_group == group)).nonzero()[0]
    return int(k[0]) if len(k) else -1


def _entry(core: "TrafficCore", r: int, group: int) -> int:
    """The entry of row `r` at passage `group`, a blank one added if it has none."""
    k = _find(core, r, group)
    if k >= 0:
        return k
    for name, value in ARRAYS.items():
        a = getattr(core, name)
        setattr(core, name, np.append(a, np.array([value], dtype=a.dtype)))
    core.pe_row[-1], core.pe_group[-1] = r, group
    return len(core.pe_row) - 1


def _of(core: "TrafficCore", slot: int, group: int, mask: np.ndarray) -> np.ndarray:
    """The entries of `mask` at passage `group` whose rows are of `slot`, in row order."""
    k = (mask & (core.pe_group == group)).nonzero()[0]
    k = k[core.env[core.pe_row[k]] == slot]
    return k[np.argsort(core.pe_row[k], kind="stable")]


def holders(core: "TrafficCore", slot: int, group: int, side: int) -> np.ndarray:
    """The rows of `slot` that hold passage `group` from `side`, in row order."""
    return core.pe_row[_of(core, slot, group, (core.pe_hold >> side) & 1 == 1)]


def holds(core: "TrafficCore", r: int, group: int, side: int) -> bool:
    """Whether row `r` (-1: none) holds passage `group` from `side`."""
    k = _find(core, r, group) if r >= 0 else -1
    return k >= 0 and bool((core.pe_hold[k] >> side) & 1)


def waiters(core: "TrafficCore", slot: int, group: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(rows, the side each waits from, since when) of the rows of `slot` waiting for passage
    `group`, in row order."""
    k = _of(core, slot, group, core.pe_wait >= 0)
    return core.pe_row[k], core.pe_wait[k], core.pe_since[k]


def waits(core: "TrafficCore", r: int) -> list[tuple[int, int, float]]:
    """(passage group, side, since when) of each passage row `r` waits for, by group."""
    k = ((core.pe_row == r) & (core.pe_wait >= 0)).nonzero()[0]
    k = k[np.argsort(core.pe_group[k], kind="stable")]
    return list(zip(core.pe_group[k].tolist(), core.pe_wait[k].tolist(), core.pe_since[k].tolist()))


def waiting_rows(core: "TrafficCore") -> np.ndarray:
    """The rows waiting for some passage."""
    return core.pe_row[core.pe_wait >= 0]


def places(core: "TrafficCore", slot: int, group: int, side: int) -> np.ndarray:
    """The rows of `slot` that took a place to wait before passage `group` from `side`, in row order."""
    return core.pe_row[_of(core, slot, group, (core.pe_room >> side) & 1 == 1)]


def taken(core: "TrafficCore", group: int) -> bool:
    """Whether a row of any slot holds or waits for passage `group` (most passages, most frames:
    nobody)."""
    return bool(((core.pe_group == group) & ((core.pe_hold != 0) | (core.pe_wait >= 0))).any())


def in_use(core: "TrafficCore", slot: int, column: str) -> list[int]:
    """The passage groups at which a row of `slot` has something in `column` ("pe_hold",
    "pe_wait" or "pe_room"), ascending."""
    if not len(core.pe_row):
        return []
    a = getattr(core, column)
    m = (a >= 0) if column == "pe_wait" else (a != 0)
    m &= core.env[core.pe_row] == slot
    return sorted(set(core.pe_group[m].tolist()))


def hold(core: "TrafficCore", r: int, group: int, side: int) -> None:
    """Row `r` holds passage `group` from `side` (it is within it; -1: no row, nothing)."""
    if r < 0:
        return
    k = _entry(core, r, group)
    core.pe_hold[k] |= 1 << side


def enrol(core: "TrafficCore", r: int, chain: list[tuple[int, int]], ok: bool, room: tuple[int, int] | None,
          t: float) -> None:
    """Row `r` takes its place at the passages of `chain` ((group, side) pairs) at clock `t`:
    allowed (`ok`), among the holders of all and the place to wait before passage `room`; else
    among the waiters of all (keeping an earlier wait's time), standing in the room before the first."""
    for group, side in chain:
        k = _entry(core, r, group)
        if ok:
            core.pe_hold[k] |= 1 << side
            core.pe_wait[k] = -1
        elif core.pe_wait[k] < 0:
            core.pe_wait[k] = side
            core.pe_since[k] = t
    taken = room if ok else chain[0]
    if taken is not None:
        k = _entry(core, r, taken[0])
        core.pe_room[k] |= 1 << taken[1]


def let_go(core: "TrafficCore", r: int, group: int, column: str, side: int = 0) -> None:
    """Row `r` lets go at passage `group`: of holding it from `side` ("pe_hold"), of its wait
    ("pe_wait") or of its place to wait before it from `side` ("pe_room"); `prune` then drops
    the places left empty."""
    k = _find(core, r, group)
    if column == "pe_wait":
        core.pe_wait[k] = -1
    else:
        getattr(core, column)[k] &= ~(1 << side)


def prune(core: "TrafficCore") -> None:
    """Drop the entries that hold, wait for and took nothing."""
    keep = (core.pe_hold != 0) | (core.pe_wait >= 0) | (core.pe_room != 0)
    if not keep.all():
        for name in ARRAYS:
            setattr(core, name, getattr(core, name)[keep])


def keep_rows(core: "TrafficCore", new_row: np.ndarray) -> None:
    """The rows kept move to `new_row` (their new indices, -1: gone): their entries follow, and a
    road user that left lets go of everything."""
    if not len(core.pe_row):
        return
    moved = new_row[core.pe_row]
    keep = moved >= 0
    for name in ARRAYS:
        setattr(core, name, getattr(core, name)[keep])
    core.pe_row = moved[keep]
