"""OpenDRIVE: reader geometry, export structure, round trips, netconvert, real maps, bad input."""
from __future__ import annotations

import math
import shutil
import subprocess
import sys
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from lxml import etree

from feat2map.bezier import Bezier
from feat2map.errors import Feat2MapError, MapFormatError
from feat2map.extract import extract_junctions
from feat2map.formats.opendrive.reader import SIGNAL_CODES, _Geometry, _RefLine, read_opendrive
from feat2map.formats.opendrive.writer import bezier_length, param_poly3, to_opendrive, write_opendrive

from conftest import (REPO, SKIP_NETCONVERT, adjacent_junctions_map, as_another_tools, assert_same_features,
                      fork_into_junction_and_road_map, merge_at_junction_entry_map, mirrored_to_left_hand_traffic,
                      read_shared_map, shared_map, split_and_merge_map, split_with_a_centimetre_road,
                      uneven_seams_map)

# ---------------------------------------------------------------------------------------------
# plan-view geometry


def _ref(kind: str, length: float, **params) -> _RefLine:
    return _RefLine([_Geometry(0.0, 1.0, 2.0, 0.3, length, kind, params)])


def test_line_and_arc_closed_form():
    x, y, h = _ref("line", 10.0).eval([0.0, 10.0])
    assert (x[1], y[1]) == pytest.approx((1 + 10 * math.cos(0.3), 2 + 10 * math.sin(0.3)))
    k, L = 0.05, 20.0
    x, y, h = _ref("arc", L, curvature=k).eval(np.linspace(0, L, 11))
    cx, cy = 1 - math.sin(0.3) / k, 2 + math.cos(0.3) / k  # centre of the circle on the left
    assert np.hypot(x - cx, y - cy) == pytest.approx(np.full(11, 1 / k), abs=1e-9)
    assert h[-1] == pytest.approx(0.3 + k * L)


@settings(max_examples=25, deadline=None)
@given(st.floats(-0.2, 0.2), st.floats(1.0, 80.0))
def test_spiral_with_constant_curvature_is_an_arc(k, length):
    s = np.linspace(0, length, 7)
    a = np.array(_ref("arc", length, curvature=k).eval(s))
    b = np.array(_ref("spiral", length, curvStart=k, curvEnd=k).eval(s))
    assert b == pytest.approx(a, abs=1e-3)


def test_spiral_matches_fresnel_integrals():
    import scipy.special as special  # the dev extra's
    c, L = 0.004, 60.0  # curvature 0 -> c L along the spiral
    ref = _RefLine([_Geometry(0.0, 0.0, 0.0, 0.0, L, "spiral", {"curvStart": 0.0, "curvEnd": c * L})])
    s = np.array([15.0, 30.0, 60.0])
    x, y, h = ref.eval(s)
    S, C = special.fresnel(s * math.sqrt(c / math.pi))
    scale = math.sqrt(math.pi / c)
    assert x == pytest.approx(scale * C, abs=1e-4)
    assert y == pytest.approx(scale * S, abs=1e-4)
    assert h == pytest.approx(0.5 * c * s * s)


def test_poly3_and_param_poly3_agree_on_the_same_curve():
    L_u = 30.0  # v = 0.01 u^2 as poly3 and as paramPoly3 with arcLength... measured by its length
    u = np.linspace(0, L_u, 20001)
    arc = float(np.hypot(np.diff(u), np.diff(0.01 * u * u)).sum())
    a = _ref("poly3", arc, a=0.0, b=0.0, c=0.01, d=0.0)
    b = _ref("paramPoly3", arc, aU=0.0, bU=L_u, cU=0.0, dU=0.0, aV=0.0, bV=0.0, cV=0.01 * L_u ** 2, dV=0.0,
             normalized=1.0)
    s = np.linspace(0, arc, 9)
    assert np.array(a.eval(s)) == pytest.approx(np.array(b.eval(s)), abs=2e-3)
    x, y, _ = a.eval([arc])
    end = np.array([L_u, 0.01 * L_u ** 2])
    rot = np.array([[math.cos(0.3), -math.sin(0.3)], [math.sin(0.3), math.cos(0.3)]])
    assert (x[0], y[0]) == pytest.approx(tuple(np.array([1.0, 2.0]) + rot @ end), abs=2e-3)


_coord = st.floats(-200, 200, allow_nan=False)


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(_coord, _coord), min_size=4, max_size=4))
def test_param_poly3_is_exactly_the_bezier(pts):
    b = Bezier(*pts)
    if np.hypot(*(np.asarray(pts[3]) - pts[0])) < 1.0 or bezier_length(b) < 1.0:
        return
    x, y, h, c = param_poly3(b)
    p = np.linspace(0, 1, 13)
    u = c["aU"] + p * (c["bU"] + p * (c["cU"] + p * c["dU"]))
    v = c["aV"] + p * (c["bV"] + p * (c["cV"] + p * c["dV"]))
    got = np.column_stack([x + u * math.cos(h) - v * math.sin(h), y + u * math.sin(h) + v * math.cos(h)])
    assert got == pytest.approx(b.point(p), abs=1e-7)


def test_bezier_length_is_accurate():
    b = Bezier((0, 0), (10, 30), (40, -20), (50, 5))
    pts = b.point(np.linspace(0, 1, 200001))
    assert bezier_length(b) == pytest.approx(float(np.hypot(*np.diff(pts, axis=0).T).sum()), abs=1e-6)


# ---------------------------------------------------------------------------------------------
# export: structure of the standard


