"""Robustness over real and generated maps (issue 13): every map in ../shared/maps gives the
controls its own overlaps and signals say, a non-empty route-coverage suite, and drives a sample
of it (traffic 6) without a failure; generated maps drive 5 seeds x traffic 6 x pedestrians
without an ego collision or a timeout.

The default run samples (one scenario per real map, one per seed) to keep CI short; set
FEAT2MAP_LONG_TESTS=1 to drive every scenario of every suite (tens of minutes)."""
from __future__ import annotations

import os
import warnings
from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest

import feat2map
from conftest import SHARED_MAPS, as_another_tools, read_shared_map, shared_map_params, straight_piece
from feat2map.extract import SkippedJunction, extract_junctions
from feat2map.formats import native, read_map
from feat2map.formats.opendrive.reader import SIGNAL_CODES
from feat2map.scenarios.rollout import run_suite
from feat2map.scenarios.routes import build_suite
from feat2map.scenarios.scenario import Scenario, Suite, make_env

LONG = os.environ.get("FEAT2MAP_LONG_TESTS") == "1"
TRAFFIC = 6
PEDESTRIAN_RATE = 3.0  # per crosswalk per minute
SEEDS = range(5)
long_only = pytest.mark.skipif(not LONG, reason="long version: set FEAT2MAP_LONG_TESTS=1")


REAL_MAPS = shared_map_params("apollo/*/*.bin", "apollo/*/*.txt", "opendrive/*/*.xodr")
# maps whose drives fail for a known reason outside the map readers (strict: an unexpected pass fails)
KNOWN_DRIVE_FAILURES: dict[str, str] = {}


@lru_cache(maxsize=None)
def _controls(rel: str) -> dict[str, str]:
    """Junction id -> control extraction gives (junctions it skips included)."""
    skipped: list[SkippedJunction] = []
    m = read_shared_map(rel)  # the map's own findings name its file
    with warnings.catch_warnings(record=True) as said:
        warnings.simplefilter("always")
        found = extract_junctions(m, rel, skipped=skipped)
    assert all(rel in str(w.message) for w in said), [str(w.message) for w in said]
    return {**{j.id: j.feature.control for j in found}, **{s.id: s.control for s in skipped}}


def _apollo_truth(path: Path) -> dict[str, str]:
    """Per junction, from the junction's own overlaps (SOURCES.md's rule): signal if it overlaps
    a signal, stop if a stop sign and no signal, else bare."""
    from feat2map.formats.apollo import schema as aps

    pb = aps.parse_map(path.read_bytes(), str(path))
    overlaps = {o.id.id: o for o in pb.overlap}
    out = {}
    for j in pb.junction:
        kinds = {ob.WhichOneof("overlap_info") for x in j.overlap_id if x.id in overlaps
                 for ob in overlaps[x.id].object}
        out[j.id.id] = ("signal" if "signal_overlap_info" in kinds else "stop" if "stop_sign_overlap_info" in kinds
                        else "bare")
    return out


def _opendrive_lit(path: Path) -> tuple[set[str], bool]:
    """The junction elements a traffic light is placed on or referenced from (a connecting road
    of the element), and whether the file has any light or stop sign at all."""
    from lxml import etree

    root = etree.parse(str(path)).getroot()
    lit, any_control = set(), False
    for r in root.findall("road"):
        kinds = [SIGNAL_CODES.get((s.get("type") or "").strip()) for s in r.findall("signals/signal")]
        any_control |= any(k in ("signal", "stop") for k in kinds)
        lights = [s.get("id") for s, k in zip(r.findall("signals/signal"), kinds) if k == "signal"]
        if r.get("junction") not in (None, "-1") and (lights or r.findall("signals/signalReference")):
            lit.add(r.get("junction"))
    return lit, any_control


