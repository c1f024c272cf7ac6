"""Junction extraction on the real maps in ../shared/maps (issue 3's acceptance numbers).

Every test skips cleanly when the folder is absent. Maps are read once per module.
"""
from __future__ import annotations

import json
import math
import warnings
from collections import Counter
from functools import lru_cache

import pytest

from conftest import read_shared_map, shared_map
from feat2map.cli import main
from feat2map.extract import ExtractedJunction, SkippedJunction, extract_junctions, map_feature
from feat2map.readers import read_map

pytestmark = pytest.mark.real_maps


@lru_cache(maxsize=None)
def _extract(rel: str) -> tuple[tuple[ExtractedJunction, ...], tuple[SkippedJunction, ...]]:
    skipped: list[SkippedJunction] = []
    m = read_shared_map(rel)
    with warnings.catch_warnings(record=True) as warned:  # each skipped junction, named with the map
        warnings.simplefilter("always")
        found = extract_junctions(m, rel, skipped=skipped)
    assert all(str(w.message).startswith(f"{rel}: junction ") for w in warned), [str(w.message) for w in warned]
    return tuple(found), tuple(skipped)


def _controls(found, skipped) -> Counter:
    return Counter([j.feature.control for j in found] + [s.control for s in skipped])


def test_san_francisco():
    found, skipped = _extract("apollo/san_francisco/base_map.bin")
    assert len(found) + len(skipped) == 91
    assert _controls(found, skipped) == {"signal": 88, "stop": 3}
    assert sum(j.feature.crosswalk for j in found) + sum(s.crosswalk for s in skipped) == 13
    assert {j.feature.n_roads for j in found} == {3, 4}
    # the two skipped elements are signalled road bends, not junctions of 3+ roads
    assert [(s.n_arms, s.control) for s in skipped] == [(2, "signal"), (2, "signal")]
    space = map_feature(found)
    assert space.road_counts == (3, 4) and set(space.controls) == {"signal", "stop"}
    assert set(space.crosswalks) == {True, False}


def test_gomentum_has_signal_stop_and_bare():
    found, skipped = _extract("apollo/gomentum/base_map.bin")
    assert len(found) + len(skipped) == 33
    assert {j.feature.control for j in found} == {"signal", "stop", "bare"}
    assert {j.feature.n_roads for j in found} <= {3, 4}


def test_shalun():
    found, skipped = _extract("apollo/shalun/base_map.bin")
    assert len(found) == 17 and not skipped
    assert _controls(found, skipped) == {"signal": 8, "stop": 9}
    assert {j.feature.n_roads for j in found} == {3, 4}


def test_carla_town01_twelve_signalized_t_junctions():
    found, _ = _extract("opendrive/carla_town01/Town01.xodr")
    assert [(j.feature.n_roads, j.feature.control) for j in found] == [(3, "signal")] * 12


def test_carla_town05_21_intersections():
    found, _ = _extract("opendrive/carla_town05/Town05.xodr")
    assert Counter(j.feature.n_roads for j in found) == {3: 8, 4: 13}


def _wrap(d: float) -> float:
    return (d + 180.0) % 360.0 - 180.0


def _cyclic_fit(x: ExtractedJunction, y: ExtractedJunction) -> tuple[float, bool]:
    """Largest socket-angle error after the best common rotation and cyclic matching of the
    two junctions' arms (the files use different frames, and near-equal largest gaps may start
    the normalized order at different sockets), and whether lanes per socket agree there."""
    a = sorted(x.arms, key=lambda r: r.angle_deg % 360.0)
    b = sorted(y.arms, key=lambda r: r.angle_deg % 360.0)
    n = len(a)
    best = (math.inf, False)
    for shift in range(n):
        diffs = [_wrap(b[(i + shift) % n].angle_deg - a[i].angle_deg) for i in range(n)]
        mean = math.degrees(math.atan2(sum(math.sin(math.radians(d)) for d in diffs),
                                       sum(math.cos(math.radians(d)) for d in diffs)))
        err = max(abs(_wrap(d - mean)) for d in diffs)
        lanes = all((a[i].lanes_in, a[i].lanes_out) == (b[(i + shift) % n].lanes_in, b[(i + shift) % n].lanes_out)
                    for i in range(n))
        best = min(best, (err, lanes), key=lambda t: (not t[1], t[0]))
    return best


