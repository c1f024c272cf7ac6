"""HDMap -> highway-env network: exact polyline lanes, the y flip, the grid index against a
brute-force scan, lane-graph routing, conflict tables and stop lines."""
from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import feat2map
from feat2map.envs import lanes as lanes_mod
from feat2map.envs.lanes import PolylineLane, project_rows
from feat2map.envs.network import GRID_CELL_M, MapNetwork

J = feat2map.JunctionFeature.make
FEATS = [J([0, 90, 180, 270], "signal", True), J([0, 90, 180, 270], "stop", False), J([0, 90, 180], "bare", True)]


@pytest.fixture(scope="module")
def net() -> MapNetwork:
    return MapNetwork.from_map(feat2map.generate_from_features(FEATS, seed=0))


@pytest.mark.parametrize("block", [lanes_mod.PROJECT_BLOCK, 50])
def test_projecting_many_lanes_at_once_equals_each_lane_bit_for_bit(net, monkeypatch, block):
    """`project_rows` of points on many lanes (lanes of very different lengths: grouped, padded
    and, with a small PROJECT_BLOCK, cut into blocks) gives each lane's `local_coordinates`."""
    monkeypatch.setattr(lanes_mod, "PROJECT_BLOCK", block)
    rng = np.random.default_rng(4)
    lanes = rng.integers(0, len(net._lanes), 300)
    x, y = rng.uniform(-50, 450, (300, 5)), rng.uniform(-450, 50, (300, 5))
    s, lat = project_rows(net.segment_table(), lanes, x, y)
    want = np.array([[net._lanes[k].local_coordinates(np.array([a, b])) for a, b in zip(xr, yr)]
                     for k, xr, yr in zip(lanes.tolist(), x, y)])
    assert np.array_equal(s, want[:, :, 0]) and np.array_equal(lat, want[:, :, 1])
    assert np.array_equal(project_rows(net.segment_table(), lanes, x, y, lateral=False)[0], s)


@settings(max_examples=60, deadline=None)
@given(pts=st.lists(st.tuples(st.floats(-50, 50), st.floats(-50, 50)), min_size=2, max_size=6, unique=True),
       u=st.floats(0.0, 1.0), lat=st.floats(-1.0, 1.0))
def test_polyline_lane_round_trip(pts, u, lat):
    """Every segment's own frame round-trips: local_coordinates(position(s, r)) == (s, r) when the
    point's nearest segment is the one it was placed on (always true for r = 0)."""
    pts = np.array(pts)
    if np.min(np.hypot(*np.diff(pts, axis=0).T)) < 1e-3:
        return
    lane = PolylineLane(pts, 3.5)
    s = u * lane.length
    p = lane.position(s, 0.0)
    s2, r2 = lane.local_coordinates(p)
    assert r2 == pytest.approx(0.0, abs=1e-6)
    np.testing.assert_allclose(lane.position(s2, r2), p, atol=1e-6)
    # a straight lane is exact for any lateral offset and beyond its ends
    straight = PolylineLane(np.array([[0.0, 0.0], [10.0, 0.0], [25.0, 0.0]]), 3.5)
    for s in (-3.0, u * 25, 28.0):
        s2, r2 = straight.local_coordinates(straight.position(s, lat))
        assert (s2, r2) == pytest.approx((s, lat), abs=1e-9)


def test_lanes_match_the_map_with_y_flipped(net):
    m = net.hdmap
    for lid, ln in list(m.lanes.items())[:40]:
        lane = net.lane_of[lid]
        assert lane.length == pytest.approx(ln.length, rel=1e-9)
        x, y = ln.centerline[0]
        np.testing.assert_allclose(lane.position(0.0, 0.0), [x, -y], atol=1e-9)
        # right-hand traffic: the lane's right (positive lateral in highway-env) is the map's right boundary
        rx, ry = ln.right_boundary[0]
        s, r = lane.local_coordinates(np.array([rx, -ry]))
        assert r == pytest.approx(ln.width / 2, abs=0.01)  # boundaries are offset Béziers


