"""Random Riccati maps switched by a Markov chain (Kar & Moura's Theorem-8 process).

    p̃(0) ~ Uniform(V),   p̃(t+1) ~ Ā[p̃(t), :],   P̃(t+1) = f_{p̃(t)}(P̃(t))          (20), (30), (31)

With C.1 (Ā irreducible, aperiodic), Q ≻ 0 and D.1 the law of P̃(t) converges to the invariant
measure μ^Ā from any initial law (Theorem 8). The samplers below are

* forward replicas (S1): independent chains, keep P̃(T); the chain is drawn from Ā
  (`sample_chain`) or, when Ā is not known exactly, by an independent copy of the gossip
  protocol (S3, `sample_protocol_chain`): p̃(t+1) = ->(p̃(t)) under a fresh matching, which is
  exactly a Ā-chain whatever the protocol;
* the pull-back (S2): f_{ω₋₁} ∘ … ∘ f_{ω₋T}(X) along one backward path, which converges
  pathwise to the random equilibrium u(ω) (Theorem 26(b));
* a forward coupling diagnostic: the same switching from 0 and from c I, whose relative gap
  tells how long the burn-in must be.

Chains are batched on a leading axis. The maps are the Joseph-form Riccati of
:mod:`dse.estimators.gikf_maps`, or with ``sqrt=True`` its square-root (array) form, which carries a
factor S of X = S Sᵀ and stays accurate and finite when ‖X‖ is huge (a start at c·I with c ≫ 1, or a
direction no sensor of the path sees); features are then computed from the factor.
"""
from __future__ import annotations

import itertools
from typing import Sequence

import numpy as np

from .gikf_maps import (GossipSystem, covariance_features, error_norm, factor_features, factor_psd, propagate_error,
                        riccati_roundoff, riccati_sqrt_step, riccati_step, use_compiled)

__all__ = ["LazyChain", "sample_chain", "sample_protocol_chain", "switched_riccati", "pullback", "coupling_gap", "exact_small_t_law",
           "trace_law_atoms", "chain_paths"]


class LazyChain:
    """(size, steps) states of a chain, generated column by column as they are read in increasing t
    (`path[:, t]`, `path.shape`): a long horizon costs one column of memory, not size × steps, and the
    generator sees exactly the draws of the eager sampler (read every column before drawing from the same
    generator again; `array()` materialises the whole path)."""

    def __init__(self, start: np.ndarray, steps: int, advance, rng: np.random.Generator, *, last_draw: bool):
        self._p, self._t, self._steps = start, 0, steps
        self._advance, self._rng, self._last_draw = advance, rng, last_draw

    @property
    def shape(self) -> tuple[int, int]:
        return (len(self._p), self._steps)

    def __getitem__(self, index):
        rows, t = index
        if rows != slice(None) or not isinstance(t, (int, np.integer)):
            raise IndexError("a LazyChain is read one column at a time: path[:, t]")
        t = int(t)
        if t < 0:
            t += self._steps
        if t == self._t - 1:
            return self._prev
        if t != self._t:
            raise IndexError(f"a LazyChain is read in increasing t (column {self._t} or {self._t - 1} next, asked {t})")
        col = self._p
        if t + 1 < self._steps or self._last_draw:
            self._p = self._advance(col, self._rng)
        self._prev, self._t = col, t + 1
        return col

    def array(self) -> np.ndarray:
        """The whole (size, steps) path (of a chain not read yet)."""
        return np.stack([self[:, t] for t in range(self._steps)], axis=1)


def sample_chain(Abar: np.ndarray, size: int, steps: int, rng: np.random.Generator,
                 start: np.ndarray | int | None = None, *, lazy: bool = False):
    """(size, steps) states of the Ā-chain; start uniform (stationary) unless given. `lazy`: a LazyChain."""
    n = len(Abar)
    cum = np.cumsum(Abar, axis=1)
    cum[:, -1] = 1.0
    p = rng.integers(0, n, size) if start is None else np.broadcast_to(np.asarray(start), (size,)).copy()

    def advance(p, rng):
        u = rng.random(size)
        if use_compiled(size, item_s=2e-9 * n):            # numpy: ~2 ns per state and row
            from . import gikf_compiled

            out = np.empty(size, np.int64)
            gikf_compiled.chain_step(cum, p, u, out)
            return out
        return (cum[p] <= u[:, None]).sum(axis=1)

    chain = LazyChain(p, steps, advance, rng, last_draw=True)
    return chain if lazy else chain.array()


