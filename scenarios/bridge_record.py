"""Recordings of planner-bridge sessions, and their replay against a planner without the env.

`feat2map rollout SUITE --planner-cmd CMD --record DIR` keeps, per scenario, DIR/<scenario>/:
`messages.jsonl` (every message both ways, one JSON object a line: `dir` "to_planner" or
"from_planner", `wall` the wall-clock time [s since the epoch], and `message`, or `line` for a
reply that was not JSON), `map/` (the map export the planner got) and `recording.json` (the map
file's name in `map/`, the planner command, the scenario). `feat2map replay DIR/<scenario>
--planner-cmd CMD` sends the recorded messages to a planner, with `init.map` pointing at the
recorded map, and reports where its replies differ from the recorded ones (docs/planners.md).
"""
from __future__ import annotations

import json
import math
import re
import shutil
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from feat2map import atomic
from feat2map.errors import Feat2MapError

from .bridge import START_TIMEOUT_S, STEP_TIMEOUT_S, BridgeError, PlannerProcess

MESSAGES = "messages.jsonl"
META = "recording.json"
MAP_DIR = "map"
REPLAY_TOLERANCE = 1e-6  # replies' numbers (control, trajectory points) equal within this
TRAJECTORY_KEYS = ("t", "x", "y", "heading", "speed")
HELLO_KEYS = ("protocol", "map_format", "output", "replan_s")


def recording_folder(record: str | Path, scenario: str) -> Path:
    """The folder of `scenario`'s recording under `record` (its name, made a safe folder name)."""
    return Path(record) / (re.sub(r"[^A-Za-z0-9._-]", "_", scenario).lstrip(".") or "scenario")


def save_recording(folder: str | Path, transcript: list[dict], map_path: str, planner: str = "") -> None:
    """Write one session's `transcript` and a copy of its map export (`map_path`'s folder, which
    holds that export only) to `folder`, whole or not at all (an earlier recording replaced)."""
    folder = Path(folder)
    with atomic.staged_dir(folder, (MESSAGES,)) as tmp:
        if map_path:
            shutil.copytree(Path(map_path).parent, tmp / MAP_DIR)
        atomic.write_text(tmp / MESSAGES, "".join(json.dumps(e, separators=(",", ":")) + "\n" for e in transcript))
        atomic.write_text(tmp / META, json.dumps({"map": Path(map_path).name if map_path else "", "planner": planner,
                                                  "scenario": folder.name}, indent=1) + "\n")


def load_recording(folder: str | Path) -> tuple[dict, list[dict]]:
    """(recording.json, the transcript) of a recording folder; Feat2MapError if it is none."""
    folder = Path(folder)
    try:
        meta = json.loads((folder / META).read_text())
        entries = [json.loads(x) for x in (folder / MESSAGES).read_text().splitlines() if x.strip()]
    except (OSError, ValueError) as exc:
        raise Feat2MapError(f"not a bridge recording ({MESSAGES} and {META}): {exc}", str(folder)) from None
    return meta, entries


@dataclass(frozen=True)
class ReplayResult:
    """How a planner's replies to a recording's messages compare with the recorded ones."""

    messages: int  # messages sent
    differences: tuple[str, ...]  # each names its step and message type, first first


def _exchanges(entries: list[dict]) -> list[tuple[dict, dict | None]]:
    """Each message to the planner with the reply recorded after it (None: none came)."""
    out: list[tuple[dict, dict | None]] = []
    for e in entries:
        if e.get("dir") == "to_planner":
            out.append((e["message"], None))
        elif e.get("dir") == "from_planner" and out and out[-1][1] is None:
            out[-1] = (out[-1][0], e)
    return out


def _close(a: Any, b: Any, tol: float) -> bool:
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return math.isclose(float(a), float(b), rel_tol=0.0, abs_tol=tol)
    return a == b


def compare_reply(recorded: dict, got: dict, tol: float = REPLAY_TOLERANCE) -> str:
    """What differs between a recorded reply and a replayed one ("" when nothing does): the
    type, the step, the hello's choices, the stage, control values and trajectory points
    (numbers within `tol`)."""
    keys = ["type", "step", "stage", "scenario"]
    kind = recorded.get("type")
    if kind == "hello":
        keys += HELLO_KEYS
    elif kind == "control":
        keys += ["acceleration", "steering"]
    for k in keys:
        if not _close(recorded.get(k), got.get(k), tol):
            return f"{k} {got.get(k)!r:.60}, recorded {recorded.get(k)!r:.60}"
    if kind == "trajectory":
        rp, gp = recorded.get("points") or [], got.get("points") or []
        if len(rp) != len(gp):
            return f"{len(gp)} trajectory points, recorded {len(rp)}"
        for i, (r, g) in enumerate(zip(rp, gp)):
            for k in TRAJECTORY_KEYS:
                if not _close(r.get(k), g.get(k), tol):
                    return f"point {i} {k} {g.get(k)!r:.30}, recorded {r.get(k)!r:.30}"
    return ""


def replay(folder: str | Path, cmd: str | list[str], *, tolerance: float = REPLAY_TOLERANCE,
           step_timeout: float = STEP_TIMEOUT_S, start_timeout: float = START_TIMEOUT_S,
           cwd: str | None = None) -> ReplayResult:
    """Send a recording's messages to the planner `cmd` in their order and step ids (`init.map`
    pointing at the recorded map) and compare its replies with the recorded ones; a planner
    that fails (crashes, misses a deadline, replies garbage) is a difference, the last."""
    folder = Path(folder)
    meta, entries = load_recording(folder)
    exchanges = _exchanges(entries)
    if not exchanges:
        raise Feat2MapError("the recording holds no message to the planner", str(folder / MESSAGES))
    diffs: list[str] = []
    sent = 0
    proc = PlannerProcess(cmd, cwd=cwd)
    try:
        for msg, rec in exchanges:
            kind = str(msg.get("type"))
            where = f"step {msg.get('step')} ({kind})"
            body = {k: v for k, v in msg.items() if k != "step"}
            if kind == "init" and meta.get("map"):
                body["map"] = str((folder / MAP_DIR / meta["map"]).resolve())
            proc.step = int(msg.get("step", proc.step))
            sent += 1
            try:
                got = proc.request(body, start_timeout if kind in ("hello", "init") else step_timeout, kind)
            except BridgeError as exc:
                diffs.append(f"{where}: the planner failed: {exc}")
                break
            if kind == "hello" and got.get("protocol") in (1, 2):
                proc.protocol = int(got["protocol"])
            if rec is None:
                diffs.append(f"{where}: the recording has no reply here (the recorded planner failed)")
                break
            if "message" not in rec:
                diffs.append(f"{where}: the recorded reply was not JSON: {str(rec.get('line'))[:80]!r}")
                continue
            diff = compare_reply(rec["message"], got, tolerance)
            if diff:
                diffs.append(f"{where}: {diff}")
    finally:
        proc.discard()  # the recording's close was replayed (or the planner failed): no second one
    return ReplayResult(sent, tuple(diffs))
