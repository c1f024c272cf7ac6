"""Apollo reader: a hand-built T-junction map (binary and text), real maps, bad input, CLI."""
from __future__ import annotations

import json
import math
import random
import re
import warnings

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from conftest import shared_map
from feat2map.formats.apollo import schema as aps
from feat2map.cli import main
from feat2map.errors import MapFormatError
from feat2map.extract import extract_junctions
from feat2map.features import normalize_rotation
from feat2map.readers import read_map
from feat2map.formats.apollo import read_apollo, read_apollo_bytes

X0, Y0 = 553000.25, 4182000.75  # UTM-like offsets, as in the SVL maps
W = 3.5  # lane width


def _curve(curve, pts) -> None:
    seg = curve.segment.add()
    for x, y in pts:
        p = seg.line_segment.point.add()
        p.x, p.y = X0 + x, Y0 + y
    seg.start_position.x, seg.start_position.y = X0 + pts[0][0], Y0 + pts[0][1]


def _lane(m, lid: str, pts, *, turn=aps.Lane.NO_TURN, preds=(), succs=()) -> None:
    ln = m.lane.add()
    ln.id.id = lid
    pts = np.asarray(pts, dtype=float)
    _curve(ln.central_curve, pts)
    d = np.diff(pts, axis=0)
    normal = np.array([-d[0][1], d[0][0]]) / np.hypot(*d[0])
    _curve(ln.left_boundary.curve, pts + normal * W / 2)
    _curve(ln.right_boundary.curve, pts - normal * W / 2)
    ln.left_boundary.boundary_type.add(s=0.0, types=[aps.LaneBoundaryType.DOUBLE_YELLOW])
    ln.right_boundary.boundary_type.add(s=0.0, types=[aps.LaneBoundaryType.CURB])
    ln.length = float(np.hypot(*d.T).sum())
    ln.speed_limit = 11.2
    ln.type = aps.Lane.CITY_DRIVING
    ln.turn = turn
    ln.direction = aps.Lane.FORWARD
    for s in np.linspace(0, ln.length, 3):
        ln.left_sample.add(s=s, width=W / 2)
        ln.right_sample.add(s=s, width=W / 2)
    for p in preds:
        ln.predecessor_id.add().id = p
    for s in succs:
        ln.successor_id.add().id = s


def _overlap(m, oid: str, a: tuple[str, str], b: tuple[str, str]) -> None:
    ov = m.overlap.add()
    ov.id.id = oid
    for kind, ident in (a, b):
        obj = ov.object.add()
        obj.id.id = ident
        info = getattr(obj, f"{kind}_overlap_info")
        info.SetInParent()
        if kind == "lane":
            info.start_s, info.end_s = 0.0, 1.0


