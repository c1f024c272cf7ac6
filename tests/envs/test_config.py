"""Strict env configuration and action checks: unknown keys name the closest valid key, bad
values (type, finite, range) and bad actions are one-line Feat2MapErrors naming the element, and
Gymnasium's checker has nothing to warn about."""
from __future__ import annotations

import math
import os
import warnings
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils.env_checker import check_env

import feat2map
from feat2map.envs import config, info
from feat2map.envs.driver import DRIVER_ACTION_CONFIG
from feat2map.envs.rules import VIOLATIONS
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


def test_configure_checks_the_values_changed_since_the_last_check(monkeypatch):
    """`configure` checks the values it changes and any that user code changed in `config` since
    the last check (replaced, or a nested value changed in place), not the others (a training
    script's draws change a key or two per episode; the action's and the observation's checks
    are the costly ones)."""
    env = make()
    u = env.unwrapped
    checked: list[str] = []
    schema = dict(config.SCHEMA)
    for key, check in schema.items():
        monkeypatch.setitem(config.SCHEMA, key, lambda v, where, c=check: (checked.append(where), c(v, where)))
    u.configure({"traffic_vehicles": 3})
    assert checked == ["config.traffic_vehicles"]
    u.config["duration"] = -1.0  # replaced behind configure's back: checked at the next one
    with pytest.raises(Feat2MapError, match="config.duration"):
        u.configure({"traffic_vehicles": 2})
    u.config["duration"] = 60.0
    u.config["observation"]["vehicle_count"] = 5  # changed in place
    with pytest.raises(Feat2MapError, match="config.observation"):
        u.configure({})
    env.close()


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


@pytest.mark.parametrize("action_config", [{"type": "DiscreteMetaAction"}, {"type": "DiscreteAction"}])
def test_a_discrete_action_given_as_an_array_of_one_value_is_that_value(action_config):
    """`check_action` lets np.array([k]) through for a Discrete space: the env drives it as k."""
    runs = []
    for wrap in (int, lambda k: np.array([k])):
        env = make({"action": action_config})
        env.reset(seed=0)
        runs.append([(o.tolist(), r, te, tr) for o, r, te, tr, _ in (env.step(wrap(k)) for k in (2, 2, 0, 1, 2))])
        env.close()
    assert runs[0] == runs[1]


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


# ---- one table per setting family: SETTINGS (config keys) and INFO_KEYS (info keys) ------------
README = Path(__file__).resolve().parents[2] / "envs" / "README.md"


def readme_block(name: str) -> str:
    text = README.read_text()
    start = text.index(f"<!-- {name} table: ")
    start = text.index("\n", start) + 1
    return text[start:text.index(f"<!-- end {name} table -->")]


def test_readme_tables_are_made_from_the_tables():
    """envs/README.md's config and info tables are the rendered SETTINGS and INFO_KEYS (after
    changing a row, `scripts/env_tables.py` rewrites them)."""
    assert readme_block("config") == config.markdown_table()
    assert readme_block("info") == info.markdown_table()
    assert "| `traffic_vehicles` | MapEnv | `8` | integer in [0, 500] |" in config.markdown_table()


def test_default_config_keys_are_the_table_keys_and_the_checked_keys():
    from feat2map.envs import multi_agent
    from feat2map.envs.junction_env import JunctionGridEnv, MapFileEnv

    for env, family in ((JunctionGridEnv, config.GRID), (MapFileEnv, config.FILE)):
        keys = [s.key for s in config.settings(config.MAP_ENV, family)]
        assert list(env.default_config()) == keys  # same keys, in the table's order
        assert set(keys) <= set(config.SCHEMA)
    assert set(config.SCHEMA) == {s.key for s in config.settings(config.MAP_ENV, config.GRID, config.FILE)}
    assert list(multi_agent.AGENT_DEFAULTS) == [s.key for s in config.settings(config.MULTI)]
    assert multi_agent.WORLD_DEFAULTS == {"simulation_frequency": 10, "policy_frequency": 2, "route_junctions": 1}
    assert JunctionGridEnv.default_config()["signal_green"] == feat2map.config.SIGNAL_GREEN_S
    for s in config.SETTINGS:
        s.check(s.default, f"config.{s.key}")  # every default passes its own check
        assert s.doc and config.accepts(s.check), s.key


@pytest.mark.parametrize("config_, where, text", [
    ({"other_vehicles_type": "highway_env.vehicle.behavior.IDMVehicle"}, "config.other_vehicles_type",
     "highway-env's 'other_vehicles_type' is not a key here (traffic is the env's own IDM/MOBIL vehicles)"),
    ({"neighbour_vehicles_connected_lanes": True}, "config.neighbour_vehicles_connected_lanes", "has no effect here"),
])
def test_keys_without_effect_are_refused(config_, where, text):
    with pytest.raises(Feat2MapError) as err:
        make(config_)
    assert err.value.where == where and text in err.value.message, str(err.value)


@pytest.mark.parametrize("key, value, text", [("route", [("J0", "R0", "R1")], "agent_routes"),
                                             ("offroad_terminal", False, "agents steer along their routes"),
                                             ("manual_control", True, "there is no ego")])
def test_the_multi_agent_env_refuses_the_keys_it_does_not_read(key, value, text):
    from feat2map.envs import parallel_env

    with pytest.raises(Feat2MapError) as err:
        parallel_env({**SMALL, key: value})
    assert err.value.where == f"config.{key}" and "has no effect in the multi-agent env" in err.value.message
    assert text in err.value.message


def assert_info_matches(got: dict, keys: dict[str, type], where: str) -> None:
    assert set(got) == set(keys), (where, set(got) ^ set(keys))
    for key, kind in keys.items():
        assert isinstance(got[key], kind), (where, key, type(got[key]))


def test_info_has_exactly_the_table_keys_with_their_types():
    """A real reset's and step's info (single env), the native vector env's batched info (the
    same keys; values stacked as arrays, nested dicts as dicts of arrays) and the multi-agent
    env's infos (the MapEnv keys and its own)."""
    from feat2map.envs import multi_agent

    top = info.info_keys(config.MAP_ENV)
    feature = {k.key.split(".", 1)[1]: k.type for k in info.INFO_KEYS if k.key.startswith("junction_feature.")}
    env = make({"traffic_vehicles": 2})
    infos = [env.reset(seed=0)[1]] + [env.step(env.action_space.sample())[-1] for _ in range(3)]
    for got in infos:
        assert_info_matches(got, top, "single")
        assert_info_matches(got["junction_feature"], feature, "junction_feature")
        assert set(got["violations"]) == set(VIOLATIONS) and set(got["rewards"]) == set(env.unwrapped._reward_terms())
    env.close()

    venv = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, config={**SMALL, "traffic_vehicles": 2})
    venv.reset(seed=0)
    batched = venv.step(venv.action_space.sample())[-1]
    assert {k for k in batched if not k.startswith("_") and not k.startswith("final_")} == set(top)
    for key, kind in top.items():
        value = batched[key]
        if kind is dict:
            assert isinstance(value, dict), key
        else:
            assert isinstance(value, np.ndarray) and len(value) == 2, key
            assert value.dtype.kind == {float: "f", bool: "b", int: "i", str: "O", list: "O"}.get(kind, value.dtype.kind)
    venv.close()

    ma = multi_agent.parallel_env({**SMALL, "agents": 2, "traffic_vehicles": 1})
    _, infos_ = ma.reset(seed=0)
    for got in infos_.values():
        assert_info_matches(got, info.info_keys(), "multi-agent")
        assert set(got["violations"]) == set(multi_agent.AGENT_VIOLATIONS)
    ma.close()
