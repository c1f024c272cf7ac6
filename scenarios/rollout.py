"""Headless rollouts of scenarios with a planner under test: one `Outcome` per scenario, a
`SuiteResult` per suite, run in-process, over spawned processes, or on Ray.

Determinism: every scenario builds its own env from its own seed and a fresh planner, and
every worker runs with PYTHONHASHSEED=HASH_SEED, so the results (everything but wall-clock
times and GIF bytes) do not depend on the worker count or the backend. Scenarios that do not
complete are re-run with `render_mode="rgb_array"` to record a GIF (whatever the failure
policy), so only they pay for rendering.

A scenario whose ego stands still with nothing in its way for `blocked_after` seconds
(`BlockedClock`, default BLOCKED_AFTER_S) ends early as a `timeout` whose message says "blocked".

Nothing outlives a rollout: a worker ends, killing the planner processes it started, on SIGTERM
or once its parent is gone however it ended (`worker_pool`); a SIGTERM to the process running a
suite ends it like Ctrl-C, with the report so far and without its workers (`run_suite`).
"""
from __future__ import annotations

import contextlib
import copy
import hashlib
import importlib
import io
import inspect
import os
import pickle
import signal
import sys
import threading
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, replace
from multiprocessing import get_context
from pathlib import Path
from typing import Any, Callable, Iterable, Iterator, Mapping, NoReturn, Sequence

from feat2map.config import BLOCKED_AFTER_S, WORKER_PARENT_POLL_S
from feat2map.errors import Feat2MapError

OUTCOMES = ("completed", "collision", "off_road", "timeout", "violation", "error")  # error: planner/env raised
FAIL_POLICIES = {  # --fail-on: which outcomes make the run fail
    "any": frozenset({"collision", "off_road", "timeout", "violation", "error"}),
    "collision": frozenset({"collision", "off_road", "error"}),
    "violation": frozenset({"collision", "off_road", "violation", "error"}),
    "none": frozenset(),
}
BACKENDS = ("process", "ray")
ROAD_CONTEXT = "(road)"  # code-coverage context before the first junction is known
PARTIAL_ATTR = "feat2map_partial"  # on an exception out of a drive: the planner's stage path and stderr so far
MIXED_DIGEST = "mixed"  # SuiteResult.planner_digest when the planner's sources changed mid-run
GIF_MAX_FRAMES = 160  # failure GIFs are subsampled to at most this many frames
GIF_WIDTH_PX = 360  # and scaled down to this width
GIF_SPEEDUP = 2.0  # playback speed relative to simulated time
MAX_STEPS_SAFETY = 100_000  # guards against an env that never ends
HASH_SEED = "0"  # PYTHONHASHSEED of every worker: set iteration orders (and so which planner lines
# run) must not differ between processes; a suite therefore runs in spawned workers (even one)
# unless this process was started with the same PYTHONHASHSEED


# ---- planner specs ----------------------------------------------------------------------------
class PlannerFactory:
    """A picklable zero-argument factory of fresh planners from a spec: "baseline",
    "module:attr" or the object itself: a Policy class or a zero-argument factory (called per
    scenario), a Policy instance (deep-copied per scenario), a callable `obs -> action` or
    `(obs, info) -> action` (told apart by its signature) or an SB3 model (wrapped by `as_policy`)."""

    def __init__(self, spec: Any = "baseline") -> None:
        self.spec = spec

    @property
    def name(self) -> str:
        if isinstance(self.spec, str):
            return self.spec
        return getattr(self.spec, "__qualname__", type(self.spec).__qualname__)

    def _resolve(self) -> Any:
        spec = self.spec
        if spec is None or spec == "baseline":
            from .planner import BaselinePlanner

            return BaselinePlanner
        if not isinstance(spec, str):
            return spec
        mod_name, sep, attr = spec.partition(":")
        if not sep or not mod_name or not attr:
            raise Feat2MapError("planner must be 'baseline' or 'module:attr'", f"planner {spec!r}")
        try:
            obj: Any = importlib.import_module(mod_name)
        except ImportError as exc:
            raise Feat2MapError(f"cannot import module ({exc})", f"planner {spec!r}") from None
        for part in attr.split("."):
            if not hasattr(obj, part):
                raise Feat2MapError(f"module has no attribute {part!r}", f"planner {spec!r}")
            obj = getattr(obj, part)
        return obj

    def __call__(self) -> Any:
        obj = self._resolve()
        if isinstance(obj, type) or (not hasattr(obj, "predict") and _zero_arg_callable(obj)):
            policy = obj()  # a class or factory: a fresh planner per scenario
        elif hasattr(obj, "act") and hasattr(obj, "reset"):
            policy = copy.deepcopy(obj)
        else:
            policy = obj
        if not (hasattr(policy, "act") and hasattr(policy, "reset")):
            from .planner import as_policy

            try:
                policy = as_policy(policy)
            except TypeError as exc:
                raise Feat2MapError(str(exc), f"planner {self.name!r}") from None
        return policy


def _zero_arg_callable(obj: Any) -> bool:
    """A factory (callable without required arguments), as opposed to a policy `obs -> action`."""
    if not callable(obj) or (hasattr(obj, "act") and hasattr(obj, "reset")):
        return False
    try:
        params = inspect.signature(obj).parameters.values()
    except (TypeError, ValueError):
        return False
    return all(p.default is not p.empty or p.kind in (p.VAR_POSITIONAL, p.VAR_KEYWORD) for p in params)


