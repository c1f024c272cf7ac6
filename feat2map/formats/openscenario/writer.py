"""Write a scenario suite as ASAM OpenSCENARIO XML 1.3: one `.xosc` per scenario beside the
OpenDRIVE export of its map, built with `scenariogeneration` (the xosc object model) and
checked by asam-qc-openscenarioxml in the tests.

What a scenario becomes (the env's model with its defaults, `feat2map.config.DRIVE_DEFAULTS`, under
the scenario's own `env` settings, drawn once from the scenario's seed, and no wall-clock date: the
same suite gives the same bytes):
- the ego starts `ego_start_distance` before the end of the road lane leading into its first
  manoeuvre at `ego_initial_speed`, with an `AssignRouteAction` whose waypoints are the
  junction lanes the env drives for each manoeuvre (`feat2map.routes.manoeuvre_lane`) and the goal
  `goal_distance` into the last exit lane; the storyboard stops at the goal or at `duration`;
- `traffic_vehicles` cars on road lanes at `traffic_initial_speed`, spread at random;
- pedestrians cross the crosswalks of the route's junctions as the env spawns them: Poisson
  arrivals at `pedestrian_rate` per minute, random direction, lateral offset and speed, at
  most `pedestrians_per_crosswalk` on one crosswalk at once; each waits at the kerb until its
  arrival time, then follows a two-point trajectory across;
- every signalized junction is a `TrafficSignalController` cycling the env's phase plan
  (`feat2map.phases`: green, amber, all-red per phase), started at the junction's offset
  (`signal_offsets`, else a uniform draw over the cycle). Signal states are the three lamps
  red;amber;green as on/off, and name the OpenDRIVE signal ids of the exported map.
"""
from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from datetime import datetime, timezone
from pathlib import Path
from typing import Any

import numpy as np

from ... import atomic
from ...config import DRIVE_DEFAULTS
from ...errors import Feat2MapError
from ...model import HDMap, Lane
from ...phases import junction_phases
from ...routes import is_lane_route, manoeuvre_lane, road_lanes_between
from .. import FORMATS
from ..base import header_date

OSC_MINOR = 3  # OpenSCENARIO XML 1.3
EPOCH = datetime(1970, 1, 1, tzinfo=timezone.utc)  # the header date when SOURCE_DATE_EPOCH is unset
LAMPS = {"red": "on;off;off", "amber": "off;on;off", "green": "off;off;on"}  # red;amber;green lamps
CAR_SIZE = (4.5, 1.8, 1.5)  # length, width, height [m]
PEDESTRIAN_SIZE = (0.8, 0.8, 1.8)
TRAFFIC_CLEARANCE_M = 12.0  # between two placed cars on one lane, and from the ego
TRAFFIC_MARGIN_M = 5.0  # cars start at least this far from either end of their lane
GOAL_RADIUS_M = 2.0  # the storyboard stops when the ego is this close to the goal
_SAFE_NAME = re.compile(r"[^A-Za-z0-9._-]+")


@dataclass(frozen=True)
class _Crossing:
    """One pedestrian: where and when it starts walking across a crosswalk, and how fast."""

    name: str
    start: tuple[float, float]
    end: tuple[float, float]
    t0: float
    speed: float


def file_stem(name: str) -> str:
    """A file name for a scenario or map name (anything outside [A-Za-z0-9._-] becomes '_')."""
    return _SAFE_NAME.sub("_", name).strip("._") or "scenario"


