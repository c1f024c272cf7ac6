"""Junction feature extraction from any HD map model (paper Sec. III-C).

Arms are found by clustering the outward headings of the lanes that enter and leave the
junction area (not by road ids, which real maps cut into pieces); an arm's socket runs from
the junction polygon's centroid to the mean of its lane end points. Control is `signal` if a
signal governs a lane entering the junction, else `stop` if a stop sign does, else `bare`;
a crosswalk counts when it lies in or touches the junction area.
"""
from __future__ import annotations

import math
import warnings
from dataclasses import dataclass
from typing import Iterable, Sequence

import numpy as np
from shapely import STRtree
from shapely.geometry import Polygon

from .features import FeatureSpace, JunctionFeature, Socket, normalize_rotation
from .model import HDMap, Lane

ARM_CLUSTER_DEG = 12.0  # lane headings of one arm differ by less than this; generated arms are >= 20 apart
MIN_EXTRACTED_SEPARATION_DEG = 1.0  # real maps may have legs much closer than generated ones


@dataclass(frozen=True)
class Arm:
    angle_deg: float  # absolute socket angle
    point: tuple[float, float]
    lanes_in: int
    lanes_out: int


@dataclass(frozen=True)
class ExtractedJunction:
    """One junction's measured feature; `arms` in absolute angles, in feature (normalized) order."""

    map_name: str
    id: str
    feature: JunctionFeature
    center: tuple[float, float]
    arms: tuple[Arm, ...]

    def to_dict(self) -> dict:
        return {"map": self.map_name, "id": self.id, "n_roads": self.feature.n_roads,
                "rotation": [round(a, 4) for a in self.feature.rotation], "control": self.feature.control,
                "crosswalk": self.feature.crosswalk, "lanes_in": [s.lanes_in for s in self.feature.sockets],
                "lanes_out": [s.lanes_out for s in self.feature.sockets]}


def _circular_clusters(angles: np.ndarray, tol_deg: float) -> np.ndarray:
    """Cluster labels for angles (degrees) split at gaps wider than `tol_deg`, on the circle."""
    order = np.argsort(angles)
    a = angles[order]
    gaps = np.diff(np.append(a, a[0] + 360.0))
    labels = np.zeros(len(a), dtype=int)
    if len(a) == 1 or gaps.max() <= tol_deg:
        return labels[np.argsort(order)]
    start = int(np.argmax(gaps)) + 1  # begin after the widest gap so no cluster wraps
    lab = 0
    for k in range(len(a)):
        i = (start + k) % len(a)
        if k > 0 and gaps[(i - 1) % len(a)] > tol_deg:
            lab += 1
        labels[i] = lab
    out = np.empty_like(labels)
    out[order] = labels
    return out


def _arms(m: HDMap, lanes: Sequence[Lane], center: np.ndarray) -> list[Arm]:
    """Arms from the end points of the junction's lanes; headings from the road lanes that
    feed and leave them where there are any (junction lanes turn sharply)."""
    def entry_heading(ln: Lane) -> float:
        preds = [m.lanes[p] for p in ln.predecessors if m.lanes[p].junction_id is None]
        return (preds[0].heading_at_end() if preds else ln.heading_at_start()) + math.pi

    def exit_heading(ln: Lane) -> float:
        succs = [m.lanes[s] for s in ln.successors if m.lanes[s].junction_id is None]
        return succs[0].heading_at_start() if succs else ln.heading_at_end()

    ends: dict[tuple[float, float], tuple[tuple[float, float], float, str]] = {}
    for ln in lanes:  # entry points (outward = against travel) and exit points, each once
        ends.setdefault((round(ln.start[0], 3), round(ln.start[1], 3)), (ln.start, entry_heading(ln), "in"))
        ends.setdefault((round(ln.end[0], 3), round(ln.end[1], 3)), (ln.end, exit_heading(ln), "out"))
    pts = np.array([v[0] for v in ends.values()])
    kinds = [v[2] for v in ends.values()]
    heads = np.degrees(np.array([v[1] for v in ends.values()])) % 360.0
    labels = _circular_clusters(heads, ARM_CLUSTER_DEG)
    arms = []
    for lab in np.unique(labels):
        idx = np.flatnonzero(labels == lab)
        p = pts[idx].mean(axis=0)
        ang = math.degrees(math.atan2(p[1] - center[1], p[0] - center[0]))
        arms.append(Arm(ang, (float(p[0]), float(p[1])), sum(kinds[i] == "in" for i in idx),
                        sum(kinds[i] == "out" for i in idx)))
    return arms


def extract_junctions(m: HDMap, map_name: str = "map") -> list[ExtractedJunction]:
    """The junction feature of every junction that has lanes and at least 3 arms."""
    by_junction = m.lanes_by_junction
    xw_polys = [Polygon(c.polygon) for c in m.crosswalks.values() if len(c.polygon) >= 3]
    xw_tree = STRtree(xw_polys) if xw_polys else None
    xw_junctions = {c.junction_id for c in m.crosswalks.values() if c.junction_id}
    controls: dict[str, set[str]] = {}
    lane_controls: dict[str, set[str]] = {}
    for kind, items in (("signal", m.signals), ("stop", m.stop_signs)):
        for s in items.values():
            if s.junction_id:
                controls.setdefault(s.junction_id, set()).add(kind)
            for lid in s.lane_ids:
                lane_controls.setdefault(lid, set()).add(kind)
    out = []
    for jid, j in m.junctions.items():
        lanes = by_junction.get(jid, [])
        if not lanes or len(j.polygon) < 3:
            warnings.warn(f"junction {jid}: no lanes or no polygon, skipped", stacklevel=2)
            continue
        poly = Polygon(j.polygon)
        c = np.array(j.center)
        arms = _arms(m, lanes, c)
        if len(arms) < 3:
            continue
        norm = normalize_rotation([a.angle_deg for a in arms])
        arms = [arms[i] for i in norm.order]
        kinds = set(controls.get(jid, set()))
        for ln in lanes:
            kinds |= lane_controls.get(ln.id, set())
            for p in ln.predecessors:
                kinds |= lane_controls.get(p, set())
        control = "signal" if "signal" in kinds else "stop" if "stop" in kinds else "bare"
        crosswalk = jid in xw_junctions or (
            xw_tree is not None and len(xw_tree.query(poly, predicate="intersects")) > 0)
        feature = JunctionFeature(
            tuple(Socket(a, arm.lanes_in, arm.lanes_out) for a, arm in zip(norm.angles, arms)),
            control, crosswalk, MIN_EXTRACTED_SEPARATION_DEG)
        out.append(ExtractedJunction(map_name, jid, feature, (float(c[0]), float(c[1])), tuple(arms)))
    return out


def map_feature(junctions: Iterable[ExtractedJunction | JunctionFeature]) -> FeatureSpace:
    """The map feature of one or several maps: union of discrete values, per-n angle ranges."""
    return FeatureSpace.from_features(j.feature if isinstance(j, ExtractedJunction) else j for j in junctions)
