"""The planner side of feat2map's planner bridge (protocol: docs/planners.md), in plain Python
(standard library only), so that any planner process, in any venv, can use it:

- `serve(planner)`: the message loop over stdin/stdout (hello, init, step, close);
- `Route`: the ego's route as one polyline (the route lanes' centrelines from the native map
  the bridge wrote), with projection, poses by arc length and the route's stop lines;
- `RuleGate`: where the traffic rules make the ego stop (red/amber signals, stop signs in
  queue order, and giving way where the step's `ahead.hold` names conflicting traffic,
  pedestrians or a narrow passage) from a step message, for planners that have no rules of
  their own.

A planner object has `hello() -> dict`, `init(msg) -> None`, `step(msg) -> dict` and optionally
`close() -> dict` (extra fields of the bye, e.g. coverage).
"""
from __future__ import annotations

import bisect
import json
import math
import sys
from typing import Any

PROTOCOL_VERSION = 2  # 2: each reply echoes its request's "step"; a bridge that speaks only 1 gets 1
STOP_MARGIN_M = 1.5  # the ego's front stops this far before a stop line
FULL_STOP_S = 1.0  # a stop sign needs a full stop this long
STOPPED_MPS = 0.3
COMFORT_DECEL = 3.0  # [m/s^2] amber: stop only if the line can be reached braking at most this
HOLD_MARGIN_M = 0.5  # [m] the front halts this far short of the point where the env's rules hold the ego
YIELD_RULES = {"conflict", "pedestrian", "passage"}  # of step.ahead.hold.by: the gate stops where these hold the ego
PATH_HALF_WIDTH_M = 1.8  # a road user this close to the route ahead is in the ego's way


def serve(planner: Any, stdin=None, stdout=None) -> int:
    """Answer the bridge's messages until `close` (or end of input); 0 on a clean close. Each
    reply echoes its request's `step` (protocol 2)."""
    stdin = stdin or sys.stdin
    stdout = stdout or sys.stdout

    def reply(request: dict, answer: dict) -> None:
        if "step" in request:
            answer = {**answer, "step": request["step"]}
        stdout.write(json.dumps(answer, separators=(",", ":")) + "\n")
        stdout.flush()

    for line in stdin:
        if not line.strip():
            continue
        msg = json.loads(line)
        kind = msg.get("type")
        if kind == "hello":
            reply(msg, {"type": "hello", "protocol": min(int(msg.get("protocol", 1)), PROTOCOL_VERSION),
                        **planner.hello()})
        elif kind == "init":
            planner.init(msg)
            reply(msg, {"type": "ready"})
        elif kind == "step":
            reply(msg, planner.step(msg))
        elif kind == "close":
            extra = planner.close() if hasattr(planner, "close") else {}
            reply(msg, {"type": "bye", **(extra or {})})
            return 0
    return 1


