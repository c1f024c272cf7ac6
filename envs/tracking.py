"""Trajectory following for an ego driven by an external planner (the planner bridge,
`feat2map.scenarios.bridge`): a time-indexed trajectory of poses and speeds, tracked every
simulation frame by a standard controller: pure pursuit for the steering and a P controller on
the speed (with the trajectory's acceleration as feed-forward and a gain on the along-track
position error).

Hooked into the ego by `EgoVehicle.tracker` (envs/vehicles.py): when set, the ego asks it for
its command each frame, whatever the action type holds.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

import numpy as np

from ..config import (TRACKING_ACCEL_RANGE, TRACKING_HOLD_WINDOW_S, TRACKING_LOOKAHEAD_MIN_M, TRACKING_LOOKAHEAD_TIME_S,
                      TRACKING_POSITION_GAIN, TRACKING_PREVIEW_S, TRACKING_SPEED_GAIN, TRACKING_STOP_SPEED_MPS)
from .sim.vehicle import VehicleModel, pursuit_steering



def tracking_model(model: VehicleModel) -> dict[str, Any]:
    """How `TrajectoryTracker` follows a trajectory with `model`, as numbers for a planner in
    another process (the planner bridge's init; read from the constants it uses)."""
    return {"steering": "pure_pursuit", "pursuit_point": "rear_axle", "lookahead_min_m": TRACKING_LOOKAHEAD_MIN_M,
            "lookahead_time_s": TRACKING_LOOKAHEAD_TIME_S, "speed_gain": TRACKING_SPEED_GAIN,
            "position_gain": TRACKING_POSITION_GAIN, "preview_s": TRACKING_PREVIEW_S,
            "acceleration_range": [float(x) for x in TRACKING_ACCEL_RANGE], "max_steering": model.max_steering,
            "stop_speed_mps": TRACKING_STOP_SPEED_MPS, "hold_window_s": TRACKING_HOLD_WINDOW_S}


@dataclass(frozen=True)
class Trajectory:
    """Timestamped poses of the vehicle centre: time [s, simulation clock], x, y [m], heading
    [rad], speed [m/s]; at least one point, times strictly increasing."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    heading: np.ndarray
    speed: np.ndarray

    @classmethod
    def of(cls, points: Sequence[Sequence[float]]) -> "Trajectory":
        """From rows (t, x, y, heading, speed); raises ValueError on a malformed one."""
        a = np.asarray(points, dtype=float)
        if a.ndim != 2 or a.shape[1] != 5 or len(a) < 1:
            raise ValueError(f"a trajectory is a list of (t, x, y, heading, speed) rows, got shape {a.shape}")
        if not np.all(np.isfinite(a)):
            raise ValueError("a trajectory must hold finite numbers only")
        if len(a) > 1 and np.any(np.diff(a[:, 0]) <= 0):
            raise ValueError("trajectory times must be strictly increasing")
        if np.any(a[:, 4] < -0.5):
            raise ValueError("trajectory speeds must not be negative")
        return cls(a[:, 0], a[:, 1], a[:, 2], a[:, 3], np.maximum(a[:, 4], 0.0))


class TrajectoryTracker:
    """Pure pursuit + speed P control along one trajectory; `clock()` gives the simulation time."""

    def __init__(self, trajectory: Trajectory, clock: Callable[[], float], model: VehicleModel | None = None) -> None:
        self.traj = trajectory
        self.clock = clock
        self.model = model or VehicleModel.of()  # the bicycle it steers (pure pursuit of its rear axle)
        pts = np.column_stack([trajectory.x, trajectory.y])
        seg = np.hypot(*np.diff(pts, axis=0).T) if len(pts) > 1 else np.zeros(0)
        self.s = np.concatenate([[0.0], np.cumsum(seg)])
        self.pts = pts

    def _point_at(self, s: float) -> np.ndarray:
        s = float(np.clip(s, 0.0, self.s[-1]))
        return np.array([np.interp(s, self.s, self.pts[:, 0]), np.interp(s, self.s, self.pts[:, 1])])

    def _project(self, p: np.ndarray) -> float:
        """Arc length of the trajectory point nearest `p`."""
        if len(self.pts) == 1:
            return 0.0
        a, b = self.pts[:-1], self.pts[1:]
        d = b - a
        L2 = np.maximum((d * d).sum(axis=1), 1e-12)
        u = np.clip(((p - a) * d).sum(axis=1) / L2, 0.0, 1.0)
        q = a + d * u[:, None]
        k = int(np.argmin(((q - p) ** 2).sum(axis=1)))
        return float(self.s[k] + u[k] * math.sqrt(L2[k]))

    def command(self, position: Sequence[float], heading: float, speed: float) -> dict[str, float]:
        """{"acceleration", "steering"} for a vehicle at this pose and speed, now."""
        tr = self.traj
        t = self.clock()
        v_ref = float(np.interp(t + TRACKING_PREVIEW_S, tr.t, tr.speed))
        if len(tr.t) > 1:
            k = int(np.clip(np.searchsorted(tr.t, t) - 1, 0, len(tr.t) - 2))
            a_ff = float((tr.speed[k + 1] - tr.speed[k]) / (tr.t[k + 1] - tr.t[k])) if tr.t[0] <= t <= tr.t[-1] else 0.0
        else:
            a_ff = 0.0
        p = np.asarray(position[:2], dtype=float)
        s_ego = self._project(p)
        s_ref = float(np.interp(t, tr.t, self.s))
        ahead = (tr.t >= t) & (tr.t <= t + TRACKING_HOLD_WINDOW_S)
        v_ahead = max(v_ref, float(tr.speed[ahead].max()) if ahead.any() else 0.0)
        if v_ahead < TRACKING_STOP_SPEED_MPS and (t >= tr.t[-1] or s_ego >= s_ref - 0.5):  # asked to stay
            acc = -TRACKING_SPEED_GAIN * max(speed, 0.0) - (2.0 if speed > 0.05 else 0.0)
        else:
            acc = a_ff + TRACKING_SPEED_GAIN * (v_ref - speed) + TRACKING_POSITION_GAIN * (s_ref - s_ego)
        lookahead = TRACKING_LOOKAHEAD_MIN_M + TRACKING_LOOKAHEAD_TIME_S * max(speed, 0.0)
        if self.s[-1] > 0:
            target = self._point_at(s_ego + lookahead)
            if s_ego + lookahead > self.s[-1]:  # beyond the end: continue along the last heading
                extra = s_ego + lookahead - self.s[-1]
                target = target + extra * np.array([math.cos(tr.heading[-1]), math.sin(tr.heading[-1])])
        else:
            target = p + lookahead * np.array([math.cos(tr.heading[-1]), math.sin(tr.heading[-1])])
        steering = pursuit_steering(float(p[0]), float(p[1]), heading, float(target[0]), float(target[1]), self.model)
        return {"acceleration": float(np.clip(acc, *TRACKING_ACCEL_RANGE)),
                "steering": steering}
