"""The judge (`sim.judge`, one program over the rows due) is the judge as worded
(tests/envs/rule_specs.py), in the single, batched and multi-agent envs; it is asked only where its
check can change anything (`TrafficCore.judge_due`): on drives that run red lights and stop signs,
pass pedestrians and leave the road, its verdicts are those of a judge asked after every frame."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import example_map_file

import feat2map  # noqa: F401  (registers the envs)
from feat2map.config import OFF_ROAD_LATERAL_M, PEDESTRIAN_YIELD_SPEED_MPS, PEDESTRIAN_YIELD_STRETCH_M
from feat2map.envs.rules import JUDGED
from feat2map.envs.sim import judge
from feat2map.formats import native
from rule_specs import JudgeAsWorded

CONTINUOUS = {"action": {"type": "ContinuousAction"}}


def fastest(t: int):
    return 2  # the top target speed: through every line on red or without a stop


def stop_and_go(t: int):
    return 0 if (t // 12) % 2 else 2  # slower to a stop, then faster: stops anywhere, some at a line


def weaving(t: int):
    return np.array([1.0, 0.6 * np.sin(t / 7.0)], dtype=np.float32)  # full throttle, steering off the lanes


def kept(c, row: int) -> tuple[frozenset, ...]:
    """What the judge of row `row` of core `c` keeps to find more (`judge.SETS`)."""
    return tuple(frozenset(v for v in getattr(c, name)[row].tolist() if v >= 0) for name in judge.SETS)


def judged(u) -> tuple:
    """What a judge has found, and what it keeps to find more (not where it last looked)."""
    j = u.judge
    return dict(j.violations), j.off_road, j.done, kept(u.road.core, u.vehicle.row)


def every_frame(env) -> None:
    """The env's judge looks after every frame."""
    env.unwrapped.road.core.judge_due = lambda rows: np.ones(len(rows), dtype=bool)


@pytest.mark.parametrize("case, policy, expect", [
    ("grid", fastest, {"red_light", "stop_sign", "pedestrian_yield"}),
    ("grid", stop_and_go, {"red_light", "stop_sign"}),
    ("grid-continuous", weaving, {"red_light", "stop_sign", "off_road"}),
    ("midblock", weaving, {"red_light", "off_road"}),
])
def test_the_judge_asked_where_due_finds_what_a_judge_asked_every_frame_does(case, policy, expect, tmp_path_factory,
                                                                             monkeypatch):
    if case == "midblock":
        make = lambda: gym.make("feat2map/MapFile-v0", config={  # noqa: E731
            "map": native.load(example_map_file(tmp_path_factory, "midblock")), "traffic_vehicles": 4, **CONTINUOUS})
    else:
        make = lambda: gym.make("feat2map/JunctionGrid-v0", config={  # noqa: E731
            "traffic_vehicles": 6, **(CONTINUOUS if case == "grid-continuous" else {})})
    due, every = make(), make()
    asked = {"due": 0, "every": 0}
    seen: set[str] = set()
    c = due.unwrapped.config
    per_step, frames, ended = c["simulation_frequency"] // c["policy_frequency"], 0, False
    for t in range(500):
        if t == 0 or ended:
            for env in (due, every):
                env.reset(seed=0 if t == 0 else None)
            every_frame(every)
            for name, env in (("due", due), ("every", every)):
                c = env.unwrapped.road.core
                check = c.judge

                def counted(rows, check=check, name=name):
                    asked[name] += len(rows)
                    check(rows)
                c.judge = counted
        a = due.step(policy(t))
        b = every.step(policy(t))
        frames += per_step
        assert a[4]["new_violations"] == b[4]["new_violations"], (case, t)
        assert judged(due.unwrapped) == judged(every.unwrapped), (case, t)
        seen |= set(a[4]["new_violations"]) | ({"off_road"} if a[4]["off_road"] else set())
        ended = a[2] or a[3]
    assert expect <= seen  # the drives broke the rules the case is for
    assert asked["every"] == frames and asked["due"] < frames  # ... on frames where the judge was not asked


