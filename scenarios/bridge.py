"""The planner bridge: a planner in another process (its own venv, its own Python) drives the
ego of a scenario env through JSON lines over its stdin/stdout (protocol: docs/planners.md).

    hello  ->  hello (protocol version, the map format it wants, trajectory or control output)
    init   ->  ready (map file in that format + id mapping, the route, the goal, the clock)
    step   ->  trajectory | control (the world each decision: ego, vehicles, pedestrians,
               signals with time to change, stop signs with their queues)
    close  ->  bye (optionally the planner's line coverage per junction)

Protocol 2: every message carries the step index ("step") and every reply echoes it, so that a
stale, doubled or early reply is caught; a planner whose hello answers 1 replies without it.

Every position, heading and trajectory is in the map's own frame (x east, y north, heading
anticlockwise from x: the frame of the native map and of every export); the bridge converts
to and from the env's (y down). A trajectory (timestamped poses and speeds) is followed every simulation frame by the env's
tracking controller (`feat2map.envs.tracking`: pure pursuit + speed P control); a control
(acceleration, steering) is held over the decision period. A planner that crashes, misses a
deadline or replies garbage raises `BridgeError` (the rollout records an `error` outcome with
its message and the tail of the planner's stderr) and every process of it is killed and the
planner reaped: never a hang, never an aborted run, whatever the planner does (`PlannerProcess`).
A planner whose hello allows it (`"prestart": true`) has its next scenario's process started
while this one drives (`prestart_planner`); each scenario still gets a fresh process.

    BridgePlanner(".venv-crplanner/bin/python adapters/commonroad/planner.py")

is a `Policy` like any other (`run_suite(suite, BridgePlanner(cmd))`, or `feat2map rollout SUITE
--planner-cmd CMD`).
"""
from __future__ import annotations

import atexit
import hashlib
import itertools
import json
import math
import os
import selectors
import shlex
import signal
import subprocess
import tempfile
import threading
import time
from collections import deque
from pathlib import Path
from typing import Any, ClassVar

import numpy as np

from feat2map.config import BLOCKED_AFTER_S

PROTOCOL_VERSION = 2  # the newest the bridge speaks; it sends it in its hello
PROTOCOLS = (1, 2)  # what a planner's hello may answer (2: every message and reply carries "step")
MAP_FORMATS = ("commonroad", "lanelet2", "opendrive", "apollo", "native")
MAP_SUFFIX = {"commonroad": "map.xml", "lanelet2": "map.osm", "opendrive": "map.xodr", "apollo": "apollo",
              "native": "map.json"}
OUTPUTS = ("trajectory", "control")
SETUP_COMMAND = "bash scripts/setup.sh"  # installs feat2map's base environment (.venv)
FORMAT_SETUP = {"commonroad": f"{SETUP_COMMAND} commonroad"}  # a format needing an extra: what installs it
START_TIMEOUT_S = 120.0  # hello and init (a planner may import heavy libraries, build its map)
STEP_TIMEOUT_S = 10.0  # each decision's reply
CLOSE_TIMEOUT_S = 30.0  # the bye (a planner may save coverage data first)
BYE_EXIT_S = 2.0  # after its bye, the planner has this long to exit before its group is killed
EXIT_POLL_S = 0.1  # while waiting for a reply, how often the bridge looks whether the planner exited
EXIT_GRACE_S = 1.0  # a planner that exited: its last output still read; one that closed stdout: its exit awaited
PLANNER_TAG_VAR = "FEAT2MAP_PLANNER_TAG"  # in the planner's environment: finds every process it started
KILL_ROUNDS = 5  # find-and-kill passes over the planner's processes (a forking one spawns between passes)
KILL_ROUND_PAUSE_S = 0.02
REAP_TIMEOUT_S = 10.0  # for a killed planner to be reaped (a process in the kernel may take a moment)
READER_JOIN_S = 1.0  # for the reader thread to end once the planner is killed
STDERR_TAIL_CHARS = 1500  # of the planner's stderr, quoted in an error outcome
MAX_LINE_BYTES = 4 << 20  # a reply longer than this is garbage (10,000 trajectory points take about 1.2 MB)
READ_CHUNK_BYTES = 1 << 16
MAX_UNASKED_REPLIES = 4  # replies beyond those asked for, read ahead, before the planner counts as flooding
MAX_NUMBER = 1e9  # a number in a reply larger than this in magnitude is garbage (metres, seconds, ids)
MAX_NUMBER_DIGITS = 20  # an integer written with more digits is garbage, before it is parsed
MAX_TRAJECTORY_POINTS = 10_000
# the likely cause of a missing hello: the planner's stdout is block-buffered (a pipe, not a terminal)
NO_HELLO_HINT = "no reply line: does the planner flush stdout after each line? (python -u)"
BRIDGE_NAME_PREFIX = "bridge: "  # a BridgePlanner's name (the suite's planner) starts with it
WORLD_RADIUS_M = 150.0  # vehicles and pedestrians this close to the ego are sent
HOLD_RULES = ("signal", "stop", "conflict", "pedestrian", "passage")  # step.ahead.hold.by names these
BRIDGE_ACTION_CONFIG: dict[str, Any] = {"type": "ContinuousAction", "longitudinal": True, "lateral": True,
                        "acceleration_range": [-8.0, 4.0], "steering_range": [-math.pi / 3, math.pi / 3]}


