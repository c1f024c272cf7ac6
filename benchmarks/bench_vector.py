"""Env-steps per second of the native batched vector env (envs/vector.py: N sub-envs whose traffic
shares one core, stepped by one call per frame) against the single env and gym.make_vec's async
workers, at 1 Hz and 10 Hz decisions, 10 and 30 vehicles per sub-env, on the default map; memory
per extra sub-env; optionally the profile of a batched step.

Speeds are measured in one process, interleaved (a round of each setup in turn, the median of
the rounds), as env-steps per second of this process's CPU time (on a shared machine other
jobs' load stretches wall time, not CPU time), with wall-clock rates beside them; make_vec's
async workers are other processes, so their line is wall clock only.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_vector.py [--rounds N] [--sizes 1,16,64,256,1024]
     [--quick] [--profile] [--freeze-gc]
"""
from __future__ import annotations

import argparse
import cProfile
import gc
import os
import statistics
import subprocess
import sys
import time

import gymnasium as gym
import numpy as np

import feat2map  # noqa: F401  (registers the environment ids)
from bench_env import print_profile  # noqa: E402  (benchmarks/ is the script's folder)

HZ = {1: {"simulation_frequency": 15, "policy_frequency": 1},  # the env's default
      10: {"simulation_frequency": 20, "policy_frequency": 10}}
ENV_STEPS = {1: 60, 10: 600}  # env-steps per round and setup (at least 2 batched steps)
VEHICLES = (10, 30)  # ego + traffic per sub-env
SIZES = (1, 16, 64, 256, 1024)
IDLE = 1  # DiscreteMetaAction's IDLE
FREEZE_GC = False  # --freeze-gc: gc.freeze() once the envs are made, as a training script may


def config(hz: int, vehicles: int) -> dict:
    return {**HZ[hz], "traffic_vehicles": vehicles - 1, "duration": 1e9, "route_junctions": 3}


class Setup:
    """A single env or a vector env stepped IDLE in rounds; env-steps/s per round (CPU, wall)."""

    def __init__(self, env, n: int) -> None:
        self.env, self.n = env, n
        env.reset(seed=0)
        self.cpu: list[float] = []
        self.wall: list[float] = []

    def round(self, env_steps: int) -> None:
        steps = max(2, -(-env_steps // self.n)) if self.n > 1 else env_steps
        single = self.n == 0
        action = IDLE if single else np.full(self.n, IDLE)
        t, w = time.process_time(), time.perf_counter()
        for _ in range(steps):
            out = self.env.step(action)
            if single and (out[2] or out[3]):
                self.env.reset()
        done = steps * max(self.n, 1)
        self.cpu.append(done / max(time.process_time() - t, 1e-9))
        self.wall.append(done / (time.perf_counter() - w))


def speed_table(rounds: int, sizes: list[int], hzs=(1, 10), vehicles=VEHICLES) -> list[dict]:
    rows = []
    for hz in hzs:
        for veh in vehicles:
            cfg = config(hz, veh)
            setups = {0: Setup(gym.make("feat2map/JunctionGrid-v0", config=cfg), 0)}
            for n in sizes:
                setups[n] = Setup(gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n,
                                               vectorization_mode="vector_entry_point", config=cfg), n)
            if FREEZE_GC:
                gc.collect()
                gc.freeze()  # the envs' objects out of the cyclic collector's full passes
            for _ in range(rounds):
                for s in setups.values():
                    s.round(ENV_STEPS[hz])
            base = statistics.median(setups[0].cpu)
            for n, s in setups.items():
                cpu, wall = statistics.median(s.cpu), statistics.median(s.wall)
                rows.append({"hz": hz, "vehicles": veh, "n": n, "cpu": cpu, "wall": wall, "x": cpu / base})
                s.env.close()
            print(f"  measured {hz:2d} Hz {veh} vehicles", file=sys.stderr, flush=True)
    return rows


def print_speed(rows: list[dict]) -> None:
    print("env-steps/s of CPU time (median of interleaved rounds; x single = against the single env in the same run)")
    print(f"{'Hz':>3} {'veh':>4} {'setup':>16} {'env-steps/s':>12} {'x single':>9} {'wall env-steps/s':>17}")
    for r in rows:
        name = "single env" if r["n"] == 0 else f"batched N={r['n']}"
        print(f"{r['hz']:>3} {r['vehicles']:>4} {name:>16} {r['cpu']:>12.0f} {r['x']:>8.2f}x {r['wall']:>17.0f}")


def async_line(rounds: int, n: int = 256, seconds: float = 3.0) -> None:
    """Wall-clock env-steps/s of make_vec async (2 workers, one per core) against the batched env
    (N sub-envs) and the single env, interleaved: 10 Hz, 10 vehicles, the default map."""
    cfg = config(10, 10)
    setups = {"single env": (gym.make("feat2map/JunctionGrid-v0", config=cfg), 0),
              "async 2 workers": (gym.make_vec("feat2map/JunctionGrid-v0", num_envs=2, vectorization_mode="async",
                                               config=cfg), 2),
              f"batched N={n}": (gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n,
                                              vectorization_mode="vector_entry_point", config=cfg), n)}
    rates: dict = {k: [] for k in setups}
    for env, _ in setups.values():
        env.reset(seed=0)
    for _ in range(rounds):
        for name, (env, k) in setups.items():
            action = IDLE if k == 0 else np.full(k, IDLE)
            steps, t = 0, time.perf_counter()
            while time.perf_counter() - t < seconds:
                out = env.step(action)
                if k == 0 and (out[2] or out[3]):
                    env.reset()
                steps += max(k, 1)
            rates[name].append(steps / (time.perf_counter() - t))
    base = statistics.median(rates["single env"])
    print("\nwall clock, all processes (10 Hz, 10 vehicles, default map), median of interleaved rounds")
    for name, (env, _) in setups.items():
        rate = statistics.median(rates[name])
        env.close()
        print(f"  {name:16s}: {rate:7.0f} env-steps/s  ({rate / base:.2f}x the single env)")


