"""What the noisy-consensus-filter claims share: the one `ClaimSet` they register into, the ids of
the hypotheses, and the round-off allowances and readings of the results that several checks use.

Tolerances are round-off allowances (`dse.verify.rules.roundoff_tolerance`) built from the
size of the inputs, the length of the operation chain and the conditioning. The one
condition number that recurs: the Stein equation P = ÃPÃᵀ + B of the steady state, with
Ã = (1−ℓ)A and A = Q† or Q^m nonnegative and doubly stochastic (so ‖A‖₂ ≤ 1), has
condition at most (1 + (1−ℓ)²)/(1 − (1−ℓ)²); scipy solves it directly (N² unknowns) for
N < 10 and through a bilinear transform with two inverses of I + Ã otherwise, whose
condition enters squared. Identities that inherit the input's deviation δ from double
stochasticity (Q†1 = 1 and the like) add the propagated (m+1)·δ.
"""
from __future__ import annotations

import numpy as np

import dse.estimators.consensus_covariance as cc
import dse.estimators.gain_tuning as gt
from dse.contract.claims import ClaimSet
from dse.verify.rules import EPS, roundoff_tolerance

from ..cells import Cell
from ..results import Results

claims = ClaimSet(modules=tuple(f"{__package__}.{m}" for m in ("hypotheses", "model", "theorem1", "monte_carlo", "gains",
                                                              "large_m", "carli", "figures")))  # report order

DS = DOUBLY_STOCHASTIC = "savas.hyp.Q_doubly_stochastic"
PRIM = PRIMITIVE = "savas.hyp.Q_primitive"
NORMAL = "savas.hyp.Q_normal"
SYM = SYMMETRIC = "savas.hyp.Q_symmetric"
GAINS = "savas.hyp.gains"
NET = NETWORK = "savas.hyp.network"
#: scope of the claims about the paper's own example
P = "paper-example"

#: the family's validation tolerance on row and column sums (dse.scenario.graphs.check_consensus_matrix)
SUM_TOL = 1e-10
#: the exact tests hold at any sample size; two trials are the least that make a sum of squares a test
MIN_TRIALS = 2
SQRT_EPS = float(np.sqrt(EPS))


def stochastic_deviation(Q: np.ndarray) -> float:
    """max |Q1 − 1|, |1ᵀQ − 1ᵀ|: how far the scenario's Q is from doubly stochastic (an input error
    that identities such as Q†1 = 1 inherit, multiplied by the number of powers taken)."""
    return float(max(np.abs(Q.sum(axis=1) - 1).max(), np.abs(Q.sum(axis=0) - 1).max()))


def tol(**kw) -> float:
    return roundoff_tolerance(**kw)[0]


def stein_condition(ell: float) -> float:
    a = (1.0 - ell) ** 2
    return (1.0 + a) / (1.0 - a)


def lyapunov_allowance(A: np.ndarray, ell: float, P: np.ndarray) -> float:
    """Round-off allowance on the entries of scipy's solution of P = ÃPÃᵀ + B, Ã = (1−ℓ)A."""
    n = len(A)
    cond = stein_condition(ell)
    if n >= 10:  # scipy's bilinear transform inverts I + Ã twice
        cond *= float(np.linalg.cond(np.eye(n) + (1.0 - ell) * A)) ** 2
    return tol(scale=float(np.abs(P).max()), operations=n * n + 10, condition=cond)


def steady(res: Results, *, ell, zeta, m, sigma_c, reinjection=True):
    """Lyapunov steady state, its transition matrix A and the round-off allowance of its entries."""
    sc = res.scenario
    kw = dict(ell=ell, m=m, sigma_c=sigma_c, q=sc.model.q, r=sc.model.r, reinjection=reinjection, zeta=zeta)
    P = cc.asymptotic_covariance_lyapunov(sc.Q, **kw)
    A = cc.error_transition_matrix(sc.Q, m, zeta, reinjection=reinjection)
    return P, A, lyapunov_allowance(A, ell, P)


def spectrum(Q: np.ndarray) -> np.ndarray:
    """Eigenvalues of Q: real (eigvalsh) when Q is exactly symmetric, complex otherwise."""
    return np.linalg.eigvalsh(Q) if np.array_equal(Q, Q.T) else np.linalg.eigvals(Q)


def input_deviation(res: Results) -> float:
    """The input's deviation δ from a nonnegative doubly stochastic matrix (row and column sums, twice the most
    negative entry): identities like Q†1 = 1 and ‖Q†‖_∞ = 1 inherit it once per power of Q."""
    Q = res.scenario.Q
    return max(stochastic_deviation(Q), 2 * float(max(-Q.min(), 0.0)))


def stochastic_defects(A: np.ndarray) -> np.ndarray:
    """|A1 − 1|_∞, |‖A‖_∞ − 1| and the most negative entry: all 0 iff ρ(A) = ‖A‖_∞ = 1 with A ≥ 0, A1 = 1."""
    return np.array([np.abs(A.sum(axis=1) - 1).max(), abs(np.abs(A).sum(axis=1).max() - 1), max(-A.min(), 0.0)])


def alg_cells(res: Results, alg: str, m_min: int = 0) -> list[Cell]:
    return [c for c in res.cells if c.alg == alg and c.m >= m_min]


def table_rounds(res: Results) -> list[int]:
    """m values for checks over the number of rounds: 0..min(rounds_max, 20) and the scenario's m."""
    sc = res.scenario
    return sorted(set(range(min(sc.rounds_max, 20) + 1)) | set(sc.sweep.rounds))


def step_index(res: Results, cell: Cell, k: int) -> int:
    """Position of step k among the cell's recorded steps (eval_step and the last step always are)."""
    return int(np.searchsorted(res.design.steps_of(cell), k))


def steps_text(res: Results) -> str:
    n_steps = res.scenario.sweep.n_steps
    n = len(res.design.steps)
    return f"every k < {n_steps}" if n == n_steps else f"{n} recorded steps k in 0..{n_steps - 1}"


def eval_traces(res: Results, alg: str) -> np.ndarray:
    """Exact tr P(k_eval|k_eval−1) of the cells of one filter, (σ_c, m)."""
    sweep = res.scenario.sweep
    out = np.empty((len(sweep.sigma_c), len(sweep.rounds)))
    for s, s_c in enumerate(sweep.sigma_c):
        for j, m in enumerate(sweep.rounds):
            c = res.design.cell(alg, m, s_c)
            out[s, j] = res.design.exact(c).trace[step_index(res, c, sweep.eval_step)]
    return out


def centralized(res: Results) -> tuple[float, float, float]:
    """(K_c, N P_c⁻, N P₁⁻): the centralized Kalman gain and costs (closed forms)."""
    sc = res.scenario
    Kc, NPc = gt.optimal_gain_no_communication(sc.model.q, sc.model.r / sc.n, sc.n)
    return Kc, NPc, gt.optimal_gain_no_communication(sc.model.q, sc.model.r, sc.n)[1]


def formula_allowance(J, ell) -> np.ndarray:
    """Round-off of (16): each mode divides by 1 − (1−ℓ)²μ², at worst 1 − (1−ℓ)² (relative loss eps/(1−(1−ℓ)²))."""
    ell = np.asarray(ell, float)
    return 10 * 20 * EPS * np.abs(J) / (1 - (1 - ell) ** 2)
