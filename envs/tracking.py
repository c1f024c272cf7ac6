"""Trajectory following for an ego driven by an external planner (the planner bridge,
`feat2map.scenarios.bridge`): a time-indexed trajectory of poses and speeds, tracked every
simulation frame by a standard controller: pure pursuit for the steering and a P controller on
the speed (with the trajectory's acceleration as feed-forward and a gain on the along-track
position error).

Hooked into the ego by `ControlledRow.tracker` (envs/controlled.py): when set, the env asks it
for the ego's command each frame (`ControlledRow.track`), whatever the action type holds.
"""
from __future__ import annotations

import bisect
import math
from dataclasses import dataclass
from typing import Any, Callable, Sequence

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
    [rad], speed [m/s]; at least one point, times strictly increasing. Tuples of floats: the
    tracker reads a few of its ~20 points each frame, where NumPy's per-call cost would dominate."""

    t: tuple[float, ...]
    x: tuple[float, ...]
    y: tuple[float, ...]
    heading: tuple[float, ...]
    speed: tuple[float, ...]

    @classmethod
    def of(cls, points: Sequence[Sequence[float]]) -> "Trajectory":
        """From rows (t, x, y, heading, speed); raises ValueError on a malformed one."""
        try:
            rows = [tuple(float(v) for v in p) for p in points]
        except TypeError:
            rows = []
        if not rows or any(len(r) != 5 for r in rows):
            raise ValueError("a trajectory is a list of at least one (t, x, y, heading, speed) row")
        if not all(math.isfinite(v) for r in rows for v in r):
            raise ValueError("a trajectory must hold finite numbers only")
        if any(b[0] <= a[0] for a, b in zip(rows, rows[1:])):
            raise ValueError("trajectory times must be strictly increasing")
        if any(r[4] < -0.5 for r in rows):
            raise ValueError("trajectory speeds must not be negative")
        t, x, y, h, v = zip(*rows)
        return cls(t, x, y, h, tuple(max(s, 0.0) for s in v))


def _interp(x: float, xs: Sequence[float], ys: Sequence[float]) -> float:
    """`ys` at `x`, linear between the increasing `xs` and held beyond their ends (np.interp)."""
    if x <= xs[0]:
        return ys[0]
    if x >= xs[-1]:
        return ys[-1]
    k = bisect.bisect_right(xs, x) - 1
    return ys[k] + (ys[k + 1] - ys[k]) * (x - xs[k]) / (xs[k + 1] - xs[k])


class TrajectoryTracker:
    """Pure pursuit + speed P control along one trajectory; `clock()` gives the simulation time."""

    def __init__(self, trajectory: Trajectory, clock: Callable[[], float], model: VehicleModel | None = None) -> None:
        self.traj = trajectory
        self.clock = clock
        self.model = model or VehicleModel.of()  # the bicycle it steers (pure pursuit of its rear axle)
        tr = trajectory
        # each segment k: start (x, y), direction (dx, dy), squared length
        self._seg = [(x0, y0, x1 - x0, y1 - y0, max((x1 - x0) ** 2 + (y1 - y0) ** 2, 1e-12))
                     for x0, y0, x1, y1 in zip(tr.x, tr.y, tr.x[1:], tr.y[1:])]
        s = [0.0]
        for x0, y0, x1, y1 in zip(tr.x, tr.y, tr.x[1:], tr.y[1:]):
            s.append(s[-1] + math.hypot(x1 - x0, y1 - y0))
        self.s = s  # arc length at each point

    def _point_at(self, s: float) -> tuple[float, float]:
        s = min(max(s, 0.0), self.s[-1])
        return _interp(s, self.s, self.traj.x), _interp(s, self.s, self.traj.y)

    def _project(self, px: float, py: float) -> float:
        """Arc length of the trajectory point nearest (px, py) (the first of equals)."""
        best, s_best = math.inf, 0.0
        for k, (x0, y0, dx, dy, L2) in enumerate(self._seg):
            u = min(max(((px - x0) * dx + (py - y0) * dy) / L2, 0.0), 1.0)
            d2 = (x0 + dx * u - px) ** 2 + (y0 + dy * u - py) ** 2
            if d2 < best:
                best, s_best = d2, self.s[k] + u * math.sqrt(L2)
        return s_best

    def command(self, position: Sequence[float], heading: float, speed: float) -> dict[str, float]:
        """{"acceleration", "steering"} for a vehicle at this pose and speed, now."""
        tr = self.traj
        t = self.clock()
        v_ref = _interp(t + TRACKING_PREVIEW_S, tr.t, tr.speed)
        a_ff = 0.0
        if len(tr.t) > 1 and tr.t[0] <= t <= tr.t[-1]:
            k = min(max(bisect.bisect_left(tr.t, t) - 1, 0), len(tr.t) - 2)
            a_ff = (tr.speed[k + 1] - tr.speed[k]) / (tr.t[k + 1] - tr.t[k])
        px, py = float(position[0]), float(position[1])
        s_ego = self._project(px, py)
        s_ref = _interp(t, tr.t, self.s)
        lo, hi = bisect.bisect_left(tr.t, t), bisect.bisect_right(tr.t, t + TRACKING_HOLD_WINDOW_S)
        v_ahead = max(v_ref, max(tr.speed[lo:hi], default=0.0))
        if v_ahead < TRACKING_STOP_SPEED_MPS and (t >= tr.t[-1] or s_ego >= s_ref - 0.5):  # asked to stay
            acc = -TRACKING_SPEED_GAIN * max(speed, 0.0) - (2.0 if speed > 0.05 else 0.0)
        else:
            acc = a_ff + TRACKING_SPEED_GAIN * (v_ref - speed) + TRACKING_POSITION_GAIN * (s_ref - s_ego)
        lookahead = TRACKING_LOOKAHEAD_MIN_M + TRACKING_LOOKAHEAD_TIME_S * max(speed, 0.0)
        if self.s[-1] > 0:
            tx, ty = self._point_at(s_ego + lookahead)
            extra = s_ego + lookahead - self.s[-1]  # beyond the end: continue along the last heading
        else:
            (tx, ty), extra = (px, py), lookahead
        if extra > 0:
            tx, ty = tx + extra * math.cos(tr.heading[-1]), ty + extra * math.sin(tr.heading[-1])
        steering = pursuit_steering(px, py, float(heading), tx, ty, self.model)
        lo_acc, hi_acc = TRACKING_ACCEL_RANGE
        return {"acceleration": min(max(acc, lo_acc), hi_acc), "steering": steering}
