"""Driving motorway ramps (examples/ramps.yaml and a sampled map with every ramp value) and
motorway links (examples/motorway_links.yaml and a sampled map with every link value): the
network makes every ramp merge a conflict (a car on the acceleration lane and one on the main
lane take the merge in turn) and no link a merge (its lane is an added lane), traffic and the
baseline planner drive the motorway at its speed and slow down on the ramps, and the
route-coverage suites merge from every on-ramp or link, diverge onto every off-ramp or link (on
one- and two-lane motorways) and complete at traffic 6 with the baseline planner, which drives
ramps in its ramp scenarios (RAMP_MERGE, RAMP_DIVERGE), the scenarios named after their merge or
diverge. Ramps joined through a direct link (no junction: OpenDRIVE's direct junctions) get lane
routes that do the same, on our own map and on public ones."""
from __future__ import annotations

import warnings
from dataclasses import replace
from pathlib import Path

import pytest
from conftest import corpus_map, example_map_file, shared_map

from feat2map.config import JUNCTION_SPEED_LIMIT_MPS, MOTORWAY_SPEED_LIMIT_MPS, RAMP_SPEED_LIMIT_MPS, SPEED_LIMIT_MPS
from feat2map.envs.network import MapNetwork, merge_pairs
from feat2map.features import PAPER_SF_FEATURE_SPACE
from feat2map.formats import native
from feat2map.generate import generate
from feat2map.model import HDMap


@pytest.fixture(scope="module")
def map_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "ramps")


def sampled_map_file(tmp_path_factory, folder: str, ramps: tuple[str, ...]) -> Path:
    """The paper's SF space with ramp values `ramps`, generated at seed 0 and saved in a fresh folder."""
    path = tmp_path_factory.mktemp(folder) / "map.json"
    native.save(generate(replace(PAPER_SF_FEATURE_SPACE, ramp=ramps), seed=0), path)
    return path


@pytest.fixture(scope="module")
def sampled_path(tmp_path_factory) -> Path:
    return sampled_map_file(tmp_path_factory, "sampled_ramps", ("none", "on", "off", "both"))


@pytest.fixture(scope="module")
def links_path(tmp_path_factory) -> Path:
    return example_map_file(tmp_path_factory, "motorway_links")


@pytest.fixture(scope="module")
def sampled_links_path(tmp_path_factory) -> Path:
    return sampled_map_file(tmp_path_factory, "sampled_links", ("none", "link-on", "link-off", "link-both"))


@pytest.fixture(scope="module")
def two_lane_path(tmp_path_factory) -> Path:
    """A sampled map whose ramp junctions lie on one- and two-lane motorways (`motorway_lanes`)."""
    path = tmp_path_factory.mktemp("two_lane_ramps") / "map.json"
    space = replace(PAPER_SF_FEATURE_SPACE, ramp=("none", "on", "off", "both"), motorway_lanes=(1, 2))
    native.save(generate(space, seed=0), path)
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


