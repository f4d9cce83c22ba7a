"""The hybrid-observer claims on the bounds: Lemma 4's (44), (45), (49), the idealised
attenuation (20), Theorem 1's event and continuous bounds and rate, Theorem 2's bound, the
symmetric special case (54), Lemma 8's (62) and the offsets' bound (63); and the Section 6
example's (44) with q = 50 and its rate."""
from __future__ import annotations

import math

import numpy as np

from dse.verify.rules import ERRATUM, FAIL, PASS, Verdict, identity, inequality, not_checkable, roundoff_tolerance

from ..design import alpha_power
from ..scenario import RunSection
from ..simulation import is_theorem_run, run_epsilon
from ..stages import Part, Parts
from .common import (EQ44, IDEAL, PID, SYM, THM, Cells, alpha_used, at_most_one, claims, combine, constants,
                     fit_rate, simulation_tolerance, worst_verdict)

# max_i ||e_i(sT)|| of the Section 6 example's synchronous run with the paper's initial conditions,
# computed independently of this code (numpy/scipy scratch computations) to 3 significant digits
REFERENCE_SYNC_ERRORS = [20.5, 11.2, 1.97, 0.308, 4.13e-2, 5.9e-3, 7.7e-4]


def _matrix_tolerance(r: Part, run: RunSection, scale: float) -> tuple[float, str]:
    """A(s), B(s), Φ_s(k), G(s) are products and sums of up to q mn-square matrices."""
    return roundoff_tolerance(scale=scale, operations=run.q * r.scenario.m * r.scenario.n)


@claims.claim(PID + ".lemma4.eq44", "Lemma 4, (44)", "|A(s)| <= e^(-λT) when q satisfies (22)", "inequality",
              hypotheses=EQ44)
def check_eq44(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: run.rule == "mean" and run.leave is None, ("q", "strong_connectivity"), timing=True)
    out = []
    for label, r, run in cs.items:
        vals = r.runs[run.name]["A_mixed"]
        vals = vals[~np.isnan(vals)]
        lim = math.exp(-r.scenario.lam * r.scenario.T)
        tol, text = _matrix_tolerance(r, run, float(r.design["norm_eAT"]))
        out.append((label, inequality(vals, np.full_like(vals, lim), tolerance=tol,
                                      detail=f"max |A(s)| = {vals.max():.3g} vs e^(-λT) = {lim:.6g} (q = {run.q}); {text}")))
    return cs.verdict(out, "run with rule (13) whose q satisfies (22)")


@claims.claim(PID + ".sec6.eq44_q50", "Sec. 6, (44)", "with q = 50 (outside (22)) |A(s)| <= e^(-λT) still holds",
              "inequality", scope="paper-example")
def check_eq44_q50(res: Parts) -> Verdict:
    """The paper's example with its q = 50, which misses (22): (44) measured."""
    r = res["paper"]
    out = []
    for run in r.scenario.runs:
        if run.rule != "mean" or run.leave is not None:
            continue
        vals = r.runs[run.name]["A_mixed"]
        vals = vals[~np.isnan(vals)]
        lim = math.exp(-r.scenario.lam * r.scenario.T)
        out.append((f"paper/{run.name}", inequality(vals, np.full_like(vals, lim),
                                                    detail=f"max |A(s)| = {vals.max():.3g} vs e^(-λT) = {lim:.6g} "
                                                           f"(q = {run.q})")))
    return combine(out, detail=" Outside the hypotheses (q = 50 misses (22) and (27), see the hypotheses "
                                "q_eq22 and q_eq27): (44) holds empirically, because ρ = 0.")


@claims.claim(PID + ".lemma4.eq45_eq49", "Lemma 4, (45), (49)", "|B(s)| <= q e^(||A||T)|Q| and |Φ_s(k)| <= 1",
              "inequality")
