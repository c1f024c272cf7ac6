"""ASAM OpenDRIVE (.xodr): read CARLA, SVL, esmini and CommonRoad files (`reader`), write
generated maps with exact paramPoly3 geometry (`writer`) and check files with ASAM's own
checker, asam-qc-opendrive (`validate_opendrive`)."""
from __future__ import annotations

import warnings
from pathlib import Path

from ..asam_qc import OPENDRIVE, problems, run_bundle
from ...errors import Feat2MapError, RepairWarning
from ..base import Problem
from .reader import read_opendrive
from .writer import VERSIONS, to_opendrive, write_opendrive


def validate_opendrive(path: str | Path, progress: bool = False) -> list[Problem]:
    """Every issue asam-qc-opendrive (schema, semantic, geometry, performance, smoothness
    checks) finds in the .xodr file `path`, and what feat2map's reader refuses or skips there
    (values the checker lets through: a NaN or 1e9 length, a negative width, a dangling link)."""
    found = problems(run_bundle(path, OPENDRIVE))
    name = Path(path).name
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        try:
            read_opendrive(path)
        except Feat2MapError as exc:
            found.append(Problem(name, f"feat2map reader: {exc}"))
    return found + [Problem(name, f"feat2map reader: {w.message}", warning=issubclass(w.category, RepairWarning))
                    for w in caught]


__all__ = ["VERSIONS", "read_opendrive", "to_opendrive", "validate_opendrive", "write_opendrive"]
