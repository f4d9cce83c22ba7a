"""Claims on the model and the propositions of the random-communication filtering paper: Lemma III.3
(Jensen's inequality for convex combinations), the fusion weights (3) and (6), the Poisson clocks
(P1)-(P2) of the simulated paths; Proposition III.2 (along a fixed clock path the per-path bound
P_i(t; τ) of (14) dominates the exact conditional covariance (15), checked exactly on many random
paths and by Monte Carlo on one frozen path; the batched per-path computation against an independent
one; the corrected error flow (13a)); and Proposition III.4 (the mean of P_i over the clock paths
solves the ODE (9))."""
from __future__ import annotations

import math

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_covariance as gc
from dse.simulate.stats import chi2_two_sided_p
from dse.verify.rules import FAIL, PASS, Verdict, identity, inequality, p_value_test, roundoff_tolerance

from .claims_common import (MIN_TRIALS, SECOND, cell_var_note, chi2_upper_p, claims, hyp, min_eig, path_mean_pvalues,
                            path_test, path_tolerance, second_variance, sps, worst_cell)
from .references import directions
from .results import ScenarioResults


@claims.claim("{paper}.lemma3_3.jensen", "Lemma III.3, eq. (16)", "zzᵀ ≤ Σγ_j x_jx_jᵀ for a convex combination "
              "z = Σγ_j x_j", "inequality")
def check_jensen(_res) -> Verdict:
    """Lemma III.3 on random vectors and Dirichlet weights, and its exact gap."""
    rng = np.random.default_rng(20210930)
    worst, ident, tol_rel = np.inf, 0.0, 0.0
    for _ in range(2000):
        m, n = rng.integers(1, 6), rng.integers(1, 6)
        X = rng.standard_normal((m, n)) * rng.exponential(1.0, (m, 1))
        g = rng.dirichlet(np.ones(m))
        z = g @ X
        gap = np.einsum("j,ja,jb->ab", g, X, X) - np.outer(z, z)
        scale = float(np.abs(X).max() ** 2)
        worst = min(worst, float(min_eig(gap)) / scale)
        exact = np.einsum("j,ja,jb->ab", g, X - z, X - z)
        ident = max(ident, float(np.abs(gap - exact).max()) / scale)
        tol_rel = max(tol_rel, roundoff_tolerance(scale=1.0, operations=2 * m + 2 * n)[0])
    ok = worst >= -tol_rel and ident <= tol_rel
    return Verdict(PASS if ok else FAIL, measured=worst, reference=0.0, tolerance=tol_rel, margin=worst + tol_rel,
                   detail=f"2000 random cases (m, n ≤ 5): smallest eigenvalue of Σγ_j x_jx_jᵀ − zzᵀ relative to max|x|² "
                          f"{worst:.3e}; the gap equals Σγ_j(x_j − z)(x_j − z)ᵀ to {ident:.1e}; round-off allowance "
                          f"{tol_rel:.2g} = 10·(2m + 2n) operations·eps (sums of m outer products and the eigenvalue solve)")


@claims.claim("{paper}.model.fusion_weights{.scenario}", "eq. (3), (6)", "Π = I − α𝓛 is symmetric, doubly stochastic "
              "and nonnegative for 0 < α ≤ 1/d_max, and the mean jump of the edge clocks is λ(Π − I)", "identity",
              hypotheses=hyp("alpha"))
def check_fusion(r: ScenarioResults) -> Verdict:
    s = r.sys
    Pi = np.eye(s.N) - s.alpha * s.laplacian
    jump_sum = sum(s.jump(c) - np.eye(s.N) for c in range(len(s.clocks)))
    err = max(np.abs(Pi.sum(0) - 1).max(), np.abs(Pi.sum(1) - 1).max(), np.abs(jump_sum + s.alpha * s.laplacian).max(),
              np.abs(Pi - Pi.T).max())
    tol, how = roundoff_tolerance(scale=1.0, operations=2 * s.N + len(s.clocks))
    ok = err <= tol and Pi.min() >= -tol
    return Verdict(PASS if ok else FAIL, measured=float(Pi.min()), reference=0.0, tolerance=tol, margin=float(Pi.min()),
                   detail=f"Π = I − α𝓛 with α = {s.alpha:.6g}: symmetric, row/column sums 1 and Σ_c (J_c − I) = −α𝓛 "
                          f"hold to {err:.1e} ({how}); smallest entry {Pi.min():.4g} ≥ 0")


