"""The tables of a gossip-kalman run: every number a claim, a figure or a recording uses.

Design tables (also printed by `dse check`): the scalar design quantities (`design`: C.1 and its
spectra, D.1's decision, the witness walk and its constants, the observability rank, the
number of walks of minimal length, α = ‖F‖, α₀ of Lemma 14, the accurate range, ...), the
eigenvalues of F, Ā and its spectrum, per sensor its type, class and detectability, per class
of Ā its observability rank, every witness walk, the design matrices (F, Q, P0, Gramians, Σ_sub
in its corrected and printed forms, g_w0(cI), the limit of the centralized filter), Lemma 15's
tail bounds with k(J), the total-variation decay of the token chain and the reference series
(the centralized filter, the class floors and the Lyapunov envelope per slot).

Run tables: per sensor the law of P̂_n(T) (quantiles, Monte Carlo mean with its standard error,
the Theorem-8 law conditioned on the sensor, the centralized reference, their ratio and the
Loewner margin) and the entries of E P̂_n(T); quantiles over runs of log tr P̂_n(t) at the
statistic slots; the laws of a random sensor and of the Theorem-8 process at the record times
(quantile functions) with their KS distances; tails; Loewner margins; the sample runs (traces,
errors, states, estimates, matchings); NEES; the token chain; and the summary `metrics` of
sweeps. Logarithms are natural unless the column says log10.
"""
from __future__ import annotations

import math

import numpy as np
import pandas as pd

import dse.estimators.walk_detectability as wd
from dse.estimators.gikf_maps import FEATURES
from dse.estimators.gikf_monte_carlo import QUANTILES as RUN_QUANTILES
from dse.outputs.tables import spec

from .bounds import J_GRID
from .results import Design, Results, ScenarioDesign, ScenarioResults

FI = {name: i for i, name in enumerate(FEATURES)}
SC = ("scenario", "", "scenario name")
NODE = ("node", "1", "sensor n = 0..N-1")
LAW_PROBS = np.linspace(0.0, 1.0, 101)

DESIGN = spec("design", "scenario and scalar design quantity", [
    SC, ("quantity", "", "name (see definition)"), ("value", "as stated", "the value (booleans as 1/0; NaN: not "
                                                                          "computed or undecided)"),
    ("unit", "", "unit of the value"), ("definition", "", "what it is")])
F_EIGENVALUES = spec("f_eigenvalues", "eigenvalue of F", [
    SC, ("index", "1", "position (descending modulus)"), ("real", "1", "real part"), ("imag", "1", "imaginary part"),
    ("modulus", "1", "|λ|"),
    ("unobservable", "", "true when λ is an eigenvalue of F on the unobservable subspace of (F, C_all) (PBH test)")])
ABAR = spec("abar", "entry of Ā = E[A(t)] (eq (6))", [
    SC, ("row", "1", "row"), ("col", "1", "column"), ("value", "1", "Ā entry (a Monte Carlo estimate when not exact)"),
    ("standard_error", "1", "standard error of the estimate (0 when exact)")])
ABAR_SPECTRUM = spec("abar_spectrum", "eigenvalue of the symmetric part of Ā", [
    SC, ("index", "1", "position (ascending)"), ("eigenvalue", "1", "eigenvalue")])
SENSORS = spec("sensors", "scenario and sensor", [
    SC, NODE, ("type", "1", "sensor type (index into sensors.C)"), ("rows", "1", "observation rows m_n (0: actuator)"),
    ("class", "1", "communicating class of Ā the sensor belongs to"),
    ("detectable_alone", "", "(F, C_n) detectable (no D.1 needed for this sensor alone)"),
    ("blind_class", "", "its class of Ā cannot detect an eigenvalue |λ| ≥ 1"),
    ("divergence_rate", "1/slot", "2 log|λ| of the fastest mode its class cannot see (0: none)")])
CLASSES = spec("classes", "communicating class of Ā", [
    SC, ("class", "1", "class index"), ("size", "1", "number of sensors"), ("nodes", "", "its sensors"),
    ("observability_rank", "1", "numerical rank of the observability matrix of (F, stacked C of the class)"),
    ("unseen_moduli", "", "moduli |λ| ≥ 1 of the eigenvalues the class cannot see ('undecided' when unknown)")])
WITNESS_WALKS = spec("witness_walks", "node of an Ā-walk of the witness length with an invertible Gramian", [
    SC, ("walk", "1", "walk index (0 = the recorded witness w0 of D.1)"), ("position", "1", "position in the walk"),
    ("node", "1", "sensor"), ("recorded", "", "true for the recorded witness w0")],
    "Every walk of the minimal length ℓ whose observability Gramian is invertible (the windows of Lemma 15's "
    "all-windows bound), when there are at most 200,000 of them.")
