"""The structural claims (scenarios with the role "full": the paper's E1 and E2, every user scenario): the
Riccati maps' order, sublinearity and concavity (Lemma 11, (71)), the token chain (Proposition 6), the token
recursion pathwise (Proposition 7[ii], with the corrected indexing of (13)/(17)), the comparison (71)-(74) and
the token chain's total-variation decay (83).
"""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.walk_detectability as wd
from dse.contract.claims import ClaimSet, role
from dse.estimators.gikf_maps import error_norm, gikf_covariance_step, lyapunov_roundoff, lyapunov_step
from dse.estimators.gikf_roundoff import compose_with_error, fro, loewner_slack, spectral_norm
from dse.estimators.gossip_protocols import matching_at
from dse.verify.rules import (EPS, ERRATUM, FAIL, PASS, Verdict, inequality, not_checkable, p_value_test,
                              roundoff_tolerance)

from . import stats as kst
from .checking import ROUNDOFF_SENTENCE, hyp, random_psd, slack_verdict
from .results import ScenarioResults

claims = ClaimSet()


@claims.claim("kar-moura.lemma11.riccati-maps{.scenario}", "Lemma 11[ii], [iii]; (71)",
              "Compositions of f_n are order preserving, strongly sublinear; f_n concave, f_n ⪯ f_0", "inequality",
              hypotheses=hyp("s1"), when=role("full"))
def check_lemma11(r: ScenarioResults) -> Verdict:
    """Lemma 11 [ii] order preserving, [iii] strong sublinearity with margin (1−λ)Q (from concavity,
    f(0) = Q and f(Q) ⪰ Q), concavity of each f_n and (71) f_n ⪯ f_0, on random PSD inputs with scales
    up to 1e8, rank-deficient inputs and random compositions of length 1-20."""
    sys_ = r.scenario.system
    rng = np.random.default_rng(11)
    M, N, Q = sys_.M, sys_.N, sys_.Q
    slack, raw, worst = [], [], {}

    def add(key, s_, m_):
        slack.append(np.ravel(s_))
        raw.append(np.ravel(m_))
        worst[key] = min(worst.get(key, math.inf), float(np.min(m_)))

    for length in (1, 2, 5, 20):
        seq = rng.integers(0, N, length)
        X = random_psd(rng, 300, M)
        D = np.diag([0.0] + [1.0] * (M - 1))
        X[:50] = D @ X[:50] @ D  # rank-deficient
        Z = random_psd(rng, 300, M)
        XZ = X + Z
        gX, eX = compose_with_error(sys_, X, seq, 0.0)
        gXZ, eXZ = compose_with_error(sys_, XZ, seq, EPS * fro(XZ))
        add("monotone", *loewner_slack(gX, gXZ, error_norm(eX) + error_norm(eXZ)))
        Xp = X[50:] + 1e-3 * np.eye(M)
        lam = rng.uniform(0.05, 0.95, len(Xp))[:, None, None]
        g1, e1 = compose_with_error(sys_, Xp, seq, EPS * fro(Xp))
        g2, e2 = compose_with_error(sys_, lam * Xp, seq, 2 * EPS * fro(lam * Xp))
        lower = lam * g1 + (1 - lam) * Q
        tol = error_norm(e2) + lam[:, 0, 0] * error_norm(e1) + 4 * EPS * (fro(g2) + fro(lam * g1) + fro(Q))
        add("sublinear", *loewner_slack(lower, g2, tol))
    for n in range(N):
        X, Y = random_psd(rng, 300, M), random_psd(rng, 300, M)
        lam = rng.uniform(0, 1, 300)[:, None, None]
        mix = lam * X + (1 - lam) * Y
        fX, eX = compose_with_error(sys_, X, [n], 0.0)
        fY, eY = compose_with_error(sys_, Y, [n], 0.0)
        fM, eM = compose_with_error(sys_, mix, [n], 3 * EPS * fro(mix))
        lower = lam * fX + (1 - lam) * fY
        tol = error_norm(eM) + lam[:, 0, 0] * error_norm(eX) + (1 - lam[:, 0, 0]) * error_norm(eY) + 4 * EPS * (fro(fM) + fro(lower))
        add("concave", *loewner_slack(lower, fM, tol))
        f0 = lyapunov_step(X, sys_.F, Q)
        d0, _ = lyapunov_roundoff(X, sys_.F, Q)
        add("f_n ⪯ f_0", *loewner_slack(fX, f0, error_norm(eX) + d0))
    v = slack_verdict(np.concatenate(slack), np.concatenate(raw),
                      ("smallest raw relative margins: " + ", ".join(f"{k} {x:.2e}" for k, x in worst.items())
                       + ". Strong sublinearity is checked with its explicit margin φ(λX) − λφ(X) ⪰ (1−λ)Q. " + ROUNDOFF_SENTENCE
                       + " Inputs formed in floating point (X + Z, λX, mixtures) carry a few eps‖·‖ more."))
    return v