def as_factory(planner: Any) -> Callable[[], Any]:
    """A zero-argument planner factory from a spec, a PlannerFactory, or a factory callable."""
    if isinstance(planner, PlannerFactory):
        return planner
    return PlannerFactory(planner)


# ---- outcome ------------------------------------------------------------------------------------
@dataclass(frozen=True)
class Outcome:
    """What happened in one scenario. Equality ignores wall-clock time and GIF bytes."""

    name: str
    outcome: str  # one of OUTCOMES
    violations: Mapping[str, int]
    sim_s: float
    steps: int
    stage_path: tuple[str, ...]
    transitions: tuple[tuple[str, str], ...]
    junctions: tuple[str, ...]  # junctions the ego drove into, in order
    route_progress: float
    events: tuple[tuple[int, float, str | None, str, str], ...] = ()  # (step, time, junction, scenario, stage)
    junction_lines: Mapping[str, tuple[str, ...]] = field(default_factory=dict)  # junction -> "module:line"
    message: str = ""
    seed: int | None = None
    map: str = ""
    planner_digest: str = ""  # of the planner sources this scenario measured (coverage on)
    planner_stderr: str = ""  # the tail of an out-of-process planner's stderr (a scenario that did not complete)
    criticality: Mapping[str, float] = field(default_factory=dict)  # scenarios/criticality.py's MEASURES
    site: Mapping[str, Any] = field(default_factory=dict)  # where it failed: junction, its feature, manoeuvre, rule
    wall_s: float = field(default=0.0, compare=False)
    cpu_s: float = field(default=0.0, compare=False)  # CPU time of the process that drove it (GIF included)
    gif: bytes | None = field(default=None, compare=False, repr=False)

    @property
    def passed(self) -> bool:
        return self.outcome == "completed"

    def fails(self, fail_on: str = "any") -> bool:
        return self.outcome in FAIL_POLICIES[fail_on]

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d.pop("gif")
        d["stage_path"] = list(self.stage_path)
        d["transitions"] = [list(t) for t in self.transitions]
        d["junctions"] = list(self.junctions)
        d["events"] = [list(e) for e in self.events]
        d["violations"] = dict(self.violations)
        d["junction_lines"] = {j: list(v) for j, v in self.junction_lines.items()}
        return d

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "outcome") -> "Outcome":
        try:
            return cls(
                name=str(d["name"]), outcome=str(d["outcome"]), violations=dict(d["violations"]),
                sim_s=float(d["sim_s"]), steps=int(d["steps"]), stage_path=tuple(d["stage_path"]),
                transitions=tuple((str(a), str(b)) for a, b in d["transitions"]),
                junctions=tuple(d["junctions"]), route_progress=float(d["route_progress"]),
                events=tuple((int(s), float(t), j, str(sc), str(st)) for s, t, j, sc, st in d.get("events", ())),
                junction_lines={str(j): tuple(v) for j, v in d.get("junction_lines", {}).items()},
                message=str(d.get("message", "")), seed=d.get("seed"), map=str(d.get("map", "")),
                planner_digest=str(d.get("planner_digest", "")), planner_stderr=str(d.get("planner_stderr", "")),
                criticality={str(k): float(v) for k, v in d.get("criticality", {}).items()},
                site=dict(d.get("site", {})), wall_s=float(d.get("wall_s", 0.0)), cpu_s=float(d.get("cpu_s", 0.0)))
        except (KeyError, TypeError, ValueError) as exc:
            raise Feat2MapError(f"malformed outcome ({exc!r})", where) from None


@dataclass(frozen=True)
class SuiteResult:
    """All outcomes of a suite, in suite order."""

    name: str
    planner: str
    outcomes: tuple[Outcome, ...]
    coverage: bool = False
    planner_digest: str = ""  # of the measured planner sources (MIXED_DIGEST if scenarios differ)
    workers: int = field(default=1, compare=False)
    backend: str = field(default="process", compare=False)
    wall_s: float = field(default=0.0, compare=False)
    stopped: str = ""  # why the run ended before every scenario ran ("" when it did not)
    scenarios: int | None = field(default=None, compare=False)  # in the suite (None: as many as outcomes)

    @property
    def sent_no_coverage(self) -> bool:
        """Line coverage was asked of a planner in its own process (the planner bridge, which
        measures itself) and none came back: its lines covered are unknown, not 0."""
        from .bridge import BRIDGE_NAME_PREFIX

        return self.coverage and self.planner.startswith(BRIDGE_NAME_PREFIX) and \
            not any(o.junction_lines for o in self.outcomes)

    def failures(self, fail_on: str = "any") -> list[Outcome]:
        return [o for o in self.outcomes if o.fails(fail_on)]

    def exit_code(self, fail_on: str = "any") -> int:
        """0 when no outcome fails under the policy and the whole suite ran, else 1."""
        return 1 if self.failures(fail_on) or self.stopped else 0

    def counts(self) -> dict[str, int]:
        return {k: sum(o.outcome == k for o in self.outcomes) for k in OUTCOMES}

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "planner": self.planner, "coverage": self.coverage,
                "planner_digest": self.planner_digest,
                "workers": self.workers, "backend": self.backend, "wall_s": self.wall_s,
                "stopped": self.stopped, "scenarios": len(self.outcomes) if self.scenarios is None else self.scenarios,
                "counts": self.counts(), "outcomes": [o.to_dict() for o in self.outcomes]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], where: str = "summary") -> "SuiteResult":
        try:
            outcomes = tuple(Outcome.from_dict(o, f"{where}: outcome {i}") for i, o in enumerate(d["outcomes"]))
            return cls(name=str(d["name"]), planner=str(d["planner"]), outcomes=outcomes,
                       coverage=bool(d.get("coverage", False)), planner_digest=str(d.get("planner_digest", "")),
                       workers=int(d.get("workers", 1)),
                       backend=str(d.get("backend", "process")), wall_s=float(d.get("wall_s", 0.0)),
                       stopped=str(d.get("stopped", "")), scenarios=int(d.get("scenarios", len(outcomes))))
        except Feat2MapError:
            raise  # an outcome's own error, naming it
        except (KeyError, TypeError, ValueError) as exc:
            raise Feat2MapError(f"malformed suite result ({exc!r})", where) from None


