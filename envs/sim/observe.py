"""The Kinematics observation of controlled road users as one array program (docs/architecture.md,
"observe"): the single env's ego is a batch of one, the batched env's egos and the multi-agent
env's agents are batches of many, and all get highway-env's `KinematicObservation` values bit for
bit (tests/envs/test_core.py compares them on random states and options) without pandas or a
projection per road user.

An observer sees the road users of its own slot (every row of it but its own, in row order, then
its road's objects, such as pedestrians) within PERCEPTION_DISTANCE, the nearest by distance along
its lane first (or, shuffled, the first in that order); the candidates are projected once per
(slot, lane) for all observers at once (`lanes.project_rows`)."""
from __future__ import annotations

from typing import Any

import numpy as np

from ..core import DRIVEN
from ..lanes import project_rows
from ..vehicles import Pedestrian

FEATURES = frozenset({"presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d",
                      "long_off", "lat_off", "ang_off"})
RELATIVE = ("x", "y", "vx", "vy")  # relative to the observer unless `absolute`
OFFSETS = ("long_off", "lat_off", "ang_off")  # `Vehicle.lane_offset`, read from the chosen vehicles


def supported(obs: Any) -> bool:
    """Options the program reproduces (others, and the first normalized observation without a
    features_range, which highway-env derives from the lanes, go to highway-env's code), for
    the env's own vehicle."""
    return _observer(obs) is not None


def _observer(obs: Any) -> tuple[tuple, Any] | None:
    """(its options, its vehicle) of an observation the program reproduces (`supported`), else None."""
    opt, v = _options(obs), obs.observer_vehicle
    return (opt, v) if opt[0] and v is obs.env.vehicle else None


def kinematics(observers: list, core: Any) -> list[np.ndarray | None]:
    """One [vehicles_count, features] float32 array per observer (Kinematics observation types on
    roads of `core`), or None for an observer the program does not reproduce (`supported`, a
    config other than the first's, a road user in its slot that the core does not drive): that
    one observes through highway-env's code."""
    out: list[np.ndarray | None] = [None] * len(observers)
    first: tuple | None = None
    picks, roads, views, at = [], {}, [], []
    for k, o in enumerate(observers):  # one config (the first's), of a row of this core
        got = _observer(o)
        if got is None:
            continue
        opt_k, v = got
        road = o.env.road
        if road.core is not core or getattr(v, "_core", None) is not core:
            continue
        if first is None:
            first = opt_k
        elif opt_k is not first and opt_k != first:
            continue
        picks.append(k)
        views.append(v)
        at.append(road.slot)
        roads[road.slot] = road
    if not picks:
        return out
    opt = observers[picks[0]]
    core.sync(list(roads.values()))  # respawned traffic
    net = core.net
    # slots holding a road user the core does not drive (user code's own objects): highway-env's code
    foreign = (np.bincount(core.env[core.kind != DRIVEN], minlength=len(core.roads)) > 0)[at]
    if foreign.any():
        keep = (~foreign).nonzero()[0].tolist()
        picks, views, at = [picks[n] for n in keep], [views[n] for n in keep], [at[n] for n in keep]
    keep_g, slots, own = picks, at, [v._row for v in views]  # (rows after the sync)
    if not keep_g:
        return out
    m = len(keep_g)
    V, kind, row_of, rank = _candidates(core, slots, roads, opt.include_obstacles)
    # the observer's own (x, y, heading, speed) first, from its column
    rows = np.array(own, dtype=np.int64)
    lanes = core.lane[rows].tolist()  # (indices of the network's lanes)
    g = np.arange(m)[:, None]
    self_col = 1 + rank[rows]
    V[:, 0] = V[g[:, 0], self_col]
    length = core.length[rows]
    real, vehicle = kind > 0, kind == ROW
    real[g[:, 0], rank[rows]] = False  # not itself
    X, Y = V[:, :, 0], V[:, :, 1]
    along = _along(net, slots, lanes, V, self_col)
    dist = along[:, 1:] - along[:, :1]
    dx, dy = X[:, 1:] - X[:, :1], Y[:, 1:] - Y[:, :1]
    near = np.sqrt(dx * dx + dy * dy) < opt.env.PERCEPTION_DISTANCE
    behind_ok = -2 * length[:, None] < dist
    keep = near & real
    if not opt.see_behind:
        keep &= behind_ok
    keep &= vehicle | behind_ok  # objects: only from 2 lengths behind
    # sorted: the nearest along the lane first; shuffled: the first in road order (then shuffled)
    key = np.where(keep, np.abs(dist) if opt.order == "sorted" else np.arange(dist.shape[1], dtype=float), np.inf)
    pick = np.argsort(key, axis=1, kind="stable")[:, :opt.vehicles_count - 1]
    valid = key[g, pick] < np.inf
    K = pick.shape[1]
    idx = np.zeros((m, 1 + K), dtype=np.int64)  # [m, 1 + K]: the observer, then the chosen columns
    idx[:, 1:] = pick + 1
    filled, isv = np.ones((m, 1 + K), dtype=bool), np.ones((m, 1 + K), dtype=bool)
    filled[:, 1:], isv[:, 1:] = valid, vehicle[g, pick]
    table = _table(opt, V[g, idx], isv)
    if set(OFFSETS) & set(opt.features):
        offsets = _offsets(observers, keep_g, core, row_of[g, pick], valid, isv)
        for j, f in enumerate(opt.features):
            if f in offsets:
                table[:, :, j] = offsets[f]
    _relative_and_normalized(opt, table)
    table[~filled] = 0.0
    full = np.zeros((m, opt.vehicles_count, len(opt.features)), dtype=np.float32)
    full[:, :table.shape[1]] = table
    for n, k in enumerate(keep_g):
        if opt.order == "shuffled":  # the rows after the observer's, with its env's generator
            observers[k].env.np_random.shuffle(full[n, 1:])
        out[k] = full[n]
    return out


