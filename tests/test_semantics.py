"""Load-time semantic checks (feat2map.semantics), conflict-free phase plans (feat2map.phases)
and the readers' handling of what maps declare, on maps the project makes itself: generated
maps exported to OpenDRIVE / Apollo and edited the way other tools write them."""
from __future__ import annotations

import math

import warnings
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from conftest import SKIP_COMMONROAD_IO, keyhole_uturn_map, turned_link_map
from lxml import etree

import feat2map
from feat2map.errors import Feat2MapError
from feat2map.extract import extract_junctions
from feat2map.features import JunctionFeature as JF
from feat2map.features import Socket
from feat2map.formats import write_map
from feat2map.formats.apollo import read_apollo
from feat2map.formats.apollo import schema as aps
from feat2map.formats.opendrive import read_opendrive, write_opendrive
from feat2map.phases import declared_group_conflicts, junction_phases, phase_conflicts
from feat2map import semantics


def _quiet(fn, *a, **kw):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        out = fn(*a, **kw)
    return out, [str(w.message) for w in caught]


@pytest.fixture(scope="module")
def four_way():
    return feat2map.generate_from_features([JF.make([0, 90, 180, 270], "signal", False)], seed=1)


@pytest.fixture(scope="module")
def four_way_xodr(tmp_path_factory, four_way):
    path = tmp_path_factory.mktemp("xodr") / "four.xodr"
    write_opendrive(four_way, path)
    return path


def _edit(src: Path, dst: Path, fn) -> Path:
    root = etree.parse(str(src)).getroot()
    fn(root)
    dst.write_bytes(etree.tostring(root))
    return dst


def _governed(m) -> dict[str, tuple[str, ...]]:
    return {s.name if hasattr(s, "name") else k: tuple(sorted(s.lane_ids)) for k, s in m.signals.items()}


# ---------------------------------------------------------------------------------- phases

def test_legs_at_minus_16_80_179_207_get_a_conflict_free_plan(tmp_path):
    """The generated junction of issue 21 (a Baidu-style map's legs): the angle rule put three of
    its four signals in one phase (CommonRoad validate: 1 problem); grouping by path conflicts
    gives none green together."""
    f = JF(tuple(Socket(a, 1, 1) for a in (-16, 80, 179, 207)), "signal", False)
    m = feat2map.generate_from_features([f], seed=0)
    for paired in (True, False):
        plan = junction_phases(m, paired)
        assert sorted(s for ph in plan["J0"] for s in ph) == sorted(m.signals)
        assert phase_conflicts(m, plan, paired) == []
        assert max(len(ph) for ph in plan["J0"]) <= 2
    assert not [f for f in semantics.findings(m) if f.fatal]
    from feat2map.formats.commonroad import validate_commonroad
    from feat2map.formats.commonroad.writer import commonroad_io

    try:
        commonroad_io()  # scripts/setup.sh puts commonroad-io off sys.path (see commonroad_io)
    except Feat2MapError:
        pytest.skip(SKIP_COMMONROAD_IO)

    write_map(m, tmp_path / "m.xml", "commonroad")
    assert validate_commonroad(tmp_path / "m.xml") == []


def test_a_generated_four_way_pairs_opposite_approaches(four_way):
    plan = junction_phases(four_way)
    (phases,) = plan.values()
    assert len(phases) == 2 and all(len(p) == 2 for p in phases)
    assert len(junction_phases(four_way, paired=False)[next(iter(plan))]) == 4
    assert phase_conflicts(four_way, plan) == []


def test_a_plan_that_puts_crossing_approaches_together_is_reported(four_way):
    jid = next(iter(junction_phases(four_way)))
    everyone = {jid: (tuple(sorted(four_way.signals)),)}
    assert phase_conflicts(four_way, everyone)


def test_declared_groups_are_checked_and_conflicting_ones_kept_apart(four_way):
    (jid, (first, second)), = junction_phases(four_way).items()
    ok = replace(four_way, meta={**four_way.meta, "signal_groups": {"c1": list(first)}})
    assert declared_group_conflicts(ok) == [] and junction_phases(ok)[jid][0] == first
    bad = replace(four_way, meta={**four_way.meta, "signal_groups": {"c2": [first[0], second[0]]}})
    assert declared_group_conflicts(bad) and declared_group_conflicts(bad)[0][0] == "c2"
    assert phase_conflicts(bad, junction_phases(bad)) == []
    found = semantics.findings(bad)
    assert any(f.element == "signal group c2" and not f.fatal for f in found)


# ---------------------------------------------------------------------------------- semantics

def test_dangling_references_are_dropped_with_one_warning_each(four_way):
    sid = next(iter(four_way.signals))
    sig = four_way.signals[sid]
    broken = replace(four_way, signals={**four_way.signals, sid: replace(sig, lane_ids=sig.lane_ids + ("nowhere",))})
    assert any(f.fatal and "nowhere" in f.message for f in semantics.findings(broken))
    with pytest.raises(Feat2MapError, match="nowhere"):
        semantics.assert_sound(broken)
    fixed, caught = _quiet(semantics.drop_dangling, broken, "m.json")
    assert fixed.signals[sid].lane_ids == sig.lane_ids
    assert caught == [f"m.json: signal {sid}: governs unknown lane(s) nowhere, skipped"]
    assert semantics.drop_dangling(four_way) is four_way


def test_checks_are_a_list_others_extend(four_way, monkeypatch):
    """i21b's checks (coincident opposite lanes, merge conflicts) append to CHECKS; the env
    refuses at reset a map with a fatal finding."""
    from feat2map.envs.junction_env import MapFileEnv

    def always(m):
        yield semantics.Finding("lane x", "made-up problem", True)

    monkeypatch.setattr(semantics, "CHECKS", semantics.CHECKS + [always])
    assert semantics.findings(four_way)[-1].message == "made-up problem"
    with pytest.raises(Feat2MapError, match="made-up problem"):  # highway-env resets on construction
        MapFileEnv(config={"map": four_way, "traffic_vehicles": 0}).reset(seed=0)


def test_validate_reports_semantic_findings(four_way_xodr, tmp_path):
    from feat2map.formats.opendrive import validate_opendrive

    def everyone_in_one_controller(root):
        c = etree.SubElement(root, "controller", id="77", name="all")
        for s in root.iter("signal"):
            etree.SubElement(c, "control", signalId=s.get("id"), type="0")
    path = _edit(four_way_xodr, tmp_path / "one_controller.xodr", everyone_in_one_controller)
    m, caught = _quiet(read_opendrive, path)
    assert set(m.meta["signal_groups"]) == {"controller 77"}
    assert any("signal group controller 77" in w for w in caught)
    assert phase_conflicts(m, junction_phases(m)) == []
    problems = [p for p in validate_opendrive(path) if "signal group" in p.message]
    assert problems


# ---------------------------------------------------------------------------------- OpenDRIVE declarations

def test_whole_road_validity_governs_the_orientation_direction_only(four_way_xodr, tmp_path):
    """fromLane=0 toLane=0 (or no validity) means the lanes of the signal's orientation, not
    both directions of the road (a CARLA town put every signal of a junction in one phase)."""
    whole = read_opendrive(four_way_xodr)

    def zero(root):
        for s in root.iter("signal"):
            for v in s.findall("validity"):
                v.set("fromLane", "0")
                v.set("toLane", "0")

    def none(root):
        for s in root.iter("signal"):
            for v in s.findall("validity"):
                s.remove(v)
    for fn in (zero, none):
        m = read_opendrive(_edit(four_way_xodr, tmp_path / f"{fn.__name__}.xodr", fn))
        assert {k: s.lane_ids for k, s in m.signals.items()} == {k: s.lane_ids for k, s in whole.signals.items()}
        assert junction_phases(m) == junction_phases(whole)
        assert phase_conflicts(m, junction_phases(m)) == []


