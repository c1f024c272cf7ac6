"""Train a Stable-Baselines3 PPO ego on every junction type of a generated grid, then evaluate it
per (junction type, manoeuvre) against the rule-following ScriptedDriver.

The map holds one junction per (road count n, control, crosswalk) combination and a motorway
ramp junction (RAMP_JUNCTION: an on- and an off-ramp). Each episode is one sampled manoeuvre
through one junction with traffic and crosswalk pedestrians (the env's sampled routes: the ramp
junction's merge and diverge are drawn as often as its entry lanes are among all junctions').
Cells: left / straight / right at each junction without ramps, merge (on-ramp onto the main
road) / diverge (main road onto the off-ramp) at the ramp junction.
- Action: a target speed (TARGET_SPEEDS) at 2 Hz; the `TargetSpeed` wrapper turns it into the
  constant acceleration that reaches it by the next decision (bounded), steering follows the
  route. Braking to 0 from a creeping speed stops within a metre, so the 6 m stop zone is easy to hit.
- Observation: the env's `DriverView` (envs/driver_view.py): ego speed, distance to the stop line
  (fine near it), control, manoeuvre (left, straight, right, merge, diverge), signal colour and
  time to change, protected movement, full stop made, arrival-order queue, conflicting junction
  traffic with and without priority, pedestrians in the path, the leader.
- Reward (`TaskRewards` on the env's terms): route progress (1 for the route) + 1 on arrival,
  FAILURE_PENALTY for a collision, leaving the road or a violation, each ending the episode (as
  they end a success); +STOP_BONUS once when the ego drives on into the junction after its full
  stop at a stop sign (not for the stop itself: see `shaped_reward`); -TIME_COST per decision,
  so that waiting is never free and standing at the line until the time limit pays less than
  nothing; near misses (`near_miss_cost`): -ENTRY_COST for entering the junction while the
  decision before saw a conflicting lane taken, and a charge for speed a pedestrian's stop point
  ahead leaves no comfortable room to brake from.
- Training: PPO on `--n-envs` sub-envs of the native batched vector env (envs/vector.py: the
  traffic of a process's sub-envs in one array program), in the training process or split over
  `--workers` processes that step at once (envs/sb3.py; on the project's 2-core machine two
  workers step the batch 1.15x as fast but train no faster: PPO's updates and the policy's
  actions run between the steps; `--subprocess` for a copy of the single env per subprocess
  instead), torch single-threaded in every process, for `--train-minutes` of wall
  time (or `--timesteps`, whichever ends first); each training episode draws its traffic count
  from TRAIN_TRAFFIC and its pedestrian rate from TRAIN_PEDESTRIANS.
- Evaluation: `--episodes-per-cell` episodes per (junction type, manoeuvre) cell from fixed seeds
  that training never draws (EVAL_SEED on), for PPO (deterministic) and the ScriptedDriver, in
  parallel processes.

Printed: the per-cell table, wall times of training and evaluation, the machine's load. Written
to OUT: `summary.md` (the block of examples/README.md), `success.csv` / `success.md` (per cell:
episodes, success, mean return of PPO and the scripted driver, PPO's failures by kind),
`success.png` (heat maps), `learning_curve.csv` / `learning_curve.png` (training episodes'
success and return against steps and wall time), `ppo_model.zip`, `run.json` (sizes, wall
times, load).

A success is a completed route without collision, leaving the road or any rule violation.

Run: .venv/bin/python examples/train_ppo.py --out out/ppo
Needs the `rl` extra: bash scripts/setup.sh rl
Progress: a bar on a terminal, a line every PROGRESS_LINE_S seconds otherwise (stderr).
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import multiprocessing as mp
import os
import sys
import time
from collections import defaultdict
from dataclasses import asdict, dataclass, field, replace
from functools import partial
from pathlib import Path
from typing import Callable, Sequence

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym  # noqa: E402
from gymnasium.vector import AutoresetMode  # noqa: E402
import numpy as np  # noqa: E402

import feat2map  # noqa: E402  (registers the feat2map/ environment ids)
from feat2map import atomic  # noqa: E402
from feat2map.config import (AGENT_ACCELERATION_RANGE, AGENT_TARGET_SPEEDS, DRIVER_VIEW_PEDESTRIAN_SCALE_M,  # noqa: E402
                             DRIVER_VIEW_SPEED_SCALE_MPS, RAMP_MANOEUVRES)
from feat2map.extract_ramps import ramp_moves  # noqa: E402
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver  # noqa: E402
from feat2map.envs.driver_view import DRIVER_VIEW_FEATURES  # noqa: E402
from feat2map.envs.junction_env import JunctionGridEnv  # noqa: E402
from feat2map.envs.sb3 import sb3_vec_env, sb3_workers  # noqa: E402
from feat2map.envs.vector import MapVectorEnv, info_of  # noqa: E402
from feat2map.envs.rules import manoeuvre_name  # noqa: E402
from feat2map.features import ramp_junction  # noqa: E402
from feat2map.render import save_figure  # noqa: E402

ROAD_ANGLES = {3: (0, 90, 180), 4: (0, 90, 180, 270)}
CONTROLS = ("signal", "stop", "bare")
MANOEUVRES = ("left", "straight", "right")  # the cells of a junction without ramps
RAMP_ANGLE_DEG = 15.0  # the ramps' angle from the main road
RAMP_JUNCTION = ramp_junction("both", RAMP_ANGLE_DEG)  # an on- and an off-ramp: the merge and diverge cells
RAMP_LABELS = {"on": "on-ramp", "off": "off-ramp", "both": "on- and off-ramp"}  # by JunctionFeature.ramp_value
RAMP_CELLS = tuple(RAMP_MANOEUVRES.values())  # the cells of a ramp junction: "merge", "diverge"
COLUMNS = MANOEUVRES + RAMP_CELLS  # the per-cell tables' manoeuvres
FAILURES = ("collision", "off_road", "red_light", "stop_sign", "pedestrian_yield", "timeout")

TARGET_SPEEDS = AGENT_TARGET_SPEEDS  # [m/s] the agent's actions (the multi-agent env's default too)
ACCELERATION_RANGE = AGENT_ACCELERATION_RANGE  # [m/s2] the TargetSpeed wrapper's bounds
DECISION_HZ = 2
#: What the agent sees and does: the driver's view of the rules; longitudinal acceleration
#: (steering follows the route), set by the TargetSpeed wrapper.
AGENT_CONFIG = {"observation": {"type": "DriverView"}, "action": DRIVER_ACTION_CONFIG,
                "policy_frequency": DECISION_HZ, "simulation_frequency": 10}
#: The task: one junction per route, traffic and pedestrians; the env's reward terms (the
#: wrapper ends the episode on a violation, as it ends a success).
#: A failure's reward. Five seeds' models re-evaluated on 40 episodes a cell (7,600 episodes each
#: way) failed 1.97% of them with -5 (16 red lights run, 95 collisions) and 1.54% with this (2 red
#: lights, 88 collisions).
FAILURE_PENALTY = -10.0
TASK_CONFIG = {
    "route_junctions": 1, "duration": 60.0, "traffic_vehicles": 4, "pedestrian_rate": 3.0,
    "reward_progress": 1.0, "reward_arrived": 1.0,
    **{f"reward_{k}": FAILURE_PENALTY for k in ("collision", "red_light", "stop_sign", "pedestrian_yield", "off_road")},
}
TRAIN_TRAFFIC = (2, 8)  # training episodes draw their traffic count from this range (evaluation: 4)
#: [per crosswalk and minute] training episodes draw their pedestrian rate from this range
#: (evaluation: 3): crossings and the waits they make are met more often. With the evaluation's rate
#: in training, seeds 2-4 left 4 / 2 / 2 cells below 0.9 (31 failures, 15 of them red lights run);
#: with this range, 2 / 0 / 0 (14 failures, none a red light).
TRAIN_PEDESTRIANS = (3.0, 12.0)
STOP_BONUS = 0.3
TIME_COST = 0.01
#: Near misses the task pays for (`near_miss_cost`): entering a junction while the decision before
#: saw a conflicting lane occupied or reserved (DriverView's conflict_occupied), and each decision
#: that ends faster than the speed from which BRAKE_MPS2 stops the ego at a pedestrian's stop point.
#: Five seeds' models evaluated on 40 episodes a cell failed 1.09% of them with these against 1.54%
#: without (collisions 45 against 88); with ENTRY_COST 1.0 one seed's policy learned to stand at
#: clear bare junctions until the time limit.
ENTRY_COST = 0.5
LATE_BRAKE_COST = 1.0
BRAKE_MPS2 = 3.0
LOAD_SAMPLE_S = 30.0  # the machine's load average is sampled this often during training
PROGRESS_LINE_S = 60.0  # off a terminal (a log, CI), a progress line this often; on one, a bar
EVAL_SEED = 10_000  # first seed of the evaluation episodes (training envs are seeded below it)
STOP_MADE = DRIVER_VIEW_FEATURES.index("stop_made")
IN_JUNCTION, OCCUPIED, PEDESTRIAN, SPEED = (DRIVER_VIEW_FEATURES.index(k) for k in
                                            ("in_junction", "conflict_occupied", "pedestrian", "speed"))

Policy = Callable[[object, gym.Env], object]  # (observation, env) -> action


def junction_features(ns: Sequence[int] = (3, 4), controls: Sequence[str] = CONTROLS,
                      crosswalks: Sequence[bool] = (True, False)) -> list[feat2map.JunctionFeature]:
    """One feature per (road count, control, crosswalk) combination."""
    return [feat2map.JunctionFeature.make(list(ROAD_ANGLES[n]), c, cw)
            for n in ns for c in controls for cw in crosswalks]


def task_features() -> tuple[feat2map.JunctionFeature, ...]:
    """The map's junctions: every `junction_features()` combination and RAMP_JUNCTION."""
    return (*junction_features(), RAMP_JUNCTION)


