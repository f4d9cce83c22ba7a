"""The rules of a hybrid-observer file that tie its tables together (the file's validator calls
them in the order their errors are reported): the outputs against A and (16), the local bases,
gains and poles against the local designs and (15), the centralized poles, the neighbour graphs
against m, the design q against (22) and (27), w_i(0), and each run against the design, the
graphs and T; each error names its key. `settled_runs` also fills in the runs' defaults that
depend on other tables (name, switching, q, Δ, zero jitter and offsets)."""
from __future__ import annotations

import numpy as np

import dse.estimators.jointly_observable_design as jd
from dse.errors import ScenarioError, printable
from dse.scenario.declare import matrix

from .scenario import (MAX_AGENT_STATES, MAX_AGENTS, MAX_GROWTH_EXPONENT, MAX_Q, SIGMA_MAX_AGENTS, GraphsSection,
                       HybridFile, LeaveSection, RunSection, default_central_poles, default_Delta, default_poles,
                       default_run_name, default_switching)


def output_matrices(sc: HybridFile) -> tuple[np.ndarray, ...]:
    """C_i with n columns, nonzero; 2 <= m <= MAX_AGENTS, m·n <= MAX_AGENT_STATES; (16) at the rank tolerance."""
    n = sc.A.shape[0]
    C = tuple(matrix(c, f"system.C[{i}]") for i, c in enumerate(sc.system.C))
    for i, Ci in enumerate(C):
        if Ci.shape[1] != n:
            raise ScenarioError(f"system.C[{i}]", f"must have n = {n} columns, got {Ci.shape[1]}")
        if not np.any(Ci):
            raise ScenarioError(f"system.C[{i}]", "is zero (every agent must sense something: C_i != 0)")
    m = len(C)
    if m < 2:
        raise ScenarioError("system.C", "needs at least 2 agents (with one agent there is nothing to distribute)")
    if m > MAX_AGENTS:
        raise ScenarioError("system.C", f"{m} agents; this family handles at most {MAX_AGENTS}")
    if m * n > MAX_AGENT_STATES:
        raise ScenarioError("system.C", f"m·n = {m * n} estimator states per trial; this family handles at most "
                                        f"{MAX_AGENT_STATES}")
    rank = jd.observable_basis(sc.A, np.vstack(C), sc.rank_tol).rows.shape[0]
    if rank < n:
        raise ScenarioError("system.C", f"(C, A) is not jointly observable: the observable space of the stacked "
                                        f"outputs has dimension {rank} < n = {n} (relative rank tolerance "
                                        f"{sc.rank_tol:g}); condition (16) fails")
    return C


def given_bases(sc: HybridFile) -> tuple[np.ndarray, ...] | None:
    """The given L_i: one per agent, full row rank, kernel the unobservable space of (C_i, A)."""
    if sc.design.L is None:
        return None
    L = tuple(matrix(Li, f"design.L[{i}]") for i, Li in enumerate(sc.design.L))
    if len(L) != sc.m:
        raise ScenarioError("design.L", f"must list one matrix per agent ({sc.m}), got {len(L)}")
    for i, Li in enumerate(L):
        if Li.shape[1] != sc.n or not jd.same_kernel(Li, sc.A, sc.C[i], sc.rank_tol):
            raise ScenarioError(f"design.L[{i}]", "must have full row rank and kernel equal to the unobservable "
                                                  f"space of (C_{i + 1}, A)")
    return L


def gains_choice(sc: HybridFile) -> tuple[tuple | None, tuple | None]:
    """(the given K_i, None) with gains = 'given', else (None, the poles to place); every local
    observer's spectral abscissa below -λ̄ (15) (placed gains are computed with the design, scipy.signal
    being slow to import: their abscissa is the largest requested pole here, the achieved one a hypothesis)."""
    K, poles = _gains(sc)
    abscissas = [jd.spectral_abscissa(loc.Abar + K[i] @ loc.Cbar) for i, loc in enumerate(sc.locs)] \
        if K is not None else [max(p) for p in poles]
    for i, sa in enumerate(abscissas):
        if sa > -sc.lam_bar + 1e-9:
            raise ScenarioError("design.lambda_bar", f"agent {i + 1}'s local observer has spectral abscissa "
                                                     f"{sa:.6g} > -λ̄ = {-sc.lam_bar:g}: (15) cannot hold")
    return K, poles


