"""Readers of HD map files into the feat2map model, chosen by content and extension."""
from __future__ import annotations

from pathlib import Path

from ..errors import MapFormatError
from ..model import HDMap


def read_map(path: str | Path) -> HDMap:
    """Read a native map (.json) or an OpenDRIVE file (.xodr)."""
    path = Path(path)
    if not path.is_file():
        raise MapFormatError("no such map file", str(path))
    with path.open("rb") as fh:
        head = fh.read(512).lstrip()
    if path.suffix == ".json" or head.startswith(b"{"):
        from ..mapio import load

        return load(path)
    if path.suffix == ".xodr" or head.startswith(b"<"):
        from .opendrive import read_opendrive

        return read_opendrive(path)
    raise MapFormatError("unsupported map format: expected a feat2map .json or an OpenDRIVE .xodr "
                         "(the Apollo reader is not built yet)", str(path))