def structure_problems(root) -> list[str]:
    """Check an OpenDRIVE 1.6 document against the structure the standard requires."""
    bad: list[str] = []

    def need(el, *attrs):
        for a in attrs:
            if el.get(a) is None:
                bad.append(f"<{el.tag}> line {el.sourceline}: missing {a}")

    def order(el, tags):
        seen = [c.tag for c in el if isinstance(c.tag, str)]
        idx = [tags.index(t) for t in seen if t in tags]
        if idx != sorted(idx):
            bad.append(f"<{el.tag}> line {el.sourceline}: children out of order {seen}")
        for t in seen:
            if t not in tags:
                bad.append(f"<{el.tag}> line {el.sourceline}: unexpected child <{t}>")

    if root.tag != "OpenDRIVE":
        return ["root is not <OpenDRIVE>"]
    order(root, ["header", "road", "controller", "junction", "junctionGroup", "station"])
    header = root.find("header")
    if header is None or root.index(header) != 0:
        bad.append("header missing or not first")
    else:
        need(header, "revMajor", "revMinor")
    roads = {r.get("id"): r for r in root.findall("road")}
    junctions = {j.get("id"): j for j in root.findall("junction")}
    signals = {}
    for r in root.findall("road"):
        need(r, "id", "length", "junction")
        order(r, ["link", "type", "planView", "elevationProfile", "lateralProfile", "lanes", "objects", "signals",
                  "surface", "railroad"])
        for kind in ("predecessor", "successor"):
            for lk in r.findall(f"link/{kind}"):
                need(lk, "elementType", "elementId")
                table = roads if lk.get("elementType") == "road" else junctions
                if lk.get("elementId") not in table:
                    bad.append(f"road {r.get('id')}: {kind} {lk.get('elementId')} does not exist")
                if lk.get("elementType") == "road" and lk.get("contactPoint") not in ("start", "end"):
                    bad.append(f"road {r.get('id')}: road link without contactPoint")
        geoms = r.findall("planView/geometry")
        if not geoms:
            bad.append(f"road {r.get('id')}: no geometry")
        total = 0.0
        for g in geoms:
            need(g, "s", "x", "y", "hdg", "length")
            total += float(g.get("length", 0))
            kinds = [c.tag for c in g]
            if len(kinds) != 1 or kinds[0] not in ("line", "arc", "spiral", "poly3", "paramPoly3"):
                bad.append(f"road {r.get('id')}: geometry children {kinds}")
            for pp in g.findall("paramPoly3"):
                need(pp, "aU", "bU", "cU", "dU", "aV", "bV", "cV", "dV", "pRange")
        if abs(total - float(r.get("length", -1))) > 1e-6:
            bad.append(f"road {r.get('id')}: length {r.get('length')} != sum of geometries {total}")
        if r.get("junction") != "-1" and r.get("junction") not in junctions:
            bad.append(f"road {r.get('id')}: junction {r.get('junction')} does not exist")
        secs = r.findall("lanes/laneSection")
        if not secs:
            bad.append(f"road {r.get('id')}: no laneSection")
        for sec in secs:
            need(sec, "s")
            order(sec, ["left", "center", "right"])
            centre = sec.findall("center/lane")
            if len(centre) != 1 or centre[0].get("id") != "0":
                bad.append(f"road {r.get('id')}: center lane must be exactly lane 0")
            for side, sign in (("left", 1), ("right", -1)):
                ids = sorted(abs(int(ln.get("id"))) for ln in sec.findall(f"{side}/lane"))
                if ids != list(range(1, len(ids) + 1)):
                    bad.append(f"road {r.get('id')}: {side} lane ids {ids} not consecutive")
                for ln in sec.findall(f"{side}/lane"):
                    need(ln, "id", "type")
                    if int(ln.get("id")) * sign <= 0:
                        bad.append(f"road {r.get('id')}: lane {ln.get('id')} on the wrong side")
                    order(ln, ["link", "width", "border", "roadMark", "material", "speed", "access", "height", "rule",
                               "include", "userData", "dataQuality"])  # then g_additionalData
                    if not ln.findall("width") and not ln.findall("border"):
                        bad.append(f"road {r.get('id')}: lane {ln.get('id')} has no width")
                    for w in ln.findall("width"):
                        need(w, "sOffset", "a", "b", "c", "d")
        for s in r.findall("signals/signal"):
            need(s, "s", "t", "id", "orientation", "zOffset", "dynamic", "type", "subtype")
            if s.get("orientation") not in ("+", "-", "none"):
                bad.append(f"signal {s.get('id')}: orientation {s.get('orientation')}")
            if s.get("id") in signals:
                bad.append(f"signal {s.get('id')}: duplicate id")
            signals[s.get("id")] = s
        for o in r.findall("objects/object"):
            need(o, "id", "s", "t", "zOffset")
            for c in o.findall("outlines/outline/cornerLocal"):
                need(c, "u", "v", "z")
    for c in root.findall("controller"):
        need(c, "id")
        for ctl in c.findall("control"):
            need(ctl, "signalId")
            if ctl.get("signalId") not in signals:
                bad.append(f"controller {c.get('id')}: unknown signal {ctl.get('signalId')}")
    controllers = {c.get("id") for c in root.findall("controller")}
    for j in root.findall("junction"):
        need(j, "id")
        order(j, ["connection", "priority", "controller", "surface"])
        for c in j.findall("connection"):
            need(c, "id", "incomingRoad", "connectingRoad", "contactPoint")
            con = roads.get(c.get("connectingRoad"))
            if c.get("incomingRoad") not in roads or con is None:
                bad.append(f"junction {j.get('id')}: connection {c.get('id')} names a missing road")
            elif con.get("junction") != j.get("id"):
                bad.append(f"junction {j.get('id')}: connecting road {con.get('id')} is not in this junction")
            if not c.findall("laneLink"):
                bad.append(f"junction {j.get('id')}: connection {c.get('id')} has no laneLink")
            for ll in c.findall("laneLink"):
                need(ll, "from", "to")
        for c in j.findall("controller"):
            if c.get("id") not in controllers:
                bad.append(f"junction {j.get('id')}: unknown controller {c.get('id')}")
    return bad


@pytest.fixture(scope="module")
def exported(tmp_path_factory, sf_default_map):
    path = tmp_path_factory.mktemp("xodr") / "m1.xodr"
    write_opendrive(sf_default_map, path)
    return path


def test_export_has_the_structure_the_standard_requires(exported, sf_default_map):
    root = etree.parse(str(exported)).getroot()
    assert structure_problems(root) == []
    m = sf_default_map
    header = root.find("header")
    assert (header.get("revMajor"), header.get("revMinor")) == ("1", "8")
    assert "+proj=tmerc" in header.find("geoReference").text
    assert len(root.findall("road")) == len(m.roads)
    assert len(root.findall("junction")) == len(m.junctions)
    assert len(root.findall("junction/connection/laneLink")) == sum(
        1 for ln in m.lanes.values() if ln.junction_id is not None)
    assert len(root.findall("road/signals/signal[@type='1000001']")) == len(m.signals)
    assert len(root.findall("road/signals/signal[@type='206']")) == len(m.stop_signs)
    assert len(root.findall("road/objects/object[@type='crosswalk']")) == len(m.crosswalks)
    assert len(root.findall("controller")) == len(m.signals)
    signalized = {s.junction_id for s in m.signals.values()}
    assert {j.get("name") for j in root.findall("junction") if j.findall("controller")} == signalized
    for r in root.findall("road"):  # one exact paramPoly3 per road
        geoms = r.findall("planView/geometry")
        assert len(geoms) == 1 and geoms[0].find("paramPoly3").get("pRange") == "normalized"


def test_structure_check_catches_broken_documents(exported):
    root = etree.parse(str(exported)).getroot()
    root.find("road/planView/geometry").attrib.pop("hdg")
    conn = root.find("junction/connection")
    conn.set("connectingRoad", "99999")
    root.find("road").set("length", "1.0")
    problems = structure_problems(root)
    assert any("missing hdg" in p for p in problems)
    assert any("missing road" in p for p in problems)
    assert any("sum of geometries" in p for p in problems)


def test_paramPoly3_in_file_reproduces_the_model_bezier(exported, sf_default_map):
    root = etree.parse(str(exported)).getroot()
    for r in root.findall("road"):
        road = sf_default_map.roads[r.get("name")]
        g = r.find("planView/geometry")
        c = {k: float(v) for k, v in g.find("paramPoly3").attrib.items() if k != "pRange"}
        x, y, h = (float(g.get(k)) for k in ("x", "y", "hdg"))
        p = np.linspace(0, 1, 7)
        u = c["aU"] + p * (c["bU"] + p * (c["cU"] + p * c["dU"]))
        v = c["aV"] + p * (c["bV"] + p * (c["cV"] + p * c["dV"]))
        got = np.column_stack([x + u * math.cos(h) - v * math.sin(h), y + u * math.sin(h) + v * math.cos(h)])
        assert got == pytest.approx(road.reference.point(p), abs=1e-9)


# ---------------------------------------------------------------------------------------------
# round trip through our reader


def test_round_trip_gives_the_same_junction_features(exported, sf_default_map):
    m = sf_default_map
    back = read_opendrive(exported)
    assert len(back.junctions) == len(m.junctions)
    assert (len(back.lanes), len(back.signals), len(back.stop_signs), len(back.crosswalks)) == (
        len(m.lanes), len(m.signals), len(m.stop_signs), len(m.crosswalks))
    assert back.origin == pytest.approx((587000.0, 4141000.0))
    assert_same_features(m, back)
    turns = Counter(ln.turn for ln in back.lanes.values() if ln.junction_id)
    assert turns == Counter(ln.turn for ln in m.lanes.values() if ln.junction_id)
    for ln in back.lanes.values():  # lanes meet their successors
        for s in ln.successors:
            assert math.dist(ln.end, back.lanes[s].start) < 0.05


