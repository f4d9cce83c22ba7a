"""The design stage of the hybrid-observer family: every deterministic quantity the theorems
are made of, without simulating (`dse check` prints them; the hypotheses are decided on them).

Per agent: L_i, Ā_i, C̄_i, Q_i, P_i, the gain K_i, the spectrum of Ā_i + K_i C̄_i and c_i of
(15). For the system: ||A||, (16), ρ of (17) with its witness word, α of Lemma 5 and as
printed in (18), r = (λ + ||A||)T / ln(1/α) and the q of (22), of (21)+(19) and the minimal
one of Lemma 4's proof for both α and for the design and printed λ; σ of (26) with its worst
graph, r and q of (27). Per run: the constants b, c, d, d', g of the bounds (51), (54), (63).
The sampled checks of Lemmas 5 and 6 are a separate, slower stage (`lemma_samples`).
"""
from __future__ import annotations

import math

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.simulate.seeding import stream_seed
from dse.simulate.units import block_generator

from .scenario import SIGMA_MAX_AGENTS, HybridFile, RunSection

BASIS_CONDITION = 100.0     # condition number of the non-orthogonal change of basis of footnote 3
LEMMA5_SAMPLES = 20_000
LEMMA5_FLOPS = 10 ** 9      # at most about this many flops for the sampled products of Lemma 5
LEMMA6_SAMPLES = 2000
LEMMA6_FLOPS = 10 ** 9
SAMPLE_BATCH_BYTES = 64 * 2**20
#: σ of (26) is computed when (number of connected graphs)·(mn)³ stays below this
SIGMA_FLOPS = 5 * 10 ** 10
Q_KEYS = ("q_thm22", "q_thm21", "q_minimal", "q_thm22_printed_alpha", "q_thm21_printed_alpha",
          "q_minimal_printed_alpha")


def lambda_variants(sc: HybridFile) -> list[tuple[str, float]]:
    """('', λ of the design) and ('_paper', the printed λ) when the scenario gives one that differs."""
    lam_p = sc.printed_lam
    return [("", sc.lam)] + ([("_paper", lam_p)] if lam_p != sc.lam else [])


