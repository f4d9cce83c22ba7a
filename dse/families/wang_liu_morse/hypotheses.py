"""The hypotheses of the hybrid observer's theorems, as checks of their own.

Scenario-level (one row per scenario):

- ``joint_observability``: (16), ∩ image P_i = 0, i.e. σ_min([I - P_1; ...; I - P_m]) > 0;
- ``strong_connectivity``: every neighbour graph the scenario uses is strongly connected
  (Theorems 1 and 2: N(t) strongly connected for all t);
- ``local_observers``: (15) with λ < λ̄: every Ā_i + K_i C̄_i has spectral abscissa < -λ̄;
- ``q_eq22``: the design q satisfies (22), q > N·ceil((λ + ||A||)T / ln(1/α)), with ρ of (17)
  and α of Lemma 5 (Theorems 1, 2, Lemma 4 and (63) rest on it);
- ``q_eq27``: the design q satisfies (27), the condition of the symmetric special case.

Run-level (one row per run that needs it; ids carry the run's name):

- ``<run>.q_eq22`` / ``<run>.q_eq27``: a run whose q is not the design q (a symmetric-rule
  run is judged by (27));
- ``<run>.eq10``: (10), ε_i + ε_j <= β and ε_i + ε_j + β < Δ, and Δq + ε <= T (Lemma 1,
  Lemma 3, Theorem 2; Section 4 with ε = max |t_i0|);
- ``<run>.windows``: N(t) is constant on every window 𝓘_s(k) of (23) (Lemma 3, Theorem 2);
- ``<run>.strong_connectivity``: every graph the run uses is strongly connected (only when some
  graph of the scenario is not: the scenario-level row then fails, and each run is judged by the
  graphs it uses).

Ids: ``wang-liu-morse.hyp.[<scenario>.]<name>``; the scenario is named when a reproduction
checks several. Claims that span several scenarios or runs check each (scenario, run) cell
against the hypotheses that cell rests on (`cell_failures`) and name the cells left out.
Every check reads the design stage only (`design.Design`, or a run's results, which carry it),
so that `dse check` decides them without simulating.
"""
from __future__ import annotations

import math
from typing import Callable

import numpy as np

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.verify.rules import Holds, Hypothesis

from .bounds import run_epsilon
from .scenario import HybridScenario, RunSpec

PID = "wang-liu-morse"
EPS = float(np.finfo(float).eps)
SCENARIO_LEVEL = ("joint_observability", "strong_connectivity", "local_observers", "q_eq22", "q_eq27")
#: hypotheses the scenario validation already enforces (they hold on every valid scenario)
VALIDATED = ("joint_observability", "local_observers")


def hyp_id(part: str, name: str, multi: bool) -> str:
    return f"{PID}.hyp.{part}.{name}" if multi else f"{PID}.hyp.{name}"


# -- scenario level --------------------------------------------------------------------------------

def joint_observability(r) -> Holds:
    """(16): the smallest singular value of [I - P_1; ...; I - P_m] is above the rank tolerance
    the observable subspaces were computed with (it is 0 iff a nonzero x lies in every image P_i)."""
    smin = float(r.design["sigma_min_16"])
    tol = r.scenario.rank_tol
    return Holds(smin > tol, smin, tol, f"σ_min([I - P_1; ...; I - P_m]) = {smin:.6g} vs the rank tolerance {tol:g}")


def strong_connectivity(r, graphs: list[int] | None = None) -> Holds:
    """Every neighbour graph (of the scenario, or the ones in `graphs`) is strongly connected."""
    names = r.scenario.graph_names
    idx = list(range(len(r.scenario.graphs))) if graphs is None else graphs
    ok = [bool(jd.is_strongly_connected(r.scenario.graphs[g])) for g in idx]
    bad = [names[g] for g, o in zip(idx, ok) if not o]
    return Holds(all(ok), int(sum(ok)), len(ok), f"{sum(ok)} of {len(ok)} neighbour graphs strongly connected "
                                                 "(arc j -> i iff j ∈ N_i, self-arcs included)"
                                                 + (f"; not: {', '.join(bad)}" if bad else ""))


