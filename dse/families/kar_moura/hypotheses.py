"""The hypotheses Kar & Moura's theorems rest on, decided per scenario on its design (`dse check` and every
run): C.1, S.1, D.1, a recorded witness walk, the exact Ā, a class blind to a mode |λ| ≥ 1, i.i.d. matchings,
and, where a second protocol is given, that both protocols have the same Ā (Remark 9). A claim whose
hypotheses do not hold is not checkable, naming them.
"""
from __future__ import annotations

import math

import numpy as np

import dse.estimators.walk_detectability as wd
from dse.contract.claims import ClaimSet, role
from dse.verify.rules import Holds, roundoff_tolerance

from .assumptions import WITNESS_MAX_LEN, exact_mean
from .results import ScenarioDesign

claims = ClaimSet()


@claims.hypothesis("kar-moura.hyp.c1{.scenario}", "C.1: Ā irreducible and aperiodic (SLEM < 1) ({scenario})")
def hyp_c1(r: ScenarioDesign) -> Holds:
    b, a = r.bounds, r.assume
    return Holds(bool(a.c1), value=float(b["slem"]), threshold=1.0, expected=r.scenario.expect.c1,
                 detail=(f"support of Ā: {len(a.classes)} communicating class(es), irreducible = {a.irreducible}, aperiodic = "
                         f"{a.aperiodic}; SLEM = {float(b['slem']):.6f}"
                         + ("" if bool(b["Abar_exact"]) else " (Ā estimated; the structure is exact)")))


@claims.hypothesis("kar-moura.hyp.s1{.scenario}",
                   "S.1: (F, Q^½) stabilisable, with Q ≻ 0 as the proofs use ({scenario})")
def hyp_s1(r: ScenarioDesign) -> Holds:
    lam = float(np.linalg.eigvalsh(r.scenario.Q)[0])
    return Holds(lam > 0, value=lam, threshold=0.0,
                 detail=f"λ_min(Q) = {lam:.4g}: Q ≻ 0, which the proofs use and which makes (F, Q^½) stabilisable")


@claims.hypothesis("kar-moura.hyp.d1{.scenario}",
                   "D.1: some Ā-walk has an invertible observability Gramian ({scenario})")
def hyp_d1(r: ScenarioDesign) -> Holds:
    d = r.assume.d1
    return Holds(d.holds, value=float(d.search.ratio), threshold=wd.CERTAIN_RATIO, expected=r.scenario.expect.d1,
                 detail=f"{d.how}; {d.search.walks_checked} walks of length ≤ {WITNESS_MAX_LEN} searched")


@claims.hypothesis("kar-moura.hyp.witness{.scenario}",
                   "a witness walk w0 of D.1 is recorded (search depth 6) ({scenario})")
def hyp_witness(r: ScenarioDesign) -> Holds:
    s = r.assume.d1.search
    return Holds(s.witness is not None, value=len(s.witness) if s.witness else None, threshold=WITNESS_MAX_LEN,
                 expected=False if r.scenario.expect.d1 is False else None,   # no witness without D.1
                 detail=(f"witness walk w0 = {s.witness} recorded (Gramian λ_min/λ_max {s.ratio:.3g})" if s.witness else
                         f"no witness walk of length ≤ {WITNESS_MAX_LEN} (the constants of Lemmas 14-15 need one)"))


@claims.hypothesis("kar-moura.hyp.exact-abar{.scenario}", "Ā = E[A(t)] known exactly ({scenario})")
def hyp_exact_abar(r: ScenarioDesign) -> Holds:
    b = r.bounds
    exact = bool(b["Abar_exact"])
    return Holds(exact, value=float(b["Abar_se"].max()), threshold=0.0,
                 detail="Ā in closed form or by the exact recursion" if exact else
                 f"Ā is a Monte Carlo estimate ({int(b['Abar_draws']):,} matchings of the greedy protocol)")


@claims.hypothesis("kar-moura.hyp.undetectable-class{.scenario}",
                   "some class of Ā cannot detect a mode |λ| ≥ 1 ({scenario})")
def hyp_undetectable(r: ScenarioDesign) -> Holds:
    a = r.assume
    rows = [f"class {i}: " + ("undecided" if bl is None else (", ".join(f"|λ| = {abs(x):.4g}" for x in bl) or "sees every |λ| ≥ 1"))
            for i, bl in enumerate(a.blind)]
    return Holds(a.undetectable, value=math.exp(a.rate / 2) if a.rate > 0 else None, threshold=1.0,
                 expected=r.scenario.expect.diverges,
                 detail="modes |λ| ≥ 1 on the unobservable subspace of each class of Ā: " + "; ".join(rows))


@claims.hypothesis("kar-moura.hyp.random-protocol{.scenario}",
                   "the matchings A(t) are i.i.d. draws of one law (not a replayed sequence) ({scenario})")
def hyp_random_protocol(r: ScenarioDesign) -> Holds:
    p = r.scenario.protocol
    return Holds(p.random, value=None, threshold=None,
                 detail=(f"protocol '{p.kind}': a fresh matching drawn independently at every slot, as Section II assumes"
                         if p.random else
                         f"protocol 'sequence': {len(p.pairs)} given matching(s) replayed in every run; nothing is "
                         "random, so the laws of the theorems (and the token chain) do not apply; Ā is the average of "
                         "A(t) over one cycle"))


@claims.hypothesis("kar-moura.hyp.same-abar{.scenario}", "the two protocols have the same Ā ({scenario})",
                   when=role("comparison"))
def hyp_same_abar(r: ScenarioDesign) -> Holds:
    sc = r.scenario
    A, B = (exact_mean(p, sc) for p in (sc.protocol, sc.comparison_protocol))
    if A is None or B is None:
        return Holds(None, detail="a protocol has no exact Ā (greedy matching on a large graph)")
    d = float(np.abs(A - B).max())
    tol, how = roundoff_tolerance(scale=1.0, operations=sc.N)
    return Holds(d <= tol, value=d, threshold=tol, detail=f"max |Ā₁ − Ā₂| = {d:.3g} ({how})")