def sample_protocol_chain(protocol, size: int, steps: int, rng: np.random.Generator,
                          start: np.ndarray | int | None = None, *, lazy: bool = False):
    """(size, steps) states of a Ā-chain driven by the protocol itself (sampler S3):
    p̃(t+1) = partner of p̃(t) in a fresh matching A' ~ D. P(p̃(t+1) = l | p̃(t) = k) = E[A'_kl] = Ā_kl
    exactly, so no estimate of Ā enters (an estimated Ā would bias μ). Start uniform unless given."""
    n = protocol.n
    p = rng.integers(0, n, size) if start is None else np.broadcast_to(np.asarray(start), (size,)).copy()
    rows = np.arange(size)
    chain = LazyChain(p, steps, lambda p, rng: protocol.sample(size, rng)[rows, p], rng, last_draw=False)
    return chain if lazy else chain.array()


def apply_maps(sys: GossipSystem, X: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """f_{nodes[b]}(X[b]) for every b."""
    return riccati_step(X, sys.C[nodes], sys.R[nodes], sys.F, sys.Q)


class _Iterate:
    """A batch of B matrices under switched Riccati maps, in Joseph form (the matrices) or in
    square-root form (factors S with X = S Sᵀ)."""

    def __init__(self, sys: GossipSystem, X0: np.ndarray, B: int, sqrt: bool, track_error: bool = False):
        self.sys, self.sqrt, self.track = sys, sqrt, track_error and not sqrt
        X = np.broadcast_to(np.asarray(X0, float), (B,) + sys.Q.shape)
        self.E = np.zeros((B,) + sys.Q.shape)  # first-order round-off bound of the Joseph-form iterate (riccati_roundoff)
        if sqrt:
            self.R_half, self.Q_half = sys.R_chol, np.linalg.cholesky(sys.Q)
            self.state = factor_psd(X)
        else:
            self.state = X.copy()

    def step(self, nodes: np.ndarray) -> None:
        s = self.sys
        if self.sqrt:
            self.state = riccati_sqrt_step(self.state, s.C[nodes], self.R_half[nodes], s.F, self.Q_half)
        elif self.track:
            X = self.state
            self.state, K = riccati_step(X, s.C[nodes], s.R[nodes], s.F, s.Q, return_gain=True)
            delta, G = riccati_roundoff(X, K, s.C[nodes], s.R[nodes], s.F, s.Q)
            self.E = propagate_error(self.E, G, delta)
        else:
            self.state = apply_maps(s, self.state, nodes)

    @property
    def err(self) -> np.ndarray:
        """Bound of the spectral norm of the accumulated round-off, per batch entry."""
        return error_norm(self.E)

    def matrix(self) -> np.ndarray:
        S = self.state
        return S @ np.swapaxes(S, -1, -2) if self.sqrt else S

    def features(self) -> np.ndarray:
        return factor_features(self.state) if self.sqrt else covariance_features(self.state)


def switched_riccati(sys: GossipSystem, path: np.ndarray, X0: np.ndarray, record_times: Sequence[int] = (),
                     *, keep_final: bool = False, sqrt: bool = False, track_error: bool = False) -> dict[str, np.ndarray]:
    """Run P̃(t+1) = f_{path[:, t]}(P̃(t)) for t < T = path.shape[1] from X0 ((M, M) or (B, M, M)).

    Returns features (covariance_features) at each record time t ≤ T, stacked (len(times), F, B),
    the last switch path[:, t-1] at each record time, P̃(T) with its round-off bound (`final_err`,
    Joseph form) if keep_final, and the round-off bound at each record time (`err`) if track_error.
    """
    B, T = path.shape
    track = keep_final or track_error
    it = _Iterate(sys, X0, B, sqrt, track_error=track)
    times = sorted(set(int(t) for t in record_times))
    feats, last, errs = [], [], []
    if 0 in times:
        feats.append(it.features())
        last.append(np.full(B, -1))
        errs.append(it.err)
    for t in range(T):
        it.step(path[:, t])
        if t + 1 in times:
            feats.append(it.features())
            last.append(path[:, t])
            errs.append(it.err)
    out = {"times": np.array(times, dtype=np.int64), "features": np.array(feats), "last": np.array(last)}
    if track_error:
        out["err"] = np.array(errs)
    if keep_final:
        out["final"] = it.matrix()
        out["final_err"] = it.err
    return out


def pullback(sys: GossipSystem, backward: np.ndarray, X: np.ndarray, horizons: Sequence[int], *,
             sqrt: bool = False, with_error: bool = False):
    """f_{ω₋₁} ∘ … ∘ f_{ω₋T}(X) for each T in horizons; backward[:, k] = ω₋(k+1). Returns (len(horizons), B, M, M),
    and with `with_error` (Joseph form) also the round-off bounds (len(horizons), B)."""
    B = backward.shape[0]
    out, errs = [], []
    for T in horizons:
        it = _Iterate(sys, X, B, sqrt, track_error=with_error)
        for k in range(T - 1, -1, -1):
            it.step(backward[:, k])
        out.append(it.matrix())
        errs.append(it.err)
    return (np.array(out), np.array(errs)) if with_error else np.array(out)


def coupling_gap(sys: GossipSystem, path: np.ndarray, c: float, record_times: Sequence[int], *,
                 sqrt: bool = True) -> np.ndarray:
    """‖φ(t, ω, cI) − φ(t, ω, 0)‖ / ‖φ(t, ω, 0)‖ (spectral norms), (len(times), B), same switching.
    Square-root form by default: the copy started at c·I may be huge for a while."""
    B, T = path.shape
    M = sys.M
    lo = _Iterate(sys, np.zeros((M, M)), B, sqrt)
    hi = _Iterate(sys, c * np.eye(M), B, sqrt)
    times = set(int(t) for t in record_times)
    gaps = []
    for t in range(T):
        lo.step(path[:, t])
        hi.step(path[:, t])
        if t + 1 in times:
            L, H = lo.matrix(), hi.matrix()
            gaps.append(np.linalg.norm(H - L, 2, axis=(1, 2)) / np.linalg.norm(L, 2, axis=(1, 2)))
    return np.array(gaps)


def exact_small_t_law(sys: GossipSystem, Abar: np.ndarray, t: int, X0: np.ndarray, *, last: int | None = None,
                      decimals: int = 9) -> tuple[np.ndarray, np.ndarray]:
    """Atoms (log trace, rounded) and probabilities of P̃(t), enumerating chain paths with
    probabilities (1/N) Π Ā (optionally conditioned on p̃(t-1) = last)."""
    n = len(Abar)
    atoms: dict[float, float] = {}
    for path in itertools.product(range(n), repeat=t):
        p = 1.0 / n
        for a, b in zip(path[:-1], path[1:]):
            p *= Abar[a, b]
        if p == 0.0 or (last is not None and path[-1] != last):
            continue
        X = np.asarray(X0, float)
        for node in path:
            X = riccati_step(X, sys.C[node], sys.R[node], sys.F, sys.Q)
        key = round(float(np.log(np.trace(X))), decimals)
        atoms[key] = atoms.get(key, 0.0) + p
    keys = np.array(sorted(atoms))
    probs = np.array([atoms[k] for k in keys])
    return keys, probs / probs.sum()


def trace_law_atoms(sys_: GossipSystem, Abar: np.ndarray, t: int, X0: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact law of log tr P̃(t) from X0, enumerating every Ā-path at once (probability (1/N)ΠĀ): the atoms
    (ascending; values closer than tol merged) and their probabilities."""
    N = len(Abar)
    paths = np.array(list(itertools.product(range(N), repeat=t)))
    prob = np.full(len(paths), 1.0 / N)
    for k in range(1, t):
        prob *= Abar[paths[:, k - 1], paths[:, k]]
    paths, prob = paths[prob > 0], prob[prob > 0]
    X = np.broadcast_to(X0, (len(paths),) + X0.shape).copy()
    for k in range(t):
        X = apply_maps(sys_, X, paths[:, k])
    v = np.log(np.trace(X, axis1=-2, axis2=-1))
    order = np.argsort(v)
    v, prob = v[order], prob[order]
    group = np.cumsum(np.concatenate([[True], np.diff(v) > tol])) - 1
    return v[np.flatnonzero(np.concatenate([[True], np.diff(v) > tol]))], np.bincount(group, weights=prob)


def chain_paths(Abar: np.ndarray, length: int) -> tuple[np.ndarray, np.ndarray]:
    """All Ā-paths (i_1, ..., i_L) with positive kernel weight Π_r Ā[i_r, i_(r+1)] (any i_1), and the weights."""
    N = len(Abar)
    paths = np.arange(N)[:, None]
    w = np.ones(N)
    for _ in range(length - 1):
        parent, child = np.nonzero(Abar[paths[:, -1]] > 0)
        w = w[parent] * Abar[paths[parent, -1], child]
        paths = np.hstack([paths[parent], child[:, None]])
    return paths, w