@settings(max_examples=6, deadline=None)
@given(st.integers(0, 10_000))
def test_round_trip_for_any_seed(tmp_path_factory, seed):
    import feat2map

    m = feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=seed)
    path = tmp_path_factory.mktemp("seed") / "m.xodr"
    write_opendrive(m, path)
    assert_same_features(m, read_opendrive(path))


def test_split_junction_elements_are_merged(exported, sf_default_map, tmp_path):
    """CARLA-style: one intersection written as two <junction> elements reads as one junction."""
    root = as_another_tools(etree.parse(str(exported)).getroot())
    j = root.find("junction")
    conns = j.findall("connection")
    twin = etree.SubElement(root, "junction", id="9999", name="split")
    moved = set()
    for c in conns[: len(conns) // 2]:
        j.remove(c)
        twin.append(c)
        moved.add(c.get("connectingRoad"))
    for r in root.findall("road"):
        if r.get("id") in moved:
            r.set("junction", "9999")
    path = tmp_path / "split.xodr"
    path.write_bytes(etree.tostring(root))
    back = read_opendrive(path)
    assert len(back.junctions) == len(sf_default_map.junctions)
    assert sorted(back.meta["junction_elements"][j.get("id")]) == sorted([j.get("id"), "9999"])
    assert_same_features(sf_default_map, back)


def test_yield_signs_are_not_stop_signs_and_lights_govern_signs_under_them(tmp_path):
    """Every light gets a yield sign and a stop sign on its pole (as CARLA draws them for when
    the light is dark), and the stop junction's stop signs become yield signs: the lights
    govern their lanes alone, and a junction with yield signs only is bare."""
    import feat2map
    from feat2map.envs.network import MapNetwork
    from feat2map.features import JunctionFeature as JF

    m = feat2map.generate_from_features([JF.make([0, 90, 180, 270], "signal", False),
                                         JF.make([0, 90, 180], "stop", False)], seed=1)
    path = tmp_path / "signs.xodr"
    write_opendrive(m, path)
    root = etree.parse(str(path)).getroot()
    signals = root.findall("road/signals/signal")
    for k, el in enumerate(signals):
        if el.get("type") == "1000001":
            for code in ("205", "206"):
                twin = etree.fromstring(etree.tostring(el))
                twin.set("id", f"{code}{k}")
                twin.set("type", code)
                el.getparent().append(twin)
        elif el.get("type") == "206":
            el.set("type", "205")
    path.write_bytes(etree.tostring(root))
    back = read_opendrive(path)
    lit = {x for s in back.signals.values() for x in s.lane_ids}
    assert len(back.signals) == len(m.signals) and not back.stop_signs
    assert len(back.yield_signs) == len(m.stop_signs)
    assert {x for s in back.yield_signs.values() for x in s.lane_ids}.isdisjoint(lit)
    assert sorted((j.feature.n_roads, j.feature.control) for j in extract_junctions(back)) == [(3, "bare"), (4, "signal")]
    kinds = {lid: sl.kind for lid, sl in MapNetwork.from_map(back).stop_lines.items()}
    assert set(kinds) == lit and set(kinds.values()) == {"signal"}


def test_a_centimetre_road_inside_a_merged_junction_is_no_arm_and_no_route_end(tmp_path):
    """A T junction written as two elements joined by a 1.3 cm road (as CARLA does): still a
    T (n=3, not 4), the road's lane is part of the one junction lane of its manoeuvre, and
    no manoeuvre starts or ends on it."""
    import feat2map
    from feat2map.features import JunctionFeature as JF
    from feat2map.scenarios.routes import coverage_routes, manoeuvres

    m = feat2map.generate_from_features([JF.make([0, 90, 180], "signal", False)], seed=0)
    write_opendrive(m, tmp_path / "t.xodr")
    (tmp_path / "t.xodr").write_bytes(etree.tostring(as_another_tools(etree.parse(str(tmp_path / "t.xodr")).getroot())))
    split_with_a_centimetre_road(tmp_path / "t.xodr", tmp_path / "split.xodr")
    whole, split = read_opendrive(tmp_path / "t.xodr"), read_opendrive(tmp_path / "split.xodr")
    assert split.meta["junction_elements"] == {"1": ["1", "999"]}
    assert not {"902", "903"} & set(split.roads)
    (joined,) = [ln for ln in split.lanes.values() if "902_0_-1" in ln.id]
    assert joined.junction_id == "1" and joined.length == pytest.approx(39.0, abs=0.1)
    assert manoeuvres(split) == manoeuvres(whole) and len(manoeuvres(split)) == 6
    assert [(j.feature.n_roads, j.feature.control) for j in extract_junctions(split)] == [(3, "signal")]
    assert extract_junctions(split)[0].feature.rotation == pytest.approx(extract_junctions(whole)[0].feature.rotation)
    assert {e for r in coverage_routes(split) for _, e, x in r for e in (e, x)} == {"1", "2", "3"}
    assert sorted(len(s.lane_ids) for s in split.signals.values()) == sorted(len(s.lane_ids) for s in whole.signals.values())


def test_a_centimetre_road_is_no_arm_in_any_map():
    """The same piece in a map from any reader (a road lane of 1 cm with both ends in one
    junction): extraction and route coverage leave it out."""
    import dataclasses

    import feat2map
    from feat2map.features import JunctionFeature as JF
    from feat2map.model import Lane, Road
    from feat2map.scenarios.routes import manoeuvres

    m = feat2map.generate_from_features([JF.make([0, 90, 180], "bare", False)], seed=0)
    a = next(ln for ln in m.lanes.values() if ln.junction_id and ln.turn == "none")
    end = np.array(a.end)
    d = np.array(a.centerline[-1]) - np.array(a.centerline[-2])
    d /= np.hypot(*d)
    piece = Lane("piece", "piece_road", ((float(end[0]), float(end[1])), tuple(map(float, end + 0.01 * d))),
                 a.left_boundary[-2:], a.right_boundary[-2:], a.width, a.speed_limit, predecessors=(a.id,),
                 successors=(a.id,))  # leads back into the junction
    lanes = {**m.lanes, "piece": piece, a.id: dataclasses.replace(a, successors=a.successors + ("piece",))}
    bent = dataclasses.replace(m, lanes=lanes, roads={**m.roads, "piece_road": Road("piece_road", "chain", ("piece",))})
    assert manoeuvres(bent) == manoeuvres(m)
    assert [j.feature for j in extract_junctions(bent)] == [j.feature for j in extract_junctions(m)]


def test_a_lane_offset_jumping_at_a_section_end_does_not_fold_the_lane(tmp_path):
    """CARLA (Town03/05/06: 87 lanes) jumps the lane offset at a lane section's start and widens
    an inner non-driving lane by as much, so the driving lane runs straight on; the section
    before must keep its own offset at its last sample (taking the next record folded the lane
    back 2.5 m at every such boundary, and the ego's lane keeping left the road)."""
    doc = """<OpenDRIVE><header revMajor="1" revMinor="4"/>
      <road id="1" length="40" junction="-1"><planView>
        <geometry s="0" x="0" y="0" hdg="0" length="40"><line/></geometry></planView>
        <lanes><laneOffset s="0" a="0" b="0" c="0" d="0"/><laneOffset s="20" a="2.5" b="0" c="0" d="0"/>
          <laneSection s="0"><center><lane id="0" type="none"/></center><right>
            <lane id="-1" type="driving"><link><successor id="-2"/></link><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
          </right></laneSection>
          <laneSection s="20"><center><lane id="0" type="none"/></center><right>
            <lane id="-1" type="none"><width sOffset="0" a="2.5" b="0" c="0" d="0"/></lane>
            <lane id="-2" type="driving"><link><predecessor id="-1"/></link><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>
          </right></laneSection></lanes></road></OpenDRIVE>"""
    (tmp_path / "jump.xodr").write_text(doc)
    (lane,) = read_opendrive(tmp_path / "jump.xodr").lanes.values()
    pts = np.array(lane.centerline)
    assert np.all(np.diff(pts[:, 0]) > 0) and pts[:, 1] == pytest.approx(-1.75)
    assert lane.length == pytest.approx(40.0)


def test_cli_export_opendrive(tmp_path, capsys):
    from feat2map.cli import main

    out = tmp_path / "m"
    assert main(["generate", "--seed", "2", "--out", str(out), "--quiet", "--no-picture"]) == 0
    assert main(["export", "opendrive", str(out / "map.json"), "--out", str(tmp_path / "x.xodr")]) == 0
    assert "wrote" in capsys.readouterr().out
    assert structure_problems(etree.parse(str(tmp_path / "x.xodr")).getroot()) == []
    assert main(["export", "opendrive", str(tmp_path / "nope.json"), "--out", str(tmp_path / "y.xodr")]) == 2
    assert not (tmp_path / "y.xodr").exists()


# ---------------------------------------------------------------------------------------------
# independent reader: SUMO netconvert


def _netconvert() -> str | None:
    exe = Path(sys.executable).parent / "netconvert"
    if exe.exists():
        return str(exe)
    try:
        import sumo  # eclipse-sumo wheel

        cand = Path(sumo.SUMO_HOME) / "bin" / "netconvert"
        if cand.exists():
            return str(cand)
    except ImportError:
        pass
    return shutil.which("netconvert")


def test_netconvert_reads_our_export(exported, sf_default_map, tmp_path):
    exe = _netconvert()
    if exe is None:
        pytest.skip(SKIP_NETCONVERT)
    net = tmp_path / "m1.net.xml"
    res = subprocess.run([exe, "--opendrive-files", str(exported), "--no-turnarounds", "-o", str(net)],
                         capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    root = etree.parse(str(net)).getroot()
    m = sf_default_map
    names = {j.get("id"): j.get("name") for j in etree.parse(str(exported)).getroot().findall("junction")}
    nodes = {n.get("id"): n for n in root.findall("junction") if n.get("type") != "internal"}
    assert set(names) <= set(nodes)  # every OpenDRIVE junction is a SUMO node
    connections = [c for c in root.findall("connection") if not c.get("from").startswith(":")]
    at_junctions = [c for c in connections if c.get("via")]
    assert len(at_junctions) == sum(1 for ln in m.lanes.values() if ln.junction_id is not None)
    signalized = {s.junction_id for s in m.signals.values()}
    assert len(root.findall("tlLogic")) == len(signalized)
    assert {names[n] for n, node in nodes.items() if node.get("type") == "traffic_light"} == signalized


# ---------------------------------------------------------------------------------------------
# real maps


@pytest.mark.real_maps
def test_carla_town01_has_twelve_signalized_three_way_junctions():
    js = extract_junctions(read_opendrive(shared_map("opendrive/carla_town01/Town01.xodr")))
    assert len(js) == 12
    assert Counter(j.feature.n_roads for j in js) == {3: 12}
    assert {j.feature.control for j in js} == {"signal"}


@pytest.mark.real_maps
def test_carla_town05_has_21_intersections():
    js = extract_junctions(read_opendrive(shared_map("opendrive/carla_town05/Town05.xodr")))
    assert Counter(j.feature.n_roads for j in js) == {3: 8, 4: 13}


@pytest.mark.real_maps
@pytest.mark.parametrize("rel,control,crosswalk", [
    ("opendrive/commonroad_four_way_crossing/four_way_crossing.xodr", "signal", True),
    ("opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr", "signal", False),
])
def test_other_dialects_signals_and_crosswalks(rel, control, crosswalk):
    js = extract_junctions(read_opendrive(shared_map(rel)))
    assert [(j.feature.n_roads, j.feature.control, j.feature.crosswalk) for j in js] == [(4, control, crosswalk)]


@pytest.mark.real_maps
def test_svl_cubetown_controls():
    js = extract_junctions(read_opendrive(shared_map("opendrive/svl_cubetown/cubetown.xodr")))
    assert sorted((j.feature.n_roads, j.feature.control) for j in js) == [(3, "signal"), (3, "stop")]


@pytest.mark.real_maps
@pytest.mark.parametrize("xodr,apollo", [
    ("opendrive/svl_borregas_ave/borregasave.xodr", "apollo/borregas_ave/base_map.bin"),
    ("opendrive/svl_cubetown/cubetown.xodr", "apollo/cube_town/base_map.bin"),
])
def test_same_map_in_apollo_and_opendrive_agrees(xodr, apollo):
    from feat2map.formats.apollo import read_apollo

    with warnings.catch_warnings(record=True) as found:  # the maps' own flaws, each named with its file
        warnings.simplefilter("always")
        a = extract_junctions(read_apollo(shared_map(apollo)))
        b = extract_junctions(read_opendrive(shared_map(xodr)))
    assert all(str(w.message).startswith((str(shared_map(apollo)), str(shared_map(xodr)))) for w in found), \
        [str(w.message) for w in found]
    assert sorted((j.feature.n_roads, j.feature.control) for j in a) == sorted(
        (j.feature.n_roads, j.feature.control) for j in b)


# ---------------------------------------------------------------------------------------------
# bad input


def test_signal_code_table_covers_the_dialects_in_the_wild():
    assert SIGNAL_CODES["1000001"] == "signal" and SIGNAL_CODES["1000011"] == "signal"
    assert SIGNAL_CODES["206"] == "stop" and SIGNAL_CODES["205"] == "yield"
    assert "274" not in SIGNAL_CODES  # speed limits are not junction controls


def test_malformed_xml_names_the_file(tmp_path):
    p = tmp_path / "broken.xodr"
    p.write_text("<OpenDRIVE><header revMajor='1'><road></OpenDRIVE>")
    with pytest.raises(MapFormatError, match="broken.xodr.*malformed XML"):
        read_opendrive(p)
    q = tmp_path / "other.xodr"
    q.write_text("<osm version='0.6'/>")
    with pytest.raises(MapFormatError, match="not <OpenDRIVE>"):
        read_opendrive(q)
    r = tmp_path / "empty.xodr"
    r.write_text("<OpenDRIVE><header revMajor='1' revMinor='4'/></OpenDRIVE>")
    with pytest.raises(MapFormatError, match="no readable <road>"):
        read_opendrive(r)


def test_a_file_whose_every_road_is_unreadable_says_why(tmp_path):
    """A dialect that draws lanes as point sets (no <planView>, empty lengths) has no road the
    reader can use: the refusal counts them and names the first with its reason, so a user sees
    what kind of file it is from one line, not only "no readable <road> elements"."""
    p = tmp_path / "pointsets.xodr"
    roads = "".join(f'<road id="R{i}" length="" junction="-1"><lanes><laneSection><left><lane id="1">'
                    f'<border><geometry><pointSet><point x="0" y="{i}"/><point x="9" y="{i}"/></pointSet>'
                    f'</geometry></border></lane></left></laneSection></lanes></road>' for i in range(3))
    p.write_text(f"<OpenDRIVE><header/>{roads}</OpenDRIVE>")
    with pytest.warns(UserWarning, match="skipping bad road"), pytest.raises(MapFormatError) as err:
        read_opendrive(p)
    assert str(err.value) == (f"{p}: no readable <road> elements: all 3 unreadable (first: road R0 (line 1): "
                              "attribute 'length' is not a number: '')")


def test_one_bad_road_is_skipped_with_a_warning_naming_it(exported, tmp_path):
    root = etree.parse(str(exported)).getroot()
    road = root.find("road")
    road.find("planView/geometry").set("x", "not-a-number")
    p = tmp_path / "bad_road.xodr"
    p.write_bytes(etree.tostring(root))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = read_opendrive(p)
    messages = [str(w.message) for w in caught]
    assert any(f"road {road.get('id')} <geometry>" in msg and "'x' is not a number" in msg for msg in messages)
    assert all("bad_road.xodr" in msg for msg in messages)  # every warning names the file
    assert road.get("id") not in m.roads and len(m.roads) == len(root.findall("road")) - 1


def test_cli_reports_broken_xodr_with_exit_code_2(tmp_path, capsys):
    from feat2map.cli import main

    p = tmp_path / "broken.xodr"
    p.write_text("<OpenDRIVE><road id='1'")
    assert main(["extract", str(p)]) == 2
    err = capsys.readouterr().err
    assert "broken.xodr" in err and "Traceback" not in err and len(err.strip().splitlines()) == 1


@pytest.mark.real_maps
@pytest.mark.parametrize("rel", ["opendrive/carla_town01/Town01.xodr",
                                 "opendrive/commonroad_four_way_crossing/four_way_crossing.xodr"])
def test_maps_read_from_files_re_export_with_the_same_features(rel, tmp_path):
    """Roads without a Bézier are written lane by lane as polylines; features survive."""
    m = read_opendrive(shared_map(rel))
    out = tmp_path / "again.xodr"
    write_opendrive(m, out)
    assert structure_problems(etree.parse(str(out)).getroot()) == []
    assert_same_features(m, read_opendrive(out))


_FUZZ_ATTRS = ["s", "x", "y", "hdg", "length", "id", "a", "b", "sOffset", "curvature", "elementId", "incomingRoad",
               "connectingRoad", "from", "to", "junction", "type", "contactPoint", "aU", "bV", "t"]


@settings(max_examples=12, deadline=None)
@given(st.data())
def test_corrupted_documents_read_or_fail_cleanly(tmp_path_factory, data):
    """Random damage (deleted elements, bad or missing attributes): an HDMap or a MapFormatError
    naming the file, never another exception."""
    import feat2map

    root = etree.fromstring(to_opendrive(feat2map.generate(feat2map.PAPER_SF_FEATURE_SPACE, seed=5)))
    elements = [e for e in root.iter() if isinstance(e.tag, str) and e is not root]
    for _ in range(data.draw(st.integers(1, 8))):
        el = elements[data.draw(st.integers(0, len(elements) - 1))]
        action = data.draw(st.sampled_from(["drop", "garble", "remove_attr"]))
        if action == "drop" and el.getparent() is not None:
            el.getparent().remove(el)
        elif action == "garble":
            el.set(data.draw(st.sampled_from(_FUZZ_ATTRS)), data.draw(st.sampled_from(["", "nan", "x", "-1", "1e400"])))
        elif el.attrib:
            el.attrib.pop(data.draw(st.sampled_from(sorted(el.attrib))))
    path = tmp_path_factory.mktemp("fuzz") / "damaged.xodr"
    path.write_bytes(etree.tostring(root))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            m = read_opendrive(path)
        except MapFormatError as exc:
            assert "damaged.xodr" in str(exc)
            return
    try:  # the model it returns is usable; degenerate junctions may be refused, cleanly
        extract_junctions(m)
    except Feat2MapError:
        pass


# ---------------------------------------------------------------------------------------------
# direct junctions (OpenDRIVE 1.7): lane splits and merges without connecting roads

def _direct_junction_xodr() -> bytes:
    """Road 1 (two lanes eastwards) splits at a direct junction into road 2 (one lane on) and road
    3 (an exit bending away): the junction links road 1's lanes to the other roads' lanes."""
    def road(rid, x, y, hdg, lanes, link):
        right = "".join(f'<lane id="{-k}" type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>'
                        for k in range(1, lanes + 1))
        return (f'<road id="{rid}" length="50" junction="-1"><link>{link}</link><planView>'
                f'<geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="50"><line/></geometry></planView>'
                f'<lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right>{right}</right>'
                f'</laneSection></lanes></road>')
    return ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="7"/>'
            + road("1", 0, 0, 0, 2, '<successor elementType="junction" elementId="4"/>')
            + road("2", 50, 0, 0, 1, '<predecessor elementType="junction" elementId="4"/>')
            + road("3", 50, -3.5, -0.2, 1, '<predecessor elementType="junction" elementId="4"/>')
            + '<junction id="4" type="direct">'
              '<connection id="0" incomingRoad="1" linkedRoad="2" contactPoint="start"><laneLink from="-1" to="-1"/>'
              '</connection><connection id="1" incomingRoad="1" linkedRoad="3" contactPoint="start">'
              '<laneLink from="-2" to="-1"/></connection></junction></OpenDRIVE>').encode()


def test_direct_junctions_link_the_roads_lanes(tmp_path):
    path = tmp_path / "direct.xodr"
    path.write_bytes(_direct_junction_xodr())
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = read_opendrive(path)
    assert not [w for w in caught if "unknown road id" in str(w.message)]
    assert m.lanes["1_0_-1"].successors == ("2_0_-1",) and m.lanes["1_0_-2"].successors == ("3_0_-1",)
    assert m.lanes["3_0_-1"].predecessors == ("1_0_-2",)
    assert not m.junctions  # a lane split is no junction manoeuvre


def _link_ends(m) -> set:
    """Each lane link as (end of the lane, end of its successor), to the metre: ids differ across a round trip."""
    def at(p) -> tuple:
        return tuple(np.round(p).astype(int).tolist())
    return {(at(ln.end), at(m.lanes[s].end)) for ln in m.lanes.values() for s in ln.successors}


def test_a_split_or_merge_outside_junctions_is_written_as_a_direct_junction(tmp_path):
    """A lane with two successors (predecessors) outside any junction: a road link would be
    ambiguous (two roads naming one road end), so the roads meet in a direct junction, which
    reads back to the same lane links and no junction."""
    m = split_and_merge_map()
    path = tmp_path / "split.xodr"
    write_opendrive(m, path)
    root = etree.parse(str(path)).getroot()
    assert len(root.findall("junction[@type='direct']")) == 2
    named = Counter((lk.get("elementId"), lk.get("contactPoint")) for r in root.findall("road")
                    if r.get("junction") == "-1" for lk in r.find("link") if lk.get("elementType") == "road")
    assert all(n == 1 for n in named.values()), named
    back = read_opendrive(path)
    assert _link_ends(back) == _link_ends(m) and len(back.lanes) == len(m.lanes)
    assert not back.junctions and extract_junctions(back) == []


def test_a_road_end_at_a_junction_joins_no_direct_junction():
    """a forks into junction lane j and ordinary lane b, which c merges into: a's end links to
    junction 1 (a is its incoming road), not to a direct junction with b and c."""
    root = etree.fromstring(to_opendrive(fork_into_junction_and_road_map()))
    a = next(r for r in root.findall("road") if r.get("name") == "a")
    assert a.find("link/successor").attrib == {"elementType": "junction", "elementId": "1"}
    assert not root.findall("junction[@type='direct']")


def test_a_connecting_road_is_no_incoming_road_of_the_next_junction(tmp_path):
    """Junction lane b continues straight into junction lane c of the adjacent junction: c's
    junction lists no connection from b's connecting road (connecting roads are no incoming
    roads); the road and lane links keep the lane link."""
    m = adjacent_junctions_map()
    path = tmp_path / "adjacent.xodr"
    write_opendrive(m, path)
    root = etree.parse(str(path)).getroot()
    in_junction = {r.get("id") for r in root.findall("road") if r.get("junction") != "-1"}
    incoming = [c.get("incomingRoad") for c in root.iter("connection")]
    assert len(incoming) == 2 and not in_junction & set(incoming)
    assert _link_ends(read_opendrive(path)) == _link_ends(m)


def test_a_lane_forking_into_a_merge_ends_along_the_merged_lane():
    """x forks into s0 and s1 while y merges into s0 at the same point: s0 keeps its start (two
    predecessors), so x's last chord turns to s0's heading and s1 starts along x's last chord;
    ends across different headings left their borders apart (about 0.15 m)."""
    root = etree.fromstring(to_opendrive(merge_at_junction_entry_map()))

    def hdg(name: str, at: int) -> float:
        return float(next(r for r in root.findall("road") if r.get("name") == name).findall(
            "planView/geometry")[at].get("hdg"))
    assert hdg("x", -1) == pytest.approx(hdg("s0", 0), abs=1e-9) == pytest.approx(math.radians(10), abs=1e-3)
    assert hdg("s1", 0) == pytest.approx(hdg("x", -1), abs=1e-9)


def _end_widths(root, name: str) -> tuple[float, float]:
    """The lane width the one-lane road `name` writes at its reference's start and end."""
    road = next(r for r in root.findall("road") if r.get("name") == name)
    ws = road.findall("lanes/laneSection/right/lane/width")
    last = ws[-1]
    return float(ws[0].get("a")), float(last.get("a")) + float(last.get("b")) * (
        float(road.get("length")) - float(last.get("sOffset")))


def test_a_lane_takes_the_width_of_the_lane_it_continues_where_they_meet():
    """Source cross-sections 4 m and 3.5 m wide at a seam: written as they are, the borders
    would jump 0.25 m there. b starts as wide as a ends; h, merging into i, ends as wide as i
    starts; the ends linked to nothing keep their own width."""
    root = etree.fromstring(to_opendrive(uneven_seams_map()))
    assert _end_widths(root, "b")[0] == pytest.approx(3.5, abs=1e-9)
    assert _end_widths(root, "h")[1] == pytest.approx(3.5, abs=1e-9)
    assert _end_widths(root, "b")[1] == pytest.approx(3.5, abs=1e-6)
    assert _end_widths(root, "h")[0] == pytest.approx(3.5, abs=1e-6)


# ---------------------------------------------------------------------------------------------
# road marks and left-hand traffic

_MIRROR_TURN = {"left": "right", "right": "left"}


def _mirror_id(lid: str) -> str:
    road, sec, lane = lid.rsplit("_", 2)
    return f"{road}_{sec}_{-int(lane)}"


def test_road_marks_give_the_boundary_types_and_lane_changes(tmp_path):
    """Broken lines between same-direction lanes read as dotted (a lane change may cross
    them), the centre line and edges as solid: the multi-lane example round-trips its types."""
    from feat2map.invariants import lane_changes
    from feat2map.spec import build_spec, load_spec

    m = build_spec(load_spec(REPO / "examples" / "multi_lane.yaml"))
    write_opendrive(m, tmp_path / "m.xodr")
    back = read_opendrive(tmp_path / "m.xodr")
    roads = [x for x in back.lanes.values() if x.junction_id is None]
    assert Counter((x.left_boundary_type, x.right_boundary_type) for x in roads) == Counter(
        (x.left_boundary_type, x.right_boundary_type) for x in m.lanes.values() if x.junction_id is None)
    assert sum(len(lane_changes(x)) for x in roads) == sum(len(lane_changes(x)) for x in m.lanes.values()) > 0
    # a double line: its inner line is the inner lane's, its outer line the outer lane's
    text = (tmp_path / "m.xodr").read_text()
    first = text.index('type="broken"')
    (tmp_path / "d.xodr").write_text(text[:first] + 'type="solid broken"' + text[first + len('type="broken"'):])
    d = read_opendrive(tmp_path / "d.xodr")
    changed = [k for k in d.lanes if (d.lanes[k].left_boundary_type, d.lanes[k].right_boundary_type)
               != (back.lanes[k].left_boundary_type, back.lanes[k].right_boundary_type)]
    assert len(changed) == 1 and lane_changes(d.lanes[changed[0]]) == ()


def test_left_hand_traffic_reads_as_the_mirror_of_its_right_hand_twin(tmp_path):
    """rule="LHT": positive lane ids drive along the reference line, the centre is on the
    driver's right. The mirror image of a right-hand map read as left-hand traffic drives the
    mirrored paths, keeps its lane changes and exports to Apollo with every exit reachable."""
    from feat2map.formats.apollo.validate import validate_map
    from feat2map.formats.apollo.writer import to_apollo
    from feat2map.spec import build_spec, load_spec

    m = build_spec(load_spec(REPO / "examples" / "multi_lane.yaml"))
    write_opendrive(m, tmp_path / "rht.xodr")
    mirrored_to_left_hand_traffic(tmp_path / "rht.xodr", tmp_path / "lht.xodr")
    rht, lht = read_opendrive(tmp_path / "rht.xodr"), read_opendrive(tmp_path / "lht.xodr")
    assert len(rht.lanes) == len(lht.lanes)
    for lid, a in rht.lanes.items():
        b = lht.lanes[_mirror_id(lid)]
        assert np.allclose(np.asarray(b.centerline), np.asarray(a.centerline) * [1, -1], atol=1e-6), lid
        assert (b.left_boundary_type, b.right_boundary_type) == (a.right_boundary_type, a.left_boundary_type)
        assert (b.left_neighbors, b.right_neighbors) == (tuple(map(_mirror_id, a.right_neighbors)),
                                                         tuple(map(_mirror_id, a.left_neighbors)))
        assert b.successors == tuple(map(_mirror_id, a.successors))
        assert b.turn == _MIRROR_TURN.get(a.turn, a.turn)
    problems = [p for p in validate_map(to_apollo(lht)) if "reachable" in p.message]
    assert problems == []


def test_junction_ids_survive_a_round_trip(exported, tmp_path):
    """A map read from OpenDRIVE keeps its junction ids through export and re-read (a 57-junction
    city's ids were all renumbered 1, 2, ...); generated maps' ids (J0, ...) are numbered, with
    the id as the junction's name, which our reader takes back."""
    root = as_another_tools(etree.parse(str(exported)).getroot())
    new = {j.get("id"): str(100 + 7 * k) for k, j in enumerate(root.findall("junction"))}
    for el in root.iter():
        if el.tag == "junction":
            el.set("id", new[el.get("id")])
        elif el.tag == "road" and el.get("junction") in new:
            el.set("junction", new[el.get("junction")])
        elif el.tag in ("predecessor", "successor") and el.get("elementType") == "junction":
            el.set("elementId", new[el.get("elementId")])
    (tmp_path / "ids.xodr").write_bytes(etree.tostring(root))
    m = read_opendrive(tmp_path / "ids.xodr")
    assert set(m.junctions) == set(new.values())
    write_opendrive(m, tmp_path / "again.xodr")
    assert set(read_opendrive(tmp_path / "again.xodr").junctions) == set(new.values())
    assert [j.get("id") for j in etree.parse(str(exported)).getroot().findall("junction")] == [
        str(k + 1) for k in range(len(new))]

    back = read_opendrive(tmp_path / "again.xodr")  # ours again: ids come back as written
    assert set(read_opendrive(exported).junctions) == {j.get("name") for j in etree.parse(str(exported)).getroot()
                                                        .findall("junction") if j.get("type") != "direct"}
    assert set(back.junctions) == set(new.values())


def test_our_own_files_keep_back_to_back_junctions_ids_and_declared_turns(tmp_path):
    """A map with two junctions back to back (as Apollo's GoMentum has: its 33 became 24 when
    its OpenDRIVE export was read back, the touching elements joined) keeps both through our
    OpenDRIVE file, under their own ids (J_a, J_b, not 1, 2), and each junction lane keeps the
    turn it declares (a U-turn drawn at 168 degrees came back a right turn). Another tool's file
    with the same elements is read by the rules for other producers: one junction."""
    import dataclasses

    m = adjacent_junctions_map()
    ids = {"1": "J_a", "2": "J_b"}
    m = dataclasses.replace(
        m, lanes={k: dataclasses.replace(ln, junction_id=ids.get(ln.junction_id, ln.junction_id),
                                         turn="uturn" if k == "c" else ln.turn) for k, ln in m.lanes.items()},
        roads={k: dataclasses.replace(r, junction_id=ids.get(r.junction_id, r.junction_id)) for k, r in m.roads.items()},
        junctions={ids[k]: dataclasses.replace(j, id=ids[k]) for k, j in m.junctions.items()})
    write_opendrive(m, tmp_path / "ours.xodr")
    back = read_opendrive(tmp_path / "ours.xodr")
    assert set(back.junctions) == {"J_a", "J_b"}
    turns = {ln.junction_id: ln.turn for ln in back.lanes.values() if ln.junction_id and len(ln.predecessors) == 1
             and back.lanes[ln.predecessors[0]].junction_id == "J_a"}
    assert turns == {"J_b": "uturn"}  # c, as declared (its geometry runs straight)
    root = as_another_tools(etree.parse(str(tmp_path / "ours.xodr")).getroot())
    (tmp_path / "theirs.xodr").write_bytes(etree.tostring(root))
    theirs = read_opendrive(tmp_path / "theirs.xodr")
    assert len(theirs.junctions) == 1
    assert all(ln.turn != "uturn" for ln in theirs.lanes.values())  # turns from geometry: c runs straight


# ---------------------------------------------------------------------------------------------
# a connecting road whose lanes name no <link>: the road link links the lanes of the same id

def _unlinked_connector_xodr(rule: str, tail_to_tail: bool) -> bytes:
    """Road 1 (north, ending at junction 9), connecting road 2 (its lanes without <link>s; the
    junction's laneLinks name the incoming side only) and road 3 beyond it, in traffic `rule`.
    With `tail_to_tail` road 3 runs back south and meets road 2 end to end (lane ids mirror)."""
    def lanes(ids: tuple[int, ...]) -> str:
        out = {"left": "", "right": ""}
        for k in ids:
            out["left" if k > 0 else "right"] += (f'<lane id="{k}" type="driving"><width sOffset="0" a="3.5" b="0" '
                                                   f'c="0" d="0"/></lane>')
        return (f'<lanes><laneSection s="0"><left>{out["left"]}</left><center><lane id="0" type="none"/></center>'
                f'<right>{out["right"]}</right></laneSection></lanes>')

    def road(rid, y, hdg, junction, link):
        return (f'<road id="{rid}" length="10" junction="{junction}" rule="{rule}"><link>{link}</link><planView>'
                f'<geometry s="0" x="0" y="{y}" hdg="{hdg}" length="10"><line/></geometry></planView>'
                f'{lanes((1, -1))}</road>')
    ahead = ('<successor elementType="road" elementId="3" contactPoint="end"/>' if tail_to_tail else
             '<successor elementType="road" elementId="3" contactPoint="start"/>')
    road3 = (road("3", 30, -math.pi / 2, -1, '<successor elementType="junction" elementId="9"/>') if tail_to_tail
             else road("3", 20, math.pi / 2, -1, '<predecessor elementType="junction" elementId="9"/>'))
    inner, outer = (1, -1) if rule == "LHT" else (-1, 1)  # the lane driving north on road 1, the one driving south
    back = -outer if tail_to_tail else outer  # road 3's lane driving south, towards the junction
    return ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>'
            + road("1", 0, math.pi / 2, -1, '<successor elementType="junction" elementId="9"/>')
            + road("2", 10, math.pi / 2, 9, '<predecessor elementType="road" elementId="1" contactPoint="end"/>' + ahead)
            + road3
            + '<junction id="9">'
              f'<connection id="0" incomingRoad="1" connectingRoad="2" contactPoint="start">'
              f'<laneLink from="{inner}" to="{inner}"/></connection>'
              f'<connection id="1" incomingRoad="3" connectingRoad="2" contactPoint="end">'
              f'<laneLink from="{back}" to="{outer}"/></connection></junction></OpenDRIVE>').encode()


