"""Greedy grid placement of junction features (Algorithm 1, lines 12-23).

Each feature goes to the empty grid point of highest match score. The score is the paper's:
k = the most roads the junction can connect, after a quarter-turn rotation, to its E/N/W/S
neighbours (a leg facing an empty point counts, it can connect later); -inf when n > k.
Draws are broken by (1) the number of roads connected now, which keeps maps compact,
then (2) a seeded random choice. Two rules keep the network connected: after the first
junction a placement must connect at least one road, and it must leave an open socket
while features remain. A ramp junction none of whose main legs could face any placed junction's
leg lane for lane (a sampled two-lane motorway's among one-lane town junctions) starts a road
network of its own, two grid points east of them all, which later junctions of its lanes join.
A quarter-turn keeps the normalized rotation feature unchanged (the alignment cost has period 90
degrees), so a placed junction still realizes its feature.

Junctions with more than four legs (and legs that face a neighbour without a matching
socket) cannot reach a grid neighbour: such legs end in stub roads, like the legs left open
when placement ends. Stubs are the map's entries and exits.
"""
from __future__ import annotations

import bisect
import itertools
import math
from dataclasses import dataclass
from typing import Sequence

import numpy as np

from .angles import wrap_degrees
from .config import MAX_CARDINAL_DEVIATION_DEG
from .errors import LayoutError
from .features import JunctionFeature, Socket

Cell = tuple[int, int]
DIRECTIONS: tuple[Cell, ...] = ((1, 0), (0, 1), (-1, 0), (0, -1))  # E, N, W, S


@dataclass(frozen=True)
class Link:
    """Socket `socket` of junction `junction` (indices into the placement list)."""

    junction: int
    socket: int


@dataclass(frozen=True)
class Placement:
    """A junction feature placed at a grid cell, turned by `quarter_turns` x 90 degrees CCW."""

    feature: JunctionFeature
    cell: Cell
    quarter_turns: int
    links: tuple[Link | None, ...]  # per socket: the socket it is connected to, or None (stub)

    @property
    def rotation_deg(self) -> float:
        return 90.0 * self.quarter_turns


def cardinal_assignment(feature: JunctionFeature, max_deviation_deg: float = MAX_CARDINAL_DEVIATION_DEG
                        ) -> tuple[int | None, ...]:
    """Per socket the cardinal direction (0=E..3=S) it serves, or None (a stub): injective, as
    many sockets as can be, then least squared deviation. A socket serves a direction only
    when no other leg lies between them and it is within `max_deviation_deg`: a road turning
    from its socket across another leg to the neighbour would overlap that leg's road outside
    the junction, so such a socket ends in a stub instead, as does every ramp (`Socket.ramp`)."""
    n = feature.n_roads
    angles = feature.rotation
    dev = [[wrap_degrees(angles[s] - 90.0 * d) for d in range(4)] for s in range(n)]

    def allowed(s: int, d: int) -> bool:
        if feature.sockets[s].ramp != "none":  # a ramp's road runs beside its main road's: a stub
            return False
        if abs(dev[s][d]) > max_deviation_deg + 1e-9:
            return False
        side = math.copysign(1.0, dev[s][d])
        return not any(0.0 < side * dev[k][d] < abs(dev[s][d]) for k in range(n) if k != s)

    for size in range(min(n, 4), 0, -1):
        best: tuple[float, tuple[int | None, ...]] | None = None
        for chosen in itertools.combinations(range(n), size):
            for dirs in itertools.permutations(range(4), size):
                if not all(allowed(s, d) for s, d in zip(chosen, dirs)):
                    continue
                cost = sum(dev[s][d] ** 2 for s, d in zip(chosen, dirs))
                if best is None or cost < best[0] - 1e-9:
                    assign: list[int | None] = [None] * n
                    for s, d in zip(chosen, dirs):
                        assign[s] = d
                    best = (cost, tuple(assign))
        if best is not None:
            return best[1]
    return (None,) * n


