"""Driving filter lanes (a generated map, examples/filter_lanes.yaml): the network knows which
filter lanes give way at a yield sign, the rules hold a car at such an entry while traffic merges
or conflicts, and the route-coverage suite takes every filter lane and completes at traffic 6
with the baseline planner."""
from __future__ import annotations

from pathlib import Path
from types import SimpleNamespace

import pytest
from conftest import example_map_file

from feat2map.envs.network import MapNetwork
from feat2map.formats import native
from feat2map.scenarios.scenario import Scenario, make_env

REPO = Path(__file__).resolve().parents[2]
FILTER_MOVES = {("J0", "R2", "R3"), ("J0", "R3", "R0"), ("J1", "R4", "R5")}  # (junction, entry, exit) of each


@pytest.fixture(scope="module")
def map_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "filter_lanes")


def test_the_network_knows_the_yield_filter_lanes(map_path):
    net = MapNetwork.from_map(native.load(map_path))
    assert net.yield_entries == {"J0_f3_0", "J1_f1_0"}  # J0_f2_0 has a light of its own
    assert net.stop_lines["R2_1"].kind == "signal" and net.stop_lines["R2_1"].control_id == "J0_filter2"
    assert "R3_1" not in net.stop_lines  # a yield sign draws no stop line: the car gives way, it need not stop


def test_a_yield_filter_lane_gives_way_to_merging_traffic(map_path, monkeypatch):
    env = make_env(Scenario(name="filter", map=str(map_path), route=(("J1", "R4", "R5"),), seed=0))
    try:
        env.reset(seed=0)
        rules, ego = env.unwrapped.control, env.unwrapped.vehicle
        assert not rules.yield_held(ego, "J1_f1_0")
        assert rules.may_enter(ego, "R4_1", "J1_f1_0", 20.0)
        # a car 5 m before the exit road's lane that the core feeds, at 8 m/s
        car = SimpleNamespace(speed=8.0)
        monkeypatch.setattr(type(rules), "traffic_towards",
                            lambda self, lane, exclude=None: [(5.0, car)] if lane == "R5a_0" else [])
        assert rules.yield_held(ego, "J1_f1_0")
        assert not rules.may_enter(ego, "R4_1", "J1_f1_0", 20.0)
        assert rules.may_enter(ego, "R4_1", "J1_f1_0", 20.0, ignore=frozenset({"conflict"}))
    finally:
        env.close()


def test_info_names_a_yield_filter_lane_as_the_control_ahead(map_path):
    for route, want in (((("J1", "R4", "R5"),), "yield"), ((("J0", "R2", "R3"),), "signal")):
        env = make_env(Scenario(name="filter", map=str(map_path), route=route, seed=0))
        try:
            _, info = env.reset(seed=0)
            assert info["control_ahead"] == want
        finally:
            env.close()


def test_the_suite_takes_every_filter_lane_and_completes_at_traffic_6(map_path):
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    suite = build_suite(map_path, traffic_vehicles=6, seed=0)
    taking = [sc for sc in suite.scenarios if FILTER_MOVES & {tuple(mv) for mv in sc.route}]
    assert FILTER_MOVES <= {tuple(mv) for sc in taking for mv in sc.route}
    for sc in taking:
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, out.message)


def test_a_filter_lane_conflicts_with_the_lanes_it_merges_with_after_the_road_splits(map_path):
    """A filter lane joins its exit road just after the road piece the junction's own lanes run on
    (R3a, R0a, R5a): the lanes into that piece conflict with it, whatever its control."""
    m = native.load(map_path)
    net = MapNetwork.from_map(m)
    for f in ("J0_f2_0", "J0_f3_0", "J1_f1_0"):
        (exit_lane,) = m.lanes[f].successors
        (piece,) = (p for p in m.lanes[exit_lane].predecessors if p != f)
        assert m.lanes[piece].junction_id is None
        assert set(m.lanes[piece].predecessors) <= net.conflicts[f], f


def test_straight_traffic_and_a_signalised_filter_lane_merge_in_turn(tmp_path):
    """A highway-and-city map (the paper's space with every mid-block, filter and ramp value), route
    r010 of its suite at traffic 6: the ego went straight through J2 onto the piece before the
    filter lane's join while a car came off the signalised filter lane on the same green, and the
    two met side by side; the filter lane now conflicts with the lanes it merges with."""
    import dataclasses

    import feat2map
    from feat2map.scenarios.rollout import run_scenario

    space = dataclasses.replace(feat2map.PAPER_SF_FEATURE_SPACE, midblock=("none", "bare", "signal"),
                                filter=("none", "yield", "signal"), ramp=("none", "on", "off", "both"))
    m = feat2map.generate(space, seed=5)
    assert m.junctions["J2"].feature.sockets[1].filter == "signal"  # the situation is still there
    path = tmp_path / "hc.json"
    native.save(m, path)
    route = (("J5", "R12", "R14a"), ("J7", "R14b", "R18"), ("J12", "R18", "R5"), ("J2", "R5", "R6a"))
    out = run_scenario(Scenario(name="hc-r010", map=str(path), route=route, traffic_vehicles=6, seed=10,
                                duration=267.8), record_failure_gif=False)
    assert out.outcome == "completed", out.message
