"""Gymnasium API of the feat2map environments: registration, check_env, observation and action
types, seeding, vector envs, map files."""
from __future__ import annotations

import os
import subprocess
import sys
import warnings

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env, data_equivalence

import feat2map
from feat2map.formats import native
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver

from conftest import shared_map

J = feat2map.JunctionFeature.make
SMALL = [J([0, 90, 180, 270], "signal", True).to_dict(), J([0, 90, 180], "stop", False).to_dict()]
BASE = {"features": SMALL, "traffic_vehicles": 4}


def make(config=None, env_id="feat2map/JunctionGrid-v0", **kw):
    return gym.make(env_id, config={**BASE, **(config or {})}, **kw)


@pytest.mark.parametrize("config", [  # besides the observation x action matrix below
    {"action": DRIVER_ACTION_CONFIG, "observe_traffic_control": True},
    {"new_map_each_reset": True, "features": None},  # the paper's SF feature space, fresh maps
])
def test_check_env_junction_grid(config):
    env = make(config)
    with warnings.catch_warnings(record=True) as caught:  # the checker warns on infinite bounds, reused info dicts
        warnings.simplefilter("always")
        check_env(env.unwrapped, skip_render_check=True)
    assert [str(w.message) for w in caught] == []
    env.close()


def test_check_env_map_file(tmp_path):
    m = feat2map.generate_from_features([J([0, 90, 180, 270], "stop", True)], seed=1)
    path = tmp_path / "map.json"
    native.save(m, path)
    for cfg in ({"map_file": str(path)}, {"map": m}):
        env = gym.make("feat2map/MapFile-v0", config={**cfg, "traffic_vehicles": 3})
        check_env(env.unwrapped, skip_render_check=True)
        _, info = env.reset(seed=0)
        assert info["junction"] == "J0" and info["control_ahead"] == "stop"


def _drive(env, seed):
    """Drive the scripted driver to the end; (final info, controls seen ahead on the way)."""
    env.reset(seed=seed)
    driver = ScriptedDriver(env)
    seen = set()
    while True:
        _, _, term, trunc, info = env.step(driver.act())
        seen.add(info["control_ahead"])
        if term or trunc:
            return info, seen


