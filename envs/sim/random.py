"""Counter-based draws: a uniform value that is a pure function of (key, counter, stream, index),
for any number of slots at once, with no generator object and no order of drawing (the design's
`random`, docs/architecture.md). A slot's key is drawn once per episode from its env's
generator; the counter is the slot's frame; the stream names the purpose; the index the item
(a crosswalk of the slot). A sub-env of a batch draws what the single env on its seed draws,
whatever the other sub-envs do. A JAX port puts `jax.random`'s counter-based generator here."""
from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1, _M2 = np.uint64(0xBF58476D1CE4E5B9), np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31, _S32, _S11, _ONE = (np.uint64(k) for k in (30, 27, 31, 32, 11, 1))


def _mix(z: np.ndarray) -> np.ndarray:
    """SplitMix64's finaliser: a bijection of 64-bit words that spreads every input bit."""
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


def uniform(key: ArrayLike, counter: ArrayLike, stream: ArrayLike, index: ArrayLike) -> np.ndarray:
    """Per element of the broadcast arrays, a draw in [0, 1) (53 bits) from (key, counter,
    stream, index); `key` uint64, the others non-negative ints (index < 2**32)."""
    # (arrays of at least one dimension: their words wrap silently, as meant)
    key, counter, stream, index = (np.atleast_1d(np.asarray(a, dtype=np.uint64)) for a in (key, counter, stream, index))
    z = _mix(key + _GOLDEN)  # each input absorbed in turn
    z = _mix(z + _GOLDEN * (counter + _ONE))
    z = _mix(z + _GOLDEN * (((stream << _S32) | index) + _ONE))
    return (z >> _S11).astype(np.float64) * 2.0 ** -53