MATRICES = spec("matrices", "entry of a design matrix", [
    SC, ("matrix", "", "F, Q, P0, x0 (a column), gramian (G_w0 of D.1), gramian_weighted (with R⁻¹, (117)), sigma_sub "
                       "(Σ_sub of Lemma 14, corrected), sigma_sub_printed ((118)-(120) as printed), g_w0(cI) c=... "
                       "(the witness composition at c·I), P_central_inf (limit of the centralized prior covariance, "
                       "DARE), P_central_T (the centralized prior covariance at the last slot)"),
    ("row", "1", "row"), ("col", "1", "column"), ("value", "state²", "entry")])
TAIL_BOUNDS = spec("tail_bounds", "threshold J of Lemma 15's tail bound", [
    SC, ("J", "state²", "threshold on ‖P̃(t)‖"), ("k_J", "1", "k(J) of (122): walks after which ‖X‖ > J is impossible "
                                                              "(−1: for every k)"),
    ("beta_single", "1", "β_t(J) with the single witness walk (NaN: not computed, Ā estimated or too large)"),
    ("beta_multi", "1", "β_t(J) over every witness window (NaN: not computed)")])
TV_DECAY = spec("tv_decay", "slot s of the token chain's total-variation decay (eq (83))", [
    SC, ("s", "slot", "steps of the Ā-chain"), ("tv_max", "1", "max over n of d_v(e_nᵀ Āˢ, uniform) (every n when N ≤ 64, "
                                                           "else 64 start nodes, 0 and 1 among them)"),
    ("bound", "1", "(√N/2) SLEM^s")])
REFERENCE_SERIES = spec("reference_series", "slot and reference curve", [
    SC, ("t", "slot", "slot"), ("series", "", "central (prior covariance of the centralized filter, same P0), floor "
                                              "(the centralized filter of one class of Ā) or envelope (f_0^t(P0), eq (73))"),
    ("class", "1", "class of Ā (floor only)"), ("trace", "state²", "trace (inf beyond float64)"),
    ("log_trace", "1", "natural log of the trace (finite for the rescaled envelope)"),
    ("roundoff", "state²", "first-order round-off bound of the matrix (spectral norm; the envelope's relative to its "
                           "scale)")])

NODES = spec("nodes", "scenario and sensor: the law of P̂_n(T) at the last slot", [
    SC, NODE, ("type", "1", "sensor type"), ("class", "1", "class of Ā"), ("T", "slot", "last slot"),
    ("runs", "1", "GIKF runs"), ("median_trace", "state²", "median over runs of tr P̂_n(T)"),
    ("q05_trace", "state²", "5% quantile of tr P̂_n(T)"), ("q95_trace", "state²", "95% quantile of tr P̂_n(T)"),
    ("mean_trace", "state²", "Monte Carlo mean of tr P̂_n(T) (the mean of μ can be infinite: prefer quantiles)"),
    ("mean_trace_se", "state²", "its standard error"),
    ("theorem8_median_trace", "state²", "median of tr P̃(T) given the last switch p̃(T−1) = n (the law P̂_n(T) has)"),
    ("mu_median_trace", "state²", "median of tr P̃(T) (the Theorem-8 law μ_T, all sensors)"),
    ("central_trace", "state²", "tr P_c(T), centralized filter (same P0)"),
    ("central_inf_trace", "state²", "tr of the centralized filter's limit (DARE; NaN when (F, C_all) is not detectable)"),
    ("floor_trace", "state²", "tr of the centralized filter of the sensor's class at T (its pathwise lower bound)"),
    ("ratio_median_to_central", "1", "median_trace / central_trace"),
    ("loewner_margin", "1", "min over the checked runs of λ_min(P̂_n(T) − floor)/max(1, ‖P̂_n(T)‖) (≥ 0 up to "
                            "round-off: P̂_n ⪰ its class floor)"),
    ("loewner_slack", "1", "the same with the round-off allowance added")])
NODE_ENTRIES = spec("node_entries", "scenario, sensor and entry of E P̂_n(T)", [
    SC, NODE, ("row", "1", "row"), ("col", "1", "column"),
    ("mean", "state²", "Monte Carlo mean over runs of the entry of P̂_n(T) (the sensor's error covariance averaged over "
                       "gossip paths)"), ("standard_error", "state²", "its standard error"),
    ("central", "state²", "entry of P_c(T)"), ("central_inf", "state²", "entry of the centralized limit (NaN if none)")])
QUANTILES = spec("quantiles", "statistic slot, sensor and quantile of log tr P̂_n(t) over runs", [
    SC, ("protocol", "", "protocol or comparison_protocol"), ("t", "slot", "slot"), NODE,
    ("probability", "1", "quantile level"), ("log_trace", "1", "quantile of log tr P̂_n(t) (natural log)")])
LAWS = spec("laws", "record time, law and probability: quantile functions of log tr", [
    SC, ("t", "slot", "record time"), ("law", "", "random_sensor (P̂_q(t), q uniform), theorem8 (P̃(t)), sensor (P̂_n(t)) "
                                                "or theorem8_given_last (P̃(t) given p̃(t−1) = n)"),
    ("node", "1", "sensor n (empty for random_sensor and theorem8)"), ("probability", "1", "level"),
    ("log_trace", "1", "quantile of log tr (natural log)"), ("samples", "1", "sample size")])