def test_signal_dependencies_switch_together(four_way_xodr, tmp_path):
    """OpenDRIVE 1.6/1.7 `<dependency id=X>` in a signal: it controls signal X (a light switching
    a secondary light). Two lights so linked are a declared group, like a controller's; a
    dependency that names no signal of the file is skipped with one warning."""
    plain = read_opendrive(four_way_xodr)
    together = next(p for plan in junction_phases(plain).values() for p in plan if len(p) > 1)
    a, b = together[0], together[1]

    def depend(root):
        for s in root.iter("signal"):
            if s.get("id") == a:
                etree.SubElement(s, "dependency", id=b, type="secondary")
                etree.SubElement(s, "dependency", id="no-such-signal", type="sign")
    m, caught = _quiet(read_opendrive, _edit(four_way_xodr, tmp_path / "dependency.xodr", depend))
    assert m.meta["signal_groups"] == {f"dependency {a}": [a, b]}
    assert [w for w in caught if "<dependency>" in w] == \
        [f"{tmp_path / 'dependency.xodr'}: <signal id={a}>: <dependency> on unknown signal(s) no-such-signal, skipped"]
    assert declared_group_conflicts(m) == [] and phase_conflicts(m, junction_phases(m)) == []
    assert junction_phases(m) == junction_phases(plain)  # the pair already shares a phase

    crossing = next(x for plan in junction_phases(plain).values() for p in plan for x in p if x not in together)

    def depend_across(root):  # a dependency between crossing approaches: reported, kept apart
        for s in root.iter("signal"):
            if s.get("id") == a:
                etree.SubElement(s, "dependency", id=crossing, type="secondary")
    m, _ = _quiet(read_opendrive, _edit(four_way_xodr, tmp_path / "across.xodr", depend_across))
    assert set(m.meta["signal_groups"]) == {f"dependency {a}"}
    assert declared_group_conflicts(m) and phase_conflicts(m, junction_phases(m)) == []


def test_crosswalk_markings_and_unknown_types_are_no_lights(four_way_xodr, tmp_path):
    def add(root):
        for k, sigs in enumerate(root.iter("signals")):
            for code, name, dyn in (("1000003", "SgRMCrosswalk-2Lanes-4m.flt", "no"), ("987654", "mystery", "yes"),
                                    ("1000001", "painted light", "no")):
                etree.SubElement(sigs, "signal", s="1", t="0", id=f"x{code}_{k}", name=name, dynamic=dyn,
                                 orientation="+", country="OpenDRIVE", type=code, subtype="-1")
    m, caught = _quiet(read_opendrive, _edit(four_way_xodr, tmp_path / "markings.xodr", add))
    plain = read_opendrive(four_way_xodr)
    assert set(m.signals) == set(plain.signals)
    unknown = [w for w in caught if "not in the code tables" in w]
    assert len(unknown) == 1 and "'987654'" in unknown[0]
    static = [w for w in caught if 'dynamic="no"' in w]
    assert len(static) == 1 and "'1000001'" in static[0]
    assert not [w for w in caught if "1000003" in w]  # a known marking: no warning


def test_free_text_traffic_light_types_are_lights(four_way_xodr, tmp_path):
    """Converters from OSM write type="traffic_light" with no country."""
    def free_text(root):
        for s in root.iter("signal"):
            if s.get("type") == "1000001":
                s.set("type", "traffic_light")
                s.set("country", "")
    m = read_opendrive(_edit(four_way_xodr, tmp_path / "free.xodr", free_text))
    plain = read_opendrive(four_way_xodr)
    assert {k: s.lane_ids for k, s in m.signals.items()} == {k: s.lane_ids for k, s in plain.signals.items()}
    assert [j.feature.control for j in extract_junctions(m)] == ["signal"]


def test_a_signal_written_twice_on_its_road_is_one_control(four_way_xodr, tmp_path):
    """VIRES's sample database writes a yield sign twice on one road (same id, place and type):
    that made a second control (`<road>_<id>`). Read once, with one warning naming it."""
    import copy

    def twice(root):
        for sigs in root.iter("signals"):
            for s in list(sigs.findall("signal")):
                sigs.append(copy.deepcopy(s))
    m, caught = _quiet(read_opendrive, _edit(four_way_xodr, tmp_path / "twice.xodr", twice))
    plain = read_opendrive(four_way_xodr)
    assert plain.signals and {k: s.lane_ids for k, s in m.signals.items()} == {
        k: s.lane_ids for k, s in plain.signals.items()}
    assert len([w for w in caught if "declared twice" in w]) == 1


def test_a_stop_line_spans_its_lanes_in_any_listed_order(tmp_path):
    """A signal's lanes listed out of their lateral order (CARLA Town06's 5, 4, 6) gave a stop
    line from one lane's right border to another's left border: zero length where they touch.
    It now runs from the rightmost border to the leftmost across every governed lane."""
    m3 = feat2map.generate_from_features([JF.make([0, 90, 180, 270], "signal", False, lanes=3)], seed=1)
    src = tmp_path / "three.xodr"
    write_opendrive(m3, src)

    def shuffle(root):  # list each side's lanes 2, 1, 3 (file order is free)
        for side in list(root.iter("right")) + list(root.iter("left")):
            lanes = side.findall("lane")
            if len(lanes) == 3:
                for ln in lanes:
                    side.remove(ln)
                for k in (1, 0, 2):
                    side.append(lanes[k])
    m = read_opendrive(_edit(src, tmp_path / "shuffled.xodr", shuffle))
    assert m.signals
    for s in m.signals.values():
        width = sum(m.lanes[g].width for g in s.lane_ids)
        assert len(s.lane_ids) == 3 and abs(math.dist(s.stop_line[0], s.stop_line[-1]) - width) < 0.05


def test_opendrive_1_3_motorway_lane_types_are_driven(four_way_xodr, tmp_path):
    """VIRES ROD writes OpenDRIVE 1.1-1.3's lane types "mwyEntry"/"mwyExit" for ramp lanes; they
    were dropped as undrivable (VIRES's sample database lost its ramps' lanes)."""
    def old_types(root):
        for k, ln in enumerate(root.iter("lane")):
            if ln.get("type") == "driving":
                ln.set("type", "mwyEntry" if k % 2 else "mwyExit")
    m = read_opendrive(_edit(four_way_xodr, tmp_path / "mwy.xodr", old_types))
    assert set(m.lanes) == set(read_opendrive(four_way_xodr).lanes)


