#!/usr/bin/env python3
"""CommonRoad's reactive planner (commonroad-reactive-planner 2025.1, TUM) as a feat2map bridge
planner. Runs in its own venv (adapters/commonroad/setup.sh makes .venv-crplanner):

    feat2map rollout suite.yaml --planner-cmd ".venv-crplanner/bin/python adapters/commonroad/planner.py" --out out/cr

What it does (docs/planners.md):
- init: reads the map's CommonRoad export (commonroad-io's reader); commonroad-route-planner
  gives the reference path along the scenario's route (from the ego's first lanelet to the
  continuation lanelet past its exit lanelet, so the path never ends inside the horizon; our
  route's lanelets are the fallback when the route planner picks another lane); the reactive
  planner's curvilinear frame is built with CLCSParams() passed explicitly; its
  multiprocessing is off.
- step: the ego's state becomes the planner's initial state (rear axle); every vehicle and
  pedestrian near the ego, not behind it, becomes a dynamic obstacle predicted at its speed
  along its lane (straight on where it leaves its lane or the lanes branch) over the horizon,
  next to the road boundary, in a fresh collision checker; the traffic rules the step message
  states (red/amber signals, stop signs in queue order, the env's rules holding the ego:
  `ahead.hold`; the reactive planner has none of its own) and a standing queue ahead put it
  in "stopping" mode before the stop point, else "velocity_keeping" at the lane's speed limit
  (curves slower). Its lateral samples stay within LATERAL_RANGE_M of the path. The optimal trajectory
  goes back with its states shifted to the vehicle centre. When it finds none (or raises), the
  adapter brakes along the reference path and says so in its stage (FALLBACK_...).
- close: with coverage requested, the reactive planner's own lines (commonroad_rp) per
  junction, measured by coverage.py in this process.
"""
from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import sys
import traceback
import warnings
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from bridge_client import RuleGate, serve  # noqa: E402

COVERED_PACKAGES = ("commonroad_rp",)  # the planner under test, measured for RQ3
DT = 0.1  # the reactive planner's time step [s]
HORIZON_STEPS = 30  # 3 s
REPLAN_S = 0.6  # the bridge asks for a new plan this often (the planner costs ~0.3 s a call on a loaded 2-core machine)
SAMPLING_LEVELS = 3  # the planner tries sampling levels 1..SAMPLING_LEVELS-1 until one finds a trajectory
OBSTACLE_RADIUS_M = 80.0
JUNCTION_SPEED_MPS = 6.0
LAT_ACC_MPS2 = 1.5
STOP_MARGIN_M = 1.5
FALLBACK_DECEL = 6.0
ENGAGE_MPS = 1.0  # [m/s] the planner's initial speed when the ego is to move off from (near) standstill
APPROACH_DECEL = 2.0  # [m/s^2] speed cap towards a stop point: it can stop there braking this hard
CREEP_GAP_M = 2.0  # [m] the creep stops this far behind a road user ahead on the path
BOUNDARY_REACH_M = 60.0  # [m] the road boundary is built from the lanelets this close to the reference path
STALL_CREEP_M = 3.0  # [m] with no trajectory at standstill, the ego creeps on at most this far along the path
CREEP_ROOM_M = 1.0  # [m] slower than ENGAGE_MPS further than this before its stop point, the ego creeps on
STOPPING_RANGE_M = 10.0  # "stopping" mode (a target position) this far beyond the braking distance
WINDOW_BACK_M = 20.0  # the reference path's window starts this far behind the ego
WINDOW_AHEAD_M = 80.0  # and moves on when the ego comes this close to its end (the horizon: <= 45 m)
WINDOW_THETA_MARGIN = 0.3  # [rad] kept off commonroad-clcs's [-2pi, 2pi] orientation bound
SELF_GAP_M = 10.0  # [m] a window ends before its path comes back this close to an earlier part of it
SELF_ARC_M = 30.0  # [m] ... that lies at least this far behind along the path (a loop, not a bend)
STOP_REACH_MARGIN_M = 1.0  # [m] "stopping" only when the stop target lies within a smooth stop in the horizon
STOP_REACH_MIN_M = 10.0  # [m] ... or at least this close (at low speed the reach alone left it crawling up)
LATERAL_RANGE_M = 1.0  # [m] lateral samples end at most this far beside the path (its default 3 m: the oncoming lane)
PREDICT_LAT_M = 1.5  # [m] a road user this close to its lane's centreline ...
PREDICT_HEADING_RAD = 0.6  # ... and heading this close to the lane's is predicted along its lane
PREDICT_AHEAD_M = 60.0  # [m] the lane path reaches this far past its lane's end (the horizon at 20 m/s)
QUEUE_MPS = 1.0  # [m/s] a vehicle ahead on the path this slow is a stop target (the back of a queue)
ROAD_CONTEXT = "(road)"  # coverage context before the first junction (as feat2map's rollout)


