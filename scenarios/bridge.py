"""The planner bridge: a planner in another process (its own venv, its own Python) drives the
ego of a scenario env through JSON lines over its stdin/stdout (protocol: docs/planners.md).

    hello  ->  hello (protocol version, the map format it wants, trajectory or control output)
    init   ->  ready (map file in that format + id mapping, the route, the goal, the clock)
    step   ->  trajectory | control (the world each decision: ego, vehicles, pedestrians,
               signals with time to change, stop signs with their queues)
    close  ->  bye (optionally the planner's line coverage per junction)

Every position, heading and trajectory is in the map's own frame (x east, y north, heading
anticlockwise from x: the frame of the native map and of every export); the bridge converts
to and from the env's (y down). A trajectory (timestamped poses and speeds) is followed every simulation frame by the env's
tracking controller (`feat2map.envs.tracking`: pure pursuit + speed P control); a control
(acceleration, steering) is held over the decision period. A planner that crashes, misses a
deadline or replies garbage raises `BridgeError` (the rollout records an `error` outcome with
its message and the tail of the planner's stderr) and its whole process group is killed and
reaped: never a hang, never an aborted run.

    BridgePlanner(".venv-crplanner/bin/python adapters/commonroad/planner.py")

is a `Policy` like any other (`run_suite(suite, BridgePlanner(cmd))`, or `feat2map rollout SUITE
--planner-cmd CMD`).
"""
from __future__ import annotations

import hashlib
import json
import math
import os
import queue
import shlex
import signal
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

PROTOCOL_VERSION = 1
MAP_FORMATS = ("commonroad", "lanelet2", "opendrive", "apollo", "native")
MAP_SUFFIX = {"commonroad": "map.xml", "lanelet2": "map.osm", "opendrive": "map.xodr", "apollo": "apollo",
              "native": "map.json"}
OUTPUTS = ("trajectory", "control")
START_TIMEOUT_S = 120.0  # hello and init (a planner may import heavy libraries, build its map)
STEP_TIMEOUT_S = 10.0  # each decision's reply
CLOSE_TIMEOUT_S = 30.0  # the bye (a planner may save coverage data first)
STDERR_TAIL_CHARS = 1500  # of the planner's stderr, quoted in an error outcome
MAX_LINE_BYTES = 16 << 20  # a reply longer than this is garbage
MAX_TRAJECTORY_POINTS = 10_000
# the likely cause of a missing hello: the planner's stdout is block-buffered (a pipe, not a terminal)
NO_HELLO_HINT = "no reply line: does the planner flush stdout after each line? (python -u)"
WORLD_RADIUS_M = 150.0  # vehicles and pedestrians this close to the ego are sent
BRIDGE_ACTION_CONFIG: dict[str, Any] = {"type": "ContinuousAction", "longitudinal": True, "lateral": True,
                        "acceleration_range": [-8.0, 4.0], "steering_range": [-math.pi / 3, math.pi / 3]}


class BridgeError(RuntimeError):
    """The planner process failed: crashed, missed a deadline, or broke the protocol."""


