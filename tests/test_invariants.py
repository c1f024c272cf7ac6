"""Invariants on every leg count, outside the paper's feature space: random feature spaces of
3-8 legs (generate), random specs (build_spec) and random features with one-way and
multi-lane legs (generate_from_features) give maps without a single check_map violation,
or a clear Feat2MapError; the Apollo validator catches what check_map catches.

Hypothesis draws new examples on every run (no example database in CI), so the runs add up;
the profile (tests/conftest.py) sets how many per run: "ci" (default: 100 per test, a few
hundred maps in all) or, with FEAT2MAP_LONG_TESTS=1, "thorough" (1,500 per test, thousands).
"""
from __future__ import annotations

import contextlib

import dataclasses
import math

import pytest
from hypothesis import event, given, settings
from hypothesis import strategies as st

import feat2map
from feat2map.config import LANE_END_SNAP_M, MAX_LEGS, MIN_LEG_SEPARATION_DEG, MIN_STUB_LENGTH_M, GenerationConfig
from feat2map.construct import junction_radius
from feat2map.errors import Feat2MapError
from feat2map.features import FeatureSpace, JunctionFeature
from feat2map.formats import write_map
from feat2map.invariants import check_map, exits_reached
from feat2map.spec import build_spec, parse_spec

LEGS = st.integers(3, MAX_LEGS)


@st.composite
def leg_angles(draw, n: int) -> list[float]:
    """n counter-clockwise angles at least the leg rule apart: gaps of the rule plus random shares."""
    spare = 360.0 - n * MIN_LEG_SEPARATION_DEG - 1e-6
    weights = draw(st.lists(st.floats(0.05, 1.0), min_size=n, max_size=n))
    gaps = [MIN_LEG_SEPARATION_DEG + spare * w / sum(weights) for w in weights]
    start = draw(st.floats(-180.0, 180.0))
    return [start + sum(gaps[:i]) for i in range(n)]


@st.composite
def junction_features(draw, one_way: bool = True) -> JunctionFeature:
    """A junction of 3-8 legs; with `one_way`, legs may be one-way and have 1-3 lanes (two
    legs stay two-way, so every approach has a way through it)."""
    n = draw(LEGS)
    angles = draw(leg_angles(n))
    types = ["in-out"] * n
    lanes = [1] * n
    if one_way:
        two_way = set(draw(st.permutations(range(n)))[:2])
        types = [t if i in two_way else draw(st.sampled_from(["in-out", "in", "out"])) for i, t in enumerate(types)]
        lanes = draw(st.lists(st.integers(1, 3), min_size=n, max_size=n))
    return JunctionFeature.make(angles, draw(st.sampled_from(["bare", "signal", "stop"])), draw(st.booleans()),
                                road_types=types, lanes=lanes)


def roomy(features, **kw) -> GenerationConfig:
    """A config whose grid leaves every junction the room its lanes need (a tighter grid is a
    clear LayoutError, tested elsewhere)."""
    base = GenerationConfig(**kw)
    need = max((junction_radius(f.normalized(), base) for f in features), default=0.0)
    return dataclasses.replace(base, grid_gap=max(base.grid_gap, math.ceil(2 * (need + MIN_STUB_LENGTH_M +
                                                                                 base.junction_margin + 1))))


def assert_valid(m) -> None:
    problems = check_map(m)
    assert problems == [], problems[:5]


@settings(deadline=None)
@given(st.lists(junction_features(), min_size=1, max_size=4), st.integers(0, 2**32 - 1))
def test_random_features_with_one_way_and_multi_lane_legs(features, seed):
    try:
        m = feat2map.generate_from_features(features, seed=seed, config=roomy(features))
    except Feat2MapError as exc:  # an impossible layout or network is refused, naming why
        event(f"refused: {type(exc).__name__}")
        assert str(exc) and "\n" not in str(exc)
        return
    event("built")
    assert len(m.junctions) == len(features)
    assert_valid(m)


