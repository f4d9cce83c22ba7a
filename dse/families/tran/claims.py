"""The claims of the coestimation paper, each registered on its check (ids `tran.<where>.<what>`, in
report order) on the family's `ClaimSet`, whose hypotheses are `hypotheses.py`.

Every claim names the hypotheses its conclusion rests on, and with `requires` what the run must
contain to be checked at all (a given P_i, the comparison run, a vertex enumeration); the claims
about the paper's own example (its printed numbers, figures, the example's gains, a fixed
counterexample) have scope "paper-example" and are absent from users' runs. Bounds that hold with a huge slack pass and report
the slack ratio: slack is a finding, not a failure. Every tolerance is a round-off or integration
allowance derived from the computation, stated in the detail.
"""
from __future__ import annotations

import numpy as np

import dse.estimators.input_state_coestimation as ce
import dse.estimators.lyapunov_bounds as lb
from dse.simulate.stats import chi2_two_sided_p, normal_two_sided_p
from dse.verify.rules import (FAIL, PASS, Verdict, claim_confidence, erratum, identity, inequality, not_checkable,
                              p_value_test, roundoff_tolerance)

from . import hypotheses as hy
from .design import coestimation, gains
from .hypotheses import claims
from .law import mean_square_constants
from .runs import Results, mc_moments

EPS = float(np.finfo(float).eps)
SAFETY = 10.0
MIN_TRIALS_ONE_SIDED = 10
REFERENCE = {            # regression values of our reconstruction of the paper's example
    "bound18_single": 1.796e9, "bound18_pernode": 3.557e7, "bound18_certified": 2.686e6, "phibar": 15.4672,
    "phibar_tight": 4.4625, "lamP_min": 0.05280, "lamP_max": 5.62512, "qstar": 1.8196e-3, "bound18_qstar": 9.871e5,
}
PE = "paper-example"
LMI, FIX, INP, INT = hy.H_LMI, hy.H_FIXED, hy.H_INPUT, hy.H_INTEG


# -- helpers ----------------------------------------------------------------------------------

def lyapunov_values(res: Results, z: np.ndarray) -> np.ndarray:
    return np.einsum("tni,nij,tnj->t", z, res.P, z)


def error_derivative(res: Results, run: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """ż from the error system (26)/(33) along a run: (z, ż, |ż|-scale), all (T, N, q) (`ce.error_rate`).
    Kept on `res` (read-only) for the run's other claims: two read the time-varying-role run's."""
    kept = res.__dict__.setdefault("_error_derivative", {})
    if run not in kept:
        sc, G, r, z = res.scenario, gains(res.scenario), res.runs[run], res.errors(run)
        zdot, scale = ce.error_rate(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], G["sigma"], res.P, sc.lap,
                                    sc.coupling.alpha, z, r["g"], r["w"], res.signal().rate(r["t"]))
        for a in (z, zdot, scale):
            a.flags.writeable = False
        kept[run] = z, zdot, scale
    return kept[run]


def tail(res: Results, run: str) -> np.ndarray:
    return res.runs[run]["t"] >= res.scenario.simulation.tail_start


def rms(z: np.ndarray, n: int) -> tuple[float, float]:
    return (float(np.sqrt(np.mean(np.sum(z[..., :n] ** 2, -1)))), float(np.sqrt(np.mean(np.sum(z[..., n:] ** 2, -1)))))


def _integration_allowance(res: Results, run: str) -> float:
    """A bound of ‖z_h(t) − z(t)‖₂ from step halving: √(Nq) · 2·max|Δ| (see runs.integration_error)."""
    est = res.design.integration[run.removesuffix("_half")]["error"]
    return float(np.sqrt(res.scenario.N * res.scenario.q) * est)


# -- model facts ----------------------------------------------------------------------------

@claims.claim("tran.ex51.observability", "Sec. 5, footnote 2", "(A, C_i) observable for every node type of the "
              "example; collective observability holds", "identity", scope=PE)
def check_observability(res: Results) -> Verdict:
    d, n = res.design, res.scenario.n
    local, coll = d["rank_obsv_local"], int(d["rank_obsv_collective"])
    detail = (f"rank obsv(A, C_i) per node type = {local.tolist()}, collective rank = {coll} (n = {n}); augmented "
              f"([[A, B], [0, 0]], [C_i, 0]) ranks = {d['rank_obsv_augmented'].tolist()} of {res.scenario.q}: "
              "velocity-only nodes cannot see the input's constant part on their own")
    ok = bool(np.all(local == n)) and coll == n
    return Verdict(PASS if ok else FAIL, measured=local.tolist() + [coll], reference=n, detail=detail)


@claims.claim("tran.fn3.hurwitz_construction", "footnote 3", "L_i = J_i = 0 with σ_i K_i > 0 makes Ā_i Hurwitz",
              "inequality", hypotheses=(hy.H_A,))
def check_footnote3(res: Results) -> Verdict:
    v = res.design["fn3_max_real"]
    return inequality(v, np.zeros_like(v), strict=True,
                      detail="max Re λ(Ā_i(1)) with L_i = J_i = 0 per node type (block triangular: eig(A) ∪ eig(−σK))")


@claims.claim("tran.eq9.error_dynamics", "(3)-(9), (22)-(26)", "the estimator (22)-(23) yields the error system (26)",
              "identity")