# ---- one scenario -------------------------------------------------------------------------------
def classify(info: Mapping[str, Any]) -> str:
    """Outcome of a finished episode from its last info (collision > off road > violation >
    completed > timeout)."""
    if info.get("collision"):
        return "collision"
    if info.get("off_road"):
        return "off_road"
    if sum(dict(info.get("violations") or {}).values()) > 0:
        return "violation"
    if info.get("route_completed"):
        return "completed"
    return "timeout"


def _when(info: Mapping[str, Any]) -> str:
    """When in the episode its last info is from, for the outcome messages."""
    return f"at t={float(info.get('time', 0.0)):.1f} s, route {100 * float(info.get('route_progress', 0.0)):.0f}%"


def _message(kind: str, info: Mapping[str, Any], first_violation: tuple[str, float, Any] | None = None) -> str:
    where = _when(info)
    if kind == "violation":
        v = ", ".join(f"{k} x{n}" for k, n in sorted(dict(info["violations"]).items()) if n)
        first = "" if first_violation is None else \
            f"; first: {first_violation[0]} at t={first_violation[1]:.1f} s at junction {first_violation[2]}"
        return f"traffic rule violation: {v}{first} (episode ended {where})"
    if kind == "collision":  # past the route's last junction there is none to name: the lane says where
        near = f"near junction {info['junction']}" if info.get("junction") else \
            f"on lane {info.get('lane_id') or '(none)'}, no junction ahead"
        return f"collision {near} ({where})"
    if kind == "off_road":
        return f"left the road on lane {info.get('lane_id')} ({where})"
    if kind == "timeout":
        return f"route not completed within the duration ({where})"
    return ""


class BlockedClock:
    """The blocked early end (CARLA leaderboard's AgentBlockedTest, less the waits the rules
    justify): `update` after every decision says when the ego has stood still (`has_stopped`)
    for `after` seconds of simulated time with nothing justifying the wait
    (`EgoJudge.wait_reason`: no red or amber signal at its next stop line, no stop-sign turn,
    conflicting traffic or pedestrian holding it, no road user close ahead). Justified seconds
    do not count (a red light, a queue) but do not reset the count either: only moving does, so
    a planner stuck before a signal line is caught over its greens."""

    def __init__(self, after: float) -> None:
        self.after = float(after)
        self.standing = 0.0  # [s] since the ego last moved
        self.blocked = 0.0  # [s] of those with nothing justifying the wait
        self._t: float | None = None  # sim time of the last update while standing

    def update(self, env: Any, info: Mapping[str, Any]) -> bool:
        """True when the episode must end as blocked (never with `after` 0)."""
        from feat2map.envs.rules import has_stopped

        t = float(info.get("time", 0.0))
        if not self.after or not has_stopped(float(info.get("speed", 0.0))):
            self.standing, self.blocked, self._t = 0.0, 0.0, None
            return False
        if self._t is not None:  # standing since the last decision
            dt = t - self._t
            self.standing += dt
            if not env.unwrapped.judge.wait_reason():
                self.blocked += dt
        self._t = t
        return self.blocked >= self.after - 1e-9

    def message(self, env: Any, info: Mapping[str, Any]) -> str:
        """Blocked where (lane, junction or the distance to the next stop line, position) and for how long."""
        net = env.unwrapped.net
        lid = str(info.get("lane_id") or "")
        lane = net.hdmap.lanes.get(lid)
        if lane is not None and lane.junction_id is not None:
            place = f"inside junction {lane.junction_id} on lane {lid}"
        else:
            place = f"on lane {lid or '?'}"
            d = float(info.get("distance_to_stop_line", float("inf")))
            line = {"signal": "signal's stop line", "stop": "stop sign's line"}.get(str(info.get("control_ahead")), "entry")
            if d < float("inf") and info.get("junction"):
                place += f", {d:.1f} m before the {line} of junction {info['junction']}"
        x, y = (float(c) for c in env.unwrapped.vehicle.position)
        return (f"blocked: stood still {self.standing:.1f} s {place} at ({x:.1f}, {y:.1f}), {self.blocked:.1f} s of "
                f"them with no red light, stop-sign turn, conflicting traffic, pedestrian or road user holding it "
                f"(ended early {_when(info)}; blocked_after {self.after:g} s)")


def _env_config(policy: Any) -> dict[str, Any]:
    config: dict[str, Any] = dict(getattr(policy, "env_config", None) or {})
    action = getattr(policy, "action_config", None)
    if action:
        config["action"] = dict(action)
    return config