@pytest.mark.parametrize("rule", ["RHT", "LHT"])
@pytest.mark.parametrize("tail_to_tail", [False, True])
def test_a_connecting_road_without_lane_links_joins_the_road_it_names(tmp_path, rule, tail_to_tail):
    """Without lane <link>s a connecting road's lanes go on into the lanes of the same id of the
    road its road link names (the mirrored id where the roads meet end to end): both ways through
    the junction are manoeuvres."""
    path = tmp_path / f"{rule}.xodr"
    path.write_bytes(_unlinked_connector_xodr(rule, tail_to_tail))
    m = read_opendrive(path)
    inner, outer = (1, -1) if rule == "LHT" else (-1, 1)
    r3_north, r3_south = (inner, outer) if not tail_to_tail else (-inner, -outer)
    assert m.lanes[f"2_0_{inner}"].successors == (f"3_0_{r3_north}",)
    assert m.lanes[f"3_0_{r3_south}"].successors == (f"2_0_{outer}",)
    assert m.lanes[f"2_0_{outer}"].successors == (f"1_0_{outer}",)


# ---------------------------------------------------------------------------------------------
# lane borders of linked polyline roads meet (ASAM's lane_smoothness.contact_point_no_horizontal_gaps)

def _bend_xodr() -> bytes:
    """Two one-lane roads on one 5 m-radius bend, road 1 running into road 2."""
    def road(rid, x, y, hdg, link):
        return (f'<road id="{rid}" length="6" junction="-1"><link>{link}</link><planView>'
                f'<geometry s="0" x="{x}" y="{y}" hdg="{hdg}" length="6"><arc curvature="0.2"/></geometry></planView>'
                '<lanes><laneSection s="0"><center><lane id="0" type="none"/></center><right><lane id="-1" '
                'type="driving"><width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane></right></laneSection></lanes></road>')
    end = _RefLine([_Geometry(0.0, 0.0, 0.0, 0.0, 6.0, "arc", {"curvature": 0.2})]).eval(np.array([6.0]))
    return ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>'
            + road("1", 0, 0, 0, '<successor elementType="road" elementId="2" contactPoint="start"/>')
            + road("2", float(end[0][0]), float(end[1][0]), float(end[2][0]),
                   '<predecessor elementType="road" elementId="1" contactPoint="end"/>')
            + '</OpenDRIVE>').encode()


