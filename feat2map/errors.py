"""Exceptions that carry the file and element they are about, for one-line CLI errors."""
from __future__ import annotations


class Feat2MapError(Exception):
    """Base error: `where` names the file and/or element, `message` says what is wrong."""

    def __init__(self, message: str, where: str | None = None) -> None:
        self.message = message
        self.where = where
        super().__init__(f"{where}: {message}" if where else message)


class FeatureError(Feat2MapError, ValueError):
    """An invalid junction feature, feature space or spec."""


class MapFormatError(Feat2MapError, ValueError):
    """A map file that cannot be read: corrupt, truncated, or referencing unknown ids."""


class LayoutError(Feat2MapError):
    """A feature set that cannot be placed or built as a valid map."""
