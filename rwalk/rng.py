"""Counter-based random numbers: a pure function of (key, counter), vectorised.

Every episode start draws its random numbers from its own key, so that env i
of a batch seeded s starts exactly like a single env seeded s + i (Gymnasium's
convention for vector envs), whatever else the batch does and in whatever
order envs reset. SplitMix64 on numpy's wrapping uint64 arithmetic.
"""

from __future__ import annotations

import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)


def _splitmix64(x: np.ndarray) -> np.ndarray:
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def uniform(keys: np.ndarray, n: int) -> np.ndarray:
    """Independent uniform numbers in [0, 1) for each key.

    Args:
        keys: one non-negative integer key per stream. Shape: (M,).
        n: numbers per stream.

    Returns:
        Shape: (M, n) float64. Row i depends only on keys[i].
    """
    with np.errstate(over="ignore"):
        k = _splitmix64(np.asarray(keys).astype(np.uint64))
        counters = np.arange(1, n + 1, dtype=np.uint64)
        bits = _splitmix64(k[:, None] ^ _splitmix64(counters)[None, :])
    return (bits >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))
