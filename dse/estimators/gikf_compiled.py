"""Compiled (numba) kernels of the GIKF hot loops, each the same scalar operations in the same order as its
numpy reference in `gikf_maps` / `gossip_protocols`, so the results are the same IEEE doubles bit for bit.

Why compiled: the numpy references work entry by entry, each entry a vector over the batch, so a slot of a
2 × 2 Riccati map is ~100 numpy calls, each a pass over memory (Python overhead at small batches, memory
traffic at large ones). Here one loop over the batch keeps every matrix in registers. No fastmath (numba's
default): LLVM neither reassociates nor contracts a*b + c into a fused multiply-add, and sums keep the order
of the reference (Python `sum` starts from 0, `_sum` from the first term; both are reproduced as written).

Imported only by the functions that call these kernels (numba costs ~0.2 s to import), so that `dse list`,
`dse check` and the other families never load it. `cache=True` stores the machine code beside this file in
__pycache__ (NUMBA_CACHE_DIR moves it): the first run compiles (a few seconds), later processes, forked
workers and test workers load it.
"""
from __future__ import annotations

import numba
import numpy as np


def dims(n: int) -> tuple:
    """A tuple of n zeros, passed to the matrix kernels for their size: numba compiles one version per tuple
    type, in which the size is a constant, so LLVM unrolls the loops over the entries and keeps the small
    matrices in registers (3-5x faster than the same loops over a run-time size)."""
    return (0,) * n


@numba.njit(cache=True, error_model="numpy")
def riccati_scalar_obs(X, c, r, F, Q, out, K, dims):
    """f(X) of eq (11) in Joseph form for one observation row (m = 1), `gikf_maps._riccati_scalar_obs`:
    X (n, M, M), c (n, M) the rows C, r (n,) the variances R; writes out (n, M, M) and the gains K (n, M).
    dims: a tuple of M entries (see `dims`)."""
    n, M = X.shape[0], len(dims)
    u = np.empty(M)
    A = np.empty((M, M))
    AX = np.empty((M, M))
    Pf = np.empty((M, M))
    G = np.empty((M, M))
    for b in range(n):
        rb = r[b]
        for i in range(M):
            acc = 0.0
            for j in range(M):
                acc += X[b, i, j] * c[b, j]
            u[i] = acc
        s = 0.0
        for i in range(M):
            s += c[b, i] * u[i]
        s = s + rb
        for i in range(M):
            K[b, i] = u[i] / s
        for i in range(M):
            for j in range(M):
                A[i, j] = (1.0 if i == j else 0.0) - K[b, i] * c[b, j]
        for i in range(M):
            for j in range(M):
                acc = 0.0
                for l in range(M):
                    acc += A[i, l] * X[b, l, j]
                AX[i, j] = acc
        for i in range(M):
            for j in range(i + 1):
                acc = 0.0
                for l in range(M):
                    acc += AX[i, l] * A[j, l]
                Pf[i, j] = Pf[j, i] = acc + rb * K[b, i] * K[b, j]
        for i in range(M):
            for j in range(M):
                acc = 0.0
                for l in range(M):
                    if F[i, l] != 0:
                        acc += F[i, l] * Pf[l, j]
                G[i, j] = acc
        for i in range(M):
            for j in range(i + 1):
                acc = 0.0
                for l in range(M):
                    if F[j, l] != 0:
                        acc += G[i, l] * F[j, l]
                out[b, i, j] = out[b, j, i] = acc + Q[i, j]