MEMORY_CODE = """
import gymnasium as gym, feat2map, sys, numpy as np
def rss():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) / 1024 for l in f if l.startswith("VmRSS"))
n = int(sys.argv[1])
envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                    config={"policy_frequency": 10, "simulation_frequency": 20, "traffic_vehicles": 9,
                            "duration": 1e9, "route_junctions": 3})
envs.reset(seed=0)
for _ in range(20):
    envs.step(np.ones(n, dtype=np.int64))
print(rss())
"""


def memory(small: int = 16, large: int = 256) -> None:
    """Resident memory of fresh processes holding a batch of `small` and of `large` sub-envs
    (default map, 10 vehicles, after 20 steps): the difference per extra sub-env."""
    mib = {}
    for n in (small, large):
        out = subprocess.run([sys.executable, "-c", MEMORY_CODE, str(n)], capture_output=True, text=True,
                             env={**os.environ, "SDL_VIDEODRIVER": "offscreen"}, check=True)
        mib[n] = float(out.stdout.split()[-1])
    per = (mib[large] - mib[small]) / (large - small)
    print(f"\nmemory: {mib[small]:.0f} MiB resident with N={small}, {mib[large]:.0f} MiB with N={large} "
          f"(default map, 10 vehicles): {per * 1024:.0f} KiB per extra sub-env")


def profile(n: int = 256, steps: int = 20) -> None:
    """cProfile of batched steps: N sub-envs, 10 Hz, 10 vehicles, the default map."""
    envs = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                        config=config(10, 10))
    envs.reset(seed=0)
    action = np.full(n, IDLE)
    for _ in range(3):
        envs.step(action)
    prof = cProfile.Profile()
    prof.enable()
    for _ in range(steps):
        envs.step(action)
    prof.disable()
    print_profile(prof, f"{steps} batched steps (N={n}, 10 Hz, 10 vehicles, default map)", 22, 5000)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3, help="interleaved measurement rounds (default: 3)")
    ap.add_argument("--sizes", default=",".join(map(str, SIZES)), help="batch sizes N (default: 1,16,64,256,1024)")
    ap.add_argument("--quick", action="store_true", help="10 Hz, 10 vehicles only; no async line or memory")
    ap.add_argument("--profile", action="store_true", help="also print the profile of a batched step")
    ap.add_argument("--freeze-gc", action="store_true",
                    help="gc.freeze() once the envs are made (the cyclic collector then skips their objects)")
    args = ap.parse_args(argv)
    global FREEZE_GC
    FREEZE_GC = args.freeze_gc
    sizes = [int(x) for x in args.sizes.split(",")]
    print(f"machine: {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f} at start")
    if args.quick:
        print_speed(speed_table(args.rounds, sizes, hzs=(10,), vehicles=(10,)))
    else:
        print_speed(speed_table(args.rounds, sizes))
        async_line(args.rounds)
        memory()
    if args.profile:
        profile()
    print(f"load average at the end {os.getloadavg()[0]:.1f}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