def test_each_reason_to_look_makes_a_row_due(monkeypatch):
    env = gym.make("feat2map/JunctionGrid-v0", config={"traffic_vehicles": 0})
    env.reset(seed=0)
    u = env.unwrapped
    c, row = u.road.core, np.array([u.vehicle.row])
    t = c.table
    lane = int(np.nonzero(~t.junction & ~t.crossing & ~t.midblock)[0][0])  # a plain road lane
    c.at_lane[row], c.at_s[row], c.at_lat[row], c.speed[row] = lane, 1.0, 0.0, 5.0
    c.route_pos[row], c.route_end[row] = 0, 3
    c.judged[row] = -1
    assert c.judge_due(row).tolist() == [True]  # a lane it was not looked at on
    assert c.judge_due(row).tolist() == [False]  # ... looked at now: nothing to look at
    reasons = {
        "stopped": ("speed", 0.0),
        "past the lane's end": ("at_s", t.length[lane] + 0.1),
        "wide of the lane": ("at_lat", t.width[lane] / 2 + OFF_ROAD_LATERAL_M + 0.1),
        "on the route's last lane": ("route_pos", 3),
    }
    for why, (column, value) in reasons.items():
        old = getattr(c, column)[row].copy()
        getattr(c, column)[row] = value
        assert c.judge_due(row).tolist() == [True], why
        getattr(c, column)[row] = old
        assert c.judge_due(row).tolist() == [False], why
    marked = t.midblock.copy()  # a mid-block crossing's line
    marked[lane] = True
    with monkeypatch.context() as m:
        m.setattr(t, "midblock", marked)
        assert c.judge_due(row).tolist() == [True], "midblock"
    assert c.judge_due(row).tolist() == [False], "midblock"
    # a crosswalk's stretch of its lane, moving, with a walker of its slot on that crosswalk
    lid, (cw, s0, s1) = next((lid, cs[0]) for lid, cs in u.net.crossings.items())
    cross = t.index[lid]
    c.at_lane[row], c.at_s[row], c.judged[row] = cross, (s0 + s1) / 2, cross
    assert c.judge_due(row).tolist() == [False], "nobody on the crosswalk"
    slot, k = int(c.env[row[0]]), c.crosswalks.index[cw]
    other = next(i for i in range(len(c.crosswalks.ids)) if i != k)
    for p_env, p_cw, s, speed, expect in [
        (slot, k, (s0 + s1) / 2, 5.0, True),
        (slot, k, s0 - PEDESTRIAN_YIELD_STRETCH_M, 5.0, True), (slot, k, s1 + PEDESTRIAN_YIELD_STRETCH_M, 5.0, True),
        (slot, k, s0 - PEDESTRIAN_YIELD_STRETCH_M - 0.01, 5.0, False),
        (slot, k, s1 + PEDESTRIAN_YIELD_STRETCH_M + 0.01, 5.0, False),
        (slot, k, (s0 + s1) / 2, PEDESTRIAN_YIELD_SPEED_MPS, False),  # not moving (nor stopped)
        (slot + 1, k, (s0 + s1) / 2, 5.0, False),  # another slot's walker
        (slot, other, (s0 + s1) / 2, 5.0, False),  # on another crosswalk
    ]:
        with monkeypatch.context() as m:
            m.setattr(c, "p_env", np.array([p_env]))
            m.setattr(c, "p_cw", np.array([p_cw]))
            c.at_s[row], c.speed[row] = s, speed
            assert c.judge_due(row).tolist() == [expect], (p_env, p_cw, s, speed)


def test_the_verdicts_are_the_rows_and_move_with_them_in_a_batch():
    """A judge's verdicts are its row's columns of the core (`violations`, `new_violations`,
    `off_road`): while respawns and resets move every sub-env's rows, each info's episode counts
    stay the sum of the step's new violations it reported, and its `off_road` stays set."""
    env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=6, vectorization_mode="vector_entry_point",
                       config={"traffic_vehicles": 8, **CONTINUOUS})
    env.reset(seed=2)
    kinds = ("red_light", "stop_sign", "pedestrian_yield")
    sums = np.zeros((6, len(kinds)), dtype=np.int64)
    left = np.zeros(6, dtype=bool)
    moved = seen = 0
    layout = env.unwrapped.core.layout
    for t in range(240):
        # sub-envs drive at full throttle, half of them weaving off the lanes
        actions = np.array([weaving(t) if i % 2 else np.array([1.0, 0.0], dtype=np.float32) for i in range(6)])
        _, _, term, trunc, info = env.step(actions)
        moved += env.unwrapped.core.layout != layout
        layout = env.unwrapped.core.layout
        for i in range(6):
            if not info["_violations"][i]:
                continue  # (a sub-env's reset step)
            sums[i] += [info["new_violations"][i].count(k) for k in kinds]
            assert [info["violations"][k][i] for k in kinds] == sums[i].tolist()
            assert not left[i] or info["off_road"][i]
            left[i] = info["off_road"][i]
            seen += len(info["new_violations"][i])
            if term[i] or trunc[i]:
                sums[i], left[i] = 0, False
    assert seen > 5 and moved > 20


