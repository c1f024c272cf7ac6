"""Smoke version of examples/train_ppo.py: a tiny PPO training and the per-cell evaluation through
the same code path (`run`) on a two-junction map, its batch split over two worker processes
(`sb3.sb3_workers`), and the task's wrappers (target speeds, rewards)."""
from __future__ import annotations

import csv
import importlib.util
import json
import os
import sys
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest
from conftest import SKIP_RL

pytest.importorskip("torch", reason=SKIP_RL)
pytest.importorskip("stable_baselines3", reason=SKIP_RL)

EXAMPLE = Path(__file__).resolve().parents[2] / "examples" / "train_ppo.py"
NEAR_MISS_SEEDS = 3


@pytest.fixture(scope="module")
def tp():
    spec = importlib.util.spec_from_file_location("train_ppo", EXAMPLE)
    mod = importlib.util.module_from_spec(spec)
    sys.modules["train_ppo"] = mod
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="module")
def tiny(tp):
    feats = (*tp.junction_features(ns=(4,), controls=("signal",), crosswalks=(True,)),
             *tp.junction_features(ns=(3,), controls=("stop",), crosswalks=(False,)))
    return replace(tp.RunConfig(), features=feats, timesteps=256, n_envs=2, workers=2, subprocess=False, n_steps=64,
                   batch_size=64, n_epochs=2, episodes_per_cell=1, eval_workers=1, progress=False)


