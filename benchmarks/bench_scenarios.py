"""Route coverage and the baseline planner, timed in one process.

1. `manoeuvres` / `coverage_routes` on generated maps of 8, 80, 400 and 1,008 junctions: time,
   routes, manoeuvres per route, ratio of time per manoeuvre against the 8-junction map.
2. Env steps per second with the baseline planner against the env's own ScriptedDriver (the
   same scenarios, seeds and action config): the planner's overhead per decision.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_scenarios.py [--quick]
"""
from __future__ import annotations

import argparse
import time
from pathlib import Path

import feat2map
from feat2map.config import GenerationConfig
from feat2map.envs.driver import ScriptedDriver
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.routes import coverage_routes, manoeuvres, route_coverage
from feat2map.scenarios.scenario import load_suite, make_env

CI_SUITE = Path(__file__).resolve().parents[1] / "scenarios" / "ci_suite.yaml"


def bench_coverage(sizes: list[int]) -> None:
    print("| junctions | manoeuvres | routes | manoeuvres/route | coverage | time [s] | us/manoeuvre | ratio vs 8 |")
    print("|---:|---:|---:|---:|---:|---:|---:|---:|")
    base = None
    for k in sizes:
        m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=1, config=GenerationConfig(samples_per_combination=k))
        t = time.perf_counter()
        moves = manoeuvres(m)
        routes = coverage_routes(m)
        dt = time.perf_counter() - t
        per = dt / len(moves) * 1e6
        base = base or per
        print(f"| {len(m.junctions)} | {len(moves)} | {len(routes)} | {len(moves) / len(routes):.2f} | "
              f"{route_coverage(m, routes):.3f} | {dt:.3f} | {per:.0f} | {per / base:.2f} |")


def drive(make_policy, scenarios) -> tuple[int, float]:
    steps, wall = 0, 0.0
    for sc in scenarios:
        env = make_env(sc)
        obs, info = env.reset(seed=sc.seed)
        policy = make_policy(env)
        t = time.perf_counter()
        while True:
            obs, _, term, trunc, info = env.step(policy(obs, info))
            steps += 1
            if term or trunc:
                break
        wall += time.perf_counter() - t
        env.close()
    return steps, wall


def bench_planner() -> None:
    scenarios = load_suite(CI_SUITE).scenarios

    def baseline(env):
        p = BaselinePlanner()
        p.reset(env)
        return p.act

    def scripted(env):
        d = ScriptedDriver(env)
        return lambda obs, info: d.act()

    print("\n| policy | steps | steps/s | ratio vs ScriptedDriver |")
    print("|---|---:|---:|---:|")
    s_steps, s_wall = drive(scripted, scenarios)
    b_steps, b_wall = drive(baseline, scenarios)
    ref = s_steps / s_wall
    for name, st, wall in (("ScriptedDriver", s_steps, s_wall), ("BaselinePlanner", b_steps, b_wall)):
        print(f"| {name} | {st} | {st / wall:.0f} | {st / wall / ref:.2f} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="maps of 8 and 80 junctions only")
    args = ap.parse_args()
    bench_coverage([1, 10] if args.quick else [1, 10, 50, 126])
    bench_planner()


if __name__ == "__main__":
    main()
