"""Second moments of the stacked errors of N nodes, and how one step of a network filter maps them.

The joint error e = (e_0, …, e_{N−1}) of a network of filters of an n-dimensional state has the
second moment Σ = E[e eᵀ], stored as an (N, n, N, n) array: Σ[i, :, j, :] = E[e_i e_jᵀ]. Linear
filters move it by three kinds of maps, all exact:

* node-wise: e_i ← A_i e_i (a gain applied at every node): Σ ← A Σ Aᵀ with A block diagonal;
* node mixing: e ← (W ⊗ I_n) e (a consensus or combination round): Σ ← (W ⊗ I) Σ (W ⊗ I)ᵀ;
* state-wise: e_i ← F e_i + w with w common to all nodes: Σ ← (I ⊗ F) Σ (I ⊗ F)ᵀ + 1 1ᵀ ⊗ Q.

For a random round W = I − Σ_e b_e q_e D_e (D_e = (u_a − u_b)(u_a − u_b)ᵀ for edge e = (a, b),
independent b_e ~ Bernoulli(s_e) drawn afresh in each round, independent of the errors), the mean
of the mixed moment is exact (Σ being independent of the round's draws):

    E[W Σ Wᵀ] = W̄ Σ W̄ᵀ + Σ_e s_e (1 − s_e) q_e² D_e Σ D_e,     W̄ = I − Σ_e s_e q_e D_e,

because Cov(b_e, b_f) = 0 for e ≠ f. Each D_e Σ D_e is the 2 x 2 node pattern [[1, −1], [−1, 1]]
at (a, b) times the n x n block Σ_aa − Σ_ab − Σ_ba + Σ_bb.
"""
from __future__ import annotations

import numpy as np

__all__ = ["common_start", "node_wise", "node_mix", "state_wise", "add_block_diagonal", "mean_random_round",
           "edge_pattern_sum", "edge_pattern_matrix", "apply_edge_pattern", "node_blocks", "mean_square_per_node", "disagreement", "as_matrix", "from_matrix"]


def common_start(N: int, P0: np.ndarray) -> np.ndarray:
    """Every node starts from the same prior mean: e_i(0) = x(0) − x0 for all i, Σ = 1 1ᵀ ⊗ P0."""
    n = P0.shape[0]
    return np.broadcast_to(P0[None, :, None, :], (N, n, N, n)).copy()


def as_matrix(S: np.ndarray) -> np.ndarray:
    N, n = S.shape[:2]
    return S.reshape(N * n, N * n)


def from_matrix(M: np.ndarray, N: int) -> np.ndarray:
    n = M.shape[0] // N
    return M.reshape(N, n, N, n)


def node_wise(A: np.ndarray, S: np.ndarray, B: np.ndarray | None = None) -> np.ndarray:
    """Σ ← A Σ Bᵀ for block-diagonal A = diag(A_i), B = diag(B_i) ((N, n, n); B = A by default)."""
    B = A if B is None else B
    N, n = S.shape[:2]
    T = np.matmul(A, S.reshape(N, n, N * n)).reshape(N, n, N, n)          # rows: A_i Σ_ij
    T = np.matmul(T.transpose(2, 0, 1, 3).reshape(N, N * n, n), np.swapaxes(B, 1, 2))   # columns: · B_jᵀ
    return T.reshape(N, N, n, n).transpose(1, 2, 0, 3)


def node_mix(W: np.ndarray, S: np.ndarray) -> np.ndarray:
    """Σ ← (W ⊗ I) Σ (W ⊗ I)ᵀ for an (N, N) W."""
    N, n = S.shape[:2]
    T = (W @ S.reshape(N, -1)).reshape(S.shape)                          # rows
    T = np.moveaxis(T, 2, 0).reshape(N, -1)                              # (j, i a c)
    return np.moveaxis((W @ T).reshape(N, N, n, n), 0, 2)                # columns


def state_wise(F: np.ndarray, S: np.ndarray, Q: np.ndarray | None = None) -> np.ndarray:
    """Σ ← (I ⊗ F) Σ (I ⊗ F)ᵀ (+ 1 1ᵀ ⊗ Q, a noise common to every node)."""
    out = (F @ S.transpose(0, 2, 1, 3) @ F.T).transpose(0, 2, 1, 3)
    if Q is not None:
        out = out + Q[None, :, None, :]
    return out


def add_block_diagonal(S: np.ndarray, blocks: np.ndarray) -> np.ndarray:
    """Σ + diag(blocks) with blocks (N, n, n) (noise independent from node to node)."""
    out = S.copy()
    idx = np.arange(S.shape[0])
    out[idx, :, idx, :] += blocks
    return out


def edge_pattern_matrix(N: int, edges: np.ndarray) -> np.ndarray:
    """(N², E): column e holds the node pattern of D_e = (u_a − u_b)(u_a − u_b)ᵀ, flattened."""
    E = len(edges)
    inc = np.zeros((N, E))
    inc[edges[:, 0], np.arange(E)] = 1.0
    inc[edges[:, 1], np.arange(E)] = -1.0
    return (inc[:, None, :] * inc[None, :, :]).reshape(N * N, E)


def apply_edge_pattern(pattern: np.ndarray, S: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Σ_e c_e D_e Σ D_e for a pattern matrix with columns already scaled by c_e (`edge_pattern_matrix`)."""
    N, n = S.shape[:2]
    a, b = edges[:, 0], edges[:, 1]
    d = S[a, :, a, :] - S[a, :, b, :] - S[b, :, a, :] + S[b, :, b, :]     # (E, n, n): the blocks of D_e Σ D_e
    return (pattern @ d.reshape(len(edges), n * n)).reshape(N, N, n, n).transpose(0, 2, 1, 3)


def edge_pattern_sum(S: np.ndarray, edges: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Σ_e c_e D_e Σ D_e for edges (E, 2) and coefficients c (E,)."""
    return apply_edge_pattern(edge_pattern_matrix(S.shape[0], edges) * c, S, edges)


def mean_random_round(S: np.ndarray, incidence: np.ndarray, edges: np.ndarray, q: np.ndarray,
                      s: np.ndarray) -> np.ndarray:
    """E[W Σ Wᵀ] for W = I − Σ_e b_e q_e D_e with independent b_e ~ Bernoulli(s_e) (module doc)."""
    Wbar = np.eye(incidence.shape[0]) - (incidence * (s * q)) @ incidence.T
    out = node_mix(Wbar, S)
    var = s * (1.0 - s) * q * q
    if np.any(var > 0):
        out += edge_pattern_sum(S, edges, var)
    return out


def node_blocks(S: np.ndarray) -> np.ndarray:
    """(N, n, n): the diagonal blocks E[e_i e_iᵀ]."""
    idx = np.arange(S.shape[0])
    return S[idx, :, idx, :]


def mean_square_per_node(S: np.ndarray) -> np.ndarray:
    """(N,): E‖e_i‖² = tr Σ_ii."""
    return np.einsum("iaia->i", S)


def disagreement(S: np.ndarray) -> float:
    """E (1/N) Σ_i ‖e_i − ē‖², ē the node average: the estimates' spread (x̂_i − mean x̂ = ē − e_i)."""
    N = S.shape[0]
    total = np.einsum("iaia->", S)
    mean_part = np.einsum("iaja->", S) / N
    return float((total - mean_part) / N)
