"""Readers of HD map files (kept for documented imports; the formats live in feat2map.formats)."""
from __future__ import annotations

from ..formats import read_map
from ..formats.apollo import read_apollo, read_apollo_bytes
from ..formats.native import load as read_native
from ..formats.opendrive import read_opendrive

__all__ = ["read_apollo", "read_apollo_bytes", "read_map", "read_native", "read_opendrive"]
