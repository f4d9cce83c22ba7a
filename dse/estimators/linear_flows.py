"""Exact solutions of constant-coefficient linear and affine flows.

* affine ODE ``ṗ = M p + g`` on a uniform grid through one matrix exponential of the
  augmented generator ``[[M, g], [0, 0]]`` (exact, also when M is singular or unstable, and
  unconditionally stable for stiff M: no step-size restriction);
* steady states by a linear solve, spectral abscissae and the critical parameter at which a
  parameterised generator becomes Hurwitz (bisection);
* the Van Loan integral ``Q(δ) = ∫_0^δ e^{As} G e^{Aᵀs} ds`` for one δ, and for a whole batch
  of different δ at once through an eigendecomposition of a block-diagonal A.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Callable, Sequence

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it


def affine_flow_grid(M: np.ndarray, g: np.ndarray, p0: np.ndarray, step: float, n_steps: int) -> np.ndarray:
    """p(k·step), k = 0..n_steps, for ṗ = M p + g, p(0) = p0 (exact up to rounding).

    Returns an array (n_steps + 1, len(p0)). Overflow for an unstable M is allowed to happen
    (the values become inf): callers report a diverging bound, they do not crash on it.
    """
    d = len(p0)
    aug = np.zeros((d + 1, d + 1))
    aug[:d, :d] = M
    aug[:d, d] = g
    E = scipy.linalg.expm(aug * step)
    F, c = E[:d, :d], E[:d, d]
    out = np.empty((n_steps + 1, d))
    out[0] = p0
    with np.errstate(over="ignore", invalid="ignore"):
        for k in range(n_steps):
            out[k + 1] = F @ out[k] + c
    return out


def spectral_abscissa(M: np.ndarray) -> float:
    """max Re eig(M)."""
    return float(np.max(np.linalg.eigvals(M).real))


def affine_steady_state(M: np.ndarray, g: np.ndarray) -> np.ndarray | None:
    """The equilibrium −M⁻¹g of ṗ = Mp + g if M is Hurwitz, else None (the flow diverges or
    has no unique limit)."""
    if spectral_abscissa(M) >= 0:
        return None
    return np.linalg.solve(M, -g)


def critical_parameter(abscissa: Callable[[float], float], *, tol: Callable[[float], float] | float = 0.0,
                       upper: float = 1e9, rtol: float = 1e-10, start: float | None = None) -> float:
    """inf{λ ≥ 0 : abscissa(λ) < 0} for an abscissa that decreases through zero once.

    `tol(λ)` (or a constant) is the rounding level of the computed abscissa: a value within
    ±tol cannot be told from 0. Returns 0.0 when abscissa(0) < −tol, and also when abscissa(0)
    is zero up to rounding while small λ > 0 are stable (the marginal case: the flow at λ = 0
    is only marginally stable, and the sign change sits at λ = 0 up to rounding, so the
    bisection stops as soon as the abscissa can no longer be told from 0 instead of chasing
    rounding noise down to λ ≈ 1e-16). Returns inf when no λ up to `upper` gives an abscissa
    below −tol.
    """
    level = tol if callable(tol) else (lambda lam, _t=float(tol): _t)
    a0 = abscissa(0.0)
    if a0 < -level(0.0):
        return 0.0
    lo, hi = 0.0, (start if start is not None else 1e-3)      # `start`: a known stable value
    while abscissa(hi) >= -level(hi):
        lo, hi = hi, hi * 4
        if hi > upper:
            return math.inf
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi)
        a = abscissa(mid)
        if a < -level(mid):
            hi = mid
        elif a > level(mid):
            lo = mid
        else:                                                   # zero up to rounding: the sign change is here
            hi = mid
            break
    return 0.0 if lo == 0.0 and a0 <= level(0.0) else hi


def critical_parameter_by_test(hurwitz: Callable[[float], bool], a0: float, t0: float, *, upper: float = 1e9,
                               rtol: float = 1e-10, start: float | None = None) -> float:
    """As `critical_parameter`, with stability decided by `hurwitz(λ)` (e.g. one linear solve for a
    resolvent positive generator) instead of an abscissa; a0 ± t0 is the abscissa at λ = 0 and its
    round-off level (0 when a0 < −t0; 0 too when a0 is zero to round-off and a small λ > 0 is stable)."""
    if a0 < -t0:
        return 0.0
    if abs(a0) <= t0 and hurwitz(1e-9):
        return 0.0
    lo, hi = 0.0, 1e-3
    if start is not None and math.isfinite(start) and start > 0 and hurwitz(start):
        hi = start
    while not hurwitz(hi):
        lo, hi = hi, hi * 4
        if hi > upper:
            return math.inf
    while hi - lo > rtol * hi:
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if hurwitz(mid) else (mid, hi)
    return hi


def abscissa_tolerance(M: np.ndarray) -> float:
    """Rounding level of the computed spectral abscissa of M: 10·dim·eps·‖M‖₁ (backward error of
    the eigenvalue solver; eigenvalues of a normal matrix move by at most that much)."""
    return 10.0 * len(M) * float(np.finfo(float).eps) * float(np.abs(M).sum(axis=0).max())


def van_loan(A: np.ndarray, G: np.ndarray, delta: float) -> tuple[np.ndarray, np.ndarray]:
    """(e^{Aδ}, ∫_0^δ e^{As} G e^{Aᵀs} ds) by Van Loan's block exponential.

    The block exponential contains e^{−Aδ}, which overflows or loses every digit when ‖A‖δ is
    large (stiff node dynamics, e.g. gains of 1e4). It is therefore formed on δ/2^k with
    ‖A‖₁δ/2^k ≤ 1/2, and the interval doubled k times: Φ(2d) = Φ(d)², Q(2d) = Q(d) + Φ(d)Q(d)Φ(d)ᵀ
    (every step adds positive semidefinite terms: no cancellation)."""
    n = len(A)
    norm = float(np.abs(A).sum(axis=0).max()) * abs(delta)
    k = int(math.ceil(math.log2(norm / 0.5))) if norm > 0.5 else 0
    d = delta / 2 ** k
    C = np.zeros((2 * n, 2 * n))
    C[:n, :n] = -A
    C[:n, n:] = G
    C[n:, n:] = A.T
    E = scipy.linalg.expm(C * d)
    Phi = E[n:, n:].T
    Q = Phi @ E[:n, n:]
    Q = (Q + Q.T) / 2
    for _ in range(k):
        Q = Q + Phi @ Q @ Phi.T
        Q = (Q + Q.T) / 2
        Phi = Phi @ Phi
    return Phi, Q


def phi1(c: np.ndarray, delta: np.ndarray) -> np.ndarray:
    """∫_0^δ e^{cs} ds = (e^{cδ} − 1)/c, = δ at c = 0, for complex c (elementwise, broadcast)."""
    c = np.asarray(c, dtype=complex)
    delta = np.asarray(delta, dtype=float)
    x = c * delta
    small = np.abs(x) < 1e-5
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        big = np.where(small, 0.0, np.expm1(x) / np.where(c == 0, 1.0, c))
    series = delta * (1 + x / 2 + x * x / 6 + x * x * x / 24)
    return np.where(small, series, big)


@dataclass(frozen=True)
class BlockDiagonalFlow:
    """A = blkdiag(A_0, …, A_{b−1}) (equal n×n blocks) with noise intensity G (bn×bn).

    Holds the eigendecomposition of every block so that e^{Aδ} and the Van Loan integral
    Q(δ) can be formed for a whole batch of different δ (one per Monte Carlo trial):
    Q(δ)_{ab} = V_a [G̃_{ab} ∘ φ(μ_a ⊕ μ_b, δ)] V_bᵀ with G̃_{ab} = V_a⁻¹ G_{ab} V_b⁻ᵀ.
    Needs every block diagonalisable; `condition` reports the worst eigenvector condition
    number so that callers can refuse defective blocks.
    """

    vecs: np.ndarray     # (b, n, n) complex
    inv: np.ndarray      # (b, n, n) complex
    eigs: np.ndarray     # (b, n) complex
    Gt: np.ndarray       # (b, b, n, n) complex
    sums: np.ndarray     # (b, b, n, n) complex: μ_a[i] + μ_b[j]
    condition: float

    @classmethod
    def of(cls, blocks: Sequence[np.ndarray], G: np.ndarray) -> "BlockDiagonalFlow":
        b, n = len(blocks), blocks[0].shape[0]
        eigs, vecs = zip(*(np.linalg.eig(np.asarray(Ab, float)) for Ab in blocks))
        vecs = np.array(vecs, dtype=complex)
        eigs = np.array(eigs, dtype=complex)
        with np.errstate(all="ignore"):
            cond = float(max(np.linalg.cond(v) for v in vecs))
        if not cond < 1e8:     # (nearly) defective: report it, do not invert
            zero = np.zeros((b, b, n, n), dtype=complex)
            return cls(vecs, vecs, eigs, zero, zero, math.inf)
        inv = np.linalg.inv(vecs)
        Gb = np.asarray(G, float).reshape(b, n, b, n).transpose(0, 2, 1, 3)
        Gt = inv[:, None] @ Gb @ inv[None, :].transpose(0, 1, 3, 2)
        sums = eigs[:, None, :, None] + eigs[None, :, None, :]
        return cls(vecs, inv, eigs, Gt, sums, cond)

    @property
    def n_blocks(self) -> int:
        return self.vecs.shape[0]

    @property
    def block(self) -> int:
        return self.vecs.shape[1]

    @cached_property
    def _dense(self) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Block-diagonal eigenvector matrix V (bn, bn), all eigenvalues μ (bn,), G̃ (bn, bn)
        and 1/(μ_a + μ_b) (0 where the sum vanishes)."""
        b, n = self.n_blocks, self.block
        V = np.zeros((b * n, b * n), dtype=complex)
        for a in range(b):
            V[a * n:(a + 1) * n, a * n:(a + 1) * n] = self.vecs[a]
        Gt = self.Gt.transpose(0, 2, 1, 3).reshape(b * n, b * n)
        mu = self.eigs.reshape(-1)
        sums = mu[:, None] + mu[None, :]
        inv = np.where(sums == 0, 0.0, 1.0 / np.where(sums == 0, 1.0, sums))
        return V, mu, Gt, inv

    def transition(self, delta: np.ndarray) -> np.ndarray:
        """e^{A_a δ_k} for every k and block a: (K, b, n, n), real."""
        d = np.asarray(delta, float)[:, None, None]
        E = np.exp(self.eigs[None] * d)                       # (K, b, n)
        return ((self.vecs[None] * E[:, :, None, :]) @ self.inv[None]).real

    @cached_property
    def _noise_parts(self) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
        """G̃ ∘ 1/(μ_a + μ_b) (bn, bn), the sums μ_a + μ_b, min |μ_a + μ_b|, and Vᵀ per block."""
        _, mu, Gt, inv = self._dense
        sums = mu[:, None] + mu[None, :]
        return Gt * inv, sums, float(np.abs(sums).min()), self.vecs.transpose(0, 2, 1).copy()

    def noise(self, delta: np.ndarray) -> np.ndarray:
        """Q(δ_k) for every k: (K, bn, bn), real and symmetric.

        φ(μ_a + μ_b, δ) = (e^{μ_aδ}e^{μ_bδ} − 1)/(μ_a + μ_b), with a 4-term series where
        |(μ_a + μ_b)δ| < 1e-3 (no cancellation, and exact at a vanishing sum).

        Cost (profiled in `dse reproduce tanwani`, where this is the event-driven simulator's
        hot spot): G̃ ∘ 1/(μ_a + μ_b) is formed once; the series is evaluated only on the rows
        k that have a small entry; V is block diagonal, so V X Vᵀ is done block row by block
        row (b times fewer flops than the dense complex product)."""
        _, mu, Gt, _ = self._dense
        H, sums, smallest, vecs_T = self._noise_parts
        b, n = self.n_blocks, self.block
        d = b * n
        delta = np.asarray(delta, float)
        K = len(delta)
        E = np.exp(mu[None] * delta[:, None])                   # (K, bn)
        X = E[:, :, None] * E[:, None, :]
        X -= 1.0
        X *= H                                                  # G̃ ∘ φ off the small entries
        rows = np.flatnonzero(delta * smallest < 1e-3)          # rows holding a small entry
        if rows.size:
            x = sums[None] * delta[rows, None, None]
            k, i, j = np.nonzero(np.abs(x) < 1e-3)
            if k.size:
                xs = x[k, i, j]
                X[rows[k], i, j] = Gt[i, j] * (delta[rows[k]] * (1 + xs / 2 + xs * xs / 6 + xs * xs * xs / 24))
        # V X Vᵀ with V = blkdiag(V_a): left factor per block row, right factor per block column
        Y = (self.vecs[None] @ X.reshape(K, b, n, d)).reshape(K, d, b, n)
        Z = (Y.transpose(0, 2, 1, 3) @ vecs_T[None]).real      # (K, b, d, n): block column c of V X Vᵀ
        Q = Z.transpose(0, 2, 1, 3).reshape(K, d, d)
        return (Q + Q.transpose(0, 2, 1)) / 2


