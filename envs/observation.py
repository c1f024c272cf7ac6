"""Observations: highway-env's types with finite bounds where the values are bounded, a fast
path for the Kinematics observation on the arrays core (same values as highway-env's, without
pandas or per-vehicle projections), and the traffic-control vector ({"observation",
"traffic_control"} when `observe_traffic_control`)."""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.observation import (KinematicObservation, ObservationType, OccupancyGridObservation,
                                                 TimeToCollisionObservation, observation_factory)


from .driver_view import DriverViewObservation

ANY_FLOAT32 = float(np.finfo(np.float32).max)  # the bound of a feature that has none: any float32 value
UNIT_FEATURES = ("cos_h", "sin_h", "cos_d", "sin_d")
DEFAULT_RANGED = ("x", "y", "vx", "vy")  # features highway-env normalizes when features_range is not given
FAST_FEATURES = frozenset({"presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h", "cos_d", "sin_d",
                           "long_off", "lat_off", "ang_off"})
RELATIVE = ("x", "y", "vx", "vy")
TRAFFIC_CONTROL_FEATURES = ("green", "amber", "red", "stop_sign", "stop_line_distance", "pedestrian_ahead")


class Kinematics(KinematicObservation):
    """highway-env's Kinematics observation with finite bounds: presence in [0, 1], headings'
    cosines and sines in [-1, 1], normalized and clipped features in [-1, 1], any float32 for
    the others."""

    def space(self) -> spaces.Space:
        lo = np.full((self.vehicles_count, len(self.features)), -ANY_FLOAT32, dtype=np.float32)
        hi = np.full_like(lo, ANY_FLOAT32)
        ranged = set(self.features_range or DEFAULT_RANGED) if self.normalize and self.clip else set()
        for i, f in enumerate(self.features):
            if f == "presence":
                lo[:, i], hi[:, i] = 0.0, 1.0
            elif f in UNIT_FEATURES or f in ranged:
                lo[:, i], hi[:, i] = -1.0, 1.0
        return spaces.Box(lo, hi, dtype=np.float32)


    def observe(self) -> np.ndarray:
        """highway-env's values; on the arrays core computed from its rows (see `fast`)."""
        core = getattr(self.env.road, "core", None) if self.env.road else None
        if core is None or not self.fast_supported():
            return super().observe()
        return self.fast(core)

    def fast_supported(self) -> bool:
        """Options the fast path reproduces; others (and the first normalized observation without
        a features_range, which highway-env derives from the lanes) go to highway-env's code."""
        return (set(self.features) <= FAST_FEATURES and self.vehicles_count >= 2
                and self.order in ("sorted", "shuffled") and (self.features_range or not self.normalize)
                and self.observer_vehicle is self.env.vehicle)

    def fast(self, core) -> np.ndarray:
        """`KinematicObservation.observe` from the core's rows: the observer's row (absolute),
        then the nearest road users within PERCEPTION_DISTANCE by distance along the observer's
        lane (behind it only with see_behind; pedestrians from 2 lengths behind), relative to
        it, normalized and clipped, zero rows to fill."""
        ego = self.observer_vehicle
        road = self.env.road
        core.sync([road])  # vehicles respawned or added since the last frame
        mine = core.rows(road).tolist()  # this road's rows (a batch holds other sub-envs' too)
        objs = core.objs
        rows = [i for i in mine if objs[i] is not ego]
        if len(rows) != len(mine) - 1 or (core.kind[rows] != 1).any():
            return super().observe()  # vehicles the core does not drive (user code added foreign ones)
        obstacles = self.env.road.objects if self.include_obstacles else []
        ex, ey = float(ego.position[0]), float(ego.position[1])
        idx = np.array(rows, dtype=np.int64)
        x = np.concatenate([[ex], core.x[idx], [o.position[0] for o in obstacles]])
        y = np.concatenate([[ey], core.y[idx], [o.position[1] for o in obstacles]])
        n_v = len(rows)
        dx, dy = x[1:] - ex, y[1:] - ey
        near = np.sqrt(dx * dx + dy * dy) < self.env.PERCEPTION_DISTANCE
        along = project_s(ego.lane, x, y)
        dist = along[1:] - along[0]
        behind_ok = -2 * ego.LENGTH < dist
        keep = near & (behind_ok if not self.see_behind else True)
        keep[n_v:] &= behind_ok[n_v:]
        cand = keep.nonzero()[0]
        if self.order == "sorted":
            cand = cand[np.argsort(np.abs(dist[cand]), kind="stable")]
        cand = cand[:self.vehicles_count - 1]
        table = self._rows(core, ego, idx, obstacles, cand, n_v)
        obs = np.zeros((self.vehicles_count, len(self.features)))
        obs[:1 + len(cand)] = np.stack([table[f] for f in self.features], axis=1)
        if self.normalize:  # highway-env's arithmetic, on the ranged columns at once
            cols, lo, hi = self._ranged()
            if cols:
                got = -1 + (obs[:1 + len(cand), cols] - lo) * (1 - (-1)) / (hi - lo)
                obs[:1 + len(cand), cols] = np.minimum(np.maximum(got, -1), 1) if self.clip else got
        if self.order == "shuffled":
            self.env.np_random.shuffle(obs[1:])
        return obs.astype(np.float32)

    def _ranged(self) -> tuple[list[int], np.ndarray, np.ndarray]:
        """(columns of the features with a range, their lows, their highs), made again only
        when `features_range` is another dict."""
        held = self.__dict__.get("_ranged_held")
        if held is None or held[0] is not self.features_range:
            ranged = [(j, *self.features_range[f]) for j, f in enumerate(self.features) if f in self.features_range]
            held = self._ranged_held = (self.features_range, [j for j, _, _ in ranged],
                                        np.array([a for _, a, _ in ranged], dtype=float),
                                        np.array([b for _, _, b in ranged], dtype=float))
        return held[1:]

    def _rows(self, core, ego, idx, obstacles, cand, n_v) -> dict[str, np.ndarray]:
        """Feature columns of the observer's row and the chosen road users' rows, as
        `Vehicle.to_dict` / `RoadObject.to_dict` give them (objects have no heading or lane
        offsets: NaN, as pandas fills them)."""
        n = 1 + len(cand)
        is_v = np.concatenate([[True], cand < n_v])
        vr = idx[cand[cand < n_v]]  # core rows of the chosen vehicles, in order
        vrows = is_v.nonzero()[0][1:]
        h, sp, px, py = np.full(n, np.nan), np.zeros(n), np.empty(n), np.empty(n)
        h[0], sp[0] = ego.heading, ego.speed
        px[0], py[0] = ego.position[0], ego.position[1]
        h[vrows], sp[vrows], px[vrows], py[vrows] = core.heading[vr], core.speed[vr], core.x[vr], core.y[vr]
        cos_h, sin_h = np.cos(h), np.sin(h)
        vx, vy = sp * cos_h, sp * sin_h
        orows = (~is_v).nonzero()[0]
        if len(orows):
            objs = [obstacles[k - n_v] for k in cand[cand >= n_v]]
            oh = np.array([o.heading for o in objs], dtype=float)
            cos_h[orows], sin_h[orows] = np.cos(oh), np.sin(oh)
            px[orows] = [o.position[0] for o in objs]
            py[orows] = [o.position[1] for o in objs]
            vx[orows] = vy[orows] = 0.0
        col = {"presence": np.ones(n), "x": px, "y": py, "vx": vx, "vy": vy, "heading": h, "cos_h": cos_h,
               "sin_h": sin_h, "cos_d": np.zeros(n), "sin_d": np.zeros(n)}
        if not self.absolute:
            for name in RELATIVE:
                col[name][1:] -= col[name][0]
        if {"long_off", "lat_off", "ang_off"} & set(self.features):
            off = np.array([m.lane_offset for m in [ego] + [core.objs[r] for r in vr]])
            for j, name in enumerate(("long_off", "lat_off", "ang_off")):
                col[name] = np.full(n, np.nan)
                col[name][is_v] = off[:, j]
        return {f: col[f] for f in self.features}


