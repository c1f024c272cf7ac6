"""A bare junction entry (no line) waits clear of the junction paths drawn over its approach, as a
stop line does (`network._clear_of_paths_over`). osm2xodr draws a cluster's paths over bare
approaches too: durlacher-tor's `j_14892149_c16` crosses `w656222580_0_0_-1` 0.8 m before its end,
and the ego waiting at the entry stood in its path (r010; scheck-in r091 likewise,
docs/realmaps.md). The wait point is one number per incoming lane (`MapNetwork.setbacks`), read by
the rules (`rules.line_setback`, so the passage code and the planner too) and the traffic core
(`LaneTable.line_setback`)."""
from __future__ import annotations

import dataclasses
import os

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import numpy as np
import pytest

import feat2map
from feat2map.config import CROSSING_CLEARANCE_M
from feat2map.envs.core import LaneTable
from feat2map.envs.network import MapNetwork
from feat2map.envs.rules import line_plan, line_setback


def _redrawn(control: str):
    """A generated 4-way junction (`control`) whose right turn from R1 (J0_c3_0) is redrawn to cut
    across R0_1's last metre (R0_1 runs from x = -44.5 to -19.5 along y = -1.75): the map, and the
    network built from it."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], control, False)], seed=0)
    ln = m.lanes["J0_c3_0"]
    pts = np.array([m.lanes["R1_1"].centerline[-1], (-20.5, -8.0), (-20.5, -1.75), (-20.5, 4.0),
                    m.lanes["R2_0"].centerline[0]], dtype=float)
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731
    redrawn = dataclasses.replace(ln, centerline=tup(pts), left_boundary=tup(pts), right_boundary=tup(pts), bezier=None)
    m = dataclasses.replace(m, lanes={**m.lanes, "J0_c3_0": redrawn})
    return m, MapNetwork.from_map(m)


def test_bare_entry_waits_clear_of_a_junction_path_drawn_over_the_approach():
    """At a bare junction R0_1's wait point moves back from its end (s = 25) to where the redrawn
    path comes onto it (s = 24) less half the path's width and CROSSING_CLEARANCE_M, exactly where
    a stop line goes on the same junction signalled (fails without the rule: no setback, the car
    waited at the entry, in the path). Approaches nothing crosses keep waiting at their entry."""
    m, net = _redrawn("bare")
    assert not net.stop_lines
    width = m.lanes["J0_c3_0"].width
    assert net.setbacks["R0_1"] == pytest.approx(25.0 - (24.0 - width / 2 - CROSSING_CLEARANCE_M), abs=0.05)
    assert set(net.setbacks) == {"R0_1"} and net.max_line_setback == net.setbacks["R0_1"]
    _, signalled = _redrawn("signal")
    assert net.setbacks["R0_1"] == pytest.approx(net.lane_of["R0_1"].length - signalled.stop_lines["R0_1"].s)
    # a path no lane leads into carries no one: it sets nothing back (CommonRoad's Guetersloh
    # 21_0_1, with no predecessor, starts on the end of the approach 36_0_-1)
    unlinked = dataclasses.replace(m, lanes={**m.lanes, "J0_c3_0": dataclasses.replace(m.lanes["J0_c3_0"], predecessors=())})
    assert not MapNetwork.from_map(unlinked).setbacks
    # the same junction as generated: no path over any approach, no setback anywhere
    plain = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)], seed=0)
    assert not MapNetwork.from_map(plain).setbacks


def test_rules_and_traffic_core_read_one_wait_point():
    """The rules' distance to the line of a bare entry and the traffic core's table give the same
    setback, for the lane that has one and for one that has none."""
    _, net = _redrawn("bare")
    table = LaneTable(net)
    for lane in ("R0_1", "R3_1"):
        assert table.line_setback[table.index[lane]] == pytest.approx(line_setback(net, lane))
    j_lane = next(s for s in net.hdmap.lanes["R0_1"].successors)
    lengths, back, found = line_plan(net, ["R0_1", j_lane], 0)  # a car on R0_1, the entry at its end
    assert found == (None, "R0_1", j_lane) and lengths == ()
    assert back == pytest.approx(net.setbacks["R0_1"]) and back > 1.0  # the line lies before the entry


def test_road_lane_across_a_junction_lanes_last_metre_conflicts():
    """A road lane of another road, linked to nothing of the junction, drawn across the last
    half metre of a junction lane (osm2xodr's `w669252633_0_0_-1` across `j_26026265_c55_0_-1`,
    0.9 m before its end: scheck-in r078, where the ego crossed in c55 blind to the car on it):
    the crossing, in the middle of the road lane, is a conflict both ways (fails without the rule:
    a crossing within CROSSING_CLEARANCE_M of either lane's end was dropped). Lanes that join at
    the junction's edge still cross nothing."""
    from shapely.geometry import LineString

    from feat2map.envs.network import _road_lanes, road_crossings

    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False)], seed=0)
    jl = [ln for ln in m.lanes.values() if ln.junction_id is not None]
    lines = [LineString(ln.centerline) for ln in jl]
    assert road_crossings(jl, lines, _road_lanes(m), m.lanes) == []
    # the straight J0_c1_0 ends at (19.5, -1.75); RX_0 runs north along x = 19.0 from y = -14 to 0
    pts = np.stack([np.full(8, 19.0), np.linspace(-14.0, 0.0, 8)], 1)
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731
    rx = dataclasses.replace(m.lanes["R2_0"], id="RX_0", road_id="RX", centerline=tup(pts), left_boundary=tup(pts - (1.75, 0)),
                             right_boundary=tup(pts + (1.75, 0)), predecessors=(), successors=(), left_neighbors=(),
                             right_neighbors=(), left_reverse_neighbors=(), bezier=None)
    road = dataclasses.replace(m.roads["R2"], id="RX", right_lanes=("RX_0",), left_lanes=(), reference=None,
                               start_junction=None, end_junction=None)
    m = dataclasses.replace(m, lanes={**m.lanes, "RX_0": rx}, roads={**m.roads, "RX": road})
    pairs = road_crossings(jl, lines, _road_lanes(m), m.lanes)
    assert ("J0_c1_0", "RX_0") in pairs and all(b == "RX_0" for _, b in pairs)
    assert road_crossings(jl, lines, _road_lanes(m)) == []  # the ends-only rule, without the lanes
    net = MapNetwork.from_map(m)
    assert "RX_0" in net.conflicts["J0_c1_0"] and "J0_c1_0" in net.conflicts["RX_0"]
