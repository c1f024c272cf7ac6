"""Equality joins of arrays by key (sorting; a matrix of every pair only for a few keys): how rows
meet the rows, lanes or walkers of their own slot, and which keys are among a set of them
(`member`)."""
from __future__ import annotations

import numpy as np

SMALL_JOIN = 4096  # len(a) x len(b) up to this: one equality matrix costs less than the sort's fixed cost


def same_key_pairs(key_a: np.ndarray, key_b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Every (i, j) with key_a[i] == key_b[j], grouped by i, each group's j ascending (an
    equality join by sorting: no len(a) x len(b) matrix, so that rows of many sub-envs pair only
    within their own; a few keys, such as one slot's, by the matrix, the same pairs in the same
    order). Each key of a is searched once among the distinct keys of b."""
    if len(key_a) * len(key_b) <= SMALL_JOIN:
        i, j = np.equal.outer(key_a, key_b).nonzero()
        return i, j
    order = key_b.argsort(kind="stable")
    sk = key_b[order]
    head = np.empty(len(sk), dtype=bool)  # the first of each run of equal keys
    head[:1] = True
    np.not_equal(sk[1:], sk[:-1], out=head[1:])
    start = head.nonzero()[0]
    at = np.minimum(sk[start].searchsorted(key_a), len(start) - 1)  # (b has keys: else the matrix)
    lo = start[at]
    cnt = np.where(sk[lo] == key_a, np.diff(start, append=len(sk))[at], 0)
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