def check_error_dynamics(res: Results) -> Verdict:
    """The estimate form (22)-(23) and the error form (26) give the same ż, to round-off: each side is
    a sum of products whose rounding is at most (Nq + n)·eps times the sum of the magnitudes of its
    terms, evaluated per sample."""
    sc, r, sig = res.scenario, res.runs["coest"], res.signal()
    net = coestimation(sc, res.P)
    z, zdot, zscale = error_derivative(res, "coest")
    idx = np.linspace(0, len(r["t"]) - 1, 200).astype(int)
    Mabs = np.abs(net.estimate_drift())
    LJC = np.abs(np.einsum("iqm,imn->iqn", net.LJ, net.C))
    errs, tols = [], []
    ops = sc.N * sc.q + sc.n
    for k in idx:
        x, e, g, t = r["x"][k], r["e"][k], r["g"][k], r["t"][k]
        xdot = sc.A @ x + sc.B @ r["w"][k]
        edot = net.estimate_rhs(x, e, g, r["w"][k])
        zd = np.concatenate([xdot[None] - edot[:, :sc.n], edot[:, sc.n:] - sig.rate(t)[None]], axis=1)
        est_scale = ((Mabs @ np.abs(e).reshape(-1)).reshape(sc.N, -1)
                     + g[:, None] * np.einsum("iqn,in->iq", LJC, np.abs(x[None] - e[:, :sc.n])))
        est_scale[:, :sc.n] += (np.abs(sc.A) @ np.abs(x) + np.abs(sc.B) @ np.abs(r["w"][k]))[None]
        est_scale[:, sc.n:] += np.abs(sig.rate(t))[None]
        errs.append(np.abs(zd - zdot[k]).max())
        tols.append(SAFETY * ops * EPS * float((est_scale + zscale[k]).max()))
    errs, tols = np.array(errs), np.array(tols)
    return inequality(errs, tols, detail=f"max |ż_estimate-form − ż_(26)| at {len(idx)} samples of the time-varying-role "
                                         f"run against a per-sample round-off allowance {SAFETY:g}·{ops}·eps·(sum of the "
                                         f"magnitudes of the terms), largest {tols.max():.3g} (signs −M, +S, +T, −N of "
                                         "(3)-(4) against (9))")


# -- LMIs -----------------------------------------------------------------------------------

@claims.claim("tran.eq62.printed_P", "(62)-(63)", "the printed P_i satisfy (28)-(29) with the printed ε for the "
              "printed gains", "inequality", scope=PE,
              requires=[(lambda res: "given_sweep" in res.design, "the scenario gives no P_i")])
