"""ρ of (17) in the hybrid-observer paper: the largest 2-norm of a product of N = (m-1)² + 1
orthogonal projections P_i in which every P_i occurs, by an exhaustive depth-first search that
uses the structure of the problem (`rho_exact`).

The reductions, all exact:

- P_i² = P_i: a word with a letter twice in a row has the product of the shorter word, so the
  products are those of words with no letter repeated in a row, of length <= N, containing every
  letter (a shorter one is padded to N by repeating a letter).
- Agents with the same projection are one letter; with k distinct projections a word over the
  classes of length <= N - (m - k) expands to a word over the agents of length <= N (each class's
  first occurrence is written as its agents in a row, which leaves the product unchanged).
- ||W P_c|| <= ||W|| and ||P_c W|| <= ||W|| (every ||P_c|| <= 1): a complete word is at least
  as large as any word it is a prefix or a suffix of, so the maximum is attained on a word whose
  first letter a occurs once and which becomes complete only at its last letter b (which then
  occurs once too). The search starts from each first letter a, never uses a again, evaluates
  ||U_a' M U_b|| (U_i an orthonormal basis of the range of P_i) when a prefix a M misses one letter
  b, and does not extend a complete word. A word and its reverse have the same norm (every P_i is
  symmetric), so only words whose first letter is below their last are formed.
- A prefix X = U_a' M bounds every word that extends it: ||X R U_b|| <= ||X||, and, with Π the
  orthogonal projection on the space F that every letter used so far leaves fixed,
  ||X R U_b|| <= ||X Π|| B(T) + ||X - X Π||, where B(T) bounds ||Π R U_b|| over the
  continuations that contain the missing letters (`tail_bounds`). A prefix whose bound is at or
  below the best complete word found (plus the round-off allowance τ) is dropped. The second
  bound is what ends the search when several letters share an unobserved mode (F ≠ 0): their
  products keep norm 1 on F however long, and only the missing letters can reduce it.

Prefixes are expanded in batches, deepest and largest bound first, so a good complete word is found
early. Past its budget of prefixes (or the frontier's memory) the search stops with a proven
bracket: `rho` is then the best complete word found, `upper` the largest bound of a prefix still
open.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class RhoResult:
    """ρ of (17). `rho`: the largest norm found (ρ itself when `exact`); `upper`: a proven upper
    bound (ρ <= upper <= rho + roundoff when exact). `words`: complete products evaluated;
    `prefixes`: partial products examined; `worst_word`: the agents of the word attaining `rho`
    (0-based, in order); `roundoff`: τ, the allowance within which a prefix's bound counts as
    reached; `distinct`: the number of distinct projections searched over; `merge_deviation`:
    the largest ||P_i - P_r|| of an agent i merged into the class of agent r (the ρ of the given
    P_i differs from the one searched by at most N times that)."""

    rho: float
    exact: bool
    words: int
    worst_word: tuple[int, ...]
    upper: float = float("nan")
    prefixes: int = 0
    roundoff: float = 0.0
    distinct: int = 0
    merge_deviation: float = 0.0


#: projections closer than this in 2-norm are the same projection (round-off apart: the ranges of
#: agents observing the same modes agree to about 1e-14, distinct ones differ by O(1))
MERGE_TOL = 1e-10
#: a singular value of [I - P_t; ...] below this spans the space the letters t leave fixed
FIXED_TOL = 1e-8
#: work the search may do before it stops with a bracket, in units of a small prefix: a prefix of an
#: n-state system costs 1 + n³/40 units (its products and norms), so about 2,000,000 prefixes of a
#: 3-state system, 300,000 of a 6-state one, 2,400 of a 32-state one (about a second each)
RHO_WORK_UNITS = 2_000_000
#: memory the search's frontier may hold (prefix products of n_a x n each and their words)
RHO_FRONTIER_BYTES = 256 * 2**20
#: the tail bounds B(T) are formed for every subset T of the letters up to this many letters
TAIL_MAX_LETTERS = 10


def spectral_norm(M: np.ndarray) -> np.ndarray:
    """||M||_2 batched over leading axes."""
    M = np.asarray(M, float)
    G = np.swapaxes(M, -1, -2) @ M if M.shape[-1] <= M.shape[-2] else M @ np.swapaxes(M, -1, -2)
    return np.sqrt(np.maximum(np.linalg.eigvalsh(G)[..., -1], 0.0))


def range_bases(P_blocks: np.ndarray) -> list[np.ndarray]:
    """Orthonormal bases U_i of the ranges of orthogonal projections P_i (eigenvalues ~ 1)."""
    out = []
    for P in np.asarray(P_blocks, float):
        w, V = np.linalg.eigh((P + P.T) / 2)
        out.append(V[:, w > 0.5])
    return out


def projection_classes(P: np.ndarray, tol: float = MERGE_TOL) -> tuple[list[int], list[int], float]:
    """One representative agent per distinct projection, the class of every agent, and the largest
    ||P_i - P_rep|| within a class (projections within `tol` of a representative join its class)."""
    reps: list[int] = []
    cls: list[int] = []
    deviation = 0.0
    for i in range(len(P)):
        dist = [float(np.linalg.norm(P[r] - P[i], 2)) for r in reps]
        c = int(np.argmin(dist)) if dist and min(dist) <= tol else len(reps)
        if c == len(reps):
            reps.append(i)
        else:
            deviation = max(deviation, dist[c])
        cls.append(c)
    return reps, cls, deviation


def rho_exact(P_blocks: np.ndarray, *, max_states: int | None = None, merge_tol: float = MERGE_TOL) -> RhoResult:
    """ρ = max ||P_{i1} ··· P_{iN}|| over products of N = (m-1)² + 1 factors containing every
    P_i (17), by the exhaustive search of this module (see the module docstring); `max_states`
    prefixes at most (default `prefix_budget`), then a proven bracket."""
    P = np.asarray(P_blocks, float)
    m = len(P)
    reps, cls, deviation = projection_classes(P, merge_tol)
    k = len(reps)
    members = [[i for i in range(m) if cls[i] == c] for c in range(k)]
    res = _search(P[reps], (m - 1) ** 2 + 1 - (m - k), prefix_budget(P.shape[1]) if max_states is None else max_states)
    word, seen = [], set()
    for c in res.worst_word:                         # expand each class's first occurrence into its agents
        word += members[c] if c not in seen else [members[c][0]]
        seen.add(c)
    return RhoResult(res.rho, res.exact, res.words, tuple(word), res.upper, res.prefixes, res.roundoff, k, deviation)


def prefix_budget(n: int) -> int:
    """Prefixes the search examines at most for an n-state system (RHO_WORK_UNITS)."""
    return int(RHO_WORK_UNITS / (1 + n ** 3 / 40))


def fixed_spaces(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every subset T of the letters (a bit mask): Π_T, the orthogonal projection on the space
    the letters of T leave fixed (the right singular vectors of [I - P_t; ...] with singular value
    below FIXED_TOL), and ε_T = max_t ||Π_T P_t - Π_T||, how far the computed P_t are from fixing it."""
    k, n = len(P), P.shape[1]
    Pi, eps = np.zeros((1 << k, n, n)), np.zeros(1 << k)
    Pi[0] = np.eye(n)
    for T in range(1, 1 << k):
        letters = [t for t in range(k) if T >> t & 1]
        _, s, Vt = np.linalg.svd(np.vstack([np.eye(n) - P[t] for t in letters]))
        V = Vt[np.concatenate([s, np.zeros(n - len(s))]) <= FIXED_TOL].T
        Pi[T] = V @ V.T
        eps[T] = max(float(np.linalg.norm(Pi[T] @ P[t] - Pi[T], 2)) for t in letters)
    return Pi, eps


