"""Agent-steps per second of the multi-agent env (feat2map.envs.parallel_env) with ~20 agents on a
4-way signalled junction, against the single env (feat2map/JunctionGrid-v0: one agent) on the same
map, and against MetaDrive's MultiAgentIntersectionEnv (30 agents) where its scratch venv exists
(/work/shared/tools/metadrive-venv.sh makes /tmp/md-venv; never a feat2map dependency).

Scene: one generated 4-way signalled junction with 150 m approaches; `AGENTS` agents per
episode on the map's route-coverage routes (every manoeuvre), up to 3 queued per approach, so
that ~20 are on the road at once (MetaDrive's bench keeps ~22 of its 30; agents waiting for a
free place enter as others leave); no other traffic or pedestrians (MetaDrive's intersection
has only its agents); decisions at 10 Hz
(2 simulation frames of 50 ms; MetaDrive: 5 physics steps of 20 ms per decision), each agent
holding a 5 m/s target speed (TargetSpeed action; MetaDrive's bench: constant throttle);
Kinematics observations (10 vehicles x 7 features) for every agent. An episode ends when no
agent is left (or after 60 s) and the next one starts; resets count in the time.

With `--worlds W` (W > 1) a third runner steps the multi-agent env with W worlds of that scene in
one simulation (`worlds` config key: one arrays core, the frame of all worlds in one call), as
training does; its agent-steps/s count the agents of every world.

Measured in one process, interleaved rounds (median), CPU time of this process (the machine is
shared: other jobs' load stretches wall time, not CPU time), wall clock beside it; MetaDrive runs
in a subprocess between the rounds and reports its own CPU and wall rates the same way.

Run: SDL_VIDEODRIVER=offscreen nice -n 10 .venv/bin/python benchmarks/bench_marl.py [--rounds N] [--steps N]
     [--worlds W]
"""
from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym  # noqa: E402

import feat2map  # noqa: E402
from feat2map.envs import parallel_env  # noqa: E402

AGENTS = 60  # per episode; ~20 on the road at once
HOLD = 3  # TargetSpeed index of 5 m/s
SCENE = {"features": [feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False).to_dict()],
         "generation": {"grid_gap": 400.0, "stub_length": 150.0}, "traffic_vehicles": 0, "pedestrian_rate": 0.0,
         "simulation_frequency": 20, "policy_frequency": 10, "duration": 60.0}
MULTI = {**SCENE, "agents": AGENTS, "agent_queue": 3, "agent_routes": "coverage"}
SINGLE = {**SCENE, "route_junctions": 1, "action": {"type": "DiscreteMetaAction", "longitudinal": True,
                                                    "lateral": False, "target_speeds": [0.0, 2.5, 5.0]}}
MD_PYTHON = Path("/tmp/md-venv/bin/python")
MD_CODE = """
import time
from metadrive.envs.marl_envs import MultiAgentIntersectionEnv
env = MultiAgentIntersectionEnv(dict(num_agents=30, use_render=False, log_level=50))
env.reset()
n = agent_steps = 0
t, c = time.perf_counter(), time.process_time()
while n < {steps}:
    o, r, te, tr, i = env.step({{k: [0.0, 0.5] for k in env.agents}})
    n += 1; agent_steps += len(o)
    if te.get("__all__") or tr.get("__all__"): env.reset()
w, c = time.perf_counter() - t, time.process_time() - c
print(agent_steps / c, agent_steps / w, agent_steps / n)
env.close()
"""


class MultiRunner:
    def __init__(self, worlds: int = 1) -> None:
        self.env = parallel_env({**MULTI, "worlds": worlds})
        self.env.reset(seed=0)
        self.cpu: list[float] = []
        self.wall: list[float] = []
        self.per_step: list[float] = []
        self.episodes = 0

    def round(self, steps: int) -> None:
        env = self.env
        n = 0
        t, w = time.process_time(), time.perf_counter()
        for _ in range(steps):
            if not env.agents:
                env.reset()
                self.episodes += 1
            acts = {a: HOLD for a in env.agents}
            env.step(acts)
            n += len(acts)
        self.cpu.append(n / max(time.process_time() - t, 1e-9))
        self.wall.append(n / (time.perf_counter() - w))
        self.per_step.append(n / steps)


