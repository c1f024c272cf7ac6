"""The road of an episode: highway-env's `Road` on a `MapNetwork`, with traffic control. Two
cores move its traffic: `MapRoad` steps one highway-env object per vehicle (lane buckets for
neighbour search, grid-hash collision checks); `ArrayRoad` advances all traffic together in
arrays (core.py), its vehicles views of their rows."""
from __future__ import annotations

from highway_env.road.road import Road
from highway_env.vehicle.kinematics import Vehicle

from .control import TrafficControl
from .core import TrafficCore
from .network import MapNetwork
from .vehicles import Pedestrian, TrafficVehicle

COLLISION_CELL_M = 10.0


class MapRoad(Road):
    """A `Road` on a `MapNetwork` with traffic control; local neighbour and collision checks."""

    def __init__(self, network: MapNetwork, control: TrafficControl, np_random, record_history=False) -> None:
        super().__init__(network, [], [], np_random, record_history)
        self.control = control

    def spawn(self, lane_id: str, s: float, speed: float, route: list[str]) -> TrafficVehicle:
        """A traffic vehicle at s on `lane_id` (the start of `route`), added to the road."""
        lane = self.network.lane_of[lane_id]
        v = TrafficVehicle(self, lane.position(s, 0.0), lane.heading_at(s), speed)
        v.init_route(route)
        v.target_speed = lane.speed_limit
        self.vehicles.append(v)
        return v

    def occupancy(self) -> tuple[list[str | None], list[float]]:
        """Map lane id (None off the map's lanes) and speed of every vehicle, in road order."""
        id_of = self.network.id_of
        return [id_of.get(v.lane_index) for v in self.vehicles], [v.speed for v in self.vehicles]

    def act(self) -> None:
        for v in self.vehicles:
            v.act()

    def step(self, dt: float) -> None:
        for v in self.vehicles:
            v.step(dt)
        for o in self.objects:
            if isinstance(o, Pedestrian):
                o.step(dt)
        self.control.update(self, dt)
        self._collisions(dt)

    def _collisions(self, dt: float) -> None:
        cells: dict[tuple[int, int], list] = {}
        for o in self.vehicles + self.objects:
            key = (int(o.position[0] // COLLISION_CELL_M), int(o.position[1] // COLLISION_CELL_M))
            cells.setdefault(key, []).append(o)
        seen = set()
        for (cx, cy), objs in cells.items():
            near = [o for dx in (-1, 0, 1) for dy in (-1, 0, 1) for o in cells.get((cx + dx, cy + dy), ())]
            for a in objs:
                if not isinstance(a, Vehicle):
                    continue
                for b in near:
                    if b is a or (id(b), id(a)) in seen:
                        continue
                    seen.add((id(a), id(b)))
                    a.handle_collisions(b, dt)

    def neighbour_vehicles(self, vehicle, lane_index=None):
        lane_index = lane_index or vehicle.lane_index
        if not lane_index:
            return None, None
        net: MapNetwork = self.network
        lid = net.id_of.get(lane_index)
        lane = net.get_lane(lane_index)
        s = lane.local_coordinates(vehicle.position)[0]
        front = rear = None
        sf = sr = None
        cands = [(lid, 0.0)]
        if lid in net.hdmap.lanes:
            cands += [(x, lane.length) for x in net.hdmap.lanes[lid].successors]
            cands += [(x, -net.lane_of[x].length) for x in net.hdmap.lanes[lid].predecessors if x in net.lane_of]
        for cl, off in cands:
            for v in self.control.buckets.get(cl, ()):
                if v is vehicle:
                    continue
                sv = net.lane_of[cl].local_coordinates(v.position)[0] + off
                if sv >= s and (sf is None or sv < sf):
                    sf, front = sv, v
                if sv < s and (sr is None or sv > sr):
                    sr, rear = sv, v
        return front, rear


class ArrayRoad(MapRoad):
    """A `MapRoad` whose traffic the batched core (core.py) advances; `vehicles` holds the ego,
    views of the traffic rows and anything user code adds (taken in at the next frame). With
    `slot` = (core, k) it is sub-env k of a batch whose roads share that core (vector.py)."""

    def __init__(self, network: MapNetwork, control: TrafficControl, np_random, record_history=False,
                 slot: tuple[TrafficCore, int] | None = None) -> None:
        super().__init__(network, control, np_random, record_history)
        self.core, k = slot if slot is not None else (TrafficCore(network), 0)
        self.core.attach(self, k)

    def sync(self) -> None:
        self.core.sync([self])

    def spawn(self, lane_id: str, s: float, speed: float, route: list[str]) -> TrafficVehicle:
        return self.core.add_traffic(self, lane_id, s, speed, route)

    def occupancy(self) -> tuple[list[str | None], list[float]]:
        self.core.sync([self])
        return self.core.occupancy(self)

    def act(self) -> None:
        self.core.act([self])

    def step(self, dt: float) -> None:
        self.core.step([self], dt)