def test_implausible_declared_speeds_get_one_warning_and_the_default(four_way_xodr, tmp_path):
    """A converter wrote `<speed max="2.68016" unit="mph"/>` on every lane: 1.2 m/s, no town's
    limit. It reads as the default limits, with one warning naming the file and lanes (it read
    silently as 1.2 m/s and every scenario timed out)."""
    from feat2map.config import JUNCTION_SPEED_LIMIT_MPS, PLAUSIBLE_SPEED_MPS, SPEED_LIMIT_MPS

    def crawl(root):
        for sp in root.iter("speed"):
            sp.set("max", "2.68016")
            sp.set("unit", "mph")
    path = _edit(four_way_xodr, tmp_path / "mph.xodr", crawl)
    m, said = _quiet(read_opendrive, path)
    hits = [w for w in said if "implausible" in w]
    assert len(hits) == 1 and hits[0].startswith(f"{path}: {len(m.lanes)} of {len(m.lanes)} lanes (lanes ")
    assert "1.2 m/s" in hits[0] and f"outside {PLAUSIBLE_SPEED_MPS[0]:g}-{PLAUSIBLE_SPEED_MPS[1]:g} m/s" in hits[0]
    assert {ln.speed_limit for ln in m.lanes.values()} == {SPEED_LIMIT_MPS, JUNCTION_SPEED_LIMIT_MPS}
    assert not [w for w in _quiet(read_opendrive, four_way_xodr)[1] if "implausible" in w]


def test_code_tables():
    from feat2map.formats.opendrive.reader import known_non_control, signal_kind

    assert [signal_kind(t) for t in ("1000001", "traffic_light", "206", "DE:206", "R1-1", "205", "give_way")] == [
        "signal", "signal", "stop", "stop", "stop", "yield", "yield"]
    assert signal_kind("206", "USA") is None and signal_kind("1000001", "OpenDRIVE", "no") is None
    assert signal_kind("1000003", "OpenDRIVE", "no") is None and known_non_control("1000003")
    assert known_non_control("DE:274[60]") and not known_non_control("987654")
    assert known_non_control("roadmark") and signal_kind("roadmark", "", "no") is None  # RoadRunner's stop lines


def test_a_reference_to_a_lane_joined_away_follows_it(tmp_path):
    """CARLA and netconvert maps: a signal referenced from a junction road whose lane the reader
    joins into one junction lane (through a centimetre road) crashed with KeyError '<road>_0_-1'."""
    from conftest import split_with_a_centimetre_road

    m0 = feat2map.generate_from_features([JF.make([0, 90, 180], "signal", False)], seed=0)
    write_opendrive(m0, tmp_path / "t.xodr")
    split_with_a_centimetre_road(tmp_path / "t.xodr", tmp_path / "split.xodr")

    def reference(root):
        sid = next(s.get("id") for s in root.iter("signal") if s.get("type") == "1000001")
        for rid in ("901", "903"):
            road = next(r for r in root.findall("road") if r.get("id") == rid)
            sigs = road.find("signals")
            if sigs is None:
                sigs = etree.SubElement(road, "signals")
            ref = etree.SubElement(sigs, "signalReference", id=sid, s="0", t="0", orientation="+")
            etree.SubElement(ref, "validity", fromLane="-1", toLane="-1")
    path = _edit(tmp_path / "split.xodr", tmp_path / "ref.xodr", reference)
    m, caught = _quiet(read_opendrive, path)
    assert not [w for w in caught if "does not hold" in w]
    (joined,) = [ln for ln in m.lanes.values() if "902_0_-1" in ln.id]
    governs = {x for s in m.signals.values() for x in s.lane_ids}
    assert set(joined.predecessors) <= governs
    assert [j.feature.control for j in extract_junctions(m)] == ["signal"]


# ---------------------------------------------------------------------------------- Apollo

@pytest.fixture(scope="module")
def apollo_pb(tmp_path_factory, four_way):
    out = tmp_path_factory.mktemp("apollo") / "map"
    write_map(four_way, out, "apollo")
    return aps.parse_map((out / "base_map.bin").read_bytes(), "base_map.bin"), out


def _write_pb(pb, tmp_path: Path, name: str) -> Path:
    path = tmp_path / name
    path.write_bytes(pb.SerializeToString())
    return path


def test_apollo_empty_id_objects_are_skipped_not_the_map(apollo_pb, tmp_path):
    pb0, folder = apollo_pb
    plain = read_apollo(folder / "base_map.bin")
    pb = aps.Map()
    pb.CopyFrom(pb0)
    ov = pb.overlap.add()
    ov.id.id = "svl_broken"
    a, b = ov.object.add(), ov.object.add()
    a.id.id = pb.lane[0].id.id
    a.lane_overlap_info.start_s, a.lane_overlap_info.end_s = 0.0, 1.0
    b.id.id = ""
    b.stop_sign_overlap_info.SetInParent()
    pb.stop_sign.add()  # an empty stop sign element, too
    m, caught = _quiet(read_apollo, _write_pb(pb, tmp_path, "empty.bin"))
    assert set(m.signals) == set(plain.signals) and set(m.junctions) == set(plain.junctions)
    assert any("overlap 'svl_broken': holds a stop_sign with an empty id, skipped" in w for w in caught)
    assert any("stop_sign #0: empty id, skipped" in w for w in caught)


def test_apollo_signals_without_overlaps_govern_by_their_stop_line(apollo_pb, tmp_path):
    """Maps converted from other formats tie signals to no lane: the lanes their stop lines
    cross into the junction are governed (a heuristic where the map declares nothing)."""
    pb0, folder = apollo_pb
    plain = read_apollo(folder / "base_map.bin")
    pb = aps.Map()
    pb.CopyFrom(pb0)
    keep = [ov for ov in pb.overlap if not any(o.HasField("signal_overlap_info") for o in ov.object)]
    del pb.overlap[:]
    pb.overlap.extend(keep)
    for s in pb.signal:
        del s.overlap_id[:]
    m = read_apollo(_write_pb(pb, tmp_path, "no_overlaps.bin"))
    assert {k: s.lane_ids for k, s in m.signals.items()} == {k: s.lane_ids for k, s in plain.signals.items()}
    assert [j.feature.control for j in extract_junctions(m)] == ["signal"]


def test_apollo_junction_overlap_ids_naming_lanes_change_nothing(apollo_pb, tmp_path):
    pb0, folder = apollo_pb
    plain = read_apollo(folder / "base_map.bin")
    pb = aps.Map()
    pb.CopyFrom(pb0)
    for j in pb.junction:
        del j.overlap_id[:]
        for ln in pb.lane[:5]:
            j.overlap_id.add().id = ln.id.id
    m = read_apollo(_write_pb(pb, tmp_path, "lane_ids.bin"))
    assert {k: s.lane_ids for k, s in m.signals.items()} == {k: s.lane_ids for k, s in plain.signals.items()}
    assert [j.feature for j in extract_junctions(m)] == [j.feature for j in extract_junctions(plain)]


# ---------------------------------------------------------------------------------- extraction

def test_legs_at_one_angle_are_skipped_with_the_leg_rule(monkeypatch, four_way):
    """Two legs at the same angle (an older CARLA town): the leg rule's reason, not the
    internal 'socket angles must be strictly increasing'."""
    import numpy as np

    from feat2map import extract

    real = extract._arms

    def twins(m, jid, lanes):
        arms = real(m, jid, lanes)
        return arms[:-1] + [replace(arms[0], lanes_in=1, lanes_out=0)]
    monkeypatch.setattr(extract, "_arms", twins)
    skipped: list = []
    _, caught = _quiet(extract.extract_junctions, four_way, "m", skipped=skipped)
    assert len(skipped) == 1 and skipped[0].reason.startswith("sockets 0.00 degrees apart, closer than the minimum")
    assert not any("strictly increasing" in w for w in caught)
    assert np.isfinite(skipped[0].n_arms)


