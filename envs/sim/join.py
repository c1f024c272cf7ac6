"""Equality joins of arrays by key (sorting, no matrix of every pair): how rows meet the rows,
lanes or walkers of their own slot."""
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
