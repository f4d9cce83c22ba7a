"""Errata of the random-communication filtering paper, each checked on the run's main scenario (role
"main": S2 in the paper's reproduction) against an independent computation, and the statements no
computation can check. A printed formula that disagrees with the independent computation while its
correction agrees is an `erratum`."""
from __future__ import annotations

import math

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

from dse.estimators.linear_flows import van_loan
from dse.verify.rules import ERRATUM, FAIL, PASS, Verdict, not_checkable, roundoff_tolerance

from .claims_common import claims
from .results import Results, ScenarioResults


def generator_by_definition(r: ScenarioResults, Q: np.ndarray) -> tuple[np.ndarray, float]:
    """The generator (17) of the P-process at the state Q (N, n, n), from its definition
    𝓛(Q) = lim_{ε→0} (E[P(ε) | P(0) = Q] − Q)/ε and the path rules (14) alone (no use of (9)):
    over [0, ε] no ring (probability e^{−Λε}, Λ = λ·#clocks) gives the Lyapunov flow of every
    node (exact Van Loan), one ring of clock c (probability λε e^{−Λε}) the flow to ε/2, the
    jump (14b), the flow to ε; more rings and the midpoint rule change E[P(ε)] by O(ε²). The
    difference quotient is extrapolated twice (Richardson, error O(ε²)); the returned error
    bound is the change of the extrapolation under ε → ε/2 plus the rounding of the quotient."""
    s, lam = r.sys, r.scenario.main_rate
    Lam = lam * len(s.clocks)
    kappa = max(np.linalg.norm(A, 2) for A in s.Ai) + Lam
    eps0 = 1e-3 / kappa
    jumps = [s.jump(c) for c in range(len(s.clocks))]

    def mean_after(eps: float) -> np.ndarray:
        half = [van_loan(A, G, eps / 2) for A, G in zip(s.Ai, s.Gi)]
        flow = lambda P: np.array([F @ Pi @ F.T + Qn for (F, Qn), Pi in zip(half, P)])
        none = flow(flow(Q))
        mid = flow(Q)
        one = sum(flow(np.einsum("ij,jab->iab", J, mid)) for J in jumps)
        return math.exp(-Lam * eps) * (none + lam * eps * one)

    quotient = lambda eps: (mean_after(eps) - Q) / eps
    richardson = lambda eps: 2 * quotient(eps / 2) - quotient(eps)
    g1, g2 = richardson(eps0), richardson(eps0 / 2)
    rounding = roundoff_tolerance(scale=float(np.abs(Q).max()) / (eps0 / 4), operations=4 * s.N * s.n)[0]
    return g2, float(np.abs(g1 - g2).max()) + rounding


def generator_formula(r: ScenarioResults, Q: np.ndarray, coupling: np.ndarray) -> np.ndarray:
    """A_iQ_i + Q_iA_iᵀ + G_i + λ Σ_j W_ij Q_j for a coupling matrix W (N, N)."""
    s = r.sys
    flow = np.einsum("iab,ibc->iac", s.Ai, Q)
    return flow + np.swapaxes(flow, 1, 2) + s.Gi + r.scenario.main_rate * np.einsum("ij,jab->iab", coupling, Q)


def erratum_states(r: ScenarioResults) -> np.ndarray:
    """Node states at which the generators are compared: 𝒫_i(T) of (9) (or P0 if it diverged) plus
    distinct random positive definite perturbations, so that neighbours differ."""
    s = r.sys
    base = r.bound(r.scenario.main_rate)[-1]
    if not np.all(np.isfinite(base)):
        base = np.broadcast_to(s.P0, (s.N, s.n, s.n))
    rng = np.random.default_rng(17)
    Z = rng.standard_normal((s.N, s.n, s.n))
    scale = max(1.0, float(np.abs(base).max()))
    return base + 0.5 * scale * (Z @ np.swapaxes(Z, 1, 2)) / s.n


def _generator_erratum(r: ScenarioResults, printed_coupling: np.ndarray, text: str) -> Verdict:
    s = r.sys
    Q = erratum_states(r)
    ref_, tol = generator_by_definition(r, Q)
    corrected = generator_formula(r, Q, sum(s.jump(c) - np.eye(s.N) for c in range(len(s.clocks))))
    printed = generator_formula(r, Q, printed_coupling)
    ep, ec = float(np.abs(printed - ref_).max()), float(np.abs(corrected - ref_).max())
    status = PASS if ep <= tol else (ERRATUM if ec <= tol else FAIL)
    w = np.unravel_index(int(np.argmax(np.abs(printed - ref_))), ref_.shape)
    return Verdict(status, measured=float(ref_[w]), reference=float(ref_[w]), tolerance=tol, margin=tol - ec,
                   printed=float(printed[w]), corrected=float(corrected[w]),
                   detail=f"{text} The generator computed from its definition (17) and the path rules (14) alone, at "
                          f"distinct node states, differs from the printed formula by up to {ep:.4g} and from the "
                          f"corrected one by {ec:.2e} (allowed {tol:.2e}: extrapolation error and rounding of the "
                          f"difference quotient); λ = {r.scenario.main_rate:g}")


