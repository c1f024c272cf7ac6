"""Traffic changes lanes only onto a neighbour that runs beside it. osm2xodr opens a turn lane
along a road (Testfeld_Karlsruhe's `w134650843_0_1_-2` begins 20 m after its neighbour
`w134650843_0_0_-1` does, and is listed as its neighbour from the start): a car that changed onto
it 20 m before it began drove on its backward extension, inside its old lane, blind to the ego
ahead of it there, and ran into it (Testfeld r014, docs/realmaps.md)."""
from __future__ import annotations

import dataclasses
import os
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")

import numpy as np
import pytest

import feat2map
from feat2map.formats import native
from feat2map.scenarios.scenario import Scenario, make_env

OPENS_AT_X = 49.5  # the opening lane R2_1 begins here (R2_0 runs from x = 19.5 to 79.5)


@pytest.fixture(scope="module")
def opening_lane(tmp_path_factory) -> Path:
    """A generated bare 4-way junction with two lanes a direction whose exit east (R2) gets its
    outer lane R2_1 only from x = 49.5 on (30 m after R2_0 begins), still R2_0's neighbour."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False, lanes=2)],
                                        seed=0)

    def along(ln, pts):
        tup = lambda a: tuple(map(tuple, a))  # noqa: E731
        n = np.array([0.0, ln.width / 2])
        return dataclasses.replace(ln, centerline=tup(pts), left_boundary=tup(pts + n), right_boundary=tup(pts - n),
                                   bezier=None)

    assert "R2_1" in m.lanes["R2_0"].left_neighbors + m.lanes["R2_0"].right_neighbors
    x0, x1 = np.linspace(19.5, 79.5, 31), np.linspace(OPENS_AT_X, 79.5, 16)
    lanes = dict(m.lanes)
    lanes["R2_0"] = along(m.lanes["R2_0"], np.stack([x0, np.full_like(x0, -1.75)], 1))
    lanes["R2_1"] = along(m.lanes["R2_1"], np.stack([x1, np.full_like(x1, -5.25)], 1))
    path = tmp_path_factory.mktemp("opening") / "opening_lane.json"
    native.save(dataclasses.replace(m, lanes=lanes), path)
    return path


def test_no_lane_change_onto_a_lane_before_it_begins(opening_lane):
    """A car on R2_0 behind a car standing at x = 60 wants the free lane R2_1 (MOBIL), but R2_1
    begins only at x = 49.5: the car is never on R2_1 before that (fails without the rule: it
    changed at once, 25 m before the lane began, and drove on through the standing car's lane)."""
    sc = Scenario("fixture", str(opening_lane), (("J0", "R1", "R3"),), seed=0, duration=20.0)
    # the load reports the connectors whose successor R2_1 begins 30 m on (the fixture's point)
    with pytest.warns(UserWarning, match=r"opening_lane\.json: lane J0_c\d+_0: successor R2_1 starts 30\.0 m") as rec:
        env = make_env(sc, config={"traffic_vehicles": 0, "traffic_respawn": False})
        env.reset(seed=0)
    assert all(str(opening_lane) in str(w.message) for w in rec), [str(w.message) for w in rec]
    u = env.unwrapped
    core = u.road.core
    blocker = core.add_traffic(u.road, "R2_0", 40.5, 0.0, ["R2_0"])
    blocker.crashed = True  # stands where it is
    car = core.add_traffic(u.road, "R2_0", 2.0, 10.0, ["R2_0"])
    for _ in range(60):
        u.road.act()
        u.road.step(1 / u.config["simulation_frequency"])
        lane = u.net.id_of.get(car.lane_index)
        x = float(car.position[0])
        assert lane != "R2_1" or x >= OPENS_AT_X, f"on R2_1 at x = {x:.1f}, before it begins"
        if x > 45.0 or car.speed < 0.1:
            break
    env.close()
    assert not car.crashed


# ---- a junction path drawn over the last metre of an approach (osm2xodr clusters) ---------------

def test_stop_line_lies_clear_of_a_junction_path_drawn_over_the_approach():
    """A generated signalled 4-way junction whose right turn from R1 (J0_c3_0) is redrawn to cut
    across R0_1's last metre, as osm2xodr draws a cluster's paths over an approach (scheck-in's
    `j_14959944_c98`, 0.9 m from the centre of `w268002703_2_0_-1` at its line): R0_1's line moves
    back to clear it by half its width and CROSSING_CLEARANCE_M (fails without the rule: the line
    stays at the lane's end, and the car waiting there stood in the path). Another approach's
    line, which nothing crosses, stays where it was."""
    from feat2map.config import CROSSING_CLEARANCE_M
    from feat2map.envs.network import MapNetwork

    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "signal", False)], seed=0)
    base = MapNetwork.from_map(m).stop_lines
    ln = m.lanes["J0_c3_0"]
    # from R1_1's end (1.75, -19.5) west across R0_1 (y = -1.75) 1 m before its end (x = -20.5), to R2_0's start
    pts = np.array([m.lanes["R1_1"].centerline[-1], (-20.5, -8.0), (-20.5, -1.75), (-20.5, 4.0),
                    m.lanes["R2_0"].centerline[0]], dtype=float)
    tup = lambda a: tuple(map(tuple, a))  # noqa: E731
    redrawn = dataclasses.replace(ln, centerline=tup(pts), left_boundary=tup(pts), right_boundary=tup(pts), bezier=None)
    lines = MapNetwork.from_map(dataclasses.replace(m, lanes={**m.lanes, "J0_c3_0": redrawn})).stop_lines
    assert base["R0_1"].s == pytest.approx(25.0)
    # the path runs onto R0_1 at x = -20.5, s = 24.0 (R0_1 runs from x = -44.5 to -19.5)
    assert lines["R0_1"].s == pytest.approx(24.0 - ln.width / 2 - CROSSING_CLEARANCE_M, abs=0.05)
    assert lines["R3_1"].s == pytest.approx(base["R3_1"].s)