def test_links_between_lanes_that_do_not_meet_are_dropped(four_way):
    """osm2xodr links the roads on both sides of a junction past its connecting roads (gaps up
    to 85 m): routes jumped across the junction. Such links are dropped with one warning."""
    road_lanes = [ln for ln in four_way.lanes.values() if ln.junction_id is None]
    a, b = road_lanes[0], max(road_lanes, key=lambda ln: np.hypot(*np.subtract(ln.start, road_lanes[0].end)))
    lanes = dict(four_way.lanes)
    lanes[a.id] = replace(a, successors=a.successors + (b.id,))
    lanes[b.id] = replace(b, predecessors=b.predecessors + (a.id,))
    jumping = replace(four_way, lanes=lanes)
    assert [f.element for f in semantics.findings(jumping)] == [f"lane {a.id}"]
    fixed, caught = _quiet(semantics.drop_far_links, jumping, "m.xodr")
    assert fixed.lanes[a.id] == a and fixed.lanes[b.id] == b
    assert len(caught) == 1 and caught[0].startswith("m.xodr: 1 lane link(s) between ends more than 5 m apart dropped")
    assert semantics.drop_far_links(four_way) is four_way


def test_a_signal_over_crossing_approaches_is_split(four_way):
    """A CARLA town's references give one light two crossing approaches: one light cannot keep
    them apart, so the readers split it (and the phase plans keep the parts apart)."""
    a, b = list(four_way.signals.values())[:2]
    both = replace(four_way, signals={a.id: replace(a, lane_ids=a.lane_ids + b.lane_ids),
                                      **{k: s for k, s in four_way.signals.items() if k not in (a.id, b.id)}})
    assert any(f.element == f"signal {a.id}" for f in semantics.findings(both))
    split, caught = _quiet(semantics.split_conflicting_signals, both, "m")
    assert {split.signals[a.id].lane_ids, split.signals[f"{a.id}~2"].lane_ids} == {a.lane_ids, b.lane_ids}
    assert len(caught) == 1 and f"split into signals {a.id}, {a.id}~2" in caught[0]
    assert phase_conflicts(split, junction_phases(split)) == []
    assert semantics.split_conflicting_signals(four_way) is four_way
    for part, orig in ((split.signals[a.id], a), (split.signals[f"{a.id}~2"], b)):  # each part: its own lanes' line
        assert np.allclose(part.stop_line, orig.stop_line, atol=1e-6)


def test_apollo_speed_limits_in_kmh_are_converted(apollo_pb, tmp_path):
    """A CARLA-to-Apollo converter wrote 60 (km/h) into every lane's m/s speed_limit: traffic
    entered junctions at 28 m/s. An implausible median is read as km/h, with one warning."""
    pb0, folder = apollo_pb
    plain = read_apollo(folder / "base_map.bin")
    pb = aps.Map()
    pb.CopyFrom(pb0)
    for ln in pb.lane:
        ln.speed_limit = 60.0
    m, caught = _quiet(read_apollo, _write_pb(pb, tmp_path, "kmh.bin"))
    assert [ln.speed_limit for ln in m.lanes.values()] == pytest.approx([60 / 3.6] * len(m.lanes))
    assert sum("read as km/h" in w for w in caught) == 1
    assert max(ln.speed_limit for ln in plain.lanes.values()) < 40


# ---------------------------------------------------------------------------------- SUMO turnarounds

def _add_turnaround(root, road_id: str = "1") -> str:
    """A netconvert-style turnaround connection at the junction end of road `road_id` (a generated
    map's leg: lane 1 drives into the junction at s=0, lane -1 leaves it): an arc turning 126 deg
    in 4.3 m from the incoming lane's end to the outgoing lane's start, with 27 deg kinks at both
    ends (SUMO's `turnaround` connections). Returns the new road's id."""
    road = next(r for r in root.findall("road") if r.get("id") == road_id)
    g = road.find("planView/geometry")
    x0, y0, h = float(g.get("x")), float(g.get("y")), float(g.get("hdg")) + np.pi  # into the junction
    width = 3.5
    lx, ly = x0 + np.sin(h) * width / 2, y0 - np.cos(h) * width / 2  # lane 1's centre: right of h
    turn = np.radians(126.0)
    radius = width / (2 * np.sin(turn / 2))
    new = str(max(int(r.get("id")) for r in root.findall("road")) + 1)
    jid = next(iter(root.findall("junction"))).get("id")
    rd = etree.SubElement(root, "road", name="turnaround", length=f"{radius * turn}", id=new, junction=jid)
    link = etree.SubElement(rd, "link")
    etree.SubElement(link, "predecessor", elementType="road", elementId=road_id, contactPoint="start")
    etree.SubElement(link, "successor", elementType="road", elementId=road_id, contactPoint="start")
    pv = etree.SubElement(rd, "planView")
    geo = etree.SubElement(pv, "geometry", s="0", x=f"{lx}", y=f"{ly}", hdg=f"{h + (np.pi - turn) / 2}",
                           length=f"{radius * turn}")
    etree.SubElement(geo, "arc", curvature=f"{1 / radius}")
    lanes = etree.SubElement(rd, "lanes")
    sec = etree.SubElement(lanes, "laneSection", s="0")
    etree.SubElement(etree.SubElement(sec, "center"), "lane", id="0", type="none")
    ln = etree.SubElement(etree.SubElement(sec, "right"), "lane", id="-1", type="driving")
    ll = etree.SubElement(ln, "link")
    etree.SubElement(ll, "predecessor", id="1")
    etree.SubElement(ll, "successor", id="-1")
    etree.SubElement(ln, "width", sOffset="0", a=f"{width}", b="0", c="0", d="0")
    junction = next(iter(root.findall("junction")))
    con = etree.SubElement(junction, "connection", id="99", incomingRoad=road_id, connectingRoad=new,
                           contactPoint="start")
    etree.SubElement(con, "laneLink", **{"from": "1", "to": "-1"})
    return new


@pytest.fixture(scope="module")
def turnaround_xodr(tmp_path_factory, four_way_xodr) -> Path:
    """The generated four-way with a SUMO-style turnaround connection on its first leg."""
    return _edit(four_way_xodr, tmp_path_factory.mktemp("uturn") / "turnaround.xodr", _add_turnaround)


def test_a_turnaround_connection_is_a_uturn_and_no_suite_manoeuvre(turnaround_xodr):
    """netconvert's turnaround connections turn 126 deg themselves and reverse the road's heading
    with kinks at both ends (radius ~1 m): read as left turns, the route-coverage suite drove them
    and left the road (32 off-road scenarios on two SUMO maps). The connection reverses direction,
    so it is a U-turn; tighter than a car turns, it is left out of the suite with one warning."""
    from feat2map.routes import coverage_routes, manoeuvres, suite_manoeuvres
    from feat2map.scenarios.routes import build_suite, route_coverage

    m, _ = _quiet(read_opendrive, turnaround_xodr)
    (lane,) = [ln for ln in m.lanes.values() if ln.junction_id is not None
               and {m.lanes[x].road_id for x in ln.predecessors + ln.successors} == {"1"}]
    assert lane.turn == "uturn"
    mv = (lane.junction_id, "1", "1")
    assert mv in manoeuvres(m) and mv not in suite_manoeuvres(m)
    routes = coverage_routes(m)
    assert all(mv not in r for r in routes) and route_coverage(m, routes) == 1.0
    suite, caught = _quiet(build_suite, turnaround_xodr)
    assert sum("1 manoeuvre no car drives (U-turns tighter than a car turns, lanes that loop) left out" in w
               for w in caught) == 1
    assert all(mv not in sc.route for sc in suite.scenarios)