@claims.claim("{paper}.errata.pi_sign", "§III.C", "'Π = I_N + α𝓛' (printed) vs Π = I_N − α𝓛 (eq. 3)", "identity")
def check_erratum_pi_sign(res: Results) -> Verdict:
    r = res.scenarios[res.main]
    return _generator_erratum(r, r.sys.alpha * r.sys.laplacian,
                              "§III.C 'we recall that Π = I_N + α𝓛' vs eq. (3) Π = I_N − α𝓛, in the stacked ODE "
                              "𝒫' = F(𝒫) + G + λ(Π⊗I)𝒫 − λ𝒫 (with + the coupling pushes neighbours apart).")


@claims.claim("{paper}.errata.generator_sum", "proof of Prop. III.4, (17)", "the final generator formula lacks "
              "Σ_{j∈N_i}", "identity")
def check_erratum_generator(res: Results) -> Verdict:
    r = res.scenarios[res.main]
    s = r.sys
    if s.degrees.max() < 2:
        return not_checkable("every node has one neighbour: the missing Σ_{j∈N_i} makes no difference here")
    W = np.zeros((s.N, s.N))
    for i in range(s.N):
        j = int(np.flatnonzero(s.laplacian[i] < 0)[0])
        W[i, j], W[i, i] = s.alpha, -s.alpha
    return _generator_erratum(r, W, "Proof of Prop. III.4: the final generator formula carries one neighbour's term "
                                    "λ(E[ψ^j(Q)] − Q) without Σ_{j∈N_i} (read here with the first neighbour); (9) has "
                                    "the sum.")


@claims.claim("{paper}.errata.inverse_transform", "§III.C", "'𝒫 = sqrt(N(U⊗I)^{-1})𝒬' should read √N(U⊗I)^{-1}𝒬",
              "identity")
def check_erratum_inverse(res: Results) -> Verdict:
    """§III.C: '𝒫 = sqrt(N(U⊗I)^{-1})𝒬' vs 𝒫 = sqrt(N)(U⊗I)^{-1}𝒬 = sqrt(N)(Uᵀ⊗I)𝒬."""
    r = res.scenarios[res.main]
    s = r.sys
    w, Uv = np.linalg.eigh(s.laplacian)
    U = Uv.T.copy()
    U[0] = np.sign(U[0].sum()) * U[0]
    P = r.bound(r.scenario.main_rate)[-1].reshape(s.N * s.n, s.n)
    if not np.all(np.isfinite(P)):
        P = np.tile(s.P0, (s.N, 1))
    UI = np.kron(U, np.eye(s.n))
    Q = UI @ P / np.sqrt(s.N)
    printed = (scipy.linalg.sqrtm(s.N * np.linalg.inv(UI)) @ Q).real
    corrected = np.sqrt(s.N) * np.kron(U.T, np.eye(s.n)) @ Q
    scale = np.linalg.norm(P)
    rp, rc = np.linalg.norm(printed - P) / scale, np.linalg.norm(corrected - P) / scale
    tol, how = roundoff_tolerance(scale=1.0, operations=2 * s.N * s.n)
    status = PASS if rp <= tol else (ERRATUM if rc <= tol else FAIL)
    return Verdict(status, measured=float(rp), reference=0.0, tolerance=tol, margin=float(tol - rc),
                   printed=float(rp), corrected=float(rc),
                   detail="relative Frobenius error of the reconstruction of 𝒫 from 𝒬 = (1/√N)(U⊗I)𝒫 (U the "
                          "orthogonal eigenbasis of 𝓛, first row 1/√N): printed 'sqrt(N(U⊗I)⁻¹)𝒬' (a matrix square "
                          f"root) gives {rp:.3g}, corrected √N(Uᵀ⊗I)𝒬 gives {rc:.1e} ({how}; 𝒫 = 𝒫(T) at "
                          f"λ = {r.scenario.main_rate:g})")


claims.unchecked("{paper}.nc.lemma_a1", "Lemma A.1", "W ≤ −a_1r² + a_2rs − a_3s² + g s implies W ≤ −c(r² + s²) outside "
                 "a ball", "qualitative", scope="paper-example",
                 reason="as stated it lacks the hypothesis 4a_1a_3 > a_2² and c, χ are only cited ([5, Lemma 2]); the "
                        "explicit (12) checks replace it")
claims.unchecked("{paper}.nc.markov", "proof of Prop. III.4", "'P_i(t) is Markovian'", "qualitative",
                 scope="paper-example", reason="false for one node alone (its jumps use P_j); true for (P_1..P_N), "
                                               "which is all (9) needs; not a numerical statement")
claims.unchecked("{paper}.nc.fig1", "Fig. 1", "layout of the distributed filters (schematic)", "qualitative",
                 scope="paper-example", reason="a schematic without data; regenerated as figures/fig1_network_events.png "
                                               "and the graph of every recording")