# ---- lane changes only across a dashed line ---------------------------------------------------

@pytest.mark.parametrize("line", ["dotted_white", "solid_white"])
def test_traffic_changes_lanes_only_across_a_dashed_line(tmp_path, line):
    """A car on R2_0 behind a standing car changes onto the free neighbour R2_1 (MOBIL) across a
    dashed line, and stays behind it across a solid one (it changed across any line before)."""
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180, 270], "bare", False, lanes=2)],
                                        seed=0, config=feat2map.GenerationConfig(grid_gap=300.0, stub_length=100.0))
    lanes = dict(m.lanes)
    assert "R2_1" in m.lanes["R2_0"].right_neighbors and m.lanes["R2_0"].length > 90
    lanes["R2_0"] = dataclasses.replace(m.lanes["R2_0"], right_boundary_type=line)
    lanes["R2_1"] = dataclasses.replace(m.lanes["R2_1"], left_boundary_type=line)
    path = tmp_path / "lines.json"
    native.save(dataclasses.replace(m, lanes=lanes), path)
    env = make_env(Scenario("fixture", str(path), (("J0", "R1", "R3"),), seed=0, duration=20.0),
                   config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    blocker = u.road.core.add_traffic(u.road, "R2_0", 50.0, 0.0, ["R2_0"])
    blocker.crashed = True  # stands where it is
    car = u.road.core.add_traffic(u.road, "R2_0", 2.0, 10.0, ["R2_0"])
    seen = set()
    for _ in range(150):
        u.road.act()
        u.road.step(1 / u.config["simulation_frequency"])
        seen.add(u.net.id_of.get(car.lane_index))
        if car.speed < 0.1:
            break
    env.close()
    assert ("R2_1" in seen) == (line == "dotted_white"), seen