def check_printed_P(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    sweep = d["given_sweep"]
    eps = np.array([t.eps for t in sc.types])
    vert = sweep[:, [0, -1]]
    return inequality(vert, -eps[:, None] * np.ones_like(vert),
                      detail=f"max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)) at g = 0, 1 per type: {vert.tolist()}; required ≤ −ε_i = "
                             f"{(-eps).tolist()}; relative margins {((-vert.max(1) - eps) / eps).round(3).tolist()}")


@claims.claim("tran.lemma31.vertex_lmis", "Lemma 3.1, (30)", "(28)-(29) at the vertices imply Ā_i(g)ᵀP_i + P_iĀ_i(g) "
              "≤ −εI for all g ∈ [0, 1]", "inequality", hypotheses=(LMI,))
def check_lemma31(res: Results) -> Verdict:
    d = res.design
    sweep, tol, eps = d["lemma_sweep"], d["lemma_tol"], d["eps_nodes"]
    return inequality(sweep, np.broadcast_to(-eps[:, None] + tol[:, None], sweep.shape).copy(),
                      detail=f"(30): max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)) ≤ −ε_i on g ∈ linspace(0, 1, {sweep.shape[1]}) for each "
                             f"node, with the P_i used and a round-off allowance per node (largest {tol.max():.2g}: "
                             f"products of length 2q with inputs of size ‖|Ā|ᵀ|P|‖); max Re λ(Ā_i(g)) over the grid "
                             f"{float(np.max(d['lmi_hurwitz_sweep'])):.4g} (Hurwitz, as (30) implies)")


@claims.claim("tran.step_i.lmi_feasible", "Sec. 3.2 step (i), Remark 3.2", "(28)-(29) are feasible for the example's "
              "gains (Clarabel)", "inequality", scope=PE)
def check_lmi_feasible(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    status, margin, ver = d["lmi_status"], d["lmi_margin"], d["lmi_verified"]
    ok = bool(np.all(margin > 0)) and bool(np.all(np.abs(ver + margin) <= 1e-6 + 1e-3 * np.abs(margin)))
    detail = (f"Clarabel: feasibility (ε_i = {[t.eps for t in sc.types]}) status {status.tolist()}; normalised "
              f"margin t* (tr P = n + p) {margin.tolist()}, re-verified max eig at P*: {ver.tolist()}")
    return Verdict(PASS if ok else FAIL, measured=margin.tolist(), reference=0.0, margin=float(margin.min()),
                   detail=detail)


@claims.claim("tran.ex51.J_tradeoff", "Sec. 5.1 (after Fig. 5)", "J_i cannot be made large while keeping (28)-(29) "
              "feasible", "qualitative", scope=PE,
              requires=[(lambda res: "J_sweep_margin" in res.design, "the J sweep was not computed")])
def check_J_sweep(res: Results) -> Verdict:
    d = res.design
    scale, margin = d["J_sweep"], d["J_sweep_margin"]
    first_bad = [float(scale[np.argmax(m < 0)]) if np.any(m < 0) else None for m in margin]
    ok = bool(np.all(margin[:, 0] > 0)) and any(x is not None for x in first_bad)
    return Verdict(PASS if ok else FAIL, measured=margin.tolist(), reference=0.0,
                   detail=f"normalised (28)-(29) margin for J_i scaled by {scale.tolist()}: {np.round(margin, 5).tolist()}; "
                          f"first infeasible scale per type {first_bad}. Feasible at the printed J, infeasible for a "
                          "larger J: J cannot be raised freely (the lag claim itself is qualitative)")


# -- fixed roles: Thm 2.1, Cor 2.1, Rem 4.3 --------------------------------------------------

@claims.claim("tran.thm21.identity54", "(54), Thm 2.1 proof", "SᵀP + PS = −Q̄ with Q̄ = Q + 2α(L⊗I)", "identity")
def check_identity54(res: Results) -> Verdict:
    d = res.design
    r, tol = float(d["identity54_residual"]), float(d["identity54_tol"])
    return inequality(np.array([r]), np.array([tol]),
                      detail=f"max |SᵀP + PS + Q̄| = {r:.3g} (max |Q̄| = {float(d['identity54_scale']):.4g}) against the "
                             f"round-off allowance {tol:.3g} ({SAFETY:g}·Nq·eps·κ(P)·max of |S|ᵀ|P| + |P||S| + |Q̄|; "
                             f"H = P⁻¹ is inverted with condition κ(P)); fixed roles "
                             f"{list(res.scenario.fixed_roles.active)}")


@claims.claim("tran.rem43.S_hurwitz", "Remark 4.3", "S is Hurwitz", "inequality")
def check_S_hurwitz(res: Results) -> Verdict:
    """S(g) = Ā(g) − αH(L⊗I) is Hurwitz where (54) holds with Q̄ > 0: at every g ∈ [0, 1]^N when the P_i
    satisfy (28)-(29) (then S(g)ᵀP + PS(g) ≤ −Q̄_ε), at the fixed roles when Q_i > 0. Cells whose
    hypothesis fails are not checked (either hypothesis suffices, so neither is required). Computed
    eigenvalues are compared with 0 up to the Bauer-Fike allowance cond(V)·‖S‖·Nq·eps."""
    d = res.design
    v, tol = d["S_max_real"], d["S_tol"]
    lmi, fixed = hy.vertex_lmi(d).holds, hy.fixed_local(d).holds
    if not (lmi or fixed):
        return not_checkable(f"neither {hy.H_LMI} nor {hy.H_FIXED} holds: (54) gives no Q̄ > 0 for any S")
    cells = np.ones(len(v), bool) if lmi else np.arange(len(v)) == 2
    which = "all cells" if lmi else f"the fixed roles only ({hy.H_LMI} does not hold)"
    return inequality(v[cells], tol[cells], strict=True,
                      detail=f"max Re λ(S(g)) at g ≡ 0 ({v[0]:.4g}), g ≡ 1 ({v[1]:.4g}), the fixed roles ({v[2]:.4g}) and "
                             f"{len(v) - 3} random g; checked: {which}; Bauer-Fike allowance up to {tol[cells].max():.2g}; "
                             f"most negative eigenvalues {d['S_min_real'].round(1).tolist()} (the stiffness the "
                             "integrator handles)")


@claims.claim("tran.rem43.necessary_condition", "Remark 4.3 (last paragraph)", "Ā or every Ā_i Hurwitz is necessary "
              "for S Hurwitz (refuted by one fixed two-node counterexample)", "qualitative", scope=PE)
def check_necessary_condition(res: Results) -> Verdict:
    """Remark 4.3 says Ā (or every Ā_i) Hurwitz is necessary for S Hurwitz. Counterexample: two scalar
    nodes, Ā = diag(0.5, −2), H = I, α = 1, path graph: S = [[−0.5, 1], [1, −3]] is Hurwitz."""
    Abar = np.diag([0.5, -2.0])
    S = Abar - np.array([[1.0, -1.0], [-1.0, 1.0]])
    ev = np.linalg.eigvals(S).real
    return Verdict(FAIL, measured=float(ev.max()), reference=float(np.linalg.eigvals(Abar).real.max()),
                   detail=f"counterexample: Ā_1 = 0.5 (unstable), S = Ā − α H (L ⊗ I) has eigenvalues {np.round(ev, 4).tolist()} "
                          "(Hurwitz). The statement is false in general; within the paper's design S is Hurwitz by "
                          "(54) anyway, so nothing else depends on it")


def vdot_check(res: Results, run: str, qmin_key: str, qnorm_key: str, label: str) -> Verdict:
    """2zᵀPż ≤ −λ_min(Q̄)‖z‖² + 2‖z‖‖P‖φ̄ at every sample, with a per-sample round-off allowance: the
    sum 2Σ(Pz)·ż of Nq products whose inputs are of size |Pz|·(|ż|-scale), plus λ_min(Q̄)'s own
    eigenvalue error Nq·eps·‖Q̄‖ times ‖z‖²."""
    d, sc = res.design, res.scenario
    qmin, qnorm = float(d[qmin_key]), float(d[qnorm_key])
    z, zdot, zscale = error_derivative(res, run)
    Pz = np.einsum("nij,tnj->tni", res.P, z)
    lhs = 2 * np.sum(Pz * zdot, axis=(1, 2))
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)
    rhs = -qmin * nz ** 2 + 2 * nz * float(d["lamP_max"]) * float(d["phibar"])
    ops = sc.N * sc.q
    tol = SAFETY * EPS * (2 * ops * np.sum(np.abs(Pz) * zscale, axis=(1, 2)) + ops * qnorm * nz ** 2)
    return inequality(lhs, rhs + tol, detail=f"2zᵀPż ≤ −λ_min(Q̄)‖z‖² + 2‖z‖‖P‖φ̄ at {len(z)} samples ({label}, "
                                             f"λ_min(Q̄) = {qmin:.4g}, φ̄ = {float(d['phibar']):.4g}); round-off allowance "
                                             f"per sample, largest {tol.max():.3g}")


def invariant_check(res: Results, run: str, mu_key: str) -> Verdict:
    """V(t) ≤ max(V(0), λ_max(P)μ²): V can grow only inside ‖z‖ ≤ μ, where V ≤ λ_max(P)μ². Allowance:
    the integration error δ of z (step halving) changes V by at most λ_max(P)(2‖z‖δ + δ²)."""
    d, z = res.design, res.errors(run)
    mu = float(d[mu_key])
    V = lyapunov_values(res, z)
    lmax = float(d["lamP_max"])
    level = max(V[0], lmax * mu ** 2)
    delta = _integration_allowance(res, run)
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)
    allow = lmax * (2 * nz * delta + delta ** 2) + SAFETY * z[0].size * EPS * lmax * nz ** 2
    return inequality(V, level + allow, detail=f"V(t) ≤ max(V(0), λ_max(P) μ²) = {level:.4g}; max V = {V.max():.4g}, "
                                               f"V(0) = {V[0]:.4g}; slack ratio {level / V.max():.3g}; integration "
                                               f"allowance (δ = {delta:.2g}) up to {allow.max():.3g}")