class BridgeError(RuntimeError):
    """The planner process failed: crashed, missed a deadline, or broke the protocol."""


def _parse_int(text: str) -> int:
    if len(text.lstrip("-")) > MAX_NUMBER_DIGITS:
        raise ValueError(f"an integer of {len(text)} digits")
    value = int(text)
    if abs(value) > MAX_NUMBER:
        raise ValueError(f"a number out of range: {text}")
    return value


def _parse_constant(text: str) -> float:
    raise ValueError(f"a non-finite number: {text}")


def parse_reply(line: bytes) -> Any:
    """A reply line as JSON, or ValueError (RecursionError from deep nesting included) for
    anything but finite numbers of at most MAX_NUMBER in magnitude."""
    try:
        return json.loads(line, parse_int=_parse_int, parse_float=_number, parse_constant=_parse_constant)
    except json.JSONDecodeError:
        raise ValueError("not JSON") from None
    except RecursionError:
        raise ValueError("nested too deep") from None
    except UnicodeDecodeError:
        raise ValueError("not UTF-8") from None


def _show(value: Any, n: int = 80) -> str:
    """At most `n` characters of a parsed reply, for a message (a deeply nested one included)."""
    try:
        return str(value)[:n]
    except RecursionError:
        return "(nested too deep)"


def _number(value: Any) -> float:
    """A reply's number as a float: finite and at most MAX_NUMBER in magnitude (a string such as
    "nan", "1e308" or JSON's "1e400" included), else ValueError."""
    x = float(value)
    if not abs(x) <= MAX_NUMBER:
        raise ValueError(f"a number out of range: {_show(value, 40)}")
    return x


def _exit_text(code: int) -> str:
    if code < 0:
        try:
            return f"was killed by {signal.Signals(-code).name}"
        except ValueError:
            return f"was killed by signal {-code}"
    return f"exited (code {code})"


def planner_processes(pid: int, tag: str, pipes: set[tuple[str, int]]) -> set[int]:
    """The live processes that belong to the planner `pid` (Linux /proc; elsewhere none): the
    members of its session; those whose environment holds PLANNER_TAG_VAR=`tag` (every process
    it started, daemons that left its session included, unless one cleared its environment);
    those holding the planner's end of one of its `pipes` ("pipe:[inode]", O_RDONLY or
    O_WRONLY); and the descendants of all of them."""
    me = os.getpid()
    try:
        names = [int(n) for n in os.listdir("/proc") if n.isdigit()]
    except OSError:
        return set()
    children: dict[int, list[int]] = {}
    found: set[int] = set()
    marker = f"{PLANNER_TAG_VAR}={tag}".encode()
    for p in names:
        if p == me:
            continue
        try:
            with open(f"/proc/{p}/stat", "rb") as f:
                stat = f.read()
            fields = stat[stat.rindex(b")") + 2:].split()
        except (OSError, ValueError):
            continue  # gone meanwhile
        if fields[0] in (b"Z", b"X"):
            continue  # dead: only its parent's reaping left
        ppid, sid = int(fields[1]), int(fields[3])
        children.setdefault(ppid, []).append(p)
        if sid == pid or _tagged(p, marker) or _holds(p, pipes):
            found.add(p)
    todo = [pid, *found]
    while todo:
        for c in children.get(todo.pop(), ()):
            if c not in found:
                found.add(c)
                todo.append(c)
    return found


def _tagged(p: int, marker: bytes) -> bool:
    """Whether process `p`'s environment holds `marker` (NAME=value)."""
    try:
        with open(f"/proc/{p}/environ", "rb") as f:
            return marker in f.read().split(b"\0")
    except OSError:
        return False  # another user's, or gone


def _holds(p: int, pipes: set[tuple[str, int]]) -> bool:
    """Whether process `p` has one of `pipes` open at the planner's end."""
    links = {link for link, _ in pipes}
    try:
        fds = os.listdir(f"/proc/{p}/fd")
    except OSError:
        return False
    for fd in fds:
        try:
            link = os.readlink(f"/proc/{p}/fd/{fd}")
            if link not in links:
                continue
            with open(f"/proc/{p}/fdinfo/{fd}") as f:
                flags = next(int(x.split()[1], 8) for x in f if x.startswith("flags:"))
        except (OSError, StopIteration, ValueError, IndexError):
            continue
        if (link, flags & os.O_ACCMODE) in pipes:
            return True
    return False


_TAGS = itertools.count()
_LIVE: dict[int, "PlannerProcess"] = {}  # the planners started and not killed yet (by id), for kill_planners


def kill_planners() -> None:
    """SIGKILL every planner this process started and has not killed yet, with every process of
    theirs, for a process that must end now (a rollout worker SIGTERMed or orphaned). Signals
    only: it closes nothing, reaps nothing, waits on no lock and no planner, so a signal handler
    or another thread may call it while the main thread is anywhere in the bridge."""
    for proc in tuple(_LIVE.values()):
        proc.signal_processes()