def compatible(a: Socket, b: Socket) -> bool:
    """Facing sockets can share a road: what leaves one enters the other, lane for lane
    (`out` k faces `in` k, `in-out` (a, b) faces `in-out` (b, a))."""
    return a.lanes_out == b.lanes_in and a.lanes_in == b.lanes_out


def describe_socket(s: Socket) -> str:
    return f"{s.road_type} ({s.lanes_in} in, {s.lanes_out} out)"


def place(features: Sequence[JunctionFeature], rng: np.random.Generator,
          fixed_cells: Sequence[Cell | None] | None = None,
          names: Sequence[str] | None = None,
          prefer_turns: Sequence[int | None] | None = None,
          max_deviation_deg: float = MAX_CARDINAL_DEVIATION_DEG) -> list[Placement]:
    """Place every feature on the grid; returns placements in the order of `features`.

    `fixed_cells` optionally pins features to cells (custom specs); pinned ones are placed first.
    Sockets facing each other across a grid gap must be `compatible` (one-way roads must keep
    their direction, lane counts must agree): a placement that would face incompatible sockets
    is not taken, and a pinned junction without a compatible quarter turn is an error.
    `names` label the features in error messages (default "junction <index>"); among equally
    good placements, `prefer_turns` (per feature, or None) picks that quarter turn (custom
    specs use it to keep a junction as it was written) before the seeded random choice.
    `max_deviation_deg` bounds how far a socket may be from the grid direction it serves.
    Only empty points faced by an open socket can connect, so only those are scored: the
    paper's other empty points all score below them, and the run stays near-linear.
    """
    if not features:
        raise LayoutError("no junction features to place")
    fixed = list(fixed_cells) if fixed_cells is not None else [None] * len(features)
    label = list(names) if names is not None else [f"junction {j}" for j in range(len(features))]
    assigns = [cardinal_assignment(f, max_deviation_deg) for f in features]
    cells: dict[Cell, int] = {}
    turns: dict[int, int] = {}
    links: dict[int, list[Link | None]] = {}
    facing: dict[Cell, list[tuple[int, int]]] = {}  # empty cell -> open sockets (junction, socket) facing it
    n_open = 0
    order = [i for i in range(len(features)) if fixed[i] is not None]
    order += sorted((i for i in range(len(features)) if fixed[i] is None), key=lambda i: -features[i].n_roads)

    def evaluate(j: int, cell: Cell, k: int) -> tuple[str, list[Link | None], int, int]:
        """Junction j at `cell` turned by k: (clash or "", its links, roads connected, legs facing empty points)."""
        f = features[j]
        here = facing.get(cell, [])
        connect: list[Link | None] = [None] * f.n_roads
        n_connect = n_free = 0
        bad = ""
        for s, d0 in enumerate(assigns[j]):
            if d0 is None:
                continue
            d = (d0 + k) % 4
            other = cells.get((cell[0] + DIRECTIONS[d][0], cell[1] + DIRECTIONS[d][1]))
            if other is None:
                n_free += 1
                continue
            for o, t in here:
                if o == other and links[o][t] is None and Link(o, t) not in connect:
                    if not compatible(f.sockets[s], features[o].sockets[t]):
                        bad = (f"its {describe_socket(f.sockets[s])} leg would face the "
                               f"{describe_socket(features[o].sockets[t])} leg of {label[o]}")
                        break
                    connect[s] = Link(o, t)
                    n_connect += 1
                    break
        return bad, connect, n_connect, n_free

    changed: list[Cell] = []  # cells whose score may have changed, in placement order (see _Frontier)
    frontiers: dict[tuple, _Frontier] = {}
    legs: set[tuple[int, int]] = set()  # (lanes in, lanes out) of the placed junctions' legs
    roots = [order[0]]  # the first junction of each road network
    for step, j in enumerate(order):
        f = features[j]
        remaining = len(order) - step - 1
        want = prefer_turns[j] if prefer_turns is not None else None
        mine = [(f.sockets[s].lanes_in, f.sockets[s].lanes_out) for s, d in enumerate(assigns[j]) if d is not None]
        if f.has_ramp and cells and fixed[j] is None and mine and not any((b, a) in legs for a, b in mine):
            cell, k, connect = _apart(j, cells, evaluate)
            roots.append(j)
        elif cells and fixed[j] is None and (remaining == 0 or n_open > 4):
            # every candidate leaves an open socket (a point is faced by at most 4), so the paper's
            # score alone ranks them: kept per feature signature and updated where junctions land
            sig = (assigns[j], tuple((s.lanes_in, s.lanes_out) for s in f.sockets))
            frontier = frontiers.get(sig)
            if frontier is None:
                frontier = frontiers[sig] = _Frontier(j, evaluate, facing, len(changed))
            else:
                frontier.update(j, changed, facing)
            ties = frontier.best(want)
            if not ties:
                raise LayoutError("no grid point connects this junction to the network (no matching open socket)",
                                  f"{label[j]} ({f.n_roads} legs, {f.control})")
            cell, k = ties[int(rng.integers(len(ties)))]
            connect = frontier.connect[(cell, k)]
        else:
            cell, k, connect = _score_all(j, f, cells, fixed, facing, evaluate, n_open, remaining, label, want, rng)
        legs.update(mine)
        cells[cell] = j
        turns[j] = k
        links[j] = list(connect)
        for s, ln in enumerate(connect):
            if ln is not None:
                links[ln.junction][ln.socket] = Link(j, s)
        n_open -= len(facing.pop(cell, []))
        changed.append(cell)
        for s, d0 in enumerate(assigns[j]):
            if d0 is None:
                continue
            d = (d0 + k) % 4
            nb = (cell[0] + DIRECTIONS[d][0], cell[1] + DIRECTIONS[d][1])
            if nb not in cells:
                facing.setdefault(nb, []).append((j, s))
                n_open += 1
        changed.extend((cell[0] + dx, cell[1] + dy) for dx, dy in DIRECTIONS)
    where = {j: c for c, j in cells.items()}
    _check_connected(order, roots, links, where, label)
    return [Placement(features[j], where[j], turns[j], tuple(links[j])) for j in range(len(features))]


