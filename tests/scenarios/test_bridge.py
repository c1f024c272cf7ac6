"""The planner bridge: a planner in another process drives scenarios through JSON lines; the
reference planner (examples/bridge_planner.py) completes a small signalled suite; a planner that
crashes, hangs past its deadline, returns garbage or speaks another protocol gives an `error`
outcome with its stderr in the message, its process group killed and reaped, and the rollout
goes on to write its report (never a hang, never exit 2)."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import textwrap
import time
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import numpy as np
import pytest

import feat2map
from feat2map import cli
from feat2map.envs.sim.vehicle import VehicleModel, integrate
from feat2map.envs.tracking import Trajectory, TrajectoryTracker
from feat2map.formats import native
from feat2map.scenarios.bridge import BridgeError, BridgePlanner, PlannerProcess
from feat2map.scenarios.rollout import run_suite
from feat2map.scenarios.scenario import Suite, load_suite, save_suite

ROOT = Path(__file__).resolve().parents[2]
REFERENCE = f"{sys.executable} {ROOT / 'examples' / 'bridge_planner.py'}"
J = feat2map.JunctionFeature.make


@pytest.fixture(scope="module")
def suite_file(tmp_path_factory) -> Path:
    """A signalled T junction: its route-coverage suite with 2 traffic vehicles (6 scenarios)."""
    d = tmp_path_factory.mktemp("bridge")
    m = feat2map.generate_from_features([J([0, 90, 180], "signal", False)], seed=0)
    native.save(m, d / "t.json")
    assert cli.main(["suite", str(d / "t.json"), "--out", str(d / "suite.yaml"), "--traffic", "2"]) == 0
    return d / "suite.yaml"


def _script(tmp_path: Path, name: str, body: str) -> str:
    """A tiny planner script; returns its command."""
    p = tmp_path / f"{name}.py"
    p.write_text(body)
    return f"{sys.executable} {p}"


HELLO = textwrap.dedent("""
    import json, sys
    def send(m):
        sys.stdout.write(json.dumps(m) + "\\n"); sys.stdout.flush()
    def recv():
        return json.loads(sys.stdin.readline())
    recv(); send({"type": "hello", "protocol": 1, "map_format": "native", "output": "control"})
    recv(); send({"type": "ready"})