class PlannerProcess:
    """One planner child process: JSON lines in and out, stderr to a file, a deadline on every
    message and reply, read-ahead bounded, every process it started killed and itself reaped
    on close.

    The planner starts in its own session, with PLANNER_TAG_VAR in its environment. `kill`
    SIGKILLs, in rounds, its process group and every process `planner_processes` finds,
    whatever the planner itself did (exited, closed stdout, forked, left its session). Only a
    process that left the session, cleared its environment, closed the planner's pipes and
    lost its parent escapes: it may outlive the scenario, but it cannot block the rollout (the
    bridge waits on no pipe without a deadline, and `kill` ends the reader thread)."""

    def __init__(self, cmd: str | list[str], cwd: str | None = None, env: dict | None = None) -> None:
        argv = shlex.split(cmd) if isinstance(cmd, str) else list(cmd)
        if not argv:
            raise BridgeError("empty planner command")
        self.argv = argv
        self.stderr = tempfile.TemporaryFile()
        self.tag = f"{os.getpid()}-{next(_TAGS)}-{time.time_ns()}"
        env = {**(os.environ if env is None else env), PLANNER_TAG_VAR: self.tag}
        # a Python planner's print() reaches the pipe at once, flushed or not (its env may say otherwise)
        env.setdefault("PYTHONUNBUFFERED", "1")
        try:
            self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self.stderr,
                                         cwd=cwd, env=env, start_new_session=True)
        except OSError as exc:
            self.stderr.close()
            raise BridgeError(f"cannot start the planner {argv[0]!r}: {exc.strerror or exc}") from None
        _LIVE[id(self)] = self
        assert self.proc.stdin is not None and self.proc.stdout is not None  # Popen(stdin=PIPE, stdout=PIPE)
        self._in = self.proc.stdin.fileno()
        os.set_blocking(self._in, False)
        self._writable = selectors.DefaultSelector()
        self._writable.register(self._in, selectors.EVENT_WRITE)
        self._pipes = {(f"pipe:[{os.fstat(self._in).st_ino}]", os.O_RDONLY),
                       (f"pipe:[{os.fstat(self.proc.stdout.fileno()).st_ino}]", os.O_WRONLY)}
        self.step = 0  # the step index of the next message (protocol 2): the step messages sent so far
        self.transcript: list[dict] | None = None  # when a list: every message and reply, for a recording
        self.tail = ""  # the stderr tail, kept by `end`
        self.environ = dict(os.environ)  # the environment it started in (a spare is used only in the same)
        self.protocol: int | None = None  # the version the planner's hello answered
        self._cv = threading.Condition()
        self._lines: deque[bytes] = deque()
        self._asked = 0  # messages sent (each asks for one reply)
        self._received = 0  # non-blank lines read
        self._read_end: str | None = None  # why reading stopped: "eof", "overlong", "flood", "killed"
        self._wake_r, self._wake_w = os.pipe()  # closing the write end ends the reader thread
        self._killed = False
        self.closed = False
        self._end_lock = threading.Lock()
        self._ended = False
        self._ender: threading.Thread | None = None  # close(wait=False)'s
        self.reader = threading.Thread(target=self._read, daemon=True)
        self.reader.start()

    # ---- the reader thread ----------------------------------------------------------------
    def _read(self) -> None:
        out = self.proc.stdout
        assert out is not None  # Popen(stdout=PIPE)
        sel = selectors.DefaultSelector()
        try:
            sel.register(out.fileno(), selectors.EVENT_READ)
            sel.register(self._wake_r, selectors.EVENT_READ)
            end = self._read_lines(out.fileno(), sel)
            with self._cv:  # why, before the pipe closes: a write that breaks after it finds the cause
                self._read_end = end
                self._cv.notify_all()
        finally:
            sel.close()
            out.close()  # only this thread reads it: closing never waits on a read in progress
            os.close(self._wake_r)

    def _read_lines(self, fd: int, sel: selectors.BaseSelector) -> str:
        """Queue the planner's lines until its output ends ("eof"), a line exceeds
        MAX_LINE_BYTES ("overlong"), it sends more than MAX_UNASKED_REPLIES replies nobody asked
        for ("flood") or `kill` wakes this thread ("killed")."""
        buf = bytearray()
        while True:
            if any(key.fd == self._wake_r for key, _ in sel.select()):
                return "killed"
            try:
                chunk = os.read(fd, READ_CHUNK_BYTES)
            except OSError:
                chunk = b""
            if not chunk:
                return "eof" if self._queue(bytes(buf)) else "flood"
            if b"\n" not in chunk:
                buf += chunk
                if len(buf) > MAX_LINE_BYTES:
                    return "overlong"
                continue
            first, *middle, rest = chunk.split(b"\n")
            buf += first
            for line in (bytes(buf), *middle):
                if len(line) > MAX_LINE_BYTES:
                    return "overlong"
                if not self._queue(line):
                    return "flood"
            buf = bytearray(rest)

    def _queue(self, line: bytes) -> bool:
        """Queue a line (blank lines are dropped); False once the planner floods."""
        if not line.strip():
            return True
        with self._cv:
            self._lines.append(line)
            self._received += 1
            self._cv.notify_all()
            return self._received - self._asked <= MAX_UNASKED_REPLIES

    # ---- messages -------------------------------------------------------------------------
    def request(self, msg: dict, timeout: float, what: str) -> dict:
        """Send `msg` (with the current step index) and return its reply, both within `timeout`
        seconds; a step message moves the step index on."""
        deadline = time.monotonic() + timeout
        self.send({**msg, "step": self.step}, deadline, what)
        reply = self.receive(timeout, what, deadline)
        if msg.get("type") == "step":
            self.step += 1
        return reply

    def send(self, msg: dict, deadline: float, what: str) -> None:
        """Write `msg` by `deadline` (the planner's stdin is non-blocking: a planner that does
        not read it is a timeout, never a hang)."""
        data = memoryview((json.dumps(msg, separators=(",", ":"), allow_nan=False) + "\n").encode())
        if self.transcript is not None:
            self.transcript.append({"dir": "to_planner", "wall": time.time(), "message": msg})
        with self._cv:
            self._asked += 1
        size = len(data)
        while data:
            try:
                data = data[os.write(self._in, data):]
                continue
            except BlockingIOError:
                pass
            except OSError:  # BrokenPipeError: nobody reads the pipe any more (maybe as it flooded us: say that)
                raise BridgeError(self.failure(self._output_fault(what) or self._gone(f"before its {what} reply",
                                                                                      "closed its stdin"))) from None
            left = deadline - time.monotonic()
            if left <= 0:
                raise BridgeError(self.failure(
                    f"planner timeout: the planner does not read its stdin ({len(data)} of {size} bytes of the "
                    f"{msg.get('type')} message unsent by the deadline)"))
            self._writable.select(left)

    def receive(self, timeout: float, what: str, deadline: float | None = None) -> dict:
        """The next reply (a JSON object, checked against the step index), or BridgeError by
        `deadline` (default: `timeout` seconds from now)."""
        deadline = time.monotonic() + timeout if deadline is None else deadline
        line = self._next_line(deadline, timeout, what)
        try:
            msg = parse_reply(line)
            if self.transcript is not None:
                self.transcript.append({"dir": "from_planner", "wall": time.time(), "message": msg})
        except ValueError as exc:
            if self.transcript is not None:
                self.transcript.append({"dir": "from_planner", "wall": time.time(),
                                        "line": line.decode("utf-8", "replace")})
            raise BridgeError(self.failure(f"garbage {what} reply ({exc}): {line[:80]!r}")) from None
        if not isinstance(msg, dict):
            raise BridgeError(self.failure(f"garbage {what} reply (not a JSON object): {line[:80]!r}"))
        if "step" in msg:
            if type(msg["step"]) is not int or msg["step"] != self.step:
                raise BridgeError(self.failure(f"{what} reply for step {_show(msg['step'], 20)} at step {self.step}"))
        elif (self.protocol or 1) >= 2:
            raise BridgeError(self.failure(f"{what} reply without its 'step' (protocol {self.protocol} echoes it)"))
        return msg

    def _output_fault(self, what: str) -> str | None:
        """Why reading stopped when the planner's output was at fault (a flood of replies nobody
        asked for, an overlong line), else None."""
        with self._cv:
            if self._read_end == "flood":
                return f"the planner sent {self._received - self._asked} replies without being asked (at its {what} reply)"
            if self._read_end == "overlong":
                return f"garbage {what} reply: a line over {MAX_LINE_BYTES} bytes"
        return None

    def _next_line(self, deadline: float, timeout: float, what: str) -> bytes:
        exited_at: float | None = None
        while True:
            with self._cv:
                if self._read_end == "flood" or (self._read_end == "overlong" and not self._lines):
                    message = self._output_fault(what) or ""
                    break
                if self._lines:
                    return self._lines.popleft()
                if self._read_end is not None:  # end of output
                    message = self._gone(f"before its {what} reply", "closed its stdout while still running,")
                    break
                now = time.monotonic()
                if exited_at is not None and now - exited_at > EXIT_GRACE_S:  # a child holds its stdout
                    message = self._gone(f"before its {what} reply; a process it started holds its stdout", "")
                    break
                if now >= deadline:
                    hint = f": {NO_HELLO_HINT}" if what == "hello" else ""
                    message = f"planner timeout: no {what} reply within {timeout:g} s{hint}"
                    break
                news = self._cv.wait(min(deadline - now, EXIT_POLL_S))
            if not news and exited_at is None and self.exit_code() is not None:  # quiet: did it exit?
                exited_at = time.monotonic()
        raise BridgeError(self.failure(message))

    def exit_code(self) -> int | None:
        """The planner's exit status (negative: the signal) once it exited, else None; it is
        left unreaped until `kill`, so its process group id stays its own."""
        if self.proc.returncode is not None:
            return self.proc.returncode
        try:
            info = os.waitid(os.P_PID, self.proc.pid, os.WEXITED | os.WNOHANG | os.WNOWAIT)
        except ChildProcessError:
            return self.proc.poll()
        if info is None:
            return None
        return info.si_status if info.si_code == os.CLD_EXITED else -info.si_status

    def _gone(self, when: str, running: str) -> str:
        """What the planner did: exited (with its code, awaited EXIT_GRACE_S) or `running`."""
        code = self.wait_exit(EXIT_GRACE_S)
        return f"the planner {_exit_text(code) if code is not None else running} {when}"

    def wait_exit(self, seconds: float) -> int | None:
        """The planner's exit code once it exits within `seconds` (None if it does not), polled
        from 1 ms up to 10 ms apart (a planner exits a few ms after its bye), never reaped here."""
        stop, pause = time.monotonic() + seconds, 0.001
        while (code := self.exit_code()) is None and time.monotonic() < stop:
            time.sleep(pause)
            pause = min(2 * pause, 0.01)
        return code

    # ---- the end ---------------------------------------------------------------------------
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
        """Kill the planner and every process of it that /proc shows (see the class), reap it,
        close the bridge's pipe ends and end the reader thread (idempotent; never waits on the
        planner beyond REAP_TIMEOUT_S and READER_JOIN_S)."""
        if self._killed:
            return
        self._killed = True
        self.signal_processes()
        _LIVE.pop(id(self), None)
        try:
            self.proc.wait(timeout=REAP_TIMEOUT_S)
        except subprocess.TimeoutExpired:
            pass
        self._writable.close()
        try:
            assert self.proc.stdin is not None  # Popen(stdin=PIPE)
            self.proc.stdin.close()  # nothing buffered: every write went straight to the pipe
        except OSError:
            pass
        os.close(self._wake_w)  # the reader thread ends and closes stdout
        self.reader.join(READER_JOIN_S)

    def signal_processes(self) -> None:
        """SIGKILL, in rounds, the planner's process group and every process `planner_processes`
        finds; only signals (`kill` does the rest: reaping, pipes, the reader thread)."""
        for _ in range(KILL_ROUNDS):
            pids = planner_processes(self.proc.pid, self.tag, self._pipes)
            for pgid_or_pid, kill in ((self.proc.pid, os.killpg), *((p, os.kill) for p in pids)):
                try:
                    kill(pgid_or_pid, signal.SIGKILL)
                except (ProcessLookupError, PermissionError):
                    pass
            if not pids:
                break
            time.sleep(KILL_ROUND_PAUSE_S)

    def close(self, timeout: float = CLOSE_TIMEOUT_S, wait: bool = True) -> dict | None:
        """Send `close` and wait for `bye` (returned, None if it never came); then `end` the
        planner: now, or (`wait` False) in a background thread while the caller goes on (a
        planner takes a few ms to exit after its bye; `end` waits for that thread)."""
        if self.closed:
            return None
        self.closed = True
        bye = None
        try:
            if self.exit_code() is None and not self._killed:
                bye = self.request({"type": "close"}, timeout, "bye")
        except BridgeError:
            bye = None
        if wait:
            self.end()
        else:
            _ENDING[id(self)] = self
            self._ender = threading.Thread(target=self.end, name="feat2map-planner-end", daemon=True)
            self._ender.start()
        return bye if bye and bye.get("type") == "bye" else None

    def end(self, grace: float = BYE_EXIT_S) -> str:
        """Give the planner `grace` seconds to exit, kill and reap it (`kill`) and keep its stderr
        tail (returned); once, whichever thread asks first (the others wait for it)."""
        with self._end_lock:
            if not self._ended:
                try:
                    if not self._killed and grace > 0:
                        self.wait_exit(grace)
                finally:
                    self.kill()
                    self.tail = self.stderr_tail()
                    self.stderr.close()
                    self._ended = True
                    _ENDING.pop(id(self), None)
        return self.tail

    def discard(self) -> None:
        """Kill the planner now, without a `close` (an unused spare; a replay that sent the
        recorded one), and free its stderr file."""
        self.closed = True
        self.end(grace=0.0)


