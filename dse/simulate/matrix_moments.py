"""Monte Carlo second-moment matrices with the fourth moments their standard errors need.

For vectors e of shape (trials, T, N, n) (T output times, N groups, e.g. nodes, of n-vectors)
`MatrixMoments` keeps, per (time, group), Σ e eᵀ, Σ (eᵀe)² and Σ e_a²e_b²: the mean Ê[e eᵀ],
its trace and its entries then get standard errors, in memory that grows like T·N·n², not n⁴.
Second moments are about zero, not about the sample mean (1/K, not 1/(K−1)).

Streaming: `zeros` and `add(index, e)` fill the time slots `index` from a batch of trials (a
window of output times); parts combine by summation in a fixed order (`combine`), so that a
result does not depend on how the trials were chunked.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class MatrixMoments:
    count: int
    s2: np.ndarray        # (T, N, n, n) Σ e eᵀ
    s4_trace: np.ndarray  # (T, N)       Σ (eᵀe)²
    s4_entry: np.ndarray  # (T, N, n, n) Σ e_a² e_b²

    @classmethod
    def zeros(cls, count: int, T: int, N: int, n: int) -> "MatrixMoments":
        return cls(count, np.zeros((T, N, n, n)), np.zeros((T, N)), np.zeros((T, N, n, n)))

    def add(self, index, e: np.ndarray) -> None:
        """Add the trials' e (count, L, N, n) to the time slots `index` (L of them), in place."""
        et = np.ascontiguousarray(np.moveaxis(e, 0, -1))           # (L, N, n, trials): one product per (t, group)
        sq = et * et
        self.s2[index] += et @ np.swapaxes(et, -1, -2)
        self.s4_trace[index] += np.square(sq.sum(axis=-2)).sum(axis=-1)
        self.s4_entry[index] += sq @ np.swapaxes(sq, -1, -2)

    @classmethod
    def of(cls, e: np.ndarray) -> "MatrixMoments":
        out = cls.zeros(e.shape[0], *e.shape[1:])
        out.add(slice(None), e)
        return out

    @classmethod
    def combine(cls, parts: Sequence["MatrixMoments"]) -> "MatrixMoments":
        first, *rest = parts
        out = first
        for p in rest:
            out = cls(out.count + p.count, out.s2 + p.s2, out.s4_trace + p.s4_trace, out.s4_entry + p.s4_entry)
        return out

    def arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        return {f"{prefix}count": np.array(self.count), f"{prefix}s2": self.s2, f"{prefix}s4_trace": self.s4_trace,
                f"{prefix}s4_entry": self.s4_entry}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray], prefix: str = "") -> "MatrixMoments":
        return cls(int(a[f"{prefix}count"]), a[f"{prefix}s2"], a[f"{prefix}s4_trace"], a[f"{prefix}s4_entry"])

    @property
    def mean(self) -> np.ndarray:
        """Ê[e eᵀ]: (T, N, n, n)."""
        return self.s2 / self.count

    def trace(self) -> tuple[np.ndarray, np.ndarray]:
        """(tr Ê, its standard error): arrays (T, N)."""
        K = self.count
        m2 = np.trace(self.mean, axis1=2, axis2=3)
        m4 = self.s4_trace / K
        return m2, np.sqrt(np.maximum(m4 - m2 ** 2, 0.0) / K)

    def entries(self) -> tuple[np.ndarray, np.ndarray]:
        """(Ê_ab, standard error of each entry): arrays (T, N, n, n)."""
        K = self.count
        m2 = self.mean
        m4 = self.s4_entry / K
        return m2, np.sqrt(np.maximum(m4 - m2 ** 2, 0.0) / K)
