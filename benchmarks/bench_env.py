"""Steps per second of feat2map/JunctionGrid-v0 against highway-env's intersection-v1, in one
process, with the same vehicle count and frequencies, on maps of 4, 100 and 400 junctions.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_env.py [--steps N]
"""
from __future__ import annotations

import argparse
import time

import gymnasium as gym
import highway_env  # noqa: F401  (registers intersection-v1)
import numpy as np

import feat2map

FREQS = {"simulation_frequency": 15, "policy_frequency": 1}
VEHICLES = 10  # intersection-v1's initial_vehicle_count


def measure(env: gym.Env, steps: int, seed: int = 0) -> tuple[float, float]:
    """(steps per second, mean vehicles on the road) over `steps` IDLE steps, resetting at episode ends."""
    env.reset(seed=seed)
    space = env.action_space
    idle = 1 if isinstance(space, gym.spaces.Discrete) else np.zeros(space.shape, dtype=space.dtype)
    counts = []
    t = time.perf_counter()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(idle)
        counts.append(len(env.unwrapped.road.vehicles))
        if term or trunc:
            env.reset()
    return steps / (time.perf_counter() - t), float(np.mean(counts))


def junction_config(k: int) -> dict:
    return {**FREQS, "generation": {"samples_per_combination": k}, "traffic_vehicles": VEHICLES - 1,
            "duration": 1e9, "route_junctions": 3}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=60)
    args = ap.parse_args(argv)
    ref = gym.make("intersection-v1", config={**FREQS, "action": {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False, "target_speeds": [0, 4.5, 9]}, "initial_vehicle_count": VEHICLES, "duration": 1e9})
    ref_sps, ref_n = measure(ref, args.steps)
    rows = [("intersection-v1", 1, 0.0, ref_sps, ref_n)]
    # the SF space has 2 road counts x 2 controls x 2 crosswalk values = 8 combinations;
    # samples_per_combination k gives 8k junctions: k = 1/2 for ~4 (explicit features), 12, 50
    sizes = {4: None, 100: 12, 400: 50}
    for n, k in sizes.items():
        if k is None:
            J = feat2map.JunctionFeature.make
            cfg = {**FREQS, "features": [J([0, 90, 180, 270], "signal", True).to_dict(),
                                         J([0, 90, 180, 270], "stop", True).to_dict(),
                                         J([0, 90, 180], "bare", False).to_dict(),
                                         J([0, 90, 180, 270], "bare", True).to_dict()],
                   "traffic_vehicles": VEHICLES - 1, "duration": 1e9, "route_junctions": 3}
        else:
            cfg = junction_config(k)
        t = time.perf_counter()
        env = gym.make("feat2map/JunctionGrid-v0", config=cfg)
        build = time.perf_counter() - t
        junctions = len(env.unwrapped.net.hdmap.junctions)
        sps, nv = measure(env, args.steps)
        rows.append(("feat2map JunctionGrid-v0", junctions, build, sps, nv))
    base4 = rows[1][3]
    print(f"{'env':28s} {'junctions':>9s} {'build s':>8s} {'steps/s':>8s} {'vehicles':>8s} {'vs ref':>7s} {'vs 4-j':>7s}")
    for name, j, build, sps, nv in rows:
        print(f"{name:28s} {j:9d} {build:8.2f} {sps:8.1f} {nv:8.1f} {sps / ref_sps:7.2f} {sps / base4:7.2f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
