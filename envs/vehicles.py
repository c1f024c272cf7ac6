"""Road users: crosswalk pedestrians, and vehicles that follow explicit lane routes (highway-env
vehicles: traffic, which the arrays core (core.py) drives by IDM and MOBIL through views of its
rows, and the ego, driven by the agent's actions)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.controller import ControlledVehicle, MDPVehicle
from highway_env.vehicle.kinematics import Vehicle
from highway_env.vehicle.objects import RoadObject

from ..config import FINISH_MARGIN_M, LANE_KEEPING_TAU_S, LOOKAHEAD_M, MOBIL_DETOUR_M, MOBIL_MIN_GAP_M
from ..invariants import lane_changes
from .network import MapNetwork
from .sim.vehicle import VehicleModel, integrate, keeping_steering, lane_keeping, speed_control, yaw_rate
from .rules import body_reach, enters_junction, idm, in_the_way, may_change_lane, mobil_accepts, mobil_safe, route_memo


class Pedestrian(RoadObject):
    """A person walking straight across a crosswalk at constant speed."""

    LENGTH = 0.8
    WIDTH = 0.8

    def __init__(self, road, start: np.ndarray, end: np.ndarray, speed: float, crosswalk_id: str) -> None:
        d = end - start
        super().__init__(road, start.copy(), float(math.atan2(d[1], d[0])), speed)
        self.end = end
        self.crosswalk_id = crosswalk_id
        self.remaining = float(np.hypot(*d))
        self.collidable = True
        self.solid = False
        self.check_collisions = False

    def step(self, dt: float) -> None:
        move = min(self.speed * dt, self.remaining)
        self.position: np.ndarray = self.position + move * self.direction
        self.remaining -= move

    @property
    def done(self) -> bool:
        return self.remaining <= 1e-6


class RouteFollower:
    """Mixin: follow an explicit list of map lane ids; re-plan by Dijkstra after a lane change."""

    lane_route: list[str]
    route_pos: int
    _projected_at: tuple[float, float] | None = None
    _projections: dict = {}
    if TYPE_CHECKING:  # the highway-env vehicle it is mixed into has these
        road: Any
        position: np.ndarray
        speed: float
        heading: float
        history: Any
        LENGTH: float

        @classmethod
        def create_from(cls, vehicle: Any) -> Any: ...

    def init_route(self, lane_route: list[str]) -> None:
        self.lane_route = list(lane_route)
        self.route_pos = 0
        self.lane_s = 0.0
        self.lane_lat = 0.0
        self.reserved: str | None = None
        net: MapNetwork = self.road.network
        self.target_lane_index = net.index_of[self.lane_route[0]]
        self.route = None

    @property
    def net(self) -> MapNetwork:
        return self.road.network

    def current_lane_id(self) -> str:
        return self.lane_route[self.route_pos]

    def projection(self, lane_id: str) -> tuple[float, float]:
        """(s, lateral) of the vehicle centre on lane `lane_id`, each lane projected once per
        position."""
        lane = self.net.lane_of[lane_id]
        p = self.position
        at = (float(p[0]), float(p[1]))
        if at != self._projected_at:
            self._projected_at, self._projections = at, {}
        out = self._projections.get(lane_id)
        if out is None:
            out = self._projections[lane_id] = lane.local_coordinates(p)
        return out

    def route_s(self) -> float:
        """Longitudinal position of the vehicle centre along its current route lane."""
        return self.projection(self.lane_route[self.route_pos])[0]

    def s_on(self, lane_id: str) -> float:
        """Longitudinal position of the vehicle centre along lane `lane_id`."""
        return self.projection(lane_id)[0]

    def follow_road(self) -> None:
        net = self.net
        tid = net.id_of[self.target_lane_index]
        s, _ = self.projection(tid)
        if s <= net.lane_of[tid].length - 1.0:
            return
        if tid != self.lane_route[self.route_pos]:  # changed lane: re-plan from here
            path = self.parallel_route(tid) or net.lane_route(tid, self.lane_route[-1])
            if not path:
                return
            self.lane_route = self.lane_route[:self.route_pos] + path
        if self.route_pos + 1 < len(self.lane_route):
            self.route_pos += 1
            self.target_lane_index = net.index_of[self.lane_route[self.route_pos]]

    def parallel_route(self, start: str) -> list[str]:
        """The rest of the route moved beside itself after a lane change onto `start`: each next
        lane the successor of the previous one on the same road edge ([] where they part, e.g.
        at a junction). Keeps loops round a ring road whose lanes never merge."""
        net = self.net
        m = net.hdmap
        path = [start]
        for lid in self.lane_route[self.route_pos + 1:]:
            edge = net.index_of[lid][:2]
            nxt = next((x for x in m.lanes[path[-1]].successors if x in net.index_of and net.index_of[x][:2] == edge), None)
            if nxt is None:
                return []
            path.append(nxt)
        return path

    def on_state_update(self) -> None:
        if self.road:
            hint = self.location_hint()
            self.located(self.road.network.locate(self.position, self.heading, hint), hint)

    def location_hint(self):
        """The lane to look on first when locating the vehicle (its target lane)."""
        return getattr(self, "target_lane_index", None) or getattr(self, "lane_index", None)

    def located(self, location: tuple, hint) -> None:
        """Take the (lane index, s, lateral) that `MapNetwork.locate` found with `hint`."""
        if self.road:
            net = self.road.network
            self.lane_index, self.lane_s, self.lane_lat = location
            self.lane = net.get_lane(self.lane_index)
            if self.lane_index == hint:  # locate projected on the hint lane
                p = self.position
                self._projected_at = (float(p[0]), float(p[1]))
                self._projections = {net.id_of[hint]: (self.lane_s, self.lane_lat)}
            if self.road.record_history:
                self.history.appendleft(self.create_from(self))

    def route_distance_done(self) -> float:
        """Metres driven along the route: lanes behind plus the position on the current one."""
        net = self.net
        route, pos = self.lane_route, self.route_pos
        done = route_memo(self, "done before", lambda: sum(net.lane_of[l].length for l in route[:pos]))
        return done + min(max(self.route_s(), 0.0), net.lane_of[route[pos]].length)

    def route_length(self) -> float:
        return sum(self.net.lane_of[l].length for l in self.lane_route)

    def upcoming(self, horizon: float = LOOKAHEAD_M):
        """(route index, lane id, distance from the vehicle to the lane start, own s on it) ahead."""
        return route_upcoming(self.net.lane_of, self.lane_route, self.route_pos, self.route_s(), horizon)

    def leader_gaps(self) -> list[tuple[float, float]]:
        """(bumper gap, speed) of every road user in the path ahead along the route: on the route's
        lanes, on junction lanes that diverge from or cross them and on road lanes converging with
        them (`MapNetwork.near_lanes`), where they are in the way."""
        net = self.net
        m = net.hdmap
        buckets = self.road.control.buckets
        gaps = []
        for _k, lid, d, s_own in self.upcoming():
            lane = net.lane_of[lid]
            others = [(o, lid) for o in buckets.get(lid, ())]
            for x in net.near_lanes(lid):
                others += [(o, x) for o in buckets.get(x, ()) if all(o is not q for q, _ in others)]
            for o, on in others:
                if o is self:
                    continue
                so, ro = lane.local_coordinates(o.position)
                if on != lid and m.lanes[lid].junction_id is None:  # converging road lanes: zip
                    if not net.zip_leader(lid, s_own, on, so, self.position, o.position, self.LENGTH):
                        continue
                elif s_own is not None and so <= s_own or not in_the_way(
                        so, ro, lane.width, lane.length, self.LENGTH,
                        body_reach(getattr(o, "WIDTH", 0.0), getattr(o, "LENGTH", 0.0),
                                   float(getattr(o, "heading", 0.0)) - lane.heading_at(so))):
                    continue
                gaps.append(((so - s_own if s_own is not None else d + so) - self.LENGTH, float(getattr(o, "speed", 0.0))))
        return gaps

    def next_junction_lane(self) -> tuple[str | None, str | None, float]:
        """(incoming lane, junction lane, distance to the stop line) of the next junction entry."""
        m = self.net.hdmap
        for k, lid, d, _ in self.upcoming(1e9):
            if k > self.route_pos and enters_junction(m.lanes, self.lane_route[k - 1], lid):
                return self.lane_route[k - 1], lid, d
        return None, None, math.inf


def route_upcoming(lane_of: dict, route: list[str], pos: int, s: float,
                   horizon: float) -> list[tuple[int, str, float, float | None]]:
    """`RouteFollower.upcoming` of a road user at `s` on `route[pos]`."""
    out: list[tuple[int, str, float, float | None]] = [(pos, route[pos], -s, s)]
    d = lane_of[route[pos]].length - s
    for k in range(pos + 1, len(route)):
        if d > horizon:
            break
        lid = route[k]
        out.append((k, lid, d, None))
        d += lane_of[lid].length
    return out


class TrafficVehicle(RouteFollower, IDMVehicle):
    """A traffic vehicle on its own lane route. The arrays core (core.py) drives it (IDM behind
    leaders and before the rules' stop points, MOBIL lane changes) through `core.ArrayVehicle`
    views; one user code appends to `road.vehicles` is taken in as a row at the next frame."""

    def mobil_change(self) -> bool:
        """MOBIL on multi-lane roads: move to a same-direction neighbour lane when it raises the
        acceleration (with politeness) and the new follower stays safe; the route is re-planned
        from that lane by Dijkstra and the change is taken only if it costs no detour."""
        net, m = self.net, self.net.hdmap
        lid = self.lane_route[self.route_pos]
        if lid != net.id_of.get(self.target_lane_index):
            return False
        ln = m.lanes[lid]
        lane = net.lane_of[lid]
        s, _ = lane.local_coordinates(self.position)
        if not may_change_lane(ln.junction_id is not None, lane.length - s, self.speed):
            return False
        remaining = sum(net.lane_of[l].length for l in self.lane_route[self.route_pos:])
        a_cur = idm(self, self.leader_gaps())
        buckets = self.road.control.buckets
        for n in lane_changes(ln):  # only across a dashed line
            if n not in m.lanes:
                continue
            goal = m.lanes[self.lane_route[-1]]
            paths = [net.lane_route(n, g) for g in (goal.id,) + goal.left_neighbors + goal.right_neighbors
                     if g in m.lanes]  # any lane of the destination road will do
            paths = [p for p in paths if p and sum(net.lane_of[l].length for l in p) <= remaining + MOBIL_DETOUR_M]
            if not paths:
                continue
            path = min(paths, key=len)
            nl = net.lane_of[n]
            sn, _ = nl.local_coordinates(self.position)
            if not 0.0 <= sn <= nl.length:  # no change onto a neighbour where it does not run beside us yet
                continue  # (a lane that opens along the road: it would drive its lane's extension, blind)
            ahead, behind = [], None
            for o in buckets.get(n, ()):
                so, _ = nl.local_coordinates(o.position)
                if so >= sn:
                    ahead.append((so - sn - self.LENGTH, float(o.speed)))
                elif behind is None or so > behind[0]:
                    behind = (so, o)
            if any(g < MOBIL_MIN_GAP_M for g, _ in ahead):
                continue
            a_new = idm(self, ahead)
            follower_loss = 0.0
            if behind is not None:
                so, f = behind
                gap = sn - so - self.LENGTH
                if gap < MOBIL_MIN_GAP_M or not isinstance(f, RouteFollower):
                    continue
                a_f = idm(f, [(gap, self.speed)])
                if not mobil_safe(a_f):
                    continue
                follower_loss = max(0.0, idm(f, []) - a_f)
            if mobil_accepts(a_cur, a_new, follower_loss):
                self.lane_route = self.lane_route[:self.route_pos] + path
                self.target_lane_index = net.index_of[n]
                self.lane_changes = getattr(self, "lane_changes", 0) + 1
                return True
        return False

    @property
    def finished(self) -> bool:
        """On the last lane of its route, within FINISH_MARGIN_M of its end."""
        if self.route_pos < len(self.lane_route) - 1:
            return False
        return self.route_s() >= self.net.lane_of[self.lane_route[-1]].length - FINISH_MARGIN_M


class Ego(RouteFollower):
    """Mixin of the controlled egos: our kinematic bicycle (`sim.vehicle`) with the config's body
    in place of highway-env's (wheelbase = length = 5 m, axles at +-length/2), and lane keeping
    through it."""

    model = VehicleModel.of()
    if TYPE_CHECKING:
        action: dict
        impact: Any
        crashed: bool
        WIDTH: float
        MAX_STEERING_ANGLE: float

        def clip_actions(self) -> None: ...

    def fit(self, model: VehicleModel) -> None:
        """Take `model`'s body and steering limit (highway-env reads LENGTH, WIDTH, diagonal)."""
        self.model = model
        self.LENGTH, self.WIDTH, self.MAX_STEERING_ANGLE = model.length, model.width, model.max_steering
        self.diagonal = math.hypot(model.length, model.width)

    def steering_control(self, target_lane_index) -> float:
        """Lane keeping on the target lane (`sim.vehicle.lane_keeping`)."""
        net = self.road.network
        s, r = self.projection(net.id_of[target_lane_index])
        return lane_keeping(net.get_lane(target_lane_index), s, r, self.heading, self.speed, self.model)

    def speed_control(self, target_speed: float) -> float:
        """`sim.vehicle.speed_control` (highway-env's law, written once for the ego and the agents)."""
        return speed_control(target_speed, self.speed)

    def step(self, dt: float) -> None:
        step_egos([self], dt)

    def settle(self) -> None:
        """After a step: no reversing while no reverse is asked for."""
        if self.speed < 0 and not self.reversing():
            self.speed = 0.0

    def reversing(self) -> bool:
        return False


class EgoMDPVehicle(Ego, MDPVehicle):
    """The ego under DiscreteMetaAction: MDPVehicle that follows the episode's lane route."""

    def act(self, action=None) -> None:
        """A meta-action as highway-env's MDPVehicle takes it (FASTER / SLOWER: the target speed
        one step from the one nearest the speed; LANE_LEFT / LANE_RIGHT: the neighbour lane of
        the target lane where it is reachable), except that a lane change needs a dashed line
        between the two lanes (`invariants.lane_changes`). Without an action, this frame's command
        (`command`): the core asks for it after the decision (`TrafficCore.act`), so a decision
        frame computes it once. Our own code throughout: highway-env's controller chain is not run."""
        self.follow_road()
        if action is None:
            self.command()
        elif action in ("FASTER", "SLOWER"):
            index = self.speed_to_index(self.speed) + (1 if action == "FASTER" else -1)
            self.speed_index = int(min(max(index, 0), self.target_speeds.size - 1))
            self.target_speed = self.index_to_speed(self.speed_index)
        elif action in ("LANE_LEFT", "LANE_RIGHT"):
            self.change_lane(-1 if action == "LANE_LEFT" else 1)

    def change_lane(self, side: int) -> None:
        """Target the neighbour lane on `side` (-1 left, +1 right, highway-env's lane order on
        the road edge) where it is reachable from here and the line to it is dashed."""
        net = self.net
        _from, _to, _id = self.target_lane_index
        index = (_from, _to, int(min(max(_id + side, 0), len(net.graph[_from][_to]) - 1)))
        old, new = net.id_of.get(self.target_lane_index), net.id_of.get(index)
        if index != self.target_lane_index and net.get_lane(index).is_reachable_from(self.position) and (
                old is None or new in lane_changes(net.hdmap.lanes[old])):
            self.target_lane_index = index

    def command(self) -> None:
        """This frame's command: lane keeping on the target lane and the speed control towards
        the target speed (what highway-env's `ControlledVehicle.act()` computes)."""
        self.action = {"steering": self.steering_control(self.target_lane_index),
                       "acceleration": speed_control(self.target_speed, self.speed)}

    def reversing(self) -> bool:
        return self.target_speed < 0


class SpeedGrid:
    """Mixin of vehicles that have no discrete target speeds of their own (the continuous ego,
    the multi-agent env's agents): the speeds highway-env's TimeToCollision observation
    predicts for (`target_speeds`, `index_to_speed`), the current one the nearest to the speed."""

    target_speeds = np.array([0.0, 4.5, 9.0])
    if TYPE_CHECKING:
        speed: float

    def index_to_speed(self, index: int) -> float:
        return float(self.target_speeds[index])

    @property
    def speed_index(self) -> int:
        return int(np.argmin(np.abs(self.target_speeds - self.speed)))


class EgoVehicle(SpeedGrid, Ego, ControlledVehicle):
    """The ego under ContinuousAction: takes acceleration/steering; when the action type has no
    lateral control, steering follows the route (a lane-keeping assist)."""

    auto_steer = True
    tracker = None  # an envs.tracking.TrajectoryTracker: when set, it commands the ego every frame

    def act(self, action=None) -> None:
        """A new command (a dict) at each decision; between decisions (`action` None) the
        acceleration is held and, with `auto_steer`, the steering follows the route every frame
        (a lane-keeping assist: steering held over a decision period drifts out of turns).
        With a `tracker` (an external planner's trajectory) the tracker commands every frame."""
        if self.tracker is not None:
            self.follow_road()
            Vehicle.act(self, self.tracker.command(self.position, self.heading, self.speed))
            return
        if action is None and self.auto_steer and isinstance(self.action, dict) and "acceleration" in self.action:
            action = {"acceleration": self.action["acceleration"]}
        if isinstance(action, dict):
            action = dict(action)
            self.follow_road()
            if self.auto_steer:
                action["steering"] = self.steering_control(self.target_lane_index)
            Vehicle.act(self, action)

    def reversing(self) -> bool:
        return self.action.get("acceleration", 0) > 0


def vehicle_model(vehicle: Ego, acceleration_range: Any, steering_range: Any) -> dict[str, Any]:
    """The ego's motion model for a planner in another process (the planner bridge's init): its
    `sim.vehicle.VehicleModel`, the env's action limits (steering within the model's) and speeds."""
    m = vehicle.model
    lo, hi = (float(x) for x in steering_range)
    return {**m.describe(), "acceleration_range": [float(x) for x in acceleration_range],
            "steering_range": [max(lo, -m.max_steering), min(hi, m.max_steering)],
            "max_speed": float(getattr(vehicle, "MAX_SPEED", 40.0)), "min_speed": 0.0}


def bicycle_state(vehicle: Ego) -> tuple[float, float, float]:
    """(steering, yaw rate, acceleration) of `vehicle` in the env's frame: its last command
    (steering within the model's limit) and the yaw rate the bicycle gives it."""
    action = vehicle.action if isinstance(vehicle.action, dict) else {}
    m = vehicle.model
    steering = min(max(float(action.get("steering", 0.0)), -m.max_steering), m.max_steering)
    return steering, yaw_rate(float(vehicle.speed), steering, m.wheelbase), float(action.get("acceleration", 0.0))


def command_egos(egos: list["EgoMDPVehicle"]) -> None:
    """`act()` between decisions of many meta-action egos at once: each follows its route, then
    their lane keeping on the target lanes (`sim.vehicle.keeping_steering`) and speed control
    as one array program. NumPy's functions give math's values bit for bit here, so each ego
    gets `command`'s (tests/envs/test_vector_native.py runs both)."""
    ahead, lat, heading, speed, wheelbase, limit, target = ([] for _ in range(7))
    for v in egos:
        v.follow_road()
        net = v.net
        tid = net.id_of[v.target_lane_index]
        s, r = v.projection(tid)
        ahead.append(net.lane_of[tid].heading_at(s + v.speed * LANE_KEEPING_TAU_S))
        lat.append(r)
        heading.append(v.heading)
        speed.append(v.speed)
        wheelbase.append(v.model.wheelbase)
        limit.append(v.model.max_steering)
        target.append(v.target_speed)
    v_arr = np.array(speed, dtype=float)
    steer = keeping_steering(np.array(ahead, dtype=float), np.array(lat, dtype=float), np.array(heading, dtype=float),
                             v_arr, np.array(wheelbase), np.array(limit))
    acc = speed_control(np.array(target, dtype=float), v_arr)
    for v, st, a in zip(egos, steer.tolist(), acc.tolist()):
        v.action = {"steering": st, "acceleration": a}


def step_egos(egos: list, dt: float) -> None:
    """`step(dt)` of egos: the bicycle (`sim.vehicle.integrate`) over all of them at once (with
    floats for one), a pending impact applied as highway-env does, then their lane locations
    (`on_state_update`, with `MapNetwork.locate_many` for several) and `settle`."""
    for v in egos:
        v.clip_actions()
    if len(egos) == 1:
        v = egos[0]
        m = v.model
        steer = min(max(v.action["steering"], -m.max_steering), m.max_steering)
        x, y, heading, speed = integrate(float(v.position[0]), float(v.position[1]), float(v.heading), float(v.speed),
                                         steer, v.action["acceleration"], dt, m.wheelbase, m.rear_offset, math)
        moved = [(x, y, heading, speed)]
    else:
        limit = np.array([v.model.max_steering for v in egos])
        steer = np.clip([v.action["steering"] for v in egos], -limit, limit)
        x, y, heading, speed = integrate(
            np.array([v.position[0] for v in egos], dtype=float), np.array([v.position[1] for v in egos], dtype=float),
            np.array([v.heading for v in egos], dtype=float), np.array([v.speed for v in egos], dtype=float), steer,
            np.array([v.action["acceleration"] for v in egos], dtype=float), dt,
            np.array([v.model.wheelbase for v in egos]), np.array([v.model.rear_offset for v in egos]))
        moved = list(zip(x.tolist(), y.tolist(), heading.tolist(), speed.tolist()))
    for v, (x, y, heading, speed) in zip(egos, moved):
        p = v.position
        p[0], p[1] = x, y
        if v.impact is not None:
            p += v.impact
            v.crashed, v.impact = True, None
        v.heading, v.speed = heading, speed
    located = [v for v in egos if v.road]
    if len(located) == 1:  # `locate` (locate_many's arrays cost more than they save for one)
        located[0].on_state_update()
    elif located:
        hints = [v.location_hint() for v in located]
        places = located[0].road.network.locate_many([v.position for v in located], [v.heading for v in located], hints)
        for v, place, hint in zip(located, places, hints):
            v.located(place, hint)
    for v in egos:
        v.settle()
