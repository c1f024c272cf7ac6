"""Rollouts end to end, headless: a route-coverage suite of a small generated map runs through
the CLI (summary, JUnit XML, report); results do not depend on the worker count or backend; a
deliberately broken planner (runs red lights) fails the run with a readable report and a GIF;
bad input is one line and exit code 2."""
from __future__ import annotations

import functools
import json
import os
import re
import xml.etree.ElementTree as ET
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
from conftest import SKIP_RAY

import feat2map
import feat2map.errors
from feat2map import cli
from feat2map.formats import native
from feat2map.scenarios.planner import BaselinePlanner
from feat2map.scenarios.report import load_result
from feat2map.scenarios.rollout import (FAIL_POLICIES, Outcome, PlannerFactory, SuiteResult, classify,
                                        run_scenario, run_suite)
from feat2map.scenarios.scenario import Suite, load_suite, save_suite

J = feat2map.JunctionFeature.make
KEEP = ("t-r000", "t-r002", "t-r005")  # right turn, straight, unprotected left at a signal


class RedLightRunner(BaselinePlanner):
    """The deliberately broken planner: the baseline that ignores signals."""

    def __init__(self) -> None:
        super().__init__(ignore={"signal"})


class Crashing(BaselinePlanner):
    """A planner that raises mid-episode."""

    def act(self, obs, info):
        if self._steps >= 3:
            raise RuntimeError("planner bug")
        return super().act(obs, info)


@pytest.fixture(scope="module")
def suite_file(tmp_path_factory) -> Path:
    """A T junction with a signal and crosswalks; the CLI's route-coverage suite, cut to 3."""
    d = tmp_path_factory.mktemp("rollout")
    m = feat2map.generate_from_features([J([0, 90, 180], "signal", True)], seed=0)
    native.save(m, d / "t.json")
    assert cli.main(["suite", str(d / "t.json"), "--out", str(d / "full.yaml"), "--traffic", "2",
                     "--pedestrian-rate", "2"]) == 0
    full = load_suite(d / "full.yaml")
    assert len(full.scenarios) == 6  # every manoeuvre of a T junction, one route each
    save_suite(Suite("t", tuple(s for s in full.scenarios if s.name in KEEP), full.base_dir), d / "suite.yaml")
    return d / "suite.yaml"


@pytest.fixture(scope="module")
def cli_run(suite_file, tmp_path_factory):
    out = tmp_path_factory.mktemp("out") / "report"
    code = cli.main(["rollout", str(suite_file), "--out", str(out), "--quiet", "--line-coverage"])
    return code, out


def test_suite_runs_end_to_end_through_the_cli(cli_run, capsys):
    code, out = cli_run
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    assert [o["name"] for o in summary["outcomes"]] == list(KEEP)
    assert all(o["outcome"] == "completed" for o in summary["outcomes"]), summary["failed"]
    assert summary["counts"]["completed"] == 3 and summary["failed"] == []
    for o in summary["outcomes"]:
        assert o["stage_path"][0] == "LF" and o["stage_path"][-1] == "LF" and len(o["stage_path"]) >= 3
        assert o["junctions"] == ["J0"] and o["route_progress"] == pytest.approx(1.0, abs=0.05)
        assert o["junction_lines"]["J0"], "--line-coverage measures the planner's lines"
    root = ET.parse(out / "junit.xml").getroot()
    cases = root.findall("./testsuite/testcase")
    assert [c.get("name") for c in cases] == list(KEEP)
    assert root.get("tests") == "3" and root.get("failures") == "0"
    assert not root.findall(".//failure")
    report = (out / "report.md").read_text()
    assert "**passed**" in report and "## Behaviour coverage" in report and "## Planner line coverage" in report
    for png in ("outcomes.png", "coverage.png"):
        assert (out / png).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    assert not (out / "failures").exists()