def cell_manoeuvres(feature: feat2map.JunctionFeature) -> tuple[str, ...]:
    """The manoeuvres evaluated at a junction of `feature`: merge and diverge at a ramp junction
    (its main lanes and on-ramp to off-ramp lane are driven in training only), else the turns."""
    return RAMP_CELLS if feature.has_ramp else MANOEUVRES


def env_config(features: Sequence[feat2map.JunctionFeature], map_seed: int = 0, **overrides) -> dict:
    """Config of feat2map/JunctionGrid-v0 for the agent on a map of `features`."""
    return {**AGENT_CONFIG, **TASK_CONFIG, "features": [f.to_dict() for f in features],
            "map_seed": map_seed, **overrides}


class TargetSpeed(gym.ActionWrapper):
    """Discrete target speeds over the env's longitudinal ContinuousAction: the constant
    acceleration (within ACCELERATION_RANGE) that reaches the chosen speed by the next decision."""

    def __init__(self, env: gym.Env, speeds: Sequence[float] = TARGET_SPEEDS) -> None:
        super().__init__(env)
        self.speeds = tuple(speeds)
        self.action_space = gym.spaces.Discrete(len(self.speeds))
        u = env.unwrapped
        self.period = 1.0 / u.config["policy_frequency"]
        self.lo, self.hi = u.action_type.acceleration_range

    def action(self, action) -> np.ndarray:
        v = self.env.unwrapped.vehicle.speed
        return np.array([speed_command(self.speeds[int(action)], v, self.period, self.lo, self.hi)], dtype=np.float32)