@settings(deadline=None)
@given(st.lists(junction_features(), min_size=1, max_size=3), st.integers(0, 2**32 - 1), st.booleans())
def test_random_specs(features, seed, cells):
    junctions = []
    for i, f in enumerate(features):
        j = {"control": f.control, "crosswalk": f.crosswalk,
             "sockets": [{"angle": s.angle, "lanes_in": s.lanes_in, "lanes_out": s.lanes_out} for s in f.sockets]}
        if cells:
            j["cell"] = [i, 0]
        junctions.append(j)
    cfg = roomy(features)
    try:
        m = build_spec(parse_spec({"version": 1, "config": {"grid_gap": cfg.grid_gap}, "junctions": junctions}, "s"),
                       seed=seed)
    except Feat2MapError as exc:
        event(f"refused: {type(exc).__name__}")
        assert str(exc).startswith("s") and "\n" not in str(exc)
        return
    event("built")
    assert_valid(m)


@st.composite
def feature_spaces(draw) -> FeatureSpace:
    counts = draw(st.sets(LEGS, min_size=1, max_size=3))
    ranges = {}
    for n in counts:
        step = 360.0 / n
        spread = max(0.0, (step - MIN_LEG_SEPARATION_DEG) / 2 - 0.5)  # any draw keeps the leg rule
        ranges[n] = tuple((i * step - s, i * step + s) for i, s in
                          enumerate(draw(st.lists(st.floats(0.0, spread), min_size=n, max_size=n))))
    return FeatureSpace(tuple(counts), tuple(draw(st.sets(st.sampled_from(["bare", "signal", "stop"]), min_size=1))),
                        tuple(draw(st.sets(st.booleans(), min_size=1))), ranges)


@settings(deadline=None)
@given(feature_spaces(), st.integers(0, 2**32 - 1))
def test_random_feature_spaces_of_3_to_8_legs(space, seed):
    m = feat2map.generate(space, seed=seed)
    assert_valid(m)
    assert sorted(j.feature.n_roads for j in m.junctions.values()) == sorted(
        n for n in space.road_counts for _ in range(len(space.controls) * len(space.crosswalks)))


# ------------------------------------------------------------------ the validator sees the same defects

@pytest.fixture(scope="module")
def sound_maps():
    """A two-way map and one with one-way legs, both without violations."""
    J = JunctionFeature.make
    two_way = feat2map.generate_from_features([J([0, 90, 180, 270], "signal", True), J([0, 120, 240], "stop")], seed=1)
    one_way = feat2map.generate_from_features([J([0, 90, 180, 270], "bare", False, road_types=["in-out", "in", "in-out",
                                                                                               "out"])], seed=1)
    assert check_map(two_way) == [] == check_map(one_way)
    return two_way, one_way


def _moved(m, dx, dy, prefix):
    """`m` moved by (dx, dy) with every id prefixed: a second, separate network."""
    def mv(pts):
        return tuple((x + dx, y + dy) for x, y in pts)

    def ids(xs):
        return tuple(prefix + x for x in xs)
    lanes = {prefix + k: dataclasses.replace(
        ln, id=prefix + k, road_id=prefix + ln.road_id, centerline=mv(ln.centerline),
        left_boundary=mv(ln.left_boundary), right_boundary=mv(ln.right_boundary), bezier=None, predecessors=ids(ln.predecessors),
        successors=ids(ln.successors), left_neighbors=ids(ln.left_neighbors), right_neighbors=ids(ln.right_neighbors),
        left_reverse_neighbors=ids(ln.left_reverse_neighbors),
        junction_id=None if ln.junction_id is None else prefix + ln.junction_id) for k, ln in m.lanes.items()}
    roads = {prefix + k: dataclasses.replace(r, id=prefix + k, right_lanes=ids(r.right_lanes), left_lanes=ids(r.left_lanes),
                                             reference=None,
                                             junction_id=None if r.junction_id is None else prefix + r.junction_id,
                                             start_junction=None if r.start_junction is None else prefix + r.start_junction,
                                             end_junction=None if r.end_junction is None else prefix + r.end_junction)
             for k, r in m.roads.items()}
    junctions = {prefix + k: dataclasses.replace(j, id=prefix + k, polygon=mv(j.polygon), feature=None,
                                                 socket_roads=ids(j.socket_roads)) for k, j in m.junctions.items()}
    return lanes, roads, junctions


