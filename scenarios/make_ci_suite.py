"""Regenerate the CI suite: `scenarios/ci_map.json` and `scenarios/ci_suite.yaml`.

The map: six junctions sampled from the paper's San Francisco rotation ranges, two per control
(signal, stop, bare), each control with a 4-way junction and a 3-way one and crosswalks
alternating so every (road count, crosswalk) pair occurs. The suite: from the map's route-coverage
routes, the few that together touch every junction and every (control, turn) pair, with traffic
and pedestrians. Deterministic: running it again rewrites identical files.

    .venv/bin/python scenarios/make_ci_suite.py [--out-dir scenarios] [--picture]
"""
from __future__ import annotations

import argparse
import dataclasses
import sys
from pathlib import Path

import numpy as np

from feat2map import PAPER_SF_FEATURE_SPACE
from feat2map.envs.rules import TURN_NAMES
from feat2map.formats import native
from feat2map.generate import generate_from_features
from feat2map.messages import counted
from feat2map.model import HDMap
from feat2map.routes import manoeuvre_lane
from feat2map.sampling import sample_features
from feat2map.scenarios.routes import Route, coverage_routes, render_routes, route_duration
from feat2map.scenarios.scenario import Scenario, Suite, save_suite

MAP_SEED = 1
# (road count, control, crosswalk) of the six junctions
JUNCTION_TYPES = ((4, "signal", True), (3, "signal", False), (4, "stop", False), (3, "stop", True),
                  (4, "bare", True), (3, "bare", False))
ROUTE_JUNCTIONS = 3
TRAFFIC_VEHICLES = 4
PEDESTRIAN_RATE = 4.0  # per crosswalk per minute


def ci_map() -> HDMap:
    """The CI map: the junction types above, rotations sampled from the SF feature space."""
    space = dataclasses.replace(PAPER_SF_FEATURE_SPACE, controls=("signal", "stop", "bare"))
    feats = {(f.n_roads, f.control, f.crosswalk): f for f in sample_features(space, np.random.default_rng([MAP_SEED, 0]))}
    return generate_from_features([feats[t] for t in JUNCTION_TYPES], seed=MAP_SEED,
                                  meta={"purpose": "feat2map CI scenario suite"})


def behaviour_keys(m: HDMap, route: Route) -> set[tuple]:
    """What a route exercises: each junction, and each (control, turn) pair."""
    keys: set[tuple] = set()
    for jid, entry, exit_ in route:
        j = m.junctions[jid]
        lane = manoeuvre_lane(m, (jid, entry, exit_))
        if lane is None:
            raise ValueError(f"route {list(route)}: no lane of junction {jid} leads from road {entry} to road {exit_}")
        control = j.feature.control if j.feature else "unknown"
        keys |= {("junction", jid), ("turn", control, TURN_NAMES.get(lane.turn, lane.turn))}
    return keys


def ci_routes(m: HDMap) -> list[Route]:
    """Greedy cover of `behaviour_keys` by the map's coverage routes (most new keys first)."""
    candidates = coverage_routes(m, ROUTE_JUNCTIONS)
    wanted = set().union(*(behaviour_keys(m, r) for r in candidates))
    chosen: list[Route] = []
    while wanted:
        best = max(candidates, key=lambda r: (len(behaviour_keys(m, r) & wanted), -len(r)))
        chosen.append(best)
        wanted -= behaviour_keys(m, best)
    return chosen


def ci_suite(map_path: Path) -> Suite:
    m = native.load(map_path)
    scenarios = tuple(
        Scenario(name=f"ci-{i:02d}-" + "-".join(mv[0] for mv in r), map=str(map_path), route=r,
                 traffic_vehicles=TRAFFIC_VEHICLES, pedestrian_rate=PEDESTRIAN_RATE, seed=i,
                 duration=route_duration(m, r))
        for i, r in enumerate(ci_routes(m)))
    return Suite("ci", scenarios, map_path.parent)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out-dir", type=Path, default=Path(__file__).resolve().parent)
    ap.add_argument("--picture", action="store_true", help="also draw the routes (ci_suite.png)")
    args = ap.parse_args(argv)
    map_path = args.out_dir / "ci_map.json"
    native.save(ci_map(), map_path)
    suite = ci_suite(map_path)
    save_suite(suite, args.out_dir / "ci_suite.yaml")
    if args.picture:
        render_routes(native.load(map_path), [sc.route for sc in suite.scenarios], args.out_dir / "ci_suite.png",
                      names=[sc.name for sc in suite.scenarios])
    print(f"{map_path}: {counted(len(native.load(map_path).junctions), 'junction')}; "
          f"{args.out_dir / 'ci_suite.yaml'}: {counted(len(suite.scenarios), 'scenario')}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
