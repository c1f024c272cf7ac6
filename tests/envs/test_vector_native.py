"""The native batched vector env (envs/vector.py): N sub-envs whose traffic shares one core give,
with the same seeds and actions, exactly what N single envs give (Gymnasium's SyncVectorEnv
over gym.make), through episode ends and autoresets, on several configs; Gymnasium's vector
conventions (spaces, seeding, reset_mask, autoreset modes, info arrays); unsupported configs
are refused naming the key."""
from __future__ import annotations

import os
import re

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
from types import SimpleNamespace

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from conftest import REPO, SKIP_RL
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode

import feat2map
from feat2map.envs.driver import DRIVER_ACTION_CONFIG
from feat2map.envs.vector import MapVectorEnv
from feat2map.errors import Feat2MapError

J = feat2map.JunctionFeature.make
FEATS = [J([0, 90, 180], "signal", True).to_dict(), J([0, 90, 180, 270], "stop", False).to_dict()]
# short episodes through one junction: many episode ends, autoresets and respawns
SHORT = {"features": FEATS, "traffic_vehicles": 3, "route_junctions": 1, "duration": 2.5, "policy_frequency": 2}
# pedestrians on every crosswalk, queues at the stop sign, the driver's view, continuous action
BUSY = {"features": [J([0, 90, 180, 270], "signal", True).to_dict(), J([0, 90, 180, 270], "stop", True).to_dict()],
        "traffic_vehicles": 14, "pedestrian_rate": 40.0, "route_junctions": 2, "duration": 12.0,
        "policy_frequency": 5, "simulation_frequency": 10, "observation": {"type": "DriverView"},
        "action": DRIVER_ACTION_CONFIG}
# the default map, 10 Hz decisions, the traffic-control vector (a Dict observation)
DEFAULT_10HZ = {"policy_frequency": 10, "simulation_frequency": 20, "traffic_vehicles": 10, "duration": 4.0,
                "observe_traffic_control": True, "right_turn_on_red": True}


def assert_same(a, b, path="") -> None:
    """Equal values (arrays bit for bit, NaN equal to NaN, dicts' keys in the same order),
    recursively; `action` of a reset's info is a random sample of the action space and is left out."""
    if isinstance(a, dict):
        assert list(a) == list(b), (path, list(a), list(b))
        for k in a:
            if k not in ("action", "_action"):
                assert_same(a[k], b[k], f"{path}.{k}")
    elif isinstance(a, np.ndarray):
        assert a.dtype == b.dtype and a.shape == b.shape, (path, a.dtype, b.dtype, a.shape, b.shape)
        if a.dtype == object:
            for x, y in zip(a.ravel(), b.ravel()):
                assert_same(x, y, path)
        else:
            np.testing.assert_array_equal(a, b, err_msg=path)
    else:
        assert a == b or (a != a and b != b), (path, a, b)


def run_both(env_id: str, config: dict, n: int, steps: int, seed: int = 0, **kwargs) -> int:
    """Step the batched env and a SyncVectorEnv of single envs side by side with the same seeds
    and random actions; every output must be equal. Returns the number of episode ends."""
    batched = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", config=config, **kwargs)
    assert isinstance(batched.unwrapped, MapVectorEnv)
    single = gym.make_vec(env_id, num_envs=n, vectorization_mode="sync", config=config,
                          vector_kwargs={"autoreset_mode": kwargs.get("autoreset_mode", AutoresetMode.NEXT_STEP)})
    seeds = [seed + 7 * k for k in range(n)]
    ob, ib = batched.reset(seed=seeds)
    os_, is_ = single.reset(seed=seeds)
    assert_same(ob, os_)
    assert_same(ib, is_)
    assert batched.observation_space == single.observation_space and batched.action_space == single.action_space
    space = batched.action_space
    space.seed(seed)
    ends = 0
    for t in range(steps):
        action = space.sample()
        out_b, out_s = batched.step(action), single.step(action)
        for name, x, y in zip(("obs", "reward", "terminated", "truncated", "info"), out_b, out_s):
            assert_same(x, y, f"step {t} {name}")
        assert batched.observation_space.contains(out_b[0])
        ends += int(np.sum(out_b[2] | out_b[3]))
    batched.close()
    single.close()
    return ends


