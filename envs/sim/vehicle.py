"""The controlled vehicle: a kinematic bicycle about the rear axle with a real car's body
(docs/architecture.md, "The vehicle"). One set of functions over arrays (or floats: a single
ego is a batch of one) integrates it, turns a wanted yaw rate into steering, and describes it
to planners in other processes."""
from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from ...angles import wrap_angle
from ...config import (DRIVE_DEFAULTS, LANE_KEEPING_KP_HEADING, LANE_KEEPING_KP_LATERAL, LANE_KEEPING_TAU_S,
                       SPEED_CONTROL_KP)
from ...errors import Feat2MapError


@dataclass(frozen=True)
class VehicleModel:
    """The body and steering of a controlled vehicle; (x, y) is the body's centre and the rear
    axle lies `rear_offset` behind it along the heading."""

    length: float
    width: float
    wheelbase: float
    front_overhang: float
    max_steering: float  # [rad] at the front wheels, either way

    @classmethod
    def of(cls, config: Mapping[str, Any] | None = None, where: str = "config.vehicle") -> "VehicleModel":
        """From the env config's `vehicle` dict (the defaults where keys are missing); a body the
        wheelbase and overhang do not fit is an error naming the key."""
        values = {**DRIVE_DEFAULTS["vehicle"], **(config or {})}
        model = cls(**{k: float(values[k]) for k in DRIVE_DEFAULTS["vehicle"]})
        if model.wheelbase + model.front_overhang > model.length:
            raise Feat2MapError(f"wheelbase + front_overhang ({model.wheelbase} + {model.front_overhang} m) must "
                                f"fit in the length ({model.length} m)", where)
        return model

    @property
    def rear_overhang(self) -> float:
        return self.length - self.wheelbase - self.front_overhang

    @property
    def rear_offset(self) -> float:
        """Metres from the body's centre back to the rear axle."""
        return self.wheelbase / 2 + (self.rear_overhang - self.front_overhang) / 2

    def describe(self) -> dict[str, Any]:
        """The model as numbers for a planner in another process (the planner bridge's init):
        axles as metres along the heading from the reference point, the body's centre."""
        return {"kind": "kinematic_bicycle", "reference_point": "centre", **asdict(self),
                "rear_overhang": self.rear_overhang, "front_axle": self.wheelbase - self.rear_offset,
                "rear_axle": -self.rear_offset}


class Floats:
    """The functions `integrate` and `keeping_steering` take for floats (a single road user: no
    array overhead): math's sin and cos, numpy's tan, asin and atan, whose last bit libm's differ
    in for some arguments (here about 1 in 200, 1 in 12 and 1 in 900), so that a row driven with
    floats moves exactly as a row of the arrays."""
    sin, cos = math.sin, math.cos

    @staticmethod
    def tan(v: float) -> float:
        return float(np.tan(v))

    @staticmethod
    def asin(v: float) -> float:
        return float(np.arcsin(v))

    @staticmethod
    def atan(v: float) -> float:
        return float(np.arctan(v))


FLOATS = Floats()


def integrate(x, y, heading, speed, steering, acceleration, dt: float, wheelbase, rear_offset, lib: Any = np):
    """(x, y, heading, speed) after `dt` of the bicycle: the rear axle runs along the arc of
    curvature tan(steering) / wheelbase at `speed` (its chord, to 1e-8 for turns under a radian a
    step), the body's centre `rear_offset` ahead of it; the speed then changes by acceleration *
    dt. Arrays with `lib` numpy, or floats with `lib` FLOATS."""
    ds = speed * dt
    turn = ds * lib.tan(steering) / wheelbase
    half = turn / 2
    sq = half * half
    chord = ds * (1.0 - sq / 6.0 + sq * sq / 120.0)  # ds * sin(half) / half
    cos0, sin0 = lib.cos(heading), lib.sin(heading)
    heading = heading + turn
    cos1, sin1 = lib.cos(heading), lib.sin(heading)
    mid = heading - half
    return (x + rear_offset * (cos1 - cos0) + chord * lib.cos(mid),
            y + rear_offset * (sin1 - sin0) + chord * lib.sin(mid), heading, speed + acceleration * dt)


def yaw_rate(speed: float, steering: float, wheelbase: float) -> float:
    """The body's yaw rate [rad/s] at this speed and steering."""
    return speed * math.tan(steering) / wheelbase


def _clip(value, lo, hi, lib: Any):
    return np.minimum(np.maximum(value, lo), hi) if lib is np else min(max(value, lo), hi)  # (np.clip's values, sooner)


def keeping_steering(heading_ahead, r, heading, speed, wheelbase, max_steering, lib: Any = np):
    """Lane keeping's steering for a body `r` beside its lane, heading `heading`, where the lane
    heads `heading_ahead` LANE_KEEPING_TAU_S ahead: highway-env's law (lateral P -> heading P ->
    yaw rate), its yaw rate made by the bicycle's steering within +-max_steering. Arrays with
    `lib` numpy (the rows of the arrays), or floats with `lib` FLOATS (one road user)."""
    v: Any = np.where(np.abs(speed) > 1e-2, speed, 1e-2) if lib is np else speed if abs(speed) > 1e-2 else 1e-2
    heading_cmd = lib.asin(_clip(-LANE_KEEPING_KP_LATERAL * r / v, -1.0, 1.0, lib))
    heading_ref = heading_ahead + _clip(heading_cmd, -math.pi / 4, math.pi / 4, lib)
    rate = LANE_KEEPING_KP_HEADING * wrap_angle(heading_ref - heading)
    steer = lib.atan(wheelbase * rate / _clip(v, 1e-2, math.inf, lib))
    return _clip(steer, -max_steering, max_steering, lib)


def lane_keeping(lane: Any, s: float, r: float, heading: float, speed: float, model: VehicleModel) -> float:
    """The steering that keeps the body's centre on `lane`, where it stands at (s along, r
    beside): `keeping_steering` with the lane's heading LANE_KEEPING_TAU_S ahead."""
    return keeping_steering(lane.heading_at(s + speed * LANE_KEEPING_TAU_S), r, heading, speed, model.wheelbase,
                            model.max_steering, FLOATS)


def speed_control(target, speed):
    """The acceleration that tracks a target speed: highway-env's P law (floats or arrays; the
    caller clips it to its range)."""
    return SPEED_CONTROL_KP * (target - speed)


def pursuit_steering(x: float, y: float, heading: float, tx: float, ty: float, model: VehicleModel) -> float:
    """Pure pursuit: the steering that takes the rear axle on the arc through target (tx, ty)."""
    rx, ry = x - model.rear_offset * math.cos(heading), y - model.rear_offset * math.sin(heading)
    alpha = math.atan2(ty - ry, tx - rx) - heading
    ld = max(math.hypot(tx - rx, ty - ry), 1e-3)
    steer = math.atan2(2.0 * model.wheelbase * math.sin(alpha), ld)
    return min(max(steer, -model.max_steering), model.max_steering)
