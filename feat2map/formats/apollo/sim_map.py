"""Apollo's sim_map (what Dreamview draws), as `modules/map/tools/sim_map_generator.cc` makes
it from a base map: lane width and road samples cleared, segment 0 of each lane's three curves
downsampled by angle, then by distance (`modules/common/util/points_downsampler.h`)."""
from __future__ import annotations

import math
from typing import Any

import numpy as np

from . import schema as aps
from ...config import (SIM_MAP_ANGLE_THRESHOLD_RAD, SIM_MAP_DOWNSAMPLE_DISTANCE_M,
                     SIM_MAP_STEEP_TURN_DOWNSAMPLE_DISTANCE_M)


def downsample_by_angle(points: np.ndarray, threshold: float = SIM_MAP_ANGLE_THRESHOLD_RAD) -> list[int]:
    """Indices kept when the direction change accumulated since the last kept point exceeds
    `threshold` (Apollo's DownsampleByAngle: segment `start` against each later segment)."""
    n = len(points)
    if n == 0:
        return []
    out = [0]
    if n > 1:
        d = np.diff(np.asarray(points, dtype=float).reshape(-1, 2), axis=0)
        dx, dy = d[:, 0].tolist(), d[:, 1].tolist()  # plain floats: this loop is the hot path
        norm = [math.hypot(x, y) for x, y in zip(dx, dy)]
        start, end, acc = 0, 1, 0.0
        while end < n - 1:
            denom = norm[start] * norm[end]
            cosv = (dx[start] * dx[end] + dy[start] * dy[end]) / denom if denom > 0 else math.nan
            acc += math.acos(cosv) if -1.0 <= cosv <= 1.0 else 0.0  # acos out of range: NaN -> 0
            if acc > threshold:
                out.append(end)
                start, acc = end, 0.0
            end += 1
        out.append(end)
    return out


def downsample_by_distance(points: np.ndarray, distance: float = SIM_MAP_DOWNSAMPLE_DISTANCE_M,
                           steep_distance: float = SIM_MAP_STEEP_TURN_DOWNSAMPLE_DISTANCE_M) -> list[int]:
    """Indices kept every `distance` metres (`steep_distance` when the curve turns by 90 degrees
    or more end to end); first and last always; 4 points or fewer are kept whole."""
    n = len(points)
    if n <= 4:
        return list(range(n))
    p = np.asarray(points, dtype=float).reshape(-1, 2)
    v0, v1 = p[1] - p[0], p[-1] - p[-2]
    step = steep_distance if float(v0 @ v1) <= 0 else distance
    seg = np.hypot(*np.diff(p, axis=0).T).tolist()
    out, acc = [0], 0.0
    for pos in range(1, n - 1):
        acc += seg[pos - 1]
        if acc > step:
            out.append(pos)
            acc = 0.0
    out.append(n - 1)
    return out


def _downsample_curve(curve: Any) -> None:
    if not curve.segment:
        return
    pts_field = curve.segment[0].line_segment.point
    pts = [(p.x, p.y, p.z) for p in pts_field]
    xy = np.asarray([(p[0], p[1]) for p in pts], dtype=float).reshape(-1, 2)
    by_angle = downsample_by_angle(xy)
    first = [pts[i] for i in by_angle]
    keep = downsample_by_distance(xy[by_angle])
    del pts_field[:]
    for i in keep:
        x, y, z = first[i]
        p = pts_field.add()
        p.x, p.y = x, y
        if z:
            p.z = z


def to_sim_map(base: Any) -> Any:
    """Apollo's sim_map: lane width and road samples cleared, segment 0 of each lane's three
    curves downsampled by angle (1 degree) then distance (5 m, 1 m on steep turns)."""
    sim = aps.Map()
    sim.CopyFrom(base)
    for lane in sim.lane:
        for field in ("left_sample", "right_sample", "left_road_sample", "right_road_sample"):
            lane.ClearField(field)
        _downsample_curve(lane.central_curve)
        _downsample_curve(lane.left_boundary.curve)
        _downsample_curve(lane.right_boundary.curve)
    return sim
