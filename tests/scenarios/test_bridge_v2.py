"""Bridge protocol 2's planner-facing description of the env: `init` carries the ego's vehicle
model, the route's stop lines and the compliance rules as numbers; each `step.ego` carries its
steering, yaw rate and acceleration, and `step.ahead.hold` the env's rules in the ego's place.
Checked on a generated map with a signal (J0) and a stop sign (J1), for planners answering
protocol 1 and 2."""
from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import textwrap
from pathlib import Path

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
from highway_env.vehicle.kinematics import Vehicle

import feat2map
from feat2map import config
from feat2map.envs.rules import has_stopped, in_stop_zone, pedestrian_in_path, stops_at_amber
from feat2map.formats import native
from feat2map.scenarios.bridge import BRIDGE_ACTION_CONFIG, BridgePlanner
from feat2map.scenarios.rollout import run_scenario
from feat2map.scenarios.scenario import Scenario, make_env

J = feat2map.JunctionFeature.make
STEER = 0.03  # the recording planner's control
ACCEL = 1.0

RECORDER = textwrap.dedent("""
    import json, sys
    log = open(sys.argv[1], "w")
    protocol = int(sys.argv[2])
    for line in sys.stdin:
        msg = json.loads(line)
        log.write(line); log.flush()
        kind = msg["type"]
        reply = {"hello": {"type": "hello", "protocol": protocol, "map_format": "native", "output": "control"},
                 "init": {"type": "ready"}, "close": {"type": "bye"}}.get(kind)
        if reply is None:
            reply = {"type": "control", "acceleration": %r, "steering": %r}
        if protocol >= 2:
            reply["step"] = msg["step"]
        print(json.dumps(reply), flush=True)
        if kind == "close":
            break
""" % (ACCEL, STEER))


@pytest.fixture(scope="module")
def scenario(tmp_path_factory) -> Scenario:
    """A drive through a signalled junction (J0), then a stop-sign junction (J1)."""
    d = tmp_path_factory.mktemp("v2")
    m = feat2map.generate_from_features([J([0, 90, 180], "signal", False), J([0, 90, 180], "stop", False)], seed=0)
    native.save(m, d / "m.json")
    return Scenario("sig-stop", str(d / "m.json"), (("J0", "R0", "R2"), ("J1", "R2", "R3")), duration=3.0)


def _record(scenario: Scenario, tmp_path: Path, protocol: int) -> list[dict]:
    script = tmp_path / "recorder.py"
    script.write_text(RECORDER)
    log = tmp_path / f"messages{protocol}.jsonl"
    planner = BridgePlanner([sys.executable, str(script), str(log), str(protocol)])
    run_scenario(scenario, planner, record_failure_gif=False, blocked_after=12.5)
    return [json.loads(x) for x in log.read_text().splitlines()]


def _on_polyline(p: tuple[float, float], line: list) -> float:
    """Distance from `p` to the polyline `line`."""
    best = math.inf
    for (x0, y0), (x1, y1) in zip(line, line[1:]):
        dx, dy = x1 - x0, y1 - y0
        u = max(0.0, min(1.0, ((p[0] - x0) * dx + (p[1] - y0) * dy) / (dx * dx + dy * dy or 1e-12)))
        best = min(best, math.hypot(p[0] - x0 - u * dx, p[1] - y0 - u * dy))
    return best


