"""The info values of controlled rows (the ego's, each agent's: `info.INFO_KEYS`), worked out for
every row of a batch at once: a column per key over the rows (`columns`); for one row (an int)
each column is that row's value, in the same operations.

What holds while a row's route position does (the junction ahead, its manoeuvre and feature,
the next stop line's control, signal and the lanes to it, whose signal states to give) is a
route fact: worked out once per stretch of route from a lane up to the next junction entry
(`RouteFacts`), each row holding the index of its fact (`TrafficCore.fact`) as of its
`info_key` (route version and position then).
The rest are gathers from the core's arrays: speed, crash, place, the signals' states and times
to their next change at each slot's clock (`TrafficCore.signal_codes`, `signal_waits_of`)."""
from __future__ import annotations

import math
from typing import Any, NamedTuple, Sequence

import numpy as np

from . import task
from .rules import SIGNAL_STATES, enters_junction, line_plan, manoeuvre_name, violation_names


class Records(NamedTuple):
    """A column whose value in each row is a dict with the same keys (the violation counts): the
    values as one [rows, keys] array; `dicts` makes the rows' dicts, the batched env stacks the
    array's columns."""

    keys: tuple[str, ...]
    values: np.ndarray

    def dicts(self) -> list[dict[str, Any]]:
        return [dict(zip(self.keys, row)) for row in self.values.tolist()]

    def at(self, idx: Any) -> "Records":
        return Records(self.keys, self.values[idx])


def junction_ahead(net: Any, route: Sequence[str], pos: int) -> tuple[str | None, str | None]:
    """(junction id, manoeuvre) of the first junction lane of `route` from position `pos` on
    ((None, None) without one)."""
    lanes = net.hdmap.lanes
    for lid in route[pos:]:
        ln = lanes[lid]
        if ln.junction_id is not None:
            return ln.junction_id, manoeuvre_name(ln, net.ramp_moves)
    return None, None