def _two_sided_discrete(cdf_k, sf_k) -> np.ndarray:
    return np.minimum(1.0, 2 * np.minimum(cdf_k, sf_k))


@claims.claim("{paper}.model.poisson_clocks{.scenario}", "§II, (P1)-(P2)", "node counters are Poisson of rate d_iλ; "
              "rings are never simultaneous, so every activation set is a singleton", "statistical")
def check_poisson(r: ScenarioResults) -> Verdict:
    """Node counters against their exact laws: the total count over n paths is Poisson(n·d_iλT)
    and the number of paths without any event is Binomial(n, e^{−d_iλT}) (exact tests)."""
    ev, sc, s = r.event, r.scenario, r.sys
    n = int(ev["n"])
    mu = s.degrees * sc.main_rate * sc.horizon
    total, zeros = np.asarray(ev["c1"], float), np.asarray(ev["c0"], float)
    p_sum = _two_sided_discrete(sps().poisson.cdf(total, n * mu), sps().poisson.sf(total - 1, n * mu))
    p0 = np.exp(-mu)
    p_zero = _two_sided_discrete(sps().binom.cdf(zeros, n, p0), sps().binom.sf(zeros - 1, n, p0))
    spacing = float(ev["spacing"])
    v = p_value_test(np.concatenate([p_sum, p_zero]), trials=n, min_trials=MIN_TRIALS,
                     measured=float((total / n)[np.argmin(p_sum)]), reference=float(mu[np.argmin(p_sum)]),
                     detail=f"exact tests of the node event counts on [0, {sc.horizon:g}] at λ = {sc.main_rate:g}: total "
                            f"over {n} paths ~ Poisson(n·d_iλT) (means {np.round(total / n, 3).tolist()} vs "
                            f"{np.round(mu, 3).tolist()}), paths without event ~ Binomial(n, e^(−d_iλT)) "
                            f"({zeros.astype(int).tolist()} vs expected {np.round(n * p0, 2).tolist()}); smallest spacing "
                            f"between events {spacing:.3g} > 0 (no simultaneous rings)")
    if v.status == PASS and not spacing > 0:
        return Verdict(FAIL, detail="two events at the same instant. " + v.detail)
    return v


def worst_direction(X: np.ndarray) -> np.ndarray:
    """Unit eigenvector of the smallest eigenvalue of symmetric X (…, n, n) → (…, n)."""
    return np.linalg.eigh((X + np.swapaxes(X, -1, -2)) / 2)[1][..., 0]


@claims.claim("{paper}.prop3_2.per_path{.scenario}", "Prop. III.2, eq. (15)", "for a fixed clock path, "
              "E[e_ie_iᵀ | τ](t) ≤ P_i(t) (eq. 14) for all t (exact per-path computation, many random paths)",
              "inequality", hypotheses=hyp("alpha", "initial", "numerics"))
def check_prop32_path(r: ScenarioResults) -> Verdict:
    ev = r.event
    g = float(ev["min_gap"])
    tol, how = path_tolerance(r, float(ev["max_scale"]))
    v = inequality([0.0], [g], tolerance=tol, detail=(
        f"smallest eigenvalue of P_i(t; τ) − E[e_ie_iᵀ | τ](t) over {int(ev['n'])} random clock paths, every node, "
        f"every event and output time on [0, {r.scenario.horizon:g}] at λ = {r.scenario.main_rate:g}: {g:.3e} (largest "
        f"‖P_i‖_F {float(ev['max_scale']):.3g}); {how}. Equality holds before a node's first event, so the margin "
        "is 0 up to rounding"))
    return Verdict(v.status, measured=g, reference=-tol, tolerance=tol, margin=g + tol, trials=int(ev["n"]),
                   detail=v.detail)


def _path_references(r: ScenarioResults) -> tuple[np.ndarray, np.ndarray]:
    """(batched simulator, per-interval Van Loan) values of P_i(t; τ) and Σ_ii(t; τ) on the stored paths."""
    sc, s = r.scenario, r.sys
    measured, reference = [], []
    for p in range(r.event["sample_sigma"].shape[0]):
        t, c = r.event["sample_event_times"][p], r.event["sample_event_clocks"][p]
        P, Sig = gc.path_bound_and_covariance(s, t[c >= 0], c[c >= 0], sc.output_times)
        measured += [r.event["sample_pbound"][p].ravel(), r.event["sample_sigma"][p].ravel()]
        reference += [P.ravel(), gc.diagonal_blocks(Sig, s.N, s.n).ravel()]
    return np.concatenate(measured), np.concatenate(reference)


