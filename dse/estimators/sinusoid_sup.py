"""Certified suprema of ‖w(t)‖₂ and ‖ẇ(t)‖₂ for a sum of sinusoids, over all t ≥ 0.

The bounds (15)-(16) of the coestimation paper use w̄ ≥ sup_t ‖w(t)‖₂ and sup_t ‖ẇ(t)‖₂. For
w_k(t) = o_k + Σ_j a_kj sin(ν_kj t + φ_kj) the norm ‖w(t)‖ is periodic only when the
frequencies are commensurate, and its period is that of the smallest common frequency ν₀
(e.g. two close frequencies beat with the difference frequency), which can be much longer
than any single period or the simulated horizon. Sampling a finite window can then miss the
maximum. Here, with the distinct positive frequencies ν_1..ν_D and
w(t) = F(ν t), F(θ) = o + Σ_d (c_d cos θ_d + s_d sin θ_d):

* commensurate frequencies (each ν_d/ν_min a fraction with denominator ≤ 1000, matching to a
  relative 1e-9; decimal inputs such as 0.3 and 0.5 are read as the exact ratios they denote):
  ν_d = k_d ν₀ with integers k_d, and the supremum over t ≥ 0 is the maximum over one
  period τ = ν₀ t ∈ [0, 2π) of ‖F(k τ)‖;
* otherwise: the maximum of ‖F(θ)‖ over the torus θ ∈ [0, 2π)^D, an upper bound of the
  supremum over t (equal to it when the frequencies are rationally independent, by
  Kronecker's theorem); with more than 5 such frequencies, the sum of the amplitudes per component
  (rigorous, with the slack to a sampled value reported).

Either maximum is bracketed by branch and bound. On a box with centre x_c and half-widths h
(x the period parameter τ or the torus angles θ, θ_d = K_d·x), F(x_c + δ) = F_c + J_c δ + R
with ‖R‖ ≤ ½ Σ_d A_d (Σ_j |K_dj| h_j)², A_d = ‖[c_d s_d]‖₂ (each sinusoid's second derivative
has norm ≤ A_d); ‖F_c + J_c δ‖ is convex in δ, so its maximum over the box is at a vertex.
This second-order bound makes the boxes that survive near a smooth maximum few. The search
stops when upper − lower ≤ 1e-8 of the scale (or at a work budget): `upper` is always a
rigorous bound, `lower` a value attained, and their difference is reported as the slack. The
supremum itself (`value`) is then found to round-off by local ascent from the best boxes left:
the maximum lies in one of them, and near a smooth maximum the ascent converges quadratically.
"""
from __future__ import annotations

import itertools
import math
from dataclasses import dataclass
from fractions import Fraction

import numpy as np

MAX_DENOMINATOR = 1000
RATIO_RTOL = 1e-9
MAX_HARMONIC = 20_000
REL_TOL = 1e-8
MAX_BOXES = 1_000_000
CHUNK = 8192
MAX_TORUS_DIM = 5   # beyond this many incommensurate frequencies: the per-component triangle inequality


@dataclass(frozen=True)
class SupBound:
    """sup_t ‖·‖₂ bracketed: lower ≤ sup ≤ upper. `method`: "constant", "period" (exact
    period 2π/ν₀ searched), "torus" (independent phases; an upper bound of the supremum
    over t) or "triangle" (more than MAX_TORUS_DIM incommensurate frequencies: the sum of the
    amplitudes per component); `period`: the period of the signal in t (inf otherwise).
    `value`: the supremum to round-off (of the torus for "torus"): the maximum the final ascent
    reached, attained and so also the lower end; for "triangle", where the supremum is not
    computed, the upper bound."""

    upper: float
    lower: float
    method: str
    period: float

    @property
    def value(self) -> float:
        return self.upper if self.method == "triangle" else self.lower

    @property
    def slack(self) -> float:
        return self.upper - self.lower


