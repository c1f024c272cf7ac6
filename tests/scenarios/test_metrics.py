"""Diversity metrics: behaviour coverage (scenario/stage-path pairs, stage transitions) and
planner line coverage per junction and accumulated; stable for a fixed seed; `feat2map coverage`
compares two maps' results (table + plot)."""
from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import feat2map
from feat2map import cli
from feat2map.formats import native
from feat2map.scenarios import planner as planner_module
from feat2map.scenarios.metrics import (Comparison, compare, junctions_to_reach, outcome_behaviour,
                                        suite_coverage)
from feat2map.scenarios.report import write_report
from feat2map.scenarios.rollout import MIXED_DIGEST, ROAD_CONTEXT, Outcome, SuiteResult, run_suite, suite_digest
from feat2map.scenarios.routes import build_suite
from feat2map.scenarios.scenario import Suite

J = feat2map.JunctionFeature.make


def outcome(name: str, events=(), lines=None, junctions=("J0",)) -> Outcome:
    return Outcome(name=name, outcome="completed", violations={}, sim_s=10.0, steps=50, stage_path=(),
                   transitions=(), junctions=tuple(junctions), route_progress=1.0, events=tuple(events),
                   junction_lines=lines or {})


def test_behaviour_per_junction_from_stage_events():
    ev = [(0, 0.0, None, "LANE_FOLLOW", "LF"), (3, 0.6, "J0", "STOP_SIGN", "S_PS"), (9, 1.8, "J0", "STOP_SIGN", "S_S"),
          (14, 2.8, "J0", "STOP_SIGN", "S_I"), (20, 4.0, None, "LANE_FOLLOW", "LF"),
          (25, 5.0, "J1", "BARE", "B_A"), (30, 6.0, "J1", "BARE", "B_I"), (35, 7.0, None, "LANE_FOLLOW", "LF")]
    b = outcome_behaviour(outcome("a", ev))
    assert b["J0"][0] == {("STOP_SIGN", ("S_PS", "S_S", "S_I"))}
    assert b["J0"][1] == {("LANE_FOLLOW.LF", "STOP_SIGN.S_PS"), ("STOP_SIGN.S_PS", "STOP_SIGN.S_S"),
                          ("STOP_SIGN.S_S", "STOP_SIGN.S_I"), ("STOP_SIGN.S_I", "LANE_FOLLOW.LF")}
    assert b["J1"][0] == {("BARE", ("B_A", "B_I"))}
    assert b[ROAD_CONTEXT] == ({("LANE_FOLLOW", ("LF",))}, frozenset())
    assert ("STOP_SIGN.S_I", "LANE_FOLLOW.LF") in b["J0"][1] and ("BARE.B_I", "LANE_FOLLOW.LF") in b["J1"][1]


def test_accumulated_coverage_in_junction_order():
    a = outcome("a", lines={"J0": ("p:1", "p:2"), "J1": ("p:2", "p:3")}, junctions=("J0", "J1"))
    b = outcome("b", lines={"J2": ("p:1",), "J1": ("p:4",)}, junctions=("J2", "J1"))
    c = suite_coverage(SuiteResult("s", "x", (a, b), coverage=True))
    assert c.junctions == ("J0", "J1", "J2")
    assert c.accumulated_lines == (2, 4, 4) and c.new_lines() == (2, 2, 0)
    assert junctions_to_reach(c.accumulated_lines) == 2 and junctions_to_reach(()) == 0


lines_st = st.dictionaries(st.sampled_from([f"J{i}" for i in range(6)]),
                           st.lists(st.integers(1, 40).map(lambda i: f"m:{i}"), max_size=12).map(tuple), max_size=6)