def _gains(sc: HybridFile) -> tuple[tuple | None, tuple | None]:
    des, m, locs = sc.design, sc.m, sc.locs
    if des.gains != "given":
        if des.K is not None:
            raise ScenarioError("design.K", "only allowed with gains = 'given'")
        if des.poles is None:
            poles = tuple(default_poles(sc.lam_bar, loc.n_i) for loc in locs)
        else:
            if len(des.poles) != m:
                raise ScenarioError("design.poles", f"must list one pole set per agent ({m})")
            poles = tuple(tuple(float(x) for x in p) for p in des.poles)
            for i, p in enumerate(poles):
                if len(p) != locs[i].n_i:
                    raise ScenarioError(f"design.poles[{i}]", f"must have n_i = {locs[i].n_i} poles")
        for i in range(m):
            why = jd.unplaceable(poles[i], np.linalg.matrix_rank(locs[i].Cbar))
            if why:
                raise ScenarioError(f"design.poles[{i}]", f"pole placement fails: {why}")
        return None, poles
    if des.K is None:
        raise ScenarioError("design.K", "missing (needed for gains = 'given')")
    if sc.L_given is None:
        raise ScenarioError("design.L", "missing (a given K is expressed in a given basis L)")
    if des.poles is not None:
        raise ScenarioError("design.poles", "only with gains = 'place'")
    K = tuple(matrix(Ki, f"design.K[{i}]") for i, Ki in enumerate(des.K))
    if len(K) != m:
        raise ScenarioError("design.K", f"must list one matrix per agent ({m}), got {len(K)}")
    for i, Ki in enumerate(K):
        if Ki.shape != (locs[i].n_i, sc.C[i].shape[0]):
            raise ScenarioError(f"design.K[{i}]", f"must have shape {locs[i].n_i}x{sc.C[i].shape[0]}, got "
                                                  f"{Ki.shape[0]}x{Ki.shape[1]}")
    return K, None


def central_poles(sc: HybridFile) -> list[float]:
    """The centralized reference's poles (given or default): n negative real poles that can be placed."""
    poles = [float(p) for p in sc.design.central_poles] if sc.design.central_poles is not None \
        else default_central_poles(sc)
    if len(poles) != sc.n or max(poles) >= 0:
        raise ScenarioError("design.central_poles", f"must be {sc.n} negative real poles")
    why = jd.unplaceable(poles, jd.stacked_rank(np.vstack(sc.C), sc.rank_tol)[0])
    if why:
        raise ScenarioError("design.central_poles", f"pole placement for the centralized reference fails: {why}")
    return poles


def initial_w(sc: HybridFile) -> np.ndarray | None:
    """The stacked w_i(0) (n_i entries each, in the given bases L_i), or None (every w_i(0) = 0)."""
    w0 = sc.initial.w0
    if w0 is None:
        return None
    if len(w0) != sc.m:
        raise ScenarioError("initial.w0", f"must list one vector per agent ({sc.m}), got {len(w0)}")
    for i, w in enumerate(w0):
        if len(w) != sc.locs[i].n_i:
            raise ScenarioError(f"initial.w0[{i}]", f"must have n_i = {sc.locs[i].n_i} entries (rank of agent "
                                                    f"{i + 1}'s observability matrix), got {len(w)}")
    if sc.L_given is None:
        raise ScenarioError("initial.w0", "needs design.L (w_i lives in the coordinates of L_i); omit w0 to start "
                                          "every local observer at w_i = 0")
    return np.concatenate([np.array(w, float) for w in w0])


def graph_masks(g: GraphsSection, m: int) -> np.ndarray:
    """The neighbour lists as masks (labels 1..m, self excluded, no repeats), and their names."""
    graphs = []
    for k, rows in enumerate(g.neighbors):
        f = f"graphs.neighbors[{k}]"
        if len(rows) != m:
            raise ScenarioError(f, f"must list the neighbours of each of the {m} agents, got {len(rows)}")
        for i, labels in enumerate(rows):
            for j in labels:
                if not 1 <= j <= m:
                    raise ScenarioError(f"{f}[{i}]", f"agent labels are 1..{m}, got {j}")
                if j == i + 1:
                    raise ScenarioError(f"{f}[{i}]", f"lists agent {j} as its own neighbour (every agent is; do not "
                                                     "list it)")
            if len(set(labels)) != len(labels):
                raise ScenarioError(f"{f}[{i}]", f"repeats a neighbour: {labels}")
        graphs.append(jd.neighbour_mask([[j - 1 for j in labels] for labels in rows], m))
    if len(g.names) != len(graphs):
        raise ScenarioError("graphs.names", f"must name each of the {len(graphs)} graphs, got {len(g.names)}")
    for k, label in enumerate(g.names):
        if not label.strip() or len(label) > 64 or printable(label) != label:
            raise ScenarioError(f"graphs.names[{k}]", "must be 1 to 64 characters without control or format "
                                                      f"(bidirectional, zero-width) characters, got '{label[:64]}'")
    return np.array(graphs)


