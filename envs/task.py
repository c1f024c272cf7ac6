"""A controlled row's task (the ego's, an agent's) as row arrays of the core, and what a step of
it is worth, asked of every controlled row of a batch at once (the single env's ego is a batch
of one).

The task's row arrays (`TrafficCore`; unused for traffic): `progress` the route metres at the
last reward, `goal` the route metres to the goal (both set when the task starts), `goal_dist`
the config's goal_distance; `behind` the route metres of the lanes before the row's route
position and `goal_s` the s on the route's last lane from which the route is completed, found
again (in Python, one row at a time) only when the row's route or position changed since
(`task_key`)."""
from __future__ import annotations

import operator
from typing import Any

import numpy as np

from ..routes import first_tight_bend
from .rules import VIOLATIONS

REWARD_TERMS = ("progress", "arrived", "collision", "off_road", *VIOLATIONS)  # the ego's reward terms, in order
_ROUTE_POSITIONS = 1 << 32  # `task_key`: route version * this + route position
WEIGHTED_ARRAY_ROWS = 16  # rows from which `weighted` sums as arrays (fewer: Python floats, the same sums)


def goal_s(net: Any, lane: Any, goal_distance: float) -> float:
    """The goal on a route's last lane: `goal_distance` into it, at most a metre before its end,
    and never past its first bend tighter than a car turns (`first_tight_bend`): no car follows
    the lane there. osm2xodr folds the lanes of a road at the map's edge into one point
    (digitaf's `w648817642_1_0_-1` turns 75 degrees 0.6 m after its start, radius 2.7 m): the
    ego driving on to a goal beyond swung over the lane beside it (r214)."""
    bend = net.memo(("first tight bend", lane.lane_id), lambda: max(first_tight_bend(lane.points), 0.0))
    return min(float(goal_distance), lane.length - 1.0, bend)


def start(core: Any, row: int, goal_distance: float) -> None:
    """The task of controlled row `row` starts where the row stands: its progress is the route
    metres done, its goal `goal_distance` into the route's last lane (`goal_s`)."""
    core.goal_dist[row] = goal_distance
    core.task_key[row] = -1
    core.progress[row] = route_done(core, row)
    net, route = core.net, core.route_ids[row]
    last = net.lane_of[route[-1]]
    core.goal[row] = sum(net.lane_of[x].length for x in route) - last.length + core.goal_s[row]


def changed_rows(core: Any, rows: Any, held: np.ndarray) -> list[int]:
    """The rows of `rows` (an array, or one row: an int) whose route or route position changed
    since `held` (a row array of route keys: `task_key`, `info_key`) noted them; noted now. A
    route key is the row's route version and route position as one int."""
    key = core.route_ver[rows] * _ROUTE_POSITIONS + core.route_pos[rows]
    stale = key != held[rows]
    if not (stale if isinstance(rows, int) else stale.any()):
        return []
    held[rows] = key
    return np.atleast_1d(rows)[np.atleast_1d(stale)].tolist()


def _refresh(core: Any, rows: Any) -> None:
    """`behind` and `goal_s` of the rows (an array, or one row: an int) whose route or route
    position changed since they were found."""
    net = core.net
    for i in changed_rows(core, rows, core.task_key):
        route, pos = core.route_ids[i], int(core.route_pos[i])
        core.behind[i] = sum(net.lane_of[x].length for x in route[:pos])
        core.goal_s[i] = goal_s(net, net.lane_of[route[-1]], core.goal_dist[i])


def route_done(core: Any, rows: Any, fresh: bool = False) -> Any:
    """Route metres each of `rows` (an array, or one row: an int, for a float) has driven: the
    lanes behind plus its place on its route lane (within the lane); `fresh`: `behind` is
    known to be up to date."""
    if not fresh:
        _refresh(core, rows)
    s, length = core.s[rows], core.table.length[core.lane[rows]]
    if isinstance(rows, int):  # (numpy scalars: the builtins take the same values, without a ufunc's fixed cost)
        return core.behind[rows] + min(max(s, 0.0), length)
    return core.behind[rows] + np.minimum(np.maximum(s, 0.0), length)


def completed(core: Any, rows: Any, fresh: bool = False) -> Any:
    """Whether each of `rows` (an array, or one row: an int, for a bool) has completed its route:
    on the route's last lane, at least `goal_s` into it (`fresh`: as `route_done`'s)."""
    if isinstance(rows, int) and core.route_pos[rows] < core.route_end[rows]:
        return False  # (one row short of its last lane: nothing to look up)
    if not fresh:
        _refresh(core, rows)
    return (core.route_pos[rows] >= core.route_end[rows]) & (core.s[rows] >= core.goal_s[rows])


def route_state(core: Any, rows: Any) -> tuple[Any, Any]:
    """(`route_done`, `completed`) of `rows` (an array, or one row: an int)."""
    _refresh(core, rows)
    return route_done(core, rows, fresh=True), completed(core, rows, fresh=True)


def reward_terms(core: Any, rows: Any, done: Any, arrived: Any, off_road: Any) -> np.ndarray:
    """[rows, REWARD_TERMS] (one row, an int: [REWARD_TERMS]): this step's reward terms of each of
    `rows`, given its route metres `done`, whether it `arrived` and left the road (`off_road`),
    with its judge's violations this step (`TrafficCore.new_violations`); each row's progress
    moves on to `done`."""
    terms = np.zeros(len(REWARD_TERMS) if isinstance(rows, int) else (len(rows), len(REWARD_TERMS)))
    terms[..., 0] = (done - core.progress[rows]) / (max(core.goal[rows], 1e-6) if isinstance(rows, int)
                                                     else np.maximum(core.goal[rows], 1e-6))
    terms[..., 1] = arrived
    terms[..., 2] = core.crashed[rows]
    terms[..., 3] = off_road
    terms[..., 4:] = core.new_violations[rows, :len(VIOLATIONS)]
    core.progress[rows] = done
    return terms


def weighted(terms: np.ndarray, weights: Any) -> np.ndarray:
    """Per row, sum(weight * term) over the terms in their order (a sum term by term: the float
    operations of one row's sum; under WEIGHTED_ARRAY_ROWS rows as Python floats, the same
    operations). `weights`: an array, or a row of weights per row of `terms`."""
    if len(terms) < WEIGHTED_ARRAY_ROWS:
        return np.array([sum(map(operator.mul, w, t)) for w, t in zip(weights, terms.tolist())], dtype=float)
    weights = np.asarray(weights, dtype=float)
    reward = np.zeros(len(terms))
    for k in range(terms.shape[1]):
        reward = reward + weights[:, k] * terms[:, k]
    return reward


def ended(crashed: Any, completed: Any, off_road: Any, offroad_terminal: Any) -> Any:
    """Whether each task ended (bools or arrays): a crash, the route completed, or off the road
    where that ends it (`offroad_terminal`)."""
    return crashed | completed | (offroad_terminal & off_road)


def route_progress(core: Any, rows: Any, done: Any) -> Any:
    """The fraction of the route to the goal each of `rows` (an array, or one row: an int) has
    driven, given its route metres `done` (0..1)."""
    if isinstance(rows, int):
        return min(done / max(core.goal[rows], 1e-6), 1.0)
    return np.minimum(done / np.maximum(core.goal[rows], 1e-6), 1.0)
