"""Strict configuration of the environments, as MetaDrive's: an unknown key is an error naming
the key and the closest valid one, and every value is checked (type, finite, range) before any
work, with a one-line `Feat2MapError` naming `config.<key>`. Nested observation/action dicts are
checked against the parameters of their highway-env type.
"""
from __future__ import annotations

import copy
import difflib
import inspect
import math
import numbers
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable

from highway_env.envs.common import action as he_action
from highway_env.envs.common import observation as he_obs

from ..config import AGENT_ACCELERATION_RANGE, AGENT_TARGET_SPEEDS, DRIVE_DEFAULTS
from ..errors import Feat2MapError
from ..features import PAPER_SF_FEATURE_SPACE
from .driver_view import DriverViewObservation
from .sim.vehicle import VehicleModel

MAX_TRAFFIC_VEHICLES = 500  # a larger count is a typo, not a scene (raise it here if you mean it)
MAX_FREQUENCY_HZ = 1000.0
MAX_AGENTS = 500  # multi-agent env
MAX_WORLDS = 1024  # multi-agent env: worlds in one simulation
AGENT_ACTION_KEYS = {"TargetSpeed": {"target_speeds", "acceleration_range"},
                     "DiscreteMetaAction": {"target_speeds", "longitudinal", "lateral"},
                     "ContinuousAction": {"acceleration_range", "longitudinal", "lateral"}}
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


def described(check: Check, text: str) -> Check:
    """`check` with what it accepts in words (the README's config table shows it)."""
    check.accepts = text  # type: ignore[attr-defined]
    return check


def accepts(check: Check) -> str:
    return str(getattr(check, "accepts", ""))


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
    kind = "integer" if integer else "number"
    if lo is not None and hi is not None:
        text = f"{kind} in {'(' if lo_open else '['}{lo}, {hi}]"
    elif lo is not None:
        text = f"{kind} {'>' if lo_open else '>='} {lo}"
    else:
        text = f"{kind} <= {hi}" if hi is not None else kind
    return described(check, text)


def boolean(value: Any, where: str) -> None:
    if not isinstance(value, bool) and type(value).__name__ != "bool_":
        fail(where, f"must be true or false, got {type(value).__name__} {value!r:.40}")


described(boolean, "bool")


def one_of(*choices: Any) -> Check:
    def check(value: Any, where: str) -> None:
        if value not in choices:
            close = difflib.get_close_matches(str(value), [str(c) for c in choices], n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            fail(where, f"must be one of {', '.join(map(repr, choices))}, got {value!r:.40}{hint}")
    return described(check, f"one of {', '.join(map(repr, choices))}")


def optional(check: Check) -> Check:
    def inner(value: Any, where: str) -> None:
        if value is not None:
            check(value, where)
    return described(inner, f"{accepts(check)} or None")


def pair(lo: float | None = None) -> Check:
    """Two finite numbers."""
    def check(value: Any, where: str) -> None:
        if isinstance(value, (str, bytes)) or not isinstance(value, Sequence) or len(value) != 2:
            fail(where, f"must be a pair of numbers, got {value!r:.40}")
        for i, x in enumerate(value):
            number(lo)(x, f"{where}[{i}]")
    return described(check, "pair of numbers")


def text(value: Any, where: str) -> None:
    if not isinstance(value, str):
        fail(where, f"must be a string, got {type(value).__name__}")


described(text, "string")


def path_like(value: Any, where: str) -> None:
    if not isinstance(value, (str, Path)) or not str(value):
        fail(where, f"must be a file path, got {value!r:.60}")


described(path_like, "file path")


def mapping(value: Any, where: str) -> None:
    if not isinstance(value, Mapping):
        fail(where, f"must be a mapping, got {type(value).__name__}")


described(mapping, "mapping")


def offsets(value: Any, where: str) -> None:
    """{junction or signal id: seconds}."""
    mapping(value, where)
    for k, v in value.items():
        number()(v, f"{where}.{k}")


described(offsets, "{id: seconds}")


def vehicle_body(value: Any, where: str) -> None:
    """The body and steering of the ego (and the agents): keys of DRIVE_DEFAULTS["vehicle"], positive lengths, a
    steering limit under 90 degrees, the wheelbase and front overhang inside the length."""
    mapping(value, where)
    for key, v in value.items():
        if key not in DRIVE_DEFAULTS["vehicle"]:
            fail(f"{where}.{key}", unknown_key_message(key, DRIVE_DEFAULTS["vehicle"], "vehicle"))
        number(0, math.pi / 2 if key == "max_steering" else 100.0, lo_open=key != "front_overhang")(v, f"{where}.{key}")
    VehicleModel.of(value, where)


described(vehicle_body, "{length, width, wheelbase, front_overhang [m], max_steering [rad]}")


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


described(route, "route list, lane route mapping or None")


def fixed(reason: str) -> Check:
    """A key highway-env reads that has no effect here: only its default is taken."""
    def check(value: Any, where: str) -> None:
        if value is not False:
            fail(where, f"has no effect here ({reason}), got {value!r:.40}")
    return described(check, "False (no effect)")


def unchecked(by: str) -> Check:
    """A value checked where it is used (`by`), not here."""
    return described(lambda value, where: None, f"checked by {by}")


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
    return described(check, f"{kind} dict of a known type")


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
                    "collision_reward": "use reward_collision", "high_speed_reward": "use reward_progress",
                    "other_vehicles_type": "traffic is the env's own IDM/MOBIL vehicles"}


