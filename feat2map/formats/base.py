"""What every map format offers: a record of its faces (read, write, validate), and the
`Problem` a validator reports. Faces are named as "module:function" and imported on first
use, so the table costs nothing until a format is used."""
from __future__ import annotations

import importlib
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from typing import Any, Callable

from ..errors import Feat2MapError


def header_date() -> str | None:
    """The date a writer stamps into a file header (ISO 8601, UTC), or None to leave it out.
    Never the wall clock, so the same map always gives the same bytes: the date is
    SOURCE_DATE_EPOCH (seconds since 1970, the reproducible-builds convention) when it is set."""
    raw = os.environ.get("SOURCE_DATE_EPOCH")
    if raw is None or not raw.strip():
        return None
    try:
        return datetime.fromtimestamp(int(raw), timezone.utc).strftime("%Y-%m-%dT%H:%M:%S")
    except (ValueError, OverflowError, OSError):
        raise Feat2MapError("must be whole seconds since 1970-01-01 UTC", f"SOURCE_DATE_EPOCH={raw[:40]!r}") from None


@dataclass(frozen=True)
class Problem:
    """One thing wrong with a map: the element (kind and id, or file) and what is wrong."""

    element: str
    message: str

    def __str__(self) -> str:
        return f"{self.element}: {self.message}"


@dataclass(frozen=True)
class ExportOption:
    """A writer keyword exposed as `feat2map export FORMAT --flag`: argparse keywords for it."""

    flag: str
    kwarg: str
    argparse: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class MapFormat:
    """One map format and its faces; `output` is "file" (with `suffixes[0]`) or "dir"."""

    name: str
    title: str
    suffixes: tuple[str, ...] = ()
    output: str = "file"
    input: str = "map"  # what `write` takes: "map" (an HDMap) or "suite" (a scenario suite)
    read: str | None = None  # "module:function": (path) -> HDMap
    write: str | None = None  # (HDMap or Suite, path, **options) -> None, atomic
    validate: str | None = None  # (path, progress=False) -> list[Problem]
    picture: str | None = None  # (path, out, problems, title) -> None: the map with its problems marked
    sniff: Callable[[bytes], bool] | None = None  # does a file starting with these bytes hold this format?
    options: tuple[ExportOption, ...] = ()
    markers: tuple[str, ...] = ()  # "dir" output: files of an earlier export (a folder holding one is replaced whole)

    def face(self, name: str) -> Callable[..., Any]:
        """The function behind face `name` (read, write, validate, picture), imported now."""
        ref = getattr(self, name)
        if ref is None:
            raise LookupError(f"format {self.name} has no {name}")
        module, func = ref.split(":")
        return getattr(importlib.import_module(module), func)