@numba.njit(cache=True, error_model="numpy")
def roundoff_entries(X, K, C, R, F, rows, gamma, s_min, fF, fQ, delta, G, dims, obs_dims):
    """`gikf_maps._roundoff_entries`, the first-order round-off bound of one Joseph-form step (delta, n) and its
    closed loop G = F (I − K C) (n, M, M), for X (n, M, M), K (n, M, m), C (n, m, M), R (n, m, m), s_min (n,);
    rows[i]: row i of F is not zero (G's row i is zero otherwise, as G is pre-filled). dims, obs_dims: tuples of
    M and m entries (see `dims`)."""
    n, M, m = X.shape[0], len(dims), len(obs_dims)
    A = np.empty((M, M))
    axc = np.empty((M, m))
    for b in range(n):
        for i in range(M):
            for j in range(M):
                acc = K[b, i, 0] * C[b, 0, j]
                for l in range(1, m):
                    acc = acc + K[b, i, l] * C[b, l, j]
                A[i, j] = (1.0 if i == j else 0.0) - acc
        k2 = 0.0
        first = True
        for i in range(M):
            for a in range(m):
                v = K[b, i, a] * K[b, i, a]
                k2 = v if first else k2 + v
                first = False
        a2 = A[0, 0] * A[0, 0]
        for i in range(M):
            for j in range(M):
                if i + j > 0:
                    a2 = a2 + A[i, j] * A[i, j]
        x2 = X[b, 0, 0] * X[b, 0, 0]
        for i in range(M):
            for j in range(M):
                if i + j > 0:
                    x2 = x2 + X[b, i, j] * X[b, i, j]
        r2 = R[b, 0, 0] * R[b, 0, 0]
        for a in range(m):
            for c_ in range(m):
                if a + c_ > 0:
                    r2 = r2 + R[b, a, c_] * R[b, a, c_]
        scale = fF * (a2 * np.sqrt(x2) + k2 * np.sqrt(r2)) + fQ
        for i in range(M):
            for a in range(m):
                acc = abs(X[b, i, 0]) * abs(C[b, a, 0])
                for j in range(1, M):
                    acc = acc + abs(X[b, i, j]) * abs(C[b, a, j])
                axc[i, a] = acc
        axc2 = axc[0, 0] * axc[0, 0]
        for i in range(M):
            for a in range(m):
                if i + a > 0:
                    axc2 = axc2 + axc[i, a] * axc[i, a]
        e22 = 0.0
        for a in range(m):
            for c_ in range(m):
                acc = abs(C[b, a, 0]) * axc[0, c_]
                for i in range(1, M):
                    acc = acc + abs(C[b, a, i]) * axc[i, c_]
                v = acc + abs(R[b, a, c_])
                e22 = v * v if a + c_ == 0 else e22 + v * v
        s_max = 0.0
        for a in range(m):
            acc = 0.0
            for i in range(M):
                xc = X[b, i, 0] * C[b, a, 0]
                for j in range(1, M):
                    xc = xc + X[b, i, j] * C[b, a, j]
                acc = C[b, a, i] * xc if i == 0 else acc + C[b, a, i] * xc
            v = acc + R[b, a, a]
            s_max = v if a == 0 else s_max + v
        E1 = gamma * np.sqrt(axc2)
        E2 = gamma * np.sqrt(e22)
        k = np.sqrt(k2)
        sm = s_min[b]
        dK = (E1 + k * E2) / np.sqrt(sm) + k * gamma * (s_max / sm) * np.sqrt(s_max)
        delta[b] = gamma * scale + fF * dK * dK
        for i in range(M):
            if not rows[i]:
                continue
            for j in range(M):
                acc = 0.0
                first = True
                for l in range(M):
                    if F[i, l] != 0:
                        v = F[i, l] * A[l, j]
                        acc = v if first else acc + v
                        first = False
                G[b, i, j] = acc


@numba.njit(cache=True, error_model="numpy")
def propagate_error(E, G, delta, out, dims):
    """G E Gᵀ + delta·I entry by entry, `gikf_maps.propagate_error` for M ≤ ENTRYWISE_MAX_M: E, G (n, M, M),
    delta (n,); lower triangle computed, mirrored. dims: a tuple of M entries (see `dims`)."""
    n, M = E.shape[0], len(dims)
    ge = np.empty((M, M))
    for b in range(n):
        for i in range(M):
            for l in range(M):
                acc = G[b, i, 0] * E[b, 0, l]
                for j in range(1, M):
                    acc = acc + G[b, i, j] * E[b, j, l]
                ge[i, l] = acc
        for i in range(M):
            for j in range(i + 1):
                v = ge[i, 0] * G[b, j, 0]
                for l in range(1, M):
                    v = v + ge[i, l] * G[b, j, l]
                out[b, i, j] = out[b, j, i] = v + delta[b] if i == j else v


