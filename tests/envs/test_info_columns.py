"""The info values of a batch's controlled rows, worked out at once (envs/info_columns.py): every
row's values are what the rules answer that road user one by one (the next stop line along its
route, the signal's state and time to its change, the junction's signal states, a mid-block
light before the line), the batch's columns are each row's own values, and the route facts
they read stay one per stretch of road up to a junction entry however many routes are driven."""
from __future__ import annotations

import math
import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from conftest import example_map_file

import feat2map
from feat2map.envs import info_columns
from feat2map.envs.rules import enters_junction

J = feat2map.JunctionFeature.make
SIGNALS = {"features": [J([0, 90, 180, 270], "signal", True).to_dict(), J([0, 120, 240], "stop", False).to_dict(),
                        J([0, 90, 180], "signal", False).to_dict()],
           "traffic_vehicles": 6, "route_junctions": 3, "duration": 30.0, "policy_frequency": 2}


@pytest.fixture(scope="module")
def midblock(tmp_path_factory) -> dict:
    return {"map_file": str(example_map_file(tmp_path_factory, "midblock")), "traffic_vehicles": 6,
            "duration": 30.0, "policy_frequency": 2, "route": [["J0", "R2", "R0"], ["J1", "R0", "R4"]]}


def rules_values(env) -> dict:
    """What the rules answer the ego one by one (and its route, walked lane by lane): the keys
    of the info that come from its route and the signals."""
    ego, rules, m = env.vehicle, env.control, env.net.hdmap
    sl, _, j_lane, d = rules.line_ahead(ego)
    sig = sl.control_id if sl is not None and sl.kind == "signal" else ""
    states = rules.signal_states(m.lanes[j_lane].junction_id) if j_lane else {}
    mid = rules.midblock_ahead(ego, d)
    if mid is not None:
        sig, d = mid
        states = rules.signal_states(None)
    jid, turn = info_columns.junction_ahead(env.net, ego.lane_route, ego.route_pos)  # (the route walked)
    assert env.junction_ahead() == (jid, turn)
    return {"junction": jid or "", "manoeuvre": turn or "", "signal_id": sig, "distance_to_stop_line": d,
            "signal_state": rules.signal_state(sig) if sig else "",
            "signal_time_to_change": rules.signal_change(sig) if sig else math.inf, "signal_states": states,
            "lane_id": env.net.id_of[ego.lane_index], "speed": ego.speed, "route_completed": env.route_completed()}


def drive(config: dict, steps: int, check) -> None:
    """A batch of 4 on `config` with random actions, `check(batch)` after every step."""
    env = gym.make_vec("feat2map/MapFile-v0" if "map_file" in config else "feat2map/JunctionGrid-v0", num_envs=4,
                       vectorization_mode="vector_entry_point", config=config)
    env.reset(seed=0)
    env.action_space.seed(0)
    for _ in range(steps):
        env.step(env.action_space.sample())
        check(env.unwrapped)
    env.close()


@pytest.mark.parametrize("which", ["signals", "midblock"])
def test_every_rows_info_is_what_the_rules_answer_it_and_the_batch_is_its_rows(which, midblock):
    config = SIGNALS if which == "signals" else midblock
    seen = {"lines": 0, "signals": 0, "midblock": 0}

    def check(batch):
        envs = [e for e in batch.envs if e.vehicle is not None]
        core = batch.core
        rows = np.array([e.vehicle.row for e in envs], dtype=np.int64)
        actions = [0] * len(envs)
        cols = info_columns.columns(core, rows, envs, actions)
        for env, values in zip(envs, info_columns.row_values(cols)):
            one = info_columns.columns(core, env.vehicle.row, [env], [0])
            assert values.keys() == one.keys()
            for key, value in one.items():
                assert type(values[key]) is type(value) and (values[key] == value or value != value), key
            for key, value in rules_values(env).items():
                assert values[key] == value, (key, values[key], value)
            seen["lines"] += math.isfinite(values["distance_to_stop_line"])
            seen["signals"] += values["signal_state"] in ("green", "amber", "red")
            seen["midblock"] += values["signal_id"] in {s for lines in env.net.midblock_lines.values() for s, _ in lines}

    drive(config, 80, check)
    assert seen["lines"] > 50 and seen["signals"] > 20
    if which == "midblock":
        assert seen["midblock"] > 5  # the mid-block light before the junction's line was named


def test_route_facts_are_one_per_stretch_up_to_a_junction_entry():
    """However many routes are driven, a fact is kept per stretch of route from a lane up to
    and including the next junction entry's lane (or per lane where no entry lies ahead): the
    table is bounded by the map, not by the routes."""
    env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                       config={**SIGNALS, "duration": 3.0})
    env.reset(seed=0)
    for _ in range(120):
        env.step(env.action_space.sample())
    core = env.unwrapped.core
    lanes = core.net.hdmap.lanes
    facts = core.route_facts
    assert len(facts.index) == len(facts.facts) > 10
    for key in facts.index:
        if key[1] is None and len(key) == 3 and isinstance(key[2], bool):
            continue  # (a lane with no entry ahead)
        entries = [k for k in range(1, len(key)) if enters_junction(lanes, key[k - 1], key[k])]
        assert entries == [len(key) - 1], key
    env.close()