def test_tiny_training_and_success_table(tp, tiny, tmp_path):
    res = tp.run(tmp_path, tiny)
    for name in ("success.csv", "success.md", "success.png", "ppo_model.zip", "run.json"):
        assert (tmp_path / name).stat().st_size > 100, name
    with open(tmp_path / "success.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    keys = {(int(r["n"]), r["control"], r["crosswalk"] == "True", r["ramp"], r["manoeuvre"]) for r in rows}
    # one row per junction type and manoeuvre the map offers: 4-leg signal + crosswalk, 3-leg stop
    hdmap = tp.make_env(tp.env_config(tiny.features), agent=False).unwrapped.net.hdmap
    assert keys == {c.key for c in tp.junction_cases(hdmap)}
    assert {k[:4] for k in keys} == {(4, "signal", True, "none"), (3, "stop", False, "none")}
    assert {"left", "straight", "right"} <= {k[4] for k in keys}
    for r in rows:
        assert int(r["episodes"]) == 1
        assert 0.0 <= float(r["ppo_success"]) <= 1.0
        assert (r["ppo_failures"] == "-") == (float(r["ppo_success"]) == 1.0)
        # the rule-following reference driver succeeds everywhere: the evaluation itself is sound
        assert float(r["scripted_success"]) == 1.0, r
    md = (tmp_path / "success.md").read_text()
    assert "success" in md and md.count("\n| ") == len(rows) + 1
    summary = (tmp_path / "summary.md").read_text()  # for examples/README.md: one table row per junction type
    assert summary.count("\n| n=") == 2 and "total" in summary and "machine load" in summary
    timing = json.loads((tmp_path / "run.json").read_text())["timing"]
    assert timing["total_s"] == pytest.approx(timing["train_s"] + timing["eval_s"], abs=0.2)
    assert timing["cells"] == len(rows) == res["cells"]
    if res["curve"]:  # training episodes that ended: the learning curve
        assert (tmp_path / "learning_curve.png").stat().st_size > 100
        assert res["curve"][-1]["steps"] <= tiny.timesteps


def test_ramp_cells_merge_and_diverge(tp):
    """The task's map holds the ramp junction: its merge and diverge are cells (the table's ramp
    row), DriverView and the info name them, and the scripted driver completes both."""
    assert tp.RAMP_JUNCTION in tp.task_features() and tp.RunConfig().features == tp.task_features()
    config = tp.env_config((*tp.junction_features(ns=(3,), controls=("bare",), crosswalks=(False,)), tp.RAMP_JUNCTION))
    env = tp.make_env(config, agent=False)
    cases = tp.junction_cases(env.unwrapped.net.hdmap)
    ramp = {c.manoeuvre: c for c in cases if c.ramp == "both"}
    assert list(ramp) == list(tp.RAMP_CELLS) == ["merge", "diverge"]
    assert {c.manoeuvre for c in cases if c.ramp == "none"} == set(tp.MANOEUVRES)
    agent = tp.make_env(config)
    for name, case in ramp.items():
        o = tp.run_episode(env, tp.scripted_policy, tp.EVAL_SEED, case.routes[0])
        assert o.success, (name, o)
        agent.unwrapped.configure({"route": list(case.routes[0])})
        obs, info = agent.reset(seed=0)
        assert info["manoeuvre"] == name
        assert [f for f, v in zip(tp.DRIVER_VIEW_FEATURES, obs) if f in tp.COLUMNS and v > 0.5] == [name]
    rows = [{"n": c.n, "control": c.control, "crosswalk": c.crosswalk, "ramp": c.ramp, "manoeuvre": c.manoeuvre,
             "episodes": 1, "ppo_success": 1.0, "scripted_success": 1.0} for c in cases]
    timing = {"timesteps": 1, "training_episodes": 1, "train_s": 1.0, "eval_s": 1.0, "total_s": 2.0,
              "episodes_per_cell": 1, "cells": len(rows), "load_avg_1min": tp.load_summary([1.0]),
              "mean_cell_success": {"ppo": 1.0, "scripted": 1.0}, "min_cell_success_ppo": 1.0, "ppo_failures": {}}
    table = tp.summary_markdown(rows, timing, tp.RunConfig()).splitlines()
    assert "| left | straight | right | merge | diverge |" in table[5]
    assert table[-1] == "| ramp junction (on- and off-ramp) | – | – | – | 1.00 (1.00) | 1.00 (1.00) |"
    assert table[-2] == "| n=3 bare | 1.00 (1.00) | 1.00 (1.00) | 1.00 (1.00) | – | – |"


def _single(tp, control, **config):
    feats = tp.junction_features(ns=(4,), controls=(control,), crosswalks=(False,))
    return tp.make_env(tp.env_config(feats, traffic_vehicles=0, pedestrian_rate=0.0, **config))


def test_target_speeds_are_reached_by_the_next_decision(tp):
    env = _single(tp, "bare")
    env.reset(seed=0)
    ego = env.unwrapped.vehicle
    for i in (3, 2, 1, 0, 0):  # 5.0, 3.0, 1.5, 0 m/s, each within the acceleration bounds from the last
        env.step(i)
        assert ego.speed == pytest.approx(tp.TARGET_SPEEDS[i], abs=0.05)
    _, _, _, _, info = env.step(0)
    assert info["speed"] == 0.0


def test_stop_bonus_once_and_a_violation_ends_the_episode(tp):
    env = _single(tp, "stop")
    obs, _ = env.reset(seed=0)
    rewards, stops = [], []
    while True:  # creep to the line, stop in the zone, then go
        near, stop, inside = (obs[tp.DRIVER_VIEW_FEATURES.index(f)] for f in ("line_near", "stop", "in_junction"))
        go = obs[tp.STOP_MADE] > 0.5 or stop == 0 or inside
        action = 4 if go else (0 if near < 0.4 else 2 if near < 1 else 3)
        obs, r, term, trunc, info = env.step(action)
        rewards.append(r)
        stops.append(obs[tp.STOP_MADE] > 0.5)
        if term or trunc:
            break
    assert info["route_completed"] and info["violations"]["stop_sign"] == 0
    first = stops.index(True)
    entry = len(stops) - stops[::-1].index(True)  # the step that drove on into the junction
    assert rewards[first] < tp.STOP_BONUS / 2  # the stop itself is not paid ...
    assert rewards[entry] > tp.STOP_BONUS - tp.TIME_COST - 0.05  # ... driving on after it is
    assert sum(r > tp.STOP_BONUS / 2 for r in rewards[:-1]) == 1  # the bonus once (the last step: arrival)

    obs, _ = env.reset(seed=0)  # stop in the zone and stay: the episode times out
    ret, held = 0.0, False
    while True:
        near = obs[tp.DRIVER_VIEW_FEATURES.index("line_near")]
        held = held or obs[tp.STOP_MADE] > 0.5
        obs, r, term, trunc, info = env.step(0 if held or near < 0.4 else 2 if near < 1 else 3)
        ret += r
        if term or trunc:
            break
    assert trunc and not info["route_completed"] and info["violations"]["stop_sign"] == 0
    assert ret < 0.0  # halting for good at the line pays less than nothing: waiting is never free

    obs, _ = env.reset(seed=0)
    for steps in range(200):  # full speed through the stop sign  # noqa: B007 (steps is read after it)
        obs, r, term, trunc, info = env.step(len(tp.TARGET_SPEEDS) - 1)
        if term or trunc:
            break
    assert term and info["violations"]["stop_sign"] == 1 and not info["route_completed"]
    assert r < -1.5
    o = tp.outcome(info, 0.0, steps)
    assert not o.success and o.failure == "stop_sign"


def test_near_misses_cost_what_they_are_named_for(tp):
    """Entering the junction while the decision before saw a conflicting lane taken costs
    ENTRY_COST, a clear entry nothing; moving faster than the speed that stops the ego at a
    pedestrian's stop point with BRAKE_MPS2 costs in proportion to the excess, slower nothing."""
    F = tp.DRIVER_VIEW_FEATURES
    before, after = np.zeros((4, len(F))), np.zeros((4, len(F)))
    before[:, tp.PEDESTRIAN] = after[:, tp.PEDESTRIAN] = 1.0  # (1: nobody in the path)
    before[:2, tp.OCCUPIED] = 1.0
    after[[0, 2], tp.IN_JUNCTION] = 1.0  # rows 0 and 2 enter; row 0 with a conflicting lane taken
    cost = tp.near_miss_cost(before, after)
    assert cost.tolist() == [tp.ENTRY_COST, 0.0, 0.0, 0.0]
    stop_m, speed = 6.0, 9.0  # 6 m to the stop point at 9 m/s: stopping there takes 6.75 m/s2
    after = np.zeros(len(F))
    after[tp.PEDESTRIAN] = stop_m / tp.DRIVER_VIEW_PEDESTRIAN_SCALE_M
    after[tp.SPEED] = speed / tp.DRIVER_VIEW_SPEED_SCALE_MPS
    safe = (2 * tp.BRAKE_MPS2 * stop_m) ** 0.5
    expected = tp.LATE_BRAKE_COST * (speed - safe) / tp.DRIVER_VIEW_SPEED_SCALE_MPS
    assert float(tp.near_miss_cost(np.zeros(len(F)), after)) == pytest.approx(expected)
    after[tp.SPEED] = 0.9 * safe / tp.DRIVER_VIEW_SPEED_SCALE_MPS
    assert float(tp.near_miss_cost(np.zeros(len(F)), after)) == 0.0


def test_outcome_counts_only_clean_completions(tp):
    env = _single(tp, "bare")
    o = tp.run_episode(env, lambda obs, env: 0, seed=3)  # target speed 0: never arrives
    assert not o.completed and not o.success and o.failure == "timeout"
    assert o.steps == int(tp.TASK_CONFIG["duration"] * tp.DECISION_HZ)
    assert tp.Outcome(True, False, False, 1, 1.0, 5).success is False
    assert tp.Outcome(True, False, False, 0, 1.0, 5).success is True
    s = tp.summarize([o, tp.Outcome(True, False, False, 0, 2.0, 5)])
    assert s["success"] == 0.5 and s["return"] == pytest.approx((o.ret + 2.0) / 2)
    assert s["failures"]["timeout"] == 1


def test_bad_arguments_exit_2(tp, capsys):
    with pytest.raises(SystemExit) as e:
        tp.main(["--timesteps", "0"])
    assert e.value.code == 2 and "timesteps" in capsys.readouterr().err


def test_batched_task_pays_what_the_wrappers_pay(tp):
    """BatchedTask (the training's shaping on the batched env) gives the rewards and the episode
    end of TaskRewards(TargetSpeed(env)) on the same seed and actions: stop, then drive on."""
    cfg = tp.env_config(tp.junction_features(ns=(4,), controls=("stop",), crosswalks=(False,)),
                        traffic_vehicles=0, pedestrian_rate=0.0)
    single = tp.make_env(cfg)
    batch = tp.BatchedTask(tp.MapVectorEnv(tp.JunctionGridEnv, 1, config=cfg, autoreset_mode=tp.AutoresetMode.SAME_STEP))
    obs, _ = single.reset(seed=0)
    bobs, _ = batch.reset(seed=0)
    rewards, brewards = [], []
    while True:
        assert np.allclose(obs, bobs[0])
        near, inside = obs[tp.DRIVER_VIEW_FEATURES.index("line_near")], obs[tp.DRIVER_VIEW_FEATURES.index("in_junction")]
        go = obs[tp.STOP_MADE] > 0.5 or inside
        action = 4 if go else (0 if near < 0.4 else 2 if near < 1 else 3)
        obs, r, term, trunc, info = single.step(action)
        bobs, br, bterm, btrunc, _ = batch.step(np.array([action]))
        rewards.append(r)
        brewards.append(float(br[0]))
        assert (term, trunc) == (bool(bterm[0]), bool(btrunc[0]))
        if term or trunc:
            break
    assert info["route_completed"] and sum(r > tp.STOP_BONUS / 2 for r in rewards[:-1]) == 1
    assert np.allclose(rewards, brewards)


def test_batched_task_charges_the_near_misses_the_wrappers_charge(tp):
    """Through a busy bare junction with a crosswalk at full speed, BatchedTask's rewards are
    TaskRewards' step for step, near misses (`near_miss_cost`) among them."""
    cfg = tp.env_config(tp.junction_features(ns=(4,), controls=("bare",), crosswalks=(True,)),
                        traffic_vehicles=10, pedestrian_rate=20.0)
    single = tp.make_env(cfg)
    batch = tp.BatchedTask(tp.MapVectorEnv(tp.JunctionGridEnv, 1, config=cfg, autoreset_mode=tp.AutoresetMode.SAME_STEP))
    full = len(tp.TARGET_SPEEDS) - 1
    charged = 0.0
    for seed in range(NEAR_MISS_SEEDS):
        obs, _ = single.reset(seed=seed)
        batch.reset(seed=seed)
        while True:
            last = obs
            obs, r, term, trunc, _ = single.step(full)
            _, br, bterm, btrunc, _ = batch.step(np.array([full]))
            assert r == pytest.approx(float(br[0])) and (term, trunc) == (bool(bterm[0]), bool(btrunc[0]))
            charged += float(tp.near_miss_cost(last, obs))
            if term or trunc:
                break
    assert charged > 0.0  # (the seeds meet near misses: the comparison covers them)


def test_training_episodes_draw_their_traffic_and_pedestrians_the_same_in_both_paths(tp):
    """Each training episode of the batched env (BatchedTask, which configures a sub-env's next
    episode as the one before it starts) and of a wrapped single env (TrafficRange, at its reset)
    draws its traffic count and pedestrian rate from the training ranges: the same draws from the
    same seed, spread over the ranges."""
    cfg = tp.env_config(tp.junction_features(ns=(3,), controls=("bare",), crosswalks=(True,)), duration=0.5)
    single = tp.make_env(cfg, traffic=tp.TRAIN_TRAFFIC, pedestrians=tp.TRAIN_PEDESTRIANS)
    batch = tp.BatchedTask(tp.MapVectorEnv(tp.JunctionGridEnv, 1, config=cfg, autoreset_mode=tp.AutoresetMode.SAME_STEP),
                           tp.TRAIN_TRAFFIC, pedestrians=tp.TRAIN_PEDESTRIANS)
    sub = batch.unwrapped.envs[0]

    def drawn(env):
        return env.config["traffic_vehicles"], env.config["pedestrian_rate"]

    single.reset(seed=5)
    batch.reset(seed=5)
    singles, nexts = [drawn(single.unwrapped)], [drawn(sub)]
    for _ in range(12):
        done = False
        while not done:
            _, _, term, trunc, _ = single.step(0)
            done = term or trunc
            _, _, bterm, btrunc, _ = batch.step(np.array([0]))
            assert (term, trunc) == (bool(bterm[0]), bool(btrunc[0]))
        single.reset()
        singles.append(drawn(single.unwrapped))
        nexts.append(drawn(sub))
    assert nexts[:-1] == singles[1:]  # the batch's next episode is the single env's next
    traffic, rate = np.array(singles).T
    assert traffic.min() >= tp.TRAIN_TRAFFIC[0] and traffic.max() <= tp.TRAIN_TRAFFIC[1] and len(set(traffic)) > 2
    assert rate.min() >= tp.TRAIN_PEDESTRIANS[0] and rate.max() < tp.TRAIN_PEDESTRIANS[1] and rate.std() > 1.0


def test_progress_is_a_line_a_minute_off_a_terminal(tp, capsys, monkeypatch):
    monkeypatch.setattr(tp, "PROGRESS_LINE_S", 0.0)  # a line at every update
    bar = tp.Progress(10, "training", "step", enabled=True, minutes=24)
    bar.set_postfix(success="0.50")
    bar.update(4)
    bar.close()
    lines = capsys.readouterr().err.splitlines()  # captured stderr is no terminal
    assert len(lines) == 2 and lines[0].startswith("training: 4 of 10 steps, 0.0 of 24 min, success 0.50"), lines
    quiet = tp.Progress(10, "training", "step", enabled=False)
    quiet.update(4)
    quiet.close()
    assert capsys.readouterr().err == ""