def check_eq45_49(res: Parts) -> Verdict:
    """(45) and (49) follow from |P_i| <= 1 and row-stochastic weights, whatever q is."""
    cs = Cells(res, lambda r, run: run.rule == "mean")
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        ok, okp = ~np.isnan(a["B_mixed"]), ~np.isnan(a["Phi_max"])
        if not ok.any():
            continue
        bnd = constants(r, run)["b"]
        tol, text = _matrix_tolerance(r, run, bnd)
        tol1, _ = _matrix_tolerance(r, run, 1.0)
        lhs = np.concatenate([a["B_mixed"][ok] / bnd, a["Phi_max"][okp]])
        out.append((label, inequality(lhs, np.ones(lhs.size), tolerance=max(tol / bnd, tol1),
                                      detail=f"max |B(s)| = {a['B_mixed'][ok].max():.4g} <= q e^(||A||T)|Q| = {bnd:.4g} "
                                             f"over {ok.sum()} intervals; max |Φ_s(k)| = {a['Phi_max'][okp].max():.12f} "
                                             f"<= 1 at {int(a['phi_k_checked'])} values of k in each of the first "
                                             f"{okp.sum()} intervals (both as ratios to their bounds); {text}")))
    return cs.verdict(out, "run with rule (13) and every agent present in some interval")


@claims.claim(PID + ".sec2.idealized_attenuation", "text after (19), (20)", "with ē ≡ 0: max||π(q)|| <= α^p "
              "max||π(0)|| and |e(s)| <= e^(||A||T) α^p |e(s-1)|", "inequality", hypotheses=IDEAL)
def check_c3(res: Parts) -> Verdict:
    """With ē ≡ 0 (w_i(0) = L_i x(0)) and p = floor(q/N): max_i||π_is(q)|| <= α^p max_i||π_is(0)|| and
    |e(s)| <= e^(||A||T) α^p |e(s-1)|, plus the simulation's round-off allowance (evaluated during the run)."""
    cs = Cells(res, lambda r, run: run.ideal and run.rule == "mean" and run.leave is None and not run.noise,
               ("strong_connectivity",))
    out = []
    for label, r, run in cs.items:
        alpha, atext = alpha_used(r)
        N = (r.scenario.m - 1) ** 2 + 1
        p = run.q // N
        if alpha is None and p > 0:
            out.append((label, not_checkable(atext)))
            continue
        if alpha is None:
            atext = "α^0 = 1 whatever ρ"
        a = r.runs[run.name]
        _, text = simulation_tolerance(r, run)
        first = float(a["max_c3_piq1"]) / float(a["max_c3_pi01"])
        out.append((label, worst_verdict(a, "c3", detail=f"ē(0) = 0, p = floor(q/N) = {p}, {atext}, α^p = "
                                                         f"{alpha_power(r.design, p):.6g}; measured max_i||π(q)|| / max_i||π(0)|| in the "
                                                         f"first interval = {first:.3g}; the simulated ē is not exactly 0 "
                                                         f"(round-off, largest |ē(s)| = {float(a['max_eb_max']):.3g}), so "
                                                         f"its terms are added through (37)-(43): q|Q||ē(s-1)| for π(q), "
                                                         f"|B(s)||ē(s-1)| for e(s); {text}")))
    return cs.verdict(out, "run with ē(0) = 0 ('ideal') and rule (13)")


@claims.claim(PID + ".thm1.event_bound", "Theorem 1, (51)", "|e(s)| <= e^(-λsT)(|e(0)| + d|ē(0)|)", "inequality",
              hypotheses=THM, args=("sync",))
def check_event_bound(res: Parts, timing: str) -> Verdict:
    cs = Cells(res, lambda r, run: run.timing == timing and is_theorem_run(run), ("q", "strong_connectivity"), timing=True)
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        _, text = simulation_tolerance(r, run)
        v = worst_verdict(a, "eq51", detail=f"max measured/bound = {float(a['max_ratio51']):.3g} (d = "
                                            f"{constants(r, run)['d']:.4g}); {text}")
        out.append((label, Verdict(v.status, v.measured, v.reference, tolerance=v.tolerance, margin=v.margin,
                                   trials=int(a["trials"]), detail=v.detail)))
    return cs.verdict(out, f"{timing} noise-free run with rule (13) and every agent present")


@claims.claim(PID + ".thm1.continuous_bound", "Theorem 1, proof", "||e_i(t)|| <= e^(||A||T - λt)(|e(0)| + d|ē(0)|) "
              "for t >= 0", "inequality", hypotheses=THM)