KS = spec("ks", "record time: Kolmogorov-Smirnov distances of the random sensor's law", [
    SC, ("t", "slot", "record time"), ("ks_to_mu_t", "1", "KS distance of log tr P̂_q(t) to the Theorem-8 law at t (0 "
                                                          "in law: an exact identity)"),
    ("ks_to_mu_T", "1", "KS distance to the Theorem-8 law at the last slot (→ 0 as t grows)"),
    ("runs", "1", "GIKF runs"), ("reference_runs", "1", "Theorem-8 runs"),
    ("noise_floor_95", "1", "1.36 √((n + m)/(n m)), the asymptotic 95% level of a two-sample KS distance")])
TAILS = spec("tails", "threshold J and sensor: tail probabilities", [
    SC, ("J", "state²", "threshold"), NODE, ("sup_t_tail", "1", "max over the statistic slots t ≥ 1 of the fraction of "
                                                                 "runs with ‖P̂_n(t)‖ ≥ J"),
    ("mu_tail", "1", "fraction of Theorem-8 runs with ‖P̃(T)‖ > J"), ("N_mu_bound", "1", "min(1, N × mu_tail), (27)")])
MARGINS = spec("margins", "statistic slot, sensor and Loewner comparison", [
    SC, ("t", "slot", "slot"), NODE, ("kind", "", "floor (P̂ ⪰ class floor), Q (P̂ ⪰ Q, t ≥ 1) or envelope "
                                                "(P̂ ⪯ f_0^t(P0))"),
    ("margin", "1", "min over the checked runs of the relative λ_min of the difference"),
    ("slack", "1", "the same with the round-off allowance of both sides added (a counterexample only if < 0)")])
SAMPLE_PATHS = spec("sample_paths", "sample run, series slot, sensor and state component", [
    SC, ("run", "1", "sample run"), ("t", "slot", "slot"), ("node", "1", "sensor (empty: the centralized filter)"),
    ("component", "1", "state component j"), ("trace", "state²", "tr P̂_n(t) (P_c(t) for the centralized filter)"),
    ("error", "state", "x_j(t) − x̂_{n,j}(t)"), ("state", "state", "x_j(t) (from the prior mean model.x0)"),
    ("estimate", "state", "x̂_{n,j}(t) = state − error")])
MATCHINGS = spec("matchings", "sample run, slot and sensor: the matching A(t)", [
    SC, ("run", "1", "sample run"), ("t", "slot", "slot t (the step t → t+1; A(0) = I)"), NODE,
    ("partner", "1", "→(n, t): the sensor whose pair n receives (n itself when unmatched)")])
NEES = spec("nees", "slot and filter: the normalised estimation error squared", [
    SC, ("t", "slot", "slot (empty: the window of slots that the sums cover)"), ("filter", "", "random_sensor or central"),
    ("mean", "1", "mean NEES over runs (χ²_M has mean M)"), ("runs", "1", "samples"),
    ("fraction_above", "1", "fraction above the 99% point of χ²_M (window rows)")])
TOKENS = spec("tokens", "slot and sensor: where token 0 is", [
    SC, ("t", "slot", "slot"), NODE, ("count", "1", "runs with p_0(t) = n"),
    ("probability", "1", "exact e_0ᵀ Āᵗ (the Ā-chain law, Proposition 6)")])
METRICS = spec("metrics", "metric and sensor (empty node: the whole network)", [
    SC, ("metric", "", "median_log_trP, q90_log_trP (log tr P̂ at the last slot over runs and sensors), "
                       "nonfinite_fraction, central_log_trP (log tr of the centralized limit), slem, c1, d1"),
    ("node", "1", "sensor (empty: network-wide)"), ("value", "as stated", "the value")])


# -- design -----------------------------------------------------------------------------------------------

def _scalar(b: dict, key: str, default=float("nan")) -> float:
    return float(np.asarray(b[key])) if key in b else default


