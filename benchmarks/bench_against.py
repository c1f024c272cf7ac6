"""This checkout's env speed against another revision's, measured alternately in one run: the
single env's steps/s and the native batched env's env-steps/s (10 Hz decisions, 10 vehicles per
sub-env, the default map), and with `--marl` the multi-agent env's agent-steps/s (the scene of
benchmarks/bench_marl.py: ~20 agents at a 4-way signalled junction), as CPU time of the
measuring process. What a change to envs/ reports ("before and after, alternately in one run,
and the ratio").

The other revision is checked out into a temporary git worktree and imported from there (its
`envs/` and `scenarios/` linked into its `feat2map/` as the installed package maps them); this
checkout runs as installed. Each round runs one process per revision in turn, so load on a shared
machine falls on both alike; the table gives the median of the rounds and after/before.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_against.py [--base main] [--rounds 5]
     [--sizes 1,64,256] [--marl] [--metadrive]   (--sizes "" --marl: the multi-agent env alone;
     --metadrive: MetaDrive 0.4.3's single-agent env in each round, from /tmp/md-venv)
"""
from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
CONFIG = {"simulation_frequency": 20, "policy_frequency": 10, "traffic_vehicles": 9, "duration": 1e9,
          "route_junctions": 3}
ENV_STEPS = 600  # env-steps per measurement and setup
BATCH_MIN_STEPS = 10  # batched steps per measurement at the least (N = 256: 2,560 env-steps)
IDLE = 1  # DiscreteMetaAction's IDLE
MARL_HOLD = 3  # the agents' TargetSpeed index held in the multi-agent measurement (bench_marl.py's HOLD: 5 m/s)

# one measurement in a fresh process: {size: env-steps per CPU second} (size 1: the single env),
# and {"marl": agent-steps per CPU second} with a multi-agent config (bench_marl.py's scene)
MEASURE = r"""
import json, sys, time
import gymnasium as gym
import numpy as np
import feat2map

config, steps, sizes, BATCH_MIN_STEPS, marl, hold = json.loads(sys.argv[1])
out = {"feat2map": feat2map.__file__}
if marl:
    from feat2map.envs import parallel_env
    env = parallel_env(marl)
    env.reset(seed=0)
    agent_steps = 0
    for k in range(20 + steps):  # 20 steps of warm-up (lane and pair tables)
        if k == 20:
            agent_steps, t = 0, time.process_time()
        if not env.agents:
            env.reset()
        agent_steps += len(env.agents)
        env.step({a: hold for a in env.agents})
    out["marl"] = agent_steps / (time.process_time() - t)
    env.close()
for n in sizes:
    if n == 1:
        env = gym.make("feat2map/JunctionGrid-v0", config=config)
        env.reset(seed=0)
        t = time.process_time()
        for _ in range(steps):
            *_, term, trunc, _ = env.step(1)
            if term or trunc:
                env.reset()
    else:
        env = gym.make_vec("feat2map/JunctionGrid-v0", num_envs=n, vectorization_mode="vector_entry_point",
                           config=config)
        env.reset(seed=0)
        action = np.full(n, 1)
        t = time.process_time()
        for _ in range(max(steps // n, BATCH_MIN_STEPS)):
            env.step(action)
    out[n] = (max(steps // n, BATCH_MIN_STEPS) * n if n > 1 else steps) / (time.process_time() - t)
    env.close()
print(json.dumps(out))
"""


# MetaDrive 0.4.3's single-agent env as ../shared/tools/metadrive_bench.py drives it (3 blocks, traffic
# density 0.1, 10 Hz decisions, constant throttle), in CPU time of its process: env-steps/s
MD_SINGLE = """
import time
from metadrive.envs.metadrive_env import MetaDriveEnv
env = MetaDriveEnv(dict(num_scenarios=10, start_seed=0, traffic_density=0.1, use_render=False, log_level=50, map=3))
env.reset()
t = time.process_time()
for _ in range({steps}):
    o, r, te, tr, i = env.step([0.0, 0.5])
    if te or tr:
        env.reset()
print({steps} / (time.process_time() - t))
env.close()
"""


def marl_config() -> dict:
    """bench_marl.py's multi-agent config (its scene, made in this checkout)."""
    sys.path.insert(0, str(REPO / "benchmarks"))
    from bench_marl import MULTI

    return MULTI


def base_checkout(rev: str, where: Path) -> Path:
    """`rev` checked out at `where`, importable as the package `feat2map` from `where`."""
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(where), rev], check=True)
    for sub in ("envs", "scenarios"):
        (where / "feat2map" / sub).symlink_to(where / sub, target_is_directory=True)
    return where