@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_short_episodes_equal_single_envs(mode):
    """Many ends: with same-step autoreset a sub-env's info is its new episode's, whose keys
    (the signal states of another junction) are not the last step's."""
    assert run_both("feat2map/JunctionGrid-v0", SHORT, n=3, steps=40, autoreset_mode=mode) >= 15


def test_pedestrians_stop_signs_driver_view_continuous_equal_single_envs():
    assert run_both("feat2map/JunctionGrid-v0", BUSY, n=2, steps=70, seed=3) >= 1


def test_default_map_dict_observation_same_step_autoreset_equal_single_envs():
    assert run_both("feat2map/JunctionGrid-v0", DEFAULT_10HZ, n=3, steps=45, seed=1,
                    autoreset_mode=AutoresetMode.SAME_STEP) >= 3


def test_map_file_env_equals_single_envs(tmp_path):
    from feat2map.formats.opendrive.writer import write_opendrive

    m = feat2map.generate_from_features([J([0, 90, 180], "bare", True), J([0, 90, 180, 270], "signal", False)], seed=2)
    write_opendrive(m, tmp_path / "two.xodr")
    config = {**SHORT, "map_file": str(tmp_path / "two.xodr")}
    del config["features"]
    assert run_both("feat2map/MapFile-v0", config, n=2, steps=30) >= 10


# pedestrians seen in the Kinematics observation, signals and stop signs, 3 Hz decisions
KINEMATIC_BUSY = {**BUSY, "observation": {"type": "Kinematics", "vehicles_count": 8,
                                          "features": ["presence", "x", "y", "vx", "vy", "heading", "cos_h", "sin_h"],
                                          "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-20, 20],
                                                             "vy": [-20, 20]}, "see_behind": False},
                  "policy_frequency": 3, "simulation_frequency": 12}


def scalar_code(monkeypatch) -> None:
    """The per-row and per-sub-env code the batch's array programs stand in for: the rules asked
    row by row (every row's question, then the claims of the rows whose answer takes something,
    in row order), each ego observing alone, each sub-env's reward and info dict, each road's
    lane buckets read from its vehicles and its stop-sign queues brought up to date on their own."""
    from feat2map.envs import core, vector
    from feat2map.envs.sim import stop_signs

    def rule_stops(self, traffic):
        dist = np.full(len(self.objs), np.inf)
        wants, claims = [], []
        for i in (traffic & ~self.crashed).nonzero()[0].tolist():
            v = self.objs[i]
            dist[i] = self.roads[self.env[i]].control.ask(v, self.rule_scan_of(v), claims)
            if claims:
                wants.append(i)
                claims.clear()
        for i in wants:
            dist[i] = self.roads[self.env[i]].control.claim(self.objs[i])
        return dist

    monkeypatch.setattr(core.TrafficCore, "_rule_stops", rule_stops)
    monkeypatch.setattr(vector.MapVectorEnv, "observe", lambda self, envs: [None] * len(envs))
    monkeypatch.setattr(vector.MapVectorEnv, "batch_end", lambda self, envs: False)  # each sub-env's end_step
    def buckets(self, road):  # each vehicle's lane read from its view
        out: dict = {}
        for v in road.vehicles:
            lane = self.net.id_of.get(v.lane_index)
            if lane is not None:
                out.setdefault(lane, []).append(v)
        return out

    monkeypatch.setattr(core.TrafficCore, "buckets", buckets)
    slot_by_slot = SimpleNamespace(queues=stop_signs.queues, turns=stop_signs.turns, update=lambda core_, rows: [
        stop_signs.update(core_, rows & (core_.env == k)) for k in np.unique(core_.env[rows]).tolist()])  # each slot alone
    monkeypatch.setattr(core, "stop_signs", slot_by_slot)


def trajectory(config: dict, n: int, steps: int, seed: int) -> list:
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        config=config)
    out = [envs.reset(seed=seed)]
    envs.action_space.seed(seed)
    for _ in range(steps):
        out.append(envs.step(envs.action_space.sample()))
    envs.close()
    return out