@pytest.mark.parametrize("protocol", [1, 2])
def test_init_carries_the_vehicle_model_stop_lines_and_rules(scenario, tmp_path, protocol):
    msgs = _record(scenario, tmp_path, protocol)
    init = next(m for m in msgs if m["type"] == "init")
    v = init["vehicle"]
    body = config.DRIVE_DEFAULTS["vehicle"]  # the env's default vehicle, which the rollout drives
    assert (v["length"], v["width"]) == (body["length"], body["width"]) == (init["ego"]["length"], init["ego"]["width"])
    assert v["wheelbase"] == body["wheelbase"] == v["front_axle"] - v["rear_axle"]
    assert v["length"] / 2 - v["front_axle"] == pytest.approx(body["front_overhang"]) == v["front_overhang"]
    assert v["kind"] == "kinematic_bicycle" and v["reference_point"] == "centre"
    assert v["max_steering"] == body["max_steering"] == v["tracker"]["max_steering"]
    assert v["acceleration_range"] == BRIDGE_ACTION_CONFIG["acceleration_range"]
    lo, hi = BRIDGE_ACTION_CONFIG["steering_range"]
    assert v["steering_range"] == pytest.approx([max(lo, -body["max_steering"]), min(hi, body["max_steering"])])
    assert v["max_speed"] == Vehicle.MAX_SPEED
    t = v["tracker"]
    assert (t["lookahead_min_m"], t["speed_gain"], t["preview_s"], t["hold_window_s"]) == (
        config.TRACKING_LOOKAHEAD_MIN_M, config.TRACKING_SPEED_GAIN, config.TRACKING_PREVIEW_S,
        config.TRACKING_HOLD_WINDOW_S)

    # the stop lines: the env's own (MapNetwork.stop_lines), on the native map's lane centreline
    env = make_env(scenario)
    env.reset(seed=scenario.seed)
    net = env.unwrapped.net
    route = init["route"]["lanes"]
    expect = [(lid, net.stop_lines[lid]) for lid in route if lid in net.stop_lines]
    rtor = env.unwrapped.control.right_turn_on_red()
    goal_s = env.unwrapped.goal_s(net.lane_of[route[-1]])  # where the env completes the route
    env.close()
    assert init["goal"]["lane"] == route[-1] and init["goal"]["s"] == pytest.approx(goal_s)
    lines = init["stop_lines"]
    assert [(x["junction"], x["kind"]) for x in lines] == [("J0", "signal"), ("J1", "stop")]
    lanes = {ln["id"]: ln for ln in json.loads(Path(scenario.map).read_text())["lanes"]}
    m = native.load(scenario.map)
    for x, (lid, sl) in zip(lines, expect):
        assert (x["lane"], x["control"], x["s"]) == (lid, sl.control_id, pytest.approx(sl.s))
        assert x["control"] in (m.signals if x["kind"] == "signal" else m.stop_signs)
        assert route[x["route_index"]] == lid
        pos = net.lane_of[lid].position(sl.s, 0.0)
        assert (x["x"], x["y"]) == pytest.approx((pos[0], -pos[1]))
        assert _on_polyline((x["x"], x["y"]), lanes[lid]["centerline"]) < 1e-3  # the map's frame
        cl = lanes[lid]["centerline"]
        assert math.cos(x["heading"] - math.atan2(cl[-1][1] - cl[-2][1], cl[-1][0] - cl[-2][0])) > 0.99

    # the rules: the numbers the judge decides with
    r = init["rules"]
    stop = r["full_stop"]
    assert has_stopped(stop["speed_mps"]) and not has_stopped(stop["speed_mps"] + 1e-6)
    assert in_stop_zone(stop["zone_m"]) and not in_stop_zone(stop["zone_m"] + 1e-6) and not in_stop_zone(-1e-6)
    a = r["amber"]
    v0 = 10.0
    d0 = v0 ** 2 / (2 * a["brake_mps2"]) + a["margin_m"]
    assert stops_at_amber(d0 + 1e-6, v0) and not stops_at_amber(d0 - 1e-6, v0)
    ped = r["pedestrian_yield"]
    assert pedestrian_in_path(1.75 + ped["in_path_m"] - 1e-6, 3.5) and not pedestrian_in_path(1.75 + ped["in_path_m"], 3.5)
    assert (ped["moving_mps"], ped["stretch_m"]) == (config.PEDESTRIAN_YIELD_SPEED_MPS, config.PEDESTRIAN_YIELD_STRETCH_M)
    assert r["blocked"] == {"after_s": 12.5, "near_m": config.BLOCKED_NEAR_M}
    assert r["signal"] == {"red": "violation", "amber": "allowed", "right_turn_on_red": rtor}


