"""The template family's stages: the design (exact, no Monte Carlo) and the Monte Carlo.

The error of node i after t rounds is e(t) = x(t) − θ1 = Wᵗ v, so its covariance is exactly
P(t) = r W^{2t} (W symmetric); the design holds P(t)'s diagonal (the mean-square error of every
node) and the spectrum of W. The Monte Carlo draws v and iterates the consensus, keeping only the
sums of e_i(t)² over trials per RNG unit: memory does not grow with the trials.
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from dse.contract.stages import stage
from dse.simulate.seeding import stream_seed
from dse.simulate.units import RNG_UNIT, run_units

from .scenario import ConsensusFile


@dataclass(frozen=True)
class Design:
    """P(t)_ii = r (W^{2t})_ii for t = 0..rounds (rows) and every node (columns), and the
    eigenvalues of W in increasing order."""

    scenario: ConsensusFile
    mse: np.ndarray
    eigenvalues: np.ndarray

    @property
    def second_modulus(self) -> float:
        """max |λ_k| over the eigenvalues but the largest (the consensus rate; 1 when disconnected)."""
        return float(np.max(np.abs(self.eigenvalues[:-1]))) if len(self.eigenvalues) > 1 else 0.0


def design(sc: ConsensusFile) -> Design:
    """The exact mean-square errors by the covariance recursion P(t+1) = W P(t) Wᵀ, P(0) = r I."""
    P = sc.model.r * np.eye(sc.n)
    mse = np.empty((sc.model.rounds + 1, sc.n))
    for t in range(sc.model.rounds + 1):
        mse[t] = np.diag(P)
        P = sc.W @ P @ sc.W.T
    return Design(sc, mse, np.linalg.eigvalsh(sc.W))


@dataclass(frozen=True)
class Results:
    design: Design
    trials: int
    sq: np.ndarray          # (rounds + 1, N): Σ over trials of e_i(t)²

    @property
    def mse(self) -> np.ndarray:
        return self.sq / self.trials


@stage(unkeyed=("budget_bytes",))
def monte_carlo(sc: ConsensusFile, seed: int, trials: int, budget_bytes: float) -> dict[str, np.ndarray]:
    """Σ_trials e_i(t)² for t = 0..rounds, trials streamed in seeded units of RNG_UNIT."""
    def chunk(streams):
        e = np.sqrt(sc.model.r) * streams.standard_normal((sc.n,))      # (B, N): e(0) = v
        sq = np.empty((e.shape[0], sc.model.rounds + 1, sc.n))
        for t in range(sc.model.rounds + 1):
            sq[:, t] = e * e
            e = e @ sc.W.T                                               # e(t+1) = W e(t), row by row
        return [part.sum(axis=0) for part in streams.split(sq)]         # per unit, folded in unit order

    total = run_units(chunk, lambda acc, part: part if acc is None else acc + part, trials,
                      stream_seed(seed, "template", "v"), bytes_per_trial=8.0 * 3 * (sc.model.rounds + 2) * sc.n,
                      budget_bytes=budget_bytes, portable=True)
    return {"sq": total}