def unknown_key_message(key: Any, valid, what: str = "config") -> str:
    names = sorted(map(str, valid))
    close = difflib.get_close_matches(str(key), names, n=1)
    if what == "config" and str(key) in HIGHWAY_ENV_KEYS:  # highway-env's own name: say what to use here
        hint = f"; highway-env's {str(key)!r} is not a key here ({HIGHWAY_ENV_KEYS[str(key)]})"
    elif close:
        hint = f"; did you mean {close[0]!r}?"
    elif other := difflib.get_close_matches(str(key), list(HIGHWAY_ENV_KEYS), n=1):
        hint = f"; highway-env's {other[0]!r} is not a key here ({HIGHWAY_ENV_KEYS[other[0]]})"
    else:
        hint = f"; the keys are default_config()'s: {', '.join(names)}"
    return f"unknown {what} key {str(key)!r:.60}{hint}"


# ---- the settings: one table of every key, its default, its check and its doc ------------------
MAP_ENV, GRID, FILE, MULTI = "MapEnv", "JunctionGrid-v0", "MapFile-v0", "multi-agent"
SAME: Any = object()  # `Setting.multi_agent`: the multi-agent env keeps the MapEnv default


@dataclass(frozen=True)
class NotTaken:
    """`Setting.multi_agent`: the multi-agent env refuses this MapEnv key (nothing there reads it)."""
    reason: str


@dataclass(frozen=True)
class Setting:
    """One config key: `default_config()`, the checks and the README's config table are made
    from the rows of `SETTINGS` (tests/envs/test_config.py keeps the README equal)."""
    key: str
    default: Any
    check: Check
    doc: str
    env: str = MAP_ENV  # MapEnv (every env), JunctionGrid-v0, MapFile-v0 or multi-agent (its own keys)
    highway_env: bool = False  # a key of highway-env's AbstractEnv (which reads it too)
    multi_agent: Any = SAME  # the multi-agent env's default for this MapEnv key where it differs, or NotTaken
    shown: str = ""  # the default as the README shows it, where its value is too long


def agent_routes(value: Any, where: str) -> None:
    if not (value is None or value == "coverage"):
        if isinstance(value, (str, bytes, Mapping)) or not isinstance(value, Sequence) or not value:
            fail(where, f"must be null, 'coverage' or a non-empty list of routes, got {value!r:.60}")


described(agent_routes, "None, 'coverage' or a list of routes")


def agent_action(act: Any, where: str) -> None:
    """The multi-agent action dict: a type of AGENT_ACTION_KEYS and only its keys."""
    if not isinstance(act, Mapping):
        fail(where, f"must be a mapping, got {type(act).__name__}")
    one_of(*AGENT_ACTION_KEYS)(act.get("type"), f"{where}.type")
    for key in act:
        if key != "type" and key not in AGENT_ACTION_KEYS[act["type"]]:
            fail(f"{where}.{key}", unknown_key_message(key, AGENT_ACTION_KEYS[act["type"]], f"{act['type']} action"))
    if act.get("lateral"):
        fail(f"{where}.lateral", "agents steer along their routes: lateral actions are not supported")
    if "acceleration_range" in act:
        pair()(act["acceleration_range"], f"{where}.acceleration_range")
        lo, hi = act["acceleration_range"]
        if not lo < hi:
            fail(f"{where}.acceleration_range",
                 f"must be (low, high) with low < high, got {list(act['acceleration_range'])}")
    if "target_speeds" in act:
        speeds = act["target_speeds"]
        if isinstance(speeds, (str, bytes)) or not isinstance(speeds, Sequence) or not speeds:
            fail(f"{where}.target_speeds", "must be a non-empty list of speeds")
        for i, v in enumerate(speeds):
            number(0, 40.0)(v, f"{where}.target_speeds[{i}]")