class _ScenarioWriter:
    """Builds one scenario's xosc document against the exported map (`xodr` its file name)."""

    def __init__(self, m: HDMap, xodr: str, ids, cfg: dict) -> None:
        from scenariogeneration import xosc

        self.X = xosc
        self.m, self.xodr, self.ids, self.cfg = m, xodr, ids, cfg

    # -- positions -----------------------------------------------------------------------
    def lane_position(self, lane: Lane, distance: float):
        """The LanePosition `distance` metres along `lane` (driving direction) in the export."""
        road, odr_lane = self.ids.lanes[lane.id]
        length = self.ids.road_length[road]
        s = min(max(distance / max(lane.length, 1e-9), 0.0), 1.0) * length
        return self.X.LanePosition(_r(s if odr_lane < 0 else length - s), 0, odr_lane, road)

    def world(self, p, h: float):
        return self.X.WorldPosition(_r(p[0]), _r(p[1]), 0, _r(h))

    # -- document ------------------------------------------------------------------------
    def build(self, sc) -> bytes:
        X, cfg = self.X, self.cfg
        rng = np.random.default_rng(sc.seed)
        lanes = self.route_lanes(sc)
        init, entities = X.Init(), X.Entities()
        entities.add_scenario_object("ego", _ego(X, cfg["vehicle"]))
        start = lanes[0]
        s0 = max(0.0, start.length - float(cfg["ego_start_distance"]))  # the body's centre, as the env
        rear = s0 - _rear_offset(cfg["vehicle"])  # OpenSCENARIO's reference point: the rear axle
        init.add_init_action("ego", X.TeleportAction(self.lane_position(start, max(rear, 0.0))))
        init.add_init_action("ego", X.AbsoluteSpeedAction(float(cfg["ego_initial_speed"]), _step(X)))
        route = X.Route(f"{sc.name} route")
        route.add_waypoint(self.lane_position(start, s0), X.RouteStrategy.shortest)
        for ln in lanes[1:-1]:
            route.add_waypoint(self.lane_position(ln, ln.length / 2), X.RouteStrategy.shortest)
        goal = self.lane_position(lanes[-1], min(float(cfg["goal_distance"]), lanes[-1].length - 1.0))
        route.add_waypoint(goal, X.RouteStrategy.shortest)
        init.add_init_action("ego", X.AssignRouteAction(route))
        for k, (lane, s) in enumerate(self.traffic(sc, rng, start, s0)):
            name = f"traffic_{k + 1}"
            entities.add_scenario_object(name, _car(X, name))
            init.add_init_action(name, X.TeleportAction(self.lane_position(lane, s)))
            init.add_init_action(name, X.AbsoluteSpeedAction(float(cfg["traffic_initial_speed"]), _step(X)))
        network = X.RoadNetwork(roadfile=self.xodr)
        for controller in self.controllers(sc, rng):
            network.add_traffic_signal_controller(controller)
        crossings = self.crossings(sc, rng, lanes)
        story = self.pedestrians(crossings, entities, init) if crossings else None
        board = X.StoryBoard(init, self.stop_trigger(sc, goal))
        if story is not None:
            board.add_story(story)
        doc = X.Scenario(sc.name, "feat2map", X.ParameterDeclarations(), entities, board, network, X.Catalog(),
                         osc_minor_version=OSC_MINOR, creation_date=_file_date())
        el = doc.get_element()
        ET.indent(el)
        return ET.tostring(el, encoding="UTF-8", xml_declaration=True) + b"\n"

    def route_lanes(self, sc) -> list[Lane]:
        """The lane before the first manoeuvre, each manoeuvre's junction lane, the exit lane (a
        lane route's lanes: a ramp joined through a direct link)."""
        m = self.m
        if is_lane_route(sc.route):
            if "lanes" not in sc.route:
                raise Feat2MapError("a lane route is exported with its lanes ({lanes: [...]}), not its ends",
                                    f"{sc.name}.route")
            return [m.lanes[x] for x in sc.route["lanes"]]
        out: list[Lane] = []
        for i, mv in enumerate(sc.route):
            ln = manoeuvre_lane(m, mv)
            if ln is None:
                raise Feat2MapError(f"no junction lane drives manoeuvre {list(mv)}", f"{sc.name}.route[{i}]")
            out.append(ln)
        entry = next((m.lanes[p] for p in out[0].predecessors if m.lanes[p].junction_id is None), None)
        exit_ = next((m.lanes[s] for s in out[-1].successors if m.lanes[s].junction_id is None), None)
        if entry is None or exit_ is None:
            raise Feat2MapError("the route's first manoeuvre has no entry lane or its last no exit lane",
                                f"{sc.name}.route")
        return [entry, *out, exit_]

    def traffic(self, sc, rng, ego_lane: Lane, ego_s: float) -> list[tuple[Lane, float]]:
        """(lane, distance along it) of each traffic car: random road lanes and spots, apart."""
        cands = [ln for ln in self.m.lanes.values()
                 if ln.junction_id is None and ln.length > 2 * TRAFFIC_MARGIN_M and ln.id in self.ids.lanes]
        taken: list[tuple[str, float]] = [(ego_lane.id, ego_s)]
        out: list[tuple[Lane, float]] = []
        for _ in range(int(sc.traffic_vehicles)):
            for _try in range(50):
                if not cands:
                    break
                ln = cands[int(rng.integers(len(cands)))]
                s = float(rng.uniform(TRAFFIC_MARGIN_M, ln.length - TRAFFIC_MARGIN_M))
                if all(lid != ln.id or abs(s - t) >= TRAFFIC_CLEARANCE_M for lid, t in taken):
                    taken.append((ln.id, s))
                    out.append((ln, s))
                    break
        return out

    def controllers(self, sc, rng) -> list:
        """One TrafficSignalController per signalized junction, from its offset into the cycle."""
        X, cfg = self.X, self.cfg
        g, a, r = float(cfg["signal_green"]), float(cfg["signal_amber"]), float(cfg["signal_all_red"])
        out = []
        by_junction = junction_phases(self.m, cfg["signal_phases"] == "paired")
        for jid in sorted(by_junction, key=str):
            phases = by_junction[jid]
            sig_ids = sorted(s.id for s in self.m.signals.values() if s.junction_id == jid)
            cycle = len(phases) * (g + a + r)
            offset = float(rng.uniform(0, cycle))  # drawn always, so a fixed offset keeps the other draws
            key = next((k for k in [jid, *sig_ids] if k is not None and str(k) in sc.signal_offsets), None)
            if key is not None:
                offset = float(sc.signal_offsets[str(key)])
            plan = []  # (name, duration, {signal: state})
            for i, phase in enumerate(phases):
                for part, dur in (("green", g), ("amber", a), ("all_red", r)):
                    lit = "red" if part == "all_red" else part
                    plan.append((f"phase{i + 1}_{part}", dur, {s: lit if s in phase else "red" for s in sig_ids}))
            ctrl = X.utils.TrafficSignalController(f"junction {jid}" if jid is not None else "signals outside junctions")
            for name, dur, states in _rotate(plan, offset % cycle if cycle > 0 else 0.0):
                ph = X.Phase(name, _r(dur))
                for sid, state in states.items():
                    if sid in self.ids.signals:
                        ph.add_signal_state(self.ids.signals[sid], LAMPS[state])
                ctrl.add_phase(ph)
            out.append(ctrl)
        return out

    def crossings(self, sc, rng, lanes: list[Lane]) -> list[_Crossing]:
        """Pedestrians on the crosswalks of the route's junctions and on the mid-block ones its
        road lanes cross, as the env spawns them."""
        rate = float(sc.pedestrian_rate) / 60.0
        if rate <= 0:
            return []
        cfg = self.cfg
        junctions = {ln.junction_id for ln in lanes} - {None}
        crossed = _midblock_crossed(self.m, sc.route, lanes)
        out: list[_Crossing] = []
        for cw in self.m.crosswalks.values():
            if cw.junction_id not in junctions and cw.id not in crossed:
                continue
            a, b, width = _axis(cw.polygon)
            t = 0.0
            walking: list[float] = []  # end times of the pedestrians on this crosswalk
            while True:
                t += float(rng.exponential(1.0 / rate))
                if t >= sc.duration:
                    break
                walking = [e for e in walking if e > t]
                flip = rng.uniform() < 0.5
                off = float(rng.uniform(-0.3, 0.3)) * width
                speed = float(cfg["pedestrian_speed"] * rng.uniform(0.85, 1.15))
                if len(walking) >= int(cfg["pedestrians_per_crosswalk"]):
                    continue
                p, q = (b, a) if flip else (a, b)
                d = (q - p) / max(float(np.hypot(*(q - p))), 1e-9)
                n = np.array([-d[1], d[0]]) * off
                start, end = p + n, q + n
                walking.append(t + float(np.hypot(*(end - start))) / speed)
                out.append(_Crossing(f"pedestrian_{file_stem(cw.id)}_{len(out) + 1}", tuple(start), tuple(end),
                                     t, speed))
        return out

    def pedestrians(self, crossings: list[_Crossing], entities, init):
        """Each pedestrian waits at the kerb (init), then walks across at its arrival time: a
        story with one maneuver group per pedestrian."""
        X = self.X
        act = X.Act("crossings", X.ValueTrigger("start", 0, X.ConditionEdge.none,
                                                X.SimulationTimeCondition(0, X.Rule.greaterOrEqual)))
        for c in crossings:
            h = math.atan2(c.end[1] - c.start[1], c.end[0] - c.start[0])
            entities.add_scenario_object(c.name, X.Pedestrian(c.name, 80, X.PedestrianCategory.pedestrian,
                                                               _box(X, PEDESTRIAN_SIZE)))
            init.add_init_action(c.name, X.TeleportAction(self.world(c.start, h)))
            line = X.Polyline([0.0, _r(math.dist(c.start, c.end) / c.speed)],
                              [self.world(c.start, h), self.world(c.end, h)])
            traj = X.Trajectory(f"{c.name} path", False)
            traj.add_shape(line)
            event = X.Event(f"{c.name} crosses", X.Priority.override)
            event.add_action(f"{c.name} walks", X.FollowTrajectoryAction(
                traj, X.FollowingMode.position, X.ReferenceContext.relative, 1, 0))
            event.add_trigger(X.ValueTrigger(f"{c.name} arrives", 0, X.ConditionEdge.none,
                                             X.SimulationTimeCondition(_r(c.t0), X.Rule.greaterThan)))
            man = X.Maneuver(f"{c.name} maneuver")
            man.add_event(event)
            group = X.ManeuverGroup(f"{c.name} group")
            group.add_actor(c.name)
            group.add_maneuver(man)
            act.add_maneuver_group(group)
        story = X.Story("pedestrians")
        story.add_act(act)
        return story

    def stop_trigger(self, sc, goal):
        X = self.X
        trig = X.Trigger("stop")
        timeout = X.ConditionGroup()
        timeout.add_condition(X.ValueTrigger("duration", 0, X.ConditionEdge.rising,
                                             X.SimulationTimeCondition(_r(sc.duration), X.Rule.greaterThan)))
        reached = X.ConditionGroup()
        reached.add_condition(X.EntityTrigger("goal", 0, X.ConditionEdge.rising,
                                              X.DistanceCondition(GOAL_RADIUS_M, X.Rule.lessThan, goal, False, False,
                                                                  X.RelativeDistanceType.euclidianDistance,
                                                                  X.CoordinateSystem.entity), "ego"))
        trig.add_conditiongroup(timeout)
        trig.add_conditiongroup(reached)
        return trig


