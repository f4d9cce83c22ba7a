"""Common quadratic Lyapunov functions by semidefinite programming (Clarabel, called directly).

Two families of LMIs:

* homogeneous vertex LMIs A_kᵀ P + P A_k ≤ −ε I, P > 0 (k over the vertices of a polytope,
  e.g. (28)-(29)): feasibility is decided by the sign of the normalised margin
  t* = max { t : tr P = d, P ⪰ 0, A_kᵀ P + P A_k ⪯ −t I }, an always-feasible problem;
* affine LMIs R_k(P) ⪯ 0 with constant blocks (e.g. (38)-(39)): t* = max { t : P ⪰ 0,
  tr P ≤ cap, R_k(P) ⪯ −t I }; t* < 0 certifies infeasibility of R_k(P) ⪯ 0 for every
  P ⪰ 0 with tr P ≤ cap (and, since t is capped by the constant blocks, for large P too when
  the cap is not active).

Both also run the plain feasibility problem the paper describes (objective 0) and report the
solver's status in cvxpy's words ("optimal", "optimal_inaccurate", "infeasible", ...; a solver
failure is "solver_error: …", never an exception). Every returned P is re-verified with numpy
eigenvalues.

The problems are small (P of order 4 to 12), so they go to Clarabel as they are: the unknowns are
the upper triangle of P (by columns) and t, each LMI M(P, t) ⪰ 0 one positive semidefinite cone in
Clarabel's scaled triangle form, its coefficients read off the affine map on the basis of symmetric
matrices. Building them through cvxpy took 15 ms of canonicalisation per problem and 0.5 s of
imports; this takes well under 1 ms. The solutions agree with cvxpy's (same solver and
tolerances) to the solver's accuracy (margins to 1e-5 relative or better on the paper's LMIs).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import numpy as np

SOLVER = "CLARABEL"
#: the status of a feasibility problem that was not asked for (`feasibility=False`)
NOT_SOLVED = "not solved"
#: Clarabel's statuses in cvxpy's words; any other is a solver error
_STATUS = {"Solved": "optimal", "AlmostSolved": "optimal_inaccurate", "PrimalInfeasible": "infeasible",
           "AlmostPrimalInfeasible": "infeasible_inaccurate", "DualInfeasible": "unbounded",
           "AlmostDualInfeasible": "unbounded_inaccurate", "MaxIterations": "user_limit", "MaxTime": "user_limit"}
_SOLVED = ("optimal", "optimal_inaccurate")


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


def _triangle(d: int) -> list[tuple[int, int]]:
    """(i, j), i ≤ j, of the upper triangle by columns: the order of Clarabel's triangle cones."""
    return [(i, j) for j in range(d) for i in range(j + 1)]


def _svec(M: np.ndarray) -> np.ndarray:
    """The scaled triangle vector of symmetric matrices (..., s, s): off-diagonal entries times √2."""
    i, j = np.array(_triangle(M.shape[-1])).T
    return M[..., i, j] * np.where(i == j, 1.0, np.sqrt(2.0))