@pytest.mark.real_maps
@pytest.mark.parametrize("rel", REAL_MAPS)
def test_real_map_controls_match_its_own_overlaps_and_signals(rel):
    path = SHARED_MAPS / rel
    got = _controls(rel)
    if rel.startswith("apollo/"):
        assert got == _apollo_truth(path)
        return
    m = read_shared_map(rel)  # its findings (signals split, groups kept apart) must name the file
    lit, any_control = _opendrive_lit(path)
    if not any_control:
        assert set(got.values()) <= {"bare"}
    merged = {odr: j for j, odrs in m.meta["junction_elements"].items() for odr in odrs}
    # lights referenced from inside a junction element make its junction a signal one; every
    # light that governs lanes names a junction
    assert all(got.get(merged[e], "signal") == "signal" for e in lit if e in merged)
    assert all(s.junction_id for s in m.signals.values() if s.lane_ids)


@lru_cache(maxsize=None)
def _suite(rel: str) -> Suite:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return build_suite(SHARED_MAPS / rel, traffic_vehicles=TRAFFIC, name=rel.replace("/", "_"))


def _sample(suite: Suite) -> Suite:
    """The whole suite in the long run, else its middle scenario."""
    if LONG:
        return suite
    return Suite(suite.name, (suite.scenarios[len(suite.scenarios) // 2],), suite.base_dir)


def _failures(suite: Suite, fail_on: str = "any") -> list[str]:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        result = run_suite(suite, "baseline", workers=2 if LONG else 1, progress=False, record_failure_gif=False)
    return [f"{o.name}: {o.outcome}: {o.message}" for o in result.failures(fail_on)]


@pytest.mark.real_maps
@pytest.mark.parametrize("rel", REAL_MAPS)
def test_real_map_suite_is_not_empty_and_a_sample_drives_clean(rel, request):
    suite = _suite(rel)
    assert suite.scenarios, rel
    if rel in KNOWN_DRIVE_FAILURES:
        request.applymarker(pytest.mark.xfail(reason=KNOWN_DRIVE_FAILURES[rel], strict=True))
    assert _failures(_sample(suite)) == []


@pytest.fixture(scope="module")
def generated(tmp_path_factory) -> dict[int, Path]:
    """The paper's San Francisco feature space with every control, one map per seed."""
    import dataclasses

    space = dataclasses.replace(feat2map.PAPER_SF_FEATURE_SPACE, controls=("signal", "stop", "bare"))
    d = tmp_path_factory.mktemp("generated")
    out = {}
    for seed in SEEDS:
        out[seed] = d / f"seed{seed}.json"
        native.save(feat2map.generate(space, seed=seed), out[seed])
    return out


@pytest.mark.parametrize("seed", SEEDS)
def test_generated_maps_drive_with_traffic_and_pedestrians_without_collision_or_timeout(generated, seed):
    suite = build_suite(generated[seed], seed=100 * seed, traffic_vehicles=TRAFFIC, pedestrian_rate=PEDESTRIAN_RATE)
    picked = suite if LONG else Suite(suite.name, (suite.scenarios[seed % len(suite.scenarios)],), suite.base_dir)
    assert _failures(picked) == []


def _split_approach(src: Path, dst: Path, pieces: tuple[float, ...]) -> None:
    """CARLA-style short roads before a stop line: the exported stub road 1 (junction at its
    start, a stop sign there) cut into roads of `pieces` metres from the junction out, the rest
    of its length last; straight stubs become lines."""
    from lxml import etree

    root = as_another_tools(etree.parse(str(src)).getroot())
    road = next(r for r in root.findall("road") if r.get("id") == "1")
    total = float(road.find("planView/geometry").get("length"))
    lengths = [*pieces, total - sum(pieces)]
    ids = ["1"] + [str(900 + k) for k in range(1, len(lengths))]
    parent, at = road.getparent(), road.getparent().index(road)
    parent.remove(road)
    s0 = 0.0
    for k, length in enumerate(lengths):
        r = straight_piece(road, ids[k], s0, length)
        link = r.find("link")
        if k > 0:
            for el in list(link):
                link.remove(el)
            etree.SubElement(link, "predecessor", elementType="road", elementId=ids[k - 1], contactPoint="end")
            for sig in r.findall("signals/signal"):
                sig.getparent().remove(sig)
        if k + 1 < len(lengths):
            etree.SubElement(link, "successor", elementType="road", elementId=ids[k + 1], contactPoint="start")
        for ln in r.findall("lanes/laneSection/*/lane"):
            lk = ln.find("link")
            if lk is None or ln.get("id") == "0":
                continue
            if k > 0:
                etree.SubElement(lk, "predecessor", id=ln.get("id"))
            if k + 1 < len(lengths):
                etree.SubElement(lk, "successor", id=ln.get("id"))
        parent.insert(at + k, r)
        s0 += length
    dst.write_bytes(etree.tostring(root))


def test_short_roads_before_a_stop_line_drive_clean(tmp_path):
    """An OpenDRIVE map the test makes (a stop-controlled T exported, one approach cut into a
    2.4 m last road before the line, a 1.5 m road and the rest, as CARLA draws them): read
    back, every manoeuvre's route drives with traffic, the ego starting a braking distance
    before the line and its stop on the short last lane counting."""
    from feat2map.formats.opendrive.writer import write_opendrive

    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "stop", False)], seed=0)
    write_opendrive(m, tmp_path / "t.xodr")
    _split_approach(tmp_path / "t.xodr", tmp_path / "short.xodr", (2.4, 1.5))
    short = read_map(tmp_path / "short.xodr")
    lens = sorted(round(ln.length, 1) for ln in short.lanes.values() if ln.junction_id is None)
    assert lens[:4] == [1.5, 1.5, 2.4, 2.4]
    assert any(round(short.lanes[x].length, 1) == 2.4 for s in short.stop_signs.values() for x in s.lane_ids)
    suite = build_suite(tmp_path / "short.xodr", traffic_vehicles=2)
    assert len(suite.scenarios) == 6  # every manoeuvre of the T
    assert _failures(suite) == []