_SPARES: dict[tuple, PlannerProcess] = {}  # (argv, cwd) -> a started planner nobody has spoken to yet
_ENDING: dict[int, PlannerProcess] = {}  # planners said bye, being ended in the background (by id)


def _planner_key(cmd: str | list[str], cwd: str | None) -> tuple:
    return tuple(shlex.split(cmd) if isinstance(cmd, str) else cmd), cwd


def start_planner(cmd: str | list[str], cwd: str | None = None) -> PlannerProcess:
    """A started planner process for one scenario: the spare `prestart_planner` started for this
    command, if it is still running and this process's environment is the one it started with
    (else it is discarded), or a new one."""
    key = _planner_key(cmd, cwd)
    spare = _SPARES.pop(key, None)
    if spare is not None:
        if spare.exit_code() is None and spare.environ == os.environ:
            return spare
        spare.discard()
    return PlannerProcess(list(key[0]), cwd=cwd)


def prestart_planner(cmd: str | list[str], cwd: str | None = None) -> None:
    """Start the next scenario's planner now, while this one drives, so that its start-up (an
    interpreter, its imports: 40 ms for the reference planner, seconds for heavy ones) runs on
    another core instead of in the next reset; for a planner whose hello says `"prestart": true`
    (two of its processes may run at once and an unused start harms nothing), one spare per
    command. Every scenario still gets a fresh process; the spare left over is killed at the end
    of a suite (`discard_spares`), at exit, or on a signal (`kill_planners`)."""
    key = _planner_key(cmd, cwd)
    if key in _SPARES:
        return
    try:
        _SPARES[key] = PlannerProcess(list(key[0]), cwd=cwd)
    except BridgeError:
        pass  # the next reset starts it again and reports why it cannot