def sinusoid_terms(offset, amplitude, frequency, phase) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(o, c, s, ν): w(t) = o + Σ_d c_d cos(ν_d t) + s_d sin(ν_d t) with distinct ν_d > 0.

    a sin(νt + φ) = a sin φ cos νt + a cos φ sin νt; ν = 0 terms are constants. Frequencies equal
    to 12 significant digits share one phase variable."""
    o = np.array(offset, float).copy()
    a, f, ph = (np.asarray(x, float) for x in (amplitude, frequency, phase))
    o += np.sum(np.where(f == 0, a * np.sin(ph), 0.0), axis=1)
    pos = f > 0
    nus = np.unique(np.round(f[pos], 12 - int(np.floor(np.log10(f[pos].max())))) if pos.any() else np.zeros(0))
    c = np.zeros((len(nus), len(o)))
    s = np.zeros((len(nus), len(o)))
    for k, j in zip(*np.nonzero(pos)):
        d = int(np.argmin(np.abs(nus - f[k, j])))
        c[d, k] += a[k, j] * np.sin(ph[k, j])
        s[d, k] += a[k, j] * np.cos(ph[k, j])
    keep = np.any(c != 0, axis=1) | np.any(s != 0, axis=1)
    return o, c[keep], s[keep], nus[keep]


def common_harmonics(nus: np.ndarray) -> np.ndarray | None:
    """Integers k with ν = k ν₀ (gcd 1), or None when the ratios are not small fractions."""
    base = float(nus.min())
    fracs = []
    for nu in nus:
        r = float(nu) / base
        fr = Fraction(r).limit_denominator(MAX_DENOMINATOR)
        if abs(float(fr) - r) > RATIO_RTOL * r:
            return None
        fracs.append(fr)
    den = math.lcm(*(fr.denominator for fr in fracs))
    k = np.array([fr.numerator * (den // fr.denominator) for fr in fracs], dtype=np.int64)
    k //= math.gcd(*k.tolist())
    return None if k.max() > MAX_HARMONIC else k


def _evaluate(o, c, s, K, x):
    """F(x) (B, p) and its Jacobian dF/dx (B, p, P) for F(x) = o + Σ_d c_d cos(K_d·x) + s_d sin(K_d·x)."""
    th = x @ K.T                                                   # (B, D)
    cos, sin = np.cos(th), np.sin(th)
    F = o + cos @ c + sin @ s
    dtheta = cos[:, :, None] * s[None] - sin[:, :, None] * c[None]   # (B, D, p): dF/dθ_d
    return F, np.swapaxes(dtheta, 1, 2) @ K


def _polish(o, c, s, K, starts, gtol: float = 1e-5) -> float:
    """The largest ‖F‖ found by local ascent (BFGS, stopped at gradient norm `gtol`) from the given points:
    a value attained. With the default, a lower bound that lets the branch and bound discard boxes early; with
    a small `gtol` near a smooth maximum, the maximum to round-off (the error in ‖F‖ is of the order of
    gtol² over the curvature)."""
    from scipy.optimize import minimize

    def neg(x):
        F, J = _evaluate(o, c, s, K, x[None])
        nf = float(np.linalg.norm(F[0]))
        return -nf, -(F[0] @ J[0]) / max(nf, 1e-300)
    return max(-minimize(neg, x0, jac=True, method="BFGS", options={"gtol": gtol}).fun for x0 in starts)


def _branch_and_bound(o, c, s, K, width: float, grid: np.ndarray) -> tuple[float, float]:
    """max over x ∈ [0, width)^P of ‖o + Σ_d c_d cos(K_d·x) + s_d sin(K_d·x)‖, as (upper, lower)."""
    Pdim = K.shape[1]
    cs = np.stack([c, s], -1)                                      # (D, p, 2)
    A = np.sqrt(np.maximum(np.linalg.eigvalsh(np.einsum("dki,dkj->dij", cs, cs))[:, -1], 0.0))
    absK = np.abs(K).astype(float)
    axes = [(np.arange(g) + 0.5) * width / g for g in grid]
    centres = np.stack(np.meshgrid(*axes, indexing="ij"), -1).reshape(-1, Pdim)
    half = width / (2.0 * grid.astype(float))
    signs = np.array(list(itertools.product((-1.0, 1.0), repeat=Pdim)))
    tol = REL_TOL * (float(np.abs(o).sum() + A.sum()) or 1.0)
    lower, discarded, evaluated = 0.0, 0.0, 0
    first = True
    while True:
        vals, lin = np.empty(len(centres)), np.empty(len(centres))
        for a in range(0, len(centres), CHUNK):   # bounded memory: (chunk, p, 2^P) at a time
            F, dF = _evaluate(o, c, s, K, centres[a:a + CHUNK])
            vals[a:a + CHUNK] = np.linalg.norm(F, axis=1)
            lin[a:a + CHUNK] = np.linalg.norm(F[:, :, None] + dF @ (signs * half).T, axis=1).max(1)
        lower = max(lower, float(vals.max()))
        if first:   # a good lower bound first: local ascent from the best grid points
            lower = max(lower, _polish(o, c, s, K, centres[np.argsort(vals)[-8:]]))
            first = False
        ub = lin + 0.5 * float(np.sum(A * (absK @ half) ** 2))
        evaluated += len(centres)
        alive = ub > lower + tol
        if np.any(~alive):
            discarded = max(discarded, float(ub[~alive].max()))
        n_next = int(alive.sum()) * len(signs)
        if n_next == 0 or evaluated + n_next > MAX_BOXES:
            upper = max(discarded, float(ub.max()), lower)
            # the maximum is in a box left (or within tol of `lower`): ascend from the best of them to round-off
            best = centres[np.argsort(np.where(alive, vals, -np.inf))[-8:]]
            return upper, min(max(lower, _polish(o, c, s, K, best, gtol=1e-10)), upper)
        centres = centres[alive]
        half = half / 2.0
        centres = (centres[:, None, :] + signs[None] * half).reshape(-1, Pdim)


def sup_norm(o, c, s, nus) -> SupBound:
    """Certified sup over t ≥ 0 of ‖o + Σ_d c_d cos ν_d t + s_d sin ν_d t‖₂ (see the module docstring)."""
    if len(nus) == 0:
        v = float(np.linalg.norm(o))
        return SupBound(v, v, "constant", float("inf"))
    k = common_harmonics(nus)
    if k is not None:
        nu0 = float(nus.min()) / float(k[np.argmin(nus)])
        grid = np.array([max(64, 16 * int(k.max()))])
        up, lo = _branch_and_bound(o, c, s, k[:, None].astype(float), 2 * np.pi, grid)
        return SupBound(up, lo, "period", 2 * np.pi / nu0)
    D = len(nus)
    if D > MAX_TORUS_DIM:
        # ‖w(t)‖ ≤ ‖(|o_k| + Σ_d |(c_dk, s_dk)|)_k‖ (each sinusoid at most its amplitude); attained value by sampling
        upper = float(np.linalg.norm(np.abs(o) + np.hypot(c, s).sum(axis=0)))
        t = np.linspace(0.0, 200 * 2 * np.pi / float(nus.min()), 200_001)
        lower = 0.0
        for a in range(0, len(t), CHUNK):
            th = np.outer(t[a:a + CHUNK], nus)
            lower = max(lower, float(np.linalg.norm(o + np.cos(th) @ c + np.sin(th) @ s, axis=1).max()))
        return SupBound(upper, lower, "triangle", float("inf"))
    grid = np.full(D, {1: 32, 2: 16, 3: 10}.get(D, 6))
    up, lo = _branch_and_bound(o, c, s, np.eye(D), 2 * np.pi, grid)
    return SupBound(up, lo, "torus", float("inf"))


def input_sup_bounds(offset, amplitude, frequency, phase) -> tuple[SupBound, SupBound]:
    """(bound on sup‖w‖₂, bound on sup‖ẇ‖₂) over t ≥ 0 for w_k = o_k + Σ_j a_kj sin(ν_kj t + φ_kj)."""
    o, c, s, nus = sinusoid_terms(offset, amplitude, frequency, phase)
    # ẇ = Σ_d ν_d (s_d cos ν_d t − c_d sin ν_d t)
    return sup_norm(o, c, s, nus), sup_norm(np.zeros_like(o), nus[:, None] * s, -nus[:, None] * c, nus)