def speed_command(target, speed, period: float, lo: float, hi: float):
    """The normalized longitudinal action (ContinuousAction's [-1, 1] over [lo, hi]) of the
    constant acceleration, within ACCELERATION_RANGE, that takes `speed` to `target` in
    `period` (scalars or arrays: one env or a batch)."""
    a = np.clip((target - speed) / period, *ACCELERATION_RANGE)
    return 2 * (a - lo) / (hi - lo) - 1


def shaped_reward(r, stopped, was_stopped, failed=False):
    """The task's shaping of the env's reward (scalars or arrays): +STOP_BONUS when the ego
    drives on into the junction after its full stop at a stop sign (DriverView's stop_made
    turning off) without a violation or collision (`failed`), -TIME_COST per decision.

    Paid on the way in, not when the stop is made: a bonus for the stop itself made standing at
    the line look good to the policy, and a greedy (deterministic) policy stayed there until the
    episode timed out."""
    entered = np.logical_and(was_stopped, np.logical_not(stopped))
    return r + STOP_BONUS * np.logical_and(entered, np.logical_not(failed)) - TIME_COST


def near_miss_cost(before, after):
    """What the task charges for a decision from DriverView `before` to `after` (one observation
    or a batch of rows), whatever it ended in: ENTRY_COST for entering the junction
    while `before` saw a conflicting lane occupied or reserved (the conflict rule holds a driver
    there), and LATE_BRAKE_COST per DRIVER_VIEW_SPEED_SCALE_MPS of speed over the speed from which
    BRAKE_MPS2 stops the ego at the stop point a pedestrian makes (`after`). Both are what a
    collision or a pedestrian not yielded to follows from, met far more often than those are."""
    before, after = np.asarray(before), np.asarray(after)
    entry = (before[..., IN_JUNCTION] < 0.5) & (after[..., IN_JUNCTION] > 0.5) & (before[..., OCCUPIED] > 0.5)
    near = after[..., PEDESTRIAN] < 1.0
    stop_m = np.maximum(after[..., PEDESTRIAN], 0.0) * DRIVER_VIEW_PEDESTRIAN_SCALE_M
    over = after[..., SPEED] * DRIVER_VIEW_SPEED_SCALE_MPS - np.sqrt(2.0 * BRAKE_MPS2 * stop_m)
    late = np.where(near, np.maximum(over, 0.0) / DRIVER_VIEW_SPEED_SCALE_MPS, 0.0)
    return ENTRY_COST * entry + LATE_BRAKE_COST * late


class TaskRewards(gym.Wrapper):
    """The task's shaping on top of the env's reward (`shaped_reward`: +STOP_BONUS on driving
    on after the full stop at a stop sign, -TIME_COST per decision; `near_miss_cost`); a
    violation ends the episode (it already ends a success)."""

    def reset(self, **kwargs):
        obs, info = self.env.reset(**kwargs)
        self._obs = obs
        return obs, info

    def step(self, action):
        obs, r, term, trunc, info = self.env.step(action)
        stopped = obs[STOP_MADE] > 0.5
        failed = bool(info["new_violations"]) or bool(info["collision"])
        r = shaped_reward(r, stopped, self._obs[STOP_MADE] > 0.5, failed) - float(near_miss_cost(self._obs, obs))
        self._obs = obs
        return obs, r, term or bool(info["new_violations"]), trunc, info


def episode_draw(rng: np.random.Generator, traffic: tuple[int, int] | None,
                 pedestrians: tuple[float, float] | None) -> dict:
    """One training episode's config draws: its traffic count from `traffic` and its pedestrian
    rate from `pedestrians` (none without a range), so that the agent meets conflicting traffic
    and crossings more often (and sparser scenes too) than at the evaluation's fixed values."""
    out: dict = {}
    if traffic is not None:
        out["traffic_vehicles"] = int(rng.integers(traffic[0], traffic[1] + 1))
    if pedestrians is not None:
        out["pedestrian_rate"] = float(rng.uniform(*pedestrians))
    return out


class TrafficRange(gym.Wrapper):
    """Training only: each episode draws its traffic count and pedestrian rate (`episode_draw`)."""

    def __init__(self, env: gym.Env, traffic: tuple[int, int] | None, pedestrians: tuple[float, float] | None) -> None:
        super().__init__(env)
        self.traffic, self.pedestrians = traffic, pedestrians
        self._rng = np.random.default_rng()

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            self._rng = np.random.default_rng(seed + 1)
        self.env.unwrapped.configure(episode_draw(self._rng, self.traffic, self.pedestrians))
        return self.env.reset(seed=seed, options=options)