def tail_bounds(P: np.ndarray, Pi: np.ndarray, eps: np.ndarray, N: int) -> np.ndarray:
    """B(T) >= ||Π_T R U_b|| for every word R of length <= N that contains every letter outside T
    and becomes complete at its last letter b (Π_all = 0, B(all) = 0). With c the first letter of R
    outside T, R = R_T P_c R', R_T over T: Π_T R_T = Π_T + E with ||E|| <= N ε_T (telescoping), and
    Π_T P_c = Π_{T+c} + (Π_T P_c - Π_{T+c}), so B(T) = max over c of
    N ε_T + min(||Π_T P_c||, B(T+c) + ||Π_T P_c - Π_{T+c}||), capped at 1."""
    k = len(P)
    full = (1 << k) - 1
    B = np.zeros(1 << k)
    for T in sorted(range(full), key=lambda x: -bin(x).count("1")):
        worst = 0.0
        for c in range(k):
            if T >> c & 1:
                continue
            Tc = T | 1 << c
            step = Pi[T] @ P[c]
            nxt = Pi[Tc] if Tc != full else np.zeros_like(step)
            worst = max(worst, N * eps[T] + min(float(np.linalg.norm(step, 2)),
                                                B[Tc] + float(np.linalg.norm(step - nxt, 2))))
        B[T] = min(worst, 1.0)
    return B


