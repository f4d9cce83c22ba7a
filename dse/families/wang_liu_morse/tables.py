"""The tables of a hybrid-observer run: every number a claim, a figure or a recording uses.

Design tables (also printed by `dse check`): per agent the local design and its checks, the
local matrices and spectra, the scalar design quantities in every variant the paper gives (ρ,
α, r, q of (22), (21)+(19) and the minimal one, each for the Lemma-5 and the printed α and for
the design and the printed λ; σ, r and q of (27)), the graphs and their properties, the spectra
of A and of the centralized observer, each run's timing and the constants of its bounds, and
the event times. Run tables add the sampled Lemma 5/6 checks, per interval the matrices of
(42)-(43) and the communication, per event index and per agent the errors against (41), (51)
and the centralized reference (`events`, `nodes`), the stored samples of the continuous-time
errors and states, trial 0's estimator iterates and source sets, the decay-rate fits, the worst
cases the claims are decided on (`checks`) and the summary `metrics` of sweeps.
"""
from __future__ import annotations

import math
from decimal import Decimal

import numpy as np
import pandas as pd

from dse.outputs.tables import matrix_rows, spec

from . import simulation
from .monitor import COUNTS, MAXIMA, WORST
from .design import Q_KEYS, alpha_power, constants, lambda_variants
from .stages import Parts

SC = ("scenario", "", "scenario name (the paper's reproduction has 'paper' and 'generic')")
RUN = ("run", "", "run name")
AGENT = ("node", "1", "agent i = 1..m")

AGENTS = spec("agents", "scenario and agent", [
    SC, AGENT, ("n_i", "1", "rank of agent i's observability matrix (size of its local observer)"),
    ("outputs", "1", "s_i, the rows of C_i"), ("kappa_L", "1", "condition number of L_i"),
    ("spectral_abscissa", "1/time", "largest real part of the eigenvalues of Ā_i + K_i C̄_i"),
    ("abscissa_roundoff", "1/time", "round-off allowance of those eigenvalues (Bauer-Fike)"),
    ("c_i", "1", "sup_τ ||e^((Ā_i + K_i C̄_i)τ)|| e^(λ̄τ) of (15)"),
    ("residual_C", "1", "max |C_i - C̄_i L_i| / ||C_i||"), ("residual_A", "1", "max |L_i A - Ā_i L_i| / (||A|| ||L_i||)"),
    ("discarded", "1", "largest singular value the rank decisions discarded (relative)"),
    ("row_space_distance", "1", "distance of L_i's rows from the computed observable space (0 unless L_i is given)"),
    ("observability_rank", "1", "rank of the observability matrix of (C̄_i, Ā_i) (= n_i)"),
    ("footnote3_deviation", "1", "max |P_i(M L_i) - P_i(L_i)| over an orthogonal M and an M of condition 100"),
    ("kappa_ML", "1", "largest condition number of M L_i in that comparison")])
LOCAL_MATRICES = spec("local_matrices", "entry of a per-agent design matrix", [
    SC, AGENT, ("matrix", "", "L (n_i x n), Abar = Ā_i, Cbar = C̄_i, K = K_i, F = Ā_i + K_i C̄_i, Q = Q_i = L_i'(L_i L_i')^-1, "
                              "P = P_i = I - Q_i L_i"),
    ("row", "1", "row index"), ("col", "1", "column index"), ("value", "as the matrix", "the entry")])
LOCAL_SPECTRA = spec("local_spectra", "eigenvalue of a local observer matrix Ā_i + K_i C̄_i (ascending real part)", [
    SC, AGENT, ("index", "1", "position"), ("real", "1/time", "real part"), ("imag", "1/time", "imaginary part")])
SYSTEM_SPECTRA = spec("system_spectra", "eigenvalue of A or of the centralized observer A + K_c C", [
    SC, ("matrix", "", "A, or central (A + K_c C with the design's central_poles)"), ("index", "1", "position"),
    ("real", "1/time", "real part"), ("imag", "1/time", "imaginary part")])
DESIGN = spec("design", "scalar design quantity (and λ for the ones that depend on it)", [
    SC, ("quantity", "", "name (see definition)"),
    ("lam", "1/time", "the λ it is computed for (the design's, or the printed one); NaN when it does not depend on λ"),
    ("value", "as stated", "the value as a float (q values beyond 2^53 are rounded here: see exact)"),
    ("exact", "", "the exact value when it is an integer, a decimal or a word (empty otherwise)"),
    ("unit", "", "unit of the value"), ("definition", "", "what it is")],
    "q and r are computed in exact decimal arithmetic (1 - α can be 10^-1000); ρ by an exhaustive search "
    "(bracketed in [rho, rho_upper] when the search is cut; rho_method says which and how many products).")
GRAPHS = spec("graphs", "arc j -> i of a neighbour graph (j ∈ N_i, self-arcs not listed)", [
    SC, ("graph", "1", "graph index (1-based, as in runs.graph)"), ("name", "", "graph name"),
    ("receiver", "1", "agent i"), ("sender", "1", "agent j")])
GRAPH_PROPERTIES = spec("graph_properties", "neighbour graph", [
    SC, ("graph", "1", "graph index (1-based)"), ("name", "", "graph name"), ("arcs", "1", "arcs j -> i, j != i"),
    ("strongly_connected", "", "every agent reaches every other (a hypothesis of the theorems)"),
    ("symmetric", "", "j ∈ N_i iff i ∈ N_j (needed by the rule (25))"),
    ("vertex_redundant", "", "still strongly connected without any one agent (Section 5)")])
