"""Train one PPO policy shared by every agent of the multi-agent env (feat2map.envs.parallel_env),
then evaluate it per junction type against every agent driven by the rule-following ScriptedDriver.

- Worlds: one map per junction type (3- and 4-way; signal, stop sign, bare; with a crosswalk),
  each a single generated junction with `--agents` agents on the map's route-coverage routes
  (every manoeuvre, dealt round), a little IDM traffic and crosswalk pedestrians. Training steps
  all worlds in turn in this process (a vector of parallel envs); with `--worlds W` each junction
  type's env holds W copies of its world in one simulation (the env's `worlds` key: W times the
  agents per step for much less than W times the time), evaluation one.
- Agent: the DriverView observation, the TargetSpeed action (target speeds at 2 Hz), the env's
  reward terms (progress, arrival, collisions, violations incl. not yielding and stop order),
  -TIME_COST per decision and +STOP_BONUS once for the full stop at a stop sign (train_ppo.py pays its
  bonus on driving on after the stop instead: a greedy policy paid for the stop halts at the line).
- PPO: a small loop (torch): each agent's trajectory gets its own GAE (an agent that leaves is a
  terminal; one still driving at the rollout's end, or truncated, is bootstrapped), one shared
  actor-critic, clipped updates. SuperSuit's vector wrappers need every possible agent present
  from reset to the end (black death), which agents that enter later are not.
- Evaluation: `--episodes` episodes per junction type from seeds training never drew, PPO
  (greedy, and sampling its actions) and the ScriptedDriver (on the same seeds: the same routes,
  traffic and pedestrians).

Per junction type: success (agents that reached their goal without a crash or a violation),
collisions between agents, stop-sign order violations, not-yielding violations, mean wait
(seconds stopped per agent). Written to OUT: summary.md (the block of examples/README.md),
table.csv, learning_curve.csv, policy.pt, run.json.

Run: nice -n 10 .venv/bin/python examples/train_marl.py --out out/marl
Needs the `rl` extra (torch): bash scripts/setup.sh rl
"""
from __future__ import annotations

import argparse
import csv
import io
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import numpy as np  # noqa: E402

import feat2map  # noqa: E402
from feat2map import atomic  # noqa: E402
from feat2map.envs import parallel_env  # noqa: E402
from feat2map.envs.driver import DRIVER_ACTION_CONFIG, ScriptedDriver  # noqa: E402
from feat2map.envs.driver_view import DRIVER_VIEW_FEATURES  # noqa: E402

TYPES = [(n, c) for n in (3, 4) for c in ("signal", "stop", "bare")]
ANGLES = {3: [0, 90, 180], 4: [0, 90, 180, 270]}
PENALTY = -5.0
TIME_COST = 0.005
STOP_BONUS = 0.3  # once, when DriverView's stop_made turns on (the full stop at a stop sign) (train_ppo.py pays it on driving on)
STOP_MADE = DRIVER_VIEW_FEATURES.index("stop_made")
EVAL_SEED = 10_000
WORLD = {"observation": {"type": "DriverView"}, "agent_routes": "coverage", "route_junctions": 1,
         "traffic_vehicles": 2, "pedestrian_rate": 3.0, "duration": 60.0, "agent_spacing": 12.0, "agent_queue": 2,
         "generation": {"grid_gap": 200.0, "stub_length": 60.0},
         **{f"reward_{k}": PENALTY for k in ("collision", "red_light", "stop_sign", "pedestrian_yield")},
         "reward_not_yielding": -2.0, "reward_stop_order": -2.0}


def world_config(n: int, control: str, agents: int, **extra) -> dict:
    return {**WORLD, "features": [feat2map.JunctionFeature.make(ANGLES[n], control, True).to_dict()],
            "agents": agents, **extra}


@dataclass
class Traj:
    obs: list
    act: list
    logp: list
    val: list
    rew: list


