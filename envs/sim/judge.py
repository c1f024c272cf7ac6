"""The judge (docs/architecture.md, "judge"): the violations of controlled rows (the ego's, each
agent's) and their leaving the road, after a frame, as one program over the rows due
(`TrafficCore.judge_due`), for every env; `rules.EgoJudge` is a row's view of it.

- red_light: the row crossed a signal's stop line into the junction while red (amber is allowed;
  with `right_turn_on_red`, a right turn after a full stop is too), or a mid-block crossing's
  line on red;
- stop_sign: it entered without a full stop (speed <= STOPPED_SPEED_MPS within STOP_ZONE_M of
  the line, along its route);
- pedestrian_yield: it moved on a crosswalk with a pedestrian in its path;
- off road: wide of its lane, or past the end of a lane without successors;
- agents (`j_agent`): not_yielding and stop_order, when the row enters the junction lane whose
  verdict was noted before it (`multi_agent.AgentJudge.note`) against that verdict.

What a judge keeps to find more are row columns: the lane and place it last looked at the row
on (`j_lane`, `j_s`), and four small sets as columns of ints (-1: empty; widened when a row's
set is full): the incoming lanes whose line the row stopped at (`j_stop`, kept until it is on
another road lane), the road lanes it entered a junction from (`j_cross`, likewise), the
mid-block lines crossed on red (`j_mid`: signal * lanes + lane) and the crosswalks it was
flagged at (`j_ped`: lane * crosswalks + crosswalk), both for the episode. Route walks (the
lane a junction was entered from, the turn after it) are made only for the rows that entered a
junction lane this frame."""
from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ...config import OFF_ROAD_END_M, OFF_ROAD_LATERAL_M, PEDESTRIAN_YIELD_SPEED_MPS
from .. import task
from ..info_columns import facts_of, line_distance
from ..network import LINE_SIGNAL, LINE_STOP_SIGN, MapNetwork
from ..rules import JUDGED, SIGNAL_STATES, has_stopped, in_stop_zone, on_yield_stretch, pedestrian_in_path
from . import crossings

if TYPE_CHECKING:
    from ..core import TrafficCore

SETS = ("j_stop", "j_cross", "j_mid", "j_ped")  # a judge's sets, as row columns of the core
RED_LIGHT, STOP_SIGN, PEDESTRIAN_YIELD, NOT_YIELDING, STOP_ORDER = (
    JUDGED.index(k) for k in ("red_light", "stop_sign", "pedestrian_yield", "not_yielding", "stop_order"))
_RED = SIGNAL_STATES.index("red")


@dataclass(frozen=True)
class JudgeTable:
    """Per lane (`MapNetwork.lane_ids` order): its stop line's s (NaN without one), whether it has
    no successor (where running past its end is leaving the road), and its mid-block lines
    `mid_start[lane]` up to `mid_start[lane] + mid_count[lane]` in `mid_signal` (the light: an
    index of `LaneTable.signal_ids`, -1 without a plan) and `mid_s`."""
    line_s: np.ndarray
    dead_end: np.ndarray
    mid_start: np.ndarray
    mid_count: np.ndarray
    mid_signal: np.ndarray
    mid_s: np.ndarray


def judge_table(net: MapNetwork, signal_index: dict[str, int]) -> JudgeTable:
    """The judge's table of `net` (a memo of the network's)."""
    def build() -> JudgeTable:
        m = net.hdmap
        lines = [net.midblock_lines.get(lid, ()) for lid in net.lane_ids]
        count = np.array([len(x) for x in lines], dtype=np.int64)
        flat = [x for row in lines for x in row]
        return JudgeTable(
            np.array([net.stop_lines[lid].s if lid in net.stop_lines else np.nan for lid in net.lane_ids]),
            np.array([not m.lanes[lid].successors for lid in net.lane_ids]),
            np.concatenate([[0], np.cumsum(count)[:-1]]).astype(np.int64), count,
            np.array([signal_index.get(sid, -1) for sid, _ in flat], dtype=np.int64),
            np.array([s for _, s in flat], dtype=float))
    return net.memo("judge table", build)


