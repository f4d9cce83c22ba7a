"""The stages of the Theorem-8 process P̃(t) (the switched Riccati process driven by a stationary Ā-chain):
the reference sample of its law μ_t, the samples only the theorem's conclusions use (run where C.1 and D.1
hold), and the pull-backs of Theorem 26(a) (run where C.1 holds and a mode |λ| ≥ 1 is unseen). The chain is
drawn from Ā (sampler S1) when Ā is exact, else driven by an independent copy of the protocol (S3).
"""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.switched_riccati as sr
from dse.contract.stages import stage
from dse.estimators.gikf_maps import covariance_features
from dse.estimators.gikf_roundoff import centralized_filter
from dse.simulate.seeding import stream_seed
from dse.simulate.units import block_generator

from .assumptions import accurate_range
from .bounds import envelope_error, envelope_matrix
from .results import PULLBACK_LAW_T, record_times
from .scenario import GossipKalmanFile

#: the top of the sandwich 0 ⪯ X0 ⪯ cI of the coupling (at least 10 ‖P0‖)
COUPLING_C = 1e6
#: horizons of the pathwise convergence of the pull-back from 0 (a few doublings)
PULLBACK_PATH_T = (16, 32, 64, 128, 256)
#: round-off bounds may exceed float64 (a bound that large says only that nothing is resolved: an infinite allowance)
ERROR_BOUNDS = ("final_err", "pullback_err", "pullback_monotone_err", "central_from_zero_err", "token0_err", "token1_err",
                "restart_err", "init_zero_err", "init_huge_err", "init_wishart_err")


def chain_sampler(sc: GossipKalmanFile, bounds: dict):
    """sample(size, steps, rng, start=None, lazy=False) -> (size, steps) Ā-chain paths (a LazyChain, read
    column by column, with `lazy`): from Ā (S1) when it is exact, else driven by an independent copy of the
    protocol (S3)."""
    if bool(bounds["Abar_exact"]):
        Abar = bounds["Abar"]
        return lambda size, steps, rng, start=None, lazy=False: sr.sample_chain(Abar, size, steps, rng, start=start,
                                                                               lazy=lazy)
    protocol = sc.protocol.build(sc.network)
    return lambda size, steps, rng, start=None, lazy=False: sr.sample_protocol_chain(protocol, size, steps, rng,
                                                                                    start=start, lazy=lazy)


