"""Issue 33: no planner can hang or exhaust a rollout. The abusive planners of
scripts/harden_harness.py's bridge section (all but the slowest) each drive a one-scenario
rollout through the bridge: the outcome and message expected, within bounded time, and no
process of the planner alive afterwards. A watchdog fails a hang instead of waiting on it
(pytest-timeout is not a dependency)."""
from __future__ import annotations

import importlib.util
import io
import json
import os
import signal
import sys
import threading
import time
from collections.abc import Iterator

os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
os.environ.setdefault("MPLBACKEND", "Agg")

import pytest
from conftest import REPO

from feat2map.scenarios.bridge import MAX_NUMBER, BridgePlanner, parse_reply
from feat2map.scenarios.rollout import HASH_SEED, run_suite
from feat2map.scenarios.scenario import Suite, load_suite

_spec = importlib.util.spec_from_file_location("harden_harness", REPO / "scripts" / "harden_harness.py")
assert _spec is not None and _spec.loader is not None
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)

SLOW_CASES = {"stderr_100mb", "line_50mb"}  # writing 100 MB / 50 MB: in the harness only
WALL_LIMIT_S = 20.0  # one abusive planner's rollout (2-7 s on a busy 2-core machine)
WATCHDOG_S = 60  # a rollout still running then hangs: the test fails (SIGALRM), or the run ends (os._exit)


@pytest.fixture(scope="module")
def suite(tmp_path_factory) -> Suite:
    return load_suite(harness.bridge_suite(tmp_path_factory.mktemp("abuse")))


@pytest.fixture
def watchdog() -> Iterator[None]:
    """SIGALRM raises in the test after WATCHDOG_S; should that not end it (a wait signals do
    not interrupt), the whole run exits 30 s later rather than hang."""
    def fire(signum: int, frame: object) -> None:
        raise TimeoutError(f"the rollout hung for {WATCHDOG_S} s")

    def hard_exit() -> None:
        sys.__stderr__.write(f"\ntest_bridge_abuse: a rollout hung past {WATCHDOG_S + 30} s; exiting\n")
        os._exit(3)

    previous = signal.signal(signal.SIGALRM, fire)
    signal.alarm(WATCHDOG_S)
    hard = threading.Timer(WATCHDOG_S + 30, hard_exit)
    hard.daemon = True
    hard.start()
    try:
        yield
    finally:
        signal.alarm(0)
        hard.cancel()
        signal.signal(signal.SIGALRM, previous)


CASES = [pytest.param(body, outcome, text, id=name) for name, _, body, outcome, text in harness.BRIDGE_CASES
         if name not in SLOW_CASES]


@pytest.mark.parametrize("body,outcome,text", CASES)
def test_an_abusive_planner_ends_its_rollout_in_time_and_leaves_no_process(suite, tmp_path, monkeypatch, watchdog,
                                                                          body, outcome, text):
    tag = f"{tmp_path.name}-{time.time_ns()}"
    monkeypatch.setenv(harness.HARNESS_TAG_VAR, tag)  # inherited by the planner and all it starts
    monkeypatch.setenv("PYTHONHASHSEED", HASH_SEED)  # run_suite drives in this process, no worker
    script = tmp_path / "planner.py"
    script.write_text(harness.PLANNER_PRELUDE + body)
    planner = BridgePlanner(f"{sys.executable} {script}", step_timeout=harness.BRIDGE_STEP_TIMEOUT_S,
                            start_timeout=5, close_timeout=5)
    t0 = time.monotonic()
    o = run_suite(suite, planner, progress=False, record_failure_gif=False, coverage=False).outcomes[0]
    wall = time.monotonic() - t0
    assert o.outcome == outcome and text in o.message, (o.outcome, o.message)
    assert wall < WALL_LIMIT_S, wall
    stop = time.monotonic() + 2.0  # SIGKILLed processes may take a moment to die
    while (alive := harness.tagged_processes(tag)) and time.monotonic() < stop:
        time.sleep(0.05)
    assert not alive, f"planner processes survived: {alive}"


@pytest.mark.parametrize("line,error", [
    (b"[" * 100_000 + b"]" * 100_000, "nested too deep"),
    (b'{"a": ' + b"9" * 400 + b"}", "an integer of 400 digits"),
    (b'{"a": 1e308}', "a number out of range"),
    (b'{"a": -1e400}', "a number out of range"),
    (b'{"a": NaN}', "a non-finite number: NaN"),
    (b'{"a": -Infinity}', "a non-finite number: -Infinity"),
    (b'{"a": 1', "not JSON"),
    (b'{"a": "\xff"}', "not UTF-8"),
])
def test_a_reply_with_garbage_numbers_or_nesting_is_a_value_error(line, error):
    with pytest.raises(ValueError, match=error):
        parse_reply(line)


def test_a_reply_within_the_limits_parses():
    assert parse_reply(b'{"a": [1, -2.5, %d, %r]}' % (int(MAX_NUMBER), -MAX_NUMBER)) == {"a": [1, -2.5, MAX_NUMBER,
                                                                                             -MAX_NUMBER]}


def test_the_client_echoes_the_step_and_answers_the_bridges_protocol():
    sys.path.insert(0, str(REPO / "adapters"))
    try:
        from bridge_client import serve
    finally:
        sys.path.remove(str(REPO / "adapters"))

    class Planner:
        def hello(self) -> dict:
            return {"output": "control"}

        def init(self, msg: dict) -> None:
            pass

        def step(self, msg: dict) -> dict:
            return {"type": "control", "acceleration": 0.0, "steering": 0.0}

    def replies(*requests: dict) -> list[dict]:
        out = io.StringIO()
        assert serve(Planner(), io.StringIO("".join(json.dumps(r) + "\n" for r in requests)), out) == 0
        return [json.loads(x) for x in out.getvalue().splitlines()]

    v2 = replies({"type": "hello", "protocol": 2, "step": 0}, {"type": "init", "step": 0},
                 {"type": "step", "step": 0}, {"type": "step", "step": 1}, {"type": "close", "step": 2})
    assert [r.get("step") for r in v2] == [0, 0, 0, 1, 2] and v2[0]["protocol"] == 2
    v1 = replies({"type": "hello", "protocol": 1}, {"type": "init"}, {"type": "step"}, {"type": "close"})
    assert all("step" not in r for r in v1) and v1[0]["protocol"] == 1