class PlannerProcess:
    """One planner child process: JSON lines in and out, stderr to a file, deadlines on every
    reply, the process group killed and reaped on close."""

    def __init__(self, cmd: str | list[str], cwd: str | None = None, env: dict | None = None) -> None:
        argv = shlex.split(cmd) if isinstance(cmd, str) else list(cmd)
        if not argv:
            raise BridgeError("empty planner command")
        self.argv = argv
        self.stderr = tempfile.TemporaryFile()
        self.lines: queue.Queue = queue.Queue()
        # a Python planner's print() reaches the pipe at once, flushed or not (its env may say otherwise)
        child_env = dict(os.environ if env is None else env)
        child_env.setdefault("PYTHONUNBUFFERED", "1")
        try:
            self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                         cwd=cwd, env=child_env, start_new_session=True)
        except OSError as exc:
            self.stderr.close()
            raise BridgeError(f"cannot start the planner {argv[0]!r}: {exc.strerror or exc}") from None
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()
        self.closed = False

    def _read(self) -> None:
        out = self.proc.stdout
        assert out is not None  # Popen(stdout=PIPE)
        try:
            while True:
                line = out.readline(MAX_LINE_BYTES + 1)
                if not line:
                    break
                self.lines.put(line)
        except (OSError, ValueError):
            pass
        self.lines.put(None)  # end of output

    def send(self, msg: dict) -> None:
        assert self.proc.stdin is not None  # Popen(stdin=PIPE)
        try:
            self.proc.stdin.write((json.dumps(msg, separators=(",", ":"), allow_nan=False) + "\n").encode())
            self.proc.stdin.flush()
        except (BrokenPipeError, OSError, ValueError):
            raise BridgeError(self.failure(f"the planner closed its input before {msg.get('type')!r}")) from None

    def receive(self, timeout: float, what: str) -> dict:
        """The next reply (a JSON object), or BridgeError after `timeout` seconds."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                line = self.lines.get(timeout=max(left, 0.0))
            except queue.Empty:
                hint = f": {NO_HELLO_HINT}" if what == "hello" else ""
                raise BridgeError(self.failure(f"planner timeout: no {what} reply within {timeout:g} s{hint}")) from None
            if line is None:
                self.proc.poll()
                time.sleep(0.05)
                code = self.proc.poll()
                raise BridgeError(self.failure(f"the planner exited (code {code}) before its {what} reply"))
            if not line.strip():
                continue
            if len(line) > MAX_LINE_BYTES:
                raise BridgeError(self.failure(f"garbage {what} reply: a line over {MAX_LINE_BYTES} bytes"))
            try:
                msg = json.loads(line)
            except (ValueError, UnicodeDecodeError):
                raise BridgeError(self.failure(f"garbage {what} reply (not JSON): {line[:80]!r}")) from None
            if not isinstance(msg, dict):
                raise BridgeError(self.failure(f"garbage {what} reply (not a JSON object): {line[:80]!r}"))
            return msg

    def request(self, msg: dict, timeout: float, what: str) -> dict:
        self.send(msg)
        return self.receive(timeout, what)

    def stderr_tail(self, n: int = STDERR_TAIL_CHARS) -> str:
        try:
            self.stderr.flush()
            size = self.stderr.seek(0, os.SEEK_END)
            self.stderr.seek(max(0, size - n))
            return self.stderr.read().decode("utf-8", "replace").strip()
        except (OSError, ValueError):
            return ""

    def failure(self, message: str) -> str:
        """`message` with the tail of the planner's stderr (the process is killed first, so the
        tail is complete)."""
        self.kill()
        tail = self.stderr_tail()
        return f"{message}; planner stderr: {tail}" if tail else f"{message} (planner stderr empty)"

    def kill(self) -> None:
        """Kill the planner's process group and reap it (idempotent)."""
        if self.proc.poll() is None:
            try:
                os.killpg(self.proc.pid, signal.SIGKILL)
            except (ProcessLookupError, PermissionError):
                pass
        try:
            self.proc.wait(timeout=10)
        except subprocess.TimeoutExpired:
            pass
        for f in (self.proc.stdin, self.proc.stdout):
            if f is None:  # never: both are pipes
                continue
            try:
                f.close()
            except (OSError, ValueError):
                pass

    def close(self, timeout: float = CLOSE_TIMEOUT_S) -> dict | None:
        """Send `close`, wait for `bye` (returned, None if it never came), then kill and reap."""
        if self.closed:
            return None
        self.closed = True
        bye = None
        try:
            if self.proc.poll() is None:
                bye = self.request({"type": "close"}, timeout, "bye")
                try:
                    self.proc.wait(timeout=2.0)
                except subprocess.TimeoutExpired:
                    pass
        except BridgeError:
            bye = None
        finally:
            self.kill()
            self.stderr.close()
        return bye if bye and bye.get("type") == "bye" else None