def design_rows(d: ScenarioDesign) -> list[dict]:
    b, sc, a = d.bounds, d.scenario, d.assume
    F_eig = np.linalg.eigvals(sc.F)
    d1 = a.d1.holds
    w = d.witness()
    rows = [
        ("N", sc.N, "1", "sensors"), ("M", sc.M, "1", "state dimension"), ("slots", d.slots, "slot",
                                                                            "horizon simulated (cut where a blind class "
                                                                            "would leave the accurate range)"),
        ("runs", d.runs, "1", "GIKF runs"), ("reference_runs", d.reference_runs, "1", "Theorem-8 runs"),
        ("random_protocol", bool(b["random_protocol"]), "", "matchings i.i.d. per slot (not a replayed sequence)"),
        ("c1", a.c1, "", "C.1: Ā irreducible and aperiodic"), ("irreducible", a.irreducible, "", "Ā irreducible"),
        ("aperiodic", a.aperiodic, "", "every class of Ā aperiodic"),
        ("n_classes", len(a.classes), "1", "communicating classes of Ā"),
        ("unit_multiplicity", _scalar(b, "unit_multiplicity"), "1", "multiplicity of the eigenvalue 1 of Ā"),
        ("slem", _scalar(b, "slem"), "1", "second largest eigenvalue modulus of Ā"),
        ("min_eig_abar", _scalar(b, "min_eig_Abar"), "1", "smallest eigenvalue of Ā (−1: periodic)"),
        ("abar_exact", bool(b["Abar_exact"]), "", "Ā in closed form or by the exact recursion"),
        ("abar_draws", _scalar(b, "Abar_draws"), "1", "matchings behind a Monte Carlo Ā (0: exact)"),
        ("abar_se_max", float(np.max(b["Abar_se"])), "1", "largest standard error of an Ā entry"),
        ("d1", float("nan") if d1 is None else float(d1), "", "D.1: some Ā-walk has an invertible Gramian (NaN: "
                                                               "undecided)"),
        ("d1_covering", bool(b["d1_covering"]), "", "D.1 under the reading 'a walk covering every node'"),
        ("d1_certificate_ratio", _scalar(b, "d1_certificate_ratio"), "1",
         "largest σ_min/σ_max of [C_n; O_c F]: ≤ 300 eps certifies that D.1 fails"),
        ("witness_length", len(w) if w else float("nan"), "slot", "length ℓ of the recorded witness walk w0"),
        ("witness_ratio", _scalar(b, "witness_ratio"), "1", "λ_min/λ_max of the witness Gramian (the best ratio seen "
                                                            "when there is none)"),
        ("witness_max_rank", _scalar(b, "witness_max_rank"), "1", "largest Gramian rank over the walks searched"),
        ("walks_checked", _scalar(b, "walks_checked"), "1", "walks searched (length ≤ 6, equal futures merged)"),
        ("witness_walks", _scalar(b, "n_windows", float("nan")), "1",
         "number of Ā-walks of the minimal length ℓ with an invertible Gramian (−1: more than 200,000)"),
        ("walks_of_length_ell", _scalar(b, "n_walks_length_ell"), "1", "number of Ā-walks of length ℓ"),
        ("gramian_condition", _scalar(b, "gramian_cond"), "1", "condition number of the weighted witness Gramian"),
        ("alpha", _scalar(b, "alpha"), "1", "‖F‖ (spectral norm), α of (122)"),
        ("q_norm", _scalar(b, "qnorm"), "state²", "‖Q‖"),
        ("alpha0", _scalar(b, "alpha0"), "state²", "α₀ = λ_max(Σ_sub) along w0 (Lemma 14, corrected)"),
        ("alpha0_multi", _scalar(b, "alpha0_multi"), "state²", "max of α₀ over every witness window"),
        ("lifted_states", _scalar(b, "lifted_states"), "1", "states of the lifted window chain (132)"),
        ("spectral_radius_F", float(np.abs(F_eig).max()), "1", "max |λ(F)|"),
        ("lambda_min_Q", float(np.linalg.eigvalsh(sc.Q)[0]), "state²", "λ_min(Q) (S.1 needs Q ≻ 0)"),
        ("central_detectable", bool(b["central_detectable"]), "", "(F, C_all) detectable"),
        ("central_observable", bool(b["central_observable"]), "", "(F, C_all) observable"),
        ("observability_rank", _scalar(b, "observability_rank"), "1", "numerical rank of the observability matrix of "
                                                                      "(F, C_all)"),
        ("observability_ratio", _scalar(b, "observability_ratio"), "1", "its smallest σ/σ_max"),
        ("accurate_range", _scalar(b, "accurate_range"), "state²", "largest ‖X‖ at which the Joseph form still "
                                                                   "resolves every innovation variance"),
        ("max_divergence_rate", float(np.max(b["divergence_rate"])), "1/slot", "largest 2 log|λ| a class cannot see"),
        ("central_inf_trace", float(np.trace(b["P_central_inf"])) if "P_central_inf" in b else float("nan"), "state²",
         "tr of the centralized filter's limit (DARE)"),
    ]
    return [{"scenario": sc.name, "quantity": q, "value": float(v), "unit": u, "definition": de} for q, v, u, de in rows]