@pytest.mark.parametrize("config", [SHORT, KINEMATIC_BUSY, DEFAULT_10HZ], ids=["short", "busy", "default"])
def test_array_programs_equal_the_scalar_code(config, monkeypatch):
    """The batch's array programs (the rules' stop distances, `sim.observe.kinematics`, the
    rewards and info columns of `MapVectorEnv.end_steps`, `TrafficCore.buckets`, the
    stop-sign queues of every slot at once) give bit for bit what the rules asked row by row and
    each sub-env's own observation, reward and info give (the equality with single envs above
    cannot see this: a single env is the same core with one slot)."""
    fast = trajectory(config, 3, 40, seed=5)
    scalar_code(monkeypatch)
    slow = trajectory(config, 3, 40, seed=5)
    for t, (a, b) in enumerate(zip(fast, slow)):
        for name, x, y in zip(("obs", "reward", "terminated", "truncated", "info"), a, b):
            assert_same(x, y, f"step {t} {name}")


def test_vector_conventions():
    """Batched spaces, seeding (same seeds: same observations; different sub-envs differ),
    reset_mask, next-step autoreset (reset observation with reward 0), render of one sub-env."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=3, config=SHORT, render_mode="rgb_array")
    assert isinstance(envs.unwrapped, MapVectorEnv)  # the vector entry point is the default
    single = gym.make("feat2map/JunctionGrid-v0", config=SHORT)
    assert envs.single_observation_space == single.observation_space
    assert envs.observation_space.shape == (3, *single.observation_space.shape)
    assert envs.action_space == gym.spaces.MultiDiscrete([single.action_space.n] * 3)
    obs, info = envs.reset(seed=5)
    again, _ = envs.reset(seed=5)
    np.testing.assert_array_equal(obs, again)
    assert not np.array_equal(obs[0], obs[1])
    assert info["speed"].shape == (3,) and info["_speed"].all() and info["junction_feature"]["rotation"].shape == (3, 8)
    part, pinfo = envs.reset(options={"reset_mask": np.array([False, True, False])})
    np.testing.assert_array_equal(part[0], obs[0])
    assert pinfo["_speed"].tolist() == [False, True, False]
    ended = np.zeros(3, dtype=bool)
    for _ in range(12):
        before = ended
        obs, rew, term, trunc, info = envs.step(np.ones(3, dtype=np.int64))
        assert np.all(rew[before] == 0.0) and not np.any((term | trunc)[before])  # next step: reset
        assert np.all(info["time"][before] == 0.0)
        ended = term | trunc
    frame = envs.render()
    assert frame.ndim == 3 and frame.shape[2] == 3
    core = envs.unwrapped.core
    assert sorted(set(core.env.tolist())) == [0, 1, 2]  # one table holds the rows of every sub-env
    assert len(core.objs) == sum(len(e.road.vehicles) for e in envs.unwrapped.envs)
    envs.close()


@pytest.mark.parametrize("key, value", [("new_map_each_reset", True), ("manual_control", True)])
def test_unsupported_configs_are_refused_naming_the_key(key, value):
    with pytest.raises(Feat2MapError, match=key):
        gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                     config={**SHORT, key: value})


def test_sb3_adapter_steps_through_episode_ends():
    pytest.importorskip("stable_baselines3", reason=SKIP_RL)
    from stable_baselines3.common.vec_env import VecMonitor

    from feat2map.envs.sb3 import sb3_vec_env

    batch = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, config=SHORT)  # as a user writes it: next-step
    assert batch.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    venv = VecMonitor(sb3_vec_env(batch))
    assert batch.metadata["autoreset_mode"] == batch.autoreset_mode == AutoresetMode.SAME_STEP
    venv.seed(0)
    obs = venv.reset()
    assert obs.shape == (2, *batch.single_observation_space.shape)
    episodes = 0
    for _ in range(20):
        obs, rew, done, infos = venv.step(np.array([2, 1]))
        assert len(infos) == 2 and rew.dtype == np.float32
        for d, info in zip(done, infos):
            if d:  # SB3's conventions: the final observation and the episode's summary in info
                assert info["terminal_observation"].shape == obs.shape[1:] and "episode" in info
                assert info["TimeLimit.truncated"] == (not info["route_completed"] and not info["crashed"])
                episodes += 1
    assert episodes >= 6
    assert venv.get_attr("time") == [e.time for e in batch.unwrapped.envs]
    venv.close()


def test_a_reset_cannot_change_the_batchs_map():
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, config=SHORT)
    envs.reset(seed=0, options={"config": {"traffic_vehicles": 1}})  # anything else may change
    assert all(len(e.road.vehicles) <= 2 for e in envs.unwrapped.envs)
    with pytest.raises(Feat2MapError, match="map_seed"):
        envs.reset(options={"config": {"map_seed": 4}})
    with pytest.raises(Feat2MapError, match="new_map_each_reset"):
        envs.reset(options={"config": {"new_map_each_reset": True}})
    envs.close()


def test_sb3_adapter_takes_either_autoreset_mode_with_the_same_steps():
    pytest.importorskip("stable_baselines3", reason=SKIP_RL)
    from feat2map.envs.sb3 import sb3_vec_env

    runs = []
    for kwargs in ({}, {"autoreset_mode": AutoresetMode.SAME_STEP}):  # the default, and the keyword that makes it
        venv = sb3_vec_env(gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, config=SHORT, **kwargs))
        venv.seed(0)
        steps = [venv.reset()]
        for _ in range(12):
            obs, rew, done, infos = venv.step(np.array([2, 1]))
            steps += [obs, rew, done, [sorted(i) for i in infos]]
        runs.append(steps)
        venv.close()
    assert len(runs[0]) == len(runs[1])
    for a, b in zip(*runs):
        assert data_equivalence(a, b)


def _busy_batch(n: int):
    return gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, config={**BUSY, "duration": 3.0},
                        autoreset_mode=AutoresetMode.SAME_STEP)


def test_sb3_workers_step_their_shares_as_one_batch_steps_them_all():
    """Three sub-envs split over two worker processes (two and one) give what one batch of the
    three gives from the same seeds and actions, through episode ends; attributes and methods
    reach the sub-env asked; a bad action is refused naming the sub-env before any worker steps,
    and an error in a worker reaches the caller naming it."""
    pytest.importorskip("stable_baselines3", reason=SKIP_RL)
    from feat2map.envs.sb3 import sb3_vec_env, sb3_workers

    whole, split = sb3_vec_env(_busy_batch(3)), sb3_workers(_busy_batch, 3, workers=2)
    try:
        assert split.observation_space == whole.observation_space and split.action_space == whole.action_space
        runs = []
        for venv in (whole, split):
            venv.seed(7)
            steps = [venv.reset()]
            rng = np.random.default_rng(0)
            for _ in range(30):
                obs, rew, done, infos = venv.step(rng.uniform(-1, 1, (3, 1)).astype(np.float32))
                steps += [obs, rew, done, [sorted(i.items()) for i in infos]]
            runs.append(steps)
        assert sum(d.sum() for d in runs[0][3::4]) >= 2  # episodes ended and were reset in both
        for a, b in zip(*runs):
            assert data_equivalence(a, b)
        assert split.get_attr("time") == whole.get_attr("time")
        split.set_attr("probe", 5, indices=[2])
        assert split.get_attr("probe", indices=2) == [5] and split.env_method("_is_truncated", indices=[0, 2]) == \
            whole.env_method("_is_truncated", indices=[0, 2])
        before = split.get_attr("time")
        bad = np.zeros((3, 1), dtype=np.float32)
        bad[2, 0] = np.nan
        with pytest.raises(Feat2MapError, match=re.escape("actions[2] (sub-env 2)")):
            split.step(bad)
        assert split.get_attr("time") == before  # no worker stepped
        with pytest.raises(RuntimeError, match="worker 1 failed"):
            split.env_method("no_such_method", indices=[2])
        split.step(np.zeros((3, 1), dtype=np.float32))  # the workers go on
        assert split.get_attr("time") != before
    finally:
        whole.close()
        split.close()
    with pytest.raises(Feat2MapError, match="workers"):
        sb3_workers(_busy_batch, 2, workers=3)


def test_gymnasiums_vector_kwargs_is_refused_and_the_adapter_says_what_to_write():
    """Gymnasium refuses `vector_kwargs` for any vector_entry_point env before feat2map is called;
    envs/README.md gives the keyword that works, and so does the adapter's error for an env that
    cannot switch to same-step itself."""
    from feat2map.envs.vector import SAME_STEP_HOWTO, same_step

    with pytest.raises(gym.error.Error, match="only through kwargs"):
        gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    readme = (REPO / "envs" / "README.md").read_text()
    assert "autoreset_mode=AutoresetMode.SAME_STEP" in readme and "sb3_vec_env(gym.make_vec(" in readme

    class Remote(gym.vector.VectorEnv):  # as AsyncVectorEnv: its mode lives in worker processes
        metadata = {"autoreset_mode": AutoresetMode.NEXT_STEP}

    with pytest.raises(Feat2MapError, match=re.escape("gym.make_vec(ID, num_envs=N, autoreset_mode='SameStep')")):
        same_step(Remote())
    assert "autoreset_mode='SameStep'" in SAME_STEP_HOWTO


def same_outputs(a: tuple, b: tuple, label: str) -> None:
    names = ("obs", "info") if len(a) == 2 else ("obs", "reward", "terminated", "truncated", "info")
    assert len(a) == len(b) == len(names)
    for name, x, y in zip(names, a, b):
        assert_same(x, y, f"{label} {name}")


BAD_BATCHES = {"one short": ([0, 1, 2], r"^actions: must be one action per sub-env: 4, got 3"),
               "one long": ([0, 1, 2, 1, 1], r"^actions: must be one action per sub-env: 4, got 5"),
               "out of space": ([0, 1, 2, 99], r"^actions\[3\] \(sub-env 3\): must be in \[0, 3\), got 99"),
               "negative": (np.array([0, -1, 2, 1]), r"^actions\[1\] \(sub-env 1\): must be in \[0, 3\), got -1"),
               "not integers": ([0, 1, 2, 0.5], r"^actions\[3\] \(sub-env 3\): must be an integer"),
               "a scalar": (1, r"^actions: must be one action per sub-env \(4\), got int"),
               "None": (None, r"^actions: must be one action per sub-env \(4\), got NoneType")}


@pytest.mark.parametrize("bad", BAD_BATCHES)
def test_a_refused_batch_action_leaves_every_sub_env_untouched(bad):
    """Issue 35: a batch action of the wrong length or with a value out of the space is refused
    (a ValueError naming the sub-env and the value) before any sub-env is stepped or autoreset:
    afterwards the batch steps exactly as a twin that never saw the refused step."""
    envs, twin = (gym.make_vec("feat2map/JunctionGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                               config=SHORT) for _ in range(2))
    same_outputs(envs.reset(seed=3), twin.reset(seed=3), "reset")
    good = np.array([1, 2, 0, 1])
    for t in range(5):  # to the episodes' end: the next step autoresets them
        same_outputs(envs.step(good), twin.step(good), f"step {t}")
    action, message = BAD_BATCHES[bad]
    clocks = [e.time for e in envs.unwrapped.envs]
    with pytest.raises(ValueError, match=message):
        envs.step(action)
    assert [e.time for e in envs.unwrapped.envs] == clocks
    for t in range(7):
        same_outputs(envs.step(good), twin.step(good), f"step {t} after")
    envs.close()
    twin.close()


def test_a_refused_continuous_batch_action_names_the_sub_env():
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode="vector_entry_point",
                        config={**SHORT, "action": DRIVER_ACTION_CONFIG})
    envs.reset(seed=0)
    shape = envs.single_action_space.shape
    with pytest.raises(ValueError, match=r"^actions\[1\] \(sub-env 1\): must be finite"):
        envs.step(np.stack([np.zeros(shape), np.full(shape, np.nan)]))
    with pytest.raises(ValueError, match=r"^actions: must be one action per sub-env: 2, got 3"):
        envs.step(np.zeros((3, *shape)))
    assert [e.time for e in envs.unwrapped.envs] == [0, 0]
    envs.close()


@pytest.mark.parametrize("options, where", [("config", "options"), ([1], "options"), (5, "options"),
                                            ({"config": "abc"}, "options.config")])
def test_reset_options_that_are_not_a_dict_are_a_clear_error(options, where):
    """Issue 35: not an AttributeError deep inside, for the batch and for a single env."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode="vector_entry_point", config=SHORT)
    single = gym.make("feat2map/JunctionGrid-v0", config=SHORT)
    for env in (envs, single):
        with pytest.raises(ValueError, match=f"^{where}: must be a dict"):
            env.reset(seed=0, options=options)
        env.reset(seed=0, options={"config": {"traffic_vehicles": 1}})  # a dict is taken
    envs.close()


