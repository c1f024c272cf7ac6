"""The Kinematics observation of many observers at once (the agents of envs/multi_agent.py): the
values `observation.Kinematics.fast` gives each of them, from one array program over all
observers (observers on the same lane share one projection of the road users onto it)."""
from __future__ import annotations

import numpy as np

from .lanes import project_rows, segment_table
from .observation import RELATIVE, Kinematics, project_s

SIMILAR = 1.5  # lanes whose vertex counts are within this factor are projected in one program
BATCH_FEATURES = frozenset({"presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d"})


def batch_supported(obs: Kinematics, core) -> bool:
    """Options the batch reproduces (Kinematics.fast's, without lane offsets or shuffling), on
    a core of one road whose rows are all driven (traffic and agents)."""
    return (type(obs) is Kinematics and set(obs.features) <= BATCH_FEATURES and obs.vehicles_count >= 2
            and obs.order == "sorted" and bool(obs.features_range or not obs.normalize)
            and bool((core.kind == 1).all()) and bool((core.env == core.env[:1]).all()))  # one road's rows


def observe_many(obs: Kinematics, core, rows: np.ndarray, lanes: list, objects: list, perception: float) -> np.ndarray:
    """[observers, vehicles_count, features] float32: for each observer (its core row in `rows`,
    its lane in `lanes`) its own row (absolute) then the nearest road users (other rows, then
    `objects` such as pedestrians) within `perception` metres by distance along its lane."""
    m, n_v = len(rows), len(core.objs)
    objs = objects if obs.include_obstacles else []
    X = np.concatenate([core.x, [o.position[0] for o in objs]])
    Y = np.concatenate([core.y, [o.position[1] for o in objs]])
    N = len(X)
    by_lane: dict[int, list[int]] = {}
    for k, lane in enumerate(lanes):
        by_lane.setdefault(id(lane), []).append(k)
    along = np.empty((m, N))
    groups = sorted(by_lane.values(), key=lambda ks: len(lanes[ks[0]]._ax))
    start = 0
    while start < len(groups):  # lanes of similar vertex counts projected together
        end = start + 1
        while end < len(groups) and len(lanes[groups[end][0]]._ax) <= SIMILAR * len(lanes[groups[start][0]]._ax):
            end += 1
        if end - start == 1:
            along[groups[start]] = project_s(lanes[groups[start][0]], X, Y)
        else:
            projected = project_many([lanes[ks[0]] for ks in groups[start:end]], X, Y)
            for g, ks in enumerate(groups[start:end]):
                along[ks] = projected[g]
        start = end
    own = along[np.arange(m), rows]
    dist = along - own[:, None]
    dx, dy = X[None, :] - core.x[rows][:, None], Y[None, :] - core.y[rows][:, None]
    keep = np.sqrt(dx * dx + dy * dy) < perception
    behind_ok = dist > -2 * core.length[rows][:, None]  # the observer's LENGTH, as Kinematics.fast
    if not obs.see_behind:
        keep &= behind_ok
    keep[:, n_v:] &= behind_ok[:, n_v:]
    keep[np.arange(m), rows] = False
    key = np.where(keep, np.abs(dist), np.inf)
    K = obs.vehicles_count - 1
    order = np.argsort(key, axis=1, kind="stable")[:, :K]
    valid = np.take_along_axis(key, order, axis=1) < np.inf  # [m, K]
    # columns of every row (vehicles, then objects), as Vehicle.to_dict / RoadObject.to_dict give them
    h = np.concatenate([core.heading, np.full(len(objs), np.nan)])
    oh = np.array([o.heading for o in objs], dtype=float)
    cos_h = np.concatenate([np.cos(core.heading), np.cos(oh)])
    sin_h = np.concatenate([np.sin(core.heading), np.sin(oh)])
    sp = np.concatenate([core.speed, np.zeros(len(objs))])
    vx, vy = sp * cos_h, sp * sin_h
    vx[n_v:] = vy[n_v:] = 0.0
    cols = {"presence": np.ones(N), "x": X, "y": Y, "vx": vx, "vy": vy, "heading": h, "cos_h": cos_h, "sin_h": sin_h,
            "cos_d": np.zeros(N), "sin_d": np.zeros(N)}
    idx = np.concatenate([rows[:, None], order], axis=1)  # [m, 1 + K]
    out = np.zeros((m, obs.vehicles_count, len(obs.features)))
    filled = np.concatenate([np.ones((m, 1), dtype=bool), valid], axis=1)
    col = np.stack([cols[f] for f in obs.features])[:, idx]  # [features, m, 1 + K]
    rel = [j for j, f in enumerate(obs.features) if not obs.absolute and f in RELATIVE]
    if rel:
        col[rel, :, 1:] -= col[rel, :, :1]
    ranges = obs.features_range or {}
    norm = [j for j, f in enumerate(obs.features) if obs.normalize and f in ranges]
    if norm:  # per feature the same arithmetic as Kinematics.fast's
        a, b = (np.array([float(ranges[obs.features[j]][e]) for j in norm])[:, None, None] for e in (0, 1))
        scaled = -1 + (col[norm] - a) * (1 - (-1)) / (b - a)
        col[norm] = np.clip(scaled, -1, 1) if obs.clip else scaled
    out[:, :idx.shape[1], :] = np.where(filled[None], col, 0.0).transpose(1, 2, 0)
    return out.astype(np.float32)