ROW, OBJECT = 1, 2  # a candidate's kind: a road user's row, a road object (0: padding)


def _along(net: Any, slots: list[int], lanes: list[int], V: np.ndarray, self_col: np.ndarray) -> np.ndarray:
    """[observers, 1 + P]: arc length of each observer's candidates (column 0: itself) along its
    lane, projected once per (slot, lane): observers queued on one lane share the projection of
    their slot's candidates (`lanes.project_rows`, the same values as one by one); an observer's
    own place is its own row's column `self_col`."""
    table = net.segment_table()
    pair: dict[tuple[int, int], int] = {}
    of = np.array([pair.setdefault(k, n) for n, k in enumerate(zip(slots, lanes))], dtype=np.int64)
    first = np.array(list(pair.values()), dtype=np.int64)
    lane_arr = np.array(lanes, dtype=np.int64)
    if len(first) == len(of):
        return project_rows(table, lane_arr, V[:, :, 0], V[:, :, 1], lateral=False)[0]
    shared = project_rows(table, lane_arr[first], V[first, :, 0], V[first, :, 1], lateral=False)[0]
    shared = shared[np.searchsorted(first, of)]  # each observer's pair's (first holds ascending observers)
    n = np.arange(len(of))
    shared[:, 0] = shared[n, self_col]
    return shared


def _candidates(core: Any, slots: list[int], roads: dict[int, Any], obstacles: bool) -> tuple[np.ndarray, ...]:
    """Each observer's row of candidates, column 0 left for the observer: its slot's rows in row
    order, then its road's objects (with `obstacles`): (V [observers, 1 + P, 4] of x, y,
    heading, speed; kind [observers, P]; their rows [observers, P], -1 for objects; each row's
    column among its slot's candidates)."""
    S = len(core.roads)
    if S == 1:  # one slot: its rows in row order
        used, u_of = [slots[0]], np.zeros(len(slots), dtype=np.int64)
        rank = np.arange(len(core.env))
        counts = [len(rank)]
    else:
        used_arr, u_of = np.unique(np.array(slots, dtype=np.int64), return_inverse=True)
        used = used_arr.tolist()
        order = np.argsort(core.env, kind="stable")  # rows by slot, in row order within a slot
        senv = core.env[order]
        rank = np.empty(len(order), dtype=np.int64)
        rank[order] = np.arange(len(order)) - np.searchsorted(senv, senv, side="left")
        counts = np.bincount(core.env, minlength=S)[used_arr].tolist()
    objs = [roads[q].objects if obstacles else [] for q in used]
    P = max(n + len(x) for n, x in zip(counts, objs))
    U = len(used)
    V = np.zeros((U, 1 + P, 4))
    kind = np.zeros((U, P), dtype=np.int8)
    row_of = np.full((U, P), -1, dtype=np.int64)
    if S == 1:
        n = counts[0]
        V[0, 1:n + 1, 0], V[0, 1:n + 1, 1], V[0, 1:n + 1, 2], V[0, 1:n + 1, 3] = core.x, core.y, core.heading, core.speed
        kind[0, :n] = ROW
        row_of[0, :n] = rank
    else:
        where = np.full(S, -1, dtype=np.int64)
        where[used_arr] = np.arange(U)
        u = where[core.env]
        mine = (u >= 0).nonzero()[0]
        um, cm = u[mine], rank[mine]
        V[um, 1 + cm, 0], V[um, 1 + cm, 1], V[um, 1 + cm, 2], V[um, 1 + cm, 3] = \
            core.x[mine], core.y[mine], core.heading[mine], core.speed[mine]
        kind[um, cm] = ROW
        row_of[um, cm] = mine
    at_n, at_j, walkers, heading, others = [], [], [], [], []  # (a walker row's place read from the core's arrays)
    for n, items in enumerate(objs):
        for j, o in enumerate(items, counts[n]):
            at_n.append(n)
            at_j.append(j)
            heading.append(o.heading)
            if type(o) is Pedestrian and o._core is core:
                walkers.append(o._row)
            else:
                walkers.append(-1)
                others.append((len(walkers) - 1, o.position))
    if at_n:
        n_, j_, w = np.array(at_n), np.array(at_j), np.array(walkers, dtype=np.int64)
        on = w >= 0
        V[n_[on], j_[on] + 1, 0], V[n_[on], j_[on] + 1, 1] = core.p_x[w[on]], core.p_y[w[on]]
        for k, pos in others:
            V[at_n[k], at_j[k] + 1, :2] = pos
        V[n_, j_ + 1, 2] = heading
        kind[n_, j_] = OBJECT
    if U != len(slots) or (u_of != np.arange(U)).any():
        V, kind, row_of = V[u_of], kind[u_of], row_of[u_of]  # one row per observer (several in a slot)
    return V, kind, row_of, rank