def _dead_end(m):
    """Remove every junction lane out of one incoming lane (and the references to them): it
    becomes a dead end at its junction."""
    gone = set(next(ln.successors for ln in m.lanes.values() if ln.junction_id is None and ln.successors))
    lanes = {k: dataclasses.replace(ln, predecessors=tuple(x for x in ln.predecessors if x not in gone),
                                    successors=tuple(x for x in ln.successors if x not in gone))
             for k, ln in m.lanes.items() if k not in gone}
    dropped = {m.lanes[x].road_id for x in gone}
    return dataclasses.replace(m, lanes=lanes, roads={k: r for k, r in m.roads.items() if k not in dropped})


def _defect(maps, defect):
    two_way, one_way = maps
    m = one_way if "one-way" in defect else two_way
    if defect == "overlapping roads":  # a second network laid across the first, links intact
        lanes, roads, junctions = _moved(m, 37.0, 41.0, "B")
        return dataclasses.replace(m, lanes={**m.lanes, **lanes}, roads={**m.roads, **roads},
                                   junctions={**m.junctions, **junctions}, signals={}, stop_signs={}, crosswalks={})
    if defect == "overlapping junctions":  # a second junction area over the first
        first = next(iter(m.junctions.values()))
        return dataclasses.replace(m, junctions={**m.junctions, "copy": dataclasses.replace(first, id="copy")})
    if defect.startswith("dead end"):
        return _dead_end(m)
    if defect == "broken link":  # beyond the seams the exports close (LANE_END_SNAP_M)
        return _seam(m, LANE_END_SNAP_M + 1.0)
    first = next(iter(m.crosswalks.values()))  # overlapping crosswalks
    return dataclasses.replace(m, crosswalks={**m.crosswalks, "copy": dataclasses.replace(first, id="copy")})


def _seam(m, gap: float):
    """`m` with one road lane's end moved `gap` metres off its successor's start."""
    lid = next(ln.id for ln in m.lanes.values() if ln.junction_id is None and ln.successors)
    ln = m.lanes[lid]
    return dataclasses.replace(m, lanes={**m.lanes, lid: dataclasses.replace(
        ln, centerline=ln.centerline[:-1] + ((ln.end[0] + gap, ln.end[1]),), bezier=None)})


def test_the_apollo_export_closes_a_seam_it_may_close(sound_maps, tmp_path):
    """A seam up to LANE_END_SNAP_M between linked lanes (real maps carry 0.1-0.5 m ones) is
    closed by bending the lane into its successor: the export validates and is written."""
    m = _seam(sound_maps[0], 0.5)
    assert check_map(m)
    write_map(m, tmp_path / "apollo", "apollo")
    assert (tmp_path / "apollo" / "base_map.bin").is_file()


@pytest.mark.parametrize("defect", ["overlapping roads", "overlapping junctions", "dead end", "dead end, one-way roads",
                                    "broken link", "overlapping crosswalks"])
def test_the_apollo_validator_catches_what_check_map_catches(sound_maps, tmp_path, defect):
    m = _defect(sound_maps, defect)
    # the copied junction area owns no lanes of its own: the junction checks say they skip it
    expected = (pytest.warns(UserWarning, match=r"^map: junction copy: no lanes or no valid polygon, skipped")
                if defect == "overlapping junctions" else contextlib.nullcontext())
    with expected:
        assert check_map(m), defect
        # the export holds a generated map to validate's rules before writing: it refuses it
        with pytest.raises(Feat2MapError, match="refusing to export a map that would not validate"):
            write_map(m, tmp_path / "apollo", "apollo")
    assert not (tmp_path / "apollo").exists()


@given(st.integers(1, 40).flatmap(lambda n: st.tuples(
    st.just(n), st.lists(st.tuples(st.integers(0, n - 1), st.integers(0, n - 1)), max_size=3 * n),
    st.sets(st.integers(0, n - 1)))))
