"""Map formats, one package each, behind one table (`FORMATS`): `read_map`, the CLI's
`extract`, `export` and `validate` dispatch on it, so a new format is one folder and one line here.

| format | read | write | validate |
|---|---|---|---|
| native (feat2map JSON) | yes | yes | structure on read |
| apollo (base/sim/routing map) | yes | yes | Apollo's rules |
| opendrive (.xodr) | yes | yes (1.8; 1.7, 1.6, 1.4) | asam-qc-opendrive |
| openscenario (.xosc) | | a scenario suite | asam-qc-openscenarioxml |
| lanelet2 (.osm, Autoware) | | yes | the lanelet2 wheel: loader, routing graph, manoeuvres |
| commonroad (.xml) | | yes | commonroad-io: schema, reader, intersections, manoeuvres |
"""
from __future__ import annotations

import re
from pathlib import Path

from ..config import OPENDRIVE_VERSIONS
from ..errors import MapFormatError
from ..model import HDMap
from .base import ExportOption, MapFormat, Problem
from .geo import GEO_OPTIONS

_PROTO_TEXT = re.compile(rb"\s*(#[^\n]*\n\s*)*[A-Za-z_]\w*\s*[{:]")  # protobuf text: `header {`
_CONTROL = bytes(b for b in range(32) if b not in (9, 10, 11, 12, 13))  # never in text files


def _is_protobuf(head: bytes) -> bool:
    return any(b in head for b in _CONTROL) or _PROTO_TEXT.match(head) is not None


_P = "feat2map.formats"
FORMATS: dict[str, MapFormat] = {f.name: f for f in (
    MapFormat("apollo", "Apollo HD map: base_map, sim_map, routing_map (.bin + .txt)", (".bin", ".pb", ".txt"),
              output="dir", markers=("base_map.bin", "base_map.txt"),
              read=f"{_P}.apollo:read_apollo", write=f"{_P}.apollo:write_apollo",
              validate=f"{_P}.apollo:validate_apollo", picture=f"{_P}.apollo:render_problems",
              sniff=_is_protobuf, options=GEO_OPTIONS),
    MapFormat("commonroad", "CommonRoad scenario (.xml, 2020a)", (".xml",), write=f"{_P}.commonroad:write_commonroad",
              validate=f"{_P}.commonroad:validate_commonroad", options=GEO_OPTIONS,
              sniff=lambda head: b"<commonRoad" in head),
    MapFormat("lanelet2", "Lanelet2 for Autoware (.osm, map_projector_info.yaml beside it)", (".osm",),
              write=f"{_P}.lanelet2:write_lanelet2", validate=f"{_P}.lanelet2:validate_lanelet2", options=GEO_OPTIONS,
              check=f"{_P}.lanelet2:check_projector_target",
              sniff=lambda head: b"<osm" in head),
    MapFormat("native", "feat2map map (.json)", (".json",), read=f"{_P}.native:load", write=f"{_P}.native:save",
              sniff=lambda head: head.lstrip().startswith(b"{")),
    MapFormat("opendrive", "ASAM OpenDRIVE 1.8 (.xodr)", (".xodr",), read=f"{_P}.opendrive:read_opendrive",
              write=f"{_P}.opendrive:write_opendrive", validate=f"{_P}.opendrive:validate_opendrive",
              sniff=lambda head: head.lstrip().startswith(b"<"), options=(
                  ExportOption("--odr-version", "version", {"choices": OPENDRIVE_VERSIONS,
                                                            "help": f"OpenDRIVE revision (default {OPENDRIVE_VERSIONS[0]})"}),)),
    MapFormat("openscenario", "ASAM OpenSCENARIO XML 1.3: a suite as one .xosc per scenario + its maps' .xodr",
              (".xosc",), output="dir", markers=("*.xosc",), input="suite",
              write=f"{_P}.openscenario:write_openscenario",
              validate=f"{_P}.openscenario:validate_openscenario"),
)}


def detect(path: str | Path, face: str = "read") -> MapFormat:
    """The format of `path` that has `face`: a folder is a directory format (Apollo), a file is
    chosen by its suffix, else by its first bytes."""
    path = Path(path)
    cands = [f for f in FORMATS.values() if getattr(f, face) is not None]
    if path.is_dir():
        found = [f for f in cands if f.output == "dir"]
    else:
        if not path.is_file():
            raise MapFormatError("no such map file", str(path))
        found = [f for f in cands if path.suffix.lower() in f.suffixes]
        with path.open("rb") as fh:
            head = fh.read(512)
        if not found:
            found = [f for f in cands if f.sniff is not None and f.sniff(head)]
        elif path.suffix.lower() == ".txt" and not _is_protobuf(head):  # .txt: any text, not only Apollo's
            raise MapFormatError("not a map feat2map reads: a .txt map is Apollo protobuf text, which starts "
                                 "with a field such as `header {`; this file does not", str(path))
    if not found:
        known = ", ".join(f"{f.name} ({' '.join(f.suffixes) or 'folder'})" for f in cands)
        raise MapFormatError(f"unsupported map format for {face}: expected one of {known}", str(path))
    return found[0]


def read_map(path: str | Path) -> HDMap:
    """Read any map file feat2map knows (see FORMATS), chosen by suffix, else by content."""
    return detect(path, "read").face("read")(Path(path))


def check_target(path: str | Path, format: str) -> Path:
    """`path` when format `format` may be written there (see feat2map.atomic); before any work."""
    from .. import atomic

    fmt = FORMATS[format]
    target = atomic.check_dir_target(path, fmt.markers) if fmt.output == "dir" else atomic.check_file_target(path)
    if fmt.check is not None:
        fmt.face("check")(target)
    return target


def write_map(m: HDMap, path: str | Path, format: str, **options) -> None:
    """Write `m` to `path` (a file, or a folder for directory formats) in `format`, atomically;
    a map with values no format can hold (NaN, ...) is refused naming the element."""
    from ..validation import validate_model

    check_target(path, format)
    validate_model(m, "map to write")
    return FORMATS[format].face("write")(m, path, **options)


__all__ = ["FORMATS", "ExportOption", "MapFormat", "Problem", "check_target", "detect", "read_map", "write_map"]