def project_many(lanes: list, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """[lanes, points]: `observation.project_s(lane, x, y)` of each lane in one program (segments
    padded to the lane with the most; padding never wins the nearest segment), with the same
    arithmetic, so the values are identical."""
    L = len(lanes)
    ax, ay, ux, uy, lo, hi, cum, real = _packed(lanes)
    ux, uy = ux[:, None, :], uy[:, None, :]
    # the same operations as project_s, in place ([lanes, points, segments] arrays are large)
    rx = x[None, :, None] - ax[:, None, :]
    ry = y[None, :, None] - ay[:, None, :]
    tc = rx * ux
    tmp = ry * uy
    tc += tmp
    np.maximum(tc, lo[:, None, :], out=tc)
    np.minimum(tc, hi[:, None, :], out=tc)
    np.subtract(rx, np.multiply(tc, ux, out=tmp), out=rx)  # dx
    np.subtract(ry, np.multiply(tc, uy, out=tmp), out=ry)  # dy
    np.multiply(rx, rx, out=rx)
    np.multiply(ry, ry, out=ry)
    rx += ry
    np.copyto(rx, np.inf, where=~real[:, None, :])
    i = rx.argmin(axis=2)
    return cum[np.arange(L)[:, None], i] + np.take_along_axis(tc, i[:, :, None], axis=2)[:, :, 0]


def _packed(lanes: list) -> tuple[np.ndarray, ...]:
    """The padded segment arrays of `lanes` for project_many (ax, ay, ux, uy, lo, hi, cum, real),
    packed once per set of lanes (lanes are fixed once built; the same set recurs every step)."""
    key = tuple(map(id, lanes))
    held = _PACKED.get(key)
    if held is not None and all(a is b for a, b in zip(held[0], lanes)):
        return held[1]
    L, S = len(lanes), max(len(ln._ax) for ln in lanes)
    ax, ay, ux, uy, lo, hi, cum = (np.zeros((L, S)) for _ in range(7))
    real = np.zeros((L, S), dtype=bool)
    for g, ln in enumerate(lanes):
        n = len(ln._ax)
        ax[g, :n], ay[g, :n], ux[g, :n], uy[g, :n] = ln._ax, ln._ay, ln._ux, ln._uy
        lo[g, :n], hi[g, :n], cum[g, :n] = ln._lo, ln._hi, ln.cum[:n]
        real[g, :n] = True
    if len(_PACKED) > 1024:
        _PACKED.clear()
    packed = _PACKED[key] = (list(lanes), (ax, ay, ux, uy, lo, hi, cum, real))
    return packed[1]


_PACKED: dict[tuple[int, ...], tuple[list, tuple[np.ndarray, ...]]] = {}  # lane ids -> (lanes, arrays)


def observe_egos(observers: list, core) -> list:
    """`Kinematics.fast` of many sub-envs' egos on one core (a batch, envs/vector.py), from one
    array program: each observer sees only its own slot's rows (its ego an external row, the
    others driven) and its road's objects. Returns one [vehicles_count, features] float32 array
    per observer, or None for an observer the batch does not reproduce (options outside
    `Kinematics.fast`'s sorted case, lane offsets, vehicles the core does not drive): that one
    observes as a single env does. The same arithmetic as `fast` and `project_s`, so the values
    are identical (tests/envs/test_vector_native.py compares with single envs)."""
    out: list = [None] * len(observers)
    picks = [k for k, o in enumerate(observers) if _ego_batchable(o, core)]
    if not picks:
        return out
    first = _options(observers[picks[0]])
    picks = [k for k in picks if _options(observers[k]) == first]  # one config (a reset may change one)
    net = core.net
    lane_index = net.memo("lane object index", lambda: {id(ln): k for k, ln in enumerate(net._lanes)})
    obs0 = observers[picks[0]]
    # each observer's candidates: the driven rows of its slot in row order (as core.rows), then objects
    slots = np.array([o.env.road.slot for o in (observers[k] for k in picks)], dtype=np.int64)
    where = np.full(len(core.roads), -1, dtype=np.int64)
    where[slots] = np.arange(len(picks))
    order = np.argsort(core.env, kind="stable")
    ext = order[core.kind[order] != 1]
    sel = order[core.kind[order] == 1]
    ego_row = np.full(len(core.roads), -1, dtype=np.int64)
    ego_row[core.env[ext]] = ext
    if len(ext) != len(np.unique(core.env[ext])) or any(
            ego_row[q] < 0 or core.objs[ego_row[q]] is not observers[k].observer_vehicle
            for q, k in zip(slots.tolist(), picks)):
        return out  # a slot whose only external road user is not its ego: each observes alone
    nv = np.bincount(core.env[sel], minlength=len(core.roads))[slots]
    senv = core.env[sel]
    rank = np.arange(len(sel)) - np.searchsorted(senv, senv, side="left")
    objs = [o.env.road.objects if o.include_obstacles else [] for o in (observers[k] for k in picks)]
    no = np.array([len(x) for x in objs], dtype=np.int64)
    m, P = len(picks), int((nv + no).max()) if len(picks) else 0
    X, Y, H, SP = (np.zeros((m, 1 + P)) for _ in range(4))
    real = np.zeros((m, 1 + P), dtype=bool)
    vehicle = np.zeros((m, 1 + P), dtype=bool)
    mine = where[senv] >= 0
    r, c = where[senv[mine]], 1 + rank[mine]
    rows = sel[mine]
    X[r, c], Y[r, c], H[r, c], SP[r, c] = core.x[rows], core.y[rows], core.heading[rows], core.speed[rows]
    real[r, c] = vehicle[r, c] = True
    lanes = np.empty(m, dtype=np.int64)
    length = np.empty(m)
    for g, k in enumerate(picks):
        ego = observers[k].observer_vehicle
        X[g, 0], Y[g, 0] = float(ego.position[0]), float(ego.position[1])
        H[g, 0], SP[g, 0] = ego.heading, ego.speed
        length[g] = ego.LENGTH
        lane = ego.lane
        lk = lane_index.get(id(lane), -1)
        if lk < 0 or net._lanes[lk] is not lane:
            return out
        lanes[g] = lk
        for j, o in enumerate(objs[g]):
            col = 1 + nv[g] + j
            X[g, col], Y[g, col] = o.position[0], o.position[1]
            H[g, col], real[g, col] = o.heading, True
    real[:, 0] = vehicle[:, 0] = True
    along = _project_rows(net, lanes, X, Y)
    dist = along[:, 1:] - along[:, :1]
    dx, dy = X[:, 1:] - X[:, :1], Y[:, 1:] - Y[:, :1]
    near = np.sqrt(dx * dx + dy * dy) < obs0.env.PERCEPTION_DISTANCE
    behind_ok = -2 * length[:, None] < dist
    keep = near & real[:, 1:]
    if not obs0.see_behind:
        keep &= behind_ok
    keep &= vehicle[:, 1:] | behind_ok  # objects: only from 2 lengths behind
    key = np.where(keep, np.abs(dist), np.inf)
    K = obs0.vehicles_count - 1
    pick = np.argsort(key, axis=1, kind="stable")[:, :K]
    valid = np.take_along_axis(key, pick, axis=1) < np.inf
    idx = np.concatenate([np.zeros((m, 1), dtype=np.int64), 1 + pick], axis=1)  # [m, 1 + K] columns
    filled = np.concatenate([np.ones((m, 1), dtype=bool), valid], axis=1)
    h, sp = np.take_along_axis(H, idx, axis=1), np.take_along_axis(SP, idx, axis=1)
    isv = np.take_along_axis(vehicle, idx, axis=1)
    cos_h, sin_h = np.cos(h), np.sin(h)
    vx, vy = sp * cos_h, sp * sin_h
    vx[~isv] = vy[~isv] = 0.0
    h[~isv] = np.nan
    zero = np.zeros(idx.shape)
    col = {"presence": np.ones(idx.shape), "x": np.take_along_axis(X, idx, axis=1),
           "y": np.take_along_axis(Y, idx, axis=1), "vx": vx, "vy": vy, "heading": h, "cos_h": cos_h, "sin_h": sin_h,
           "cos_d": zero, "sin_d": zero}
    if not obs0.absolute:
        for name in RELATIVE:
            col[name] = np.concatenate([col[name][:, :1], col[name][:, 1:] - col[name][:, :1]], axis=1)
    if obs0.normalize:
        for feature, (a, b) in obs0.features_range.items():
            if feature in col:
                v = -1 + (col[feature] - a) * (1 - (-1)) / (b - a)
                col[feature] = np.clip(v, -1, 1) if obs0.clip else v
    table = np.zeros((m, obs0.vehicles_count, len(obs0.features)))
    for j, f in enumerate(obs0.features):
        table[:, :idx.shape[1], j] = np.where(filled, col[f], 0.0)
    table = table.astype(np.float32)
    for g, k in enumerate(picks):
        out[k] = table[g]
    return out


def _options(obs) -> tuple:
    """What an observer's values depend on besides the road: its observation options (held on
    the observation object, which a config change replaces)."""
    held = getattr(obs, "_batch_options", None)
    if held is None:
        held = obs._batch_options = (tuple(obs.features), obs.vehicles_count, repr(obs.features_range), obs.absolute,
                                     obs.see_behind, obs.normalize, obs.clip, obs.include_obstacles,
                                     obs.env.PERCEPTION_DISTANCE)
    return held


def _ego_batchable(obs, core) -> bool:
    """Whether `observe_egos` reproduces this observer's `Kinematics.fast` (all observers of a
    batch share one config)."""
    return (type(obs) is Kinematics and obs.fast_supported() and obs.order == "sorted"
            and set(obs.features) <= BATCH_FEATURES and getattr(obs.env.road, "core", None) is core)


def _project_rows(net, lanes: np.ndarray, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """[observers, points]: `observation.project_s(lane, x[g], y[g])` of each observer g's lane
    (`lanes`, indices into net._lanes) in one program (`lanes.project_rows`)."""
    return project_rows(net.memo("segment table", lambda: segment_table(net._lanes)), lanes, x, y)[0]