def ultimate_check(res: Results, run: str, qmin_key: str, mu_key: str, label: str) -> Verdict:
    """(18) 'for t ≥ T' in the explicit form the proof of Thm 2.1 gives: with s = (V/λ_max)^{1/2},
    ṡ ≤ −κ(s − μ) while s > μ (κ = λ_min(Q̄)/(2λ_max)), so
    ‖z(t)‖ ≤ (λ_max/λ_min)^{1/2} (μ + (s(0) − μ)⁺ e^{−κt}) for all t, which tends to (18)."""
    d, z, t = res.design, res.errors(run), res.runs[run]["t"]
    qmin, mu = float(d[qmin_key]), float(d[mu_key])
    lmax, lmin = float(d["lamP_max"]), float(d["lamP_min"])
    V0 = float(lyapunov_values(res, z[:1])[0])
    kappa = qmin / (2 * lmax)
    s0 = np.sqrt(V0 / lmax)
    bound18 = np.sqrt(lmax / lmin) * mu
    env = np.sqrt(lmax / lmin) * (mu + max(s0 - mu, 0.0) * np.exp(-kappa * t))
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)
    delta = _integration_allowance(res, run)
    allow = delta + SAFETY * z[0].size * EPS * nz
    T1 = float(np.log((s0 - mu) / (0.01 * mu)) / kappa) if s0 > 1.01 * mu else 0.0
    m = tail(res, run)
    ratio = bound18 / nz[m].max() if m.any() and nz[m].max() > 0 else float("inf")
    return inequality(nz, env + allow,
                      detail=f"‖z(t)‖ against (λ_max/λ_min)^{{1/2}}(μ + (s(0) − μ)⁺e^{{−κt}}) at {len(t)} samples ({label}); "
                             f"(18) = {bound18:.4g}, reached within 1% after T = {T1:.3g}; max ‖z‖ for t ≥ "
                             f"{res.scenario.simulation.tail_start:g} = {nz[m].max() if m.any() else float('nan'):.4g}, "
                             f"slack ratio (18)/max‖z‖ = {ratio:.3g}; integration allowance δ = {delta:.2g}")


claims.claim("tran.thm21.vdot", "Thm 2.1 proof", "V̇ ≤ −λ_min(Q̄)‖z‖² + 2‖z‖‖P‖φ̄ along solutions (fixed roles)",
             "inequality", hypotheses=(FIX, INP),
             args=("fixed", "fixed_qbar_min", "fixed_qbar_norm", "fixed roles, Q_i from (10)"))(vdot_check)
claims.claim("tran.thm21.bounded", "Thm 2.1", "solutions are uniformly bounded: V(t) ≤ max(V(0), λ_max(P)μ²)",
             "inequality", hypotheses=(FIX, INP, INT), args=("fixed", "fixed_mu"))(invariant_check)
claims.claim("tran.cor21.ultimate_bound", "Cor 2.1, (18)", "‖z(t)‖ ≤ sqrt(λ_max/λ_min) μ ultimately (fixed roles)",
             "inequality", hypotheses=(FIX, INP, INT),
             args=("fixed", "fixed_qbar_min", "fixed_mu", "fixed roles, Q̄ = Q + 2α(L⊗I)"))(ultimate_check)


# -- time-varying roles: Thm 3.1, Cor 3.1 ------------------------------------------------------

@claims.claim("tran.thm31.vertices", "Thm 3.1 proof", "S(g)ᵀP + PS(g) ≤ −Q̄_ε for all role vectors g", "inequality",
              hypotheses=(LMI,), requires=[(lambda res: np.isfinite(float(res.design["thm31_vertex_max"])),
                                            "the 2^N vertex enumeration is skipped for this many nodes in this mode; "
                                            "the per-node vertex check (tran.lemma31.vertex_lmis) covers it by block "
                                            "affinity")])
def check_thm31_vertices(res: Results) -> Verdict:
    v, tol = float(res.design["thm31_vertex_max"]), float(res.design["thm31_vertex_tol"])
    return inequality(np.array([v]), np.array([tol]),
                      detail=f"max over all 2^{res.scenario.N} role vertices of λ_max(S(g)ᵀP + PS(g) + Q̄_ε) = {v:.4g} "
                             f"(single ε = {res.design['eps_nodes'].min():g}) ≤ 0 up to the round-off allowance {tol:.2g} "
                             "(products of length Nq, H = P⁻¹ with condition κ(P))")


claims.claim("tran.thm31.vdot", "Thm 3.1 proof", "V̇ ≤ −ε‖z‖² + 2‖z‖‖P‖φ̄ along solutions (time-varying roles)",
             "inequality", hypotheses=(LMI, INP),
             args=("coest", "qbar_single", "qbar_single_norm", "time-varying roles, Q̄_ε with single ε"))(vdot_check)
claims.claim("tran.thm31.bounded", "Thm 3.1", "solutions of (33) are uniformly bounded", "inequality",
             hypotheses=(LMI, INP, INT), args=("coest", "mu_single"))(invariant_check)


@claims.claim("tran.cor31.ultimate_bound", "Cor 3.1, (18)", "‖z(t)‖ ≤ sqrt(λ_max/λ_min) μ ultimately (time-varying "
              "roles)", "inequality", hypotheses=(LMI, INP, INT))
