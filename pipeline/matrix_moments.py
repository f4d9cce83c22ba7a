"""Monte Carlo second-moment matrices with the fourth moments needed for their errors.

`MatrixMoments.of(e)` takes vectors e of shape (trials, T, N, n) (T output times, N groups,
e.g. nodes, of n-vectors) and keeps Σ e eᵀ and Σ (e eᵀ) ⊗ (e eᵀ) per (t, group), so that
any quadratic form uᵀ Ê u = (1/K) Σ (uᵀe)² and the trace get a standard error afterwards,
for directions u chosen after the simulation (e.g. the worst eigenvector of a bound's gap).
Second moments are about zero, not about the sample mean (1/K, not 1/(K−1)).
Blocks combine by summation in a fixed order (bit-identical whatever the chunking).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence

import numpy as np


@dataclass(frozen=True)
class MatrixMoments:
    count: int
    s2: np.ndarray   # (T, N, n, n)      Σ e eᵀ
    s4: np.ndarray   # (T, N, n, n, n, n) Σ e_a e_b e_c e_d

    @classmethod
    def of(cls, e: np.ndarray) -> "MatrixMoments":
        s2 = np.einsum("ktna,ktnb->tnab", e, e)
        ee = e[..., :, None] * e[..., None, :]
        s4 = np.einsum("ktnab,ktncd->tnabcd", ee, ee)
        return cls(e.shape[0], s2, s4)

    @classmethod
    def combine(cls, parts: Sequence["MatrixMoments"]) -> "MatrixMoments":
        first, *rest = parts
        out = first
        for p in rest:
            out = cls(out.count + p.count, out.s2 + p.s2, out.s4 + p.s4)
        return out

    def arrays(self, prefix: str = "") -> dict[str, np.ndarray]:
        return {f"{prefix}count": np.array(self.count), f"{prefix}s2": self.s2, f"{prefix}s4": self.s4}

    @classmethod
    def from_arrays(cls, a: dict[str, np.ndarray], prefix: str = "") -> "MatrixMoments":
        return cls(int(a[f"{prefix}count"]), a[f"{prefix}s2"], a[f"{prefix}s4"])

    @property
    def mean(self) -> np.ndarray:
        """Ê[e eᵀ]: (T, N, n, n)."""
        return self.s2 / self.count

    def quadratic(self, u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(uᵀÊu, its standard error) for directions u (T, N, n): arrays (T, N)."""
        K = self.count
        m2 = np.einsum("tna,tnab,tnb->tn", u, self.mean, u)
        m4 = np.einsum("tna,tnb,tnc,tnd,tnabcd->tn", u, u, u, u, self.s4) / K
        return m2, np.sqrt(np.maximum(m4 - m2 ** 2, 0.0) / K)

    def trace(self) -> tuple[np.ndarray, np.ndarray]:
        """(tr Ê, its standard error): arrays (T, N)."""
        K = self.count
        m2 = np.trace(self.mean, axis1=2, axis2=3)
        m4 = np.einsum("tnaabb->tn", self.s4) / K
        return m2, np.sqrt(np.maximum(m4 - m2 ** 2, 0.0) / K)

    def entries(self) -> tuple[np.ndarray, np.ndarray]:
        """(Ê_ab, standard error of each entry): arrays (T, N, n, n)."""
        K = self.count
        m2 = self.mean
        m4 = np.einsum("tnabab->tnab", self.s4) / K
        return m2, np.sqrt(np.maximum(m4 - m2 ** 2, 0.0) / K)