RUNS = spec("runs", "simulated run", [
    SC, RUN, ("timing", "", "sync, async (jittered iteration times) or offset (event-time offsets)"),
    ("switching", "", "fixed, alternate_interval or alternate_iteration"), ("graph", "1", "the graph of a fixed switching"),
    ("rule", "", "mean (13) or symmetric (25)"), ("q", "1", "iterations per interval"),
    ("q_label", "", "where q comes from: given, theory (22), symmetric (27)"), ("Delta", "time", "Δ"),
    ("beta", "time", "β"), ("epsilon", "time", "ε of (24): the largest jitter bound or offset"),
    ("intervals", "1", "event intervals S"), ("horizon", "time", "S T"), ("noise", "", "input b cos(ωt) on"),
    ("ideal", "", "ē(0) = 0"), ("monte_carlo", "", "random initial conditions for trials 1.."),
    ("leave_agent", "1", "the agent that leaves (NA: none)"), ("leave_at", "time", "when it leaves"),
    ("rejoin_at", "time", "when it re-joins"), ("leave_policy", "", "reinit, resume or open_loop"),
    ("reference_run", "", "the synchronous run an asynchronous one must reproduce"),
    ("b", "1", "q e^(||A||T)|Q| of (45)"), ("c", "1", "max_i c_i of (15)"),
    ("d", "1", "c b e^(λT)/(1 - e^(-(λ̄-λ)T)) of (51)"), ("b_sym", "1", "q e^(||A||T)||Q||_2 (55)"),
    ("d_sym", "1", "d with b_sym: the 2-norm constant of the symmetric case"),
    ("g", "1", "2mq||A||e^(||A||(T+β)) of (62)-(63)"), ("decay", "1", "e^(-λT), the bound of (44) and (54)"),
    ("p", "1", "floor(q/N), N = (m-1)²+1: the blocks of (20)"),
    ("alpha_p", "1", "α^p with the Lemma-5 α of ρ's upper end (the safe one: α grows with ρ); 1 for p = 0, and 1 "
                     "when no upper bound of ρ below 1 is known (every step has |P(S⊗I)| <= 1)")])
EVENT_TIMES = spec("event_times", "event time t_is of an agent in a run", [
    SC, RUN, AGENT, ("s", "1", "event index (0: the start t_i0)"), ("t", "time", "t_is = t_i0 + sT"),
    ("t_ns", "ns", "the same in integer nanoseconds, as simulated")])
LEMMA_SAMPLES = spec("lemma_samples", "sampled check of Lemma 5 or 6", [
    SC, ("quantity", "", "name"), ("value", "1", "value"), ("definition", "", "what it is")])
VERTEX_LOSS = spec("vertex_loss", "agent removed (Section 5's design for losing one agent; paper reproduction)", [
    SC, ("removed", "1", "the agent removed"), ("jointly_observable", "", "the others stay jointly observable"),
    ("strongly_connected", "", "every graph stays strongly connected without it"),
    ("rho_d", "1", "upper bound of ρ of the others (-1: not jointly observable)"),
    ("q_d", "", "q of (22) for the others with the printed λ (exact integer; empty when none)")])
MISMATCH = spec("mismatch_series", "time of the model-mismatch demonstration (Section 4; paper reproduction)", [
    SC, ("t", "time", "time"), ("x_norm", "state", "||x(t)||"),
    ("error_exact_model", "state", "error of a centralized Kalman filter with the exact A"),
    ("error_mismatch", "state", "error of the same filter with A + δE, ||δE|| = 1e-3")])
INTERVALS = spec("intervals", "event interval s of a run (the matrices of (41) and the communication)", [
    SC, RUN, ("s", "1", "interval [(s-1)T, sT)"), ("participating", "1", "agents taking part"),
    ("nominal_graph", "1", "the graph at the first nominal instant (s-1)T + β (1-based)"),
    ("A_mixed", "1", "|A(s)| (mixed norm) of (42); NaN when an agent sits the interval out"),
    ("B_mixed", "1", "|B(s)| of (43)"), ("G_mixed", "1", "|G(s)| of (61') (0 without offsets)"),
    ("A_2", "1", "||A(s)||_2"), ("B_2", "1", "||B(s)||_2"),
    ("Phi_max", "1", "max over the evaluated k of |Φ_s(k)| (first intervals only)"),
    ("source_mismatch", "1", "source-set entries S_is(k) that differ from N_i((s-1)T+(k-1)Δ+β)"),
    ("source_entries", "1", "source-set entries compared"), ("decay", "1", "e^(-λT)")])
EVENTS = spec("events", "event index s of a run (network-wide: |·| is the max over agents)", [
    SC, RUN, ("s", "1", "event index"), ("t", "time", "t_1s, agent 1's event time"),
    ("trials", "1", "trials"), ("error_trial0", "state", "|e(s)| = max_i ||e_i(t_is)|| of trial 0"),
    ("error_mean", "state", "mean over trials of |e(s)|"), ("error_se", "state", "its standard error"),
    ("error_max", "state", "max over trials of |e(s)|"),
    ("ebar_trial0", "state", "|ē(s)| = max_i ||ē_i(t_is)|| of trial 0"),
    ("bound51_trial0", "state", "e^(-λsT)(|e(0)| + d|ē(0)|) of trial 0 ((51); rule (13) runs without input)"),
    ("bound51_max", "state", "max over trials of that bound"),
    ("ratio51_max", "1", "max over trials of |e(s)| / bound (51)"),
    ("floor_trial0", "state", "the round-off allowance of trial 0 at s (tolerance × size of the states)"),
    ("carried_trial0", "state", "the local observers' round-off carried to s through (41) (added to the bounds)")])
