"""Scenarios and suites: a map, an ego route of junction manoeuvres, traffic, pedestrians,
signal offsets, a seed and a duration; suites are YAML or JSON files validated against
`feat2map/schemas/scenario.schema.json` (format: scenarios/README.md).

Relative map paths in a suite file are resolved against the file's folder when it is loaded
(`Scenario.map` then holds an absolute path) and written relative to the target folder when a
suite is saved, so suite files and their maps move together.
"""
from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass, field, fields
from functools import lru_cache
from pathlib import Path
from typing import Any, Mapping, cast

import yaml

from ..atomic import write_text
from ..documents import check_schema, load_document
from ..errors import Feat2MapError, snippet
from ..routes import AnyRoute, Manoeuvre, Route, is_lane_route  # noqa: F401 (Manoeuvre re-exported)

SCHEMA_RESOURCE = ("feat2map", "schemas/scenario.schema.json")  # package data
SUITE_FORMAT_VERSION = 1
ENV_ID = "feat2map/MapFile-v0"
POLICY_FREQUENCY_HZ = 5  # planner decisions per simulated second in scenario envs


class ScenarioError(Feat2MapError):
    """An invalid scenario or suite file: `where` names the file and element."""


class FrozenDict(dict):
    """A read-only, hashable, picklable dict (frozen dataclasses' mapping fields)."""

    def _readonly(self, *args: Any, **kwargs: Any) -> None:
        raise TypeError("FrozenDict is read-only")

    __setitem__ = __delitem__ = clear = pop = popitem = setdefault = update = _readonly  # type: ignore[assignment]
    __ior__ = _readonly  # type: ignore[assignment]

    def __hash__(self) -> int:  # type: ignore[override]
        return hash(tuple(sorted(self.items())))

    def __reduce__(self):
        return (FrozenDict, (dict(self),))


@dataclass(frozen=True)
class Scenario:
    """One drive: the ego follows `route` (junction, entry road, exit road) on `map`."""

    name: str
    map: str  # map file path (native .json or OpenDRIVE .xodr)
    route: AnyRoute  # manoeuvres in driving order, or a lane-level route ({"lanes": [...]}: a direct-link ramp)
    traffic_vehicles: int = 0
    pedestrian_rate: float = 0.0  # per crosswalk per minute
    signal_offsets: Mapping[str, float] = field(default_factory=dict)  # signal/junction id -> seconds
    seed: int = 0
    duration: float = 60.0  # [s] truncation
    env: Mapping[str, Any] = field(default_factory=dict)  # more MapFile-v0 settings (the schema's `env` keys)

    def __post_init__(self) -> None:
        where = f"scenario {snippet(self.name)}"
        for name in ("traffic_vehicles", "seed"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(value, int):
                raise ScenarioError(f"must be an integer, got {snippet(value)}", f"{where}.{name}")
        values = {"pedestrian_rate": self.pedestrian_rate, "duration": self.duration,
                  **{f"signal_offsets.{k}": v for k, v in dict(self.signal_offsets).items()}}
        for name, value in values.items():
            if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
                raise ScenarioError(f"must be a finite number, got {snippet(value)}", f"{where}.{name}")
        object.__setattr__(self, "route", _normal_route(self.route))
        object.__setattr__(self, "signal_offsets",
                           FrozenDict({str(k): float(v) for k, v in dict(self.signal_offsets).items()}))
        object.__setattr__(self, "env", FrozenDict(dict(self.env)))

    def __hash__(self) -> int:
        return hash((self.name, self.map, self.route, self.traffic_vehicles, self.pedestrian_rate,
                     tuple(sorted(self.signal_offsets.items())), self.seed, self.duration,
                     tuple(sorted(self.env.items()))))

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Scenario) and self.to_dict() == other.to_dict()

    def to_dict(self) -> dict:
        """Plain JSON/YAML-ready dict (the file format of one scenario; `env` only when it holds settings)."""
        d = {"name": self.name, "map": self.map, "route": route_document(self.route),
             "traffic_vehicles": int(self.traffic_vehicles), "pedestrian_rate": float(self.pedestrian_rate),
             "signal_offsets": dict(self.signal_offsets), "seed": int(self.seed), "duration": float(self.duration)}
        if self.env:
            d["env"] = dict(self.env)
        return d

    @classmethod
    def from_dict(cls, d: Any, where: str = "scenario") -> "Scenario":
        """Validate one scenario dict against the schema and build it; errors name `where`."""
        check_schema(d, {**_schema()["$defs"]["scenario"], "$defs": _schema()["$defs"]}, where, ScenarioError)
        for key in ("map", "route"):
            if key not in d:
                raise ScenarioError(f"missing required field '{key}'", where)
        return cls(name=d["name"], map=str(d["map"]), route=d["route"],
                   traffic_vehicles=int(d.get("traffic_vehicles", 0)),
                   pedestrian_rate=float(d.get("pedestrian_rate", 0.0)),
                   signal_offsets=dict(d.get("signal_offsets", {})), seed=int(d.get("seed", 0)),
                   duration=float(d.get("duration", 60.0)), env=dict(d.get("env", {})))