described(agent_action, "action dict of a known type")

REWARD = number()
SPEED = number(0, 40.0)
_drive = DRIVE_DEFAULTS.__getitem__
SETTINGS: tuple[Setting, ...] = (
    # highway-env's AbstractEnv (its `other_vehicles_type` is not taken: traffic is the env's own)
    Setting("observation", {
        "type": "Kinematics", "vehicles_count": 10, "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"],
        "features_range": {"x": [-100, 100], "y": [-100, 100], "vx": [-20, 20], "vy": [-20, 20]},
        "absolute": False, "see_behind": True},
        space_config("observation", OBSERVATION_TYPES), "observation type and its parameters (highway-env's "
        "types and DriverView); a dict of the same type merges into the default", highway_env=True,
        shown="Kinematics, 10 vehicles"),
    Setting("action", {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False,
                       "target_speeds": [0.0, 4.5, 9.0]},
            space_config("action", ACTION_TYPES), "action type and its parameters (highway-env's types); "
            "steering follows the route without lateral actions", highway_env=True,
            shown="DiscreteMetaAction, longitudinal, targets 0/4.5/9 m/s"),
    Setting("simulation_frequency", 15, number(0, MAX_FREQUENCY_HZ, lo_open=True),
            "[Hz] simulation frames per second", highway_env=True, multi_agent=10),
    Setting("policy_frequency", 1, number(0, MAX_FREQUENCY_HZ, lo_open=True),
            "[Hz] decisions per second (at most simulation_frequency)", highway_env=True, multi_agent=2),
    Setting("screen_width", 600, number(1, 10_000, integer=True), "[px] rendered image width", highway_env=True),
    Setting("screen_height", 600, number(1, 10_000, integer=True), "[px] rendered image height", highway_env=True),
    Setting("centering_position", [0.5, 0.5], pair(), "where the ego is drawn, as fractions of the image",
            highway_env=True),
    Setting("scaling", 5.5, number(0, lo_open=True), "[px/m] rendering scale", highway_env=True),
    Setting("show_trajectories", False, boolean, "record and draw vehicles' past positions", highway_env=True),
    Setting("render_agent", True, boolean, "on screen, draw the agent's view beside the scene", highway_env=True),
    Setting("offscreen_rendering", None, optional(boolean), "render without a window (None: unless "
            "render_mode is human)", highway_env=True),
    Setting("manual_control", False, boolean, "drive the ego from the keyboard (render_mode human)",
            highway_env=True, multi_agent=NotTaken("there is no ego: every agent takes its action")),
    Setting("real_time_rendering", False, boolean, "on screen, pace frames at simulation_frequency",
            highway_env=True),
    Setting("neighbour_vehicles_connected_lanes", False, fixed("the neighbour search always follows connected "
            "lanes"), "read by highway-env's reset; has no effect here", highway_env=True),
    # MapEnv
    Setting("duration", 60.0, number(0, lo_open=True), "[s] episode length (truncation)"),
    Setting("route", None, route, "[(junction, entry road, exit road), ...], {\"lanes\": [...]}, "
            "{\"from_lane\": a, \"to_lane\": b}, or None to sample",
            multi_agent=NotTaken("agents take their routes from agent_routes")),
    Setting("route_junctions", 2, number(0, integer=True), "junctions on a sampled route (0: a lane walk of "
            "route_length)", multi_agent=1),
    Setting("route_length", 200.0, number(0, lo_open=True), "[m] driven on a sampled lane walk (maps without "
            "junctions)"),
    Setting("ego_start_distance", _drive("ego_start_distance"), number(0),
            "[m] before the end of the route's first lane (the first stop line)"),
    Setting("ego_initial_speed", _drive("ego_initial_speed"), SPEED, "[m/s] the ego's speed at reset (less "
            "where it cannot stop before the first line)"),
    Setting("goal_distance", _drive("goal_distance"), number(0), "[m] into the last lane of the route: "
            "completion"),
    Setting("vehicle", dict(_drive("vehicle")), vehicle_body, "the body and steering limit of the ego (of each "
            "agent in the multi-agent env): a kinematic bicycle about the rear axle; a dict merges into the default",
            shown="4.8 x 1.9 m, 2.9 m wheelbase, 0.95 m front overhang, 35 deg"),
    Setting("traffic_vehicles", 8, number(0, MAX_TRAFFIC_VEHICLES, integer=True), "traffic vehicles, on the "
            "ego route and the roads crossing it"),
    Setting("traffic_respawn", True, boolean, "traffic that finished its route or crashed is replaced"),
    Setting("traffic_initial_speed", _drive("traffic_initial_speed"), SPEED, "[m/s] traffic speed at spawn"),
    Setting("signal_green", _drive("signal_green"), number(0, lo_open=True), "[s] green time of a phase"),
    Setting("signal_amber", _drive("signal_amber"), number(0), "[s] amber time"),
    Setting("signal_all_red", _drive("signal_all_red"), number(0), "[s] all-red time between phases"),
    Setting("signal_phases", _drive("signal_phases"), one_of("paired", "single"),
            "\"paired\": opposite approaches together; \"single\": one approach at a time"),
    Setting("right_turn_on_red", False, boolean, "a right turn past a red signal after a full stop is legal"),
    Setting("signal_offsets", {}, offsets, "{junction or signal id: phase plan offset [s]}; others drawn from "
            "np_random"),
    Setting("pedestrian_rate", 3.0, number(0), "pedestrians per crosswalk per minute (crosswalks of route "
            "junctions and mid-block ones the route crosses)"),
    Setting("pedestrian_speed", _drive("pedestrian_speed"), number(0, 10.0, lo_open=True), "[m/s] walking speed"),
    Setting("pedestrians_per_crosswalk", _drive("pedestrians_per_crosswalk"), number(0, 100, integer=True),
            "at most this many on a crosswalk at once"),
    Setting("observe_traffic_control", False, boolean, "the observation becomes {\"observation\", "
            "\"traffic_control\"}: the 6-vector of the next stop line"),
    Setting("reward_progress", 1.0, REWARD, "weight of the fraction of the route driven this step"),
    Setting("reward_arrived", 1.0, REWARD, "weight of route completion"),
    Setting("reward_collision", -5.0, REWARD, "weight of a collision"),
    Setting("reward_red_light", -2.0, REWARD, "weight of a red_light violation"),
    Setting("reward_stop_sign", -1.0, REWARD, "weight of a stop_sign violation"),
    Setting("reward_pedestrian_yield", -2.0, REWARD, "weight of a pedestrian_yield violation"),
    Setting("reward_off_road", -1.0, REWARD, "weight of leaving the road"),
    Setting("offroad_terminal", True, boolean, "leaving the road ends the episode",
            multi_agent=NotTaken("agents steer along their routes; a crash or the goal ends an agent")),
    Setting("show_route", True, boolean, "draw the ego's route"),
    # JunctionGridEnv
    Setting("feature_space", PAPER_SF_FEATURE_SPACE.to_dict(), unchecked("FeatureSpace"),
            "FeatureSpace or its dict: the junctions generated", GRID, shown="the paper's SF space"),
    Setting("features", None, unchecked("JunctionFeature"), "explicit list of JunctionFeature (or dicts), one "
            "junction each: overrides feature_space", GRID),
    Setting("map_seed", 0, number(0, 2**63 - 1, integer=True), "seed of the generated map", GRID),
    Setting("generation", {}, optional(mapping), "GenerationConfig fields, e.g. {\"samples_per_combination\": 2}",
            GRID),
    Setting("new_map_each_reset", False, boolean, "draw a fresh map seed from np_random at every reset", GRID),
    # MapFileEnv
    Setting("map_file", None, optional(path_like), "a map file feat2map reads (native JSON, OpenDRIVE, Apollo)",
            FILE),
    Setting("map", None, unchecked("MapFileEnv"), "an HDMap object (instead of map_file)", FILE),
    # the multi-agent env's own keys (the rest is MapEnv's, with the multi-agent defaults above)
    Setting("agents", 8, number(1, MAX_AGENTS, integer=True), "agents per world (possible agents: "
            "agent_0..agent_{agents x worlds - 1})", MULTI),
    Setting("worlds", 1, number(1, MAX_WORLDS, integer=True), "worlds of the map in one simulation (for "
            "training): world w holds agent_{w*agents}..agent_{w*agents+agents-1}, resets with seed + w", MULTI),
    Setting("agent_routes", None, agent_routes, "None: sampled; \"coverage\": the map's route-coverage routes; "
            "or a list of routes", MULTI),
    Setting("agent_spacing", 12.0, number(0, lo_open=True), "[m] between agents queued on one approach at their "
            "start", MULTI),
    Setting("agent_queue", 3, number(1, 100, integer=True), "places on an approach (the first at "
            "ego_start_distance before the stop line)", MULTI),
    Setting("reward_not_yielding", -1.0, REWARD, "weight of a not_yielding violation", MULTI),
    Setting("reward_stop_order", -1.0, REWARD, "weight of a stop_order violation", MULTI),
    Setting("action", {"type": "TargetSpeed", "target_speeds": list(AGENT_TARGET_SPEEDS),
                       "acceleration_range": list(AGENT_ACCELERATION_RANGE)}, agent_action,
            "the agents' action: TargetSpeed, DiscreteMetaAction or ContinuousAction (longitudinal only)", MULTI,
            shown="TargetSpeed, 0-10 m/s, -6..3 m/s2"),
)


