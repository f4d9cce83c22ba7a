"""The design stage of a scenario (`bounds`): everything deterministic the hypotheses, the claims and the
tables read, without Monte Carlo. Ā (closed form, exact recursion or estimate) and its spectrum, C.1's
structure, D.1's decision with the witness walk, Lemma 14's constant along every witness window and
Lemma 15's tail bounds, the centralized filter (same P0) with its round-off bound and its limit (DARE),
the centralized filter of every class of Ā (a pathwise lower bound of its sensors), the Lyapunov
envelope f_0^t(P0) (eq (73)) carried rescaled; and a stage of its own (`bound_checks`, on top of it) for
the independent computations only claims use (filterpy's centralized filter, the lifted window chain's
stationary law), so that `dse check` and `dse run` compute the same `bounds` stage under one key.
"""
from __future__ import annotations

from typing import Any

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.kalman as kal
import dse.estimators.walk_detectability as wd
from dse.contract.stages import StageResult, stage
from dse.estimators.gikf_maps import GossipSystem
from dse.estimators.gikf_roundoff import centralized_filter, lyapunov_envelope

from .assumptions import accurate_range, mean_adjacency
from .scenario import GossipKalmanFile

#: thresholds J of Lemma 15's tail bound and of the tail statistics
J_GRID = np.logspace(0, 12, 49)
#: filterpy (the oracle of our centralized recursion) is run over the first slots only: the claim compares two
#: recursions, and filterpy inverts an N m x N m innovation covariance per step
FILTERPY_STEPS = 300
#: arrays that may hold NaN (not computed) or inf (beyond float64)
PARTIAL = ("beta_multi", "beta_single", "alpha0_multi", "envelope", "envelope_err", "P_floor",
           "P_floor_err", "P_central", "P_central_err")


