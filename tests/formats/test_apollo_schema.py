"""Apollo protobuf schema: Apollo's field numbers, binary/text round trips, real maps, bad input."""
from __future__ import annotations

import random

import pytest
from conftest import SHARED_MAPS, shared_map_params
from hypothesis import given, settings
from hypothesis import strategies as st

from feat2map.formats.apollo import schema as aps
from feat2map.errors import MapFormatError

APOLLO_MAPS = SHARED_MAPS / "apollo"


def _number(cls, field: str) -> int:
    return cls.DESCRIPTOR.fields_by_name[field].number


@pytest.mark.parametrize(
    "cls, field, number",
    [
        (aps.Map, "header", 1), (aps.Map, "junction", 3), (aps.Map, "lane", 4), (aps.Map, "overlap", 8),
        (aps.Map, "road", 11), (aps.Map, "pnc_junction", 13), (aps.Map, "rsu", 14),
        (aps.Header, "vendor", 12), (aps.Header, "left", 8),
        (aps.Lane, "central_curve", 2), (aps.Lane, "speed_limit", 6), (aps.Lane, "successor_id", 9),
        (aps.Lane, "turn", 13), (aps.Lane, "junction_id", 16), (aps.Lane, "direction", 19),
        (aps.Lane, "self_reverse_lane_id", 22), (aps.LaneBoundary, "virtual", 3),
        (aps.LaneBoundaryType, "types", 2), (aps.CurveSegment, "line_segment", 1),
        (aps.CurveSegment, "start_position", 7), (aps.CurveSegment, "length", 9),
        (aps.Road, "junction_id", 3), (aps.Junction, "type", 4), (aps.Signal, "stop_line", 6),
        (aps.Signal, "sign_info", 7), (aps.StopSign, "stop_line", 2), (aps.StopSign, "overlap_id", 3),
        (aps.StopSign, "type", 4), (aps.LaneOverlapInfo, "region_overlap_id", 4),
        (aps.ObjectOverlapInfo, "junction_overlap_info", 7), (aps.ObjectOverlapInfo, "rsu_overlap_info", 13),
        (aps.Overlap, "region_overlap", 3), (aps.Node, "road_id", 8), (aps.Edge, "direction_type", 4),
        (aps.Graph, "edge", 4),
    ],
)
def test_field_numbers_match_apollo(cls, field: str, number: int) -> None:
    assert _number(cls, field) == number


def test_enums_defaults_and_packages() -> None:
    assert aps.Map.DESCRIPTOR.full_name == "apollo.hdmap.Map"
    assert aps.Graph.DESCRIPTOR.full_name == "apollo.routing.Graph"
    assert aps.PointENU.DESCRIPTOR.full_name == "apollo.common.PointENU"
    assert aps.Lane.CITY_DRIVING == 2 and aps.Lane.U_TURN == 4 and aps.Lane.FORWARD == 1
    assert aps.Signal.MIX_3_VERTICAL == 5 and aps.Subsignal.CIRCLE == 2
    assert aps.StopSign.ALL_WAY == 5 and aps.LaneBoundaryType.DOTTED_WHITE == 2
    assert aps.Edge.LEFT == 1 and aps.Junction.CROSS_ROAD == 2
    assert aps.Node().is_virtual is True
    assert aps.PointENU().x != aps.PointENU().x  # default NaN, as in Apollo
    # Apollo 10+ additions are absent (Apollo 7-9's parser rejects them).
    assert "ad_area" not in aps.Map.DESCRIPTOR.fields_by_name
    assert "barrier_gate" not in aps.Map.DESCRIPTOR.fields_by_name
    assert "SHARED" not in aps.Lane.LaneType.keys()
    assert aps.ObjectOverlapInfo.DESCRIPTOR.oneofs_by_name["overlap_info"].fields
    stop = aps.StopSign.DESCRIPTOR.fields_by_name
    assert stop["stop_line"].is_repeated and set(stop) == {
        "id", "stop_line", "overlap_id", "type"}


