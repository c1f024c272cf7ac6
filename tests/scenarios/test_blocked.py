"""The blocked early end of rollouts (scenarios/rollout.py `BlockedClock`): a planner that stands
still with nothing in its way ends as a timeout saying where and for how long; standing at a red
light never counts, whatever the limit."""
from __future__ import annotations

import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest

import feat2map
from feat2map import cli
from feat2map.config import BLOCKED_AFTER_S
from feat2map.errors import Feat2MapError
from feat2map.formats import native
from feat2map.routes import manoeuvres
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.rollout import run_scenario, run_suite
from feat2map.scenarios.scenario import Scenario, Suite, save_suite

J = feat2map.JunctionFeature.make
STEP_S = 0.2  # the scenario env's decision period (POLICY_FREQUENCY_HZ 5)
RED_AT_ARRIVAL = {"J0": 15.0}  # signal offset that turns the ego's light red as it arrives (13 s wait)


class StandingLog(BaselinePlanner):
    """The baseline planner (or, `dead`, full braking from the first step) logging how long the ego
    stood at each signal state and the longest it stood at a red light at once."""

    dead = False

    def reset(self, env):
        super().reset(env)
        self.stood = {"red": 0.0, "amber": 0.0, "green": 0.0, "": 0.0}
        self.red_wait = self.longest_red_wait = 0.0
        self.first_stop = None

    def act(self, obs, info):
        if info["speed"] <= 0.3:
            self.first_stop = info["time"] if self.first_stop is None else self.first_stop
            self.stood[info["signal_state"]] += STEP_S
        red = info["speed"] <= 0.3 and info["signal_state"] == "red"
        self.red_wait = self.red_wait + STEP_S if red else 0.0
        self.longest_red_wait = max(self.longest_red_wait, self.red_wait)
        a = super().act(obs, info)
        return np.array([-1.0], dtype=np.float32) if self.dead else a


class DeadStop(StandingLog):
    dead = True


def _scenario(tmp_path, control: str, **kw) -> Scenario:
    m = feat2map.generate_from_features([J([0, 90, 180], control, False)], seed=0)
    native.save(m, tmp_path / f"{control}.json")
    return Scenario(f"{control}-straight", str(tmp_path / f"{control}.json"), (manoeuvres(m)[1],), **kw)


def test_a_planner_that_stops_dead_on_a_clear_road_ends_early_as_blocked(tmp_path):
    sc = _scenario(tmp_path, "stop", duration=60.0)  # 30 m before a stop sign: not at its line, nothing holds it
    p = DeadStop()
    out = run_scenario(sc, lambda: p, record_failure_gif=False, blocked_after=3.0)
    assert out.outcome == "timeout" and out.message.startswith("blocked: stood still"), out.message
    assert out.sim_s == pytest.approx(p.first_stop + 3.0, abs=2 * STEP_S)  # not the 60 s duration
    lane = p.env.net.id_of[p.env.vehicle.lane_index]
    assert f"on lane {lane}" in out.message and "before the stop sign's line of junction J0" in out.message
    assert "3.0 s of them" in out.message and out.route_progress < 0.2
    # 0: never blocked, the duration ends it
    short = Scenario(sc.name, sc.map, sc.route, duration=8.0)
    out = run_scenario(short, DeadStop, record_failure_gif=False, blocked_after=0)
    assert out.outcome == "timeout" and out.sim_s == pytest.approx(8.0) and "blocked" not in out.message
    # the default limit applies to a suite run; a bad limit is refused before any drive
    assert run_suite([sc], DeadStop, progress=False, record_failure_gif=False).outcomes[0].sim_s == \
        pytest.approx(p.first_stop + BLOCKED_AFTER_S, abs=2 * STEP_S)
    with pytest.raises(Feat2MapError, match="blocked_after"):
        run_suite([sc], DeadStop, progress=False, blocked_after=-1.0)


def test_waiting_at_a_red_light_longer_than_blocked_after_is_not_blocked(tmp_path):
    sc = _scenario(tmp_path, "signal", signal_offsets=RED_AT_ARRIVAL, duration=60.0)
    p = StandingLog()
    out = run_scenario(sc, lambda: p, record_failure_gif=False, blocked_after=5.0)
    assert p.longest_red_wait > 5.0 + 1.0, "the scenario must hold the ego at a red light longer than the limit"
    assert out.outcome == "completed", out.message
    # a planner standing dead before the light: its red and amber seconds do not count, only the green ones
    dead = DeadStop()
    out = run_scenario(sc, lambda: dead, record_failure_gif=False, blocked_after=5.0)
    assert out.outcome == "timeout" and "blocked" in out.message
    held = dead.stood["red"] + dead.stood["amber"]
    assert held > 5.0 and dead.stood["green"] == pytest.approx(5.0, abs=2 * STEP_S)
    assert out.sim_s == pytest.approx(dead.first_stop + held + 5.0, abs=2 * STEP_S)


def test_the_cli_takes_blocked_after(tmp_path, capsys):
    sc = _scenario(tmp_path, "stop", duration=60.0)
    save_suite(Suite("dead", (sc,)), tmp_path / "suite.yaml")
    code = cli.main(["rollout", str(tmp_path / "suite.yaml"), "--planner", f"{__name__}:DeadStop", "--out",
                     str(tmp_path / "out"), "--quiet", "--no-coverage", "--no-gif", "--blocked-after", "2"])
    text = capsys.readouterr().out
    assert code == 1 and "timeout: blocked: stood still" in text and "blocked_after 2 s" in text
    assert cli.main(["rollout", str(tmp_path / "suite.yaml"), "--out", str(tmp_path / "o2"), "--blocked-after",
                     "-1"]) == 2
    assert "--blocked-after" in capsys.readouterr().err


def test_a_road_user_close_ahead_justifies_the_wait_and_a_clear_road_does_not(tmp_path):
    """A queue never counts: the judge sees the car standing ahead of the ego."""
    from feat2map.scenarios.scenario import make_env

    sc = _scenario(tmp_path, "stop")
    env = make_env(sc)  # the baseline planner's action: an acceleration
    env.reset(seed=0)
    e = env.unwrapped
    brake = np.array([-1.0], dtype=np.float32)
    env.step(brake)
    assert e.judge.wait_reason() == ""  # 30 m before a stop sign's line: nothing holds it there
    ego = e.vehicle
    lane = e.net.id_of[ego.lane_index]
    e.road.spawn(lane, ego.lane_s + 12.0, 0.0, list(ego.lane_route[ego.route_pos:]))
    env.step(brake)
    assert e.judge.wait_reason() == "road user ahead"
    env.close()
