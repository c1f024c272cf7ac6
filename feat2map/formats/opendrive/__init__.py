"""ASAM OpenDRIVE (.xodr): read CARLA, SVL, esmini and CommonRoad files (`reader`), write
generated maps with exact paramPoly3 geometry (`writer`) and check files with ASAM's own
checker, asam-qc-opendrive (`validate_opendrive`)."""
from __future__ import annotations

from pathlib import Path

from ..asam_qc import OPENDRIVE, problems, run_bundle
from ..base import Problem
from .reader import read_opendrive
from .writer import VERSIONS, to_opendrive, write_opendrive


def validate_opendrive(path: str | Path, progress: bool = False) -> list[Problem]:
    """Every issue asam-qc-opendrive (schema, semantic, geometry, performance, smoothness
    checks) finds in the .xodr file `path`."""
    return problems(run_bundle(path, OPENDRIVE))


__all__ = ["VERSIONS", "read_opendrive", "to_opendrive", "validate_opendrive", "write_opendrive"]
