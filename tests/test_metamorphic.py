"""Metamorphic tests: transformations that keep a map's meaning must keep what feat2map reads
from it: the junction features, the controls of each junction and its phase groups.

OpenDRIVE: rename every id, translate and rotate the whole map, split every lane section in
two, drop optional elements. Apollo: rename every id, translate and rotate, thin the curves as
Apollo's sim_map does, drop optional elements. Run over maps the project generates itself
(exported to .xodr and Apollo) and over the maps in ../shared/maps: a few small ones by
default, all of them with FEAT2MAP_LONG_TESTS=1 (skipped cleanly without ../shared/maps).
"""
from __future__ import annotations

import copy
import math
import warnings
from collections.abc import Sequence
from pathlib import Path

import pytest
from lxml import etree

import feat2map
from conftest import LONG_TESTS, shared_map, shared_map_params
from feat2map.extract import extract_junctions
from feat2map.features import JunctionFeature as JF
from feat2map.formats import write_map
from feat2map.formats.apollo import read_apollo
from feat2map.formats.apollo import schema as aps
from feat2map.formats.apollo.sim_map import to_sim_map
from feat2map.formats.opendrive import read_opendrive, write_opendrive
from feat2map.phases import junction_phases, phase_conflicts

SMALL_XODR = ("opendrive/svl_cubetown/cubetown.xodr", "opendrive/commonroad_four_way_crossing/four_way_crossing.xodr",
              "opendrive/esmini_fabriksgatan/fabriksgatan_traffic_lights.xodr")
SMALL_APOLLO = ("apollo/cube_town/base_map.bin",)
ANGLE = 0.7  # radians: a rotation no grid direction survives
SHIFT = (1234.5, -678.25)


def _read(fn, path):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return fn(path)


def meaning(m) -> list[tuple]:
    """What a map means to feat2map, independent of ids and placement: per junction its arm
    count, control, crosswalk, signal / stop sign / yield sign counts, phase group sizes
    (paired and single), and its arms counter-clockwise as (lanes in, lanes out, gap in degrees
    to the next arm). Phase plans must be conflict-free."""
    paired, single = junction_phases(m, True), junction_phases(m, False)
    assert phase_conflicts(m, paired, True) == [] and phase_conflicts(m, single, False) == []
    out = []
    for j in extract_junctions(m):
        f = j.feature
        kinds = tuple(sum(1 for s in getattr(m, t).values() if s.junction_id == j.id)
                      for t in ("signals", "stop_signs", "yield_signs"))
        rot = f.rotation
        gaps = [(rot[(i + 1) % len(rot)] - rot[i]) % 360.0 for i in range(len(rot))]
        arms = tuple((s.lanes_in, s.lanes_out, g) for s, g in zip(f.sockets, gaps))
        out.append(((f.n_roads, f.control, f.crosswalk, kinds, tuple(sorted(len(p) for p in paired.get(j.id, ()))),
                     tuple(sorted(len(p) for p in single.get(j.id, ())))), arms))
    return sorted(out, key=lambda x: (x[0], sorted(a[:2] for a in x[1])))


def _same_arms(a, b, tol: float) -> bool:
    """Arms equal up to where the cycle starts (normalization picks among tied gaps), gaps
    within `tol` degrees."""
    n = len(a)
    return len(b) == n and any(all(x[:2] == y[:2] and abs(x[2] - y[2]) <= tol for x, y in zip(a, b[r:] + b[:r]))
                               for r in range(n))


def assert_same_meaning(a, b, angle_tol_deg: float = 1.0) -> None:
    """Every junction of `a` has one of `b` with the same features, controls and phase groups;
    leg gaps within `angle_tol_deg`."""
    ma, mb = meaning(a), meaning(b)
    assert len(ma) == len(mb), (len(ma), len(mb))
    left = list(mb)
    for key, arms in ma:
        hit = next((k for k, (kb, armsb) in enumerate(left) if kb == key and _same_arms(arms, armsb, angle_tol_deg)), None)
        assert hit is not None, (key, arms, [x for x in left if x[0][0] == key[0]][:3])
        left.pop(hit)