def check_cor31(res: Results) -> Verdict:
    d = res.design
    v = ultimate_check(res, "coest", "qbar_single", "mu_single", "single ε = min ε_i, as Thm 3.1 states it")
    extra = (f" Other valid Q̄: per-node ε_i → {float(d['bound18_pernode']):.4g}; certified per-node margins → "
             f"{float(d['bound18_certified']):.4g}; vertex q* → {float(d['bound18_qstar']):.4g}; tight φ̄ (separate "
             f"w, ẇ bounds, {float(d['phibar_tight']):.4g} vs {float(d['phibar']):.4g}) → "
             f"{float(d['bound18_single_tight_phi']):.4g}.")
    return Verdict(**{**v.__dict__, "detail": v.detail + extra})


@claims.claim("tran.cor31.tight_bound", "project addition (from the proof of Thm 3.1)", "the vertex-q* version of (18) "
              "also holds", "inequality", hypotheses=(hy.H_QSTAR, INP, INT))
def check_cor31_tight(res: Results) -> Verdict:
    d = res.design
    return ultimate_check(res, "coest", "qstar", "mu_qstar",
                          f"tighter rigorous variant, q* = {float(d['qstar']):.4g} at g = {d['qstar_g'].tolist()}")


@claims.claim("tran.rem22.small_sigmaK", "Remark 2.2 / after Cor 3.1", "a smaller σ_iK_i reduces the bound (at fixed "
              "P)", "inequality", hypotheses=(LMI,))
def check_small_sigmaK(res: Results) -> Verdict:
    d, G = res.design, gains(res.scenario)
    scales = np.array([0.25, 0.5, 1.0, 2.0, 4.0])
    mus = []
    for s in scales:
        _, ph = lb.forcing_bound(G["sigma"] * s, G["K"], float(d["wbar"]), float(d["wbar"]))
        mus.append(lb.ultimate_bound(res.P, float(d["qbar_single"]), ph)[0])
    mus = np.array(mus)
    return inequality(mus[:-1], mus[1:], strict=True,
                      detail=f"μ at fixed P and Q̄_ε for σ_i scaled by {scales.tolist()}: {np.round(mus, 1).tolist()} "
                             "(increasing; if P is re-solved per σ the claim is not guaranteed)")


# -- stochastic: Prop 4.1, Rem 4.2 ----------------------------------------------------------

def one_sided_upper(mean: np.ndarray, sd: np.ndarray, bound: np.ndarray, R: int, what: str, *,
                    confidence: float | None = None) -> Verdict:
    """Test of H0: E X ≤ bound in every cell against E X > bound, failing only on evidence of a violation:
    one-sided Student t with R − 1 degrees of freedom, Bonferroni over the cells. Exact for normal
    samples; for the positively skewed samples here (V = zᵀPz given the role path is a noncentral quadratic
    form of a Gaussian vector; norms are bounded below by 0) a large mean comes with a large standard
    deviation, so its upper tail is lighter than Student's and the level is conservative; a sample
    dominated by a few large draws makes t ≈ 1, never a rejection. Needs ≥ MIN_TRIALS_ONE_SIDED trials."""
    from scipy.special import stdtrit   # Student's t quantile (scipy.stats.t.ppf's own), without scipy.stats

    conf = claim_confidence() if confidence is None else confidence
    if R < MIN_TRIALS_ONE_SIDED:
        return not_checkable(f"needs ≥ {MIN_TRIALS_ONE_SIDED} trials for the one-sided t test; ran {R}. {what}")
    if not (np.all(np.isfinite(mean)) and np.all(np.isfinite(sd)) and np.all(np.isfinite(bound))):
        return not_checkable(f"non-finite Monte Carlo values or bound (a diverging run). {what}")
    cells = mean.size
    crit = float(stdtrit(R - 1, 1 - (1 - conf) / cells))
    se = sd / np.sqrt(R)
    with np.errstate(divide="ignore", invalid="ignore"):
        tstat = np.where(se > 0, (mean - bound) / np.where(se > 0, se, 1.0), np.where(mean > bound, np.inf, -np.inf))
    k = int(np.argmax(tstat))
    lower = mean - crit * se
    ok = bool(np.all(tstat <= crit))
    ratio = np.min(bound / np.maximum(mean + crit * se, 1e-300))
    return Verdict(PASS if ok else FAIL, measured=float(lower.flat[k]), reference=float(bound.flat[k]), tolerance=crit,
                   margin=float(crit - tstat.flat[k]) if np.isfinite(tstat.flat[k]) else None, confidence=conf, trials=R,
                   detail=f"one-sided t test (R − 1 = {R - 1} dof, Bonferroni over {cells} cells, critical t {crit:.2f} for "
                          f"confidence {conf:.6g}): fails only if the lower confidence limit of the mean exceeds the bound; "
                          f"largest t = {tstat.flat[k]:.3g}; smallest slack ratio bound/upper limit {ratio:.3g}. {what}")