# ---- the map the planner asked for -------------------------------------------------------------
_EXPORTS: dict[tuple[str, float, str], tuple[str, dict]] = {}  # (map file, mtime, format) -> (path, ids)
_EXPORT_DIR: list[str] = []


def export_dir() -> str:
    """This process's folder of map exports for planners (removed at exit)."""
    if not _EXPORT_DIR:
        import atexit
        import shutil

        _EXPORT_DIR.append(tempfile.mkdtemp(prefix="feat2map-bridge-"))
        atexit.register(shutil.rmtree, _EXPORT_DIR[0], True)
    return _EXPORT_DIR[0]


def export_for_planner(map_path: str, hdmap: Any, fmt: str) -> tuple[str, dict]:
    """(file in format `fmt`, {"lanes": {our lane id: the format's id}}) for a scenario's map,
    written once per process (a temporary folder removed at exit)."""
    from feat2map.formats import write_map

    key = (str(map_path), os.path.getmtime(map_path) if os.path.exists(map_path) else 0.0, fmt)
    if key in _EXPORTS and os.path.exists(_EXPORTS[key][0]):
        return _EXPORTS[key]
    export_dir()
    tag = hashlib.sha256(repr(key).encode()).hexdigest()[:12]
    out = Path(_EXPORT_DIR[0]) / tag / MAP_SUFFIX[fmt]
    out.parent.mkdir(parents=True, exist_ok=True)
    if fmt == "native" and str(map_path).endswith(".json"):
        import shutil

        shutil.copyfile(map_path, out)
    else:
        write_map(hdmap, out, fmt)
    if fmt == "commonroad":
        from feat2map.formats.commonroad import lanelet_ids

        ids = {k: int(v) for k, v in lanelet_ids(hdmap).items()}
    else:  # native and Apollo keep our lane ids; Lanelet2/OpenDRIVE: see docs/planners.md
        ids = {lid: lid for lid in hdmap.lanes} if fmt in ("native", "apollo") else {}
    _EXPORTS[key] = (str(out), {"lanes": ids})
    return _EXPORTS[key]