def test_report_explains_its_codes_and_its_counts_add_up(cli_run):
    """Every stage code shown is explained; the header's distinct counts are the last accumulated
    ones of the behaviour table; the 95% sentence names the junctions."""
    from feat2map.scenarios.planner import STAGE_NAMES

    report = (cli_run[1] / "report.md").read_text()
    behaviour = report.split("## Behaviour coverage")[1].split("\n## ")[0]
    legend = report.split("## Stage codes")[1]
    shown = set(re.findall(r"\b([A-Z]{1,2}(?:_[A-Z]{1,2})?)\b(?= →|$| \|)", report, flags=re.M)) & set(STAGE_NAMES)
    assert "LF" in shown and len(shown) >= 3
    for code in shown:
        assert f"| `{code}` | {STAGE_NAMES[code]} |" in legend
    n_pairs = int(re.search(r"made (\d+) distinct \(planner scenario, stage path\) pair", behaviour).group(1))
    n_trans = int(re.search(r"(\d+) distinct stage transition", behaviour).group(1))
    rows = [r.split("|")[1:-1] for r in behaviour.splitlines() if r.startswith("| ") and not r.startswith("| junction")]
    assert rows[0][0].strip() == "roads between junctions" and rows[-1][0].strip() == "J0"
    assert (int(rows[-1][2]), int(rows[-1][4])) == (n_pairs, n_trans)
    assert f"sums to {sum(int(r[1]) for r in rows)})" in behaviour
    assert re.search(r"The first 1 junction the suite reaches \(J0\) already cover 95% of them", report)


def test_report_html_is_self_contained(cli_run):
    page = (cli_run[1] / "report.html").read_text()
    assert page.startswith("<!DOCTYPE html>") and "<table>" in page and "Stage codes" in page
    srcs = re.findall(r'<img[^>]*src="([^"]+)"', page)
    assert len(srcs) == 2 and all(s.startswith("data:image/png;base64,") for s in srcs)


def test_results_are_independent_of_worker_count(suite_file, cli_run):
    """workers=1 (the CLI run above) and workers=2 over spawned processes give equal outcomes."""
    suite = load_suite(suite_file)
    two = run_suite(suite, "baseline", workers=2, coverage=True, progress=False)
    one = load_result(cli_run[1])
    assert one == two
    assert [o.outcome for o in two.outcomes] == ["completed"] * 3
    assert two.outcomes[0].wall_s > 0


def test_ray_backend_gives_the_local_results(suite_file, cli_run):
    pytest.importorskip("ray", reason=SKIP_RAY)
    suite = load_suite(suite_file)
    # one scenario in one Ray worker: Ray's start and a line-covered drive are the cost (150 s for two under load)
    remote = run_suite(suite.scenarios[:1], "baseline", workers=1, backend="ray", coverage=True, progress=False)
    local = load_result(cli_run[1])  # the in-process CLI run of the same scenarios
    assert remote.outcomes == local.outcomes[:1] and remote.backend == "ray"


def test_broken_planner_fails_with_readable_report_and_gif(suite_file, tmp_path, capsys):
    suite = load_suite(suite_file)
    one = tmp_path / "one.yaml"
    save_suite(Suite("red", suite.scenarios[:1], suite.base_dir), one)
    out = tmp_path / "red"
    code = cli.main(["rollout", str(one), "--planner", f"{__name__}:RedLightRunner", "--out", str(out),
                     "--quiet"])
    assert code == 1
    printed = capsys.readouterr().out
    assert "FAIL t-r000: violation: traffic rule violation: red_light x1" in printed
    root = ET.parse(out / "junit.xml").getroot()
    fail = root.find("./testsuite/testcase/failure")
    assert fail is not None and fail.get("type") == "violation" and "red_light" in fail.get("message")
    summary = json.loads((out / "summary.json").read_text())
    assert summary["failed"] == ["t-r000"] and summary["outcomes"][0]["violations"]["red_light"] >= 1
    assert summary["coverage"] is False and summary["outcomes"][0]["junction_lines"] == {}, "line coverage is opt-in"
    assert "line coverage was not measured (`feat2map rollout --line-coverage`" in (out / "report.md").read_text()
    gif = out / summary["gifs"]["t-r000"]
    from PIL import Image

    with Image.open(gif) as im:
        assert im.format == "GIF" and im.n_frames > 10 and im.size[0] > 100
    report = (out / "report.md").read_text()
    assert "**FAILED**" in report and "## Failures" in report and "failures/t-r000.gif" in report
    # the failure policy decides the exit code only: under --fail-on none the violation passes the run
    # and still gets its GIF and its section (the README's bridge line relies on it)
    (out / "failures" / "t-r000.gif").write_bytes(b"old")
    assert cli.main(["rollout", str(one), "--planner", f"{__name__}:RedLightRunner", "--out", str(out),
                     "--quiet", "--fail-on", "none"]) == 0
    assert ET.parse(out / "junit.xml").getroot().get("failures") == "0"
    summary = json.loads((out / "summary.json").read_text())
    assert summary["outcomes"][0]["outcome"] == "violation" and summary["failed"] == []
    assert summary["gifs"] == {"t-r000": "failures/t-r000.gif"} and sorted(os.listdir(out / "failures")) == ["t-r000.gif"]
    with Image.open(out / "failures" / "t-r000.gif") as im:
        assert im.format == "GIF" and im.n_frames > 10
    report = (out / "report.md").read_text()
    assert "**passed**" in report and "### t-r000: violation (*passes*)" in report and "failures/t-r000.gif" in report


