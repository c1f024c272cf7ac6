"""One drive through the Python API: a map file in `feat2map/MapFile-v0`, the baseline planner
on a sampled route, headless. Writes OUT/drive.png (the last rendered frame) and prints the
outcome and the planner's stage path.

    .venv/bin/python examples/demo.py --map out/demo/m1/map.json --out out/demo
"""
from __future__ import annotations

import argparse
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym  # noqa: E402
import matplotlib  # noqa: E402

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

import feat2map  # noqa: E402,F401  (registers the feat2map/ environment ids)
from feat2map.scenarios.planner import BaselinePlanner  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--map", required=True, help="a map file (.json, .xodr or Apollo .bin/.txt)")
    ap.add_argument("--out", default="out/demo")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    env = gym.make("feat2map/MapFile-v0", render_mode="rgb_array", config={
        "map_file": args.map, "action": BaselinePlanner.action_config, "policy_frequency": 5,
        "route_junctions": 3, "traffic_vehicles": 6, "pedestrian_rate": 6.0, "duration": 120})
    planner = BaselinePlanner()
    obs, info = env.reset(seed=args.seed)
    planner.reset(env)
    done, steps = False, 0
    while not done:
        obs, _, terminated, truncated, info = env.step(planner.act(obs, info))
        done = terminated or truncated
        steps += 1
    plt.imsave(out / "drive.png", env.render())
    env.close()
    print(f"drove {steps} steps: completed={info['route_completed']} collision={info['collision']} "
          f"progress={info['route_progress']:.2f} violations={info['violations']}")
    print("stage path:", " -> ".join(planner.stage_path()), f"; frame: {out / 'drive.png'}")


if __name__ == "__main__":
    main()
