"""`feat2map search` end to end and in parts: the known-answer check (the planted fault of
`StopSignRoller` is found within a small budget, with the right signature, and its written
regression scenario replays with the same outcome), the same seed giving the same candidates and
signatures with one worker or two, shrinking, and bad arguments (one line naming the argument,
exit code 2). Small budgets: the whole file takes about half a minute on two cores."""
from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

from feat2map import cli
from feat2map.errors import Feat2MapError
from feat2map.features import FeatureSpace
from feat2map.scenarios.rollout import Outcome, run_scenario
from feat2map.scenarios.scenario import Scenario, load_suite
from feat2map.scenarios.shrink import neighbours, shrink
from feat2map.scenarios.signature import Signature, signature_of

optuna = pytest.importorskip("optuna", reason="feat2map search needs Optuna: bash scripts/setup.sh search "
                                               "(scripts/test.sh installs it with the dev extra)")

from feat2map.scenarios.search import check_budget, evaluator, search  # noqa: E402  (needs optuna)
from feat2map.scenarios.search_space import Start  # noqa: E402

ROLLER = "feat2map.scenarios.faulty_planners:StopSignRoller"
SPACE = FeatureSpace(road_counts=(3, 4), controls=("signal", "stop", "bare"), crosswalks=(True, False),
                     rotation_ranges={3: ((-20.0, 10.0), (70.0, 120.0), (160.0, 200.0)),
                                      4: ((-5.0, 10.0), (80.0, 95.0), (175.0, 190.0), (255.0, 270.0))})


