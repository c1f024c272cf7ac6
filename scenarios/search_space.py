"""The space `feat2map search` explores, joining the scenario model's layers: the junction (layers
1-3: legs, their angles within the feature space's ranges, control, crosswalk, lanes per
direction, a one-way leg; generated on the fly), traffic and people (layer 4: how many vehicles,
their speed at spawn, pedestrians' rate and walking speed, the signal plan's green, amber and
all-red times, its phases and offset) and the ego (its manoeuvre, start distance and speed, and
the env seed, which places and times every spawn).

Each candidate is drawn through an Optuna trial (define-by-run: a parameter exists only where it
applies, e.g. the signal plan only at a signal, the angles of the drawn leg count only), so the
parameters that found a failure are the trial's `params`. A start is a feature space (a junction
generated per candidate), or a fixed map (a spec, built once, or a real map file): then the
candidate picks one of the map's route-coverage routes instead of a junction.

Every range is legal driving within the env's checks (SEARCH_* in feat2map/config.py).
"""
from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Sequence

from feat2map.config import (SEARCH_EGO_SPEED_MPS, SEARCH_EGO_START_M, SEARCH_ENV_SEED_MAX, SEARCH_LANES_MAX,
                             SEARCH_PEDESTRIAN_RATE_MAX, SEARCH_PEDESTRIAN_SPEED_MPS, SEARCH_SIGNAL_ALL_RED_S,
                             SEARCH_SIGNAL_AMBER_S, SEARCH_SIGNAL_GREEN_S, SEARCH_TRAFFIC_MAX,
                             SEARCH_TRAFFIC_SPEED_MPS)
from feat2map.errors import Feat2MapError
from feat2map.features import FeatureSpace, JunctionFeature
from feat2map.model import HDMap
from feat2map.routes import Manoeuvre

from .scenario import Scenario

TURNS = ("left", "straight", "right")  # the ego's manoeuvre at a generated junction (lane turn "none": straight)
ONE_WAY_DIRECTIONS = ("in", "out")


class Infeasible(Exception):
    """A candidate whose junction cannot be built (legs closer than the generator allows, no
    manoeuvre of the drawn kind): the search tells the optimiser and draws another."""


@dataclass(frozen=True)
class Start:
    """Where a search starts: a feature space whose junctions are generated per candidate, or a
    fixed map (`map_path`, read once into `hdmap`) whose route-coverage `routes` are searched."""

    label: str
    space: FeatureSpace | None = None
    map_path: Path | None = None
    hdmap: HDMap | None = None
    routes: tuple[tuple[Manoeuvre, ...], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"label": self.label, "feature_space": self.space.to_dict() if self.space else None,
                "map": str(self.map_path) if self.map_path else None, "routes": len(self.routes)}


def start_from(*, features: str | Path | None = None, spec: str | Path | None = None,
               map_file: str | Path | None = None, workdir: Path) -> Start:
    """The start of a search from at most one of a feature-space JSON, a spec or a map file (the
    paper's San Francisco feature space without any); a spec's map is built and written into
    `workdir`. Errors name the option."""
    from feat2map.features import PAPER_SF_FEATURE_SPACE

    given = [(k, v) for k, v in (("--features", features), ("--spec", spec), ("--map", map_file)) if v is not None]
    if len(given) > 1:
        raise Feat2MapError(f"give one starting point, not {' and '.join(k for k, _ in given)}", "command line")
    if features is not None:
        return Start(f"feature space {Path(features).name}", space=FeatureSpace.load(features))
    if spec is not None:
        from feat2map.formats import write_map
        from feat2map.spec import build_spec, load_spec

        m = build_spec(load_spec(spec))
        path = workdir / "spec_map.json"
        write_map(m, path, "native")
        return _fixed(f"spec {Path(spec).name}", path, m)
    if map_file is not None:
        from feat2map.formats import read_map

        path = Path(map_file)
        if not path.is_file():
            raise Feat2MapError("map file not found", f"--map {path}")
        return _fixed(f"map {path.name}", path.resolve(), read_map(path))
    return Start("the paper's San Francisco feature space", space=PAPER_SF_FEATURE_SPACE)


def _fixed(label: str, path: Path, m: HDMap) -> Start:
    from feat2map.routes import coverage_routes

    routes = tuple(tuple(r) for r in coverage_routes(m))
    if not routes:
        raise Feat2MapError("the map has no route through a junction to search", label)
    return Start(label, map_path=path, hdmap=m, routes=routes)


class MapCache:
    """Generated junction maps, one native JSON file each under `folder`, named by a digest of
    the feature (a candidate that draws the same junction again reuses its file)."""

    def __init__(self, folder: Path) -> None:
        self.folder = folder
        self.maps: dict[str, tuple[Path, HDMap]] = {}

    def get(self, feature: JunctionFeature) -> tuple[Path, HDMap]:
        from feat2map.formats import write_map
        from feat2map.generate import generate_from_features

        key = hashlib.sha256(json.dumps(feature.to_dict(), sort_keys=True).encode()).hexdigest()[:16]
        if key not in self.maps:
            try:
                m = generate_from_features([feature], seed=0)
            except Feat2MapError as exc:
                raise Infeasible(f"junction not buildable: {exc}") from None
            path = self.folder / f"junction-{key}.json"
            self.folder.mkdir(parents=True, exist_ok=True)
            write_map(m, path, "native")
            self.maps[key] = (path, m)
        return self.maps[key]