@stage(allow_nonfinite=ERROR_BOUNDS)
def theorem8(sc: GossipKalmanFile, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Theorem-8 process from P0 (sampler S1) with its last switch at each record time; the chain is drawn
    slot by slot (memory does not grow with the horizon)."""
    sys_ = sc.system
    rng = block_generator(stream_seed(seed, sc.name, "theorem8"))
    path = chain_sampler(sc, bounds)(ref_runs, slots, rng, lazy=True)
    out = sr.switched_riccati(sys_, path, sc.P0, record_times(sc, slots), keep_final=True)
    return out


def restart_slot(Abar: np.ndarray, slots: int, tokens: list[int]) -> tuple[int, np.ndarray]:
    """s for the finite-horizon form of Theorem 10[ii] ((72)-(84)): the first s ≤ T/2 at which the
    tokens' chains are within 1e-3 of uniform in total variation (else T/2), and d_v(p_n(s), U)."""
    N = len(Abar)
    P = np.eye(N)[tokens]
    for s in range(slots // 2 + 1):
        dv = 0.5 * np.abs(P - 1.0 / N).sum(axis=1)
        if dv.max() <= 1e-3 or s == slots // 2:
            return s, dv
        P = P @ Abar
    return slots // 2, dv


@stage(allow_nonfinite=ERROR_BOUNDS)
def aux(sc: GossipKalmanFile, bounds: dict, seed: int, ref_runs: int, slots: int) -> dict[str, np.ndarray]:
    """Samples that only the theorem's conclusions use (run where C.1 and D.1 hold): other initial laws
    (Theorem 8), tokens from fixed sensors and the restarted stationary process Q^s(T) (Theorem 10[ii]),
    forward coupling (burn-in), pull-back (Lemma 23, Theorem 26(b)). Copies started at c·I with c ≫ 1
    run in square-root form, which stays accurate and finite however large the iterates get."""
    sys_ = sc.system
    chain = chain_sampler(sc, bounds)
    M = sc.M
    times = record_times(sc, slots)
    half = max(ref_runs // 2, 100)
    out: dict[str, np.ndarray] = {}
    rng = block_generator(stream_seed(seed, sc.name, "aux"))
    from scipy.stats import wishart     # here: `dse list` and `dse check` import this module

    wish = wishart(df=M + 2, scale=np.eye(M)).rvs(size=half, random_state=rng.integers(2**31)).reshape(half, M, M)
    out["wishart_lam_max"] = np.linalg.eigvalsh(wish)[:, -1]
    c = max(COUPLING_C, 10.0 * float(np.linalg.norm(sc.P0, 2)))  # the sandwich 0 ⪯ X0 ⪯ cI must contain P0
    out["coupling_c"] = np.array(c)
    for label, X0 in (("zero", np.zeros((M, M))), ("huge", c * np.eye(M)), ("wishart", wish)):
        path = chain(half, slots, rng, lazy=True)
        sqrt = float(np.max(np.linalg.norm(X0, 2, axis=(-2, -1)))) > accurate_range(sc)  # Joseph where it is accurate
        run = sr.switched_riccati(sys_, path, X0, [slots], sqrt=sqrt, track_error=not sqrt)
        out[f"init_{label}"] = run["features"][0]
        out[f"init_{label}_err"] = run["err"][0] if not sqrt else np.zeros(half)
    tokens = sorted({0, min(1, sc.N - 1)})
    for n in tokens:
        path = chain(half, slots, rng, start=n, lazy=True)
        tok = sr.switched_riccati(sys_, path, sc.P0, times, track_error=True)
        out[f"token{n}"], out[f"token{n}_err"] = tok["features"], tok["err"][-1]
    if bool(bounds["Abar_exact"]):
        s, dv = restart_slot(bounds["Abar"], slots, tokens)
        path = chain(half, slots - s, rng, lazy=True)
        out["restart_s"], out["restart_dv"] = np.array(s), dv
        # the same arithmetic as the tokens (Joseph form) unless f_0^s(P0) is beyond its accurate range
        start = envelope_matrix(bounds, s)
        huge = float(bounds["envelope_log"][s]) > math.log(accurate_range(sc))
        rs = sr.switched_riccati(sys_, path, start, [slots - s], sqrt=huge, track_error=not huge)
        out["restart"] = rs["features"][0]
        out["restart_err"] = rs["err"][0] + envelope_error(bounds, s) if not huge else np.zeros(half)
    cpl_times = [t for t in (10, 20, 40, 80, 160, 320) if t <= slots] or [slots]
    path = chain(min(2000, ref_runs), slots, rng, lazy=True)
    out["coupling_times"] = np.array(cpl_times)
    gaps = sr.coupling_gap(sys_, path, c, sorted(set(cpl_times) | {slots}))
    out["coupling"] = gaps[[sorted(set(cpl_times) | {slots}).index(t) for t in cpl_times]]
    out["coupling_final"] = gaps[-1]
    law_T = [t for t in PULLBACK_LAW_T if t <= slots]
    if law_T:
        back = chain(half, max(law_T), rng)  # Ā symmetric: the reversed stationary chain is again a Ā-chain
        pb = sr.pullback(sys_, back, sc.P0, law_T)
        out["pullback_law_T"] = np.array(law_T)
        out["pullback_law"] = np.array([covariance_features(x) for x in pb])
    path_T = [t for t in PULLBACK_PATH_T if t <= max(64, 2 * slots)]  # pathwise convergence: a few horizon doublings
    back = chain(500, max(path_T), rng)
    lo, err = sr.pullback(sys_, back, np.zeros((M, M)), path_T, with_error=True)
    hi = sr.pullback(sys_, back, c * np.eye(M), path_T, sqrt=True)
    _pullback_paths(out, lo, err, path_T)
    out["pullback_gap"] = np.linalg.norm(hi - lo, 2, axis=(-2, -1)) / out["pullback_lo_norm"]
    return out


def _pullback_paths(out: dict, lo: np.ndarray, err: np.ndarray, path_T: list[int]) -> None:
    """Pull-backs L_T from 0 with their round-off bounds: norms, relative changes between horizons, and
    λ_min(L_T' − L_T) (≥ 0 in exact arithmetic: f monotone and f(0) = Q ⪰ 0, so L_T grows with T)."""
    out["pullback_path_T"] = np.array(path_T)
    out["pullback_lo_norm"] = np.linalg.norm(lo, 2, axis=(-2, -1))
    out["pullback_err"] = err
    steps = np.diff(lo, axis=0)
    out["pullback_step"] = np.linalg.norm(steps, 2, axis=(-2, -1)) / out["pullback_lo_norm"][1:]
    out["pullback_monotone"] = np.linalg.eigvalsh(steps)[..., 0]
    out["pullback_monotone_err"] = err[1:] + err[:-1]


@stage(allow_nonfinite=ERROR_BOUNDS)
def pullback_divergent(sc: GossipKalmanFile, bounds: dict, seed: int) -> dict[str, np.ndarray]:
    """Theorem 26, alternative (a) (run where C.1 holds and a mode |λ| ≥ 1 is unseen): pull-backs from 0
    along 500 backward paths and the centralized filter from 0 (a pathwise lower bound of every
    pull-back), both in Joseph form with their round-off bounds, at the horizons whose pull-backs stay
    inside the range where the Joseph form is accurate (`accurate_range`)."""
    sys_ = sc.system
    rng = block_generator(stream_seed(seed, sc.name, "pullback-divergent"))
    horizons = (4, 8, 16, 32, 64, 128, 256)
    back = chain_sampler(sc, bounds)(500, max(horizons), rng)
    limit = accurate_range(sc)
    kept, lows, errs = [], [], []
    with np.errstate(all="ignore"):
        for T in horizons:
            lo, err = sr.pullback(sys_, back, np.zeros((sc.M, sc.M)), [T], with_error=True)
            if not (np.all(np.isfinite(lo)) and np.linalg.norm(lo, 2, axis=(-2, -1)).max() <= limit):
                break
            kept.append(T)
            lows.append(lo[0])
            errs.append(err[0])
    out: dict[str, np.ndarray] = {"pullback_range": np.array(limit)}
    if len(kept) < 2:
        out["pullback_path_T"] = np.array(kept, dtype=np.int64)
        return out
    lo, err = np.array(lows), np.array(errs)
    _pullback_paths(out, lo, err, kept)
    Pc, _, ec = centralized_filter(sc.F, sys_.C_all, sc.Q, sys_.R_all, np.zeros((sc.M, sc.M)), max(kept) + 1)
    out["central_from_zero"] = Pc[kept]
    out["central_from_zero_err"] = ec[kept]
    out["pullback_vs_central"] = np.linalg.eigvalsh(lo - Pc[kept][:, None])[..., 0]   # (len(kept), 500)
    return out
