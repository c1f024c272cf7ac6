"""Strict configuration of the environments, as MetaDrive's: an unknown key is an error naming
the key and the closest valid one, and every value is checked (type, finite, range) before any
work, with a one-line `Feat2MapError` naming `config.<key>`. Nested observation/action dicts are
checked against the parameters of their highway-env type.
"""
from __future__ import annotations

import difflib
import inspect
import math
import numbers
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any, Callable

from highway_env.envs.common import action as he_action
from highway_env.envs.common import observation as he_obs

from ..errors import Feat2MapError
from .driver_view import DriverViewObservation

MAX_TRAFFIC_VEHICLES = 500  # a larger count is a typo, not a scene (raise it here if you mean it)
MAX_FREQUENCY_HZ = 1000.0
OBSERVATION_TYPES = {
    "Kinematics": he_obs.KinematicObservation, "OccupancyGrid": he_obs.OccupancyGridObservation,
    "TimeToCollision": he_obs.TimeToCollisionObservation, "LidarObservation": he_obs.LidarObservation,
    "GrayscaleObservation": he_obs.GrayscaleObservation, "KinematicsGoal": he_obs.KinematicsGoalObservation,
    "AttributesObservation": he_obs.AttributesObservation, "TupleObservation": he_obs.TupleObservation,
    "ExitObservation": he_obs.ExitObservation, "DriverView": DriverViewObservation,
}
ACTION_TYPES = {"ContinuousAction": he_action.ContinuousAction, "DiscreteAction": he_action.DiscreteAction,
                "DiscreteMetaAction": he_action.DiscreteMetaAction}

Check = Callable[[Any, str], None]


def fail(where: str, message: str) -> None:
    raise Feat2MapError(message, where)


def number(lo: float | None = None, hi: float | None = None, *, lo_open: bool = False,
           integer: bool = False) -> Check:
    """A finite real (an integer when `integer`) in [lo, hi] ((lo, hi] when `lo_open`)."""
    def check(value: Any, where: str) -> None:
        kind = "an integer" if integer else "a number"
        if isinstance(value, bool) or not isinstance(value, numbers.Integral if integer else numbers.Real):
            fail(where, f"must be {kind}, got {type(value).__name__} {value!r:.40}")
        if not math.isfinite(float(value)):
            fail(where, f"must be finite, got {value}")
        if lo is not None and (value <= lo if lo_open else value < lo):
            fail(where, f"must be {'>' if lo_open else '>='} {lo}, got {value}")
        if hi is not None and value > hi:
            fail(where, f"must be <= {hi}, got {value}")
    return check


def boolean(value: Any, where: str) -> None:
    if not isinstance(value, bool) and type(value).__name__ != "bool_":
        fail(where, f"must be true or false, got {type(value).__name__} {value!r:.40}")


def one_of(*choices: Any) -> Check:
    def check(value: Any, where: str) -> None:
        if value not in choices:
            close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            fail(where, f"must be one of {', '.join(map(repr, choices))}, got {value!r:.40}{hint}")
    return check


def optional(check: Check) -> Check:
    def inner(value: Any, where: str) -> None:
        if value is not None:
            check(value, where)
    return inner


def pair(lo: float | None = None) -> Check:
    """Two finite numbers."""
    def check(value: Any, where: str) -> None:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
            fail(where, f"must be a pair of numbers, got {value!r:.40}")
        for i, x in enumerate(value):
            number(lo)(x, f"{where}[{i}]")
    return check


def text(value: Any, where: str) -> None:
    if not isinstance(value, str):
        fail(where, f"must be a string, got {type(value).__name__}")


def path_like(value: Any, where: str) -> None:
    if not isinstance(value, (str, Path)) or not str(value):
        fail(where, f"must be a file path, got {value!r:.60}")


def mapping(value: Any, where: str) -> None:
    if not isinstance(value, Mapping):
        fail(where, f"must be a mapping, got {type(value).__name__}")


def offsets(value: Any, where: str) -> None:
    """{junction or signal id: seconds}."""
    mapping(value, where)
    for k, v in value.items():
        number()(v, f"{where}.{k}")


def route(value: Any, where: str) -> None:
    """None, a list of (junction, entry road, exit road), or a lane-route mapping (checked
    against the map at reset)."""
    if value is None or isinstance(value, Mapping):
        return
    if isinstance(value, (str, bytes)) or not isinstance(value, Sequence):
        fail(where, f"must be a list of (junction, entry road, exit road), a lane route mapping or null, got "
                    f"{type(value).__name__}")
    for i, item in enumerate(value):
        if isinstance(item, (str, bytes)) or not isinstance(item, Sequence) or len(item) != 3:
            fail(f"{where}[{i}]", f"must be (junction id, entry road id, exit road id), got {item!r:.60}")