@numba.njit(cache=True, error_model="numpy")
def greedy_chosen_words(order, masks, chosen):
    """The greedy scan of `GreedyMatchingGossip.greedy_chosen` for at most 64 nodes: for each row of edge orders
    (B, E) (numpy's argsort of the priorities: its SIMD sort is ~8x faster than numba's, and the order is then
    numpy's even for ties), the k-th edge is taken iff both its endpoint bits (masks[e]) are still set in the
    row's word of free nodes, and taking it clears them (branch-free: ~1 ns per edge, against ~4 ns with a
    branch that the random order mispredicts). Writes the (B, E) bool `chosen`."""
    B, E = order.shape
    for b in range(B):
        free = np.uint64(0xFFFFFFFFFFFFFFFF)
        for i in range(E):
            e = order[b, i]
            m = masks[e]
            taken = (free & m) == m
            chosen[b, e] = taken
            free ^= m * np.uint64(taken)


@numba.njit(cache=True, error_model="numpy")
def greedy_chosen_flags(order, u, v, n_nodes, chosen):
    """`greedy_chosen_words` for any number of nodes, with one free flag per node: the edge order[b, i] is taken
    when both its endpoints u[e], v[e] are still free. Writes `chosen` (pre-filled False)."""
    B, E = order.shape
    free = np.empty(n_nodes, np.bool_)
    for b in range(B):
        free[:] = True
        for i in range(E):
            e = order[b, i]
            a, c = u[e], v[e]
            if free[a] and free[c]:
                chosen[b, e] = True
                free[a] = False
                free[c] = False


@numba.njit(cache=True, error_model="numpy")
def matching_partners(chosen, works, u, v, out):
    """Partner arrays from the chosen edges, `GreedyMatchingGossip.sample`: out (B, N) pre-filled with each node's
    own index, and for the k-th chosen edge in row-major order (np.nonzero's) whose link works (works[k]), its
    endpoints swap."""
    B, E = chosen.shape
    k = 0
    for b in range(B):
        for e in range(E):
            if chosen[b, e]:
                if works[k]:
                    out[b, u[e]] = v[e]
                    out[b, v[e]] = u[e]
                k += 1


@numba.njit(cache=True, error_model="numpy")
def chain_step(cum, p, x, out):
    """One step of the Ā-chain by inversion, `switched_riccati.sample_chain`: out[b] = #{j : cum[p[b], j] <= x[b]}
    (cum: the rows of Ā cumulated, last entry 1)."""
    n = cum.shape[1]
    for b in range(p.shape[0]):
        row = cum[p[b]]
        count = 0
        for j in range(n):
            if row[j] <= x[b]:
                count += 1
        out[b] = count


@numba.njit(cache=True, error_model="numpy")
def _np_min(x, y):
    """np.minimum of two numbers that are not NaN: the second when they compare equal (-0.0, 0.0)."""
    return x if x < y else y


@numba.njit(cache=True, error_model="numpy")
def _np_max(x, y):
    """np.maximum of two numbers that are not NaN: the second when they compare equal."""
    return x if x > y else y