def t_junction_map(arm_angles: dict[str, float] | None = None) -> aps.Map:
    """A junction at the origin, by default a T: arms East, West, South (stem); 40 m roads,
    one lane each way; a signal on the incoming lanes; one named crosswalk on a junction lane
    and one unnamed crosswalk without overlaps; roads inside the junction carry junction_id.
    `arm_angles` (name -> degrees) builds any other junction on a round polygon."""
    m = aps.Map()
    m.header.version = b"1.500000"
    m.header.vendor = b"test"
    m.header.projection.proj = "+proj=utm +zone=10 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
    r, h = 10.0, W / 2  # junction half-size, lane offset
    angles = arm_angles or {"e": 0.0, "w": 180.0, "s": 270.0}
    arms = {k: (round(math.cos(math.radians(a)), 12), round(math.sin(math.radians(a)), 12)) for k, a in angles.items()}
    for a, (dx, dy) in arms.items():
        nx, ny = -dy, dx  # left of the outward direction = right of the inward one
        # right-hand traffic: the incoming lane lies left of the outward direction
        start = (dx * (r + 40) + nx * h, dy * (r + 40) + ny * h)
        end = (dx * r + nx * h, dy * r + ny * h)
        _lane(m, f"in_{a}", [start, ((start[0] + end[0]) / 2, (start[1] + end[1]) / 2), end],
              succs=[f"j_{a}_{b}" for b in arms if b != a])
        o_start = (dx * r - nx * h, dy * r - ny * h)
        o_end = (dx * (r + 40) - nx * h, dy * (r + 40) - ny * h)
        _lane(m, f"out_{a}", [o_start, ((o_start[0] + o_end[0]) / 2, (o_start[1] + o_end[1]) / 2), o_end],
              preds=[f"j_{b}_{a}" for b in arms if b != a])
        road = m.road.add()
        road.id.id = f"road_{a}"
        sec = road.section.add()
        sec.lane_id.add().id = f"in_{a}"
        sec.lane_id.add().id = f"out_{a}"
    for a, (dx, dy) in arms.items():
        for b, (ex, ey) in arms.items():
            if a == b:
                continue
            s = (dx * r - dy * h, dy * r + dx * h)  # end of in_a
            e = (ex * r + ey * h, ey * r - ex * h)  # start of out_b
            cross = dx * ey - dy * ex  # > 0: the exit lies to the right of the entry direction
            turn = aps.Lane.NO_TURN if abs(cross) < 0.5 else (aps.Lane.RIGHT_TURN if cross > 0 else aps.Lane.LEFT_TURN)
            _lane(m, f"j_{a}_{b}", [s, ((s[0] + e[0]) / 2 * 0.5, (s[1] + e[1]) / 2 * 0.5), e], turn=turn,
                  preds=[f"in_{a}"], succs=[f"out_{b}"])
            road = m.road.add()
            road.id.id = f"jroad_{a}_{b}"
            road.junction_id.id = "J_0"
            road.section.add().lane_id.add().id = f"j_{a}_{b}"
            _overlap(m, f"ov_j_{a}_{b}", ("junction", "J_0"), ("lane", f"j_{a}_{b}"))
    j = m.junction.add()
    j.id.id = "J_0"
    outline = [(-r, -r), (r, -r), (r, r), (-r, r)] if arm_angles is None else [
        (1.2 * r * math.cos(k * math.pi / 8), 1.2 * r * math.sin(k * math.pi / 8)) for k in range(16)]
    for x, y in outline:
        p = j.polygon.point.add()
        p.x, p.y = X0 + x, Y0 + y
    sig = m.signal.add()
    sig.id.id = "signal_0"
    sig.type = aps.Signal.MIX_3_VERTICAL
    for x, y in [(12, 6), (12.5, 6), (12.5, 7), (12, 7)]:
        p = sig.boundary.point.add()
        p.x, p.y = X0 + x, Y0 + y
    _curve(sig.stop_line.add(), [(r, 0.0), (r, W)])
    for a in arms:
        _overlap(m, f"ov_sig_{a}", ("lane", f"in_{a}"), ("signal", "signal_0"))
    _overlap(m, "ov_sig_j", ("junction", "J_0"), ("signal", "signal_0"))
    for cid, (x0, x1) in (("CW_1", (-r, -r + 3)), ("", (r - 3, r))):
        cw = m.crosswalk.add()
        cw.id.id = cid
        for x, y in [(x0, -r), (x1, -r), (x1, r), (x0, r)]:
            p = cw.polygon.point.add()
            p.x, p.y = X0 + x, Y0 + y
    if arm_angles is None:
        _overlap(m, "ov_cw", ("crosswalk", "CW_1"), ("lane", "j_w_e"))
    return m


@pytest.fixture(scope="module")
def t_map():
    with splits_its_signal("t.bin"):
        return read_apollo_bytes(t_junction_map().SerializeToString(), "t.bin")


def splits_its_signal(where: object):
    """Expect the reader's finding on t_junction_map's one light over every approach (the
    through road's and the stem's paths conflict): it names the file and splits signal_0."""
    return pytest.warns(UserWarning, match=rf"^{re.escape(str(where))}: signal signal_0: governs approaches whose "
                        r"paths conflict \(roads road_\w+.*\): split into signals signal_0, signal_0~2")


def test_reads_lanes_roads_and_origin(t_map):
    m = t_map
    assert m.origin == (math.floor(X0 - 50.0), math.floor(Y0 - 50.0))
    assert len(m.lanes) == 12 and len(m.junctions) == 1
    ln = m.lanes["in_e"]
    assert ln.start == pytest.approx((X0 + 50.0 - m.origin[0], Y0 + W / 2 - m.origin[1]))
    assert ln.width == pytest.approx(W) and ln.speed_limit == pytest.approx(11.2)
    assert ln.successors == ("j_e_w", "j_e_s") and ln.junction_id is None
    assert (ln.left_boundary_type, ln.right_boundary_type) == ("solid_yellow", "curb")
    # membership through road.junction_id and junction-lane overlaps
    assert {x.id for x in m.junction_lanes("J_0")} == {f"j_{a}_{b}" for a in "ews" for b in "ews" if a != b}
    assert m.lanes["j_e_w"].turn == "none" and m.lanes["j_e_s"].turn == "left" and m.lanes["j_w_s"].turn == "right"
    assert m.roads["road_e"].right_lanes == ("in_e",) and m.roads["road_e"].left_lanes == ("out_e",)
    assert m.roads["jroad_e_w"].junction_id == "J_0" and m.roads["jroad_e_w"].kind == "junction"
    assert m.meta["format"] == "apollo" and m.meta["projection"].startswith("+proj=utm")