def settings(*envs: str) -> tuple[Setting, ...]:
    """The rows of the given env families (every one without arguments)."""
    return tuple(s for s in SETTINGS if not envs or s.env in envs)


def defaults(*envs: str) -> dict[str, Any]:
    """A fresh dict of the defaults of `envs`' own keys (copies: callers may change them)."""
    return {s.key: copy.deepcopy(s.default) for s in settings(*envs)}


def multi_agent_defaults() -> dict[str, Any]:
    """The MapEnv defaults the multi-agent env changes (decisions at 2 Hz, one junction per route)."""
    return {s.key: s.multi_agent for s in SETTINGS if s.multi_agent is not SAME and not isinstance(s.multi_agent, NotTaken)}


def multi_agent_not_taken() -> dict[str, str]:
    """{MapEnv key the multi-agent env refuses: why}."""
    return {s.key: s.multi_agent.reason for s in SETTINGS if isinstance(s.multi_agent, NotTaken)}


def checks(*envs: str) -> dict[str, Check]:
    return {s.key: s.check for s in settings(*envs)}


SCHEMA: dict[str, Check] = checks(MAP_ENV, GRID, FILE)  # every single-env key and its check


def markdown_table() -> str:
    """The config table of envs/README.md, made from SETTINGS."""
    def cell(text: str) -> str:
        return text.replace("|", "\\|")

    rows = ["| key | env | default | accepts | what |", "|---|---|---|---|---|"]
    for s in SETTINGS:
        default = s.shown or repr(s.default)
        marl = ("" if s.multi_agent is SAME else " (multi-agent: not taken)" if isinstance(s.multi_agent, NotTaken)
                else f" (multi-agent: `{s.multi_agent!r}`)")
        env = s.env + (" (highway-env's)" if s.highway_env else "")
        rows.append(f"| `{s.key}` | {env} | {cell(default if s.shown else f'`{default}`')}{marl} | "
                    f"{cell(accepts(s.check))} | {cell(s.doc)} |")
    return "\n".join(rows) + "\n"


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
        elif key == "vehicle" and isinstance(val, Mapping) and isinstance(cur, Mapping):
            base[key] = {**cur, **val}
        else:
            base[key] = val
    return base