def test_linked_roads_exported_as_polylines_meet_border_to_border(tmp_path):
    """A read map's lanes are exported as polylines of lines, and a lane's borders at an end lie
    across its end chord. On a bend the end chords of two linked lanes differ, and their borders
    missed each other by 2 cm (ASAM's checker allows 1 cm); the export aligns each joint."""
    src, out = tmp_path / "bend.xodr", tmp_path / "out.xodr"
    src.write_bytes(_bend_xodr())
    m = read_opendrive(src)
    write_opendrive(m, out)
    back = read_opendrive(out)
    first = next(ln for ln in back.lanes.values() if ln.successors)
    second = back.lanes[first.successors[0]]
    for side in ("left_boundary", "right_boundary"):
        gap = np.hypot(*(np.asarray(getattr(first, side))[-1] - np.asarray(getattr(second, side))[0]))
        assert gap < 0.005, (side, gap)


# ---------------------------------------------------------------------------------------------
# a road link whose contactPoint names the far end of the road it links to (CommonRoad's export)

def _far_contact_xodr(contact: str) -> bytes:
    """Two-way road 1 running north to y = 10 and two-way road 2 going on from there, 3 degrees
    off (its lanes' ends miss road 1's by 9 cm). Each road link names `contact` for the other
    road: "far" names the end away from the joint, as CommonRoad's OpenDRIVE export does."""
    def road(rid, y, hdg, link):
        lane = ('<lane id="{k}" type="driving"><link><predecessor id="{k}"/><successor id="{k}"/></link>'
                '<width sOffset="0" a="3.5" b="0" c="0" d="0"/></lane>')
        return (f'<road id="{rid}" length="10" junction="-1"><link>{link}</link><planView>'
                f'<geometry s="0" x="0" y="{y}" hdg="{hdg}" length="10"><line/></geometry></planView>'
                f'<lanes><laneSection s="0"><left>{lane.format(k=1)}</left><center><lane id="0" type="none"/>'
                f'</center><right>{lane.format(k=-1)}</right></laneSection></lanes></road>')
    one, two = ("start", "end") if contact == "far" else ("end", "start")
    return ('<?xml version="1.0"?><OpenDRIVE><header revMajor="1" revMinor="6"/>'
            + road("1", 0, math.pi / 2, f'<successor elementType="road" elementId="2" contactPoint="{two}"/>')
            + road("2", 10, math.pi / 2 + math.radians(3), f'<predecessor elementType="road" elementId="1" '
                                                          f'contactPoint="{one}"/>')
            + '</OpenDRIVE>').encode()