def top_speeds(map_path: Path, route: tuple, traffic: int = 6) -> tuple[dict[str, float], dict[str, float]]:
    """One drive of the baseline planner on `route` among `traffic` cars: the highest speeds of the
    ego and of the traffic on the motorway ("main": ramp junctions' main roads and lanes straight
    on) and on the ramps ("ramp": ramp roads and the deceleration lanes into them)."""
    from feat2map.scenarios.planner import BaselinePlanner
    from feat2map.scenarios.scenario import Scenario, make_env

    m = native.load(map_path)
    ramps = ramp_roads(m)
    motorway = {j for j, x in m.junctions.items() if x.feature is not None and x.feature.has_ramp}
    mains = {r for j in motorway for r in m.junctions[j].socket_roads} - ramps

    def kind(lid: str) -> str:
        ln = m.lanes[lid]
        if ln.road_id in ramps or any(m.lanes[x].road_id in ramps for x in ln.successors):
            return "ramp"
        if ln.junction_id in motorway and not any(m.lanes[x].road_id in ramps for x in ln.predecessors):
            return "main"
        return "main" if ln.road_id in mains and ln.junction_id is None and all(
            j in motorway for j in (m.roads[ln.road_id].start_junction, m.roads[ln.road_id].end_junction) if j) else ""

    env = make_env(Scenario(name="speeds", map=str(map_path), route=route, duration=30.0, traffic_vehicles=traffic))
    ego: dict[str, float] = {"main": 0.0, "ramp": 0.0}
    others: dict[str, float] = {"main": 0.0, "ramp": 0.0}
    try:
        obs, info = env.reset(seed=0)
        u = env.unwrapped
        planner = BaselinePlanner()
        planner.reset(env)
        for _ in range(1000):
            obs, _, terminated, truncated, info = env.step(planner.act(obs, info))
            for v in u.road.vehicles:
                k = kind(u.net.id_of[v.lane_index]) if v.lane_index in u.net.id_of else ""
                seen = ego if v is u.vehicle else others
                if k:
                    seen[k] = max(seen[k], float(v.speed))
            if terminated or truncated:
                break
    finally:
        env.close()
    assert info["route_completed"]
    return ego, others


def test_the_motorway_is_driven_at_its_speed_and_the_ramps_slower(map_path):
    """Traffic reaches the motorway's speed on the main road and the baseline planner drives it
    above the town's limit; the ego leaving on an off-ramp slows to the ramp's limit on the
    deceleration lane and keeps it on the ramp."""
    ego, traffic = top_speeds(map_path, (("J0", "R2", "R1"), ("J1", "R1", "R5")))  # east through both junctions
    assert traffic["main"] >= 0.95 * MOTORWAY_SPEED_LIMIT_MPS and traffic["main"] <= MOTORWAY_SPEED_LIMIT_MPS + 0.1
    assert ego["main"] > SPEED_LIMIT_MPS + 5.0 > JUNCTION_SPEED_LIMIT_MPS
    ramp, _ = top_speeds(map_path, (("J0", "R2", "R0"),))  # onto J0's off-ramp
    assert JUNCTION_SPEED_LIMIT_MPS < ramp["ramp"] <= RAMP_SPEED_LIMIT_MPS + 0.1 < ego["main"]


@pytest.mark.parametrize("which", ["map_path", "sampled_path", "two_lane_path", "links_path", "sampled_links_path"])
def test_the_suite_merges_and_diverges_at_every_ramp_and_completes_at_traffic_6(request, which):
    from feat2map.scenarios.rollout import run_scenario
    from feat2map.scenarios.routes import build_suite

    path = request.getfixturevalue(which)
    m = native.load(path)
    ramps, ons, offs = ramp_roads(m), ramp_roads(m, ("on",)), ramp_roads(m, ("off",))
    suite = build_suite(path, traffic_vehicles=6, seed=0)
    taking = [sc for sc in suite.scenarios if any(mv[1] in ramps or mv[2] in ramps for mv in sc.route)]
    assert {r for sc in taking for mv in sc.route for r in mv[1:] if r in ramps} == ramps  # every ramp, both ways
    for sc in taking:  # named after each merge (ramp -> main) and diverge (main -> ramp), as real maps' ramps are
        kinds = ["merge" if mv[1] in ramps else "diverge" for mv in sc.route if (mv[1] in ramps) != (mv[2] in ramps)]
        assert sc.name == "-".join([sc.name.split("-")[0], sc.name.split("-")[1], *kinds]), sc.route
    for sc in taking:
        out = run_scenario(sc, record_failure_gif=False)
        assert out.outcome == "completed", (sc.name, out.message)
        # the planner drives them as ramps: a merge along the acceleration lane, a diverge along the deceleration
        # lane (from an on-ramp straight on to an off-ramp is neither)
        merges = sum(mv[1] in ons and mv[2] not in ramps for mv in sc.route)
        diverges = sum(mv[2] in offs and mv[1] not in ramps for mv in sc.route)
        assert (out.stage_path.count("M_I"), out.stage_path.count("D_I")) == (merges, diverges), (sc.name, out.stage_path)


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