def test_a_raising_planner_is_an_error_outcome_with_its_gif(suite_file, tmp_path):
    sc = load_suite(suite_file).scenarios[0]
    res = run_suite([sc], Crashing, progress=False)
    o = res.outcomes[0]
    assert o.outcome == "error" and "RuntimeError: planner bug" in o.message
    assert res.exit_code("collision") == 1 and res.exit_code("none") == 0
    from PIL import Image

    assert o.gif  # replayed with rendering up to the raise, as any failure
    (tmp_path / "e.gif").write_bytes(o.gif)
    with Image.open(tmp_path / "e.gif") as im:
        assert im.format == "GIF" and im.n_frames >= 3


class BadAction(BaselinePlanner):
    """A planner that returns a bad action (NaN, None, a wrong shape, garbage) at its 3rd step."""

    bad: object = None

    def act(self, obs, info):
        a = super().act(obs, info)
        return self.bad if self._steps >= 3 else a


class NaNAction(BadAction):
    bad = [float("nan")]


class NoneAction(BadAction):
    bad = None


class ShapeAction(BadAction):
    bad = [0.0, 0.0, 0.0]


class GarbageAction(BadAction):
    bad = "go fast"


@pytest.mark.parametrize("planner", [NaNAction, NoneAction, ShapeAction, GarbageAction])
def test_a_planner_returning_a_bad_action_is_an_error_outcome_and_the_report_is_written(suite_file, tmp_path,
                                                                                         planner, capsys):
    out = tmp_path / "rep"
    one = tmp_path / "one.yaml"
    save_suite(Suite("one", load_suite(suite_file).scenarios[:1], suite_file.parent), one)
    rc = cli.main(["rollout", str(one), "--planner", f"{__name__}:{planner.__name__}", "--out", str(out),
                   "--quiet", "--no-coverage", "--no-gif"])
    assert rc == 1  # a failed scenario, not bad input (2)
    o = json.loads((out / "summary.json").read_text())["outcomes"][0]
    assert o["outcome"] == "error" and "bad action" in o["message"]
    assert "FAIL t-r000: error:" in capsys.readouterr().out and (out / "report.md").is_file()


def test_unpicklable_planners_run_in_process_or_fail_clearly(suite_file):
    sc = load_suite(suite_file).scenarios[0]
    with pytest.warns(UserWarning, match="cannot be pickled"):
        res = run_suite([sc], lambda: Crashing(), progress=False, record_failure_gif=False)
    assert res.outcomes[0].outcome == "error"
    with pytest.raises(feat2map.errors.Feat2MapError, match="cannot be pickled"):
        run_suite([sc, sc], lambda: Crashing(), workers=2, progress=False)


def test_classification_and_policies():
    base = {"collision": False, "off_road": False, "violations": {"red_light": 0}, "route_completed": True}
    assert classify(base) == "completed"
    assert classify({**base, "route_completed": False}) == "timeout"
    assert classify({**base, "violations": {"red_light": 1}}) == "violation"
    assert classify({**base, "off_road": True, "violations": {"red_light": 1}}) == "off_road"
    assert classify({**base, "collision": True, "off_road": True}) == "collision"
    assert FAIL_POLICIES["none"] == frozenset()
    o = Outcome("a", "timeout", {}, 1.0, 5, (), (), (), 0.5)
    assert o.fails("any") and not o.fails("violation") and not o.fails("collision")
    r = SuiteResult("s", "baseline", (o,))
    assert SuiteResult.from_dict(json.loads(json.dumps(r.to_dict()))) == r


