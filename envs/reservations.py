"""Junction reservations as arrays of the core, and the mapping view the rules read them through.

The state is two arrays of `TrafficCore` over (slot, lane): `res`, the row holding the lane's
reservation (`NONE`: nobody; `LEFT`: a road user that is no row of the core now, released with
a hand-over at its slot's next update), and `res_seq`, when it was taken (the order the update
releases in); a row column counts the reservations each row holds (`res_count`). Only rows hold
reservations; a lane is found by its index, so a question costs one array read whatever the
map's size, and the arrays answer for every slot at once (`sim.entries`). `Reservations` is one
slot's view as {lane id: the road user holding it}, what the rules' scalar questions and tests
read and write.
"""
from __future__ import annotations

from collections.abc import MutableMapping
from typing import TYPE_CHECKING, Any, Iterator

import numpy as np

if TYPE_CHECKING:
    from .core import TrafficCore

NONE, LEFT = -1, -2  # `res` values that are no row


class Left:
    """The holder of a reservation taken by a road user that has left the road (or was never a
    row of the core): it is nobody on the road, so it is never the road user asking."""

    def __repr__(self) -> str:
        return "<a road user that has left>"


LEFT_HOLDER = Left()


class Reservations(MutableMapping):
    """Slot `slot`'s junction reservations, {lane id: holder}, a view of `core.res` (module
    docstring); writing it writes the arrays."""

    __slots__ = ("_core", "_res", "_seq", "_index", "_ids")

    def __init__(self, core: "TrafficCore", slot: int) -> None:
        self._core = core
        self._res = core.res[slot]  # (views of the slot's rows of the arrays)
        self._seq = core.res_seq[slot]
        self._index = core.table.index
        self._ids = core.net.lane_ids

    def _holder(self, r: int) -> Any:
        return self._core.objs[r] if r >= 0 else LEFT_HOLDER

    def get(self, lane: str, default: Any = None) -> Any:
        j = self._index.get(lane)
        r = NONE if j is None else self._res.item(j)
        return default if r == NONE else self._holder(r)

    def __getitem__(self, lane: str) -> Any:
        r = self._res.item(self._index[lane])
        if r == NONE:
            raise KeyError(lane)
        return self._holder(r)

    def __contains__(self, lane: object) -> bool:
        j = self._index.get(lane)  # type: ignore[call-overload]
        return j is not None and self._res.item(j) != NONE

    def __setitem__(self, lane: str, holder: Any) -> None:
        j = self._index[lane]
        core, old = self._core, self._res.item(j)
        if old == NONE:  # a new reservation comes last in the order (a dict's insertion order)
            self._seq[j] = core.next_reservation()
        elif old >= 0:
            core.res_count[old] -= 1
        r = self._res[j] = core.row_of(holder)
        if r >= 0:
            core.res_count[r] += 1

    def setdefault(self, lane: str, holder: Any = None) -> Any:
        j = self._index[lane]
        if self._res.item(j) == NONE:
            self[lane] = holder
        return self._holder(self._res.item(j))

    def __delitem__(self, lane: str) -> None:
        j = self._index[lane]
        old = self._res.item(j)
        if old == NONE:
            raise KeyError(lane)
        if old >= 0:
            self._core.res_count[old] -= 1
        self._res[j] = NONE

    def __iter__(self) -> Iterator[str]:
        held = np.flatnonzero(self._res != NONE)
        return iter([self._ids[j] for j in held[np.argsort(self._seq[held], kind="stable")].tolist()])

    def __len__(self) -> int:
        return int(np.count_nonzero(self._res != NONE))

    def held_by(self, vehicle: Any) -> bool:
        """Whether `vehicle` holds any reservation (its row's count, `TrafficCore.res_count`)."""
        r = self._core.row_of(vehicle)
        return r >= 0 and self._core.res_count.item(r) > 0
