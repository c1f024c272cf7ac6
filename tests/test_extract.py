"""Junction extraction (feat2map.extract) on maps built here in code: where sockets point when a
junction's centre lies beyond one of its mouths."""
from __future__ import annotations

import math
import warnings

import numpy as np
import pytest

from feat2map.extract import SkippedJunction, extract_junctions
from feat2map.model import HDMap, Junction, Lane, Road, as_polyline

W = 3.5  # lane width


def _lane(lid: str, road: str, pts, preds=(), succs=(), junction: str | None = None) -> Lane:
    """A lane along `pts` with borders W/2 to either side."""
    p = np.asarray(pts, dtype=float)
    d = np.gradient(p, axis=0)
    n = np.c_[-d[:, 1], d[:, 0]] / np.hypot(d[:, 0], d[:, 1])[:, None]
    return Lane(lid, road, as_polyline(p), as_polyline(p + n * W / 2), as_polyline(p - n * W / 2), W, 20.0,
                predecessors=tuple(preds), successors=tuple(succs), junction_id=junction)


def _merge_map(ramp_deg: float, mouth_y: float = -6.0) -> HDMap:
    """A one-way road of two lanes (y = 0 and y = W, heading +x) running straight through a
    junction from x = 0 to x = 12, and a one-lane on-ramp that meets the junction at (1, -6)
    heading `ramp_deg` and merges into the right lane. The junction's outline reaches 30 m
    along the road (as CARLA's 2019 Town06 draws its merges, with the shoulders), so the lines
    of the three arms meet beyond the out mouths: both arms of the through road lie on one
    side of that point."""
    a = math.radians(ramp_deg)
    mouth = np.array([1.0, mouth_y])
    ramp_start = mouth - 40.0 * np.array([math.cos(a), math.sin(a)])
    lanes = [
        _lane("in_r", "in", [(-40, 0), (-20, 0), (0, 0)], succs=["j_r"]),
        _lane("in_l", "in", [(-40, W), (-20, W), (0, W)], succs=["j_l"]),
        _lane("j_r", "jr", [(0, 0), (6, 0), (12, 0)], preds=["in_r"], succs=["out_r"], junction="J"),
        _lane("j_l", "jl", [(0, W), (6, W), (12, W)], preds=["in_l"], succs=["out_l"], junction="J"),
        _lane("j_ramp", "jramp", [tuple(mouth), (6, mouth_y / 3), (12, 0)], preds=["ramp"], succs=["out_r"], junction="J"),
        _lane("out_r", "out", [(12, 0), (32, 0), (52, 0)], preds=["j_r", "j_ramp"]),
        _lane("out_l", "out", [(12, W), (32, W), (52, W)], preds=["j_l"]),
        _lane("ramp", "ramp", [tuple(ramp_start), tuple((ramp_start + mouth) / 2), tuple(mouth)], succs=["j_ramp"]),
    ]
    lanes = [ln if ln.id not in ("in_r", "out_r") else Lane(**{**ln.__dict__, "left_neighbors": (
        "in_l" if ln.id == "in_r" else "out_l",)}) for ln in lanes]
    roads = {r: Road(r, "junction" if r.startswith("j") else "road", junction_id="J" if r.startswith("j") else None)
             for r in {ln.road_id for ln in lanes}}
    outline = as_polyline([(0, -7), (30, -7), (30, W + W / 2), (0, W + W / 2)])
    return HDMap({ln.id: ln for ln in lanes}, roads, {"J": Junction("J", outline)})