class ReactiveAdapter:
    def __init__(self) -> None:
        self.cov = None
        self.context = None
        self.failures: dict[str, int] = {}

    def hello(self) -> dict:
        return {"name": "commonroad-reactive-planner 2025.1 (feat2map adapter)", "map_format": "commonroad",
                "output": "trajectory", "replan_s": REPLAN_S}

    # ---- init ---------------------------------------------------------------------------------
    def init(self, msg: dict) -> None:
        if msg.get("coverage"):
            import coverage

            self.cov = coverage.Coverage(data_file=None, config_file=False, source_pkgs=list(COVERED_PACKAGES))
            self.cov.set_option("run:disable_warnings", ["no-data-collected", "module-not-measured"])
            self.cov.start()
            self._switch(ROAD_CONTEXT)
        logging.disable(logging.WARNING)  # commonroad-io's and the planner's INFO/WARNING chatter
        from commonroad.common.file_reader import CommonRoadFileReader
        from commonroad_clcs.config import CLCSParams
        from commonroad_dc.boundary.boundary import create_road_boundary_obstacle
        from commonroad_rp.reactive_planner import ReactivePlanner
        from commonroad_rp.utility.config import ReactivePlannerConfiguration
        from commonroad_rp.utility.utils_coordinate_system import CoordinateSystem

        self.scenario, problems = CommonRoadFileReader(msg["map"]).open()
        self.net = self.scenario.lanelet_network
        route = msg["route"]
        self.route_lanes = route["lanes"]
        self.lanelets = [int(x) for x in route["lanes_in_format"]]
        self.junction_of_lane = route["junction_of_lane"]
        self.limits = route["speed_limits"]
        self.ego_len, self.ego_wid = float(msg["ego"]["length"]), float(msg["ego"]["width"])
        self.lanelet_of = {k: int(v) for k, v in (msg.get("ids") or {}).get("lanes", {}).items() if v is not None}
        self.lane_paths: dict[int, tuple[np.ndarray, np.ndarray]] = {}  # lanelet -> its path ahead (_lane_path)
        self.full_stop = msg.get("rules", {}).get("full_stop")  # protocol 2: what counts as a full stop
        config = ReactivePlannerConfiguration()
        config.debug.multiproc = False  # its worker pool dies and hangs the parent (issue 22)
        config.debug.logging_level = "ERROR"
        config.debug.show_plots = config.debug.save_plots = config.debug.draw_traj_set = False
        config.planning.dt = DT
        config.planning.time_steps_computation = HORIZON_STEPS
        config.planning.__post_init__()
        config.sampling.num_sampling_levels = SAMPLING_LEVELS
        config.sampling.d_min, config.sampling.d_max = -LATERAL_RANGE_M, LATERAL_RANGE_M
        config.vehicle.length, config.vehicle.width = self.ego_len, self.ego_wid
        pp = next(iter(problems.planning_problem_dict.values()))  # any: the planner needs one to start
        config.update(scenario=self.scenario, planning_problem=pp)
        # the planner's single-track model is the simulated ego's axles, as init.vehicle describes
        # them (along the heading from the body's centre); its steering and steering-rate limits
        # stay the default vehicle's (an adapter choice: with the ego's 35 degrees, kappa <= 0.24,
        # every sample of a slow correction inside a junction broke the curvature check and the
        # ego stood there; the env clips the tracker's steering to its own limit)
        vehicle = msg["vehicle"]
        config.vehicle.wb_front_axle, config.vehicle.wb_rear_axle = float(vehicle["front_axle"]), -float(vehicle["rear_axle"])
        config.vehicle._update_computed_params()
        self.config = config
        self.wb_rear = config.vehicle.wb_rear_axle
        self.full_ref = self._reference_path(pp)
        self.full_cum = _arc(self.full_ref)
        self._clcs = lambda path: CoordinateSystem(reference=path, preprocess_reference=True, clcs_params=CLCSParams())
        self.planner = None
        self._set_window(0.0)
        _, self.boundary = create_road_boundary_obstacle(self._near_route(), method="obb_rectangles")
        self.planner = _planner_class(ReactivePlanner, self.boundary)(config)
        self.planner.set_reference_path(coordinate_system=self.co)
        # where each route lanelet ends along the reference path, in route order (a route that
        # comes back onto its own lanes, a loop, passes a lanelet's end twice)
        ends = [self.net.find_lanelet_by_id(lid).center_vertices[-1] for lid in self.lanelets]
        self.lane_end = []
        for end, s_path in zip(ends, _ends_in_order(ends, self.full_ref, self.full_cum)):
            s_frame = self._s_of(end) if s_path < self.win_end else math.nan
            # the frame's arc length where it agrees with the path's (it runs along the smoothed path)
            self.lane_end.append(s_frame if abs(s_frame - s_path) < 2.0 else s_path)
        self.gate = None
        self.stall_room = 0.0  # [m] how far the ego may creep on this step if the planner stalls (_fallback)
        self.last_plan: tuple[float, list[float]] | None = None  # (t, steering angle per DT) of the last plan
        self.last_pts: list[dict] | None = None  # the last trajectory sent (the fallback follows its rest)
        _debug(f"init {json.dumps(msg)}")

    def _reference_path(self, pp) -> np.ndarray:
        """commonroad-route-planner's reference path from the route's first lanelet to the
        continuation past its last; our route's lanelets (and their continuations) when the
        route planner's path leaves them."""
        first = self.net.find_lanelet_by_id(self.lanelets[0])
        last = self.net.find_lanelet_by_id(self.lanelets[-1])
        tail = [s for s in last.successor]
        head = [p for p in first.predecessor if not self.net.find_lanelet_by_id(p).predecessor]
        own = head[:1] + self.lanelets + tail[:1]
        try:
            path = self._route_planner_path(own)
        except Exception as exc:  # noqa: BLE001 (a third-party failure: fall back, say so)
            print(f"route planner failed ({type(exc).__name__}: {exc}); using the route's lanelets", file=sys.stderr)
            path = None
        if path is not None and not _aligned(path):
            print("route planner's reference path turns back on itself; using the route's lanelets", file=sys.stderr)
            path = None
        if path is None:
            pts = [self.net.find_lanelet_by_id(x).center_vertices for x in own]
            path = _distinct(np.concatenate([pts[0]] + [p[1:] for p in pts[1:]]))
        return np.asarray(path, dtype=float)

    def _near_route(self):
        """A scenario of the lanelets within BOUNDARY_REACH_M of the reference path: its road
        boundary is the whole map's wherever the planner's samples can reach (any edge the cut
        makes lies beyond a lanelet that does not come that close), and building it costs
        seconds rather than the 75-90 s the whole of SF's 1,618 lanelets took."""
        from commonroad.scenario.lanelet import LaneletNetwork
        from commonroad.scenario.scenario import Scenario
        from shapely.geometry import LineString

        area = LineString(self.full_ref).buffer(BOUNDARY_REACH_M)
        near = [ll for ll in self.net.lanelets if ll.polygon.shapely_object.intersects(area)]
        scenario = Scenario(dt=DT)
        with warnings.catch_warnings():  # commonroad-io compares stop lines with None as it copies
            warnings.simplefilter("ignore", UserWarning)
            scenario.add_objects(LaneletNetwork.create_from_lanelet_list(near, cleanup_ids=True))
        return scenario

    def _route_planner_path(self, own: list[int]):
        from commonroad.common.util import Interval
        from commonroad.planning.goal import GoalRegion
        from commonroad.planning.planning_problem import PlanningProblem
        from commonroad.scenario.state import CustomState, InitialState
        from commonroad_route_planner.reference_path_planner import ReferencePathPlanner
        from commonroad_route_planner.route_planner import RoutePlanner

        start = self.net.find_lanelet_by_id(own[0]).center_vertices
        k = max(0, len(start) // 2 - 1)
        h = math.atan2(*(start[k + 1] - start[k])[::-1])
        init = InitialState(position=np.array(start[k]), orientation=h, velocity=0.0, acceleration=0.0,
                            yaw_rate=0.0, slip_angle=0.0, time_step=0)
        goal_ll = self.net.find_lanelet_by_id(own[-1])
        goal = GoalRegion([CustomState(time_step=Interval(0, 10000), position=goal_ll.polygon)], {0: [own[-1]]})
        pp = PlanningProblem(999_999, init, goal)
        routes = RoutePlanner(self.net, pp).plan_routes()
        ref = ReferencePathPlanner(self.net, pp, routes).plan_shortest_reference_path()
        if list(ref.lanelet_ids) != [x for x in own if x in ref.lanelet_ids] or not set(self.lanelets) <= set(ref.lanelet_ids):
            return None  # another lane than the scenario's route
        return ref.reference_path

    def _set_window(self, s_from: float) -> None:
        """The planner's reference path: the route's path from WINDOW_BACK_M behind `s_from` as
        far as its unwrapped orientation stays inside the curvilinear frame's [-2pi, 2pi] (an
        adapter choice: a route that turns more than about a full circle, e.g. several lefts in
        a row, trips commonroad-clcs's assertion "Reference path orientations should be in
        [-2pi, 2pi]" at init, issue 22's error outcome). The window moves on when the ego comes
        within WINDOW_AHEAD_M of its end; the whole route fits one window almost always.
        A window also ends before its path comes back within SELF_GAP_M of an earlier part of it
        (a route that loops back onto its own lanes: M2's m2-r000 starts on R0_1 and ends on it;
        over the whole loop the frame projected the ego onto either pass, 360 m apart, so its
        stop line, its speed and the planner's own start jumped between them)."""
        ref, cum = self.full_ref, self.full_cum
        i0 = max(0, int(np.searchsorted(cum, s_from - WINDOW_BACK_M)) - 1)
        seg = np.diff(ref[i0:], axis=0)
        theta = np.unwrap(np.arctan2(seg[:, 1], seg[:, 0]))
        bad = np.nonzero(np.abs(theta) > 2 * math.pi - WINDOW_THETA_MARGIN)[0]
        i1 = len(ref) if not len(bad) else i0 + int(bad[0])  # the window's points are ref[i0:i1]
        back = _comes_back(ref[i0:i1], cum[i0:i1])
        if back is not None:  # a loop: the window ends before the path comes back onto itself
            i1 = i0 + back
        i1 = max(i1, min(i0 + 3, len(ref)))
        self.win_i = (i0, i1)
        self.ref = ref[i0:i1]
        self.win_end = math.inf if i1 >= len(ref) else float(cum[i1 - 1])
        self.co = self._clcs(self.ref)
        # the frame's arc length + win_s0 = the route's (its preprocessing extends the path's start)
        self.win_s0 = float(cum[i0]) - float(self.co.convert_to_curvilinear_coords(*map(float, ref[i0]))[0])
        if self.planner is not None:
            self.planner.set_reference_path(coordinate_system=self.co)

    def _s_of(self, p) -> float:
        """The route's arc length (over the whole reference path) nearest `p`."""
        try:
            return self.win_s0 + float(self.co.convert_to_curvilinear_coords(float(p[0]), float(p[1]))[0])
        except Exception:  # noqa: BLE001 (outside the frame's domain): the nearest point of the window
            i0, i1 = self.win_i
            d = np.hypot(*(self.full_ref[i0:i1] - np.asarray(p)[:2]).T)
            return float(self.full_cum[i0 + int(np.argmin(d))])

    # ---- step ---------------------------------------------------------------------------------
    def _switch(self, ctx: str) -> None:
        if self.cov is not None and ctx != self.context:
            self.context = ctx
            self.cov.switch_context(ctx)

    def step(self, msg: dict) -> dict:
        self._switch(msg.get("junction") or self.context or ROAD_CONTEXT)
        ego = msg["ego"]
        if self.gate is None:
            self.gate = RuleGate(msg, self.route_lanes, self.junction_of_lane, self.lane_end, self.ego_len,
                                 full_stop=self.full_stop)
        try:
            return self._plan(msg, ego)
        except Exception as exc:  # noqa: BLE001 (the planner under test failed: brake, and say why)
            name = type(exc).__name__
            self.failures[name] = self.failures.get(name, 0) + 1
            if self.failures[name] <= 3 or self.failures[name] % 20 == 0:
                p = self.planner
                print(f"t={msg['t']:.1f}: reactive planner raised {name}: {exc} (rejected: "
                      f"{p.infeasible_count_kinematics} kinematics {dict(p.infeasible_reason_dict)}, "
                      f"{p.infeasible_count_collision} collision of {p.total_count_samples}; "
                      f"{len(msg.get('vehicles', []))} vehicles, {len(msg.get('pedestrians', []))} pedestrians)",
                      file=sys.stderr)
                if self.failures[name] <= 1:
                    traceback.print_exc(limit=3, file=sys.stderr)
            if os.environ.get("CR_ADAPTER_LOG"):
                _debug(f"t={msg['t']:.1f} v={float(ego['speed']):.2f} raised {name}: {_rejected(self.planner)}")
            return self._fallback(msg, ego, f"FALLBACK_{name}"[:40])

    def _plan(self, msg: dict, ego: dict) -> dict:
        import commonroad_dc.pycrcc as pycrcc
        from commonroad.scenario.state import InitialState
        from commonroad_rp.state import ReactivePlannerState

        self.stall_room = 0.0
        x, y, h, v = float(ego["x"]), float(ego["y"]), float(ego["heading"]), max(float(ego["speed"]), 0.0)
        s_centre = self._s_of((x, y))
        if s_centre > self.win_end - WINDOW_AHEAD_M:
            self._set_window(s_centre)
            s_centre = self._s_of((x, y))
        stop, why = self.gate.stop_s(msg, s_centre, v)
        queue = s_centre + self._free_ahead(msg, s_centre, slower_than=QUEUE_MPS)
        if queue < stop:  # the back of a queue (M3's m3-r018 swerved past one waiting at a red light)
            stop, why = queue, "QUEUE"
        room = stop - s_centre
        free = self._free_ahead(msg, s_centre)  # room behind any road user on the path (the creeps' limit)
        self.stall_room = min(room, free, STALL_CREEP_M)  # _fallback's creep
        if math.isfinite(stop) and room > v * v / (2 * APPROACH_DECEL) + STOPPING_RANGE_M:
            mode, stage = "approach", f"APPROACH_{why}"  # far from the stop point
        elif math.isfinite(stop):
            mode, stage = "stopping", f"STOPPING_{why}"
        else:
            mode, stage = "keeping", "VELOCITY_KEEPING"
        # moving off: the planner starts from at least ENGAGE_MPS (an adapter choice, as Autoware's
        # engage velocity: from v = 0 its first samples are coincident points whose finite-
        # difference curvature breaks its kappa_dot/acceleration checks, so every sample is
        # rejected and the ego never moves off; issue 22's standstill timeouts)
        if mode == "stopping" and v < ENGAGE_MPS and room > CREEP_ROOM_M:
            # halted short of its stop point (the fallback's braking): the planner's "stopping"
            # samples from here all broke its checks and the ego stood outside the full-stop
            # zone for good (issue 33): creep on to the point
            return self._creep(msg, ego, f"CREEP_{why}", min(room, free))
        if mode == "stopping" and room > _stop_reach(v):
            # the planner's "stopping" samples end at the target, at rest, within its horizon: one
            # further than a smooth stop from v reaches first speeds up (M2's m2-r001 went from 9.5 to
            # 10.4 m/s at an amber light 22 m ahead, then could not stop before it). Until the
            # target is within reach: velocity keeping at the speed a constant deceleration to it
            # has at the horizon's end
            mode = "braking"
        v_plan = max(v, ENGAGE_MPS) if mode != "stopping" else v
        acc = float(ego.get("acceleration", 0.0)) if v > 0.1 else 0.0  # a stopped car does not decelerate
        init = InitialState(position=np.array([x, y]), orientation=h, velocity=v_plan, acceleration=acc,
                            yaw_rate=0.0, slip_angle=0.0, time_step=0)
        x0 = ReactivePlannerState.create_from_initial_state(init, self.config.vehicle.wheelbase, self.wb_rear)
        x0.steering_angle = self._steering_now(float(msg["t"]), x, y)
        x0.yaw_rate = v_plan * math.tan(x0.steering_angle) / self.config.vehicle.wheelbase
        cc = pycrcc.CollisionChecker()
        cc.add_collision_object(self.boundary)
        obstacles = self._obstacles(msg, x, y, h)
        for obs in obstacles:
            cc.add_collision_object(obs)
        p = self.planner
        p.reset(initial_state_cart=x0, collision_checker=cc, coordinate_system=self.co)
        if mode == "stopping":
            self.config.sampling.longitudinal_mode = "stopping"
            p.set_desired_lon_position(max(stop - self.win_s0 - self.wb_rear, p.x_0_cl[0][0]))
        else:
            if mode == "approach":  # keep a speed from which it can still stop there comfortably
                cap = math.sqrt(2 * APPROACH_DECEL * max(room - STOPPING_RANGE_M, 0.0)) + 1.0
                desired = min(self._desired_speed(s_centre), cap)
            elif mode == "braking":
                desired = _braking_speed(room, v)
            else:
                desired = self._desired_speed(s_centre)
            self.config.sampling.longitudinal_mode = "velocity_keeping"
            p.set_desired_velocity(desired, current_speed=v_plan)
        result = p.plan()
        if os.environ.get("CR_ADAPTER_LOG"):
            ref_h = float(np.interp(p.x_0_cl[0][0], self.co.ref_pos, np.unwrap(self.co.ref_theta)))
            _debug(f"t={msg['t']:.1f} v={v:.2f} s={s_centre:.1f} d={p.x_0_cl[1][0]:.2f} heading error={h - ref_h:.2f} "
                   f"steer={x0.steering_angle:.3f} stop={stop:.1f} {stage} trajectory={result is not None}: {_rejected(p)}")
        if result is None:
            return self._fallback(msg, ego, "FALLBACK_NO_TRAJECTORY")
        states = result[0].state_list
        if all(st.velocity < 0.05 for st in states) and v < 0.05:
            stage = "STANDSTILL" if stage == "VELOCITY_KEEPING" else stage
        t0 = float(msg["t"])
        self.last_plan = (t0, [float(st.steering_angle) for st in states])
        pts = []
        for st in states:
            c = ReactivePlannerState.shift_state_to_center(st, self.wb_rear)
            pts.append({"t": t0 + (st.time_step - states[0].time_step) * DT, "x": float(c.position[0]),
                        "y": float(c.position[1]), "heading": float(c.orientation), "speed": max(float(c.velocity), 0.0)})
        self.last_pts = pts
        return {"type": "trajectory", "points": pts, "scenario": "REACTIVE", "stage": stage}

    def _fallback(self, msg: dict, ego: dict, stage: str) -> dict:
        """No trajectory this time: brake at FALLBACK_DECEL along the path of the last trajectory
        while it reaches past the braking distance (an adapter choice: the last feasible plan's
        path, as a planner's own loop keeps it through a failed cycle; its speeds are not kept,
        since it was planned without the obstacles seen now), else along the reference path.
        The stage says FALLBACK_<why> either way. From (near) standstill, where nothing holds
        the ego within STALL_CREEP_M, it creeps on instead (CREEP_STALLED)."""
        t, v = float(msg["t"]), max(float(ego["speed"]), 0.0)
        if v < ENGAGE_MPS and self.stall_room > CREEP_ROOM_M:
            # stalled: from (near) standstill with a heading error inside a tight turn every sample
            # broke the planner's curvature-rate check (commonroad_rp/reactive_planner.py:1088-1094)
            # and the ego stood there for good (M4's m4-r000, SF's sf-r000): creep on along the path
            self.last_plan = self.last_pts = None
            return self._creep(msg, ego, "CREEP_STALLED", self.stall_room)
        rest = [q for q in (self.last_pts or []) if q["t"] >= t - DT / 2]
        if len(rest) >= 3:
            path = _distinct(np.array([[float(ego["x"]), float(ego["y"])]] + [[q["x"], q["y"]] for q in rest]))
            cum = _arc(path)
            if len(path) >= 2 and cum[-1] >= v * v / (2 * FALLBACK_DECEL) + 0.5:
                return self._brake(msg, ego, stage, path, cum)
        self.last_plan = self.last_pts = None
        return self._brake(msg, ego, stage, self.full_ref, self.full_cum)

    def _steering_now(self, t: float, x: float, y: float) -> float:
        """The steering angle the ego drives with now (the bridge sends no yaw rate): the angle the
        last trajectory planned for this instant, else the one that follows the reference path's
        curvature where the ego is. An adapter choice: from a measured state alone the planner
        assumes straight wheels (steering from yaw rate 0), and in a junction's curve every
        sample then starts with a curvature jump it rejects (kappa/kappa_dot), at low speed all
        of them (issue 22's standstill timeouts)."""
        delta_max = float(self.config.vehicle.delta_max)
        if self.last_plan is not None:
            t0, deltas = self.last_plan
            k = int(round((t - t0) / DT))
            if 0 <= k < len(deltas):
                return float(np.clip(deltas[k], -delta_max, delta_max))
        ref_s, ref_k = np.asarray(self.co.ref_pos) + self.win_s0, np.asarray(self.co.ref_curv)
        kappa = float(np.interp(self._s_of((x, y)), ref_s, ref_k))
        return float(np.clip(math.atan(self.config.vehicle.wheelbase * kappa), -delta_max, delta_max))

    def _free_ahead(self, msg: dict, s_ego: float, slower_than: float = math.inf) -> float:
        """Metres the ego's centre can move on along the reference path before it comes within
        CREEP_GAP_M of a road user ahead on its path (inf when none; vehicles only, and only
        those slower than `slower_than` when given): the creep is the adapter's own trajectory,
        which the planner's collision check never sees (M2's m2-r000 crept into the car queued
        at J1's red light)."""
        free = math.inf
        for kind in ("vehicles", "pedestrians") if slower_than == math.inf else ("vehicles",):
            for o in msg.get(kind, []):
                if float(o["speed"]) >= slower_than:
                    continue
                try:
                    s, d = self.co.convert_to_curvilinear_coords(float(o["x"]), float(o["y"]))
                except Exception:  # noqa: BLE001 (outside the frame's domain: not on the path)
                    continue
                s += self.win_s0
                length, width = float(o.get("length", 0.8)), float(o.get("width", 0.8))
                if s > s_ego and abs(d) < (self.ego_wid + width) / 2 + 0.5:
                    free = min(free, s - s_ego - (self.ego_len + length) / 2 - CREEP_GAP_M)
        return max(free, 0.0)

    def _desired_speed(self, s: float) -> float:
        i = int(np.searchsorted(self.lane_end, s))
        i = min(i, len(self.limits) - 1)
        v = float(self.limits[i])
        if self.junction_of_lane[i] or (i + 1 < len(self.junction_of_lane) and self.junction_of_lane[i + 1]
                                        and self.lane_end[i] - s < 30.0):
            v = min(v, JUNCTION_SPEED_MPS)
        # curvature of the reference over the next 25 m
        ref_s, ref_k = np.asarray(self.co.ref_pos) + self.win_s0, np.abs(np.asarray(self.co.ref_curv))
        window = (ref_s >= s) & (ref_s <= s + 25.0)
        if window.any():
            kmax = float(ref_k[window].max())
            if kmax > 1e-3:
                v = min(v, max(3.0, math.sqrt(LAT_ACC_MPS2 / kmax)))
        return v

    def _obstacles(self, msg: dict, ex: float, ey: float, eh: float):
        from commonroad.geometry.shape import Rectangle
        from commonroad.prediction.prediction import TrajectoryPrediction
        from commonroad.scenario.obstacle import DynamicObstacle, ObstacleType
        from commonroad.scenario.state import CustomState, InitialState
        from commonroad.scenario.trajectory import Trajectory
        from commonroad_dc.collision.collision_detection.pycrcc_collision_dispatch import create_collision_object

        out = []
        fwd = np.array([math.cos(eh), math.sin(eh)])
        for kind in ("vehicles", "pedestrians"):
            for o in msg.get(kind, []):
                rel = np.array([o["x"] - ex, o["y"] - ey])
                if np.hypot(*rel) > OBSTACLE_RADIUS_M or float(rel @ fwd) < -self.ego_len / 2:
                    continue  # far, or behind the ego: its business to keep its distance
                length = float(o.get("length", 0.8))
                width = float(o.get("width", 0.8))
                h, v = float(o["heading"]), float(o["speed"])
                poses = self._predict(o, h, v, HORIZON_STEPS + 2)
                states = [CustomState(time_step=k, position=poses[k, :2], orientation=float(poses[k, 2]), velocity=v)
                          for k in range(1, HORIZON_STEPS + 2)]
                shape = Rectangle(length, width)
                init = InitialState(position=np.array([o["x"], o["y"]]), orientation=h, velocity=v, time_step=0,
                                    acceleration=0.0, yaw_rate=0.0, slip_angle=0.0)
                dyn = DynamicObstacle(100_000 + int(o["id"]),
                                      ObstacleType.CAR if kind == "vehicles" else ObstacleType.PEDESTRIAN, shape, init,
                                      TrajectoryPrediction(Trajectory(1, states), shape))
                out.append(create_collision_object(dyn))
        return out

    def _predict(self, o: dict, h: float, v: float, n: int) -> np.ndarray:
        """(x, y, heading) of road user `o` at each of n steps of DT from now, at its speed: along
        its lane and the lanes that follow it where they do not branch, when it drives along its
        lane (within PREDICT_LAT_M of its centreline, heading within PREDICT_HEADING_RAD of it),
        then straight on; otherwise straight along its heading. A car turning inside a junction
        was predicted straight down the ego's lane (M3's m3-r000, m3-r011): every sample in the
        lane collided with it and the planner swerved into the oncoming lane."""
        p = np.array([float(o["x"]), float(o["y"])])
        steps = np.arange(n) * DT * v
        path = self._lane_path(self.lanelet_of.get(o.get("lane"))) if o.get("lane") is not None else None
        if path is not None:
            pts, cum = path
            s0, lat, hl = _project(pts, cum, p)
            if abs(lat) < PREDICT_LAT_M and abs(_wrap(h - hl)) < PREDICT_HEADING_RAD:
                return _poses_along(pts, cum, s0 + steps)
        return np.column_stack([p[0] + steps * math.cos(h), p[1] + steps * math.sin(h), np.full(n, h)])

    def _lane_path(self, lanelet: int | None) -> tuple[np.ndarray, np.ndarray] | None:
        """The centreline of `lanelet` and of its successors while each has just one, up to
        PREDICT_AHEAD_M past the lanelet's end (points, arc lengths); once per lanelet."""
        if lanelet is None:
            return None
        if lanelet not in self.lane_paths:
            try:
                ll = self.net.find_lanelet_by_id(lanelet)
            except Exception:  # noqa: BLE001 (an id the map does not have: predict straight)
                ll = None
            if ll is None:
                return None
            parts, ahead = [ll.center_vertices], 0.0
            while len(ll.successor) == 1 and ahead < PREDICT_AHEAD_M and len(parts) < 64:  # (a ring of empty lanelets)
                ll = self.net.find_lanelet_by_id(ll.successor[0])
                parts.append(ll.center_vertices[1:])
                ahead += float(np.hypot(*np.diff(ll.center_vertices, axis=0).T).sum())
            pts = _distinct(np.concatenate(parts))
            if len(pts) < 2:
                return None
            self.lane_paths[lanelet] = (pts, _arc(pts))
        return self.lane_paths[lanelet]

    def _brake(self, msg: dict, ego: dict, stage: str, ref: np.ndarray, cum: np.ndarray) -> dict:
        """Brake at FALLBACK_DECEL along the polyline `ref` (arc lengths `cum`) from where the ego is."""
        v = max(float(ego["speed"]), 0.0)
        profile = []
        for i in range(HORIZON_STEPS + 1):
            t = i * DT
            vi = max(v - FALLBACK_DECEL * t, 0.0)
            profile.append((vi, v * t - FALLBACK_DECEL * t * t / 2 if vi > 0 else v * v / (2 * FALLBACK_DECEL)))
        return self._along(msg, ego, stage, ref, cum, profile)

    def _creep(self, msg: dict, ego: dict, stage: str, room: float) -> dict:
        """Creep `room` metres on along the reference path at up to ENGAGE_MPS and stop there (an
        adapter choice, as Autoware's creep to a stop line: from a standstill short of its stop
        point the planner rejects every "stopping" sample, its few metres from v = 0 breaking
        its curvature and acceleration checks)."""
        profile, v, done = [], max(float(ego["speed"]), 0.0), 0.0
        for _ in range(HORIZON_STEPS + 1):
            profile.append((v, done))
            done = min(done + v * DT, room)
            v = min(ENGAGE_MPS, v + FALLBACK_DECEL * DT, math.sqrt(2 * FALLBACK_DECEL * max(room - done, 0.0)))
        return self._along(msg, ego, stage, self.full_ref, self.full_cum, profile)

    @staticmethod
    def _along(msg: dict, ego: dict, stage: str, ref: np.ndarray, cum: np.ndarray,
               profile: list[tuple[float, float]]) -> dict:
        """A trajectory along the polyline `ref` (arc lengths `cum`) from the point nearest the ego,
        one point per DT of `profile`'s (speed, metres from the start)."""
        k = int(np.argmin(np.hypot(*(ref - np.array([ego["x"], ego["y"]])).T)))
        pts = []
        for i, (vi, ds) in enumerate(profile):
            si = cum[k] + ds
            px, py = np.interp(si, cum, ref[:, 0]), np.interp(si, cum, ref[:, 1])
            j = min(int(np.searchsorted(cum, si)), len(ref) - 1)
            a, b = ref[max(j - 1, 0)], ref[max(j, 1)]
            pts.append({"t": float(msg["t"]) + i * DT, "x": float(px), "y": float(py),
                        "heading": float(math.atan2(b[1] - a[1], b[0] - a[0])), "speed": float(vi)})
        return {"type": "trajectory", "points": pts, "scenario": "REACTIVE", "stage": stage}

    # ---- close --------------------------------------------------------------------------------
    def close(self) -> dict:
        if self.cov is None:
            return {}
        self.cov.stop()
        data = self.cov.get_data()
        lines: dict[str, set[str]] = {}
        files = {}
        for fname in data.measured_files():
            mod = _module_name(fname)
            if mod is None:
                continue
            files[fname] = mod
            for line, ctxs in data.contexts_by_lineno(fname).items():
                for ctx in ctxs:
                    if ctx:
                        lines.setdefault(ctx, set()).add(f"{mod}:{line}")
        import commonroad_rp

        h = hashlib.sha256()
        root = Path(commonroad_rp.__file__).parent
        for f in sorted(root.rglob("*.py")):
            h.update(str(f.relative_to(root)).encode() + b"\0" + f.read_bytes())
        return {"coverage": {"lines": {k: sorted(v) for k, v in lines.items()}, "digest": h.hexdigest()[:16]}}


def _debug(line: str) -> None:
    """One line per decision to $CR_ADAPTER_LOG (a diagnostic for single scenarios; off by default)."""
    path = os.environ.get("CR_ADAPTER_LOG")
    if path:
        with open(path, "a") as f:
            f.write(line + "\n")


def _rejected(p) -> str:
    """How many of the planner's samples its last plan() rejected, and why."""
    return (f"rejected {p.infeasible_count_kinematics} for kinematics {dict(p.infeasible_reason_dict)}, "
            f"{p.infeasible_count_collision} for collisions, of {p.total_count_samples}")


def _planner_class(base: type, boundary) -> type:
    """The reactive planner with the adapter's road boundary: its constructor (and any reset
    without a collision checker) builds its own from the whole scenario, never used since every
    plan gets the adapter's checker; on SF's 1,618 lanelets that took 45 s of the start."""

    class Planner(base):
        def set_collision_checker(self, scenario=None, collision_checker=None, road_boundary_obstacle=None):
            if collision_checker is None and road_boundary_obstacle is None:
                road_boundary_obstacle = boundary
            super().set_collision_checker(scenario, collision_checker, road_boundary_obstacle)

    return Planner


def _distinct(pts: np.ndarray) -> np.ndarray:
    """The polyline `pts` without the points within 1 mm of the one before (zero-length segments)."""
    return pts[np.concatenate([[True], np.hypot(*np.diff(pts, axis=0).T) > 1e-3])]


def _arc(pts: np.ndarray) -> np.ndarray:
    """The arc length at each point of the polyline `pts`."""
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pts, axis=0).T))])