@stage(allow_nonfinite=PARTIAL)
def bounds(sc: GossipKalmanFile, slots: int) -> dict[str, np.ndarray]:
    """The design quantities of a scenario over `slots` slots (what `dse check` computes)."""
    sys_, assume = sc.system, sc.assumptions
    Abar, Abar_se, Abar_exact, Abar_draws = mean_adjacency(sc)
    chk = wd.check_chain(Abar)
    out: dict[str, Any] = {"Abar": Abar, "Abar_se": Abar_se, "Abar_exact": Abar_exact, "Abar_draws": Abar_draws,
                           "irreducible": assume.irreducible, "aperiodic": assume.aperiodic, "c1": assume.c1,
                           "n_classes": len(assume.classes), "unit_multiplicity": chk.unit_multiplicity, "slem": chk.slem,
                           "min_eig_Abar": chk.min_eig, "tv": wd.tv_to_uniform(Abar, 200),
                           "Abar_eigenvalues": np.linalg.eigvalsh(0.5 * (Abar + Abar.T)),
                           "random_protocol": sc.protocol.random, "slots": slots}
    labels = np.zeros(sc.N, dtype=np.int64)
    for c, cls in enumerate(assume.classes):
        labels[list(cls)] = c
    out["class_of"] = labels
    F = sc.F
    out["sensor_detectable"] = np.array([not wd.pbh_undetectable(F, sys_.C[n]) for n in range(sc.N)])
    out["central_detectable"] = bool(assume.central_detectable)
    out["central_observable"] = wd.observable(F, sys_.C_all) is True
    ratios = wd.singular_ratios(wd.observability_matrix(F, sys_.C_all), sc.M)
    out["observability_rank"] = int((ratios > wd.SINGULAR_RATIO).sum())
    out["observability_ratio"] = float(ratios[-1])
    out["class_observability_rank"] = np.array([
        int((wd.singular_ratios(wd.observability_matrix(F, sys_.C[list(cls)].reshape(-1, sc.M)), sc.M)
             > wd.SINGULAR_RATIO).sum()) for cls in assume.classes])
    rates = np.zeros(sc.N)
    for cls, unseen in zip(assume.classes, assume.blind):
        rates[list(cls)] = max([0.0] + [2 * np.log(abs(x)) for x in (unseen or ())])
    out["divergence_rate"] = rates  # growth rate of log tr P̂ per slot where a class cannot see |λ| > 1
    out["blind"] = np.array([bool(b) for b in assume.blind])[labels]
    search = assume.d1.search
    out["d1"] = assume.d1.holds is True
    out["d1_decided"] = assume.d1.holds is not None
    out["d1_certificate_ratio"] = float(assume.d1.certificate_ratio)
    out["d1_covering"] = search.witness is not None and assume.irreducible
    out["witness"] = np.array(search.witness if search.witness else [], dtype=np.int64)
    out["witness_ratio"] = float(search.ratio)
    out["witness_max_rank"] = search.max_rank
    out["walks_checked"] = search.walks_checked
    out["q_pd"] = bool(np.linalg.eigvalsh(sc.Q).min() > 0)
    out["alpha"] = float(np.linalg.norm(F, 2))
    out["qnorm"] = float(np.linalg.norm(sc.Q, 2))
    out["accurate_range"] = accurate_range(sc)
    if search.witness is not None:
        _witness_bounds(out, sys_, search, Abar, Abar_exact, slots)
    # centralized reference (same P0): our recursion with its round-off bound, filterpy, and the DARE
    P_c, K_c, err_c = centralized_filter(F, sys_.C_all, sc.Q, sys_.R_all, sc.P0, slots + 1)
    out["P_central"], out["K_central"], out["P_central_err"] = P_c, K_c, err_c
    if assume.central_detectable:
        out["P_central_inf"] = kal.steady_state_prior_covariance(F, sys_.C_all, sc.Q, sys_.R_all)
    # the lower bound of each sensor: the centralized filter of its class (tokens never leave a class), one per class
    floor, floor_err = np.empty((slots + 1, len(assume.classes), sc.M, sc.M)), np.empty((slots + 1, len(assume.classes)))
    for c, cls in enumerate(assume.classes):
        idx = list(cls)
        if len(assume.classes) == 1:
            Pk, ek = P_c, err_c
        else:
            with np.errstate(over="ignore", invalid="ignore"):
                Pk, _, ek = centralized_filter(F, sys_.C[idx].reshape(-1, sc.M), sc.Q, scipy.linalg.block_diag(*sys_.R[idx]),
                                         sc.P0, slots + 1)
        floor[:, c], floor_err[:, c] = Pk, ek
    out["P_floor"], out["P_floor_err"] = floor, floor_err
    out["envelope_log"], out["envelope"], out["envelope_err"] = lyapunov_envelope(F, sc.Q, sc.P0, slots)
    return {k: np.asarray(v) for k, v in out.items()}


def envelope_matrix(bounds: dict, t: int) -> np.ndarray:
    """f_0^t(P0) from the rescaled envelope (inf entries where it leaves float64)."""
    with np.errstate(over="ignore"):
        return np.exp(float(bounds["envelope_log"][t])) * bounds["envelope"][t]


def envelope_error(bounds: dict, t: int) -> float:
    with np.errstate(over="ignore"):
        return float(np.exp(float(bounds["envelope_log"][t])) * float(bounds["envelope_err"][t]))


