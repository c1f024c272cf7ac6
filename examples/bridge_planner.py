#!/usr/bin/env python3
"""A tiny reference planner speaking feat2map's planner bridge protocol (docs/planners.md), in
plain Python: it asks for the native map, follows the route's lane centres at a safe speed
(the lanes' limits, curves, leaders, pedestrians on its path) and stops for red signals and
stop signs from each step message. Run it through the bridge:

    feat2map rollout suite.yaml --planner-cmd "python examples/bridge_planner.py" --out out/ref

It shows the protocol, nothing more: use it as the skeleton of an adapter for your planner.
"""
from __future__ import annotations

import bisect
import json
import math
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "adapters"))
from bridge_client import Route, RuleGate, serve  # noqa: E402

HORIZON_S = 4.0
DT_S = 0.2
BRAKE = 3.0  # [m/s^2] the planned deceleration towards a stop point
GAP_M = 3.0  # standstill distance to a leader
HEADWAY_S = 1.2
PROJECT_WINDOW_M = 20.0  # the ego is looked for this far along the route either side of where it was


class ReferencePlanner:
    def hello(self) -> dict:
        return {"name": "feat2map reference bridge planner", "map_format": "native", "output": "trajectory",
                "prestart": True}  # its start has no side effects: the bridge may start the next one early

    def init(self, msg: dict) -> None:
        native = json.loads(Path(msg["map"]).read_text())
        self.lanes = {ln["id"]: ln for ln in native["lanes"]}
        self.route = Route(self.lanes, msg["route"]["lanes"])
        self.lane_limits = [float(self.lanes[lid].get("speed_limit") or 13.4) for lid in self.route.lanes]
        self.init_msg = msg
        self.gate = None  # from the first step (it lists the signals and stop signs)
        self.half = msg["ego"]["length"] / 2
        self.s = None

    def _limit(self, s: float) -> float:
        i = max(0, min(len(self.lane_limits) - 1, bisect.bisect_right(self.route.lane_start, s) - 1))
        return min(self.lane_limits[i], self.route.curvature_speed(s))

    def step(self, msg: dict) -> dict:
        ego = msg["ego"]
        if self.gate is None:
            r = self.init_msg["route"]
            self.gate = RuleGate(msg, r["lanes"], r["junction_of_lane"], self.route.lane_end,
                                 self.init_msg["ego"]["length"], self.route,
                                 full_stop=self.init_msg.get("rules", {}).get("full_stop"))
        s, _ = self.route.project(ego["x"], ego["y"], near=self.s, window=PROJECT_WINDOW_M)
        self.s = s
        v = max(float(ego["speed"]), 0.0)
        stop, why = self.gate.stop_s(msg, s, v)
        stage = why or "CRUISE"
        for s_obj, v_obj, kind in self.gate.obstacles_ahead(msg, s):
            limit = s_obj - self.half - GAP_M - HEADWAY_S * v
            if limit < stop:
                stop, stage = (limit, "YIELD_PEDESTRIAN") if kind == "pedestrians" else (limit + v_obj * HEADWAY_S, "FOLLOW")
            break
        points, t, sv = [], float(msg["t"]), s
        for k in range(int(HORIZON_S / DT_S) + 1):
            x, y, h = self.route.pose(sv)
            points.append({"t": t + k * DT_S, "x": x, "y": y, "heading": h, "speed": v})
            room = max(stop - sv, 0.0)
            v_stop = math.sqrt(2 * BRAKE * room)  # the speed from which BRAKE stops it at the point
            v_des = min(self._limit(sv), v_stop)
            if v > v_stop + 0.5:  # brake to stop at the point
                a = -min(6.0, v * v / (2 * max(room, 0.1)))
            else:
                a = max(-6.0, min(2.0, 1.5 * (v_des - v)))
            nv = max(0.0, v + a * DT_S)
            sv += (v + nv) / 2 * DT_S
            v = nv
        return {"type": "trajectory", "points": points, "scenario": "REFERENCE", "stage": stage}


if __name__ == "__main__":
    sys.exit(serve(ReferencePlanner()))
