"""Common quadratic Lyapunov functions by semidefinite programming (cvxpy + Clarabel).

Two families of LMIs:

* homogeneous vertex LMIs A_kᵀ P + P A_k ≤ −ε I, P > 0 (k over the vertices of a polytope,
  e.g. (28)-(29)): feasibility is decided by the sign of the normalised margin
  t* = max { t : tr P = d, P ⪰ 0, A_kᵀ P + P A_k ⪯ −t I }, an always-feasible problem;
* affine LMIs R_k(P) ⪯ 0 with constant blocks (e.g. (38)-(39)): t* = max { t : P ⪰ 0,
  tr P ≤ cap, R_k(P) ⪯ −t I }; t* < 0 certifies infeasibility of R_k(P) ⪯ 0 for every
  P ⪰ 0 with tr P ≤ cap (and, since t is capped by the constant blocks, for large P too when
  the cap is not active).

Both also run the plain feasibility problem the paper describes (objective 0) and report the
solver's own status string; a solver exception becomes a status, never a crash. Every
returned P is re-verified with numpy eigenvalues.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

SOLVER = "CLARABEL"
#: the status of a feasibility problem that was not asked for (`feasibility=False`)
NOT_SOLVED = "not solved"


@dataclass(frozen=True)
class LmiResult:
    """`status`: the solver's status of the feasibility problem ("optimal" means feasible,
    "infeasible", or "solver_error: …"); `margin`: t* of the normalised margin problem
    (> 0: strictly feasible); `P`: the margin problem's maximiser (None if it failed);
    `verified`: max eigenvalue of the LMI matrices at `P` recomputed with numpy."""

    status: str
    margin: float
    P: np.ndarray | None
    verified: float
    margin_status: str
    feasible_P: np.ndarray | None = None


def _solve(prob) -> str:
    import warnings

    import cvxpy as cp

    try:
        with warnings.catch_warnings():
            # "Solution may be inaccurate" is reported through the status ("optimal_inaccurate")
            warnings.simplefilter("ignore", UserWarning)
            prob.solve(solver=SOLVER)
        return str(prob.status)
    except cp.error.SolverError as exc:
        return f"solver_error: {str(exc).splitlines()[0][:120]}"


def lyapunov_matrices(vertices: Sequence[np.ndarray], P: np.ndarray) -> np.ndarray:
    return np.stack([A.T @ P + P @ A for A in vertices])


def vertex_margin(vertices: Sequence[np.ndarray], P: np.ndarray) -> float:
    """max_k λ_max(A_kᵀ P + P A_k): ≤ −ε means (28)-(29) hold with ε."""
    return float(max(np.linalg.eigvalsh((X + X.T) / 2).max() for X in lyapunov_matrices(vertices, P)))


def common_lyapunov(vertices: Sequence[np.ndarray], eps: float, *, feasibility: bool = True) -> LmiResult:
    """Decide A_kᵀ P + P A_k ≤ −ε I (all k), P > 0; see the module docstring. `feasibility=False` solves the
    margin problem only (status "not solved")."""
    import cvxpy as cp

    vertices = [np.asarray(A, float) for A in vertices]
    d = vertices[0].shape[0]
    I = np.eye(d)
    P, t = cp.Variable((d, d), symmetric=True), cp.Variable()
    cons = [P >> 0, cp.trace(P) == d] + [A.T @ P + P @ A << -t * I for A in vertices]
    margin_prob = cp.Problem(cp.Maximize(t), cons)
    margin_status = _solve(margin_prob)
    Pm = None if P.value is None else (P.value + P.value.T) / 2
    margin = float(t.value) if t.value is not None else float("nan")
    verified = vertex_margin(vertices, Pm) if Pm is not None else float("nan")
    if not feasibility:
        return LmiResult(NOT_SOLVED, margin, Pm, verified, margin_status)
    # the paper's feasibility problem (objective 0) with ε inflated by 10% against solver tolerance
    Pf = cp.Variable((d, d), symmetric=True)
    feas = cp.Problem(cp.Minimize(0), [Pf >> eps * I] + [A.T @ Pf + Pf @ A << -1.1 * eps * I for A in vertices])
    status = _solve(feas)
    Pfv = None if Pf.value is None or status not in ("optimal", "optimal_inaccurate") else (Pf.value + Pf.value.T) / 2
    return LmiResult(status, margin, Pm, verified, margin_status, Pfv)


def affine_lmi(blocks: Sequence[Callable], d: int, *, lower: float = 0.0, cap: float = 1e4,
               feasibility: bool = True) -> LmiResult:
    """Decide R_k(P) ⪯ 0 (all k), P ⪰ lower·I, for affine maps R_k given as cvxpy expression builders
    `R_k(P) -> expression` (symmetric). Also returns the max-margin P over lower·I ⪯ P, tr P ≤ cap.
    `feasibility=False` solves the margin problem only (status "not solved")."""
    import cvxpy as cp

    P, t = cp.Variable((d, d), symmetric=True), cp.Variable()
    sizes = [R(np.zeros((d, d))).shape[0] for R in blocks]
    cons = [P >> lower * np.eye(d), cp.trace(P) <= cap] + [R(P) << -t * np.eye(s) for R, s in zip(blocks, sizes)]
    margin_status = _solve(cp.Problem(cp.Maximize(t), cons))
    Pm = None if P.value is None else (P.value + P.value.T) / 2
    margin = float(t.value) if t.value is not None else float("nan")
    verified = float(max(np.linalg.eigvalsh(np.asarray(R(Pm), float)).max() for R in blocks)) if Pm is not None else float("nan")
    if not feasibility:
        return LmiResult(NOT_SOLVED, margin, Pm, verified, margin_status)
    Pf = cp.Variable((d, d), symmetric=True)
    status = _solve(cp.Problem(cp.Minimize(0), [Pf >> lower * np.eye(d)] + [R(Pf) << 0 for R in blocks]))
    Pfv = None if Pf.value is None or status not in ("optimal", "optimal_inaccurate") else (Pf.value + Pf.value.T) / 2
    return LmiResult(status, margin, Pm, verified, margin_status, Pfv)
