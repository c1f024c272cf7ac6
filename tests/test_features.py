"""Feature model: validation, rotation normalization (exact vs brute force), JSON round trips."""
from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from feat2map.errors import FeatureError
from feat2map.features import (PAPER_SF_FEATURE_SPACE, FeatureSpace, JunctionFeature, alignment_cost,
                               best_alignment, normalize_rotation)

angle_sets = st.lists(st.floats(0, 360, exclude_max=True, allow_nan=False), min_size=3, max_size=8).filter(
    lambda a: min(np.diff(np.sort(np.append(a, min(a) + 360)))) > 1.0)


@settings(max_examples=200, deadline=None)
@given(angle_sets)
def test_exact_alignment_matches_brute_force(angles):
    norm = normalize_rotation(angles)
    offsets = [a - norm.angles[0] for a in norm.angles]
    exact = alignment_cost(norm.angles[0], offsets)
    grid = np.arange(-45.0, 45.0, 0.005)
    brute = min(alignment_cost(a, offsets) for a in grid)
    assert exact <= brute + 1e-6
    assert -45.0 <= norm.angles[0] < 45.0
    assert all(b > a for a, b in zip(norm.angles, norm.angles[1:]))
    assert norm.angles[-1] < norm.angles[0] + 360.0


@settings(max_examples=100, deadline=None)
@given(angle_sets, st.floats(-720, 720, allow_nan=False), st.randoms())
def test_normalization_ignores_rotation_and_input_order(angles, turn, rnd):
    shuffled = list(angles)
    rnd.shuffle(shuffled)
    a = normalize_rotation(angles).angles
    b = normalize_rotation([x + turn for x in shuffled]).angles
    # equal up to ties between equally good alignments, which give equal costs
    if not np.allclose(a, b, atol=1e-6):
        oa = [x - a[0] for x in a]
        ob = [x - b[0] for x in b]
        assert alignment_cost(a[0], oa) == pytest.approx(alignment_cost(b[0], ob), abs=1e-6)


@settings(max_examples=100, deadline=None)
@given(angle_sets)
def test_largest_gap_closes_the_cycle(angles):
    norm = normalize_rotation(angles).angles
    gaps = np.diff(np.append(norm, norm[0] + 360.0))
    assert gaps[-1] >= gaps.max() - 1e-9


def test_normalization_of_a_t_junction():
    norm = normalize_rotation([90 + 7, 270 + 7, 0 + 7])
    # the 180-degree gap (from the 97 to the 277 socket) closes the cycle: 277 becomes socket 1
    assert np.allclose(norm.angles, [0.0, 90.0, 180.0])
    assert norm.order == (1, 2, 0)
    assert norm.rotation_deg == pytest.approx(83.0)
    assert best_alignment([0.0, 90.0, 180.0]) == 0.0


@pytest.mark.parametrize("kwargs, message", [
    (dict(angles=[0, 90]), "at least 3 roads"),
    (dict(angles=[0, 180, 90]), "strictly increasing"),
    (dict(angles=[0, 90, 90]), "strictly increasing"),
    (dict(angles=[0, 10, 180]), "minimum separation"),
    (dict(angles=[0, 90, 180], control="yield"), "unknown control"),
    (dict(angles=[0, 90, 400]), "span less than 360"),
    (dict(angles=[0, 90, 180], road_types=["in", "in", "in"]), "outgoing"),
    (dict(angles=[0, 90, 180], road_types=["in", "sideways", "out"]), "unknown road type"),
])
def test_invalid_features_are_rejected(kwargs, message):
    with pytest.raises(FeatureError, match=message):
        JunctionFeature.make(**kwargs)


def test_min_separation_is_configurable():
    """Legs 10 degrees apart: refused under the default rule, accepted when the caller lowers it
    (and then still refused below the lowered one)."""
    with pytest.raises(FeatureError, match="minimum separation"):
        JunctionFeature.make([0, 10, 180])
    f = JunctionFeature.make([0, 10, 180], min_separation_deg=5)
    assert f.rotation == (0.0, 10.0, 180.0) and f.n_roads == 3
    with pytest.raises(FeatureError, match="minimum separation"):
        JunctionFeature.make([0, 4, 180], min_separation_deg=5)


def test_feature_dict_round_trip():
    f = JunctionFeature.make([0, 72, 144, 216, 288], "signal", True, ["in", "out", "in-out", "in-out", "in-out"],
                             [2, 1, 1, 3, 1])
    assert JunctionFeature.from_dict(f.to_dict()) == f


def test_feature_space_json_round_trip_and_validation():
    space = PAPER_SF_FEATURE_SPACE
    assert FeatureSpace.from_json(space.to_json()) == space
    bad = space.to_dict()
    bad["rotation_ranges"]["3"] = bad["rotation_ranges"]["3"][:2]
    with pytest.raises(FeatureError, match=r"rotation_ranges.3.*needs 3 angle ranges"):
        FeatureSpace.from_dict(bad)
    bad = space.to_dict()
    bad["controls"] = ["signal", "roundabout"]
    with pytest.raises(FeatureError, match="unknown control"):
        FeatureSpace.from_dict(bad)
    with pytest.raises(FeatureError, match="not valid JSON"):
        FeatureSpace.from_json("{", "x.json")
    bad = space.to_dict()
    bad["rotation_ranges"]["4"][1] = [-100, -90]
    with pytest.raises(FeatureError, match="increase counter-clockwise"):
        FeatureSpace.from_dict(bad)


def test_merge_is_union_of_values_and_ranges():
    a = FeatureSpace.from_features([JunctionFeature.make([0, 90, 180], "stop")])
    b = FeatureSpace.from_features([JunctionFeature.make([10, 100, 200], "signal", True),
                                    JunctionFeature.make([0, 90, 180, 270], "bare")])
    m = a.merge(b)
    assert m.road_counts == (3, 4)
    assert m.controls == ("bare", "signal", "stop")
    assert m.crosswalks == (True, False)
    assert m.rotation_ranges[3] == ((0.0, 10.0), (90.0, 100.0), (180.0, 200.0))
    assert json.loads(m.to_json())["road_counts"] == [3, 4]
