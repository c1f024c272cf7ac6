"""Road users: crosswalk pedestrians, and vehicles that follow explicit lane routes (highway-env
vehicles: traffic, which the arrays core (core.py) drives by IDM and MOBIL through views of its
rows; the controlled rows' views, the ego's and the agents', are in controlled.py)."""
from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import numpy as np
from highway_env.vehicle.behavior import IDMVehicle
from highway_env.vehicle.objects import RoadObject

from ..config import FINISH_MARGIN_M, LOOKAHEAD_M
from .network import MapNetwork
from .sim.vehicle import yaw_rate
from .rules import enters_junction


class Pedestrian(RoadObject):
    """A person walking straight across a crosswalk at constant speed: a walker row of its road's
    arrays core (`TrafficCore.walk` moves the walkers of every slot at once; `drop_walkers` lets
    them go), of which this object is the view."""

    LENGTH = 0.8
    WIDTH = 0.8

    def __init__(self, road, start: np.ndarray, end: np.ndarray, speed: float, crosswalk_id: str) -> None:
        d = end - start
        heading = float(math.atan2(d[1], d[0]))
        self._core = road.core
        self._row = self._core.add_walker(self, road.slot, crosswalk_id, heading, float(speed), float(np.hypot(*d)))
        super().__init__(road, start.copy(), heading, speed)
        self.end = end
        self.crosswalk_id = crosswalk_id
        self.collidable = True
        self.solid = False
        self.check_collisions = False

    @property
    def position(self) -> np.ndarray:
        c, i = self._core, self._row
        return np.array([c.p_x[i], c.p_y[i]])

    @position.setter
    def position(self, value) -> None:
        c, i = self._core, self._row
        c.p_x[i], c.p_y[i] = float(value[0]), float(value[1])

    @property
    def remaining(self) -> float:
        """Metres left to the crosswalk's far end."""
        return float(self._core.p_left[self._row])

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

    def upcoming(self, horizon: float = LOOKAHEAD_M):
        """(route index, lane id, distance from the vehicle to the lane start, own s on it) ahead."""
        return route_upcoming(self.net.lane_of, self.lane_route, self.route_pos, self.route_s(), horizon)

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

    @property
    def finished(self) -> bool:
        """On the last lane of its route, within FINISH_MARGIN_M of its end."""
        if self.route_pos < len(self.lane_route) - 1:
            return False
        return bool(route_finished(self.route_s(), self.net.lane_of[self.lane_route[-1]].length))


def route_finished(s: Any, last_length: Any) -> Any:
    """Whether a road user at `s` on its route's last lane (of `last_length`) has finished the
    route: within FINISH_MARGIN_M of that lane's end (floats, or arrays of rows)."""
    return s >= last_length - FINISH_MARGIN_M


def vehicle_model(vehicle: Any, acceleration_range: Any, steering_range: Any) -> dict[str, Any]:
    """The ego's motion model for a planner in another process (the planner bridge's init): its
    `sim.vehicle.VehicleModel`, the env's action limits (steering within the model's) and speeds."""
    m = vehicle.model
    lo, hi = (float(x) for x in steering_range)
    return {**m.describe(), "acceleration_range": [float(x) for x in acceleration_range],
            "steering_range": [max(lo, -m.max_steering), min(hi, m.max_steering)],
            "max_speed": float(getattr(vehicle, "MAX_SPEED", 40.0)), "min_speed": 0.0}


def bicycle_state(vehicle: Any) -> tuple[float, float, float]:
    """(steering, yaw rate, acceleration) of `vehicle` in the env's frame: its last command
    (steering within the model's limit) and the yaw rate the bicycle gives it."""
    action = vehicle.action if isinstance(vehicle.action, dict) else {}
    m = vehicle.model
    steering = min(max(float(action.get("steering", 0.0)), -m.max_steering), m.max_steering)
    return steering, yaw_rate(float(vehicle.speed), steering, m.wheelbase), float(action.get("acceleration", 0.0))