class BatchedTask(gym.vector.VectorWrapper):
    """The agent's task on the native batched vector env (same-step autoreset), as array
    operations over the sub-envs: TargetSpeed's action, TaskRewards' shaping and its end of an
    episode on a violation (those sub-envs are reset through `reset_mask`), each episode's draws
    (`episode_draw`, made when the episode before it starts)."""

    def __init__(self, venv, traffic: tuple[int, int] | None = None, speeds: Sequence[float] = TARGET_SPEEDS,
                 pedestrians: tuple[float, float] | None = None) -> None:
        super().__init__(venv)
        self.subs = venv.unwrapped.envs
        u = self.subs[0]
        self.speeds = np.asarray(speeds, dtype=float)
        self.period = 1.0 / u.config["policy_frequency"]
        self.lo, self.hi = u.action_type.acceleration_range
        self.single_action_space = gym.spaces.Discrete(len(self.speeds))
        self.action_space = gym.spaces.MultiDiscrete([len(self.speeds)] * self.num_envs)
        self.traffic, self.pedestrians = traffic, pedestrians
        self._rngs = [np.random.default_rng() for _ in self.subs]
        self._obs = np.zeros((self.num_envs, *self.single_observation_space.shape))  # (the last observations)

    def _draw(self, which) -> None:
        if self.traffic is not None or self.pedestrians is not None:
            for i in np.nonzero(which)[0].tolist():
                self.subs[i].configure(episode_draw(self._rngs[i], self.traffic, self.pedestrians))

    def reset(self, *, seed=None, options=None):
        if seed is not None:
            seeds = [seed + k for k in range(self.num_envs)] if isinstance(seed, int) else seed
            self._rngs = [np.random.default_rng(None if s is None else s + 1) for s in seeds]
        everyone = np.ones(self.num_envs, dtype=bool)
        self._draw(everyone)
        obs, info = self.env.reset(seed=seed, options=options)
        self._draw(everyone)  # the next episode's count
        self._obs = obs
        return obs, info

    def step(self, actions):
        speeds = np.array([e.vehicle.speed for e in self.subs])
        command = speed_command(self.speeds[np.asarray(actions)], speeds, self.period, self.lo, self.hi)
        obs, r, term, trunc, info = self.env.step(command[:, None].astype(np.float32))
        done = term | trunc
        last = obs.copy()
        for i in np.nonzero(done)[0].tolist():
            last[i] = info["final_obs"][i]
        new = [info["final_info"]["new_violations"][i] if done[i] else info["new_violations"][i]
               for i in range(self.num_envs)]
        hit = [info["final_info"]["collision"][i] if done[i] else info["collision"][i] for i in range(self.num_envs)]
        stopped = last[:, STOP_MADE] > 0.5
        r = shaped_reward(r, stopped, self._obs[:, STOP_MADE] > 0.5, np.array([bool(v) or bool(h) for v, h in zip(new, hit)]))
        r = r - near_miss_cost(self._obs, last)
        ended = np.array([bool(v) for v in new]) & ~done  # a violation ends the task's episode
        if ended.any():
            for i in np.nonzero(ended)[0].tolist():
                info = self.env.unwrapped._add_info(info, {"final_obs": obs[i], "final_info": info_of(info, i)}, i)
            obs, _ = self.env.reset(options={"reset_mask": ended})
            term = term | ended
        self._draw(done | ended)
        self._obs = obs
        return obs, r, term, trunc, info


def make_env(config: dict, agent: bool = True, traffic: tuple[int, int] | None = None,
             pedestrians: tuple[float, float] | None = None) -> gym.Env:
    """The env of `config`; with `agent`, wrapped into the agent's task (target speeds, rewards);
    with `traffic` or `pedestrians` (training), a traffic count and a pedestrian rate drawn per
    episode from those ranges (`episode_draw`)."""
    env = gym.make("feat2map/JunctionGrid-v0", config=config)
    if traffic is not None or pedestrians is not None:
        env = TrafficRange(env, traffic, pedestrians)
    return TaskRewards(TargetSpeed(env)) if agent else env


@dataclass(frozen=True)
class Outcome:
    """How one episode ended."""

    completed: bool
    collision: bool
    off_road: bool
    violations: int
    ret: float
    steps: int
    failure: str = ""  # the first of FAILURES that applies ("" for a success)

    @property
    def success(self) -> bool:
        return self.completed and not self.collision and not self.off_road and self.violations == 0


def run_episode(env: gym.Env, policy: Policy, seed: int, route=None) -> Outcome:
    """One episode from `seed` (on the explicit `route` if given, else a sampled one)."""
    env.unwrapped.configure({"route": [tuple(r) for r in route] if route else None})
    obs, info = env.reset(seed=seed)
    ret, steps = 0.0, 0
    while True:
        obs, r, term, trunc, info = env.step(policy(obs, env))
        ret += float(r)
        steps += 1
        if term or trunc:
            return outcome(info, ret, steps)


def outcome(info: dict, ret: float, steps: int) -> Outcome:
    """The Outcome of an episode from its last info."""
    v = info["violations"]
    flags = {"collision": info["collision"], "off_road": info["off_road"], **{k: v[k] > 0 for k in v},
             "timeout": not info["route_completed"]}
    failure = next((k for k in FAILURES if flags.get(k)), "")
    return Outcome(bool(info["route_completed"]), bool(info["collision"]), bool(info["off_road"]),
                   int(sum(v.values())), ret, steps, failure)


def model_policy(model) -> Policy:
    """A deterministic policy from an SB3 model."""
    return lambda obs, env: int(model.predict(obs, deterministic=True)[0])


def scripted_policy(obs, env: gym.Env):
    """The rule-following reference driver (on the env without the agent's wrappers)."""
    return ScriptedDriver(env).act()


def summarize(outcomes: Sequence[Outcome]) -> dict:
    n = max(len(outcomes), 1)
    fails = {k: sum(o.failure == k for o in outcomes) for k in FAILURES}
    return {"episodes": len(outcomes), "success": sum(o.success for o in outcomes) / n,
            "completed": sum(o.completed for o in outcomes) / n, "return": sum(o.ret for o in outcomes) / n,
            "collisions": sum(o.collision for o in outcomes), "violations": sum(o.violations for o in outcomes),
            "failures": fails}


@dataclass(frozen=True)
class Case:
    """One evaluation cell: a manoeuvre through a junction of a given type, with its routes."""

    n: int
    control: str
    crosswalk: bool
    ramp: str  # JunctionFeature.ramp_value: "none", or the ramps of a ramp junction
    manoeuvre: str
    routes: tuple[tuple[tuple[str, str, str], ...], ...]

    @property
    def key(self) -> tuple[int, str, bool, str, str]:
        return (self.n, self.control, self.crosswalk, self.ramp, self.manoeuvre)


def junction_type(row: dict) -> tuple[int, str, bool, str]:
    """The junction type of a table row: (n, control, crosswalk, ramp)."""
    return (row["n"], row["control"], row["crosswalk"], row["ramp"])


