"""ASAM OpenDRIVE (.xodr): read CARLA, SVL, esmini and CommonRoad files (`reader`) and write
generated maps with exact paramPoly3 geometry (`writer`)."""
from __future__ import annotations

from .reader import read_opendrive
from .writer import to_opendrive, write_opendrive

__all__ = ["read_opendrive", "to_opendrive", "write_opendrive"]