# ---------------------------------------------------------------------------------- OpenDRIVE

def xodr_rename(root) -> None:
    """Every road, junction and signal id prefixed, and every reference to one."""
    for r in root.findall("road"):
        r.set("id", "r" + r.get("id"))
        if r.get("junction") not in (None, "-1", ""):
            r.set("junction", "j" + r.get("junction"))
        for kind in ("predecessor", "successor"):
            e = r.find(f"link/{kind}")
            if e is not None and e.get("elementId") is not None:
                e.set("elementId", ("j" if e.get("elementType") == "junction" else "r") + e.get("elementId"))
        for s in r.findall("signals/signal") + r.findall("signals/signalReference"):
            s.set("id", "s" + s.get("id"))
    for j in root.findall("junction"):
        j.set("id", "j" + j.get("id"))
        for c in j.findall("connection"):
            for k in ("incomingRoad", "connectingRoad"):
                if c.get(k) is not None:
                    c.set(k, "r" + c.get(k))
    for c in root.findall("controller"):
        for k in c.findall("control"):
            k.set("signalId", "s" + k.get("signalId"))


def xodr_move(root) -> None:
    """The whole map rotated by ANGLE about the origin and shifted by SHIFT."""
    c, s = math.cos(ANGLE), math.sin(ANGLE)
    for g in root.iter("geometry"):
        x, y = float(g.get("x")), float(g.get("y"))
        g.set("x", repr(c * x - s * y + SHIFT[0]))
        g.set("y", repr(s * x + c * y + SHIFT[1]))
        g.set("hdg", repr(float(g.get("hdg")) + ANGLE))


def _shift_poly(el, d: float, key: str) -> None:
    """A cubic record a + b u + c u^2 + d u^3 re-expanded about u = d (its new start)."""
    a, b, c, e = (float(el.get(k, "0")) for k in "abcd")
    el.set("a", repr(a + b * d + c * d * d + e * d ** 3))
    el.set("b", repr(b + 2 * c * d + 3 * e * d * d))
    el.set("c", repr(c + 3 * e * d))
    el.set(key, "0")


def xodr_split_sections(root) -> None:
    """Every lane section cut in two at its middle (width records re-expanded, lanes linked
    across the cut): the same lanes in more pieces."""
    for r in root.findall("road"):
        lanes = r.find("lanes")
        secs = lanes.findall("laneSection")
        ends = [float(x.get("s")) for x in secs[1:]] + [float(r.get("length"))]
        for sec, end in zip(secs, ends):
            s0 = float(sec.get("s"))
            mid = (s0 + end) / 2
            if end - s0 < 1.0 or sec.findall(".//border") or any(len(ln.findall("width")) != 1 for ln in sec.iter("lane")
                                                                 if ln.get("id") != "0"):
                continue
            second = copy.deepcopy(sec)
            second.set("s", repr(mid))
            for ln in second.iter("lane"):
                for w in ln.findall("width"):
                    _shift_poly(w, mid - s0, "sOffset")
                for rm in ln.findall("roadMark"):
                    ln.remove(rm)
            for first_ln, second_ln in zip(sec.iter("lane"), second.iter("lane")):
                lid = first_ln.get("id")
                if lid == "0":
                    continue
                for ln, _keep, new in ((first_ln, "predecessor", "successor"), (second_ln, "successor", "predecessor")):
                    link = ln.find("link")
                    if link is None:
                        link = etree.Element("link")
                        ln.insert(0, link)
                    for x in link.findall(new):
                        link.remove(x)
                    etree.SubElement(link, new, id=lid)
            sec.addnext(second)