def type_label(t: tuple[int, str, bool, str]) -> str:
    """How the tables name junction type `t` (`junction_type`)."""
    n, control, crosswalk, ramp = t
    if ramp != "none":
        return f"ramp junction ({RAMP_LABELS[ramp]})"
    return f"n={n} {control}{', crosswalk' if crosswalk else ''}"


def junction_cases(hdmap) -> list[Case]:
    """One cell per junction and manoeuvre of it (`cell_manoeuvres`), with every (entry, exit)
    pair of it as a one-junction route."""
    cases = []
    ramps = ramp_moves(hdmap)
    for jid in sorted(hdmap.junctions, key=lambda j: (len(j), j)):
        f = hdmap.junctions[jid].feature
        by_turn: dict[str, list[tuple[str, str, str]]] = defaultdict(list)
        for ln in sorted(hdmap.lanes_by_junction.get(jid, []), key=lambda ln: ln.id):
            if not ln.predecessors or not ln.successors:
                continue
            turn = manoeuvre_name(ln, ramps)
            m = (jid, hdmap.lanes[ln.predecessors[0]].road_id, hdmap.lanes[ln.successors[0]].road_id)
            if m not in by_turn[turn]:
                by_turn[turn].append(m)
        for turn in cell_manoeuvres(f):
            if by_turn[turn]:
                cases.append(Case(len(f.sockets), f.control, f.crosswalk, f.ramp_value, turn,
                                  tuple((m,) for m in by_turn[turn])))
    return cases


# ---- evaluation in worker processes -------------------------------------------------------------
_WORKER: dict = {}


def _init_worker(config: dict, model_bytes: bytes | None) -> None:
    import torch
    from stable_baselines3 import PPO

    torch.set_num_threads(1)
    _WORKER["scripted"] = (make_env(config, agent=False), scripted_policy)
    if model_bytes is not None:
        model = PPO.load(io.BytesIO(model_bytes), device="cpu")
        _WORKER["ppo"] = (make_env(config), model_policy(model))


def _run_job(job: tuple[str, int, tuple, int]) -> tuple[str, int, Outcome]:
    name, case_index, route, seed = job
    env, policy = _WORKER[name]
    return name, case_index, run_episode(env, policy, seed, route)


class Progress:
    """Progress of `total` units: a tqdm bar on a terminal, else a line on stderr every
    PROGRESS_LINE_S seconds (and at the end), so that a log shows the run is alive."""

    def __init__(self, total: int, desc: str, unit: str, enabled: bool = True, minutes: float | None = None) -> None:
        self.total, self.desc, self.unit, self.n, self.minutes = total, desc, unit, 0, minutes
        self.terminal = enabled and sys.stderr.isatty()
        self.lines = enabled and not self.terminal
        self.t0 = self.t_line = time.perf_counter()
        self.postfix: dict[str, object] = {}
        self.bar = None
        if self.terminal:
            from tqdm import tqdm

            self.bar = tqdm(total=total, desc=desc, unit=unit, mininterval=5.0)

    def update(self, n: int = 1) -> None:
        self.n += n
        if self.bar is not None:
            self.bar.update(n)
        elif self.lines and time.perf_counter() - self.t_line >= PROGRESS_LINE_S:
            self.line()

    def set_postfix(self, **values: object) -> None:
        self.postfix = values
        if self.bar is not None:
            self.bar.set_postfix(**values)

    def line(self) -> None:
        """One progress line: done of total, elapsed wall time, the postfix values."""
        self.t_line = time.perf_counter()
        extra = "".join(f", {k} {v}" for k, v in self.postfix.items())
        budget = f" of {self.minutes:g}" if self.minutes else ""
        print(f"{self.desc}: {self.n:,} of {self.total:,} {self.unit}s, {(self.t_line - self.t0) / 60:.1f}{budget} min"
              f"{extra}", file=sys.stderr, flush=True)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()
        elif self.lines:
            self.line()


def evaluate_cases(config: dict, cases: Sequence[Case], model_bytes: bytes | None, episodes: int,
                   workers: int, progress: bool = True) -> tuple[list[dict], dict]:
    """Per cell, `episodes` episodes (its routes in turn, seeds EVAL_SEED + i) of PPO (when
    `model_bytes`) and the scripted driver, over `workers` processes: one table row per cell,
    and each policy's summary over all cells."""
    names = ["ppo", "scripted"] if model_bytes is not None else ["scripted"]
    jobs = [(name, ci, c.routes[i % len(c.routes)], EVAL_SEED + i)
            for ci, c in enumerate(cases) for i in range(episodes) for name in names]
    results: dict[int, dict[str, list[Outcome]]] = defaultdict(lambda: defaultdict(list))
    bar = Progress(len(jobs), "evaluating", "episode", progress)
    if workers > 1:
        with mp.get_context("fork").Pool(workers, _init_worker, (config, model_bytes)) as pool:
            for name, ci, o in pool.imap_unordered(_run_job, jobs, chunksize=4):
                results[ci][name].append(o)
                bar.update()
    else:
        _init_worker(config, model_bytes)
        for job in jobs:
            name, ci, o = _run_job(job)
            results[ci][name].append(o)
            bar.update()
    bar.close()
    rows = []
    for ci, c in enumerate(cases):
        row = {"n": c.n, "control": c.control, "crosswalk": c.crosswalk, "ramp": c.ramp, "manoeuvre": c.manoeuvre,
               "episodes": episodes}
        for name in names:
            s = summarize(results[ci][name])
            row.update({f"{name}_success": round(s["success"], 3), f"{name}_return": round(s["return"], 3)})
            if name == "ppo":
                row["ppo_failures"] = " ".join(f"{k}:{v}" for k, v in s["failures"].items() if v) or "-"
        rows.append(row)
    rows.sort(key=lambda r: (r["ramp"] != "none", r["n"], CONTROLS.index(r["control"]), not r["crosswalk"],
                             COLUMNS.index(r["manoeuvre"])))
    return rows, {name: summarize([o for ci in results for o in results[ci][name]]) for name in names}


