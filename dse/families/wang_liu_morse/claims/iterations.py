"""The hybrid-observer claims on the simulated communication and error recursion: (41) and (61')
along every run, the source sets of Lemmas 2 and 3, the windows of Lemma 1, and Theorem 2's
asynchronous = synchronous (bitwise)."""
from __future__ import annotations

import numpy as np

from dse.verify.rules import ERRATUM, FAIL, PASS, Verdict, identity, inequality, not_checkable, roundoff_tolerance

from ..scenario import RunSection
from ..simulation import run_epsilon
from ..stages import Part, Parts
from .common import EPS, PID, Cells, claims, simulation_tolerance


def _sources(r: Part, run: RunSection) -> Verdict:
    a = r.runs[run.name]
    mism = int(a["source_mismatch"].sum())
    viol = int(a["reception_violations"])
    return identity([mism, viol], [0, 0], rtol=0, atol=0,
                    detail=f"{mism} of {int(a['source_entries'].sum())} source-set entries differ from "
                           f"N_i((s-1)T+(k-1)Δ+β); {viol} messages outside the reception interval")


@claims.claim(PID + ".eq41.error_recursion", "(37)-(43)", "e(s) = A(s) e(s-1) + B(s) ē(s-1) along every noise-free "
              "run", "identity")
def check_eq41(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: not run.noise and run.timing != "offset")
    out = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        count = int(a["count_res"])
        if not count:
            continue
        rel = float(a["max_res_minus"])
        tol, text = simulation_tolerance(r, run)
        out.append((label, identity([rel], [0.0], rtol=0, atol=tol,
                                    detail=f"max |e(s) - A(s)e(s-1) - B(s)ē(s-1)| / scale = {rel:.3g} "
                                           f"({rel / EPS:.1f} eps) over {count} (interval, trial) pairs; {text}")))
    return cs.verdict(out, "noise-free run without event-time offsets")


@claims.claim(PID + ".eq61.offset_recursion", "(57)-(61)", "with event-time offsets, e(s) = A e(s-1) + B ē(s-1) + G "
              "x((s-1)T) as printed (sign of Γ)", "identity")
def check_eq61_sign(res: Parts) -> Verdict:
    """(61) with +Γ as printed and with -Γ; the identity is algebraic for the index-aligned
    exchange (no hypothesis), so the corrected sign must hold to round-off."""
    cs = Cells(res, lambda r, run: run.timing == "offset" and not run.noise and run.leave is None)
    rows = []
    for label, r, run in cs.items:
        a = r.runs[run.name]
        if int(a["count_res"]):
            rows.append((label, float(a["max_res_minus"]), float(a["max_res_plus"]), *simulation_tolerance(r, run)))
    if not rows:
        return not_checkable("no noise-free run with event-time offsets")
    detail = "; ".join(f"[{lab}] residual with -Γ (corrected) {c:.3g}, with +Γ (printed) {p:.3g}, allowance {t:.3g}"
                       for lab, c, p, t, _ in rows)
    corr_ok = all(c <= t for _, c, _, t, _ in rows)
    printed_ok = all(p <= t for _, _, p, t, _ in rows)
    worst = max(rows, key=lambda x: x[1] / x[3])
    status = (PASS if printed_ok else ERRATUM) if corr_ok else FAIL
    note = (" With these offsets the two signs cannot be told apart." if printed_ok and corr_ok else
            " The sign of Γ in (57), (59)-(61) is wrong." if corr_ok else "")
    return Verdict(status, measured=max(x[2] for x in rows), reference=0.0, tolerance=worst[3],
                   printed=max(x[2] for x in rows), corrected=max(x[1] for x in rows), margin=worst[3] - worst[1],
                   detail=f"(61) e(s) = A e(s-1) + B ē(s-1) ∓ G x((s-1)T), residuals relative to the size of the states: "
                          f"{detail}. Allowance: {worst[4]}.{note}")


@claims.claim(PID + ".lemma2.source_sets", "Lemma 2, (36)", "synchronous: S_is(k) = N_i((s-1)T+(k-1)Δ+β)", "identity")
def check_lemma2(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: run.timing == "sync")
    return cs.verdict([(label, _sources(r, run)) for label, r, run in cs.items], "synchronous run")


@claims.claim(PID + ".lemma3.source_sets", "Lemmas 1, 3, (36)", "asynchronous under (10) with N(t) constant on the "
              "windows (23): S_is(k) = N_i((s-1)T+(k-1)Δ+β) and every message lands in its reception interval",
              "identity")