def _law_cells(res: Results, run: str, key: str):
    """p-values of the exact law of the simulated fixed-role error along the principal directions u_j (see
    law.fixed_law): y_k = u_jᵀz_k over the R trials are independent N(u_jᵀm_h, s_j²), m_h the
    noise-free run at the simulation's step and s_j² the variance of the simulated recursion, so
    Σ(y_k − ȳ)²/s_j² ~ χ²(R − 1) and (ȳ − u_jᵀm_h)/(s_j²/R)^{1/2} ~ N(0, 1), exactly at any R ≥ 2. The mean test
    allows the round-off of the simulation (steps·D·eps·cond(V)·|u|·max|z|: per-step rounding, at most cond(V)
    amplified by the stable recursion; subtracted from |ȳ − u_jᵀm_h| before the p-value); directions whose
    standard deviation is below 1e3 times that (where round-off could change a sum of squares by 0.2 %) are
    not tested. None when no direction qualifies. The Monte Carlo keeps ȳ and Σ(y_k − ȳ)² per cell, merged
    over the units of trials."""
    sc = res.scenario
    law, ex, r = res.design.law, res.runs["exact_fixed"], res.runs[run]
    if "proj_mean" not in r:
        return None
    sel = np.isin(law["probe_index"], r["probe_index"])
    dirs, var, mu = law["probe_dirs"][sel], law[f"sim_var_{key}"][sel], ex[f"mean_proj_{key}"][sel]
    ybar, ss = r["proj_mean"], r["proj_m2"]                        # (times, k)
    R = int(r["trials"])
    steps = int(round(float(r["t"][-1]) / sc.stochastic.step)) * (2 if key == "half" else 1)
    zmax = float(np.sqrt(float(r["V_max"]) / float(res.design["lamP_min"])))
    growth = float(res.design["S_fixed_cond"])      # ‖e^{St}‖ ≤ cond(V) for a stable, diagonalisable S
    rnd = SAFETY * steps * dirs.shape[-1] * EPS * growth * np.linalg.norm(dirs, axis=-1) * zmax     # (times, k)
    use = (var > 0) & (np.sqrt(var) > 1e3 * rnd)
    if not use.any():
        return None
    with np.errstate(divide="ignore", invalid="ignore"):
        zmean = np.maximum(np.abs(ybar - mu) - rnd, 0.0) / np.sqrt(var / R)
        chi = ss / var
    return normal_two_sided_p(zmean[use]), chi2_two_sided_p(chi[use], R - 1), R, int(use.sum())


def _deterministic_moments(res: Results) -> Verdict:
    """No noise: every trial is the noise-free run, so E{V} = V of that run, to the round-off of the
    recursion (steps·D·eps relative)."""
    ex, r = res.runs["exact_fixed"], res.runs["sde_fixed"]
    mean = r["V_mean"]
    EV = ex["EV"][:len(mean)]
    steps = int(round(float(r["t"][-1]) / res.scenario.stochastic.step))
    tol, sentence = roundoff_tolerance(scale=float(np.nanmax(np.abs(EV))) or 1.0, operations=steps * res.scenario.N *
                                       res.scenario.q, condition=float(res.design["S_fixed_cond"]))
    return inequality(np.abs(mean - EV), np.full_like(EV, tol),
                      detail=f"zero noise intensities: Monte Carlo E{{V}} equals the noise-free run's V; {sentence}")


@claims.claim("tran.prop41.exact_moments", "(45), (60), Remark 4.3", "the SDE simulation's error has the Gaussian law "
              "of (60) (fixed roles), at step h and h/2", "statistical", hypotheses=(hy.H_SFIX, hy.H_SDE, INT))
def check_exact_law(res: Results) -> Verdict:
    """The Monte Carlo of the fixed-role SDE (at h and h/2) against the exact law (45)/(60)."""
    law = res.design.law
    pvals, trials, detail = [], [], []
    for run, key in (("sde_fixed", "h"), ("sde_fixed_half", "half")):
        cells = _law_cells(res, run, key)
        if cells is None:
            detail.append(f"{run}: no direction with noise above round-off")
            continue
        pm, pc, R, k = cells
        pvals += [pm, pc]
        trials.append(R)
        detail.append(f"{run}: {k} (time, direction) cells, smallest p: mean {pm.min():.3g}, spread {pc.min():.3g}")
    if not pvals:
        if float(np.max(law["tr_PSigma"])) == 0.0:
            return _deterministic_moments(res)
        return not_checkable("the noise is below the simulation's round-off along every principal direction: "
                             + "; ".join(detail))
    frac = float(np.nanmin(np.sum(law["probe_var"], axis=1) / np.maximum(law["tr_PSigma"][law["probe_index"]], 1e-300)))
    return p_value_test(np.concatenate(pvals), trials=min(trials), min_trials=2,
                        detail=f"exact tests of the Monte Carlo against the Gaussian law of the simulated recursion "
                               f"(fixed roles), along the {law['probe_dirs'].shape[1]} principal directions of "
                               f"E{{zᵀPz}} under (60) (≥ {frac:.0%} of tr(PΣ)) at {len(law['probe_index'])} times: mean "
                               f"(normal) and spread (χ²(R − 1)), exact at any R ≥ 2; the recursion's law against "
                               f"(60) itself is {hy.H_SDE}. " + "; ".join(detail))


@claims.claim("tran.prop41.bound_fixed", "Prop 4.1, (46)", "E{zᵀPz} ≤ e^{−κt}V(0) + η/κ (fixed roles, exact moments)",
              "inequality", hypotheses=(FIX, INP, hy.H_NOISE, INT))
def check_prop41_fixed(res: Results) -> Verdict:
    """(46) against the exact E{V(t)} (fixed roles); allowance: the integration error δ of the noise-free
    part m(t) changes mᵀPm by at most λ_max(P)(2‖m‖δ + δ²)."""
    c = mean_square_constants(res.design, fixed=True)
    ex = res.runs["exact_fixed"]
    EV = ex["EV"]
    bound = lb.mean_square_bound(ex["t"], EV[0], c["kappa"], c["eta"])
    z = res.errors("fixed")
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)[:len(EV)]
    delta = _integration_allowance(res, "fixed")
    lmax = float(res.design["lamP_max"])
    allow = lmax * (2 * nz * delta + delta ** 2) + SAFETY * z[0].size * EPS * np.abs(EV)
    return inequality(EV, bound + allow,
                      detail=f"exact E{{V(t)}} (fixed roles) ≤ (46) with κ = {c['kappa']:.4g}, η = {c['eta']:.4g}, "
                             f"η/κ = {c['eta'] / c['kappa']:.4g}; slack ratio at the end {bound[-1] / EV[-1]:.3g}; "
                             f"integration allowance up to {allow.max():.2g}")


