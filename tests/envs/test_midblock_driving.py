"""Driving past mid-block crosswalks (a generated map, examples/midblock.yaml): pedestrians walk
on them, the network holds their lights' lines on the road lanes, traffic and the baseline
planner stop for the light and the people, and a planner that ignores signals runs the red."""
from __future__ import annotations

from pathlib import Path

import pytest
from conftest import example_map_file

from feat2map.envs.network import MapNetwork
from feat2map.formats import native
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.scenario import Scenario, make_env

REPO = Path(__file__).resolve().parents[2]
ROUTE = (("J0", "R2", "R0"), ("J1", "R0", "R4"))  # through the signalised crossing on R0 and the bare one on R4


@pytest.fixture(scope="module")
def map_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "midblock")


def test_the_network_holds_midblock_lines_and_crossings(map_path):
    net = MapNetwork.from_map(native.load(map_path))
    assert set(net.midblock_lines) == {"R0_0", "R0_1"}  # one light per direction
    assert net.stop_lines["R0_0"].kind == "stop"  # J1's own sign still governs the lane's end
    for lid, lines in net.midblock_lines.items():
        ((sid, s),) = lines
        ((cw, s0, _),) = net.crossings[lid]
        assert cw == "R0_cw" and 0.0 < s0 - s < 3.0  # the line right before the crosswalk
    assert [c for c, _, _ in net.crossings["R4_0"]] == ["R4_cw"]  # the bare crossing


def drive(map_path: Path, planner: BaselinePlanner, **kw) -> tuple[dict, dict]:
    """One episode on ROUTE: (last info, what was seen: pedestrians per crosswalk, red-light passes
    by traffic, whether the ego stood before the line while red, the lanes of its red-light runs)."""
    sc = Scenario(name="midblock", map=str(map_path), route=ROUTE, duration=90.0, **kw)
    env = make_env(sc)
    seen: dict = {"pedestrians": set(), "traffic_on_red": [], "ego_waited": False, "red_light_on": [],
                  "signals_ahead": set()}
    last: dict = {}
    try:
        obs, info = env.reset(seed=sc.seed)
        u = env.unwrapped
        planner.reset(env)
        for _ in range(5000):
            obs, _, terminated, truncated, info = env.step(planner.act(obs, info))
            seen["pedestrians"] |= {cw for cw, people in u.control.pedestrians.items() if people}
            seen["signals_ahead"].add(info["signal_id"])
            if "red_light" in info["new_violations"]:
                seen["red_light_on"].append(info["lane_id"])
            for v in u.road.vehicles:
                lid = u.net.id_of.get(v.lane_index)
                for sid, s in u.net.midblock_lines.get(lid, ()):
                    red = u.control.signal_state(sid) == "red"
                    before = last.get((id(v), lid))
                    if v is u.vehicle and red and v.lane_s < s and v.speed < 0.2:
                        seen["ego_waited"] = True
                    if v is not u.vehicle and red and before is not None and before < s <= v.lane_s:
                        seen["traffic_on_red"].append((info["time"], lid))
                    last[(id(v), lid)] = v.lane_s
            if terminated or truncated:
                break
    finally:
        env.close()
    return info, seen


def test_pedestrians_cross_and_the_baseline_planner_stops_for_them_and_the_light(map_path):
    # offset 0: the crossing's light turns red 15 s into the episode, as the ego comes down R0
    info, seen = drive(map_path, BaselinePlanner(), traffic_vehicles=6, pedestrian_rate=12.0, seed=1,
                       signal_offsets={"R0_signal0": 0.0})
    assert {"R0_cw", "R4_cw"} <= seen["pedestrians"]
    assert info["route_completed"] and not info["collision"]
    assert info["violations"] == {"red_light": 0, "stop_sign": 0, "pedestrian_yield": 0}
    assert seen["ego_waited"]  # held before the line on red
    assert "R0_signal0" in seen["signals_ahead"]  # info names the crossing's light as the next control
    assert seen["traffic_on_red"] == []


def test_a_planner_ignoring_signals_runs_the_midblock_red(map_path):
    # offset 15: red for the first 19 s of the 34 s cycle; the ego, stopping for no light, passes the line at ~9 s
    info, seen = drive(map_path, BaselinePlanner(ignore={"signal"}), traffic_vehicles=0, pedestrian_rate=0.0, seed=1,
                       signal_offsets={"R0_signal0": 15.0})
    assert "R0_0" in seen["red_light_on"]


def test_the_suite_drives_every_midblock_lane_and_completes_at_traffic_6(map_path):
    """The route-coverage suite passes each mid-block crosswalk in both directions, and its
    scenarios through them complete with the baseline planner among 6 traffic vehicles."""
    from feat2map.routes import road_lanes_between, midblock_lanes
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    m = native.load(map_path)
    suite = build_suite(map_path, traffic_vehicles=6, pedestrian_rate=4.0, seed=0)
    through = {}
    for sc in suite.scenarios:
        for a, b in zip(sc.route, sc.route[1:]):
            for lid in road_lanes_between(m, a, b):
                through.setdefault(lid, sc)
    lanes = [lid for _, lid in midblock_lanes(m)]
    assert sorted(lanes) == ["R0_0", "R0_1", "R4_0", "R4_1"] and set(lanes) <= set(through)
    for sc in dict.fromkeys(through[lid] for lid in lanes):  # one scenario per lane, each once
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, out.message)


def test_midblock_lanes_get_routes_of_their_own_when_the_cover_misses_them(map_path):
    from feat2map.routes import (_midblock_routes, road_lanes_between, midblock_lanes, successor_graph,
                                 suite_manoeuvres)

    m = native.load(map_path)
    moves = suite_manoeuvres(m)
    extra = _midblock_routes(m, successor_graph(m, moves), [], {mv: i for i, mv in enumerate(moves)})
    assert all(len(r) == 2 for r in extra)
    driven = {x for r in extra for x in road_lanes_between(m, *r)}
    assert {lid for _, lid in midblock_lanes(m)} <= driven