def project_s(lane, x: np.ndarray, y: np.ndarray) -> np.ndarray:
    """`lane.local_coordinates(p)[0]` of many points at once (a `PolylineLane`), with the same
    arithmetic, so the values are identical."""
    rx = x[:, None] - lane._ax[None, :]
    ry = y[:, None] - lane._ay[None, :]
    t = rx * lane._ux + ry * lane._uy
    tc = np.minimum(np.maximum(t, lane._lo), lane._hi)
    dx = rx - tc * lane._ux
    dy = ry - tc * lane._uy
    i = (dx * dx + dy * dy).argmin(axis=1)
    return lane.cum[i] + tc[np.arange(len(x)), i]


class OccupancyGrid(OccupancyGridObservation):
    """highway-env's occupancy grid; values are clipped to [-1, 1] when `clip`."""

    def space(self) -> spaces.Space:
        if self.as_image:
            return super().space()
        bound = 1.0 if self.clip else ANY_FLOAT32
        return spaces.Box(shape=self.grid.shape, low=-bound, high=bound, dtype=np.float32)


class TimeToCollision(TimeToCollisionObservation):
    """highway-env's time-to-collision grid (3 speeds x 3 lanes x horizon steps, in [0, 1]), its
    space known without observing (highway-env's observes, and falls back to an unbounded
    `spaces.Space` where the env has a road but no observer yet: the multi-agent env's world)."""

    def space(self) -> spaces.Space:
        steps = int(self.horizon * self.env.config["policy_frequency"])
        return spaces.Box(shape=(3, 3, steps), low=0, high=1, dtype=np.float32)


def make_observation(env, config: dict) -> ObservationType:
    """The observation type of `config` (highway-env's factory, with the bounded classes above)."""
    kind = config.get("type")
    if kind == "Kinematics":
        return Kinematics(env, **config)
    if kind == "OccupancyGrid":
        return OccupancyGrid(env, **config)
    if kind == "TimeToCollision":
        return TimeToCollision(env, **config)
    if kind == "DriverView":
        return DriverViewObservation(env)
    return observation_factory(env, config)


class TrafficControlObservation(ObservationType):
    """Wraps any observation into {"observation", "traffic_control"}; the latter is
    TRAFFIC_CONTROL_FEATURES: [green, amber, red, stop sign, distance to the stop line / 100
    (clipped to 1), pedestrian ahead] (`MapEnv.traffic_control_vector`)."""

    def __init__(self, env, inner: ObservationType) -> None:
        super().__init__(env)
        self.inner = inner

    def space(self) -> spaces.Space:
        return spaces.Dict({"observation": self.inner.space(),
                            "traffic_control": spaces.Box(0.0, 1.0, (len(TRAFFIC_CONTROL_FEATURES),), dtype=np.float32)})

    def observe(self):
        return {"observation": self.inner.observe(), "traffic_control": self.env.traffic_control_vector()}