def _normal_route(route: Any) -> AnyRoute:
    """A route as a scenario holds it (hashable, ids as strings): a tuple of manoeuvre tuples, or
    a read-only lane route whose lane list is a tuple."""
    if is_lane_route(route):
        return FrozenDict({str(k): tuple(str(x) for x in v) if k == "lanes" else str(v) for k, v in route.items()})
    return cast(Route, tuple(tuple(str(x) for x in item) for item in route))


def route_document(route: AnyRoute) -> Any:
    """A route as suite files and the env's config take it: lists of manoeuvres, or a lane
    route's dict (lanes as a list)."""
    if is_lane_route(route):
        return {k: list(v) if k == "lanes" else v for k, v in route.items()}
    return [list(r) for r in route]


@dataclass(frozen=True)
class Suite:
    """A named list of scenarios; `base_dir` is the folder relative map paths refer to."""

    name: str
    scenarios: tuple[Scenario, ...]
    base_dir: Path | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "scenarios", tuple(self.scenarios))

    def to_dict(self, relative_to: Path | None = None) -> dict:
        """The suite file's content; map paths relative to `relative_to` when given."""
        out = []
        for sc in self.scenarios:
            d = sc.to_dict()
            path = self.map_path(sc)
            if relative_to is not None:
                d["map"] = Path(os.path.relpath(path, relative_to)).as_posix()
            out.append(d)
        return {"version": SUITE_FORMAT_VERSION, "name": self.name, "scenarios": out}

    def map_path(self, scenario: Scenario) -> Path:
        """Absolute path of a scenario's map (relative paths resolve against `base_dir`)."""
        p = Path(scenario.map)
        return p if p.is_absolute() else (self.base_dir or Path.cwd()) / p


@lru_cache(maxsize=1)
def _schema() -> dict:
    from importlib.resources import files

    pkg, name = SCHEMA_RESOURCE
    return json.loads(files(pkg).joinpath(name).read_text(encoding="utf-8"))


def suite_from_dict(data: Any, where: str = "suite", base_dir: Path | None = None) -> Suite:
    """Validate a whole suite document (schema + defaults + unique names) and build it."""
    if not isinstance(data, dict):  # the document is not quoted: it may be any file
        raise ScenarioError(f"a suite must be a mapping with 'name' and 'scenarios', got a {type(data).__name__}",
                            where)
    check_schema(data, _schema(), where, ScenarioError)
    defaults = dict(data.get("defaults", {}))
    scenarios, names = [], set()
    for i, raw in enumerate(data["scenarios"]):
        elem = f"{where}: scenarios[{i}]"
        sc = Scenario.from_dict({**defaults, **raw}, elem)
        if sc.name in names:
            raise ScenarioError(f"duplicate scenario name {sc.name!r}", f"{elem}.name")
        names.add(sc.name)
        if base_dir is not None and not Path(sc.map).is_absolute():
            sc = _replace_map(sc, str((base_dir / sc.map).resolve()))
        scenarios.append(sc)
    return Suite(str(data["name"]), tuple(scenarios), base_dir)


