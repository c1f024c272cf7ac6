"""A polyline lane on highway-env's `AbstractLane`: exact, vectorised projection.

highway-env's `PolyLane` precomputes widths in O(L^2) and `PolyLaneFixedWidth` projects with a
Python loop; this lane projects a point on all segments at once with numpy. The polyline *is*
the lane geometry (maps sample their Bézier lanes every couple of metres), so coordinates are
exact for it: `position(*local_coordinates(p)) == p` for points beside the lane, and the first
and last segments extend beyond the ends so longitudinal coordinates run below 0 and past
`length` as highway-env expects.
"""
from __future__ import annotations

import bisect
import math
from typing import Any

import numpy as np
from highway_env.road.lane import AbstractLane, LineType

from ..angles import wrap_angle
from ..config import CURVE_MIN_SPEED_MPS, CURVE_WINDOW_M, FOLD_SEGMENT_M, FOLD_TURN_DEG, LATERAL_ACCEL_MPS2


def unfold(pts: np.ndarray) -> np.ndarray:
    """`pts` without the vertices where the polyline folds back on itself (consecutive segments
    turning more than FOLD_TURN_DEG, one of them shorter than FOLD_SEGMENT_M), repeatedly: the
    inner lane of a curve tighter than the lane's offset from its reference line is drawn with a
    cusp (Issue295a's 995_0_-1 turns back 0.4 m at its apex), where projections jump and the ego
    tracking the lane lost it. A turn drawn with long segments is kept as drawn."""
    limit = math.cos(math.radians(FOLD_TURN_DEG))
    while len(pts) > 2:
        d = np.diff(pts, axis=0)
        n = np.maximum(np.hypot(*d.T), 1e-12)
        u = d / n[:, None]
        cos = np.einsum("ij,ij->i", u[:-1], u[1:])
        bad = np.nonzero((cos < limit) & (np.minimum(n[:-1], n[1:]) < FOLD_SEGMENT_M))[0]
        if not len(bad):
            break
        pts = np.delete(pts, bad[0] + 1, axis=0)
    return pts