NODES = spec("nodes", "agent and event index of a run", [
    SC, RUN, AGENT, ("s", "1", "event index"), ("t", "time", "t_is"),
    ("error_trial0", "state", "||e_i(t_is)|| after the reset, trial 0"),
    ("error_before_reset", "state", "||e_i(t_is⁻)||, trial 0"),
    ("error_mean", "state", "mean over trials of ||e_i(t_is)||"), ("error_se", "state", "its standard error"),
    ("error_max", "state", "max over trials"), ("ebar_trial0", "state", "||ē_i(t_is)|| = ||w_i - L_i x||, trial 0"),
    ("bound41_trial0", "state", "Σ_j ||A_ij(s)|| ||e_j(s-1)|| + Σ_j ||B_ij(s)|| ||ē_j(s-1)|| + ||G_i(s)|| ||x((s-1)T)||: "
                                "agent i's row of (41)/(61') in norms, trial 0 (NaN with an input or an absent agent)"),
    ("bound51_trial0", "state", "e^(-λsT)(|e(0)| + d|ē(0)|) of trial 0 (bounds every agent; rule (13) runs)"),
    ("central_trial0", "state", "||x_c(t_is) - x(t_is)|| of the centralized observer, trial 0"),
    ("central_mean", "state", "its mean over trials"),
    ("ratio_to_central", "1", "error_mean / central_mean")])
NODE_SERIES = spec("node_series", "stored sample time and agent of a run", [
    SC, RUN, ("t", "time", "time"), AGENT, ("error_trial0", "state", "||x_i(t) - x(t)||, trial 0"),
    ("error_mean", "state", "mean over trials"), ("error_max", "state", "max over trials")])
NETWORK_SERIES = spec("network_series", "stored sample time of a run", [
    SC, RUN, ("t", "time", "time"), ("error_trial0", "state", "max_i ||x_i(t) - x(t)||, trial 0"),
    ("central_trial0", "state", "||x_c(t) - x(t)|| of the centralized observer, trial 0"),
    ("central_mean", "state", "its mean over trials"),
    ("kalman_trial0", "state", "error of a centralized Kalman filter (filterpy), trial 0 (runs with an input)"),
    ("x_norm_trial0", "state", "||x(t)||, trial 0"),
    ("bound_printed_trial0", "state", "e^(||A||T - λt)(|e(0)| + d|ē(0)|): Theorem 1's continuous bound as printed"),
    ("bound_corrected_trial0", "state", "e^((||A||+λ)T - λt)(|e(0)| + d|ē(0)|): the corrected bound")])
STATE_SERIES = spec("state_series", "stored sample time, state component and source of a run (trial 0)", [
    SC, RUN, ("t", "time", "time"), ("source", "", "truth (x), agent (x_i) or central (x_c)"),
    ("node", "1", "agent i for source = agent (NA otherwise)"), ("component", "1", "state component 1..n"),
    ("value", "state", "the component")])
ITERATES = spec("iterates", "iteration k of agent i in interval s (trial 0, the first stored intervals)", [
    SC, RUN, ("s", "1", "interval"), ("k", "1", "iteration 0..q"), AGENT,
    ("t", "time", "τ_is(k), the iteration time"),
    ("error", "state", "||π_is(k)|| = ||z_is(k) - x(t_i(s-1))||, trial 0")])
SOURCE_SETS = spec("source_sets", "arc j -> i at iteration k of interval s (first stored intervals)", [
    SC, RUN, ("s", "1", "interval"), ("k", "1", "iteration 1..q"), ("receiver", "1", "agent i"),
    ("sender", "1", "agent j != i"), ("used", "", "j ∈ S_is(k), the sources of (11)"),
    ("nominal", "", "j ∈ N_i((s-1)T+(k-1)Δ+β)")])
FITS = spec("fits", "trial of a synchronous run with rule (13) (least-squares decay rate of |e(s)|)", [
    SC, RUN, ("trial", "1", "trial"), ("rate", "1/time", "-slope of log|e(s)| against t_1s (NaN: < 3 samples)"),
    ("first", "1", "first event index fitted"), ("stop", "1", "first index at the round-off floor (excluded)"),
    ("error0", "state", "|e(0)|"), ("ebar0", "state", "|ē(0)|")])
CHECKS = spec("checks", "quantity a claim is decided on, per run", [
    SC, RUN, ("quantity", "", "name"), ("value", "as defined", "value (inf / -inf / NaN: no case)"),
    ("definition", "", "what it is")])
METRICS = spec("metrics", "summary metric (sweeps plot the network-wide ones with one row)", [
    SC, ("metric", "", "name"), ("node", "1", "agent (empty: network-wide)"), ("run", "", "run (empty: the design)"),
    ("value", "as defined", "value")])


# -- design tables -------------------------------------------------------------------------------------

def labels(names: list[str], codes: np.ndarray) -> pd.arrays.ArrowStringArray:
    """The string column names[codes] built in Arrow (a column of repeated Python strings is
    converted one object at a time: 17 ms per 200,000 rows, against 1 ms)."""
    import pyarrow as pa

    return pd.array(pa.array(names, pa.large_string()).take(pa.array(codes)), dtype="str")