@pytest.mark.parametrize("contact", ["far", "near"])
def test_a_road_link_naming_the_far_end_is_read_at_the_end_that_touches(tmp_path, contact):
    """A road link's contactPoint that names the other road's far end while its near end touches
    is read at the near end, with one warning naming the link: CommonRoad's OpenDRIVE export
    writes such links, and half of ARG_Carcarana's lanes led nowhere (Apollo's export reported
    1,156 exits no entry reached). A link that names the touching end reads silently."""
    from feat2map.invariants import connectivity

    path = tmp_path / f"{contact}.xodr"
    path.write_bytes(_far_contact_xodr(contact))
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        m = read_opendrive(path)
    said = [str(w.message) for w in caught if "far end" in str(w.message)]
    assert len(said) == (1 if contact == "far" else 0), said
    if said:
        assert "road 1 <successor> road 2" in said[0] and "road 2 <predecessor> road 1" in said[0]
    assert m.lanes["1_0_-1"].successors == ("2_0_-1",)
    assert m.lanes["2_0_1"].successors == ("1_0_1",)
    assert connectivity(m) == []


@pytest.mark.real_maps
def test_carcarana_reads_with_every_exit_reachable():
    """CommonRoad's ARG_Carcarana names the far end in 44 of its 102 road links: read at the end
    that touches, every entry reaches every exit (bar its own road's)."""
    from feat2map.invariants import connectivity

    m = read_shared_map("opendrive/commonroad_arg_carcarana/ARG_Carcarana-1_1_T-1.xodr", read_opendrive)
    assert connectivity(m) == [] and len(m.entry_lanes) == len(m.exit_lanes) == 12