def graphs_of(sc: HybridScenario, run: RunSpec) -> list[int]:
    """The graphs a run uses."""
    return [run.graph] if run.switching == "fixed" else list(range(len(sc.graphs)))


def all_strongly_connected(sc: HybridScenario) -> bool:
    return all(jd.is_strongly_connected(g) for g in sc.graphs)


def local_observers(r) -> Holds:
    """(15) with λ < λ̄: every local observer matrix F_i has spectral abscissa <= -λ̄ (to the
    round-off of its computed eigenvalues, Bauer-Fike) and c_i = sup ||e^(F_i τ)|| e^(λ̄τ) is finite."""
    sc = r.scenario
    sa_i = np.asarray(r.design["local_abscissa"], float)
    tol_i = np.asarray(r.design["local_abscissa_tol"], float)
    k = int(np.argmax(sa_i - tol_i))
    sa = float(sa_i.max())
    c = float(np.max(r.design["c_i"]))
    ok = bool(sc.lam < sc.lam_bar and np.all(sa_i - tol_i <= -sc.lam_bar) and math.isfinite(c))
    return Holds(ok, sa, -sc.lam_bar, f"largest spectral abscissa of Ā_i + K_i C̄_i = {sa:.6g} <= -λ̄ = {-sc.lam_bar:g} "
                                      f"(eigenvalue round-off allowance of agent {k + 1}: {tol_i[k]:.3g}); λ = {sc.lam:g} "
                                      f"< λ̄; c = max_i c_i = {c:.4g} (15)")


def _int(v) -> int:
    return jd.exact_int(str(np.asarray(v)))


#: an integer for people (the q of (22) has about (m-1)² log10(m) digits; the exact value is in the design table)
big = jd.readable_int


def number(q: int) -> int | float:
    """A hypothesis' value or threshold: the integer itself, or a float beyond 10^15 (inf beyond 1e308)."""
    if q < 10**15:
        return q
    try:
        return float(q)
    except OverflowError:
        return math.inf


def q_eq22(r, q: int) -> Holds:
    """q satisfies (22) with α of Lemma 5. With ρ exact the answer is exact; with ρ only
    bracketed (m >= 6) it holds when q meets (22) for the upper bound of ρ, fails when q misses
    it for the lower bound, and is undecided in between."""
    dz, sc = r.design, r.scenario
    m = sc.m
    N = (m - 1) ** 2 + 1
    lo = _int(dz["q_thm22"])
    hi = _int(dz["q_thm22_upper"]) if "q_thm22_upper" in dz else None
    exact = bool(dz["rho_exact"])
    rho = f"{float(dz['rho']):.6g}" if exact else f"in [{float(dz['rho']):.6g}, {float(dz['rho_upper']):.6g}]"
    text = (f"q = {q:,}; (22) with the Lemma-5 α = 1 - (m-1)(1-ρ)/m^((m-1)²) = {float(dz['alpha_lemma5']):.12g} "
            f"(m = {m}, N = {N}, ρ {'= ' if exact else ''}{rho}, ||A|| = {float(dz['norm_A']):.6g}, λ = {sc.lam:g}, "
            f"T = {sc.T:g}) needs q >= {big(lo)} "
            f"[(21) with (19): {big(_int(dz['q_thm21']))}; minimal sufficient from the proof of Lemma 4: "
            f"{big(_int(dz['q_minimal']))}; with α as printed in (18): {big(_int(dz['q_thm22_printed_alpha']))}]")
    lam_p = float(sc.paper_values.get("lambda", sc.lam))
    if lam_p != sc.lam:
        text += (f"; for the printed λ = {lam_p:g}: q >= {big(_int(dz['q_thm22_paper']))} (α as printed: "
                 f"{big(_int(dz['q_thm22_printed_alpha_paper']))})")
    if exact:
        return Holds(q >= lo, q, number(lo), text)
    if q < lo:
        return Holds(False, q, number(lo), text + "; q misses (22) already for the lower bound of ρ")
    if hi is not None and q >= hi:
        return Holds(True, q, number(hi), text + f"; q meets (22) for the upper bound of ρ (needs {big(hi)})")
    return Holds(None, q, number(hi) if hi is not None else None,
                 text + "; ρ is only bracketed and q lies between the two requirements")


