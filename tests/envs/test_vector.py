"""Vector envs: gym.make_vec (sync and async) and SB3's SubprocVecEnv step through many episode
ends; every info key keeps its type and shape in every step and env."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from conftest import SKIP_RL

import feat2map

J = feat2map.JunctionFeature.make
# short episodes on a small map: a sampled route through one junction, 2.5 s long at 2 Hz
SHORT = {"features": [J([0, 90, 180], "signal", True).to_dict(), J([0, 90, 180, 270], "stop", False).to_dict()],
         "traffic_vehicles": 3, "route_junctions": 1, "duration": 2.5, "policy_frequency": 2}


def signature(value):
    """What must stay the same for vector envs to stack a value: its type, and dtype and shape."""
    if isinstance(value, dict):
        return dict, {k: signature(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return np.ndarray, value.dtype, value.shape
    return type(value)


def _stable_keys(info: dict) -> dict:
    """Keys whose values must keep their type (signal_states' keys name the junction's signals)."""
    return {k: signature(v) for k, v in info.items() if k != "signal_states"}


def test_info_keys_keep_their_types_across_steps_episodes_and_maps():
    env = gym.make("feat2map/JunctionGrid-v0", config=SHORT)
    _, info = env.reset(seed=0)
    ref = _stable_keys(info)
    ends, ids = 0, set()
    for step in range(60):
        _, _, term, trunc, new = env.step(env.action_space.sample())
        assert new is not info and _stable_keys(new) == ref, step
        ids.add(new["junction"])
        info = new
        if term or trunc:
            ends += 1
            _, info = env.reset()
            assert _stable_keys(info) == ref
    assert ends >= 10 and len(ids) > 1
    env.close()


@pytest.mark.parametrize("mode", ["sync", "async"])
def test_make_vec_steps_through_episode_ends(mode):
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode=mode, config=SHORT)
    obs, info = envs.reset(seed=[0, 1])
    envs.action_space.seed(0)
    ends = 0
    for _ in range(40):
        obs, rew, term, trunc, info = envs.step(envs.action_space.sample())
        assert obs.shape == (2, *envs.single_observation_space.shape) and np.all(np.isfinite(rew))
        assert info["junction_feature"]["rotation"].shape == (2, 8) and info["speed"].dtype == np.float64
        ends += int(np.sum(term | trunc))
    assert ends >= 10
    envs.close()


def test_sb3_subproc_vec_env_steps_through_episode_ends():
    pytest.importorskip("stable_baselines3", reason=SKIP_RL)
    from stable_baselines3.common.vec_env import SubprocVecEnv

    # the workers start afresh (forkserver): "feat2map:" makes gym.make import feat2map there
    venv = SubprocVecEnv([lambda: gym.make("feat2map:feat2map/JunctionGrid-v0", config=SHORT)] * 2, start_method="forkserver")
    venv.seed(0)
    venv.reset()
    dones = 0
    for _ in range(30):
        _, rew, done, infos = venv.step(np.array([venv.action_space.sample() for _ in range(2)]))
        dones += int(done.sum())
        assert len(infos) == 2 and np.all(np.isfinite(rew))
    assert dones >= 6
    venv.close()
