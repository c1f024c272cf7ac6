"""Criticality of one rollout, measured at every decision: the smallest time-to-collision and
distance to another road user, the hardest braking, the time blocked and the red margin (the
surrogate safety measures the search is guided by, scenarios/search.py), and where the drive
failed (the junction, its feature and the ego's manoeuvre there, for failure signatures).

The red margin is how close the ego's arrival at the next signal's stop line, at its current
speed, comes to that signal turning red (within RED_MARGIN_RANGE_M of a line, moving, on green or
amber): the dilemma zone, where a late stop or a run through the red happen.

Time-to-collision is the gap over the closing speed of each vehicle or pedestrian within
TTC_RANGE_M of the ego, at constant velocities (the gap: the widest separation of the two bodies
along their four axes, so a car in the next lane is its lateral clearance away); a road user that
is not closing in has none. Capped values (TTC_CAP_S, DISTANCE_CAP_M) keep every number
finite, so outcomes stay JSON and compare equal.
"""
from __future__ import annotations

import math
from typing import Any, Mapping

import numpy as np

from feat2map.config import (BRAKE_CAP_MPS2, DISTANCE_CAP_M, RED_MARGIN_CAP_S, RED_MARGIN_RANGE_M, TTC_CAP_S,
                             TTC_RANGE_M)

MEASURES = ("min_ttc_s", "min_distance_m", "max_brake_mps2", "blocked_s", "red_margin_s")


class CriticalityMeter:
    """Fed the env after every decision (`update`); `values()` the measures, `site()` where the
    drive failed: the first violation's step, else the last step."""

    def __init__(self) -> None:
        self.min_ttc = TTC_CAP_S
        self.min_distance = DISTANCE_CAP_M
        self.max_brake = 0.0
        self.blocked = 0.0
        self.red_margin = RED_MARGIN_CAP_S
        self._last: tuple[float, float] | None = None  # (time, speed) of the previous decision
        self._site: dict[str, Any] = {}
        self._violation_site: dict[str, Any] = {}

    def update(self, env: Any, info: Mapping[str, Any], blocked_s: float = 0.0) -> None:
        """One decision's measures from the env's road users and its info."""
        u = env.unwrapped
        ego = u.vehicle
        t, v = float(info.get("time", 0.0)), float(info.get("speed", 0.0))
        if self._last is not None and t > self._last[0]:
            self.max_brake = max(self.max_brake, (self._last[1] - v) / (t - self._last[0]))
        self._last = (t, v)
        self.blocked = max(self.blocked, float(blocked_s))
        others = [o for o in (*u.road.vehicles, *u.road.objects) if o is not ego]
        if others:
            pos = np.array([o.position for o in others], dtype=float)
            vel = np.array([o.velocity for o in others], dtype=float)
            rel = pos - np.asarray(ego.position, dtype=float)
            rng = np.hypot(rel[:, 0], rel[:, 1])
            near = rng <= TTC_RANGE_M
            if near.any():
                size = np.array([(float(getattr(o, "LENGTH", 0.0)), float(getattr(o, "WIDTH", 0.0)), float(o.heading))
                                 for o, n in zip(others, near) if n]).reshape(-1, 3)
                gap = _gaps(rel[near], size, (float(ego.LENGTH), float(ego.WIDTH), float(ego.heading)))
                self.min_distance = min(self.min_distance, float(gap.min()))
                closing = -np.einsum("ij,ij->i", rel[near], vel[near] - np.asarray(ego.velocity, dtype=float))
                closing = closing / np.maximum(rng[near], 1e-6)
                ttc = np.where(closing > 1e-6, gap / np.maximum(closing, 1e-6), math.inf)
                self.min_ttc = min(self.min_ttc, float(ttc.min()))
        if v > 0.5:
            self.red_margin = min(self.red_margin, _red_margin(u.control, ego, t, v))
        self._site = _site(info)
        if info.get("new_violations") and not self._violation_site:
            self._violation_site = dict(self._site, rule=str(info["new_violations"][0]))

    def values(self) -> dict[str, float]:
        """The measures, rounded (they are compared across runs of the same seed)."""
        return {"min_ttc_s": round(self.min_ttc, 4), "min_distance_m": round(self.min_distance, 4),
                "max_brake_mps2": round(self.max_brake, 4), "blocked_s": round(self.blocked, 4),
                "red_margin_s": round(self.red_margin, 4)}

    def site(self) -> dict[str, Any]:
        """Where the drive failed: the first violation's junction, else the last step's."""
        return dict(self._violation_site or self._site)


