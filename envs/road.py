"""The road of an episode: highway-env's `Road` on a `MapNetwork`, with traffic control, whose
traffic the arrays core (core.py) advances all together; its vehicles are views of the core's rows."""
from __future__ import annotations

from highway_env.road.road import Road

from .control import TrafficControl
from .core import TrafficCore
from .network import MapNetwork
from .vehicles import TrafficVehicle


class VehicleList(list):
    """A road's `vehicles`: a list that tells its road's core when it changes, so that a sync
    looks only at the roads whose vehicles user code (or an env) changed since the last one
    (`TrafficCore.edited`), not at every road of a batch each frame."""

    __slots__ = ("road",)

    def __init__(self, road: "MapRoad", items=()) -> None:
        super().__init__(items)
        self.road = road

    def _edit(self) -> None:
        core = getattr(self.road, "core", None)
        if core is not None:
            core.edited.add(self.road.slot)


def _editing(name: str):
    """List method `name` that tells the road's core of the change."""
    method = getattr(list, name)

    def edit(self, *args, **kwargs):
        result = method(self, *args, **kwargs)
        self._edit()
        return self if name in ("__iadd__", "__imul__") else result
    edit.__name__ = name
    return edit


for _name in ("append", "extend", "insert", "remove", "pop", "clear", "sort", "reverse", "__setitem__",
              "__delitem__", "__iadd__", "__imul__"):
    setattr(VehicleList, _name, _editing(_name))


class MapRoad(Road):
    """A `Road` on a `MapNetwork` with traffic control; `vehicles` holds the ego, views of the
    traffic rows and anything user code adds (taken in at the next frame). With `slot` = (core, k)
    it is sub-env k of a batch whose roads share that core (vector.py)."""

    def __init__(self, network: MapNetwork, control: TrafficControl, np_random, record_history=False,
                 slot: tuple[TrafficCore, int] | None = None) -> None:
        super().__init__(network, [], [], np_random, record_history)
        self.control = control
        self.core, k = slot if slot is not None else (TrafficCore(network), 0)
        self.core.attach(self, k)
        self.core.clock[k] = control.t  # the episode's clock is its slot's from here on
        control.road = self
        control.reservations = self.core.reservations(k)

    @property
    def vehicles(self) -> VehicleList:
        return self._vehicles

    @vehicles.setter
    def vehicles(self, value) -> None:
        self._vehicles = VehicleList(self, value)
        self._vehicles._edit()

    def sync(self) -> None:
        self.core.sync([self])

    def spawn(self, lane_id: str, s: float, speed: float, route: list[str]) -> TrafficVehicle:
        """A traffic vehicle at s on `lane_id` (the start of `route`), added to the road."""
        return self.core.add_traffic(self, lane_id, s, speed, route)

    def act(self) -> None:
        self.core.act([self])

    def step(self, dt: float) -> None:
        self.core.step([self], dt)

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