def design_q(sc: HybridFile) -> int:
    """The design q: an integer as given; 'theory', the q of (22) for the proven upper bound of ρ;
    'symmetric', the q of (27). Refused beyond MAX_Q (too many iterations to simulate)."""
    q_raw, m, T = sc.design.q, sc.m, sc.T
    if not isinstance(q_raw, str):
        return int(q_raw)
    P = np.array([loc.P for loc in sc.locs])
    if q_raw == "theory":
        # (22) grows with ρ: its value at ρ = 0 is a lower bound, enough to refuse without computing ρ
        q = jd.sufficient_q(0.0, m, sc.norm_A, sc.lam, T).q_thm22
        if q > MAX_Q:
            raise ScenarioError("design.q", f"the theory q is {jd.readable_int(q)} or more (> {MAX_Q:,}): too many "
                                            "iterations to simulate; give an integer q (the hypotheses report the "
                                            "required q)")
        rho = jd.rho_exact(P)
        if rho.upper >= 1:
            raise ScenarioError("design.q", f"ρ of (17) is only bracketed in [{rho.rho:.6g}, {rho.upper:.6g}]: no "
                                            "sufficient q is known; give an integer q")
        q = jd.sufficient_q(rho.upper, m, sc.norm_A, sc.lam, T).q_thm22
    else:
        if m > SIGMA_MAX_AGENTS:
            raise ScenarioError("design.q", f"'symmetric' needs m <= {SIGMA_MAX_AGENTS} (σ of (26) by enumeration)")
        q = symmetric_q(jd.sigma_symmetric(P)[0], sc.norm_A, sc.lam, T, "design.q")
    if q > MAX_Q:
        raise ScenarioError("design.q", f"the {q_raw} q is {jd.readable_int(q)} (> {MAX_Q:,}): too many iterations to "
                                        "simulate; give an integer q (the hypotheses report the required q)")
    return q


def symmetric_q(sigma: float, norm_A: float, lam: float, T: float, field: str) -> int:
    """q of (27), or a ScenarioError naming `field` when σ is not below 1."""
    try:
        return jd.q_symmetric(sigma, norm_A, lam, T)
    except ValueError as exc:
        raise ScenarioError(field, f"(27) gives no q: {exc}") from None


def settled_runs(sc: HybridFile, runs: list[RunSection]) -> list[RunSection]:
    """Every run checked against the design, the graphs and T, its derived defaults filled in."""
    out: list[RunSection] = []
    sigma: list[float] = []
    for r_i, raw in enumerate(runs):
        f = f"runs[{r_i}]"
        name = raw.name if raw.name is not None else default_run_name(r_i)
        if name in {r.name for r in out}:
            raise ScenarioError(f"{f}.name", f"must be unique, got '{name}' twice")
        switching = raw.switching or default_switching(sc)
        if raw.graph > len(sc.graph_masks):
            raise ScenarioError(f"{f}.graph", f"must be <= the number of graphs ({len(sc.graph_masks)}), got {raw.graph}")
        if raw.noise and sc.noise_b is None:
            raise ScenarioError(f"{f}.noise", "needs a [noise] table with b")
        used = [sc.graph_masks[raw.graph - 1]] if switching == "fixed" else list(sc.graph_masks)
        if raw.rule == "symmetric" and not all(np.array_equal(G, G.T) for G in used):
            raise ScenarioError(f"{f}.rule", "the convex rule (25) is for symmetric graphs; a graph this run uses is "
                                             "directed (use switching = 'fixed' with a symmetric graph)")
        q, q_label = _run_q(sc, raw.q, f, sigma)
        eps = [float(x) for x in raw.epsilon] if raw.epsilon is not None else [0.0] * sc.m
        offsets = [float(x) for x in raw.offsets] if raw.offsets is not None else [0.0] * sc.m
        Delta = float(raw.Delta) if raw.Delta is not None else default_Delta(sc, q)
        _check_timing(sc, raw, f, q, eps, offsets, Delta)
        _check_leave(raw.leave, f"{f}.leave", sc.m, sc.T, offsets, raw.intervals)
        if raw.reference_run and raw.reference_run not in {r.name for r in out}:
            raise ScenarioError(f"{f}.reference_run", f"must name an earlier run, got '{raw.reference_run}'")
        run = raw.model_copy(update={"name": name, "switching": switching, "q": q, "epsilon": eps, "offsets": offsets,
                                     "Delta": Delta})
        run._q_label = q_label
        out.append(run)
    return out