def test_a_collision_message_says_where_it_happened():
    """With a junction ahead it names it; past the last one it names the lane (the message read
    "collision near junction  (at t=6.0 s, route 66%)" there)."""
    from feat2map.scenarios.rollout import _message

    info = {"time": 6.0, "route_progress": 0.66, "lane_id": "R7_0"}
    assert _message("collision", {**info, "junction": "J3"}) == "collision near junction J3 (at t=6.0 s, route 66%)"
    assert _message("collision", {**info, "junction": ""}) == \
        "collision on lane R7_0, no junction ahead (at t=6.0 s, route 66%)"


def test_report_counts_take_the_singular():
    """"1 scenario", "1 worker", not "1 scenarios" (messages.counted everywhere a count is written)."""
    from feat2map.scenarios.report import report_markdown

    o = Outcome("a", "timeout", {}, 1.0, 5, (), (), (), 0.5)
    one = report_markdown(SuiteResult("s", "baseline", (o,), workers=1, stopped="stop", scenarios=1))
    assert "`baseline`, 1 scenario, failure policy" in one and "on 1 worker, backend" in one
    assert "1 of 1 scenario ran" in one and "1 scenarios" not in one and "worker(s)" not in one
    two = report_markdown(SuiteResult("s", "baseline", (o, o), workers=2, stopped="stop", scenarios=3))
    assert "`baseline`, 2 scenarios, failure policy" in two and "on 2 workers, backend" in two
    assert "2 of 3 scenarios ran" in two


def test_planner_specs(suite_file):
    assert isinstance(PlannerFactory("baseline")(), BaselinePlanner)
    assert isinstance(PlannerFactory(f"{__name__}:RedLightRunner")(), RedLightRunner)
    made = PlannerFactory(functools.partial(BaselinePlanner, ignore={"signal"}))()  # a factory
    assert isinstance(made, BaselinePlanner) and made.ignore == {"signal"}
    assert type(PlannerFactory(lambda obs: obs)()).__name__ == "CallablePolicy"  # a policy obs -> action
    # a plain callable obs -> action drives through as_policy
    sc = load_suite(suite_file).scenarios[1]
    out = run_scenario(sc, PlannerFactory(_full_throttle), record_failure_gif=False)
    assert out.steps > 0 and out.stage_path == ()


def _full_throttle(obs):
    import numpy as np

    return np.array([0.2], dtype=np.float32)


def _throttle_seeing_info(obs, info):
    assert isinstance(info, dict) and "time" in info  # the documented (obs, info) form gets the step info
    return _full_throttle(obs)


class Quitter(BaselinePlanner):
    """A planner that asks to stop (SystemExit or KeyboardInterrupt) in its first scenario."""

    signal = SystemExit

    def act(self, obs, info):
        if self._steps >= 3:
            raise self.signal(3)
        return super().act(obs, info)


class Interrupter(Quitter):
    signal = KeyboardInterrupt


@pytest.mark.parametrize("fn", [_full_throttle, _throttle_seeing_info, lambda obs, info=None: _full_throttle(obs)])
def test_callable_planners_take_obs_or_obs_and_info(suite_file, fn):
    sc = load_suite(suite_file).scenarios[1]
    out = run_scenario(sc, PlannerFactory(fn), record_failure_gif=False)
    assert out.outcome != "error" and out.steps > 0, out.message