class PolylineLane(AbstractLane):
    """A lane whose centreline is a polyline (highway-env frame: y down), constant width."""

    curve_speed: np.ndarray | None = None  # `curve_speeds(self)`, made on first use

    def __init__(self, points: np.ndarray, width: float = 3.5, line_types=(LineType.NONE, LineType.NONE),
                 forbidden: bool = False, speed_limit: float = 20.0, priority: int = 0,
                 lane_id: str = "") -> None:
        pts = np.asarray(points, dtype=float)
        keep = np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-9])
        pts = unfold(pts[keep])
        if len(pts) < 2:
            raise ValueError(f"lane {lane_id!r} needs at least two distinct points")
        self.points = pts
        self.a = pts[:-1]
        d = np.diff(pts, axis=0)
        self.seg_len = np.hypot(d[:, 0], d[:, 1])
        self.u = d / self.seg_len[:, None]
        self.cum = np.concatenate([[0.0], np.cumsum(self.seg_len)])
        self.length = float(self.cum[-1])
        self.seg_heading = np.arctan2(self.u[:, 1], self.u[:, 0])
        # vertex headings (mean of adjacent segments) for a continuous heading_at
        hv = np.empty(len(pts))
        hv[0], hv[-1] = self.seg_heading[0], self.seg_heading[-1]
        if len(pts) > 2:
            s = self.u[:-1] + self.u[1:]
            hv[1:-1] = np.arctan2(s[:, 1], s[:, 0])
        self.vertex_heading = np.unwrap(hv)
        self.width = float(width)
        self.line_types = list(line_types)
        self.forbidden = forbidden
        self.speed_limit = speed_limit
        self.priority = priority
        self.lane_id = lane_id
        self.bbox = (*pts.min(axis=0), *pts.max(axis=0))
        self._n = len(self.seg_len)
        self._ax, self._ay = self.a[:, 0].copy(), self.a[:, 1].copy()
        self._ux, self._uy = self.u[:, 0].copy(), self.u[:, 1].copy()
        self._lo = np.zeros(self._n)
        self._hi = self.seg_len.copy()
        self._lo[0] = -np.inf  # the first segment extends backwards, the last one forwards
        self._hi[-1] = np.inf

    _LISTS = {"_uxl": "_ux", "_uyl": "_uy", "_cuml": "cum", "_axl": "_ax", "_ayl": "_ay", "_vh": "vertex_heading"}

    def __getattr__(self, name: str):
        """Python-list copies of the arrays for scalar lookups, made on first use: a big map's
        lanes mostly never see one, and the lists cost more memory than the arrays."""
        source = PolylineLane._LISTS.get(name)
        if source is None:
            raise AttributeError(name)
        value = getattr(self, source).tolist()
        setattr(self, name, value)
        return value

    def _segment(self, s: float) -> int:
        i = bisect.bisect_right(self._cuml, float(s)) - 1
        return min(max(i, 0), self._n - 1)

    def position(self, longitudinal: float, lateral: float) -> np.ndarray:
        i = self._segment(longitudinal)
        ux, uy = self._uxl[i], self._uyl[i]
        ds = longitudinal - self._cuml[i]
        return np.array([self._axl[i] + ds * ux - lateral * uy, self._ayl[i] + ds * uy + lateral * ux])

    def local_coordinates(self, position: np.ndarray) -> tuple[float, float]:
        x, y = float(position[0]), float(position[1])
        rx = x - self._ax
        ry = y - self._ay
        t = rx * self._ux + ry * self._uy
        tc = np.minimum(np.maximum(t, self._lo), self._hi)
        dx = rx - tc * self._ux
        dy = ry - tc * self._uy
        i = int((dx * dx + dy * dy).argmin())
        lat = self._uxl[i] * float(ry[i]) - self._uyl[i] * float(rx[i])
        return self._cuml[i] + float(tc[i]), lat

    def heading_at(self, longitudinal: float) -> float:
        s = min(max(float(longitudinal), 0.0), self.length)
        i = bisect.bisect_right(self._cuml, s) - 1
        if i >= self._n:
            return self._vh[-1]
        f = (s - self._cuml[i]) / self._cuml_len(i)
        return self._vh[i] + f * (self._vh[i + 1] - self._vh[i])

    def _cuml_len(self, i: int) -> float:
        return self._cuml[i + 1] - self._cuml[i]

    def width_at(self, longitudinal: float) -> float:
        return self.width

    def on_lane(self, position, longitudinal=None, lateral=None, margin=0) -> bool:
        if longitudinal is None or lateral is None:
            longitudinal, lateral = self.local_coordinates(position)
        return (abs(lateral) <= self.width / 2 + margin
                and -self.VEHICLE_LENGTH <= longitudinal < self.length + self.VEHICLE_LENGTH)

    @classmethod
    def from_config(cls, config: dict) -> "PolylineLane":
        return cls(np.asarray(config["points"]), config.get("width", 3.5), config.get("line_types", (0, 0)),
                   config.get("forbidden", False), config.get("speed_limit", 20.0), config.get("priority", 0),
                   config.get("lane_id", ""))

    def to_config(self) -> dict:
        return {"class_path": f"{__name__}.PolylineLane", "config": {
            "points": self.points.tolist(), "width": self.width, "line_types": list(self.line_types),
            "forbidden": self.forbidden, "speed_limit": self.speed_limit, "priority": self.priority,
            "lane_id": self.lane_id}}

    def __repr__(self) -> str:
        return f"PolylineLane({self.lane_id!r}, length={self.length:.1f})"