def test_a_fold_spiking_into_the_next_junction_does_not_join_them():
    """Junction elements are one intersection when their lanes' areas touch, with the borders'
    folds dropped first: a skewed merge lane written back by the writer spiked 0.9 m past its
    end, over a 0.2 m road, into the next element, and the re-read joined two junctions
    (SUMO's WBeaverAve lost a junction in the round trip)."""
    from types import SimpleNamespace

    from feat2map.formats.opendrive.reader import _Builder, _LaneGeom

    def geom(road: str, x0: float, x1: float, spike: float = 0.0) -> _LaneGeom:
        x = np.linspace(x0, x1, 5)
        left = np.c_[x, np.full(5, 1.75)]
        if spike:  # a skewed end (the left border ends 1 m short), and the border runs past the lane's end first
            left = np.vstack([left[:-1], [x1 + spike, 1.9], [x1 - 1.0, 1.75]])
        return _LaneGeom((road, 0, -1), np.c_[x, np.zeros(5)], left, np.c_[x, np.full(5, -1.75)], 3.5, 10.0)

    for spike, joined in ((0.0, False), (0.9, False)):
        geoms = {g.key: g for g in (geom("a", 0.0, 10.0, spike), geom("b", 10.2, 20.0))}
        stand_in = SimpleNamespace(geoms=geoms, ours=False, roads={"a": SimpleNamespace(junction="1"),
                                                       "b": SimpleNamespace(junction="2")})
        groups = _Builder._junction_groups(stand_in)  # type: ignore[arg-type]
        assert (groups["1"] == groups["2"]) is joined