def _shorten_link(src: Path, dst: Path, length: float) -> None:
    """Back-to-back junctions, as Shalun has them: the exported straight road between J0 and J1
    (road 3, west to east, stop lines at both ends) cut to `length` metres, J1 and its roads
    moved west by what was cut."""
    from lxml import etree

    root = as_another_tools(etree.parse(str(src)).getroot())
    roads = {r.get("id"): r for r in root.findall("road")}
    link = roads["3"]
    cut = float(link.get("length")) - length
    geo = link.find("planView/geometry")
    geo.remove(geo[0])
    etree.SubElement(geo, "line")
    geo.set("length", repr(length))
    link.set("length", repr(length))
    for sig in link.findall("signals/signal"):
        sig.set("s", repr(min(float(sig.get("s")), length)))
    east = [r for r in roads.values() if r.get("junction") == "2" or any(
        e.get("elementType") == "junction" and e.get("elementId") == "2" for e in r.find("link")) and r is not link]
    for r in east:
        for g in r.findall("planView/geometry"):
            g.set("x", repr(float(g.get("x")) - cut))
    dst.write_bytes(etree.tostring(root))


def test_back_to_back_stop_junctions_drive_clean(tmp_path):
    """An OpenDRIVE map the test makes (two 4-way stop junctions joined by a 3 m road, as
    Shalun's J_1 and J_14 are): a vehicle stopped at the second junction's line stands with its
    centre inside the first; its stop counts there (it joins the second junction's stop-sign
    queue, the ego's judge records it), so every route drives on (Shalun r001 and nine more
    timed out with a car waiting forever at J_14's line inside J_1)."""
    from feat2map.formats.opendrive.writer import write_opendrive

    four = feat2map.JunctionFeature.make([0, 90, 180, 270], "stop", False)
    write_opendrive(feat2map.generate_from_features([four, four], seed=0), tmp_path / "twin.xodr")
    _shorten_link(tmp_path / "twin.xodr", tmp_path / "back_to_back.xodr", 3.0)
    m = read_map(tmp_path / "back_to_back.xodr")
    link = [ln for ln in m.lanes.values() if ln.road_id == "3"]
    assert len(link) == 2 and all(abs(ln.length - 3.0) < 1e-6 for ln in link)
    assert {s.junction_id for s in m.stop_signs.values() if set(s.lane_ids) & {ln.id for ln in link}} == {"1", "2"}
    suite = build_suite(tmp_path / "back_to_back.xodr", traffic_vehicles=2)
    assert _failures(suite) == []
    # traffic: a car that leaves J0 for J1 waits at J1's line inside J0, then drives on
    held = Scenario("held", str(tmp_path / "back_to_back.xodr"), (("1", "2", "4"),), seed=0, duration=60.0)
    env = make_env(held, config={"traffic_respawn": False})  # the ego waits on J0's south approach
    env.reset(seed=0)
    u = env.unwrapped

    def through(jid: str, entry: str, exit_: str) -> str:
        return next(ln.id for ln in m.lanes_by_junction[jid] if m.lanes[ln.predecessors[0]].road_id == entry
                    and m.lanes[ln.successors[0]].road_id == exit_)

    j0, j1 = through("1", "1", "3"), through("2", "3", "6")
    route = [j0, m.lanes[j0].successors[0], j1, m.lanes[j1].successors[0]]
    car = u.road.spawn(route[0], u.net.lane_of[route[0]].length - 8.0, 5.0, route)
    for _ in range(40 * u.config["policy_frequency"]):
        env.step(np.array([-1.0]))  # full brake: the ego stands
        if u.net.id_of.get(car.lane_index) == route[-1]:
            break
    env.close()
    assert u.net.id_of.get(car.lane_index) == route[-1]


