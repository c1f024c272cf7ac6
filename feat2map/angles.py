"""Angle arithmetic, written once: the signed difference of two headings, wrapped.

Every module that compares headings or socket angles uses these (radians in the model, degrees
in features and specs); they take floats or NumPy arrays and give the same bits as the inline
`(a + pi) % (2 pi) - pi` they replace.
"""
from __future__ import annotations

import math
from typing import TypeVar

import numpy as np

A = TypeVar("A", float, np.ndarray)


def wrap_angle(a: A) -> A:
    """`a` (radians) wrapped into [-pi, pi): the signed smallest turn equal to it."""
    return (a + math.pi) % (2 * math.pi) - math.pi


def wrap_degrees(a: A) -> A:
    """`a` (degrees) wrapped into [-180, 180)."""
    return (a + 180.0) % 360.0 - 180.0