def test_grid_index_agrees_with_brute_force(net):
    rng = np.random.default_rng(0)
    lanes = [net.lane_of[l] for l in net.lane_ids]
    for _ in range(300):
        lane = lanes[rng.integers(len(lanes))]
        p = lane.position(rng.uniform(0, lane.length), rng.uniform(-1.5, 1.5))
        idx, s, r = net.locate(p)

        def dist(ln, p=p):
            t, q = ln.local_coordinates(p)
            return abs(q) + max(t - ln.length, 0) + max(-t, 0)

        best = min(dist(ln) for ln in lanes)
        assert dist(net.get_lane(idx)) == pytest.approx(best, abs=1e-6)


@settings(max_examples=200, deadline=None)
@given(x=st.floats(-2000, 2000), y=st.floats(-2000, 2000))
def test_a_place_off_the_map_is_located_on_the_lane_with_the_nearest_box(net, x, y):
    """Off every grid cell, `locate` finds the first lane whose bounding box is nearest (the sum
    of the gaps along x and y), and its place on that lane."""
    p = np.array([x, y])
    if (math.floor(x / GRID_CELL_M), math.floor(y / GRID_CELL_M)) in net._cells:  # (on the map: the grid's answer)
        return
    index, s, r = net.locate(p)
    gaps = [max(b[0] - x, 0.0, x - b[2]) + max(b[1] - y, 0.0, y - b[3]) for b in (ln.bbox for ln in net._lanes)]
    assert net._lanes.index(net.get_lane(index)) == int(np.argmin(gaps))
    assert (s, r) == net.get_lane(index).local_coordinates(p)