def as_float(exact: str) -> float:
    """An exact integer (or decimal) as a float: inf beyond the float range (q of (22) for many agents)."""
    return float(Decimal(exact))


def _agents(name: str, dz: dict, sc) -> pd.DataFrame:
    m = sc.m
    return pd.DataFrame({
        "scenario": name, "node": np.arange(1, m + 1), "n_i": dz["n_i"], "outputs": [c.shape[0] for c in sc.C],
        "kappa_L": dz["kappa_L"], "spectral_abscissa": dz["local_abscissa"], "abscissa_roundoff": dz["local_abscissa_tol"],
        "c_i": dz["c_i"], "residual_C": dz["residual_C"], "residual_A": dz["residual_A"], "discarded": dz["discarded"],
        "row_space_distance": dz["row_space_dist"], "observability_rank": dz["obs_rank_local"],
        "footnote3_deviation": dz["P_basis_dev"], "kappa_ML": dz["kappa_ML"]})


def _local_matrices(name: str, d) -> pd.DataFrame:
    rows = []
    for i in range(d.m):
        for label, M in (("L", d.L[i]), ("Abar", d.Abar[i]), ("Cbar", d.Cbar[i]), ("K", d.K[i]), ("F", d.F(i)),
                         ("Q", d.Q[i]), ("P", d.P[i])):
            rows += [{"scenario": name, "node": i + 1, "matrix": label, **row} for row in matrix_rows(M)]
    return pd.DataFrame(rows, columns=LOCAL_MATRICES.column_names)


def _spectrum_rows(name: str, label_col: str, label, ev: np.ndarray) -> list[dict]:
    ev = ev[np.isfinite(ev)]
    ev = ev[np.lexsort((ev.imag, ev.real))]
    return [{"scenario": name, label_col: label, "index": j, "real": float(v.real), "imag": float(v.imag)}
            for j, v in enumerate(ev)]


def _design_rows(name: str, dz: dict, sc) -> list[dict]:
    rows = []
    nan = float("nan")

    def add(quantity, value, definition, unit="1", lam=nan, exact=""):
        rows.append({"scenario": name, "quantity": quantity, "lam": lam, "value": float(value), "exact": exact,
                     "unit": unit, "definition": definition})

    m = sc.m
    N = (m - 1) ** 2 + 1
    add("m", m, "agents"), add("n", sc.n, "state dimension"), add("N", N, "(m-1)²+1, the factors of (17)")
    add("T", sc.T, "event spacing", "time"), add("lambda", sc.lam, "the rate λ the theorems are checked for", "1/time")
    add("lambda_bar", sc.lam_bar, "λ̄ of (15)", "1/time")
    add("q_design", sc.q_design, f"the design q ({sc.q_label})", exact=str(sc.q_design))
    add("norm_A", dz["norm_A"], "||A||_2", "1/time"), add("norm_eAT", dz["norm_eAT"], "||e^(AT)||_2")
    add("joint_rank", dz["joint_rank"], "dimension of the observable space of the stacked outputs (= n: (C, A) "
                                        "jointly observable)")
    add("sigma_min_16", dz["sigma_min_16"], "σ_min([I - P_1; ...; I - P_m]): > 0 iff (16) holds")
    add("rank_tol", sc.rank_tol, "relative tolerance of the rank decisions")
    add("Q_mixed", dz["Q_mixed"], "|Q| (mixed norm of diag(Q_i))"), add("Q_2", dz["Q_2"], "||Q||_2")
    add("c", float(np.max(dz["c_i"])), "max_i c_i of (15)")
    add("rho", dz["rho"], "ρ of (17) (the largest product norm found: exact when rho_exact = 1)")
    add("rho_upper", dz["rho_upper"], "a proven upper bound of ρ (at most rho + rho_roundoff when rho_exact = 1)")
    add("rho_exact", bool(dz["rho_exact"]), "1 when the exhaustive search finished (ρ exact)")
    add("rho_words", dz["rho_words"], "complete products evaluated by the search")
    _rho_method_rows(add, dz, N)
    word = " ".join(str(int(x) + 1) for x in np.atleast_1d(dz["rho_worst_word"]))
    add("rho_witness_length", len(np.atleast_1d(dz["rho_worst_word"])),
        "the word P_i1 ··· P_ik attaining ρ (exact: the agents, in order)", exact=word)
    if "q_thm22_upper" in dz:
        add("alpha_lemma5_upper", dz["alpha_lemma5_upper"], "α of Lemma 5 with ρ's upper bound")
        add("q_thm22_upper", as_float(str(dz["q_thm22_upper"])), "q of (22) with ρ's upper bound (sufficient for sure)",
            exact=str(dz["q_thm22_upper"]))
    defs = {"q_thm22": "q of (22), N ceil(r) + 1, Lemma-5 α", "q_thm21": "q of (21) with (19), N (ceil(r) + 1), Lemma-5 α",
            "q_minimal": "the smallest q of the proof of Lemma 4, N (floor(r) + 1), Lemma-5 α",
            "q_thm22_printed_alpha": "q of (22) with α as printed in (18)",
            "q_thm21_printed_alpha": "q of (21) with (19) and α as printed in (18)",
            "q_minimal_printed_alpha": "the smallest q of Lemma 4's proof with α as printed in (18)"}
    for label, lam in lambda_variants(sc):
        add("alpha_lemma5", dz[f"alpha_lemma5{label}"], "α = 1 - (m-1)(1-ρ)/m^((m-1)²) of Lemma 5", lam=lam)
        add("alpha_printed", dz[f"alpha_printed{label}"], "α = 1 - (m-1)(1-ρ)/(m(m-1)²) as printed in (18)", lam=lam)
        add("one_minus_alpha_log10", dz[f"one_minus_alpha_log10{label}"], "log10(1 - α), Lemma-5 α", lam=lam)
        add("r_lemma5", dz[f"r_lemma5{label}"], "r = (λ + ||A||)T / ln(1/α), Lemma-5 α", lam=lam,
            exact=str(dz[f"r_lemma5_exact{label}"]))
        add("r_printed", dz[f"r_printed{label}"], "r with α as printed in (18)", lam=lam,
            exact=str(dz[f"r_printed_exact{label}"]))
        for k in Q_KEYS:
            q = str(dz[f"{k}{label}"])
            add(k, as_float(q), defs[k], lam=lam, exact=q)
    if "sigma_skipped_reason" in dz:
        add("sigma_not_enumerated", dz["sigma_skipped_graphs"], "σ of (26) and q of (27) are not computed: the value "
            "is the number of connected graphs on m vertices, exact gives the reason", exact=str(dz["sigma_skipped_reason"]))
    if "sigma" in dz:
        add("sigma", dz["sigma"], "σ of (26): max over connected graphs G of ||P(M_G ⊗ I)||_2")
        add("sigma_graphs", dz["sigma_graphs"], "connected graphs on m vertices enumerated")
        edges = [(i + 1, j + 1) for i in range(m) for j in range(i + 1, m) if dz["sigma_worst_mask"][i, j]]
        add("sigma_worst_graph_edges", len(edges), "the graph attaining σ (exact: its edges)",
            exact=" ".join(f"{a}-{b}" for a, b in edges))
        for label, lam in lambda_variants(sc):
            if f"q27{label}" in dz:
                add("r27", dz[f"r27{label}"], "r = (λ + ||A||)T / ln(1/σ) of (27)", lam=lam)
                add("q27", dz[f"q27{label}"], "q of (27): ceil(r) + 1", lam=lam, exact=str(int(dz[f"q27{label}"])))
                add("q27_minimal", dz[f"q27_minimal{label}"], "the smallest q with e^(||A||T)σ^q < e^(-λT)", lam=lam,
                    exact=str(int(dz[f"q27_minimal{label}"])))
    return rows