def design_quantities(sc: HybridFile, seed: int, extras: bool = False) -> dict[str, np.ndarray]:
    """Every deterministic design quantity; `extras` adds Section 5's vertex-loss design, which
    only the paper's claims use."""
    d = sc.observer
    m, n = d.m, d.n
    out: dict[str, np.ndarray] = {}
    nA = float(np.linalg.norm(sc.A, 2))
    out["norm_A"] = np.array(nA)
    out["norm_eAT"] = np.array(np.linalg.norm(scipy.linalg.expm(sc.A * sc.T), 2))
    out["eig_A"] = np.linalg.eigvals(sc.A)
    out["P"] = d.P
    out["n_i"] = np.array(d.n_i)
    out.update(local_design_checks(sc, d, seed))
    out["joint_rank"] = np.array(jd.observable_basis(sc.A, np.vstack(sc.C), sc.rank_tol).rows.shape[0])
    stack = np.vstack([np.eye(n) - d.P[i] for i in range(m)])
    out["sigma_min_16"] = np.array(np.linalg.svd(stack, compute_uv=False).min())
    F = [d.F(i) for i in range(m)]
    width = max(d.n_i)
    eig = np.full((m, width), np.nan + 0j)
    for i, Fi in enumerate(F):
        ev = np.linalg.eigvals(Fi)
        eig[i, :len(ev)] = ev[np.lexsort((ev.imag, ev.real))]
    out["local_eigs"] = eig
    out["local_abscissa"] = np.array([jd.spectral_abscissa(Fi) for Fi in F])
    out["local_abscissa_tol"] = np.array([eigenvalue_roundoff(Fi) for Fi in F])
    out["c_i"] = np.array([jd.transient_constant(Fi, sc.lam_bar) for Fi in F])
    out["Q_mixed"] = np.array(jd.mixed_norm(scipy.linalg.block_diag(*d.Q), [n] * m, d.n_i))
    out["Q_2"] = np.array(np.linalg.norm(scipy.linalg.block_diag(*d.Q), 2))
    out["eig_central"] = np.linalg.eigvals(sc.A + sc.central_gain @ np.vstack(sc.C))
    rho = jd.rho_exact(d.P)
    out["rho"], out["rho_exact"], out["rho_words"] = np.array(rho.rho), np.array(rho.exact), np.array(rho.words)
    out["rho_upper"] = np.array(rho.upper)
    out["rho_worst_word"] = np.array(rho.worst_word)
    out["rho_prefixes"], out["rho_roundoff"] = np.array(rho.prefixes), np.array(rho.roundoff)
    out["rho_distinct"], out["rho_merge_deviation"] = np.array(rho.distinct), np.array(rho.merge_deviation)
    if rho.upper < 1:           # (22) from the proven upper bound on ρ: a q that is sufficient for sure
        sq = jd.sufficient_q(rho.upper, m, nA, sc.lam, sc.T)
        out["alpha_lemma5_upper"] = np.array(float(sq.alpha_lemma5))
        out["q_thm22_upper"] = np.array(jd.exact_text(sq.q_thm22))
    for label, lam in lambda_variants(sc):
        sq = jd.sufficient_q(rho.rho, m, nA, lam, sc.T)
        out[f"alpha_lemma5{label}"] = np.array(float(sq.alpha_lemma5))
        out[f"one_minus_alpha_log10{label}"] = np.array(sq.log10_one_minus_alpha)
        out[f"alpha_printed{label}"] = np.array(float(sq.alpha_printed))
        out[f"r_lemma5{label}"] = np.array(float(sq.r_lemma5))
        out[f"r_printed{label}"] = np.array(float(sq.r_printed))
        out[f"r_lemma5_exact{label}"] = np.array(str(sq.r_lemma5))
        out[f"r_printed_exact{label}"] = np.array(str(sq.r_printed))
        for k in Q_KEYS:
            out[f"{k}{label}"] = np.array(jd.exact_text(getattr(sq, k)))
    skipped = sigma_skip_reason(m, n)
    graphs = jd.connected_undirected_graphs(m) if skipped is None else None
    if skipped is not None:
        out["sigma_skipped_graphs"], out["sigma_skipped_reason"] = np.array(skipped[0]), np.array(skipped[1])
    if graphs is not None:
        sig, worst, vals = jd.sigma_symmetric(d.P, graphs)
        out["sigma"], out["sigma_worst"], out["sigma_graphs"] = np.array(sig), np.array(worst), np.array(len(vals))
        out["sigma_worst_mask"] = graphs[worst]
        for label, lam in lambda_variants(sc):
            if sig < 1:
                out[f"r27{label}"] = np.array(jd.r_symmetric(sig, nA, lam, sc.T))
                out[f"q27{label}"] = np.array(jd.q_symmetric(sig, nA, lam, sc.T))
                out[f"q27_minimal{label}"] = np.array(jd.q_symmetric_minimal(sig, nA, lam, sc.T))
    out["graph_strong"] = np.array([jd.is_strongly_connected(G) for G in sc.graph_masks])
    out["graph_symmetric"] = np.array([bool(np.array_equal(G, G.T)) for G in sc.graph_masks])
    out["graph_vertex_redundant"] = np.array([all(jd.is_strongly_connected(np.delete(np.delete(G, i, 0), i, 1))
                                                  for i in range(m)) for G in sc.graph_masks])
    if extras:
        out.update(section5_design(sc, d, nA))
    return out


