"""CommonRoad scenarios (XML 2020a): write the lanelet network with intersections, traffic
lights and stop signs through commonroad-io's writer (`writer`), read it back with
commonroad-io and check it (`validate`)."""
from __future__ import annotations

from .validate import CommonRoadReport, check_commonroad, validate_commonroad
from .writer import lanelet_ids, to_commonroad, to_scenario, write_commonroad

__all__ = ["CommonRoadReport", "check_commonroad", "lanelet_ids", "to_commonroad", "to_scenario", "validate_commonroad",
           "write_commonroad"]