@pytest.mark.parametrize("protocol", [1, 2])
def test_step_ego_carries_steering_yaw_rate_and_acceleration(scenario, tmp_path, protocol):
    msgs = _record(scenario, tmp_path, protocol)
    init = next(m for m in msgs if m["type"] == "init")
    wheelbase = init["vehicle"]["wheelbase"]
    steps = [m["ego"] for m in msgs if m["type"] == "step"]
    assert len(steps) >= 10
    assert steps[0]["steering"] == 0.0 and steps[0]["yaw_rate"] == 0.0
    for ego in steps[1:]:
        # the control's steering turns clockwise in the map's frame (the env's sign): the ego's steering
        # is reported anticlockwise-positive, as its heading and yaw rate
        assert ego["steering"] == pytest.approx(-STEER) and ego["acceleration"] == pytest.approx(ACCEL)
        assert ego["yaw_rate"] == pytest.approx(ego["speed"] * math.tan(ego["steering"]) / wheelbase)
    dt = init["dt"]
    a, b = steps[5], steps[6]
    turned = (b["heading"] - a["heading"]) / dt
    assert turned < 0 and turned == pytest.approx((a["yaw_rate"] + b["yaw_rate"]) / 2, rel=0.1)


def test_step_ahead_hold_is_the_env_rules_answer_and_asking_changes_nothing(scenario):
    """`step.ahead.hold`: where the env's rules would stop its own traffic in the ego's place, and
    which rules each would; asking it every decision leaves the episode exactly as it was."""
    from feat2map.scenarios.bridge import HOLD_RULES, rule_hold
    from feat2map.scenarios.planner import BaselinePlanner

    sc = dataclasses.replace(scenario, duration=40.0, traffic_vehicles=6)

    def drive(ask: bool) -> tuple[list, dict]:
        env = make_env(sc)
        obs, info = env.reset(seed=sc.seed)
        planner = BaselinePlanner()
        planner.reset(env)
        trace, holds = [], {}
        for _ in range(400):
            obs, _, term, trunc, info = env.step(planner.act(obs, info))
            u = env.unwrapped
            trace.append((*map(float, u.vehicle.position), float(u.vehicle.speed)))
            if ask:
                hold = rule_hold(u.control, u.vehicle)
                stop = u.control.stop_distance(u.vehicle)
                assert (hold is None) == (stop == math.inf)
                if hold is not None:
                    assert hold["distance"] == stop and hold["by"] and set(hold["by"]) <= set(HOLD_RULES)
                    for r in hold["by"]:  # each named rule on its own stops the ego there
                        alone = u.control.stop_distance(u.vehicle, ignore=frozenset(HOLD_RULES) - {r})
                        assert alone <= stop + 0.5
                    if info.get("signal_state") == "red":
                        assert "signal" in hold["by"]
                    holds.setdefault(tuple(hold["by"]), 0)
                    holds[tuple(hold["by"])] += 1
            if term or trunc:
                break
        env.close()
        return trace, holds

    asked, holds = drive(True)
    assert drive(False)[0] == asked  # pure queries
    named = {r for by in holds for r in by}
    assert {"signal", "stop"} <= named, holds  # a red at J0, the stop sign at J1


def test_the_bridged_ego_reserves_its_junction_lanes_as_traffic_in_its_place_would(scenario, monkeypatch):
    """Every decision the bridge claims for the ego by the env's rule (`BridgePlanner._claim`):
    before it drives onto J0's junction lane it holds it (traffic then gives way to it), and on
    a red light, where the rule holds it, it holds nothing."""
    sc = dataclasses.replace(scenario, duration=40.0, traffic_vehicles=4)
    seen = []
    act = BridgePlanner.act

    def spy(self, obs, info):
        u = self.env.unwrapped
        out = act(self, obs, info)
        held = {lid for lid, v in u.control.reservations.items() if v is u.vehicle}
        seen.append((u.net.id_of.get(u.vehicle.lane_index), held, info.get("signal_state")))
        return out

    monkeypatch.setattr(BridgePlanner, "act", spy)
    planner = BridgePlanner(REFERENCE.split())
    outcome = run_scenario(sc, planner, record_failure_gif=False)
    assert outcome.outcome == "completed", outcome.message
    route = make_env(sc)
    route.reset(seed=sc.seed)
    j0 = next(x for x in route.unwrapped.vehicle.lane_route if x.startswith("J0"))
    route.close()
    first_on = next(k for k, (lane, _, _) in enumerate(seen) if lane == j0)
    assert any(j0 in held for _, held, _ in seen[:first_on])  # reserved before driving onto it
    assert all(j0 not in held for lane, held, state in seen[:first_on] if state == "red")


