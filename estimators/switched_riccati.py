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

Chains are batched on a leading axis; all maps are the Joseph-form Riccati of
:mod:`estimators.gossip_kalman`.
"""
from __future__ import annotations

import itertools
from typing import Sequence

import numpy as np

from .gossip_kalman import GossipSystem, covariance_features, riccati_step

__all__ = ["sample_chain", "sample_protocol_chain", "switched_riccati", "pullback", "coupling_gap", "exact_small_t_law"]


def sample_chain(Abar: np.ndarray, size: int, steps: int, rng: np.random.Generator,
                 start: np.ndarray | int | None = None) -> np.ndarray:
    """(size, steps) states of the Ā-chain; start uniform (stationary) unless given."""
    n = len(Abar)
    cum = np.cumsum(Abar, axis=1)
    cum[:, -1] = 1.0
    path = np.empty((size, steps), dtype=np.int64)
    p = rng.integers(0, n, size) if start is None else np.broadcast_to(np.asarray(start), (size,)).copy()
    for t in range(steps):
        path[:, t] = p
        u = rng.random(size)
        p = (cum[p] <= u[:, None]).sum(axis=1)
    return path


def sample_protocol_chain(protocol, size: int, steps: int, rng: np.random.Generator,
                          start: np.ndarray | int | None = None) -> np.ndarray:
    """(size, steps) states of a Ā-chain driven by the protocol itself (spec §5, sampler S3):
    p̃(t+1) = partner of p̃(t) in a fresh matching A' ~ D. P(p̃(t+1) = l | p̃(t) = k) = E[A'_kl] = Ā_kl
    exactly, so no estimate of Ā enters (spec §11 P9). Start uniform unless given."""
    n = protocol.n
    path = np.empty((size, steps), dtype=np.int64)
    p = rng.integers(0, n, size) if start is None else np.broadcast_to(np.asarray(start), (size,)).copy()
    rows = np.arange(size)
    for t in range(steps):
        path[:, t] = p
        if t + 1 < steps:
            p = protocol.sample(size, rng)[rows, p]
    return path


def apply_maps(sys: GossipSystem, X: np.ndarray, nodes: np.ndarray) -> np.ndarray:
    """f_{nodes[b]}(X[b]) for every b."""
    return riccati_step(X, sys.C[nodes], sys.R[nodes], sys.F, sys.Q)


def switched_riccati(sys: GossipSystem, path: np.ndarray, X0: np.ndarray, record_times: Sequence[int] = (),
                     *, keep_final: bool = False) -> dict[str, np.ndarray]:
    """Run P̃(t+1) = f_{path[:, t]}(P̃(t)) for t < T = path.shape[1] from X0 ((M, M) or (B, M, M)).

    Returns features (covariance_features) at each record time t ≤ T, stacked (len(times), F, B),
    the last switch path[:, t-1] at each record time, and P̃(T) if keep_final.
    """
    B, T = path.shape
    X = np.broadcast_to(np.asarray(X0, float), (B,) + sys.Q.shape).copy()
    times = sorted(set(int(t) for t in record_times))
    feats, last = [], []
    if 0 in times:
        feats.append(covariance_features(X))
        last.append(np.full(B, -1))
    for t in range(T):
        X = apply_maps(sys, X, path[:, t])
        if t + 1 in times:
            feats.append(covariance_features(X))
            last.append(path[:, t])
    out = {"times": np.array(times, dtype=np.int64), "features": np.array(feats), "last": np.array(last)}
    if keep_final:
        out["final"] = X
    return out


def pullback(sys: GossipSystem, backward: np.ndarray, X: np.ndarray, horizons: Sequence[int]) -> np.ndarray:
    """f_{ω₋₁} ∘ … ∘ f_{ω₋T}(X) for each T in horizons; backward[:, k] = ω₋(k+1). Returns (len(horizons), B, M, M)."""
    B = backward.shape[0]
    out = []
    for T in horizons:
        Y = np.broadcast_to(np.asarray(X, float), (B,) + sys.Q.shape).copy()
        for k in range(T - 1, -1, -1):
            Y = apply_maps(sys, Y, backward[:, k])
        out.append(Y)
    return np.array(out)


def coupling_gap(sys: GossipSystem, path: np.ndarray, c: float, record_times: Sequence[int]) -> np.ndarray:
    """‖φ(t, ω, cI) − φ(t, ω, 0)‖ / ‖φ(t, ω, 0)‖ (spectral norms), (len(times), B), same switching."""
    B, T = path.shape
    M = sys.M
    lo = np.zeros((B, M, M))
    hi = np.broadcast_to(c * np.eye(M), (B, M, M)).copy()
    times = set(int(t) for t in record_times)
    gaps = []
    for t in range(T):
        lo = apply_maps(sys, lo, path[:, t])
        hi = apply_maps(sys, hi, path[:, t])
        if t + 1 in times:
            gaps.append(np.linalg.norm(hi - lo, 2, axis=(1, 2)) / np.linalg.norm(lo, 2, axis=(1, 2)))
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
