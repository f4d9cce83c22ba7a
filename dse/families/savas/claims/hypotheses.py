"""The hypotheses the noisy-consensus-filter claims rest on, each decided on the scenario's design.

Theorem 1 (eqs. (15), (22)-(23)) needs Q row stochastic (so that Q†1 = 1) and nonnegative
(so that ρ(Q†) = 1), and ℓ in (0, 1] (ℓ = 0 has no steady state). The paper assumes Q
doubly stochastic and says that a connected undirected graph makes the unit eigenvalue
simple with all others inside the unit disk (that needs aperiodicity as well). The trace
formula (16) and the identity (24) use a modal decomposition and so need Q normal. Our
gain tables (minimisers of (16)) and the modal closed forms are computed for symmetric Q.
The claim that ζ* → 0 is about averaging over a network of at least two agents.

Thresholds are the family's validation tolerance (doubly stochastic) or round-off levels
(symmetric, normal): a matrix that is normal only up to 1e-13 is reported as not normal,
with its number, rather than compared against formulas that assume it exactly.
"""
from __future__ import annotations

import numpy as np

from dse.verify.rules import EPS, Holds

from ..design import Design
from .common import DOUBLY_STOCHASTIC, GAINS, NETWORK, NORMAL, PRIMITIVE, SUM_TOL, SYMMETRIC, claims, stochastic_deviation


@claims.hypothesis(DOUBLY_STOCHASTIC, "Q is nonnegative and doubly stochastic (Q1 = 1, 1ᵀQ = 1ᵀ), as §II assumes; "
                   "Theorem 1 uses Q†1 = 1 and ρ(Q†) = 1")
def doubly_stochastic(design: Design) -> Holds:
    Q = design.scenario.Q
    dev, neg = stochastic_deviation(Q), float(max(-Q.min(), 0.0))
    worst = max(dev, neg)
    return Holds(worst <= SUM_TOL, value=worst, threshold=SUM_TOL,
                 detail=f"max |row or column sum − 1| = {dev:.2e}, most negative entry {-neg:.2e}")


@claims.hypothesis(PRIMITIVE, "Q has a simple unit eigenvalue and every other eigenvalue strictly inside the unit disk")
def primitive(design: Design) -> Holds:
    Q = design.scenario.Q
    if len(Q) == 1:
        return Holds(True, value=0.0, threshold=1.0, detail="a single agent: Q = [1]")
    second = float(np.sort(np.abs(np.linalg.eigvals(Q)))[-2])
    return Holds(second < 1.0, value=second, threshold=1.0, detail=f"second largest |λ(Q)| = {second:.9f}")


def normality_tolerance(n: int) -> float:
    """Round-off of the entries of QQᵀ − QᵀQ for a normal Q with entries in [0, 1]."""
    return 10.0 * 2 * n * EPS


@claims.hypothesis(NORMAL, "Q is normal (QQᵀ = QᵀQ, e.g. symmetric): the modal decomposition behind (16) and (24)")
def normal(design: Design) -> Holds:
    Q = design.scenario.Q
    dev = float(np.abs(Q @ Q.T - Q.T @ Q).max())
    tol = normality_tolerance(len(Q))
    return Holds(dev <= tol, value=dev, threshold=tol,
                 detail=f"max |QQᵀ − QᵀQ| = {dev:.3g} (round-off level {tol:.2g}; symmetric Q are normal)")


@claims.hypothesis(SYMMETRIC, "Q is symmetric: the optimal gains (minimisers of (16)) and the modal closed forms are "
                   "computed for symmetric Q")
def symmetric(design: Design) -> Holds:
    Q = design.scenario.Q
    dev = float(np.abs(Q - Q.T).max())
    tol = 10.0 * EPS
    return Holds(dev <= tol, value=dev, threshold=tol, detail=f"max |Q − Qᵀ| = {dev:.3g}")


@claims.hypothesis(GAINS, "every cell's gains satisfy 0 < ℓ ≤ 1 and 0 ≤ ζ ≤ 1 (Theorem 1; ℓ = 0 has no steady state)")
def gains(design: Design) -> Holds:
    cells = list(design.cells) + ([design.long_cell] if design.long_cell is not None else [])
    ells = np.array([c.ell for c in cells])
    zetas = np.array([c.zeta for c in cells])
    ok = bool(np.all((ells > 0) & (ells <= 1)) and np.all((zetas >= 0) & (zetas <= 1)))
    return Holds(ok, value=float(ells.min()), threshold=0.0,
                 detail=f"ℓ in [{ells.min():.6g}, {ells.max():.6g}], ζ in [{zetas.min():.6g}, {zetas.max():.6g}] over "
                        f"{len(cells)} cells; then ρ((1−ℓ)A) = 1 − ℓ < 1 and (22) has a steady state")


@claims.hypothesis(NETWORK, "the network has at least two agents (averaging over neighbours is what re-injection "
                   "trades off)")
def network(design: Design) -> Holds:
    n = design.scenario.n
    return Holds(n >= 2, value=n, threshold=2, detail=f"N = {n} agents")