def test_signals_and_crosswalks(t_map):
    sig = t_map.signals["signal_0"]
    # one light over the T's three approaches: split so the through road and the stem can differ
    assert set(sig.lane_ids) == {"in_e", "in_w"} and sig.junction_id == "J_0"
    assert t_map.signals["signal_0~2"].lane_ids == ("in_s",)
    assert sig.position == pytest.approx((12.25 + X0 - t_map.origin[0], 6.5 + Y0 - t_map.origin[1]))
    # the light faces the traffic of its first lane (in_e drives west, so it faces east)
    assert math.cos(sig.heading) == pytest.approx(1.0, abs=1e-6)
    cws = t_map.crosswalks
    assert set(cws) == {"CW_1", "crosswalk_unnamed_1"}
    assert cws["CW_1"].junction_id == "J_0"  # through its junction lane
    assert cws["crosswalk_unnamed_1"].junction_id == "J_0"  # geometrically


def test_extraction_of_the_t_junction(t_map):
    (j,) = extract_junctions(t_map)
    f = j.feature
    assert (f.n_roads, f.control, f.crosswalk) == (3, "signal", True)
    assert f.rotation == pytest.approx((0.0, 90.0, 180.0), abs=1e-6)  # stem South: largest gap closes
    assert [(s.lanes_in, s.lanes_out) for s in f.sockets] == [(1, 1)] * 3


def test_lane_mouths_at_one_point_are_one_arm():
    """Two incoming lanes of different roads that end at one point are one leg, even when their
    last segments differ by more than any merge angle (an Apollo sim_map's thinned
    curves: GoMentum J_22/J_24 came out with two sockets at one angle and were skipped)."""
    pb = t_junction_map()
    r, h = 10.0, W / 2
    end = (r, h)  # where in_e meets the junction
    a = math.radians(35.0)  # the second lane comes in 35 degrees off the arm's direction (beyond ARM_CLUSTER_DEG)
    start = (end[0] + 40 * math.cos(a), end[1] + 40 * math.sin(a))
    _lane(pb, "in_e2", [start, ((start[0] + end[0]) / 2, (start[1] + end[1]) / 2), end], succs=["j_e2_w"])
    pb.road.add(id=aps.Id(id="road_e2")).section.add().lane_id.add().id = "in_e2"
    w_start = (-r, h)  # start of out_w
    _lane(pb, "j_e2_w", [end, (0.0, h), w_start], preds=["in_e2"], succs=["out_w"])
    jroad = pb.road.add()
    jroad.id.id, jroad.junction_id.id = "jroad_e2_w", "J_0"
    jroad.section.add().lane_id.add().id = "j_e2_w"
    _overlap(pb, "ov_j_e2_w", ("junction", "J_0"), ("lane", "j_e2_w"))
    with splits_its_signal("mouths.bin"):
        m = read_apollo_bytes(pb.SerializeToString(), "mouths.bin")
    (j,) = extract_junctions(m)
    assert j.feature.n_roads == 3
    assert sorted((s.lanes_in, s.lanes_out) for s in j.feature.sockets) == [(1, 1), (1, 1), (2, 1)]


@settings(max_examples=15, deadline=None)
@given(st.lists(st.floats(0, 360, exclude_max=True, allow_nan=False), min_size=3, max_size=6).filter(
    lambda a: min(np.diff(np.sort(np.append(a, min(a) + 360)))) > 35.0))
def test_extraction_recovers_any_junction(angles):
    pb = t_junction_map({f"a{i}": a for i, a in enumerate(angles)})
    with splits_its_signal("any.bin"):
        m = read_apollo_bytes(pb.SerializeToString(), "any.bin")
    (j,) = extract_junctions(m)
    assert j.feature.rotation == pytest.approx(normalize_rotation(angles).angles, abs=1e-6)
    assert (j.feature.n_roads, j.feature.control, j.feature.crosswalk) == (len(angles), "signal", True)
    assert all((s.lanes_in, s.lanes_out) == (1, 1) for s in j.feature.sockets)