def space_config(kind: str, types: Mapping[str, type]) -> Check:
    """An observation/action dict: a known highway-env `type` and only that type's parameters."""
    def check(value: Any, where: str) -> None:
        mapping(value, where)
        name = value.get("type")
        if name not in types:
            close = difflib.get_close_matches(str(name), list(types), n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            fail(f"{where}.type", f"unknown {kind} type {name!r:.40}{hint}; known: {', '.join(types)}")
        allowed = set(parameters(types[name])) | {"type"}
        for key in value:
            if key not in allowed:
                fail(f"{where}.{key}", unknown_key_message(key, allowed, f"{name} {kind}"))
    return check


def parameters(cls: type) -> list[str]:
    """Named parameters of a class's __init__ along its MRO (those passed on by **kwargs)."""
    names: dict[str, None] = {}
    for klass in cls.__mro__:
        init = klass.__dict__.get("__init__")
        if init is None:
            continue
        for p in list(inspect.signature(init).parameters.values())[1:]:
            if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "env":
                names[p.name] = None
    return list(names)


# highway-env keys of its own envs that these envs do not take, and what to use instead
HIGHWAY_ENV_KEYS = {"lanes_count": "the map sets the lanes", "vehicles_count": "use traffic_vehicles",
                    "vehicles_density": "use traffic_vehicles", "controlled_vehicles": "one ego vehicle",
                    "initial_lane_id": "use route", "ego_spacing": "use ego_start_distance",
                    "collision_reward": "use reward_collision", "high_speed_reward": "use reward_progress"}


def unknown_key_message(key: Any, valid, what: str = "config") -> str:
    names = sorted(map(str, valid))
    close = difflib.get_close_matches(str(key), names, n=1)
    if close:
        hint = f"; did you mean {close[0]!r}?"
    elif other := difflib.get_close_matches(str(key), list(HIGHWAY_ENV_KEYS), n=1):
        hint = f"; highway-env's {other[0]!r} is not a key here ({HIGHWAY_ENV_KEYS[other[0]]})"
    else:
        hint = f"; the keys are default_config()'s: {', '.join(names)}"
    return f"unknown {what} key {str(key)!r:.60}{hint}"


# ---- the schema of MapEnv and its subclasses -------------------------------------------------
REWARD = number()
SCHEMA: dict[str, Check] = {
    # highway-env's AbstractEnv
    "observation": space_config("observation", OBSERVATION_TYPES),
    "action": space_config("action", ACTION_TYPES),
    "simulation_frequency": number(0, MAX_FREQUENCY_HZ, lo_open=True),
    "policy_frequency": number(0, MAX_FREQUENCY_HZ, lo_open=True),
    "other_vehicles_type": text,
    "screen_width": number(1, 10_000, integer=True), "screen_height": number(1, 10_000, integer=True),
    "centering_position": pair(), "scaling": number(0, lo_open=True),
    "show_trajectories": boolean, "render_agent": boolean, "offscreen_rendering": optional(boolean),
    "manual_control": boolean, "real_time_rendering": boolean, "neighbour_vehicles_connected_lanes": boolean,
    # MapEnv
    "duration": number(0, lo_open=True),
    "route": route, "route_junctions": number(0, integer=True), "route_length": number(0, lo_open=True),
    "ego_start_distance": number(0), "ego_initial_speed": number(0, 40.0), "goal_distance": number(0),
    "traffic_vehicles": number(0, MAX_TRAFFIC_VEHICLES, integer=True), "traffic_respawn": boolean,
    "traffic_initial_speed": number(0, 40.0),
    "signal_green": number(0, lo_open=True), "signal_amber": number(0), "signal_all_red": number(0),
    "signal_phases": one_of("paired", "single"), "right_turn_on_red": boolean, "signal_offsets": offsets,
    "pedestrian_rate": number(0), "pedestrian_speed": number(0, 10.0, lo_open=True),
    "pedestrians_per_crosswalk": number(0, 100, integer=True),
    "observe_traffic_control": boolean, "offroad_terminal": boolean, "show_route": boolean,
    "reward_progress": REWARD, "reward_arrived": REWARD, "reward_collision": REWARD, "reward_red_light": REWARD,
    "reward_stop_sign": REWARD, "reward_pedestrian_yield": REWARD, "reward_off_road": REWARD,
    # JunctionGridEnv
    "feature_space": lambda v, w: None, "features": lambda v, w: None,  # checked by FeatureSpace/JunctionFeature
    "map_seed": number(0, 2**63 - 1, integer=True), "generation": optional(mapping), "new_map_each_reset": boolean,
    # MapFileEnv
    "map_file": optional(path_like), "map": lambda v, w: None,
}


def merge_config(base: dict, delta: Mapping | None) -> dict:
    """Merge `delta` into `base` (the defaults); observation/action dicts merge when their type
    is kept. A key `base` does not have is an error naming the closest valid key."""
    if delta is not None and not isinstance(delta, Mapping):
        fail("config", f"must be a mapping, got {type(delta).__name__}")
    for key, val in (delta or {}).items():
        if key not in base:
            fail(f"config.{key}", unknown_key_message(key, base))
        cur = base.get(key)
        if key in ("observation", "action") and isinstance(val, Mapping) and isinstance(cur, Mapping):
            base[key] = {**cur, **val} if val.get("type", cur.get("type")) == cur.get("type") else dict(val)
        else:
            base[key] = val
    return base


def validate_config(config: Mapping[str, Any]) -> None:
    """Check every value of a merged config against SCHEMA (keys without a check pass)."""
    for key, value in config.items():
        check = SCHEMA.get(key)
        if check is not None:
            check(value, f"config.{key}")
    sim, policy = config.get("simulation_frequency"), config.get("policy_frequency")
    if sim is not None and policy is not None and policy > sim:
        fail("config.policy_frequency", f"must be <= simulation_frequency ({sim}), got {policy}")
