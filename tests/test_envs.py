"""Gymnasium API of the feat2map environments: registration, check_env, observation and action
types, seeding, vector envs, map files."""
from __future__ import annotations

import os
import subprocess
import sys

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import feat2map
from feat2map import mapio
from feat2map.envs.driver import DRIVER_ACTION_CONFIG

J = feat2map.JunctionFeature.make
SMALL = [J([0, 90, 180, 270], "signal", True).to_dict(), J([0, 90, 180], "stop", False).to_dict()]
BASE = {"features": SMALL, "traffic_vehicles": 4}


def make(config=None, env_id="feat2map/JunctionGrid-v0", **kw):
    return gym.make(env_id, config={**BASE, **(config or {})}, **kw)


@pytest.mark.parametrize("config", [
    {},
    {"observe_traffic_control": True},
    {"action": DRIVER_ACTION_CONFIG},
    {"action": {"type": "ContinuousAction"}},
    {"new_map_each_reset": True, "features": None},  # the paper's SF feature space, fresh maps
])
def test_check_env_junction_grid(config):
    env = make(config)
    check_env(env.unwrapped, skip_render_check=True)
    env.close()


def test_check_env_map_file(tmp_path):
    m = feat2map.generate_from_features([J([0, 90, 180, 270], "stop", True)], seed=1)
    path = tmp_path / "map.json"
    mapio.save(m, path)
    for cfg in ({"map_file": str(path)}, {"map": m}):
        env = gym.make("feat2map/MapFile-v0", config={**cfg, "traffic_vehicles": 3})
        check_env(env.unwrapped, skip_render_check=True)
        _, info = env.reset(seed=0)
        assert info["junction"] == "J0" and info["control_ahead"] == "stop"


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


@pytest.mark.parametrize("obs", [
    {"type": "Kinematics"},
    {"type": "OccupancyGrid", "features": ["presence", "vx", "vy"], "grid_size": [[-20, 20], [-20, 20]],
     "grid_step": [5, 5]},
    {"type": "TimeToCollision", "horizon": 5},
    {"type": "LidarObservation", "cells": 16},
    {"type": "GrayscaleObservation", "observation_shape": (64, 32), "stack_size": 2,
     "weights": [0.2989, 0.5870, 0.1140], "scaling": 1.5},
])
@pytest.mark.parametrize("action", [
    {"type": "DiscreteMetaAction"},
    {"type": "ContinuousAction"},
    {"type": "DiscreteAction"},
])
def test_observation_and_action_types(obs, action):
    env = make({"observation": obs, "action": action})
    o, _ = env.reset(seed=0)
    assert env.observation_space.contains(o)
    for _ in range(2):
        o, r, term, trunc, info = env.step(env.action_space.sample())
        assert env.observation_space.contains(o) and np.isfinite(r)
        if term or trunc:
            break


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