class Route:
    """The route lanes' centrelines joined into one polyline (from the native map JSON)."""

    def __init__(self, lanes: dict[str, dict], route: list[str]) -> None:
        pts: list[tuple[float, float]] = []
        self.lane_start: list[float] = []  # arc length where each route lane starts
        self.lane_end: list[float] = []
        s = 0.0
        for lid in route:
            line = [(float(p[0]), float(p[1])) for p in lanes[lid]["centerline"]]
            if pts and math.dist(pts[-1], line[0]) < 0.5:
                line = line[1:]
            self.lane_start.append(s)
            for p in line:
                if pts:
                    s += math.dist(pts[-1], p)
                pts.append(p)
            self.lane_end.append(s)
        self.pts = pts
        self.s = [0.0]
        for a, b in zip(pts, pts[1:]):
            self.s.append(self.s[-1] + math.dist(a, b))
        self.h = [math.atan2(b[1] - a[1], b[0] - a[0]) for a, b in zip(pts, pts[1:])] or [0.0]  # each segment's
        self.length = self.s[-1]
        self.lanes = list(route)

    def pose(self, s: float) -> tuple[float, float, float]:
        """(x, y, heading) at arc length `s` (clamped; past the end along the last heading)."""
        pts, ss = self.pts, self.s
        if len(pts) < 2:
            return pts[0][0], pts[0][1], 0.0
        k = self._segment(s)
        (x0, y0), (x1, y1) = pts[k], pts[k + 1]
        seg = max(ss[k + 1] - ss[k], 1e-9)
        u = (s - ss[k]) / seg
        return x0 + u * (x1 - x0), y0 + u * (y1 - y0), self.h[k]

    def _segment(self, s: float) -> int:
        """The index of the segment holding arc length `s` (the first or last beyond the ends)."""
        return max(0, min(bisect.bisect_right(self.s, s) - 1, len(self.pts) - 2))

    def project(self, x: float, y: float, near: float | None = None, window: float = 60.0) -> tuple[float, float]:
        """(arc length, signed lateral offset, left positive) of the nearest route point (within
        `window` of `near` when given)."""
        best = (math.inf, 0.0, 0.0)
        pts, ss = self.pts, self.s
        lo, hi = 0, len(pts) - 1  # the segments k in [lo, hi) that reach into the window
        if near is not None:
            lo = max(bisect.bisect_left(ss, near - window) - 1, 0)
            hi = min(bisect.bisect_right(ss, near + window), len(pts) - 1)
        for k in range(lo, hi):
            (x0, y0), (x1, y1) = pts[k], pts[k + 1]
            dx, dy = x1 - x0, y1 - y0
            L2 = dx * dx + dy * dy or 1e-12
            u = max(0.0, min(1.0, ((x - x0) * dx + (y - y0) * dy) / L2))
            qx, qy = x0 + u * dx, y0 + u * dy
            d2 = (x - qx) ** 2 + (y - qy) ** 2
            if d2 < best[0]:
                side = 1.0 if dx * (y - y0) - dy * (x - x0) >= 0 else -1.0
                best = (d2, ss[k] + u * math.sqrt(L2), side * math.sqrt(d2))
        return best[1], best[2]

    def heading_at(self, s: float) -> float:
        return self.h[self._segment(s)]

    def curvature_speed(self, s: float, lat_acc: float = 2.5, v_min: float = 3.0, window: float = 4.0) -> float:
        """The speed at which the route's curve at `s` keeps the lateral acceleration below `lat_acc`."""
        h0, h1 = self.heading_at(s - window / 2), self.heading_at(s + window / 2)
        dh = abs((h1 - h0 + math.pi) % (2 * math.pi) - math.pi)
        if dh < 1e-3:
            return math.inf
        return max(v_min, math.sqrt(lat_acc * window / dh))