def _rotate(plan: list, into: float) -> list:
    """The cyclic phase list started `into` seconds into its cycle (the phase running then is
    split in two); zero-length parts are dropped (OpenSCENARIO phases have positive durations)."""
    out, t = [], 0.0
    for i, (name, dur, states) in enumerate(plan):
        if t + dur > into:
            cut = into - t
            out = [(name, dur - cut, states)] + plan[i + 1:] + plan[:i] + [(f"{name}_start", cut, states)]
            break
        t += dur
    else:
        out = list(plan)
    return [p for p in out if p[1] > 1e-9]


def _axis(polygon) -> tuple[np.ndarray, np.ndarray, float]:
    """Ends of a crosswalk's long centre line (where people walk) and its width, from its
    minimum rotated rectangle (as the env reads crosswalks)."""
    from shapely.geometry import Polygon

    rect = np.asarray(Polygon(polygon).minimum_rotated_rectangle.exterior.coords)[:4]
    e0, e1 = rect[1] - rect[0], rect[2] - rect[1]
    long, short = (e0, e1) if np.hypot(*e0) >= np.hypot(*e1) else (e1, e0)
    centre = rect.mean(axis=0)
    return centre - long / 2, centre + long / 2, float(np.hypot(*short))


def _file_date() -> datetime:
    """The header's date (required in OpenSCENARIO): SOURCE_DATE_EPOCH, else 1970-01-01, never
    the wall clock (same suite, same bytes)."""
    date = header_date()
    return datetime.fromisoformat(date).replace(tzinfo=timezone.utc) if date else EPOCH