def test_exits_reached_is_what_a_search_from_each_node_finds(graph):
    """The route checks' one-pass reachability (bit sets over strongly connected components)
    gives, for every node of a random directed graph with cycles, the exits a search finds."""
    n, edges, exit_nodes = graph
    adj: dict[str, list[str]] = {str(i): [] for i in range(n)}
    for a, b in edges:
        adj[str(a)].append(str(b))
    exits = [str(i) for i in sorted(exit_nodes)]
    reached = exits_reached(adj, adj.__getitem__, exits)
    for start in adj:
        seen, todo = {start}, [start]
        while todo:
            for nxt in adj[todo.pop()]:
                if nxt not in seen:
                    seen.add(nxt)
                    todo.append(nxt)
        assert [x for i, x in enumerate(exits) if reached[start] >> i & 1] == [x for x in exits if x in seen]


# ------------------------------------------------------------------ the one leg rule

def test_the_leg_rule_is_one_rule_for_specs_features_generation_and_extraction():
    """Legs at least MIN_LEG_SEPARATION_DEG apart, one-way ones side by side included, come
    back from extraction as as many legs; closer legs and a ninth leg are refused everywhere."""
    from feat2map.config import LEG_MERGE_DEG
    from feat2map.extract import extract_junctions

    assert LEG_MERGE_DEG < MIN_LEG_SEPARATION_DEG
    angles = [0, 20, 40, 90, 150, 200, 222, 290]  # 8 legs, gaps of exactly the rule among them
    types = ["in", "in", "in-out", "out", "in-out", "out", "out", "in-out"]
    spec = {"version": 1, "config": {"grid_gap": 240}, "junctions": [
        {"sockets": [{"angle": a, "type": t} for a, t in zip(angles, types)], "control": "signal"}]}
    m = build_spec(parse_spec(spec, "eight.yaml"))
    (got,) = extract_junctions(m)
    assert got.feature.n_roads == 8 and check_map(m) == []
    closer = {**spec, "junctions": [{"sockets": [0, 19, 90, 180]}]}
    with pytest.raises(Feat2MapError, match="minimum separation 20"):
        parse_spec(closer, "close.yaml")
    with pytest.raises(Feat2MapError, match="at most 8"):
        JunctionFeature.make([i * 36.0 for i in range(9)])
    with pytest.raises(Feat2MapError, match="3 to 8"):
        FeatureSpace((9,), ("bare",), (False,), {9: tuple((i * 40.0, i * 40.0) for i in range(9))})
    with pytest.raises(Feat2MapError, match="min_socket_separation_deg"):
        GenerationConfig(min_socket_separation_deg=MIN_LEG_SEPARATION_DEG - 1)


def test_a_junction_needs_a_way_through_for_every_approach():
    with pytest.raises(Feat2MapError, match="dead ends"):  # the in-out leg's lanes could only U-turn
        JunctionFeature.make([0, 90, 180], road_types=["in", "in-out", "in"])
    with pytest.raises(Feat2MapError, match="nothing could drive into them"):
        JunctionFeature.make([0, 90, 180], road_types=["out", "in-out", "out"])
    JunctionFeature.make([0, 90, 180], road_types=["in", "in-out", "out"])


def test_roads_that_would_cross_are_laid_out_again():
    """A 4-leg junction whose legs both serve grid directions far from them would sweep one
    road across another's start (first found by the property test; angles re-found when nearly
    opposite legs stopped widening junctions): generation lays the map out again with sockets
    within 45 degrees, and the map is clean."""
    import numpy as np

    from feat2map.construct import build_map
    from feat2map.errors import CrossingRoadsError
    from feat2map.layout import place

    J = JunctionFeature.make
    features = [J([0, 120, 240], lanes=[1, 1, 2]), J([0, 90, 180, 270], lanes=[1, 1, 1, 2]), J([0, 120, 240]),
                J([0, 58.882, 229.988, 303.014], lanes=[2, 2, 1, 1])]
    cfg = GenerationConfig()
    with pytest.raises(CrossingRoadsError):
        build_map(place([f.normalized() for f in features], np.random.default_rng([0, 1])), cfg)
    assert check_map(feat2map.generate_from_features(features, seed=0, config=cfg)) == []