def check_continuous_bound(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: run.timing == "sync" and is_theorem_run(run), ("q", "strong_connectivity"))
    rows = [(label, float(r.runs[run.name]["max_cont_printed"]), float(r.runs[run.name]["max_cont_corrected"]),
             simulation_tolerance(r, run)[1]) for label, r, run in cs.items]
    if not rows:
        return not_checkable("no synchronous noise-free run with rule (13) and q satisfying (22)." + cs.note())
    printed = max(x[1] for x in rows)
    corrected = max(x[2] for x in rows)
    detail = "; ".join(f"[{lab}] max ||e_i(t)||/printed bound = {p:.4g}, /corrected bound = {c:.4g}" for lab, p, c, _ in rows)
    status = ERRATUM if (printed > 1 and corrected <= 1) else (PASS if printed <= 1 else FAIL)
    return Verdict(status, measured=printed, reference=1.0, printed=printed, corrected=corrected, margin=1 - corrected,
                   detail=f"printed: ||e_i(t)|| <= e^(||A||T - λt)(|e(0)| + d|ē(0)|); corrected: an extra factor e^(λT) "
                          f"(the proof uses e^(-λ(s-1)T) <= e^(-λt) on [(s-1)T, sT], which is false). {detail}. Every "
                          f"sample of every trial and the left limits at the resets are compared. The printed bound "
                          f"fails just before the first reset when ē(0) = 0. Allowance: {rows[0][3]}." + cs.note())


@claims.claim(PID + ".thm1.rate", "Theorem 1", "each e_i tends to zero as fast as e^(-λt)", "inequality",
              hypotheses=THM)
def check_rate(res: Parts) -> Verdict:
    """'Each e_i tends to zero as fast as e^(-λt)': the bound (51) restarted at every event index
    s0 >= 1 holds for every later s (with the local observers' round-off carried along). Least-squares
    rates are reported, not judged."""
    cs = Cells(res, lambda r, run: run.timing == "sync" and is_theorem_run(run), ("q", "strong_connectivity"))
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        count = int(a["count_restart"])
        if not count:
            continue
        rates = a["trial_fit_rate"]
        fitted = (f"least-squares decay rates of max_i||e_i(t_is)|| until round-off: min {np.nanmin(rates):.4f}, median "
                  f"{np.nanmedian(rates):.4f}" if np.isfinite(rates).any() else "too few samples above round-off for a fit")
        _, text = simulation_tolerance(r, run)
        out.append((label, at_most_one(float(a["max_restart"]), count,
                                       f"max over s0 < s of |e(s)| / (e^(-λ(s-s0)T)(|e(s0)| + d|ē(s0)|)) over (s0, s, "
                                       f"trial) triples, λ = {r.scenario.lam:g}; {fitted}; {text}")))
    return cs.verdict(out, "synchronous noise-free run with rule (13), every agent present, q satisfying (22)")


@claims.claim(PID + ".sec6.rate", "Sec. 6", "the example converges at rate λ = 2", "inequality", scope="paper-example")
def check_paper_rate(res: Parts) -> Verdict:
    r = res["paper"]
    a = r.runs["sync"]
    e, fl = np.linalg.norm(a["t0_e_post"], axis=-1).max(axis=-1), a["t0_floor"]
    t = a["event_ns"][0] / 1e9
    rate0, first, last = fit_rate(t, e, fl)
    pv = r.scenario.paper_values
    lam_p = float(pv.lam if pv.lam is not None else 2.0)
    got = [float(x) for x in e[1:1 + len(REFERENCE_SYNC_ERRORS)]]
    reg = identity(got, REFERENCE_SYNC_ERRORS, rtol=6e-3,
                   detail="trial 0 max_i||e_i(sT)|| vs independent values to 3 digits")
    all_rates = a["trial_fit_rate"]
    detail = (f"trial 0 (paper's ICs) fitted rate {rate0:.4f} (s = {first}..{last - 1}); all trials min "
              f"{np.nanmin(all_rates):.4f}; the target λ = {lam_p:g} is reached only marginally because the local "
              f"observers themselves decay at rate 2. max_i||e_i(sT)|| = {[f'{x:.3g}' for x in got]} ({reg.status} "
              f"against the independent values: {reg.detail}). q = 50 misses (22) and (27) (hypotheses q_eq22, "
              f"q_eq27): an empirical finding outside the theorems.")
    if reg.status != PASS:
        return Verdict(FAIL, measured=got[0], reference=REFERENCE_SYNC_ERRORS[0], detail=detail)
    return Verdict(PASS if abs(rate0 - lam_p) <= 0.05 else FAIL, measured=float(rate0), reference=lam_p, tolerance=0.05,
                   margin=0.05 - abs(float(rate0) - lam_p), trials=int(np.sum(np.isfinite(all_rates))), detail=detail)


