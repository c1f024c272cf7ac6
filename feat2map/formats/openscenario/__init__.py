"""ASAM OpenSCENARIO XML (.xosc): scenario suites written one file per scenario beside the
OpenDRIVE export of their maps (`writer`), checked by ASAM's own checker,
asam-qc-openscenarioxml (`validate_openscenario`)."""
from __future__ import annotations

from pathlib import Path

from ..asam_qc import OPENSCENARIO, problems, run_bundle
from ..base import Problem
from .writer import write_openscenario


def validate_openscenario(path: str | Path, progress: bool = False) -> list[Problem]:
    """Every issue asam-qc-openscenarioxml (schema, references, parameters, data types) finds
    in the .xosc file `path` (its OpenDRIVE road network read from beside it)."""
    return problems(run_bundle(path, OPENSCENARIO))


__all__ = ["validate_openscenario", "write_openscenario"]
