"""The judge is asked only where its check can change anything (`TrafficCore.judge_due`): on
drives that run red lights and stop signs, pass pedestrians and leave the road, its verdicts are
those of a judge asked after every frame."""
from __future__ import annotations

import gymnasium as gym
import numpy as np
import pytest
from conftest import example_map_file

import feat2map  # noqa: F401  (registers the envs)
from feat2map.config import OFF_ROAD_LATERAL_M, PEDESTRIAN_YIELD_SPEED_MPS, PEDESTRIAN_YIELD_STRETCH_M
from feat2map.envs import core
from feat2map.formats import native

CONTINUOUS = {"action": {"type": "ContinuousAction"}}


def fastest(t: int):
    return 2  # the top target speed: through every line on red or without a stop


def stop_and_go(t: int):
    return 0 if (t // 12) % 2 else 2  # slower to a stop, then faster: stops anywhere, some at a line


def weaving(t: int):
    return np.array([1.0, 0.6 * np.sin(t / 7.0)], dtype=np.float32)  # full throttle, steering off the lanes


def judged(u) -> tuple:
    """What a judge has found, and what it keeps to find more (not where it last looked)."""
    j = u.judge
    return (dict(j.violations), j.off_road, j.done, set(j._stopped), set(j._crossed), set(j._crossed_mid),
            set(j._ped_flags))


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
    monkeypatch.setattr(core, "JUDGE_MIN_ROWS", 1)  # the test for one ego too
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
                check = env.unwrapped.judge.check

                def counted(check=check, name=name):
                    asked[name] += 1
                    check()
                env.unwrapped.judge.check = counted
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
    monkeypatch.setattr(core, "JUDGE_MIN_ROWS", 1)
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
    monkeypatch.setattr(core, "JUDGE_MIN_ROWS", 2)  # fewer rows than that: every judge is asked
    assert c.judge_due(row).tolist() == [True]


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
