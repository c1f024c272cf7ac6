"""Train a Stable-Baselines3 PPO ego on a generated junction grid, then evaluate it by junction type.

The map holds one junction per feature combination (road count n x control x crosswalk). The
agent chooses target speeds (DiscreteMetaAction, longitudinal only: steering follows the route)
from Kinematics plus the traffic-control vector (signal colour, stop sign, distance to the stop
line, pedestrian ahead) with two features added by `StopLineFeatures` (stop-line closeness,
full stop made). Printed: success rate and mean return of the untrained and the trained
policy on a fixed evaluation set. Written to OUT: `success.csv`, `success.md` and `success.png`
(success per (n, control, crosswalk, manoeuvre) for the trained and untrained policy and, as a
reference, the rule-following ScriptedDriver), and `ppo_model.zip`.

A success is a completed route without collision, leaving the road or any rule violation.

Run: .venv/bin/python examples/train_ppo.py --out out/ppo [--timesteps 30000]
Needs the `rl` extra: pip install torch==2.13.0 && pip install -e '.[rl]'
"""
from __future__ import annotations

import argparse
import csv
import io
import os
import time
from collections import defaultdict
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Iterable, Sequence

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import feat2map  # noqa: E402  (registers the feat2map/ environment ids)
from feat2map import atomic  # noqa: E402
from feat2map.render import save_figure  # noqa: E402
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver  # noqa: E402
from feat2map.envs.traffic import STOP_ZONE_M, STOPPED_SPEED_MPS  # noqa: E402

ROAD_ANGLES = {3: (0, 90, 180), 4: (0, 90, 180, 270)}
CONTROLS = ("signal", "stop", "bare")
MANOEUVRES = ("left", "straight", "right")
TURN_NAMES = {"left": "left", "none": "straight", "right": "right"}

#: What the agent sees and does: target speeds at 2 Hz, steering follows the route.
AGENT_CONFIG = {
    "observation": {"type": "Kinematics", "vehicles_count": 6,
                    "features": ["presence", "x", "y", "vx", "vy", "cos_h", "sin_h"]},
    "observe_traffic_control": True,
    "action": {"type": "DiscreteMetaAction", "longitudinal": True, "lateral": False,
               "target_speeds": [0.0, 4.5, 9.0]},
    "policy_frequency": 2,
}
#: The task: one junction per route, light traffic and pedestrians, violations cost more than
#: the whole route's progress reward so that rushing through does not pay.
TASK_CONFIG = {
    "route_junctions": 1, "duration": 40.0, "traffic_vehicles": 4, "pedestrian_rate": 3.0,
    "reward_progress": 1.0, "reward_arrived": 1.0, "reward_collision": -3.0, "reward_red_light": -2.0,
    "reward_stop_sign": -2.0, "reward_pedestrian_yield": -2.0, "reward_off_road": -1.0,
}
CLOSENESS_RANGE_M = 30.0
EVAL_SEED = 10_000  # first seed of the fixed evaluation set (training uses seeds below it)

Policy = Callable[[object, gym.Env], object]  # (observation, env) -> action


def junction_features(ns: Sequence[int] = (3, 4), controls: Sequence[str] = CONTROLS,
                      crosswalks: Sequence[bool] = (True, False)) -> list[feat2map.JunctionFeature]:
    """One feature per (road count, control, crosswalk) combination."""
    return [feat2map.JunctionFeature.make(list(ROAD_ANGLES[n]), c, cw)
            for n in ns for c in controls for cw in crosswalks]


def env_config(features: Sequence[feat2map.JunctionFeature], map_seed: int = 0, **overrides) -> dict:
    """Config of feat2map/JunctionGrid-v0 for the agent on a map of `features`."""
    return {**AGENT_CONFIG, **TASK_CONFIG, "features": [f.to_dict() for f in features],
            "map_seed": map_seed, **overrides}