def test_an_agent_that_left_keeps_its_verdicts():
    """An agent's judge keeps its verdicts once its row has left the core (`EgoJudge.let_go`):
    what `view(agent).violations` says after the agent is gone is its last info's count, whatever
    row another road user now has."""
    from feat2map.envs.multi_agent import MultiAgentMapEnv

    env = MultiAgentMapEnv(config={"action": {"type": "TargetSpeed"}, "agents": 6})
    env.reset(seed=0)
    last: dict[str, dict] = {}
    gone: dict[str, dict] = {}
    for _ in range(400):
        if not env.agents:
            break
        _, _, term, trunc, infos = env.step({a: 2 for a in env.agents})  # the top speed: through lines on red
        for a, info in infos.items():
            last[a] = info
            if term.get(a) or trunc.get(a):
                gone[a] = info["violations"]
    assert sum(sum(v.values()) for v in gone.values()) > 0
    for a, counts in gone.items():
        assert env.view(a).violations == counts and env.view(a).off_road == last[a]["off_road"]


def worded_alongside(c, specs) -> None:
    """The judges as worded (`specs()`, a list) check after every frame, before core `c`'s judge
    (which uses up an agent's noted verdict)."""
    real = c.judge

    def both(rows):
        for spec in specs():
            spec.check()
        real(rows)
    c.judge = both


def as_worded(spec: JudgeAsWorded, c) -> tuple:
    """A judge as worded's verdicts and sets, in the core's terms (`judge.SETS`' ints)."""
    index, nl, ncw = c.table.index, len(c.table.length), len(c.crosswalks.ids)
    sets = (frozenset(index[x] for x in spec.stopped), frozenset(index[x] for x in spec.crossed),
            frozenset(c.table.signal_index[sid] * nl + index[lid] for sid, lid in spec.crossed_mid),
            frozenset(index[lid] * ncw + c.crosswalks.index[cw] for lid, cw in spec.ped_flags))
    return [spec.counts[k] for k in JUDGED], spec.off_road, spec.done, sets


def of_core(c, row: int) -> tuple:
    return c.violations[row].tolist(), bool(c.off_road[row]), bool(c.j_done[row]), kept(c, row)


@pytest.mark.parametrize("case, policy", [("grid", fastest), ("grid", stop_and_go), ("grid-rtor", stop_and_go),
                                          ("grid-continuous", weaving), ("midblock", weaving)])
def test_the_judge_is_the_judge_as_worded_in_the_single_env(case, policy, tmp_path_factory):
    """After every step, the verdicts and sets of the env's judge are those of the judge as
    worded asked after every frame (right turns on red allowed in "grid-rtor")."""
    if case == "midblock":
        env = gym.make("feat2map/MapFile-v0", config={
            "map": native.load(example_map_file(tmp_path_factory, "midblock")), "traffic_vehicles": 4, **CONTINUOUS})
    else:
        env = gym.make("feat2map/JunctionGrid-v0", config={
            "traffic_vehicles": 6, "right_turn_on_red": case == "grid-rtor",
            **(CONTINUOUS if case == "grid-continuous" else {})})
    seen: set[str] = set()
    ended = True
    for t in range(300):
        if ended:
            env.reset(seed=t)
            u = env.unwrapped
            spec = JudgeAsWorded(u.control, u.vehicle, arrives=True)
            worded_alongside(u.road.core, lambda spec=spec: [spec])
        _, _, term, trunc, info = env.step(policy(t))
        assert of_core(u.road.core, u.vehicle.row) == as_worded(spec, u.road.core), (case, t)
        seen |= set(info["new_violations"]) | ({"off_road"} if info["off_road"] else set())
        ended = term or trunc
    assert len(seen) >= 2, seen  # the drives broke rules


def test_the_judge_is_the_judge_as_worded_in_a_batch_whose_rows_move():
    """The batched env's judges, one program over the due rows of every sub-env, while respawns
    and resets move the rows: each sub-env's verdicts and sets are those of the judge as worded."""
    n = 6
    env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       config={"traffic_vehicles": 8, **CONTINUOUS})
    env.reset(seed=3)
    subs, c = env.unwrapped.envs, env.unwrapped.core
    specs: dict[int, tuple] = {}

    def current() -> list:
        for i, sub in enumerate(subs):  # a sub-env reset since: a new judge
            if i not in specs or specs[i][0] is not sub.judge:
                specs[i] = (sub.judge, JudgeAsWorded(sub.control, sub.vehicle, arrives=True))
        return [spec for _, spec in specs.values()]
    worded_alongside(c, current)
    current()
    seen = 0
    for t in range(200):
        actions = np.array([weaving(t) if i % 2 else np.array([1.0, 0.0], dtype=np.float32) for i in range(n)])
        env.step(actions)
        for i, sub in enumerate(subs):
            judge_, spec = specs[i]
            if judge_ is sub.judge:  # (not a sub-env reset this step)
                assert of_core(c, sub.vehicle.row) == as_worded(spec, c), (i, t)
                seen += sum(spec.counts.values())
    assert seen > 5