def test_a_uturn_joined_from_kinked_pieces_is_tight_where_its_ends_are_far_apart():
    """netconvert U-turns that the reader joins from five pieces through a junction's interior run
    round a box with right-angle kinks: the circle through their ends and middle is wide, the
    car on them is not (off road on every such U-turn). The sharpest stretch decides. Joined
    internal lanes can also run round the interior more than once (up to 700 deg): they loop."""
    from feat2map.model import Lane, as_polyline
    from feat2map.routes import sharpest_radius, tight_uturn

    def lane(pts, turn="uturn"):
        c = as_polyline(np.asarray(pts, dtype=float))
        return Lane("u", "r", c, c, c, 3.0, 10.0, turn=turn, junction_id="J")

    legs = [np.c_[np.arange(0, 10), np.zeros(10)], np.c_[np.full(12, 10), np.arange(0, 12)],
            np.c_[np.arange(10, -1, -1), np.full(11, 12)]]
    box = lane(np.vstack(legs))  # 1 m pieces round a 10 x 12 m box: ends 12 m apart, right-angle kinks
    assert sharpest_radius(box) < 2.0 and tight_uturn(box)
    t = np.linspace(-np.pi / 2, np.pi / 2, 40)
    wide = lane(np.c_[8 * np.cos(t), 8 * np.sin(t)])  # a U-turn of radius 8 m
    assert sharpest_radius(wide) == pytest.approx(8.0, rel=0.05) and not tight_uturn(wide)
    assert not tight_uturn(replace(box, turn="left"))  # only U-turns are left out
    from feat2map.routes import loops, undrivable

    t = np.linspace(0, 3 * np.pi, 120)  # round a 4 m circle one and a half times: 540 deg
    spin = lane(np.c_[4 * np.sin(t), 4 - 4 * np.cos(t)], turn="left")
    assert loops(spin) and undrivable(spin) and not loops(wide) and not loops(replace(box, turn="left"))


# ---------------------------------------------------------------------------------- osm2xodr stubs

def _cut_leg(root, road_id: str = "1", length: float = 1.2) -> None:
    """Cut a generated map's leg (a road from the junction to the map's edge) to `length` metres,
    as osm2xodr cuts OSM ways at the map's bounds just past a junction."""
    road = next(r for r in root.findall("road") if r.get("id") == road_id)
    road.set("length", f"{length}")
    g = road.find("planView/geometry")
    g.set("length", f"{length}")
    for child in list(g):
        g.remove(child)
    etree.SubElement(g, "line")


def test_a_stub_at_the_maps_edge_is_part_of_its_junction(four_way_xodr, tmp_path):
    """osm2xodr maps end OSM ways 1.2 m past a junction: a route from such a stub started the ego
    inside the junction's swept area, where turning traffic hit it (Testfeld_Karlsruhe r018).
    A road at the map's edge shorter than EDGE_STUB_LENGTH_M is part of its junction: no route
    starts or ends on it, and the other legs keep their manoeuvres."""
    from feat2map.routes import coverage_routes, manoeuvres

    full, _ = _quiet(read_opendrive, four_way_xodr)
    m, _ = _quiet(read_opendrive, _edit(four_way_xodr, tmp_path / "stub.xodr", _cut_leg))
    stub = [ln for ln in m.lanes.values() if ln.road_id == "1"]
    assert stub and all(ln.junction_id is not None for ln in stub)
    moves = manoeuvres(m)
    assert moves and all("1" not in mv[1:] for mv in moves)
    assert set(moves) == {mv for mv in manoeuvres(full) if "1" not in mv[1:]}
    assert all("1" not in mv[1:] for r in coverage_routes(m) for mv in r)


def test_an_approach_lane_at_the_maps_edge_too_short_for_a_car_is_no_route_start(four_way):
    """osm2xodr's Testfeld `w850595601_0_0_1`: a 1.1 m approach lane of a 108 m road (the road is
    no stub, so its junction does not take it in), with a signal line at its end and nothing
    before it. The route-coverage suite started the ego there with its front in the junction, and
    a car turning past swung over it (r192). A manoeuvre whose approach holds less than half a
    car, with no lane before it, is left out of the suite (one warning); the same short lane with
    a junction lane before it keeps its manoeuvre (the route starts before that junction)."""
    from feat2map.routes import approach_room, coverage_routes, edge_stub, manoeuvres, suite_manoeuvres
    from feat2map.scenarios.routes import route_coverage

    ln = min((x for x in four_way.lanes.values() if x.junction_id is not None and x.turn == "none"), key=lambda x: x.id)
    (p,) = ln.predecessors
    a = four_way.lanes[p]
    assert not a.predecessors and a.length > 20.0

    def tail(poly):  # the lane's last 1.2 m, straight along its end heading
        pts = np.asarray(poly, dtype=float)
        u = (pts[-1] - pts[-2]) / np.hypot(*(pts[-1] - pts[-2]))
        return (tuple(pts[-1] - 1.2 * u), tuple(pts[-1]))

    short = replace(a, centerline=tail(a.centerline), left_boundary=tail(a.left_boundary),
                    right_boundary=tail(a.right_boundary), bezier=None)
    m = replace(four_way, lanes={**four_way.lanes, p: short})
    assert short.length == pytest.approx(1.2, abs=0.05)
    moved = {mv for mv in manoeuvres(m) if mv[1] == a.road_id}
    assert moved and all(edge_stub(m, mv) and approach_room(m, mv) < 2.5 for mv in moved)
    assert not any(edge_stub(four_way, mv) for mv in manoeuvres(four_way))
    assert set(suite_manoeuvres(m)) == set(suite_manoeuvres(four_way)) - moved
    routes = coverage_routes(m)
    assert all(mv not in moved for r in routes for mv in r) and route_coverage(m, routes) == 1.0
    other = next(x for x in four_way.lanes.values() if x.junction_id is not None and x.successors
                 and x.successors[0] != p and four_way.lanes[x.successors[0]].road_id != a.road_id)
    fed = replace(m, lanes={**m.lanes, p: replace(short, predecessors=(other.id,))})
    assert not any(edge_stub(fed, mv) for mv in moved)  # a junction lane leads in: a route can start before it


