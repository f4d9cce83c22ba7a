"""The hypotheses of the hybrid observer's theorems, registered on their checks (the family's
`ClaimSet` is made here; the claims modules add the claims to it). Per scenario: (16) joint
observability, strong connectivity of every neighbour graph (Theorems 1 and 2 need N(t) strongly
connected at every t), (15) for the local observers with λ < λ̄, and the design q against (22)
(ρ of (17), α of Lemma 5) and against (27). Per run that needs it: the graphs it uses strongly
connected (when some graph of the scenario is not), its own q against (22) or (27) when it is not
the design q, and for jittered iterations or event-time offsets (10) with Δq + ε <= T and N(t)
constant on the windows 𝓘_s(k) of (23). Ids `wang-liu-morse.hyp.[<scenario>.][<run>.]<name>`,
the scenario named when a run checks several. Every check reads the design stage only."""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.jointly_observable_design as jd
from dse.contract.claims import ClaimSet, Where
from dse.verify.rules import Holds

from ..scenario import HybridFile, RunSection
from ..simulation import run_epsilon, schedule_for
from ..stages import Part

PID = "wang-liu-morse"
EPS = float(np.finfo(float).eps)
#: hypotheses the scenario validation already enforces (they hold on every valid scenario)
VALIDATED = ("joint_observability", "local_observers")

claims = ClaimSet(select_design=lambda design, name: design.named(name),
                  modules=tuple(f"{__package__}.{m}" for m in ("hypotheses", "designs", "iterations", "bounds", "figures")))
HYP = PID + ".hyp.{scenario.}"


def hyp_id(label: str, name: str, several: bool, run_id: str = PID) -> str:
    """A hypothesis id as the claims name it: `run_id` is the paper's id, or a user's scenario name (the ids of
    a user's run start with it; `dse.contract.claims` does the same for the declared templates)."""
    return f"{run_id}.hyp.{label}.{name}" if several else f"{run_id}.hyp.{name}"


def rests_on(*names: str):
    """The hypotheses every cell of a claim rests on, scenario by scenario: the validated ones
    always, strong connectivity when every graph of the scenario has it (otherwise each run is
    gated by the graphs it uses), and in a one-scenario run 'q_eq22' when every run with rule (13)
    uses the design q (otherwise each cell is gated by its own row)."""
    def ids(where: Where) -> tuple[str, ...]:
        several = len(where.scenarios) > 1
        out = []
        for sc in where.run.scenarios:
            for name in names:
                if name in VALIDATED or (name == "strong_connectivity" and sc.all_strongly_connected) or (
                        name == "q_eq22" and not several and all(r.q == sc.q_design for r in sc.runs if r.rule == "mean")):
                    out.append(hyp_id(sc.name, name, several))
        return tuple(out)
    return ids


# -- per scenario --------------------------------------------------------------------------------------

@claims.hypothesis(HYP + "joint_observability", "{scenario: }(16): (C, A) jointly observable, ∩ image P_i = 0")
def joint_observability(r: Part) -> Holds:
    """(16): the smallest singular value of [I - P_1; ...; I - P_m] is above the rank tolerance
    the observable subspaces were computed with (it is 0 iff a nonzero x lies in every image P_i)."""
    smin = float(r.design["sigma_min_16"])
    tol = r.scenario.rank_tol
    return Holds(smin > tol, smin, tol, f"σ_min([I - P_1; ...; I - P_m]) = {smin:.6g} vs the rank tolerance {tol:g}")


@claims.hypothesis(HYP + "strong_connectivity", "{scenario: }every neighbour graph N(t) is strongly connected")
def strong_connectivity(r: Part, graphs: list[int] | None = None) -> Holds:
    """Every neighbour graph (of the scenario, or the ones in `graphs`) is strongly connected."""
    sc = r.scenario
    idx = list(range(len(sc.graph_masks))) if graphs is None else graphs
    ok = [bool(jd.is_strongly_connected(sc.graph_masks[g])) for g in idx]
    bad = [sc.graphs.names[g] for g, o in zip(idx, ok) if not o]
    return Holds(all(ok), int(sum(ok)), len(ok), f"{sum(ok)} of {len(ok)} neighbour graphs strongly connected "
                                                 "(arc j -> i iff j ∈ N_i, self-arcs included)"
                                                 + (f"; not: {', '.join(bad)}" if bad else ""))