def _compose(coef: list[float], shift: float, sign: float = 1.0) -> list[float]:
    """Coefficients (a, b, c, d) of q(x) = p(shift - x) for the cubic p with coefficients `coef`,
    times `sign`."""
    a, b, c, d = coef
    return [sign * (a + b * shift + c * shift ** 2 + d * shift ** 3), sign * -(b + 2 * c * shift + 3 * d * shift ** 2),
            sign * (c + 3 * d * shift), sign * -d]


def _reverse_records(els, start_key: str, span: float, sign: float = 1.0) -> None:
    """Piecewise cubic records (start `start_key`, a..d) over [0, span] rewritten for the
    reversed direction: record j on [o_j, o_j+1) becomes one on [span - o_j+1, span - o_j)."""
    recs = sorted(((float(e.get(start_key)), [float(e.get(k, "0")) for k in "abcd"], e) for e in els), key=lambda r: r[0])
    ends = [r[0] for r in recs[1:]] + [span]
    for (o, coef, e), end in zip(recs, ends):
        new = _compose(coef, end - o, sign)  # x' from the reversed start: p(end - o - x')
        e.set(start_key, repr(max(span - end, 0.0)))
        for k, v in zip("abcd", new):
            e.set(k, repr(v))


def _reversible(r) -> bool:
    geoms = r.findall("planView/geometry")
    kinds = [next((c.tag for c in g if isinstance(c.tag, str)), None) for g in geoms]
    return bool(geoms) and all(k in ("line", "arc", "spiral", "paramPoly3") for k in kinds) and not r.findall(".//border")


def _reverse_geometry(g, x1: float, y1: float, h1: float) -> None:
    """One geometry record driven backwards from its end pose (x1, y1, h1)."""
    prim = next(c for c in g if isinstance(c.tag, str))
    length = float(g.get("length"))
    h0 = float(g.get("hdg"))
    g.set("x", repr(x1))
    g.set("y", repr(y1))
    g.set("hdg", repr(h1 + math.pi))
    if prim.tag == "arc":
        prim.set("curvature", repr(-float(prim.get("curvature"))))
    elif prim.tag == "spiral":
        a, b = float(prim.get("curvStart")), float(prim.get("curvEnd"))
        prim.set("curvStart", repr(-b))
        prim.set("curvEnd", repr(-a))
    elif prim.tag == "paramPoly3":
        pmax = 1.0 if prim.get("pRange", "normalized") != "arcLength" else length
        u = [float(prim.get(k, "0")) for k in ("aU", "bU", "cU", "dU")]
        v = [float(prim.get(k, "0")) for k in ("aV", "bV", "cV", "dV")]
        ur, vr = _compose(u, pmax), _compose(v, pmax)  # P(pmax - p'), still in the old local frame
        ur[0] -= sum(c * pmax ** i for i, c in enumerate(u))  # relative to the old end point
        vr[0] -= sum(c * pmax ** i for i, c in enumerate(v))
        rot = h0 - (h1 + math.pi)  # old local frame -> new local frame
        c, s = math.cos(rot), math.sin(rot)
        for k, (a, b) in enumerate(zip(ur, vr)):
            prim.set(("aU", "bU", "cU", "dU")[k], repr(c * a - s * b))
            prim.set(("aV", "bV", "cV", "dV")[k], repr(s * a + c * b))