@claims.claim("{paper}.prop3_2.reference_path{.scenario}", "Prop. III.2, eq. (14)", "the batched per-path P_i(t; τ) "
              "and Σ(t; τ) equal an independent per-interval Van Loan computation", "identity",
              hypotheses=hyp("numerics"))
def check_prop32_reference(r: ScenarioResults) -> Verdict:
    """The batched simulator's per-path Σ(t; τ) and P(t; τ) against a plain Van Loan loop."""
    m, ref_ = _path_references(r)
    tol, how = path_tolerance(r, float(np.abs(ref_).max()))
    return identity(m, ref_, rtol=0, atol=tol,
                    detail=f"{r.event['sample_sigma'].shape[0]} stored clock paths: the batched propagation (eigenbasis "
                           f"or dense Van Loan) equals a per-interval Van Loan computation (scipy expm); {how}")


def _first_event_times(r: ScenarioResults) -> np.ndarray:
    """(paths, N): time of each node's first event on the stored sample paths."""
    ev_t, ev_c = r.event["sample_event_times"], r.event["sample_event_clocks"]
    s = r.sys
    out = np.full((ev_t.shape[0], s.N), np.inf)
    for p in range(ev_t.shape[0]):
        for t, c in zip(ev_t[p], ev_c[p]):
            if c < 0:
                continue
            i, j = s.clocks[c]
            for node in ((i, j) if s.mode == "edge" else (i,)):
                out[p, node] = min(out[p, node], t)
    return out


@claims.claim("{paper}.prop3_2.flow_equality{.scenario}", "proof of Prop. III.2, eq. (13a) corrected", "between "
              "events E[e_ie_iᵀ | τ] follows the Lyapunov flow of (14a) exactly (equality until node i's first event)",
              "identity", hypotheses=hyp("numerics"))
def check_prop32_flow(r: ScenarioResults) -> Verdict:
    """Proof step (a) with the corrected (13a): between events E[e_ie_iᵀ | τ] follows the same
    Lyapunov flow as P_i, so until node i's first event their difference is the initial one carried
    by the homogeneous flow, P_i(t) − Σ_ii(t) = e^{A_it}(P_i(0) − E[e_i(0)e_i(0)ᵀ])e^{A_iᵀt} (zero when P_i(0)
    is the initial second moment)."""
    s = r.sys
    first = _first_event_times(r)
    times = r.scenario.output_times
    D0 = np.asarray(s.P_init) - s.P0
    a, b = [], []
    for p in range(first.shape[0]):
        for i in range(s.N):
            k = times < first[p, i]
            Phi = np.array([scipy.linalg.expm(s.Ai[i] * t) for t in times[k]]) if np.any(D0[i]) else None
            carried = 0.0 if Phi is None else Phi @ D0[i] @ np.swapaxes(Phi, 1, 2)
            a.append((r.event["sample_sigma"][p, k, i] + carried).ravel())
            b.append(r.event["sample_pbound"][p, k, i].ravel())
    a, b = np.concatenate(a), np.concatenate(b)
    tol, how = path_tolerance(r, float(np.abs(b).max()) if b.size else 0.0)
    return identity(a, b, rtol=0, atol=tol,
                    detail=f"{a.size} entries before each node's first event on the stored paths; uses the corrected "
                           "error dynamics (13a) de_i = (A − L_iH_i)e_i dt + B dω − L_i dv_i (the printed "
                           f"'(A − L_iH_i) de_i' has no meaning); {how}")