@pytest.mark.parametrize("apollo, xodr", [
    ("apollo/borregas_ave/base_map.bin", "opendrive/svl_borregas_ave/borregasave.xodr"),
    ("apollo/cube_town/base_map.bin", "opendrive/svl_cubetown/cubetown.xodr"),
])
def test_same_map_in_two_formats_agrees(apollo, xodr):
    a, _ = _extract(apollo)
    b, _ = _extract(xodr)
    key = lambda j: (j.feature.n_roads, j.feature.control)  # noqa: E731
    assert sorted(map(key, a)) == sorted(map(key, b))
    for x in a:  # the partner with the same n and control (one per control in these maps)
        (y,) = [y for y in b if key(y) == key(x)]
        err, lanes_agree = _cyclic_fit(x, y)
        assert lanes_agree and err < 7.0, (x.id, y.id, err)


def test_sim_map_text_gives_the_base_map_features():
    base, _ = _extract("apollo/shalun/base_map.bin")
    sim, _ = _extract("apollo/shalun/sim_map.txt")
    assert [(j.id, j.feature.n_roads, j.feature.control, j.feature.crosswalk) for j in sim] == [
        (j.id, j.feature.n_roads, j.feature.control, j.feature.crosswalk) for j in base]
    for a, b in zip(base, sim):  # sim maps thin out curve points: angles move a little
        assert a.feature.rotation == pytest.approx(b.feature.rotation, abs=3.0)


def test_polygon_centre_option_is_the_papers_centroid():
    m = read_map(shared_map("apollo/cube_town/base_map.bin"))
    by_arms = extract_junctions(m)
    by_poly = extract_junctions(m, centre="polygon")
    from shapely.geometry import Polygon

    for a, p in zip(by_arms, by_poly):
        c = Polygon(m.junctions[p.id].polygon).centroid
        assert p.center == pytest.approx((c.x, c.y))
        assert (a.feature.n_roads, a.feature.control) == (p.feature.n_roads, p.feature.control)
    with pytest.raises(ValueError, match="centre"):
        extract_junctions(m, centre="middle")


def test_cli_extract_json_on_three_apollo_maps(tmp_path, capsys):
    maps = [str(shared_map(f"apollo/{n}/base_map.bin")) for n in ("shalun", "gomentum", "san_francisco")]
    out = tmp_path / "space.json"
    pic = tmp_path / "shalun.png"
    assert main(["extract", *maps, "--json", "--out", str(out), "--picture", str(pic)]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["maps"] == maps
    assert len(doc["junctions"]) + len(doc["skipped"]) == 91 + 33 + 17
    j = doc["junctions"][0]
    assert set(j) >= {"map", "id", "n_roads", "rotation", "control", "crosswalk"}
    assert j["n_roads"] == len(j["rotation"]) and j["control"] in ("signal", "stop", "bare")
    space = doc["feature_space"]
    assert space["road_counts"] == [3, 4] and set(space["controls"]) == {"signal", "stop", "bare"}
    assert json.loads(out.read_text()) == space
    assert pic.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # each socket range of the merged feature covers every junction's angle
    for jj in doc["junctions"]:
        for i, a in enumerate(jj["rotation"]):
            lo, hi = space["rotation_ranges"][str(jj["n_roads"])][i]
            assert lo - 1e-4 <= a <= hi + 1e-4  # JSON angles are rounded to 4 decimals


def test_generate_from_real_maps(tmp_path):
    maps = [str(shared_map("apollo/cube_town/base_map.bin")), str(shared_map("opendrive/svl_cubetown/cubetown.xodr"))]
    assert main(["generate", "--from-maps", *maps, "--seed", "1", "--out", str(tmp_path / "g"),
                 "--quiet", "--no-picture"]) == 0
    space = json.loads((tmp_path / "g" / "features.json").read_text())
    assert space["road_counts"] == [3] and set(space["controls"]) == {"signal", "stop"}
    lo, hi = space["rotation_ranges"]["3"][1]
    assert math.isclose(lo, 90.0, abs_tol=3.0) and math.isclose(hi, 90.0, abs_tol=3.0)


def test_cli_extract_table_for_an_apollo_text_map(capsys):
    path = str(shared_map("apollo/cube_town/sim_map.txt"))
    assert main(["extract", path]) == 0
    out = capsys.readouterr().out
    table = out.split(f"{path}: 2 junctions\n")[1].split("\n\n")[0].splitlines()[1:]  # under the column names
    assert len(table) == 2 and {r.split()[2] for r in table} == {"signal", "stop"}
    assert "2 junctions (0 skipped), 0 mid-block crosswalks (0 signalised), 0 filter lanes (0 signalised); map feature:" in out
