"""The road of an episode: highway-env's `Road` on a `MapNetwork`, with traffic control, lane
buckets for neighbour search and grid-hash collision checks (no all-pairs scans)."""
from __future__ import annotations

from highway_env.road.road import Road
from highway_env.vehicle.kinematics import Vehicle

from .control import TrafficControl
from .network import MapNetwork
from .vehicles import Pedestrian

COLLISION_CELL_M = 10.0


class MapRoad(Road):
    """A `Road` on a `MapNetwork` with traffic control; local neighbour and collision checks."""

    def __init__(self, network: MapNetwork, control: TrafficControl, np_random, record_history=False) -> None:
        super().__init__(network, [], [], np_random, record_history)
        self.control = control

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