def design_tables(design: Design) -> list:
    out = {k: [] for k in ("design", "f_eig", "abar", "abar_spec", "sensors", "classes", "walks", "matrices", "tails",
                           "tv", "ref")}
    for d in design.scenarios.values():
        _design_one(d, out)
    return [(DESIGN, pd.DataFrame(out["design"], columns=DESIGN.column_names)),
            (F_EIGENVALUES, pd.concat(out["f_eig"], ignore_index=True)),
            (ABAR, pd.concat(out["abar"], ignore_index=True)),
            (ABAR_SPECTRUM, pd.concat(out["abar_spec"], ignore_index=True)),
            (SENSORS, pd.concat(out["sensors"], ignore_index=True)),
            (CLASSES, pd.DataFrame(out["classes"], columns=CLASSES.column_names)),
            (WITNESS_WALKS, pd.DataFrame(out["walks"], columns=WITNESS_WALKS.column_names).astype(
                {"walk": "int64", "position": "int64", "node": "int64", "recorded": "bool"})),
            (MATRICES, pd.DataFrame(out["matrices"], columns=MATRICES.column_names)),
            (TAIL_BOUNDS, pd.DataFrame(out["tails"], columns=TAIL_BOUNDS.column_names)),
            (TV_DECAY, pd.concat(out["tv"], ignore_index=True)),
            (REFERENCE_SERIES, pd.concat(out["ref"], ignore_index=True))]


def _design_one(d: ScenarioDesign, out: dict) -> None:
    b, sc, a = d.bounds, d.scenario, d.assume
    name, N, M = sc.name, sc.N, sc.M
    out["design"] += design_rows(d)
    lam = np.linalg.eigvals(sc.F)
    lam = lam[np.argsort(-np.abs(lam), kind="stable")]
    hidden_modes = wd.unobservable_modes(sc.F, sc.system.C_all)[1]
    hidden = [any(abs(x - u) <= 1e-9 * max(1.0, abs(u)) for u in hidden_modes) for x in lam]
    out["f_eig"].append(pd.DataFrame({"scenario": name, "index": np.arange(M), "real": lam.real, "imag": lam.imag,
                                      "modulus": np.abs(lam), "unobservable": hidden}))
    A, se = np.asarray(b["Abar"], float), np.asarray(b["Abar_se"], float)
    r, c = np.indices(A.shape)
    out["abar"].append(pd.DataFrame({"scenario": name, "row": r.ravel(), "col": c.ravel(), "value": A.ravel(),
                                     "standard_error": se.ravel()}))
    ev = np.asarray(b["Abar_eigenvalues"], float)
    out["abar_spec"].append(pd.DataFrame({"scenario": name, "index": np.arange(len(ev)), "eigenvalue": ev}))
    rows = np.array([c_.shape[0] for c_ in sc.C_types])[list(sc.types)]
    out["sensors"].append(pd.DataFrame({"scenario": name, "node": np.arange(N), "type": np.array(sc.types), "rows": rows,
                                        "class": np.asarray(b["class_of"]),
                                        "detectable_alone": np.asarray(b["sensor_detectable"], bool),
                                        "blind_class": np.asarray(b["blind"], bool),
                                        "divergence_rate": np.asarray(b["divergence_rate"], float)}))
    ranks = np.asarray(b["class_observability_rank"])
    for k, (cls, blind) in enumerate(zip(a.classes, a.blind)):
        out["classes"].append({"scenario": name, "class": k, "size": len(cls), "nodes": " ".join(map(str, cls)),
                               "observability_rank": int(ranks[k]),
                               "unseen_moduli": "undecided" if blind is None else " ".join(f"{abs(x):.17g}" for x in blind)})
    w = d.witness()
    if w:
        windows = list(a.d1.search.windows) or [w]
        ordered = [tuple(w)] + [tuple(v) for v in windows if tuple(v) != tuple(w)]
        for k, walk in enumerate(ordered):
            out["walks"] += [{"scenario": name, "walk": k, "position": i, "node": int(n), "recorded": k == 0}
                             for i, n in enumerate(walk)]
    mats = [("F", sc.F), ("Q", sc.Q), ("P0", sc.P0), ("x0", sc.x0[:, None])]
    for key in ("gramian", "gramian_weighted", "sigma_sub", "sigma_sub_printed", "P_central_inf"):
        if key in b:
            mats.append((key, b[key]))
    if "g_of_cI" in b:
        mats += [(f"g_w0(cI) c={c_:g}", G) for c_, G in zip(b["g_of_cI_c"], b["g_of_cI"])]
    mats.append(("P_central_T", b["P_central"][-1]))
    for key, X in mats:
        X = np.atleast_2d(np.asarray(X, float))
        out["matrices"] += [{"scenario": name, "matrix": key, "row": i, "col": j, "value": float(X[i, j])}
                            for i in range(X.shape[0]) for j in range(X.shape[1])]
    if "kJ" in b:
        for J, k, bs, bm in zip(J_GRID, b["kJ"], b["beta_single"], b["beta_multi"]):
            out["tails"].append({"scenario": name, "J": float(J), "k_J": int(k), "beta_single": float(bs),
                                 "beta_multi": float(bm)})
    tv = np.asarray(b["tv"], float)
    out["tv"].append(pd.DataFrame({"scenario": name, "s": np.arange(len(tv)), "tv_max": tv,
                                   "bound": 0.5 * math.sqrt(N) * float(b["slem"]) ** np.arange(len(tv))}))
    out["ref"].append(reference_series(d))