def _apart(j: int, cells: dict[Cell, int], evaluate) -> tuple[Cell, int, list[Link | None]]:
    """Junction j where no placed junction neighbours it (two grid points east of them all): the
    first of a new road network, turned to leave the most legs open (the least turn of those)."""
    cell = (max(c[0] for c in cells) + 2, min(c[1] for c in cells))
    k = max(range(4), key=lambda q: (evaluate(j, cell, q)[3], -q))
    return cell, k, evaluate(j, cell, k)[1]


def _score_all(j: int, f: JunctionFeature, cells: dict[Cell, int], fixed: Sequence[Cell | None],
               facing: dict[Cell, list[tuple[int, int]]], evaluate, n_open: int, remaining: int,
               label: Sequence[str], want: int | None, rng: np.random.Generator
               ) -> tuple[Cell, int, list[Link | None]]:
    """Score every candidate (cell, quarter turn) of junction j and draw one of the best: the
    first junction, pinned ones and the last few open sockets come here."""
    pinned = fixed[j]
    candidates = [pinned] if pinned is not None else (sorted(facing) if cells else [(0, 0)])
    best_key = None
    best: list[tuple[Cell, int, list[Link | None]]] = []
    clash = ""
    for cell in candidates:
        n_here = len(facing.get(cell, []))
        for k in range(4):
            bad, connect, n_connect, n_free = evaluate(j, cell, k)
            if bad:
                clash = clash or bad
                continue
            if cells and n_connect == 0 and fixed[j] is None:
                continue
            key = (*_paper_key(f.n_roads, n_connect, n_free)[:2], remaining == 0 or n_open - n_here + n_free > 0,
                   n_connect)
            if best_key is None or key > best_key:
                best_key, best = key, [(cell, k, connect)]
            elif key == best_key:
                best.append((cell, k, connect))
    if not best and pinned is not None:
        raise LayoutError(
            f"no quarter turn at cell {tuple(pinned)} makes the sockets facing its neighbours "
            f"direction-compatible ({clash}; an out socket must face an in socket with as many lanes)",
            label[j])
    if not best:
        raise LayoutError(
            "no grid point connects this junction to the network (no matching open socket)",
            f"{label[j]} ({f.n_roads} legs, {f.control})",
        )
    if want is not None and any(k == want for _, k, _ in best):
        best = [c for c in best if c[1] == want]
    return best[int(rng.integers(len(best)))]


