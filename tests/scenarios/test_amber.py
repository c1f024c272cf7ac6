"""The amber decision of a planner that slows for its turn behind the line: an amber never finds
the ego where it can neither stop (`stops_at_amber`) nor cross before red. SVL San Francisco
2019 (20 m/s declared on every lane): the go at amber assumed the speed held to the line, the
planner braked for the junction lane's curve behind it and crossed 0.05-0.6 s after red."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import numpy as np
import pytest

import feat2map
from feat2map.config import GenerationConfig
from feat2map.envs.rules import amber_arrival_speed, amber_speed_cap, stops_at_amber
from feat2map.formats import native
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.scenario import Scenario, make_env

FAST = 20.0  # [m/s] on every lane, the junction's too, as the 2019 San Francisco map declares
DRIVE = {"traffic_vehicles": 0, "ego_start_distance": 100.0, "ego_initial_speed": FAST}


def test_go_at_amber_must_cross_before_red():
    """A vehicle that cannot stop must be fast enough to cross in the amber time, slowing for its
    turn; where it cannot, its speed there is capped to one it can stop from."""
    amber = 3.0
    # holding 20 m/s crosses 60 m in 3 s; slowing to 5 m/s at the line covers only 37.5 m
    assert amber_arrival_speed(60.0, FAST, amber) == pytest.approx(20.0)
    assert amber_arrival_speed(37.5, 5.0, amber) == pytest.approx(20.0)
    # the trace of r129: 36 m before the line at 17.8 m/s, too close to stop at 3 m/s^2 ...
    assert not stops_at_amber(36.0, 17.8)
    # ... and too slow to reach it before red when slowing for the turn (it crossed 3.05 s after
    # the amber began; the planner allows the 3 s less its 0.2 s decision step): capped
    cap = amber_speed_cap(36.0, 17.8, 6.5, amber - 0.2)
    assert cap < 17.8 and stops_at_amber(36.0, float(cap))
    # a straight approach at 13.4 m/s (the generated maps' limit) is never capped
    x = np.arange(1.0, 100.0)
    assert np.all(np.isinf(amber_speed_cap(x, 13.4, 13.4, amber)) | (amber_speed_cap(x, 13.4, 13.4, amber) >= 13.4))


@pytest.fixture(scope="module")
def fast_turn(tmp_path_factory):
    """A generated signalled 4-way junction whose lanes all declare 20 m/s, with 120 m
    approaches, and the ego's route through its right turn (29 m turning 87 degrees), started
    100 m before the line at 20 m/s."""
    cfg = GenerationConfig(speed_limit=FAST, junction_speed_limit=FAST, stub_length=120.0, grid_gap=300.0)
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False)],
                                        seed=0, config=cfg)
    path = tmp_path_factory.mktemp("amber") / "fast_turn.json"
    native.save(m, path)
    jid = next(iter(m.junctions))
    ln = min((ln for ln in m.lanes_by_junction[jid] if ln.turn == "right"), key=lambda ln: ln.id)
    return Scenario("amber", str(path), ((jid, m.lanes[ln.predecessors[0]].road_id,
                                          m.lanes[ln.successors[0]].road_id),), seed=0, duration=15.0)


def _drive(sc: Scenario, amber_at: float) -> dict:
    """Drive the ego's route with the baseline planner, its signal turning amber `amber_at`
    seconds after the start (green before); the final info."""
    env = make_env(sc, config=DRIVE)
    env.reset(seed=0)
    u = env.unwrapped
    sid = u.net.stop_lines[u.route_lanes[0]].control_id
    plan = u.control.plans[sid]
    env.close()
    slot = plan.green + plan.amber + plan.all_red
    offset = (plan.phase_of(sid) * slot + plan.green - amber_at) % plan.cycle
    env = make_env(sc, config={**DRIVE, "signal_offsets": {sc.route[0][0]: offset}})
    obs, info = env.reset(seed=0)
    planner = BaselinePlanner()
    planner.reset(env)
    while True:
        obs, _, term, trunc, info = env.step(planner.act(obs, info))
        if term or trunc:
            env.close()
            return info


@pytest.mark.parametrize("amber_at", [2.0, 2.2, 2.4, 2.6])
def test_a_fast_approach_to_a_tight_turn_never_runs_the_red(fast_turn, amber_at):
    """Without the cap these ambers found the ego 48-60 m before the line at 20 m/s: too close
    to stop at 3 m/s^2 (68 m), and braking for the turn it crossed the line on red (at 4.8-8.3
    m/s). It now meets them at 16-17 m/s, stops, and turns on the next green."""
    info = _drive(fast_turn, amber_at)
    assert info["violations"]["red_light"] == 0
    assert not info["collision"]


def test_the_turn_is_still_driven_on_green(fast_turn):
    """With no amber on the way the capped approach still completes the turn."""
    info = _drive(fast_turn, 12.0)
    assert info["violations"]["red_light"] == 0 and not info["collision"]
    assert info["route_progress"] == pytest.approx(1.0)