def _basis(d: int) -> np.ndarray:
    """The symmetric matrices E_m with P = Σ_m x_m E_m, x the upper triangle of P by columns."""
    E = np.zeros((d * (d + 1) // 2, d, d))
    for m, (i, j) in enumerate(_triangle(d)):
        E[m, i, j] = E[m, j, i] = 1.0
    return E


@dataclass(frozen=True)
class _Lmi:
    """M(P, t) = M0 + Σ_m x_m Mx[m] + t·Mt ⪰ 0."""

    M0: np.ndarray
    Mx: np.ndarray
    Mt: np.ndarray


def _solve(lmis: Sequence[_Lmi], d: int, *, maximize_t: bool, trace_equal: float | None = None,
           trace_at_most: float | None = None) -> tuple[str, np.ndarray | None, float]:
    """(status, P, t) of max t (or of the feasibility problem) subject to the LMIs and the trace constraint."""
    import clarabel
    from scipy.sparse import csc_matrix

    nx = d * (d + 1) // 2
    trace = np.r_[[1.0 if i == j else 0.0 for i, j in _triangle(d)], 0.0]
    rows, rhs, cones = [], [], []
    if trace_equal is not None:
        rows.append(trace[None])
        rhs.append([trace_equal])
        cones.append(clarabel.ZeroConeT(1))
    if trace_at_most is not None:
        rows.append(trace[None])
        rhs.append([trace_at_most])
        cones.append(clarabel.NonnegativeConeT(1))
    for lmi in lmis:      # s = svec(M(x)) = svec(M0) − A x with A = −[svec(Mx), svec(Mt)]
        rows.append(-np.column_stack([_svec(lmi.Mx).T, _svec(lmi.Mt)]))
        rhs.append(_svec(lmi.M0))
        cones.append(clarabel.PSDTriangleConeT(lmi.M0.shape[0]))
    q = np.zeros(nx + 1)
    q[-1] = -1.0 if maximize_t else 0.0
    settings = clarabel.DefaultSettings()
    settings.verbose = False
    try:
        solution = clarabel.DefaultSolver(csc_matrix((nx + 1, nx + 1)), q, csc_matrix(np.vstack(rows)),
                                          np.concatenate(rhs), cones, settings).solve()
    except Exception as exc:  # noqa: BLE001 - a solver failure is a status, never a crash
        return f"solver_error: {str(exc).splitlines()[0][:120]}", None, float("nan")
    raw = str(solution.status)
    status = _STATUS.get(raw, f"solver_error: Clarabel status {raw}")
    if status not in _SOLVED:
        return status, None, float("nan")
    x = np.asarray(solution.x, float)
    P = np.einsum("m,mij->ij", x[:nx], _basis(d))
    return status, P, float(x[-1]) if maximize_t else float("nan")


def lyapunov_matrices(vertices: Sequence[np.ndarray], P: np.ndarray) -> np.ndarray:
    return np.stack([A.T @ P + P @ A for A in vertices])


def vertex_margin(vertices: Sequence[np.ndarray], P: np.ndarray) -> float:
    """max_k λ_max(A_kᵀ P + P A_k): ≤ −ε means (28)-(29) hold with ε."""
    return float(max(np.linalg.eigvalsh((X + X.T) / 2).max() for X in lyapunov_matrices(vertices, P)))


def common_lyapunov(vertices: Sequence[np.ndarray], eps: float, *, feasibility: bool = True) -> LmiResult:
    """Decide A_kᵀ P + P A_k ≤ −ε I (all k), P > 0; see the module docstring. `feasibility=False` solves the
    margin problem only (status "not solved")."""
    vertices = [np.asarray(A, float) for A in vertices]
    d = vertices[0].shape[0]
    E, I, Z = _basis(d), np.eye(d), np.zeros((d, d))
    lyap = [-(A.T @ E + E @ A) for A in vertices]                          # −(AᵀE_m + E_mA)
    lmis = [_Lmi(Z, E, Z)] + [_Lmi(Z, L, -I) for L in lyap]                # P ⪰ 0, −(AᵀP + PA) − tI ⪰ 0
    margin_status, Pm, margin = _solve(lmis, d, maximize_t=True, trace_equal=float(d))
    Pm = None if Pm is None else (Pm + Pm.T) / 2
    verified = vertex_margin(vertices, Pm) if Pm is not None else float("nan")
    if not feasibility:
        return LmiResult(NOT_SOLVED, margin, Pm, verified, margin_status)
    # the paper's feasibility problem (objective 0) with ε inflated by 10% against solver tolerance
    status, Pf, _ = _solve([_Lmi(-eps * I, E, Z)] + [_Lmi(-1.1 * eps * I, L, Z) for L in lyap], d, maximize_t=False)
    return LmiResult(status, margin, Pm, verified, margin_status, None if Pf is None else (Pf + Pf.T) / 2)


def affine_lmi(blocks: Sequence[Callable[[np.ndarray], np.ndarray]], d: int, *, lower: float = 0.0, cap: float = 1e4,
               feasibility: bool = True) -> LmiResult:
    """Decide R_k(P) ⪯ 0 (all k), P ⪰ lower·I, for affine maps R_k of symmetric d×d matrices, given as
    functions (numpy in, symmetric numpy out). Also returns the max-margin P over lower·I ⪯ P, tr P ≤ cap.
    `feasibility=False` solves the margin problem only (status "not solved")."""
    E, I, Z = _basis(d), np.eye(d), np.zeros((d, d))
    affine = []
    for R in blocks:                          # R(P) = R0 + Σ_m x_m (R(E_m) − R0)
        R0 = np.asarray(R(Z), float)
        affine.append((R0, np.stack([np.asarray(R(e), float) - R0 for e in E])))
    lower_lmi = _Lmi(-lower * I, E, Z)                                      # P − lower·I ⪰ 0
    lmis = [lower_lmi] + [_Lmi(-R0, -Rx, -np.eye(len(R0))) for R0, Rx in affine]   # −R(P) − tI ⪰ 0
    margin_status, Pm, margin = _solve(lmis, d, maximize_t=True, trace_at_most=cap)
    Pm = None if Pm is None else (Pm + Pm.T) / 2
    verified = float(max(np.linalg.eigvalsh(np.asarray(R(Pm), float)).max() for R in blocks)) if Pm is not None else float("nan")
    if not feasibility:
        return LmiResult(NOT_SOLVED, margin, Pm, verified, margin_status)
    status, Pf, _ = _solve([lower_lmi] + [_Lmi(-R0, -Rx, np.zeros_like(R0)) for R0, Rx in affine], d, maximize_t=False)
    return LmiResult(status, margin, Pm, verified, margin_status, None if Pf is None else (Pf + Pf.T) / 2)