def _r(x: float) -> float:
    """Rounded to 1e-6: the file does not depend on the last bits of the arithmetic."""
    return round(float(x), 6)


def _box(X, size):
    length, width, height = size
    return X.BoundingBox(width, length, height, 0, 0, height / 2)


def _rear_offset(body) -> float:
    """Metres from the body's centre back to the rear axle (the env's `VehicleModel.rear_offset`)."""
    rear_overhang = body["length"] - body["wheelbase"] - body["front_overhang"]
    return body["wheelbase"] / 2 + (rear_overhang - body["front_overhang"]) / 2


def _ego(X, body):
    """The env's ego (DRIVE_DEFAULTS["vehicle"]): its body about the rear axle, its axles and
    steering limit."""
    length, width, height = body["length"], body["width"], CAR_SIZE[2]
    box = X.BoundingBox(width, length, height, _rear_offset(body), 0, height / 2)
    track = width - 0.3
    return X.Vehicle("ego", X.VehicleCategory.car, box, X.Axle(body["max_steering"], 0.7, track, body["wheelbase"], 0.35),
                     X.Axle(0.0, 0.7, track, 0.0, 0.35), 40, 5, 9)


def _car(X, name: str):
    return X.Vehicle(name, X.VehicleCategory.car, _box(X, CAR_SIZE), X.Axle(0.5, 0.8, 1.6, 2.9, 0.4),
                     X.Axle(0.0, 0.8, 1.6, 0.0, 0.4), 40, 5, 9)