def _events(policy: Any) -> tuple[tuple[int, float, str | None, str, str], ...]:
    out = []
    for e in getattr(policy, "events", None) or ():
        out.append((int(e.step), round(float(e.time), 6), None if e.junction is None else str(e.junction),
                    str(e.scenario), str(e.stage)))
    return tuple(out)


def stage_path_of(events: Sequence[tuple]) -> tuple[str, ...]:
    """"Scenario.Stage" names in order, consecutive repeats merged."""
    path: list[str] = []
    for e in events:
        name = f"{e[3]}.{e[4]}"
        if not path or path[-1] != name:
            path.append(name)
    return tuple(path)


def _module_files(policy: Any, extra: Iterable[str] = ()) -> dict[str, str]:
    """{source file: module name} of the planner's own module(s) measured for line coverage."""
    names = [type(policy).__module__, *getattr(policy, "coverage_modules", ()), *extra]
    files: dict[str, str] = {}
    for name in dict.fromkeys(names):
        mod = sys.modules.get(name) or importlib.import_module(name)
        try:
            src = inspect.getsourcefile(mod)
        except TypeError:
            src = None
        if src:
            files[os.path.realpath(src)] = name
    return files


def _digest(files: Mapping[str, str]) -> str:
    """sha256 (hex, 16 digits) of the planner's measured source files {path: module}."""
    h = hashlib.sha256()
    for path, mod in sorted(files.items(), key=lambda kv: kv[1]):
        h.update(mod.encode() + b"\0" + Path(path).read_bytes() + b"\0")
    return h.hexdigest()[:16]


def suite_digest(outcomes: Iterable[Outcome]) -> str:
    """The planner digest all measured scenarios share, or MIXED_DIGEST when the planner's
    sources changed during the run (its line numbers then do not compare)."""
    digests = {o.planner_digest for o in outcomes if o.planner_digest}
    return digests.pop() if len(digests) == 1 else (MIXED_DIGEST if digests else "")


class _LineCoverage:
    """coverage.py measurement of the planner's modules, with one dynamic context per junction."""

    def __init__(self, files: Mapping[str, str]) -> None:
        import coverage

        self.files = dict(files)
        self.digest = _digest(self.files)
        self.cov = coverage.Coverage(data_file=None, config_file=False, branch=False,
                                     include=list(self.files))
        self.cov.set_option("run:disable_warnings", ["no-data-collected", "module-not-measured",
                                                     "already-imported", "couldnt-parse"])
        self.context: str | None = None

    def start(self) -> None:
        self.cov.start()

    def switch(self, context: str) -> None:
        if context != self.context:
            self.context = context
            self.cov.switch_context(context)

    def stop(self) -> dict[str, tuple[str, ...]]:
        self.cov.stop()
        data = self.cov.get_data()
        by_ctx: dict[str, set[str]] = {}
        for fname in data.measured_files():
            mod = self.files.get(os.path.realpath(fname))
            if mod is None:
                continue
            for line, contexts in data.contexts_by_lineno(fname).items():
                for ctx in contexts:
                    if ctx:
                        by_ctx.setdefault(ctx, set()).add(f"{mod}:{line}")
        return {c: tuple(sorted(v, key=_line_key)) for c, v in sorted(by_ctx.items())}


def _line_key(s: str) -> tuple[str, int]:
    mod, _, line = s.rpartition(":")
    return mod, int(line)


class _Frames(list):
    """Rendered frames, thinned as they come: past 2 x GIF_MAX_FRAMES every other one is
    dropped and the stride doubles, so a long episode keeps at most that many in memory."""

    def __init__(self) -> None:
        super().__init__()
        self.stride, self.seen = 1, 0
        self.step_s = 1.0  # simulated seconds per frame before thinning (set by _drive)

    def add(self, frame: Any) -> None:
        self.last = frame
        if self.seen % self.stride == 0:
            self.append(frame)
            if len(self) > 2 * GIF_MAX_FRAMES:
                del self[1::2]
                self.stride *= 2
        self.seen += 1

    def with_last(self) -> list:
        """The kept frames and the episode's last one."""
        last = getattr(self, "last", None)
        return list(self) + ([last] if self and last is not None and last is not self[-1] else [])