@pytest.fixture(scope="module")
def space_file(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("space") / "space.json"
    path.write_text(SPACE.to_json())
    return path


def test_the_planted_stop_sign_fault_is_found_and_replays(space_file, tmp_path, capsys, monkeypatch):
    """Known answer: the planner that rolls through stop signs is caught at a stop junction, its
    S_S stage missing; the shrunk scenario keeps no traffic it does not need; the written suite
    fails the same way when rolled out again, and the report shows it with its GIF. `--out` is
    relative, as in the README (its maps were once written under the folder twice)."""
    monkeypatch.chdir(tmp_path)
    out = tmp_path / "out" / "search"
    code = cli.main(["search", "--features", str(space_file), "--planner", ROLLER, "--budget-scenarios", "6",
                     "--batch", "3", "--workers", "2", "--seed", "0", "--quiet", "--out", "out/search"])
    assert code == 1, "a failure found exits 1"
    doc = json.loads((out / "search.json").read_text())
    stop = [f for f in doc["findings"] if f["signature"]["rule"] == "stop_sign"]
    assert stop, f"the planted fault was not found: {[f['key'] for f in doc['findings']]}"
    f = stop[0]
    assert f["signature"]["outcome"] == "violation" and f["signature"]["junction"].split(",")[0].endswith("stop")
    assert f["signature"]["stage_path"] == ["S_PS", "S_C", "S_I"], "the full stop (S_S) is what it skips"
    assert f["replays"] and f["shrunk"]["traffic_vehicles"] == 0 and f["shrunk"]["pedestrian_rate"] == 0.0
    assert f["params"]["control"] == "stop" and len(doc["trials"]) == 6
    html = (out / "report.html").read_text()
    assert f["name"] in html and "data:image/gif;base64," in html and (out / f["gif"]).is_file()
    assert any(p.suffix == ".xosc" for p in (out / "openscenario").iterdir())
    sc = next(s for s in load_suite(out / "regressions.yaml").scenarios if s.name == f["name"])
    again = run_scenario(sc, ROLLER, record_failure_gif=False)
    assert again.outcome == "violation" and again.violations["stop_sign"] == 1
    assert signature_of(again) == Signature(**{**f["signature"], "stage_path": tuple(f["signature"]["stage_path"])})
    baseline = run_scenario(sc, "baseline", record_failure_gif=False)
    assert baseline.outcome == "completed", "the scenario fails the weakened planner, not the baseline"


def _search(tmp_path: Path, workers: int):
    with evaluator(ROLLER, workers=workers) as ev:
        return search(Start("space", space=SPACE), ev, workdir=tmp_path, budget_scenarios=4, batch=2, seed=3,
                      shrink_failures=False, startup=2)  # the second batch is TPE's own (constant liar)


def test_same_seed_same_candidates_and_signatures_whatever_the_workers(tmp_path):
    one, two = _search(tmp_path / "one", 1), _search(tmp_path / "two", 2)

    def key(result):
        return [(t.number, t.params, replace(t.outcome, map=""), t.signature) for t in result.trials]

    assert key(one) == key(two) and len(one.trials) == 4
    assert [f.signature for f in one.findings] == [f.signature for f in two.findings]


def _fake_outcome(sc: Scenario) -> Outcome:
    """A drive that fails (a stop-sign violation at J1) while 3 or more vehicles are there and
    the route still holds J1; a completed one otherwise."""
    fails = sc.traffic_vehicles >= 3 and any(mv[0] == "J1" for mv in sc.route)
    site = {"junction": "J1", "manoeuvre": "left", "n_roads": 4, "control": "stop", "crosswalk": True,
            "lanes_in": [1] * 4, "lanes_out": [1] * 4, "rule": "stop_sign"}
    return Outcome(name=sc.name, outcome="violation" if fails else "completed",
                   violations={"stop_sign": int(fails)}, sim_s=10.0, steps=50, stage_path=(), transitions=(),
                   junctions=("J1",), route_progress=1.0, events=((3, 1.0, "J1", "STOP_SIGN_UNPROTECTED", "S_PS"),),
                   site=site if fails else {})


def test_shrinking_keeps_only_what_the_failure_needs():
    sc = Scenario(name="x", map="m.json", route=(("J0", "R0", "R1"), ("J1", "R1", "R2"), ("J2", "R2", "R3")),
                  traffic_vehicles=10, pedestrian_rate=6.0, seed=1, env={"ego_start_distance": 50.0})
    sig = signature_of(_fake_outcome(sc))
    assert sig is not None and sig.rule == "stop_sign" and sig.junction == "4-leg stop, crosswalk"
    assert all(len(n.route) < 3 or n.traffic_vehicles < 10 or n.pedestrian_rate == 0 or
               n.env["ego_start_distance"] < 50 for n in neighbours(sc, "J1"))
    batches = []

    def evaluate(scenarios):
        batches.append(len(scenarios))
        return [_fake_outcome(s) for s in scenarios]

    small, o = shrink({sig: (sc, _fake_outcome(sc))}, evaluate)[sig]
    assert (small.traffic_vehicles, small.pedestrian_rate, small.route) == (3, 0.0, (("J1", "R1", "R2"),))
    assert small.env["ego_start_distance"] == 10.0 and signature_of(o) == sig and len(batches) <= 6


@pytest.mark.parametrize("args, needle", [
    ([], "--budget-seconds or --budget-scenarios"),
    (["--budget-scenarios", "0"], "--budget-scenarios"),
    (["--budget-seconds", "-5"], "--budget-seconds"),
    (["--budget-scenarios", "2", "--workers", "0"], "--workers"),
    (["--budget-scenarios", "2", "--batch", "0"], "--batch"),
    (["--budget-scenarios", "2", "--seed", "-1"], "--seed"),
    (["--budget-scenarios", "2", "--features", "missing.json"], "missing.json"),
    (["--budget-scenarios", "2", "--map", "missing.json"], "--map"),
    (["--budget-scenarios", "2", "--planner", "no_such_module_x:P"], "no_such_module_x"),
    (["--budget-scenarios", "2", "--planner-cmd", " "], "--planner-cmd"),
    (["--budget-scenarios", "2", "--sampler", "cmaes"], "--sampler"),
    (["--budget-scenarios", "2", "--features", "a.json", "--map", "b.json"], "--map"),
])
def test_bad_arguments_are_one_line_naming_them_and_exit_2(args, needle, tmp_path, capsys):
    args = [str(tmp_path / a) if a.endswith(".json") else a for a in args]
    try:
        code = cli.main(["search", *args, "--out", str(tmp_path / "o")])
    except SystemExit as exc:  # argparse's own errors
        code = exc.code
    err = capsys.readouterr().err
    assert code == 2 and needle in err and len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "o").exists()


def test_the_python_api_names_bad_budgets():
    with pytest.raises(Feat2MapError, match="--budget-scenarios"):
        check_budget(None, 1.5)
    with pytest.raises(Feat2MapError, match="--budget-seconds"):
        check_budget(float("nan"), None)
