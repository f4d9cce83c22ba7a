"""The hybrid-observer scenario family: a jointly observable (A, C_1..C_m), local observer
gains, a set of strongly connected neighbour graphs, and a list of runs (synchronous,
asynchronous with jittered iteration times, event-time offsets, agents leaving and joining).

Agents are labelled 1..m in scenario files, as in the paper; internally 0..m-1.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

import estimators.jointly_observable_design as jd
from pipeline.errors import ScenarioError
from pipeline.scenario import (scenario_root, as_float, as_float_tuple, as_int, as_list, as_matrix, as_str, join, load_toml,
                               reject_unknown, section)

SECTIONS = ("name", "system", "design", "graphs", "initial", "monte_carlo", "noise", "runs", "paper_values")
TIMINGS = ("sync", "async", "offset")
SWITCHINGS = ("fixed", "alternate_interval", "alternate_iteration")
RULES = ("mean", "symmetric")
POLICIES = ("reinit", "resume", "open_loop")
MAX_Q = 20_000


@dataclass(frozen=True)
class Leave:
    agent: int          # 0-based
    at: float
    rejoin: float
    policy: str


@dataclass(frozen=True)
class RunSpec:
    name: str
    timing: str
    switching: str
    graph: int
    intervals: int
    noise: bool
    rule: str
    q: int
    q_label: str
    mc: bool
    ideal: bool
    epsilon: tuple[float, ...]
    beta: float
    Delta: float
    offsets: tuple[float, ...]
    leave: Leave | None
    reference_run: str
    jitter_seed_label: str = ""

    def key(self) -> dict[str, Any]:
        return {k: (v.__dict__ if isinstance(v, Leave) else v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class HybridScenario:
    name: str
    A: np.ndarray
    C: tuple
    rank_tol: float
    T: float
    q_design: int
    q_label: str
    lam: float
    lam_bar: float
    gains: str
    L_given: tuple | None
    K_given: tuple | None
    poles: tuple | None
    central_poles: tuple
    graph_names: tuple[str, ...]
    graphs: np.ndarray
    x0: np.ndarray
    w0: np.ndarray | None
    xhat0: np.ndarray
    trials: int
    quick_trials: int
    ic_scale: float
    noise_b: np.ndarray | None
    noise_omega: float
    runs: tuple[RunSpec, ...]
    paper_values: dict = field(default_factory=dict)

    @property
    def m(self) -> int:
        return len(self.C)

    @property
    def n(self) -> int:
        return self.A.shape[0]

    def key(self) -> dict[str, Any]:
        d = {}
        for k, v in self.__dict__.items():
            if k in ("name", "quick_trials", "trials"):
                continue
            if k == "runs":
                d[k] = [r.key() for r in v]
            elif isinstance(v, np.ndarray):
                d[k] = v.tolist()
            elif isinstance(v, tuple) and v and isinstance(v[0], np.ndarray):
                d[k] = [x.tolist() for x in v]
            else:
                d[k] = v
        return d

    @classmethod
    def from_dict(cls, data: Any) -> "HybridScenario":
        data, name = scenario_root(data, allowed=SECTIONS, required=("system", "design", "graphs", "initial"))

        # -- system -----------------------------------------------------------------------------
        sysd = section(data["system"], "system")
        reject_unknown(sysd, ("A", "C", "rank_tol"), "system")
        for k in ("A", "C"):
            if k not in sysd:
                raise ScenarioError(f"system.{k}", "missing")
        A = as_matrix(sysd["A"], "system.A")
        n = A.shape[0]
        if A.shape != (n, n):
            raise ScenarioError("system.A", f"must be square, got {A.shape[0]}x{A.shape[1]}")
        C = tuple(as_matrix(c, f"system.C[{i}]") for i, c in enumerate(as_list(sysd["C"], "system.C")))
        m = len(C)
        for i, Ci in enumerate(C):
            if Ci.shape[1] != n:
                raise ScenarioError(f"system.C[{i}]", f"must have n = {n} columns, got {Ci.shape[1]}")
            if not np.any(Ci):
                raise ScenarioError(f"system.C[{i}]", "is zero (every agent must sense something: C_i != 0)")
        rank_tol = as_float(sysd.get("rank_tol", 1e-9), "system.rank_tol", low=0.0, high=1e-2, low_open=True)
        rank = jd.observable_basis(A, np.vstack(C), rank_tol).rows.shape[0]
        if rank < n:
            raise ScenarioError("system.C", f"(C, A) is not jointly observable: the observable space of the stacked "
                                            f"outputs has dimension {rank} < n = {n} (relative rank tolerance "
                                            f"{rank_tol:g}); condition (16) fails")
        if m < 2:
            raise ScenarioError("system.C", "needs at least 2 agents (with one agent there is nothing to distribute)")

        # -- design -----------------------------------------------------------------------------
        des = section(data["design"], "design")
        reject_unknown(des, ("T", "q", "lambda", "lambda_bar", "gains", "L", "K", "poles", "central_poles"), "design")
        for k in ("T", "q", "lambda", "lambda_bar"):
            if k not in des:
                raise ScenarioError(f"design.{k}", "missing")
        T = as_float(des["T"], "design.T", low=0.0, low_open=True)
        lam = as_float(des["lambda"], "design.lambda", low=0.0, low_open=True)
        lam_bar = as_float(des["lambda_bar"], "design.lambda_bar", low=0.0, low_open=True)
        if lam >= lam_bar:
            raise ScenarioError("design.lambda", f"must be < lambda_bar = {lam_bar} (the constant d of Theorem 1 "
                                                 f"divides by 1 - e^(-(λ̄-λ)T)), got {lam}")
        L_given = None
        if "L" in des:
            L_given = tuple(as_matrix(Li, f"design.L[{i}]") for i, Li in enumerate(as_list(des["L"], "design.L")))
            if len(L_given) != m:
                raise ScenarioError("design.L", f"must list one matrix per agent ({m}), got {len(L_given)}")
            for i, Li in enumerate(L_given):
                if Li.shape[1] != n or not jd.same_kernel(Li, A, C[i], rank_tol):
                    raise ScenarioError(f"design.L[{i}]", "must have full row rank and kernel equal to the unobservable "
                                                          f"space of (C_{i + 1}, A)")
        gains = as_str(des.get("gains", "place"), "design.gains", ("given", "place"))
        K_given = poles = None
        locs = [jd.local_design(A, C[i], rank_tol=rank_tol, L=None if L_given is None else L_given[i]) for i in range(m)]
        if gains == "given":
            if "K" not in des:
                raise ScenarioError("design.K", "missing (needed for gains = 'given')")
            if L_given is None:
                raise ScenarioError("design.L", "missing (a given K is expressed in a given basis L)")
            K_given = tuple(as_matrix(Ki, f"design.K[{i}]") for i, Ki in enumerate(as_list(des["K"], "design.K")))
            if len(K_given) != m:
                raise ScenarioError("design.K", f"must list one matrix per agent ({m}), got {len(K_given)}")
            for i, Ki in enumerate(K_given):
                if Ki.shape != (locs[i].n_i, C[i].shape[0]):
                    raise ScenarioError(f"design.K[{i}]", f"must have shape {locs[i].n_i}x{C[i].shape[0]}, got "
                                                          f"{Ki.shape[0]}x{Ki.shape[1]}")
            Fs = [locs[i].Abar + K_given[i] @ locs[i].Cbar for i in range(m)]
        else:
            if "K" in des:
                raise ScenarioError("design.K", "only allowed with gains = 'given'")
            if "poles" in des:
                plist = as_list(des["poles"], "design.poles")
                if len(plist) != m:
                    raise ScenarioError("design.poles", f"must list one pole set per agent ({m})")
                poles = tuple(as_float_tuple(p, f"design.poles[{i}]") for i, p in enumerate(plist))
                for i, p in enumerate(poles):
                    if len(p) != locs[i].n_i:
                        raise ScenarioError(f"design.poles[{i}]", f"must have n_i = {locs[i].n_i} poles")
            else:
                poles = tuple(default_poles(lam_bar, loc.n_i) for loc in locs)
            Fs = []
            for i in range(m):
                try:
                    K = jd.place_gain(locs[i].Abar, locs[i].Cbar, poles[i])
                except ValueError as exc:
                    raise ScenarioError(f"design.poles[{i}]", f"pole placement failed: {exc}") from None
                Fs.append(locs[i].Abar + K @ locs[i].Cbar)
        for i, F in enumerate(Fs):
            sa = jd.spectral_abscissa(F)
            if sa > -lam_bar + 1e-9:
                raise ScenarioError("design.lambda_bar", f"agent {i + 1}'s local observer has spectral abscissa "
                                                         f"{sa:.6g} > -λ̄ = {-lam_bar}: (15) cannot hold")
        central_poles = as_float_tuple(des.get("central_poles", list(default_poles(lam_bar, n))), "design.central_poles")
        if len(central_poles) != n or max(central_poles) >= 0:
            raise ScenarioError("design.central_poles", f"must be {n} negative real poles")
        try:
            jd.stacked_gain(A, np.vstack(C), central_poles, rank_tol)
        except ValueError as exc:
            raise ScenarioError("design.central_poles", f"pole placement for the centralized reference failed: "
                                                        f"{exc}") from None
        nA = float(np.linalg.norm(A, 2))

        # -- graphs -----------------------------------------------------------------------------
        gd = section(data["graphs"], "graphs")
        reject_unknown(gd, ("names", "neighbors"), "graphs")
        if "neighbors" not in gd:
            raise ScenarioError("graphs.neighbors", "missing")
        glist = as_list(gd["neighbors"], "graphs.neighbors")
        graphs = []
        for g, gl in enumerate(glist):
            f = f"graphs.neighbors[{g}]"
            rows = as_list(gl, f)
            if len(rows) != m:
                raise ScenarioError(f, f"must list the neighbours of each of the {m} agents, got {len(rows)}")
            nb = []
            for i, r in enumerate(rows):
                lab = as_list(r, f"{f}[{i}]", min_len=0)
                nb.append([as_int(j, f"{f}[{i}]", low=1, high=m) - 1 for j in lab])
            N = jd.neighbour_mask(nb, m)
            if not jd.is_strongly_connected(N):
                raise ScenarioError(f, "graph is not strongly connected (Theorems 1 and 2 need N(t) strongly connected "
                                       "for all t)")
            graphs.append(N)
        graphs = np.array(graphs)
        names = tuple(as_str(x, f"graphs.names[{i}]") for i, x in enumerate(as_list(gd.get("names", [f"G{g + 1}" for g in range(len(graphs))]), "graphs.names")))
        if len(names) != len(graphs):
            raise ScenarioError("graphs.names", f"must name each of the {len(graphs)} graphs")

        # -- q ----------------------------------------------------------------------------------
        q_raw = des["q"]
        if isinstance(q_raw, str):
            q_label = as_str(q_raw, "design.q", ("theory", "symmetric"))
            if q_label == "theory":
                # (22) grows with ρ: its value at ρ = 0 is a lower bound, enough to refuse without computing ρ
                q_design = jd.sufficient_q(0.0, m, nA, lam, T).q_thm22
                if q_design <= MAX_Q:
                    rho = jd.rho_exact(np.array([loc.P for loc in locs]))
                    if rho.upper >= 1:
                        raise ScenarioError("design.q", f"ρ of (17) is only bracketed in [{rho.rho:.6g}, {rho.upper:.6g}]: "
                                                        "no sufficient q is known; give an integer q")
                    q_design = jd.sufficient_q(rho.upper, m, nA, lam, T).q_thm22
                else:
                    raise ScenarioError("design.q", f"the theory q is {q_design} or more (> {MAX_Q}): too many "
                                                    "iterations to simulate; give an integer q (the hypotheses report "
                                                    "the required q)")
            else:
                sig = jd.sigma_symmetric(np.array([loc.P for loc in locs]))[0] if m <= 6 else None
                if sig is None:
                    raise ScenarioError("design.q", "'symmetric' needs m <= 6 (σ of (26) by enumeration)")
                q_design = symmetric_q(sig, nA, lam, T, "design.q")
            if q_design > MAX_Q:
                raise ScenarioError("design.q", f"the {q_label} q is {q_design} (> {MAX_Q}): too many iterations to "
                                                "simulate; give an integer q (the hypotheses report the required q)")
        else:
            q_design = as_int(q_raw, "design.q", low=1, high=MAX_Q)
            q_label = "given"

        # -- initial conditions ---------------------------------------------------------------------
        ini = section(data["initial"], "initial")
        reject_unknown(ini, ("x0", "w0", "xhat0"), "initial")
        for k in ("x0", "xhat0"):
            if k not in ini:
                raise ScenarioError(f"initial.{k}", "missing")
        x0 = np.array(as_float_tuple(ini["x0"], "initial.x0"))
        if x0.shape != (n,):
            raise ScenarioError("initial.x0", f"must have n = {n} entries")
        w0 = None
        if "w0" in ini:
            wl = as_list(ini["w0"], "initial.w0")
            if len(wl) != m:
                raise ScenarioError("initial.w0", f"must list one vector per agent ({m})")
            w0 = []
            for i, w in enumerate(wl):
                v = np.array(as_float_tuple(w, f"initial.w0[{i}]"))
                if v.shape != (locs[i].n_i,):
                    raise ScenarioError(f"initial.w0[{i}]", f"must have n_i = {locs[i].n_i} entries (rank of agent "
                                                            f"{i + 1}'s observability matrix)")
                w0.append(v)
            if L_given is None:
                raise ScenarioError("initial.w0", "needs design.L (w_i lives in the coordinates of L_i); omit w0 to "
                                                  "start every local observer at w_i = 0")
            w0 = np.concatenate(w0)
        xh = as_matrix(ini["xhat0"], "initial.xhat0", shape=(m, n))

        # -- Monte Carlo, noise ---------------------------------------------------------------------------
        mc = section(data.get("monte_carlo", {}), "monte_carlo")
        reject_unknown(mc, ("trials", "quick_trials", "scale"), "monte_carlo")
        trials = as_int(mc.get("trials", 64), "monte_carlo.trials", low=1, high=100_000)
        quick_trials = as_int(mc.get("quick_trials", min(trials, 16)), "monte_carlo.quick_trials", low=1, high=trials)
        ic_scale = as_float(mc.get("scale", 5.0), "monte_carlo.scale", low=0.0, low_open=True)
        nz = section(data.get("noise", {}), "noise")
        reject_unknown(nz, ("b", "omega"), "noise")
        noise_b = None
        if "b" in nz:
            noise_b = np.array(as_float_tuple(nz["b"], "noise.b"))
            if noise_b.shape != (n,):
                raise ScenarioError("noise.b", f"must have n = {n} entries")
        noise_omega = as_float(nz.get("omega", 10.0), "noise.omega", low=0.0)

        runs = parse_runs(data.get("runs"), m=m, T=T, q_design=q_design, q_label=q_label, graphs=graphs,
                          noise_b=noise_b, n_graphs=len(graphs), A=A, C=C, nA=nA, lam=lam, locs=locs)
        pv = section(data.get("paper_values", {}), "paper_values")
        return cls(name, A, C, rank_tol, T, q_design, q_label, lam, lam_bar, gains, L_given, K_given, poles,
                   central_poles, names, graphs, x0, w0, xh, trials, quick_trials, ic_scale, noise_b, noise_omega,
                   runs, dict(pv))


def symmetric_q(sigma: float, norm_A: float, lam: float, T: float, field: str) -> int:
    """q of (27), or a ScenarioError naming `field` when σ is not below 1."""
    try:
        return jd.q_symmetric(sigma, norm_A, lam, T)
    except ValueError as exc:
        raise ScenarioError(field, f"(27) gives no q: {exc}") from None


def default_poles(lam_bar: float, k: int) -> tuple[float, ...]:
    """Distinct real poles strictly beyond -λ̄: -λ̄(1.25 + 0.25 j), j = 0..k-1."""
    return tuple(-lam_bar * (1.25 + 0.25 * j) for j in range(k))


RUN_KEYS = ("name", "timing", "switching", "graph", "intervals", "noise", "rule", "q", "monte_carlo", "ideal",
            "epsilon", "beta", "Delta", "offsets", "leave", "reference_run")


def parse_runs(value: Any, *, m: int, T: float, q_design: int, q_label: str, graphs: np.ndarray, noise_b, n_graphs: int,
               A, C, nA, lam, locs) -> tuple[RunSpec, ...]:
    symmetric = all(np.array_equal(G, G.T) for G in graphs)
    if value is None:
        value = [{"name": "sync", "timing": "sync", "monte_carlo": True},
                 {"name": "ideal", "timing": "sync", "ideal": True, "monte_carlo": True},
                 {"name": "async", "timing": "async", "reference_run": "sync", "monte_carlo": True}]
        if symmetric:
            value.append({"name": "symmetric", "timing": "sync", "rule": "symmetric", "q": "symmetric",
                          "monte_carlo": True})
    runs = []
    names = set()
    for r_i, raw in enumerate(as_list(value, "runs")):
        f = f"runs[{r_i}]"
        raw = section(raw, f)
        reject_unknown(raw, RUN_KEYS, f)
        name = as_str(raw.get("name", f"run{r_i}"), join(f, "name"))
        if not name or not all(c.isalnum() or c in "-_" for c in name) or name in names:
            raise ScenarioError(join(f, "name"), f"must be a unique identifier, got '{name}'")
        names.add(name)
        timing = as_str(raw.get("timing", "sync"), join(f, "timing"), TIMINGS)
        switching = as_str(raw.get("switching", "alternate_interval" if n_graphs > 1 else "fixed"), join(f, "switching"),
                           SWITCHINGS)
        graph = as_int(raw.get("graph", 1), join(f, "graph"), low=1, high=n_graphs) - 1
        intervals = as_int(raw.get("intervals", 15), join(f, "intervals"), low=1, high=2000)
        noise = bool(raw.get("noise", False))
        if not isinstance(raw.get("noise", False), bool):
            raise ScenarioError(join(f, "noise"), "must be true or false")
        if noise and noise_b is None:
            raise ScenarioError(join(f, "noise"), "needs a [noise] section with b")
        rule = as_str(raw.get("rule", "mean"), join(f, "rule"), RULES)
        used = [graphs[graph]] if switching == "fixed" else list(graphs)
        if rule == "symmetric" and not all(np.array_equal(G, G.T) for G in used):
            raise ScenarioError(join(f, "rule"), "the convex rule (25) is for symmetric graphs; a graph this run "
                                                 "uses is directed (use switching = 'fixed' with a symmetric graph)")
        qv = raw.get("q", "design")
        if isinstance(qv, str):
            ql = as_str(qv, join(f, "q"), ("design", "symmetric"))
            if ql == "design":
                q, q_lab = q_design, q_label
            else:
                if m > 6:
                    raise ScenarioError(join(f, "q"), "'symmetric' needs m <= 6 (σ of (26) by enumeration)")
                sig = jd.sigma_symmetric(np.array([loc.P for loc in locs]))[0]
                q, q_lab = symmetric_q(sig, nA, lam, T, join(f, "q")), "symmetric"
                if q > MAX_Q:
                    raise ScenarioError(join(f, "q"), f"q of (27) is {q} (> {MAX_Q}); give an integer")
        else:
            q, q_lab = as_int(qv, join(f, "q"), low=1, high=MAX_Q), "given"
        for flag in ("monte_carlo", "ideal"):
            if not isinstance(raw.get(flag, False), bool):
                raise ScenarioError(join(f, flag), "must be true or false")
        mc_flag, ideal = bool(raw.get("monte_carlo", False)), bool(raw.get("ideal", False))
        eps = tuple(as_float_tuple(raw["epsilon"], join(f, "epsilon"), low=0.0)) if "epsilon" in raw else (0.0,) * m
        if len(eps) != m:
            raise ScenarioError(join(f, "epsilon"), f"must have one bound per agent ({m})")
        offsets = tuple(as_float_tuple(raw["offsets"], join(f, "offsets"))) if "offsets" in raw else (0.0,) * m
        if len(offsets) != m:
            raise ScenarioError(join(f, "offsets"), f"must have one offset per agent ({m})")
        if timing == "async" and "epsilon" not in raw:
            eps = (0.0,) * m
        if timing != "async" and any(eps) and timing != "offset":
            raise ScenarioError(join(f, "epsilon"), "jitter bounds only apply to timing = 'async'")
        if timing != "offset" and any(offsets):
            raise ScenarioError(join(f, "offsets"), "offsets only apply to timing = 'offset'")
        if timing == "offset":
            eps = tuple(abs(o) for o in offsets)
            if max(offsets) - min(offsets) >= T:
                raise ScenarioError(join(f, "offsets"), f"the spread of the offsets must be < T = {T} (the index-aligned "
                                                        "exchange needs every agent's interval data before any reset)")
        beta = as_float(raw.get("beta", 0.0), join(f, "beta"), low=0.0)
        Delta = as_float(raw.get("Delta", T / q), join(f, "Delta"), low=0.0, low_open=True)
        if beta >= Delta:
            raise ScenarioError(join(f, "beta"), f"must be < Delta = {Delta}, got {beta}")
        if Delta * q + (max(eps) if timing == "async" else 0.0) > T * (1 + 1e-12):
            raise ScenarioError(join(f, "Delta"), f"q Δ + ε = {Delta * q + max(eps):.6g} must be <= T = {T} "
                                                  "(all q iterations must fit in an event interval)")
        if timing == "async" and max(eps) > 0 and 2 * max(eps) >= Delta:
            raise ScenarioError(join(f, "epsilon"), f"2ε = {2 * max(eps)} must be < Δ = {Delta} (iteration times "
                                                    "would reorder)")
        if timing == "async" and ideal:
            raise ScenarioError(join(f, "ideal"), "only for synchronous runs")
        leave = None
        if "leave" in raw:
            lv = section(raw["leave"], join(f, "leave"))
            reject_unknown(lv, ("agent", "at", "rejoin", "policy"), join(f, "leave"))
            for k in ("agent", "at", "rejoin"):
                if k not in lv:
                    raise ScenarioError(join(join(f, "leave"), k), "missing")
            ag = as_int(lv["agent"], join(f, "leave.agent"), low=1, high=m) - 1
            at = as_float(lv["at"], join(f, "leave.at"), low=0.0, low_open=True)
            rejoin = as_float(lv["rejoin"], join(f, "leave.rejoin"), low=0.0)
            if rejoin <= at:
                raise ScenarioError(join(f, "leave.rejoin"), f"must be > leave.at = {at}")
            for key, t in (("at", at), ("rejoin", rejoin)):
                s = (t - offsets[ag]) / T
                if abs(s - round(s)) > 1e-9:
                    raise ScenarioError(join(f, f"leave.{key}"), f"must be an event time of agent {ag + 1} "
                                                                 f"(t_i0 + sT), got {t}")
            if rejoin > offsets[ag] + intervals * T:
                raise ScenarioError(join(f, "leave.rejoin"), "must fall inside the run's horizon")
            policy = as_str(lv.get("policy", "reinit"), join(f, "leave.policy"), POLICIES)
            leave = Leave(ag, at, rejoin, policy)
        ref = as_str(raw.get("reference_run", ""), join(f, "reference_run"))
        if ref and ref not in names:
            raise ScenarioError(join(f, "reference_run"), f"must name an earlier run, got '{ref}'")
        runs.append(RunSpec(name, timing, switching, graph, intervals, noise, rule, q, q_lab, mc_flag, ideal, eps,
                            beta, Delta, offsets, leave, ref, name))
    return tuple(runs)


def load(path: Path) -> HybridScenario:
    data = load_toml(path)
    data.pop("family", None)
    return HybridScenario.from_dict(data)


def paper_scenario() -> HybridScenario:
    return load(Path(__file__).with_name("paper.toml"))


def generic_scenario() -> HybridScenario:
    return load(Path(__file__).with_name("generic.toml"))
