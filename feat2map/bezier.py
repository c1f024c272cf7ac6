"""Cubic Bézier curves (paper eqs. 1-2): control points, evaluation, arc-length sampling."""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property

import numpy as np

Point = tuple[float, float]
_DENSE = 64  # samples used to tabulate arc length
_T_DENSE = np.linspace(0.0, 1.0, _DENSE + 1)


@dataclass(frozen=True)
class Bezier:
    """A cubic Bézier curve given by its four control points P0..P3."""

    p0: Point
    p1: Point
    p2: Point
    p3: Point

    @classmethod
    def from_poses(cls, start: Point, start_heading: float, end: Point, end_heading: float) -> "Bezier":
        """Paper eq. 2: P1/P2 pushed along the end headings by d0 = d1 = half the chord."""
        d = 0.5 * math.hypot(end[0] - start[0], end[1] - start[1])
        return cls(
            (float(start[0]), float(start[1])),
            (start[0] + d * math.cos(start_heading), start[1] + d * math.sin(start_heading)),
            (end[0] - d * math.cos(end_heading), end[1] - d * math.sin(end_heading)),
            (float(end[0]), float(end[1])),
        )

    @cached_property
    def control(self) -> np.ndarray:
        return np.array([self.p0, self.p1, self.p2, self.p3], dtype=float)

    @cached_property
    def _power(self) -> np.ndarray:
        """Power-basis coefficients a0..a3 with B(t) = a0 + a1 t + a2 t^2 + a3 t^3."""
        c = self.control
        return np.array([c[0], 3 * (c[1] - c[0]), 3 * (c[2] - 2 * c[1] + c[0]), c[3] - 3 * c[2] + 3 * c[1] - c[0]])

    def point(self, t: np.ndarray | float) -> np.ndarray:
        """B(t) for scalar or array t in [0, 1]; shape (..., 2)."""
        t = np.asarray(t, dtype=float)[..., None]
        a = self._power
        return a[0] + t * (a[1] + t * (a[2] + t * a[3]))

    def derivative(self, t: np.ndarray | float) -> np.ndarray:
        t = np.asarray(t, dtype=float)[..., None]
        a = self._power
        return a[1] + t * (2 * a[2] + t * 3 * a[3])

    def heading(self, t: np.ndarray | float) -> np.ndarray:
        d = self.derivative(t)
        return np.arctan2(d[..., 1], d[..., 0])

    def offset_point(self, t: np.ndarray | float, offset: float) -> np.ndarray:
        """The true offset curve: B(t) moved `offset` metres along its left unit normal."""
        return self.offset_points(t, (offset,))[0]

    def offset_points(self, t: np.ndarray | float, offsets: tuple[float, ...]) -> list[np.ndarray]:
        """`offset_point` for several offsets, evaluating the curve and its normals once."""
        d = self.derivative(t)
        n = np.stack([-d[..., 1], d[..., 0]], axis=-1)
        p = self.point(t)
        norm = np.maximum(np.hypot(n[..., 0], n[..., 1]), 1e-12)[..., None]
        return [p + offset * n / norm for offset in offsets]

    @cached_property
    def _arc(self) -> tuple[np.ndarray, np.ndarray]:
        pts = self.point(_T_DENSE)
        d = np.diff(pts, axis=0)
        s = np.concatenate([[0.0], np.cumsum(np.sqrt((d * d).sum(axis=1)))])
        return _T_DENSE, s

    @property
    def length(self) -> float:
        return float(self._arc[1][-1])

    def param_at(self, s: float) -> float:
        """The parameter t at arc length `s` from the start (clamped to the curve)."""
        t, arc = self._arc
        return float(np.interp(s, arc, t))

    def sample_params(self, spacing: float) -> np.ndarray:
        """Parameters t of points at (nearly) equal arc-length spacing, t=0 and t=1 included."""
        t, s = self._arc
        k = max(2, int(math.ceil(s[-1] / spacing)) + 1)
        stop = float(s[-1])
        step = stop / (k - 1)  # np.linspace(0, stop, k), the same floats without its overhead
        grid = np.arange(k, dtype=float) * step if step != 0 else np.zeros(k)
        grid[-1] = stop
        ts = np.interp(grid, s, t)
        ts[0], ts[-1] = 0.0, 1.0
        return ts

    def sample(self, spacing: float) -> np.ndarray:
        """Points at (nearly) equal arc-length spacing, end points exact; shape (k, 2), k >= 2."""
        return self.point(self.sample_params(spacing))


def polyline_length(points: np.ndarray) -> float:
    return float(np.hypot(*np.diff(np.asarray(points, dtype=float), axis=0).T).sum())


def unit(angle: float) -> np.ndarray:
    return np.array([math.cos(angle), math.sin(angle)])


def left_normal(angle: float) -> np.ndarray:
    return np.array([-math.sin(angle), math.cos(angle)])