def start(core: "TrafficCore", row: int, arrives: bool, agent: bool) -> None:
    """A judge for controlled row `row`, looking from where it stands, with nothing found yet:
    with `arrives` it stops judging once the row has completed its route; `agent`: it judges
    the agents' two violations too."""
    core.j_done[row], core.j_arrives[row], core.j_agent[row] = False, arrives, agent
    core.j_lane[row], core.j_s[row] = core.at_lane[row], core.at_s[row]
    for name in SETS:
        getattr(core, name)[row] = -1
    core.v_lane[row], core.v_clear[row], core.v_order[row] = -1, True, True


def check(core: "TrafficCore", rows: np.ndarray) -> None:
    """Judge controlled `rows` (row indices) after a frame: the one program of every env's judge.
    A row whose judge is done (its route completed, with `j_arrives`) is no longer judged: frames
    after the goal within the same policy step are no part of the drive (a goal on a 4.9 m road
    1 m before a red line, osm2xodr's karl-wilhelm r027: at 12 m/s the ego passed both within
    one step, and the line was judged)."""
    rows = rows[~core.j_done[rows]]
    arriving = core.j_arrives[rows]
    if arriving.any():
        done = np.zeros(len(rows), dtype=bool)
        done[arriving] = task.completed(core, rows[arriving])
        core.j_done[rows[done]] = True
        rows = rows[~done]
    if not len(rows):
        return
    t = core.table
    lid, prev, s, speed = core.at_lane[rows], core.j_lane[rows], core.at_s[rows], core.speed[rows]
    junction = t.junction[lid]
    agents = core.j_agent[rows].any()
    reds = core.new_violations[rows, RED_LIGHT].copy() if agents else rows[:0]
    k = has_stopped(speed).nonzero()[0]
    stops = core.j_stop[rows]  # on a road lane, the stops made before another line are let go
    tidy = (~junction & ((stops >= 0) & (stops != lid[:, None])).any(axis=1)).nonzero()[0]
    if len(k) or len(tidy):  # the incoming lane of the entry ahead (`TrafficRules.line_ahead`)
        facts = facts_of(core, rows)
        cols = core.route_facts.arrays()
        ahead_in = np.where(cols["has_line"][facts], cols["in_lane"][facts], -1)
    # a full stop at a line (`TrafficRules.waiting_line`): its own lane's, else the next entry's within the zone
    if len(k):
        jt = judge_table(core.net, t.signal_index)
        own = (t.line_kind[lid[k]] > 0) & in_stop_zone(jt.line_s[lid[k]] - s[k])
        control = cols["control"][facts[k]]
        kind = np.where(control == "stop", LINE_STOP_SIGN, np.where(control == "signal", LINE_SIGNAL, 0))
        d = line_distance(core, rows[k], facts[k])
        ahead = (kind > 0) & in_stop_zone(d)
        in_lane = np.where(own, lid[k], np.where(ahead, ahead_in[k], -1))
        kind = np.where(own, t.line_kind[lid[k]], kind)
        ok = (in_lane >= 0) & ((kind == LINE_STOP_SIGN) | core.rtor[core.env[rows[k]]])
        add(core, "j_stop", rows[k[ok]], in_lane[ok])
    # on a road lane: the stops count until the row is on another road lane, or past the next
    # line; the crossings until it is on another road lane
    if len(tidy):
        keep_only(core, "j_stop", rows[tidy], lid[tidy], ahead_in[tidy])
    crossed = core.j_cross[rows]
    k = (~junction & ((crossed >= 0) & (crossed != lid[:, None])).any(axis=1)).nonzero()[0]
    if len(k):
        keep_only(core, "j_cross", rows[k], lid[k], lid[k])
    # into a junction: the line crossed (a flicker across it is one crossing)
    k = ((lid != prev) & (prev >= 0) & junction).nonzero()[0]
    if len(k):
        _entered(core, rows[k], lid[k], prev[k])
    # a mid-block crossing's line crossed on red (on the lane, or at the lane change onto it)
    k = t.midblock[lid].nonzero()[0]
    if len(k):
        _midblock(core, rows[k], lid[k], np.where(lid[k] == prev[k], core.j_s[rows[k]], -np.inf), s[k])
    core.j_lane[rows], core.j_s[rows] = lid, s
    # moving on a crosswalk's stretch with a pedestrian in its path
    k = (t.crossing[lid] & (speed > PEDESTRIAN_YIELD_SPEED_MPS)).nonzero()[0]
    if len(k):
        _pedestrians(core, rows[k], lid[k], s[k])
    wide = np.abs(core.at_lat[rows]) > t.width[lid] / 2 + OFF_ROAD_LATERAL_M
    past = (s > t.length[lid] + OFF_ROAD_END_M) & judge_table(core.net, t.signal_index).dead_end[lid]
    core.off_road[rows[wide | past]] = True
    if agents:
        k = (core.j_agent[rows] & (lid != prev) & junction & ((prev < 0) | ~t.junction[np.maximum(prev, 0)])).nonzero()[0]
        if len(k):
            _verdicts(core, rows[k], lid[k], core.new_violations[rows[k], RED_LIGHT] > reds[k])