class RuleGate:
    """Stop lines on the route (the end of a route lane that a signal or stop sign governs,
    before a junction lane) and where a step message's rules make the ego stop."""

    def __init__(self, step: dict, route_lanes: list[str], junction_of_lane: list, lane_end: list[float],
                 ego_length: float, route: "Route | None" = None, full_stop: dict | None = None) -> None:
        """From the first step message (its signals and stop signs, with the lanes they govern),
        the route's lanes, the junction of each (None on roads), the arc length where each ends
        along the planner's path, and init's `rules.full_stop` (what the judge counts as a full
        stop: at most `speed_mps` with the centre within `zone_m` before the line)."""
        self.half = ego_length / 2
        full_stop = full_stop or {}
        self.stopped_mps = float(full_stop.get("speed_mps", STOPPED_MPS))
        self.zone_m = float(full_stop.get("zone_m", STOP_MARGIN_M + 3.0 + self.half))
        control: dict[str, tuple[str, str]] = {}
        for s in step.get("signals", []):
            for lid in s.get("lanes", []):
                control[lid] = ("signal", s["id"])
        for s in step.get("stop_signs", []):
            for lid in s.get("lanes", []):
                control[lid] = ("stop", s["id"])
        self.lines: list[tuple[float, str, str]] = []  # (route arc length of the line, kind, control id)
        for i, lid in enumerate(route_lanes[:-1]):
            if lid in control and junction_of_lane[i + 1] and not junction_of_lane[i]:
                self.lines.append((lane_end[i], *control[lid]))
        self.route = route
        self.stopped_at: dict[str, float] = {}  # stop sign line -> time the full stop began
        self.passed: set[str] = set()

    def stop_s(self, msg: dict, s_ego: float, speed: float) -> tuple[float, str]:
        """(arc length where the ego's centre must stop, why) for this step; (inf, "") if nowhere.
        Signals and stop signs from the step's `signals` and `stop_signs`; giving way (conflicting
        traffic, pedestrians, narrow passages: "YIELD") where the step's `ahead.hold` says the
        env's rules hold the ego, unless it can no longer stop braking at COMFORT_DECEL."""
        t = float(msg["t"])
        hold = (msg.get("ahead") or {}).get("hold")  # protocol 2: the env's rules in the ego's place
        yield_s = math.inf
        if hold and set(hold.get("by", ())) & YIELD_RULES and \
                float(hold["distance"]) - self.half >= speed * speed / (2 * COMFORT_DECEL):  # it can stop comfortably
            yield_s = s_ego + float(hold["distance"]) - self.half - HOLD_MARGIN_M  # the front short of the point
        signals = {x["id"]: x for x in msg.get("signals", [])}
        stops = {x["id"]: x for x in msg.get("stop_signs", [])}
        for line_s, kind, cid in self.lines:
            front = s_ego + self.half
            if front > line_s + (0.5 if kind == "stop" else 3.0) or cid + str(line_s) in self.passed:
                continue
            target = line_s - STOP_MARGIN_M - self.half
            if kind == "signal":
                state = signals.get(cid, {}).get("state", "green")
                dist = line_s - front
                if state == "red" or (state == "amber" and dist > speed * speed / (2 * COMFORT_DECEL)):
                    return min(target, yield_s), "STOP_SIGNAL"
            else:
                key = cid + str(line_s)
                if speed < self.stopped_mps and line_s - s_ego < self.zone_m:  # the judge's full stop
                    self.stopped_at.setdefault(key, t)
                began = self.stopped_at.get(key)
                queue = stops.get(cid, {}).get("queue", [])
                if began is not None and t - began >= FULL_STOP_S and (not queue or queue[0] == "ego"):
                    self.passed.add(key)
                    continue
                return min(target, yield_s), "STOP_SIGN"
        return (yield_s, "YIELD") if yield_s < math.inf else (math.inf, "")

    def obstacles_ahead(self, msg: dict, s_ego: float, horizon: float = 60.0) -> list[tuple[float, float, str]]:
        """(arc length, speed along the route, kind) of road users on the route ahead."""
        assert self.route is not None, "obstacles_ahead needs the Route"
        ex, ey = float(msg["ego"]["x"]), float(msg["ego"]["y"])
        reach = horizon + PATH_HALF_WIDTH_M + 5.0  # farther from the ego, a road user cannot be on the route ahead
        out = []
        for kind in ("vehicles", "pedestrians"):
            for v in msg.get(kind, []):
                if abs(v["x"] - ex) > reach or abs(v["y"] - ey) > reach:
                    continue
                s, d = self.route.project(v["x"], v["y"], near=s_ego + horizon / 2, window=horizon / 2 + 5)
                if not (s_ego < s <= s_ego + horizon) or abs(d) > PATH_HALF_WIDTH_M + (0.0 if kind == "vehicles" else 1.0):
                    continue
                along = v["speed"] * math.cos(v["heading"] - self.route.heading_at(s))
                half = float(v.get("length", 1.0)) / 2
                out.append((s - half, max(along, 0.0) if kind == "vehicles" else 0.0, kind))
        return sorted(out)