@claims.claim("kar-moura.prop6.token-chain{.scenario}", "Proposition 6[i], [ii]",
              "Token locations form a Ā-Markov chain (law e_nᵀĀᵗ → uniform)", "statistical",
              hypotheses=hyp("exact-abar", "random-protocol"), when=role("full"))
def check_token_chain(r: ScenarioResults) -> Verdict:
    """Prop 6: every transition count out of node k is Binomial(n_k, Ā[k, l]), the law of p_0(t) is e_0ᵀĀᵗ
    for t = 1..20 and at T (exact binomial test per cell, Bonferroni)."""
    g, Abar = r.gikf, r.bounds["Abar"]
    N = r.scenario.N
    cells, lines = [], []
    n_k = g["trans"].sum(axis=1, keepdims=True)
    pv = kst.binom_p(g["trans"], np.broadcast_to(n_k, g["trans"].shape), Abar).ravel()
    cells += list(pv)
    lines.append(f"transition counts vs Ā: smallest p {pv.min():.3g} over {N}×{N} cells ({int(g['trans'].sum())} transitions)")
    Pk, tok_p = np.eye(N)[0], []
    last = min(len(g["token0"]) - 1, r.slots - 1)          # the run fills p_0(t) for the slots it simulated
    for t in range(1, last + 1):
        Pk = Pk @ Abar
        tok_p += list(kst.binom_p(g["token0"][t], r.runs, Pk))
    cells += tok_p
    if tok_p:
        lines.append(f"law of p_0(t) vs e_0ᵀĀᵗ, t = 1..{last}: smallest p {min(tok_p):.3g}")
    # the last slot's matching moves the tokens after the last covariance update: the final count is p_0(T − 1)
    PT = np.eye(N)[0] @ np.linalg.matrix_power(Abar, r.slots - 1)
    pf = kst.binom_p(g["token0_final"], r.runs, PT)
    cells += list(pf)
    dv = 0.5 * float(np.abs(PT - 1.0 / N).sum())
    lines.append(f"law of p_0(T−1) vs e_0ᵀĀ^(T−1) at T = {r.slots}: smallest p {pf.min():.3g}; its distance to uniform "
                 f"d_v = {dv:.2e} (Prop 6[ii]: → 0 under C.1)")
    return p_value_test(cells, trials=r.runs, min_trials=kst.MIN_SAMPLE,
                        detail=("exact binomial tests (twice the smaller tail), Bonferroni over the cells: " + "; ".join(lines)
                                + ". Counts are independent: one transition per node, slot and run (the tokens form a "
                                  "permutation), and token 0 only for the laws."))


@claims.claim("kar-moura.prop7-ii.pathwise{.scenario}", "Proposition 7[ii], eq (19), with (13)/(17)",
              "Token recursion equals the sensors' covariances pathwise", "identity", when=role("full"))