def xodr_reverse(root) -> None:
    """Every road whose reference line is made of lines, arcs, spirals or paramPoly3 driven the
    other way: geometry reversed, lanes renumbered (left <-> right, ids negated), sections,
    widths and the lane offset reversed, links, junction connections, signals (s, t,
    orientation, validity) and objects moved to the new s and t."""
    from feat2map.formats.opendrive.reader import _geometry, _Ctx, _RefLine

    ctx = _Ctx("reverse")
    flipped = {r.get("id") for r in root.findall("road") if _reversible(r)}
    swap_cp = {"start": "end", "end": "start"}
    for r in root.findall("road"):
        if r.get("id") not in flipped:
            continue
        length = float(r.get("length"))
        geoms = r.findall("planView/geometry")
        ref = _RefLine([_geometry(ctx, g, r.get("id")) for g in geoms])
        starts = [float(g.get("s")) for g in geoms]
        ends = starts[1:] + [length]
        pv = r.find("planView")
        for g, _s0, s1 in zip(geoms, starts, ends):
            x, y, h = ref.eval([s1 - 1e-9])
            _reverse_geometry(g, float(x[0]), float(y[0]), float(h[0]))
            g.set("s", repr(length - s1))
            pv.remove(g)
        for g in sorted(geoms, key=lambda e: float(e.get("s"))):
            pv.append(g)
        link = r.find("link")
        if link is not None:
            p, q = link.find("predecessor"), link.find("successor")
            if p is not None:
                p.tag = "successor"
            if q is not None:
                q.tag = "predecessor"
            for e in link:
                if e.get("elementType", "road") == "road" and e.get("elementId") in flipped and e.get("contactPoint"):
                    pass  # the other road turns too: its contact point stays the same word
        lanes = r.find("lanes")
        _reverse_records(lanes.findall("laneOffset"), "s", length, -1.0)
        secs = lanes.findall("laneSection")
        s_starts = [float(x.get("s")) for x in secs]
        s_ends = s_starts[1:] + [length]
        for sec, s0, s1 in zip(secs, s_starts, s_ends):
            lanes.remove(sec)
            sec.set("s", repr(length - s1))
            left, right = sec.find("left"), sec.find("right")
            for side in (left, right):
                if side is None:
                    continue
                for ln in side.findall("lane"):
                    ln.set("id", str(-int(ln.get("id"))))
                    _reverse_records(ln.findall("width"), "sOffset", s1 - s0)
                    for tag in ("roadMark", "speed", "access", "height", "material", "rule"):
                        for e in ln.findall(tag):
                            ln.remove(e)
                    lk = ln.find("link")
                    if lk is not None:
                        for e in lk:
                            e.tag = {"predecessor": "successor", "successor": "predecessor"}.get(e.tag, e.tag)
                            if e.get("id") is not None:
                                e.set("id", str(-int(e.get("id"))))
            if left is not None:
                left.tag = "right"
            if right is not None:
                right.tag = "left"
            for side in (sec.find("left"), sec.find("right")):  # lanes listed outward-in as the standard shows
                if side is not None:
                    side[:] = sorted(side, key=lambda e: -int(e.get("id")))
            order = [x for x in (sec.find("left"), sec.find("center"), sec.find("right")) if x is not None]
            for x in order:
                sec.remove(x)
            sec.extend(order)
            center = sec.find("center")
            if center is not None:
                for ln in center.findall("lane"):
                    for e in ln.findall("roadMark"):
                        ln.remove(e)
        for sec in sorted(secs, key=lambda e: float(e.get("s"))):
            lanes.append(sec)
        for e in r.findall("type")[1:]:
            r.remove(e)
        for e in r.findall("type"):
            e.set("s", "0.0")
        for tag in ("elevationProfile", "lateralProfile"):
            for e in r.findall(tag):
                r.remove(e)
        for sg in r.findall("signals/signal") + r.findall("signals/signalReference"):
            sg.set("s", repr(length - float(sg.get("s", "0"))))
            sg.set("t", repr(-float(sg.get("t", "0"))))
            sg.set("orientation", {"+": "-", "-": "+"}.get(sg.get("orientation", "+"), sg.get("orientation")))
            for v in sg.findall("validity"):
                a, b = -int(v.get("fromLane")), -int(v.get("toLane"))
                v.set("fromLane", str(min(a, b)))
                v.set("toLane", str(max(a, b)))
        for o in r.findall("objects/object"):
            o.set("s", repr(length - float(o.get("s", "0"))))
            o.set("t", repr(-float(o.get("t", "0"))))
            o.set("hdg", repr(float(o.get("hdg", "0")) - math.pi))
            for k in o.iter("cornerRoad"):
                k.set("s", repr(length - float(k.get("s"))))
                k.set("t", repr(-float(k.get("t"))))
    for r in root.findall("road"):  # links to a turned road meet its other end
        for e in r.findall("link/predecessor") + r.findall("link/successor"):
            if e.get("elementType", "road") == "road" and e.get("elementId") in flipped and e.get("contactPoint"):
                e.set("contactPoint", swap_cp[e.get("contactPoint")])
    for j in root.findall("junction"):
        for c in j.findall("connection"):
            if c.get("connectingRoad") in flipped and c.get("contactPoint"):
                c.set("contactPoint", swap_cp[c.get("contactPoint")])
            for ll in c.findall("laneLink"):
                if c.get("incomingRoad") in flipped:
                    ll.set("from", str(-int(ll.get("from"))))
                if c.get("connectingRoad") in flipped:
                    ll.set("to", str(-int(ll.get("to"))))


