"""Nothing outlives a rollout whose parent is gone: `feat2map rollout --workers 2` with planners
that hang (and ignore SIGTERM) in every worker; once both planners run, the parent is SIGTERMed
or SIGKILLed, and within a few seconds no worker and no planner process may be left (found in
Linux /proc by an environment variable every process of the run inherits). A SIGTERMed parent
still writes its partial report."""
from __future__ import annotations

import contextlib
import importlib.util
import io
import json
import os
import signal
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from conftest import REPO

_spec = importlib.util.spec_from_file_location("harden_harness", REPO / "scripts" / "harden_harness.py")
assert _spec is not None and _spec.loader is not None
harness = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(harness)

TAG_VAR = "FEAT2MAP_ORPHAN_TEST_TAG"  # in the rollout's environment: inherited by its workers and planners
START_LIMIT_S = 90.0  # for both workers to start their planners (spawn and import on a loaded 2-core machine)
GONE_LIMIT_S = 8.0  # after the parent's signal, for workers and planners to be gone (0.1-0.3 s unloaded)
REPORT_LIMIT_S = 60.0  # for a SIGTERMed parent to write its report and exit (3 s unloaded)
SCENARIOS = 4  # more than the workers: some are still queued when the parent goes
# answers hello and init, notes its pid, then hangs at the first step with SIGTERM ignored
PLANNER = """\
import json, os, signal, sys, time
def answer(req, m):
    sys.stdout.write(json.dumps(dict(m, step=req["step"]) if "step" in req else m) + "\\n"); sys.stdout.flush()
req = json.loads(sys.stdin.readline())
answer(req, {"type": "hello", "protocol": 2, "map_format": "native", "output": "control"})
answer(json.loads(sys.stdin.readline()), {"type": "ready"})
sys.stdin.readline()
signal.signal(signal.SIGTERM, signal.SIG_IGN)
open(os.path.join(sys.argv[1], str(os.getpid())), "w").close()
time.sleep(600)
"""


@pytest.fixture(scope="module")
def suite_file(tmp_path_factory) -> Path:
    import feat2map
    from feat2map import cli
    from feat2map.formats import native
    from feat2map.scenarios.scenario import Suite, load_suite, save_suite

    work = tmp_path_factory.mktemp("orphans")
    m = feat2map.generate_from_features([feat2map.JunctionFeature.make([0, 90, 180], "signal", False)], seed=0)
    native.save(m, work / "t.json")
    with contextlib.redirect_stdout(io.StringIO()):
        assert cli.main(["suite", str(work / "t.json"), "--out", str(work / "all.yaml"), "--duration", "5"]) == 0
    suite = load_suite(work / "all.yaml")
    assert len(suite.scenarios) >= SCENARIOS
    save_suite(Suite("orphans", suite.scenarios[:SCENARIOS], suite.base_dir), work / "four.yaml")
    return work / "four.yaml"


def tagged(tag: str) -> list[int]:
    """Live processes whose environment holds TAG_VAR=`tag` (the harness's /proc scan)."""
    return harness.tagged_processes(tag, TAG_VAR)


@contextlib.contextmanager
def rollout(suite_file: Path, tmp_path: Path) -> Iterator[tuple[subprocess.Popen, str, Path]]:
    """The rollout's parent process, its tag and the folder its planners note their pids in;
    whatever is left of the run is SIGKILLed afterwards (a failing test leaks nothing)."""
    tag = f"{tmp_path.name}-{time.time_ns()}"
    pids = tmp_path / "pids"
    pids.mkdir()
    script = tmp_path / "planner.py"
    script.write_text(PLANNER)
    env = {**os.environ, TAG_VAR: tag, "SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}
    env.pop("PYTHONHASHSEED", None)
    parent = subprocess.Popen(
        [sys.executable, "-m", "feat2map.cli", "rollout", str(suite_file), "--workers", "2", "--quiet",
         "--planner-cmd", f"{sys.executable} {script} {pids}", "--planner-timeout", "300",
         "--out", str(tmp_path / "out")], env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
    try:
        stop = time.monotonic() + START_LIMIT_S
        while len(os.listdir(pids)) < 2:
            assert parent.poll() is None, parent.communicate()[1].decode()[-2000:]
            assert time.monotonic() < stop, "the workers did not start their planners"
            time.sleep(0.1)
        yield parent, tag, pids
    finally:
        for pid in [parent.pid, *tagged(tag)]:
            with contextlib.suppress(ProcessLookupError):
                os.kill(pid, signal.SIGKILL)
        parent.wait()
        assert parent.stderr is not None
        parent.stderr.close()


def wait_gone(tag: str, parent: int | None = None) -> list[int]:
    """The run's processes still alive after GONE_LIMIT_S (none, once they all ended), but for
    `parent` and its multiprocessing resource tracker (which ends with it) when given."""
    def alive() -> list[int]:
        return [p for p in tagged(tag) if p != parent and not (parent and b"resource_tracker" in cmdline(p))]

    stop = time.monotonic() + GONE_LIMIT_S
    while (left := alive()) and time.monotonic() < stop:
        time.sleep(0.05)
    return left


def cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ")
    except OSError:
        return b""


def describe(pids: list[int], parent: subprocess.Popen) -> str:
    """The processes left (state and parent from /proc/PID/stat, command line) and what the run
    wrote to stderr so far (its workers' too: they inherit it), for a failure to explain itself."""
    def stat(pid: int) -> str:
        try:
            fields = Path(f"/proc/{pid}/stat").read_bytes().rsplit(b")", 1)[1].split()
            return f"state {fields[0].decode()}, parent {int(fields[1])}"
        except (OSError, IndexError):
            return "gone"
    assert parent.stderr is not None
    os.set_blocking(parent.stderr.fileno(), False)
    err = (parent.stderr.read() or b"").decode(errors="replace")[-3000:]
    return "; ".join(f"{p} ({stat(p)}): {cmdline(p)[:120]!r}" for p in pids) + f"\nthe run's stderr:\n{err}"


def test_a_sigkilled_rollout_parent_leaves_no_worker_or_planner(suite_file, tmp_path):
    with rollout(suite_file, tmp_path) as (parent, tag, _):
        parent.kill()
        alive = wait_gone(tag)
        assert not alive, f"survived the parent's SIGKILL: {describe(alive, parent)}"


def test_a_sigtermed_rollout_ends_with_its_workers_and_planners_and_writes_the_report_so_far(suite_file, tmp_path):
    with rollout(suite_file, tmp_path) as (parent, tag, _):
        parent.terminate()
        alive = wait_gone(tag, parent.pid)
        assert not alive, f"survived the parent's SIGTERM: {describe(alive, parent)}"
        assert parent.wait(timeout=REPORT_LIMIT_S) == 1
        alive = wait_gone(tag)
        assert not alive, f"survived the parent: {describe(alive, parent)}"
        summary = json.loads((tmp_path / "out" / "summary.json").read_text())
        assert summary["stopped"] == "interrupted (SIGTERM)" and summary["scenarios"] == SCENARIOS