@numba.njit(cache=True, error_model="numpy")
def eigvalsh2(X, out, far, lo, hi):
    """Ascending eigenvalues of symmetric 2 × 2 matrices X (n, 2, 2) (lower triangle), `gikf_maps.eigvalsh`:
    LAPACK's split test and dlae2 formulas, evaluated per matrix instead of as ~30 numpy passes over the batch.
    Writes out (n, 2), and far[b] = True where LAPACK would rescale the matrix first (largest entry beyond
    [lo, hi] or not finite; the caller hands those to LAPACK); no NaN reaches a comparison of the others."""
    eps = 0.5 * np.finfo(np.float64).eps
    for i in range(X.shape[0]):
        a, b, c = X[i, 0, 0], X[i, 1, 0], X[i, 1, 1]
        size = max(abs(a), abs(X[i, 0, 1]), abs(b), abs(c))
        if np.isnan(a) or np.isnan(b) or np.isnan(c) or np.isnan(X[i, 0, 1]) or not (
                size <= hi and (size >= lo or size == 0)):
            far[i] = True
            out[i, 0] = out[i, 1] = np.nan
            continue
        if abs(b) <= np.sqrt(abs(a)) * np.sqrt(abs(c)) * eps or b * b <= (eps * eps * abs(a)) * abs(c):
            out[i, 0], out[i, 1] = _np_min(a, c), _np_max(a, c)
            continue
        sm, adf, ab = a + c, abs(a - c), abs(b + b)
        if abs(a) > abs(c):
            acmx, acmn = a, c
        else:
            acmx, acmn = c, a
        if adf > ab:
            q = ab / adf
            rt = adf * np.sqrt(1.0 + q * q)
        elif adf < ab:
            q = adf / ab
            rt = ab * np.sqrt(1.0 + q * q)
        else:
            rt = ab * np.sqrt(2.0)
        rt1 = 0.5 * (sm - rt) if sm < 0 else 0.5 * (sm + rt)
        rt2 = -0.5 * rt if sm == 0 else (acmx / rt1) * acmn - (b / rt1) * b
        out[i, 0], out[i, 1] = _np_min(rt1, rt2), _np_max(rt1, rt2)


#: the state sizes M whose m = 1 Riccati step `warm_cache` compiles (kar-moura's maps have M ≤ 6); the entrywise
#: kernels are compiled for M ≤ gikf_maps.ENTRYWISE_MAX_M, their only sizes
WARM_RICCATI_M = range(1, 7)


def warm_cache() -> None:
    """Compile every kernel for the array types and sizes the estimators call it with (float64, int64 and bool
    arrays, C-contiguous and writable), on empty batches, and store the machine code in numba's cache: done once
    by the set-up (the Makefile's .venv step, like compileall), so that neither the first runs nor each test
    process that first meets a kernel compiles it (a few seconds of CPU each). A size not listed here compiles
    when it is first called, as before."""
    from .gikf_maps import ENTRYWISE_MAX_M

    i, b = np.int64, np.bool_
    for M in WARM_RICCATI_M:
        riccati_scalar_obs(np.empty((0, M, M)), np.empty((0, M)), np.empty(0), np.empty((M, M)), np.empty((M, M)),
                           np.empty((0, M, M)), np.empty((0, M)), dims(M))
    for M in range(1, ENTRYWISE_MAX_M + 1):
        propagate_error(np.empty((0, M, M)), np.empty((0, M, M)), np.empty(0), np.empty((0, M, M)), dims(M))
        for m in range(1, M + 1):
            roundoff_entries(np.empty((0, M, M)), np.empty((0, M, m)), np.empty((0, m, M)), np.empty((0, m, m)),
                             np.empty((M, M)), np.empty(M, b), 0.0, np.empty(0), 0.0, 0.0, np.empty(0),
                             np.empty((0, M, M)), dims(M), dims(m))
    greedy_chosen_words(np.empty((0, 1), i), np.empty(1, np.uint64), np.empty((0, 1), b))
    greedy_chosen_flags(np.empty((0, 1), i), np.empty(1, i), np.empty(1, i), 2, np.empty((0, 1), b))
    matching_partners(np.empty((0, 1), b), np.empty(0, b), np.empty(1, i), np.empty(1, i), np.empty((0, 2), i))
    chain_step(np.empty((1, 1)), np.empty(0, i), np.empty(0), np.empty(0, i))
    eigvalsh2(np.empty((0, 2, 2)), np.empty((0, 2)), np.empty(0, b), 1e-120, 1e145)
