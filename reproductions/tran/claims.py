"""The claim catalogue of the coestimation paper (spec §4, C1-C12, plus the comparison and
numerical checks). Ids follow `tran.<where>.<what>`. Bounds that hold with a huge slack pass
and report the slack ratio: slack is a finding, not a failure (spec P5)."""
from __future__ import annotations

import numpy as np

import estimators.input_state_coestimation as ce
import estimators.lyapunov_bounds as lb
from pipeline.stats import z_for_confidence
from pipeline.verify import (FAIL, PASS, Claim, Verdict, erratum, identity, inequality, not_checkable,
                             statistical)

from .compute import Results, coestimation, gains

CONFIDENCE = 0.999
STEP_TOL = 2e-3          # stated tolerance of the deterministic integration (absolute, on x̂, ŵ)
REFERENCE = {            # spec §6 regression values (paper scenario only)
    "bound18_single": 1.796e9, "bound18_pernode": 3.557e7, "bound18_certified": 2.686e6, "phibar": 15.4672,
    "phibar_tight": 4.4625, "lamP_min": 0.05280, "lamP_max": 5.62512, "qstar": 1.8196e-3, "bound18_qstar": 9.871e5,
}


# -- helpers ----------------------------------------------------------------------------------

def errors(res: Results, run: str) -> np.ndarray:
    r = res.runs[run]
    return ce.errors_from_estimates(r["x"], r["w"], r["e"], res.scenario.n)


def lyapunov_values(res: Results, z: np.ndarray) -> np.ndarray:
    return np.einsum("tni,nij,tnj->t", z, res.P, z)


def error_derivative(res: Results, run: str) -> tuple[np.ndarray, np.ndarray]:
    """ż from the error system (26)/(33) along a run: (z, ż), both (T, N, q)."""
    sc, G = res.scenario, gains(res.scenario)
    r = res.runs[run]
    z = errors(res, run)
    n = sc.n
    sig = res.signal()
    Ab0 = np.stack([ce.error_matrix(sc.A, sc.B, G["C"][i], G["L"][i], G["J"][i], G["sigma"][i], G["K"][i], 0.0)
                    for i in range(sc.N)])
    Ab1 = np.stack([ce.error_matrix(sc.A, sc.B, G["C"][i], G["L"][i], G["J"][i], G["sigma"][i], G["K"][i], 1.0)
                    for i in range(sc.N)])
    g = r["g"]
    local = np.einsum("inm,tim->tin", Ab0, z) + g[..., None] * np.einsum("inm,tim->tin", Ab1 - Ab0, z)
    H = np.linalg.inv(res.P)
    coup = -sc.alpha * np.einsum("ij,iab,tjb->tia", sc.lap, H, z)
    phi = np.zeros_like(z)
    phi[..., n:] = ce.input_forcing(G["K"], G["sigma"], r["w"], sig.rate(r["t"]))
    return z, local + coup + phi


def tail(res: Results, run: str) -> np.ndarray:
    return res.runs[run]["t"] >= res.scenario.tail_start


def rms(z: np.ndarray, n: int) -> tuple[float, float]:
    return (float(np.sqrt(np.mean(np.sum(z[..., :n] ** 2, -1)))), float(np.sqrt(np.mean(np.sum(z[..., n:] ** 2, -1)))))


def _paper_only(res: Results) -> Verdict | None:
    return None if res.scenario.name == "paper" else not_checkable("reference numbers exist for the paper's example only")


# -- model facts ----------------------------------------------------------------------------

def check_observability(res: Results) -> Verdict:
    d, n = res.design, res.scenario.n
    local, coll = d["rank_obsv_local"], int(d["rank_obsv_collective"])
    detail = (f"rank obsv(A, C_i) per node type = {local.tolist()}, collective rank = {coll} (n = {n}); augmented "
              f"([[A, B], [0, 0]], [C_i, 0]) ranks = {d['rank_obsv_augmented'].tolist()} of {n + res.scenario.p}: "
              "velocity-only nodes cannot see the input's DC part alone (spec §6.1)")
    ok = bool(np.all(local == n)) and coll == n
    return Verdict(PASS if ok else FAIL, measured=local.tolist() + [coll], reference=n, detail=detail)