def _rho_method_rows(add, dz: dict, N: int) -> None:
    """How ρ was obtained: the search's size, the letters it ran over and its round-off allowance."""
    words, prefixes = int(dz["rho_words"]), int(dz["rho_prefixes"])
    k, dev = int(dz["rho_distinct"]), float(dz["rho_merge_deviation"])
    if bool(dz["rho_exact"]):
        how = (f"exhaustive search: {words} complete word(s) and {prefixes} prefix(es) over {k} distinct projections; "
               f"every other word extends a prefix whose proven bound is at most the best word + rho_roundoff")
    else:
        how = (f"bracket: the search stopped after {prefixes} prefix(es) ({words} complete word(s), {k} distinct "
               f"projections); every word not evaluated extends an open prefix bounded by rho_upper")
    add("rho_method", words + prefixes, "how ρ was proven; the value is the number of products examined "
                                        "(complete words and prefixes)", exact=how)
    add("rho_prefixes", prefixes, "partial products (prefixes) examined by the search")
    add("rho_distinct", k, "distinct projections the words run over (agents whose P_i agree within 1e-10 are one)")
    add("rho_merge_deviation", dev, f"largest ||P_i - P_r|| of an agent merged into agent r's class: ρ of the "
                                    f"computed P_i is within N·{dev:.3g} = {N * dev:.3g} of rho")
    add("rho_roundoff", dz["rho_roundoff"], "τ: a prefix whose bound is within τ of the best word is not extended "
                                            "(round-off of N products and of the projections' common fixed spaces)")


def _graph_tables(name: str, sc, dz: dict) -> tuple[pd.DataFrame, pd.DataFrame]:
    arcs, props = [], []
    for g, G in enumerate(sc.graph_masks):
        for i in range(sc.m):
            for j in range(sc.m):
                if i != j and G[i, j]:
                    arcs.append({"scenario": name, "graph": g + 1, "name": sc.graphs.names[g], "receiver": i + 1,
                                 "sender": j + 1})
        props.append({"scenario": name, "graph": g + 1, "name": sc.graphs.names[g], "arcs": int(G.sum() - sc.m),
                      "strongly_connected": bool(dz["graph_strong"][g]), "symmetric": bool(dz["graph_symmetric"][g]),
                      "vertex_redundant": bool(dz["graph_vertex_redundant"][g])})
    return pd.DataFrame(arcs, columns=GRAPHS.column_names), pd.DataFrame(props, columns=GRAPH_PROPERTIES.column_names)


