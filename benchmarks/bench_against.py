"""This checkout's env speed against another revision's, measured alternately in one run: the
single env's steps/s and the native batched env's env-steps/s (10 Hz decisions, 10 vehicles per
sub-env, the default map), and with `--marl` the multi-agent env's agent-steps/s (the scene of
benchmarks/bench_marl.py: ~20 agents at a 4-way signalled junction), as CPU time of the
measuring process. What a change to envs/ reports ("before and after, alternately in one run,
and the ratio").

The other revision is checked out into a temporary git worktree and imported from there (its
`envs/` and `scenarios/` linked into its `feat2map/` as the installed package maps them); this
checkout runs as installed. One worker process per revision (and one for MetaDrive with
`--metadrive`) makes its envs once, warms them up, then measures short chunks on request; all
workers run on one CPU and the chunks of the revisions alternate (ABBA), so that a change of the
machine's speed, which on a shared machine moves a measurement by a quarter within seconds, and
another process on a core fall on both alike. The table
gives each revision's median rate and the median of the chunks' after/before ratios with its
interquartile range.

Run: SDL_VIDEODRIVER=offscreen .venv/bin/python benchmarks/bench_against.py [--base main] [--rounds 30]
     [--sizes 1,64,256] [--marl] [--metadrive] [--map FILE] [--observation DriverView]   (--sizes ""
     --marl: the multi-agent env alone; --metadrive: MetaDrive 0.4.3's single-agent env in each
     round, from /tmp/md-venv; --map: the single and batched envs on that map file,
     `feat2map/MapFile-v0`; --observation: every env with that observation type)
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
sys.path.insert(0, str(REPO / "benchmarks"))
from bench_marl import MD_PYTHON, MULTI  # noqa: E402  (benchmarks/ is the script's folder)

CONFIG = {"simulation_frequency": 20, "policy_frequency": 10, "traffic_vehicles": 9, "duration": 1e9,
          "route_junctions": 3}
CHUNK_ENV_STEPS = 300  # env-steps per measured chunk (a batched chunk: at least one step)
MARL_CHUNK_STEPS = 30  # multi-agent env steps per chunk (~20 agents each)
MD_CHUNK_STEPS = 100  # MetaDrive env steps per chunk
CPU = max(os.sched_getaffinity(0))  # every worker on this one CPU: they take turns on the same core and caches
WARM_UP_STEPS = 20  # steps before the first chunk (lane and pair tables)
IDLE = 1  # DiscreteMetaAction's IDLE
MARL_HOLD = 3  # the agents' TargetSpeed index held in the multi-agent measurement (bench_marl.py's HOLD: 5 m/s)

# a worker: makes its envs, then answers each request line [key, steps] with the rate of that
# chunk in CPU time (key 1: the single env's steps/s; N: the batched env's env-steps/s; "marl":
# the multi-agent env's agent-steps/s)
WORKER = r"""
import json, sys, time
import gymnasium as gym
import numpy as np
import feat2map

config, sizes, marl, hold, idle, warm = json.loads(sys.argv[1])
envs = {}
env_id = "feat2map/MapFile-v0" if "map_file" in config else "feat2map/JunctionGrid-v0"
for n in sizes:
    if n == 1:
        envs[n] = gym.make(env_id, config=config)
    else:
        envs[n] = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", config=config)
    envs[n].reset(seed=0)
if marl:
    from feat2map.envs import parallel_env
    envs["marl"] = parallel_env(marl)
    envs["marl"].reset(seed=0)


def run(key, steps):
    env = envs[key]
    if key == "marl":
        count = 0
        for _ in range(steps):
            if not env.agents:
                env.reset()
            count += len(env.agents)
            env.step({a: hold for a in env.agents})
        return count
    if key == 1:
        for _ in range(steps):
            *_, term, trunc, _ = env.step(idle)
            if term or trunc:
                env.reset()
        return steps
    action = np.full(key, idle)
    for _ in range(steps):
        env.step(action)
    return steps * key


for key in envs:
    run(key, warm)
print(json.dumps({"feat2map": feat2map.__file__}), flush=True)
for line in sys.stdin:
    key, steps = json.loads(line)
    t = time.process_time()
    count = run(key, steps)
    print(json.dumps(count / (time.process_time() - t)), flush=True)