def check_lemma3(res: Parts) -> Verdict:
    cs = Cells(res, lambda r, run: run.timing == "async", ("eq10", "windows"))
    return cs.verdict([(label, _sources(r, run)) for label, r, run in cs.items], "asynchronous run")


@claims.claim(PID + ".lemma1.windows", "Lemma 1, (23)", "under (10) the q windows 𝓘_s(k) are disjoint and lie in [sT, "
              "(s+1)T)", "inequality")
def check_lemma1(res: Parts) -> Verdict:
    """Windows 𝓘_s(k) = [sT + (k-1)Δ + β - ε, sT + (k-1)Δ + β + ε] are disjoint and inside
    [sT, (s+1)T); the gaps are differences of inputs of size T, so the allowance is 10·q·eps·T."""
    cs = Cells(res, lambda r, run: run.timing in ("async", "offset"), ("eq10",))
    out = []
    for label, r, run in cs.items:
        eps = run_epsilon(run)
        T = r.scenario.T
        centres = np.arange(run.q) * run.Delta + run.beta
        gaps = np.concatenate([[centres[0] - eps], (centres[1:] - eps) - (centres[:-1] + eps),
                               [T - (centres[-1] + eps)]])
        tol, text = roundoff_tolerance(scale=T, operations=run.q)
        v = inequality(np.zeros_like(gaps), gaps, tolerance=tol,
                       detail=f"smallest gap {gaps.min():.3g} between consecutive windows (and the interval ends), ε = "
                              f"{eps:g}, β = {run.beta:g}, Δ = {run.Delta:g}, q = {run.q}; {text}")
        out.append((label, v))
    return cs.verdict(out, "run with jitter or offsets satisfying (10)")


@claims.claim(PID + ".thm2.async_equals_sync", "Theorem 2, Lemma 3", "under Theorem 2's hypotheses the asynchronous "
              "observer produces the synchronous iterates exactly", "identity")
def check_async_equals_sync(res: Parts) -> Verdict:
    """Bitwise: under (10) and N(t) constant on the windows, every source set is the nominal one,
    so the iterates are computed from the same numbers in the same order. Compared: a 64-bit
    fingerprint of every trial's e(s) over every event index, a hash of trial 0's iterates over
    every interval, and trial 0's stored values themselves."""
    cs = Cells(res, lambda r, run: run.timing == "async" and bool(run.reference_run), ("eq10", "windows"))
    out = []
    for label, r, run in cs.items:
        ref = r.spec(run.reference_run)
        a, b = r.runs[run.name], r.runs[ref.name]
        same = (ref.timing == "sync" and ref.q == run.q and ref.rule == run.rule and ref.noise == run.noise
                and ref.ideal == run.ideal and ref.leave == run.leave and ref.intervals == run.intervals
                and np.array_equal(a["nominal_graph"], b["nominal_graph"]) and a["nominal0"].shape == b["nominal0"].shape
                and np.array_equal(a["nominal0"], b["nominal0"]))
        if not same:
            out.append((label, not_checkable(f"the reference run {ref.name} is not the same observer with synchronous "
                                             "timing (q, rule, input, initial conditions or nominal graphs differ)")))
            continue
        B = min(len(a["trial_fingerprint"]), len(b["trial_fingerprint"]))
        differ = int((a["trial_fingerprint"][:B] != b["trial_fingerprint"][:B]).sum())
        de = float(np.nanmax(np.abs(a["t0_e_post"] - b["t0_e_post"])))
        dz = float(np.nanmax(np.abs(a["t0_z"] - b["t0_z"]))) if "t0_z" in a and "t0_z" in b else 0.0
        hashes = str(a["iterate_hash"]) == str(b["iterate_hash"])
        out.append((label, identity([differ, de, dz, 0 if hashes else 1], [0, 0.0, 0.0, 0], rtol=0, atol=0,
                                    detail=f"{differ} of {B} trials' e(s) fingerprints differ; trial 0: max |e_async(s) "
                                           f"- e_sync(s)| = {de:.3g}, max |z_async - z_sync| = {dz:.3g} over the "
                                           f"stored intervals, iterate hashes over every interval "
                                           f"{'equal' if hashes else 'differ'} (jitter up to "
                                           f"{max(run.epsilon):.3g}); bitwise equal iterates")))
    return cs.verdict(out, "asynchronous run with a synchronous reference run")