def _runs(name: str, sc, dz: dict) -> pd.DataFrame:
    N = (sc.m - 1) ** 2 + 1
    rows = []
    for run in sc.runs:
        k = constants(dz, sc, run)
        lv = run.leave
        rows.append({"scenario": name, "run": run.name, "timing": run.timing, "switching": run.switching,
                     "graph": run.graph, "rule": run.rule, "q": run.q, "q_label": run.q_label, "Delta": run.Delta,
                     "beta": run.beta, "epsilon": simulation.run_epsilon(run), "intervals": run.intervals,
                     "horizon": run.intervals * sc.T, "noise": run.noise, "ideal": run.ideal, "monte_carlo": run.monte_carlo,
                     "leave_agent": lv.agent if lv else None, "leave_at": lv.at if lv else math.nan,
                     "rejoin_at": lv.rejoin if lv else math.nan, "leave_policy": lv.policy if lv else "",
                     "reference_run": run.reference_run, "b": k["b"], "c": k["c"], "d": k["d"], "b_sym": k["b_sym"],
                     "d_sym": k["d_sym"], "g": k["g"], "decay": math.exp(-sc.lam * sc.T), "p": run.q // N,
                     "alpha_p": alpha_power(dz, run.q // N)})
    return pd.DataFrame(rows, columns=RUNS.column_names).astype({"leave_agent": "Int64"})


def _event_times(name: str, sc) -> pd.DataFrame:
    frames = []
    for run in sc.runs:
        ev = simulation.event_times(sc, run)
        m, S1 = ev.shape
        frames.append(pd.DataFrame({"scenario": name, "run": run.name, "node": np.repeat(np.arange(1, m + 1), S1),
                                    "s": np.tile(np.arange(S1), m), "t": ev.ravel() / 1e9, "t_ns": ev.ravel()}))
    return pd.concat(frames, ignore_index=True)


def design_tables(design: Parts) -> list:
    """The design stage's tables (`dse check` prints them; a run has them too)."""
    out: dict[str, list] = {}

    def add(table, frame):
        out.setdefault(table.name, [table, []])[1].append(frame)

    for name, part in design.parts.items():
        sc, dz = part.scenario, part.design
        add(AGENTS, _agents(name, dz, sc))
        add(LOCAL_MATRICES, _local_matrices(name, part.obs))
        add(LOCAL_SPECTRA, pd.DataFrame([r for i in range(sc.m) for r in
                                         _spectrum_rows(name, "node", i + 1, dz["local_eigs"][i])],
                                        columns=LOCAL_SPECTRA.column_names))
        add(SYSTEM_SPECTRA, pd.DataFrame(_spectrum_rows(name, "matrix", "A", dz["eig_A"])
                                         + _spectrum_rows(name, "matrix", "central", dz["eig_central"]),
                                         columns=SYSTEM_SPECTRA.column_names))
        add(DESIGN, pd.DataFrame(_design_rows(name, dz, sc), columns=DESIGN.column_names))
        arcs, props = _graph_tables(name, sc, dz)
        add(GRAPHS, arcs)
        add(GRAPH_PROPERTIES, props)
        add(RUNS, _runs(name, sc, dz))
        add(EVENT_TIMES, _event_times(name, sc))
        if "vertex_loss_rho" in dz:
            add(VERTEX_LOSS, pd.DataFrame({"scenario": name, "removed": np.arange(1, sc.m + 1),
                                           "jointly_observable": dz["redundant_observable"],
                                           "strongly_connected": dz["redundant_connected"].all(axis=0),
                                           "rho_d": dz["vertex_loss_rho"], "q_d": dz["vertex_loss_q"].astype(str)}))
        if "kp_t" in dz:
            add(MISMATCH, pd.DataFrame({"scenario": name, "t": dz["kp_t"], "x_norm": dz["kp_xnorm"],
                                        "error_exact_model": dz["kp_err_exact"],
                                        "error_mismatch": dz["kp_err_mismatch"]}))
    return [(t, pd.concat(frames, ignore_index=True)) for t, frames in out.values()]


# -- run tables --------------------------------------------------------------------------------------------

def _intervals(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    S = run.intervals
    return pd.DataFrame({"scenario": name, "run": run.name, "s": np.arange(1, S + 1),
                         "participating": a["participating"].sum(axis=1), "nominal_graph": a["nominal_graph"] + 1,
                         "A_mixed": a["A_mixed"], "B_mixed": a["B_mixed"], "G_mixed": a["G_mixed"], "A_2": a["A_2"],
                         "B_2": a["B_2"], "Phi_max": a["Phi_max"], "source_mismatch": a["source_mismatch"],
                         "source_entries": a["source_entries"], "decay": math.exp(-r.scenario.lam * r.scenario.T)})


def _se(sd: np.ndarray, count: np.ndarray) -> np.ndarray:
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 1, sd / np.sqrt(np.maximum(count, 1)), np.nan)


def _events(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    cnt = a["ev_count"]
    return pd.DataFrame({"scenario": name, "run": run.name, "s": np.arange(run.intervals + 1),
                         "t": a["event_ns"][0] / 1e9, "trials": cnt,
                         "error_trial0": np.linalg.norm(a["t0_e_post"], axis=-1).max(axis=-1),
                         "error_mean": a["net_mean"], "error_se": _se(a["net_sd"], cnt), "error_max": a["net_max"],
                         "ebar_trial0": trial0_ebar(r, a).max(axis=-1), "bound51_trial0": a["t0_bound51"],
                         "bound51_max": a["bound51_max"], "ratio51_max": a["ratio51_s"], "floor_trial0": a["t0_floor"],
                         "carried_trial0": a["t0_carried"]})


def trial0_ebar(r, a: dict) -> np.ndarray:
    """||ē_i(t_is)|| of trial 0, (S+1, m)."""
    return np.stack([np.linalg.norm(a["t0_ebar"][:, w], axis=-1) for w in r.obs.w_slices], axis=1)


def _nodes(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    S1, m = a["ev_mean"].shape
    cnt = np.repeat(a["ev_count"][:, None], m, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        ratio = a["ev_mean"] / a["ev_central_mean"]
    cols = {"error_trial0": np.linalg.norm(a["t0_e_post"], axis=-1),
            "error_before_reset": np.linalg.norm(a["t0_e_pre"], axis=-1), "error_mean": a["ev_mean"],
            "error_se": _se(a["ev_sd"], cnt), "error_max": a["ev_max"], "ebar_trial0": trial0_ebar(r, a),
            "bound41_trial0": a["t0_bound41"], "bound51_trial0": np.repeat(a["t0_bound51"][:, None], m, axis=1),
            "central_trial0": a["t0_central"], "central_mean": a["ev_central_mean"], "ratio_to_central": ratio}
    frame = {"scenario": name, "run": run.name, "node": np.tile(np.arange(1, m + 1), S1),
             "s": np.repeat(np.arange(S1), m), "t": a["event_ns"].T.ravel() / 1e9}
    frame.update({k: v.ravel() for k, v in cols.items()})
    return pd.DataFrame(frame)


def _node_series(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    t = a["g_t_ns"] / 1e9
    G, m = a["g_mean"].shape
    return pd.DataFrame({"scenario": name, "run": run.name, "t": np.repeat(t, m), "node": np.tile(np.arange(1, m + 1), G),
                         "error_trial0": a["t0_err"].ravel(), "error_mean": a["g_mean"].ravel(),
                         "error_max": a["g_max"].ravel()})


def continuous_bounds(r, run, a: dict) -> tuple[np.ndarray, np.ndarray]:
    """Theorem 1's continuous bound for trial 0 at the stored samples, as printed and corrected
    (NaN for runs it is not about)."""
    t = a["g_t_ns"] / 1e9
    if not (simulation.is_theorem_run(run) and run.timing == "sync"):
        return np.full(len(t), np.nan), np.full(len(t), np.nan)
    sc = r.scenario
    k = constants(r.design, sc, run)
    K0 = float(np.linalg.norm(a["t0_e_post"][0], axis=-1).max() + k["d"] * trial0_ebar(r, a)[0].max())
    printed = np.exp(k["norm_A"] * sc.T - sc.lam * t) * K0
    return printed, printed * math.exp(sc.lam * sc.T)


def _network_series(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    printed, corrected = continuous_bounds(r, run, a)
    return pd.DataFrame({"scenario": name, "run": run.name, "t": a["g_t_ns"] / 1e9,
                         "error_trial0": a["t0_err"].max(axis=-1), "central_trial0": a["t0_cerr"],
                         "central_mean": a["g_central_mean"], "kalman_trial0": a["t0_kf"],
                         "x_norm_trial0": a["t0_xnorm"], "bound_printed_trial0": printed,
                         "bound_corrected_trial0": corrected})


#: the state series (trial 0) hold at most this many rows per run (further decimated beyond)
STATE_ROWS = 2_000_000


def _state_series(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    m, n = r.scenario.m, r.scenario.n
    t = a["g_t_ns"] / 1e9
    keep = np.arange(0, len(t), max(1, -(-len(t) * n * (m + 2) // STATE_ROWS)))
    t = t[keep]
    # blocks truth, agent 1..m, central, each (time, component) in row order
    values = np.concatenate([a["t0_x"][keep][None], a["t0_xhat"][keep].transpose(1, 0, 2), a["t0_xc"][keep][None]])
    per_block = len(t) * n
    node = np.repeat(np.arange(m + 2), per_block)
    return pd.DataFrame({"scenario": name, "run": run.name, "t": np.tile(np.repeat(t, n), m + 2),
                         "source": labels(["truth", "agent", "central"], np.repeat(np.r_[0, [1] * m, 2], per_block)),
                         "node": pd.arrays.IntegerArray(node, (node == 0) | (node == m + 1)),
                         "component": np.tile(np.arange(1, n + 1), (m + 2) * len(t)), "value": values.ravel()})


def _iterates(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    if "t0_z" not in a:
        return pd.DataFrame(columns=ITERATES.column_names)
    z = a["t0_z"]                                          # (K, q+1, m, n)
    K, q1, m, _ = z.shape
    x_start = a["t0_x_event"][:K]                          # x(t_i(s-1)) per agent, (K, m, n)
    err = np.linalg.norm(z - x_start[:, None], axis=-1)     # (K, q+1, m)
    tau = a["tau0"][:K].transpose(0, 2, 1)                 # (K, q+1, m)
    return pd.DataFrame({"scenario": name, "run": run.name, "s": np.repeat(np.arange(1, K + 1), q1 * m),
                         "k": np.tile(np.repeat(np.arange(q1), m), K), "node": np.tile(np.arange(1, m + 1), K * q1),
                         "t": tau.ravel(), "error": err.ravel()})


def _source_sets(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    src, nom = a["sources0"], a["nominal0"]
    off = ~np.eye(src.shape[-1], dtype=bool)[None, None]
    s, k, i, j = np.nonzero((src | nom) & off)
    return pd.DataFrame({"scenario": name, "run": run.name, "s": s + 1, "k": k + 1, "receiver": i + 1, "sender": j + 1,
                         "used": src[s, k, i, j], "nominal": nom[s, k, i, j]})


def _fits(name: str, r, run) -> pd.DataFrame | None:
    if not (simulation.is_theorem_run(run) and run.timing == "sync"):
        return None
    a = r.runs[run.name]
    B = len(a["trial_fit_rate"])
    return pd.DataFrame({"scenario": name, "run": run.name, "trial": np.arange(B), "rate": a["trial_fit_rate"],
                         "first": a["trial_fit_first"], "stop": a["trial_fit_stop"], "error0": a["trial_e0"],
                         "ebar0": a["trial_eb0"]})


def _checks(name: str, r, run) -> pd.DataFrame:
    a = r.runs[run.name]
    tol, _ = simulation.simulation_tolerance(r.scenario, r.design, run, a)
    rows = [("tolerance", tol, "round-off allowance relative to the size of the states")]
    for k, text in WORST.items():
        rows += [(f"{k}_slack", a[f"w_{k}_slack"], f"smallest slack up - lo of {text}"),
                 (f"{k}_lo", a[f"w_{k}_lo"], "the measured side at the smallest slack"),
                 (f"{k}_up", a[f"w_{k}_up"], "the bound side at the smallest slack"),
                 (f"{k}_relative", a[f"w_{k}_rel"], "smallest slack relative to the bound"),
                 (f"{k}_cases", a[f"w_{k}_count"], "cases compared"), (f"{k}_nonfinite", a[f"w_{k}_bad"],
                                                                      "cases with a non-finite side")]
    rows += [(k, a[f"max_{k}"], text) for k, text in MAXIMA.items()]
    rows += [(f"{k}_cases", a[f"count_{k}"], f"cases behind the {k} maximum") for k in COUNTS]
    rows += [("reception_violations", a["reception_violations"], "messages outside the receiver's reception interval"),
             ("distinct_intervals", a["distinct_intervals"], "distinct weight sequences among the intervals"),
             ("trials", a["trials"], "trials simulated"), ("samples", a["g_total"], "samples of the continuous errors"),
             ("sample_stride", a["g_stride"], "every k-th sample is stored")]
    return pd.DataFrame([{"scenario": name, "run": run.name, "quantity": q, "value": float(v), "definition": d}
                         for q, v, d in rows], columns=CHECKS.column_names)


def _metrics(name: str, r) -> list[dict]:
    rows = []

    def add(metric, value, node=None, run=""):
        rows.append({"scenario": name, "metric": metric, "node": node, "run": run, "value": float(value)})

    dz = r.design
    add("rho", dz["rho"]), add("rho_upper", dz["rho_upper"])
    for k in ("q_thm22", "q_minimal"):
        add(k, as_float(str(dz[k])))
    if "sigma" in dz:
        add("sigma", dz["sigma"])
        if "q27" in dz:
            add("q27", dz["q27"])
    for run in r.scenario.runs:
        a = r.runs[run.name]
        start = float(a["net_max"][0])
        add("err_final_max", a["net_max"][-1], run=run.name)
        add("err_final_mean", a["net_mean"][-1], run=run.name)
        add("err_ratio", a["net_max"][-1] / start if start > 0 else math.nan, run=run.name)
        for i in range(r.scenario.m):
            add("err_final_mean", a["ev_mean"][-1, i], node=i + 1, run=run.name)
        if simulation.is_theorem_run(run) and run.timing == "sync" and np.isfinite(a["trial_fit_rate"]).any():
            add("decay_rate_median", np.nanmedian(a["trial_fit_rate"]), run=run.name)
    return rows


def run_tables(res) -> list:
    """Every table of a run: the design tables, then the sampled lemmas and the simulated runs."""
    out = list(design_tables(res))
    groups: dict[str, list] = {}
    per_run = (INTERVALS, _intervals), (EVENTS, _events), (NODES, _nodes), (NODE_SERIES, _node_series), \
        (NETWORK_SERIES, _network_series), (STATE_SERIES, _state_series), (ITERATES, _iterates), \
        (SOURCE_SETS, _source_sets), (FITS, _fits), (CHECKS, _checks)
    samples, metrics = [], []
    for name, r in res.parts.items():
        sm = r.samples
        samples += [{"scenario": name, "quantity": q, "value": float(sm[q]), "definition": d} for q, d in (
            ("lemma5_max", "largest |P(S_μ⊗I)···P(S_1⊗I)| over the sampled products of N steps (Lemma 5)"),
            ("lemma5_samples", "products sampled (every constant sequence first)"),
            ("lemma5_pool", "strongly connected graphs the steps are drawn from"),
            ("lemma6_max", "largest ||P(F⊗I)||_2 over the random doubly stochastic F (Lemma 6)"),
            ("lemma6_count", "matrices F with a strongly connected graph"))]
        metrics += _metrics(name, r)
        for run in r.scenario.runs:
            for table, build in per_run:
                frame = build(name, r, run)
                if frame is not None:
                    groups.setdefault(table.name, [table, []])[1].append(frame)
    out.append((LEMMA_SAMPLES, pd.DataFrame(samples, columns=LEMMA_SAMPLES.column_names)))
    out += [(t, pd.concat(frames, ignore_index=True)) for t, frames in groups.values()]
    out.append((METRICS, pd.DataFrame(metrics, columns=METRICS.column_names).astype({"node": "Int64"})))
    return out
