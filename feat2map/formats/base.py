"""What every map format offers: a record of its faces (read, write, validate), the shape
of each face (the Protocols `MapReader`, `MapWriter`, `SuiteWriter`, `MapValidator`,
`ProblemPicture`), and the `Problem` a validator reports. Faces are named as "module:function"
and imported on first use, so the table costs nothing until a format is used;
`MapFormat.check_faces` (run by the tests for every entry) says where an entry's function does
not fit its Protocol."""
from __future__ import annotations

import importlib
import inspect
import os
from dataclasses import dataclass, field
from datetime import datetime, timezone
from pathlib import Path
from typing import TYPE_CHECKING, Any, Callable, Protocol, Sequence

from ..errors import Feat2MapError
from ..messages import printable

if TYPE_CHECKING:
    from ..model import HDMap


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
    """One thing wrong with a map: the element (kind and id, or file) and what is wrong. Shown
    on one line: ids from a damaged file may hold newlines or escapes, written escaped. A
    `warning` is what the format's own tool rates a warning, not an error (lanelet2_validation's
    curvature and point-distance checks): shown, but the map still validates."""

    element: str
    message: str
    warning: bool = False

    def __str__(self) -> str:
        return printable(f"{'warning: ' if self.warning else ''}{self.element}: {self.message}")


class MapReader(Protocol):
    """A format's `read` face: the map in the file (or folder) `path`; bad input raises
    `MapFormatError` naming the file and the element."""

    def __call__(self, path: str | Path, /) -> HDMap: ...


class MapWriter(Protocol):
    """A format's `write` face for maps: write `m` to `path` atomically (same map, same bytes);
    format options (`MapFormat.options`) come as keywords with defaults."""

    def __call__(self, m: HDMap, path: str | Path, /) -> object: ...


class SuiteWriter(Protocol):
    """A format's `write` face for scenario suites (`MapFormat.input == "suite"`): write the
    suite to the folder `out` atomically."""

    def __call__(self, suite: Any, out: str | Path, /) -> object: ...


class MapValidator(Protocol):
    """A format's `validate` face: every problem of the file `path` (none: it passed);
    `progress` shows a progress bar on a terminal."""

    def __call__(self, path: str | Path, /, progress: bool = False) -> list[Problem]: ...


class ProblemPicture(Protocol):
    """A format's `picture` face: the map in `path` drawn with `problems` marked, to `out`."""

    def __call__(self, path: str | Path, out: str | Path, problems: Sequence[Problem] = (), /,
                 title: str | None = None) -> None: ...


def fits(func: Callable[..., Any], protocol: type) -> str | None:
    """None when `func` can be called as `protocol.__call__` is (every positional parameter
    positionally, every keyword parameter by name), else what does not fit. Checks the
    parameters, not their types (the type checker does that where the function is named)."""
    want = list(inspect.signature(protocol.__call__).parameters.values())[1:]  # without self
    try:
        have = inspect.signature(func)
    except (TypeError, ValueError):
        return "has no inspectable signature"
    positional = [object()] * sum(p.kind is p.POSITIONAL_ONLY for p in want)
    keywords = {p.name: object() for p in want if p.kind is p.POSITIONAL_OR_KEYWORD or p.kind is p.KEYWORD_ONLY}
    required = [p for p in want if p.kind is p.POSITIONAL_ONLY and p.default is p.empty]
    for args, kwargs in ((positional, keywords), ([object()] * len(required), {})):
        try:
            have.bind(*args, **kwargs)
        except TypeError as exc:
            return f"cannot be called as {protocol.__name__}: {exc}"
    return None


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
    check: str | None = None  # (path) -> None: a Feat2MapError when more than `path` may not be written (files beside it)

    def face(self, name: str) -> Callable[..., Any]:
        """The function behind face `name` (read, write, validate, picture), imported now."""
        ref = getattr(self, name)
        if ref is None:
            raise LookupError(f"format {self.name} has no {name}")
        module, func = ref.split(":")
        return getattr(importlib.import_module(module), func)

    def protocol(self, name: str) -> type:
        """The Protocol face `name` must fit."""
        if name == "write":
            return SuiteWriter if self.input == "suite" else MapWriter
        return {"read": MapReader, "validate": MapValidator, "picture": ProblemPicture}[name]

    def check_faces(self) -> list[str]:
        """What does not fit: each face that does not import, is not callable or does not fit
        its Protocol (an export option the writer does not take included), one line each."""
        out = []
        for name in ("read", "write", "validate", "picture"):
            if getattr(self, name) is None:
                continue
            try:
                func = self.face(name)
            except (ImportError, AttributeError, ValueError) as exc:
                out.append(f"{self.name}.{name}: {getattr(self, name)!r} does not import ({exc})")
                continue
            problem = fits(func, self.protocol(name)) if callable(func) else "is not callable"
            if problem is None and name == "write" and self.options:
                try:
                    inspect.signature(func).bind(object(), object(), **{o.kwarg: object() for o in self.options})
                except TypeError as exc:
                    problem = f"does not take its export options: {exc}"
            if problem:
                out.append(f"{self.name}.{name}: {getattr(self, name)} {problem}")
        return out