""")


def _one(suite_file: Path, tmp_path: Path) -> Path:
    one = tmp_path / "one.yaml"
    suite = load_suite(suite_file)
    save_suite(Suite("one", suite.scenarios[:1], suite.base_dir), one)
    return one


def test_the_reference_planner_drives_a_suite_through_the_bridge(suite_file, tmp_path, capsys):
    out = tmp_path / "ref"
    rc = cli.main(["rollout", str(suite_file), "--planner-cmd", REFERENCE, "--out", str(out), "--quiet", "--no-gif",
                   "--fail-on", "violation"])
    summary = json.loads((out / "summary.json").read_text())
    counts = summary["counts"]
    assert counts["completed"] >= 5 and counts["error"] == 0 and counts["violation"] == 0, summary["counts"]
    assert rc == (0 if counts["completed"] == 6 else 1)
    assert summary["planner"].startswith("bridge: ")
    o = summary["outcomes"][0]
    assert o["stage_path"] and set(o["stage_path"]) <= {"CRUISE", "STOP_SIGNAL", "STOP_SIGN", "FOLLOW",
                                                        "YIELD_PEDESTRIAN"}


@pytest.mark.parametrize("name,body,expect", [
    ("crashing", HELLO + "recv(); sys.stderr.write('Traceback: planner exploded\\n'); sys.exit(3)\n",
     ["exited (code 3)", "planner exploded"]),
    ("hanging", HELLO + "recv(); sys.stderr.write('thinking forever\\n'); sys.stderr.flush()\n"
                        "import time\nwhile True: time.sleep(1)\n", ["planner timeout", "thinking forever"]),
    ("garbage", HELLO + "recv(); sys.stdout.write('{{{ not json\\n'); sys.stdout.flush(); recv()\n",
     ["garbage step reply (not JSON)"]),
    ("nan_control", HELLO + "recv(); sys.stdout.write('{\"type\": \"control\", \"acceleration\": NaN, "
                            "\"steering\": 0}\\n'); sys.stdout.flush(); recv()\n", ["garbage step reply", "NaN"]),
    ("bad_trajectory", HELLO + "recv(); send({'type': 'trajectory', 'points': [{'t': 0, 'x': 'a'}]}); recv()\n",
     ["garbage trajectory"]),
    ("wrong_protocol", "import json, sys\nsys.stdin.readline()\n"
                       "print(json.dumps({'type': 'hello', 'protocol': 99}), flush=True)\nsys.stdin.readline()\n",
     ["bad hello", "protocol 99"]),
])
def test_a_failing_planner_is_an_error_outcome_with_its_stderr(suite_file, tmp_path, name, body, expect):
    cmd = _script(tmp_path, name, body)
    out = tmp_path / "rep"
    t0 = time.monotonic()
    rc = cli.main(["rollout", str(_one(suite_file, tmp_path)), "--planner-cmd", cmd, "--planner-timeout", "2",
                   "--out", str(out), "--quiet", "--no-gif"])
    assert time.monotonic() - t0 < 60  # never a hang
    assert rc == 1  # a failed scenario, the report written: not bad input (2)
    o = json.loads((out / "summary.json").read_text())["outcomes"][0]
    assert o["outcome"] == "error"
    for text in expect:
        assert text in o["message"], o["message"]
    assert "BridgeError" in (out / "report.md").read_text()


NOTING = textwrap.dedent("""
    import json, os, sys, time
    log = open(sys.argv[1], "a")
    def note(what):
        log.write(f"{what} {os.getpid()} {time.monotonic()}\\n"); log.flush()
    note("start")
    for line in sys.stdin:
        msg = json.loads(line)
        note(msg["type"])
        reply = {"hello": {"type": "hello", "protocol": 2, "map_format": "native", "output": "control",
                           "prestart": sys.argv[2] == "1"},
                 "init": {"type": "ready"}, "close": {"type": "bye"}}.get(msg["type"])
        reply = {**(reply or {"type": "control", "acceleration": 0.0, "steering": 0.0}), "step": msg["step"]}
        print(json.dumps(reply), flush=True)
        if msg["type"] == "close":
            break