class SingleRunner:
    def __init__(self) -> None:
        self.env = gym.make("feat2map/JunctionGrid-v0", config=SINGLE)
        self.env.reset(seed=0)
        self.cpu: list[float] = []
        self.wall: list[float] = []

    def round(self, steps: int) -> None:
        env = self.env
        t, w = time.process_time(), time.perf_counter()
        for _ in range(steps):
            _, _, term, trunc, _ = env.step(2)
            if term or trunc:
                env.reset()
        self.cpu.append(steps / max(time.process_time() - t, 1e-9))
        self.wall.append(steps / (time.perf_counter() - w))


def metadrive_run(code: str, values: int) -> tuple[float, ...] | None:
    """The last `values` numbers `code` prints, run by MetaDrive's venv (/tmp/md-venv), or None
    when it is absent or the run fails."""
    if not MD_PYTHON.exists():
        return None
    try:
        out = subprocess.run([str(MD_PYTHON), "-c", code], capture_output=True, text=True,
                             timeout=900, check=True).stdout.split()
        return tuple(float(x) for x in out[-values:])
    except (subprocess.SubprocessError, ValueError, IndexError, OSError):
        return None


def metadrive_round(steps: int) -> tuple[float, ...] | None:
    """(agent-steps/s CPU, wall, agents per step) of MetaDrive's multi-agent intersection, or None."""
    return metadrive_run(MD_CODE.format(steps=steps), 3)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--steps", type=int, default=300, help="env steps per round")
    ap.add_argument("--no-metadrive", action="store_true")
    ap.add_argument("--worlds", type=int, default=1, help="also measure the env with this many worlds (> 1)")
    args = ap.parse_args(argv)
    load0 = os.getloadavg()[0]
    multi, single, md = MultiRunner(), SingleRunner(), []
    many = MultiRunner(args.worlds) if args.worlds > 1 else None
    for runner in (multi, many):
        if runner is not None:
            runner.round(20)  # warm-up: lane tables, pair tables
            runner.cpu.clear(), runner.wall.clear(), runner.per_step.clear()
    for _ in range(args.rounds):
        multi.round(args.steps)
        single.round(args.steps)
        if many is not None:
            many.round(max(1, args.steps // args.worlds))
        if not args.no_metadrive:
            r = metadrive_round(args.steps)
            if r is not None:
                md.append(r)
    med = statistics.median
    lines = [f"agent-steps/s (median of {args.rounds} interleaved rounds of {args.steps} env steps; CPU time of the "
             f"process, wall clock in brackets); 1-min load average {load0:.1f} at the start, "
             f"{os.getloadavg()[0]:.1f} at the end",
             f"  feat2map multi-agent, 4-way signal:   {med(multi.cpu):8.0f}  ({med(multi.wall):8.0f} wall)  "
             f"{med(multi.per_step):.1f} agents/step, {multi.episodes} episode ends",
             f"  feat2map single env, same junction:   {med(single.cpu):8.0f}  ({med(single.wall):8.0f} wall)  "
             f"1 agent/step",
             f"  multi-agent / single env:             {med(multi.cpu) / med(single.cpu):8.1f}x "
             f"({med(multi.wall) / med(single.wall):.1f}x wall)"]
    if many is not None:
        lines += [f"  feat2map multi-agent, {args.worlds} worlds:{'':>{max(0, 9 - len(str(args.worlds)))}}"
                  f"{med(many.cpu):8.0f}  ({med(many.wall):8.0f} wall)  {med(many.per_step):.1f} agents/step",
                  f"  {args.worlds} worlds / one world:{'':>{max(0, 13 - len(str(args.worlds)))}}"
                  f"{med(many.cpu) / med(multi.cpu):8.1f}x ({med(many.wall) / med(multi.wall):.1f}x wall)"]
    if md:
        cpu, wall, per = med([r[0] for r in md]), med([r[1] for r in md]), med([r[2] for r in md])
        lines += [f"  MetaDrive MultiAgentIntersectionEnv:  {cpu:8.0f}  ({wall:8.0f} wall)  {per:.1f} agents/step",
                  f"  feat2map multi-agent / MetaDrive:     {med(multi.cpu) / cpu:8.1f}x "
                  f"({med(multi.wall) / wall:.1f}x wall)"]
        if many is not None:
            lines.append(f"  {args.worlds} worlds / MetaDrive:{'':>{max(0, 14 - len(str(args.worlds)))}}"
                         f"{med(many.cpu) / cpu:8.1f}x ({med(many.wall) / wall:.1f}x wall)")
    elif args.no_metadrive:
        lines.append("  MetaDrive: not measured (--no-metadrive)")
    else:
        lines.append("  MetaDrive: not measured (no /tmp/md-venv: run /work/shared/tools/metadrive-venv.sh)")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