def check_footnote3(res: Results) -> Verdict:
    v = res.design["fn3_max_real"]
    return inequality(v, np.zeros_like(v), strict=True,
                      detail="max Re λ(Ā_i(1)) with L_i = J_i = 0 per node type (block triangular: eig(A) ∪ eig(−σK))")


def check_error_dynamics(res: Results) -> Verdict:
    """The estimate form (22)-(23) and the error form (26) give the same ż (machine precision)."""
    sc = res.scenario
    r = res.runs["coest"]
    net = coestimation(sc, res.P)
    sig = res.signal()
    z, zdot = error_derivative(res, "coest")
    idx = np.linspace(0, len(r["t"]) - 1, 200).astype(int)
    errs, scale = [], []
    for k in idx:
        x, e, g, t = r["x"][k], r["e"][k], r["g"][k], r["t"][k]
        xdot = sc.A @ x + sc.B @ r["w"][k]
        edot = net.estimate_rhs(x, e, g, r["w"][k])
        zd = np.concatenate([xdot[None] - edot[:, :sc.n], edot[:, sc.n:] - sig.rate(t)[None]], axis=1)
        errs.append(np.abs(zd - zdot[k]).max())
        scale.append(np.abs(zdot[k]).max())
    rel = np.array(errs) / np.maximum(np.array(scale), 1e-300)
    return identity(rel, np.zeros_like(rel), rtol=0, atol=1e-11,
                    detail=f"max |ż_estimate-form − ż_(26)| / max|ż| over {len(idx)} samples of the Ex. 5.1 run "
                           "(signs −M, +S, +T, −N of (3)-(4) against (9))")


# -- LMIs -----------------------------------------------------------------------------------