claims.claim(PID + ".thm2.event_bound", "Theorem 2", "asynchronous: the same bound (51)", "inequality",
              hypotheses=THM, args=("async",))(check_event_bound)


@claims.claim(PID + ".sec3.symmetric_case", "(25)-(27), Lemma 7, (54)", "symmetric graphs with rule (25) and q from "
              "(27): ||A(s)||_2 <= e^(-λT) and the 2-norm analogue of (51)", "inequality", hypotheses=SYM)
def check_special(res: Parts) -> Verdict:
    """Lemma 7: ||A(s)||_2 <= e^(-λT) (54), and ||e(s)||_2 <= e^(-λsT)(||e(0)||_2 + d'||ē(0)||_2) with
    d' = c q e^(||A||T)||Q||_2 e^(λT)/(1 - e^(-(λ̄-λ)T)) (the same proof in 2-norms)."""
    cs = Cells(res, lambda r, run: run.rule == "symmetric" and run.leave is None and not run.noise,
               ("q", "strong_connectivity"), timing=True)
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        lim = math.exp(-r.scenario.lam * r.scenario.T)
        vals = a["A_2"][~np.isnan(a["A_2"])]
        tol, text = _matrix_tolerance(r, run, float(r.design["norm_eAT"]))
        out.append((f"{label}/eq54", inequality(vals, np.full_like(vals, lim), tolerance=tol,
                                                detail=f"max ||A(s)||_2 = {vals.max():.4g} vs e^(-λT) = {lim:.4g} with "
                                                       f"q = {run.q}; {text}")))
        _, text2 = simulation_tolerance(r, run)
        out.append((f"{label}/bound", worst_verdict(a, "sym", detail=f"||e(s)||_2 <= e^(-λsT)(||e(0)||_2 + "
                                                                     f"d'||ē(0)||_2), max ratio "
                                                                     f"{float(a['max_ratio_sym']):.3g}; {text2}")))
    return cs.verdict(out, "noise-free run with the convex rule (25) and q satisfying (27)")


@claims.claim(PID + ".lemma8.eq62", "Lemma 8, (62)", "|G(s)| <= 2mqε||A||e^(||A||(T+β))", "inequality")
def check_lemma8(res: Parts) -> Verdict:
    """(62) |G(s)| <= 2mqε||A||e^(||A||(T+β)). The proof's intermediate inequality
    ||e^(Mt) - e^(Mτ)|| <= ||M(t-τ)||e^(||Mt||) is false in general; ||M|||t-τ|e^(||M|| max(|t|,|τ|))
    replaces it and gives the same conclusion because |t_i0| <= ε <= β under (10)."""
    cs = Cells(res, lambda r, run: run.timing == "offset" and run.leave is None, ("eq10",))
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        eps = run_epsilon(run)
        bnd = eps * constants(r, run)["g"]
        vals = a["G_mixed"][~np.isnan(a["G_mixed"])]
        if not vals.size:
            continue
        tol, text = _matrix_tolerance(r, run, bnd)
        out.append((label, inequality(vals, np.full_like(vals, bnd), tolerance=tol,
                                      detail=f"max |G(s)| = {vals.max():.4g} <= 2mqε||A||e^(||A||(T+β)) = {bnd:.4g}; "
                                             f"{text}")))
    return cs.verdict(out, "run with event-time offsets satisfying (10)")


@claims.claim(PID + ".sec4.eq63", "(63)", "|e(s)| <= e^(-λsT)(|e(0)| + d|ē(0)|) + εg Σ e^(-λ(s-k)T)||x((k-1)T)||",
              "inequality", hypotheses=THM)
def check_eq63(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: run.timing == "offset" and is_theorem_run(run),
               ("q", "eq10", "windows", "strong_connectivity"))
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        _, text = simulation_tolerance(r, run)
        out.append((label, worst_verdict(a, "eq63", detail=f"(63), max ratio {float(a['max_ratio63']):.3g}; {text}")))
    return cs.verdict(out, "noise-free run with offsets, rule (13) and q satisfying (22)")