@dataclass(frozen=True)
class _Letters:
    """What the search needs of the k letters: P (k, n, n), the padded range bases Ut (k, r, n)
    (U_i' in the first rows, zeros below: norms unchanged), Π_T, B(T), τ."""

    P: np.ndarray
    Ut: np.ndarray
    Pi: np.ndarray | None
    B: np.ndarray | None
    tau: float
    fixed: np.ndarray | None = None      # per mask: its letters leave a nonzero space fixed

    def bound(self, X: np.ndarray, masks: np.ndarray, floor: float) -> np.ndarray:
        """An upper bound of every complete word that extends the prefixes X (letters `masks`): ||X||,
        or less where the letters leave a space fixed (module docstring). Where the Frobenius norm
        (>= ||X||) is already <= `floor`, it is the bound (the prefix is dropped anyway)."""
        out = np.sqrt(np.einsum("bij,bij->b", X, X))
        rows = np.nonzero(out > floor)[0]
        if not len(rows):
            return out
        out[rows] = spectral_norm(X[rows])
        if self.Pi is not None and masks is not None:
            rows = rows[self.fixed[masks[rows]] & (out[rows] > floor)]
            Xr, mr = X[rows], masks[rows]
            XP = Xr @ self.Pi[mr]
            out[rows] = np.minimum(out[rows], spectral_norm(XP) * self.B[mr] + spectral_norm(Xr - XP))
        return out


def _letters(P: np.ndarray, N: int) -> _Letters:
    k, n = len(P), P.shape[1]
    U = range_bases(P)
    Ut = np.zeros((k, max(u.shape[1] for u in U), n))
    for i, u in enumerate(U):
        Ut[i, :u.shape[1]] = u.T
    # round-off of N products, and of reading a word backwards (||W|| = ||W'|| for symmetric P_i)
    asym = max(float(np.linalg.norm(p - p.T, 2)) for p in P)
    tau = max(8 * N * n * float(np.finfo(float).eps), 2 * N * asym)
    if k > TAIL_MAX_LETTERS:
        return _Letters(P, Ut, None, None, tau)
    Pi, eps = fixed_spaces(P)
    # the allowance: N products' round-off, and how far the computed P_t are from fixing the common spaces
    fixed = np.trace(Pi, axis1=1, axis2=2) > 0.5
    return _Letters(P, Ut, Pi, tail_bounds(P, Pi, eps, N), max(tau, 2 * N * float(eps.max())), fixed)