def check_printed_P(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    if "P_given" not in d:
        return not_checkable("the scenario gives no P_i")
    sweep = d["given_sweep"]
    eps = np.array([t.eps for t in sc.types])
    vert = sweep[:, [0, -1]]
    v = inequality(vert, -eps[:, None] * np.ones_like(vert),
                   detail=f"max eig(Ā_i(g)ᵀP_i + P_iĀ_i(g)) at g = 0, 1 per type: {vert.tolist()}; required ≤ −ε_i = "
                          f"{(-eps).tolist()}; relative margins {((-vert.max(1) - eps) / eps).round(3).tolist()}")
    return v


def check_lemma31(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    if "P_given" not in d:
        return not_checkable("the scenario gives no P_i")
    sweep, hur = d["given_sweep"], d["given_hurwitz"]
    eps = np.array([t.eps for t in sc.types])
    bound = np.minimum(-eps[:, None] * np.ones_like(sweep), 0)
    v = inequality(np.concatenate([sweep.ravel(), hur.ravel()]), np.concatenate([bound.ravel(), np.zeros(hur.size)]),
                   strict=False,
                   detail=f"(30) on g ∈ linspace(0, 1, {sweep.shape[1]}) for each node type, and Ā_i(g) Hurwitz "
                          f"(max Re λ = {hur.max():.4g})")
    return v


def check_lmi_feasible(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    status, margin, ver = d["lmi_status"], d["lmi_margin"], d["lmi_verified"]
    ok = bool(np.all(margin > 0)) and bool(np.all(np.abs(ver + margin) <= 1e-6 + 1e-3 * np.abs(margin)))
    detail = (f"cvxpy/Clarabel: feasibility (ε_i = {[t.eps for t in sc.types]}) status {status.tolist()}; normalised "
              f"margin t* (tr P = n + p) {margin.tolist()}, re-verified max eig at P*: {ver.tolist()}")
    if "P_lmi_fallback" in d and np.any(d["P_lmi_fallback"]):
        detail += f"; no valid P for types {np.flatnonzero(d['P_lmi_fallback']).tolist()}: the runs used P = I there"
    return Verdict(PASS if ok else FAIL, measured=margin.tolist(), reference=0.0, margin=float(margin.min()),
                   detail=detail)


def check_comparison_infeasible(res: Results) -> Verdict:
    d, sc = res.design, res.scenario
    status, margin = d["comp_status"], d["comp_margin"]
    detail = (f"(38)-(39) with the coestimation gains (σ_i = {[t.sigma for t in sc.types]}): Clarabel status "
              f"{status.tolist()}, max-margin t* (P ⪰ {sc.comparison_P_lower:g} I, tr P ≤ 1e4) = {margin.tolist()}; "
              f"smallest feasible σ by bisection {d['comp_sigma_min'].tolist()} (spec: 0.296, 0.161); "
              f"reconstructed σ_b = {[t.comparison_sigma for t in sc.types]}: status {d['comp_status_b'].tolist()}, "
              f"t* = {d['comp_margin_b'].tolist()}")
    infeasible = bool(np.all(margin < 0))
    statuses = set(status.tolist())
    consistent = statuses <= {"infeasible", "infeasible_inaccurate"} or any(s.startswith("solver_error") for s in statuses)
    if sc.name != "paper":
        return Verdict(PASS, measured=margin.tolist(), reference=0.0, margin=float(-margin.max()),
                       detail="(informational for user scenarios) " + detail)
    ok = infeasible and consistent
    return Verdict(PASS if ok else FAIL, measured=margin.tolist(), reference=0.0, margin=float(-margin.max()),
                   detail=detail)


def check_comparison_reconstructed(res: Results) -> Verdict:
    d = res.design
    m = d["comp_margin_b"]
    return inequality(np.zeros_like(m), m, detail=f"(38)-(39) margins at the reconstructed σ_b with the P used in the "
                                                  f"comparison run; statuses {d['comp_status_b'].tolist()}")


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

def check_identity54(res: Results) -> Verdict:
    d = res.design
    rel = float(d["identity54_residual"] / d["identity54_scale"])
    return identity(np.array([rel]), np.array([0.0]), rtol=0, atol=1e-12,
                    detail=f"max |SᵀP + PS + Q̄| / max|Q̄| (fixed roles {list(res.scenario.fixed_active)}); "
                           f"min eig Q_i = {np.round(d['fixed_Qi_min'], 6).tolist()}, λ_min(Q̄) = {float(d['fixed_qbar_min']):.4g}")


def check_S_hurwitz(res: Results) -> Verdict:
    d = res.design
    v = d["S_max_real"]
    return inequality(v, np.zeros_like(v), strict=True,
                      detail=f"max Re λ(S(g)) at g ≡ 0 ({v[0]:.4g}), g ≡ 1 ({v[1]:.4g}), the fixed roles ({v[2]:.4g}) and "
                             f"{len(v) - 3} random g; most negative eigenvalues {d['S_min_real'].round(1).tolist()} "
                             "(the stiffness the integrator must handle)")


def _vdot_check(res: Results, run: str, qmin: float, label: str) -> Verdict:
    d = res.design
    z, zdot = error_derivative(res, run)
    Pz = np.einsum("nij,tnj->tni", res.P, z)
    lhs = 2 * np.sum(Pz * zdot, axis=(1, 2))
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)
    rhs = -qmin * nz ** 2 + 2 * nz * float(d["lamP_max"]) * float(d["phibar"])
    tol = 1e-9 * np.maximum(np.abs(lhs), 1.0)
    return inequality(lhs, rhs + tol, detail=f"2zᵀPż ≤ −λ_min(Q̄)‖z‖² + 2‖z‖‖P‖φ̄ at {len(z)} samples ({label}, "
                                               f"λ_min(Q̄) = {qmin:.4g}, φ̄ = {float(d['phibar']):.4g})")


def _invariant_check(res: Results, run: str, mu: float) -> Verdict:
    d = res.design
    V = lyapunov_values(res, errors(res, run))
    level = max(V[0], float(d["lamP_max"]) * mu ** 2)
    v = inequality(V, np.full_like(V, level), detail=f"V(t) ≤ max(V(0), λ_max(P) μ²) = {level:.4g}; max V = {V.max():.4g}, "
                                                    f"V(0) = {V[0]:.4g}; slack ratio {level / V.max():.3g}")
    return v


def _ultimate(res: Results, run: str, bound: float, label: str) -> Verdict:
    z = errors(res, run)
    nz = np.linalg.norm(z.reshape(len(z), -1), axis=1)[tail(res, run)]
    v = inequality(nz, np.full_like(nz, bound),
                   detail=f"max ‖z(t)‖ for t ≥ {res.scenario.tail_start:g} = {nz.max():.4g} against (18) = {bound:.4g} "
                          f"({label}); slack ratio bound/max‖z‖ = {bound / nz.max():.3g}")
    return v


def check_thm21_vdot(res):
    return _vdot_check(res, "fixed", float(res.design["fixed_qbar_min"]), "fixed roles, Q_i from (10)")


def check_thm21_invariant(res):
    return _invariant_check(res, "fixed", float(res.design["fixed_mu"]))


def check_cor21(res):
    return _ultimate(res, "fixed", float(res.design["fixed_bound18"]), "fixed roles, Q̄ = Q + 2α(L⊗I)")


# -- time-varying roles: Thm 3.1, Cor 3.1 ------------------------------------------------------

def check_thm31_vertices(res: Results) -> Verdict:
    v = float(res.design["thm31_vertex_max"])
    if not np.isfinite(v):
        return not_checkable("the 2^N vertex enumeration is skipped (N too large, or quick mode); the per-node vertex "
                             "check (tran.lemma31.vertex_lmis) covers it by block affinity")
    return inequality(np.array([v]), np.array([0.0]),
                      detail=f"max over all 2^{res.scenario.N} role vertices of λ_max(S(g)ᵀP + PS(g) + Q̄_ε) = {v:.4g} "
                             f"(single ε = {res.design['eps_nodes'].min():g})")


def check_thm31_vdot(res):
    return _vdot_check(res, "coest", float(res.design["qbar_single"]), "time-varying roles, Q̄_ε with single ε")


def check_thm31_invariant(res):
    return _invariant_check(res, "coest", float(res.design["mu_single"]))


def check_cor31(res: Results) -> Verdict:
    d = res.design
    v = _ultimate(res, "coest", float(d["bound18_single"]), "paper-faithful: single ε = min ε_i")
    extra = (f" Other valid Q̄: per-node ε_i → {float(d['bound18_pernode']):.4g}; certified per-node margins → "
             f"{float(d['bound18_certified']):.4g}; vertex q* → {float(d['bound18_qstar']):.4g}; tight φ̄ (separate "
             f"w, ẇ bounds, {float(d['phibar_tight']):.4g} vs {float(d['phibar']):.4g}) → "
             f"{float(d['bound18_single_tight_phi']):.4g}.")
    return Verdict(v.status, v.measured, v.reference, v.tolerance, v.margin, detail=v.detail + extra)


def check_cor31_tight(res: Results) -> Verdict:
    d = res.design
    if not np.isfinite(float(d["qstar"])):
        return not_checkable("vertex enumeration skipped (N too large or quick mode)")
    return _ultimate(res, "coest", float(d["bound18_qstar"]),
                     f"project's tighter rigorous variant, q* = {float(d['qstar']):.4g} at g = {d['qstar_g'].tolist()}")


def check_reference_values(res: Results) -> Verdict:
    skip = _paper_only(res)
    if skip:
        return skip
    d = res.design
    keys = [k for k in REFERENCE if np.isfinite(float(d[k]))]
    got = np.array([float(d[k]) for k in keys])
    ref = np.array([REFERENCE[k] for k in keys])
    return identity(got, ref, rtol=2e-3, detail=f"spec §6 values {dict(zip(keys, ref.tolist()))}")


# -- stochastic: Prop 4.1, Rem 4.2 ----------------------------------------------------------

def _sde_constants(res: Results, fixed: bool) -> dict:
    d, sc = res.design, res.scenario
    ex = res.runs["exact_fixed"]
    qmin = float(d["fixed_qbar_min"]) if fixed else float(d["qbar_single"])
    c = lb.mean_square_constants(res.P, qmin, float(d["phibar"]), float(ex["v_star"]), float(ex["r_star"]), sc.N)
    return {**c, "qmin": qmin}


def _mc_V(res: Results, run: str):
    V = res.runs[run]["red_V"]
    return V.mean(1), V.std(1, ddof=1) / np.sqrt(V.shape[1]), V.shape[1]


def check_moments(res: Results, run: str) -> Verdict:
    """Monte Carlo mean of V against the exact moment solution (fixed roles) at 1-s spaced times."""
    ex = res.runs["exact_fixed"]
    r = res.runs[run]
    mean, se, R = _mc_V(res, run)
    t = r["t"]
    stride = max(1, int(round(1.0 / (t[1] - t[0]))))
    idx = np.arange(stride, len(t), stride)
    ref = ex["EV"][idx]  # same record grid (record_dt), from t = 0
    return statistical(mean[idx], se[idx], ref, confidence=CONFIDENCE, trials=R,
                       detail=f"E{{zᵀPz}} by Monte Carlo vs m(t)ᵀPm(t) + tr(PΣ(t)) (exact, (60) with dimensions fixed) "
                              f"at {len(idx)} times")


def check_prop41_fixed(res: Results) -> Verdict:
    c = _sde_constants(res, fixed=True)
    ex = res.runs["exact_fixed"]
    EV = ex["EV"]
    bound = lb.mean_square_bound(ex["t"], EV[0], c["kappa"], c["eta"])
    v = inequality(EV, bound, detail=f"exact E{{V(t)}} (fixed roles) ≤ (46) with κ = {c['kappa']:.4g}, η = {c['eta']:.4g}, "
                                     f"η/κ = {c['eta'] / c['kappa']:.4g}; slack ratio at the end {bound[-1] / EV[-1]:.3g}")
    return v


def check_prop41_roles(res: Results) -> Verdict:
    c = _sde_constants(res, fixed=False)
    r = res.runs["sde_roles"]
    mean, se, R = _mc_V(res, "sde_roles")
    z = z_for_confidence(CONFIDENCE)
    upper = mean + z * se
    bound = lb.mean_square_bound(r["t"], mean[0], c["kappa"], c["eta"])
    v = inequality(upper, bound, detail=f"Monte Carlo upper {CONFIDENCE:.1%} limit of E{{V(t)}} ({R} trials, time-varying "
                                        f"roles, Ex. 5.2) ≤ (46), κ = {c['kappa']:.4g}, η/κ = {c['eta'] / c['kappa']:.4g}; "
                                        f"slack ratio min {np.min(bound / upper):.3g}")
    return Verdict(v.status, v.measured, v.reference, v.tolerance, v.margin, confidence=CONFIDENCE, trials=R, detail=v.detail)


def check_limit52(res: Results) -> Verdict:
    c = _sde_constants(res, fixed=False)
    r = res.runs["sde_roles"]
    late = r["t"] >= min(res.scenario.tail_start, r["t"][-1] / 2)
    zn = r["red_znorm"][late]
    R = zn.shape[1]
    per_trial = zn.mean(0)
    upper = per_trial.mean() + z_for_confidence(CONFIDENCE) * per_trial.std(ddof=1) / np.sqrt(R)
    v = inequality(np.array([upper]), np.array([c["limit52"]]),
                   detail=f"late-window mean E‖z‖ (upper {CONFIDENCE:.1%} limit over {R} trials) {upper:.4g} ≤ (52) = "
                          f"{c['limit52']:.4g}; slack ratio {c['limit52'] / upper:.3g}")
    return Verdict(v.status, v.measured, v.reference, v.tolerance, v.margin, confidence=CONFIDENCE, trials=R, detail=v.detail)


def check_rem42_text(res: Results) -> Verdict:
    """The text after (52) names the additional term 2λ_max(P)ψ̄²/(λ_min(P)λ_min(Q̄)); expanding (46)
    gives 2λ_max(P)²ψ̄²/(λ_min(P)λ_min(Q̄)) (spec T12)."""
    c = _sde_constants(res, fixed=False)
    d = res.design
    lmax, lmin, qmin = float(d["lamP_max"]), float(d["lamP_min"]), c["qmin"]
    printed = 2 * lmax * c["psibar"] ** 2 / (lmin * qmin)
    corrected = 2 * lmax ** 2 * c["psibar"] ** 2 / (lmin * qmin)
    mu = float(d["mu_single"])
    reference = c["limit52"] ** 2 - lmax / lmin * mu ** 2   # (52)² minus the deterministic part (18)²
    return erratum(printed, corrected, reference, rtol=1e-8,
                   detail="reference = (52)² − (λ_max/λ_min)μ², the additional term (52) actually contains")


def check_noisier_velocity(res: Results) -> Verdict:
    r = res.runs["sde_roles"]
    if r["kept_e"].size == 0:
        return not_checkable("no stored runs")
    n = res.scenario.n
    if n != 4:
        return not_checkable("stated for the example's 4-state process")
    z = r["kept_x"][:, :, None, :] - r["kept_e"][..., :n]          # (runs, T, N, n)
    rough = np.sqrt(np.mean(np.diff(z, axis=1) ** 2, axis=(0, 1, 2)))  # RMS increment per state
    pos, vel = rough[[0, 2]], rough[[1, 3]]
    return inequality(pos, vel, strict=True,
                      detail=f"RMS one-sample increment of x̃ per state over {z.shape[0]} runs and all nodes: "
                             f"{np.round(rough, 5).tolist()} (states 2, 4 ≥ states 1, 3)")


# -- comparison, reference, numerics ----------------------------------------------------------

def check_comparison(res: Results) -> Verdict:
    if "comparison" not in res.runs:
        return not_checkable("the comparison LMIs (38)-(39) have no solution at the scenario's comparison_sigma")
    n = res.scenario.n
    m = tail(res, "coest")
    co = rms(errors(res, "coest")[m], n)
    cp = rms(errors(res, "comparison")[m], n)
    v = inequality(np.array(co), np.array(cp), strict=True,
                   detail=f"tail RMS (t ≥ {res.scenario.tail_start:g}) of (‖x̃‖, ‖w̃‖) over nodes: coestimation "
                          f"{np.round(co, 4).tolist()} vs estimation architecture (36)-(37) {np.round(cp, 4).tolist()} "
                          f"(γ = {res.scenario.gamma:g}, σ_b = {[t.comparison_sigma for t in res.scenario.types]}; spec: "
                          "0.20/0.78 vs 0.74/1.67)")
    return v


def check_central(res: Results) -> Verdict:
    c, r = res.runs["central"], res.runs["coest"]
    stride = int(round(res.scenario.kf_dt / res.scenario.record_dt))
    n = res.scenario.n
    mt = (r["t"] >= res.scenario.tail_start)[::stride]
    err = c["det_s"][mt] - np.concatenate([r["x"][::stride], r["w"][::stride]], axis=1)[mt]
    kf = (float(np.sqrt(np.mean(np.sum(err[:, :n] ** 2, 1)))), float(np.sqrt(np.mean(np.sum(err[:, n:] ** 2, 1)))))
    co = rms(errors(res, "coest")[tail(res, "coest")], n)
    extra = ""
    if "det_all_s" in c:
        e_all = c["det_all_s"][mt] - np.concatenate([r["x"][::stride], r["w"][::stride]], axis=1)[mt]
        extra += (f"; with all 12 sensors always on: {np.round([np.sqrt(np.mean(np.sum(e_all[:, :n] ** 2, 1))), np.sqrt(np.mean(np.sum(e_all[:, n:] ** 2, 1)))], 5).tolist()}")
    if "sde_s" in c:
        s = res.runs["sde_roles"]
        ms = (s["t"] >= min(res.scenario.tail_start, s["t"][-1] / 2))
        truth = np.concatenate([s["kept_x"][0], s["w"]], axis=1)
        e_kf = c["sde_s"] - truth[::stride]
        mk = ms[::stride]
        zs = np.concatenate([s["kept_x"][0][:, None, :] - s["kept_e"][0][..., :n],
                             s["kept_e"][0][..., n:] - s["w"][:, None, :]], axis=-1)[ms]
        extra += (f"; Ex. 5.2 run 0: KF {np.round([np.sqrt(np.mean(np.sum(e_kf[mk, :n] ** 2, 1))), np.sqrt(np.mean(np.sum(e_kf[mk, n:] ** 2, 1)))], 4).tolist()}"
                  f" vs coestimation {np.round(rms(zs, n), 4).tolist()} (not checked: one run)")
    return inequality(np.array(kf), np.array(co),
                      detail=f"centralized filterpy KF on (x, w) with the active sensors (R = {res.scenario.kf_r:g} I, "
                             f"q_w = {res.scenario.kf_q_w:g}): tail RMS {np.round(kf, 5).tolist()} vs coestimation "
                             f"{np.round(co, 4).tolist()} (a project addition: the centralized filter is the floor)" + extra)


def check_step_halving(res: Results) -> Verdict:
    a, b = res.runs["coest"], res.runs["coest_half"]
    diff = float(np.abs(a["e"] - b["e"]).max())
    est = 4.0 / 3.0 * diff
    return inequality(np.array([est]), np.array([STEP_TOL]),
                      detail=f"ETD2RK at h = {res.scenario.step:g} vs h/2: max |Δ(x̂, ŵ)| = {diff:.3g}; Richardson "
                             f"error estimate of the h run 4/3·Δ = {est:.3g} ≤ stated tolerance {STEP_TOL:g}")


def check_sde_step(res: Results) -> Verdict:
    v1, v2 = check_moments(res, "sde_fixed"), check_moments(res, "sde_fixed_half")
    worst = v1 if (v1.margin or 0) < (v2.margin or 0) else v2
    status = PASS if v1.status == PASS and v2.status == PASS else FAIL
    return Verdict(status, worst.measured, worst.reference, worst.tolerance, worst.margin, CONFIDENCE, worst.trials,
                   detail=f"step h = {res.scenario.sde_step:g}: {v1.detail} | step h/2: {v2.detail}")


def check_necessary_condition(res: Results) -> Verdict:
    """Remark 4.3 says Ā (or every Ā_i) Hurwitz is necessary for S Hurwitz. Counterexample: two scalar
    nodes, Ā = diag(0.5, −2), H = I, α = 1, path graph: S = [[−0.5, 1], [1, −3]] is Hurwitz."""
    Abar = np.diag([0.5, -2.0])
    S = Abar - np.array([[1.0, -1.0], [-1.0, 1.0]])
    ev = np.linalg.eigvals(S).real
    return Verdict(FAIL, measured=float(ev.max()), reference=float(np.linalg.eigvals(Abar).real.max()),
                   detail=f"counterexample: Ā_1 = 0.5 (unstable), S = Ā − α H (L ⊗ I) has eigenvalues {np.round(ev, 4).tolist()} "
                          "(Hurwitz). The statement is false in general; within the paper's design S is Hurwitz by "
                          "(54) anyway, so nothing else depends on it (spec A9)")


def check_small_sigmaK(res: Results) -> Verdict:
    sc, d = res.scenario, res.design
    G = gains(sc)
    scales = np.array([0.25, 0.5, 1.0, 2.0, 4.0])
    mus = []
    for s in scales:
        _, ph = lb.forcing_bound(G["sigma"] * s, G["K"], float(d["wbar"]), float(d["wbar"]))
        mus.append(lb.ultimate_bound(res.P, float(d["qbar_single"]), ph)[0])
    mus = np.array(mus)
    return inequality(mus[:-1], mus[1:], strict=True,
                      detail=f"μ at fixed P and Q̄_ε for σ_i scaled by {scales.tolist()}: {np.round(mus, 1).tolist()} "
                             "(increasing; if P is re-solved per σ the claim is not guaranteed)")


def not_numeric(_: Results) -> Verdict:
    return not_checkable("motivational statements (Bayesian vs system-theoretic approaches, ease of tuning, the "
                         "literature review) are not numerical claims")


def catalogue(is_paper: bool) -> list[Claim]:
    c = Claim
    return [
        c("tran.ex51.observability", "Sec. 5, footnote 2", "(A, C_i) observable for every node type; collective "
          "observability holds", "identity", check_observability),
        c("tran.fn3.hurwitz_construction", "footnote 3", "L_i = J_i = 0 with σ_i K_i > 0 makes Ā_i Hurwitz",
          "inequality", check_footnote3),
        c("tran.eq9.error_dynamics", "(3)-(9), (22)-(26)", "the estimator (22)-(23) yields the error system (26)",
          "identity", check_error_dynamics),
        c("tran.eq62.printed_P", "(62)-(63)", "the printed P_i satisfy (28)-(29) with the printed ε for the printed "
          "gains", "inequality", check_printed_P),
        c("tran.lemma31.vertex_lmis", "Lemma 3.1, (30)", "(28)-(29) at the vertices imply Ā_i(g)ᵀP_i + P_iĀ_i(g) ≤ −εI "
          "for all g ∈ [0, 1]", "inequality", check_lemma31),
        c("tran.step_i.lmi_feasible", "Sec. 3.2 step (i), Remark 3.2", "(28)-(29) are feasible (cvxpy/Clarabel)",
          "inequality", check_lmi_feasible),
        c("tran.ex51.J_tradeoff", "Sec. 5.1 (after Fig. 5)", "J_i cannot be made large while keeping (28)-(29) "
          "feasible", "qualitative", check_J_sweep),
        c("tran.thm21.identity54", "(54), Thm 2.1 proof", "SᵀP + PS = −Q̄ with Q̄ = Q + 2α(L⊗I)", "identity",
          check_identity54),
        c("tran.rem43.S_hurwitz", "Remark 4.3", "S is Hurwitz", "inequality", check_S_hurwitz),
        c("tran.rem43.necessary_condition", "Remark 4.3 (last paragraph)", "Ā or every Ā_i Hurwitz is necessary for "
          "S Hurwitz", "qualitative", check_necessary_condition),
        c("tran.thm21.vdot", "Thm 2.1 proof", "V̇ ≤ −λ_min(Q̄)‖z‖² + 2‖z‖‖P‖φ̄ along solutions (fixed roles)",
          "inequality", check_thm21_vdot),
        c("tran.thm21.bounded", "Thm 2.1", "solutions are uniformly bounded: V(t) ≤ max(V(0), λ_max(P)μ²)",
          "inequality", check_thm21_invariant),
        c("tran.cor21.ultimate_bound", "Cor 2.1, (18)", "‖z(t)‖ ≤ sqrt(λ_max/λ_min) μ ultimately (fixed roles)",
          "inequality", check_cor21),
        c("tran.thm31.vertices", "Thm 3.1 proof", "S(g)ᵀP + PS(g) ≤ −Q̄_ε for all role vectors g", "inequality",
          check_thm31_vertices),
        c("tran.thm31.vdot", "Thm 3.1 proof", "V̇ ≤ −ε‖z‖² + 2‖z‖‖P‖φ̄ along solutions (time-varying roles)",
          "inequality", check_thm31_vdot),
        c("tran.thm31.bounded", "Thm 3.1", "solutions of (33) are uniformly bounded", "inequality",
          check_thm31_invariant),
        c("tran.cor31.ultimate_bound", "Cor 3.1, (18)", "‖z(t)‖ ≤ sqrt(λ_max/λ_min) μ ultimately (time-varying roles)",
          "inequality", check_cor31),
        c("tran.cor31.tight_bound", "project addition (spec C6)", "the vertex-q* version of (18) also holds",
          "inequality", check_cor31_tight),
        c("tran.rem22.small_sigmaK", "Remark 2.2 / after Cor 3.1", "a smaller σ_iK_i reduces the bound (at fixed P)",
          "inequality", check_small_sigmaK),
        c("tran.prop41.exact_moments", "(60), Remark 4.3", "the SDE simulation's E{V} matches the exact second-moment "
          "solution (fixed roles), at step h and h/2", "statistical", check_sde_step),
        c("tran.prop41.bound_fixed", "Prop 4.1, (46)", "E{zᵀPz} ≤ e^{−κt}V(0) + η/κ (fixed roles, exact moments)",
          "inequality", check_prop41_fixed),
        c("tran.prop41.bound_roles", "Prop 4.1, Remark 4.1, (46)", "E{zᵀPz} ≤ e^{−κt}V(0) + η/κ (time-varying roles, "
          "Ex. 5.2, Monte Carlo)", "statistical", check_prop41_roles),
        c("tran.rem42.limit52", "Remark 4.2, (52)", "limsup E‖z‖ ≤ (52)", "statistical", check_limit52),
        c("tran.rem42.additional_term", "text after (52)", "the only additional term is 2λ_max(P)ψ̄²/(λ_min(P)λ_min(Q̄))",
          "identity", check_rem42_text),
        c("tran.ex52.noisier_velocity", "Sec. 5.2", "estimates of states 2 and 4 are noisier than of states 1 and 3",
          "inequality", check_noisier_velocity),
        c("tran.rem31.comparison", "Remarks 2.1, 3.1; Figs. 3-8", "coestimation estimates x and w better than the "
          "estimation architecture (36)-(37) on the same scenario", "qualitative", check_comparison),
        c("tran.sec34.comparison_lmi_infeasible", "(38)-(39), spec §6.4", "with the example's gains the comparison "
          "LMIs (38)-(39) are infeasible", "inequality", check_comparison_infeasible),
        c("tran.ex51.comparison_reconstructed", "(38)-(39), spec §5.4", "the reconstructed comparison gains satisfy "
          "(38)-(39)", "inequality", check_comparison_reconstructed),
        c("tran.ref.central_kf", "project addition (spec §9)", "the centralized Kalman filter (all active sensors) is "
          "at least as accurate as coestimation", "inequality", check_central),
        c("tran.num.step_halving", "project (integrator)", "deterministic results do not depend on the step within "
          f"{STEP_TOL:g}", "inequality", check_step_halving),
        c("tran.spec.reference_values", "spec §6", "bounds and constants match the spec's reference numbers",
          "identity", check_reference_values),
        c("tran.intro.motivation", "Sec. 1", "motivational and comparative statements", "qualitative", not_numeric),
    ]