""")


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as f:
            return f.read().rsplit(")", 1)[1].split()[0] not in ("Z", "X")
    except (FileNotFoundError, ProcessLookupError):
        return False


@pytest.mark.parametrize("prestart", [True, False])
def test_a_planner_that_allows_it_is_started_ahead_yet_each_scenario_gets_a_fresh_one(suite_file, tmp_path,
                                                                                      monkeypatch, prestart):
    """A hello with "prestart": true lets the bridge start the next scenario's planner while this
    one drives; each scenario still talks to a process of its own, and a suite leaves none
    behind. Without it, none is started ahead."""
    from feat2map.scenarios import bridge
    from feat2map.scenarios.rollout import HASH_SEED, run_scenario

    monkeypatch.setenv("PYTHONHASHSEED", HASH_SEED)  # run_suite drives in this process
    log = tmp_path / "log"
    cmd = f"{_script(tmp_path, 'noting', NOTING)} {log} {int(prestart)}"
    first, second = [dataclasses.replace(s, duration=1.0) for s in load_suite(suite_file).scenarios[:2]]
    run_scenario(first, BridgePlanner(cmd), record_failure_gif=False)
    spare = bridge._SPARES.get(bridge._planner_key(cmd, None))
    assert (spare is not None) == prestart
    run_suite([second], BridgePlanner(cmd), progress=False, record_failure_gif=False)
    notes = [line.split() for line in log.read_text().splitlines()]
    served = [int(p) for what, p, _ in notes if what == "init"]
    assert len(set(served)) == 2 and len([n for n in notes if n[0] == "close"]) == 2  # a process per scenario
    if spare is not None:
        assert served[1] == spare.proc.pid  # the second scenario took the spare started during the first
    assert bridge._planner_key(cmd, None) not in bridge._SPARES  # the suite discarded the next spare
    stop = time.monotonic() + 5
    pids = {int(p) for _, p, _ in notes}
    while (alive := [p for p in pids if _alive(p)]) and time.monotonic() < stop:
        time.sleep(0.05)
    assert not alive, f"planner processes outlived their scenarios: {alive}"


def test_a_spare_planner_is_used_only_in_the_environment_it_started_in(tmp_path, monkeypatch):
    from feat2map.scenarios import bridge

    cmd = _script(tmp_path, "idle", "import sys\nfor line in sys.stdin:\n    pass\n")
    bridge.prestart_planner(cmd)
    spare = bridge._SPARES[bridge._planner_key(cmd, None)]
    monkeypatch.setenv("FEAT2MAP_TEST_SPARE", "changed")
    fresh = bridge.start_planner(cmd)
    assert fresh is not spare and spare.proc.poll() is not None  # discarded: it would see the old environment
    fresh.discard()
    bridge.prestart_planner(cmd)
    spare = bridge._SPARES[bridge._planner_key(cmd, None)]
    assert bridge.start_planner(cmd) is spare and bridge._planner_key(cmd, None) not in bridge._SPARES
    spare.discard()


def test_a_killed_planner_leaves_no_process_behind(tmp_path):
    cmd = _script(tmp_path, "sleeper", "import subprocess, sys, time\n"
                                       "child = subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(600)'])\n"
                                       "print('{\"pid\": %d}' % child.pid, flush=True)\ntime.sleep(600)\n")
    proc = PlannerProcess(cmd)
    grandchild = proc.receive(30, "pid")["pid"]
    proc.kill()
    assert proc.proc.poll() is not None  # reaped
    for _ in range(50):  # the whole process group got SIGKILL (the grandchild is init's to reap)
        try:
            os.kill(grandchild, 0)
            with open(f"/proc/{grandchild}/stat") as f:
                if f.read().split()[2] == "Z":
                    break
        except (ProcessLookupError, FileNotFoundError):
            break
        time.sleep(0.1)
    else:
        pytest.fail("the planner's child process survived")


def test_a_missing_planner_command_is_an_error_outcome(suite_file, tmp_path):
    res = run_suite(load_suite(_one(suite_file, tmp_path)), BridgePlanner("/nonexistent/planner --x"),
                    progress=False, record_failure_gif=False)
    assert res.outcomes[0].outcome == "error" and "cannot start the planner" in res.outcomes[0].message


# a planner as a user first writes it: print() without flush, its stdout a pipe (block-buffered)
UNFLUSHED = textwrap.dedent("""
    import json, sys
    def recv():
        return json.loads(sys.stdin.readline())
    recv(); print(json.dumps({"type": "hello", "protocol": 1, "map_format": "native", "output": "control"}))
    recv(); print(json.dumps({"type": "ready"}))
    while True:
        m = recv()
        if m["type"] == "close":
            print(json.dumps({"type": "bye"}))
            break
        print(json.dumps({"type": "control", "acceleration": 0.0, "steering": 0.0}))
