"""The consensus-on-measurements Kalman filter (Battistelli, Chisci, Mugnai, Farina & Graziano 2015), written
against dse's public plug-in protocol (`dse.plugin`) only: it sees the plant, the sensors and the graph through
`Problem`, hears its neighbours only through `network.exchange`, and is checked by the same claims as every
built-in estimator of the compare arena.

Nothing here reads dse's internals; the filter is the class `ConsensusOnMeasurements`, registered by this
package's entry point ``cm`` in the group ``dse.estimators``.
"""
from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from dse.plugin import LinearStep, Messages, NetworkFilter, Problem

__all__ = ["ConsensusOnMeasurements", "Parameters", "consensus_rounds", "consensus_matrix"]


class Parameters(BaseModel):
    """The keys of a scenario's `[estimators.cm]` table (and of `dse arena cm --param KEY=VALUE`)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    rounds: int | None = Field(
        None, ge=1, le=100,
        description="L, the consensus rounds on the measurement information in each step: at most the scenario's "
                    "synchronous rounds per step (`links.rounds`); none: all of them. Under Poisson exchanges every "
                    "exchange of the step is one pairwise round and this key is not used.")


def consensus_rounds(problem: Problem, params: Parameters) -> int:
    """L on synchronous links (`Parameters.rounds`, by default the link model's rounds); 0 under Poisson
    exchanges, where the filter averages at every exchange the step brings. A ValueError when L asks for more
    rounds than the scenario's links give."""
    if not problem.synchronous:
        return 0
    if params.rounds is None:
        return problem.rounds
    if params.rounds > problem.rounds:
        raise ValueError(f"rounds = {params.rounds} is more than the {problem.rounds} synchronous rounds per step of "
                         "the scenario's links (links.rounds)")
    return params.rounds


def consensus_matrix(problem: Problem) -> np.ndarray:
    """(N, N) the consensus weights with every link working: π_ij = q_ij on the links, π_ii = 1 − Σ_j q_ij."""
    N = problem.N
    W = np.zeros((N, N))
    for i in range(N):
        for d, j in enumerate(problem.neighbours[i]):
            if j >= 0:
                W[i, j] += problem.weights[i, d]
    W[np.arange(N), np.arange(N)] = 1.0 - W.sum(axis=1)
    return W


def pack(M: np.ndarray) -> np.ndarray:
    """(N, n(n+1)/2, B) the upper triangles of the symmetric (N, n, n, B)."""
    a, b = np.triu_indices(M.shape[1])
    return M[:, a, b]


def unpack(v: np.ndarray, n: int) -> np.ndarray:
    """(N, n, n, B) the symmetric matrices of the packed upper triangles v (N, n(n+1)/2, B)."""
    a, b = np.triu_indices(n)
    M = np.zeros((v.shape[0], n, n) + v.shape[2:])
    M[:, a, b] = v
    M[:, b, a] = v
    return M


def mix(z: np.ndarray, inbox, weights: np.ndarray) -> np.ndarray:
    """One consensus round on the messages z (N, s, B): z_i ← (1 − Σ_j q_ij) z_i + Σ_j q_ij z_j over the
    neighbours j whose message arrived (a failed link's weight stays with the node)."""
    q = weights[:, :, None] * inbox.delivered                                # (N, D, B)
    return (1.0 - q.sum(axis=1))[:, None, :] * z + np.einsum("idb,idsb->isb", q, inbox.values)


def apply(P: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, n, B) P_i v_i for P (N, B', n, n), B' = 1 (shared by the trials) or B, and v (N, n, B)."""
    if P.shape[1] == 1:
        return np.einsum("iak,ikb->iab", P[:, 0], v)
    return np.einsum("ibak,ikb->iab", P, v)


class ConsensusOnMeasurements(NetworkFilter):
    """Consensus on measurements (CM): every node averages the measurement information of the network over L
    consensus rounds, then corrects its own prior with N times the average.

    Notation: u_i = H_iᵀ R_i⁻¹ y_i(k) and U_i = H_iᵀ R_i⁻¹ H_i, node i's measurement information vector and
    matrix; π_ij the scenario's consensus weights (`Problem.weights`; π_ii = 1 − Σ_j π_ij). Our
    reconstruction of the paper's CM algorithm (its scalar correction weight ω_i set to N, the choice that
    makes CM the centralized filter as L grows), step k at node i:

    (CM1) local information: δq_i⁰ = u_i, δΩ_i⁰ = U_i;
    (CM2) L consensus rounds, l = 0..L−1, on the pair, with the weights of the links that worked:
              δq_iˡ⁺¹ = Σ_j π_ij δq_jˡ,   δΩ_iˡ⁺¹ = Σ_j π_ij δΩ_jˡ   (j over i and the neighbours it heard);
    (CM3) correction of the node's own prior (x̄_i, P̄_i) with N times the averaged information,
              P_i⁻¹ = P̄_i⁻¹ + N δΩ_iᴸ,   x̂_i = P_i (P̄_i⁻¹ x̄_i + N δq_iᴸ);
    (CM4) prediction: x̄_i ← F x̂_i, P̄_i ← F P_i Fᵀ + Q.

    The correction has no step size to tune: the paper's scalar weight ω_i of the averaged information is
    fixed at N (its CM choice), and L is the only parameter (`Parameters`).

    No state estimate travels: nodes exchange the pair (δq_i, δΩ_i), n + n(n+1)/2 numbers (δΩ_i symmetric),
    in every round. With every link working δΩ_iᴸ = Σ_j (Πᴸ)_ij U_j and δq_iᴸ = Σ_j (Πᴸ)_ij u_j; Π is doubly
    stochastic on a connected graph, so N Πᴸ → 1 1ᵀ and (CM3) becomes the centralized Kalman correction as
    L → ∞. Under Poisson exchanges a round is one exchange: the two nodes whose link rang move their pairs
    towards each other by the link's weight (the sum over the nodes is kept), at every exchange of the step.

    As computed. In information form (CM3) needs P̄_i⁻¹, which does not exist when P̄_i is singular (a
    singular F with a singular Q); the same update in covariance form needs no inverse: with M_i = N δΩ_iᴸ
    (positive semidefinite: the weights are nonnegative),
        P_i = (I + P̄_i M_i)⁻¹ P̄_i,   x̂_i = x̄_i + P_i N (δq_iᴸ − δΩ_iᴸ x̄_i),
    I + P̄_i M_i invertible because P̄_i M_i has nonnegative eigenvalues.

    Equivariant. δq_iᴸ − δΩ_iᴸ x̄_i = Σ_j a_ij H_jᵀ R_j⁻¹ (y_j − H_j x̄_i), with a_ij the weights the rounds
    applied (the same to both halves of the pair): the correction acts on innovations only. Adding c to the
    state, to x̄_i and so to every y_j adds c to x̂_i, and the gains depend on the links, never on the data:
    `equivariant = True`, and `shift` moves the predictions.

    Linear. On reliable links a_ij = (Πᴸ)_ij and P_i do not depend on the data, and the errors obey
        ê_i = (I + P̄_i M_i)⁻¹ ē_i + N Σ_j a_ij P_i H_jᵀ R_j⁻¹ v_j + (communication noise, below),
    unbiased since (I + P̄_i M_i)⁻¹ + P_i M_i = I: `matrices(k)` gives these A, B and C.

    Communication noise. The arena's convention corrupts the state estimate a node fuses from what it heard
    by N(0, σ_c² I_n), and lets matrices and measurements travel without noise. CM fuses no state estimate in
    its rounds: what it fuses is a measurement pair, whose estimate of the state is the weighted least-squares
    one, δΩ_i⁻¹ δq_i (in the directions δΩ_i observes). The convention applied to it: a node that heard a
    neighbour in round l has that estimate moved by the round's noise ξ_i (`Inbox.noise`, σ_c applied),
        δq_iˡ⁺¹ ← δq_iˡ⁺¹ + δΩ_iˡ⁺¹ ξ_i,
    exactly as the built-in consensus on information moves its fused pair (q_i ← q_i + Ω_i ξ_i); the noise
    then travels with δq through the later rounds and reaches x̂_i through the correction. Directions δΩ_i
    does not observe carry no estimate and no noise. The exact moments include it (C: for round l, the block
    of node i and sender j is N (Π^(L−1−l))_ij P_i δΩ_jˡ⁺¹).

    Covariance. P_i is the filter's own Riccati-like recursion: it treats N δΩ_iᴸ as independent measurement
    information, which it is not (the neighbours' priors it combines with are correlated with x̄_i, and
    N a_ij ≠ 1 weighs sensors unevenly with few rounds). It is not the error covariance in general and not a
    bound of it, so `covariance_law = None`: `covariance()` returns P_i for the tables' NEES, and no claim
    tests it.
    """

    title = "consensus on measurements (Battistelli et al.)"
    Parameters = Parameters
    equivariant = True
    linear = True
    covariance_law = None
    #: CPU time per step relative to the built-in local Kalman filters (process_time in dse's harness, one worker,
    #: 1,000 trials: 58x on tracking.toml, 35x on noisy_ring.toml, 37x on gossip_weak.toml; the package README)
    cost_weight = 60.0
    per_trial_matrices = True       # on random links its gains depend on the links that worked

    @classmethod
    def sends(cls, problem: Problem, params: Parameters) -> Messages:
        """The pair (δq_i, δΩ_i), n + n(n+1)/2 numbers, in each round (each Poisson exchange)."""
        consensus_rounds(problem, params)                          # a ValueError when L is out of reach
        n = problem.n
        return Messages(n + n * (n + 1) // 2, per="round")

    def __init__(self, problem: Problem, params: Parameters, trials: int):
        super().__init__(problem, params, trials)
        p = problem
        self.rounds = consensus_rounds(p, params)
        self.info_weight = np.einsum("imn,imk->ink", p.H, np.linalg.inv(p.R))   # H_iᵀ R_i⁻¹ (N, n, m)
        self.info = self.info_weight @ p.H                                       # U_i (N, n, n)
        self.xbar = np.broadcast_to(p.x0[None, :, None], (p.N, p.n, trials)).copy()
        self.Pbar = np.broadcast_to(p.P0, (p.N, 1, p.n, p.n)).copy()              # (N, 1 or B, n, n)
        self.P = self.Pbar

    def step(self, k: int, y: np.ndarray, network) -> np.ndarray:
        """(CM1)-(CM4) for every node and trial (class doc)."""
        p = self.problem
        u = np.einsum("inm,imb->inb", self.info_weight, y)
        U = np.broadcast_to(self.info[..., None], self.info.shape + (self.trials,))
        u, U = self._consensus(u, U, network)
        if p.link_model == "reliable":            # every trial heard the same links: one gain for all of them
            U = U[..., :1]
        M = p.N * np.moveaxis(U, -1, 1)                                          # (N, B', n, n)
        P = np.linalg.solve(np.eye(p.n) + self.Pbar @ M, self.Pbar)
        P = 0.5 * (P + np.swapaxes(P, -1, -2))
        innovation = u - np.einsum("iakb,ikb->iab", U, self.xbar) if U.shape[-1] > 1 else \
            u - np.einsum("iak,ikb->iab", U[..., 0], self.xbar)
        est = self.xbar + apply(P, p.N * innovation)
        self.P = P
        self.xbar = np.matmul(p.F, est)
        self.Pbar = p.F @ P @ p.F.T + p.Q
        return est

    def _consensus(self, u: np.ndarray, U: np.ndarray, network) -> tuple[np.ndarray, np.ndarray]:
        """(CM2): the rounds on the pair, through the network, with the communication noise (class doc)."""
        n = self.problem.n
        z = np.concatenate([u, pack(U)], axis=1)                                 # (N, n + n(n+1)/2, B)
        rounds = self.rounds if self.problem.synchronous else network.exchanges
        for _ in range(rounds):
            inbox = network.exchange(z)
            z = mix(z, inbox, self.problem.weights)
            if self.problem.noise_std:
                z[:, :n] += np.einsum("iakb,ikb->iab", unpack(z[:, n:], n), inbox.noise)
        return z[:, :n], unpack(z[:, n:], n)

    def shift(self, delta: np.ndarray) -> None:
        """Add delta (n, B) to every node's prediction (error coordinates)."""
        self.xbar = self.xbar + delta[None]

    def covariance(self) -> np.ndarray:
        """P_i of the last step (the filter's own; not its error covariance: class doc)."""
        return self.P[:, 0] if self.P.shape[1] == 1 else np.moveaxis(self.P, 1, -1)

    def matrices(self, k: int) -> LinearStep:
        """The `LinearStep` of step k with every link working (class doc, "Linear"); advances P̄_i."""
        p = self.problem
        N, n, m = p.N, p.n, p.m
        Pi = consensus_matrix(p)
        pairs = [self.info]                                                      # δΩ_iˡ, l = 0..L
        for _ in range(self.rounds):
            pairs.append(np.einsum("ij,jab->iab", Pi, pairs[-1]))
        Pbar = self.Pbar[:, 0]
        I_PM = np.eye(n) + Pbar @ (N * pairs[-1])
        P = np.linalg.solve(I_PM, Pbar)
        P = 0.5 * (P + np.swapaxes(P, -1, -2))
        A = np.zeros((N * n, N * n))
        for i, block in enumerate(np.linalg.inv(I_PM)):
            A[i * n:(i + 1) * n, i * n:(i + 1) * n] = block
        a = N * np.linalg.matrix_power(Pi, self.rounds)
        B = np.einsum("ij,iak,jkm->iajm", a, P, self.info_weight).reshape(N * n, N * m)
        C = None
        if p.noise_std:
            heard = (p.degrees > 0).astype(float)
            C = np.hstack([np.einsum("ij,iak,jkl,j->iajl", N * np.linalg.matrix_power(Pi, self.rounds - 1 - r), P,
                                     pairs[r + 1], heard).reshape(N * n, N * n) for r in range(self.rounds)])
        self.Pbar = (p.F @ P @ p.F.T + p.Q)[:, None]
        return LinearStep(A, B, C)