@claims.claim("tran.prop41.bound_roles", "Prop 4.1, Remark 4.1, (46)", "E{zᵀPz} ≤ e^{−κt}V(0) + η/κ (time-varying "
              "roles, Monte Carlo)", "statistical", hypotheses=(LMI, INP, hy.H_NOISE, hy.H_SDE))
def check_prop41_roles(res: Results) -> Verdict:
    """(46) for time-varying roles by Monte Carlo. The simulated process is the scheme's, not the SDE's: the
    bound is widened by the scheme's largest relative variance difference from the exact law, measured on the
    fixed-role law (hypotheses.sde_deviation)."""
    c = mean_square_constants(res.design, fixed=False)
    r = res.runs["sde_roles"]
    mean, sd, R = mc_moments(r, "V")
    dev = hy.sde_deviation(res.design)[0]
    bound = lb.mean_square_bound(r["t"], float(mean[0]), c["kappa"], c["eta"]) * (1 + dev)
    return one_sided_upper(mean, sd, bound, R,
                           f"E{{V(t)}} (time-varying roles, Monte Carlo) ≤ (46) at every recorded time, κ = "
                           f"{c['kappa']:.4g}, η/κ = {c['eta'] / c['kappa']:.4g}, r* = {c['r_star']:.4g}; bound × "
                           f"(1 + {dev:.3g}) for the scheme's discretisation of the noise")


@claims.claim("tran.rem42.limit52", "Remark 4.2, (52)", "limsup E‖z‖ ≤ (52)", "statistical",
              hypotheses=(LMI, INP, hy.H_NOISE, hy.H_SDE))
def check_limit52(res: Results) -> Verdict:
    """(52) as a bound at every time: by (46) and Jensen, E‖z(t)‖ ≤ ((e^{−κt}V(0) + η/κ)/λ_min(P))^{1/2},
    which tends to (52). Checked on the per-trial mean of ‖z‖ over the late window against the mean of
    that bound over the same window."""
    c = mean_square_constants(res.design, fixed=False)
    r = res.runs["sde_roles"]
    t = r["t"]
    late = t >= float(r["late_start"])
    lmin = float(res.design["lamP_min"])
    dev = hy.sde_deviation(res.design)[0]
    b_t = np.sqrt(lb.mean_square_bound(t[late], float(r["V_mean"][0]), c["kappa"], c["eta"]) * (1 + dev) / lmin)
    mean, sd, R = mc_moments(r, "late")
    return one_sided_upper(np.atleast_1d(mean), np.atleast_1d(sd), np.array([b_t.mean()]),
                           R, f"late-window mean of E‖z(t)‖ (t ≥ {t[late][0]:g}) ≤ the time-dependent form "
                              f"of (52), window mean {b_t.mean():.4g} (second moments widened by "
                              f"1 + {dev:.3g} for the scheme's discretisation); (52) = {c['limit52']:.4g}")


@claims.claim("tran.rem42.additional_term", "text after (52)", "the only additional term is 2λ_max(P)ψ̄²/(λ_min(P)"
              "λ_min(Q̄))", "identity")
def check_rem42_text(res: Results) -> Verdict:
    """The text after (52) names the additional term 2λ_max(P)ψ̄²/(λ_min(P)λ_min(Q̄)). The term (52) as
    displayed contains is (λ_max/λ_min)·2λ_max ψ̄²/λ_min(Q̄); derived from (46) it is η_noise/(κλ_min(P)),
    η_noise = λ_max(P)ψ̄² the noise part of η. Products and quotients of at most 8 factors: relative
    round-off ≤ 8·eps; compared at rtol 1e-12."""
    c = mean_square_constants(res.design, fixed=False)
    d = res.design
    lmax, lmin, qmin, psi = float(d["lamP_max"]), float(d["lamP_min"]), c["qmin"], c["psibar"]
    printed = 2 * lmax * psi ** 2 / (lmin * qmin)
    displayed = (lmax / lmin) * (2 * lmax * psi ** 2 / qmin)
    from_46 = lmax * psi ** 2 / (c["kappa"] * lmin)
    return erratum(printed, from_46, displayed, rtol=1e-12,
                   detail="reference: the term (52) as displayed contains beyond (λ_max/λ_min)μ²; correction: derived "
                          "from (46), η_noise/(κ λ_min(P)) (a λ_max(P) factor more than the text)")


@claims.claim("tran.ex52.noisier_velocity", "Sec. 5.2", "estimates of states 2 and 4 are noisier than of states 1 and "
              "3", "inequality", scope=PE, requires=[(lambda res: res.runs["sde_roles"]["kept_e"].size > 0, "no stored runs")])
def check_noisier_velocity(res: Results) -> Verdict:
    r = res.runs["sde_roles"]
    n = res.scenario.n
    z = r["kept_x"][:, :, None, :] - r["kept_e"][..., :n]          # (runs, T, N, n)
    rough = np.sqrt(np.mean(np.diff(z, axis=1) ** 2, axis=(0, 1, 2)))  # RMS increment per state
    pos, vel = rough[[0, 2]], rough[[1, 3]]
    return inequality(pos, vel, strict=True,
                      detail=f"RMS one-sample increment of x̃ per state over {z.shape[0]} runs and all nodes: "
                             f"{np.round(rough, 5).tolist()} (states 2, 4 ≥ states 1, 3)")


# -- comparison, reference, numerics ----------------------------------------------------------

@claims.claim("tran.rem31.comparison", "Remarks 2.1, 3.1; Figs. 3-8", "coestimation estimates x and w better than the "
              "estimation architecture (36)-(37) on the example", "qualitative", scope=PE,
              requires=[(lambda res: "comparison" in res.runs, "the comparison LMIs (38)-(39) have no solution at the "
                                                               "scenario's comparison_sigma")])
