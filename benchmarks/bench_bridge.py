"""The planner bridge's cost, in one process: env steps per wall second of the same scenarios
(seeds, traffic) driven by the in-process baseline planner (the baseline of the ratios), by the
reference planner through the bridge (examples/bridge_planner.py: the protocol's own cost:
a process, JSON both ways, trajectory tracking every frame) and by CommonRoad's reactive planner
through the bridge (when .venv-crplanner exists; adapters/commonroad/setup.sh). Each scenario is
driven for at most --sim-s simulated seconds. The planners take turns, --rounds times, so that
each round's ratio compares runs made moments apart.

Run: SDL_VIDEODRIVER=offscreen nice -n 10 .venv/bin/python benchmarks/bench_bridge.py [--scenarios N] [--sim-s S]
     [--rounds R] [--no-commonroad]
"""
from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import feat2map
from feat2map.formats import native
from feat2map.scenarios.bridge import BridgePlanner, discard_spares
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.routes import build_suite
from feat2map.scenarios.scenario import make_env

ROOT = Path(__file__).resolve().parents[1]
CRPY = ROOT / ".venv-crplanner" / "bin" / "python"


def drive(make_policy, scenarios, sim_s: float) -> tuple[int, float, float]:
    """(env steps, wall seconds, simulated seconds) over the scenarios."""
    steps, wall, sim = 0, 0.0, 0.0
    for sc in scenarios:
        policy = make_policy()
        env = make_env(sc, config={"action": dict(policy.action_config)})
        obs, info = env.reset(seed=sc.seed)
        t = time.perf_counter()
        policy.reset(env)
        while True:
            obs, _, term, trunc, info = env.step(policy.act(obs, info))
            steps += 1
            if term or trunc or info["time"] >= sim_s:
                break
        if hasattr(policy, "close"):
            policy.close()
        wall += time.perf_counter() - t
        sim += float(info["time"])
        env.close()
    t = time.perf_counter()
    discard_spares()  # as a suite's end does (a planner that allows it was started ahead of each next scenario)
    return steps, wall + time.perf_counter() - t, sim


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scenarios", type=int, default=4)
    ap.add_argument("--sim-s", type=float, default=30.0)
    ap.add_argument("--rounds", type=int, default=1, help="turns of every planner (each round gives a ratio)")
    ap.add_argument("--no-commonroad", action="store_true", help="leave CommonRoad's reactive planner out")
    args = ap.parse_args()
    import tempfile

    tmp = Path(tempfile.mkdtemp(prefix="bench-bridge-"))
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", True)], seed=0)
    native.save(m, tmp / "map.json")
    scenarios = build_suite(tmp / "map.json", traffic_vehicles=4, seed=0).scenarios[:args.scenarios]
    ref = f"{sys.executable} {ROOT / 'examples' / 'bridge_planner.py'}"
    runs = [("baseline planner, in process", BaselinePlanner),
            ("reference planner, bridge", lambda: BridgePlanner(ref))]
    if CRPY.exists() and not args.no_commonroad:
        cr = f"{CRPY} {ROOT / 'adapters' / 'commonroad' / 'planner.py'}"
        runs.append(("CommonRoad reactive planner, bridge", lambda: BridgePlanner(cr, step_timeout=60)))
    print(f"{len(scenarios)} scenarios of a 4-leg signal junction, traffic 4, <= {args.sim_s:g} s each; "
          f"load {os.getloadavg()[0]:.1f}")
    print("| round | planner | env steps | wall [s] | steps/s | sim s / wall s | ratio vs baseline |")
    print("|---:|---|---:|---:|---:|---:|---:|")
    for r in range(1, args.rounds + 1):
        base = None
        for name, make in runs:
            steps, wall, sim = drive(make, scenarios, args.sim_s)
            rate = steps / wall
            base = base or rate
            print(f"| {r} | {name} | {steps} | {wall:.1f} | {rate:.1f} | {sim / wall:.2f} | {rate / base:.3f} |",
                  flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