def discard_spares() -> None:
    """Kill the spares `prestart_planner` started (a suite that ran in this process is over)."""
    while _SPARES:
        _SPARES.popitem()[1].discard()


def _end_planners() -> None:
    """At exit: discard the spares and finish ending the planners that said bye."""
    discard_spares()
    for proc in tuple(_ENDING.values()):
        proc.end()


atexit.register(_end_planners)


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


def map_format_problem(fmt: str) -> str:
    """Why this environment cannot write map format `fmt` for a planner ("" when it can): its
    writer does not import, or the package it needs is missing (CommonRoad: commonroad-io)."""
    from feat2map.errors import Feat2MapError
    from feat2map.formats import FORMATS

    try:
        FORMATS[fmt].face("write")
        if fmt == "commonroad":
            from feat2map.formats.commonroad import writer

            writer.commonroad_io()
    except Feat2MapError as exc:
        return exc.message
    except ImportError as exc:
        return f"{type(exc).__name__}: {exc}"
    return ""


# ---- the policy --------------------------------------------------------------------------------
class BridgePlanner:
    """A `Policy` whose decisions come from a planner process speaking the bridge protocol.

    `cmd` starts the planner (a string split like a shell, or an argv list); `step_timeout`
    bounds each step message and its reply, `start_timeout` the hello's and init's,
    `close_timeout` the bye's; `replan_s` how often it is asked (default: every decision, or what its
    hello asks for); `record` a folder that keeps each scenario's session (`bridge_record`).
    Picklable before `reset` (the process starts at reset and ends at `close`).
    """

    action_config: ClassVar[dict] = dict(BRIDGE_ACTION_CONFIG)
    render_during_run: ClassVar[bool] = True  # failure GIFs are recorded while it drives (no replay)

    def __init__(self, cmd: str | list[str], *, step_timeout: float = STEP_TIMEOUT_S,
                 start_timeout: float = START_TIMEOUT_S, close_timeout: float = CLOSE_TIMEOUT_S,
                 replan_s: float | None = None, cwd: str | None = None, record: str | None = None) -> None:
        self.cmd = cmd
        self.record = record  # a folder: each scenario's messages and map file kept in record/<scenario>
        self.step_timeout = float(step_timeout)
        self.start_timeout = float(start_timeout)
        self.close_timeout = float(close_timeout)
        self.replan_s = replan_s
        self.cwd = cwd
        self.__qualname__ = f"{BRIDGE_NAME_PREFIX}{cmd if isinstance(cmd, str) else shlex.join(cmd)}"  # the suite's planner name
        self.remote_coverage = False  # set by the rollout: ask the planner for its line coverage
        self.blocked_after = BLOCKED_AFTER_S  # set by the rollout: its blocked early end, told the planner
        self.scenario_name = "scenario"  # set by the rollout: names the recording's folder
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
        self._map_path = ""  # the map file the planner got
        self._closed: PlannerProcess | None = None  # the last planner closed (it ends in the background)

    def __getstate__(self) -> dict:
        return {k: self.__dict__[k] for k in ("cmd", "step_timeout", "start_timeout", "close_timeout", "replan_s", "cwd",
                                              "__qualname__", "remote_coverage", "blocked_after", "record", "scenario_name")}

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
        self._reset_state()
        self.env = env.unwrapped
        self.proc = start_planner(self.cmd, cwd=self.cwd)
        if self.record:
            self.proc.transcript = []
        hello = self.proc.request({"type": "hello", "protocol": PROTOCOL_VERSION}, self.start_timeout, "hello")
        self._check_hello(hello)
        self.hello = hello
        self.proc.protocol = hello["protocol"]
        fmt = hello.get("map_format", "native")
        e = self.env
        path, ids = export_for_planner(str(e.config.get("map_file") or ""), e.net.hdmap, fmt) \
            if e.config.get("map_file") else self._export_inline(fmt)
        self._map_path = path
        ready = self.proc.request(self._init_message(path, fmt, ids), self.start_timeout, "init")
        if ready.get("type") != "ready":
            raise BridgeError(self.proc.failure(f"garbage init reply: expected 'ready', got {_show(ready)}"))
        if self.replan_s is None and isinstance(hello.get("replan_s"), (int, float)) and hello["replan_s"] > 0:
            self.replan_s = float(hello["replan_s"])
        if hello.get("prestart") is True:  # it may start while another scenario runs: the next one's spare
            prestart_planner(self.cmd, cwd=self.cwd)

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
            bad = f"expected a hello, got {_show(hello)}"
        elif hello.get("protocol") not in PROTOCOLS or type(hello.get("protocol")) is not int:
            bad = (f"speaks protocol {_show(hello.get('protocol'), 20)}, the bridge speaks "
                   f"{' and '.join(map(str, PROTOCOLS))}")
        elif hello.get("map_format", "native") not in MAP_FORMATS:
            bad = f"asks for map format {_show(hello.get('map_format'), 40)}; known: {', '.join(MAP_FORMATS)}"
        elif problem := map_format_problem(hello.get("map_format", "native")):
            fmt = hello.get("map_format", "native")
            bad = (f"asks for map format {fmt}, which this environment cannot write ({problem}); install it "
                   f"with `{FORMAT_SETUP.get(fmt, SETUP_COMMAND)}`")
        elif hello.get("output", "trajectory") not in OUTPUTS:
            bad = f"asks for output {_show(hello.get('output'), 40)}; known: {', '.join(OUTPUTS)}"
        if bad:
            raise BridgeError(self.proc.failure(f"bad hello: {bad}"))

    def _init_message(self, path: str, fmt: str, ids: dict) -> dict:
        from feat2map.envs.rules import compliance_rules

        e = self.env
        ego = e.vehicle
        m = e.net.hdmap
        lanes = list(ego.lane_route)
        lane_ids = ids.get("lanes", {})
        last = e.net.lane_of[lanes[-1]]
        goal_s = e.goal_s(last)  # where the env's route completes (not past the lane's first tight bend)
        gx, gy = last.position(goal_s, 0.0)
        sim_hz = float(e.config["simulation_frequency"])
        return {"type": "init", "protocol": self.hello["protocol"], "map": os.path.abspath(path), "map_format": fmt,
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
                "vehicle": self.vehicle_model(), "stop_lines": self.route_stop_lines(lane_ids),
                "rules": compliance_rules(e.control.right_turn_on_red(), self.blocked_after),
                "dt": 1.0 / float(e.config["policy_frequency"]), "sim_dt": 1.0 / sim_hz,
                "duration": float(e.config["duration"]), "coverage": bool(self.remote_coverage)}

    def vehicle_model(self) -> dict:
        """The ego's motion model (`vehicle_model`: the env's own vehicle and action limits) and
        how the env's tracker follows a trajectory (`tracking_model`)."""
        from feat2map.envs.tracking import tracking_model
        from feat2map.envs.vehicles import vehicle_model

        e = self.env
        act, ego = e.action_type, e.vehicle
        return {**vehicle_model(ego, act.acceleration_range, act.steering_range), "tracker": tracking_model(ego.model)}

    def route_stop_lines(self, lane_ids: dict) -> list[dict]:
        """The stop lines on the ego's route (`MapNetwork.stop_lines` of its route lanes), in route
        order, in the map's frame."""
        net = self.env.net
        out = []
        for k, lid in enumerate(self.env.vehicle.lane_route):
            sl = net.stop_lines.get(lid)
            if sl is None:
                continue
            lane = net.lane_of[lid]
            x, y = lane.position(sl.s, 0.0)
            out.append({"junction": sl.junction_id, "kind": sl.kind, "control": sl.control_id, "lane": lid,
                        "lane_in_format": lane_ids.get(lid), "route_index": k, "s": float(sl.s),
                        "x": float(x), "y": -float(y), "heading": -float(lane.heading_at(sl.s))})
        return out

    def act(self, obs: Any, info: dict) -> np.ndarray:
        if self.env is None or self.proc is None:
            raise RuntimeError("BridgePlanner.act before reset(env)")
        e = self.env
        t = float(e.control.t)
        ego = e.vehicle
        self._claim()
        if t + 1e-9 >= self._next_plan:
            self._next_plan = t + (self.replan_s or 0.0)
            reply = self.proc.request(self.world(info), self.step_timeout, "step")
            self._apply(reply, t, info)
        self._steps += 1
        if getattr(ego, "tracker", None) is not None:
            return np.zeros(2, dtype=np.float32)  # the tracker commands the ego every frame
        return self._control

    def _claim(self) -> None:
        """The ego reserves its junction lanes as a traffic car in its place would (within its
        commit distance of the line and let go by every rule: `EgoTask.claim`), so that traffic
        gives way to it as to each other (docs/planners.md, *Right of way*). Without it a planner
        that went on a green at the line lost the junction to a car that reserved a conflicting
        lane a moment later (M2's m2-r005)."""
        self.env.claim()

    def _apply(self, reply: dict, t: float, info: dict) -> None:
        from feat2map.envs.tracking import Trajectory, TrajectoryTracker

        assert self.proc is not None  # act checked that reset started the planner
        kind = reply.get("type")
        ego = self.env.vehicle
        stage = reply.get("stage")
        if isinstance(stage, str) and stage:
            self._log(stage[:40], _show(reply.get("scenario") or "PLANNER", 40), info)
        if kind == "trajectory":
            pts = reply.get("points")
            if not isinstance(pts, list) or not pts or len(pts) > MAX_TRAJECTORY_POINTS:
                raise BridgeError(self.proc.failure("garbage trajectory: 'points' must be a list of 1 to "
                                                    f"{MAX_TRAJECTORY_POINTS} points"))
            try:
                rows = [[_number(p["t"]), _number(p["x"]), -_number(p["y"]), -_number(p["heading"]), _number(p["speed"])]
                        for p in pts]  # the map's frame -> the env's (y down)
                traj = Trajectory.of(rows)
            except (KeyError, TypeError, ValueError) as exc:
                raise BridgeError(self.proc.failure(f"garbage trajectory: {exc}")) from None
            control = self.env.control
            ego.tracker = TrajectoryTracker(traj, clock=lambda: float(control.t), model=ego.model)
            self._control = np.zeros(2, dtype=np.float32)
        elif kind == "control":
            try:
                acc, steer = _number(reply["acceleration"]), _number(reply["steering"])
            except (KeyError, TypeError, ValueError):
                raise BridgeError(self.proc.failure(f"garbage control: {_show(reply)}")) from None
            ego.tracker = None
            (alo, ahi), (slo, shi) = BRIDGE_ACTION_CONFIG["acceleration_range"], BRIDGE_ACTION_CONFIG["steering_range"]
            self._control = np.array([2 * (np.clip(acc, alo, ahi) - alo) / (ahi - alo) - 1,
                                      2 * (np.clip(steer, slo, shi) - slo) / (shi - slo) - 1], dtype=np.float32)
        else:
            raise BridgeError(self.proc.failure(f"garbage step reply: expected 'trajectory' or 'control', "
                                                f"got {_show(reply)}"))

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
        bye = proc.close(self.close_timeout, wait=False)
        self._closed = proc
        if self.record and proc.transcript:
            from .bridge_record import recording_folder, save_recording

            save_recording(recording_folder(self.record, self.scenario_name), proc.transcript, self._map_path,
                           shlex.join(proc.argv))
        cov = (bye or {}).get("coverage")
        if isinstance(cov, dict) and isinstance(cov.get("lines"), dict):
            self.junction_lines = {str(j): tuple(sorted({str(x) for x in v}, key=_line_key))
                                   for j, v in cov["lines"].items() if isinstance(v, list)}
            self.planner_digest = str(cov.get("digest", ""))[:64]

    @property
    def stderr_tail(self) -> str:
        """The tail of the last planner's stderr once it ended (the rollout reports it for a
        failed scenario); "" before any closed."""
        return self._closed.end() if self._closed is not None else ""

    def __del__(self) -> None:
        proc = self.__dict__.get("proc")
        if proc is not None:
            proc.kill()

    # ---- the world ---------------------------------------------------------------------------
    def _vid(self, v: Any) -> int:
        return self._ids.setdefault(id(v), len(self._ids) + 1)

    def world(self, info: dict) -> dict:
        """The step message: the world as the ego's planner sees it now."""
        from feat2map.envs.vehicles import bicycle_state

        e = self.env
        net, m, rules = e.net, e.net.hdmap, e.control
        ego = e.vehicle
        ex, ey = float(ego.position[0]), -float(ego.position[1])  # the env's frame (y down) -> the map's
        steering, yaw_rate, acc = bicycle_state(ego)
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
            signals.append({"id": sid, "junction": sig.junction_id, "lanes": list(sig.lane_ids),
                            "state": rules.signal_state(sid),
                            "time_to_change": rules.signal_change(sid) if sid in rules.plans else None})
        stops = []
        for sid, ss in m.stop_signs.items():
            queue_ = rules.stop_queue.get(ss.junction_id, [])
            stops.append({"id": sid, "junction": ss.junction_id, "lanes": list(ss.lane_ids),
                          "queue": ["ego" if v is ego else self._vid(v) for v in queue_]})
        d = float(info.get("distance_to_stop_line", math.inf))
        ttc = float(info.get("signal_time_to_change", math.inf))
        hold = rule_hold(rules, ego)
        return {"type": "step", "t": float(rules.t),
                "ego": {"x": ex, "y": ey, "heading": -float(ego.heading), "speed": float(ego.speed),
                        "acceleration": acc, "yaw_rate": -yaw_rate, "steering": -steering,
                        "lane": net.id_of.get(ego.lane_index), "route_index": int(ego.route_pos)},
                "ahead": {"junction": info.get("junction") or None, "control": info.get("control_ahead") or None,
                          "stop_line_distance": d if math.isfinite(d) else None,
                          "signal": info.get("signal_id") or None, "signal_state": info.get("signal_state") or None,
                          "signal_time_to_change": ttc if math.isfinite(ttc) else None, "hold": hold},
                "junction": info.get("junction") or None,
                "vehicles": vehicles, "pedestrians": pedestrians, "signals": signals, "stop_signs": stops}


def rule_hold(rules: Any, ego: Any) -> dict | None:
    """Where the env's rules would stop its own traffic in the ego's place now, and which rules
    (`HOLD_RULES`) each on its own would stop it there: `{"distance": metres from the ego's
    centre to the point its front must not pass, "by": [...]}`, or
    None when they let it go. Pure queries (`TrafficRules.stop_distance` without claiming), so
    asking changes nothing (the ego's claims are `BridgePlanner._claim`'s)."""
    with rules.road.core.asking():  # (the rules read the rows once for all these questions)
        stop = rules.stop_distance(ego)
        if not math.isfinite(stop):
            return None
        by = [r for r in HOLD_RULES
              if rules.stop_distance(ego, ignore=frozenset(HOLD_RULES) - {r}) <= stop + 0.5]
    return {"distance": float(stop), "by": by}


def _line_key(s: str) -> tuple[str, int]:
    mod, _, line = s.rpartition(":")
    return mod, int(line) if line.isdigit() else 0