class StopLineFeatures(gym.ObservationWrapper):
    """Appends two features to the traffic-control vector: how close the next stop line is (1 at
    the line .. 0 from CLOSENESS_RANGE_M on; the env's distance/100 spans only 0..0.06 in the 6 m
    where a stop counts), and whether the ego has already made its full stop at the stop sign
    ahead (without it, "stopped at the line" looks the same before and after the stop is made)."""

    def __init__(self, env: gym.Env) -> None:
        super().__init__(env)
        spaces = dict(env.observation_space.spaces)
        spaces["traffic_control"] = gym.spaces.Box(0.0, 1.0, (spaces["traffic_control"].shape[0] + 2,), np.float32)
        self.observation_space = gym.spaces.Dict(spaces)
        self._stopped = False

    def reset(self, **kwargs):
        self._stopped = False
        return super().reset(**kwargs)

    def observation(self, obs: dict) -> dict:
        tc = obs["traffic_control"]
        distance = float(tc[4]) * 100.0
        if tc[3] < 0.5:  # no stop sign ahead: forget the last stop
            self._stopped = False
        elif distance <= STOP_ZONE_M and self.env.unwrapped.vehicle.speed <= STOPPED_SPEED_MPS:
            self._stopped = True
        close = np.clip(1.0 - distance / CLOSENESS_RANGE_M, 0.0, 1.0)
        return {**obs, "traffic_control": np.append(tc, [close, float(self._stopped)]).astype(np.float32)}


def make_env(config: dict) -> gym.Env:
    env = gym.make("feat2map/JunctionGrid-v0", config=config)
    return StopLineFeatures(env) if config.get("observe_traffic_control") else env


@dataclass(frozen=True)
class Outcome:
    """How one episode ended."""

    completed: bool
    collision: bool
    off_road: bool
    violations: int
    ret: float
    steps: int

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
            return Outcome(bool(info["route_completed"]), bool(info["collision"]), bool(info["off_road"]),
                           int(sum(info["violations"].values())), ret, steps)


def model_policy(model) -> Policy:
    """A deterministic policy from an SB3 model."""
    return lambda obs, env: model.predict(obs, deterministic=True)[0]


def scripted_policy(obs, env: gym.Env):
    """The rule-following reference driver (needs DRIVER_ACTION_CONFIG)."""
    return ScriptedDriver(env).act()


def summarize(outcomes: Sequence[Outcome]) -> dict:
    n = max(len(outcomes), 1)
    return {"episodes": len(outcomes), "success": sum(o.success for o in outcomes) / n,
            "completed": sum(o.completed for o in outcomes) / n, "return": sum(o.ret for o in outcomes) / n,
            "collisions": sum(o.collision for o in outcomes), "violations": sum(o.violations for o in outcomes)}


def evaluate(env: gym.Env, policy: Policy, seeds: Iterable[int]) -> dict:
    """Success rate and mean return over sampled routes from fixed seeds."""
    return summarize([run_episode(env, policy, s) for s in seeds])


@dataclass(frozen=True)
class Case:
    """One evaluation route: a manoeuvre through a junction of a given type."""

    n: int
    control: str
    crosswalk: bool
    manoeuvre: str
    route: tuple[tuple[str, str, str], ...]

    @property
    def key(self) -> tuple[int, str, bool, str]:
        return (self.n, self.control, self.crosswalk, self.manoeuvre)


def junction_cases(hdmap, per_manoeuvre: int = 2) -> list[Case]:
    """Up to `per_manoeuvre` (entry, exit) pairs per junction and manoeuvre, as one-junction routes."""
    cases = []
    for jid in sorted(hdmap.junctions):
        f = hdmap.junctions[jid].feature
        by_turn: dict[str, list[tuple[str, str, str]]] = defaultdict(list)
        for ln in sorted(hdmap.lanes_by_junction.get(jid, []), key=lambda ln: ln.id):
            turn = TURN_NAMES.get(ln.turn)
            if turn is None or not ln.predecessors or not ln.successors:
                continue
            m = (jid, hdmap.lanes[ln.predecessors[0]].road_id, hdmap.lanes[ln.successors[0]].road_id)
            if m not in by_turn[turn]:
                by_turn[turn].append(m)
        for turn in MANOEUVRES:
            for m in by_turn[turn][:per_manoeuvre]:
                cases.append(Case(len(f.sockets), f.control, f.crosswalk, turn, (m,)))
    return cases