def measure(pythonpath: Path | None, sizes: list[int], marl: dict | None) -> dict:
    env = dict(os.environ, SDL_VIDEODRIVER="offscreen")
    env.pop("PYTHONPATH", None)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    args = [CONFIG, ENV_STEPS, sizes, BATCH_MIN_STEPS, marl, MARL_HOLD]
    run = subprocess.run([sys.executable, "-c", MEASURE, json.dumps(args)], env=env,
                         capture_output=True, text=True, cwd=tempfile.gettempdir())
    if run.returncode != 0:
        raise SystemExit(f"measurement failed ({'base' if pythonpath else 'this checkout'}):\n{run.stderr[-2000:]}")
    return json.loads(run.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="the revision to compare with (default: main)")
    ap.add_argument("--rounds", type=int, default=5, help="alternating rounds (default: 5)")
    ap.add_argument("--sizes", default="1,64,256", help="1: the single env; N > 1: the batched env (default: 1,64,256)")
    ap.add_argument("--marl", action="store_true", help="the multi-agent env's agent-steps/s too (bench_marl.py's scene)")
    ap.add_argument("--metadrive", action="store_true",
                    help="MetaDrive 0.4.3's single-agent env in each round too (/tmp/md-venv: "
                         "../shared/tools/metadrive-venv.sh), and the single env's ratio to it")
    args = ap.parse_args()
    if args.metadrive:
        sys.path.insert(0, str(REPO / "benchmarks"))
        from bench_marl import metadrive_run
        if 1 not in [int(s) for s in args.sizes.split(",") if s]:
            ap.error("--metadrive compares the single env: --sizes must hold 1")
    sizes = [int(s) for s in args.sizes.split(",") if s]
    marl = marl_config() if args.marl else None
    keys: list[int | str] = [*sizes, *(["marl"] if marl else [])]
    rates: dict[str, dict[int | str, list[float]]] = {k: {n: [] for n in keys} for k in ("before", "after")}
    metadrive: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-against-") as tmp:
        base = base_checkout(args.base, Path(tmp) / "base")
        try:
            for r in range(args.rounds):
                if args.metadrive:
                    got_md = metadrive_run(MD_SINGLE.format(steps=ENV_STEPS), 1)
                    if got_md is None:
                        raise SystemExit("MetaDrive did not run: make /tmp/md-venv with ../shared/tools/metadrive-venv.sh")
                    metadrive.append(got_md[0])
                for label, path in (("before", base), ("after", None)):
                    got = measure(path, sizes, marl)
                    if r == 0:
                        where = Path(got["feat2map"]).parent
                        assert (where.resolve() == (base / "feat2map").resolve()) == (path is not None), where
                    for n in keys:
                        rates[label][n].append(got[str(n)])
                print(f"  round {r + 1} of {args.rounds}", file=sys.stderr, flush=True)
        finally:
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(base)], check=False)
    print(f"env-steps/s of CPU time, median of {args.rounds} alternating rounds (before: {args.base}; after: this "
          "checkout); 10 Hz, 10 vehicles per sub-env, default map" +
          ("; multi-agent: agent-steps/s, bench_marl.py's scene" if marl else ""))
    print(f"{'setup':>12} {'before':>9} {'after':>9} {'after/before':>13}  rounds after/before")
    for n in keys:
        b, a = statistics.median(rates["before"][n]), statistics.median(rates["after"][n])
        each = " ".join(f"{x / y:.2f}" for x, y in zip(rates["after"][n], rates["before"][n]))
        name = "multi-agent" if n == "marl" else "single" if n == 1 else f"N = {n}"
        print(f"{name:>12} {b:>9.0f} {a:>9.0f} {a / b:>12.2f}x  {each}")
    if metadrive:
        md = statistics.median(metadrive)
        print(f"MetaDrive 0.4.3 single-agent env: {md:.0f} env-steps/s (rounds: {' '.join(f'{x:.0f}' for x in metadrive)}); "
              + ", ".join(f"{label}: {statistics.median(rates[label][1]) / md:.2f}x MetaDrive "
                          f"(rounds {' '.join(f'{x / y:.2f}' for x, y in zip(rates[label][1], metadrive))})"
                          for label in ("before", "after")))
    for label in ("before", "after"):
        if 1 in sizes and len(sizes) > 1:
            single = statistics.median(rates[label][1])
            print(f"{label}: " + ", ".join(f"N = {n}: {statistics.median(rates[label][n]) / single:.2f}x the single env"
                                          for n in sizes if n > 1))


if __name__ == "__main__":
    main()
