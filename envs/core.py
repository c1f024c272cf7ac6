"""The traffic core: all traffic advanced together in NumPy arrays, highway-env objects only as
views for whoever reads them.

Design
------
State. One row per road user, in `road.vehicles` order: `lane` (an int, the index into
`MapNetwork.lane_ids`), `s` (arc length along it), `lat` (lateral offset: 0 on the lane centre,
non-zero only while a MOBIL lane change settles), `speed`, `acc`, `timer`, `crashed`, and the
derived `x`, `y`, `heading`. Traffic rows and controlled rows (the ego of the single and
batched envs, the multi-agent env's agents: views in controlled.py) are "driven" (the core moves
them); any other highway-env vehicle user code adds is an "external" row: it acts and steps
itself and its state is read back into its row every frame. A driven row's route is a list of lane
ints and a position in it; `W`/`C` (rows x K) hold its next K route lanes and the distance from
the start of its current lane to the start of each, rebuilt for a row only when its route
position changes.

Geometry. `LaneTable` (built once per network, cached on it) concatenates every lane's polyline:
a position is a `searchsorted` on the global cumulative arc length and one multiply-add, a
heading an interpolation of vertex headings, for all rows at once; traffic is never projected.

A frame (`MapRoad.act` + `MapRoad.step`):
1. sync: the vehicles of each road whose list changed since (`road.VehicleList` notes the
   change) are compared by identity with the rows; vehicles user code appended are taken in (a
   `TrafficVehicle` becomes a driven row), removed ones let go.
2. external rows act (a controlled row's decision is already in its row: `ControlledRow.act`).
3. traffic accelerations: IDM's free term for all rows; leaders from one (rows x K x rows) test
   of every row's lane against every row's window (on the same lane the leader's s is its row's
   s; a controlled row is on the lane it is located on, an external one at its exact place),
   plus rows on junction lanes that conflict with or diverge from a window lane, or on road
   lanes converging with one (found through one boolean matrix per junction or group of
   converging lanes; their s and offset on the window lane from a table sampled once per lane
   pair; converging lanes zip: `MapNetwork.zip_leader`); IDM per (follower, leader) pair (a stop
   point the rules impose is a standing leader) and the minimum per follower
   (`rules.idm_accelerations`, which one vehicle's IDM, `rules.idm`, calls too). The same leader
   search answers a controlled row's `leader_gaps` (its slot's rows only) and MOBIL's current
   lane. Where the rules can stop each row is one scan of every row's window
   (`sim.rule_scan`: junction entries, road lanes across junction lanes, mid-block lights,
   crosswalks with people on them, up to the first road after the next entry with room to
   wait); every row with a stop on its scan asks the rules (signals, stop signs, reservations,
   pedestrians) against the state the frame began with, the arrays answering a row held at a
   signal and a junction entry's conflicts (`sim.entries`), and the rows whose answer
   takes something then claim (`control.TrafficControl.claim`, the rules' one update) in row
   order, so that reservations are claimed in road order. MOBIL runs every MOBIL_PERIOD_S for
   rows `rules.may_change_lane` allows on lanes with same-direction neighbours, all at once
   (`sim/mobil.py`), the changes then taken in row order.
4. integration: s += v dt, v += a dt (never below 0), route lanes advance as s passes their ends;
   controlled rows drive the kinematic bicycle (`sim.vehicle`), steered by lane keeping or their
   held command, all at once, their (s, lat) projected on their route lanes and each located
   (`locate`); external rows step themselves.
5. positions of traffic rows from the lane table; pedestrians (walker rows) walk (`walk`);
   every slot's stop-sign queues, pedestrians stepping out or letting go (`sim.pedestrians`)
   and the reservations to look at (`release_looks`) are brought up to date at once, and every
   slot's clocks (`clock`, `moves`); then `TrafficControl.bookkeeping` does the rest of the
   rules' bookkeeping where a road has releases to look at or the map has passages; collisions: a
   vectorized centre-distance broad phase, separating
   axes for pairs of driven rows, and highway-env's own `handle_collisions` for the pairs that
   overlap or involve an external road user or a pedestrian (crash flags, hits; a driven row
   takes no impact displacement).

Objects. Every driven row has a view, `ArrayVehicle` (a `TrafficVehicle` whose state attributes
are properties reading its row, positions computed on read), so that highway-env's observation
types, the renderer, the rules and user code see ordinary vehicles; nothing is copied per frame.

The traffic model, where it differs from highway-env's own vehicles:
- traffic follows its lane centre exactly (no steering controller, no corner cutting), speed is
  along the lane, and a lane change is a lateral offset on the new lane that decays with
  LANE_CHANGE_TAU_S instead of a steered manoeuvre;
- a traffic vehicle is on its route lane until its centre passes the lane's end (never located
  by projection);
- a crashed traffic vehicle brakes to a stop in place (no impact displacement).
"""
from __future__ import annotations

import contextlib
import math
from collections import deque
from types import SimpleNamespace
from typing import TYPE_CHECKING, Any, Callable, Iterable, Iterator

import numpy as np

from ..config import (CURVE_BEHIND_M, CURVE_BRAKE_MPS2, CURVE_MIN_SPEED_MPS, IDM_GAP_M, IDM_STOP_GAP_M,
                      LANE_CHANGE_TAU_S, LANE_KEEPING_TAU_S, LOOKAHEAD_M, MOBIL_PERIOD_S, OFF_ROAD_LATERAL_M, PAIR_SAMPLE_M,
                      PASSAGE_HORIZON_M, PEDESTRIAN_YIELD_SPEED_MPS, PRIORITY_MARGIN_M, STOP_POINT_M)
from ..invariants import lane_changes
from . import task
from .control import no_plans, signal_arrays, signal_timing
from .info_columns import RouteFacts
from .lanes import centre_points, curve_speeds, project_rows
from .network import LINE_SIGNAL, LINE_STOP_SIGN, MapNetwork, on_lane
from .rules import (CROSSED, ENTRY, JUDGED, PEOPLE, SIGNAL_STATES, Claims, body_reach, commits, crossed_lanes, has_stopped,
                    held_at_signal, idm_accelerations, in_the_way, may_change_lane, stop_gap)
from .sim import crossings, entries, judge, mobil, passages, pedestrians, rule_scan, stop_signs
from .sim.join import same_key_pairs
from .reservations import LEFT, NONE, Reservations
from .sim.vehicle import FLOATS, VehicleModel, integrate, keeping_steering, speed_control
from .vehicles import Pedestrian, TrafficVehicle, route_finished, route_upcoming

if TYPE_CHECKING:
    from .road import MapRoad

EXTERNAL, DRIVEN = 0, 1
BATCH_MIN_DRIVEN = 4  # controlled rows (`TrafficCore.drive`: fewer drive one by one with floats)
# rows the rules are asked of (`TrafficCore._rule_stops`) from which the arrays answer a signal's
# hold and a junction entry before the rows ask one by one (fewer: each asks the rules; the
# same values)
SETTLE_MIN_ROWS = 24
# how long before a signal's next change its states are worked out again (`signal_timing`: the
# states held until then are those worked out anew, whatever the rounding)
SIGNAL_EDGE_S = 1e-6
# live reservations up to which a frame's releases look at every one (`release_looks`: the
# filter costs more than a few looks; the same releases)
LOOK_ALL_MAX = 12
ROW_SPARE = 1.5  # a row array's buffer holds this many times its rows when it grows (`_append_rows`)
WINDOWS_HELD = 65536  # windows kept by lane sequence and body length (`TrafficCore._window`; more: begun anew)
PROJECT_SEGMENTS = 3  # segments either side of a controlled row's last place that it is projected on
# a row's values where its kind leaves them unset: a traffic row has no bicycle and no commands
ROW_DEFAULTS = {"lat": 0.0, "acc": 0.0, "timer": 0.0, "mobil_t": -1e9, "crashed": False, "wheelbase": 0.0,
                "rear_offset": 0.0, "max_steer": 0.0, "steer": 0.0, "entry": math.inf, "controlled": False,
                "command": 0.0, "cmd_steer": 0.0, "keeps": True, "target": math.nan, "at_lane": -1, "at_s": 0.0,
                "at_lat": 0.0, "stop_junction": -1, "stop_seq": 0, "stop_at": math.inf, "reserved": NONE,
                "scan_len": 0, "route_ver": 0, "seen_pos": -1, "seen_lane": -2, "seen_route": -1,
                "res_count": 0, "judged": -1, "progress": 0.0, "goal": 0.0, "goal_dist": 0.0, "behind": 0.0,
                "goal_s": 0.0, "task_key": -1, "info_key": -1, "fact": -1, "violations": 0,
                "new_violations": 0, "off_road": False, "passage_d": math.inf, "passage_key": -1, "j_done": True,
                "j_arrives": False, "j_agent": False, "j_lane": -1, "j_s": 0.0, "v_lane": -1, "v_clear": True,
                "v_order": True}