@claims.hypothesis(HYP + "local_observers", "{scenario: }(15): the local observers decay at least as fast as "
                   "e^(-λ̄t), λ < λ̄")
def local_observers(r: Part) -> Holds:
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


@claims.hypothesis(HYP + "q_eq22", "{scenario: }the design q satisfies (22) (ρ of (17), α of Lemma 5)")
def design_q_eq22(r: Part) -> Holds:
    return q_eq22(r, r.scenario.q_design)


def q_eq22(r: Part, q: int) -> Holds:
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
    if sc.printed_lam != sc.lam:
        text += (f"; for the printed λ = {sc.printed_lam:g}: q >= {big(_int(dz['q_thm22_paper']))} (α as printed: "
                 f"{big(_int(dz['q_thm22_printed_alpha_paper']))})")
    if exact:
        return Holds(q >= lo, q, number(lo), text)
    if q < lo:
        return Holds(False, q, number(lo), text + "; q misses (22) already for the lower bound of ρ")
    if hi is not None and q >= hi:
        return Holds(True, q, number(hi), text + f"; q meets (22) for the upper bound of ρ (needs {big(hi)})")
    return Holds(None, q, number(hi) if hi is not None else None,
                 text + "; ρ is only bracketed and q lies between the two requirements")


@claims.hypothesis(HYP + "q_eq27", "{scenario: }the design q satisfies (27) (σ of (26), symmetric special case)")
def design_q_eq27(r: Part) -> Holds:
    return q_eq27(r, r.scenario.q_design)


def q_eq27(r: Part, q: int) -> Holds:
    """q satisfies (27) for σ of (26) (all connected graphs on m vertices, m <= 6)."""
    dz, sc = r.design, r.scenario
    if "sigma" not in dz:
        return Holds(None, q, None, str(dz["sigma_skipped_reason"]) if "sigma_skipped_reason" in dz
                     else f"σ of (26) is not computed for m = {sc.m}")
    if "q27" not in dz:
        return Holds(None, q, None, f"σ = {float(dz['sigma']):.10g} is not below 1: (27) gives no q")
    need = int(dz["q27"])
    text = (f"q = {q:,}; (27) with σ = {float(dz['sigma']):.10g} (over {int(dz['sigma_graphs'])} connected graphs), "
            f"||A|| = {float(dz['norm_A']):.6g}, λ = {sc.lam:g}, T = {sc.T:g} needs q >= {need:,} (minimal sufficient "
            f"{int(dz['q27_minimal']):,})")
    if sc.printed_lam != sc.lam and "q27_paper" in dz:
        text += f"; for the printed λ = {sc.printed_lam:g}: q >= {int(dz['q27_paper']):,}"
    return Holds(q >= need, q, need, text)


# -- per run -----------------------------------------------------------------------------------------------

def each_run(where: Where) -> list[tuple[str, RunSection]]:
    return [(run.name, run) for run in where.scenario_object.runs]


def graphs_of(sc: HybridFile, run: RunSection) -> list[int]:
    """The graphs a run uses."""
    return [run.graph_index] if run.switching == "fixed" else list(range(len(sc.graph_masks)))


def _jittered(where: Where) -> bool:
    return where.item.timing in ("async", "offset")


@claims.hypothesis(HYP + "{item}.strong_connectivity", "{scenario: }run {item}: every graph it uses is strongly "
                   "connected", each=each_run, when=lambda w: not w.scenario_object.all_strongly_connected)
def run_strong_connectivity(r: Part, run: RunSection) -> Holds:
    return strong_connectivity(r, graphs_of(r.scenario, run))