def whitening_directions(Sigma: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """For covariances Σ (…, n, n): vectors w (…, q, n) such that wᵀe ~ N(0, 1) when e ~ N(0, Σ):
    v_a/√μ_a (eigenpairs of Σ) and (v_a/√μ_a + v_b/√μ_b)/√2, and whether each is usable (the
    eigenvalues involved exceed 1e-9 of the largest: below, the errors are rounding)."""
    mu, V = np.linalg.eigh((Sigma + np.swapaxes(Sigma, -1, -2)) / 2)
    ok = mu > 1e-9 * np.maximum(mu[..., -1:], 1e-300)
    Y = V / np.sqrt(np.where(ok, mu, 1.0))[..., None, :]
    W = np.stack([Y[..., :, a] if a == b else (Y[..., :, a] + Y[..., :, b]) / math.sqrt(2) for a, b in pairs], -2)
    use = np.stack([ok[..., a] & ok[..., b] for a, b in pairs], -1)
    return W, use


@claims.claim("{paper}.prop3_2.frozen_path_mc{.scenario}", "Prop. III.2", "Monte Carlo over (x0, ω, v) on one frozen "
              "clock path reproduces the exact per-path covariance", "statistical", hypotheses=hyp("numerics"),
              args=("equal",))
def check_prop32_frozen(r: ScenarioResults, which: str) -> Verdict:
    """One frozen clock path: the errors of the K trials are i.i.d. N(0, Σ_ii(t; τ)) exactly, so
    Σ_k (wᵀe_k)² ~ χ²(K) for every whitening direction w (two-sided exact test), and under
    (15), Σ_ii ⪯ P_i, Σ_k (uᵀe_k)²/(uᵀP_iu) is stochastically below χ²(K) (one-sided)."""
    fz = r.frozen
    mom = r.frozen_moments()
    K = mom.count
    S2 = mom.s2[1:]                                     # Σ_k e eᵀ (T, N, n, n)
    Sig, P = fz["path_sigma"][1:], fz["path_pbound"][1:]
    events = len(fz["path_times"])
    if which == "equal":
        W, use = whitening_directions(Sig, gc.vech_pairs(r.sys.n))
        stat = np.einsum("...da,...ab,...db->...d", W, S2, W)[use]
        p = chi2_two_sided_p(stat, K)
        return p_value_test(p, trials=K, min_trials=MIN_TRIALS, measured=float(stat[np.argmin(p)] / K), reference=1.0,
                            detail=f"one frozen clock path ({events} events on [0, {r.scenario.horizon:g}]): Monte Carlo "
                                   f"over (x0, ω, v) of the errors whitened by the exact Σ_ii(t; τ) (eigen-directions and "
                                   f"their pairwise sums, every node and output time t > 0): Σ_k (wᵀe_k)² ~ χ²({K}) "
                                   "exactly (measured: the mean square, 1 expected)")
    U = np.concatenate([worst_direction(P - Sig)[..., None, :],
                        np.broadcast_to(directions(r.sys.n), Sig.shape[:-2] + directions(r.sys.n).shape)], -2)
    den = np.einsum("...da,...ab,...db->...d", U, P, U)
    use = den > 1e-12 * np.maximum(np.abs(P).max(axis=(-2, -1)), 1e-300)[..., None]
    stat = np.einsum("...da,...ab,...db->...d", U, S2, U)[use] / den[use]
    p = chi2_upper_p(stat, K)
    return p_value_test(p, trials=K, min_trials=MIN_TRIALS, measured=float(stat[np.argmin(p)] / K), reference=1.0,
                        detail=f"(15) on one frozen path ({events} events): Σ_k (uᵀe_k)²/(uᵀP_iu) is stochastically "
                               f"below χ²({K}) when Σ_ii ⪯ P_i (the errors are exactly Gaussian given the path); one-sided "
                               "exact test along the worst direction of P_i − Σ_ii and the fixed directions, every node "
                               "and t > 0 (measured: the ratio of the mean square to uᵀP_iu, at most 1 expected)")


claims.claim("{paper}.prop3_2.frozen_path_bound{.scenario}", "Prop. III.2, eq. (15)", "Monte Carlo on one frozen clock "
             "path: E[e_ie_iᵀ | τ] ≤ P_i(t) (one-sided, matrix order)", "statistical",
             hypotheses=hyp("alpha", "initial", "numerics"), args=("bound",))(check_prop32_frozen)


@claims.claim("{paper}.prop3_4.mean_of_P{.scenario}", "Prop. III.4", "the mean over Poisson clock paths of P_i(t) "
              "solves the linear ODE (9)", "statistical", hypotheses=hyp("numerics"), requires=SECOND)
def check_prop34(r: ScenarioResults) -> Verdict:
    ev, b = r.event, r.bounds
    n = int(ev["n"])
    mu, second = b["cell_bound"], b["cell_P_second"]
    p = path_mean_pvalues(ev["qP1"], ev["qP2"], n, mu, second_variance(b, second - np.square(b["cell_P_mean"])))
    est = ev["qP1"] / n
    m, rf = worst_cell(p, est, mu)
    return path_test(p, n=n, measured=m, reference=rf,
                     detail=f"mean over {n} clock paths of uᵀP_i(t; τ)u (eq. 14) against uᵀ𝒫_i(t)u of (9) at λ = "
                            f"{r.scenario.main_rate:g}, every node, {len(b['cell_times'])} times and the directions e_a, "
                            f"(e_a + e_b)/√2; {cell_var_note(b)}. Low means: Bernstein's bound; high means: Student "
                            "and known-variance statistics must both reject")
