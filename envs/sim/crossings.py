"""The pedestrians on the crosswalks across lanes, seen from those lanes, for many questions at
once: where a road user stops for them (the yield rule, `blocking`: the rules' one
`pedestrian_blocking`, and the traffic core's answer for every row whose first stop is a
crosswalk with people) and who is in a road user's path (`walkers`, which the judge reads).

A question is (slot, lane); the lane's crossings (`MapNetwork.crossings`: crosswalk, s0, s1) are a
table by lane, built once per network (`CrossingTable`), and the walkers on a crosswalk are the
walker rows (`TrafficCore.p_*`) of that (slot, crosswalk), joined by key (one sort of the walkers
a call): no lane is scanned but the questions' own.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import PEDESTRIAN_CORRIDOR_M
from ..lanes import project_rows
from ..network import MapNetwork
from ..rules import on_yield_stretch, pedestrian_in_path
from .join import member, same_key_pairs
from .pedestrians import crosswalks

if TYPE_CHECKING:
    from ..core import TrafficCore

NEAR_CROSSING_M = 2.0  # a walker counts for a crossing within this far beyond its ends along the lane
STOP_BEFORE_M = 1.0  # a road user yielding stops this far before the crossing
BEHIND_M = 0.5  # a crossing whose start is this far behind where the question starts still counts


@dataclass(frozen=True)
class CrossingTable:
    """Per lane (`MapNetwork.lane_ids` order) its crossings `start[lane]` up to
    `start[lane] + count[lane]` in `cw` (the crosswalk, `pedestrians.crosswalks` index), `s0`,
    `s1` (where the lane crosses it)."""
    start: np.ndarray
    count: np.ndarray
    cw: np.ndarray
    s0: np.ndarray
    s1: np.ndarray


def crossing_table(net: MapNetwork) -> CrossingTable:
    """The crossing table of `net` (a memo of the network's)."""
    def build() -> CrossingTable:
        index = crosswalks(net).index
        rows = [net.crossings.get(lid, ()) for lid in net.lane_ids]
        count = np.array([len(r) for r in rows], dtype=np.int64)
        flat = [c for r in rows for c in r]
        return CrossingTable(np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64), count,
                             np.array([index[cw] for cw, _, _ in flat], dtype=np.int64),
                             np.array([s0 for _, s0, _ in flat], dtype=float),
                             np.array([s1 for _, _, s1 in flat], dtype=float))
    return net.memo("crossing table", build)


def _crossings_of(t: CrossingTable, lanes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (question, crossing into `t`) of questions on `lanes`."""
    n = t.count[lanes]
    q = np.arange(len(lanes)).repeat(n)
    return q, t.start[lanes].repeat(n) + np.arange(int(n.sum())) - (np.cumsum(n) - n).repeat(n)


def _crosswalk_key(core: "TrafficCore", slots: np.ndarray, cws: np.ndarray) -> np.ndarray:
    """One int per (slot, crosswalk) pair: how questions meet the walkers of their slot."""
    return slots * len(core.crosswalks.ids) + cws


def walkers(core: "TrafficCore", slots: np.ndarray, lanes: np.ndarray) -> tuple[np.ndarray, ...]:
    """Every (question, crossing, walker) of questions (slots[q], lanes[q]): a walker of the slot
    on a crosswalk across the lane, with its place seen from the lane (`PolylineLane.
    local_coordinates`' arithmetic): (q, crossing (into the table), walker row, s, lateral)."""
    net = core.net
    t = crossing_table(net)
    q, c = _crossings_of(t, lanes)
    if not len(q) or not len(core.p_env):
        empty = np.zeros(0, dtype=np.int64)
        return empty, empty, empty, np.zeros(0), np.zeros(0)
    a, w = same_key_pairs(_crosswalk_key(core, slots[q], t.cw[c]), _crosswalk_key(core, core.p_env, core.p_cw))
    q, c = q[a], c[a]
    if not len(q):
        return q, c, w, np.zeros(0), np.zeros(0)
    table = net.segment_table()
    if len(lanes) == 1:  # one lane: its walkers are the points of one projection
        s, lat = project_rows(table, lanes, core.p_x[w][None, :], core.p_y[w][None, :])
        return q, c, w, s[0], lat[0]
    s, lat = project_rows(table, lanes[q], core.p_x[w][:, None], core.p_y[w][:, None])
    return q, c, w, s[:, 0], lat[:, 0]


def blocking(core: "TrafficCore", slots: np.ndarray, lanes: np.ndarray, s_from: np.ndarray) -> np.ndarray:
    """Per question (slot, lane, s_from): the s on the lane to stop at for a pedestrian in its
    path on a crosswalk across it that begins beyond s_from (within BEHIND_M), inf where none: a
    walker within NEAR_CROSSING_M of the crossing along the lane, in the path
    (`rules.pedestrian_in_path`) or walking towards it within PEDESTRIAN_CORRIDOR_M of the
    lane's edge, holds it STOP_BEFORE_M before the crossing."""
    out = np.full(len(lanes), np.inf)
    q, c, w, sp, rp = walkers(core, slots, lanes)
    if not len(q):
        return out
    t = crossing_table(core.net)
    lane, s0, s1 = lanes[q], t.s0[c], t.s1[c]
    width = core.table.width[lane]
    h = core.table.heading_at(lane, sp)  # (the lane's heading there: `LaneTable`'s)
    towards = rp * (core.p_ux[w] * -np.sin(h) + core.p_uy[w] * np.cos(h)) < 0
    hit = (s0 >= s_from[q] - BEHIND_M) & (s0 - NEAR_CROSSING_M <= sp) & (sp <= s1 + NEAR_CROSSING_M) & \
        (pedestrian_in_path(rp, width) | towards & (np.abs(rp) < width / 2 + PEDESTRIAN_CORRIDOR_M))
    np.minimum.at(out, q[hit], s0[hit] - STOP_BEFORE_M)
    return out


def peopled_stretch(core: "TrafficCore", slots: np.ndarray, lanes: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Per question (slot, lane, s): whether s lies on a crossing's stretch of the lane, widened by
    PEDESTRIAN_YIELD_STRETCH_M each way, of a crosswalk with a walker of the slot on it: the only
    places the judge's pedestrian check can find anything (`TrafficCore.judge_due`)."""
    out = np.zeros(len(lanes), dtype=bool)
    if not len(core.p_env):
        return out
    t = crossing_table(core.net)
    q, c = _crossings_of(t, lanes)
    on = on_yield_stretch(s[q], t.s0[c], t.s1[c]) & \
        member(_crosswalk_key(core, slots[q], t.cw[c]), _crosswalk_key(core, core.p_env, core.p_cw))
    out[q[on]] = True
    return out
