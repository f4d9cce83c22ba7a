"""Deterministic random streams derived from one user seed.

A stream is named by a tuple of labels (e.g. ``("carli", 3, 0.5)``); the same seed and
labels always give the same stream, whatever order the streams are created in, how the
trials are chunked or how many worker processes run them.
"""
from __future__ import annotations

import hashlib
from typing import Hashable

import numpy as np


def _label_word(label: Hashable) -> int:
    digest = hashlib.blake2b(repr(label).encode(), digest_size=4).digest()
    return int.from_bytes(digest, "little")


def stream_seed(seed: int, *labels: Hashable) -> np.random.SeedSequence:
    """The SeedSequence of the stream named `labels` under the root `seed`."""
    return np.random.SeedSequence(entropy=seed, spawn_key=tuple(_label_word(x) for x in labels))


def block_seeds(seq: np.random.SeedSequence, n_blocks: int, first: int = 0) -> list[np.random.SeedSequence]:
    """Child sequences, one per block of trials, of blocks first..n_blocks-1: block b is always seeded the same."""
    return [np.random.SeedSequence(entropy=seq.entropy, spawn_key=seq.spawn_key + (b,)) for b in range(first, n_blocks)]