def test_the_batch_is_a_vector_env_of_its_own_and_refuses_bad_seeds_and_masks():
    """MapVectorEnv is a `gymnasium.vector.VectorEnv` that keeps its own buffers (not a
    SyncVectorEnv whose internals it rewrites); its outputs are fresh arrays each call, and bad
    seeds or reset masks are refused, naming the argument, before any sub-env is reset."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=3, vectorization_mode="vector_entry_point", config=SHORT)
    base = envs.unwrapped
    assert isinstance(base, gym.vector.VectorEnv) and not isinstance(base, gym.vector.SyncVectorEnv)
    obs, _ = envs.reset(seed=1)
    kept = obs.copy()
    obs2, *_ = envs.step(np.array([1, 1, 1]))
    assert obs2 is not obs and np.array_equal(obs, kept)  # the step wrote no array it handed out before
    clocks = [e.time for e in base.envs]
    for seed, options, where in (([1, 2], None, "seed"),
                                 (None, {"reset_mask": [True, False, True]}, "options.reset_mask"),
                                 (None, {"reset_mask": np.zeros(3, dtype=bool)}, "options.reset_mask"),
                                 (None, {"reset_mask": np.ones(2, dtype=bool)}, "options.reset_mask")):
        with pytest.raises(Feat2MapError, match=f"^{re.escape(where)}: "):
            envs.reset(seed=seed, options=options)
    assert [e.time for e in base.envs] == clocks
    envs.close()


@given(st.data())
@settings(max_examples=200, deadline=None)
def test_a_batch_checked_at_once_passes_exactly_what_each_action_check_passes(data):
    """`valid_batch` (the batch's actions checked in one program) accepts an array exactly where
    `check_action` accepts every action of it: valid batches, and batches with one action just
    out of range, not finite, or of the wrong dtype or shape."""
    from feat2map.envs.map_env import check_action
    from feat2map.envs.vector import valid_batch

    space = data.draw(st.sampled_from([gym.spaces.Discrete(5), gym.spaces.Discrete(3, start=2),
                                       gym.spaces.Box(-1.0, 1.0, (2,), dtype=np.float32)]))
    n = data.draw(st.integers(1, 6))
    space.seed(data.draw(st.integers(0, 1000)))
    actions = np.array([space.sample() for _ in range(n)])
    bad = data.draw(st.sampled_from(["none", "value", "dtype", "shape"]))
    k = data.draw(st.integers(0, n - 1))
    if bad == "value":
        if isinstance(space, gym.spaces.Discrete):
            actions[k] = data.draw(st.sampled_from([int(space.start) - 1, int(space.start + space.n)]))
        else:
            actions[k, data.draw(st.integers(0, 1))] = data.draw(st.sampled_from([np.nan, np.inf, -np.inf]))
    elif bad == "dtype":
        actions = actions.astype(np.float64 if isinstance(space, gym.spaces.Discrete) else np.int64)
    elif bad == "shape":
        actions = data.draw(st.sampled_from([actions[:-1], np.concatenate([actions, actions[:1]]), actions[..., None]]))

    def each_passes() -> bool:
        if actions.shape[:1] != (n,):
            return False
        try:
            for a in actions:
                check_action(space, a)
        except Feat2MapError:
            return False
        return True
    ok = valid_batch(space, actions, n)
    assert ok == (bad == "none") or (not ok and bad == "dtype" and each_passes())  # (ints are finite floats)
    assert not ok or each_passes()


@pytest.mark.parametrize("action", [{"type": "DiscreteMetaAction"}, {"type": "ContinuousAction"}])
def test_a_steps_info_gives_each_sub_envs_action_in_the_action_spaces_dtype(action):
    """info["action"] of a step: the actions the batch was given, one row per sub-env, in the
    single action space's dtype and shape (as Gymnasium stacks the single envs' 0-d or 1-d arrays)."""
    env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=4, vectorization_mode="vector_entry_point",
                       config={"action": action, "traffic_vehicles": 2})
    env.reset(seed=0)
    env.action_space.seed(0)
    single = env.unwrapped.single_action_space
    reset = np.zeros(4, dtype=bool)  # (a sub-env reset this step gives its reset's info)
    for _ in range(4):
        actions = env.action_space.sample()
        _, _, terminated, truncated, info = env.step(actions)
        assert info["action"].dtype == single.dtype and info["action"].shape == (4, *single.shape)
        np.testing.assert_array_equal(info["action"][~reset], actions[~reset])
        assert info["_action"].all()
        reset = terminated | truncated
    env.close()