def q_eq27(r, q: int) -> Holds:
    """q satisfies (27) for σ of (26) (all connected graphs on m vertices, m <= 6)."""
    dz, sc = r.design, r.scenario
    if "sigma" not in dz:
        return Holds(None, q, None, f"σ of (26) is not computed for m = {sc.m} > 6 (enumeration of connected graphs)")
    if "q27" not in dz:
        return Holds(None, q, None, f"σ = {float(dz['sigma']):.10g} is not below 1: (27) gives no q")
    need = int(dz["q27"])
    text = (f"q = {q:,}; (27) with σ = {float(dz['sigma']):.10g} (over {int(dz['sigma_graphs'])} connected graphs), "
            f"||A|| = {float(dz['norm_A']):.6g}, λ = {sc.lam:g}, T = {sc.T:g} needs q >= {need:,} (minimal sufficient "
            f"{int(dz['q27_minimal']):,})")
    lam_p = float(sc.paper_values.get("lambda", sc.lam))
    if lam_p != sc.lam and "q27_paper" in dz:
        text += f"; for the printed λ = {lam_p:g}: q >= {int(dz['q27_paper']):,}"
    return Holds(q >= need, q, need, text)


# -- run level ---------------------------------------------------------------------------------------



def eq10(run: RunSpec, T: float) -> Holds:
    """(10) for all i, j (i = j included: 2ε <= β, 2ε + β < Δ) and Δq + ε <= T; the last with
    4 eps·T for the rounding of an input Δ = T/q."""
    eps = run_epsilon(run)
    a, b, c = 2 * eps - run.beta, 2 * eps + run.beta - run.Delta, run.Delta * run.q + eps - T
    ok = a <= 0 and b < 0 and c <= 4 * EPS * T
    parts = []
    if a > 0:
        parts.append(f"ε_i + ε_j <= β fails: 2ε = {2 * eps:g} > β = {run.beta:g}")
    if b >= 0:
        parts.append(f"ε_i + ε_j + β < Δ fails: {2 * eps + run.beta:g} >= Δ = {run.Delta:g}")
    if c > 4 * EPS * T:
        parts.append(f"Δq + ε = {run.Delta * run.q + eps:.6g} > T = {T:g}")
    text = "; ".join(parts) if parts else (f"2ε = {2 * eps:g} <= β = {run.beta:g}, 2ε + β = {2 * eps + run.beta:g} < Δ = "
                                           f"{run.Delta:g}, Δq + ε = {run.Delta * run.q + eps:.6g} <= T = {T:g}")
    return Holds(ok, max(a, b, c), 0.0, text)


def windows(sc: HybridScenario, run: RunSpec) -> Holds:
    """N(t) constant on every 𝓘_s(k) = [sT + (k-1)Δ + β - ε, sT + (k-1)Δ + β + ε] (23), s = 0..S-1
    (the window of interval s+1; the first interval included), k = 1..q: no switch of the
    right-continuous schedule in (start, end]."""
    eps = run_epsilon(run)
    sched = ho.GraphSchedule(sc.graphs, kind=run.switching, fixed=run.graph, T=sc.T, Delta=run.Delta, beta=run.beta,
                             q=run.q)
    sw = sched.switch_times((run.intervals + 1) * sc.T)
    c = (sc.T * np.arange(run.intervals))[:, None] + (np.arange(run.q) * run.Delta + run.beta)[None, :]
    inside = np.searchsorted(sw, c + eps, side="right") - np.searchsorted(sw, c - eps, side="right")
    bad = int((inside > 0).sum())
    return Holds(bad == 0, bad, 0, f"{bad} of {c.size} windows (ε = {eps:g}) contain a graph switch ({sw.size} switches "
                                   f"in the run, switching = '{run.switching}')")


