"""Driving motorway ramps (examples/ramps.yaml and a sampled map with every ramp value) and
motorway links (examples/motorway_links.yaml and a sampled map with every link value): the
network makes every ramp merge a conflict (a car on the acceleration lane and one on the main
lane take the merge in turn) and no link a merge (its lane is an added lane), and the
route-coverage suites merge from every on-ramp or link, diverge onto every off-ramp or link and
complete at traffic 6 with the baseline planner, which drives ramps in its ramp scenarios
(RAMP_MERGE, RAMP_DIVERGE)."""
from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import pytest
from conftest import example_map_file

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


@pytest.fixture(scope="module")
def links_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "motorway_links")


@pytest.fixture(scope="module")
def sampled_links_path(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("sampled_links") / "map.json"
    native.save(generate(replace(PAPER_SF_FEATURE_SPACE, ramp=("none", "link-on", "link-off", "link-both")), seed=0),
                path)
    return path


def ramp_roads(m: HDMap, kinds: tuple[str, ...] = ("on", "off")) -> set[str]:
    return {r for j in m.junctions.values() if j.feature is not None and j.feature.has_ramp
            for r, s in zip(j.socket_roads, j.feature.sockets) if s.ramp in kinds}


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


def test_no_motorway_link_is_a_merge(links_path):
    m = native.load(links_path)
    links = ramp_roads(m)
    joining = {ln.id for ln in m.lanes.values() if ln.junction_id and any(m.lanes[p].road_id in links
                                                                          for p in ln.predecessors)}
    assert len(joining) == 2  # one link lane joins at each junction, as an added lane
    assert not any(joining & set(p) for p in merge_pairs(m))


@pytest.mark.parametrize("which", ["map_path", "sampled_path", "links_path", "sampled_links_path"])
def test_the_suite_merges_and_diverges_at_every_ramp_and_completes_at_traffic_6(request, which):
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    path = request.getfixturevalue(which)
    m = native.load(path)
    ramps, ons, offs = ramp_roads(m), ramp_roads(m, ("on",)), ramp_roads(m, ("off",))
    suite = build_suite(path, traffic_vehicles=6, seed=0)
    taking = [sc for sc in suite.scenarios if any(mv[1] in ramps or mv[2] in ramps for mv in sc.route)]
    assert {r for sc in taking for mv in sc.route for r in mv[1:] if r in ramps} == ramps  # every ramp, both ways
    for sc in taking:
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, out.message)
        # the planner drives them as ramps: a merge along the acceleration lane, a diverge along the deceleration
        # lane (from an on-ramp straight on to an off-ramp is neither)
        merges = sum(mv[1] in ons and mv[2] not in ramps for mv in sc.route)
        diverges = sum(mv[2] in offs and mv[1] not in ramps for mv in sc.route)
        assert (out.stage_path.count("M_I"), out.stage_path.count("D_I")) == (merges, diverges), (sc.name, out.stage_path)