def _step(X):
    return X.TransitionDynamics(X.DynamicsShapes.step, X.DynamicsDimension.time, 0)


def write_openscenario(suite, out: str | Path) -> list[Path]:
    """Write the folder `out` (atomically, as a whole): `<scenario>.xosc` for every scenario of
    `suite` and `<map>.xodr` (OpenDRIVE 1.8) for each map they drive on; the .xosc files name
    their map by that relative path. Returns the .xosc paths."""
    from .. import read_map
    from ..opendrive.writer import opendrive_ids, to_opendrive

    cfg = dict(DRIVE_DEFAULTS)
    maps: dict[Path, tuple[str, HDMap, Any]] = {}
    names: set[str] = set()
    written = []
    with atomic.staged_dir(out, FORMATS["openscenario"].markers) as tmp:
        for sc in suite.scenarios:
            path = suite.map_path(sc).resolve()
            if path not in maps:
                m = read_map(path)
                xodr = _unique(file_stem(path.stem), names) + ".xodr"
                atomic.write_bytes(tmp / xodr, to_opendrive(m))
                maps[path] = (xodr, m, opendrive_ids(m))
            xodr, m, ids = maps[path]
            name = _unique(file_stem(sc.name), names) + ".xosc"
            env = {**cfg, **dict(getattr(sc, "env", {}))}  # the scenario's own env settings over the defaults
            atomic.write_bytes(tmp / name, _ScenarioWriter(m, xodr, ids, env).build(sc))
            written.append(Path(out) / name)
    return written


def _unique(stem: str, taken: set[str]) -> str:
    name, k = stem, 1
    while name.lower() in taken:
        k += 1
        name = f"{stem}_{k}"
    taken.add(name.lower())
    return name


def _midblock_crossed(m: HDMap, route, lanes: list[Lane]) -> set[str]:
    """The crosswalks outside junctions (mid-block crossings) that the route's road lanes cross:
    its entry and exit lanes (`lanes`' ends) and the roads between its manoeuvres."""
    from shapely.geometry import LineString, Polygon

    walks = [c for c in m.crosswalks.values() if c.junction_id is None and len(c.polygon) >= 3]
    if not walks:
        return set()
    if is_lane_route(route):
        road = {ln.id for ln in lanes if ln.junction_id is None}
    else:
        road = {lanes[0].id, lanes[-1].id} | {x for a, b in zip(route, route[1:]) for x in road_lanes_between(m, a, b)}
    lines = [LineString(m.lanes[x].centerline) for x in sorted(road) if len(m.lanes[x].centerline) >= 2]
    return {c.id for c in walks if any(line.intersects(Polygon(c.polygon)) for line in lines)}
