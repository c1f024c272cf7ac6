"""Strict env configuration and action checks: unknown keys name the closest valid key, bad
values (type, finite, range) and bad actions are one-line Feat2MapErrors naming the element, and
Gymnasium's checker has nothing to warn about."""
from __future__ import annotations

import math
import os
import warnings

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import feat2map
from feat2map.envs.driver import DRIVER_ACTION_CONFIG
from feat2map.errors import Feat2MapError

J = feat2map.JunctionFeature.make
SMALL = {"features": [J([0, 90, 180], "signal", True).to_dict()], "traffic_vehicles": 2}


def make(config=None, env_id="feat2map/JunctionGrid-v0"):
    return gym.make(env_id, config={**SMALL, **(config or {})})


@pytest.mark.parametrize("config, where, text", [
    ({"trafic_vehicles": 3}, "config.trafic_vehicles", "did you mean 'traffic_vehicles'"),
    ({"signal_gren": 10}, "config.signal_gren", "did you mean 'signal_green'"),
    ({"lanes_cont": 3}, "config.lanes_cont", "highway-env's 'lanes_count' is not a key here (the map sets the lanes)"),
    ({"zzzz": 3}, "config.zzzz", "the keys are default_config()'s: action, "),
    ({"observation": {"vehicle_count": 5}}, "config.observation.vehicle_count", "did you mean 'vehicles_count'"),
    ({"observation": {"type": "Kinematic"}}, "config.observation.type", "did you mean 'Kinematics'"),
    ({"action": {"type": "ContinuousAction", "acceleration": [-3, 3]}}, "config.action.acceleration",
     "did you mean 'acceleration_range'"),
    ({"traffic_vehicles": -1}, "config.traffic_vehicles", "must be >= 0"),
    ({"traffic_vehicles": 2.5}, "config.traffic_vehicles", "must be an integer"),
    ({"traffic_vehicles": True}, "config.traffic_vehicles", "must be an integer"),
    ({"duration": math.nan}, "config.duration", "must be finite"),
    ({"duration": math.inf}, "config.duration", "must be finite"),
    ({"duration": 0}, "config.duration", "must be > 0"),
    ({"pedestrian_rate": "3"}, "config.pedestrian_rate", "must be a number"),
    ({"signal_phases": "pairs"}, "config.signal_phases", "did you mean 'paired'"),
    ({"policy_frequency": 30}, "config.policy_frequency", "must be <= simulation_frequency"),
    ({"signal_offsets": {"J0": math.nan}}, "config.signal_offsets.J0", "must be finite"),
    ({"right_turn_on_red": "yes"}, "config.right_turn_on_red", "must be true or false"),
    ({"route": [("J0", "R0")]}, "config.route[0]", "(junction id, entry road id, exit road id)"),
])
def test_bad_config_is_a_one_line_error_naming_the_key(config, where, text):
    with pytest.raises(Feat2MapError) as err:
        make(config)
    assert err.value.where == where and text in err.value.message, str(err.value)
    assert "\n" not in str(err.value)


def test_map_file_env_checks_its_values_and_configure_is_strict(tmp_path):
    m = feat2map.generate_from_features([J([0, 90, 180], "stop", False)], seed=0)
    for cfg, where in (({"traffic_vehicles": -1}, "config.traffic_vehicles"), ({"duration": math.nan}, "config.duration"),
                       ({"features": []}, "config.features")):
        with pytest.raises(Feat2MapError) as err:
            gym.make("feat2map/MapFile-v0", config={"map": m, **cfg})
        assert err.value.where == where
    env = gym.make("feat2map/MapFile-v0", config={"map": m, "traffic_vehicles": 1})
    with pytest.raises(Feat2MapError, match="did you mean 'pedestrian_rate'"):
        env.unwrapped.configure({"pedestrians_rate": 1.0})
    with pytest.raises(Feat2MapError, match="config.duration"):
        env.reset(seed=0, options={"config": {"duration": -1.0}})
    assert env.unwrapped.config["duration"] == 60.0  # a rejected configure changes nothing
    env.unwrapped.configure({"duration": 5.0})
    assert env.unwrapped.config["duration"] == 5.0


@pytest.mark.parametrize("action_config, action, text", [
    (DRIVER_ACTION_CONFIG, np.array([math.nan], dtype=np.float32), "must be finite"),
    (DRIVER_ACTION_CONFIG, np.array([0.1, 0.2], dtype=np.float32), "shape (1,)"),
    (DRIVER_ACTION_CONFIG, None, "shape (1,)"),
    (DRIVER_ACTION_CONFIG, "fast", "shape (1,)"),
    ({"type": "DiscreteMetaAction"}, 7, "must be in [0, 3)"),
    ({"type": "DiscreteMetaAction"}, 1.5, "must be an integer"),
    ({"type": "DiscreteMetaAction"}, None, "must be an integer"),
])
def test_bad_actions_are_clear_errors(action_config, action, text):
    env = make({"action": action_config})
    env.reset(seed=0)
    with pytest.raises(Feat2MapError) as err:
        env.step(action)
    assert err.value.where == "action" and text in err.value.message
    env.step(env.action_space.sample())  # the env is still usable
    env.close()


@pytest.mark.parametrize("config", [
    {},
    {"action": DRIVER_ACTION_CONFIG, "observe_traffic_control": True},
    {"observation": {"type": "OccupancyGrid", "features": ["presence", "vx"], "grid_size": [[-20, 20], [-20, 20]],
                     "grid_step": [5, 5]}},
    {"observation": {"type": "Kinematics", "normalize": False}},
])
def test_gymnasium_checkers_do_not_warn(config):
    """check_env and the passive checker of gym.make: finite observation bounds, a new info
    dict (and action copy) every step, even when the caller passes the same action object."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        env = make(config)
        check_env(env.unwrapped, skip_render_check=True)
        env.reset(seed=0)
        action = env.action_space.sample()
        for _ in range(3):
            env.step(action)
        env.close()
    messages = [str(w.message) for w in caught if "gymnasium" in w.filename or "WARN" in str(w.message)]
    assert not messages, messages
    assert np.all(np.isfinite(env.observation_space["observation"].low if isinstance(env.observation_space, gym.spaces.Dict)
                              else env.observation_space.low))


def test_kinematics_bounds_follow_normalization():
    env = make({"observation": {"type": "Kinematics", "features": ["presence", "x", "heading", "cos_h"],
                                "features_range": {"x": [-50, 50]}}})
    space = env.observation_space
    np.testing.assert_array_equal(space.low[0], [0.0, -1.0, np.finfo(np.float32).min, -1.0])
    np.testing.assert_array_equal(space.high[0], [1.0, 1.0, np.finfo(np.float32).max, 1.0])
    assert env.unwrapped.metadata["autoreset_mode"] == gym.vector.AutoresetMode.NEXT_STEP