class LaneTable:
    """Every lane of a network as flat arrays: lengths, widths, speed limits, junction flags, and
    the concatenated polylines (global cumulative arc length `G`, segment starts and unit
    directions, vertex headings), so that positions of many (lane, s) pairs are one lookup."""

    def __init__(self, net: MapNetwork) -> None:
        m = net.hdmap
        lanes = [net.lane_of[lid] for lid in net.lane_ids]
        self.net = net
        self.index = {lid: k for k, lid in enumerate(net.lane_ids)}
        self.length = np.array([ln.length for ln in lanes])
        self.width = np.array([ln.width for ln in lanes])
        self.speed_limit = np.maximum(np.array([ln.speed_limit for ln in lanes], dtype=float), 1.0)
        self.junction = np.array([m.lanes[lid].junction_id is not None for lid in net.lane_ids])
        self.crossing = np.array([lid in net.crossings for lid in net.lane_ids])
        self.passage = np.array([lid in net.passages for lid in net.lane_ids], dtype=bool)
        self.crossed = np.array([bool(crossed_lanes(net, lid)) for lid in net.lane_ids], dtype=bool)
        self.midblock = np.array([lid in net.midblock_lines for lid in net.lane_ids], dtype=bool)  # a crossing's light
        self.neighbours = np.array([bool(lane_changes(m.lanes[lid])) for lid in net.lane_ids])  # across a dashed line
        npts = np.array([len(ln.points) for ln in lanes])
        self.first = np.concatenate([[0], np.cumsum(npts)[:-1]])  # index of each lane's first point
        self.last_seg = self.first + npts - 2  # index of each lane's last segment start
        offset = np.concatenate([[0.0], np.cumsum(self.length + 1.0)[:-1]])
        self.offset = offset
        self.G = np.concatenate([o + ln.cum for o, ln in zip(offset, lanes)])
        pts = np.concatenate([ln.points for ln in lanes])
        u = np.zeros_like(pts)
        for f, ln in zip(self.first, lanes):
            u[f:f + len(ln.u)] = ln.u
        self.ax, self.ay = pts[:, 0].copy(), pts[:, 1].copy()
        self.ux, self.uy = u[:, 0].copy(), u[:, 1].copy()
        self.vh = np.concatenate([ln.vertex_heading for ln in lanes])
        # each segment's length, what a projection clamps along it to (beyond the lane's ends on
        # its first and last segments: `PolylineLane`'s `_lo`, `_hi`), and what `heading_at`
        # interpolates over
        seg_len = self.G[1:] - self.G[:-1]
        self.seg_lo = np.zeros(len(seg_len))
        self.seg_lo[self.first] = -math.inf
        self.seg_hi = seg_len.copy()
        self.seg_hi[self.last_seg] = math.inf
        self.seg_div = np.maximum(seg_len, 1e-12)
        self.vh_step = self.vh[1:] - self.vh[:-1]
        # curves: at each vertex the least of v_c^2 + 2 b s over it and the lane's later vertices
        # (v_c its `curve_speeds`, s its arc length on its lane, b CURVE_BRAKE_MPS2), so that the
        # speed a vehicle at s may have to brake to every curve ahead on the lane is
        # sqrt(curve_q[next vertex] - 2 b s), one lookup (`TrafficCore.curve_limit`)
        q = [np.minimum.accumulate((curve_speeds(ln) ** 2 + 2 * CURVE_BRAKE_MPS2 * ln.cum)[::-1])[::-1]
             for ln in lanes]
        self.curve_q = np.concatenate(q)
        self.last_vertex = self.first + npts - 1
        # junction lanes that conflict with or diverge from each other, per junction as a dense
        # matrix (the relation never leaves a junction): near[joff[j] + a * jsize[j] + b]
        self.jid = np.full(len(lanes), -1, dtype=np.int64)
        self.jloc = np.zeros(len(lanes), dtype=np.int64)
        # (and road lanes that converge, `MapNetwork.merges`, grouped the same way: one group per
        # set of road lanes linked by such pairs)
        members: dict[object, list[int]] = {}
        merge_group: dict[str, int] = {}
        for lid in sorted(net.merges):
            if lid in merge_group:
                continue
            stack, merge_group[lid] = [lid], len(merge_group)
            g = merge_group[lid]
            while stack:
                for y in net.merges.get(stack.pop(), ()):
                    if y not in merge_group:
                        merge_group[y] = g
                        stack.append(y)
        for k, lid in enumerate(net.lane_ids):
            jid = m.lanes[lid].junction_id
            if jid is not None:
                members.setdefault(jid, []).append(k)
            elif lid in merge_group:
                members.setdefault(("merge", merge_group[lid]), []).append(k)
        self.jsize = np.array([len(v) for v in members.values()], dtype=np.int64)
        self.joff = np.concatenate([[0], np.cumsum(self.jsize ** 2)[:-1]]).astype(np.int64)
        self.near = np.zeros(int((self.jsize ** 2).sum()), dtype=bool)
        for j, ks in enumerate(members.values()):
            self.jid[ks] = j
            self.jloc[ks] = np.arange(len(ks))
        for k, lid in enumerate(net.lane_ids):
            j = self.jid[k]
            if j < 0:
                continue
            for x in net.near_lanes(lid):
                b = self.index.get(x, -1)
                if b >= 0 and self.jid[b] == j:
                    self.near[self.joff[j] + self.jloc[k] * self.jsize[j] + self.jloc[b]] = True
        self.crosswalk_lanes: dict[str, list[int]] = {}  # crosswalk -> the lanes crossing it
        for lid, across in net.crossings.items():
            for cw, _, _ in across:
                self.crosswalk_lanes.setdefault(cw, []).append(self.index[lid])
        # stop lines by incoming lane: kind (0 none, LINE_SIGNAL, LINE_STOP_SIGN), signal (index into
        # signal_ids), and how far before the lane's end the line lies (rules.line_setback)
        self.signal_ids = list(m.signals)
        sig = self.signal_index = {sid: k for k, sid in enumerate(self.signal_ids)}
        self.line_kind = np.zeros(len(lanes), dtype=np.int8)
        self.line_signal = np.full(len(lanes), -1, dtype=np.int64)
        self.line_setback = np.zeros(len(lanes))
        for lid, sl in net.stop_lines.items():
            k = self.index[lid]
            self.line_kind[k] = LINE_SIGNAL if sl.kind == "signal" else LINE_STOP_SIGN
            self.line_signal[k] = sig.get(sl.control_id, -1) if sl.kind == "signal" else -1
        for lid, back in net.setbacks.items():  # stop lines and bare entries alike (rules.line_setback)
            self.line_setback[self.index[lid]] = back
        self.stop_sign_lanes = frozenset(np.flatnonzero(self.line_kind == LINE_STOP_SIGN).tolist())
        # junctions by number (0: None, road lanes' and a stop line's outside any junction) and
        # each lane's (the stop-sign queues, `sim.stop_signs`)
        named = {ln.junction_id for ln in m.lanes.values()} | {sl.junction_id for sl in net.stop_lines.values()}
        self.junction_ids: list[str | None] = [None, *sorted(j for j in named if j is not None)]
        self.junction_number = {j: k for k, j in enumerate(self.junction_ids)}
        self.lane_junction = np.array([self.junction_number[m.lanes[lid].junction_id] for lid in net.lane_ids],
                                      dtype=np.int64)
        # lane-pair tables (`seen_from`), concatenated; the pairs by key a * lanes + b, ascending
        self.pair_key = np.zeros(0, dtype=np.int64)
        self.pair_start = np.zeros(0, dtype=np.int64)
        self.pair_count = np.zeros(0, dtype=np.int64)
        self.pair_step = np.zeros(0)
        self.pair_sa = self.pair_ra = np.zeros(0)

    def near_pairs(self, lane_a: np.ndarray, lane_b: np.ndarray) -> np.ndarray:
        """Whether junction lane b conflicts with or diverges from junction lane a, or road lane b
        converges with road lane a, elementwise (`MapNetwork.near_lanes`; False elsewhere)."""
        ja, jb = self.jid[lane_a], self.jid[lane_b]
        same = (ja >= 0) & (ja == jb)
        out = np.zeros(len(lane_a), dtype=bool)
        if same.any():
            j = ja[same]
            out[same] = self.near[self.joff[j] + self.jloc[lane_a[same]] * self.jsize[j] + self.jloc[lane_b[same]]]
        return out

    def seen_from(self, a: np.ndarray, b: np.ndarray, s_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(s along lane a, lateral offset from lane a) of the points at s_b on lanes b, from
        tables that sample each lane pair every PAIR_SAMPLE_M (built on first use; a pair is
        found by its key's place among the sorted keys, no lookup per pair)."""
        keys = a * len(self.length) + b
        at = self.pair_key.searchsorted(keys)
        missing = at >= len(self.pair_key)
        missing[~missing] = self.pair_key[at[~missing]] != keys[~missing]
        if missing.any():
            self._add_pairs(np.unique(keys[missing]))
            at = self.pair_key.searchsorted(keys)
        start, count, step = self.pair_start[at], self.pair_count[at], self.pair_step[at]
        pos = np.minimum(np.maximum(s_b / step, 0.0), count - 1)
        i = np.minimum(np.floor(pos), count - 2)
        f = pos - i
        i = (start + i).astype(np.int64)
        return (self.pair_sa[i] * (1 - f) + self.pair_sa[i + 1] * f,
                self.pair_ra[i] * (1 - f) + self.pair_ra[i + 1] * f)

    def _add_pairs(self, keys: np.ndarray) -> None:
        """Sample lane b of each new key a * lanes + b from lane a every PAIR_SAMPLE_M (each point
        `lb.position(x, 0)` seen by `la.local_coordinates`, in one program: `lanes.project_rows`),
        the keys kept sorted."""
        a, b = np.divmod(keys, len(self.length))
        count = np.maximum(2, np.ceil(self.length[b] / PAIR_SAMPLE_M).astype(np.int64) + 1)
        lanes = self.net._lanes
        x = np.zeros((len(keys), int(count.max())))  # (the padding's results are dropped)
        y = np.zeros_like(x)
        for n, (lb, c) in enumerate(zip(b.tolist(), count.tolist())):
            x[n, :c], y[n, :c] = centre_points(lanes[lb], np.linspace(0.0, self.length[lb], c)).T
        table = self.net.segment_table()
        sa, ra = project_rows(table, a, x, y)
        real = np.arange(x.shape[1])[None, :] < count[:, None]
        order = np.argsort(np.concatenate([self.pair_key, keys]), kind="stable")
        self.pair_key = np.concatenate([self.pair_key, keys])[order]
        self.pair_start = np.concatenate([self.pair_start, len(self.pair_sa) + np.cumsum(count) - count])[order]
        self.pair_count = np.concatenate([self.pair_count, count])[order]
        self.pair_step = np.concatenate([self.pair_step, self.length[b] / (count - 1)])[order]
        self.pair_sa = np.concatenate([self.pair_sa, sa[real]])
        self.pair_ra = np.concatenate([self.pair_ra, ra[real]])

    @classmethod
    def of(cls, net: MapNetwork) -> "LaneTable":
        return net.memo("lane table", lambda: cls(net))

    def segments(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        return self.segment_at(lane, self.offset[lane] + s)

    def segment_at(self, lane: np.ndarray, key: np.ndarray) -> np.ndarray:
        """The segment of each `lane` holding global arc length `key` (its offset + s), clamped
        to the lane's segments."""
        i = self.G.searchsorted(key, side="right") - 1
        return np.minimum(np.maximum(i, self.first[lane]), self.last_seg[lane])

    def project_near(self, lane: np.ndarray, s: np.ndarray, x: np.ndarray,
                     y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(s, lat, settled) of points (x, y) on `lane`s: `PolylineLane.local_coordinates`'
        arithmetic (the first and last segments extend beyond the lane's ends) over only the
        PROJECT_SEGMENTS segments either side of the one at arc length `s` (a guess: where the
        point was, moved on), so that a step never scans a whole lane. `settled` is False where
        the nearest of these is the window's last on a side with more segments: project again
        from the s found."""
        i = self.segments(lane, s)
        first, last = self.first[lane][:, None], self.last_seg[lane][:, None]
        j = np.minimum(np.maximum(i[:, None] + np.arange(-PROJECT_SEGMENTS, PROJECT_SEGMENTS + 1), first), last)
        rx, ry = x[:, None] - self.ax[j], y[:, None] - self.ay[j]
        ux, uy = self.ux[j], self.uy[j]
        t = rx * ux + ry * uy
        tc = np.minimum(np.maximum(t, self.seg_lo[j]), self.seg_hi[j])
        dx, dy = rx - tc * ux, ry - tc * uy
        k = (dx * dx + dy * dy).argmin(axis=1)
        n = np.arange(len(k))
        jk = j[n, k]
        edge = ((k == 0) & (jk > first[:, 0])) | ((k == j.shape[1] - 1) & (jk < last[:, 0]))
        return (self.G[jk] - self.offset[lane] + tc[n, k], ux[n, k] * ry[n, k] - uy[n, k] * rx[n, k], ~edge)

    # ---- the same programs for one row, with floats (a single env's ego: no array overhead; the
    # same operations in the same order, so the same values bit for bit: tests/envs/test_core.py)
    def segment_one(self, lane: int, s: float) -> int:
        i = int(self.G.searchsorted(float(self.offset[lane]) + s, side="right")) - 1
        return min(max(i, int(self.first[lane])), int(self.last_seg[lane]))

    def project_one(self, lane: int, s: float, x: float, y: float) -> tuple[float, float, bool]:
        """`project_near` of one point (over the window's distinct segments: the repeats of a
        window clamped at a lane's end never come first)."""
        i = self.segment_one(lane, s)
        first, last = int(self.first[lane]), int(self.last_seg[lane])
        lo, hi = max(i - PROJECT_SEGMENTS, first), min(i + PROJECT_SEGMENTS, last)
        G = self.G[lo:hi + 1].tolist()
        best: tuple = ()
        for n, (ax, ay, u, v, t_lo, t_hi) in enumerate(zip(*(a[lo:hi + 1].tolist() for a in (
                self.ax, self.ay, self.ux, self.uy, self.seg_lo, self.seg_hi)))):
            j = lo + n
            rx, ry = x - ax, y - ay
            t = rx * u + ry * v
            tc = min(max(t, t_lo), t_hi)
            dx, dy = rx - tc * u, ry - tc * v
            d2 = dx * dx + dy * dy
            if not best or d2 < best[0]:
                best = (d2, j, tc, rx, ry, u, v)
        _, j, tc, rx, ry, u, v = best
        edge = (j == i - PROJECT_SEGMENTS and j > first) or (j == i + PROJECT_SEGMENTS and j < last)
        return G[j - lo] - float(self.offset[lane]) + tc, u * ry - v * rx, not edge

    def heading_one(self, lane: int, s: float) -> float:
        """`heading_at` of one (lane, s)."""
        sc = min(max(s, 0.0), float(self.length[lane]))
        j = self.segment_one(lane, sc)
        return float(self.vh[j]) + (float(self.offset[lane]) + sc - float(self.G[j])) / float(self.seg_div[j]) * \
            float(self.vh_step[j])

    def place(self, lane: np.ndarray, s: np.ndarray, lat: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(x, y, lane heading) of points at (lane, s, lat); beyond a lane's ends the first and
        last segments extend, as `PolylineLane.position` does."""
        i = self.segments(lane, s)
        ds = self.offset[lane] + s - self.G[i]
        ux, uy = self.ux[i], self.uy[i]
        x = self.ax[i] + ds * ux - lat * uy
        y = self.ay[i] + ds * uy + lat * ux
        return x, y, self.heading_at(lane, s)

    def heading_at(self, lane: np.ndarray, s: np.ndarray) -> np.ndarray:
        """`PolylineLane.heading_at` of each (lane, s): vertex headings interpolated, s within the lane."""
        sc = np.minimum(np.maximum(s, 0.0), self.length[lane])
        key = self.offset[lane] + sc
        j = self.segment_at(lane, key)
        return self.vh[j] + (key - self.G[j]) / self.seg_div[j] * self.vh_step[j]

class ArrayVehicle(TrafficVehicle):
    """A traffic vehicle of the arrays core: a `TrafficVehicle` whose state (position, heading,
    speed, lane, route...) is read from and written to its row of the core. Created by the core
    (or by taking in a `TrafficVehicle` user code added to `road.vehicles`)."""

    _core: "TrafficCore"
    _row: int

    # ---- state -------------------------------------------------------------------------------
    @property
    def row(self) -> int:
        """Its row in the core's arrays (rows move when road users come and go: read it anew)."""
        return self._row

    @property
    def position(self) -> np.ndarray:
        c, i = self._core, self._row
        return np.array([c.x[i], c.y[i]])

    @position.setter
    def position(self, value) -> None:
        self._core.relocate(self._row, np.asarray(value, dtype=float))

    @property
    def heading(self) -> float:
        return float(self._core.heading[self._row])

    @heading.setter
    def heading(self, value) -> None:  # the heading follows the lane
        pass

    @property
    def speed(self) -> float:
        return float(self._core.speed[self._row])

    @speed.setter
    def speed(self, value) -> None:
        self._core.speed[self._row] = float(value)

    @property
    def crashed(self) -> bool:
        return bool(self._core.crashed[self._row])

    @crashed.setter
    def crashed(self, value) -> None:
        self._core.crashed[self._row] = bool(value)

    @property
    def timer(self) -> float:
        return float(self._core.timer[self._row])

    @timer.setter
    def timer(self, value) -> None:
        self._core.timer[self._row] = float(value)

    @property
    def action(self) -> dict:
        return {"steering": 0.0, "acceleration": float(self._core.acc[self._row])}

    @action.setter
    def action(self, value) -> None:
        pass

    @property
    def lane_index(self):
        c = self._core
        return c.net._indices[c.lane[self._row]]

    @lane_index.setter
    def lane_index(self, value) -> None:
        pass

    @property
    def lane(self):
        c = self._core
        return c.net._lanes[c.lane[self._row]]

    @lane.setter
    def lane(self, value) -> None:
        pass

    @property
    def lane_s(self) -> float:
        return float(self._core.s[self._row])

    @lane_s.setter
    def lane_s(self, value) -> None:
        pass

    @property
    def lane_lat(self) -> float:
        return float(self._core.lat[self._row])

    @lane_lat.setter
    def lane_lat(self, value) -> None:
        pass

    @property
    def lane_route(self) -> list[str]:
        return self._core.route_ids[self._row]

    @lane_route.setter
    def lane_route(self, value) -> None:
        self._core.set_route(self._row, list(value))

    @property
    def route_pos(self) -> int:
        return int(self._core.route_pos[self._row])

    @route_pos.setter
    def route_pos(self, value) -> None:
        self._core.route_pos[self._row] = int(value)
        self._core.dirty.add(self._row)

    @property
    def target_lane_index(self):
        c, i = self._core, self._row
        return c.net._indices[c.routes[i][c.route_pos[i]]]

    @target_lane_index.setter
    def target_lane_index(self, value) -> None:
        """A lane change (MOBIL): the row moves onto the target lane where it is, with the
        lateral offset that then settles."""
        c = self._core
        c.change_lane(self._row, c.table.index[c.net.id_of[value]])

    @property
    def reserved(self) -> str | None:
        k = self._core.reserved[self._row]
        return None if k < 0 else self._core.net.lane_ids[k]

    @reserved.setter
    def reserved(self, value: str | None) -> None:
        self._core.reserved[self._row] = NONE if value is None else self._core.table.index[value]

    # ---- route queries from the row (no projection) ------------------------------------------
    def route_s(self) -> float:
        return float(self._core.s[self._row])

    def route_distance_done(self) -> float:
        """Metres driven along the route (`task.route_done`, a batch of one)."""
        return float(task.route_done(self._core, self._row))

    def upcoming(self, horizon: float = LOOKAHEAD_M):
        """RouteFollower's, read straight from the row (the rules ask it of every rule row every frame)."""
        c, i = self._core, self._row
        return route_upcoming(c.net.lane_of, c.route_ids[i], int(c.route_pos[i]), float(c.s[i]), horizon)

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap, speed) of every road user in its way ahead along its route
        (`TrafficCore.leader_gaps`, traffic's leaders)."""
        return self._core.leader_gaps(self._row)

    def s_on(self, lane_id: str) -> float:
        c, i = self._core, self._row
        if c.net.lane_ids[c.lane[i]] == lane_id:
            return float(c.s[i])
        return super().s_on(lane_id)

    def act(self, action=None) -> None:  # the core drives it
        pass

    def step(self, dt: float) -> None:
        pass

    def on_state_update(self) -> None:
        pass

    def detach(self) -> None:
        """Turn back into a plain TrafficVehicle holding its last state (removed from the road)."""
        state = {k: getattr(self, k) for k in ("position", "heading", "speed", "crashed", "timer", "lane_index",
                                               "lane", "lane_s", "lane_lat", "lane_route", "route_pos",
                                               "target_lane_index", "reserved")}
        self.__class__ = TrafficVehicle
        self.__dict__.update(state)
        self.action = {"steering": 0.0, "acceleration": 0.0}


def reorder_runs(order: np.ndarray, settled: int) -> tuple | None:
    """How to make `[items[i] for i in order]` of a list in place, where the indices below
    `settled` keep their order in `order` (rows appended since a sync, put in their slots'
    places, and rows gone): (settled, the runs of the indices below `settled` that go, and each
    run of `order` that comes from above it, with its indices), for `reorder_in_place`; None
    otherwise (a new list is to be made). Runs deleted and inserted move pointers, where a copy
    of a long list touches every object in it (2.5% of a batched step at N = 256)."""
    low = order < settled
    head = order[low]
    if (head[1:] <= head[:-1]).any():
        return None
    gone = np.ones(settled, dtype=bool)
    gone[head] = False
    return settled, _runs(gone), [(a, order[a:b].tolist()) for a, b in _runs(~low)]


def reorder_in_place(items: list, runs: tuple) -> list:
    """`items` in the new order of `reorder_runs`' runs, changed in place."""
    settled, gone, come = runs
    tail = items[settled:]
    del items[settled:]
    for a, b in reversed(gone):
        del items[a:b]
    for a, idx in come:  # (ascending: each run's place is final once the ones before it are)
        items[a:a] = [tail[k - settled] for k in idx]
    return items


def _runs(mask: np.ndarray) -> list[tuple[int, int]]:
    """[(start, end)] of the runs of True in `mask`."""
    edge = np.diff(mask.astype(np.int8), prepend=0, append=0)
    return list(zip(np.flatnonzero(edge == 1).tolist(), np.flatnonzero(edge == -1).tolist()))


class TrafficCore:
    """The rows of the road users of one or more roads (one per sub-env of a batch, `slots` of
    them, all on one map) and the batched frame (see the module docstring)."""

    def __init__(self, net: MapNetwork, slots: int = 1) -> None:
        self.net = net
        self.table = LaneTable.of(self.net)
        self.roads: list[Any] = [None] * slots  # the road of each slot (sub-env)
        self.seen: list[list[Any]] = [[] for _ in range(slots)]  # each road's vehicles at its last sync
        self.edited: set[int] = set()  # the slots whose road's vehicles changed since (`road.VehicleList`)
        self.recording = False  # whether a road attached records its vehicles' history (highway-env's trajectories)
        self.stepped = np.ones(slots, dtype=bool)  # the slots being stepped (this frame)
        # each slot's clocks: its rules' time (`TrafficControl.t`, seconds into its episode) and
        # how often its rows moved, came or went (the rules' lane buckets are made again when it
        # changed: `TrafficControl.buckets`)
        self.clock = np.zeros(slots)
        self.moves = np.zeros(slots, dtype=np.int64)
        self.on = np.zeros(0, dtype=bool)  # their rows
        self._all_on = self.on
        self._external: list[int] = []  # the external rows (`_masks`)
        self._acting: list[int] = []  # those being stepped this frame (`act`)
        self.objs: list[Any] = []
        self._settled = 0  # the rows before this one are in the order the last sync left (`reorder_runs`)
        # the rows by slot and where each slot's end among them (`slot_rows`), None: to be found again
        self._slot_rows: tuple[np.ndarray, np.ndarray] | None = None
        self.layout = 0  # counts the changes of which road user each row is (rows came, went or moved)
        self.env = np.zeros(0, dtype=np.int64)  # the slot of each row
        self.kind = np.zeros(0, dtype=np.int8)
        self.lane = np.zeros(0, dtype=np.int64)
        self.s = np.zeros(0)
        self.lat = np.zeros(0)
        self.speed = np.zeros(0)
        self.acc = np.zeros(0)
        self.timer = np.zeros(0)
        self.mobil_t = np.zeros(0)
        self.crashed = np.zeros(0, dtype=bool)
        self.x = np.zeros(0)
        self.y = np.zeros(0)
        self.heading = np.zeros(0)
        self.length = np.zeros(0)
        self.width = np.zeros(0)
        # the bicycle of controlled rows (`sim.vehicle`; 0 for the others): wheelbase, the
        # rear axle's distance behind the centre, the steering limit and the last steering
        self.wheelbase = np.zeros(0)
        self.rear_offset = np.zeros(0)
        self.max_steer = np.zeros(0)
        self.steer = np.zeros(0)
        self.route_pos = np.zeros(0, dtype=np.int64)
        self.route_end = np.zeros(0, dtype=np.int64)  # index of the route's last lane
        self.entry = np.zeros(0)  # distance from the current lane's start to the next junction entry (inf: none in the window)
        self.driven = np.zeros(0, dtype=bool)
        self.max_reach = np.zeros(0)  # (`_masks`)
        # controlled rows (the egos, the agents): driven rows that take their command (no IDM, no
        # MOBIL, no rule stops) and drive the bicycle (`drive`); their lane, s and lat are
        # projections on their route lanes
        self.controlled = np.zeros(0, dtype=bool)
        self.command = np.zeros(0)
        # a controlled row's command (`ControlledRow.act` writes it at a decision, a tracker every
        # frame): `target` a speed to hold by speed control (NaN: `command` is the acceleration),
        # `keeps` steering by lane keeping on the route lane (else `cmd_steer`, held)
        self.target = np.zeros(0)
        self.keeps = np.zeros(0, dtype=bool)
        self.cmd_steer = np.zeros(0)
        # where a controlled row is (`MapNetwork.locate` with its route lane as the hint: another
        # lane where it steers off its route), what its judge and the rules' lane buckets read
        self.at_lane = np.zeros(0, dtype=np.int64)
        self.at_s = np.zeros(0)
        self.at_lat = np.zeros(0)
        self.judged = np.zeros(0, dtype=np.int64)  # the lane its judge last looked at it on (`judge_due`; -1 not yet)
        # its judge's verdicts (`rules.EgoJudge`): counts of each kind of `rules.JUDGED` this
        # episode and this policy step, and whether it left the road
        self.violations = np.zeros((0, len(JUDGED)), dtype=np.int64)
        self.new_violations = np.zeros((0, len(JUDGED)), dtype=np.int64)
        self.off_road = np.zeros(0, dtype=bool)
        # what its judge keeps to find more (`sim.judge`): whether it is done (a row without a
        # judge is), stops at the route's end, judges an agent's violations too; the lane and s it
        # last looked at the row on; its sets (`judge.SETS`, -1: empty); an agent's verdict on the
        # junction lane ahead (`multi_agent.AgentJudge.note`: the lane, -1 none; clear; in order)
        self.j_done, self.j_arrives, self.j_agent = (np.zeros(0, dtype=bool) for _ in range(3))
        self.j_lane, self.j_s = np.zeros(0, dtype=np.int64), np.zeros(0)
        self.j_stop, self.j_cross, self.j_mid, self.j_ped = (np.zeros((0, 2), dtype=np.int64) for _ in range(4))
        self.v_lane, self.v_clear, self.v_order = np.zeros(0, dtype=np.int64), np.zeros(0, dtype=bool), np.zeros(0, dtype=bool)
        self.rtor = np.zeros(slots, dtype=bool)  # each slot's config allows a right turn on red after a full stop
        # a controlled row's task (`task`): route metres at the last reward and to the goal, the
        # config's goal distance; the route metres behind its route position and the goal's s on
        # its last lane, as of `task_key` (its route version and position then)
        self.progress, self.goal, self.goal_dist = np.zeros(0), np.zeros(0), np.zeros(0)
        self.behind, self.goal_s = np.zeros(0), np.zeros(0)
        self.task_key = np.zeros(0, dtype=np.int64)
        # route metres from its route lane's start to the first narrow passage on its route (inf:
        # none within PASSAGE_HORIZON_M), as of `passage_key` (`_passages_ahead`)
        self.passage_d = np.zeros(0)
        self.passage_key = np.zeros(0, dtype=np.int64)
        # its info's route facts (`info_columns`): the index of its fact as of `info_key`
        self.info_key = np.zeros(0, dtype=np.int64)
        self.fact = np.zeros(0, dtype=np.int64)
        self.route_facts = RouteFacts(self)
        self.lane_names = np.array(net.lane_ids, dtype=object)  # lane int -> map lane id
        # stop-sign order (`sim.stop_signs`): the junction (`LaneTable.junction_ids`) whose stop
        # sign's queue a row is in (-1 none) and its place (the order of joining: `stop_count`
        # counts joins, `queued` the rows in a queue); a slot's `queue_version` changes with its
        # queues, whose views (`queue_views`) are then made again
        self.stop_junction = np.zeros(0, dtype=np.int64)
        self.stop_seq = np.zeros(0, dtype=np.int64)
        self.stop_count = 0
        self.queued = 0
        # where the first stop sign's line of the row's window lies, from its current lane's start
        # (`refresh_windows`; inf: none)
        self.stop_at = np.zeros(0)
        self.scan_len = np.zeros(0, dtype=np.int64)
        self.queue_version = np.zeros(slots, dtype=np.int64)
        self.queue_views: dict[int, tuple[int, dict]] = {}
        # the signals (`LaneTable.signal_ids`): each slot's phase plans (`control.signal_arrays` of
        # its road's control, written when a road is attached) and their states as last worked
        # out (`_time_signals`: each slot's clock then, codes, seconds to each change, the slot's
        # next change less SIGNAL_EDGE_S); a slot attached since is worked out at its next look
        signals = len(self.table.signal_ids)
        self._plans = np.repeat(no_plans(signals)[None], slots, axis=0)
        self._plans_new = np.ones(slots, dtype=bool)
        self._signals_timed = (np.zeros(slots), np.zeros((slots, signals), dtype=np.int8), np.zeros((slots, signals)),
                               np.full(slots, -math.inf))
        # what the rules read of the rows while they are `asking` (`asked`), made when first asked;
        # None otherwise
        self._asking: dict | None = None
        self._observing: tuple | None = None  # (row places, scans, leader gaps) while envs observe (`observing`)
        # walkers (crosswalk pedestrians, `vehicles.Pedestrian` their views) of every slot: place,
        # walking direction, speed and metres left to the crosswalk's far end
        self.p_env = np.zeros(0, dtype=np.int64)
        self.p_cw = np.zeros(0, dtype=np.int64)  # the crosswalk (`crosswalks` index)
        self.p_x, self.p_y, self.p_ux, self.p_uy = np.zeros(0), np.zeros(0), np.zeros(0), np.zeros(0)
        self.p_speed, self.p_left = np.zeros(0), np.zeros(0)
        self.p_objs: list[Any] = []
        # where they step out (`sim.pedestrians`): each slot's active crosswalks (-1 padded) and the
        # frame someone is due to step out on each, the slot's key and frame counter of draws
        # (`sim.random`), the chance a frame that someone steps out on a crosswalk, its room
        self.crosswalks = pedestrians.crosswalks(net)
        self.cw_of = np.full((slots, 0), -1, dtype=np.int64)
        self.ped_due = np.full((slots, 0), np.inf)
        self.ped_key = np.zeros(slots, dtype=np.uint64)
        self.ped_frame = np.zeros(slots, dtype=np.int64)
        self.ped_chance = np.zeros(slots)
        self.ped_max = np.zeros(slots, dtype=np.int64)
        self.routes: list[list[int]] = []  # lane ints
        self.route_ids: list[list[str]] = []  # the same routes as lane ids (what views hand out)
        # junction reservations (`reservations`: `res[slot, lane]` the holder's row, `res_seq` the
        # order they were taken in; `Reservations` is a slot's view) and each row's `reserved`
        # lane (the one it claimed, -1 none)
        self.reserved = np.zeros(0, dtype=np.int64)
        self.res_count = np.zeros(0, dtype=np.int64)  # the reservations each row holds
        self.res = np.full((slots, len(self.table.length)), NONE, dtype=np.int32)
        self.res_seq = np.zeros(self.res.shape, dtype=np.int64)
        self._res_taken = 0
        # what the releases last looked at (`release_looks`): per slot the last reservation taken
        # then, per row its route position, lane and route (`route_ver` counts its routes)
        self.res_looked = np.zeros(slots, dtype=np.int64)
        self.seen_stale = np.ones(slots, dtype=bool)  # a slot whose holders' places are not noted
        self.route_ver = np.zeros(0, dtype=np.int64)
        self.seen_pos, self.seen_lane, self.seen_route = (np.zeros(0, dtype=np.int64) for _ in range(3))
        self.dirty: set[int] = set()
        self._windows: dict[tuple, tuple] = {}  # `_window`'s, by (lanes, body length)
        self._spare: dict[str, tuple[np.ndarray, np.ndarray]] = {}  # row array -> (its buffer, the array): `_append_rows`
        self.W = np.full((0, 1), -1, dtype=np.int64)  # window lanes
        self.C = np.zeros((0, 1))  # distance from the current lane's start to each window lane's start
        # the rules' scan along the window (`sim.rule_scan`), what of it holds while the route
        # position does: what can stop the row on each window lane up to where the scan ends
        # (bits, `rules.ENTRY`...; a crosswalk's people are asked each frame), and how many window
        # lanes the scan reaches (`scan_len`)
        self.scan_what = np.zeros((0, 1), dtype=np.int8)
        # the narrow passages' places taken (`sim.passages`), an entry per (row, passage group) in
        # use: the sides the row holds (bits), the side it waits from (-1 none) and since when,
        # the sides before which it took a place to wait (bits)
        self.pe_row = np.zeros(0, dtype=np.int64)
        self.pe_group = np.zeros(0, dtype=np.int64)
        self.pe_hold = np.zeros(0, dtype=np.int8)
        self.pe_wait = np.zeros(0, dtype=np.int8)
        self.pe_since = np.zeros(0)
        self.pe_room = np.zeros(0, dtype=np.int8)

    # ---- rows --------------------------------------------------------------------------------
    _ARRAYS = ("env", "kind", "lane", "s", "lat", "speed", "acc", "timer", "mobil_t", "crashed", "x", "y", "heading",
               "length", "width", "wheelbase", "rear_offset", "max_steer", "steer", "route_pos", "route_end",
               "entry", "controlled", "command", "target", "keeps", "cmd_steer", "at_lane", "at_s", "at_lat",
               "stop_junction", "stop_seq", "stop_at", "reserved", "scan_len", "route_ver", "seen_pos",
               "seen_lane", "seen_route", "res_count", "judged", "progress", "goal", "goal_dist", "behind",
               "goal_s", "task_key", "info_key", "fact", "violations", "new_violations", "off_road", "passage_d",
               "passage_key", "j_done", "j_arrives", "j_agent", "j_lane", "j_s", "v_lane", "v_clear", "v_order")
    # row arrays with a column per window lane or set member (a judge's sets), and a new row's value in each
    _WIDE_ARRAYS = {"W": -1, "C": 0.0, "scan_what": 0, "j_stop": -1, "j_cross": -1, "j_mid": -1, "j_ped": -1}
    _WIDE_NAMES = tuple(_WIDE_ARRAYS)
    _MASKS = ("driven", "max_reach", "on", "_all_on")  # row arrays `_masks` makes from the others

    def attach(self, road: "MapRoad", slot: int = 0) -> None:
        """Make `road` the road of `slot`: the rows of the road there before are dropped."""
        if road.network is not self.net:
            raise ValueError("the roads of one traffic core must share its map")
        old = self.env == slot
        if old.any():
            self._select(np.flatnonzero(~old))
        self.drop_walkers([o for o, k in zip(self.p_objs, self.p_env.tolist()) if k == slot])
        held = self.res[slot][self.res[slot] >= 0]  # (holders still rows: none, their rows were dropped)
        np.subtract.at(self.res_count, held, 1)
        self.res[slot] = NONE  # a new episode there: nothing reserved
        self.set_crosswalks(slot, [], 0, 0.0, 0)  # ... and no crosswalk active
        self.roads[slot] = road
        self.recording |= bool(road.record_history)
        self.rtor[slot] = road.control.right_turn_on_red()
        self._plans[slot] = signal_arrays(road.control, self.table.signal_ids)
        self._plans_new[slot] = True
        self.seen[slot] = []
        road.slot = slot
        self.edited.add(slot)
        self.sync([road])

    def rows(self, road: "MapRoad") -> np.ndarray:
        """The rows of `road`, in its vehicles' order (after a sync)."""
        return self.slot_rows(road.slot)

    def slot_rows(self, slot: int) -> np.ndarray:
        """The rows of `slot` (a view: not to be written); the rows of every slot are found at
        once, again only when rows come or go (grouped by slot, as a sync leaves them, a slot's
        rows are a range)."""
        if self._slot_rows is None:
            env = self.env
            grouped = bool((env[1:] >= env[:-1]).all())
            order = np.arange(len(env)) if grouped else np.argsort(env, kind="stable")
            self._slot_rows = (order, np.cumsum(np.bincount(env, minlength=len(self.roads))))
        order, ends = self._slot_rows
        return order[ends[slot - 1] if slot else 0:ends[slot]]

    def add_traffic(self, road: "MapRoad", lane_id: str, s: float, speed: float, route: list[str],
                    model: VehicleModel | None = None, view: type[ArrayVehicle] = ArrayVehicle) -> ArrayVehicle:
        """A new driven row (and its `view`) on `road` at s on `lane_id`, its route starting there;
        with `model`, a controlled row (the ego's, an agent's) with that body and bicycle (its view's
        `model`), driven by its commands."""
        lane = self.table.index[lane_id]
        x, y, h = self.table.place(np.array([lane]), np.array([s]), np.zeros(1))
        v = view.__new__(view)
        bicycle = {}
        if model is not None:
            v.model, v.LENGTH, v.WIDTH = model, model.length, model.width
            bicycle = {"wheelbase": model.wheelbase, "rear_offset": model.rear_offset,
                       "max_steer": model.max_steering, "controlled": True, "at_lane": lane, "at_s": s}
        self._init_view(v, road)
        row = dict(env=road.slot, kind=DRIVEN, lane=lane, s=s, speed=speed,
                   timer=(float(x[0] + y[0]) * np.pi) % TrafficVehicle.LANE_CHANGE_DELAY, x=x[0], y=y[0],
                   heading=h[0], length=v.LENGTH, width=v.WIDTH, route_pos=0, route_end=len(route) - 1, **bicycle)
        self._append(v, row, [self.table.index[x] for x in route])
        road.vehicles.append(v)
        if self.seen[road.slot] == road.vehicles[:-1]:
            self.seen[road.slot].append(v)
        return v

    def _init_view(self, v: ArrayVehicle, road) -> None:
        """The plain attributes highway-env reads from a vehicle (what __init__ would set)."""
        v.road = road
        v.collidable, v.solid, v.check_collisions = True, True, True
        v.diagonal = math.hypot(v.LENGTH, v.WIDTH)
        v.hit = False
        v.impact = None
        v.log = []
        v.history = deque(maxlen=v.HISTORY_SIZE)
        v.prediction_type = "constant_steering"
        v.__dict__["target_speed"] = None  # (a meta-action row's is a property of its row)
        v.route = None
        v.enable_lane_change = False
        v.lane_changes = 0

    def _append(self, obj, row: dict, route: list[int]) -> None:
        i = len(self.objs)
        self.objs.append(obj)
        row = {**ROW_DEFAULTS, **row}
        # the masks `_masks` makes, for the new row alone
        row["driven"], row["max_reach"], row["on"] = self._row_masks(row["kind"], row["width"], row["length"], row["env"])
        row["_all_on"] = True
        self._append_rows(self._ARRAYS + self._MASKS, row)
        self._append_rows(self._WIDE_NAMES, self._WIDE_ARRAYS)
        self.routes.append(route)
        self.route_ids.append([self.net.lane_ids[k] for k in route])
        self._forget_buckets([int(row["env"])])
        if isinstance(obj, ArrayVehicle):
            obj._core, obj._row = self, i
        if row["kind"] == EXTERNAL:
            self._external.append(i)
        self.dirty.add(i)
        self._slot_rows = None
        self.layout += 1

    def _append_rows(self, names: tuple[str, ...], row: dict) -> None:
        """Append one row's values to the arrays `names` (each keeps its dtype; a 2-d array's row
        is filled with the value). An array is the leading rows of a buffer with spare rows
        (`_spare`), so that an append writes one row rather than copying every row of every
        array (a sub-env's reset adds its traffic one vehicle at a time, among all the batch's
        rows); an array replaced since (rows kept or reordered, a wider window) gets a new
        buffer, ROW_SPARE times its rows."""
        arrays, spare = self.__dict__, self._spare
        for name in names:
            a = arrays[name]
            n = len(a)
            held = spare.get(name)
            if held is not None and held[1] is a and len(held[0]) > n:
                buf = held[0]
            else:
                buf = np.empty((max(int(n * ROW_SPARE), n + 1), *a.shape[1:]), dtype=a.dtype)
                buf[:n] = a
            buf[n] = row[name]
            arrays[name] = view = buf[:n + 1]
            spare[name] = (buf, view)

    def _keep_rows(self, names: tuple[str, ...], idx: np.ndarray, moved: np.ndarray | None = None) -> None:
        """Keep rows `idx` of the arrays `names`, in this order; with `moved` (the places whose
        row changes, `idx[k] != k`: every other place keeps its row), an array in a buffer of
        `_append_rows` has only those places written, in place (a respawn's sync moves the rows
        of one slot)."""
        arrays, spare = self.__dict__, self._spare
        m = len(idx)
        source = idx[moved] if moved is not None else idx
        for name in names:
            a = arrays[name]
            held = spare.get(name)
            if moved is not None and held is not None and held[1] is a:
                buf = held[0]
                buf[moved] = a[source]
                arrays[name] = view = buf[:m]
                spare[name] = (buf, view)
            else:
                arrays[name] = a[idx]

    def _row_masks(self, kind, width, length, env) -> tuple:
        """(driven, the body's reach across a lane at a corner's angle beyond its half width
        (`rules.body_reach` at its most), being stepped) of rows of these values (arrays, or one
        row's scalars)."""
        return kind == DRIVEN, np.hypot(width, length) / 2 - width / 2, self.stepped[env]

    def _masks(self) -> None:
        """Masks that change only when rows come or go."""
        self.driven, self.max_reach, self.on = self._row_masks(self.kind, self.width, self.length, self.env)
        self._all_on = np.ones(len(self.env), dtype=bool)  # every row (all slots stepped); never written
        self._external = np.nonzero(self.kind == EXTERNAL)[0].tolist()
        self._slot_rows = None
        self.layout += 1

    def sync(self, roads: list | None = None) -> None:
        """Bring the rows in line with the roads' `vehicles` (by identity): take in vehicles user
        code appended, let go of removed ones (their views keep their last state), follow
        reordering. Rows are kept grouped by slot, each road's in its vehicles' order (the sorts and
        joins of a frame over keys led by the slot find them in order: rows left ungrouped by
        respawns made a batched step slower within a few hundred steps)."""
        if not self.edited:
            return
        # the edited slots among the roads' (all of them: no loop over the roads), in slot order
        edited = sorted(self.edited if roads is None or len(roads) == len(self.roads)
                        else self.edited.intersection(r.slot for r in roads))
        self.edited.difference_update(edited)
        # element by element, by identity (vehicles define no __eq__)
        changed = [r for r in map(self.roads.__getitem__, edited) if r.vehicles != self.seen[r.slot]]
        if not changed:
            return
        pos: dict[int, int] = {}
        for road in changed:
            present = {id(o) for o in road.vehicles}
            mine = [self.objs[i] for i in self.rows(road).tolist()]
            for o in mine:
                if id(o) not in present and isinstance(o, ArrayVehicle):
                    o.detach()
            known = {id(o) for o in mine}
            for o in road.vehicles:
                if id(o) not in known:
                    self._take_in(o, road)
            pos.update((id(o), k) for k, o in enumerate(road.vehicles))
        n = len(self.objs)
        within = np.arange(n)
        keep = np.ones(n, dtype=bool)
        slots = np.array([r.slot for r in changed])
        for i in np.nonzero(np.isin(self.env, slots))[0].tolist():
            k = pos.get(id(self.objs[i]))
            if k is None:
                keep[i] = False
            else:
                within[i] = k
        order = np.nonzero(keep)[0]
        order = order[np.lexsort((within[order], self.env[order]))]
        if len(order) != n or (order != np.arange(n)).any():
            self._select(order)
        else:
            self._settled = n
        self.dirty.update(np.nonzero(np.isin(self.env, slots))[0].tolist())
        for road in changed:
            self.seen[road.slot] = list(road.vehicles)

    def _select(self, idx: np.ndarray) -> None:
        """Keep these rows, in this order (`idx`, an int array)."""
        n = len(self.objs)
        gone = np.ones(n, dtype=bool)
        gone[idx] = False
        left = gone & (self.stop_junction >= 0)  # a queued road user left
        self._forget_buckets(set(self.env[gone].tolist()))
        self.queue_version[self.env[left]] += 1
        self.queued -= int(left.sum())
        moved = np.flatnonzero(idx != np.arange(len(idx)))  # the places whose row changes
        self._keep_rows(self._ARRAYS + self._WIDE_NAMES, idx, moved)
        new_row = np.full(n, -1, dtype=np.int64)
        new_row[idx] = np.arange(len(idx))
        passages.keep_rows(self, new_row)
        self.dirty = {int(new_row[d]) for d in self.dirty if d < n and new_row[d] >= 0}
        runs = reorder_runs(idx, self._settled)
        for name in ("routes", "route_ids", "objs"):
            items = getattr(self, name)
            setattr(self, name, [items[i] for i in idx.tolist()] if runs is None else reorder_in_place(items, runs))
        self._settled = len(idx)
        held = np.nonzero(self.res >= 0)  # the holders' rows move with them; one that went has left
        if len(held[0]):
            at = new_row[self.res[held]]
            self.res[held] = np.where(at >= 0, at, LEFT)
        self._masks()
        objs, external = self.objs, bool(self._external)
        for i in moved.tolist():  # the rows that moved: their views' rows
            o = objs[i]
            if not external or isinstance(o, ArrayVehicle):
                o._row = i

    def _take_in(self, obj, road) -> None:
        """A road user user code added to `road`: a TrafficVehicle on a lane route becomes a
        driven row (its object a view), anything else an external row."""
        if isinstance(obj, TrafficVehicle) and not isinstance(obj, ArrayVehicle) and getattr(obj, "lane_route", None):
            route = [self.table.index[x] for x in obj.lane_route]
            pos = int(obj.route_pos)
            lane = route[pos]
            s, lat = self.net.lane_of[obj.lane_route[pos]].local_coordinates(obj.position)
            row = dict(env=road.slot, kind=DRIVEN, lane=lane, s=s, lat=lat, speed=float(obj.speed),
                       timer=float(obj.timer), mobil_t=float(getattr(obj, "_mobil_t", -1e9)),
                       crashed=bool(obj.crashed), x=obj.position[0], y=obj.position[1], heading=obj.heading,
                       length=obj.LENGTH, width=obj.WIDTH, route_pos=pos, route_end=len(route) - 1)
            reserved = getattr(obj, "reserved", None)
            row["reserved"] = NONE if reserved is None else self.table.index[reserved]
            for name in ("position", "heading", "speed", "crashed", "timer", "lane_index", "lane", "lane_s",
                         "lane_lat", "lane_route", "route_pos", "target_lane_index", "reserved", "action"):
                obj.__dict__.pop(name, None)
            obj.__class__ = ArrayVehicle
            self._append(obj, row, route)
            self._place_rows(np.array([len(self.objs) - 1]))
        else:
            row = dict(env=road.slot, kind=EXTERNAL, lane=0, s=0.0, speed=0.0, mobil_t=0.0, x=0.0, y=0.0, heading=0.0,
                       length=obj.LENGTH, width=obj.WIDTH, route_pos=0, route_end=0)
            self._append(obj, row, [])
            self._read_external(len(self.objs) - 1)

    def _read_external(self, i: int) -> None:
        o = self.objs[i]
        self.x[i], self.y[i] = o.position[0], o.position[1]
        self.heading[i] = o.heading
        self.speed[i] = o.speed
        self.crashed[i] = o.crashed
        lid = self.net.id_of.get(getattr(o, "lane_index", None))
        if lid is not None:
            self.lane[i] = self.table.index[lid]
            self.s[i] = getattr(o, "lane_s", 0.0)
            self.lat[i] = getattr(o, "lane_lat", 0.0)
        else:
            self.lane[i] = -1

    def relocate(self, i: int, position: np.ndarray) -> None:
        """User code moved a driven row: locate it on its route (or the nearest lane). Traffic
        off its route gets that lane as its route; a controlled row keeps its route (at the
        lane's place in it, else projected on its route lane) and stands where it is put."""
        index, s, lat = self.net.locate(position, float(self.heading[i]), self.net._indices[self.lane[i]])
        lane = self.table.index[self.net.id_of[index]]
        route, pos = self.routes[i], int(self.route_pos[i])
        if lane in route[pos:]:
            self.route_pos[i] = route.index(lane, pos)
        elif self.controlled[i] and lane in route:
            self.route_pos[i] = route.index(lane)
        elif self.controlled[i]:
            lane = route[pos]
            s, lat = self.net._lanes[lane].local_coordinates(position)
        elif lane != route[pos]:
            self.set_route(i, [self.net.lane_ids[lane]])
            self.route_pos[i] = 0
        self.lane[i], self.s[i], self.lat[i] = lane, s, lat
        self.dirty.add(i)
        if self.controlled[i]:
            self.x[i], self.y[i] = position[0], position[1]
            self.locate(np.array([i]))
        else:
            self._place_rows(np.array([i]))
        self._forget_buckets([int(self.env[i])])  # (the rules' lane buckets show it where it is now)

    def set_route(self, i: int, lane_ids: list[str]) -> None:
        self.route_ids[i] = lane_ids
        self.routes[i] = [self.table.index[x] for x in lane_ids]
        self.route_end[i] = len(lane_ids) - 1
        self.route_ver[i] += 1
        self.dirty.add(i)

    def reroute(self, i: int, lane_ids: list[str], pos: int) -> None:
        """A controlled row's lane change: its route is now `lane_ids`, and it is on `lane_ids[pos]`
        where it stands (lane keeping then steers it over)."""
        self.set_route(i, lane_ids)
        self.route_pos[i] = pos
        lane = self.routes[i][pos]
        self.s[i], self.lat[i] = self.net._lanes[lane].local_coordinates(np.array([self.x[i], self.y[i]]))
        self.lane[i] = lane
        self.locate(np.array([i]))

    def change_lane(self, i: int, lane: int) -> None:
        if lane == self.lane[i]:
            return
        s, lat = self.net._lanes[lane].local_coordinates(np.array([self.x[i], self.y[i]]))
        self.lane[i], self.s[i], self.lat[i] = lane, s, lat
        route = self.routes[i]
        if lane in route:
            self.route_pos[i] = route.index(lane)
        self.dirty.add(i)

    # ---- walkers -----------------------------------------------------------------------------
    _WALKER_ARRAYS = ("p_env", "p_cw", "p_x", "p_y", "p_ux", "p_uy", "p_speed", "p_left")

    def add_walker(self, obj, slot: int, crosswalk: str, heading: float, speed: float, length: float) -> int:
        """A new walker row of `slot` on `crosswalk` (its place is set by its view) heading
        `heading` with `length` metres to walk; its row."""
        # the direction as highway-env's `RoadObject.direction` computes it
        row = {"p_env": slot, "p_cw": self.crosswalks.index[crosswalk], "p_x": 0.0, "p_y": 0.0,
               "p_ux": np.cos(heading), "p_uy": np.sin(heading), "p_speed": speed, "p_left": length}
        self._append_rows(self._WALKER_ARRAYS, row)
        self.p_objs.append(obj)
        return len(self.p_objs) - 1

    def set_crosswalks(self, slot: int, active: list[str], key: int, chance: float, most: int) -> None:
        """Slot `slot`'s pedestrians step out on crosswalks `active`, with `chance` a frame on each,
        at most `most` on one, drawn with `key` (`sim.pedestrians`); its frame counter starts again."""
        pedestrians.start(self, slot, [self.crosswalks.index[c] for c in active], key, chance, most)

    def drop_walkers(self, gone: list) -> None:
        """Let the walkers of these views go (each view keeps its last place, in a row of its own)."""
        if not gone:
            return
        for o in gone:
            i = o._row
            o._core = SimpleNamespace(p_x=self.p_x[i:i + 1], p_y=self.p_y[i:i + 1], p_left=self.p_left[i:i + 1])
            o._row = 0
        out = set(map(id, gone))
        keep = [k for k, o in enumerate(self.p_objs) if id(o) not in out]
        self._keep_rows(self._WALKER_ARRAYS, np.array(keep, dtype=np.int64))
        self.p_objs = [self.p_objs[k] for k in keep]
        for k, o in enumerate(self.p_objs):
            o._row = k

    def walk(self, dt: float) -> None:
        """Every walker of the slots being stepped moves on at its speed, up to its crosswalk's far end."""
        if not len(self.p_env):
            return
        move = np.minimum(self.p_speed * dt, self.p_left) * self.stepped[self.p_env]
        self.p_x = self.p_x + move * self.p_ux
        self.p_y = self.p_y + move * self.p_uy
        self.p_left = self.p_left - move

    # ---- windows -----------------------------------------------------------------------------
    def refresh_windows(self) -> None:
        """Rebuild the window rows whose route position or route changed: each one's lanes from
        its route, what holds along them (`_window`, kept per lane sequence and body length: the
        rows of a map drive few distinct windows), written into the rows at once."""
        if not self.dirty:
            return
        length = self.table.length
        rows, wins = [], []
        for i in self.dirty:
            if i >= len(self.objs) or self.kind[i] != DRIVEN:
                continue
            route, pos = self.routes[i], int(self.route_pos[i])
            lanes = [route[pos]]
            limit = LOOKAHEAD_M + length[route[pos]]
            d = length[route[pos]]
            for k in range(pos + 1, len(route)):
                if d > limit:
                    break
                lanes.append(route[k])
                d += length[route[k]]
            rows.append(i)
            wins.append(self._window(tuple(lanes), float(self.length[i])))
        self.dirty.clear()
        if not rows:
            return
        ws, cum, what, entry, stop_at = zip(*wins)
        width = np.array([len(x) for x in ws], dtype=np.int64)
        need = int(width.max())
        if need > self.W.shape[1]:
            pad = need - self.W.shape[1]
            self.W = np.hstack([self.W, np.full((len(self.W), pad), -1, dtype=np.int64)])
            self.C = np.hstack([self.C, np.zeros((len(self.C), pad))])
            self.scan_what = np.hstack([self.scan_what, np.zeros((len(self.W), pad), dtype=np.int8)])
        idx = np.array(rows, dtype=np.int64)
        zero = np.zeros(len(idx), dtype=np.int64)
        owner, col = entries.expand_ranges(zero, width)
        self.W[idx] = -1
        self.W[idx[owner], col] = np.concatenate(ws)
        self.C[idx[owner], col] = np.concatenate(cum)
        reach = np.array([len(x) for x in what], dtype=np.int64)
        owner, col = entries.expand_ranges(zero, reach)
        self.scan_what[idx] = 0
        self.scan_what[idx[owner], col] = np.concatenate(what)
        self.scan_len[idx] = reach
        self.entry[idx] = entry
        self.stop_at[idx] = stop_at

    def _window(self, lanes: tuple[int, ...], length: float) -> tuple:
        """(lanes, their start distances from the first's start, what of the scan holds along
        them for a road user `length` long: `rule_scan.along`, the distance to the next junction
        entry and to the first stop sign's line, inf where none) of a window of `lanes`, made
        once per (lanes, length)."""
        key = (lanes, length)
        held = self._windows.get(key)
        if held is None:
            t = self.table
            junction, stops, lane_length = t.junction, t.stop_sign_lanes, t.length
            cum, d = [0.0], lane_length[lanes[0]]
            for x in lanes[1:]:
                cum.append(d)
                d += lane_length[x]
            entry = next((cum[k] for k in range(1, len(lanes)) if junction[lanes[k]] and not junction[lanes[k - 1]]),
                         math.inf)
            stop_at = next((cum[k] + lane_length[x] - t.line_setback[x] for k, x in enumerate(lanes) if x in stops),
                           math.inf)
            if len(self._windows) >= WINDOWS_HELD:
                self._windows.clear()
            held = self._windows[key] = (np.array(lanes, dtype=np.int64), np.array(cum, dtype=float),
                                         np.array(rule_scan.along(t, list(lanes), length), dtype=np.int8),
                                         entry, stop_at)
        return held

    # ---- a frame -----------------------------------------------------------------------------
    def act(self, roads: list) -> None:
        """First half of a frame for `roads` (the others' rows stand still): sync, the external
        road users act, accelerations of the traffic."""
        self.sync(roads)
        if len(roads) == len(self.roads):
            self.stepped[:] = True
            self.on = self._all_on
        else:
            self.stepped[:] = False
            self.stepped[[r.slot for r in roads]] = True
            self.on = self.stepped[self.env]
        self._acting = [i for i in self._external if self.on[i]]  # external rows this frame (`step` too)
        for i in self._acting:
            self.objs[i].act()
        self.accelerations()

    def step(self, roads: list, dt: float) -> None:
        """Second half of a frame for `roads`: external road users step, traffic integrates,
        pedestrians walk, the rules' bookkeeping, collisions."""
        external = self._acting
        for i in external:
            self.objs[i].step(dt)
        self.integrate(dt)
        for i in external:
            self._read_external(i)
        self.sync(roads)  # the core takes in vehicles added or removed by user code
        self.walk(dt)
        stop_signs.update(self, self.on)
        pedestrians.update(self, dt, self.stepped)
        looks = self.release_looks(self.stepped)
        self.tick(self.stepped, dt)
        if self.net.passages:  # (narrow passages: every road's holders looked at)
            for road in roads:
                road.control.bookkeeping(looks.get(road.slot, ()))
        else:
            for slot in sorted(looks):  # (stepped slots alone)
                self.roads[slot].control.bookkeeping(looks[slot])
        self.collisions(roads, dt)
        for road in roads if self.recording else ():
            if road.record_history:
                for v in self.views(road):
                    v.history.appendleft(TrafficVehicle.create_from(v))

    def accelerations(self) -> None:
        """Acceleration of every driven row being stepped (see the module docstring, step 3):
        traffic's by IDM behind its leaders and the rules' stops, a controlled row's its command."""
        driven = self.driven & self.on
        if not driven.any():
            return
        traffic = driven & ~self.controlled
        if traffic.any():
            self._mobil(traffic)
        self.refresh_windows()
        acc = self._idm(traffic) if traffic.any() else np.zeros(len(self.speed))
        acc = np.where(self.controlled, self.commanded(), acc)
        self.acc = np.where(self.crashed, -self.speed, acc)  # highway-env: a crashed vehicle brakes to a stop

    def _idm(self, traffic: np.ndarray) -> np.ndarray:
        """IDM's acceleration of the `traffic` rows behind their leaders and stop points
        (`rules.idm_accelerations`; a stop point is a standing leader)."""
        v0 = np.minimum(self.table.speed_limit[self.lane], self.curve_limit())
        fi, gap, vl = self._leaders(traffic.nonzero()[0])
        jam = np.full(len(fi), IDM_GAP_M)
        with self.asking():
            sd = self._rule_stops(traffic)
        si = (sd < math.inf).nonzero()[0]
        if len(si):
            sd = sd[si]
            fi = np.concatenate([fi, si])
            gap = np.concatenate([gap, stop_gap(sd, self.length[si])])
            vl = np.concatenate([vl, np.zeros(len(si))])
            jam = np.concatenate([jam, np.full(len(si), IDM_STOP_GAP_M)])
        return idm_accelerations(self.speed, v0, fi, gap, vl, jam)

    def commanded(self) -> np.ndarray:
        """Per row, a controlled row's acceleration this frame: its command, or the speed control
        towards its target speed (`sim.vehicle.speed_control`, as highway-env's MDPVehicle)."""
        target = ~np.isnan(self.target)
        if not target.any():
            return self.command
        return np.where(target, speed_control(np.where(target, self.target, 0.0), self.speed), self.command)

    def curve_limit(self) -> np.ndarray:
        """Per row, the highest speed from which it can brake at CURVE_BRAKE_MPS2 to every curve
        of its window at that curve's comfortable speed (`lanes.curve_speeds`; curve points up
        to CURVE_BEHIND_M behind it count), never below CURVE_MIN_SPEED_MPS: traffic's desired
        speed, as the baseline planner slows for curves. One lookup per window lane (LaneTable's
        `curve_q`), no scan over lanes or vertices."""
        t = self.table
        lane = np.maximum(self.lane, 0)
        s = self.s
        j = t.G.searchsorted(t.offset[lane] + s - CURVE_BEHIND_M, side="left")
        own = np.where(j <= t.last_vertex[lane], t.curve_q[np.minimum(j, len(t.G) - 1)], math.inf)
        v2 = own - 2 * CURVE_BRAKE_MPS2 * s
        if self.W.shape[1] > 1:
            W, C = self.W[:, 1:], self.C[:, 1:]
            ahead = C - s[:, None]
            q = np.where((W >= 0) & (ahead <= LOOKAHEAD_M), t.curve_q[t.first[np.maximum(W, 0)]], math.inf)
            v2 = np.minimum(v2, (q + 2 * CURVE_BRAKE_MPS2 * ahead).min(axis=1))
        return np.sqrt(np.maximum(v2, CURVE_MIN_SPEED_MPS ** 2))

    def leader_gaps(self, i: int) -> list[tuple[float, float]]:
        """(bumper gap, speed) of every road user in row `i`'s way along its route: `_leaders`
        of that one row among the rows of its slot (what the ego's planner, DriverView and judge
        read, the same program that gives traffic its leaders)."""
        if self._observing is not None and i in self._observing[2]:
            return list(self._observing[2][i])
        self.refresh_windows()
        if not self.driven[i]:
            return []
        _, gap, speed = self._leaders(np.array([i]), self.slot_rows(int(self.env[i])))
        return list(zip(gap.tolist(), speed.tolist()))

    def leaders_of(self, rows: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(follower row, bumper gap, leader speed) of every road user in the way of driven `rows`
        (`_leaders`, their windows brought up to date first): `leader_gaps` of many rows at once."""
        self.refresh_windows()
        return self._leaders(rows)

    def _leaders(self, rows: np.ndarray, others: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(follower row, bumper gap, leader speed) of every road user in the way of driven
        `rows` (row indices) along their windows: on a window lane, on a junction lane that
        conflicts with or diverges from one, or on a road lane converging with one (zip:
        `MapNetwork.zip_leader`), where it is in the way (`rules.in_the_way`, by its body:
        `rules.body_reach`). The leaders' one rule, for every row at once; `others`: the rows of
        one slot that may lead (default: every row, of the follower's slot). A road user is where
        it is: a controlled row on its located lane, an external one at its exact place."""
        t = self.table
        W, C, s_f = self.W[rows], self.C[rows], self.s[rows]  # per follower
        valid = (W >= 0) & ((C - s_f[:, None]) <= LOOKAHEAD_M)
        nl = len(t.length)
        one = len(self.roads) == 1 or others is not None  # one slot: no slot in the keys, every pair for the conflicts
        O = np.arange(len(self.objs)) if others is None else others
        ctl = self.controlled if others is None else self.controlled[O]
        pick = (lambda a: a) if others is None else (lambda a: a[O])  # noqa: E731
        at = self.where_lanes(others)  # where each candidate is
        at_s = np.where(ctl, pick(self.at_s), pick(self.s))
        at_lat = np.where(ctl, pick(self.at_lat), pick(self.lat))
        env_f, env_o = self.env[rows], pick(self.env)
        # same lane: every candidate (of the same slot) on a window lane
        ef, ek = valid.nonzero()
        on_map = (at >= 0).nonzero()[0]
        if one:
            a, b = same_key_pairs(W[ef, ek], at[on_map])
        else:
            a, b = same_key_pairs(env_f[ef] * nl + W[ef, ek], env_o[on_map] * nl + at[on_map])
        fi, k, lj = ef[a], ek[a], on_map[b]  # follower (into rows), window place, candidate (into O)
        other = rows[fi] != O[lj]
        fi, k, lj = fi[other], k[other], lj[other]
        so, ro = at_s[lj], at_lat[lj]
        wl = W[fi, k]
        self._exactly(wl, O[lj], so, ro)
        ahead = so > s_f[fi]
        zips = np.zeros(len(fi), dtype=bool)  # converging road lanes: `MapNetwork.zip_leader` decides
        # candidates on junction lanes conflicting with or diverging from a window junction lane
        occ = ((at >= 0) & (t.jid[np.maximum(at, 0)] >= 0)).nonzero()[0]
        if len(occ):
            ef, ek = (valid & (t.jid[np.maximum(W, 0)] >= 0)).nonzero()
            if len(ef):
                if one:
                    ei, oi = np.divmod(np.arange(len(ef) * len(occ)), len(occ))
                else:
                    ei, oi = same_key_pairs(env_f[ef], env_o[occ])
                oj = occ[oi]
                hit = t.near_pairs(W[ef[ei], ek[ei]], at[oj]) & (rows[ef[ei]] != O[oj])
                pf, pk, pj = ef[ei[hit]], ek[ei[hit]], oj[hit]
                if len(pj):
                    a_l, b_l = W[pf, pk], at[pj]
                    so2, ro2 = t.seen_from(a_l, b_l, at_s[pj])
                    self._exactly(a_l, O[pj], so2, ro2)
                    ahead2 = so2 > s_f[pf]
                    zips2 = ~t.junction[a_l] & (a_l != b_l)
                    ids = self.net.lane_ids
                    for n_ in zips2.nonzero()[0].tolist():
                        f_ = int(rows[pf[n_]])
                        ahead2[n_] = self.net.zip_leader(
                            ids[a_l[n_]], float(self.s[f_]) if pk[n_] == 0 else None, ids[b_l[n_]], float(so2[n_]),
                            self.objs[f_].position, self.objs[O[pj[n_]]].position, float(self.length[f_]))
                    fi, k, lj = np.concatenate([fi, pf]), np.concatenate([k, pk]), np.concatenate([lj, pj])
                    ahead, zips = np.concatenate([ahead, ahead2]), np.concatenate([zips, zips2])
                    so, ro = np.concatenate([so, so2]), np.concatenate([ro, ro2])
                    wl = W[fi, k]
        if not len(fi):
            return fi, np.zeros(0), np.zeros(0)
        fr, lr = rows[fi], O[lj]  # follower and leader rows
        L = self.length[fr]
        lw, ll = t.width[wl], t.length[wl]
        way = in_the_way(so, ro, lw, ll, L)  # by the centre; then the bodies that may reach in at their angle
        maybe = (~way & in_the_way(so, ro, lw, ll, L, self.max_reach[lr])).nonzero()[0]
        if len(maybe):
            m = lr[maybe]
            reach = body_reach(self.width[m], self.length[m], self.heading[m] - t.heading_at(wl[maybe], so[maybe]))
            way[maybe] = in_the_way(so[maybe], ro[maybe], lw[maybe], ll[maybe], L[maybe], reach)
        ok = np.where(zips, ahead, way & ((k > 0) | ahead))
        gap = C[fi, k] - s_f[fi] + so - L
        return fr[ok], gap[ok], self.speed[lr[ok]]

    def _exactly(self, lanes: np.ndarray, rows: np.ndarray, s: np.ndarray, lat: np.ndarray) -> None:
        """(s, lat) on `lanes` of the external ones of `rows` from their positions, in place
        (their rows hold what highway-env's vehicle says of its own lane, if anything)."""
        if not self._external:
            return
        for n in (~self.driven[rows]).nonzero()[0].tolist():
            s[n], lat[n] = self.net._lanes[lanes[n]].local_coordinates(self.objs[rows[n]].position)

    def rule_scan_of(self, vehicle) -> tuple[rule_scan.Scan, int]:
        """(a scan along its route, `sim.rule_scan`, indexed; the road user's place in it): what
        `TrafficRules._rule_stop` walks when asked of one road user (the baseline planner, the
        judge, a bridge, an observation). While envs observe (`observing`), the scan made for
        all their rows at once."""
        i = vehicle._row
        if self.objs[i] is not vehicle or not self.driven[i]:
            raise ValueError(f"{vehicle!r} is no road user the core drives: the rules' stops are asked of its rows")
        if self._observing is not None and i in self._observing[0]:
            return self._observing[1], self._observing[0][i]
        self.refresh_windows()
        return rule_scan.scan(self, np.array([i])).index(), 0

    @contextlib.contextmanager
    def observing(self, rows: np.ndarray) -> Iterator[None]:
        """While envs make their observations (nothing moves), the scans along the routes of
        controlled `rows` (`rule_scan_of`) and their leader gaps (`leader_gaps`) are made for
        all of them at once, by the programs that make one row's: an observation that asks the
        rules of its ego (DriverView) then reads them, not one program per ego."""
        self.refresh_windows()
        rows = rows[self.driven[rows]]
        place = {r: k for k, r in enumerate(rows.tolist())}
        fr, gap, speed = self._leaders(rows)
        gaps: dict[int, list[tuple[float, float]]] = {r: [] for r in place}
        for f, g, v in zip(fr.tolist(), gap.tolist(), speed.tolist()):
            gaps[f].append((g, v))
        self._observing = (place, rule_scan.scan(self, rows).index(), gaps)
        try:
            yield
        finally:
            self._observing = None

    def _rule_stops(self, traffic: np.ndarray) -> np.ndarray:
        """Per row, the stop distance of its vehicle (inf outside the `traffic` mask and for
        crashed rows) from one scan of all rows, whatever their slots (`sim.rule_scan`), in two
        parts, the rules' questions and then their claims: every row with a stop on its scan asks
        (`TrafficRules.ask`, pure) against the state the frame began with, and the rows whose
        answer would take or give up something (a junction lane within commit distance of its
        line, a reservation on red) then claim (`control.TrafficControl.claim`) in row order, each
        claim seeing the claims before it (a later claimant of a lane conflicting with an earlier
        one's is held at its line), and that is their answer. A row with a narrow passage on its
        route within PASSAGE_HORIZON_M (`_passages_ahead`) claims, whatever it would take: its
        place at the passages is part of its claim, and the swept stretches out of which the
        rules move a stop point (`TrafficRules.clear_of_sweeps`) lie on passage lanes
        (`sweep.stretches`), so no other row reaches one. From SETTLE_MIN_ROWS rows asked, the
        arrays answer what they can of the others: a row whose first stop is a junction entry
        under a signal that holds it (`rules.held_at_signal`: red, or amber where it can stop)
        stops at the line (on red, a
        reservation it holds there is given up), a row whose first stop is a junction entry the
        arrays answer exactly (`_entry_answers`) is answered there, and one whose first stop is a
        crosswalk with people on it, or that such an entry lets go onto one, is answered by the
        yield rule's program (`_people_answers`) where it stops there or has no stop after it."""
        env = self.env
        n = len(self.objs)
        dist = np.full(n, math.inf)
        on = traffic & ~self.crashed
        if not on.any():
            return dist
        sc = rule_scan.scan(self)
        t = self.table
        at = sc.what != 0
        ask = on & at.any(axis=1)
        walk = self._passages_ahead(on) if self.net.passages else np.zeros(n, dtype=bool)
        ask &= ~walk
        walks = walk.nonzero()[0].tolist()
        if ask.sum() < SETTLE_MIN_ROWS:  # too few for the arrays to pay: each asks the rules
            sc.index(ask | walk)
            return self._claim(sorted(self._ask(ask, sc, dist) + walks), sc, dist)
        first = np.argmax(at, axis=1)
        ar = np.arange(n)
        entry = ask & (sc.what[ar, first] & (ENTRY | CROSSED) == ENTRY)
        in_lane = sc.lanes[ar, np.maximum(first - 1, 0)]
        signal = entry & (t.line_signal[in_lane] >= 0)
        state = np.zeros(n, dtype=np.int8)  # of the signal at the line (0: green or none)
        if signal.any():
            si = signal.nonzero()[0]
            state[si] = self._signal_states(env[si], t.line_signal[in_lane[si]])
        d_line = sc.D[ar, first] - t.line_setback[in_lane]
        halt = signal & held_at_signal(state == 2, state == 1, d_line, self.speed)
        dist[halt] = (d_line - STOP_POINT_M)[halt]
        j_lane = sc.lanes[ar, first]
        answer, refused, takes, crowd = self._entry_answers(sc, entry & ~halt, j_lane, in_lane, d_line)
        dist[answer] = np.where(refused, d_line - STOP_POINT_M, math.inf)[answer]
        crowd |= ask & ~entry & (sc.what[ar, first] == PEOPLE)  # a crosswalk with people its first stop
        if crowd.any():
            seen, stop = self._people_answers(sc, crowd, first)
            dist[seen] = stop[seen]
            answer |= seen
        takes &= answer
        enters = {i: int(j_lane[i]) for i in takes.nonzero()[0].tolist()}  # (each reserves its entry's lane)
        takes |= halt & (state == 2) & self._holders()  # red: it gives up a reservation it holds
        rest = ask & ~halt & ~answer
        sc.index(rest | takes | walk)
        for i in (signal & (rest | takes)).nonzero()[0].tolist():  # the state at its first stop's line is known
            sc.state[i] = SIGNAL_STATES[state[i]]
        return self._claim(sorted(self._ask(rest, sc, dist) + takes.nonzero()[0].tolist() + walks), sc, dist, enters)

    def _passages_ahead(self, rows: np.ndarray) -> np.ndarray:
        """Mask over the rows: those of `rows` (a mask) whose route has a narrow passage starting
        within PASSAGE_HORIZON_M ahead, or that are on one (`TrafficRules.passage_way` looks no
        farther). Each row's distance to its first passage is found again only when its route or
        route position changed (`passage_key`)."""
        idx = rows.nonzero()[0]
        lane_of, passages = self.net.lane_of, self.net.passages
        for i in task.changed_rows(self, idx, self.passage_key):
            route, pos = self.route_ids[i], int(self.route_pos[i])
            d, found, limit = 0.0, math.inf, lane_of[route[pos]].length + PASSAGE_HORIZON_M
            for lid in route[pos:]:
                if lid in passages:
                    found = d
                    break
                d += lane_of[lid].length
                if d > limit:
                    break
            self.passage_d[i] = found
        out = np.zeros(len(rows), dtype=bool)
        out[idx] = self.passage_d[idx] - self.s[idx] <= PASSAGE_HORIZON_M
        return out

    def _ask(self, rows: np.ndarray, sc: rule_scan.Scan, dist: np.ndarray) -> list[int]:
        """Each of `rows` (a mask; their scans indexed in `sc`) asks the rules its question
        (`TrafficRules.ask`), its answer into `dist`; the rows whose claim would take or give up
        something, in row order."""
        claims: Claims = []  # (what the row asking records; emptied after each)
        wants = []
        for i in rows.nonzero()[0].tolist():
            dist[i] = self.roads[self.env[i]].control.ask(self.objs[i], (sc, i), claims)
            if claims:
                wants.append(i)
                claims.clear()
        return wants

    def _claim(self, rows: list[int], sc: rule_scan.Scan, dist: np.ndarray,
               enters: dict[int, int] | None = None) -> np.ndarray:
        """The claims of `rows` (row order; their scans indexed in `sc`): each row's stop distance
        is its claim's answer (`control.TrafficControl.claim`). A row the arrays let go into the
        lane of its entry (`enters`: the lane), within commit distance and the lane reserved by
        nobody, claims that lane with its chain (what its walk records, `TrafficRules._may_enter`)
        and keeps its answer when it is the first to claim in its slot: a claim writes its own
        slot's rule state alone, so that state is the one its answer came from."""
        enters = enters or {}
        ids = self.net.lane_ids
        claimed = set()  # (the slots claimed in)
        for i in rows:
            slot = int(self.env[i])
            control, v = self.roads[slot].control, self.objs[i]
            if i in enters and slot not in claimed:
                lane = ids[enters[i]]
                control.apply(v, [("reserve", lane, control.junction_chain(v, lane))])
            else:
                dist[i] = control.claim(v, scan=(sc, i))
            claimed.add(slot)
        return dist

    def _holders(self) -> np.ndarray:
        """Per row, whether it may hold a junction reservation (a `reserved` lane, or a count of
        holdings, `res_count`): what a release can give up (`TrafficRules._holds_any`)."""
        return (self.reserved >= 0) | (self.res_count > 0)

    # ---- reservations (`reservations.py`) ----------------------------------------------------
    def reservations(self, slot: int) -> Reservations:
        """Slot `slot`'s reservations as {lane id: holder} (a view of `res`)."""
        return Reservations(self, slot)

    def pedestrian_stop(self, slot: int, lane: str, s_from: float) -> float:
        """`sim.crossings.blocking` of one question: the s on `lane` (an id) where a road user of
        `slot` stops for pedestrians on a crosswalk beyond `s_from` (inf: none), what the rules'
        `pedestrian_blocking` asks."""
        return float(crossings.blocking(self, np.array([slot]), np.array([self.table.index[lane]]),
                                        np.array([s_from]))[0])

    def walkers_across(self, slot: int, lane: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The walkers of `slot` on the crosswalks across `lane` (an id) as `sim.crossings.walkers`
        sees them: (which of the lane's crossings, `MapNetwork.crossings[lane]` order; s; lateral)."""
        k = self.table.index[lane]
        _, c, _, s, lat = crossings.walkers(self, np.array([slot]), np.array([k]))
        return c - crossings.crossing_table(self.net).start[k], s, lat

    def lanes_clear(self, slot: int, vehicle: Any, lanes: Iterable[str], priority: bool = True,
                    margin: float = PRIORITY_MARGIN_M) -> np.ndarray:
        """`sim.entries.junction_clear` of each of junction lanes `lanes` (ids) for road user
        `vehicle` of `slot` (None: nobody): what `TrafficRules.junction_clear` and
        `cross_traffic_near` ask."""
        j = np.array([self.table.index[x] for x in lanes], dtype=np.int64)
        me = self.user_row(vehicle) if vehicle is not None else NONE
        return entries.junction_clear(self, np.full(len(j), slot), np.full(len(j), me), j, priority=priority,
                                      margin=margin, one=slot)

    def rows_clear(self, rows: np.ndarray, lanes: list[str]) -> np.ndarray:
        """`sim.entries.junction_clear` of junction lane `lanes[k]` for row `rows[k]`, each in its
        slot: the conflict rule asked of many road users at once (the agents' judges)."""
        j = np.array([self.table.index[x] for x in lanes], dtype=np.int64)
        slots = self.env[rows]
        return entries.junction_clear(self, slots, rows, j, one=int(slots[0]) if (slots == slots[0]).all() else NONE)

    def row_of(self, obj: Any) -> int:
        """The row of road user `obj` (LEFT: none; only rows hold reservations)."""
        r = getattr(obj, "_row", LEFT) if getattr(obj, "_core", None) is self else LEFT
        return r if 0 <= r < len(self.objs) and self.objs[r] is obj else LEFT

    def user_row(self, obj: Any) -> int:
        """The row of road user `obj`, an external one's included (NONE: none of the rows)."""
        r = self.row_of(obj)
        return r if r != LEFT else next((i for i in self._external if self.objs[i] is obj), NONE)

    def release_looks(self, slots: np.ndarray) -> dict[int, list[str]]:
        """Per slot of `slots` (a mask), the lanes whose reservation its bookkeeping must look at
        (`TrafficControl.bookkeeping`), in the order taken: held by a road user that left, taken since
        the slot's last look, or held by a road user whose route, route position or lane changed
        since its last look (for the others the last look's answer stands: kept). One program for
        every slot; a holder's place is noted at each look (`seen_*`). Up to LOOK_ALL_MAX
        reservations, every one is looked at (their slots' notes then count as stale)."""
        every = bool(slots.all())
        flat = np.flatnonzero(self.res != NONE)  # (slot, lane) as slot * lanes + lane
        if len(flat) and not every:
            flat = flat[slots[flat // self.res.shape[1]]]
        if len(flat) > LOOK_ALL_MAX:
            slot, lane = np.divmod(flat, self.res.shape[1])
            holder = self.res[slot, lane].astype(np.int64)
            row = holder[holder >= 0]
            pos, at, ver = self.route_pos[row], self.where_lanes(row), self.route_ver[row]
            moved = self.seen_stale[slot]  # (and one that left)
            moved[holder >= 0] |= (pos != self.seen_pos[row]) | (at != self.seen_lane[row]) | (ver != self.seen_route[row])
            look = moved | (holder < 0) | (self.res_seq[slot, lane] > self.res_looked[slot])
            self.seen_pos[row], self.seen_lane[row], self.seen_route[row] = pos, at, ver
            self.seen_stale[slots] = False
            flat = flat[look]
        else:
            self.seen_stale[slots] = True
        looks: dict[int, list[str]] = {}
        if len(flat):
            ids, nl = self.net.lane_ids, self.res.shape[1]
            for k in flat[np.argsort(self.res_seq.ravel()[flat], kind="stable")].tolist():  # (in the order taken)
                looks.setdefault(k // nl, []).append(ids[k % nl])
        if every:
            self.res_looked[:] = self._res_taken
        else:
            self.res_looked[slots] = self._res_taken
        return looks

    def next_reservation(self) -> int:
        """The order of a reservation taken now (`res_seq`)."""
        self._res_taken += 1
        return self._res_taken

    def _entry_answers(self, sc: rule_scan.Scan, rows: np.ndarray, j_lane: np.ndarray, in_lane: np.ndarray,
                       d_line: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """(answered, refused, takes, crowd), masks over the rows: the rows among `rows` (whose first
        stop is the entry into `j_lane` from `in_lane`, `d_line` ahead) whose question the arrays
        answer (an entry `sim.entries` answers: not chained, no box, no yield sign; at a stop
        sign, whose turn it is: `stop_signs.turns`; held there, or let go with nothing else to
        stop for: no crosswalk with people or light on that lane, no stop after it; `rows` have
        no narrow passage ahead, and so no swept stretch, `_rule_stops`), those the rules hold at
        the line (`TrafficRules.may_enter`: a reservation of the lane lets it go, else a stop sign
        holds it unless its turn has come there, else a conflict does, `entries.junction_clear`),
        those that would reserve the lane if answered (let go, within commit distance of the line,
        the lane reserved by nobody), and those let go whose next stop is a crosswalk with people
        on that lane (`_people_answers`)."""
        n = len(rows)
        none = np.zeros(n, dtype=bool)
        if not rows.any() or self.length.max() > entries.BOX_LENGTH_M:
            return none, none, none, none
        t = self.table
        et = entries.entry_table(self.net, t)
        stop = t.line_kind[in_lane] == LINE_STOP_SIGN
        answer = rows & et.simple[j_lane]
        turn = np.zeros(n, dtype=bool)  # at the entry's stop sign, and its turn
        sign = (answer & stop).nonzero()[0]
        if len(sign):
            turn[sign] = stop_signs.turns(self, sign, j_lane[sign])
        r = answer.nonzero()[0]
        if not len(r):
            return answer, none, none, none
        holder = self.res[self.env[r], j_lane[r]]
        reserved, mine = holder != NONE, holder == r  # the lane is reserved (by the row: `mine`)
        no = stop[r] & ~mine & ~turn[r]
        ask = ~mine & ~no
        if ask.any():
            a = r[ask]
            no[ask] = ~entries.junction_clear(self, self.env[a], a, j_lane[a])
        stops = sc.what[r] != 0
        what = sc.what[r, np.argmax(stops, axis=1)]
        people = what == ENTRY | PEOPLE
        more = (stops.sum(axis=1) > 1) | (what != ENTRY)  # let go, it walks on: the rules answer, or the people
        answer[r[~no & more]] = False
        refused, takes, crowd = none.copy(), none.copy(), none.copy()
        refused[r] = no
        takes[r] = ~no & ~reserved & commits(d_line[r], self.speed[r])
        crowd[r] = ~no & people
        return answer, refused, takes, crowd

    def _people_answers(self, sc: rule_scan.Scan, rows: np.ndarray, first: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(answered, stop distance) over the rows: of `rows` (a mask), whose first stop to look at
        (window place `first`) is a crosswalk with people on it (`sim.crossings.blocking`, from
        the row's place on its current lane, else from the lane's start), those held there (the
        distance to where they stop) and those it lets go with no stop after it (inf)."""
        r = rows.nonzero()[0]
        k = first[r]
        d = sc.D[r, k]
        at = crossings.blocking(self, self.env[r], sc.lanes[r, k], np.where(k == 0, -d, 0.0))
        seen = np.zeros(len(rows), dtype=bool)
        seen[r] = (at < math.inf) | ((sc.what[r] != 0).sum(axis=1) == 1)
        stop = np.full(len(rows), math.inf)
        stop[r] = d + at
        return seen, stop

    def approach_held(self, slots: np.ndarray, lanes: np.ndarray) -> np.ndarray:
        """Per (slot, lane) pair, `TrafficRules._held`: the lane's line holds its traffic (a stop
        sign, or a signal showing red)."""
        t = self.table
        held = t.line_kind[lanes] == LINE_STOP_SIGN
        sig = (t.line_kind[lanes] == LINE_SIGNAL) & (t.line_signal[lanes] >= 0)
        if sig.any():
            held[sig] = self._signal_states(slots[sig], t.line_signal[lanes[sig]]) == 2
        return held

    def _signal_states(self, slots: np.ndarray, signals: np.ndarray) -> np.ndarray:
        """The states (`control.signal_timing` codes: 0 green, 1 amber, 2 red) of signals `signals`
        (indices into `LaneTable.signal_ids`) in slots `slots`, at each slot's clock."""
        return self.asked(("signals",), self.signal_codes)[slots, signals]  # (one look for the frame's questions)

    def signal_codes(self, slot: int | None = None) -> np.ndarray:
        """The states (`control.signal_timing` codes) of every signal (`LaneTable.signal_ids`) of
        every slot at its clock ([slots, signals]; of `slot` alone, [signals]): what the arrays
        and the rules' `signal_state` read, worked out again (`_time_signals`) only for the slots
        whose clock has reached the next change of one of their signals (or gone back), or that
        have a new road (a signal changes every few seconds: most frames read states worked out
        frames before)."""
        times, codes, _, next_change = self._signals_timed
        clock = self.clock
        if slot is not None:
            if self._plans_new[slot] or not times[slot] <= clock[slot] < next_change[slot]:
                codes = self._time_signals(np.array([slot]))[1]
            return codes[slot]
        due = self._plans_new | (clock < times) | (clock >= next_change)
        return self._time_signals(due.nonzero()[0])[1] if due.any() else codes

    def signal_waits(self, slot: int) -> np.ndarray:
        """Seconds until each signal of `slot` changes, at its clock: worked out again
        (`_time_signals`) once that clock has moved on."""
        times, _, waits, _ = self._signals_timed
        if self._plans_new[slot] or times[slot] != self.clock[slot]:
            waits = self._time_signals(np.array([slot]))[2]
        return waits[slot]

    def signal_waits_of(self, slots: np.ndarray, signals: np.ndarray) -> np.ndarray:
        """Seconds until signal `signals[k]` of slot `slots[k]` changes, at that slot's clock
        (`signal_timing` of those pairs alone: the infos of a batch)."""
        return signal_timing(self.clock[slots], self._plans[slots, :, signals].T)[1]

    def _time_signals(self, slots: np.ndarray) -> tuple:
        """`control.signal_timing`, one program for every signal of `slots` at each one's clock,
        into a new copy of what `signal_codes` and `signal_waits` keep."""
        times, codes, waits, next_change = (a.copy() for a in self._signals_timed)
        t = self.clock[slots]
        codes[slots], waits[slots] = signal_timing(t[:, None], self._plans[slots].transpose(1, 0, 2))
        times[slots] = t
        next_change[slots] = t + waits[slots].min(axis=1, initial=math.inf) - SIGNAL_EDGE_S
        self._plans_new[slots] = False
        self._signals_timed = (times, codes, waits, next_change)
        return self._signals_timed

    @contextlib.contextmanager
    def asking(self) -> Iterator[None]:
        """A stretch in which the rules are asked about the rows as they stand (a frame's rules,
        the agents' judges before a frame: nothing moves, only reservations may change): what they
        read of the rows is made once for all of them (`asked`)."""
        outer = self._asking
        self._asking = {} if outer is None else outer
        try:
            yield
        finally:
            self._asking = outer

    def asked(self, key: tuple, make: Callable[[], Any]) -> Any:
        """`make()`, kept under `key` for the other questions while the rules are `asking`."""
        memo = self._asking
        if memo is None:
            return make()
        out = memo.get(key)
        if out is None:
            out = memo[key] = make()
        return out

    def buckets(self, road: "MapRoad") -> dict[str, list]:
        """The road users of `road` on each lane id, in its vehicles' order (after a sync; a
        controlled row on its located lane): `TrafficControl.buckets`."""
        rows = self.rows(road)
        ids, objs = self.net.lane_ids, self.objs
        out: dict[str, list] = {}
        for i, lane in zip(rows.tolist(), self.where_lanes(rows).tolist()):
            if lane >= 0:
                out.setdefault(ids[lane], []).append(objs[i])
        return out

    def tick(self, slots: np.ndarray, dt: float) -> None:
        """A frame of `dt` passed in `slots` (a mask): their clocks advance and their rules' lane
        buckets are made again when next asked (their road users moved)."""
        self.clock[slots] += dt
        self.moves[slots] += 1

    def _forget_buckets(self, slots) -> None:
        """The rules' lane buckets of `slots` are made again when next asked (road users came or went)."""
        self.moves[list(slots)] += 1

    def _mobil(self, traffic: np.ndarray) -> None:
        due = traffic & (self.timer - self.mobil_t >= MOBIL_PERIOD_S) & ~self.crashed
        if not due.any():
            return
        self.mobil_t = np.where(due, self.timer, self.mobil_t)
        t = self.table
        cand = due & t.neighbours[self.lane] & may_change_lane(t.junction[self.lane], t.length[self.lane] - self.s,
                                                                self.speed)
        if not cand.any():
            return
        self.refresh_windows()
        rows = cand.nonzero()[0]
        ids = self.net.lane_ids
        for i, n, path in mobil.decide(self, rows, *self._leaders(rows)):  # (asked at once, then taken in row order)
            car = self.objs[i]
            car.lane_route = car.lane_route[:car.route_pos] + list(path)
            car.target_lane_index = self.net.index_of[ids[n]]
            car.lane_changes = getattr(car, "lane_changes", 0) + 1

    def integrate(self, dt: float) -> None:
        """Advance driven rows being stepped by dt along their routes (step 4): controlled rows
        by the bicycle (`drive`), traffic along its lanes."""
        on = self.on
        driven = self.driven & on
        if not driven.any():
            return
        bicycles = (driven & self.controlled).nonzero()[0]
        if len(bicycles):
            self.drive(bicycles, dt)
            # every other row being stepped moves; external rows are read back from their objects right after
            on = on & ~self.controlled
            driven = driven & ~self.controlled
            if not on.any():
                return
        s = self.s + self.speed * dt
        speed = np.maximum(self.speed + self.acc * dt, 0.0)
        timer = self.timer + dt
        lat = self.lat * math.exp(-dt / LANE_CHANGE_TAU_S)
        if on.all():  # (a single env, a batch stepped whole)
            self.s, self.speed, self.timer, self.lat = s, speed, timer, lat
        else:
            self.s, self.speed = np.where(on, s, self.s), np.where(on, speed, self.speed)
            self.timer, self.lat = np.where(on, timer, self.timer), np.where(on, lat, self.lat)
        length = self.table.length
        over = driven & (self.s > length[self.lane]) & (self.route_pos < self.route_end)
        for i in over.nonzero()[0].tolist():
            route = self.routes[i]
            pos = int(self.route_pos[i])
            while pos + 1 < len(route) and self.s[i] > length[route[pos]]:
                self.s[i] -= length[route[pos]]
                pos += 1
            self.route_pos[i] = pos
            self.lane[i] = route[pos]
            self.dirty.add(i)
        self._place_rows(driven.nonzero()[0])

    def drive(self, rows: np.ndarray, dt: float) -> None:
        """Controlled `rows` over dt, all at once: steering by lane keeping on the route lane
        (`sim.vehicle.keeping_steering`) or the held `cmd_steer`, the bicycle (`sim.vehicle.
        integrate`, never reversing), then (s, lat) projected on the route lane, moving on to the
        next route lane past its end, and the row located (`locate`). Fewer than
        BATCH_MIN_DRIVEN rows drive one by one with floats (`_drive_one`, the same values)."""
        if len(rows) < BATCH_MIN_DRIVEN:
            for i in rows.tolist():
                self._drive_one(i, dt)
            return
        t = self.table
        lane, speed, heading = self.lane[rows], self.speed[rows], self.heading[rows]
        limit = self.max_steer[rows]
        steer = keeping_steering(t.heading_at(lane, self.s[rows] + speed * LANE_KEEPING_TAU_S), self.lat[rows],
                                 heading, speed, self.wheelbase[rows], limit)
        keeps = self.keeps[rows]
        if not keeps.all():
            steer = np.where(keeps, steer, np.clip(self.cmd_steer[rows], -limit, limit))
        steer = np.where(self.crashed[rows], 0.0, steer)  # highway-env: a crashed vehicle steers no more
        x, y, heading, new_speed = integrate(self.x[rows], self.y[rows], heading, speed, steer, self.acc[rows], dt,
                                             self.wheelbase[rows], self.rear_offset[rows])
        self.x[rows], self.y[rows], self.heading[rows] = x, y, heading
        self.speed[rows], self.steer[rows] = np.maximum(new_speed, 0.0), steer
        self.timer[rows] += dt
        self._project(rows, self.s[rows] + speed * dt)
        self.locate(rows)

    def _drive_one(self, i: int, dt: float) -> None:
        """`drive` of row i with floats."""
        t = self.table
        lane, s, speed, heading = int(self.lane[i]), float(self.s[i]), float(self.speed[i]), float(self.heading[i])
        limit, wheelbase = float(self.max_steer[i]), float(self.wheelbase[i])
        if self.crashed[i]:
            steer = 0.0
        elif self.keeps[i]:
            steer = keeping_steering(t.heading_one(lane, s + speed * LANE_KEEPING_TAU_S), float(self.lat[i]), heading,
                                     speed, wheelbase, limit, FLOATS)
        else:
            steer = min(max(float(self.cmd_steer[i]), -limit), limit)
        x, y, heading, new_speed = integrate(float(self.x[i]), float(self.y[i]), heading, speed, steer,
                                             float(self.acc[i]), dt, wheelbase, float(self.rear_offset[i]), FLOATS)
        self.x[i], self.y[i], self.heading[i] = x, y, heading
        self.speed[i], self.steer[i] = max(new_speed, 0.0), steer
        self.timer[i] += dt
        guess = s + speed * dt
        while True:  # `_project`
            s, lat, settled = t.project_one(lane, guess, x, y)
            if s > t.length[lane] and self.route_pos[i] < self.route_end[i]:
                guess = s - t.length[lane]
                self.route_pos[i] += 1
                lane = self.lane[i] = self.routes[i][self.route_pos[i]]
                self.dirty.add(i)
            elif settled:
                break
            else:
                guess = s
        self.s[i], self.lat[i] = s, lat
        self.at_lane[i], self.at_s[i], self.at_lat[i] = lane, s, lat
        if not on_lane(t.width[lane], t.length[lane], s, lat, t.heading_one(lane, s), heading):
            self._locate_off(i)

    def locate(self, rows: np.ndarray) -> None:
        """`at_lane`, `at_s`, `at_lat` of controlled `rows`: where a row is on its route lane
        (`network.on_lane`, the test `MapNetwork.locate` puts to its hint), that lane; off it (a
        lane change under way, past its route's end, steering itself elsewhere) the lane
        `MapNetwork.locate` finds with the route lane as the hint."""
        t = self.table
        lane, s, lat = self.lane[rows], self.s[rows], self.lat[rows]
        self.at_lane[rows], self.at_s[rows], self.at_lat[rows] = lane, s, lat
        on = on_lane(t.width[lane], t.length[lane], s, lat, t.heading_at(lane, s), self.heading[rows])
        for i in rows[~on].tolist():
            self._locate_off(i)

    def _locate_off(self, i: int) -> None:
        """`locate` of a row off its route lane."""
        net = self.net
        found, s, lat = net.locate(np.array([self.x[i], self.y[i]]), float(self.heading[i]), net._indices[self.lane[i]])
        self.at_lane[i], self.at_s[i], self.at_lat[i] = self.table.index[net.id_of[found]], s, lat

    def _project(self, rows: np.ndarray, guess: np.ndarray) -> None:
        """(s, lat) of `rows` on their route lanes near arc length `guess` (`LaneTable.
        project_near`), a row whose centre is past its lane's end moving on along its route
        (projected again there)."""
        t = self.table
        while len(rows):
            lane = self.lane[rows]
            s, lat, settled = t.project_near(lane, guess, self.x[rows], self.y[rows])
            self.s[rows], self.lat[rows] = s, lat
            over = (s > t.length[lane]) & (self.route_pos[rows] < self.route_end[rows])
            for i in rows[over].tolist():
                self.route_pos[i] += 1
                self.lane[i] = self.routes[i][self.route_pos[i]]
                self.dirty.add(i)
            again = over | ~settled
            rows, guess = rows[again], np.where(over, s - t.length[lane], s)[again]

    def _place_rows(self, rows: np.ndarray) -> None:
        if not len(rows):
            return
        lane, s, lat = self.lane[rows], self.s[rows], self.lat[rows]
        x, y, h = self.table.place(lane, s, lat)
        changing = np.abs(lat) > 1e-3
        if changing.any():  # (else the term below adds 0 to every heading)
            settle = lat * (-1.0 / LANE_CHANGE_TAU_S)  # lateral speed of a settling lane change
            h = h + np.arctan2(settle, np.maximum(self.speed[rows], 0.1)) * changing
        self.x[rows], self.y[rows], self.heading[rows] = x, y, h

    def may_leave(self) -> np.ndarray:
        """[slots] bool: whether a slot may hold traffic that finished its route or crashed (a
        driven row crashed or finished, or an external traffic vehicle), so that a respawn looks
        at its vehicles; False: none did."""
        rows = (self.crashed & ~self.controlled) | ~self.driven
        rows[~self.driven] = [isinstance(self.objs[i], TrafficVehicle) for i in (~self.driven).nonzero()[0].tolist()]
        last = (self.driven & ~self.controlled & ~rows & (self.route_pos >= self.route_end)).nonzero()[0]
        if len(last):  # `TrafficVehicle.finished` of each
            ends = np.array([self.routes[i][-1] for i in last.tolist()], dtype=np.int64)
            rows[last] = route_finished(self.s[last], self.table.length[ends])
        return np.bincount(self.env[rows], minlength=len(self.roads)) > 0

    def externals(self, road) -> list[Any]:
        return [self.objs[i] for i in self.rows(road).tolist() if self.kind[i] == EXTERNAL]

    def views(self, road) -> list[ArrayVehicle]:
        return [self.objs[i] for i in self.rows(road).tolist() if self.kind[i] == DRIVEN]

    def stop_queues(self, slot: int) -> dict[Any, list]:
        """`sim.stop_signs.queues` of `slot` (what `TrafficRules.stop_queue` hands out)."""
        return stop_signs.queues(self, slot)

    def stop_turns(self, rows: np.ndarray, j_lane: np.ndarray) -> np.ndarray:
        """`sim.stop_signs.turns`: whose turn it is at a stop sign (what `TrafficRules.stop_queue_allows` asks)."""
        return stop_signs.turns(self, rows, j_lane)

    def where_lanes(self, rows: np.ndarray | None = None) -> np.ndarray:
        """Per row (of `rows`, default every row), the lane it is on: a controlled row's located
        lane (`locate`), another's its lane."""
        if rows is None:
            return np.where(self.controlled, self.at_lane, self.lane)
        return np.where(self.controlled[rows], self.at_lane[rows], self.lane[rows])

    def _all_pairs(self, n: int, m: int) -> tuple[np.ndarray, np.ndarray]:
        """Every (i, j) with i < n, i < j < m, grouped by i (`np.triu_indices`), kept for the last (n, m)."""
        held = getattr(self, "_pairs_held", None)
        if held is None or held[0] != (n, m):
            held = self._pairs_held = ((n, m), np.triu_indices(n, 1, m))
        return held[1]

    def judge_start(self, row: int, arrives: bool, agent: bool) -> None:
        """A judge for controlled row `row` (`sim.judge.start`)."""
        judge.start(self, row, arrives, agent)

    def judge(self, rows: np.ndarray) -> None:
        """Judge controlled `rows` after a frame (`sim.judge.check`: every env's judge)."""
        judge.check(self, rows)

    def judge_due(self, rows: np.ndarray) -> np.ndarray:
        """Mask over controlled rows `rows`: those whose judge (`rules.EgoJudge.check`) can change
        anything after this frame. Its check does something only on a lane other than the one it
        last looked at the row on (entering a junction), at a stop, moving on a crosswalk's stretch of
        its lane with people on that crosswalk (`sim.crossings.peopled_stretch`), on a lane with a
        mid-block crossing's line, on the route's last lane (arrived), past the end of its lane or
        wide of it (off the road); elsewhere it leaves the judge as it was, so the judges of the
        other rows are not asked (the same verdicts). Notes the rows' lanes as looked at."""
        t, lane = self.table, self.at_lane[rows]
        speed = self.speed[rows]
        due = (lane != self.judged[rows]) | has_stopped(speed) | t.midblock[lane] \
            | (self.route_pos[rows] >= self.route_end[rows]) | (self.at_s[rows] > t.length[lane]) \
            | (np.abs(self.at_lat[rows]) > t.width[lane] / 2 + OFF_ROAD_LATERAL_M)
        walk = ~due & t.crossing[lane] & (speed > PEDESTRIAN_YIELD_SPEED_MPS)
        if walk.any():
            k = walk.nonzero()[0]
            due[k] = crossings.peopled_stretch(self, self.env[rows[k]], lane[k], self.at_s[rows[k]])
        self.judged[rows] = lane
        return due

    def collisions(self, roads: list, dt: float) -> None:
        """Crash flags and hits on `roads`: a vectorized centre-distance broad phase over the
        vehicles and pedestrians of each road, highway-env's `handle_collisions` (polygons) for
        the close pairs."""
        rows = self.on.nonzero()[0]
        if not len(rows):  # (objects never meet each other)
            return
        objects: list = []
        where: list[int] = []  # (each object's slot)
        for road in roads:  # (each road once: a batch's roads are many, their objects few)
            if road.objects:
                objects += road.objects
                where += [road.slot] * len(road.objects)
        x, y, speed = self.x[rows], self.y[rows], np.abs(self.speed[rows])
        diag = np.hypot(self.length[rows], self.width[rows])
        env = self.env[rows]
        n = len(x)
        if objects:
            # a walker's place is read from the core's walker arrays, another object's from it
            walker = [o._row if type(o) is Pedestrian and o._core is self else -1 for o in objects]
            w = np.array(walker, dtype=np.int64)
            ox, oy = np.zeros(len(w)), np.zeros(len(w))
            real = w >= 0
            ox[real], oy[real] = self.p_x[w[real]], self.p_y[w[real]]
            for k in (~real).nonzero()[0].tolist():
                ox[k], oy[k] = objects[k].position
            x, y = np.concatenate([x, ox]), np.concatenate([y, oy])
            diag = np.concatenate([diag, [o.diagonal for o in objects]])
            speed = np.concatenate([speed, np.zeros(len(objects))])
            env = np.concatenate([env, where])
        single = len(self.roads) == 1
        if single:  # one slot: every pair (in the order of a rows x rows matrix)
            a, b = self._all_pairs(n, len(env))
        else:  # the pairs of a slot near each other along x
            a, b = near_in_x(x, env, n, float(diag.max() + speed.max() * dt))
        reach = (diag[a] + diag[b]) / 2 + speed[a] * dt
        close = (np.abs(x[a] - x[b]) <= reach) & (np.abs(y[a] - y[b]) <= reach)
        a, b = a[close], b[close]
        if not len(a):
            return
        if not single:
            order = np.lexsort((b, a))  # in the order of a (rows x rows) matrix
            a, b = a[order], b[order]
        # two driven rows (most close pairs: neighbours side by side, queues): their rectangles
        # by separating axes; pairs with external road users or pedestrians go straight to
        # highway-env (impacts, hits)
        both = (b < n)
        both[both] = self.driven[rows[a[both]]] & self.driven[rows[b[both]]]
        keep = ~both
        if both.any():
            keep[both] = rectangles_overlap(self, rows[a[both]], rows[b[both]])
        objs = self.objs
        one = lambda k: objs[rows[k]] if k < n else objects[k - n]  # noqa: E731
        for i, j in zip(a[keep].tolist(), b[keep].tolist()):
            one(i).handle_collisions(one(j), dt)


def near_in_x(x: np.ndarray, slot: np.ndarray, n: int, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """Every (i, j), i < j, i < n (the first n are road users, the others objects, which never
    meet each other), of one slot with |x[i] - x[j]| <= reach: a sweep along x within each slot
    (sorted by slot, then x), not every pair of a slot."""
    low = x.min()
    key = slot * (float(x.max() - low) + 2 * reach + 1.0) + (x - low)  # (slots apart by more than the reach)
    order = key.argsort()
    key = key[order]
    end = key.searchsorted(key + reach * (1 + 1e-9) + 1e-6, side="right")  # (a margin: the filter is exact after)
    p, q = entries.expand_ranges(np.arange(1, len(key) + 1), end)  # (each end is past its own place)
    i, j = order[p], order[q]
    a, b = np.minimum(i, j), np.maximum(i, j)
    keep = a < n
    return a[keep], b[keep]


def rectangles_overlap(core: TrafficCore, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Whether the footprints of rows a and b overlap (separating axes of two rectangles: the four
    axes of each pair at once)."""
    h = np.concatenate([core.heading[a], core.heading[b]])
    c, s = np.cos(h), np.sin(h)
    n = len(a)
    ca, sa, cb, sb = c[:n], s[:n], c[n:], s[n:]
    dx, dy = core.x[b] - core.x[a], core.y[b] - core.y[a]
    la, wa, lb, wb = core.length[a] / 2, core.width[a] / 2, core.length[b] / 2, core.width[b] / 2
    axes_x, axes_y = np.empty((2, 2, n)), np.empty((2, 2, n))  # (ca, -sa, cb, -sb), (sa, ca, sb, cb)
    c2, s2 = c.reshape(2, n), s.reshape(2, n)
    axes_x[:, 0], axes_y[:, 0], axes_y[:, 1] = c2, s2, c2
    np.negative(s2, out=axes_x[:, 1])
    ux, uy = axes_x.reshape(4, n), axes_y.reshape(4, n)  # [axes, pairs]
    reach = la * np.abs(ca * ux + sa * uy) + wa * np.abs(-sa * ux + ca * uy) + \
        lb * np.abs(cb * ux + sb * uy) + wb * np.abs(-sb * ux + cb * uy)
    return (np.abs(dx * ux + dy * uy) <= reach).all(axis=0)
