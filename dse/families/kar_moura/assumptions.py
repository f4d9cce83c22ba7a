"""The theorems' hypotheses of one scenario, decided from the protocol's mean matrix Ā = E[A(t)]
(eq (6)) and the signal model, without Monte Carlo: C.1 (Ā irreducible and aperiodic), D.1 (an
Ā-walk with an invertible observability Gramian, decided three ways), the modes |λ| ≥ 1 each class
of Ā cannot see; and the range of covariances the Joseph form computes accurately, which sets the
horizon where a class diverges. `GossipKalmanFile.assumptions` caches `decide(sc)`.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import numpy as np

import dse.estimators.walk_detectability as wd
from dse.estimators.gossip_protocols import GreedyMatchingGossip
from dse.simulate.seeding import stream_seed
from dse.simulate.units import block_generator

WITNESS_MAX_LEN = 6
EPS = float(np.finfo(float).eps)
#: Monte Carlo Ā when no exact form is feasible (greedy matching on a large graph)
ABAR_DRAWS = 200_000
#: log of the largest covariance entry an iterate may reach (float64: ~709)
FLOAT_LOG_BUDGET = 600.0


@dataclass(frozen=True)
class Assumptions:
    """The theorems' hypotheses decided for one scenario from the support of Ā.

    `d1.holds` and `undetectable` may be None: undecided in floating point (see
    `walk_detectability`). `blind[c]` lists the eigenvalues |λ| ≥ 1 that class c of Ā cannot see,
    or None when its unobservable subspace is undecided; `rate` is the largest 2 log|λ| over them
    (the growth rate of the covariance of a blind class, 0 when none grows exponentially)."""

    c1: bool
    irreducible: bool
    aperiodic: bool
    classes: tuple[tuple[int, ...], ...]
    d1: wd.D1Decision
    blind: tuple[tuple[complex, ...] | None, ...]
    exact_abar: bool
    central_detectable: bool | None
    rate: float

    @property
    def undetectable(self) -> bool | None:
        """Some class of Ā cannot detect an eigenvalue |λ| ≥ 1 (True), none can't (False), undecided (None)."""
        if any(b for b in self.blind if b):
            return True
        return None if any(b is None for b in self.blind) else False

    @property
    def theorem(self) -> bool:
        """C.1 and D.1 hold (S.1 always does: validation requires Q ≻ 0)."""
        return self.c1 and self.d1.holds is True


def decide(sc) -> Assumptions:
    """C.1's structure and D.1 from Ā's support (`support_matrix`), the blind modes of every class."""
    sys_ = sc.system
    S = support_matrix(sc)
    chk = wd.check_chain(S)
    d1 = wd.decide_d1(sys_, S, chk.classes, chk.c1, max_len=WITNESS_MAX_LEN)
    blind, rate = [], 0.0
    for cls in chk.classes:
        lam, found = wd.unobservable_modes(sc.F, sys_.C[list(cls)].reshape(-1, sc.M))
        unseen = [complex(x) for x in found if abs(x) >= 1 - 1e-12]
        rate = max([rate] + [2 * float(np.log(abs(x))) for x in unseen])
        blind.append(None if lam is None else tuple(unseen))
    central, _ = wd.unobservable_modes(sc.F, sys_.C_all)
    central_detectable = None if central is None else not any(abs(x) >= 1 - 1e-12 for x in central)
    protocol = sc.protocol.build(sc.network)
    exact = not isinstance(protocol, GreedyMatchingGossip) or _exact_greedy_mean(protocol) is not None
    return Assumptions(chk.c1, chk.irreducible, chk.aperiodic, chk.classes, d1, tuple(blind), exact, central_detectable,
                       rate)


def mean_adjacency(sc) -> tuple[np.ndarray, np.ndarray, bool, int]:
    """(Ā, standard error of each entry, exact?, draws). Closed forms for single-edge, node-initiated
    and user-given matchings; the greedy-matching protocol (P4) is exact on small graphs (recursion
    over edge sets) and a Monte Carlo estimate otherwise. Where Ā is estimated, the Theorem-8
    chains are driven by the protocol itself (sampler S3) and the claims that need the exact Ā are
    not checked (an estimated Ā would bias the invariant law)."""
    protocol = sc.protocol.build(sc.network)
    zero = np.zeros((sc.N, sc.N))
    if isinstance(protocol, GreedyMatchingGossip):
        exact = _exact_greedy_mean(protocol)
        if exact is None:
            rng = block_generator(stream_seed(0, sc.name, "abar-estimate"))
            A, se = protocol.estimate_mean_matrix(ABAR_DRAWS, rng)
            return A, se, False, ABAR_DRAWS
        return exact, zero, True, 0
    return protocol.mean_matrix(), zero, True, 0


@functools.lru_cache(maxsize=16)
def _exact_greedy_mean(protocol: GreedyMatchingGossip) -> np.ndarray | None:
    return protocol.exact_mean_matrix()


def support_matrix(sc) -> np.ndarray:
    """A matrix with Ā's support (exact Ā where it is cheap): enough for C.1's structure and D.1."""
    protocol = sc.protocol.build(sc.network)
    if isinstance(protocol, GreedyMatchingGossip):
        return protocol.support_matrix()
    return protocol.mean_matrix()


def exact_mean(protocol_section, sc) -> np.ndarray | None:
    """Ā of a protocol table on the scenario's graph, exact, or None (greedy matching on a large graph)."""
    prot = protocol_section.build(sc.network)
    return prot.exact_mean_matrix() if isinstance(prot, GreedyMatchingGossip) else prot.mean_matrix()


def accurate_range(sc) -> float:
    """The largest ‖X‖ at which the Joseph form still resolves every sensor's innovation variance:
    C X Cᵀ carries a round-off of ~eps‖X‖‖C‖², kept below 1e-3 λ_min(R) (so a direction that a sensor
    does not see, not along a coordinate axis, cannot make C X Cᵀ + R lose its R)."""
    sys_ = sc.system
    seen = [n for n in range(sc.N) if np.abs(sys_.C[n]).max() > 0]
    if not seen:
        return math.exp(FLOAT_LOG_BUDGET)
    r_min = min(float(np.linalg.eigvalsh(sys_.R[n])[0]) for n in seen)
    c_max = max(float(np.linalg.norm(sys_.C[n], 2)) ** 2 for n in seen)
    return min(math.exp(FLOAT_LOG_BUDGET), 1e-3 * r_min / (EPS * c_max))


def horizon(sc, slots: int) -> int:
    """Where a class of Ā cannot see a mode |λ| > 1, its covariances grow like |λ|^(2t): simulate only
    while they stay inside the range where the Joseph form is accurate (`accurate_range`)."""
    rate = sc.assumptions.rate
    if rate <= 0:
        return slots
    start = max(1.0, float(np.linalg.norm(sc.P0, 2)), float(np.linalg.norm(sc.Q, 2)))
    budget = math.log(accurate_range(sc) / start)
    return int(min(slots, max(10, budget // rate)))