def rows_csv(rows: Sequence[dict]) -> str:
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    return buf.getvalue()


def rows_markdown(rows: Sequence[dict]) -> str:
    cols = list(rows[0])
    lines = ["| " + " | ".join(cols) + " |", "|" + "---|" * len(cols)]
    lines += ["| " + " | ".join(str(r[c]) for c in cols) + " |" for r in rows]
    return "\n".join(lines) + "\n"


def plot_cells(rows: Sequence[dict], names: Sequence[str], path: Path) -> None:
    """Heat maps of success per junction type (rows) and manoeuvre (columns), one per policy."""
    import matplotlib.pyplot as plt  # headless: feat2map.render selected the Agg backend

    types = list(dict.fromkeys(junction_type(r) for r in rows))
    columns = [m for m in COLUMNS if any(r["manoeuvre"] == m for r in rows)]
    fig, axes = plt.subplots(1, len(names), figsize=(0.9 * len(columns) * len(names) + 2.4, 0.42 * len(types) + 1.6),
                             squeeze=False)
    for ax, name in zip(axes[0], names):
        grid = np.full((len(types), len(columns)), np.nan)
        for r in rows:
            grid[types.index(junction_type(r)), columns.index(r["manoeuvre"])] = r[f"{name}_success"]
        ax.imshow(grid, cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, "–" if np.isnan(v) else f"{v:.2f}", ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(columns)), columns, fontsize=8)
        ax.set_yticks(range(len(types)), [type_label(t) for t in types], fontsize=8)
        ax.set_title(f"success: {name} ({rows[0]['episodes']} episodes per cell)", fontsize=9)
        if ax is not axes[0][0]:
            ax.set_yticklabels([])
    fig.tight_layout()
    save_figure(fig, path)


def plot_curve(curve: Sequence[dict], path: Path, window: int = 200) -> None:
    """Rolling success rate and return of the training episodes against steps (wall time on top)."""
    import matplotlib.pyplot as plt  # headless: feat2map.render selected the Agg backend

    steps = np.array([c["steps"] for c in curve], dtype=float)
    wall = np.array([c["wall_s"] for c in curve], dtype=float)
    w = max(1, min(window, len(curve)))
    kernel = np.ones(w) / w
    succ = np.convolve([c["success"] for c in curve], kernel, mode="valid")
    ret = np.convolve([c["return"] for c in curve], kernel, mode="valid")
    x = steps[w - 1:]
    fig, ax = plt.subplots(figsize=(7, 3.8))
    ax.plot(x, succ, color="tab:green", label=f"success (last {w} training episodes)")
    ax.set_ylim(0, 1.02)
    ax.set_xlabel("environment steps (decisions)")
    ax.set_ylabel("success rate")
    ax2 = ax.twinx()
    ax2.plot(x, ret, color="tab:blue", alpha=0.7, label="mean return")
    ax2.set_ylabel("return")
    if len(steps) > 1:
        top = ax.secondary_xaxis("top", functions=(lambda s: np.interp(s, steps, wall / 60),
                                                   lambda m: np.interp(m, wall / 60, steps)))
        top.set_xlabel("training wall time [min]")
    lines = ax.get_lines() + ax2.get_lines()
    ax.legend(lines, [ln.get_label() for ln in lines], fontsize=8, loc="lower right")
    fig.tight_layout()
    save_figure(fig, path)


# ---- training ---------------------------------------------------------------------------------------
def batched_task(config: dict, rc: "RunConfig", n: int) -> BatchedTask:
    """The agent's task on `n` sub-envs of the native batched vector env."""
    batch = MapVectorEnv(JunctionGridEnv, n, config=config, autoreset_mode=AutoresetMode.SAME_STEP)
    return BatchedTask(batch, rc.train_traffic, pedestrians=rc.train_pedestrians)


