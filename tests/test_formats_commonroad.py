"""CommonRoad export, read back and checked with commonroad-io (its schema and its reader)."""
from __future__ import annotations

import pytest

from feat2map.errors import Feat2MapError
from feat2map.formats.commonroad import check_commonroad, lanelet_ids, write_commonroad
from feat2map.formats.commonroad.writer import commonroad_io
from feat2map.formats.commonroad.validate import lanelet_index, reachable
from feat2map.scenarios.routes import manoeuvres

try:
    commonroad_io()  # where scripts/setup.sh puts it (off sys.path, see commonroad_io)
except Feat2MapError:
    pytest.skip("commonroad-io is not installed (scripts/setup.sh installs it with --no-deps)", allow_module_level=True)


@pytest.fixture(scope="module")
def exported(ecosystem_map, tmp_path_factory):
    name, m = ecosystem_map
    path = tmp_path_factory.mktemp(f"cr-{name}") / f"{name}.xml"
    write_commonroad(m, path)
    return m, path, check_commonroad(path)


def _approaches(m) -> int:
    return len({(ln.junction_id, m.lanes[p].road_id) for ln in m.lanes.values() if ln.junction_id
                for p in ln.predecessors if m.lanes[p].junction_id is None})


def test_commonroad_io_reads_it_and_counts_match(exported):
    m, _, report = exported
    assert report.problems == []
    assert report.counts == {"lanelets": len(m.lanes) + len(m.crosswalks), "crosswalks": len(m.crosswalks),
                             "intersections": len(m.junctions), "incomings": _approaches(m),
                             "traffic_lights": len(m.signals), "traffic_signs": len(m.stop_signs)}
    assert len(report.routes) == sum(1 for ln in m.lanes.values() if ln.junction_id)


def test_every_manoeuvre_is_reachable_in_the_lanelet_network(exported):
    """From the entry road's lanelets through the junction's to the exit road's, on
    commonroad-io's successor and adjacency lists as read from the file."""
    m, _, report = exported
    lls = lanelet_index(report.scenario.lanelet_network)
    ids = lanelet_ids(m)
    road = {}
    for lid, ln in m.lanes.items():
        road.setdefault(ln.road_id, set()).add(ids[lid])
    junction = {jid: {ids[ln.id] for ln in m.junction_lanes(jid)} for jid in m.junctions}
    moves = manoeuvres(m)
    assert moves
    for jid, entry, exit_ in moves:
        allowed = road[entry] | junction[jid] | road[exit_]
        assert reachable(lls, road[entry], road[exit_], allowed), (jid, entry, exit_)
    assert not reachable(lls, road[moves[0][2]], road[moves[0][1]], road[moves[0][1]] | road[moves[0][2]])


def test_intersections_controls_and_stop_lines_follow_the_map(exported):
    m, _, report = exported
    net = report.scenario.lanelet_network
    ids = lanelet_ids(m)
    lane_of = {v: k for k, v in ids.items()}
    turns = {"outgoing_right": {"right"}, "outgoing_straight": {"none"}, "outgoing_left": {"left", "uturn"}}
    for inter in net.intersections:
        for inc in inter.incomings:
            for key, allowed in turns.items():
                assert {m.lanes[lane_of[x]].turn for x in getattr(inc, key) or ()} <= allowed
    signed = {lid for s in m.stop_signs.values() for lid in s.lane_ids}
    lit = {lid for s in m.signals.values() for lid in s.lane_ids}
    for ll in net.lanelets:
        lane = lane_of.get(ll.lanelet_id)
        if lane is None:  # a crosswalk
            assert {t.value for t in ll.lanelet_type} == {"crosswalk"}
            continue
        assert bool(ll.traffic_signs) == (lane in signed) and bool(ll.traffic_lights) == (lane in lit)
        assert (ll.stop_line is not None) == (lane in signed | lit)


def test_light_cycles_are_the_envs_phase_plan(sf_default_map, tmp_path):
    """Each light's cycle is the env's default fixed-time plan (offset 0), step by step."""
    from feat2map.config import COMMONROAD_DT_S
    from feat2map.envs.map_env import MapEnv
    from feat2map.envs.control import PhasePlan
    from feat2map.phases import junction_phases

    m = sf_default_map
    path = tmp_path / "m1.xml"
    write_commonroad(m, path)
    net = check_commonroad(path).scenario.lanelet_network
    ids = lanelet_ids(m)
    light_of = {}
    for ll in net.lanelets:
        for t in ll.traffic_lights:
            light_of[t] = ll.lanelet_id
    lights = {next(s.id for s in m.signals.values() if ids[s.lane_ids[0]] == light_of[t.traffic_light_id]): t
              for t in net.traffic_lights}
    cfg = MapEnv.default_config()
    names = {"green": "green", "amber": "yellow", "red": "red"}
    for phases in junction_phases(m).values():
        plan = PhasePlan(phases, cfg["signal_green"], cfg["signal_amber"], cfg["signal_all_red"], 0.0)
        for sid in (s for p in phases for s in p):
            steps = [el.state.value for el in lights[sid].traffic_light_cycle.cycle_elements for _ in range(el.duration)]
            assert len(steps) == round(plan.cycle / COMMONROAD_DT_S)
            assert steps == [names[plan.state(sid, (k + 0.5) * COMMONROAD_DT_S)] for k in range(len(steps))]


def test_checker_finds_broken_files(sf_default_map, tmp_path):
    """A schema violation, a dropped successor link, and two crossing approaches green at once."""
    from lxml import etree

    path = tmp_path / "m1.xml"
    write_commonroad(sf_default_map, path)
    doc = etree.parse(str(path))
    doc.getroot().set("date", "today")
    succ = next(el for el in doc.iter("successor") if el.getparent().tag == "lanelet")
    succ.getparent().remove(succ)
    for cycle in list(doc.iter("cycle"))[:4]:  # the first junction's lights: all green, always
        for el in cycle.findall("cycleElement"):
            el.find("color").text = "green"
    doc.write(str(path))
    messages = " | ".join(str(p) for p in check_commonroad(path).problems)
    assert "CommonRoad schema" in messages
    assert "does not name it as successor" in messages
    assert "green together on crossing approaches" in messages


def test_cli_export_and_validate(tmp_path, capsys):
    from feat2map.cli import main

    assert main(["generate", "--spec", "examples/mega_junction.yaml", "--out", str(tmp_path / "g"), "--no-apollo",
                 "--no-picture", "--quiet", "--commonroad"]) == 0
    out = tmp_path / "mega.xml"
    assert main(["export", "commonroad", str(tmp_path / "g" / "map.json"), "--out", str(out)]) == 0
    assert out.read_bytes() == (tmp_path / "g" / "commonroad.xml").read_bytes()
    assert main(["validate", str(out)]) == 0
    assert "0 problems" in capsys.readouterr().out