def test_text_and_binary_give_the_same_map(tmp_path, t_map):
    pb = t_junction_map()
    (tmp_path / "base_map.txt").write_text(aps.to_text(pb))
    (tmp_path / "no_suffix").write_bytes(pb.SerializeToString())
    (tmp_path / "one_line.txt").write_text(aps.to_text(pb).replace("\n", " "))
    for name in ("base_map.txt", "no_suffix", "one_line.txt"):
        with splits_its_signal(tmp_path / name):
            m = read_map(tmp_path / name)  # detected by content
        assert m.lanes == t_map.lanes and m.junctions == t_map.junctions and m.signals == t_map.signals


def test_map_round_trips_through_the_native_file(tmp_path, t_map):
    from feat2map.formats import native

    native.save(t_map, tmp_path / "m.json")
    back = native.load(tmp_path / "m.json")
    assert back.lanes == t_map.lanes and back.crosswalks == t_map.crosswalks and back.origin == t_map.origin


def _broken(mutate) -> bytes:
    pb = t_junction_map()
    mutate(pb)
    return pb.SerializeToString()


def _set_successor(pb):
    pb.lane[0].successor_id.add().id = "lane_nowhere"


def _bad_overlap(pb):
    pb.overlap[0].object[1].id.id = "lane_nowhere"


def _bad_road(pb):
    pb.road[0].section[0].lane_id.add().id = "lane_nowhere"


def _bad_road_junction(pb):
    pb.road[0].junction_id.id = "J_nowhere"


def _short_lane(pb):
    del pb.lane[2].central_curve.segment[0].line_segment.point[1:]


def _duplicate_lane(pb):
    pb.lane[1].id.id = pb.lane[0].id.id


@pytest.mark.parametrize("mutate, element", [
    (_set_successor, "lane 'in_e'"),
    (_bad_overlap, "overlap 'ov_j_e_w'"),
    (_bad_road, "road 'road_e'"),
    (_bad_road_junction, "road 'road_e'"),
    (_short_lane, "lane 'in_w'"),
    (_duplicate_lane, "lane 'in_e'"),
])
def test_dangling_ids_and_broken_elements_name_file_and_element(mutate, element):
    with pytest.raises(MapFormatError) as info:
        read_apollo_bytes(_broken(mutate), "broken.bin")
    assert info.value.where == f"broken.bin: {element}"