def _paper_key(n_roads: int, n_connect: int, n_free: int) -> tuple[bool, int, int]:
    """The paper's score (n <= k, then k; 0 when -inf), then the roads connected now."""
    k_paper = n_connect + n_free
    return n_roads <= k_paper, k_paper if n_roads <= k_paper else 0, n_connect


class _Frontier:
    """The scored (cell, quarter turn) candidates of one feature signature (its cardinal
    assignment and socket lanes, all that scoring reads of a feature), sorted per score key.
    A placement changes the scores of its cell and its four neighbours only, so each
    signature re-scores just the cells changed since it last placed a junction: placement
    stays linear in the junction count, and draws the same candidate as scoring every cell.
    `by_turn` holds the same candidates per (score key, quarter turn), for preferred turns."""

    def __init__(self, j: int, evaluate, facing: dict[Cell, list[tuple[int, int]]], seen: int) -> None:
        self.evaluate = evaluate
        self.keys: dict[Cell, list[tuple[tuple[bool, int, int], int]]] = {}
        self.by_key: dict[tuple[bool, int, int], list[tuple[Cell, int]]] = {}
        self.by_turn: dict[tuple[tuple[bool, int, int], int], list[tuple[Cell, int]]] = {}
        self.connect: dict[tuple[Cell, int], list[Link | None]] = {}
        self.seen = seen  # changes before this were scored
        for cell in facing:
            self._score(j, cell)

    def update(self, j: int, changed: list[Cell], facing: dict[Cell, list[tuple[int, int]]]) -> None:
        for cell in set(changed[self.seen:]):
            for key, k in self.keys.pop(cell, ()):
                for ties in (self.by_key[key], self.by_turn[(key, k)]):
                    del ties[bisect.bisect_left(ties, (cell, k))]
                del self.connect[(cell, k)]
            if cell in facing:
                self._score(j, cell)
        self.seen = len(changed)

    def best(self, want: int | None = None) -> list[tuple[Cell, int]]:
        """The best-scored candidates in (cell, turn) order; with `want`, only those turned by
        `want` when there are any (as `_score_all` filters them)."""
        live = [key for key, ties in self.by_key.items() if ties]
        if not live:
            return []
        key = max(live)
        preferred = self.by_turn.get((key, want)) if want is not None else None
        return preferred if preferred else self.by_key[key]

    def _score(self, j: int, cell: Cell) -> None:
        scored = []
        for k in range(4):
            bad, connect, n_connect, n_free = self.evaluate(j, cell, k)
            if bad or n_connect == 0:
                continue
            key = _paper_key(len(connect), n_connect, n_free)
            scored.append((key, k))
            bisect.insort(self.by_key.setdefault(key, []), (cell, k))
            bisect.insort(self.by_turn.setdefault((key, k), []), (cell, k))
            self.connect[(cell, k)] = connect
        self.keys[cell] = scored


def _check_connected(order: Sequence[int], roots: Sequence[int], links: dict[int, list[Link | None]],
                     where: dict[int, Cell], label: Sequence[str]) -> None:
    """Every junction joins the road network of one of `roots` (the first junction, and those
    whose lanes no earlier junction had); only pinned cells can split a network."""
    seen = set(roots)
    todo = list(roots)
    while todo:
        for ln in links[todo.pop()]:
            if ln is not None and ln.junction not in seen:
                seen.add(ln.junction)
                todo.append(ln.junction)
    for j in order:
        if j not in seen:
            raise LayoutError(
                f"pinned to cell {tuple(where[j])}, where no road connects it to {label[order[0]]}: "
                "pin it next to a junction with a facing compatible leg, or drop the cell", label[j])