def _drive(scenario: Any, factory: Callable[[], Any], *, render: bool = False, coverage: bool = False,
           coverage_modules: Sequence[str] = (), policy: Any = None,
           blocked_after: float = BLOCKED_AFTER_S, frames: _Frames | None = None) -> tuple[Outcome, _Frames]:
    """Run one episode; returns its outcome and (when rendering) its frames, collected into
    `frames` when given (the caller keeps them if the planner raises). It ends early as blocked
    (`BlockedClock`) after `blocked_after` seconds (0: never)."""
    from .criticality import CriticalityMeter
    from .scenario import make_env

    t0 = time.perf_counter()
    if render:
        os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    policy = factory() if policy is None else policy
    remote = hasattr(policy, "remote_coverage")  # an out-of-process planner measures itself (planner bridge)
    if remote:
        policy.remote_coverage = coverage
        policy.blocked_after = blocked_after
        policy.scenario_name = str(getattr(scenario, "name", "scenario"))
    env = make_env(scenario, render_mode="rgb_array" if render else None, config=_env_config(policy))
    frames = _Frames() if frames is None else frames
    frames.step_s = 1.0 / float(env.unwrapped.config.get("policy_frequency") or 1.0)
    cov = _LineCoverage(_module_files(policy, coverage_modules)) if coverage and not remote else None
    try:
        seed = getattr(scenario, "seed", None)
        obs, info = env.reset(seed=None if seed is None else int(seed))
        net = env.unwrapped.net
        visited: list[str] = []
        first_violation: tuple[str, float, Any] | None = None
        steps = 0
        clock = BlockedClock(blocked_after)
        meter = CriticalityMeter()
        blocked = ""
        if render:
            frames.add(env.render())
        if cov:
            cov.start()
            cov.switch(info.get("junction") or ROAD_CONTEXT)
        try:
            policy.reset(env)
            while steps < MAX_STEPS_SAFETY:
                if cov:
                    cov.switch(info.get("junction") or cov.context or ROAD_CONTEXT)
                action = policy.act(obs, info)
                _check_planner_action(env, action)
                obs, _, terminated, truncated, info = env.step(action)
                steps += 1
                lane = info.get("lane_id")
                jid = net.hdmap.lanes[lane].junction_id if lane in net.hdmap.lanes else None
                if jid is not None and (not visited or visited[-1] != jid):
                    visited.append(jid)
                if first_violation is None and info.get("new_violations"):
                    first_violation = (str(info["new_violations"][0]), float(info.get("time", 0.0)),
                                       jid or (visited[-1] if visited else info.get("junction")))
                if render:
                    frames.add(env.render())
                meter.update(env, info, clock.blocked)
                if terminated or truncated:
                    break
                if clock.update(env, info):
                    blocked = clock.message(env, info)
                    break
        finally:
            lines = cov.stop() if cov else {}
            if callable(getattr(policy, "close", None)):
                policy.close()  # ends a planner process (planner bridge); it may hand back its coverage
            if remote:
                lines = dict(getattr(policy, "junction_lines", None) or {})
    except Exception as exc:  # the planner or env raised: what the planner did travels to its error outcome
        setattr(exc, PARTIAL_ATTR, {"stage_path": _stage_path(policy, _events(policy)),
                                    "planner_stderr": str(getattr(policy, "stderr_tail", ""))})
        raise
    finally:
        env.close()
    kind = classify(info)
    message = _message(kind, info, first_violation)
    if blocked:
        message = blocked if kind == "timeout" else f"{message}; {blocked}"
    events = _events(policy)
    digest = cov.digest if cov else (str(getattr(policy, "planner_digest", "")) if remote and lines else "")
    path = _stage_path(policy, events)
    ev_path = stage_path_of(events)
    outcome = Outcome(
        name=str(getattr(scenario, "name", "scenario")), outcome=kind,
        violations={k: int(v) for k, v in sorted(dict(info.get("violations") or {}).items())},
        sim_s=round(float(info.get("time", 0.0)), 6), steps=steps, stage_path=path,
        transitions=tuple(zip(ev_path, ev_path[1:])), junctions=tuple(visited),
        route_progress=round(float(info.get("route_progress", 0.0)), 6), events=events,
        junction_lines=lines, message=message, seed=getattr(scenario, "seed", None),
        map=str(getattr(scenario, "map", "")), planner_digest=digest,
        planner_stderr="" if kind == "completed" else str(getattr(policy, "stderr_tail", "")),
        criticality={**meter.values(), "blocked_s": round(max(meter.blocked, clock.blocked), 4)},
        site=meter.site(), wall_s=time.perf_counter() - t0)
    return outcome, frames


def _stage_path(policy: Any, events: Sequence[tuple]) -> tuple[str, ...]:
    return tuple(str(s) for s in policy.stage_path()) if hasattr(policy, "stage_path") else stage_path_of(events)


def check_blocked_after(value: Any, where: str = "blocked_after") -> None:
    """`blocked_after` must be a finite number of seconds >= 0 (0: never end early); `where`
    names it in the error (the CLI's `--blocked-after`)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not 0 <= value < float("inf"):
        raise Feat2MapError(f"must be a finite number of seconds >= 0 (0: never), got {value!r:.40}", where)


class PlannerActionError(Exception):
    """The planner returned an action the env refuses (NaN, None, a wrong shape, garbage): the
    planner's failure, an `error` outcome, not bad input that ends the run."""


def _check_planner_action(env: Any, action: Any) -> None:
    from feat2map.envs.map_env import check_action

    try:
        check_action(env.unwrapped.action_space, action)
    except Feat2MapError as exc:
        raise PlannerActionError(f"bad action: {exc.message}") from None