def xodr_drop_optional(root) -> None:
    """Elements that carry no meaning for driving: user data, road marks, elevation, lateral
    profiles, materials, lane speeds, the header's geo reference."""
    for tag in ("userData", "roadMark", "elevationProfile", "lateralProfile", "material", "geoReference"):
        for el in list(root.iter(tag)):
            el.getparent().remove(el)


XODR_TRANSFORMS = {"rename": xodr_rename, "move": xodr_move, "split_sections": xodr_split_sections,
                   "drop_optional": xodr_drop_optional, "reverse": xodr_reverse}


def _xodr_case(src: Path, tmp: Path, name: str):
    root = etree.parse(str(src)).getroot()
    XODR_TRANSFORMS[name](root)
    out = tmp / f"{name}.xodr"
    out.write_bytes(etree.tostring(root))
    return _read(read_opendrive, out)


# ---------------------------------------------------------------------------------- Apollo

def _walk(msg, fn) -> None:
    """Call fn on every sub-message of `msg` (depth first)."""
    for field, value in msg.ListFields():
        if field.type != field.TYPE_MESSAGE:
            continue
        for v in (value if getattr(field, "is_repeated", None) or isinstance(value, Sequence) else [value]):
            fn(v)
            _walk(v, fn)


def apollo_rename(pb) -> None:
    def ren(v):
        if v.DESCRIPTOR.name == "Id" and v.id:
            v.id = "x_" + v.id
    _walk(pb, ren)


def apollo_move(pb) -> None:
    c, s = math.cos(ANGLE), math.sin(ANGLE)

    def mv(v):
        if v.DESCRIPTOR.name == "PointENU":
            x, y = v.x, v.y
            v.x, v.y = c * x - s * y + SHIFT[0], s * x + c * y + SHIFT[1]
    _walk(pb, mv)


def apollo_thin(pb) -> None:
    pb.CopyFrom(to_sim_map(pb))


def apollo_drop_optional(pb) -> None:
    for ln in pb.lane:
        for f in ("left_sample", "right_sample", "left_road_sample", "right_road_sample"):
            ln.ClearField(f)
        ln.ClearField("speed_limit")
    pb.header.ClearField("vendor")
    pb.header.ClearField("district")


APOLLO_TRANSFORMS = {"rename": apollo_rename, "move": apollo_move, "thin": apollo_thin,
                     "drop_optional": apollo_drop_optional}
# sim_map thinning is lossy: a curved road's last segment becomes a chord up to 5 m long, whose
# direction is off the tangent by a degree or two, and the measured centre of a junction with
# such arms moves (gaps up to 6 degrees off seen on a generated skewed 4-way); everything else is exact
ANGLE_TOL_DEG = {"thin": 8.0}
# thinning moves one GoMentum 3-way's mouths across arms: lossy, known, not a reader defect
LOSSY = {("apollo/gomentum/base_map.bin", "thin"): "sim_map thinning regroups one bare 3-way's lane mouths"}