@pytest.mark.parametrize("planner", ["Quitter", "Interrupter"])
def test_a_planner_that_stops_ends_the_rollout_with_the_report_so_far(suite_file, tmp_path, capsys, planner):
    out = tmp_path / "stopped"
    code = cli.main(["rollout", str(suite_file), "--planner", f"{__name__}:{planner}", "--out", str(out), "--quiet",
                     "--no-coverage", "--no-gif"])
    assert code == 1
    summary = json.loads((out / "summary.json").read_text())
    assert len(summary["outcomes"]) == 1 and summary["scenarios"] == 3
    assert summary["outcomes"][0]["outcome"] == "error" and globals()[planner].signal.__name__ in summary["stopped"]
    assert "Stopped early" in (out / "report.md").read_text()
    assert "STOPPED after 1 of 3 scenarios" in capsys.readouterr().out
    res = run_suite(load_suite(suite_file), globals()[planner], progress=False, record_failure_gif=False)
    assert len(res.outcomes) == 1 and res.stopped and res.exit_code("none") == 1


@pytest.mark.parametrize("args,needle", [
    (["rollout", "missing.yaml", "--out", "o"], "missing.yaml"),
    (["rollout", "SUITE", "--out", "o", "--planner", "no_such_module_x:P"], "no_such_module_x"),
    (["rollout", "SUITE", "--out", "o", "--planner", "feat2map:nothing"], "nothing"),
    (["rollout", "SUITE", "--out", "o", "--planner", "nocolon"], "module:attr"),
    (["rollout", "SUITE", "--out", "o", "--workers", "0"], "--workers"),
    (["rollout", "SUITE", "--out", "o", "--backend", "slurm"], "slurm"),
    (["coverage", "NORESULT", "--out", "o"], "no rollout summary"),
    (["suite", "missing.json", "--out", "s.yaml"], "missing.json"),
])
def test_bad_input_is_one_line_and_exit_2(args, needle, suite_file, tmp_path, capsys):
    args = [str(suite_file) if a == "SUITE" else str(tmp_path / a) if a in ("o", "NORESULT", "missing.yaml",
                                                                                 "missing.json", "s.yaml") else a
            for a in args]
    try:
        code = cli.main(args)
    except SystemExit as exc:  # argparse errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "s.yaml").exists()



def _no_suite_maps(d: Path) -> dict[str, Path]:
    """Maps a route-coverage suite cannot drive: every lane read as a junction lane (what a
    reader taking Baidu-style junction polygons as membership made), and no junction at all."""
    import dataclasses

    m = feat2map.generate_from_features([J([0, 90, 180], "stop", False)], seed=0)
    jid = next(iter(m.junctions))
    all_junction = dataclasses.replace(m, lanes={k: dataclasses.replace(ln, junction_id=jid)
                                                 for k, ln in m.lanes.items()})
    no_junction = dataclasses.replace(m, junctions={}, signals={}, stop_signs={}, crosswalks={},
                                      lanes={k: dataclasses.replace(ln, junction_id=None) for k, ln in m.lanes.items()})
    out = {"no manoeuvres": d / "nomoves.json", "no junctions": d / "nojunctions.json"}
    native.save(all_junction, out["no manoeuvres"])
    native.save(no_junction, out["no junctions"])
    return out


def test_maps_without_manoeuvres_and_empty_suites_are_errors_not_green_runs(tmp_path, capsys):
    for reason, path in _no_suite_maps(tmp_path).items():
        assert cli.main(["suite", str(path), "--out", str(tmp_path / "s.yaml")]) == 2
        err = capsys.readouterr().err
        assert f"{path}: {reason}" in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
        assert not (tmp_path / "s.yaml").exists()
    empty = tmp_path / "empty.yaml"
    empty.write_text("version: 1\nname: empty\nscenarios: []\n")
    assert cli.main(["rollout", str(empty), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert str(empty) in err and "scenarios" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
    with pytest.raises(feat2map.errors.Feat2MapError, match="no scenarios"):
        run_suite(Suite("empty", ()), progress=False)


def test_a_bad_route_names_the_scenario(suite_file, tmp_path, capsys):
    text = suite_file.read_text()
    assert "[J0, R0, R1]" in text
    bad = tmp_path / "bad.yaml"
    bad.write_text(text.replace("[J0, R0, R1]", "[J9, R0, R1]").replace("map: t.json", f"map: {suite_file.parent / 't.json'}"))
    assert cli.main(["rollout", str(bad), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "scenario t-r000" in err and "J9" in err and len(err.strip().splitlines()) == 1
    assert not (tmp_path / "o").exists()