def _witness_bounds(out: dict, sys_: GossipSystem, search: wd.WitnessSearch, Abar: np.ndarray, Abar_exact: bool,
                    slots: int) -> None:
    """Lemma 14's constant along the witness and every witness window, and Lemma 15's tail bounds."""
    w = search.witness
    out["gramian"] = search.gramian
    out["gramian_weighted"] = Gt = wd.walk_gramian(sys_, w, weighted=True)
    out["gramian_cond"] = float(np.linalg.cond(Gt))
    out["sigma_sub"] = wd.sigma_sub(sys_, w)
    out["sigma_sub_printed"] = wd.sigma_sub_printed(sys_, w)
    cs = np.array([1e2, 1e4, 1e6, 1e8])
    out["g_of_cI_c"] = cs
    out["g_of_cI"] = np.array([wd.compose_walk(sys_, w, c * np.eye(sys_.M)) for c in cs])
    alpha0 = float(np.linalg.eigvalsh(out["sigma_sub"])[-1])
    out["alpha0"] = alpha0
    windows = search.windows
    out["n_windows"] = len(windows) if search.windows_complete else -1
    a0_multi = max(float(np.linalg.eigvalsh(wd.sigma_sub(sys_, v))[-1]) for v in windows) if windows else np.nan
    out["alpha0_multi"] = a0_multi
    ks = np.array([wd.k_of_J(out["alpha"], alpha0, out["qnorm"], J) for J in J_GRID])
    ell = len(w)
    out["kJ"] = ks
    # β needs the exact Ā (an estimated Ā gives an estimated bound): NaN marks "not computed"
    # (every J from one propagation up to the longest path; k(J) < 0: bound 1)
    out["beta_single"] = (np.where(ks >= 0, wd.tail_bounds_single(Abar, w, np.minimum(slots, ks + ell)), 1.0)
                          if Abar_exact else np.full(len(ks), np.nan))
    small = sys_.N ** max(ell - 1, 0) <= 2000 and Abar_exact and windows
    km = np.array([wd.k_of_J(out["alpha"], a0_multi, out["qnorm"], J) for J in J_GRID]) if windows else ks
    out["beta_multi"] = (np.where(km >= 0, wd.tail_bounds_multi(Abar, windows, np.minimum(slots, km + ell)), 1.0)
                         if small else np.full(len(km), np.nan))
    support = (Abar > 1e-12).astype(float)
    n_windows = float(np.linalg.matrix_power(support, ell - 1).sum())
    out["n_walks_length_ell"] = n_windows


@stage(allow_nonfinite=("lifted_printed", "P_central_filterpy"))
def bound_checks(sc: GossipKalmanFile, slots: int, design: StageResult) -> dict[str, np.ndarray]:
    """The independent computations only claims use, on top of the `bounds` stage `design`: filterpy's
    centralized filter over the first slots, and the lifted window chain's stationary law (dense solve, when Ā
    is exact and the witness has at most 5000 windows)."""
    out = {"P_central_filterpy": _filterpy_prior(sc, sc.system, min(slots, FILTERPY_STEPS) + 1)}
    ell = len(design["witness"])
    if ell and bool(design["Abar_exact"]) and float(design["n_walks_length_ell"]) <= 5000:
        Z, pi, corr, printed = wd.lifted_chain_stationary(design["Abar"], ell)
        out["lifted_pi"], out["lifted_corrected"], out["lifted_printed"] = pi, corr, printed
        out["lifted_states"] = len(Z)
    return {k: np.asarray(v) for k, v in out.items()}


def _filterpy_prior(sc: GossipKalmanFile, sys_: GossipSystem, steps: int) -> np.ndarray:
    """P(t|t-1) of filterpy's KalmanFilter on the stacked sensors (update, then predict)."""
    from filterpy.kalman import KalmanFilter

    kf = KalmanFilter(dim_x=sc.M, dim_z=sys_.C_all.shape[0])
    kf.F, kf.Q, kf.H, kf.R, kf.P = sc.F.copy(), sc.Q.copy(), sys_.C_all.copy(), sys_.R_all.copy(), sc.P0.copy()
    kf.x = np.zeros((sc.M, 1))
    out = []
    for _ in range(steps):
        out.append(kf.P.copy())
        kf.update(np.zeros((sys_.C_all.shape[0], 1)))
        kf.predict()
    return np.array(out)


# -- Monte Carlo stages -----------------------------------------------------------------------------
