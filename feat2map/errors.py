"""Exceptions that carry the file and element they are about, for one-line CLI errors.

Every message is one line of at most ERROR_MAX_CHARS characters: control characters are
escaped and long parts cut, so an error never dumps a file's content (`snippet` is the way to
quote a short piece of the offending element)."""
from __future__ import annotations

from typing import Any

from .messages import MAX_LINE_CHARS, one_line

ERROR_MAX_CHARS = MAX_LINE_CHARS  # one error line, file and element included
WHERE_MAX_CHARS = 200
SNIPPET_MAX_CHARS = 40


def snippet(value: Any, cap: int = SNIPPET_MAX_CHARS) -> str:
    """A short, escaped quotation of an offending value for an error message."""
    text = one_line(repr(value), 10**9)
    return text if len(text) <= cap else text[: cap - 3] + "..."


class Feat2MapError(ValueError):
    """Base error: `where` names the file and/or element, `message` says what is wrong. A
    ValueError (bad input is a bad value), so code that catches ValueError catches it too."""

    def __init__(self, message: str, where: str | None = None) -> None:
        self.where = one_line(where, WHERE_MAX_CHARS) if where else where
        room = ERROR_MAX_CHARS - (len(self.where) + 2 if self.where else 0)
        self.message = one_line(message, max(room, 100))
        super().__init__(f"{self.where}: {self.message}" if self.where else self.message)

    def rename_path(self, old: str, new: str) -> None:
        """Say `new` wherever the error says `old` (a hidden staging folder the user never named)."""
        self.where = self.where.replace(old, new) if self.where else self.where
        self.message = self.message.replace(old, new)
        self.args = tuple(a.replace(old, new) if isinstance(a, str) else a for a in self.args)


class FeatureError(Feat2MapError):
    """An invalid junction feature, feature space or spec."""


class MapFormatError(Feat2MapError):
    """A map file that cannot be read: corrupt, truncated, or referencing unknown ids."""


class LayoutError(Feat2MapError):
    """A feature set that cannot be placed or built as a valid map."""


class CrossingRoadsError(LayoutError):
    """Roads between junctions (or a stub) that would cross outside junctions with this layout:
    generation lays the map out again with the strict cardinal rule before giving up."""


class ConfigError(Feat2MapError):
    """A configuration or command-line value that is not finite, out of range or of the wrong type."""


class LimitError(Feat2MapError):
    """A request above a size limit (`feat2map.config.Limits`); the message says how to raise it."""


class RepairWarning(UserWarning):
    """A reader's repair of geometry the file holds validly but the env cannot drive as it is (a
    lane border folding back round a bend tighter than the lane's width): validators report it
    as a warning, not a problem with the file."""