def reference_series(d: ScenarioDesign) -> pd.DataFrame:
    b, name = d.bounds, d.scenario.name
    T1 = len(b["P_central"])
    t = np.arange(T1)
    parts = []

    def add(series, cls, trace, log_trace, roundoff):
        parts.append(pd.DataFrame({"scenario": name, "t": t, "series": series, "class": pd.array([cls] * T1, "Int64"),
                                   "trace": trace, "log_trace": log_trace, "roundoff": roundoff}))

    with np.errstate(divide="ignore", over="ignore"):
        tr = np.trace(b["P_central"], axis1=1, axis2=2)
        add("central", None, tr, np.log(tr), np.asarray(b["P_central_err"], float))
        for k in range(b["P_floor"].shape[1]):
            trf = np.trace(b["P_floor"][:, k], axis1=1, axis2=2)
            add("floor", k, trf, np.log(trf), np.asarray(b["P_floor_err"][:, k], float))
        unit_tr = np.trace(b["envelope"], axis1=1, axis2=2)
        log_env = np.asarray(b["envelope_log"], float) + np.log(unit_tr)
        add("envelope", None, np.exp(log_env), log_env, np.asarray(b["envelope_err"], float))
    return pd.concat(parts, ignore_index=True)


# -- run ----------------------------------------------------------------------------------------------------

def run_tables(res: Results) -> list:
    specs = (NODES, NODE_ENTRIES, QUANTILES, LAWS, KS, TAILS, MARGINS, SAMPLE_PATHS, MATCHINGS, NEES, TOKENS, METRICS)
    parts: dict[str, list] = {s.name: [] for s in specs}
    for r in res.scenarios.values():
        for s, frame in _run_one(r):
            parts[s.name].append(frame)
    out = design_tables(res.design())
    for s in specs:
        frames = [f for f in parts[s.name] if len(f)]
        out.append((s, pd.concat(frames, ignore_index=True) if frames else pd.DataFrame(columns=s.column_names)))
    return out


def _trace_at(feat: np.ndarray) -> np.ndarray:
    with np.errstate(over="ignore"):
        return np.exp(feat[FI["log_trace"]])


def _run_one(r: ScenarioResults):
    g, ref, b, sc = r.gikf, r.reference, r.bounds, r.scenario
    name, N, M = sc.name, sc.N, sc.M
    times = [int(t) for t in g["times"]]
    T = times[-1]
    i_T = len(times) - 1
    tr_n = _trace_at(g["feat_n"][i_T])                               # (runs, N)
    tr_ref = _trace_at(ref["features"][-1])
    last = ref["last"][-1]
    central_T = b["P_central"][-1]
    inf = b.get("P_central_inf")
    floor_T = b["P_floor"][-1][b["class_of"]]                          # (N, M, M)
    runs = int(g["runs"])
    mean = g["final_sum"] / runs
    var = np.maximum(g["final_sq"] / runs - mean ** 2, 0.0)
    se = np.sqrt(var / max(runs - 1, 1))
    stat = g["stat_slots"]
    i_last = len(stat) - 1
    with np.errstate(invalid="ignore"):
        med = np.nanmedian(tr_n, axis=0) if np.isfinite(tr_n).any() else np.full(N, np.nan)
        cond = np.array([np.median(tr_ref[last == n]) if (last == n).any() else np.nan for n in range(N)])
        nodes = pd.DataFrame({
            "scenario": name, "node": np.arange(N), "type": np.array(sc.types), "class": np.asarray(b["class_of"]), "T": T,
            "runs": runs, "median_trace": med, "q05_trace": np.nanquantile(tr_n, 0.05, axis=0),
            "q95_trace": np.nanquantile(tr_n, 0.95, axis=0), "mean_trace": np.trace(mean, axis1=1, axis2=2),
            "mean_trace_se": np.nanstd(tr_n, axis=0, ddof=1) / math.sqrt(max(runs, 1)),
            "theorem8_median_trace": cond, "mu_median_trace": float(np.median(tr_ref)),
            "central_trace": float(np.trace(central_T)),
            "central_inf_trace": float(np.trace(inf)) if inf is not None else float("nan"),
            "floor_trace": np.trace(floor_T, axis1=1, axis2=2), "ratio_median_to_central": med / float(np.trace(central_T)),
            "loewner_margin": g["margins"][i_last, 0] if "margins" in g else np.nan,
            "loewner_slack": g["slack"][i_last, 0] if "slack" in g else np.nan})
    yield NODES, nodes
    n_, r_, c_ = np.indices((N, M, M))
    yield NODE_ENTRIES, pd.DataFrame({
        "scenario": name, "node": n_.ravel(), "row": r_.ravel(), "col": c_.ravel(), "mean": mean.ravel(),
        "standard_error": se.ravel(), "central": np.broadcast_to(central_T, (N, M, M)).ravel(),
        "central_inf": (np.broadcast_to(inf, (N, M, M)).ravel() if inf is not None else np.nan)})
    for label, gg in (("protocol", g), ("comparison_protocol", r.comparison)):
        if gg is None:
            continue
        q = gg["quantiles"]                                          # (S, N, P)
        s_, n_, p_ = np.indices(q.shape)
        yield QUANTILES, pd.DataFrame({"scenario": name, "protocol": label, "t": gg["stat_slots"][s_.ravel()],
                                       "node": n_.ravel(), "probability": np.asarray(RUN_QUANTILES)[p_.ravel()],
                                       "log_trace": q.ravel()})
    yield LAWS, _laws(r)
    yield KS, _ks(r)
    yield TAILS, _tails(r)
    if "margins" in g:
        m = g["margins"]                                             # (S, 3, N)
        s_, k_, n_ = np.indices(m.shape)
        yield MARGINS, pd.DataFrame({"scenario": name, "t": stat[s_.ravel()], "node": n_.ravel(),
                                     "kind": np.array(["floor", "Q", "envelope"])[k_.ravel()], "margin": m.ravel(),
                                     "slack": g["slack"].ravel()})
    yield SAMPLE_PATHS, _sample_paths(r)
    pp = g["path_partners"]                                          # (sp, slots, N)
    k_, t_, n_ = np.indices(pp.shape)
    yield MATCHINGS, pd.DataFrame({"scenario": name, "run": k_.ravel(), "t": t_.ravel(), "node": n_.ravel(),
                                   "partner": pp.ravel()})
    yield NEES, _nees(r)
    yield TOKENS, _tokens(r)
    yield METRICS, metrics_frame(r)