def _shorten_road(src: Path, dst: Path, road: str, length: float) -> None:
    """Road `road` of an exported west-to-east chain cut to `length` metres (a straight line),
    every road starting east of it moved west by what was cut."""
    from lxml import etree

    root = as_another_tools(etree.parse(str(src)).getroot())
    link = next(r for r in root.findall("road") if r.get("id") == road)
    geo = link.find("planView/geometry")
    x0, cut = float(geo.get("x")), float(link.get("length")) - length
    geo.remove(geo[0])
    etree.SubElement(geo, "line")
    geo.set("length", repr(length))
    link.set("length", repr(length))
    for r in root.findall("road"):
        gs = r.findall("planView/geometry")
        if r is not link and float(gs[0].get("x")) > x0 + 1.0:
            for g in gs:
                g.set("x", repr(float(g.get("x")) - cut))
    dst.write_bytes(etree.tostring(root))


def _chain(tmp_path: Path, control: str = "bare"):
    """(map, its path, the route's lanes from junction 1 through 2 and 3, a function naming a
    junction's lane from one road to another) of an OpenDRIVE map the test makes: three 4-way
    junctions under `control` in a row, joined by 3 m and 1.5 m roads, as CARLA Town04's 1249, 870
    and 483 are."""
    from feat2map.formats.opendrive.writer import write_opendrive

    four = feat2map.JunctionFeature.make([0, 90, 180, 270], control, False)
    write_opendrive(feat2map.generate_from_features([four, four, four], seed=0), tmp_path / "three.xodr")
    _shorten_road(tmp_path / "three.xodr", tmp_path / "two.xodr", "6", 1.5)
    _shorten_road(tmp_path / "two.xodr", tmp_path / "chain.xodr", "3", 3.0)
    m = read_map(tmp_path / "chain.xodr")
    assert sorted(round(ln.length, 1) for ln in m.lanes.values() if ln.road_id in ("3", "6")) == [1.5, 1.5, 3.0, 3.0]

    def through(jid: str, entry: str, exit_: str) -> str:
        return next(ln.id for ln in m.lanes_by_junction[jid] if m.lanes[ln.predecessors[0]].road_id == entry
                    and m.lanes[ln.successors[0]].road_id == exit_)

    j1, j2, j3 = through("1", "1", "3"), through("2", "3", "6"), through("3", "6", "9")
    route = [j1, m.lanes[j1].successors[0], j2, m.lanes[j2].successors[0], j3, m.lanes[j3].successors[0]]
    return m, tmp_path / "chain.xodr", route, through


