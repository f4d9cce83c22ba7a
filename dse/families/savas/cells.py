"""The cells of a noisy-consensus-filter scenario and the steps whose statistics are kept: what both
stages (design and Monte Carlo) and the cost model are organised by."""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .scenario import NoisyConsensusFile

ALGORITHMS = ("carli", "reinjection")
#: the m of the large-m gain tables (§IV)
LARGE_M = (5, 10, 20, 50, 100, 200)
#: the horizon of Theorem 1(i)'s long run, when the scenario's is shorter
LONG_RUN_STEPS = 60
#: grid of (ℓ, ζ) in quick runs
QUICK_GRID = (100, 101)


@dataclass(frozen=True)
class Cell:
    """One Monte Carlo cell: algorithm, rounds m, communication noise σ_c, its gains and horizon."""

    alg: str
    m: int
    sigma_c: float
    ell: float
    zeta: float
    n_steps: int

    @property
    def label(self) -> str:
        return f"{self.alg}_m{self.m}_sc{self.sigma_c:g}_K{self.n_steps}"

    @property
    def reinjection(self) -> bool:
        return self.alg == "reinjection"


def gain_grid(sc: NoisyConsensusFile, quick: bool) -> tuple[int, int]:
    return QUICK_GRID if quick else (sc.gains.grid[0], sc.gains.grid[1])


def recorded_steps(n_steps: int, budget: int, eval_step: int) -> np.ndarray:
    """The steps whose statistics are kept: all when n_steps <= budget, else the first budget/2 steps,
    then evenly spaced up to the last step, and eval_step."""
    if n_steps <= budget:
        return np.arange(n_steps)
    head = budget // 2
    tail = np.rint(np.linspace(head, n_steps - 1, budget - head)).astype(np.int64)
    return np.unique(np.concatenate([np.arange(head), tail, [eval_step]]))


def scenario_steps(sc: NoisyConsensusFile) -> np.ndarray:
    return recorded_steps(sc.sweep.n_steps, sc.sweep.recorded_steps, sc.sweep.eval_step)