def _entered(core: "TrafficCore", rows: np.ndarray, lid: np.ndarray, prev: np.ndarray) -> None:
    """Rows that moved onto junction lanes `lid` from `prev`: through the line of the road lane
    they entered from, a red light unless turning right on red after a full stop, a stop sign
    without one."""
    t, ids = core.table, core.net.lane_ids
    entry = np.array([_entry_lane(core, r, int(j), int(p)) for r, j, p in zip(rows.tolist(), lid, prev)],
                     dtype=np.int64)
    new = ~member(core, "j_cross", rows, entry)
    rows, entry = rows[new], entry[new]
    add(core, "j_cross", rows[~t.junction[entry]], entry[~t.junction[entry]])
    kind, stopped = t.line_kind[entry], member(core, "j_stop", rows, entry)
    red = (kind == LINE_SIGNAL) & is_red(core, core.env[rows], t.line_signal[entry])
    turn = red & core.rtor[core.env[rows]] & stopped
    for n in turn.nonzero()[0].tolist():  # (a full stop made at a red light: right on red)
        red[n] = _turn_after(core, int(rows[n]), ids[entry[n]]) != "right"
    violate(core, rows[red], RED_LIGHT)
    violate(core, rows[(kind == LINE_STOP_SIGN) & ~stopped], STOP_SIGN)


def _midblock(core: "TrafficCore", rows: np.ndarray, lid: np.ndarray, before: np.ndarray, s: np.ndarray) -> None:
    """Rows on lanes `lid` with mid-block lines: each line between `before` and `s` crossed on
    red, once an episode (per light and lane)."""
    jt = judge_table(core.net, core.table.signal_index)
    n = jt.mid_count[lid]
    q = np.arange(len(rows)).repeat(n)
    c = jt.mid_start[lid].repeat(n) + np.arange(int(n.sum())) - (np.cumsum(n) - n).repeat(n)
    key = np.maximum(jt.mid_signal[c], 0) * len(core.table.length) + lid[q]  # (a light without a plan is never red)
    hit = (before[q] < jt.mid_s[c]) & (jt.mid_s[c] <= s[q]) & is_red(core, core.env[rows[q]], jt.mid_signal[c])
    hit &= ~member(core, "j_mid", rows[q], key)
    q, key = q[hit], key[hit]
    if len(q):
        _, first = np.unique(q * (key.max() + 1) + key, return_index=True)  # (a line named twice counts once)
        q, key = q[first], key[first]
        add(core, "j_mid", rows[q], key)
        violate(core, rows[q], RED_LIGHT)


def _pedestrians(core: "TrafficCore", rows: np.ndarray, lid: np.ndarray, s: np.ndarray) -> None:
    """Rows moving on lanes `lid` with crossings: a crossing whose stretch it is on
    (`rules.on_yield_stretch`) with a walker in its path within its length along the lane
    (`sim.crossings.walkers`, as the yield rule sees them), once an episode per (lane,
    crosswalk)."""
    q, c, _, sp, rp = crossings.walkers(core, core.env[rows], lid)
    if not len(q):
        return
    t = crossings.crossing_table(core.net)
    near = pedestrian_in_path(rp, core.table.width[lid[q]]) & (np.abs(sp - s[q]) < core.length[rows[q]])
    near &= on_yield_stretch(s[q], t.s0[c], t.s1[c])
    key = lid[q] * len(core.crosswalks.ids) + t.cw[c]
    near &= ~member(core, "j_ped", rows[q], key)
    q, c, key = q[near], c[near], key[near]
    if len(q):
        _, first = np.unique(q * (c.max() + 1) + c, return_index=True)  # (a crossing counts once, whoever is on it)
        q, key = q[first], key[first]
        add(core, "j_ped", rows[q], key)
        violate(core, rows[q], PEDESTRIAN_YIELD)