def _apollo_case(src: Path, tmp: Path, name: str):
    pb = aps.parse_map(src.read_bytes(), str(src))
    APOLLO_TRANSFORMS[name](pb)
    out = tmp / f"{name}.bin"
    out.write_bytes(pb.SerializeToString())
    return _read(read_apollo, out)


# ---------------------------------------------------------------------------------- generated maps

@pytest.fixture(scope="module")
def generated(tmp_path_factory):
    """A generated map with a signalized 4-way, a stop T and a bare 5-leg junction, exported to
    OpenDRIVE and Apollo."""
    tmp = tmp_path_factory.mktemp("gen")
    m = feat2map.generate_from_features([JF.make([0, 90, 180, 270], "signal", True), JF.make([0, 90, 180], "stop", False),
                                         JF.make([-16, 80, 179, 207], "signal", False)], seed=2)
    write_opendrive(m, tmp / "gen.xodr")
    write_map(m, tmp / "apollo", "apollo")
    return tmp / "gen.xodr", tmp / "apollo" / "base_map.bin"


@pytest.mark.parametrize("name", sorted(XODR_TRANSFORMS))
def test_generated_xodr_keeps_its_meaning(generated, tmp_path, name):
    base = _read(read_opendrive, generated[0])
    assert len(meaning(base)) == 3
    assert_same_meaning(base, _xodr_case(generated[0], tmp_path, name))


@pytest.mark.parametrize("name", sorted(APOLLO_TRANSFORMS))
def test_generated_apollo_keeps_its_meaning(generated, tmp_path, name):
    base = _read(read_apollo, generated[1])
    assert len(meaning(base)) == 3
    assert_same_meaning(base, _apollo_case(generated[1], tmp_path, name), ANGLE_TOL_DEG.get(name, 1.0))


def test_the_transforms_change_the_files(generated, tmp_path):
    """A transform that left the file as it was would prove nothing."""
    src = generated[0].read_bytes()
    for name in XODR_TRANSFORMS:
        root = etree.fromstring(src)
        XODR_TRANSFORMS[name](root)
        assert etree.tostring(root) != etree.tostring(etree.fromstring(src)), name
    pb0 = aps.parse_map(generated[1].read_bytes(), "x")
    for name, fn in APOLLO_TRANSFORMS.items():
        pb = aps.Map()
        pb.CopyFrom(pb0)
        fn(pb)
        assert pb.SerializeToString() != pb0.SerializeToString(), name


# ---------------------------------------------------------------------------------- real maps

def _shared(kind: str, small: tuple[str, ...]) -> list:
    if not LONG_TESTS:
        return list(small)
    return shared_map_params("opendrive/*/*.xodr" if kind == "opendrive" else "apollo/*/base_map.bin")


@pytest.mark.real_maps
@pytest.mark.parametrize("name", sorted(XODR_TRANSFORMS))
@pytest.mark.parametrize("rel", _shared("opendrive", SMALL_XODR))
def test_shared_xodr_keeps_its_meaning(rel, name, tmp_path):
    path = shared_map(rel)
    assert_same_meaning(_read(read_opendrive, path), _xodr_case(path, tmp_path, name))


@pytest.mark.real_maps
@pytest.mark.parametrize("name", sorted(APOLLO_TRANSFORMS))
@pytest.mark.parametrize("rel", _shared("apollo", SMALL_APOLLO))
def test_shared_apollo_keeps_its_meaning(rel, name, tmp_path):
    path = shared_map(rel)
    if (rel, name) in LOSSY:
        pytest.xfail(LOSSY[rel, name])
    assert_same_meaning(_read(read_apollo, path), _apollo_case(path, tmp_path, name), ANGLE_TOL_DEG.get(name, 1.0))
