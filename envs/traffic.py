"""Former home of traffic control and traffic, kept so existing imports keep working: rules live
in `rules`, signal plans and their state in `control`, road users in `vehicles`, the road in
`road`, the batched traffic core in `core`."""
from __future__ import annotations

from .control import PhasePlan, TrafficControl, group_phases, travel_headings
from .road import MapRoad
from .rules import IDM_ACC, PEDESTRIAN_IN_PATH_M, STOP_ZONE_M, STOPPED_SPEED_MPS, idm
from .vehicles import EgoMDPVehicle, EgoVehicle, Pedestrian, RouteFollower, TrafficVehicle

__all__ = ["IDM_ACC", "PEDESTRIAN_IN_PATH_M", "STOP_ZONE_M", "STOPPED_SPEED_MPS", "EgoMDPVehicle", "EgoVehicle",
           "MapRoad", "Pedestrian", "PhasePlan", "RouteFollower", "TrafficControl", "TrafficVehicle", "group_phases",
           "idm", "travel_headings"]