def test_the_rule_gate_gives_way_where_the_env_rules_hold_the_ego_and_it_can_still_stop():
    sys.path.insert(0, str(ROOT / "adapters"))
    try:
        from bridge_client import HOLD_MARGIN_M, RuleGate
    finally:
        sys.path.remove(str(ROOT / "adapters"))
    gate = RuleGate({"signals": [], "stop_signs": []}, ["R0_1", "J0_c0_0", "R1_0"], [None, "J0", None],
                    [50.0, 70.0, 120.0], ego_length=4.8)

    def stop(by: list[str], speed: float, distance: float = 12.0) -> tuple[float, str]:
        return gate.stop_s({"t": 0.0, "ahead": {"hold": {"distance": distance, "by": by}}}, 30.0, speed)

    assert stop(["conflict"], 3.0) == (pytest.approx(30.0 + 12.0 - 2.4 - HOLD_MARGIN_M), "YIELD")
    assert stop(["pedestrian"], 3.0)[1] == stop(["passage", "signal"], 3.0)[1] == "YIELD"
    assert stop(["conflict"], 9.0) == (math.inf, "")  # 13.5 m to stop at 3 m/s^2: too late, it goes on
    assert stop(["signal"], 3.0) == (math.inf, "")  # signals and stop signs: the gate's own lines
    assert gate.stop_s({"t": 0.0, "ahead": {"hold": None}}, 30.0, 3.0) == (math.inf, "")
    assert gate.stop_s({"t": 0.0}, 30.0, 3.0) == (math.inf, "")  # a version 1 step


# ---- recording and replay ----------------------------------------------------------------------
ROOT = Path(__file__).resolve().parents[2]
REFERENCE = f"{sys.executable} {ROOT / 'examples' / 'bridge_planner.py'}"
PERTURBED = textwrap.dedent("""
    import sys
    sys.path.insert(0, %r)
    from bridge_planner import ReferencePlanner, serve

    class Perturbed(ReferencePlanner):
        def step(self, msg):
            reply = super().step(msg)
            if msg["step"] >= 4:
                reply["points"][-1]["speed"] += 0.01
            return reply

    sys.exit(serve(Perturbed()))
""" % str(ROOT / "examples"))


@pytest.fixture(scope="module")
def recorded(scenario, tmp_path_factory) -> Path:
    """The reference planner's session of `scenario`, recorded by `feat2map rollout --record`."""
    from feat2map import cli
    from feat2map.scenarios.scenario import Suite, save_suite

    d = tmp_path_factory.mktemp("rec")
    save_suite(Suite("one", (scenario,), str(d)), d / "suite.yaml")
    rc = cli.main(["rollout", str(d / "suite.yaml"), "--planner-cmd", REFERENCE, "--record", str(d / "rec"),
                   "--out", str(d / "out"), "--quiet", "--no-gif", "--fail-on", "none"])
    assert rc == 0
    return d / "rec" / scenario.name


