"""Writers of HD map files (kept for documented imports; the formats live in feat2map.formats)."""
from __future__ import annotations

from ..formats import write_map
from ..formats.apollo import to_apollo, write_apollo
from ..formats.native import save as write_native
from ..formats.opendrive import to_opendrive, write_opendrive

__all__ = ["to_apollo", "to_opendrive", "write_apollo", "write_map", "write_native", "write_opendrive"]
