"""Readers of HD map files into the feat2map model, chosen by content and extension."""
from __future__ import annotations

import re
from pathlib import Path

from ..errors import MapFormatError
from ..model import HDMap

_PROTO_TEXT = re.compile(rb"\s*(#[^\n]*\n\s*)*[A-Za-z_]\w*\s*[{:]")  # protobuf text: `header {`
_CONTROL = bytes(b for b in range(32) if b not in (9, 10, 11, 12, 13))  # never in text files


def read_map(path: str | Path) -> HDMap:
    """Read a native map (.json), an OpenDRIVE file (.xodr) or an Apollo map (.bin/.txt)."""
    path = Path(path)
    if not path.is_file():
        raise MapFormatError("no such map file", str(path))
    with path.open("rb") as fh:
        raw = fh.read(512)
    head = raw.lstrip()
    sniffed = any(b in raw for b in _CONTROL) or _PROTO_TEXT.match(raw) is not None
    if path.suffix in (".bin", ".pb") or (sniffed and path.suffix not in (".json", ".xodr")):
        from .apollo import read_apollo  # binary protobuf (checked first: it may begin with "\n{")

        return read_apollo(path)
    if path.suffix == ".json" or head.startswith(b"{"):
        from ..mapio import load

        return load(path)
    if path.suffix == ".xodr" or head.startswith(b"<"):
        from .opendrive import read_opendrive

        return read_opendrive(path)
    if path.suffix == ".txt":
        from .apollo import read_apollo

        return read_apollo(path)
    raise MapFormatError("unsupported map format: expected a feat2map .json, an OpenDRIVE .xodr "
                         "or an Apollo .bin/.txt", str(path))