def build_model(config: dict, rc: "RunConfig"):
    """An untrained PPO on `rc.n_envs` monitored sub-envs of the native batched vector env (each
    its own seed stream), in this process or split over `rc.workers` processes (one batch each,
    stepping at once), or copies of the agent's env in subprocesses when `rc.subprocess`."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env
    from stable_baselines3.common.vec_env import SubprocVecEnv, VecMonitor

    torch.set_num_threads(1)
    if rc.subprocess:
        venv = make_vec_env(make_env, n_envs=rc.n_envs, seed=rc.seed,
                            env_kwargs={"config": config, "traffic": rc.train_traffic,
                                        "pedestrians": rc.train_pedestrians},
                            vec_env_cls=SubprocVecEnv, vec_env_kwargs={"start_method": "fork"})
    elif rc.workers > 1:
        venv = VecMonitor(sb3_workers(partial(batched_task, config, rc), rc.n_envs, rc.workers))
    else:
        venv = VecMonitor(sb3_vec_env(batched_task(config, rc, rc.n_envs)))
    n_steps = rc.n_steps or max(rc.rollout // rc.n_envs, 8)
    return PPO("MlpPolicy", venv, n_steps=n_steps, batch_size=rc.batch_size, n_epochs=rc.n_epochs,
               gamma=rc.gamma, gae_lambda=0.95, learning_rate=rc.learning_rate, ent_coef=rc.ent_coef,
               policy_kwargs={"net_arch": list(rc.net_arch)}, seed=rc.seed, verbose=0, device="cpu")


def training_log(total: int, enabled: bool, minutes: float | None = None, lr_end: float = 1.0):
    """An SB3 callback: progress over training steps (`Progress`: a bar on a terminal, a line a
    minute otherwise) showing the recent success rate and the wall time budget, and the
    learning curve (one record per finished training episode) in `.curve`; training stops once
    `minutes` of wall time have passed. The learning rate decays linearly to `lr_end` times its
    start over the budget (steps or wall time, whichever runs out first): large steps early,
    fine ones for the final policy."""
    from stable_baselines3.common.callbacks import BaseCallback

    class _Log(BaseCallback):
        def _on_training_start(self) -> None:
            if enabled:
                budget = f"{minutes:g} min of wall time or {total:,} steps" if minutes else f"{total:,} steps"
                print(f"training PPO for {budget}, then the evaluation", file=sys.stderr, flush=True)
            self.bar = Progress(total, "training", "step", enabled, minutes)
            self.t0 = self.t_load = time.perf_counter()
            self.curve: list[dict] = []
            self.loads = [os.getloadavg()[0]]
            self.schedule = self.model.lr_schedule
            if lr_end < 1.0:
                lr0 = self.schedule(1.0)
                self.model.lr_schedule = lambda p: lr0 * (lr_end + (1.0 - lr_end) * self.left(p))

        def left(self, progress: float) -> float:
            """Fraction of the budget left: SB3's progress remaining (steps) or wall time."""
            if minutes is not None:
                progress = min(progress, 1.0 - (time.perf_counter() - self.t0) / (60.0 * minutes))
            return max(progress, 0.0)

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            for done, info in zip(self.locals["dones"], self.locals["infos"]):
                if done and "episode" in info:
                    o = outcome(info, float(info["episode"]["r"]), int(info["episode"]["l"]))
                    self.curve.append({"steps": self.num_timesteps, "wall_s": round(time.perf_counter() - self.t0, 2),
                                       "success": int(o.success), "return": round(o.ret, 4), "failure": o.failure})
            if self.curve and self.n_calls % 50 == 0:
                recent = self.curve[-200:]
                self.bar.set_postfix(success=f"{np.mean([c['success'] for c in recent]):.2f}",
                                     episodes=len(self.curve))
            now = time.perf_counter()
            if now - self.t_load > LOAD_SAMPLE_S:
                self.loads.append(os.getloadavg()[0])
                self.t_load = now
            return minutes is None or now - self.t0 < 60.0 * minutes

        def _on_training_end(self) -> None:
            self.bar.close()
            self.model.lr_schedule = self.schedule  # saved with the model: nothing of this callback

    return _Log()


@dataclass(frozen=True)
class RunConfig:
    """Sizes of one training + evaluation run (the smoke test uses tiny ones)."""

    features: tuple = task_features()
    timesteps: int = 2_000_000  # at most; training also ends after train_minutes
    train_minutes: float | None = 24.0
    train_traffic: tuple[int, int] | None = TRAIN_TRAFFIC
    train_pedestrians: tuple[float, float] | None = TRAIN_PEDESTRIANS
    n_envs: int = 32
    workers: int = 1  # processes the native batched env's sub-envs are split over (`sb3.sb3_workers`; 1: this one)
    subprocess: bool = False  # copies in subprocesses instead of the native batched env
    n_steps: int | None = None  # per env and rollout (None: rollout // n_envs)
    rollout: int = 2048  # steps of all envs per rollout
    batch_size: int = 128
    n_epochs: int = 10
    gamma: float = 0.99
    learning_rate: float = 3e-4
    lr_end: float = 0.1  # the learning rate decays linearly to this fraction of it over the budget
    ent_coef: float = 0.003
    net_arch: tuple[int, ...] = (128, 128)
    episodes_per_cell: int = 20
    eval_workers: int = 2
    seed: int = 0
    progress: bool = True
    extra: dict = field(default_factory=dict)  # env config overrides


def run(out: Path, rc: RunConfig = RunConfig()) -> dict:
    """Train, evaluate per (junction type, manoeuvre) against the scripted driver; write the
    tables, the learning curve, the model and the wall times."""
    config = env_config(rc.features, **rc.extra)
    t_start = time.perf_counter()
    model = build_model(config, rc)
    log = training_log(rc.timesteps, rc.progress, rc.train_minutes, rc.lr_end)
    model.learn(total_timesteps=rc.timesteps, callback=log)
    model.get_env().close()
    train_s = time.perf_counter() - t_start
    out.mkdir(parents=True, exist_ok=True)
    model_bytes = _saved(model)
    atomic.write_bytes(out / "ppo_model.zip", model_bytes)
    curve = log.curve
    if curve:
        atomic.write_text(out / "learning_curve.csv", rows_csv(curve))
        plot_curve(curve, out / "learning_curve.png")

    t_eval = time.perf_counter()
    cases = junction_cases(make_env(config, agent=False).unwrapped.net.hdmap)
    rows, totals = evaluate_cases(config, cases, model_bytes, rc.episodes_per_cell, rc.eval_workers, rc.progress)
    eval_s = time.perf_counter() - t_eval
    overall = {name: round(float(np.mean([r[f"{name}_success"] for r in rows])), 3) for name in ("ppo", "scripted")}
    worst = min(rows, key=lambda r: r["ppo_success"])
    timing = {"train_s": round(train_s, 1), "eval_s": round(eval_s, 1), "total_s": round(train_s + eval_s, 1),
              "load_avg_1min": load_summary(log.loads + [os.getloadavg()[0]]), "timesteps": int(model.num_timesteps),
              "training_episodes": len(curve), "cells": len(rows), "episodes_per_cell": rc.episodes_per_cell,
              "mean_cell_success": overall, "min_cell_success_ppo": worst["ppo_success"],
              "cells_below_0.9": sum(r["ppo_success"] < 0.9 for r in rows),
              "ppo_failures": {k: v for k, v in totals["ppo"]["failures"].items() if v}}
    atomic.write_text(out / "success.csv", rows_csv(rows))
    header = (f"PPO, {timing['timesteps']} steps ({train_s / 60:.1f} min training, {eval_s / 60:.1f} min evaluation), "
              f"{len(rc.features)} junction types, {rc.episodes_per_cell} episodes per cell: mean cell success "
              f"{overall['ppo']:.3f} (scripted {overall['scripted']:.3f}), lowest cell {worst['ppo_success']:.2f}, "
              f"{timing['cells_below_0.9']} of {len(rows)} cells below 0.9\n\n")
    atomic.write_text(out / "success.md", header + rows_markdown(rows))
    plot_cells(rows, ["ppo", "scripted"], out / "success.png")
    atomic.write_text(out / "summary.md", summary_markdown(rows, timing, rc))
    cfg = {k: v for k, v in asdict(rc).items() if k != "features"}
    atomic.write_text(out / "run.json", json.dumps({"timing": timing, "run_config": cfg}, indent=1, default=str))
    return {"rows": rows, "curve": curve, **timing}