# ---- the policy --------------------------------------------------------------------------------
class BridgePlanner:
    """A `Policy` whose decisions come from a planner process speaking the bridge protocol.

    `cmd` starts the planner (a string split like a shell, or an argv list); `step_timeout`
    bounds each reply; `replan_s` how often it is asked (default: every decision, or what its
    hello asks for). Picklable before `reset` (the process starts at reset and ends at `close`).
    """

    action_config: ClassVar[dict] = dict(BRIDGE_ACTION_CONFIG)
    render_during_run: ClassVar[bool] = True  # failure GIFs are recorded while it drives (no replay)

    def __init__(self, cmd: str | list[str], *, step_timeout: float = STEP_TIMEOUT_S,
                 start_timeout: float = START_TIMEOUT_S, replan_s: float | None = None,
                 cwd: str | None = None) -> None:
        self.cmd = cmd
        self.step_timeout = float(step_timeout)
        self.start_timeout = float(start_timeout)
        self.replan_s = replan_s
        self.cwd = cwd
        self.__qualname__ = f"bridge: {cmd if isinstance(cmd, str) else shlex.join(cmd)}"  # the suite's planner name
        self.remote_coverage = False  # set by the rollout: ask the planner for its line coverage
        self._reset_state()

    def _reset_state(self) -> None:
        self.proc: PlannerProcess | None = None
        self.env: Any = None
        self.hello: dict = {}
        self.events: list = []
        self.junction_lines: dict[str, tuple[str, ...]] = {}
        self.planner_digest = ""
        self._next_plan = -math.inf
        self._ids: dict[int, int] = {}
        self._steps = 0
        self._stage: tuple[str, str] | None = None
        self._control = np.zeros(2, dtype=np.float32)

    def __getstate__(self) -> dict:
        return {k: self.__dict__[k] for k in ("cmd", "step_timeout", "start_timeout", "replan_s", "cwd",
                                              "__qualname__", "remote_coverage")}

    def __setstate__(self, state: dict) -> None:
        self.__dict__.update(state)
        self._reset_state()

    def __deepcopy__(self, memo: dict) -> "BridgePlanner":
        new = BridgePlanner.__new__(BridgePlanner)
        new.__setstate__(self.__getstate__())
        return new

    # ---- Policy ----------------------------------------------------------------------------
    def reset(self, env: Any) -> None:
        self.close()
        coverage = self.remote_coverage
        self._reset_state()
        self.remote_coverage = coverage
        self.env = env.unwrapped
        self.proc = PlannerProcess(self.cmd, cwd=self.cwd)
        hello = self.proc.request({"type": "hello", "protocol": PROTOCOL_VERSION}, self.start_timeout, "hello")
        self._check_hello(hello)
        self.hello = hello
        fmt = hello.get("map_format", "native")
        e = self.env
        path, ids = export_for_planner(str(e.config.get("map_file") or ""), e.net.hdmap, fmt) \
            if e.config.get("map_file") else self._export_inline(fmt)
        ready = self.proc.request(self._init_message(path, fmt, ids), self.start_timeout, "init")
        if ready.get("type") != "ready":
            raise BridgeError(self.proc.failure(f"garbage init reply: expected 'ready', got {str(ready)[:80]}"))
        if self.replan_s is None and isinstance(hello.get("replan_s"), (int, float)) and hello["replan_s"] > 0:
            self.replan_s = float(hello["replan_s"])

    def _export_inline(self, fmt: str) -> tuple[str, dict]:
        from feat2map.formats import native

        m = self.env.net.hdmap
        key = f"inline-{id(m)}"
        tmp = Path(export_dir()) / key / "source.json"
        if not tmp.exists():
            tmp.parent.mkdir(parents=True, exist_ok=True)
            native.save(m, tmp)
        return export_for_planner(str(tmp), m, fmt)

    def _check_hello(self, hello: dict) -> None:
        assert self.proc is not None  # reset started the planner
        bad = None
        if hello.get("type") != "hello":
            bad = f"expected a hello, got {str(hello)[:80]}"
        elif hello.get("protocol") != PROTOCOL_VERSION:
            bad = f"speaks protocol {hello.get('protocol')!r}, the bridge speaks {PROTOCOL_VERSION}"
        elif hello.get("map_format", "native") not in MAP_FORMATS:
            bad = f"asks for map format {hello.get('map_format')!r}; known: {', '.join(MAP_FORMATS)}"
        elif hello.get("output", "trajectory") not in OUTPUTS:
            bad = f"asks for output {hello.get('output')!r}; known: {', '.join(OUTPUTS)}"
        if bad:
            raise BridgeError(self.proc.failure(f"bad hello: {bad}"))

    def _init_message(self, path: str, fmt: str, ids: dict) -> dict:
        e = self.env
        ego = e.vehicle
        m = e.net.hdmap
        lanes = list(ego.lane_route)
        lane_ids = ids.get("lanes", {})
        last = e.net.lane_of[lanes[-1]]
        goal_s = min(float(e.config["goal_distance"]), last.length)
        gx, gy = last.position(goal_s, 0.0)
        sim_hz = float(e.config["simulation_frequency"])
        return {"type": "init", "protocol": PROTOCOL_VERSION, "map": os.path.abspath(path), "map_format": fmt,
                "ids": {"lanes": {k: v for k, v in lane_ids.items()}},
                "route": {"lanes": lanes, "lanes_in_format": [lane_ids.get(x) for x in lanes],
                          "manoeuvres": [list(x) for x in (e.config.get("route") or [])
                                         if isinstance(x, (list, tuple))],
                          "junctions": [m.lanes[x].junction_id for x in lanes if m.lanes[x].junction_id],
                          "junction_of_lane": [m.lanes[x].junction_id for x in lanes],
                          "speed_limits": [float(m.lanes[x].speed_limit) for x in lanes]},
                "goal": {"lane": lanes[-1], "lane_in_format": lane_ids.get(lanes[-1]), "s": goal_s,
                         "x": float(gx), "y": -float(gy)},
                "ego": {"length": float(ego.LENGTH), "width": float(ego.WIDTH)},
                "dt": 1.0 / float(e.config["policy_frequency"]), "sim_dt": 1.0 / sim_hz,
                "duration": float(e.config["duration"]), "coverage": bool(self.remote_coverage)}

    def act(self, obs: Any, info: dict) -> np.ndarray:
        if self.env is None or self.proc is None:
            raise RuntimeError("BridgePlanner.act before reset(env)")
        e = self.env
        t = float(e.control.t)
        ego = e.vehicle
        if t + 1e-9 >= self._next_plan:
            self._next_plan = t + (self.replan_s or 0.0)
            reply = self.proc.request(self.world(info), self.step_timeout, "step")
            self._apply(reply, t, info)
        self._steps += 1
        if getattr(ego, "tracker", None) is not None:
            return np.zeros(2, dtype=np.float32)  # the tracker commands the ego every frame
        return self._control

    def _apply(self, reply: dict, t: float, info: dict) -> None:
        from feat2map.envs.tracking import Trajectory, TrajectoryTracker

        assert self.proc is not None  # act checked that reset started the planner
        kind = reply.get("type")
        ego = self.env.vehicle
        stage = reply.get("stage")
        if isinstance(stage, str) and stage:
            self._log(stage[:40], str(reply.get("scenario") or "PLANNER")[:40], info)
        if kind == "trajectory":
            pts = reply.get("points")
            if not isinstance(pts, list) or not pts or len(pts) > MAX_TRAJECTORY_POINTS:
                raise BridgeError(self.proc.failure("garbage trajectory: 'points' must be a list of 1 to "
                                                    f"{MAX_TRAJECTORY_POINTS} points"))
            try:
                rows = [[float(p["t"]), float(p["x"]), -float(p["y"]), -float(p["heading"]), float(p["speed"])]
                        for p in pts]  # the map's frame -> the env's (y down)
                traj = Trajectory.of(rows)
            except (KeyError, TypeError, ValueError) as exc:
                raise BridgeError(self.proc.failure(f"garbage trajectory: {exc}")) from None
            control = self.env.control
            ego.tracker = TrajectoryTracker(traj, clock=lambda: float(control.t))
            self._control = np.zeros(2, dtype=np.float32)
        elif kind == "control":
            try:
                acc, steer = float(reply["acceleration"]), float(reply["steering"])
            except (KeyError, TypeError, ValueError):
                raise BridgeError(self.proc.failure(f"garbage control: {str(reply)[:80]}")) from None
            if not (math.isfinite(acc) and math.isfinite(steer)):
                raise BridgeError(self.proc.failure(f"garbage control: not finite: {str(reply)[:80]}"))
            ego.tracker = None
            (alo, ahi), (slo, shi) = BRIDGE_ACTION_CONFIG["acceleration_range"], BRIDGE_ACTION_CONFIG["steering_range"]
            self._control = np.array([2 * (np.clip(acc, alo, ahi) - alo) / (ahi - alo) - 1,
                                      2 * (np.clip(steer, slo, shi) - slo) / (shi - slo) - 1], dtype=np.float32)
        else:
            raise BridgeError(self.proc.failure(f"garbage step reply: expected 'trajectory' or 'control', "
                                                f"got {str(reply)[:80]}"))

    def _log(self, stage: str, scenario: str, info: dict) -> None:
        from .planner import StageEvent

        if self._stage == (scenario, stage):
            return
        self._stage = (scenario, stage)
        self.events.append(StageEvent(self._steps, float(self.env.control.t), info.get("junction") or None,
                                      scenario, stage))

    def stage_path(self) -> tuple[str, ...]:
        """The stages the planner reported, in order, consecutive repeats merged."""
        out: list[str] = []
        for e in self.events:
            if not out or out[-1] != e.stage:
                out.append(e.stage)
        return tuple(out)

    def close(self) -> None:
        """End the planner process (its bye may carry line coverage: `junction_lines`)."""
        proc, self.proc = self.proc, None
        if self.env is not None and getattr(self.env, "vehicle", None) is not None:
            self.env.vehicle.tracker = None
        if proc is None:
            return
        bye = proc.close()
        cov = (bye or {}).get("coverage")
        if isinstance(cov, dict) and isinstance(cov.get("lines"), dict):
            self.junction_lines = {str(j): tuple(sorted({str(x) for x in v}, key=_line_key))
                                   for j, v in cov["lines"].items() if isinstance(v, list)}
            self.planner_digest = str(cov.get("digest", ""))[:64]

    def __del__(self) -> None:
        proc = self.__dict__.get("proc")
        if proc is not None:
            proc.kill()

    # ---- the world ---------------------------------------------------------------------------
    def _vid(self, v: Any) -> int:
        return self._ids.setdefault(id(v), len(self._ids) + 1)

    def world(self, info: dict) -> dict:
        """The step message: the world as the ego's planner sees it now."""
        e = self.env
        net, m, rules = e.net, e.net.hdmap, e.control
        ego = e.vehicle
        ex, ey = float(ego.position[0]), -float(ego.position[1])  # the env's frame (y down) -> the map's
        acc = float(ego.action.get("acceleration", 0.0)) if isinstance(ego.action, dict) else 0.0
        vehicles = []
        for v in e.road.vehicles:
            if v is ego:
                continue
            x, y = float(v.position[0]), -float(v.position[1])
            if math.hypot(x - ex, y - ey) > WORLD_RADIUS_M:
                continue
            vehicles.append({"id": self._vid(v), "x": x, "y": y, "heading": -float(v.heading), "speed": float(v.speed),
                             "length": float(v.LENGTH), "width": float(v.WIDTH),
                             "lane": net.id_of.get(v.lane_index)})
        pedestrians = []
        for cw, people in getattr(rules, "pedestrians", {}).items():
            for p in people:
                x, y = float(p.position[0]), -float(p.position[1])
                if math.hypot(x - ex, y - ey) <= WORLD_RADIUS_M:
                    pedestrians.append({"id": self._vid(p), "x": x, "y": y, "heading": -float(p.heading),
                                        "speed": float(p.speed), "crosswalk": cw})
        signals = []
        for sid, sig in m.signals.items():
            plan = rules.plans.get(sid)
            signals.append({"id": sid, "junction": sig.junction_id, "lanes": list(sig.lane_ids),
                            "state": rules.signal_state(sid),
                            "time_to_change": float(plan.time_to_change(sid, rules.t)) if plan else None})
        stops = []
        for sid, ss in m.stop_signs.items():
            queue_ = rules.stop_queue.get(ss.junction_id, [])
            stops.append({"id": sid, "junction": ss.junction_id, "lanes": list(ss.lane_ids),
                          "queue": ["ego" if v is ego else self._vid(v) for v in queue_]})
        d = float(info.get("distance_to_stop_line", math.inf))
        ttc = float(info.get("signal_time_to_change", math.inf))
        return {"type": "step", "t": float(rules.t),
                "ego": {"x": ex, "y": ey, "heading": -float(ego.heading), "speed": float(ego.speed),
                        "acceleration": acc, "lane": net.id_of.get(ego.lane_index), "route_index": int(ego.route_pos)},
                "ahead": {"junction": info.get("junction") or None, "control": info.get("control_ahead") or None,
                          "stop_line_distance": d if math.isfinite(d) else None,
                          "signal": info.get("signal_id") or None, "signal_state": info.get("signal_state") or None,
                          "signal_time_to_change": ttc if math.isfinite(ttc) else None},
                "junction": info.get("junction") or None,
                "vehicles": vehicles, "pedestrians": pedestrians, "signals": signals, "stop_signs": stops}


def _line_key(s: str) -> tuple[str, int]:
    mod, _, line = s.rpartition(":")
    return mod, int(line) if line.isdigit() else 0
