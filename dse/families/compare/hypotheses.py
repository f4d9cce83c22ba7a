"""The conditions the comparison's claims rest on, each decided on the design alone (`dse check`)."""
from __future__ import annotations

import numpy as np

from dse.verify.rules import Holds, Hypothesis

NOISY = "compare.hyp.noisy_links"
NOISELESS = "compare.hyp.noiseless_links"
CARLI_NOISE = "compare.hyp.carli_noise_dominated"
STABLE = "compare.hyp.mean_square_stable"
C1 = "compare.hyp.kar_moura.C1"
D1 = "compare.hyp.kar_moura.D1"
S1 = "compare.hyp.kar_moura.S1"
COLLECTIVE = "compare.hyp.collective_detectability"
LOCAL = "compare.hyp.local_detectability"


def _noisy(d) -> Holds:
    s = d.scenario.noise_std
    return Holds(s > 0, s, 0.0, f"communication noise σ_c = {s:g}")


def _noiseless(d) -> Holds:
    s = d.scenario.noise_std
    return Holds(s == 0, s, 0.0, f"communication noise σ_c = {s:g}")


def _carli_noise(d) -> Holds:
    t = d.numbers.get("tuned", {})
    if "carli" not in d.estimators or "carli_local_steady" not in t:
        return Holds(None, detail="Carli's filter does not run on this scenario: " + d.status["carli"][1])
    if d.links.kind == "matchings":
        return Holds(None, detail="under random matchings the steady state has no closed form here (the gains were "
                                  "tuned on independent links of the same mean activity)")
    carli, local = t["carli_steady"], t["carli_local_steady"]
    if not (np.isfinite(carli) or np.isfinite(local)):
        return Holds(None, detail="neither steady state exists (mean-square unstable)")
    return Holds(bool(carli > local), carli, local,
                 f"exact steady network MSE of Carli's filter with its tuned gain {carli:.6g} against the same local "
                 f"filters without fusion {local:.6g}: communication "
                 + ("hurts (the noise it integrates outweighs the averaging; the regime of Savas et al.'s Fig. 1)"
                    if carli > local else "helps"))


def _stable(d) -> Holds:
    rows = {e: g["rho"] for e, g in d.gains.items() if e in ("carli", "reinjection")}
    if len(rows) < 2:
        return Holds(None, detail="Carli's or the re-injection filter does not run on this scenario")
    if d.links.kind == "matchings":
        return Holds(None, detail="under random matchings the mean second-moment recursion has no closed form here")
    worst = max(rows.values())
    return Holds(bool(worst < 1), worst, 1.0, "spectral radius of the exact mean second-moment step: " +
                 ", ".join(f"{e} {r:.6g}" for e, r in rows.items()))


def _c1(d) -> Holds:
    v = d.numbers["c1"]
    return Holds(v, None, None, "mean of the GIKF's swap permutation irreducible and aperiodic: " + d.numbers["c1_detail"])


def _d1(d) -> Holds:
    v, r = d.numbers["d1"], d.numbers["d1_ratio"]
    text = (f"Gramian Σ (F^i)ᵀ H_{{w_i}}ᵀ H_{{w_i}} F^i along a covering walk of length {d.numbers['d1_walk_length']}: "
            f"λ_min/λ_max = {r:.3g}")
    if v is None:
        text += "; (F, H) is observable but this walk's Gramian is singular: undecided"
    elif not v:
        text += "; (F, H) of all sensors together is not observable, so no walk's Gramian is invertible"
    return Holds(v, r, 1e-10, text)


def _s1(d) -> Holds:
    v = d.numbers["stabilizable"]
    return Holds(bool(v), None, None, "(F, Q^½) stabilizable (PBH test on the modes |λ| ≥ 1)")


def _collective(d) -> Holds:
    v = d.numbers["collective_detectable"]
    return Holds(bool(v), None, None, "(F, H) of all sensors together detectable: the centralized filter's error is bounded")


def _local(d) -> Holds:
    loc = np.asarray(d.numbers["local_detectable"])
    return Holds(bool(loc.all()), int(loc.sum()), len(loc),
                 f"{int(loc.sum())} of {len(loc)} nodes can detect the state alone (what filters without communication "
                 "need; weak detectability asks only for the network)")


def catalogue() -> list[Hypothesis]:
    return [
        Hypothesis(NOISY, "the links add communication noise (σ_c > 0)", _noisy),
        Hypothesis(NOISELESS, "the links add no communication noise (σ_c = 0)", _noiseless),
        Hypothesis(CARLI_NOISE, "communication noise dominates Carli's filter: its steady mean-square error exceeds that "
                   "of the same local filters without fusion", _carli_noise),
        Hypothesis(STABLE, "Carli's and the re-injection filter's mean-square error recursions are stable (ρ < 1)", _stable),
        Hypothesis(C1, "C.1: the GIKF's mean communication matrix is irreducible and aperiodic", _c1),
        Hypothesis(D1, "D.1: weak detectability (a covering walk with an invertible observability Gramian)", _d1),
        Hypothesis(S1, "S.1: (F, Q^½) stabilizable", _s1),
        Hypothesis(COLLECTIVE, "collective detectability of (F, H)", _collective),
        Hypothesis(LOCAL, "local detectability at every node", _local),
    ]