def test_the_agents_judges_are_the_judge_as_worded():
    """The multi-agent env's judges (with not_yielding and stop_order) are the judge as worded,
    agent by agent, as agents come and go."""
    from feat2map.envs.multi_agent import MultiAgentMapEnv

    env = MultiAgentMapEnv(config={"action": {"type": "TargetSpeed"}, "agents": 8})
    env.reset(seed=1)
    c = env.world.road.core
    specs: dict[str, tuple] = {}

    def current() -> list:
        for a in env.agents:
            v = env.view(a)
            if a not in specs or specs[a][0] is not v.judge:
                specs[a] = (v.judge, JudgeAsWorded(v.control, v.vehicle, agent=True))
        return [spec for a, (_, spec) in specs.items() if a in env.agents]
    worded_alongside(c, current)
    current()
    kinds: set[str] = set()
    rng = np.random.default_rng(0)
    for t in range(300):
        if not env.agents:
            break
        live = list(env.agents)
        _, _, _, _, infos = env.step({a: int(rng.integers(3)) for a in live})
        for a in live:
            judge_, spec = specs[a]
            if a in infos and a in env.agents:
                assert of_core(c, env.view(a).vehicle.row) == as_worded(spec, c), (a, t)
            kinds |= set(infos.get(a, {}).get("new_violations", ()))
    assert kinds & {"not_yielding", "stop_order"} and "red_light" in kinds, kinds


def test_a_midblock_line_crossed_on_red_counts_once_however_often_the_row_comes_back_onto_its_lane(
        tmp_path_factory, monkeypatch):
    """A mid-block crossing's line passed on red counts once an episode, also where the row comes
    onto its lane past the line again and again (a lane change back and forth)."""
    env = gym.make("feat2map/MapFile-v0", config={
        "map": native.load(example_map_file(tmp_path_factory, "midblock")), "traffic_vehicles": 0})
    env.reset(seed=0)
    u = env.unwrapped
    c, row = u.road.core, u.vehicle.row
    lid, (_, s_line) = next((lid, lines[0]) for lid, lines in u.net.midblock_lines.items())
    lane = c.table.index[lid]
    other = int(np.nonzero(~c.table.junction & ~c.table.midblock)[0][0])
    monkeypatch.setattr(judge, "is_red", lambda _core, _slots, signals: signals >= 0)
    for _ in range(3):  # from another lane onto it, past the line
        c.j_lane[row] = other
        c.at_lane[row], c.at_s[row], c.at_lat[row], c.speed[row] = lane, s_line + 0.5, 0.0, 5.0
        c.judge(np.array([row]))
    assert c.violations[row, JUDGED.index("red_light")] == 1


def test_off_the_road_is_wide_of_the_lane_or_past_the_end_of_one_that_leads_nowhere():
    """The judge's off road: wider of its lane than OFF_ROAD_LATERAL_M beyond its half width, or
    more than OFF_ROAD_END_M past the end of a lane without successors (past the end of a lane
    that goes on is not)."""
    from feat2map.config import OFF_ROAD_END_M

    env = gym.make("feat2map/JunctionGrid-v0", config={"traffic_vehicles": 0})
    env.reset(seed=0)
    u = env.unwrapped
    c, row, t = u.road.core, u.vehicle.row, u.road.core.table
    m = u.net.hdmap
    dead = next(k for k, lid in enumerate(u.net.lane_ids) if not m.lanes[lid].successors)
    goes_on = next(k for k, lid in enumerate(u.net.lane_ids) if m.lanes[lid].successors and not t.junction[k])
    for lane, s, lat, expect in [(goes_on, t.length[goes_on] + OFF_ROAD_END_M + 1.0, 0.0, False),
                                 (dead, t.length[dead] + OFF_ROAD_END_M - 0.1, 0.0, False),
                                 (goes_on, 5.0, t.width[goes_on] / 2 + OFF_ROAD_LATERAL_M + 0.1, True),
                                 (dead, t.length[dead] + OFF_ROAD_END_M + 0.1, 0.0, True)]:
        c.off_road[row] = False
        c.j_lane[row] = c.at_lane[row] = lane
        c.at_s[row], c.at_lat[row], c.speed[row] = s, lat, 5.0
        c.judge(np.array([row]))
        assert bool(c.off_road[row]) == expect, (lane, s, lat)