def _small_map(n_points: int, speed: float, name: str) -> aps.Map:
    m = aps.Map()
    m.header.version = b"1.0"
    m.header.vendor = name.encode()
    m.header.projection.proj = "+proj=utm +zone=10"
    lane = m.lane.add()
    lane.id.id = name
    lane.speed_limit = speed
    lane.type = aps.Lane.CITY_DRIVING
    seg = lane.central_curve.segment.add()
    for i in range(n_points):
        p = seg.line_segment.point.add()
        p.x, p.y = 550000.0 + i, 4180000.0 - 0.5 * i
    lane.left_boundary.boundary_type.add(s=0.0, types=[aps.LaneBoundaryType.DOTTED_WHITE])
    ov = m.overlap.add()
    ov.id.id = "overlap_1"
    a = ov.object.add()
    a.id.id = name
    a.lane_overlap_info.start_s, a.lane_overlap_info.end_s = 1.0, 2.5
    ov.object.add().id.id = "j1"
    ov.object[1].junction_overlap_info.SetInParent()
    return m


@settings(max_examples=30, deadline=None)
@given(st.integers(2, 30), st.floats(0, 40, allow_nan=False), st.text("abc_-1234", min_size=1, max_size=12))
def test_binary_and_text_round_trip(n_points: int, speed: float, name: str) -> None:
    m = _small_map(n_points, speed, name)
    from_bin = aps.parse_map(m.SerializeToString(), "mem.bin")
    from_txt = aps.parse_map(aps.to_text(m).encode(), "mem.txt")
    assert from_bin == m and from_txt == m
    assert from_txt.overlap[0].object[1].WhichOneof("overlap_info") == "junction_overlap_info"


def test_text_one_line_and_unknown_fields_parse() -> None:
    m = _small_map(3, 10.0, "lane_1")
    one_line = aps.to_text(m).replace("\n", " ")
    extra = 'barrier_gate { id { id: "bg" } } ' + one_line + " ad_area { id { id: \"a\" } }"
    assert aps.parse_map(extra.encode(), "one_line.txt") == m


def test_routing_graph_round_trip() -> None:
    g = aps.Graph(hdmap_version="1.0")
    node = g.node.add(lane_id="l1", road_id="r1", length=10.0, cost=2.4, is_virtual=False)
    node.left_out.add().start.s = 0.0
    g.edge.add(from_lane_id="l1", to_lane_id="l2", direction_type=aps.Edge.LEFT, cost=500.0)
    assert aps.parse_graph(g.SerializeToString(), "routing_map.bin") == g
    assert aps.parse_graph(aps.to_text(g).encode(), "routing_map.txt") == g


def test_bad_input_names_the_file() -> None:
    good = _small_map(20, 10.0, "lane_1").SerializeToString()
    rng = random.Random(7)
    bad = {
        "empty.bin": b"",
        "random.bin": bytes(rng.randrange(256) for _ in range(2000)),
        "truncated.bin": good[: len(good) - 7],
        "broken.txt": b"header { version: \"1\" \n lane { id { id: \"x\" }",
        "garbage.txt": b"this is not a map at all",
        "wrong_type.txt": b"lane { speed_limit: \"fast\" }",
    }
    for where, data in bad.items():
        with pytest.raises(MapFormatError) as info:
            aps.parse_map(data, where)
        assert info.value.where == where and where in str(info.value)


@pytest.mark.parametrize("rel", shared_map_params("apollo/*/*.bin", "apollo/*/*.txt", ids=lambda r: r.split("/", 1)[1]))
def test_parses_every_real_apollo_map(rel: str) -> None:
    path = SHARED_MAPS / rel
    m = aps.parse_map(path.read_bytes(), str(path))
    assert m.lane and m.junction and m.overlap
    assert m.header.vendor == b"LGSVL"
    assert m.header.projection.proj.startswith("+proj=utm")
    # Every overlap links two objects, each with a kind.
    assert all(len(o.object) >= 2 and all(x.WhichOneof("overlap_info") for x in o.object) for o in m.overlap)
    assert all(seg.line_segment.point for ln in m.lane for seg in ln.central_curve.segment)
    # stop signs list their overlaps under Apollo's field number (3): every listed id exists
    overlaps = {o.id.id for o in m.overlap}
    assert all(s.overlap_id and {x.id for x in s.overlap_id} <= overlaps and s.stop_line for s in m.stop_sign)
    # Round trip through the binary encoding is lossless.
    assert aps.Map.FromString(m.SerializeToString()) == m