def test_links_between_lanes_a_few_metres_apart_are_bridged(four_way):
    """osm2xodr links lanes whose ends lie 1-5 m apart (a stretch without lane ahead, or the
    successor one lane over): a car following the lanes left the road there. The lane's last
    10 m are bent to meet its successor, with one warning; gaps under a metre ahead and two
    to the side (the SVL maps' 0.1-2.5 m seams, which drive clean) stay as they are."""
    a = next(ln for ln in four_way.lanes.values() if ln.junction_id is not None and len(ln.successors) == 1)
    h = a.heading_at_end()

    def moved(back: float, side: float):
        dx, dy = -back * np.cos(h) - side * np.sin(h), -back * np.sin(h) + side * np.cos(h)
        shift = lambda poly: tuple((x + dx, y + dy) for x, y in poly)  # noqa: E731
        lane = replace(a, centerline=shift(a.centerline), left_boundary=shift(a.left_boundary),
                       right_boundary=shift(a.right_boundary), bezier=None)
        return replace(four_way, lanes={**four_way.lanes, a.id: lane})

    target = four_way.lanes[a.successors[0]].start
    for back, side in ((3.0, 0.0), (0.0, 3.0)):
        fixed, caught = _quiet(semantics.bridge_gaps, moved(back, side), "m.xodr")
        assert np.allclose(fixed.lanes[a.id].end, target)
        assert len(caught) == 1 and caught[0].startswith("m.xodr: 1 lane link(s) between ends 1-5 m apart bridged")
        far = fixed.lanes[a.id].centerline[0]
        assert np.allclose(far, moved(back, side).lanes[a.id].centerline[0])  # only the tail moves
    for back, side in ((0.8, 0.0), (0.0, 1.5), (-2.0, 1.5)):
        seam = moved(back, side)
        assert semantics.bridge_gaps(seam) is seam
    assert semantics.bridge_gaps(four_way) is four_way


def test_a_boundary_folding_back_on_itself_is_unfolded(four_way):
    """SVL CubeTown's right turns: the inner border of a lane wider than twice its radius runs
    forward, back (a loop) and forward again. Lanelet2's loader then inverted the bound and the
    turn lost its links. Points behind the ones before them along the centre line are dropped,
    loops cut; both ends stay, and a map without folds is returned as it is."""
    from shapely.geometry import LineString, Point

    a = next(ln for ln in four_way.lanes.values() if ln.junction_id is not None and len(ln.right_boundary) >= 6)
    r = np.asarray(a.right_boundary, dtype=float)
    k = len(r) // 2
    back = r[k - 2] + 0.6 * (r[k - 2] - r[k])  # a spike back past two samples, and a loop across them
    folded = np.vstack([r[:k], [back, r[k - 1] + [0.3, -0.3]], r[k:]])
    m = replace(four_way, lanes={**four_way.lanes, a.id: replace(a, right_boundary=tuple(map(tuple, folded)))})
    fixed, caught = _quiet(semantics.unfolded_boundaries, m, "m.xodr")
    assert caught == [f"m.xodr: 1 lane(s) with a boundary that folds back on itself (a border tighter than the lane's "
                      f"width): the folds dropped ({a.id})"]
    out = np.asarray(fixed.lanes[a.id].right_boundary)
    axis = LineString(np.asarray(a.centerline)[:, :2])
    s = [axis.project(Point(p)) for p in out]
    assert np.all(np.diff(s) > -0.05) and LineString(out).is_simple
    assert np.allclose(out[0], r[0]) and np.allclose(out[-1], r[-1])
    assert fixed.lanes[a.id].left_boundary == a.left_boundary
    assert semantics.unfolded_boundaries(four_way) is four_way


def test_an_offset_lane_folding_round_a_tight_bend_is_cut_where_it_runs_backwards():
    """osm2xodr puts lanes 9 m to the side of roads that bend at a 5 m radius: the lane's offset
    curve folds into a loop (its heading turned 140 degrees in 5 m; the car left the road at
    once). The OpenDRIVE reader keeps the samples that move the lane forward."""
    from feat2map.formats.opendrive.reader import _unfolded

    s = np.linspace(0.0, 20.0, 201)
    h = np.where(s < 10, 0.0, (s - 10) / 3.0)  # straight, then a bend of radius 3 m
    h = np.minimum(h, np.pi / 2)
    x = np.concatenate([[0.0], np.cumsum(np.cos(h[:-1]) * np.diff(s))])
    y = np.concatenate([[0.0], np.cumsum(np.sin(h[:-1]) * np.diff(s))])
    for t in (4.5, -4.5, 1.0):  # 4.5 m to the inner side folds; to the outer side or 1 m in does not
        px, py = x - t * np.sin(h), y + t * np.cos(h)
        keep = _unfolded(s, h, np.full_like(s, t))
        d = np.diff(np.c_[px, py][keep], axis=0)
        heading = np.arctan2(d[:, 1], d[:, 0])
        along = (h[keep][:-1] + h[keep][1:]) / 2  # the reference's direction over each kept step
        assert np.all(np.abs(heading - along) < np.pi / 2 + 1e-6)  # never backwards (a corner, no loop)
        raw = np.arctan2(np.diff(py), np.diff(px))
        assert (len(keep) < len(s)) == bool(np.any(np.abs(np.angle(np.exp(1j * (raw - h[:-1])))) > np.pi / 2))



def _corner_road(path: Path, scale: float) -> Path:
    """One road with a lane 3 m wide on each side: 10.63 m straight, then osm2xodr's cubic
    rounding of a road's last OSM vertex (a paramPoly3 that turns 81 degrees in 1.7 m and
    overshoots its end heading), scaled by `scale`."""
    lane = '<lane id="{i}" type="driving"><link/><width sOffset="0" a="3" b="0" c="0" d="0"/></lane>'
    h0, straight = -0.105, 10.63
    cubic = dict(aU=0.0, bU=0.27915551, cU=2.91169902, dU=-1.45584951, aV=0.0, bV=-1.71240025, cV=3.42480050,
                 dV=-1.71240025)
    coeffs = " ".join(f'{k}="{v * scale}"' for k, v in cubic.items())
    path.write_text(f"""<?xml version="1.0"?>
<OpenDRIVE><header revMajor="1" revMinor="4"/>
<road id="1" junction="-1" length="{straight + 1.735 * scale}"><link/><planView>
<geometry s="0" x="0" y="0" hdg="{h0}" length="{straight}"><line/></geometry>
<geometry s="{straight}" x="{straight * np.cos(h0)}" y="{straight * np.sin(h0)}" hdg="1.3039834"
 length="{1.735 * scale}"><paramPoly3 {coeffs} pRange="normalized"/></geometry>
</planView><lanes><laneSection s="0"><left>{lane.format(i=1)}</left>
<center><lane id="0" type="none"/></center><right>{lane.format(i=-1)}</right></laneSection></lanes></road>
</OpenDRIVE>""")
    return path


def test_an_offset_fold_shorter_than_the_sample_spacing_leaves_no_spike(tmp_path):
    """osm2xodr rounds a road's last corner at a 1.2 m radius in 1.7 m: the lane 1.5 m to the
    inner side folds, and with samples 2 m apart one sample fell inside the fold, a 165-degree
    spike in the lane (5 cars left the road there); the outer lane folds in the cubic's overshoot
    at its end. The fold is found from the exact headings
    between samples, the spike is cut, and both lanes still end where the road ends."""

    def turns(points: np.ndarray) -> np.ndarray:
        d = np.diff(points, axis=0)
        a = np.arctan2(d[:, 1], d[:, 0])
        return np.degrees(np.abs(np.angle(np.exp(1j * np.diff(a)))))

    road = _corner_road(tmp_path / "corner.xodr", 1.0)
    m, caught = _quiet(read_opendrive, road)
    assert [w for w in caught if "fold round" in w] == [f"{road}: 2 lane(s) fold round a bend tighter than their offset from "
                                                  "the reference line; cut where they run backwards (first: lane 1_0_-1)"]
    inner, outer = m.lanes["1_0_1"], m.lanes["1_0_-1"]
    assert turns(inner.points).max() < 90.0 and turns(outer.points).max() < 90.0
    h = 1.3039834  # the cubic ends along its own u axis: the end heading is the geometry's
    end = np.array([10.63 * np.cos(-0.105), 10.63 * np.sin(-0.105)]) + 1.735 * np.array([np.cos(h), np.sin(h)])
    normal = np.array([-np.sin(h), np.cos(h)])
    assert np.allclose(inner.points[0], end + 1.5 * normal, atol=1e-3)  # the left lane starts at the road's end
    assert np.allclose(outer.points[-1], end - 1.5 * normal, atol=1e-3)
    assert np.allclose(inner.points[-1], [-1.5 * np.sin(-0.105), 1.5 * np.cos(-0.105)], atol=1e-6)
    wide, caught = _quiet(read_opendrive, _corner_road(tmp_path / "wide.xodr", 4.0))  # radius 5 m: no fold, nothing cut
    assert not [w for w in caught if "fold round" in w]  # (its inner border's loop in the overshoot is unfolded)
    assert all(len(wide.lanes[k].points) == 12 for k in ("1_0_1", "1_0_-1"))  # every sample


