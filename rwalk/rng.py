"""Counter-based random numbers: a pure function of (seed, stream, counter), vectorised.

A key is a hash of three things: a seed, a named stream (one per randomised
quantity, e.g. ``"start_pose"``) and a counter within that stream (e.g. how
many starts an env has drawn). Different seeds, streams or counters give
independent numbers; drawing from one stream never moves another, so a new
randomised quantity (a new stream name) leaves every existing draw unchanged.
The core keys env i's k-th start by (s + i, "start_pose", k), so that env i of
a batch seeded s starts exactly like a single env seeded s + i (Gymnasium's
convention for vector envs), whatever else the batch does and in whatever order
envs reset. SplitMix64 on numpy's wrapping uint64 arithmetic; seeds are taken
modulo 2^64.
"""

from __future__ import annotations

import hashlib

import numpy as np
import torch

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_MIX1 = np.uint64(0xBF58476D1CE4E5B9)
_MIX2 = np.uint64(0x94D049BB133111EB)

#: Seeds are 64-bit: 0 <= seed < SEED_LIMIT.
SEED_LIMIT = 2**64


def _splitmix64(x: np.ndarray) -> np.ndarray:
    z = x + _GOLDEN
    z = (z ^ (z >> np.uint64(30))) * _MIX1
    z = (z ^ (z >> np.uint64(27))) * _MIX2
    return z ^ (z >> np.uint64(31))


def stream_id(name: str) -> np.uint64:
    """A stable 64-bit id of a stream name (BLAKE2b; Python's ``hash`` is salted per run)."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"stream name must be a non-empty string, got {name!r}")
    digest = hashlib.blake2b(name.encode("utf-8"), digest_size=8).digest()
    return np.uint64(int.from_bytes(digest, "little"))


def keys(seeds: np.ndarray | int, stream: str, counters: np.ndarray | int) -> np.ndarray:
    """Keys of the draws numbered ``counters`` in ``stream`` under ``seeds``.

    Args:
        seeds: non-negative integers below 2^64 (broadcast with counters).
        stream: the stream's name.
        counters: non-negative integers below 2^64.

    Returns:
        Shape: broadcast of seeds and counters, uint64.
    """
    with np.errstate(over="ignore"):
        seeds = np.asarray(seeds).astype(np.uint64)
        counters = np.asarray(counters).astype(np.uint64)
        mixed = _splitmix64(_splitmix64(seeds) ^ stream_id(stream))
        return _splitmix64(mixed ^ counters)


def uniform(keys: np.ndarray, n: int) -> np.ndarray:
    """Independent uniform numbers in [0, 1) for each key.

    Args:
        keys: one non-negative integer key per draw, e.g. from ``keys()``. Shape: (M,).
        n: numbers per draw.

    Returns:
        Shape: (M, n) float64. Row i depends only on keys[i].
    """
    with np.errstate(over="ignore"):
        k = _splitmix64(np.asarray(keys).astype(np.uint64))
        counters = np.arange(1, n + 1, dtype=np.uint64)
        bits = _splitmix64(k[:, None] ^ _splitmix64(counters)[None, :])
    return (bits >> np.uint64(11)).astype(np.float64) * (1.0 / (1 << 53))


def uniform_rows(seed: int, rows, stream: str, counters, n: int):
    """n uniform [0, 1) numbers for each env of ``rows`` from env i's key (seed + i,
    ``stream``, counters[i]); each counter then moves on by one.

    Args:
        seed: the batch's base seed.
        rows: env indices, a torch tensor. Shape: (M,).
        counters: each env's draws so far, a torch long tensor (updated in place). Shape: (N,).

    Returns:
        Shape: (M, n) torch float64.
    """
    ids = rows.numpy().astype(np.uint64)
    with np.errstate(over="ignore"):
        seeds = np.uint64(seed) + ids
    drawn = keys(seeds, stream, counters[rows].numpy().astype(np.uint64))
    counters[rows] += 1
    return torch.from_numpy(uniform(drawn, n))