def _gaps(rel: np.ndarray, size: np.ndarray, ego: tuple[float, float, float]) -> np.ndarray:
    """The gap between the ego's body and each other body (`rel` [n, 2] their centres from the
    ego's, `size` [n, 3] their length, width, heading): the widest separation along the four axes
    of the two rectangles (separating axes; 0 where they overlap). A car in the next lane is its
    lateral clearance away, not its centre distance less both half lengths."""
    length, width, heading = ego
    best = np.zeros(len(rel))
    for axis in (np.full(len(rel), heading), np.full(len(rel), heading + np.pi / 2), size[:, 2], size[:, 2] + np.pi / 2):
        along = np.abs(rel[:, 0] * np.cos(axis) + rel[:, 1] * np.sin(axis))
        reach = (np.abs(size[:, 0] / 2 * np.cos(size[:, 2] - axis)) + np.abs(size[:, 1] / 2 * np.sin(size[:, 2] - axis))
                 + np.abs(length / 2 * np.cos(heading - axis)) + np.abs(width / 2 * np.sin(heading - axis)))
        best = np.maximum(best, along - reach)
    return best


def _red_margin(control: Any, ego: Any, t: float, speed: float) -> float:
    """|time until the next signal turns red - time the ego needs to reach its line| (seconds;
    RED_MARGIN_CAP_S where no signal line is within RED_MARGIN_RANGE_M or it shows red)."""
    line, _, _, d = control.line_ahead(ego, RED_MARGIN_RANGE_M)
    plan = control.plans.get(line.control_id) if line is not None and line.kind == "signal" else None
    if plan is None:
        return RED_MARGIN_CAP_S
    state = plan.state(line.control_id, t)
    if state == "red":
        return RED_MARGIN_CAP_S
    to_red = plan.time_to_change(line.control_id, t) + (plan.amber if state == "green" else 0.0)
    return min(abs(to_red - max(d, 0.0) / speed), RED_MARGIN_CAP_S)


def _site(info: Mapping[str, Any]) -> dict[str, Any]:
    """The junction the ego is in or heads for, its feature (rotation left out: signatures are
    about kinds of junction) and the ego's manoeuvre there."""
    f = info.get("junction_feature") or {}
    lanes_in = [int(x) for x in np.asarray(f.get("lanes_in", ()), dtype=int) if x >= 0]
    lanes_out = [int(x) for x in np.asarray(f.get("lanes_out", ()), dtype=int) if x >= 0]
    return {"junction": str(info.get("junction") or ""), "manoeuvre": str(info.get("manoeuvre") or ""),
            "n_roads": int(f.get("n_roads", -1)), "control": str(f.get("control") or ""),
            "crosswalk": bool(f.get("crosswalk", False)), "lanes_in": lanes_in, "lanes_out": lanes_out}


def score(values: Mapping[str, float], blocked_after: float) -> float:
    """Criticality in [0, 1]: the mean of the measures, each scaled to [0, 1] (1 the most
    critical: a time-to-collision, distance or red margin of 0, braking at BRAKE_CAP_MPS2,
    blocked the whole `blocked_after`)."""
    parts = (1 - min(values.get("min_ttc_s", TTC_CAP_S), TTC_CAP_S) / TTC_CAP_S,
             1 - min(values.get("red_margin_s", RED_MARGIN_CAP_S), RED_MARGIN_CAP_S) / RED_MARGIN_CAP_S,
             1 - min(values.get("min_distance_m", DISTANCE_CAP_M), DISTANCE_CAP_M) / DISTANCE_CAP_M,
             min(max(values.get("max_brake_mps2", 0.0), 0.0) / BRAKE_CAP_MPS2, 1.0),
             min(values.get("blocked_s", 0.0) / blocked_after, 1.0) if blocked_after > 0 else 0.0)
    return sum(parts) / len(parts)