def test_a_tight_turnaround_classed_left_is_no_suite_manoeuvre():
    """Where osm2xodr ends a dual carriageway it joins the two one-way roads with a junction lane
    turning 154 degrees in 7 m: short of a U-turn, so classed left, and tighter than a car turns
    (a car that took it left the road). A turnaround on a mean radius under 4 m is left out like
    a tight U-turn; a wider one (generated junctions turn 151 degrees on 5 m), and a sharp
    120-degree left, are not."""
    from feat2map.model import Lane, as_polyline
    from feat2map.routes import tight_turnaround, undrivable

    def arc(radius: float, degrees: float) -> Lane:
        t = np.linspace(0.0, np.radians(degrees), 30)
        c = as_polyline(np.c_[radius * np.sin(t), radius * (1 - np.cos(t))])
        return Lane("c11", "r", c, c, c, 3.0, 10.0, turn="left", junction_id="J")

    tight = arc(2.7, 154.0)
    assert tight_turnaround(tight) and undrivable(tight)
    assert not undrivable(arc(5.0, 151.0))  # a wider turnaround is driven
    assert not undrivable(arc(2.7, 120.0))  # a sharp left is no turnaround


def test_a_link_into_a_lane_heading_back_is_dropped(four_way):
    """osm2xodr links a road to the opposite carriageway beyond a junction: the successor starts
    3 m away (a gap the bridge rule closes) heading back the way the car came, and a car that
    followed the link left the road. A link whose successor starts heading more than 120
    degrees away from the lane's end is dropped with one warning; the map's own links stay."""
    a = next(ln for ln in four_way.lanes.values() if ln.junction_id is None and ln.successors)
    back = tuple(reversed(a.centerline))
    rev = replace(a, id="rev", centerline=back, left_boundary=tuple(reversed(a.right_boundary)),
                  right_boundary=tuple(reversed(a.left_boundary)), predecessors=(a.id,), successors=(),
                  left_neighbors=(), right_neighbors=(), left_reverse_neighbors=(), bezier=None)
    linked = replace(four_way, lanes={**four_way.lanes, a.id: replace(a, successors=a.successors + ("rev",)),
                                      "rev": rev})
    fixed, caught = _quiet(semantics.drop_far_links, linked, "m.xodr")
    assert fixed.lanes[a.id].successors == a.successors and fixed.lanes["rev"].predecessors == ()
    assert caught == [f"m.xodr: 1 lane link(s) whose successor starts heading more than 120 degrees away dropped "
                      f"(largest: {a.id} -> rev (180 deg))"]
    assert semantics.drop_far_links(four_way) is four_way


# ------------------------------------------------------------- real maps' controls and links

def _unlinked(four_way):
    """four_way with one signalled road lane's links into its junction cut on both sides (SVL's
    Borregas Ave leaves a right-turn lane that runs into its junction lane unlinked): the lane,
    and the junction lanes it ends at."""
    sig = next(iter(four_way.signals.values()))
    lid = sig.lane_ids[0]
    ahead = four_way.lanes[lid].successors
    lanes = dict(four_way.lanes)
    lanes[lid] = replace(lanes[lid], successors=())
    for x in ahead:
        lanes[x] = replace(lanes[x], predecessors=tuple(p for p in lanes[x].predecessors if p != lid))
    meta = {k: v for k, v in four_way.meta.items() if k != "generator"}  # a converted map: written with its flaws
    return replace(four_way, lanes=lanes, meta=meta), lid, ahead


def test_a_lane_leading_nowhere_that_ends_where_others_start_leads_into_them(four_way, tmp_path):
    """Borregas Ave: a right-turn lane ends exactly where its junction lane starts, neither
    naming the other. Apollo routed nothing from it (56 'exit not reachable' problems in the
    export) and its light governed a lane leading nowhere. The readers add the links, one
    warning naming them, and the export validates clean."""
    from feat2map.formats.apollo.validate import validate_apollo

    cut, lid, ahead = _unlinked(four_way)
    write_map(cut, tmp_path / "cut", "apollo")
    m, caught = _quiet(read_apollo, tmp_path / "cut" / "base_map.bin")
    assert set(m.lanes[lid].successors) == set(ahead)
    assert all(lid in m.lanes[x].predecessors for x in ahead)
    added = [w for w in caught if "missing link(s) added" in w]
    assert len(added) == 1 and f": {len(ahead)} missing link(s) added where a lane without successor" in added[0]
    assert f"{lid} -> {ahead[0]}" in added[0]
    assert not [w for w in caught if "not an approach" in w]
    write_map(m, tmp_path / "fixed", "apollo")
    assert validate_apollo(tmp_path / "fixed") == []
    # lanes that merely touch heading back (a dead end's two directions) stay apart
    assert not [w for w in _quiet(read_apollo, tmp_path / "fixed" / "base_map.bin")[1] if "added" in w]
    # a lane that leads on keeps the links it declares (ASAM's VT01 starts a lane where a linked one ends)
    one = replace(cut, lanes={**cut.lanes, lid: replace(cut.lanes[lid], successors=ahead[:1])})
    kept, caught = _quiet(semantics.link_touching_ends, one, "m")
    assert kept is one and caught == []


def test_a_control_naming_its_own_junction_lane_stops_at_that_lanes_start(four_way):
    """GoMentum's back-to-back junctions: a stop sign or light at a junction's entry names that
    junction's lanes, whose predecessors lie in the junction before. Such a lane is an approach
    (no finding), and the Apollo export draws its stop line and overlaps at the lane's start
    (they went to its end, where the reader took the control for another junction's)."""
    from feat2map.formats.apollo import writer as wa
    from feat2map.formats.apollo.validate import validate_map

    sig = next(iter(four_way.signals.values()))
    own = tuple(x for lid in sig.lane_ids for x in four_way.lanes[lid].successors)
    lanes = dict(four_way.lanes)
    for lid in sig.lane_ids:
        lanes[lid] = replace(lanes[lid], successors=())
    for x in own:
        lanes[x] = replace(lanes[x], predecessors=())
    m = replace(four_way, lanes=lanes, signals={**four_way.signals, sig.id: replace(sig, lane_ids=own)})
    assert not [f for f in semantics.findings(m) if "not an approach" in f.message]
    base = wa.to_apollo(m)
    signal = next(s for s in base.signal if s.id.id == sig.id)
    assert len(signal.stop_line) == 1  # one approach, though its lanes turn apart
    ranges = {o.id.id: (o.lane_overlap_info.start_s, o.lane_overlap_info.end_s) for ov in base.overlap
              for o in ov.object if o.HasField("lane_overlap_info") and any(
                  p.id.id == sig.id for p in ov.object)}
    assert set(ranges) == set(own) and all(a == 0.0 for a, _ in ranges.values())
    assert not [p for p in validate_map(base) if p.element == f"signal {sig.id}"]