@settings(max_examples=60, deadline=None)
@given(st.lists(lines_st, min_size=1, max_size=5))
def test_accumulated_lines_grow_to_the_union(per_outcome):
    outs = tuple(outcome(f"s{i}", lines=d, junctions=tuple(d)) for i, d in enumerate(per_outcome))
    c = suite_coverage(SuiteResult("s", "x", outs, coverage=True))
    acc = c.accumulated_lines
    union = set().union(*(set(v) for d in per_outcome for v in d.values()))
    assert list(acc) == sorted(acc) and (acc[-1] if acc else 0) == len(union)
    assert sum(c.new_lines()) == len(union)
    for j, n in zip(c.junctions, acc):
        assert len(c.lines.get(j, ())) <= n


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two small maps (a 4-way stop junction, a 3-way bare one), two scenarios each, run with line
    coverage; the stop map twice."""
    d = tmp_path_factory.mktemp("metrics")
    out = {}
    for key, feat in (("stop", J([0, 90, 180, 270], "stop", True)), ("bare", J([0, 90, 180], "bare", False))):
        native.save(feat2map.generate_from_features([feat], seed=0), d / f"{key}.json")
        full = build_suite(d / f"{key}.json", seed=3, traffic_vehicles=2)
        suite = Suite(key, full.scenarios[:2], full.base_dir)
        out[key] = run_suite(suite, "baseline", coverage=True, progress=False)
        write_report(out[key], d / key)
    suite = Suite("stop", build_suite(d / "stop.json", seed=3, traffic_vehicles=2).scenarios[:2], d)
    out["stop2"] = run_suite(suite, "baseline", coverage=True, progress=False)
    out["dir"] = d
    return out


def test_coverage_is_stable_for_a_fixed_seed(runs):
    first, second = suite_coverage(runs["stop"]), suite_coverage(runs["stop2"])
    assert runs["stop"] == runs["stop2"]
    assert first == second
    assert first.accumulated_lines == second.accumulated_lines and first.accumulated_lines[-1] > 20
    assert {p[0] for p in first.all_pairs} >= {"STOP_SIGN_UNPROTECTED"}
    # every covered line is a real statement of the planner module
    src = Path(planner_module.__file__).read_text().splitlines()
    for ref in first.all_lines:
        mod, _, n = ref.rpartition(":")
        assert mod == "feat2map.scenarios.planner"
        text = src[int(n) - 1].strip()
        assert text and not text.startswith("#"), ref


def test_compare_two_maps(runs):
    table = compare({"stop": runs["stop"], "bare": runs["bare"]})
    assert isinstance(table, Comparison) and table.names == ("stop", "bare")
    stop_row, bare_row = table.rows
    assert stop_row[2] == bare_row[2] == 2
    bare_pairs = table.coverages[1].all_pairs
    assert {p[0] for p in bare_pairs} >= {"BARE_INTERSECTION_UNPROTECTED"}
    assert stop_row[-2] > 0 and bare_row[-2] > 0  # each map triggers transitions the other does not
    md = table.to_markdown()
    assert md.count("\n") == 4 and "| stop |" in md and "| bare |" in md


def test_coverage_command_compares_result_dirs(runs, tmp_path, capsys):
    d = runs["dir"]
    out = tmp_path / "cmp"
    assert cli.main(["coverage", str(d / "stop"), str(d / "bare"), "--out", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "| stop |" in printed and "| bare |" in printed
    md = (out / "coverage.md").read_text()
    assert "# Coverage comparison" in md and "## stop" in md and "## bare" in md
    assert (out / "coverage.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    doc = json.loads((out / "coverage.json").read_text())
    assert [r[0] for r in doc["rows"]] == ["stop", "bare"]
    assert doc["rows"][0][doc["columns"].index("lines")] == len(suite_coverage(runs["stop"]).all_lines)
    # names must match the dirs
    assert cli.main(["coverage", str(d / "stop"), str(d / "bare"), "--out", str(tmp_path / "x"),
                     "--names", "one"]) == 2
    assert not (tmp_path / "x").exists()


def test_compare_warns_when_planner_sources_differ(runs):
    assert runs["stop"].planner_digest and runs["stop"].planner_digest == runs["bare"].planner_digest
    assert compare([runs["stop"], runs["bare"]]).warnings == ()
    a = outcome("a", lines={"J0": ("m:1",)})
    t = compare([SuiteResult("x", "p", (a,), coverage=True, planner_digest="aa"),
                 SuiteResult("x", "p", (a,), coverage=True, planner_digest="bb")])
    assert t.names == ("x", "x (2)") and len(t.warnings) == 1 and "Warning: " in t.to_markdown()
    # a planner edited mid-run: scenarios measured different sources
    mixed = (replace(a, planner_digest="aa"), replace(a, name="b", planner_digest="bb"))
    assert suite_digest(mixed) == MIXED_DIGEST and suite_digest(mixed[:1]) == "aa"
    t = compare({"m": SuiteResult("m", "p", mixed, coverage=True, planner_digest=MIXED_DIGEST)})
    assert t.warnings and "changed during the run" in t.warnings[0]


def test_coverage_command_says_which_rollouts_ran_without_line_coverage(tmp_path, capsys):
    """Line coverage is opt-in (`rollout --line-coverage`): comparing a rollout without it says so,
    naming the result and how to get the lines, in the output and in coverage.md."""
    ev = [(0, 0.0, "J0", "STOP_SIGN", "S_PS"), (5, 1.0, "J0", "STOP_SIGN", "S_S")]
    measured = SuiteResult("m", "baseline", (outcome("a", ev, {"J0": ("p:1", "p:2")}),), coverage=True,
                           planner_digest="aa")
    plain = SuiteResult("p", "baseline", (outcome("a", ev),))
    write_report(measured, tmp_path / "with")
    write_report(plain, tmp_path / "without")
    assert cli.main(["coverage", str(tmp_path / "with"), str(tmp_path / "without"), "--out", str(tmp_path / "c")]) == 0
    printed = capsys.readouterr().out
    note = [ln for ln in printed.splitlines() if ln.startswith("note: ")]
    assert len(note) == 1 and "without (" in note[0] and "with (" not in note[0] and "--line-coverage" in note[0]
    assert "| without | baseline | 1 | 1 | 0 | 1 | 1 | 1 | 1 | - | - |" in printed
    assert "--line-coverage" in (tmp_path / "c" / "coverage.md").read_text()
    assert cli.main(["coverage", str(tmp_path / "with"), "--out", str(tmp_path / "c1")]) == 0
    assert "note: " not in capsys.readouterr().out  # measured: nothing to say