def test_a_chain_of_back_to_back_junctions_is_one_box(tmp_path):
    """A car enters the first junction of a chain (`_chain`) only while its lanes in the second
    and the third are clear, since it cannot wait between them (a car waiting inside 1249 for 483
    and one inside 483 for 1249 locked up: Town04 r034)."""
    m, path, route, _ = _chain(tmp_path)
    j1, j2, j3 = route[0], route[2], route[4]
    env = make_env(Scenario("chain", str(path), (("1", "2", "4"),), seed=0), config={"traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    car = u.road.spawn(route[0], 0.5, 0.0, route)
    env.step(np.array([-1.0]))
    assert u.rules.box_clear(car, j1)  # nothing in the way
    other = sorted(u.net.conflicts[j3])[0]
    blocker = u.road.spawn(other, 2.0, 0.0, [other, m.lanes[other].successors[0]])
    env.step(np.array([-1.0]))  # the rules see the blocker on its lane
    assert any(v is blocker for v in u.rules.buckets.get(other, ()))
    assert u.rules.junction_clear(j2, car)  # the second junction alone would let it in
    assert not u.rules.box_clear(car, j1)  # but it would wait inside the first for the third
    env.close()


def test_a_stop_sign_queue_lets_later_road_users_past_one_the_box_rule_holds(tmp_path):
    """At the first junction of a chain under stop signs (`_chain`), a car that stopped first and
    wants a lane conflicting with a later car's is held by the box rule (its lane in the third
    junction is blocked): the later car's turn has come, as the rules ask it of one road user and
    as the core asks it of every queued row (`sim.stop_signs.turns`)."""
    from feat2map.envs.sim import stop_signs

    m, path, route, through = _chain(tmp_path, "stop")
    j1, j3 = route[0], route[4]
    env = make_env(Scenario("chain", str(path), (("1", "2", "4"),), seed=0),
                   config={"traffic_vehicles": 0, "traffic_respawn": False})
    env.reset(seed=0)
    u = env.unwrapped
    core = u.road.core
    crossing = next(x for x in (through("1", "2", "4"), through("1", "4", "2")) if j1 in u.net.conflicts[x])
    other = sorted(u.net.conflicts[j3])[0]
    u.road.spawn(other, 2.0, 0.0, [other, m.lanes[other].successors[0]])  # blocks the first car's way

    def stopped_at_line(junction_lane: str, rest: list[str]):
        approach = m.lanes[junction_lane].predecessors[0]
        line = u.net.stop_lines[approach].s
        return u.road.spawn(approach, line - 1.0, 0.0, [approach, junction_lane, *rest])

    first = stopped_at_line(j1, route[1:])
    env.step(np.array([-1.0]))
    later = stopped_at_line(crossing, [m.lanes[crossing].successors[0]])
    env.step(np.array([-1.0]))
    queue = u.rules.stop_queue[m.lanes[j1].junction_id]
    assert queue.index(first) < queue.index(later)
    assert not u.rules.box_clear(first, j1)
    assert u.rules.stop_queue_allows(later, crossing)
    assert stop_signs.turns(core, np.array([later.row]), np.array([core.table.index[crossing]])).tolist() == [True]
    env.close()