def gif_bytes(frames: Sequence[Any], step_s: float) -> bytes:
    """An animated GIF of rgb frames, subsampled and scaled down to stay small."""
    from PIL import Image

    if not frames:
        return b""
    stride = max(1, -(-len(frames) // GIF_MAX_FRAMES))
    picked = list(frames[::stride])
    if picked[-1] is not frames[-1]:
        picked.append(frames[-1])
    images = []
    for f in picked:
        im = Image.fromarray(f)
        h = max(1, round(im.height * GIF_WIDTH_PX / im.width))
        images.append(im.resize((GIF_WIDTH_PX, h)).convert("P", palette=Image.Palette.ADAPTIVE, colors=128))
    buf = io.BytesIO()
    duration = max(20, int(1000 * step_s * stride / GIF_SPEEDUP))
    images[0].save(buf, format="GIF", save_all=True, append_images=images[1:], duration=duration, loop=0)
    return buf.getvalue()


def run_scenario(scenario: Any, planner_factory: Any = "baseline", *, record_failure_gif: bool = True,
                 coverage: bool = False, coverage_modules: Sequence[str] = (),
                 blocked_after: float = BLOCKED_AFTER_S) -> Outcome:
    """Drive one scenario headless with a fresh planner; when it does not complete, re-run it
    with rendering and attach a GIF, whatever the failure policy (a report shows every failure;
    the policy decides only the exit code). `coverage` measures the planner's lines per junction.
    `blocked_after`: [s] the scenario ends as a timeout once the ego has stood still this long
    with nothing in its way (`BlockedClock`; 0: never)."""
    check_blocked_after(blocked_after)
    cpu0 = time.process_time()
    factory = as_factory(planner_factory)
    policy = factory()
    # a planner that costs as much to re-run as to run (an out-of-process planner, whose replay
    # need not even repeat: its timing is not ours) is rendered while it runs, not replayed
    during = record_failure_gif and bool(getattr(policy, "render_during_run", False))
    outcome, frames = _drive(scenario, factory, coverage=coverage, coverage_modules=coverage_modules,
                             policy=policy, render=during, blocked_after=blocked_after)
    if record_failure_gif and not outcome.passed:
        run = outcome
        if not during:
            run, frames = _drive(scenario, factory, render=True, blocked_after=blocked_after)
        step_s = run.sim_s / run.steps if run.steps and run.sim_s > 0 else 1.0
        outcome = replace(outcome, gif=gif_bytes(frames.with_last(), step_s * frames.stride))
    return replace(outcome, cpu_s=time.process_time() - cpu0)


def _error_gif(scenario: Any, factory: Callable[[], Any], blocked_after: float) -> bytes | None:
    """The GIF of a scenario whose planner or env raised (an `error` outcome): replayed with
    rendering up to the raise, so an error is shown like any other failure."""
    frames = _Frames()
    with contextlib.suppress(Exception):
        policy = factory()
        if getattr(policy, "record", None):
            policy.record = None  # a bridge recording keeps the session the outcome reports, not this replay
        _drive(scenario, factory, render=True, blocked_after=blocked_after, frames=frames, policy=policy)
    return gif_bytes(frames.with_last(), frames.step_s * frames.stride) or None


# ---- suites -------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Task:
    index: int
    scenario: Any
    factory: Any
    record_failure_gif: bool
    coverage: bool
    coverage_modules: tuple[str, ...]
    blocked_after: float


def _error_outcome(scenario: Any, index: int, message: str, stage_path: tuple[str, ...] = (),
                   planner_stderr: str = "") -> Outcome:
    """The outcome of a scenario whose planner or env raised; `stage_path` and `planner_stderr`
    as far as the planner got (`PARTIAL_ATTR` of the exception)."""
    return Outcome(name=str(getattr(scenario, "name", f"scenario {index}")), outcome="error", violations={},
                   sim_s=0.0, steps=0, stage_path=stage_path, transitions=(), junctions=(), route_progress=0.0,
                   message=message, seed=getattr(scenario, "seed", None), map=str(getattr(scenario, "map", "")),
                   planner_stderr=planner_stderr)


def _run_task(task: _Task) -> tuple[int, Outcome, str]:
    """(index, outcome, stop): `stop` names why the suite must end here ("" to go on): the
    planner raised SystemExit or KeyboardInterrupt, whose scenario is an error outcome."""
    import feat2map  # noqa: F401  (registers the env ids in spawned workers)

    os.environ.setdefault("SDL_VIDEODRIVER", "offscreen")
    scenario = task.scenario
    if isinstance(scenario, dict):  # scenarios travel as their dicts (plain data, always picklable)
        from .scenario import Scenario

        scenario = Scenario.from_dict(scenario, f"scenario {scenario.get('name', task.index)!r}")
    try:
        out = run_scenario(scenario, task.factory, record_failure_gif=task.record_failure_gif,
                           coverage=task.coverage, coverage_modules=task.coverage_modules,
                           blocked_after=task.blocked_after)
    except Feat2MapError as exc:  # bad input: name the scenario too
        name = f"scenario {getattr(scenario, 'name', task.index)}"
        raise Feat2MapError(exc.message, f"{name}: {exc.where}" if exc.where else name) from None
    except Exception as exc:  # a crashing planner is a failed scenario, not a crashed suite
        out = _error_outcome(scenario, task.index, f"planner or env raised {type(exc).__name__}: {exc}",
                             **getattr(exc, PARTIAL_ATTR, {}))
        if task.record_failure_gif:
            out = replace(out, gif=_error_gif(scenario, task.factory, task.blocked_after))
    except Terminated:  # SIGTERM (in-process runs): not the planner's doing
        raise
    except (SystemExit, KeyboardInterrupt) as exc:  # the planner asks to stop: end the suite, keep the report
        stop = f"the planner raised {type(exc).__name__} in scenario {getattr(scenario, 'name', task.index)}"
        return task.index, _error_outcome(scenario, task.index, f"{stop}: the rollout stopped here"), stop
    return task.index, out, ""


def run_suite(suite: Any, planner: Any = "baseline", *, workers: int = 1, backend: str = "process",
              progress: bool = True, coverage: bool = False, record_failure_gif: bool = True,
              fail_on: str = "any", coverage_modules: Sequence[str] = (),
              blocked_after: float = BLOCKED_AFTER_S, log: Callable[[str], None] | None = None,
              executor: ProcessPoolExecutor | None = None) -> SuiteResult:
    """Run every scenario of `suite` (a Suite or a sequence of scenarios) and collect the outcomes
    in suite order. `workers` > 1 uses spawned processes ("process") or Ray ("ray").
    `blocked_after`: as `run_scenario`'s. `log` gets one line per finished scenario (where no
    progress bar is drawn: a log file, CI). `executor`: a pool from `worker_pool` to run the
    process backend on (kept open for the next suite: a search runs many small ones).
    Ctrl-C, and SIGTERM to this process (`_sigterm_interrupts`; not with `executor`: SIGTERM ends
    the pool's owner, and its workers follow), end the run with the outcomes so far, `stopped`
    saying which."""
    from tqdm import tqdm

    if backend not in BACKENDS:
        raise Feat2MapError(f"unknown backend (choose {', '.join(BACKENDS)})", f"backend {backend!r}")
    if fail_on not in FAIL_POLICIES:
        raise Feat2MapError(f"unknown failure policy (choose {', '.join(FAIL_POLICIES)})", f"fail-on {fail_on!r}")
    if workers < 1:
        raise Feat2MapError("must be at least 1", f"workers {workers}")
    check_blocked_after(blocked_after)
    scenarios = list(getattr(suite, "scenarios", suite))
    if not scenarios:  # nothing driven is not a pass
        raise Feat2MapError("has no scenarios: nothing to run", f"suite {getattr(suite, 'name', '')!r}")
    factory = as_factory(planner)
    tasks = [_Task(i, s.to_dict() if hasattr(s, "to_dict") else s, factory, record_failure_gif, coverage,
                   tuple(coverage_modules), float(blocked_after))
             for i, s in enumerate(scenarios)]
    picklable = _picklable(factory)
    if not picklable and (workers > 1 or backend == "ray"):
        raise Feat2MapError("cannot be pickled for worker processes: use a module-level class or function, "
                            "or functools.partial of one", f"planner {getattr(factory, 'name', planner)!r}")
    results: dict[int, Outcome] = {}
    stopped: list[str] = []
    bar = tqdm(total=len(tasks), desc=f"rollout {getattr(suite, 'name', '')}".strip(), unit="scenario",
               disable=not progress)
    t0 = time.perf_counter()

    def done(index: int, out: Outcome, stop: str = "") -> bool:
        """Record one outcome; True when the suite must end (the planner asked to stop)."""
        if not stopped:
            results[index] = out
            if log is not None:
                log(scenario_line(out, len(results), len(tasks)))
        if stop and not stopped:
            stopped.append(stop)
        bar.update(1)
        bar.set_postfix(failed=sum(o.fails(fail_on) for o in results.values()))
        return bool(stopped)

    try:
        with contextlib.nullcontext() if executor is not None else _sigterm_interrupts():
            _run_tasks(tasks, workers, backend, picklable, executor, done)
    except KeyboardInterrupt as exc:  # Ctrl-C or SIGTERM: end with what has run so far
        stopped.append(f"interrupted ({'SIGTERM' if isinstance(exc, Terminated) else 'KeyboardInterrupt'})")
    finally:
        bar.close()
        _bridge_call("discard_spares")  # the suite is over: no planner waits for a next scenario here
    outcomes = tuple(results[i] for i in sorted(results))
    return SuiteResult(name=str(getattr(suite, "name", "suite")), planner=getattr(factory, "name", str(planner)),
                       outcomes=outcomes, coverage=coverage,
                       planner_digest=suite_digest(outcomes) if coverage else "",
                       workers=workers, backend=backend, wall_s=time.perf_counter() - t0,
                       stopped=stopped[0] if stopped else "", scenarios=len(tasks))


def _run_tasks(tasks: Sequence[_Task], workers: int, backend: str, picklable: bool,
               executor: ProcessPoolExecutor | None, done: Callable[..., bool]) -> None:
    """Run `tasks` on the backend `run_suite` chose, handing each result to `done` until it
    says the suite ends."""
    if backend == "ray":
        _run_ray(tasks, workers, done)
    elif executor is None and workers == 1 and (os.environ.get("PYTHONHASHSEED") == HASH_SEED or not picklable):
        if not picklable:
            warnings.warn("the planner cannot be pickled: running in this process, whose string hashing "
                          "may change which planner lines run (results stay the same)", stacklevel=3)
        for t in tasks:  # this process already hashes like the workers would
            if done(*_run_task(t)):
                break
    elif executor is not None:
        futures = [executor.submit(_run_task, t) for t in tasks]
        for fut in as_completed(futures):
            if done(*fut.result()):
                for rest in futures:
                    rest.cancel()
                break
    elif tasks:
        with worker_pool(min(workers, len(tasks))) as pool:
            futures = [pool.submit(_run_task, t) for t in tasks]
            for fut in as_completed(futures):
                if done(*fut.result()):
                    pool.shutdown(wait=True, cancel_futures=True)
                    break


def scenario_line(out: Outcome, done: int, total: int) -> str:
    """One line for a finished scenario: how many have finished, its name, outcome and times, and
    what went wrong."""
    from feat2map.messages import one_line

    why = f": {out.message}" if not out.passed and out.message else ""
    return one_line(f"[{done}/{total}] {out.name}: {out.outcome} ({out.sim_s:.1f} s simulated, "
                    f"{out.wall_s:.1f} s wall){why}")


def _picklable(obj: Any) -> bool:
    try:
        pickle.dumps(obj)
    except Exception:  # pickle raises many types (PicklingError, AttributeError, TypeError)
        return False
    return True


@contextlib.contextmanager
def _env_var(name: str, value: str) -> Iterator[None]:
    """Set an environment variable while spawning workers (they inherit it), then restore it."""
    old = os.environ.get(name)
    os.environ[name] = value
    try:
        yield
    finally:
        if old is None:
            os.environ.pop(name, None)
        else:
            os.environ[name] = old


@contextlib.contextmanager
def worker_pool(workers: int) -> Iterator[ProcessPoolExecutor]:
    """Spawned worker processes hashing strings like every other worker (PYTHONHASHSEED=HASH_SEED).
    None outlives this process (`_worker_init`); an exception out of the block (Ctrl-C, SIGTERM,
    bad input) ends them at once, running scenarios and queued ones alike, rather than waiting
    for every queued scenario to run."""
    with _env_var("PYTHONHASHSEED", HASH_SEED):
        pool = ProcessPoolExecutor(max_workers=workers, mp_context=get_context("spawn"),
                                   initializer=_worker_init, initargs=(os.getpid(),))
        try:
            yield pool
        except BaseException:
            for proc in tuple((getattr(pool, "_processes", None) or {}).values()):
                proc.terminate()  # SIGTERM: each kills its planners and exits (_worker_init)
            raise
        finally:
            pool.shutdown(wait=True, cancel_futures=True)


class Terminated(KeyboardInterrupt):
    """SIGTERM, raised in the main thread of a process running a suite (`_sigterm_interrupts`):
    the run ends like on Ctrl-C, with the report so far."""


@contextlib.contextmanager
def _sigterm_interrupts() -> Iterator[None]:
    """While a suite runs, SIGTERM kills the planner processes this process started and raises
    `Terminated` in its main thread, so that the run ends with its report so far and takes its
    workers with it (`worker_pool`). Only in the main thread (where Python runs handlers) and
    only over the default action: a handler the program installed is its own."""
    if threading.current_thread() is not threading.main_thread() or \
            signal.getsignal(signal.SIGTERM) not in (signal.SIG_DFL, None):  # None: a C library's (SDL's)
        yield
        return

    def terminated(signum: int, frame: Any) -> None:
        _bridge_call("kill_planners")
        raise Terminated

    signal.signal(signal.SIGTERM, terminated)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL)


def _bridge_call(name: str) -> None:
    """Call the bridge's function `name` (`kill_planners`, `discard_spares`), if this process
    loaded the bridge (else it started no planner)."""
    bridge = sys.modules.get(f"{__package__}.bridge")
    if bridge is not None:
        getattr(bridge, name)()


def _worker_init(parent: int) -> None:
    """A pool worker's start: SIGTERM ends it within moments, and so does the end of its parent
    `parent` (whatever ended it: SIGTERM, SIGKILL, a crash), which a daemon thread notices as the
    worker being re-parented. Not PR_SET_PDEATHSIG: it fires when the *thread* that spawned the
    worker ends, and ProcessPoolExecutor spawns workers in whichever thread calls `submit`.
    SDL (pygame, rendering GIFs) must not take SIGTERM over: its handler only queues a quit
    event, which left SIGTERMed workers running."""
    os.environ.setdefault("SDL_NO_SIGNAL_HANDLERS", "1")
    signal.signal(signal.SIGTERM, lambda signum, frame: _end_worker())
    threading.Thread(target=_watch_parent, args=(parent,), name="feat2map-watch-parent", daemon=True).start()


def _watch_parent(parent: int) -> None:
    """End this worker once its parent `parent` is gone (polled every WORKER_PARENT_POLL_S)."""
    while os.getppid() == parent:
        time.sleep(WORKER_PARENT_POLL_S)
    _end_worker()


def _end_worker() -> NoReturn:
    """Kill the planner processes this worker started and exit now. No unwinding: `finally`
    blocks would wait for a planner's bye (CLOSE_TIMEOUT_S) and re-render, and the pool's worker
    loop would catch the exception and take the next scenario."""
    _bridge_call("kill_planners")
    os._exit(128 + signal.SIGTERM)


@contextlib.contextmanager
def ray_session(workers: int) -> Iterator[Any]:
    """Ray, started for `workers` CPUs unless this process already started it (then left running)."""
    try:
        import ray
    except ImportError:
        raise Feat2MapError("Ray is not installed (pip install 'feat2map[ray]')", "backend 'ray'") from None
    started = not ray.is_initialized()
    if started:
        import logging

        ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR,
                 runtime_env={"env_vars": {"SDL_VIDEODRIVER": "offscreen", "MPLBACKEND": "Agg"}})
    try:
        yield ray
    finally:
        if started:
            ray.shutdown()


def _run_ray(tasks: Sequence[_Task], workers: int, done: Callable[..., bool]) -> None:
    with ray_session(workers) as ray:
        remote = ray.remote(num_cpus=1, runtime_env={"env_vars": {"PYTHONHASHSEED": HASH_SEED}})(_run_task)
        pending = [remote.remote(t) for t in tasks]
        while pending:
            ready, pending = ray.wait(pending, num_returns=1)
            for ref in ready:
                try:
                    if done(*ray.get(ref)):
                        for rest in pending:
                            ray.cancel(rest)
                        return
                except ray.exceptions.RayTaskError as exc:  # bad input in a worker: its one-line error
                    cause = getattr(exc, "cause", None)
                    if isinstance(cause, Feat2MapError):
                        raise Feat2MapError(cause.message, cause.where) from None
                    raise