""")


def test_a_planner_that_never_flushes_works(suite_file, tmp_path, monkeypatch):
    monkeypatch.delenv("PYTHONUNBUFFERED", raising=False)  # the bridge sets it for the planner
    planner = BridgePlanner(_script(tmp_path, "unflushed", UNFLUSHED), start_timeout=10, step_timeout=5)
    res = run_suite(load_suite(_one(suite_file, tmp_path)), planner, progress=False, record_failure_gif=False)
    o = res.outcomes[0]
    assert o.outcome != "error" and "BridgeError" not in o.message and o.steps > 1, (o.outcome, o.message)


def test_a_missing_hello_names_the_likely_cause(tmp_path):
    # a planner that stays silent (as an unflushed one in an env that asks for buffering)
    proc = PlannerProcess(_script(tmp_path, "silent", "import sys, time\nsys.stdin.readline()\ntime.sleep(600)\n"))
    with pytest.raises(BridgeError, match=r"no hello reply within 1 s: .*flush stdout after each line\? \(python -u\)"):
        proc.request({"type": "hello", "protocol": 1}, 1.0, "hello")


def test_the_bridge_planner_pickles_before_reset():
    import pickle

    p = pickle.loads(pickle.dumps(BridgePlanner("python x.py", step_timeout=3)))
    assert p.cmd == "python x.py" and p.step_timeout == 3 and p.proc is None


def test_the_tracker_follows_a_straight_trajectory_and_stops_at_its_end():
    clock = [0.0]
    traj = Trajectory.of([[0, 0, 0, 0, 5.0], [2, 10, 0, 0, 5.0], [4, 15, 0, 0, 0.0]])
    tr = TrajectoryTracker(traj, clock=lambda: clock[0])
    path = _drive_tracker(tr, clock, 0.0, 1.0, 0.0, 5.0, 90)  # 1 m left of the path, 6 s at 15 Hz
    (x, y), v = path[-1], clock[1]
    assert abs(y) < 0.3 and v < 0.5 and 12.0 < x < 17.0, (x, y, v)
    with pytest.raises(ValueError):
        Trajectory.of([[0, 0, 0, 0, float("nan")]])
    with pytest.raises(ValueError):
        Trajectory.of([[1, 0, 0, 0, 1], [0, 1, 0, 0, 1]])


def _drive_tracker(tr, clock, x, y, h, v, steps, hz=15):
    """The env's bicycle (`sim.vehicle.integrate`, the default model) under the tracker: the
    centre's path; the last speed is left in clock[1]."""
    m = VehicleModel.of()
    path = []
    for _ in range(steps):
        cmd = tr.command((x, y), h, v)
        x, y, h, v = integrate(x, y, h, v, cmd["steering"], cmd["acceleration"], 1 / hz, m.wheelbase, m.rear_offset,
                               math)
        v = max(0.0, v)
        clock[0] += 1 / hz
        path.append((x, y))
    clock[1:] = [v]
    return np.array(path)


def test_the_tracker_stays_on_a_junction_turn():
    """A 10 m-radius quarter turn at 4.5 m/s: the centre stays within 0.25 m of the arc (a pure
    pursuit that ignored where the model turns about cut it by 0.7 m and the reactive planner
    then saw the ego's body on the road boundary, issue 22)."""
    r, v = 10.0, 4.5
    ang = np.linspace(0.0, np.pi / 2, 60)
    t = ang * r / v
    traj = Trajectory.of(np.column_stack([t, r * np.sin(ang), r - r * np.cos(ang), ang, np.full_like(t, v)]))
    clock = [0.0]
    path = _drive_tracker(TrajectoryTracker(traj, clock=lambda: clock[0]), clock, 0.0, 0.0, 0.0, v,
                          int(t[-1] * 15) - 5)
    radial = np.hypot(path[:, 0], path[:, 1] - r)
    assert np.abs(radial - r).max() < 0.25, np.abs(radial - r).max()


def test_a_control_planner_that_leaves_the_road_fails_with_a_gif_recorded_while_it_drove(suite_file, tmp_path):
    """`control` replies drive the ego directly; the failure's GIF comes from the run itself (an
    out-of-process planner is not replayed)."""
    cmd = _script(tmp_path, "wild", HELLO + "while True:\n    m = recv()\n"
                                            "    if m['type'] == 'close':\n        send({'type': 'bye'}); break\n"
                                            "    send({'type': 'control', 'acceleration': 3.0, 'steering': 0.6})\n")
    out = tmp_path / "rep"
    rc = cli.main(["rollout", str(_one(suite_file, tmp_path)), "--planner-cmd", cmd, "--out", str(out), "--quiet",
                   "--no-coverage"])
    assert rc == 1
    o = json.loads((out / "summary.json").read_text())["outcomes"][0]
    assert o["outcome"] in ("off_road", "collision") and o["route_progress"] < 0.5
    gif = out / "failures" / f"{o['name']}.gif"
    assert gif.is_file() and gif.read_bytes()[:6] in (b"GIF89a", b"GIF87a")