def _quantile_rows(name, t, law, node, x) -> list[dict]:
    x = np.asarray(x, float)
    x = x[np.isfinite(x)]
    if not x.size:
        return []
    qs = np.quantile(x, LAW_PROBS)
    return [{"scenario": name, "t": t, "law": law, "node": node, "probability": float(p), "log_trace": float(v),
             "samples": int(x.size)} for p, v in zip(LAW_PROBS, qs)]


def _laws(r: ScenarioResults) -> pd.DataFrame:
    g, ref, name = r.gikf, r.reference, r.name
    rows = []
    times = [int(t) for t in g["times"]]
    for i, t in enumerate(times):
        rows += _quantile_rows(name, t, "random_sensor", None, g["feat_q"][i][FI["log_trace"]])
        rows += _quantile_rows(name, t, "theorem8", None, ref["features"][i][FI["log_trace"]])
    i = len(times) - 1
    last = ref["last"][-1]
    for n in range(r.scenario.N):
        rows += _quantile_rows(name, times[-1], "sensor", n, g["feat_n"][i][FI["log_trace"]][:, n])
        rows += _quantile_rows(name, times[-1], "theorem8_given_last", n, ref["features"][-1][FI["log_trace"]][last == n])
    frame = pd.DataFrame(rows, columns=LAWS.column_names)
    return frame.astype({"node": "Int64"})


def _ks_distance(a: np.ndarray, b: np.ndarray) -> float:
    a, b = np.sort(a[np.isfinite(a)]), np.sort(b[np.isfinite(b)])
    if not a.size or not b.size:
        return float("nan")
    grid = np.concatenate([a, b])
    return float(np.abs(np.searchsorted(a, grid, side="right") / a.size - np.searchsorted(b, grid, side="right") / b.size).max())


def _ks(r: ScenarioResults) -> pd.DataFrame:
    g, ref = r.gikf, r.reference
    mu_T = ref["features"][-1][FI["log_trace"]]
    n, m = r.runs, ref["features"].shape[-1]
    rows = []
    for i, t in enumerate(int(t) for t in g["times"]):
        if t < 1:
            continue
        x = g["feat_q"][i][FI["log_trace"]]
        rows.append({"scenario": r.name, "t": t, "ks_to_mu_t": _ks_distance(x, ref["features"][i][FI["log_trace"]]),
                     "ks_to_mu_T": _ks_distance(x, mu_T), "runs": n, "reference_runs": m,
                     "noise_floor_95": 1.36 * math.sqrt((n + m) / (n * m))})
    return pd.DataFrame(rows, columns=KS.column_names)


def _tails(r: ScenarioResults) -> pd.DataFrame:
    g, ref, N = r.gikf, r.reference, r.scenario.N
    ex = g["exceed"].astype(float)
    rows_ok = (g["stat_slots"] >= 1) & (ex[:, 0, 0] >= 0)
    S = ex[rows_ok].max(axis=0) / r.runs if rows_ok.any() else np.full((N, len(J_GRID)), np.nan)
    with np.errstate(over="ignore"):
        lam = np.exp(ref["features"][-1][FI["log_lam_max"]])
    mu = np.array([(lam > J).mean() for J in J_GRID])
    n_, j_ = np.indices((N, len(J_GRID)))
    return pd.DataFrame({"scenario": r.name, "J": J_GRID[j_.ravel()], "node": n_.ravel(), "sup_t_tail": S.ravel(),
                         "mu_tail": mu[j_.ravel()], "N_mu_bound": np.minimum(1.0, N * mu)[j_.ravel()]})