@dataclass(frozen=True)
class DenseFlow:
    """The same interface as `BlockDiagonalFlow` for blocks that are not diagonalisable
    (e.g. a double integrator): every δ gets its own Van Loan block exponential (batched
    scipy expm of the (2bn × 2bn) matrix). Exact, but much slower per trial."""

    blocks: tuple
    G: np.ndarray

    @classmethod
    def of(cls, blocks: Sequence[np.ndarray], G: np.ndarray) -> "DenseFlow":
        return cls(tuple(np.asarray(b, float) for b in blocks), np.asarray(G, float))

    @property
    def n_blocks(self) -> int:
        return len(self.blocks)

    @property
    def block(self) -> int:
        return self.blocks[0].shape[0]

    @cached_property
    def _generator(self) -> np.ndarray:
        A = scipy.linalg.block_diag(*self.blocks)
        d = len(A)
        C = np.zeros((2 * d, 2 * d))
        C[:d, :d] = -A
        C[:d, d:] = self.G
        C[d:, d:] = A.T
        return C

    def _both(self, delta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Batched Van Loan with the same scaling and doubling as `van_loan`: every δ is divided by
        2^k (k from its own ‖A‖₁δ, so that a row's result does not depend on the batch) and
        doubled k times, the rows with the same k together."""
        d = self._generator.shape[0] // 2
        delta = np.asarray(delta, float)
        norm = float(np.abs(self._generator[d:, d:]).sum(axis=0).max()) * delta
        with np.errstate(divide="ignore"):
            ks = np.where(norm > 0.5, np.ceil(np.log2(np.maximum(norm, 1e-300) / 0.5)), 0).astype(int)
        Phi_all, Q_all = np.empty((len(delta), d, d)), np.empty((len(delta), d, d))
        for k in np.unique(ks):
            rows = np.flatnonzero(ks == k)
            E = scipy.linalg.expm(self._generator[None] * (delta[rows] / 2 ** k)[:, None, None])
            Phi = E[:, d:, d:].transpose(0, 2, 1)
            Q = Phi @ E[:, :d, d:]
            Q = (Q + Q.transpose(0, 2, 1)) / 2
            for _ in range(k):
                Q = Q + Phi @ Q @ Phi.transpose(0, 2, 1)
                Q = (Q + Q.transpose(0, 2, 1)) / 2
                Phi = Phi @ Phi
            Phi_all[rows], Q_all[rows] = Phi, Q
        return Phi_all, Q_all

    def transition(self, delta: np.ndarray) -> np.ndarray:
        Phi, _ = self._both(delta)
        b, n = self.n_blocks, self.block
        return np.stack([Phi[:, a * n:(a + 1) * n, a * n:(a + 1) * n] for a in range(b)], axis=1)

    def noise(self, delta: np.ndarray) -> np.ndarray:
        return self._both(delta)[1]