def _run_q(sc: HybridFile, q_raw, f: str, sigma: list[float]) -> tuple[int, str]:
    """A run's q and where it comes from (σ of (26) computed once, into `sigma`)."""
    if q_raw == "design":
        return sc.q_design, sc.q_label
    if q_raw != "symmetric":
        return int(q_raw), "given"
    if sc.m > SIGMA_MAX_AGENTS:
        raise ScenarioError(f"{f}.q", f"'symmetric' needs m <= {SIGMA_MAX_AGENTS} (σ of (26) by enumeration)")
    if not sigma:
        sigma.append(jd.sigma_symmetric(np.array([loc.P for loc in sc.locs]))[0])
    q = symmetric_q(sigma[0], sc.norm_A, sc.lam, sc.T, f"{f}.q")
    if q > MAX_Q:
        raise ScenarioError(f"{f}.q", f"q of (27) is {jd.readable_int(q)} (> {MAX_Q:,}); give an integer")
    return q, "symmetric"


def _check_timing(sc: HybridFile, raw: RunSection, f: str, q: int, eps: list[float], offsets: list[float],
                  Delta: float) -> None:
    """Jitter bounds and offsets per agent, (10)'s parts that do not involve the graphs, q Δ + ε <= T,
    and a horizon over which the plant's state stays inside the floating-point range."""
    m, T = sc.m, sc.T
    if len(eps) != m:
        raise ScenarioError(f"{f}.epsilon", f"must have one bound per agent ({m}), got {len(eps)}")
    if any(x < 0 for x in eps):
        raise ScenarioError(f"{f}.epsilon", "bounds must be >= 0")
    if len(offsets) != m:
        raise ScenarioError(f"{f}.offsets", f"must have one offset per agent ({m}), got {len(offsets)}")
    if raw.timing != "async" and any(eps):
        raise ScenarioError(f"{f}.epsilon", "jitter bounds only apply to timing = 'async'")
    if raw.timing != "offset" and any(offsets):
        raise ScenarioError(f"{f}.offsets", "offsets only apply to timing = 'offset'")
    if raw.timing == "offset" and max(offsets) - min(offsets) >= T:
        raise ScenarioError(f"{f}.offsets", f"the spread of the offsets must be < T = {T:g} (the index-aligned "
                                            "exchange needs every agent's interval data before any reset)")
    if raw.beta >= Delta:
        raise ScenarioError(f"{f}.beta", f"must be < Delta = {Delta:g}, got {raw.beta:g}")
    jit = max(eps) if raw.timing == "async" else 0.0
    if Delta * q + jit > T * (1 + 1e-12):
        raise ScenarioError(f"{f}.Delta", f"q Δ + ε = {Delta * q + jit:.6g} must be <= T = {T:g} (all q iterations "
                                          "must fit in an event interval)")
    if raw.timing == "async" and jit > 0 and 2 * jit >= Delta:
        raise ScenarioError(f"{f}.epsilon", f"2ε = {2 * jit:g} must be < Δ = {Delta:g} (iteration times would "
                                            "reorder)")
    if raw.timing != "sync" and raw.ideal:
        raise ScenarioError(f"{f}.ideal", "only for synchronous runs")
    growth = float(np.max(np.linalg.eigvals(sc.A).real))
    horizon = raw.intervals * T + max(abs(x) for x in offsets)
    if growth * horizon > MAX_GROWTH_EXPONENT:
        raise ScenarioError(f"{f}.intervals", f"the plant's state grows like e^({growth:.3g} t) (the largest real part "
                                              f"of eig(A)); over the horizon {horizon:g} it would leave the "
                                              f"floating-point range: at most "
                                              f"{int(MAX_GROWTH_EXPONENT / growth / T):,} intervals of T = {T:g}")


def _check_leave(lv: LeaveSection | None, f: str, m: int, T: float, offsets: list[float], intervals: int) -> None:
    """The leaving agent exists; it leaves and re-joins at event times of its own, inside the horizon."""
    if lv is None:
        return
    if lv.agent > m:
        raise ScenarioError(f"{f}.agent", f"must be <= m = {m}, got {lv.agent}")
    ag = lv.agent - 1
    if lv.rejoin <= lv.at:
        raise ScenarioError(f"{f}.rejoin", f"must be > leave.at = {lv.at:g}")
    for name, t in (("at", lv.at), ("rejoin", lv.rejoin)):
        s = (t - offsets[ag]) / T
        if abs(s - round(s)) > 1e-9:
            raise ScenarioError(f"{f}.{name}", f"must be an event time of agent {ag + 1} (t_i0 + sT), got {t:g}")
    if lv.rejoin > offsets[ag] + intervals * T:
        raise ScenarioError(f"{f}.rejoin", "must fall inside the run's horizon")
