"""Angle arithmetic, written once: headings wrapped, and the turn a heading change makes.

Every module that compares headings or socket angles uses these (radians in the model, degrees
in features and specs); they take floats or NumPy arrays (elementwise) and give the same bits
as the inline `(a + pi) % (2 pi) - pi` / `a % (2 pi)` they replace.
"""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

from .config import STRAIGHT_TOLERANCE_DEG, UTURN_THRESHOLD_DEG

A = TypeVar("A", float, np.ndarray)


def wrap_angle(a: A) -> A:
    """`a` (radians) wrapped into [-pi, pi): the signed smallest turn equal to it."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def wrap_degrees(a: A) -> A:
    """`a` (degrees) wrapped into [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0


def positive_angle(a: A) -> A:
    """`a` (radians) wrapped into [0, 2 pi): a heading as a direction (Python's `%`: a negative
    closer to 0 than float spacing at 2 pi gives 2 pi itself)."""
    return a % (2 * math.pi)


def positive_degrees(a: A) -> A:
    """`a` (degrees) wrapped into [0, 360) (as `positive_angle`, a tiny negative gives 360): a
    socket angle, or the anticlockwise gap `b - a`."""
    return a % 360.0


def turn_name(change_deg: float, uturns: bool = False) -> str:
    """The turn of a heading change [deg, left positive, within +-180]: "none" (straight) within
    STRAIGHT_TOLERANCE_DEG, else "left" / "right"; with `uturns`, "uturn" from
    UTURN_THRESHOLD_DEG on (for lanes whose geometry is all there is to tell a U-turn by)."""
    if uturns and abs(change_deg) >= UTURN_THRESHOLD_DEG:
        return "uturn"
    if abs(change_deg) <= STRAIGHT_TOLERANCE_DEG:
        return "none"
    return "left" if change_deg > 0 else "right"


def classify_turn(entry_heading: float, exit_heading: float, uturns: bool = False) -> str:
    """The turn (`turn_name`) from `entry_heading` to `exit_heading` (radians), in the paper's
    sense: left / straight ("none") / right (/ "uturn" with `uturns`)."""
    return turn_name(math.degrees(wrap_angle(exit_heading - entry_heading)), uturns)