def summary_markdown(rows: Sequence[dict], timing: dict, rc: RunConfig) -> str:
    """The run for examples/README.md: sizes, wall times, machine load, success per cell (PPO,
    the scripted driver in brackets) as junction type x manoeuvre, PPO's failures."""
    load = timing["load_avg_1min"]
    fails = ", ".join(f"{k} {v}" for k, v in timing["ppo_failures"].items()) or "none"
    below = [f"{type_label(junction_type(r))} {r['manoeuvre']} ({r['ppo_success']:.2f})"
             for r in rows if r["ppo_success"] < 0.9]
    columns = [m for m in COLUMNS if any(r["manoeuvre"] == m for r in rows)]
    lines = [f"- training: {timing['timesteps']:,} steps ({timing['training_episodes']:,} episodes) in "
             f"{timing['train_s'] / 60:.1f} min ({rc.n_envs} {'subprocess' if rc.subprocess else 'batched'} envs); "
             f"evaluation: {timing['episodes_per_cell']} "
             f"episodes per cell for PPO and for the scripted driver, {timing['cells']} cells, {rc.eval_workers} "
             f"processes, {timing['eval_s'] / 60:.1f} min; **total {timing['total_s'] / 60:.1f} min**",
             f"- machine load during training (1-min load average, 2 cores): min {load['min']}, mean {load['mean']}, "
             f"max {load['max']}",
             f"- mean cell success: PPO **{timing['mean_cell_success']['ppo']:.3f}**, scripted driver "
             f"{timing['mean_cell_success']['scripted']:.3f}; lowest PPO cell {timing['min_cell_success_ppo']:.2f}; "
             f"cells below 0.9: {len(below)} of {timing['cells']}" + (f" ({'; '.join(below)})" if below else ""),
             f"- PPO's failed episodes by first cause: {fails}", "",
             f"| junction (success: PPO (scripted), {timing['episodes_per_cell']} episodes per cell) | "
             + " | ".join(columns) + " |", "|---|" + "---|" * len(columns)]
    for t in dict.fromkeys(junction_type(r) for r in rows):
        cell = {r["manoeuvre"]: r for r in rows if junction_type(r) == t}
        vals = [f"{cell[m]['ppo_success']:.2f} ({cell[m]['scripted_success']:.2f})" if m in cell else "–"
                for m in columns]
        lines.append(f"| {type_label(t)} | " + " | ".join(vals) + " |")
    return "\n".join(lines) + "\n"


def load_summary(loads: Sequence[float]) -> dict:
    """min / mean / max of load-average samples (the machine's load while this ran)."""
    return {"min": round(min(loads), 2), "mean": round(float(np.mean(loads)), 2), "max": round(max(loads), 2)}


def _saved(model) -> bytes:
    buf = io.BytesIO()
    model.save(buf)
    return buf.getvalue()


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/ppo")
    ap.add_argument("--timesteps", type=int, default=RunConfig.timesteps, help="at most this many training steps")
    ap.add_argument("--train-minutes", type=float, default=RunConfig.train_minutes,
                    help="training ends after this wall time (0: only --timesteps ends it)")
    ap.add_argument("--n-envs", type=int, default=RunConfig.n_envs, help="sub-envs of the batched env (or subprocesses)")
    ap.add_argument("--workers", type=int, default=RunConfig.workers,
                    help="processes the batched env's sub-envs are split over (1: the training process alone)")
    ap.add_argument("--subprocess", action="store_true", help="copies of the env in subprocesses (SB3's SubprocVecEnv) "
                    "instead of the native batched vector env")
    ap.add_argument("--episodes-per-cell", type=int, default=RunConfig.episodes_per_cell)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.timesteps < 1 or args.episodes_per_cell < 1 or args.n_envs < 1 or args.train_minutes < 0:
        ap.error("--timesteps, --n-envs and --episodes-per-cell must be positive, --train-minutes not negative")
    if not 1 <= args.workers <= args.n_envs:
        ap.error(f"--workers must be in [1, --n-envs={args.n_envs}], got {args.workers}")
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        ap.exit(2, "train_ppo: needs the rl extra: bash scripts/setup.sh rl\n")
    rc = replace(RunConfig(), timesteps=args.timesteps, train_minutes=args.train_minutes or None, n_envs=args.n_envs,
                 workers=args.workers, subprocess=args.subprocess, episodes_per_cell=args.episodes_per_cell, seed=args.seed)
    run(Path(args.out), rc)
    print((Path(args.out) / "summary.md").read_text(encoding="utf-8"))
    print(f"written: {args.out}/summary.md, success.md, success.csv, success.png, learning_curve.png, ppo_model.zip, "
          "run.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