def checked_copy(config: Mapping[str, Any]) -> dict[str, Any]:
    """What `validate_config` compares a later config with: the values, dicts as deep copies
    (user code may change a nested value in place)."""
    return {k: copy.deepcopy(v) if isinstance(v, dict) else v for k, v in config.items()}


def _unchanged(before: Any, value: Any) -> bool:
    """Whether `value` is what was checked: the same object, or an equal dict."""
    if before is value:
        return True
    if not isinstance(value, dict):
        return False
    try:
        return bool(before == value)
    except (TypeError, ValueError):  # (arrays inside)
        return False


def validate_config(config: Mapping[str, Any], before: Mapping[str, Any] | None = None) -> None:
    """Check every value of a merged config against SCHEMA (the SETTINGS of the single envs);
    with `before` (`checked_copy` of the config as last checked), only the values that changed
    since (a training script's draws change a key or two per episode; the action's and the
    observation's checks are the costly ones)."""
    for key, value in config.items():
        check = SCHEMA.get(key)
        if check is not None and (before is None or key not in before or not _unchanged(before[key], value)):
            check(value, f"config.{key}")
    sim, policy = config.get("simulation_frequency"), config.get("policy_frequency")
    if sim is not None and policy is not None and policy > sim:
        fail("config.policy_frequency", f"must be <= simulation_frequency ({sim}), got {policy}")