def connected_graph_count(m: int) -> int:
    """Connected labelled graphs on m vertices: all 2^C(m,2) graphs minus those whose vertex 1 lies in
    a component of k < m vertices (1, 1, 4, 38, 728, 26,704, 1,866,256, 251,548,592, ...)."""
    c = [0, 1]
    for v in range(2, m + 1):
        c.append(2 ** math.comb(v, 2) - sum(math.comb(v - 1, k - 1) * c[k] * 2 ** math.comb(v - k, 2)
                                            for k in range(1, v)))
    return c[m]


def sigma_skip_reason(m: int, n: int) -> tuple[int, str] | None:
    """Why σ of (26) is not enumerated (the number of connected graphs and a sentence), or None when it is."""
    count = connected_graph_count(m)
    if m > SIGMA_MAX_AGENTS:
        return count, (f"σ of (26) is a maximum over every connected graph on m = {m} vertices: {count:,} graphs "
                       f"(of 2^{math.comb(m, 2)} labelled graphs), beyond the enumeration limit m <= {SIGMA_MAX_AGENTS}; "
                       f"(27) is not evaluated")
    if count * (m * n) ** 3 > SIGMA_FLOPS:
        return count, (f"σ of (26) needs {count:,} norms of {m * n} x {m * n} matrices, about "
                       f"{count * (m * n) ** 3:.2g} flops > {SIGMA_FLOPS:.0e}; (27) is not evaluated")
    return None


def constants(design: dict, sc: HybridFile, run: RunSection) -> dict[str, float]:
    """The constants of the proofs: b = q e^(||A||T)|Q| (45), c = max c_i (15), d = c b e^(λT) /
    (1 - e^(-(λ̄-λ)T)) (51), b' and d' (their 2-norm analogues for the symmetric case), and
    g = 2mq||A||e^(||A||(T+β)) of (62)-(63)."""
    nA = float(design["norm_A"])
    c = float(np.max(design["c_i"]))
    b = run.q * math.exp(nA * sc.T) * float(design["Q_mixed"])
    den = 1.0 - math.exp(-(sc.lam_bar - sc.lam) * sc.T)
    d = c * b * math.exp(sc.lam * sc.T) / den
    b2 = run.q * math.exp(nA * sc.T) * float(design["Q_2"])
    d2 = c * b2 * math.exp(sc.lam * sc.T) / den
    g = 2 * sc.m * run.q * nA * math.exp(nA * (sc.T + run.beta))
    return {"b": b, "c": c, "d": d, "b_sym": b2, "d_sym": d2, "g": g, "norm_A": nA}


def alpha_used(design: dict) -> tuple[float | None, str]:
    """α of Lemma 5 for ρ exact, or for the proven upper bound of ρ (a larger α: a check against
    it is weaker but sound); None when no upper bound below 1 is known."""
    if bool(design["rho_exact"]):
        return float(design["alpha_lemma5"]), f"α = {float(design['alpha_lemma5']):.12g} (ρ exact)"
    if "alpha_lemma5_upper" in design:
        return float(design["alpha_lemma5_upper"]), (f"α = {float(design['alpha_lemma5_upper']):.12g} from the upper "
                                                    f"bound ρ <= {float(design['rho_upper']):.6g}")
    return None, "ρ is not bounded below 1 by the search"


def alpha_power(design: dict, p: int) -> float:
    """α^p of Lemma 5 for a run's comparison (20), p = floor(q/N): exactly 1 for p = 0 (whatever ρ);
    else from the upper end of ρ's bracket, the safe one: α = 1 - (m-1)(1-ρ)/m^((m-1)²) grows with ρ,
    so the α of an upper bound of ρ gives a bound α^p that holds for every ρ in the bracket (a larger,
    weaker one). Without an upper bound below 1, α = 1: every step has |P(S⊗I)| <= 1, so 1 bounds
    every product."""
    if p == 0:
        return 1.0
    if "alpha_lemma5_upper" in design:
        return float(design["alpha_lemma5_upper"]) ** p
    return float(design["alpha_lemma5"]) ** p if bool(design["rho_exact"]) else 1.0


# -- the sampled checks of Lemmas 5 and 6 ----------------------------------------------------------