def _replace_map(sc: Scenario, path: str) -> Scenario:
    values = {f.name: getattr(sc, f.name) for f in fields(sc)}
    values["map"] = path
    return Scenario(**values)


def load_suite(path: str | Path, check_maps: bool = True) -> Suite:
    """Read a suite file (YAML or JSON), validate it against the schema and resolve map paths
    against its folder; with `check_maps`, every referenced map file must exist."""
    path = Path(path)
    data = load_document(path, ScenarioError)
    suite = suite_from_dict(data, str(path), path.resolve().parent)
    if check_maps:
        for i, sc in enumerate(suite.scenarios):
            if not Path(sc.map).is_file():
                raise ScenarioError(f"map file not found: {sc.map}", f"{path}: scenarios[{i}].map")
    return suite


SUITE_SUFFIXES = (".yaml", ".yml", ".json")


def check_suite_path(path: str | Path, what: str = "--out") -> Path:
    """`path` when a suite can be written there: YAML (.yaml/.yml) or JSON (.json), by its suffix
    (a .txt would hold YAML its name does not announce)."""
    path = Path(path)
    if path.suffix.lower() not in SUITE_SUFFIXES:
        raise ScenarioError(f"a suite is written as YAML (.yaml, .yml) or JSON (.json), by the suffix; "
                            f"got {path.suffix or 'no suffix'!r}", f"{what} {path}")
    return path


def save_suite(suite: Suite, path: str | Path) -> None:
    """Write `suite` atomically as YAML (or JSON for a .json path), map paths relative to it."""
    path = Path(path)
    check_suite_path(path)
    data = suite.to_dict(relative_to=path.resolve().parent)
    check_schema(data, _schema(), str(path), ScenarioError)
    if path.suffix.lower() == ".json":
        text = json.dumps(data, indent=2) + "\n"
    else:
        text = yaml.safe_dump(data, sort_keys=False, default_flow_style=None, width=120)
    write_text(path, text)


def env_config(scenario: Scenario, config: Mapping | None = None) -> dict:
    """MapFile-v0 config of a scenario: its map, route, traffic, pedestrians, signal offsets and
    duration, with the baseline planner's action config (override anything with `config`)."""
    from .planner import BaselinePlanner

    cfg: dict[str, Any] = {
        "route": route_document(scenario.route),
        "traffic_vehicles": int(scenario.traffic_vehicles),
        "pedestrian_rate": float(scenario.pedestrian_rate),
        "signal_offsets": dict(scenario.signal_offsets),
        "duration": float(scenario.duration),
        "action": dict(BaselinePlanner.action_config),
        "policy_frequency": POLICY_FREQUENCY_HZ,
        "right_turn_on_red": True,  # the planner's TRAFFIC_LIGHT_UNPROTECTED_RIGHT_TURN scenario
        **dict(scenario.env),
    }
    path = Path(scenario.map)
    if path.suffix == ".json":
        cfg["map_file"] = str(path)
    else:
        cfg["map"] = _read_map_cached(str(path.resolve()), path.stat().st_mtime_ns if path.is_file() else 0)
    cfg.update(dict(config or {}))
    return cfg


@lru_cache(maxsize=8)
def _read_map_cached(path: str, mtime: int):
    from ..formats import read_map

    return read_map(path)


def make_env(scenario: Scenario, *, render_mode: str | None = None, config: dict | None = None):
    """A `feat2map/MapFile-v0` env set up for `scenario`; reset it with `seed=scenario.seed`.
    Bad routes raise Feat2MapError naming the scenario and route element at reset."""
    import gymnasium as gym

    import feat2map  # noqa: F401  (registers the env ids)

    if not math.isfinite(scenario.duration) or scenario.duration <= 0:
        raise ScenarioError(f"duration must be positive, got {scenario.duration}", f"{scenario.name}.duration")
    return gym.make(ENV_ID, render_mode=render_mode, config=env_config(scenario, config))