def _search(P: np.ndarray, N: int, max_states: int) -> RhoResult:
    """The depth-first search over the k distinct letters of P (module docstring)."""
    k, n = len(P), P.shape[1]
    if k == 1:                                       # one projection: the product is P itself
        v = float(np.linalg.norm(P[0], 2))
        return RhoResult(v, True, 1, (0,), v)
    U = range_bases(P)
    if any(u.shape[1] == 0 for u in U):              # some P_i = 0: every product is 0
        z = next(i for i, u in enumerate(U) if u.shape[1] == 0)
        return RhoResult(0.0, True, 0, (z,) + tuple(i for i in range(k) if i != z), 0.0)
    if k > 62:                                       # too many letters for the 64-bit masks: the trivial bracket
        return RhoResult(0.0, False, 0, tuple(range(k)), 1.0)
    L = _letters(P, N)
    full = (1 << k) - 1
    entry_bytes = 8 * L.Ut.shape[1] * n + 2 * N + 16
    # prefixes expanded at once: their children fit 64 MiB, and k levels of them (a first complete word) the frontier
    batch = int(max(1, min(4096, 64 * 2**20 // (entry_bytes * k), RHO_FRONTIER_BYTES // (2 * entry_bytes * k * k))))
    roots = np.arange(k)
    X0 = L.Ut[roots]
    stack = [(X0, roots[:, None].astype(np.int16), 1 << roots.astype(np.int64), L.bound(X0, 1 << roots, -1.0))]
    best, worst, words, prefixes, slack, held = -1.0, (), 0, 0, 0.0, k
    while stack:
        X, W, M, bnd = stack.pop()
        held -= len(X)
        live = bnd > best + L.tau                    # prefixes whose bound a better word has reached since
        slack = max(slack, float(bnd[~live].max(initial=0.0)))
        X, W, M, bnd = X[live], W[live], M[live], bnd[live]
        if len(X) > batch:
            stack.append((X[:-batch], W[:-batch], M[:-batch], bnd[:-batch]))
            held += len(X) - batch
            X, W, M, bnd = X[-batch:], W[-batch:], M[-batch:], bnd[-batch:]
        if not len(X):
            continue
        if prefixes >= max_states or held * entry_bytes > RHO_FRONTIER_BYTES:
            stack.append((X, W, M, bnd))             # cut: every open prefix bounds the words it leads to
            upper = max(float(max(s[3].max(initial=0.0) for s in stack)), best, slack)
            # every product of projections has norm <= 1: a bound above 1 is round-off
            return RhoResult(max(best, 0.0), False, words, worst, max(min(upper, 1.0), best), prefixes, L.tau)
        prefixes += len(X)
        cand = np.broadcast_to(roots, (len(X), k))
        allowed = (cand != W[:, -1:]) & (cand != W[:, :1])          # no letter twice in a row, a only first
        grown = M[:, None] | (1 << cand.astype(np.int64))
        # a word and its reverse have the same norm: only words whose first letter is below their last
        above = (full & ~grown) >> (W[:, :1].astype(np.int64) + 1) != 0         # a missing letter above the first
        complete = allowed & (grown == full) & (cand > W[:, :1])
        if complete.any():
            pi, ci = np.nonzero(complete)
            vals = L.bound(X[pi] @ np.swapaxes(L.Ut[ci], 1, 2), None, best)     # ||·||_2 where it can exceed best
            words += len(pi)
            j = int(np.argmax(vals))
            if vals[j] > best:
                best, worst = float(vals[j]), tuple(int(x) for x in W[pi[j]]) + (int(ci[j]),)
        missing = np.bitwise_count(full & ~grown)
        extend = allowed & (grown != full) & above & (W.shape[1] + 1 + missing <= N)   # room left for the missing
        if not extend.any():
            continue
        pi, ci = np.nonzero(extend)
        Y, masks = X[pi] @ P[ci], grown[pi, ci]
        b = L.bound(Y, masks, best + L.tau)
        keep = b > best + L.tau
        slack = max(slack, float(b[~keep].max(initial=0.0)))
        # on top: the prefixes closest to complete, the largest bound first (a good word found early)
        order = np.nonzero(keep)[0][np.lexsort((b[keep], -missing[pi[keep], ci[keep]]))]
        if len(order):
            stack.append((Y[order], np.concatenate([W[pi[order]], ci[order, None].astype(np.int16)], axis=1),
                          masks[order], b[order]))
            held += len(order)
    return RhoResult(max(best, 0.0), True, words, worst, max(best, slack, 0.0), prefixes, L.tau)


def count_complete_repeat_free_words(m: int, max_len: int) -> int:
    """Number of repeat-free words over m letters of length <= max_len containing every letter
    (inclusion-exclusion; the regression value for m = 4, max_len = 10 is 105,936)."""
    total = 0
    for length in range(1, max_len + 1):
        for k in range(m + 1):
            # words over a fixed k-letter subset, repeat-free, of this length: k (k-1)^(length-1)
            words = k * (k - 1) ** (length - 1) if k > 0 else 0
            total += (-1) ** (m - k) * math.comb(m, k) * words
    return total