def curve_speeds(lane: PolylineLane) -> np.ndarray:
    """The comfortable speed at each vertex of `lane` (at `lane.cum`): sqrt(LATERAL_ACCEL_MPS2 /
    curvature), never below CURVE_MIN_SPEED_MPS. Curvature is the turn between the chords over
    the CURVE_WINDOW_M around each vertex (kept inside the lane), so polyline kinks and zig-zags
    of read maps do not read as sharp curves. Computed once per lane (the lane is fixed once
    built); the one curve rule of traffic (envs/core.py) and the baseline planner."""
    if lane.curve_speed is not None:
        return lane.curve_speed
    s = lane.cum
    w = min(CURVE_WINDOW_M, float(s[-1]))
    mid = np.clip(s, w / 2, s[-1] - w / 2)
    a, b, c = (centre_points(lane, xs) for xs in (mid - w / 2, mid, mid + w / 2))
    h1 = np.arctan2(*(b - a).T[::-1])
    h2 = np.arctan2(*(c - b).T[::-1])
    turn = np.abs(wrap_angle(h2 - h1))
    speed = np.maximum(np.sqrt(LATERAL_ACCEL_MPS2 * (w / 2) / np.maximum(turn, 1e-6)), CURVE_MIN_SPEED_MPS)
    lane.curve_speed = speed
    return speed


def centre_points(lane: PolylineLane, s: np.ndarray) -> np.ndarray:
    """[len(s), 2]: `lane.position(x, 0.0)` of each x in `s`, with the same arithmetic."""
    i = np.minimum(np.maximum(np.searchsorted(lane.cum, s, side="right") - 1, 0), lane._n - 1)
    ds = s - lane.cum[i]
    return np.stack([lane._ax[i] + ds * lane._ux[i] - 0.0 * lane._uy[i],
                     lane._ay[i] + ds * lane._uy[i] + 0.0 * lane._ux[i]], axis=1)


SIMILAR_SEGMENTS = 1.5  # lanes whose segment counts are within this factor are projected in one program
PADDING_LIMIT = 1.3  # ... unless padding all of them to the longest costs at most this factor of the work
PROJECT_BLOCK = 40_000  # (lane, point, segment) elements a program's temporaries hold at once: they stay in cache


def segment_table(lanes: list) -> tuple[np.ndarray, ...]:
    """(first segment, segment count, then ax, ay, ux, uy, lo, hi, cum per segment) of `lanes`'
    projection arrays, concatenated (built once per network: `project_rows`)."""
    count = np.array([len(ln._ax) for ln in lanes], dtype=np.int64)
    first = np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64)
    cat = [np.concatenate([getattr(ln, a) for ln in lanes]) for a in ("_ax", "_ay", "_ux", "_uy", "_lo", "_hi")]
    cum = np.concatenate([ln.cum[:len(ln._ax)] for ln in lanes])
    return (first, count, *cat, cum)


def project_rows(table: tuple[np.ndarray, ...], lanes: np.ndarray, x: np.ndarray,
                 y: np.ndarray, lateral: bool = True) -> tuple[np.ndarray, Any]:
    """`PolylineLane.local_coordinates` of points x[g, :], y[g, :] on lane lanes[g] (indices into
    the lanes of `table`, a `segment_table`), for all g with the same arithmetic: (s, lateral),
    each [lanes, points] (lateral None unless `lateral`). One program, the segments padded to the
    longest lane's (padding never wins); where that would more than PADDING_LIMIT-fold the work,
    one program per group of lanes of similar segment counts (within SIMILAR_SEGMENTS)."""
    if len(lanes) == 1:
        return _project_block(table, lanes, x, y, lateral)
    count = table[1][lanes]
    longest = int(count.max())
    if len(lanes) * longest <= PADDING_LIMIT * count.sum():
        return _project_group(table, lanes, x, y, lateral, longest)
    s_out, r_out = np.empty(x.shape), np.empty(x.shape)
    order = np.argsort(count, kind="stable")
    c = count[order]
    start = 0
    while start < len(order):
        end = int(np.searchsorted(c, SIMILAR_SEGMENTS * c[start], side="right"))
        g = order[start:end]
        s_g, r_g = _project_group(table, lanes[g], x[g], y[g], lateral, int(c[end - 1]))
        s_out[g] = s_g
        if lateral:
            r_out[g] = r_g
        start = end
    return s_out, r_out if lateral else None