def test_a_road_running_straight_through_a_merge_keeps_its_arms_apart():
    """CARLA's 2019 Town06 draws each on-ramp as a junction on a straight one-way motorway: the
    arms' lines meet beyond the out mouths, and angles measured from there put the motorway's
    in and out arms at one angle (180.03 and 180.03 degrees): 9 of its merges were skipped as
    "sockets 0.00 degrees apart". Where the centre lies behind a mouth and its angles break the
    leg rule, each socket takes its road's own direction: in 180, out 0, the ramp 30 degrees off
    the motorway's incoming arm."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        skipped: list[SkippedJunction] = []
        (j,) = extract_junctions(_merge_map(30.0), skipped=skipped)
    assert not skipped
    by_kind = {(a.lanes_in, a.lanes_out): a.angle_deg for a in j.arms}
    assert set(by_kind) == {(2, 0), (0, 2), (1, 0)}
    assert by_kind[(2, 0)] == pytest.approx(180.0, abs=1e-6) or by_kind[(2, 0)] == pytest.approx(-180.0, abs=1e-6)
    assert by_kind[(0, 2)] == pytest.approx(0.0, abs=1e-6)
    assert by_kind[(1, 0)] % 360 == pytest.approx(210.0, abs=1e-6)  # the ramp's road, outward from its mouth


def test_a_ramp_closer_than_the_leg_rule_is_a_ramp_junction():
    """The same merge with a ramp 12 degrees off the motorway breaks the leg rule, and is an
    on-ramp: the arm that only enters lies counter-clockwise next to the motorway's incoming arm
    (right-hand traffic), with the angles its roads have (not two arms at one angle)."""
    skipped: list[SkippedJunction] = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        (j,) = extract_junctions(_merge_map(12.0, -2.0), skipped=skipped)
    assert not skipped
    assert j.feature.ramps.count("on") == 1 and j.feature.ramp_value == "on"
    by_ramp = {s.ramp: s for s in j.feature.sockets}
    assert (by_ramp["on"].lanes_in, by_ramp["on"].lanes_out) == (1, 0)
    assert [round(a, 6) for a in j.feature.rotation] == [0.0, 12.0, 180.0]  # normalized: the smallest listing
    assert j.feature.ramp_length == pytest.approx(12.0, abs=0.01)  # between the motorway's mouths


def _ramp_pair_map(along_m: float) -> HDMap:
    """A junction on a one-way road (west to east) with an exit ramp leaving south from (0, -20)
    and an entry ramp coming north into (5, -20 + along_m): the ramps' mouths lie 5 m across
    and `along_m` along their arm (ASAM's motorway example draws its two ramp pairs 15 m
    apart)."""
    entry = (5.0, -20.0 + along_m)
    lanes = [
        _lane("main_in", "main_in", [(-70, 0), (-50, 0), (-30, 0)], succs=["j_main", "j_exit"]),
        _lane("main_out", "main_out", [(30, 0), (50, 0), (70, 0)], preds=["j_main", "j_entry"]),
        _lane("exit", "exit", [(0, -20), (0, -40), (0, -60)], preds=["j_exit"]),
        _lane("entry", "entry", [(5, -60), (5, -40), entry], succs=["j_entry"]),
        _lane("j_main", "j1", [(-30, 0), (0, 0), (30, 0)], preds=["main_in"], succs=["main_out"], junction="J"),
        _lane("j_exit", "j2", [(-30, 0), (-5, -5), (0, -20)], preds=["main_in"], succs=["exit"], junction="J"),
        _lane("j_entry", "j3", [entry, (10, -2), (30, 0)], preds=["entry"], succs=["main_out"], junction="J"),
    ]
    roads = {r: Road(r, "junction" if r.startswith("j") else "road", junction_id="J" if r.startswith("j") else None)
             for r in {ln.road_id for ln in lanes}}
    return HDMap({ln.id: ln for ln in lanes}, roads, {"J": Junction("J", as_polyline([(-30, -20), (30, -20), (30, 2),
                                                                                         (-30, 2)]))})


def test_ramps_at_an_arm_limit_fall_on_one_side_of_it_whatever_the_rounding():
    """Mouths exactly ARM_MAX_DEPTH_M apart along their arm are apart, with either rounding:
    an OpenDRIVE export and re-read moved ASAM's ramp pairs by 1e-12 m across the limit, and
    its motorway junction went from skipped (4 arms) to extracted (3 arms)."""
    from feat2map.config import ARM_MAX_DEPTH_M
    arms = []
    for noise in (-1e-9, 0.0, 1e-9):
        skipped: list[SkippedJunction] = []
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            extracted = extract_junctions(_ramp_pair_map(ARM_MAX_DEPTH_M + noise), skipped=skipped)
        arms += [len(j.arms) for j in extracted] + [s.n_arms for s in skipped]
    assert arms == [4, 4, 4]  # the ramps are two arms, however the limit's distance rounds