def test_lookups_do_not_grow_with_the_map():
    small = MapNetwork.from_map(feat2map.generate_from_features(FEATS, seed=0))
    big = MapNetwork.from_map(feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, 0,
                                                feat2map.GenerationConfig(samples_per_combination=12)))
    assert len(big.lane_ids) > 20 * len(small.lane_ids) / 3

    # a lookup scans the segments of one grid cell: their number must not grow with the map
    # (the time per lookup is measured in benchmarks/bench_env.py, not asserted here)
    def cell_segments(n: MapNetwork) -> list[int]:
        return [len(cell[0]) for cell in n._cells.values()]

    assert max(cell_segments(big)) <= 1.5 * max(cell_segments(small))
    assert np.mean(cell_segments(big)) <= 1.5 * np.mean(cell_segments(small))
    for lid in big.lane_ids[:: max(len(big.lane_ids) // 50, 1)]:  # and the lookups are right
        lane = big.lane_of[lid]
        p = lane.position(lane.length / 2, 0.4)
        index, s, lat = big.locate(p, lane.heading_at(lane.length / 2))
        other = big.get_lane(index)
        assert index == big.index_of[lid] or abs(other.local_coordinates(p)[1]) <= 0.4 + 1e-6


def test_routing_is_dijkstra_over_lanes(net):
    m = net.hdmap
    start = next(l for l in m.lanes.values() if l.junction_id is None and l.successors)
    assert net.lane_route(start.id, start.id) == [start.id]
    entry = next(l for l in m.lanes.values() if not l.successors and l.junction_id is None)
    assert net.lane_route(entry.id, start.id) == []  # dead end: unreachable (highway-env's enumeration hangs here)
    reachable = [l for l in m.lanes if net.lane_route(start.id, l)]
    assert len(reachable) > 5
    for goal in reachable[:20]:
        path = net.lane_route(start.id, goal)
        assert path[0] == start.id and path[-1] == goal
        assert all(b in m.lanes[a].successors for a, b in zip(path, path[1:]))
    assert net.shortest_path("no-such-node", "n0") == []


def test_a_lane_route_is_searched_once_and_handed_out_as_a_new_list(net, monkeypatch):
    """`lane_route` keeps the routes it found (MOBIL asks the same ones every period): the same
    route, searched once, a new list each call (a caller that changes its list changes no other
    caller's), and at most LANE_ROUTES_KEPT kept. Under a length limit (`lane_route_within`) a
    route is the unlimited one where it is that short, none where it is longer, and one not
    found under a low limit is searched again under a higher one."""
    from feat2map.envs import network

    m = net.hdmap
    start = next(l for l in m.lanes.values() if l.junction_id is None and l.successors)
    goals = [l for l in m.lanes if net.lane_route(start.id, l)][:6]
    searched = []
    search = network.MapNetwork._lane_route
    monkeypatch.setattr(network.MapNetwork, "_lane_route",
                        lambda self, a, b, reach=math.inf: searched.append(b) or search(self, a, b, reach))
    first = net.lane_route(start.id, goals[-1])
    first.append("changed")
    assert net.lane_route(start.id, goals[-1]) == first[:-1] == search(net, start.id, goals[-1])
    assert searched == []  # (found before)
    monkeypatch.setattr(network, "LANE_ROUTES_KEPT", 3)
    net.memo("lane routes", dict).clear()
    for g in goals:
        net.lane_route(start.id, g)
    assert searched == goals and len(net.memo("lane routes", dict)) <= 3
    net.memo("lane routes", dict).clear()
    far = max(goals, key=lambda g: len(search(net, start.id, g)))
    route = search(net, start.id, far)
    length = sum(m.lanes[x].length for x in route)
    assert len(route) > 1 and net.lane_route_within(start.id, far, length - 1.0) is None
    assert net.lane_route_within(start.id, far, length) == (tuple(route), length)  # (searched again)
    assert net.lane_route_within(start.id, far, length - 1.0) is None  # (kept: the route is longer)


def test_conflicts_and_stop_lines(net):
    m = net.hdmap
    for jl, others in net.conflicts.items():
        for o in others:
            assert jl in net.conflicts[o]  # symmetric
            assert m.lanes[o].junction_id == m.lanes[jl].junction_id
            assert not set(m.lanes[o].predecessors) & set(m.lanes[jl].predecessors)
    # at a 4-way junction a straight movement conflicts with the crossing straights
    j0 = [l for l in m.lanes_by_junction["J0"] if l.turn == "none"]
    assert any(net.conflicts[a.id] & {b.id for b in j0} for a in j0)
    kinds = {sl.kind for sl in net.stop_lines.values()}
    assert kinds == {"signal", "stop"}
    for lid, sl in net.stop_lines.items():
        assert sl.s == pytest.approx(net.lane_of[lid].length, abs=0.1)  # generated stop lines end the lane
    assert net.crossings and all(s0 <= s1 for v in net.crossings.values() for _, s0, s1 in v)
    assert math.isfinite(sum(len(a) for a in net.crosswalk_axes.values()))


def test_network_round_trips_through_highway_env_config(net):
    from highway_env.road.road import RoadNetwork

    back = RoadNetwork.from_config(net.to_config())
    for a, b in zip(net.lanes_list(), back.lanes_list()):
        assert type(b) is PolylineLane and b.line_types == a.line_types
        np.testing.assert_allclose(b.position(3.0, 0.7), a.position(3.0, 0.7))
        assert b.local_coordinates(np.array([1.0, -2.0])) == pytest.approx(a.local_coordinates(np.array([1.0, -2.0])))


def test_signal_heads_of_one_approach_share_a_phase(net):
    """Real maps carry a signal head per lane (and their facing is often unreliable): phases are
    grouped by the direction of travel of the governed lanes, opposite approaches paired."""
    from dataclasses import replace

    from feat2map.phases import group_phases, travel_headings

    m = net.hdmap
    sigs = [s for s in m.signals.values() if s.junction_id == "J0"]
    assert len(sigs) == 4
    heads = [replace(s, id=f"{s.id}_{k}", heading=0.0) for s in sigs for k in range(3)]  # 3 heads, bad facing
    travel = travel_headings(m, heads)
    paired = group_phases(heads, True, travel)
    single = group_phases(heads, False, travel)
    assert len(paired) == 2 and len(single) == 4
    for phase in single:  # one approach: the three heads of one original signal
        assert len({h.rsplit("_", 1)[0] for h in phase}) == 1 and len(phase) == 3
    for phase in paired:  # two opposite approaches
        roads = {m.lanes[next(s for s in sigs if h.startswith(s.id)).lane_ids[0]].road_id for h in phase}
        assert len(phase) == 6 and len(roads) == 2
        a, b = {round(math.degrees(travel[h])) % 360 for h in phase}
        assert abs((a - b) % 360 - 180) < 30  # opposite directions of travel
    assert sorted(h for p in paired for h in p) == sorted(h.id for h in heads)
    # without travel directions the (identical) facings put every head in one approach
    assert group_phases(heads, False) == (tuple(sorted(h.id for h in heads)),)


def test_controls_named_on_junction_lanes_stop_on_the_road_lane(net):
    """Apollo maps put stop lines on the junction lanes' starts: the network moves them to the
    road lanes entering the junction, where vehicles stop."""
    from dataclasses import replace

    m = net.hdmap
    sign = next(s for s in m.stop_signs.values())
    junction_lanes = tuple(sorted({j for l in sign.lane_ids for j in m.lanes[l].successors}))
    assert junction_lanes and all(m.lanes[j].junction_id is not None for j in junction_lanes)
    moved = replace(m, stop_signs={**m.stop_signs, sign.id: replace(sign, lane_ids=junction_lanes)})
    net2 = MapNetwork.from_map(moved)
    for lid in sign.lane_ids:
        assert net2.stop_lines[lid].kind == "stop" and net2.stop_lines[lid].control_id == sign.id
        assert net2.stop_lines[lid].s == pytest.approx(net.stop_lines[lid].s, abs=0.5)
    assert not set(junction_lanes) & set(net2.stop_lines)


def test_stop_line_stands_clear_of_another_road_lane_crossing_before_it(net):
    """A map whose incoming lane crosses a lane of another road before its line (GoMentum's
    lane_79 crosses lane_78, an exit of J_13, 2 m before it: the ego waiting there was hit by the
    right turn into lane_78): the line moves back to half that lane's width plus
    CROSSING_CLEARANCE_M before the crossing; lanes of its own road and linked lanes do not count."""
    from dataclasses import replace

    from feat2map.envs.network import CROSSING_CLEARANCE_M
    from feat2map.model import Lane

    m = net.hdmap
    lid, sl = next((k, v) for k, v in net.stop_lines.items() if v.kind == "signal")
    ln = m.lanes[lid]
    (x0, y0), (x1, y1) = (p[:2] for p in ln.centerline[-2:])
    length = math.hypot(x1 - x0, y1 - y0)
    ux, uy = (x1 - x0) / length, (y1 - y0) / length
    cx, cy = x1 - 6.0 * ux, y1 - 6.0 * uy  # 6 m before the lane's end, across it at 80 degrees
    a = math.atan2(uy, ux) + math.radians(80)
    across = ((cx - 5 * math.cos(a), cy - 5 * math.sin(a)), (cx + 5 * math.cos(a), cy + 5 * math.sin(a)))
    cross = Lane("x", "X", across, across, across, 3.5, 10.0)
    for road, expect in (("X", 6.0 + 3.5 / 2 + CROSSING_CLEARANCE_M), (ln.road_id, 0.0)):
        net2 = MapNetwork.from_map(replace(m, lanes={**m.lanes, "x": replace(cross, road_id=road)}))
        assert net2.stop_lines[lid].s == pytest.approx(sl.s - expect, abs=0.2)
        assert all(net2.stop_lines[k].s == v.s for k, v in net.stop_lines.items() if k != lid)