@claims.hypothesis(HYP + "{item}.q_eq27", "{scenario: }run {item}: q satisfies (27)", each=each_run,
                   when=lambda w: w.item.rule == "symmetric")
def run_q_eq27(r: Part, run: RunSection) -> Holds:
    return q_eq27(r, run.q)


@claims.hypothesis(HYP + "{item}.q_eq22", "{scenario: }run {item}: q satisfies (22)", each=each_run,
                   when=lambda w: w.item.rule != "symmetric" and w.item.q != w.scenario_object.q_design)
def run_q_eq22(r: Part, run: RunSection) -> Holds:
    return q_eq22(r, run.q)


@claims.hypothesis(HYP + "{item}.eq10", "{scenario: }run {item}: (10) and Δq + ε <= T", each=each_run, when=_jittered)
def run_eq10(r: Part, run: RunSection) -> Holds:
    return eq10(run, r.scenario.T)


@claims.hypothesis(HYP + "{item}.windows", "{scenario: }run {item}: N(t) constant on every window 𝓘_s(k) of (23)",
                   each=each_run, when=_jittered)
def run_windows(r: Part, run: RunSection) -> Holds:
    return windows(r.scenario, run)


def eq10(run: RunSection, T: float) -> Holds:
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


def windows(sc: HybridFile, run: RunSection) -> Holds:
    """N(t) constant on every 𝓘_s(k) = [sT + (k-1)Δ + β - ε, sT + (k-1)Δ + β + ε] (23), s = 0..S-1
    (the window of interval s+1; the first interval included), k = 1..q: no switch of the
    right-continuous schedule in (start, end]."""
    eps = run_epsilon(run)
    sw = schedule_for(sc, run).switch_times((run.intervals + 1) * sc.T)
    c = (sc.T * np.arange(run.intervals))[:, None] + (np.arange(run.q) * run.Delta + run.beta)[None, :]
    inside = np.searchsorted(sw, c + eps, side="right") - np.searchsorted(sw, c - eps, side="right")
    bad = int((inside > 0).sum())
    return Holds(bad == 0, bad, 0, f"{bad} of {c.size} windows (ε = {eps:g}) contain a graph switch ({sw.size} switches "
                                   f"in the run, switching = '{run.switching}')")


# -- the hypotheses of one (scenario, run) cell ----------------------------------------------------------------

def _cell_hypothesis(r: Part, run: RunSection, need: str) -> tuple[str | None, Holds | None]:
    """The hypothesis row ('q', 'eq10', 'windows' or a scenario-level name) that decides `need` for
    one run, and its check; (None, None) when the run has no such row."""
    sc = r.scenario
    if need == "strong_connectivity":
        if sc.all_strongly_connected:
            return need, strong_connectivity(r)
        return f"{run.name}.{need}", strong_connectivity(r, graphs_of(sc, run))
    if need == "q":
        if run.rule == "symmetric":
            return f"{run.name}.q_eq27", q_eq27(r, run.q)
        return ("q_eq22" if run.q == sc.q_design else f"{run.name}.q_eq22"), q_eq22(r, run.q)
    if need in ("eq10", "windows"):
        if run.timing not in ("async", "offset"):
            return None, None
        return f"{run.name}.{need}", eq10(run, sc.T) if need == "eq10" else windows(sc, run)
    checks = {"joint_observability": joint_observability, "local_observers": local_observers,
              "q_eq22": design_q_eq22, "q_eq27": design_q_eq27}
    return need, checks[need](r)


def cell_failures(res, label: str, run: RunSection, needs: tuple[str, ...]) -> list[tuple[str, Holds]]:
    """The hypotheses among `needs` that do not hold (or cannot be decided) for one (scenario, run)
    cell, with their ids."""
    several = len(res.parts) > 1
    run_id = res[label].scenario.name if label == "scenario" else PID   # 'scenario' labels a user's run
    out = []
    for need in needs:
        name, h = _cell_hypothesis(res[label], run, need)
        if h is not None and h.holds is not True:
            out.append((hyp_id(label, name, several, run_id), h))
    return out