# -- which hypothesis a run's q rests on --------------------------------------------------------------

def q_name(sc: HybridScenario, run: RunSpec) -> str:
    """The hypothesis row that decides the q of `run`."""
    if run.rule == "symmetric":
        return f"{run.name}.q_eq27"
    return "q_eq22" if run.q == sc.q_design else f"{run.name}.q_eq22"


def run_rows(sc: HybridScenario) -> list[tuple[str, str, Callable]]:
    """(name, statement, check(r)) for the run-level hypotheses of a scenario."""
    rows = []
    connected = all_strongly_connected(sc)
    for run in sc.runs:
        if not connected:
            rows.append((f"{run.name}.strong_connectivity", f"run {run.name}: every graph it uses is strongly connected",
                         lambda r, run=run: strong_connectivity(r, graphs_of(r.scenario, run))))
        if run.rule == "symmetric":
            rows.append((f"{run.name}.q_eq27", f"run {run.name}: q satisfies (27)",
                         lambda r, q=run.q: q_eq27(r, q)))
        elif run.q != sc.q_design:
            rows.append((f"{run.name}.q_eq22", f"run {run.name}: q satisfies (22)", lambda r, q=run.q: q_eq22(r, q)))
        if run.timing in ("async", "offset"):
            rows.append((f"{run.name}.eq10", f"run {run.name}: (10) and Δq + ε <= T",
                         lambda r, run=run: eq10(run, r.scenario.T)))
            rows.append((f"{run.name}.windows", f"run {run.name}: N(t) constant on every window 𝓘_s(k) of (23)",
                         lambda r, run=run: windows(r.scenario, run)))
    return rows


SCENARIO_ROWS: tuple[tuple[str, str, Callable], ...] = (
    ("joint_observability", "(16): (C, A) jointly observable, ∩ image P_i = 0", joint_observability),
    ("strong_connectivity", "every neighbour graph N(t) is strongly connected", strong_connectivity),
    ("local_observers", "(15): the local observers decay at least as fast as e^(-λ̄t), λ < λ̄", local_observers),
    ("q_eq22", "the design q satisfies (22) (ρ of (17), α of Lemma 5)", lambda r: q_eq22(r, r.scenario.q_design)),
    ("q_eq27", "the design q satisfies (27) (σ of (26), symmetric special case)",
     lambda r: q_eq27(r, r.scenario.q_design)),
)


def rows_of(sc: HybridScenario) -> list[tuple[str, str, Callable]]:
    return list(SCENARIO_ROWS) + run_rows(sc)


def hypotheses(scenarios: dict[str, HybridScenario]) -> list[Hypothesis]:
    multi = len(scenarios) > 1
    out = []
    for part, sc in scenarios.items():
        for name, statement, fn in rows_of(sc):
            out.append(Hypothesis(hyp_id(part, name, multi), (f"{part}: " if multi else "") + statement,
                                  lambda res, part=part, fn=fn: fn(res[part])))
    return out


def cell_failures(res, part: str, run: RunSpec, needs: tuple[str, ...]) -> list[tuple[str, Holds]]:
    """The hypotheses among `needs` ('q', 'eq10', 'windows' or a scenario-level name) that do
    not hold (or cannot be decided) for one (scenario, run) cell, with their ids."""
    r = res[part]
    sc = r.scenario
    multi = len(res.parts) > 1
    table = {name: fn for name, _, fn in rows_of(sc)}
    out = []
    for need in needs:
        if need == "strong_connectivity":
            name = f"{run.name}.strong_connectivity" if not all_strongly_connected(sc) else need
        else:
            name = q_name(sc, run) if need == "q" else (f"{run.name}.{need}" if need in ("eq10", "windows") else need)
        if name not in table:
            continue
        h = table[name](r)
        if h.holds is not True:
            out.append((hyp_id(part, name, multi), h))
    return out