def test_a_recording_keeps_the_map_and_every_message_both_ways(recorded):
    from feat2map.scenarios.bridge_record import load_recording

    meta, entries = load_recording(recorded)
    assert meta["map"] == "map.json" and (recorded / "map" / "map.json").is_file()  # the export outlives the rollout
    dirs = [e["dir"] for e in entries]
    assert dirs == ["to_planner", "from_planner"] * (len(dirs) // 2)  # each message, then its reply
    kinds = [e["message"]["type"] for e in entries]
    assert kinds[:4] == ["hello", "hello", "init", "ready"] and kinds[-2:] == ["close", "bye"]
    steps = [e["message"] for e in entries if e["message"]["type"] == "step"]
    assert [m["step"] for m in steps] == list(range(len(steps))) and len(steps) >= 10
    walls = [e["wall"] for e in entries]
    assert walls == sorted(walls)


def test_a_replay_of_the_same_planner_has_no_difference(recorded, capsys):
    from feat2map import cli

    assert cli.main(["replay", str(recorded), "--planner-cmd", REFERENCE]) == 0
    out = capsys.readouterr().out
    assert "0 differences" in out


def test_a_replay_names_the_first_step_where_a_planner_answers_differently(recorded, tmp_path, capsys):
    from feat2map import cli
    from feat2map.scenarios.bridge_record import replay

    script = tmp_path / "perturbed.py"
    script.write_text(PERTURBED)
    cmd = f"{sys.executable} {script}"
    result = replay(recorded, cmd)
    assert result.differences[0].startswith("step 4 (step): point 20 speed")
    assert len(result.differences) == result.messages - 7  # steps 4.. differ; hello, init, steps 0-3, close do not
    assert cli.main(["replay", str(recorded), "--planner-cmd", cmd]) == 1
    assert "first difference: step 4 (step)" in capsys.readouterr().out
    assert replay(recorded, cmd, tolerance=0.02).differences == ()


# ---- reports -----------------------------------------------------------------------------------
HOLDER = textwrap.dedent("""
    import json, sys
    for line in sys.stdin:
        msg = json.loads(line)
        kind = msg["type"]
        reply = {"hello": {"type": "hello", "protocol": 2, "map_format": "native", "output": "control"},
                 "init": {"type": "ready"}, "close": {"type": "bye"}}.get(kind)
        if reply is None:
            if msg["step"] == %(crash_at)d:
                sys.stderr.write("Traceback: <b>planner *exploded*</b>\\n"); sys.exit(3)
            sys.stderr.write("holding at step %%d\\n" %% msg["step"]); sys.stderr.flush()
            reply = {"type": "control", "acceleration": -1.0, "steering": 0.0, "stage": "HOLD" if msg["step"] < 2 else "WAIT"}
        reply["step"] = msg["step"]
        print(json.dumps(reply), flush=True)
        if kind == "close":
            break
""")


def _suite(scenario: Scenario, tmp_path: Path) -> Path:
    from feat2map.scenarios.scenario import Suite, save_suite

    save_suite(Suite("one", (scenario,), str(tmp_path)), tmp_path / "suite.yaml")
    return tmp_path / "suite.yaml"


def test_a_failed_scenario_reports_the_planners_stderr_last_stage_and_missing_coverage(scenario, tmp_path, capsys):
    from feat2map import cli

    script = tmp_path / "holder.py"
    script.write_text(HOLDER % {"crash_at": -1})
    out = tmp_path / "out"
    rc = cli.main(["rollout", str(_suite(scenario, tmp_path)), "--planner-cmd", f"{sys.executable} {script}",
                   "--out", str(out), "--no-gif", "--line-coverage", "--blocked-after", "1"])
    assert rc == 1
    o = json.loads((out / "summary.json").read_text())["outcomes"][0]
    assert o["outcome"] == "timeout" and o["stage_path"] == ["HOLD", "WAIT"]
    assert o["planner_stderr"].endswith(f"holding at step {o['steps'] - 1}")
    report = (out / "report.md").read_text()
    assert "last stage: WAIT" in report and "The planner's stderr (its end):" in report
    assert f"holding at step {o['steps'] - 1}" in report
    assert "The planner sent no coverage" in report and "0 lines of the planner covered" not in report
    # off a terminal (capsys): one line per finished scenario
    assert "[1/1] sig-stop: timeout (" in capsys.readouterr().out
    # side by side too: unknown, not 0
    assert cli.main(["coverage", str(out), "--out", str(tmp_path / "cmp")]) == 0
    table = json.loads((tmp_path / "cmp" / "coverage.json").read_text())
    row = dict(zip(table["columns"], table["rows"][0]))
    assert row["lines"] == row["unique lines"] == "-"
    assert any("the planner sent no coverage" in w for w in table["warnings"])


def test_an_error_outcome_keeps_the_stage_path_and_quotes_stderr_once(scenario, tmp_path):
    from feat2map import cli

    script = tmp_path / "crasher.py"
    script.write_text(HOLDER % {"crash_at": 3})
    out = tmp_path / "out"
    assert cli.main(["rollout", str(_suite(scenario, tmp_path)), "--planner-cmd", f"{sys.executable} {script}",
                     "--out", str(out), "--no-gif", "--quiet"]) == 1
    o = json.loads((out / "summary.json").read_text())["outcomes"][0]
    assert o["outcome"] == "error" and o["stage_path"] == ["HOLD", "WAIT"]
    assert "planner *exploded*" in o["planner_stderr"] and "planner *exploded*" in o["message"]
    report = (out / "report.md").read_text()
    assert "last stage: WAIT" in report and report.count("planner *exploded*") == 1  # in the message's block
    assert "<b>" not in (out / "report.html").read_text().replace("&lt;b&gt;", "")


# ---- a map format the planner cannot get --------------------------------------------------------
WANTS_COMMONROAD = textwrap.dedent("""
    import json, sys
    sys.stdin.readline()
    print(json.dumps({"type": "hello", "protocol": 2, "step": 0, "map_format": "commonroad"}), flush=True)
    for line in sys.stdin:
        print(json.dumps({"type": "ready", "step": 0}), flush=True)
""")


@pytest.mark.parametrize("how", ["package_missing", "writer_does_not_import"])
def test_a_map_format_this_environment_cannot_write_is_an_error_at_hello(scenario, tmp_path, monkeypatch, how):
    import dataclasses

    from feat2map.errors import Feat2MapError
    from feat2map.formats import FORMATS
    from feat2map.formats.commonroad import writer
    from feat2map.scenarios.rollout import HASH_SEED, run_suite

    if how == "package_missing":
        def missing():
            raise Feat2MapError("CommonRoad export needs commonroad-io", "commonroad")

        monkeypatch.setattr(writer, "commonroad_io", missing)
    else:
        monkeypatch.setitem(FORMATS, "commonroad", dataclasses.replace(FORMATS["commonroad"],
                                                                       write="feat2map.formats.no_such_writer:write"))
    monkeypatch.setenv("PYTHONHASHSEED", HASH_SEED)  # the suite runs in this process, where the patch is
    script = tmp_path / "wants_commonroad.py"
    script.write_text(WANTS_COMMONROAD)
    suite = [scenario, dataclasses.replace(scenario, name="second")]
    result = run_suite(suite, BridgePlanner([sys.executable, str(script)]), progress=False, record_failure_gif=False)
    assert [o.outcome for o in result.outcomes] == ["error", "error"] and not result.stopped  # the rollout went on
    for o in result.outcomes:
        assert "bad hello: asks for map format commonroad, which this environment cannot write" in o.message
        assert "install it with `bash scripts/setup.sh commonroad`" in o.message
        assert ("commonroad-io" if how == "package_missing" else "no_such_writer") in o.message


def test_a_recording_keeps_the_session_of_the_outcome_not_the_gifs_replay(scenario, tmp_path):
    from feat2map import cli
    from feat2map.scenarios.bridge_record import load_recording

    runs = tmp_path / "runs"
    script = tmp_path / "flaky.py"  # the first run crashes at step 3, every later one at step 1
    script.write_text(f"import os\nruns = {str(runs)!r}\nn = os.path.getsize(runs) if os.path.exists(runs) else 0\n"
                      f"open(runs, 'a').write('x')\n" + (HOLDER % {"crash_at": -7}).replace("== -7", "== (3 if n == 0 else 1)"))
    out = tmp_path / "out"
    assert cli.main(["rollout", str(_suite(scenario, tmp_path)), "--planner-cmd", f"{sys.executable} {script}",
                     "--record", str(tmp_path / "rec"), "--out", str(out), "--quiet"]) == 1
    assert runs.read_text() == "xx"  # the error's GIF re-ran the planner
    _, entries = load_recording(tmp_path / "rec" / scenario.name)
    assert [e["message"]["step"] for e in entries if e["dir"] == "to_planner" and e["message"]["type"] == "step"] \
        == [0, 1, 2, 3]


def test_record_is_refused_before_the_run_without_a_planner_command_or_over_a_foreign_folder(scenario, tmp_path,
                                                                                              capsys):
    from feat2map import cli

    suite = str(_suite(scenario, tmp_path))
    assert cli.main(["rollout", suite, "--record", str(tmp_path / "rec"), "--out", str(tmp_path / "o1"),
                     "--quiet"]) == 2
    assert "--record needs --planner-cmd" in capsys.readouterr().err
    (tmp_path / "rec" / scenario.name).mkdir(parents=True)
    (tmp_path / "rec" / scenario.name / "notes.txt").write_text("mine")
    assert cli.main(["rollout", suite, "--planner-cmd", REFERENCE, "--record", str(tmp_path / "rec"),
                     "--out", str(tmp_path / "o2"), "--quiet"]) == 2
    assert scenario.name in capsys.readouterr().err and not (tmp_path / "o2").exists()
    assert (tmp_path / "rec" / scenario.name / "notes.txt").read_text() == "mine"