def suggest(trial: Any, start: Start, maps: MapCache, name: str) -> Scenario:
    """Draw one candidate through an Optuna trial and build its scenario (raises Infeasible)."""
    if start.space is not None:
        feature = _suggest_junction(trial, start.space)
        path, m = maps.get(feature)
        route: tuple[Manoeuvre, ...] = (_suggest_manoeuvre(trial, m),)
        signal, crosswalk = feature.control == "signal", feature.crosswalk
    else:
        assert start.map_path is not None and start.hdmap is not None
        path, m = start.map_path, start.hdmap
        route = start.routes[trial.suggest_categorical("route", list(range(len(start.routes))))]
        signal = any(s.junction_id in {mv[0] for mv in route} for s in m.signals.values())
        crosswalk = bool(m.crosswalks)
    env: dict[str, Any] = {
        "traffic_initial_speed": trial.suggest_float("traffic_speed", *SEARCH_TRAFFIC_SPEED_MPS),
        "ego_initial_speed": trial.suggest_float("ego_speed", *SEARCH_EGO_SPEED_MPS),
        "ego_start_distance": trial.suggest_float("ego_start", *SEARCH_EGO_START_M),
    }
    traffic = trial.suggest_int("traffic", 0, SEARCH_TRAFFIC_MAX)
    rate = 0.0
    if crosswalk:
        rate = trial.suggest_float("pedestrian_rate", 0.0, SEARCH_PEDESTRIAN_RATE_MAX)
        env["pedestrian_speed"] = trial.suggest_float("pedestrian_speed", *SEARCH_PEDESTRIAN_SPEED_MPS)
    offsets: dict[str, float] = {}
    if signal:
        env["signal_green"] = trial.suggest_float("signal_green", *SEARCH_SIGNAL_GREEN_S)
        env["signal_amber"] = trial.suggest_float("signal_amber", *SEARCH_SIGNAL_AMBER_S)
        env["signal_all_red"] = trial.suggest_float("signal_all_red", *SEARCH_SIGNAL_ALL_RED_S)
        env["signal_phases"] = trial.suggest_categorical("signal_phases", ["paired", "single"])
        phase = trial.suggest_float("signal_offset", 0.0, 1.0)  # a fraction of each route junction's cycle
        offsets = {j: round(phase * c, 3) for j in dict.fromkeys(mv[0] for mv in route)
                   if (c := signal_cycle(m, j, env)) > 0}
    seed = trial.suggest_int("seed", 0, SEARCH_ENV_SEED_MAX)
    env = {k: round(v, 3) if isinstance(v, float) else v for k, v in env.items()}
    return Scenario(name=name, map=str(path), route=route, traffic_vehicles=traffic, pedestrian_rate=round(rate, 3),
                    signal_offsets=offsets, seed=seed, duration=duration(m, route, env), env=env)


def _suggest_junction(trial: Any, space: FeatureSpace) -> JunctionFeature:
    """Legs, their angles (parameters named per leg count: the ranges differ), control,
    crosswalk, lanes per direction and an optional one-way leg."""
    from feat2map.errors import FeatureError

    n = trial.suggest_categorical("legs", list(space.road_counts))
    angles = [trial.suggest_float(f"angle_{n}_{i}", lo, hi) for i, (lo, hi) in enumerate(space.rotation_ranges[n])]
    control = trial.suggest_categorical("control", list(space.controls))
    crosswalk = trial.suggest_categorical("crosswalk", list(space.crosswalks))
    lanes = trial.suggest_int("lanes", 1, SEARCH_LANES_MAX)
    types = ["in-out"] * n
    if trial.suggest_categorical("one_way", [False, True]):
        leg = trial.suggest_int(f"one_way_leg_{n}", 0, n - 1)
        types[leg] = trial.suggest_categorical("one_way_direction", list(ONE_WAY_DIRECTIONS))
    try:
        return JunctionFeature.make([round(a, 3) for a in angles], control, crosswalk, types, lanes).normalized()
    except FeatureError as exc:
        raise Infeasible(f"junction feature: {exc}") from None


def _suggest_manoeuvre(trial: Any, m: HDMap) -> Manoeuvre:
    """The ego's turn, then which of the junction's manoeuvres of that turn (a fraction)."""
    from feat2map.routes import manoeuvre_lane, suite_manoeuvres

    turn = trial.suggest_categorical("turn", list(TURNS))
    pick = trial.suggest_float("manoeuvre", 0.0, 1.0)
    moves = [mv for mv in suite_manoeuvres(m) if _turn(manoeuvre_lane(m, mv)) == turn]
    if not moves:
        raise Infeasible(f"no {turn} manoeuvre at this junction")
    return moves[min(int(pick * len(moves)), len(moves) - 1)]


def _turn(lane: Any) -> str:
    turn = getattr(lane, "turn", None) or "none"
    return "straight" if turn == "none" else str(turn)


def signal_cycle(m: HDMap, junction_id: str, env: dict[str, Any]) -> float:
    """The signal cycle [s] at a junction under the candidate's plan (0 without signals)."""
    from feat2map.config import DRIVE_DEFAULTS
    from feat2map.phases import plan_junction

    signals = [s for s in m.signals.values() if s.junction_id == junction_id]
    if not signals:
        return 0.0
    cfg = {**DRIVE_DEFAULTS, **env}
    phases = plan_junction(m, signals, cfg["signal_phases"] == "paired")
    return len(phases) * (float(cfg["signal_green"]) + float(cfg["signal_amber"]) + float(cfg["signal_all_red"]))


def duration(m: HDMap, route: Sequence[Manoeuvre], env: dict[str, Any]) -> float:
    """`scenarios.routes.route_duration` with the candidate's signal cycles instead of the
    default ones (a long green must not turn into a timeout of the scenario's own making)."""
    from .routes import route_duration, signal_cycle as default_cycle, signal_cycles

    extra = sum(signal_cycles(m, mv) * max(0.0, signal_cycle(m, mv[0], env) - default_cycle(m, mv[0])) for mv in route)
    return round(route_duration(m, route) + extra, 1)
