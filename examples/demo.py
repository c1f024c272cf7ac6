"""The main job: generate the paper's M1 map, export it, and drive it headless.

Writes OUT/map.json, OUT/map.png, OUT/junctions.png, OUT/map.xodr and OUT/drive.png (the last
rendered frame), and prints the drive's outcome.
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

import feat2map  # noqa: E402  (registers the feat2map/ environment ids)
from feat2map import mapio  # noqa: E402
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver  # noqa: E402
from feat2map.render import render_junctions, render_map  # noqa: E402
from feat2map.writers.opendrive import write_opendrive  # noqa: E402


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--out", default="out/demo")
    ap.add_argument("--seed", type=int, default=1)
    args = ap.parse_args()
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)

    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=args.seed)
    mapio.save(m, out / "map.json")
    render_map(m, out / "map.png", title=f"M1 (seed {args.seed})")
    render_junctions(m, out / "junctions.png")
    write_opendrive(m, out / "map.xodr")
    print(f"generated {len(m.junctions)} junctions, {len(m.lanes)} lanes -> {out}")

    env = gym.make("feat2map/MapFile-v0", render_mode="rgb_array",
                   config={"map_file": str(out / "map.json"), "action": DRIVER_ACTION_CONFIG, "policy_frequency": 5, "duration": 90})
    env.reset(seed=args.seed)
    driver = ScriptedDriver(env)
    info: dict = {}
    done = False
    steps = 0
    while not done:
        _, _, terminated, truncated, info = env.step(driver.act())
        done = terminated or truncated
        steps += 1
    plt.imsave(out / "drive.png", env.render())
    env.close()
    print(f"drove {steps} steps: completed={info.get('route_completed')} collision={info.get('collision')} "
          f"progress={info.get('route_progress'):.2f} violations={info.get('violations')}")


if __name__ == "__main__":
    main()