def test_corrupt_truncated_random_and_broken_text(tmp_path):
    good = t_junction_map().SerializeToString()
    rng = random.Random(3)
    files = {
        "truncated.bin": good[: len(good) // 2],
        "random.bin": bytes(rng.randrange(256) for _ in range(4096)),
        "broken.txt": aps.to_text(t_junction_map())[:-40].encode(),
        "zero.bin": b"\x00" * 64,
    }
    for name, data in files.items():
        (tmp_path / name).write_bytes(data)
        with pytest.raises(MapFormatError) as info:
            read_map(tmp_path / name)
        assert str(tmp_path / name) in str(info.value)


def test_junction_without_polygon_uses_its_lanes():
    pb = t_junction_map()
    pb.junction[0].ClearField("polygon")
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = read_apollo_bytes(pb.SerializeToString(), "nopoly.bin")
    assert any("J_0" in str(w.message) and "hull" in str(w.message) for w in caught)
    assert len(m.junctions["J_0"].polygon) >= 3
    assert extract_junctions(m)[0].feature.n_roads == 3


def test_cli_extract_bad_apollo_file_exits_2_with_one_line(tmp_path, capsys):
    bad = tmp_path / "base_map.bin"
    bad.write_bytes(t_junction_map().SerializeToString()[:-25])
    assert main(["extract", str(bad)]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and str(bad) in err and "Traceback" not in err


@pytest.mark.real_maps
def test_san_francisco_is_read_whole():
    m = read_apollo(shared_map("apollo/san_francisco/base_map.bin"))
    assert (len(m.lanes), len(m.junctions), len(m.signals), len(m.stop_signs), len(m.crosswalks)) == (
        1524, 91, 201, 9, 43)
    assert 500_000 < m.origin[0] < 600_000 and 4_100_000 < m.origin[1] < 4_200_000
    lo = np.min([ln.points.min(axis=0) for ln in m.lanes.values()], axis=0)
    assert (lo >= 0).all() and (lo < 1).all()  # the origin is the whole-metre lower-left corner
    in_junction = [ln for ln in m.lanes.values() if ln.junction_id]
    assert 0 < len(in_junction) < len(m.lanes)
    assert all(s.lane_ids and s.junction_id for s in m.signals.values())
    # SF signals overlap their junction's lanes or the incoming lanes leading into it
    for s in m.signals.values():
        for lid in s.lane_ids:
            ln = m.lanes[lid]
            assert ln.junction_id == s.junction_id or (
                ln.junction_id is None and any(m.lanes[x].junction_id == s.junction_id for x in ln.successors))
    # 23 crosswalks have no id: all got unique ids and a junction
    assert sum(c.startswith("crosswalk_unnamed_") for c in m.crosswalks) == 23
    assert all(c.junction_id for c in m.crosswalks.values())
    for ln in m.lanes.values():
        for s in ln.successors:
            assert math.dist(ln.end, m.lanes[s].start) < 1.0


@pytest.mark.real_maps
def test_sim_map_text_matches_base_map():
    base = read_apollo(shared_map("apollo/cube_town/base_map.bin"))
    sim = read_apollo(shared_map("apollo/cube_town/sim_map.txt"))
    assert set(sim.lanes) == set(base.lanes) and set(sim.junctions) == set(base.junctions)
    assert {k: v.lane_ids for k, v in sim.signals.items()} == {k: v.lane_ids for k, v in base.signals.items()}
    assert [(j.feature.n_roads, j.feature.control) for j in extract_junctions(sim)] == [
        (j.feature.n_roads, j.feature.control) for j in extract_junctions(base)]


def test_cli_reports_a_bad_element_as_one_warning_line(tmp_path, capsys):
    pb = t_junction_map()
    pb.junction.add().id.id = "J_empty"  # no polygon, no lanes: skipped, the map still works
    path = tmp_path / "base_map.bin"
    path.write_bytes(pb.SerializeToString())
    assert main(["extract", str(path), "--json"]) == 0
    captured = capsys.readouterr()
    assert captured.err.splitlines()[0] == (f"feat2map: warning: {path}: junction 'J_empty': "
                                            "no usable polygon and no lanes, skipped")
    turned, split = captured.err.splitlines()[1:]  # the fixture's coarse turns end 2.3 m off their exits' sides
    assert turned.startswith(f"feat2map: warning: {path}: 2 lane link(s) whose ends are turned against each other")
    assert turned.endswith("(largest: j_w_s -> out_s (2.3 m), j_s_e -> out_e (2.3 m))")
    assert split == (f"feat2map: warning: {path}: signal signal_0: governs approaches whose paths conflict (roads "
                     "road_e, road_w / road_s): split into signals signal_0, signal_0~2")
    assert len(json.loads(captured.out)["junctions"]) == 1


def test_sidewalk_lanes_are_left_out_of_the_driving_network(t_map):
    pb = t_junction_map()
    _lane(pb, "walk", [(-10.0, -14.0), (10.0, -14.0)], preds=["in_e"])
    pb.lane[-1].type = aps.Lane.SIDEWALK
    pb.lane[0].successor_id.add().id = "walk"
    pb.road[0].section[0].lane_id.add().id = "walk"
    with splits_its_signal("walk.bin"):
        m = read_apollo_bytes(pb.SerializeToString(), "walk.bin")
    assert "walk" not in m.lanes and m.meta["non_driving_lanes"] == 1
    assert m.lanes["in_e"].successors == t_map.lanes["in_e"].successors
    assert m.roads["road_e"] == t_map.roads["road_e"]
    assert [j.feature for j in extract_junctions(m)] == [j.feature for j in extract_junctions(t_map)]


# ---- Baidu-style maps: junction polygons drawn over the approach lanes ---------------------------
def _baidu_style(pb: aps.Map, grow: float, road_junctions: bool = True) -> aps.Map:
    """An Apollo map redrawn the way Baidu's maps are: every junction polygon grown by `grow`
    metres over its approach lanes, a junction-lane overlap (with its s range) for every lane
    the grown polygon meets, no lane-level junction_id, and (unless `road_junctions`) no
    junction_id on the roads either."""
    from shapely.geometry import LineString, Polygon
    from feat2map.formats.apollo.geometry import polygon_range

    out = aps.Map()
    out.CopyFrom(pb)
    for ln in out.lane:
        ln.ClearField("junction_id")
    if not road_junctions:
        for r in out.road:
            r.ClearField("junction_id")
    centres = {ln.id.id: [(p.x, p.y) for seg in ln.central_curve.segment for p in seg.line_segment.point]
               for ln in out.lane}
    lanes = {ln.id.id: ln for ln in out.lane}
    had = {(ov.object[0].id.id, ov.object[1].id.id) for ov in out.overlap}
    for j in out.junction:
        grown = Polygon([(p.x, p.y) for p in j.polygon.point]).buffer(grow, join_style="mitre")
        del j.polygon.point[:]
        for x, y in list(grown.exterior.coords)[:-1]:
            j.polygon.point.add(x=x, y=y)
        for lid, pts in centres.items():
            if (lid, j.id.id) in had or not LineString(pts).intersects(grown):
                continue
            rng = polygon_range(tuple(pts), tuple(grown.exterior.coords))
            if rng is None:
                continue
            ov = out.overlap.add()
            ov.id.id = f"baidu_{j.id.id}_{lid}"
            a, b = ov.object.add(), ov.object.add()
            a.id.id, b.id.id = lid, j.id.id
            a.lane_overlap_info.start_s, a.lane_overlap_info.end_s = rng
            b.junction_overlap_info.SetInParent()
            lanes[lid].overlap_id.add().id = ov.id.id
            j.overlap_id.add().id = ov.id.id
    return out


@pytest.fixture(scope="module")
def baidu_source():
    """A generated map with every control next to each other (64 m grid), exported to Apollo."""
    import feat2map
    from feat2map.config import GenerationConfig
    from feat2map.features import JunctionFeature as JF
    from feat2map.formats.apollo.writer import to_apollo

    feats = [JF.make([0, 90, 180, 270], "signal", True), JF.make([0, 90, 180], "stop", False),
             JF.make([0, 90, 180, 270], "bare", False), JF.make([0, 90, 180], "bare", True),
             JF.make([0, 90, 180], "signal", False)]
    m = feat2map.generate_from_features(feats, seed=2, config=GenerationConfig(grid_gap=64.0))
    return to_apollo(m)


def _summary(m):
    """Per junction: (n, control, crosswalk, rotation) of its extracted feature."""
    return {j.id: (j.feature.n_roads, j.feature.control, j.feature.crosswalk, j.feature.rotation)
            for j in extract_junctions(m)}


def test_baidu_style_junction_polygons_over_approach_lanes_keep_road_lanes_out(baidu_source):
    clean = read_apollo_bytes(baidu_source.SerializeToString(), "clean.bin")
    pb = _baidu_style(baidu_source, grow=25.0)
    # the fixture does what Baidu's maps do: most road lanes overlap some junction polygon,
    # some lie wholly inside one
    road_lanes = {ln.id for ln in clean.lanes.values() if ln.junction_id is None}
    overlapped = {o.object[0].id.id for o in pb.overlap if o.id.id.startswith("baidu_")}
    assert len(overlapped & road_lanes) > 0.8 * len(road_lanes)
    m = read_apollo_bytes(pb.SerializeToString(), "baidu.bin")
    assert {k: ln.junction_id for k, ln in m.lanes.items()} == {k: ln.junction_id for k, ln in clean.lanes.items()}
    assert {k: (s.junction_id, s.lane_ids) for k, s in m.signals.items()} == {
        k: (s.junction_id, s.lane_ids) for k, s in clean.signals.items()}
    assert {k: (s.junction_id, s.lane_ids) for k, s in m.stop_signs.items()} == {
        k: (s.junction_id, s.lane_ids) for k, s in clean.stop_signs.items()}
    got, want = _summary(m), _summary(clean)
    assert {k: v[:3] for k, v in got.items()} == {k: v[:3] for k, v in want.items()}
    assert sorted(v[:2] for v in got.values()) == [(3, "bare"), (3, "signal"), (3, "stop"), (4, "bare"), (4, "signal")]
    for k in want:
        assert got[k][3] == pytest.approx(want[k][3], abs=1e-6)


def test_maps_whose_roads_name_no_junction_fall_back_to_whole_lane_overlaps(baidu_source):
    clean = read_apollo_bytes(baidu_source.SerializeToString(), "clean.bin")
    # grown less than the shortest road: overlaps reach into approach lanes but cover none whole
    pb = _baidu_style(baidu_source, grow=6.0, road_junctions=False)
    m = read_apollo_bytes(pb.SerializeToString(), "noroads.bin")
    assert {k: ln.junction_id for k, ln in m.lanes.items()} == {k: ln.junction_id for k, ln in clean.lanes.items()}
    assert {k: v[:3] for k, v in _summary(m).items()} == {k: v[:3] for k, v in _summary(clean).items()}


def test_yield_signs_are_read_as_yield_signs_and_lights_govern_signs_under_them():
    """A yield sign and a stop sign under every light, and yield signs instead of the stop
    junction's stop signs: the lights govern their lanes alone, the yield junction is bare,
    and yield signs round-trip through the Apollo export and the native file."""
    import dataclasses

    import feat2map
    from feat2map.features import JunctionFeature as JF
    from feat2map.formats import native
    from feat2map.formats.apollo.writer import to_apollo
    from feat2map.model import StopSign, YieldSign

    m = feat2map.generate_from_features([JF.make([0, 90, 180, 270], "signal", False),
                                         JF.make([0, 90, 180], "stop", False)], seed=1)
    fields = lambda s: dict(junction_id=s.junction_id, stop_line=s.stop_line, position=s.position,  # noqa: E731
                            heading=s.heading, lane_ids=s.lane_ids)
    yields = {f"y_{k}": YieldSign(f"y_{k}", **fields(s)) for k, s in {**m.signals, **m.stop_signs}.items()}
    stops = {f"s_{k}": StopSign(f"s_{k}", **fields(s)) for k, s in m.signals.items()}
    signed = dataclasses.replace(m, stop_signs=stops, yield_signs=yields)
    back = read_apollo_bytes(to_apollo(signed).SerializeToString(), "signs.bin")
    assert set(back.signals) == set(m.signals) and not back.stop_signs
    assert set(back.yield_signs) == {f"y_{k}" for k in m.stop_signs}
    assert {k: s.lane_ids for k, s in back.yield_signs.items()} == {
        f"y_{k}": s.lane_ids for k, s in m.stop_signs.items()}
    assert sorted((j.feature.n_roads, j.feature.control) for j in extract_junctions(back)) == [(3, "bare"), (4, "signal")]
    assert native.from_dict(native.to_dict(back)) == back


def test_a_sign_overlapping_another_junctions_lane_at_its_end_does_not_govern_that_junctions_approach(baidu_source):
    """GoMentum's stop_sign_22 (J_31) also overlaps the last 0.7 m of a J_30 junction lane that
    ends at its line: the sign is at J_30's exit, not a control of J_30's approach (reading it as
    one put a J_31 stop line on a J_30 approach, and stop-sign queues never let the ego in)."""
    pb = aps.Map()
    pb.CopyFrom(baidu_source)
    clean = read_apollo_bytes(pb.SerializeToString(), "clean.bin")
    sign = next(s for s in pb.stop_sign)
    mine = clean.stop_signs[sign.id.id].junction_id
    other = next(ln for ln in pb.lane if clean.lanes[ln.id.id].junction_id not in (None, mine))
    ov = pb.overlap.add()
    ov.id.id = "exit_overlap"
    a, b = ov.object.add(), ov.object.add()
    a.id.id, b.id.id = other.id.id, sign.id.id
    a.lane_overlap_info.start_s, a.lane_overlap_info.end_s = other.length - 0.7, other.length
    b.stop_sign_overlap_info.SetInParent()
    other.overlap_id.add().id = sign.overlap_id.add().id = "exit_overlap"
    m = read_apollo_bytes(pb.SerializeToString(), "exit.bin")
    assert m.stop_signs[sign.id.id] == clean.stop_signs[sign.id.id]


def _ring_map(radii: tuple[float, ...] = (26.0, 26.0 + W)) -> aps.Map:
    """A two-lane ring road driven anticlockwise, four quarter-circle lanes per ring, with no
    link between the rings: only lane changes join them. Every boundary is `virtual` and
    declares DOTTED_WHITE, as a Baidu-style map writes them."""
    m = aps.Map()
    m.header.projection.proj = "+proj=utm +zone=10 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
    names = [f"ring{k}" for k in range(len(radii))]
    for q in range(4):
        a = np.linspace(q * math.pi / 2, (q + 1) * math.pi / 2, 12)
        road = m.road.add()
        road.id.id = f"road_{q}"
        sec = road.section.add()
        for k, r in enumerate(radii):
            ln = m.lane.add()
            ln.id.id = f"{names[k]}_{q}"
            sec.lane_id.add().id = ln.id.id
            for curve, rr in ((ln.central_curve, r), (ln.left_boundary.curve, r - W / 2),
                              (ln.right_boundary.curve, r + W / 2)):
                _curve(curve, list(zip(rr * np.cos(a), rr * np.sin(a))))
            for b in (ln.left_boundary, ln.right_boundary):
                b.virtual = True
                b.boundary_type.add(s=0.0, types=[aps.LaneBoundaryType.DOTTED_WHITE])
            ln.length = r * math.pi / 2
            ln.speed_limit, ln.type, ln.direction = 11.2, aps.Lane.CITY_DRIVING, aps.Lane.FORWARD
            ln.successor_id.add().id = f"{names[k]}_{(q + 1) % 4}"
            ln.predecessor_id.add().id = f"{names[k]}_{(q - 1) % 4}"
            if k > 0:
                ln.left_neighbor_forward_lane_id.add().id = f"{names[k - 1]}_{q}"
            if k + 1 < len(radii):
                ln.right_neighbor_forward_lane_id.add().id = f"{names[k + 1]}_{q}"
    return m


def test_declared_boundary_types_of_virtual_boundaries_keep_the_lane_changes():
    """A boundary both `virtual` and DOTTED_WHITE may be crossed: the two rings stay one
    strongly connected network, and the Apollo re-export validates with its lane-change edges."""
    from feat2map.formats.apollo.validate import validate_map
    from feat2map.formats.apollo.writer import to_apollo
    from feat2map.invariants import connectivity, lane_changes

    m = read_apollo_bytes(_ring_map().SerializeToString(), "ring.bin")
    assert {(x.left_boundary_type, x.right_boundary_type) for x in m.lanes.values()} == {("dotted_white",) * 2}
    assert sorted(x for ln in m.lanes.values() for x in lane_changes(ln)) == sorted(m.lanes)
    assert connectivity(m) == []
    assert validate_map(to_apollo(m)) == []


def test_a_map_in_local_metres_is_placed_like_an_opendrive_file():
    """An Apollo map in local metres (x from -30 to 30 under `+zone=0`) keeps its frame with
    origin (0, 0), so the re-export is shifted to the export's UTM origin and validates (it was
    written unshifted under a zone 10 header: "lane coordinates are not absolute UTM metres")."""
    from feat2map.config import UTM_ORIGIN
    from feat2map.formats.apollo.validate import validate_map
    from feat2map.formats.apollo.writer import to_apollo

    pb = _ring_map()
    pb.header.projection.proj = "+proj=utm +zone=0 +ellps=WGS84 +datum=WGS84 +units=m +no_defs"
    for ln in pb.lane:
        for curve in (ln.central_curve, ln.left_boundary.curve, ln.right_boundary.curve):
            for seg in curve.segment:
                for p in list(seg.line_segment.point) + [seg.start_position]:
                    p.x, p.y = p.x - X0, p.y - Y0
    m = read_apollo_bytes(pb.SerializeToString(), "local.bin")
    assert m.origin == (0.0, 0.0) and min(x for ln in m.lanes.values() for x, _ in ln.centerline) < -25
    out = to_apollo(m)
    assert out.lane[0].central_curve.segment[0].line_segment.point[0].x > UTM_ORIGIN[0] - 100
    assert validate_map(out) == []
    # absolute UTM maps keep their whole-metre origin
    outer = 26.0 + W  # the outer ring's centreline radius
    assert read_apollo_bytes(_ring_map().SerializeToString(), "utm.bin").origin == (math.floor(X0 - outer),
                                                                                   math.floor(Y0 - outer))


def test_a_lane_narrower_than_apollo_holds_is_widened_with_one_warning():
    """A converter's geometry loop leaves a lane sample 0.117 m wide on one side: the Apollo
    export widens that side to APOLLO_MIN_HALF_WIDTH_M with one warning naming the lane, and
    validates (it was refused: "would not validate ... half width")."""
    from dataclasses import replace

    from feat2map.config import APOLLO_MIN_HALF_WIDTH_M
    from feat2map.formats.apollo.validate import validate_map
    from feat2map.formats.apollo.writer import to_apollo

    m = read_apollo_bytes(_ring_map().SerializeToString(), "ring.bin")
    ln = m.lanes["ring1_2"]
    pinched = list(ln.right_boundary)
    c = np.asarray(ln.centerline[5])
    pinched[5] = tuple(c + 0.117 * (np.asarray(pinched[5]) - c) / np.hypot(*(np.asarray(pinched[5]) - c)))
    m = replace(m, lanes={**m.lanes, ln.id: replace(ln, right_boundary=tuple(pinched))})
    with pytest.warns(UserWarning, match=r"1 lane\(s\) narrower than Apollo holds .*first: lane ring1_2, 0\.1\d\d m"):
        out = to_apollo(m)
    assert validate_map(out) == []
    right = next(x for x in out.lane if x.id.id == "ring1_2").right_sample
    assert min(s.width for s in right) >= APOLLO_MIN_HALF_WIDTH_M
