"""Observations: highway-env's types with finite bounds where the values are bounded, the
Kinematics observation computed from the arrays core (`sim.observe.kinematics`: highway-env's
values without pandas or per-vehicle projections), and the traffic-control vector
({"observation", "traffic_control"} when `observe_traffic_control`)."""
from __future__ import annotations

import numpy as np
from gymnasium import spaces
from highway_env.envs.common.observation import (KinematicObservation, ObservationType, OccupancyGridObservation,
                                                 TimeToCollisionObservation, observation_factory)


from .driver_view import DriverViewObservation
from .sim.observe import kinematics

ANY_FLOAT32 = float(np.finfo(np.float32).max)  # the bound of a feature that has none: any float32 value
UNIT_FEATURES = ("cos_h", "sin_h", "cos_d", "sin_d")
DEFAULT_RANGED = ("x", "y", "vx", "vy")  # features highway-env normalizes when features_range is not given
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
        """highway-env's values; on the arrays core computed from its rows (`sim.observe.kinematics`,
        a batch of one)."""
        core = getattr(self.env.road, "core", None) if self.env.road else None
        got = kinematics([self], core)[0] if core is not None else None
        return super().observe() if got is None else got


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
