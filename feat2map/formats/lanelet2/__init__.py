"""Lanelet2 (OSM XML) for Autoware: write generated maps with lanelets, shared bounds and
regulatory elements (`writer`), and check them with the `lanelet2` wheel (`validate`)."""
from __future__ import annotations

from .validate import Lanelet2Report, check_lanelet2, validate_lanelet2
from .writer import PROJECTOR_INFO, check_projector_target, to_lanelet2, write_lanelet2

__all__ = ["PROJECTOR_INFO", "Lanelet2Report", "check_lanelet2", "check_projector_target",
           "to_lanelet2", "validate_lanelet2", "write_lanelet2"]
