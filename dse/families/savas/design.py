"""The design stage of the noisy-consensus-filter family: every quantity the theorems are made of
that needs no simulation.

Q and its spectrum, the optimal gains per (m, σ_c) under the printed and the corrected (16),
the cells and their gains, the exact covariances of (22) at the recorded steps and in the
steady state (15), the centralized Kalman reference and the σ_c thresholds of Fig. 1. The stage
returns named arrays (cached); `Design` reads them, with the cells derived from them.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

import dse.estimators.consensus_covariance as cc
import dse.estimators.consensus_trace as ct
import dse.estimators.gain_tuning as gt
from dse.contract.stages import stage

from .cells import ALGORITHMS, LARGE_M, LONG_RUN_STEPS, Cell, scenario_steps
from .scenario import NoisyConsensusFile

#: steady-state covariance matrices are tabulated entry by entry up to this many agents
MATRIX_TABLE_AGENTS = 50
#: the arrays of a cell's steady state in the design (see `design_arrays`)
STEADY_ARRAYS = ("diag", "trace", "gap", "matrix")
#: the columns of the optimal-gain tables (`dse.estimators.gain_tuning.GainTable`)
GAIN_COLUMNS = ("ell", "zeta", "J", "dJ_dell", "dJ_dzeta", "d2J_dell2", "d2J_dzeta2", "kkt_residual", "kkt_scaled",
                "grid_min")


def steady_kwargs(sc: NoisyConsensusFile, cell: Cell) -> dict[str, Any]:
    """The arguments of the steady-state functions of `consensus_covariance` for a cell."""
    return dict(ell=cell.ell, m=cell.m, sigma_c=cell.sigma_c, q=sc.model.q, r=sc.model.r,
                reinjection=cell.reinjection, zeta=cell.zeta)


def filter_kwargs(sc: NoisyConsensusFile, cell: Cell) -> dict[str, Any]:
    """... and of the finite-horizon ones (from P(0|−1) = σ 11ᵀ over the cell's horizon)."""
    return dict(steady_kwargs(sc, cell), sigma0=sc.model.sigma0, n_steps=cell.n_steps)


@dataclass
class Design:
    """The deterministic stage: named arrays (cached) and the cells derived from them."""

    scenario: NoisyConsensusFile
    arrays: dict[str, np.ndarray]
    cells: list[Cell] = field(default_factory=list)
    long_cell: Cell | None = None

    @classmethod
    def of(cls, sc: NoisyConsensusFile, arrays: dict[str, np.ndarray]) -> "Design":
        return cls(sc, arrays, make_cells(sc, arrays), long_run_cell(sc, arrays))

    @property
    def steps(self) -> np.ndarray:
        return self.arrays["steps"]

    def steps_of(self, cell: Cell) -> np.ndarray:
        return self.arrays["steps"] if cell.n_steps == self.scenario.sweep.n_steps else np.arange(cell.n_steps)

    def exact(self, cell: Cell) -> cc.CovarianceAtSteps:
        """P(k|k-1) of (22) at the cell's recorded steps: diag, trace and eigenvalues."""
        a, label = self.arrays, cell.label
        return cc.CovarianceAtSteps(self.steps_of(cell), a[f"exact:{label}:diag"], a[f"exact:{label}:trace"],
                                    a[f"exact:{label}:eig"])

    def steady(self, cell: Cell) -> dict[str, np.ndarray]:
        """The exact steady state of the cell: diag, trace, gap (and matrix up to MATRIX_TABLE_AGENTS agents)."""
        a, label = self.arrays, cell.label
        return {name: a[key] for name in STEADY_ARRAYS if (key := f"steady:{label}:{name}") in a}

    def cell(self, alg: str, m: int, sigma_c: float) -> Cell:
        return next(c for c in self.cells if c.alg == alg and c.m == m and c.sigma_c == sigma_c)

    def all_cells(self) -> list[Cell]:
        """The cells of the grid, then the long run of Theorem 1(i) when it is not one of them."""
        return list(dict.fromkeys(self.cells + [self.long_cell]))

    def kf_prior(self, steps) -> np.ndarray:
        return self.arrays["kf_prior"][np.asarray(steps)]


def gain_tables(sc: NoisyConsensusFile, grid: tuple[int, int]) -> dict[str, np.ndarray]:
    """The optimal gains of (16), printed and corrected, m = 0..rounds_max (Fig. 2); the corrected
    ones at LARGE_M (§IV); the re-optimised gain of Carli's filter. Symmetric Q only."""
    out: dict[str, np.ndarray] = {}
    if not sc.symmetric:
        return out
    common = dict(sigma_c=sc.sweep.sigma_c, q=sc.model.q, r=sc.model.r)
    tables = gt.reinjection_gain_tables(sc.Q, ms=range(sc.rounds_max + 1), formulas=("corrected", "printed"),
                                        grid=grid, **common)
    tables["large_m"] = gt.reinjection_gain_tables(sc.Q, ms=LARGE_M, formulas=("corrected",), grid=grid,
                                                   **common)["corrected"]
    tables["carli_opt"] = gt.carli_gain_table(sc.Q, ms=range(sc.rounds_max + 1), **common)
    for name, t in tables.items():
        for attr in GAIN_COLUMNS:
            out[f"{name}_{attr}"] = getattr(t, attr)
    out["large_m"] = np.array(LARGE_M)
    return out


def reinjection_gains(sc: NoisyConsensusFile, arrays: dict[str, np.ndarray], m: int, sigma_c: float) -> tuple[float, float]:
    """The (ℓ, ζ) the re-injection filter uses in a cell, by the scenario's gain rule."""
    if sc.reinjection.gains == "fixed":
        return sc.reinjection.ell, sc.reinjection.zeta
    s = sc.sweep.sigma_c.index(sigma_c)
    formula = sc.reinjection.gains.removeprefix("optimal-")
    return float(arrays[f"{formula}_ell"][s, m]), float(arrays[f"{formula}_zeta"][s, m])


def make_cells(sc: NoisyConsensusFile, arrays: dict[str, np.ndarray]) -> list[Cell]:
    cells = []
    for alg in ALGORITHMS:
        for m in sc.sweep.rounds:
            for sigma_c in sc.sweep.sigma_c:
                ell, zeta = (sc.carli.ell, 1.0) if alg == "carli" else reinjection_gains(sc, arrays, m, sigma_c)
                cells.append(Cell(alg, m, sigma_c, ell, zeta, sc.sweep.n_steps))
    return cells


def long_run_cell(sc: NoisyConsensusFile, arrays: dict[str, np.ndarray]) -> Cell:
    """Theorem 1(i) check in the asymptotic regime: re-injection filter, m = 1 (or the smallest
    m > 0), the largest σ_c, its gains, over max(n_steps, LONG_RUN_STEPS) steps (the grid's own
    cell when the horizon is long enough)."""
    rounds = sc.sweep.rounds
    m = next((m for m in rounds if m > 0), rounds[-1])
    sigma_c = sc.sweep.sigma_c[-1]
    ell, zeta = reinjection_gains(sc, arrays, m, sigma_c)
    return Cell("reinjection", m, sigma_c, ell, zeta, max(sc.sweep.n_steps, LONG_RUN_STEPS))


def carli_thresholds(sc: NoisyConsensusFile, rounds) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For consecutive m → m' in `rounds`: the σ_c above which tr P(k_eval) of Carli's filter increases
    (0 if it always does, inf if never), the σ_c² coefficients b_m and the noise-free traces a_m."""
    model = sc.model
    return ct.carli_noise_thresholds(sc.Q, ell=sc.carli.ell, ms=rounds, k=sc.sweep.eval_step, q=model.q, r=model.r,
                                     sigma0=model.sigma0)


@stage(name="design", allow_nonfinite=("carli_thresholds",))
def design_arrays(sc: NoisyConsensusFile, grid: tuple[int, int]) -> dict[str, np.ndarray]:
    """Every deterministic quantity of a scenario, as named arrays (see `Design`); `grid`: the (ℓ, ζ)
    grid of the gain optimiser."""
    model, n = sc.model, sc.n
    out = gain_tables(sc, tuple(grid))
    out["Q"] = sc.Q
    lam = np.linalg.eigvalsh(sc.Q) if sc.symmetric else np.linalg.eigvals(sc.Q)
    lam = lam[np.lexsort((np.imag(lam), np.real(lam)))]
    out["eig_real"], out["eig_imag"] = np.real(lam).astype(float), np.imag(lam).astype(float)
    out["steps"] = scenario_steps(sc)
    Kc, NPc = gt.optimal_gain_no_communication(model.q, model.r / n, n)
    K1, NP1 = gt.optimal_gain_no_communication(model.q, model.r, n)
    out["centralized"] = np.array([Kc, NPc / n, K1, NP1 / n])   # K_c, P_c⁻, K_1, P_1⁻
    out["kf_prior"] = cc.centralized_prior_variances(model.q, model.r, n, model.sigma0,
                                                     max(sc.sweep.n_steps, LONG_RUN_STEPS))
    design = Design.of(sc, out)
    full = n <= MATRIX_TABLE_AGENTS
    for c in design.all_cells():
        kw = filter_kwargs(sc, c)
        del kw["n_steps"]
        P = cc.predictive_covariance_at_steps(sc.Q, steps=design.steps_of(c), **kw)
        out[f"exact:{c.label}:diag"], out[f"exact:{c.label}:trace"], out[f"exact:{c.label}:eig"] = \
            P.diag, P.trace, P.eigenvalues
        S = cc.asymptotic_covariance_summary(sc.Q, reference=NPc / n, with_matrix=full, **steady_kwargs(sc, c))
        out[f"steady:{c.label}:diag"], out[f"steady:{c.label}:trace"] = S.diag, np.array(S.trace)
        out[f"steady:{c.label}:gap"] = np.array(S.loewner_gap)
        if full:
            out[f"steady:{c.label}:matrix"] = S.matrix
    if len(sc.sweep.rounds) >= 2:
        out["carli_thresholds"], out["carli_noise_coef"], out["carli_noise_free"] = carli_thresholds(sc, sc.sweep.rounds)
    return out