def _sample_paths(r: ScenarioResults) -> pd.DataFrame:
    g, b, sc = r.gikf, r.bounds, r.scenario
    slots = g["series_slots"]
    sp, S, N, M = g["path_err"].shape
    k_, s_, n_, j_ = np.indices((sp, S, N, M))
    state = g["path_state"][k_, s_, j_]
    err = g["path_err"].ravel()
    sensors = pd.DataFrame({"scenario": sc.name, "run": k_.ravel(), "t": slots[s_.ravel()],
                            "node": pd.array(n_.ravel(), "Int64"), "component": j_.ravel(),
                            "trace": g["path_trace"][k_, s_, n_].ravel(), "error": err, "state": state.ravel(),
                            "estimate": state.ravel() - err})
    k_, s_, j_ = np.indices((sp, S, M))
    central_tr = np.trace(b["P_central"], axis1=1, axis2=2)[slots]
    cst = g["path_state"].ravel()
    cerr = g["path_err_c"].ravel()
    central = pd.DataFrame({"scenario": sc.name, "run": k_.ravel(), "t": slots[s_.ravel()],
                            "node": pd.array([None] * cerr.size, "Int64"), "component": j_.ravel(),
                            "trace": central_tr[s_.ravel()], "error": cerr, "state": cst, "estimate": cst - cerr})
    return pd.concat([sensors, central], ignore_index=True)


def _nees(r: ScenarioResults) -> pd.DataFrame:
    g, name = r.gikf, r.name
    rows = []
    for k, t in enumerate(int(t) for t in g["nees_slots"]):
        for label, arr in (("random_sensor", g["nees_q"][k]), ("central", g["nees_c"][k])):
            rows.append({"scenario": name, "t": t, "filter": label, "mean": float(np.nanmean(arr)),
                         "runs": int(np.isfinite(arr).sum()), "fraction_above": float("nan")})
    s, above, n, sc_, above_c, n_c = (float(x) for x in g["nees"])
    rows.append({"scenario": name, "t": None, "filter": "random_sensor", "mean": s / n if n else float("nan"),
                 "runs": r.runs, "fraction_above": above / n if n else float("nan")})
    rows.append({"scenario": name, "t": None, "filter": "central", "mean": sc_ / n_c if n_c else float("nan"),
                 "runs": r.runs, "fraction_above": above_c / n_c if n_c else float("nan")})
    return pd.DataFrame(rows, columns=NEES.column_names).astype({"t": "Int64"})


def _tokens(r: ScenarioResults) -> pd.DataFrame:
    g, A, N = r.gikf, np.asarray(r.bounds["Abar"], float), r.scenario.N
    tok = g["token0"]                                               # (steps + 1, N)
    law = np.zeros((len(tok), N))
    p = np.eye(N)[0]
    for t in range(len(tok)):
        law[t] = p
        p = p @ A
    t_, n_ = np.indices(tok.shape)
    return pd.DataFrame({"scenario": r.name, "t": t_.ravel(), "node": n_.ravel(), "count": tok.ravel(),
                         "probability": law.ravel()})


def metrics_frame(r: ScenarioResults) -> pd.DataFrame:
    """Network-wide summary metrics (sweeps plot them) and the per-sensor median and q90 of log tr P̂_n(T)."""
    g, b = r.gikf, r.bounds
    log_tr = np.asarray(g["feat_n"], float)[-1, FI["log_trace"]]      # (runs, N) at the last record time
    finite = log_tr[np.isfinite(log_tr)]
    net = {"median_log_trP": float(np.median(finite)) if finite.size else float("inf"),
           "q90_log_trP": float(np.quantile(finite, 0.9)) if finite.size else float("inf"),
           "nonfinite_fraction": float(1.0 - finite.size / log_tr.size),
           "central_log_trP": float(np.log(np.trace(b["P_central_inf"]))) if "P_central_inf" in b else float("nan"),
           "slem": float(b["slem"]), "c1": float(r.c1), "d1": float(r.d1)}
    rows = [{"scenario": r.name, "metric": k, "node": None, "value": v} for k, v in net.items()]
    with np.errstate(invalid="ignore"):
        for n in range(r.scenario.N):
            x = log_tr[:, n][np.isfinite(log_tr[:, n])]
            rows.append({"scenario": r.name, "metric": "median_log_trP", "node": n,
                         "value": float(np.median(x)) if x.size else float("inf")})
            rows.append({"scenario": r.name, "metric": "q90_log_trP", "node": n,
                         "value": float(np.quantile(x, 0.9)) if x.size else float("inf")})
    return pd.DataFrame(rows, columns=METRICS.column_names).astype({"node": "Int64"})