def test_a_control_over_a_lane_leaving_its_junction_drops_that_lane_with_one_warning(four_way, tmp_path):
    """GoMentum's stop sign 9: its stop line runs across both directions of the road, so it
    also overlaps the lane leaving its junction. The reader drops that lane from it (one warning
    naming both), redraws its line across the lanes it keeps, and the export reads back clean."""
    from feat2map.formats.apollo.validate import validate_apollo
    from feat2map.model import stop_line_across

    sig = next(iter(four_way.signals.values()))
    road = four_way.roads[four_way.lanes[sig.lane_ids[0]].road_id]
    leaving = next(x for x in road.lane_ids if x not in sig.lane_ids)
    both = sig.lane_ids + (leaving,)
    wide = replace(sig, lane_ids=both, stop_line=stop_line_across(four_way.lanes, both))
    m = replace(four_way, signals={**four_way.signals, sig.id: wide})
    assert [f.message for f in semantics.findings(m) if "not an approach" in f.message] == [
        f"governs lane {leaving}, which is not an approach of junction {sig.junction_id}"]
    fixed, caught = _quiet(semantics.drop_non_approaches, m, "m.bin")
    assert fixed.signals[sig.id].lane_ids == sig.lane_ids
    assert np.allclose(fixed.signals[sig.id].stop_line, sig.stop_line, atol=1e-6)
    assert caught == [f"m.bin: signal {sig.id}: governs lane(s) {leaving}, which are not approaches of junction "
                      f"{sig.junction_id}: dropped from it (it keeps {', '.join(sig.lane_ids)})"]
    alone = replace(four_way, signals={**four_way.signals, sig.id: replace(sig, lane_ids=(leaving,))})
    assert sig.id not in _quiet(semantics.drop_non_approaches, alone)[0].signals
    assert semantics.drop_non_approaches(four_way) is four_way
    write_map(m, tmp_path / "wide", "apollo")
    back, caught = _quiet(read_apollo, tmp_path / "wide" / "base_map.bin")
    assert back.signals[sig.id].lane_ids == sig.lane_ids and any("not approaches" in w for w in caught)
    write_map(back, tmp_path / "again", "apollo")
    assert validate_apollo(tmp_path / "again") == []


def test_a_stop_line_drawn_past_the_road_lanes_end_overlaps_the_junction_lanes_it_crosses(four_way):
    """San Francisco draws some stop lines a few metres into the junction, past the road lane's
    end, and ties them to the junction lanes there. The Apollo export overlapped the road lane's
    end instead, 2.3 m from the line ('overlap ... from the stop line'); it now names the
    junction lanes the line crosses, and reads back as the same control."""
    from feat2map.formats.apollo import writer as wa
    from feat2map.formats.apollo.reader import read_apollo_bytes
    from feat2map.formats.apollo.validate import validate_map

    sig = next(iter(four_way.signals.values()))
    h = four_way.lanes[sig.lane_ids[0]].heading_at_end()
    ahead = np.array([math.cos(h), math.sin(h)]) * 2.5
    moved = replace(sig, stop_line=tuple(tuple(np.add(p, ahead)) for p in sig.stop_line))
    m = replace(four_way, signals={**four_way.signals, sig.id: moved})
    base = wa.to_apollo(m)
    assert not [p for p in validate_map(base) if p.element == f"signal {sig.id}"]
    named = {o.id.id for ov in base.overlap for o in ov.object if o.HasField("lane_overlap_info")
             and any(p.id.id == sig.id for p in ov.object)}
    assert named == {x for lid in sig.lane_ids for x in four_way.lanes[lid].successors}
    back, _ = _quiet(read_apollo_bytes, base.SerializeToString())
    assert set(back.signals[sig.id].lane_ids) == set(sig.lane_ids)


def test_a_link_whose_ends_are_turned_against_each_other_is_closed_line_by_line():
    """SVL Borregas Ave joins 8-11 m wide junction lanes to their roads with a 15-25 degree kink:
    one side met, the other missed its successor's by up to 5 m, beyond the exports' per-side snap
    (LANE_END_SNAP_M). Lanelet2 found no route through the turn, CommonRoad a gap, and Apollo
    refused the link. The lane's end is bent onto its successor's start line by line (a line
    whose new end lies alongside it is cut there, not folded back), with one RepairWarning."""
    from shapely.geometry import LineString, Point

    from feat2map.config import LANE_END_SNAP_M
    from feat2map.errors import RepairWarning
    from feat2map.formats.lane_ends import lane_ends

    m = turned_link_map()
    a, b = m.lanes["a"], m.lanes["b"]
    assert math.dist(a.right_boundary[-1], b.right_boundary[0]) > LANE_END_SNAP_M  # the fixture's premise
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        fixed = semantics.loaded(m, "m.xodr")
    said = [w for w in caught if "turned against" in str(w.message)]
    assert len(said) == 1 and issubclass(said[0].category, RepairWarning) and "a -> b" in str(said[0].message)
    fa, fb = fixed.lanes["a"], fixed.lanes["b"]
    assert fb == b  # a, with one successor, is the lane bent
    for f in ("centerline", "left_boundary", "right_boundary"):
        assert math.dist(getattr(fa, f)[-1], getattr(fb, f)[0]) < 1e-9, f
        assert getattr(fa, f)[0] == getattr(a, f)[0]
    axis = LineString(fa.centerline)
    for f in ("left_boundary", "right_boundary"):  # no fold: every line still runs forward
        s = [axis.project(Point(p)) for p in getattr(fa, f)]
        assert np.all(np.diff(s) > -0.05), (f, s)
    ends = lane_ends(fixed)  # the Lanelet2 and CommonRoad exports: each side one point
    assert all(ends[("a", side, "end")] == ends[("b", side, "start")] for side in ("left", "right"))
    assert semantics.turned_link_ends(fixed) is fixed


def test_a_u_turns_inner_border_crossing_itself_where_its_ends_meet_is_no_fold():
    """A U-turn whose ends lie closer than its width has an inner border that crosses itself
    where the ends meet. Located on the whole centre line, its last points lay at the line's
    start (which the centre passes again), and the loop cut at that crossing left a 1 m stub:
    GoMentum's lane_75, whose Lanelet2 bound the loader then turned round (no route through the
    junction). The border is kept as it is; the lane is left unchanged."""
    from shapely.geometry import LineString

    m = keyhole_uturn_map()
    u = m.lanes["u"]
    assert not LineString(u.left_boundary).is_simple  # the fixture's premise: it crosses itself
    assert semantics.unfold(u.left_boundary, u.centerline) is None
    assert semantics.unfolded_boundaries(m) is m
    s = semantics.along(u.left_boundary, u.centerline)
    assert np.all(np.diff(s) > 0) and s[-1] > 0.9 * LineString(u.centerline).length