def make_policy(n_obs: int, n_act: int, hidden: int = 64):
    import torch
    from torch import nn

    class ActorCritic(nn.Module):
        def __init__(self) -> None:
            super().__init__()
            self.pi = nn.Sequential(nn.Linear(n_obs, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                                    nn.Linear(hidden, n_act))
            self.v = nn.Sequential(nn.Linear(n_obs, hidden), nn.Tanh(), nn.Linear(hidden, hidden), nn.Tanh(),
                                   nn.Linear(hidden, 1))

        def dist(self, x):
            return torch.distributions.Categorical(logits=self.pi(x))

    return ActorCritic()


def act_batch(policy, obs: dict, greedy: bool = False):
    """{agent: (action, log prob, value)} for a dict of observations."""
    import torch

    names = list(obs)
    if not names:
        return {}
    x = torch.as_tensor(np.stack([obs[a] for a in names]), dtype=torch.float32)
    with torch.no_grad():
        d = policy.dist(x)
        a = d.probs.argmax(-1) if greedy else d.sample()
        lp, v = d.log_prob(a), policy.v(x).squeeze(-1)
    return {k: (int(a[i]), float(lp[i]), float(v[i])) for i, k in enumerate(names)}


def gae(t: Traj, last_value: float, gamma: float, lam: float) -> tuple[np.ndarray, np.ndarray]:
    r, v = np.array(t.rew), np.array(t.val + [last_value])
    adv = np.zeros(len(r))
    g = 0.0
    for k in range(len(r) - 1, -1, -1):
        delta = r[k] + gamma * v[k + 1] - v[k]
        g = delta + gamma * lam * g
        adv[k] = g
    return adv, adv + v[:-1]


def train(envs: list, minutes: float, rollout: int, seed: int, progress: bool) -> tuple[object, list[dict], int]:
    """PPO on all agents of all envs, for `minutes` of wall time."""
    import torch

    torch.manual_seed(seed)
    torch.set_num_threads(1)
    n_obs = envs[0].observation_space(envs[0].possible_agents[0]).shape[0]
    n_act = int(envs[0].action_space(envs[0].possible_agents[0]).n)
    policy = make_policy(n_obs, n_act)
    opt = torch.optim.Adam(policy.parameters(), lr=3e-4)
    obs = [e.reset(seed=seed + 100 * i)[0] for i, e in enumerate(envs)]
    open_: list[dict[str, Traj]] = [{} for _ in envs]
    episode = [0] * len(envs)
    returns: dict[tuple, float] = {}
    curve, steps, t0 = [], 0, time.perf_counter()
    while time.perf_counter() - t0 < 60 * minutes:
        batch: list[tuple[Traj, float]] = []
        for _ in range(rollout):
            for i, env in enumerate(envs):
                if not env.agents:
                    episode[i] += 1
                    obs[i] = env.reset(seed=seed + 100 * i + episode[i] * len(env.worlds))[0]  # (world w: + w)
                    open_[i] = {}
                choice = act_batch(policy, {a: obs[i][a] for a in env.agents})
                for a, (act, lp, v) in choice.items():
                    t = open_[i].setdefault(a, Traj([], [], [], [], []))
                    t.obs.append(obs[i][a])
                    t.act.append(act)
                    t.logp.append(lp)
                    t.val.append(v)
                nxt, rew, term, trunc, infos = env.step({a: c[0] for a, c in choice.items()})
                steps += len(choice)
                for a in choice:
                    stop = STOP_BONUS * float(nxt[a][STOP_MADE] > 0.5 and obs[i][a][STOP_MADE] <= 0.5)
                    open_[i][a].rew.append(rew[a] - TIME_COST + stop)
                    key = (i, episode[i], a)
                    returns[key] = returns.get(key, 0.0) + rew[a]
                    if term[a] or trunc[a]:
                        last = 0.0 if term[a] else act_batch(policy, {a: nxt[a]})[a][2]
                        batch.append((open_[i].pop(a), last))
                        info = infos[a]
                        ok = info["route_completed"] and not info["collision"] and not sum(info["violations"].values())
                        curve.append({"steps": steps, "wall_s": round(time.perf_counter() - t0, 1), "success": int(ok),
                                      "return": round(returns.pop(key), 3)})
                obs[i] = nxt
        for i in range(len(envs)):  # trajectories still open: bootstrap, and start afresh
            values = act_batch(policy, {a: obs[i][a] for a in open_[i] if a in obs[i]})
            for a, t in list(open_[i].items()):
                if t.rew:
                    batch.append((t, values[a][2] if a in values else 0.0))
                open_[i][a] = Traj([], [], [], [], [])
        update(policy, opt, batch)
        if progress and curve:
            recent = curve[-200:]
            print(f"\r{time.perf_counter() - t0:6.0f} s {steps:8d} agent-steps  success "
                  f"{np.mean([c['success'] for c in recent]):.2f}  return {np.mean([c['return'] for c in recent]):+.2f}",
                  end="", flush=True)
    if progress:
        print()
    return policy, curve, steps


def update(policy, opt, batch, epochs: int = 4, minibatch: int = 512, clip: float = 0.2,
           gamma: float = 0.99, lam: float = 0.95) -> None:
    import torch

    parts = [(t, *gae(t, last, gamma, lam)) for t, last in batch if t.rew]
    if not parts:
        return
    x = torch.as_tensor(np.concatenate([np.stack(t.obs) for t, _, _ in parts]), dtype=torch.float32)
    a = torch.as_tensor(np.concatenate([t.act for t, _, _ in parts]))
    lp_old = torch.as_tensor(np.concatenate([t.logp for t, _, _ in parts]), dtype=torch.float32)
    adv = torch.as_tensor(np.concatenate([ad for _, ad, _ in parts]), dtype=torch.float32)
    ret = torch.as_tensor(np.concatenate([rt for _, _, rt in parts]), dtype=torch.float32)
    adv = (adv - adv.mean()) / (adv.std() + 1e-8)
    n = len(x)
    for _ in range(epochs):
        for idx in torch.randperm(n).split(minibatch):
            d = policy.dist(x[idx])
            ratio = torch.exp(d.log_prob(a[idx]) - lp_old[idx])
            pg = -torch.min(ratio * adv[idx], torch.clamp(ratio, 1 - clip, 1 + clip) * adv[idx]).mean()
            vl = ((policy.v(x[idx]).squeeze(-1) - ret[idx]) ** 2).mean()
            loss = pg + 0.5 * vl - 0.01 * d.entropy().mean()
            opt.zero_grad()
            loss.backward()
            torch.nn.utils.clip_grad_norm_(policy.parameters(), 0.5)
            opt.step()


def evaluate(cfg: dict, policy, episodes: int, greedy: bool = True, seed: int = 0) -> dict:
    """Per-agent outcomes of `episodes` episodes: PPO (greedy, or sampling its actions) when
    `policy`, else the ScriptedDriver."""
    import torch

    torch.manual_seed(seed)
    scripted = policy is None
    env = parallel_env({**cfg, "action": {"type": "ContinuousAction", "acceleration_range":
                                          DRIVER_ACTION_CONFIG["acceleration_range"]}} if scripted else cfg)
    agents = success = agent_collisions = order = yields = 0
    wait = 0.0
    for ep in range(episodes):
        obs, _ = env.reset(seed=EVAL_SEED + ep)
        last: dict[str, dict] = {}
        while env.agents:
            if scripted:
                acts = {a: ScriptedDriver(env.view(a)).act() for a in env.agents}
            else:
                acts = {a: c[0] for a, c in act_batch(policy, {a: obs[a] for a in env.agents}, greedy).items()}
            obs, _, term, trunc, infos = env.step(acts)
            last.update(infos)
        for info in last.values():
            agents += 1
            v = info["violations"]
            success += bool(info["route_completed"] and not info["collision"] and not sum(v.values()))
            agent_collisions += bool(info["agent_collision"])
            order += v["stop_order"]
            yields += v["not_yielding"]
            wait += info["wait_time"]
    return {"agents": agents, "success": success / max(agents, 1), "agent_collisions": agent_collisions,
            "stop_order": order, "not_yielding": yields, "mean_wait_s": wait / max(agents, 1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default="out/marl")
    ap.add_argument("--train-minutes", type=float, default=15.0)
    ap.add_argument("--agents", type=int, default=8, help="agents per junction world")
    ap.add_argument("--episodes", type=int, default=5, help="evaluation episodes per junction type")
    ap.add_argument("--rollout", type=int, default=64, help="env steps per world between updates")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--worlds", type=int, default=1, help="copies of each junction type's world in its training env")
    args = ap.parse_args(argv)
    try:
        import torch
    except ImportError:
        ap.exit(2, "train_marl: needs the rl extra: bash scripts/setup.sh rl\n")
    out = Path(args.out)
    progress = os.isatty(1)
    configs = {t: world_config(*t, args.agents) for t in TYPES}
    envs = [parallel_env({**c, "worlds": args.worlds}) for c in configs.values()]
    load0 = os.getloadavg()[0]
    t0 = time.perf_counter()
    policy, curve, steps = train(envs, args.train_minutes, args.rollout, args.seed, progress)
    train_s = time.perf_counter() - t0
    t1 = time.perf_counter()
    rows = []
    for (n, c), cfg in configs.items():
        runs = {"ppo": evaluate(cfg, policy, args.episodes), "sampled": evaluate(cfg, policy, args.episodes, False),
                "scripted": evaluate(cfg, None, args.episodes)}
        rows.append({"junction": f"{n}-way {c}", "agents": runs["ppo"]["agents"],
                     **{f"{name}_{k}": round(v, 3) for name, r in runs.items() for k, v in r.items() if k != "agents"}})
    eval_s = time.perf_counter() - t1
    out.mkdir(parents=True, exist_ok=True)
    buf = io.StringIO()
    w = csv.DictWriter(buf, fieldnames=list(rows[0]))
    w.writeheader()
    w.writerows(rows)
    atomic.write_text(out / "table.csv", buf.getvalue())
    if curve:
        buf = io.StringIO()
        w = csv.DictWriter(buf, fieldnames=list(curve[0]))
        w.writeheader()
        w.writerows(curve)
        atomic.write_text(out / "learning_curve.csv", buf.getvalue())
    pbuf = io.BytesIO()
    torch.save(policy.state_dict(), pbuf)
    atomic.write_bytes(out / "policy.pt", pbuf.getvalue())
    last = curve[-500:]
    lines = [f"- training: {steps:,} agent-steps ({len(curve):,} agent episodes) in {train_s / 60:.1f} min, "
             f"{len(envs)} junction types x {args.worlds} world(s) of {args.agents} agents stepped in one process; "
             f"evaluation: {args.episodes} episodes "
             f"per junction type for PPO and for the scripted driver, {eval_s / 60:.1f} min; 1-min load average "
             f"{load0:.1f} at the start, {os.getloadavg()[0]:.1f} at the end (2 cores)",
             f"- training success over the last {len(last)} agent episodes: "
             f"{np.mean([c['success'] for c in last]) if last else 0:.2f}", "",
             "Each cell: PPO greedy / PPO sampling its actions (every agent driven by the scripted driver).", "",
             "| junction | agents | success | agent-agent collisions | stop-order violations | not yielding | "
             "mean wait [s] |", "|---|---|---|---|---|---|---|"]

    def cell(r: dict, key: str, fmt: str = "{}") -> str:
        return " / ".join(fmt.format(r[f"{n}_{key}"]) for n in ("ppo", "sampled")) + \
            f" ({fmt.format(r[f'scripted_{key}'])})"

    for r in rows:
        lines.append(f"| {r['junction']} | {r['agents']} | {cell(r, 'success', '{:.2f}')} | "
                     f"{cell(r, 'agent_collisions')} | {cell(r, 'stop_order')} | {cell(r, 'not_yielding')} | "
                     f"{cell(r, 'mean_wait_s', '{:.1f}')} |")
    summary = "\n".join(lines) + "\n"
    atomic.write_text(out / "summary.md", summary)
    atomic.write_text(out / "run.json", json.dumps({"train_s": round(train_s, 1), "eval_s": round(eval_s, 1),
                                                    "agent_steps": steps, "args": vars(args)}, indent=1))
    print(summary)
    print(f"written: {out}/summary.md, table.csv, learning_curve.csv, policy.pt, run.json")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