def _feet(pts: np.ndarray, cum: np.ndarray, p: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(arc length, distance) of the point `p`'s foot on each segment of the polyline `pts`
    (arc lengths `cum`)."""
    a, ab = pts[:-1], np.diff(pts, axis=0)
    seg2 = np.maximum((ab ** 2).sum(axis=1), 1e-12)
    u = np.clip(((p - a) * ab).sum(axis=1) / seg2, 0.0, 1.0)
    return cum[:-1] + u * np.sqrt(seg2), np.hypot(*(a + u[:, None] * ab - p).T)


def _project(pts: np.ndarray, cum: np.ndarray, p: np.ndarray) -> tuple[float, float, float]:
    """(arc length, signed lateral offset, heading) of the point of the polyline `pts` nearest `p`."""
    s, d = _feet(pts, cum, p)
    k = int(np.argmin(d))
    (x0, y0), (x1, y1) = pts[k], pts[k + 1]
    side = (x1 - x0) * (p[1] - y0) - (y1 - y0) * (p[0] - x0)
    return float(s[k]), math.copysign(float(d[k]), side), math.atan2(y1 - y0, x1 - x0)


def _poses_along(pts: np.ndarray, cum: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(x, y, heading) at arc lengths `s` along the polyline `pts`, straight on past its end."""
    k = np.clip(np.searchsorted(cum, s, side="right") - 1, 0, len(pts) - 2)
    d = pts[k + 1] - pts[k]
    seg = np.maximum(cum[k + 1] - cum[k], 1e-9)
    u = (s - cum[k]) / seg
    xy = pts[k] + u[:, None] * d
    return np.column_stack([xy, np.arctan2(d[:, 1], d[:, 0])])


def _wrap(a: float) -> float:
    return (a + math.pi) % (2 * math.pi) - math.pi


def _stop_reach(v: float) -> float:
    """How far ahead of the ego a stop target may lie for the planner's "stopping" mode: a smooth
    (minimum-jerk) stop from `v` within the horizon covers v * horizon / 2; its samples end at
    the target at rest within the horizon, so a target further away makes them speed up first.
    Never less than STOP_REACH_MIN_M: the "braking" mode's desired speed falls with the room
    left, and at low speed the reach is a few metres, so with the reach alone the ego slowed to
    about 1 m/s 7 m before a stop sign and crawled up to it, braking and creeping in turn (5-8 s
    more per stop; M1's m1-r027 timed out; m1-r011 and m1-r024, at the line 5 s later, collided
    in the junction with crossing traffic they had missed before). Speeding up first that close
    to the target is slight (m1-r011: 2.1 to 3.8 m/s 8 m before the stop sign, then at rest on
    its line)."""
    return max(v * HORIZON_STEPS * DT / 2 + STOP_REACH_MARGIN_M, STOP_REACH_MIN_M)


def _braking_speed(room: float, v: float) -> float:
    """The speed at the horizon's end of a constant deceleration from `v` to rest `room` ahead."""
    horizon = HORIZON_STEPS * DT
    if room <= 0.0:
        return 0.0
    return max(v - v * v / (2 * room) * horizon, 0.0)


def _comes_back(pts: np.ndarray, cum: np.ndarray) -> int | None:
    """The index of the first point of the path `pts` (arc lengths `cum`) that lies within
    SELF_GAP_M of a point at least SELF_ARC_M behind it along the path (the path loops back
    onto itself), or None."""
    pts, cum = np.asarray(pts, dtype=float), np.asarray(cum, dtype=float)
    for k0 in range(0, len(pts), 256):  # in blocks: a long route's pairwise distances stay small
        blk = slice(k0, min(k0 + 256, len(pts)))
        d = np.hypot(*(pts[blk, None, :] - pts[None, :, :]).transpose(2, 0, 1))
        close = (d < SELF_GAP_M) & (cum[blk, None] - cum[None, :] > SELF_ARC_M)
        hit = np.nonzero(close.any(axis=1))[0]
        if len(hit):
            return k0 + int(hit[0])
    return None


def _ends_in_order(points, ref: np.ndarray, cum: np.ndarray) -> list[float]:
    """The arc lengths along the polyline `ref` (arc lengths `cum`) nearest each of `points` in
    turn, each at or after the one before (a route that passes a place twice, a loop, has its
    lanes' ends in route order, not all at the pass that happens to be nearest)."""
    ref, cum = np.asarray(ref, dtype=float), np.asarray(cum, dtype=float)
    out, s_min = [], 0.0
    for p in points:
        s, d = _feet(ref, cum, np.asarray(p, dtype=float)[:2])
        d[s < s_min - 1e-6] = np.inf  # not behind the last one
        k = int(np.nonzero(d <= d.min() + 0.5)[0][0])  # the first pass of the nearest (a loop's two tie)
        out.append(float(s[k]))
        s_min = out[-1]
    return out


def _aligned(path, max_turn: float = math.pi / 2) -> bool:
    """No two consecutive segments of `path` turn more than `max_turn` (CLCS's own check)."""
    d = np.diff(np.asarray(path, dtype=float), axis=0)
    d = d[np.hypot(*d.T) > 1e-6]
    h = np.arctan2(d[:, 1], d[:, 0])
    return bool(len(h) < 2 or np.all(np.abs((np.diff(h) + np.pi) % (2 * np.pi) - np.pi) < max_turn))


def _module_name(fname: str) -> str | None:
    parts = Path(fname).with_suffix("").parts
    for pkg in COVERED_PACKAGES:
        if pkg in parts:
            mod = ".".join(parts[parts.index(pkg):])
            return mod[: -len(".__init__")] if mod.endswith(".__init__") else mod
    return None


if __name__ == "__main__":
    os.environ.setdefault("MPLBACKEND", "Agg")
    sys.exit(serve(ReactiveAdapter()))
