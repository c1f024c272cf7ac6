"""Equality joins of arrays by key (sorting, no matrix of every pair): how rows meet the rows,
lanes or walkers of their own slot, and which keys are among a set of them (`member`)."""
from __future__ import annotations

import numpy as np


def same_key_pairs(key_a: np.ndarray, key_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (i, j) with key_a[i] == key_b[j], grouped by i (an equality join by sorting: no
    len(a) x len(b) matrix, so that rows of many sub-envs pair only within their own)."""
    order = key_b.argsort(kind="stable")
    sk = key_b[order]
    lo = sk.searchsorted(key_a, side="left")
    cnt = sk.searchsorted(key_a, side="right") - lo
    i = np.arange(len(key_a)).repeat(cnt)
    j = order[np.arange(int(cnt.sum())) - (cnt.cumsum() - cnt - lo).repeat(cnt)]
    return i, j


def member(keys: np.ndarray, values: np.ndarray | list[int]) -> np.ndarray:
    """`np.isin(keys, values)` of integer keys (any shape): a binary search of each key in the
    sorted values (np.isin's sort of both, or its table over the keys' range, costs ~10x more on
    the few hundred keys a frame's questions hold)."""
    v = np.sort(np.asarray(values, dtype=np.int64).ravel())
    if not len(v):
        return np.zeros(np.shape(keys), dtype=bool)
    return v[np.minimum(v.searchsorted(keys), len(v) - 1)] == keys
