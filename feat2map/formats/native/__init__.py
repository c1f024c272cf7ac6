"""The native map file: versioned JSON that loads back to an equal `HDMap` (`mapfile`)."""
from __future__ import annotations

from ...validation import check_references
from .mapfile import dumps, from_dict, load, save, to_dict

__all__ = ["check_references", "dumps", "from_dict", "load", "save", "to_dict"]