def check_comparison(res: Results) -> Verdict:
    sc, m = res.scenario, tail(res, "coest")
    co = rms(res.errors("coest")[m], sc.n)
    cp = rms(res.errors("comparison")[m], sc.n)
    return inequality(np.array(co), np.array(cp), strict=True,
                      detail=f"tail RMS (t ≥ {sc.simulation.tail_start:g}) of (‖x̃‖, ‖w̃‖) over nodes: coestimation "
                             f"{np.round(co, 4).tolist()} vs estimation architecture (36)-(37) {np.round(cp, 4).tolist()} "
                             f"(γ = {sc.comparison.gamma:g}, σ_b = {[t.comparison_sigma for t in sc.types]})")


@claims.claim("tran.sec34.comparison_lmi_infeasible", "(38)-(39)", "with the example's gains the comparison LMIs "
              "(38)-(39) are infeasible", "inequality", scope=PE)
def check_comparison_infeasible(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    status, margin = d["comp_status"], d["comp_margin"]
    detail = (f"(38)-(39) with the coestimation gains (σ_i = {[t.sigma for t in sc.types]}): Clarabel status "
              f"{status.tolist()}, max-margin t* (P ⪰ {sc.comparison.P_lower:g} I, tr P ≤ 1e4) = {margin.tolist()}; "
              f"smallest feasible σ by bisection {d['comp_sigma_min'].tolist()}; reconstructed σ_b = "
              f"{[t.comparison_sigma for t in sc.types]}: status {d['comp_status_b'].tolist()}, "
              f"t* = {d['comp_margin_b'].tolist()}")
    infeasible = bool(np.all(margin < 0))
    statuses = set(status.tolist())
    consistent = statuses <= {"infeasible", "infeasible_inaccurate"} or any(s.startswith("solver_error") for s in statuses)
    return Verdict(PASS if infeasible and consistent else FAIL, measured=margin.tolist(), reference=0.0,
                   margin=float(-margin.max()), detail=detail)


@claims.claim("tran.ex51.comparison_reconstructed", "(38)-(39), our reconstruction", "the reconstructed comparison "
              "gains satisfy (38)-(39)", "inequality", scope=PE)
def check_comparison_reconstructed(res: Results) -> Verdict:
    d = res.design
    m = d["comp_margin_b"]
    return inequality(np.zeros_like(m), m, detail=f"(38)-(39) margins at the reconstructed σ_b with the P used in the "
                                                  f"comparison run; statuses {d['comp_status_b'].tolist()}")


@claims.claim("tran.ref.central_kf", "project addition", "the centralized Kalman filter (all active sensors) is at least "
              "as accurate as coestimation on the example", "inequality", scope=PE)
def check_central(res: Results) -> Verdict:
    sc, c, r, n = res.scenario, res.runs["central"], res.runs["coest"], res.scenario.n
    stride = int(round(sc.reference.dt / sc.simulation.record_dt))
    mt = (r["t"] >= sc.simulation.tail_start)[::stride]
    truth = np.concatenate([r["x"][::stride], r["w"][::stride]], axis=1)[mt]
    kf, co = rms(c["det_s"][mt] - truth, n), rms(res.errors("coest")[tail(res, "coest")], n)
    extra = f"; with all {sc.N} sensors always on: {np.round(rms(c['det_all_s'][mt] - truth, n), 5).tolist()}" \
        if "det_all_s" in c else ""
    if "sde_s" in c:
        s = res.runs["sde_roles"]
        ms = (s["t"] >= min(sc.simulation.tail_start, s["t"][-1] / 2))
        e_kf = c["sde_s"] - np.concatenate([s["kept_x"][0], s["w"]], axis=1)[::stride]
        zs = np.concatenate([s["kept_x"][0][:, None, :] - s["kept_e"][0][..., :n],
                             s["kept_e"][0][..., n:] - s["w"][:, None, :]], axis=-1)[ms]
        extra += (f"; stochastic run 0: KF {np.round(rms(e_kf[ms[::stride]], n), 4).tolist()} vs coestimation "
                  f"{np.round(rms(zs, n), 4).tolist()} (not checked: one run)")
    return inequality(np.array(kf), np.array(co),
                      detail=f"centralized filterpy KF on (x, w) with the active sensors (R = {sc.reference.r_deterministic:g} "
                             f"I, q_w = {sc.reference.q_w:g}): tail RMS {np.round(kf, 5).tolist()} vs coestimation "
                             f"{np.round(co, 4).tolist()} (a project addition: the centralized filter is the floor)" + extra)


@claims.claim("tran.num.step_halving", "project (integrator)", "the example's deterministic results do not depend on "
              "the step", "inequality", scope=PE)
def check_step_halving(res: Results) -> Verdict:
    h = hy.integration(res.design)
    est, scale = (res.design.integration["coest"][k] for k in ("error", "scale"))
    return inequality(np.array([est]), np.array([hy.STEP_RTOL * scale]),
                      detail=f"ETD2RK at h = {res.scenario.simulation.step:g} vs h/2, error estimate 2·max|Δ(x̂, ŵ)| "
                             f"(first-order Richardson, conservative) ≤ {hy.STEP_RTOL:g} × the trajectories' size "
                             f"{scale:.3g}. " + h.detail)


@claims.claim("tran.ref.regression_values", "our reconstruction", "bounds and constants match our reconstruction's "
              "regression values", "identity", scope=PE)
def check_reference_values(res: Results) -> Verdict:
    d = res.design
    keys = [k for k in REFERENCE if np.isfinite(float(d[k]))]
    got = np.array([float(d[k]) for k in keys])
    ref = np.array([REFERENCE[k] for k in keys])
    return identity(got, ref, rtol=2e-3, detail=f"regression values of our reconstruction (4 significant digits) "
                                                f"{dict(zip(keys, ref.tolist()))}")


claims.unchecked("tran.intro.motivation", "Sec. 1", "motivational and comparative statements", "qualitative",
                 scope=PE, reason="motivational statements (Bayesian vs system-theoretic approaches, ease of tuning, "
                 "the literature review) are not numerical claims")