def evaluate_cases(cases: Sequence[Case], policies: dict[str, tuple[gym.Env, Policy]], seeds: Sequence[int],
                   progress: bool = True) -> list[dict]:
    """Success table rows per (n, control, crosswalk, manoeuvre), one column group per policy."""
    from tqdm import tqdm

    results: dict[tuple, dict[str, list[Outcome]]] = defaultdict(lambda: defaultdict(list))
    jobs = [(c, name, s) for c in cases for name in policies for s in seeds]
    for case, name, seed in tqdm(jobs, desc="evaluating", disable=not progress, unit="ep"):
        env, policy = policies[name]
        results[case.key][name].append(run_episode(env, policy, seed, case.route))
    rows = []
    for key in sorted(results, key=lambda k: (k[0], CONTROLS.index(k[1]), not k[2], MANOEUVRES.index(k[3]))):
        row = {"n": key[0], "control": key[1], "crosswalk": key[2], "manoeuvre": key[3]}
        for name in policies:
            s = summarize(results[key][name])
            row["episodes"] = s["episodes"]
            row.update({f"{name}_success": round(s["success"], 3), f"{name}_return": round(s["return"], 3)})
        rows.append(row)
    return rows


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


def plot(rows: Sequence[dict], names: Sequence[str], fixed: dict[str, dict], path: Path) -> None:
    """Heat maps of success per junction type (rows) and manoeuvre (columns), one per policy,
    and a bar chart of success and return on the fixed evaluation set."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    types = list(dict.fromkeys((r["n"], r["control"], r["crosswalk"]) for r in rows))
    fig, axes = plt.subplots(1, len(names) + 1, figsize=(3.2 * len(names) + 4, 0.42 * len(types) + 2.2),
                             gridspec_kw={"width_ratios": [1.0] * len(names) + [1.1]})
    for ax, name in zip(axes, names):
        grid = np.full((len(types), len(MANOEUVRES)), np.nan)
        for r in rows:
            grid[types.index((r["n"], r["control"], r["crosswalk"])), MANOEUVRES.index(r["manoeuvre"])] = \
                r[f"{name}_success"]
        ax.imshow(grid, cmap="RdYlGn", vmin=0, vmax=1, aspect="auto")
        for (i, j), v in np.ndenumerate(grid):
            ax.text(j, i, "–" if np.isnan(v) else f"{v:.2f}", ha="center", va="center", fontsize=8)
        ax.set_xticks(range(len(MANOEUVRES)), MANOEUVRES, fontsize=8)
        ax.set_yticks(range(len(types)), [f"n={n} {c}{' +cw' if cw else ''}" for n, c, cw in types], fontsize=8)
        ax.set_title(f"success: {name}", fontsize=9)
        if ax is not axes[0]:
            ax.set_yticklabels([])
    ax = axes[-1]
    labels = list(fixed)
    x = np.arange(len(labels))
    ax.bar(x - 0.2, [fixed[k]["success"] for k in labels], 0.4, label="success rate")
    ax.bar(x + 0.2, [fixed[k]["return"] for k in labels], 0.4, label="mean return")
    ax.set_xticks(x, labels, fontsize=8)
    ax.axhline(0, color="k", lw=0.5)
    ax.set_title("fixed evaluation set", fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    save_figure(fig, path)


def build_model(config: dict, n_envs: int, seed: int, n_steps: int, batch_size: int):
    """An untrained PPO on `n_envs` copies of the env (each with its own seed stream)."""
    import torch
    from stable_baselines3 import PPO
    from stable_baselines3.common.env_util import make_vec_env

    torch.set_num_threads(1)
    venv = make_vec_env(lambda: make_env(config), n_envs=n_envs, seed=seed)
    return PPO("MultiInputPolicy", venv, n_steps=n_steps, batch_size=batch_size, n_epochs=8, gamma=0.99,
               learning_rate=5e-4, ent_coef=0.01, policy_kwargs={"net_arch": [64, 64]}, seed=seed, verbose=0,
               device="cpu")


def progress_bar(total: int, enabled: bool):
    """An SB3 callback showing training steps with tqdm."""
    from stable_baselines3.common.callbacks import BaseCallback
    from tqdm import tqdm

    class _Bar(BaseCallback):
        def _on_training_start(self) -> None:
            self.bar = tqdm(total=total, desc="training", unit="step", disable=not enabled)

        def _on_step(self) -> bool:
            self.bar.update(self.training_env.num_envs)
            return True

        def _on_training_end(self) -> None:
            self.bar.close()

    return _Bar()


@dataclass(frozen=True)
class RunConfig:
    """Sizes of one training + evaluation run (the smoke test uses tiny ones)."""

    features: tuple = tuple(junction_features())
    timesteps: int = 60_000
    n_envs: int = 4
    n_steps: int = 256
    batch_size: int = 128
    eval_episodes: int = 40
    per_manoeuvre: int = 2
    case_seeds: tuple[int, ...] = (EVAL_SEED + 500,)
    seed: int = 0
    progress: bool = True


def run(out: Path, rc: RunConfig = RunConfig()) -> dict:
    """Train, evaluate before/after on the fixed set and per junction type; write the tables."""
    from stable_baselines3 import PPO

    config = env_config(rc.features)
    model = build_model(config, rc.n_envs, rc.seed, rc.n_steps, rc.batch_size)
    untrained = PPO.load(_saved(model), device="cpu")  # a frozen copy of the initial weights
    eval_env = make_env(config)
    seeds = range(EVAL_SEED, EVAL_SEED + rc.eval_episodes)
    before = evaluate(eval_env, model_policy(untrained), seeds)
    t = time.perf_counter()
    model.learn(total_timesteps=rc.timesteps, callback=progress_bar(rc.timesteps, rc.progress))
    train_s = time.perf_counter() - t
    after = evaluate(eval_env, model_policy(model), seeds)
    out.mkdir(parents=True, exist_ok=True)
    atomic.write_bytes(out / "ppo_model.zip", _saved(model).getvalue())

    scripted_env = make_env(env_config(rc.features, action=DRIVER_ACTION_CONFIG, policy_frequency=5))
    policies = {"ppo": (eval_env, model_policy(model)), "untrained": (eval_env, model_policy(untrained)),
                "scripted": (scripted_env, scripted_policy)}
    cases = junction_cases(eval_env.unwrapped.net.hdmap, rc.per_manoeuvre)
    rows = evaluate_cases(cases, policies, rc.case_seeds, rc.progress)
    atomic.write_text(out / "success.csv", rows_csv(rows))
    fixed = {"untrained": before, "ppo": after}
    header = (f"PPO, {rc.timesteps} steps ({train_s:.0f} s), {len(rc.features)} junction types; fixed set of "
              f"{rc.eval_episodes} sampled routes: success {before['success']:.2f} -> {after['success']:.2f}, "
              f"mean return {before['return']:.2f} -> {after['return']:.2f}\n\n")
    atomic.write_text(out / "success.md", header + rows_markdown(rows))
    plot(rows, list(policies), fixed, out / "success.png")
    return {"before": before, "after": after, "train_seconds": train_s, "rows": rows}


def _saved(model) -> io.BytesIO:
    buf = io.BytesIO()
    model.save(buf)
    buf.seek(0)
    return buf


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/ppo")
    ap.add_argument("--timesteps", type=int, default=RunConfig.timesteps)
    ap.add_argument("--eval-episodes", type=int, default=RunConfig.eval_episodes)
    ap.add_argument("--seed", type=int, default=0)
    args = ap.parse_args(argv)
    if args.timesteps < 1 or args.eval_episodes < 1:
        ap.error("--timesteps and --eval-episodes must be positive")
    try:
        import stable_baselines3  # noqa: F401
    except ImportError:
        ap.exit(2, "train_ppo: needs the rl extra: pip install torch==2.13.0 && pip install -e '.[rl]'\n")
    rc = replace(RunConfig(), timesteps=args.timesteps, eval_episodes=args.eval_episodes, seed=args.seed)
    res = run(Path(args.out), rc)
    b, a = res["before"], res["after"]
    print(f"trained {rc.timesteps} steps in {res['train_seconds']:.0f} s")
    print(f"{'policy':10s} {'success':>8s} {'completed':>9s} {'return':>7s} {'violations':>10s} {'collisions':>10s}")
    for name, s in (("untrained", b), ("ppo", a)):
        print(f"{name:10s} {s['success']:8.2f} {s['completed']:9.2f} {s['return']:7.2f} {s['violations']:10d} "
              f"{s['collisions']:10d}")
    print(f"per junction type: {args.out}/success.md, success.csv, success.png")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
