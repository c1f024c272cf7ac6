"""Driving motorway ramps (examples/ramps.yaml and a sampled map with every ramp value): the
network makes every ramp merge a conflict (a car on the acceleration lane and one on the main
lane take the merge in turn), and the route-coverage suites merge from every on-ramp, diverge
onto every off-ramp and complete at traffic 6 with the baseline planner, the scenarios named
after their merge or diverge. Ramps joined through a direct link (no junction: OpenDRIVE's
direct junctions) get lane routes that do the same, on our own map and on public ones."""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import corpus_map, example_map_file, shared_map

from feat2map.envs.network import MapNetwork, merge_pairs
from feat2map.features import PAPER_SF_FEATURE_SPACE
from feat2map.formats import native
from feat2map.generate import generate
from feat2map.model import HDMap


@pytest.fixture(scope="module")
def map_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "ramps")


@pytest.fixture(scope="module")
def sampled_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sampled_ramps") / "map.json"
    native.save(generate(replace(PAPER_SF_FEATURE_SPACE, ramp=("none", "on", "off", "both")), seed=0), path)
    return path


def ramp_roads(m: HDMap) -> set[str]:
    return {r for j in m.junctions.values() if j.feature is not None and j.feature.has_ramp
            for r, s in zip(j.socket_roads, j.feature.sockets) if s.ramp != "none"}


def test_every_ramp_merge_is_a_conflict(map_path):
    m = native.load(map_path)
    net = MapNetwork.from_map(m)
    ramps = ramp_roads(m)
    merging = [ln.id for ln in m.lanes.values() if ln.junction_id and any(m.lanes[p].road_id in ramps
                                                                          for p in ln.predecessors)]
    pairs = {frozenset(p) for p in merge_pairs(m)}
    for lid in merging:
        partners = [p for p in pairs if lid in p]
        assert partners, lid  # it merges with the main lane into the rightmost lane
        for p in partners:
            (other,) = p - {lid}
            assert other in net.conflicts[lid]


@pytest.mark.parametrize("which", ["map_path", "sampled_path"])
def test_the_suite_merges_and_diverges_at_every_ramp_and_completes_at_traffic_6(request, which):
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    path = request.getfixturevalue(which)
    ramps = ramp_roads(native.load(path))
    suite = build_suite(path, traffic_vehicles=6, seed=0)
    taking = [sc for sc in suite.scenarios if any(mv[1] in ramps or mv[2] in ramps for mv in sc.route)]
    assert {r for sc in taking for mv in sc.route for r in mv[1:] if r in ramps} == ramps  # every ramp, both ways
    for sc in taking:  # named after each merge (ramp -> main) and diverge (main -> ramp), as real maps' ramps are
        kinds = ["merge" if mv[1] in ramps else "diverge" for mv in sc.route if (mv[1] in ramps) != (mv[2] in ramps)]
        assert sc.name == "-".join([sc.name.split("-")[0], sc.name.split("-")[1], *kinds]), sc.route
    for sc in taking:
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, out.message)


def direct_ramps(m: HDMap) -> HDMap:
    """`m` with every ramp's junction lane made a road lane of its own road: each ramp joins its
    road through a direct link, as OpenDRIVE's direct junctions draw them (no junction holds it)."""
    from feat2map.extract_ramps import extract_ramps

    via = {path[1] for r in extract_ramps(m) for path in r.links if len(path) == 3}
    lanes = {k: replace(ln, junction_id=None) if k in via else ln for k, ln in m.lanes.items()}
    roads = {k: replace(r, kind="chain", junction_id=None) if set(r.lane_ids) & via else r for k, r in m.roads.items()}
    return replace(m, lanes=lanes, roads=roads)


@pytest.fixture(scope="module", params=[("json", "native"), ("xodr", "opendrive")], ids=["native", "opendrive"])
def direct_path(request, map_path, tmp_path_factory) -> Path:
    """examples/ramps.yaml's map with its ramps joined through direct links, saved natively or
    exported to OpenDRIVE (which writes them as road links that read back as such)."""
    from feat2map.formats import write_map

    suffix, fmt = request.param
    path = tmp_path_factory.mktemp("direct_ramps") / f"direct.{suffix}"
    write_map(direct_ramps(native.load(map_path)), path, fmt)
    return path


def ramp_scenarios_complete(path: Path) -> list[str]:
    """The names of the route-coverage suite's ramp scenarios (traffic 6), after asserting each
    completes with the baseline planner."""
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # what the reader repairs in a public map is not this test's subject
        suite = build_suite(path, traffic_vehicles=6, seed=0)
    taking = [sc for sc in suite.scenarios if sc.name.endswith(("-merge", "-diverge"))]
    for sc in taking:
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, sc.route, out.message)
    return [sc.name for sc in taking]


def test_ramps_through_direct_links_get_merge_and_diverge_routes_that_complete(direct_path, tmp_path):
    from feat2map.extract_ramps import extract_ramps
    from feat2map.formats import read_map
    from feat2map.formats.openscenario import write_openscenario
    from feat2map.scenarios.routes import build_suite
    from feat2map.scenarios.scenario import load_suite, save_suite

    found = extract_ramps(read_map(direct_path))
    assert sorted(r.kind for r in found) == ["off", "off", "on"] and {r.junction for r in found} == {None}
    suite = build_suite(direct_path, traffic_vehicles=6, seed=0)
    lane_routes = [sc for sc in suite.scenarios if isinstance(sc.route, dict)]
    assert sorted(sc.name.rsplit("-", 1)[1] for sc in lane_routes) == ["diverge", "diverge", "merge"]
    links = {p for r in found for p in r.links}
    for sc in lane_routes:  # each drives across a ramp's mouth
        lanes = sc.route["lanes"]
        assert links & set(zip(lanes, lanes[1:])), sc.route
    save_suite(suite, tmp_path / "suite.yaml")  # lane routes are suite-file routes
    assert load_suite(tmp_path / "suite.yaml").scenarios == suite.scenarios
    files = write_openscenario(type(suite)(suite.name, tuple(lane_routes)), tmp_path / "xosc")  # and export
    assert [f.stem for f in files] == [sc.name for sc in lane_routes]
    assert sorted(ramp_scenarios_complete(direct_path)) == sorted(sc.name for sc in lane_routes)


@pytest.mark.real_maps
@pytest.mark.parametrize("find, rel, kinds", [
    (corpus_map, "asam_qc/Ex_Entry_Exit.xodr", ["diverge", "merge"]),  # direct junctions: lane routes
    (corpus_map, "asam_examples/UC_Motorway-Exit-Entry.xodr", ["diverge", "diverge", "merge", "merge"]),  # 5 m junctions
    (shared_map, "opendrive/carla_town04/Town04.xodr", ["merge"]),
    (shared_map, "opendrive/carla_town06/Town06.xodr", ["merge"]),
], ids=["Ex_Entry_Exit", "UC_Motorway-Exit-Entry", "Town04", "Town06"])
def test_public_motorway_ramps_are_merged_and_diverged_at_traffic_6(find, rel, kinds):
    """Public motorway maps (the corpus and ../shared/maps beside the repository, docs/realmaps.md;
    skipped without them): every ramp `extract_ramps` finds is a merge or diverge scenario of the
    suite and completes."""
    names = ramp_scenarios_complete(find(rel))
    assert sorted(n.rsplit("-", 1)[1] for n in names) == kinds