def lemma_samples(sc: HybridFile, seed: int) -> dict[str, np.ndarray]:
    """Lemma 5: products of N = (m-1)²+1 steps P(S⊗I) with S flocking matrices of strongly
    connected graphs (every one for m <= 4, else 4,000 random ones), sampled at random plus every
    constant sequence; Lemma 6: random doubly stochastic F with a strongly connected graph. Both
    within a flop budget (LEMMA5_FLOPS, LEMMA6_FLOPS) and in batches of bounded memory."""
    d = sc.observer
    m, n = d.m, d.n
    mn = m * n
    N = (m - 1) ** 2 + 1
    out: dict[str, np.ndarray] = {}
    if m <= 4:
        pool = jd.strongly_connected_digraphs(m)
    else:
        gen = block_generator(stream_seed(seed, "lemma5-pool"))
        cand = gen.random((4000, m, m)) < 0.5
        cand |= np.eye(m, dtype=bool)[None]
        pool = cand[jd.strongly_connected_batch(cand)]
    flock = np.array([jd.flocking_matrix(g) for g in pool])
    per_product = N * mn ** 3
    samples = int(min(LEMMA5_SAMPLES, max(min(len(pool), LEMMA5_SAMPLES), LEMMA5_FLOPS // per_product)))
    if per_product * min(samples, len(pool)) > 20 * LEMMA5_FLOPS:
        samples = int(max(1, 20 * LEMMA5_FLOPS // per_product))     # very large m n: a few products only
    gen = block_generator(stream_seed(seed, "lemma5"))
    idx = gen.integers(0, len(pool), size=(samples, N))
    constant = min(len(pool), samples)                               # adversarial: constant sequences first
    idx[:constant] = np.arange(constant)[:, None]
    batch = max(1, SAMPLE_BATCH_BYTES // (8 * mn * mn * 2))
    used, codes = np.unique(idx, return_inverse=True)
    idx = codes.reshape(idx.shape)                   # positions in `used`
    # P(S ⊗ I) (entrywise products) of the graphs drawn: formed once when they fit the batch memory
    table = ho.step_matrix_batch(d.P, flock[used]) if len(used) * mn * mn * 8 <= SAMPLE_BATCH_BYTES else None

    def steps(cols: np.ndarray) -> np.ndarray:
        return table[cols] if table is not None else ho.step_matrix_batch(d.P, flock[used[cols]])

    best = 0.0
    # the constant sequences first, then the random ones in batches; a product whose prefix is already
    # below the largest |·| found cannot exceed it (|·| is an induced norm and every step has |P(S⊗I)| <= 1),
    # so it is dropped: the largest |·| is the same, each product that can attain it computed as before
    for a, b in [(0, constant)] + [(a, min(a + batch, samples)) for a in range(constant, samples, batch)]:
        rows = idx[a:b]
        prod = steps(rows[:, 0])
        check = best > 0
        for k in range(1, N):
            prod = steps(rows[:, k]) @ prod
            if check and k >= N // 2:       # from halfway, while a check drops at least a tenth of the products
                keep = mixed_norm_bound(prod, n, m) * (1 + 1e-12) >= best
                prod, rows, check = prod[keep], rows[keep], keep.sum() <= 0.9 * len(keep)
        if len(prod):
            best = max(best, float(jd.mixed_norm(prod, [n] * m, [n] * m).max()))
    out["lemma5_max"], out["lemma5_samples"], out["lemma5_pool"] = np.array(best), np.array(samples), np.array(len(pool))
    gen = block_generator(stream_seed(seed, "lemma6"))
    count6 = int(max(1, min(LEMMA6_SAMPLES, LEMMA6_FLOPS // (mn ** 3))))
    perms = np.array([[np.eye(m)[gen.permutation(m)] for _ in range(3)] for _ in range(count6)])
    wts = gen.dirichlet(np.ones(4), size=count6)
    Fm = wts[:, :1, None] * np.eye(m)[None] + np.einsum("bk,bkij->bij", wts[:, 1:], perms)
    Fm = Fm[jd.strongly_connected_batch(Fm > 1e-12)]
    Pbig = scipy.linalg.block_diag(*d.P)
    vals = [jd.spectral_norm(Pbig[None] @ np.einsum("fij,ab->fiajb", Fm[a:a + batch], np.eye(n)).reshape(-1, mn, mn))
            for a in range(0, len(Fm), batch)]
    out["lemma6_max"] = np.array(np.max(np.concatenate(vals)) if vals else np.nan)
    out["lemma6_count"] = np.array(len(Fm))
    return out


def mixed_norm_bound(M: np.ndarray, n: int, m: int) -> np.ndarray:
    """An upper bound of |M| (Sec. 3) for a stack of mn x mn matrices: the blockwise Frobenius
    norms in place of the spectral ones."""
    blocks = M.reshape(len(M), m, n, m, n)
    return np.sqrt(np.einsum("aibjc,aibjc->aij", blocks, blocks)).sum(axis=-1).max(axis=-1)


# -- the paper's extras ----------------------------------------------------------------------------

def section5_design(sc: HybridFile, d: ho.ObserverDesign, nA: float) -> dict[str, np.ndarray]:
    """Section 5: joint observability and strong connectivity without agent i; for every d = m
    minus one agent that stays jointly observable, ρ_d (its upper bound) and q_d of (22); q* = max."""
    m, n = d.m, d.n
    out: dict[str, np.ndarray] = {}
    red_obs = [jd.observable_basis(sc.A, np.vstack([sc.C[j] for j in range(m) if j != i]), sc.rank_tol).rows.shape[0]
               == n for i in range(m)]
    out["redundant_observable"] = np.array(red_obs)
    out["redundant_connected"] = np.array([[jd.is_strongly_connected(np.delete(np.delete(G, i, 0), i, 1))
                                            for i in range(m)] for G in sc.graph_masks])
    rho_d, q_d = [], []
    lam_p = sc.printed_lam
    for i in range(m):
        keep = [j for j in range(m) if j != i]
        if red_obs[i] and m - 1 >= 2:
            rd = jd.rho_exact(d.P[keep]).upper
            rho_d.append(rd)
            q_d.append(jd.exact_text(jd.sufficient_q(rd, m - 1, nA, lam_p, sc.T).q_thm22) if rd < 1 else "")
        else:
            rho_d.append(-1.0)
            q_d.append("")
    out["vertex_loss_ok"], out["vertex_loss_q"] = np.array(red_obs), np.array(q_d)
    out["vertex_loss_rho"] = np.array(rho_d)
    return out


def model_mismatch(sc: HybridFile, seed: int, steps: int = 2000, dt: float = 0.01, size: float = 1e-3
                   ) -> dict[str, np.ndarray]:
    """Section 4's key point: a centralized Kalman filter (filterpy) on all outputs, with the model
    A + δE (||δE|| = size) instead of A, against the same filter with the exact model; noise-free
    plant. Trajectories of ||x||, and of the error for both filters."""
    from filterpy.kalman import KalmanFilter

    n = sc.n
    Cs = np.vstack(sc.C)
    gen = block_generator(stream_seed(seed, "model-mismatch"))
    E = gen.standard_normal((n, n))
    E *= size / np.linalg.norm(E, 2)
    Phi = scipy.linalg.expm(sc.A * dt)
    x = np.empty((steps, n))
    x[0] = sc.x0
    for k in range(1, steps):
        x[k] = Phi @ x[k - 1]
    errs = {}
    for label, Ahat in (("exact", sc.A), ("mismatch", sc.A + E)):
        kf = KalmanFilter(dim_x=n, dim_z=Cs.shape[0])
        kf.F, kf.H = scipy.linalg.expm(Ahat * dt), Cs
        kf.Q, kf.R = 1e-6 * np.eye(n), 1e-4 * np.eye(Cs.shape[0])
        kf.x, kf.P = np.zeros(n), np.eye(n)
        e = np.empty(steps)
        for k in range(steps):
            if k:
                kf.predict()
            kf.update(Cs @ x[k])
            e[k] = np.linalg.norm(kf.x - x[k])
        errs[label] = e
    return {"kp_t": np.arange(steps) * dt, "kp_xnorm": np.linalg.norm(x, axis=1), "kp_err_exact": errs["exact"],
            "kp_err_mismatch": errs["mismatch"], "kp_size": np.array(size)}


# -- per-agent checks of the local design ------------------------------------------------------------

def eigenvalue_roundoff(F: np.ndarray) -> float:
    """Round-off allowance of a computed eigenvalue of F (Bauer-Fike): 10·k·eps·||F||_2·κ(V) for
    the k x k matrix F with eigenvector matrix V (infinite for a defective F)."""
    _, V = np.linalg.eig(F)
    sv = np.linalg.svd(V, compute_uv=False)
    kappa = sv[0] / sv[-1] if sv[-1] > 0 else np.inf
    return float(10 * len(F) * np.finfo(float).eps * np.linalg.norm(F, 2) * kappa)


def random_orthogonal(gen: np.random.Generator, k: int) -> np.ndarray:
    Qm, Rm = np.linalg.qr(gen.standard_normal((k, k)))
    return Qm * np.sign(np.diag(Rm))


def local_design_checks(sc: HybridFile, d: ho.ObserverDesign, seed: int) -> dict[str, np.ndarray]:
    """Per agent: the residuals of C_i = C̄_i L_i and L_i A = Ā_i L_i (relative to ||C_i||,
    ||A|| ||L_i||), the rank of the observability matrix of (C̄_i, Ā_i), and footnote 3: the
    largest entry of P_i(M L_i) - P_i(L_i) for a random orthogonal M and a random M of
    condition number BASIS_CONDITION. What each residual may be from round-off and from the
    rank decision is recorded beside it (κ(L_i), κ(M L_i), the singular value the rank
    decision discarded, the distance of a given L_i's row space from the computed one)."""
    gen = block_generator(stream_seed(seed, "basis-change"))
    rows = {k: [] for k in ("residual_C", "residual_A", "kappa_L", "discarded", "row_space_dist", "obs_rank_local",
                            "P_basis_dev", "kappa_ML")}
    for i in range(d.m):
        loc = sc.locs[i]
        basis = jd.observable_basis(sc.A, sc.C[i], sc.rank_tol)
        L = loc.L
        nL = float(np.linalg.norm(L, 2))
        rows["residual_C"].append(np.abs(sc.C[i] - loc.Cbar @ L).max() / max(float(np.linalg.norm(sc.C[i], 2)), 1e-300))
        rows["residual_A"].append(np.abs(L @ sc.A - loc.Abar @ L).max() / max(float(np.linalg.norm(sc.A, 2)) * nL, 1e-300))
        rows["kappa_L"].append(loc.condition)
        rows["discarded"].append(basis.discarded)
        rows["row_space_dist"].append(float(np.linalg.norm(L - (L @ basis.rows.T) @ basis.rows, 2)) / nL)
        rows["obs_rank_local"].append(jd.observable_basis(loc.Abar, loc.Cbar, sc.rank_tol).rows.shape[0])
        k = loc.n_i
        dev, kap = [], []
        U, V = random_orthogonal(gen, k), random_orthogonal(gen, k)
        for M in (U, U @ np.diag(np.logspace(0, np.log10(BASIS_CONDITION), k)) @ V):
            _, P_alt, cond = jd.pseudo_inverse_rows(M @ L)
            dev.append(np.abs(P_alt - loc.P).max())
            kap.append(cond)
        rows["P_basis_dev"].append(max(dev))
        rows["kappa_ML"].append(max(kap))
    return {k: np.array(v) for k, v in rows.items()}