def test_map_file_reads_opendrive(tmp_path):
    """MapFile-v0 goes through feat2map.readers.read_map: an .xodr drives like the native map."""
    from feat2map.formats.opendrive.writer import write_opendrive

    m = feat2map.generate_from_features([J([0, 90, 180, 270], "signal", True), J([0, 90, 180], "stop", False)], seed=1)
    write_opendrive(m, tmp_path / "map.xodr")
    env = gym.make("feat2map/MapFile-v0", config={"map_file": str(tmp_path / "map.xodr"), "traffic_vehicles": 3,
                                                   "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5})
    check_env(env.unwrapped, skip_render_check=True)
    assert len(env.unwrapped.net.hdmap.junctions) == 2 and env.unwrapped.net.hdmap.signals
    info, seen = _drive(env, seed=0)
    assert info["route_completed"] and sum(info["violations"].values()) == 0 and not info["collision"], info
    assert seen & {"signal", "stop"}


@pytest.mark.real_maps
def test_map_file_real_opendrive_signalized_crossing():
    """A third-party OpenDRIVE crossing with a signal head per lane: heads of one approach share a
    phase (else the cycle is 12 phases long and nobody gets through), the driver completes routes."""
    path = shared_map("opendrive/commonroad_four_way_crossing/four_way_crossing.xodr")
    env = gym.make("feat2map/MapFile-v0", config={"map_file": str(path), "traffic_vehicles": 3,
                                                   "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5,
                                                   "duration": 60})
    check_env(env.unwrapped, skip_render_check=True)
    u = env.unwrapped
    plans = {id(p): p for p in u.control.plans.values()}
    assert len(u.net.hdmap.signals) == 12 and [len(p.phases) for p in plans.values()] == [2]
    for seed in range(2):
        info, seen = _drive(env, seed)
        assert info["route_completed"] and sum(info["violations"].values()) == 0 and not info["collision"], info
        assert "signal" in seen


@pytest.mark.real_maps
def test_map_file_real_apollo_map_with_signals_and_stop_signs():
    """An Apollo base_map.bin (stop lines on junction lanes, as Apollo's overlaps put them) drives
    without violations, and the driver meets both signals and stop signs on its routes."""
    path = shared_map("apollo/cube_town/base_map.bin")
    env = gym.make("feat2map/MapFile-v0", config={"map_file": str(path), "traffic_vehicles": 3,
                                                   "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5,
                                                   "duration": 60})
    check_env(env.unwrapped, skip_render_check=True)
    seen_all = set()
    for seed in range(2):
        info, seen = _drive(env, seed)
        seen_all |= seen
        assert info["route_completed"] and sum(info["violations"].values()) == 0 and not info["collision"], info
    assert {"signal", "stop"} <= seen_all


def test_map_file_unknown_format_is_a_clear_error(tmp_path):
    bad = tmp_path / "map.txt"
    bad.write_text("not a map")
    with pytest.raises(feat2map.errors.MapFormatError) as err:  # one line naming the file
        gym.make("feat2map/MapFile-v0", config={"map_file": str(bad)})
    assert str(bad) in str(err.value) and "\n" not in str(err.value)


def test_map_file_missing_is_a_clear_error():
    with pytest.raises(feat2map.errors.Feat2MapError, match="map_file"):
        gym.make("feat2map/MapFile-v0")


def test_default_config_is_the_paper_sf_space_and_merges():
    env = gym.make("feat2map/JunctionGrid-v0", config={"observation": {"vehicles_count": 5}})
    u = env.unwrapped
    assert u.config["feature_space"] == feat2map.PAPER_SF_FEATURE_SPACE.to_dict()
    assert u.config["observation"]["type"] == "Kinematics"  # merged, not replaced
    assert env.observation_space.shape == (5, 7)
    assert len(u.net.hdmap.junctions) == 8  # one junction per SF feature combination


OBSERVATIONS = [
    {"type": "Kinematics"},
    {"type": "OccupancyGrid", "features": ["presence", "vx", "vy"], "grid_size": [[-20, 20], [-20, 20]],
     "grid_step": [5, 5]},
    {"type": "TimeToCollision", "horizon": 5},
    {"type": "LidarObservation", "cells": 16},
    {"type": "GrayscaleObservation", "observation_shape": (64, 32), "stack_size": 2,
     "weights": [0.2989, 0.5870, 0.1140], "scaling": 1.5},
]
ACTIONS = [{"type": "DiscreteMetaAction"}, {"type": "ContinuousAction"}, {"type": "DiscreteAction"}]


@pytest.fixture(scope="module")
def map_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("map") / "map.json"
    native.save(feat2map.generate_from_features([feat2map.JunctionFeature.from_dict(f) for f in SMALL], seed=0), path)
    return str(path)


@pytest.mark.parametrize("env_id", ["feat2map/JunctionGrid-v0", "feat2map/MapFile-v0"])
@pytest.mark.parametrize("traffic_control", [False, True])
@pytest.mark.parametrize("action", ACTIONS, ids=lambda a: a["type"])
@pytest.mark.parametrize("obs", OBSERVATIONS, ids=lambda o: o["type"])
def test_check_env_every_observation_action_and_id(obs, action, traffic_control, env_id, map_file):
    """Gymnasium's checker (spaces, seeding determinism, step API) for every shipped combination."""
    config = {"observation": obs, "action": action, "observe_traffic_control": traffic_control}
    if env_id.endswith("MapFile-v0"):  # a map file instead of features (an unknown key is an error)
        env = gym.make(env_id, config={"traffic_vehicles": BASE["traffic_vehicles"], "map_file": map_file, **config})
    else:
        env = make(config, env_id)
    check_env(env.unwrapped, skip_render_check=True)
    o, _ = env.reset(seed=0)
    assert env.observation_space.contains(o)
    if traffic_control:
        assert set(o) == {"observation", "traffic_control"} and o["traffic_control"].shape == (6,)
    for _ in range(2):
        o, r, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(o) and np.isfinite(r)
        if term or trunc:
            break
    env.close()


def _trajectory(seed):
    env = make({"action": DRIVER_ACTION_CONFIG, "pedestrian_rate": 20})
    env.reset(seed=seed)
    env.action_space.seed(seed)
    out = []
    for _ in range(8):
        o, r, term, trunc, info = env.step(env.action_space.sample())
        out.append((o.copy(), r, info["route_progress"], len(env.unwrapped.road.objects)))
        if term or trunc:
            break
    return out


def test_same_seed_same_trajectory():
    a, b, c = _trajectory(3), _trajectory(3), _trajectory(4)
    assert len(a) == len(b)
    for x, y in zip(a, b):
        np.testing.assert_array_equal(x[0], y[0])
        assert x[1:] == y[1:]
    assert any(not np.array_equal(x[0], y[0]) for x, y in zip(a, c))


def _env_fn():
    return gym.make("feat2map/JunctionGrid-v0", config=BASE)


@pytest.mark.parametrize("vector", [gym.vector.SyncVectorEnv, gym.vector.AsyncVectorEnv])
def test_vector_envs(vector):
    envs = vector([_env_fn, _env_fn])
    obs, info = envs.reset(seed=[0, 1])
    assert obs.shape[0] == 2
    for _ in range(2):
        obs, rew, term, trunc, info = envs.step(envs.action_space.sample())
    assert rew.shape == (2,) and "route_progress" in info
    envs.close()


def test_make_with_module_prefix_without_prior_import():
    code = ("import gymnasium as gym; env = gym.make('feat2map:feat2map/JunctionGrid-v0', "
            "config={'traffic_vehicles': 1}); env.reset(seed=0); print(type(env.unwrapped).__name__)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120,
                         env={**os.environ, "SDL_VIDEODRIVER": "offscreen"})
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip().endswith("JunctionGridEnv")


def test_register_twice_is_harmless():
    from feat2map.envs.registration import ENV_IDS, register_envs

    register_envs()
    register_envs()
    assert all(i in gym.registry for i in ENV_IDS)


def test_render_rgb_array_and_unreachable_route_error():
    env = make(render_mode="rgb_array")
    env.reset(seed=0)
    frame = env.render()
    assert frame.shape == (600, 600, 3) and frame.std() > 10  # not a blank frame
    with pytest.raises(feat2map.errors.Feat2MapError, match="route"):
        make({"route": [("J0", "R0", "R0_nonexistent")]})


def test_make_vec_async_with_spawned_workers():
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode="async",
                        vector_kwargs={"context": "spawn"}, config={**BASE, "traffic_vehicles": 2})
    obs, _ = envs.reset(seed=0)
    obs, rew, *_ = envs.step(envs.action_space.sample())
    assert obs.shape[0] == 2 and np.all(np.isfinite(rew))
    envs.close()


@pytest.mark.parametrize("phases", ["paired", "single"])
def test_each_phase_is_green_then_amber_then_red_in_turn(phases):
    """The signals' states (`signal_state`, read from the phase plans' one program): over a cycle
    each signal is green for `signal_green` seconds, then amber for `signal_amber`, then red; the
    phases take turns, never two green together, each green beginning `signal_all_red` seconds
    after the amber before it ends."""
    g, a, r, dt = 7.0, 2.0, 1.5, 0.05
    env = make({"features": SMALL[:1], "signal_phases": phases, "signal_green": g, "signal_amber": a,
                "signal_all_red": r, "traffic_vehicles": 0})
    env.reset(seed=3)
    ctl = env.unwrapped.control
    ids = sorted(ctl.plans)
    n = len({ctl.plans[s].phase_of(s) for s in ids})
    assert n == (2 if phases == "paired" else 4)
    times = np.arange(0.0, 2 * n * (g + a + r), dt)
    seen = []
    for t in times:
        ctl.t = float(t)
        seen.append([ctl.signal_state(s) for s in ids])
    seen = np.array(seen)
    for k in range(len(ids)):
        for state, seconds in (("green", g), ("amber", a), ("red", n * (g + a + r) - g - a)):
            assert (seen[:, k] == state).sum() * dt == pytest.approx(2 * seconds, abs=2 * dt)
        after = seen[1:, k][seen[:-1, k] != seen[1:, k]]  # the states it changes to
        assert set(zip(after[:-1], after[1:])) <= {("amber", "red"), ("red", "green"), ("green", "amber")}
    phase = np.array([ctl.plans[s].phase_of(s) for s in ids])
    for row in seen:
        assert len(set(phase[row != "red"])) <= 1  # one phase at a time
    ends = times[1:][(seen[:-1] == "amber").any(axis=1) & ~(seen[1:] == "amber").any(axis=1)]
    starts = times[1:][~(seen[:-1] == "green").any(axis=1) & (seen[1:] == "green").any(axis=1)]
    gaps = [s - e for e in ends for s in starts if 0 <= s - e < g]
    assert len(gaps) >= 2 * n - 1 and gaps == pytest.approx([r] * len(gaps), abs=2 * dt)


@pytest.mark.parametrize("action", [{"type": "DiscreteMetaAction"}, DRIVER_ACTION_CONFIG, {"type": "DiscreteAction"}])
def test_a_resets_info_is_the_same_from_the_same_seed_its_action_the_no_op(action):
    """No action is taken at a reset: the info's action is the no-op (a meta-action's IDLE, the
    space's first value), so two envs reset from one seed give the same info, key by key."""
    envs = [make({"traffic_vehicles": 3, "action": action}) for _ in range(2)]
    infos = [env.reset(seed=4)[1] for env in envs]
    assert infos[0].keys() == infos[1].keys()
    for key in infos[0]:
        assert data_equivalence(infos[0][key], infos[1][key]), key
    u = envs[0].unwrapped
    kind = action["type"]
    want = u.action_type.actions_indexes["IDLE"] if kind == "DiscreteMetaAction" else 0 if kind == "DiscreteAction" \
        else np.zeros(u.action_space.shape)
    np.testing.assert_array_equal(infos[0]["action"], want)