class RouteFacts:
    """The info facts of the routes of one core's map, an index per distinct rest of a route up
    to its next junction entry (`of`; a map holds few: the table stays small however many
    routes are driven), and their columns (`arrays`): junction ahead, manoeuvre, feature, the
    next stop line's control and signal (id, index in the core's signals or -1), the junction
    whose signal states the info gives (None: all, False: none), the line's setback, whether a
    line is ahead, whether a mid-block crossing's line may be before it (then
    `TrafficRules.midblock_ahead` is asked), the entry's incoming lane (a lane index, -1; the
    judge's), and the lengths of the lanes between the current one and the line's lane
    (`rules.line_plan`; "lengths", 0-padded)."""

    _COLUMNS = ("jid", "turn", "feature", "control", "sig_id", "sig", "states_of", "back", "has_line", "has_mid",
                "in_lane")
    _OBJECTS = ("jid", "turn", "feature", "control", "sig_id", "states_of")

    def __init__(self, core: Any) -> None:
        self.core = core
        self.index: dict[tuple, int] = {}
        self.facts: list[tuple] = []
        self._cols: dict[str, np.ndarray] = {}
        self._made = 0  # facts in `_cols`
        self.groups: dict[tuple[int, Any], tuple] = {}  # `signal_group`s

    def of(self, route: Sequence[str], pos: int) -> int:
        """The index of the fact of `route` from position `pos` on: it depends on the lanes up
        to the next junction entry's lane (without an entry ahead: on the current lane, and on
        whether a mid-block line lies ahead)."""
        net = self.core.net
        lanes = net.hdmap.lanes
        end = next((k + 1 for k in range(pos + 1, len(route)) if enters_junction(lanes, route[k - 1], route[k])), 0)
        if end:
            key: tuple = tuple(route[pos:end])
        else:
            mids = net.midblock_lines
            key = (route[pos], None, bool(mids) and any(lid in mids for lid in route[pos:]))
        k = self.index.get(key)
        if k is None:
            k = self.index[key] = len(self.facts)
            self.facts.append(self._fact(key[:1], key[2]) if not end else self._fact(key))
        return k

    def _fact(self, rest: tuple[str, ...], has_mid: bool | None = None) -> tuple:
        net = self.core.net
        m = net.hdmap
        jid, turn = junction_ahead(net, rest, 0)
        plan = line_plan(net, rest, 0)
        lengths, back, (sl, in_lane, j_lane) = plan if plan[0] is not None else ((), 0.0, (None, None, None))
        control = "" if in_lane is None else (sl.kind if sl else "yield" if j_lane in net.yield_entries else "bare")
        sig_id = sl.control_id if sl is not None and sl.kind == "signal" else ""
        feature = m.junctions[jid].feature if jid is not None and jid in m.junctions else None
        states_of = m.lanes[j_lane].junction_id if j_lane else False
        if has_mid is None:  # (the lanes up to the line's junction lane)
            has_mid = bool(net.midblock_lines) and any(lid in net.midblock_lines for lid in rest)
        sig = self.core.table.signal_index.get(sig_id, -1) if sig_id else -1
        in_lane = self.core.table.index[in_lane] if in_lane is not None else -1
        return (jid or "", turn or "", feature, control, sig_id, sig, states_of, float(back), plan[0] is not None,
                has_mid, in_lane, tuple(lengths))

    def arrays(self) -> dict[str, np.ndarray]:
        """The facts as columns over their indices (new facts written in, the columns grown by
        half again when full)."""
        n, made = len(self.facts), self._made
        if n == made:
            return self._cols
        new = list(zip(*self.facts[made:]))
        width = max(max(len(x) for x in new[-1]), self._cols["lengths"].shape[1] if self._cols else 0)
        if not self._cols or n > len(self._cols["jid"]) or width > self._cols["lengths"].shape[1]:
            size = max(n + n // 2, 16)
            grown = {name: np.empty(size, dtype=object) if name in self._OBJECTS else
                     np.zeros(size, dtype=np.asarray(new[k][0]).dtype) for k, name in enumerate(self._COLUMNS)}
            grown["lengths"] = np.zeros((size, width))
            for name, col in self._cols.items():
                if name == "lengths":
                    grown[name][:made, :col.shape[1]] = col[:made]
                else:
                    grown[name][:made] = col[:made]
            self._cols = grown
        for name, values in zip(self._COLUMNS, new):
            self._cols[name][made:n] = values
        for k, x in enumerate(new[-1], made):
            self._cols["lengths"][k, :len(x)] = x
        self._made = n
        return self._cols


def facts_of(core: Any, rows: Any) -> Any:
    """The route-fact index of each of `rows` (an array, or one row: an int), found again only
    for the rows whose route or route position changed since (`info_key`)."""
    facts = core.route_facts
    for i in task.changed_rows(core, rows, core.info_key):
        core.fact[i] = facts.of(core.route_ids[i], int(core.route_pos[i]))
    return core.fact[rows]


def line_distance(core: Any, rows: Any, f: Any, fact: tuple = ()) -> Any:
    """Route metres from each row's centre to its next stop line (inf without one), summed as
    `TrafficRules.line_ahead` sums them: the rest of the current lane, each lane to the line's,
    less the line's setback. One row: `fact` is its fact."""
    lane_left = core.table.length[core.lane[rows]] - core.s[rows]
    if isinstance(rows, int):
        if not fact[8]:
            return math.inf
        d = float(lane_left)
        for length in fact[-1]:
            d += length
        return d - fact[7]
    a = core.route_facts.arrays()
    lengths = a["lengths"][f]
    d = lane_left
    for k in range(lengths.shape[1]):
        d = d + lengths[:, k]
    return np.where(a["has_line"][f], d - a["back"][f], math.inf)


def signal_group(core: Any, control: Any, states_of: Any) -> tuple[tuple[str, ...], np.ndarray]:
    """(ids, core signal indices, -1 for one without a plan) of the signals whose states an info
    gives for `states_of` (a junction id; None: every signal) under `control`'s phases (its
    `signals_by_junction`, shared by the controls of one phase setting), held per core."""
    by_junction = control.signals_by_junction
    held = core.route_facts.groups.get((id(by_junction), states_of))
    if held is None or held[0] is not by_junction:
        ids = tuple(core.net.hdmap.signals if states_of is None else by_junction.get(states_of, ()))
        index = core.table.signal_index
        held = core.route_facts.groups[(id(by_junction), states_of)] = (
            by_junction, (ids, np.array([index.get(s, -1) for s in ids], dtype=np.int64)))
    return held[1]


def _states(codes: np.ndarray, group: tuple[tuple[str, ...], np.ndarray]) -> dict[str, str]:
    """{signal id: state} of a group given one slot's codes ("green" without a plan)."""
    ids, idx = group
    return {s: SIGNAL_STATES[codes[k]] if k >= 0 else "green" for s, k in zip(ids, idx.tolist())}


_GREEN = len(SIGNAL_STATES)  # `SignalStates`' code of a signal without a plan
_CODE_NAMES = np.array(SIGNAL_STATES + ("green",), dtype=object)  # a state code's name


class SignalStates(NamedTuple):
    """The "signal_states" column of a batch: each row's dict of {signal id: state} as arrays (the
    distinct signal groups `groups`, (ids, core signal indices, -1 for one without a plan); each
    row's group `of`, -1 for {}; its slot; the slots' signal codes). `dicts` makes the rows'
    dicts (each distinct combination of a group's states named once); the batched env stacks it
    a signal at a time (`stacked`), as Gymnasium stacks the dicts."""

    groups: list[tuple[tuple[str, ...], np.ndarray]]
    of: np.ndarray
    slots: np.ndarray
    codes: np.ndarray

    def at(self, idx: Any) -> "SignalStates":
        return SignalStates(self.groups, self.of[idx], self.slots[idx], self.codes)

    def _codes(self, g: int, rows: np.ndarray) -> np.ndarray:
        """[rows, group g's signals]: the state codes of group g's signals at `rows` (`_GREEN` without a plan)."""
        idx = self.groups[g][1]
        return np.where(idx >= 0, self.codes[self.slots[rows][:, None], np.maximum(idx, 0)], _GREEN)

    def dicts(self) -> list[dict[str, str]]:
        out: list[dict] = [{} for _ in range(len(self.of))]
        slots = self.slots.tolist()
        if len(set(slots)) == 1:  # one slot (the multi-agent env's world): one combination per group
            named_g: dict[int, dict] = {}
            for k, g in enumerate(self.of.tolist()):
                if g >= 0:
                    one = named_g.get(g)
                    if one is None:
                        one = named_g[g] = _states(self.codes[slots[0]], self.groups[g])
                    out[k] = dict(one)
            return out
        for g in np.unique(self.of[self.of >= 0]).tolist():
            ids = self.groups[g][0]
            rows = (self.of == g).nonzero()[0]
            sub = self._codes(g, rows)
            if len(ids) <= 31:  # (each row's codes as one int: base 4)
                _, first, inv = np.unique(sub @ (4 ** np.arange(len(ids), dtype=np.int64)), return_index=True,
                                          return_inverse=True)
                uniq = sub[first]
            else:
                uniq, inv = np.unique(sub, axis=0, return_inverse=True)
            named = [dict(zip(ids, _CODE_NAMES[u].tolist())) for u in uniq]
            for k, u in zip(rows.tolist(), inv.ravel().tolist()):
                out[k] = dict(named[u])
        return out

    def stacked(self, n: int, idx: list[int]) -> dict[str, Any]:
        """The batched env's "signal_states" of these rows (sub-envs `idx`): per signal id, in the
        order the rows' dicts first name them, an object array of states over the n sub-envs and
        its mask (what `MapVectorEnv.stack_infos` makes of the dicts)."""
        at = np.asarray(idx, dtype=np.int64)
        present = self.of >= 0
        gs, first = np.unique(self.of[present], return_index=True)
        cols: dict[str, tuple[np.ndarray, np.ndarray]] = {}
        for g in gs[np.argsort(first)].tolist():
            rows = (self.of == g).nonzero()[0]
            names = _CODE_NAMES[self._codes(g, rows)]
            for j, sid in enumerate(self.groups[g][0]):
                if sid not in cols:
                    cols[sid] = (np.full(n, None, dtype=object), np.zeros(n, dtype=np.bool_))
                array, mask = cols[sid]
                array[at[rows]] = names[:, j]
                mask[at[rows]] = True
        out: dict[str, Any] = {}
        for sid, (array, mask) in cols.items():
            out[sid], out[f"_{sid}"] = array, mask
        return out


def signal_states(core: Any, views: Sequence[Any], slots: np.ndarray, states_of: list, codes: np.ndarray) -> SignalStates:
    """The `SignalStates` of rows whose views are `views` (of `states_of`'s junction under each
    view's phases; None: every signal; False: {})."""
    groups: list = []
    where: dict[tuple, int] = {}
    of = []
    for view, x in zip(views, states_of):
        if x is False:
            of.append(-1)
            continue
        control = view.control
        key = (id(control.signals_by_junction), x)
        g = where.get(key)
        if g is None:
            g = where[key] = len(groups)
            groups.append(signal_group(core, control, x))
        of.append(g)
    return SignalStates(groups, np.array(of, dtype=np.int64), slots, codes)


def columns(core: Any, rows: Any, views: Sequence[Any], actions: Sequence[Any], completed: Any = None,
            progress: Any = None, off_road: Any = None, rewards: Records | None = None) -> dict[str, Any]:
    """The info values of controlled rows `rows` (an array; one row: an int, each value that
    row's) whose envs or agents are `views` (`EgoTask`s: their judges, clocks and last reward
    terms), given their `actions`; whether each `completed` its route, its route `progress` and
    `off_road` when already asked this step, and their reward terms as one table (`rewards`; else
    each view's last). Keys in `info.INFO_KEYS` order (the multi-agent env's own keys apart);
    containers are the views' own (`map_env.info_dict` copies them)."""
    if completed is None:
        done, completed = task.route_state(core, rows)
        progress = task.route_progress(core, rows, done)
    if isinstance(rows, int):
        return _row_values(core, rows, views[0], actions[0], completed, progress, off_road)
    return _batch_columns(core, rows, views, actions, completed, progress, off_road, rewards)


def _row_values(core: Any, row: int, view: Any, action: Any, completed: Any, progress: Any, off_road: Any) -> dict:
    """`columns` of one row: its values (Python scalars)."""
    f = facts_of(core, row)
    fact = core.route_facts.facts[f]
    jid, turn, feature, control, sig_id, sig, states_of = fact[:7]
    d = line_distance(core, row, f, fact)
    rules = view.control
    slot = int(core.env[row])
    codes = core.signal_codes(slot)
    states = _states(codes, signal_group(core, rules, states_of)) if states_of is not False else {}
    if fact[9] and (mid := rules.midblock_ahead(view.vehicle, d)) is not None:
        sig_id, d = mid
        sig, control = core.table.signal_index.get(sig_id, -1), "signal"
        states = _states(codes, signal_group(core, rules, None))
    return {
        "speed": float(core.speed[row]), "crashed": bool(core.crashed[row]), "action": action,
        "junction": jid, "junction_feature": feature, "manoeuvre": turn, "control_ahead": control,
        "signal_id": sig_id, "signal_state": (SIGNAL_STATES[codes[sig]] if sig >= 0 else "green") if sig_id else "",
        "signal_time_to_change": float(core.signal_waits(slot)[sig]) if sig >= 0 else math.inf,
        "signal_states": states, "distance_to_stop_line": float(d), "violations": view.violations,
        "new_violations": view.judge.new, "collision": bool(core.crashed[row]),
        "off_road": bool(view.judge.off_road if off_road is None else off_road),
        "route_progress": float(progress), "route_completed": bool(completed),
        "lane_id": core.lane_names[core.at_lane[row]], "time": float(view.time),
        "rewards": view._last_rewards,
    }


def _batch_columns(core: Any, rows: np.ndarray, views: Sequence[Any], actions: Sequence[Any], completed: Any,
                   progress: Any, off_road: Any, rewards: Records | None) -> dict[str, Any]:
    """`columns` of an array of rows: a column per key."""
    f = facts_of(core, rows)
    a = core.route_facts.arrays()
    d = line_distance(core, rows, f)
    control, sig_id, sig, states_of = a["control"][f], a["sig_id"][f], a["sig"][f], a["states_of"][f]
    slots = core.env[rows]
    codes = core.signal_codes()
    states_of = states_of.tolist()
    mids = np.nonzero(a["has_mid"][f])[0]
    if len(mids):
        control, sig_id, sig = control.copy(), sig_id.copy(), sig.copy()
        for k in mids.tolist():
            mid = views[k].control.midblock_ahead(views[k].vehicle, float(d[k]))
            if mid is not None:
                sig_id[k], d[k] = mid
                sig[k], control[k] = core.table.signal_index.get(mid[0], -1), "signal"
                states_of[k] = None  # (every signal's state)
    states = signal_states(core, views, slots, states_of, codes)
    has_sig = sig_id != ""
    known = sig >= 0
    state = np.where(has_sig, "green", "").astype(object)
    state[known] = _CODE_NAMES[codes[slots[known], sig[known]]]
    to_change = np.full(len(rows), math.inf)
    if known.any():
        to_change[known] = core.signal_waits_of(slots[known], sig[known])
    crashed = core.crashed[rows]
    kinds = views[0].judge.KINDS  # (the views of a batch are of one kind: the egos, or the agents)
    return {
        "speed": core.speed[rows], "crashed": crashed, "action": list(actions), "junction": a["jid"][f],
        "junction_feature": a["feature"][f], "manoeuvre": a["turn"][f], "control_ahead": control, "signal_id": sig_id,
        "signal_state": state, "signal_time_to_change": to_change, "signal_states": states,
        "distance_to_stop_line": d, "violations": Records(kinds, core.violations[rows, :len(kinds)]),
        "new_violations": _names(core.new_violations[rows]), "collision": crashed.copy(),
        "off_road": core.off_road[rows] if off_road is None else np.asarray(off_road, dtype=bool),
        "route_progress": np.asarray(progress, dtype=float), "route_completed": np.asarray(completed, dtype=bool),
        "lane_id": core.lane_names[core.at_lane[rows]], "time": np.array([v.time for v in views], dtype=float),
        "rewards": [v._last_rewards for v in views] if rewards is None else rewards,
    }


DICT_COLUMNS = (Records, SignalStates)  # columns whose rows' values are dicts made by `dicts` (`at`: some rows)


def _names(counts: np.ndarray) -> list[list[str]]:
    """Each row's violations of the step (`rules.violation_names` of its counts; a list per row)."""
    out: list[list[str]] = [[] for _ in range(len(counts))]
    for k in counts.any(axis=1).nonzero()[0].tolist():
        out[k] = violation_names(counts[k].tolist())
    return out


def row_values(cols: dict[str, Any]) -> list[dict[str, Any]]:
    """Each row's values of a batch's `columns`, as Python values (what `columns` gives of one
    row)."""
    lists = [col.tolist() if isinstance(col, np.ndarray) else col.dicts() if isinstance(col, DICT_COLUMNS) else col
             for col in cols.values()]
    return [dict(zip(cols, values)) for values in zip(*lists)]
