"""Steps per second of feat2map/JunctionGrid-v0 (its batched traffic core) against highway-env's
intersection-v1 with the same vehicle count, at 1 Hz and 10 Hz decisions, 10 and 30 vehicles,
on maps of 4, 8 (the default map), ~100 and ~400 junctions; make_vec scaling over 1 and 2
workers; resident memory of one env on the ~400-junction map; optionally the profile of a step.

Speeds are measured in one process, interleaved (a round of each env in turn, the median of the
rounds), as CPU time of this process (on a shared machine other jobs' load stretches wall time,
not CPU time), with the wall-clock ratio beside it: the ratios hold on a loaded machine, absolute
numbers do not.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_env.py [--rounds N] [--quick] [--profile]
"""
from __future__ import annotations

import argparse
import cProfile
import io
import os
import pstats
import statistics
import subprocess
import sys
import time

import warnings

import gymnasium as gym
import highway_env  # noqa: F401  (registers intersection-v1)
import numpy as np

import feat2map

HZ = {1: {"simulation_frequency": 15, "policy_frequency": 1},  # the env's default
      10: {"simulation_frequency": 20, "policy_frequency": 10}}  # as issue 15 measured
STEPS = {1: 12, 10: 120}  # per round
VEHICLES = (10, 30)  # ego + traffic (intersection-v1: initial_vehicle_count)
IDLE = 1  # DiscreteMetaAction's IDLE
J = feat2map.JunctionFeature.make
FOUR = [J([0, 90, 180, 270], "signal", True), J([0, 90, 180, 270], "stop", True), J([0, 90, 180], "bare", False),
        J([0, 90, 180, 270], "bare", True)]
# the SF space has 8 (road count, control, crosswalk) combinations: samples_per_combination k gives 8k junctions
MAPS = {4: {"features": [f.to_dict() for f in FOUR]}, 8: {}, 96: {"generation": {"samples_per_combination": 12}},
        400: {"generation": {"samples_per_combination": 50}}}


def feat2map_env(map_cfg: dict, hz: int, vehicles: int) -> gym.Env:
    return gym.make("feat2map/JunctionGrid-v0", config={
        **map_cfg, **HZ[hz], "traffic_vehicles": vehicles - 1, "duration": 1e9, "route_junctions": 3})


def intersection_env(hz: int, vehicles: int) -> gym.Env:
    return gym.make("intersection-v1", config={
        **HZ[hz], "initial_vehicle_count": vehicles, "duration": 1e9,
        "action": {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False, "target_speeds": [0, 4.5, 9]}})


class Runner:
    """An env stepped IDLE in rounds (reset at episode ends), its steps/s per round."""

    def __init__(self, env: gym.Env, seed: int = 0) -> None:
        self.env = env
        env.reset(seed=seed)
        self.rates: list[float] = []  # CPU time
        self.wall: list[float] = []
        self.counts: list[int] = []

    def round(self, steps: int) -> None:
        env = self.env
        t, w = time.process_time(), time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(IDLE)
            self.counts.append(len(env.unwrapped.road.vehicles))
            if term or trunc:
                env.reset()
        self.rates.append(steps / max(time.process_time() - t, 1e-9))
        self.wall.append(steps / (time.perf_counter() - w))

    @property
    def rate(self) -> float:
        return statistics.median(self.rates)

    @property
    def wall_rate(self) -> float:
        return statistics.median(self.wall)


def speed_table(rounds: int, sizes: list[int]) -> list[dict]:
    rows = []
    for hz in HZ:
        for n in VEHICLES:
            ref = Runner(intersection_env(hz, n))
            for size in sizes:
                new = Runner(feat2map_env(MAPS[size], hz, n))
                for _ in range(rounds):
                    for r in (ref, new):
                        r.round(STEPS[hz] if r is not new else 4 * STEPS[hz])
                rows.append({"hz": hz, "vehicles": n, "junctions": len(new.env.unwrapped.net.hdmap.junctions),
                             "ref": ref.rate, "new": new.rate, "n_ref": np.mean(ref.counts),
                             "n_new": np.mean(new.counts), "wall": new.wall_rate / ref.wall_rate})
                print(f"  measured {hz:2d} Hz {n} vehicles {rows[-1]['junctions']} junctions", file=sys.stderr, flush=True)
    return rows