def _project_group(table: tuple[np.ndarray, ...], lanes: np.ndarray, x: np.ndarray,
                   y: np.ndarray, lateral: bool, longest: int) -> tuple[np.ndarray, np.ndarray | None]:
    """`project_rows` of one group of lanes (the longest has `longest` segments): one program
    per block of lanes whose padded [lanes, points, segments] arrays hold at most PROJECT_BLOCK
    elements (big temporaries leave the cache: 256 observers' 16 points on lanes of 35 segments
    ran 2.8x faster in blocks)."""
    step = max(1, PROJECT_BLOCK // max(x.shape[1] * longest, 1))
    if len(lanes) <= step:
        return _project_block(table, lanes, x, y, lateral)
    s_out, r_out = np.empty(x.shape), np.empty(x.shape) if lateral else None
    for a in range(0, len(lanes), step):
        s_b, r_b = _project_block(table, lanes[a:a + step], x[a:a + step], y[a:a + step], lateral)
        s_out[a:a + step] = s_b
        if r_out is not None:
            r_out[a:a + step] = r_b
    return s_out, r_out


def _project_block(table: tuple[np.ndarray, ...], lanes: np.ndarray, x: np.ndarray,
                   y: np.ndarray, lateral: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """`project_rows` of one block of lanes: one program, in place where the arrays are big."""
    first, count, ax, ay, ux, uy, lo, hi, cum = table
    if len(lanes) == 1:  # one lane: its segments are a slice (no gathers)
        seg = slice(int(first[lanes[0]]), int(first[lanes[0]] + count[lanes[0]]))
        rx = x[0][:, None] - ax[seg]
        ry = y[0][:, None] - ay[seg]
        t = rx * ux[seg] + ry * uy[seg]
        tc = np.minimum(np.maximum(t, lo[seg]), hi[seg])
        dx = rx - tc * ux[seg]
        dy = ry - tc * uy[seg]
        i = (dx * dx + dy * dy).argmin(axis=1)
        p = np.arange(len(i))
        return ((cum[seg][i] + tc[p, i])[None], (ux[seg][i] * ry[p, i] - uy[seg][i] * rx[p, i])[None])
    n = count[lanes]
    S = int(n.max())
    j = np.arange(S)
    real = j[None, :] < n[:, None]
    at = np.where(real, first[lanes][:, None] + j[None, :], first[lanes][:, None])
    ux, uy, cum = ux[at], uy[at], cum[at]  # [lanes, S]
    ax, ay, lo, hi, uxs, uys = (a[:, None, :] for a in (ax[at], ay[at], lo[at], hi[at], ux, uy))
    rx = x[:, :, None] - ax
    ry = y[:, :, None] - ay
    tc = rx * uxs  # the same operations as `local_coordinates`, in place ([lanes, points, S] arrays)
    tmp = ry * uys
    tc += tmp
    np.maximum(tc, lo, out=tc)
    np.minimum(tc, hi, out=tc)
    dx = np.subtract(rx, np.multiply(tc, uxs, out=tmp), out=None if lateral else rx)
    dy = np.subtract(ry, np.multiply(tc, uys, out=tmp), out=tmp)
    dx *= dx
    dy *= dy
    dx += dy
    np.copyto(dx, np.inf, where=~real[:, None, :])
    i = dx.argmin(axis=2)  # [lanes, points]: the nearest segment
    g, p = np.arange(len(lanes))[:, None], np.arange(x.shape[1])[None, :]
    s = cum[g, i] + tc[g, p, i]
    return s, (ux[g, i] * ry[g, p, i] - uy[g, i] * rx[g, p, i]) if lateral else None