def _table(opt: Any, chosen: np.ndarray, isv: np.ndarray) -> np.ndarray:
    """[observers, 1 + K, features] of the chosen candidates' (x, y, heading, speed) as
    `Vehicle.to_dict` / `RoadObject.to_dict` give them (objects: no speed, heading NaN)."""
    h = chosen[:, :, 2]
    trig = {"cos_h": np.cos(h), "sin_h": np.sin(h)}
    table = np.zeros((*h.shape, len(opt.features)))
    for j, f in enumerate(opt.features):
        if f == "presence":
            table[:, :, j] = 1.0
        elif f in ("x", "y"):
            table[:, :, j] = chosen[:, :, 0 if f == "x" else 1]
        elif f in ("vx", "vy"):
            table[:, :, j] = chosen[:, :, 3] * trig["cos_h" if f == "vx" else "sin_h"]
            table[:, :, j][~isv] = 0.0  # objects stand
        elif f == "heading":
            table[:, :, j] = h
            table[:, :, j][~isv] = np.nan  # objects have no heading feature (pandas fills NaN)
        elif f in trig:
            table[:, :, j] = trig[f]
    return table


def _relative_and_normalized(opt: Any, table: np.ndarray) -> None:
    """highway-env's arithmetic in place: the others relative to the observer (unless
    `absolute`), then the ranged features normalized (and clipped)."""
    rel, cols, lo, hi = _columns(opt)
    if not opt.absolute and rel is not None:
        table[:, 1:, rel] -= table[:, :1, rel]
    if opt.normalize and cols is not None:
        got = -1 + (table[:, :, cols] - lo) * (1 - (-1)) / (hi - lo)
        table[:, :, cols] = np.minimum(np.maximum(got, -1), 1) if opt.clip else got


def _columns(opt: Any) -> tuple:
    """(the relative features' columns, the ranged features' columns, their lows and highs), as
    slices where they are contiguous; held on the observation object per features_range."""
    held = opt.__dict__.get("_columns_held")
    if held is None or held[0] is not opt.features_range:
        rel = [j for j, f in enumerate(opt.features) if f in RELATIVE]
        ranged = [(j, *opt.features_range[f]) for j, f in enumerate(opt.features) if f in (opt.features_range or {})]
        cols = [j for j, _, _ in ranged]
        held = opt._columns_held = (opt.features_range, _index(rel), _index(cols),
                                    np.array([a for _, a, _ in ranged], dtype=float),
                                    np.array([b for _, _, b in ranged], dtype=float))
    return held[1:]


def _index(cols: list[int]) -> slice | list[int] | None:
    """Columns as a slice where contiguous (basic indexing: views, no copies), None if none."""
    if not cols:
        return None
    return slice(cols[0], cols[-1] + 1) if cols == list(range(cols[0], cols[-1] + 1)) else cols


def _offsets(observers: list, keep_g: list[int], core: Any, rows: np.ndarray, valid: np.ndarray,
             isv: np.ndarray) -> dict[str, np.ndarray]:
    """`Vehicle.lane_offset` columns of the observers and the vehicles they chose (NaN for
    objects), read from the vehicles (an option outside the usual feature set)."""
    cols = {name: np.full(isv.shape, np.nan) for name in OFFSETS}
    for n, k in enumerate(keep_g):
        chosen = [observers[k].observer_vehicle] + [core.objs[i] for i in rows[n][valid[n] & isv[n, 1:]].tolist()]
        at = isv[n].nonzero()[0][:len(chosen)]
        off = np.array([v.lane_offset for v in chosen], dtype=float)
        for j, name in enumerate(OFFSETS):
            cols[name][n, at] = off[:, j]
    return cols


def _options(obs: Any) -> tuple:
    """(whether the program reproduces them, then the options an observer's values depend on
    besides the road), held on the observation object (a config change replaces it)."""
    held = obs.__dict__.get("_batch_options")
    if held is None:
        ok = (set(obs.features) <= FEATURES and obs.vehicles_count >= 2 and obs.order in ("sorted", "shuffled")
              and bool(obs.features_range or not obs.normalize))
        held = obs._batch_options = (ok, tuple(obs.features), obs.vehicles_count, repr(obs.features_range),
                                     obs.absolute, obs.see_behind, obs.normalize, obs.clip, obs.include_obstacles,
                                     obs.order, obs.env.PERCEPTION_DISTANCE)
    return held
