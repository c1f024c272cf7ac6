"""CI's short suite for a planner none of us wrote: CommonRoad's reactive planner, in its own venv
(adapters/commonroad/setup.sh builds .venv-crplanner; .ci/run does), drives three scenarios of a
generated map through the planner bridge: every outcome is recorded (none is a bridge `error`),
its stages come from the adapter, and the line coverage measured is the reactive planner's own
package (commonroad_rp), per junction. Skips with the reason only where that venv cannot be built."""
from __future__ import annotations

import dataclasses
import json
import os
import subprocess
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest

import feat2map
from feat2map import cli
from feat2map.formats import native
from feat2map.scenarios.scenario import Suite, load_suite, save_suite

ROOT = Path(__file__).resolve().parents[2]
CRPY = ROOT / ".venv-crplanner" / "bin" / "python"
ADAPTER = ROOT / "adapters" / "commonroad" / "planner.py"
KEEP = ("t-r000", "t-r001", "t-r003")  # a signalled T junction: right, straight, left
DURATION_S = 40.0  # each: a completed turn takes ~20 s; a stuck planner costs no more than this
STAGES = {"VELOCITY", "APPROACH", "STOPPING", "STANDSTILL", "FALLBACK"}  # the adapter's stage names


def _venv_problem() -> str | None:
    if not CRPY.exists():
        return f"the CommonRoad planner venv is not built ({CRPY} missing: bash adapters/commonroad/setup.sh)"
    r = subprocess.run([str(CRPY), "-c", "import commonroad_rp.reactive_planner, commonroad_route_planner.route_planner"],
                       capture_output=True, text=True, timeout=300)
    if r.returncode:
        return f"the CommonRoad planner venv cannot import the planner: {r.stderr.strip().splitlines()[-1:]}"
    return None


@pytest.fixture(scope="module")
def crplanner() -> str:
    problem = _venv_problem()
    if problem:
        pytest.skip(problem)
    return f"{CRPY} {ADAPTER}"


def test_the_reactive_planner_drives_a_short_suite_through_the_bridge(crplanner, tmp_path):
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "signal", False)], seed=0)
    native.save(m, tmp_path / "t.json")
    assert cli.main(["suite", str(tmp_path / "t.json"), "--out", str(tmp_path / "full.yaml"), "--traffic", "2"]) == 0
    full = load_suite(tmp_path / "full.yaml")
    kept = tuple(dataclasses.replace(s, duration=DURATION_S) for s in full.scenarios if s.name in KEEP)
    save_suite(Suite("t", kept, full.base_dir), tmp_path / "s.yaml")
    out = tmp_path / "cr"
    rc = cli.main(["rollout", str(tmp_path / "s.yaml"), "--planner-cmd", crplanner, "--planner-timeout", "60",
                   "--out", str(out), "--quiet", "--no-gif", "--fail-on", "none"])
    assert rc == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["planner"].startswith("bridge: ") and len(summary["outcomes"]) == len(KEEP)
    for o in summary["outcomes"]:
        assert o["outcome"] != "error", o["message"]  # the bridge and the adapter hold
        assert o["stage_path"] and all(s.split("_")[0] in STAGES for s in o["stage_path"]), o["stage_path"]
        lines = {x for v in o["junction_lines"].values() for x in v}
        assert lines and all(x.startswith("commonroad_rp") for x in lines)
        assert o["planner_digest"]
    assert sum(o["outcome"] == "completed" for o in summary["outcomes"]) >= 1
    assert "J0" in summary["outcomes"][0]["junction_lines"]