def _verdicts(core: "TrafficCore", rows: np.ndarray, lid: np.ndarray, red: np.ndarray) -> None:
    """Agents' rows that entered junction lanes `lid` from a road lane: against the verdict noted
    for that lane (unless that entry ran a red light), a stop_order or not_yielding; the verdict
    is used up."""
    noted = (core.v_lane[rows] == lid) & ~red
    violate(core, rows[noted & ~core.v_order[rows]], STOP_ORDER)
    violate(core, rows[noted & core.v_order[rows] & ~core.v_clear[rows]], NOT_YIELDING)
    core.v_lane[rows], core.v_clear[rows], core.v_order[rows] = -1, True, True


def _entry_lane(core: "TrafficCore", row: int, junction_lane: int, prev: int) -> int:
    """The road lane row `row` entered `junction_lane` from: its route lane before it (a lane
    short enough to be driven over within a frame is never located), else `prev`."""
    route, pos = core.routes[row], int(core.route_pos[row])
    for k in range(min(pos + 1, len(route) - 1), 0, -1):
        if route[k] == junction_lane:
            return route[k - 1] if not core.table.junction[route[k - 1]] else prev
    return prev


def _turn_after(core: "TrafficCore", row: int, lane_id: str) -> str | None:
    """The turn of row `row`'s route lane after `lane_id` (None when not on the route): the
    latest occurrence at or before the row (routes round a ring repeat lanes)."""
    route, pos = core.route_ids[row], int(core.route_pos[row])
    k = next((i + 1 for i in range(min(pos, len(route) - 1), -1, -1) if route[i] == lane_id), len(route))
    return core.net.hdmap.lanes[route[k]].turn if k < len(route) else None


def is_red(core: "TrafficCore", slots: np.ndarray, signals: np.ndarray) -> np.ndarray:
    """Whether each signal (`LaneTable.signal_ids` index; -1: none, never red) is red in its
    slot now (`TrafficCore.signal_codes`, what the rules' `signal_state` reads)."""
    out = signals >= 0
    if out.any():
        k = out.nonzero()[0]
        codes = core.signal_codes(int(slots[0])) if len(core.roads) == 1 else None
        out[k] = (codes[signals[k]] if codes is not None else core.signal_codes()[slots[k], signals[k]]) == _RED
    return out


def violate(core: "TrafficCore", rows: np.ndarray, kind: int) -> None:
    """Count a violation of `kind` (a JUDGED index) for each of `rows` (a row may repeat)."""
    if len(rows):
        np.add.at(core.violations[:, kind], rows, 1)
        np.add.at(core.new_violations[:, kind], rows, 1)


def member(core: "TrafficCore", name: str, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Whether each value is in its row's set `name`."""
    return (getattr(core, name)[rows] == values[:, None]).any(axis=1) & (values >= 0)


def add(core: "TrafficCore", name: str, rows: np.ndarray, values: np.ndarray) -> None:
    """Put each value in its row's set `name` (a value already there stays once), the set's
    columns widened where a row has no room; a row named more than once takes its values in
    turns."""
    while len(rows):
        turn = np.zeros(len(rows), dtype=bool)
        turn[np.unique(rows, return_index=True)[1]] = True
        r, v = rows[turn], values[turn]
        new = ~member(core, name, r, v)
        r, v = r[new], v[new]
        sets = getattr(core, name)
        free = sets[r] < 0
        if len(r) and not free.any(axis=1).all():
            sets = np.hstack([sets, np.full((len(sets), sets.shape[1]), -1, dtype=sets.dtype)])
            setattr(core, name, sets)
            free = sets[r] < 0
        sets[r, free.argmax(axis=1)] = v
        rows, values = rows[~turn], values[~turn]


def keep_only(core: "TrafficCore", name: str, rows: np.ndarray, a: np.ndarray, b: np.ndarray) -> None:
    """Keep of each row's set `name` only the values a and b of that row."""
    sets = getattr(core, name)
    held = sets[rows]
    sets[rows] = np.where((held == a[:, None]) | (held == b[:, None]), held, -1)