def test_neighbours_written_as_other_roads_come_back_from_our_own_files(tmp_path):
    """A map without reference lines (read from Apollo) is written one lane per road, so its
    neighbour lanes stand in other roads; our own file names them in the lane's user data and
    they come back (without them Shalun's J_15 approach read back as two arms, and its lanes
    lost their lane changes). Another producer's file with the same roads has none."""
    import feat2map
    from feat2map.features import JunctionFeature as JF
    from feat2map.formats.apollo.reader import read_apollo_bytes
    from feat2map.formats.apollo.writer import to_apollo

    spec = JF.make([0, 90, 180, 270], "signal", False, lanes=2)
    m = read_apollo_bytes(to_apollo(feat2map.generate_from_features([spec], seed=0)).SerializeToString())

    def pairs(mm) -> set:
        at = {k: tuple(np.round(ln.centerline[0], 2)) for k, ln in mm.lanes.items()}
        return {(at[k], at[x], attr) for k, ln in mm.lanes.items() if ln.junction_id is None
                for attr in ("left_neighbors", "right_neighbors", "left_reverse_neighbors") for x in getattr(ln, attr)}
    write_opendrive(m, tmp_path / "ours.xodr")
    assert pairs(m) and pairs(read_opendrive(tmp_path / "ours.xodr")) == pairs(m)
    (tmp_path / "theirs.xodr").write_bytes(etree.tostring(as_another_tools(etree.parse(str(tmp_path / "ours.xodr")).getroot())))
    assert not pairs(read_opendrive(tmp_path / "theirs.xodr"))