"""

# MetaDrive 0.4.3's single-agent env as ../shared/tools/metadrive_bench.py drives it (3 blocks, traffic
# density 0.1, 10 Hz decisions, constant throttle): a worker answering [key, steps] with env-steps/s
MD_WORKER = r"""
import json, sys, time
from metadrive.envs.metadrive_env import MetaDriveEnv
env = MetaDriveEnv(dict(num_scenarios=10, start_seed=0, traffic_density=0.1, use_render=False, log_level=50, map=3))
env.reset()
for _ in range(int(sys.argv[1])):
    env.step([0.0, 0.5])
print(json.dumps({"metadrive": True}), flush=True)
for line in sys.stdin:
    _, steps = json.loads(line)
    t = time.process_time()
    for _ in range(steps):
        o, r, te, tr, i = env.step([0.0, 0.5])
        if te or tr:
            env.reset()
    print(json.dumps(steps / (time.process_time() - t)), flush=True)
"""


class Worker:
    """A measuring process: `rate(key, steps)` asks it for one chunk."""

    def __init__(self, argv: list[str], env: dict, label: str) -> None:
        self.label = label
        self.err = tempfile.TemporaryFile(mode="w+")  # a file, not a pipe: warnings never fill it and block the worker
        self.proc = subprocess.Popen(argv, env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=self.err, text=True, cwd=tempfile.gettempdir(),
                                     preexec_fn=lambda: os.sched_setaffinity(0, {CPU}))
        self.hello = json.loads(self._line())

    def _line(self) -> str:
        assert self.proc.stdout is not None
        line = self.proc.stdout.readline()
        if not line:
            self.proc.wait(timeout=60)
            self.err.seek(0)
            raise SystemExit(f"the {self.label} worker failed:\n{self.err.read()[-2000:]}")
        return line

    def rate(self, key: int | str, steps: int) -> float:
        assert self.proc.stdin is not None
        self.proc.stdin.write(json.dumps([key, steps]) + "\n")
        self.proc.stdin.flush()
        return float(json.loads(self._line()))

    def close(self) -> None:
        if self.proc.stdin is not None:
            self.proc.stdin.close()
        self.proc.wait(timeout=60)
        self.err.close()


def feat2map_worker(pythonpath: Path | None, sizes: list[int], marl: dict | None, label: str,
                    config: dict) -> Worker:
    env = dict(os.environ, SDL_VIDEODRIVER="offscreen")
    env.pop("PYTHONPATH", None)
    if pythonpath is not None:
        env["PYTHONPATH"] = str(pythonpath)
    args = [config, sizes, marl, MARL_HOLD, IDLE, WARM_UP_STEPS]
    return Worker([sys.executable, "-c", WORKER, json.dumps(args)], env, label)


def base_checkout(rev: str, where: Path) -> Path:
    """`rev` checked out at `where`, importable as the package `feat2map` from `where`."""
    subprocess.run(["git", "-C", str(REPO), "worktree", "add", "--detach", "-q", str(where), rev], check=True)
    for sub in ("envs", "scenarios"):
        (where / "feat2map" / sub).symlink_to(where / sub, target_is_directory=True)
    return where


def chunk_steps(key: int | str) -> int:
    return MARL_CHUNK_STEPS if key == "marl" else CHUNK_ENV_STEPS if key == 1 else max(1, CHUNK_ENV_STEPS // int(key))


def quartiles(xs: list[float]) -> tuple[float, float, float]:
    q = statistics.quantiles(xs, n=4) if len(xs) > 1 else [xs[0]] * 3
    return q[0], statistics.median(xs), q[2]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", default="main", help="the revision to compare with (default: main)")
    ap.add_argument("--rounds", type=int, default=30, help="alternating rounds of short chunks (default: 30)")
    ap.add_argument("--sizes", default="1,64,256", help="1: the single env; N > 1: the batched env (default: 1,64,256)")
    ap.add_argument("--marl", action="store_true", help="the multi-agent env's agent-steps/s too (bench_marl.py's scene)")
    ap.add_argument("--metadrive", action="store_true",
                    help="MetaDrive 0.4.3's single-agent env in each round too (/tmp/md-venv: "
                         "../shared/tools/metadrive-venv.sh), and the single env's ratio to it")
    ap.add_argument("--map", help="a map file the single and batched envs drive (default: the generated default map)")
    ap.add_argument("--observation", default="Kinematics",
                    help="the observation type of every env measured (default: Kinematics; DriverView: the "
                         "observation PPO and the multi-agent example train on)")
    args = ap.parse_args()
    config = {**CONFIG, "map_file": str(Path(args.map).resolve())} if args.map else dict(CONFIG)
    if args.observation != "Kinematics":
        config["observation"] = {"type": args.observation}
    sizes = [int(s) for s in args.sizes.split(",") if s]
    if args.metadrive and 1 not in sizes:
        ap.error("--metadrive compares the single env: --sizes must hold 1")
    if args.metadrive and not MD_PYTHON.exists():
        raise SystemExit("MetaDrive is not installed: make /tmp/md-venv with ../shared/tools/metadrive-venv.sh")
    # bench_marl.py's scene, made in this checkout, with the observation asked
    marl = {**MULTI, **{k: v for k, v in config.items() if k == "observation"}} if args.marl else None
    keys: list[int | str] = [*sizes, *(["marl"] if marl else [])]
    rates: dict[str, dict[int | str, list[float]]] = {k: {n: [] for n in keys} for k in ("before", "after")}
    metadrive: list[float] = []
    with tempfile.TemporaryDirectory(prefix="bench-against-") as tmp:
        base = base_checkout(args.base, Path(tmp) / "base")
        workers: dict[str, Worker] = {}
        try:
            workers["before"] = feat2map_worker(base, sizes, marl, "before", config)
            workers["after"] = feat2map_worker(None, sizes, marl, "after", config)
            for label in ("before", "after"):
                where = Path(workers[label].hello["feat2map"]).parent
                assert (where.resolve() == (base / "feat2map").resolve()) == (label == "before"), where
            if args.metadrive:
                workers["metadrive"] = Worker([str(MD_PYTHON), "-c", MD_WORKER, str(WARM_UP_STEPS)],
                                              dict(os.environ), "MetaDrive")
            for r in range(args.rounds):
                order = ("before", "after") if r % 2 == 0 else ("after", "before")
                for n in keys:
                    for label in order:
                        rates[label][n].append(workers[label].rate(n, chunk_steps(n)))
                if args.metadrive:
                    metadrive.append(workers["metadrive"].rate(1, MD_CHUNK_STEPS))
                if (r + 1) % 5 == 0 or r + 1 == args.rounds:
                    print(f"  round {r + 1} of {args.rounds}", file=sys.stderr, flush=True)
        finally:
            for w in workers.values():
                w.close()
            subprocess.run(["git", "-C", str(REPO), "worktree", "remove", "--force", str(base)], check=False)
    print(f"env-steps/s of CPU time, {args.rounds} alternating chunks each (before: {args.base}; after: this "
          f"checkout); 10 Hz, 10 vehicles per sub-env, {args.map or 'default map'}, {args.observation} observation" +
          ("; multi-agent: agent-steps/s, bench_marl.py's scene" if marl else ""))
    print(f"{'setup':>12} {'before':>9} {'after':>9} {'after/before':>13}  (quartiles of the chunks' ratios)")
    for n in keys:
        b, a = statistics.median(rates["before"][n]), statistics.median(rates["after"][n])
        lo, mid, hi = quartiles([x / y for x, y in zip(rates["after"][n], rates["before"][n])])
        name = "multi-agent" if n == "marl" else "single" if n == 1 else f"N = {n}"
        print(f"{name:>12} {b:>9.0f} {a:>9.0f} {mid:>12.2f}x  ({lo:.2f}-{hi:.2f})")
    if metadrive:
        print(f"MetaDrive 0.4.3 single-agent env: {statistics.median(metadrive):.0f} env-steps/s")
        for label in ("before", "after"):
            lo, mid, hi = quartiles([x / y for x, y in zip(rates[label][1], metadrive)])
            print(f"  {label}: {mid:.2f}x MetaDrive ({lo:.2f}-{hi:.2f}, the chunks' ratios in the same round)")
    for label in ("before", "after"):
        if 1 in sizes and len(sizes) > 1:
            single = statistics.median(rates[label][1])
            print(f"{label}: " + ", ".join(f"N = {n}: {statistics.median(rates[label][n]) / single:.2f}x the single env"
                                          for n in sizes if n > 1))


if __name__ == "__main__":
    main()