def check_pathwise(r: ScenarioResults) -> Verdict:
    """Prop 7[ii], (19): with a common matching sequence, the token recursion reproduces the sensors'
    covariances pathwise. Corrected indexing p_n(t) = ->(p_n(t−1), t) vs the printed (13)/(17)."""
    sc = r.scenario
    sys_ = sc.system
    protocol = sc.protocol.build(sc.network)
    rng = np.random.default_rng(7)
    B, T, N = 64, min(40, r.slots), sc.N
    partners = np.array([matching_at(protocol, t, B, rng) for t in range(T)])
    P = np.broadcast_to(sc.P0, (B, N, sc.M, sc.M)).copy()
    sensors = [P]
    for t in range(T):
        P = gikf_covariance_step(P, partners[t], sys_)
        sensors.append(P)
    rows = np.arange(B)[:, None]
    errs, ratio = {}, {}
    for variant in ("corrected", "printed"):
        loc = np.tile(np.arange(N), (B, 1))
        tok = np.broadcast_to(sc.P0, (B, N, sc.M, sc.M)).copy()
        err = np.zeros((B, N, sc.M, sc.M))
        worst, worst_ratio = 0.0, 0.0
        for t in range(T):
            if variant == "corrected":
                loc = partners[t][rows, loc]          # p_n(t) = ->(p_n(t−1), t): move with slot t's matching
            node = loc                                # printed (17): π_t uses matchings 0..t−1 (one slot early)
            tok, err = compose_with_error(sys_, tok, [node], err)
            held = sensors[t + 1][rows, node]
            d = spectral_norm(tok - held)
            worst = max(worst, float((d / np.maximum(1, spectral_norm(held))).max()))
            worst_ratio = max(worst_ratio, float((d / (2 * error_norm(err) + EPS * spectral_norm(held))).max()))
            if variant == "printed":
                loc = partners[t][rows, loc]          # π_{t+1}(n) = ->(π_t(n), t)
        errs[variant], ratio[variant] = worst, worst_ratio
    if ratio["corrected"] > 1:
        status = FAIL
    elif ratio["printed"] <= 1:
        status = PASS
    else:
        status = ERRATUM
    return Verdict(status, measured=errs["printed"], reference=0.0, printed=errs["printed"], corrected=errs["corrected"],
                   margin=1.0 - ratio["corrected"],
                   detail=(f"{B} runs × {T} slots, N = {N}: max relative |P_n(t+1) − P̂_{{p_n(t)}}(t+1)| is "
                           f"{errs['corrected']:.1e} with p_n(t) = ->(p_n(t−1), t) (corrected) and {errs['printed']:.3g} with "
                           f"the printed (13)/(17), which index the matching one slot early; the difference must stay "
                           f"within twice the round-off bound of the recursion (largest ratio {ratio['corrected']:.2g} "
                           f"corrected, {ratio['printed']:.3g} printed). Laws are unaffected (A(t) i.i.d.). " + ROUNDOFF_SENTENCE))


@claims.claim("kar-moura.eq74.comparison{.scenario}", "eqs (71)-(74)",
              "P_n(t) ⪯ P^s_n(t) for t ≥ s: the token's covariance is dominated by the same switching restarted at s "
              "from f_0^s(P0)", "inequality", when=role("full"))
def check_eq74(r: ScenarioResults) -> Verdict:
    """(72)-(74): P_n(t) ⪯ P^s_n(t) for t ≥ s, pathwise, where P^s_n follows token n's own switching
    p_n(s), p_n(s+1), ... but restarts at slot s from the Lyapunov iterate f_0^s(P0) (72). The margins are a stage
    of the run (computed with the Monte Carlo, in parallel; `eq74.eq74`)."""
    e = r.eq74
    if not len(e["s_list"]):
        return not_checkable(f"f_0^s(P0) exceeds the accurate range of the Joseph form ({float(e['limit']):.2g}) for every s")
    s_list, T = [int(s) for s in e["s_list"]], int(e["T"])
    gap = dict(zip((int(s) for s in e["gap_s"]), (float(g) for g in e["gap"])))
    return slack_verdict(e["slack"], e["raw"],
                         (f"tokens {[int(n) for n in e['tokens']]}, {int(e['paths'])} paths each "
                          f"({'Ā-chain' if bool(r.bounds['Abar_exact']) else 'protocol-driven chain'}), "
                          f"restarts s ∈ {s_list}, t = s..{T}. The comparison is not vacuous: median relative gap "
                          f"‖P^s_n(T) − P_n(T)‖/‖P_n(T)‖: " + ", ".join(f"s={k}: {v:.1e}" for k, v in gap.items())
                          + ". " + ROUNDOFF_SENTENCE))


@claims.claim("kar-moura.eq83.tv-decay{.scenario}", "eq (83), Proposition 6[ii]", "d_v(p_n(s), U) ≤ (√N/2) SLEM^s",
              "inequality", hypotheses=hyp("exact-abar"), when=role("full"))
def check_tv_decay(r: ScenarioResults) -> Verdict:
    b = r.bounds
    tv = b["tv"]
    N = r.scenario.N
    s = np.arange(len(tv))
    bound = np.minimum(1.0, 0.5 * math.sqrt(N) * float(b["slem"]) ** s)
    tol, how = roundoff_tolerance(scale=1.0, operations=len(tv) * N)
    return inequality(tv, bound, tolerance=tol,
                      detail=(f"eq (83): d_v(p_n(s), U) ≤ (√N/2) SLEM^s for s < {len(tv)} (‖e_n − U‖₂ ≤ 1), "
                              f"{len(wd.tv_rows(N))} start nodes n; {how}; "
                              f"d_v(s=50) = {tv[min(50, len(tv) - 1)]:.3e}"))