def print_speed(rows: list[dict]) -> None:
    print("steps/s of CPU time (median of interleaved rounds; wall = the same ratio in wall-clock time)")
    print(f"{'Hz':>3} {'veh':>4} {'junctions':>9} {'intersection-v1':>15} {'feat2map':>8} "
          f"{'feat2map/inters.':>16} {'(wall)':>7} {'vs 4-j':>7} {'on road (ref/ours)':>18}")
    for r in rows:
        base = next(x for x in rows if x["hz"] == r["hz"] and x["vehicles"] == r["vehicles"])
        print(f"{r['hz']:>3} {r['vehicles']:>4} {r['junctions']:>9} {r['ref']:>15.0f} {r['new']:>8.0f} "
              f"{r['new'] / r['ref']:>15.1f}x {r['wall']:>6.1f}x {r['new'] / base['new']:>7.2f} "
              f"{r['n_ref']:>9.1f}/{r['n_new']:<8.1f}")


def vector_scaling(rounds: int, seconds: float = 3.0) -> None:
    """Env-steps/s (wall clock: the workers are other processes) of gym.make_vec with 1 and 2
    async workers and 2 sync envs, measured in interleaved rounds: 10 Hz, 10 vehicles, the
    default map."""
    print("\nmake_vec (10 Hz, 10 vehicles, default map): total env-steps/s, wall clock, "
          "median of interleaved rounds")
    setups = {(mode, n): gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode=mode, config={
        **HZ[10], "traffic_vehicles": 9, "duration": 1e9, "route_junctions": 3})
        for mode, n in (("async", 1), ("async", 2), ("sync", 2))}
    rates: dict = {k: [] for k in setups}
    for envs in setups.values():
        envs.reset(seed=0)
    for _ in range(rounds):
        for (mode, n), envs in setups.items():
            actions = np.full(n, IDLE)
            steps, t = 0, time.perf_counter()
            while time.perf_counter() - t < seconds:
                envs.step(actions)
                steps += n
            rates[(mode, n)].append(steps / (time.perf_counter() - t))
    base = statistics.median(rates[("async", 1)])
    for (mode, n), envs in setups.items():
        rate = statistics.median(rates[(mode, n)])
        envs.close()
        print(f"  {mode:5s} {n} worker(s): {rate:7.0f} env-steps/s  ({rate / base:.2f}x of 1 async worker)")


MEMORY_CODE = """
import gymnasium as gym, feat2map
def rss():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) / 1024 for l in f if l.startswith("VmRSS"))
env = gym.make("feat2map/JunctionGrid-v0", config={"generation": {"samples_per_combination": 50},
               "traffic_vehicles": 29})
env.reset(seed=0)
for _ in range(100):
    env.step(1)
print(rss(), len(env.unwrapped.net.hdmap.junctions), len(env.unwrapped.net.lane_ids))
"""


def memory() -> None:
    """Resident memory of a fresh process holding one env of the ~400-junction map (30
    vehicles, after 100 steps): what each vector-env worker costs."""
    print("\nmemory per env (a fresh process, ~400-junction map, 30 vehicles, after 100 steps)")
    out = subprocess.run([sys.executable, "-c", MEMORY_CODE], capture_output=True, text=True,
                         env={**os.environ, "SDL_VIDEODRIVER": "offscreen"}, check=True)
    mib, junctions, lanes = out.stdout.split()
    print(f"  {float(mib):6.0f} MiB resident ({junctions} junctions, {lanes} lanes)")


def profile(steps: int = 300) -> None:
    """cProfile of policy steps: 10 Hz, 10 vehicles, the default map."""
    env = feat2map_env({}, 10, 10)
    env.reset(seed=0)
    for _ in range(20):
        env.step(IDLE)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(steps):
        _, _, term, trunc, _ = env.step(IDLE)
        if term or trunc:
            env.reset()
    prof.disable()
    print_profile(prof, f"{steps} policy steps (10 Hz, 10 vehicles, default map)", 18, 4000)


def print_profile(prof: cProfile.Profile, what: str, rows: int, chars: int) -> None:
    """The `rows` functions of a profile with the most own time, blank lines dropped."""
    text = io.StringIO()
    pstats.Stats(prof, stream=text).sort_stats("tottime").print_stats(rows)
    print(f"\nprofile of {what}, by own time:")
    print("\n".join(line for line in text.getvalue().splitlines() if line.strip())[:chars])


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="interleaved measurement rounds (default: 3)")
    ap.add_argument("--quick", action="store_true", help="maps of 4 and 8 junctions only, no vector envs or memory")
    ap.add_argument("--profile", action="store_true", help="also print the profile of a policy step")
    args = ap.parse_args(argv)
    warnings.filterwarnings("ignore", message=".*intersection-v1 is out of date.*")
    load = os.getloadavg()[0]
    print(f"machine: {os.cpu_count()} cores, load average {load:.1f} at start")
    sizes = [4, 8] if args.quick else list(MAPS)
    print_speed(speed_table(args.rounds, sizes))
    if not args.quick:
        vector_scaling(args.rounds)
        memory()
    if args.profile:
        profile()
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
