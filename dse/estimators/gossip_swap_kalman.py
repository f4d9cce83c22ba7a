"""The gossip interactive Kalman filter (Kar & Moura, GIKF) on any link model, batched over trials.

Kar & Moura (8)-(10): at the start of each slot the sensors that communicate swap their whole
filter states (estimate and conditional error covariance); every sensor then corrects the state
it holds with its own measurement and predicts. Their communication is an i.i.d. sequence of
matchings; here a step's swaps are a permutation of the states:

* a matching (the link model's own random matching; for reliable links or independent failures,
  the random greedy maximal matching of the edges working in the step's first round, built from
  priorities drawn for this filter alone) swaps its pairs at once, as in the paper;
* Poisson exchanges swap one pair at a time in time order, so a state may travel several hops
  in one step (the generalisation: a composition of transpositions is a permutation, and a state
  is still corrected exactly once per step, by the sensor that holds it).

Communication noise (the convention of `network_step`): a state estimate that travelled h hops
arrives with N(0, h σ_c² I) added; the receiver knows σ_c and adds h σ_c² I to the covariance it
received, so the covariance stays the exact conditional covariance given the swap path and the
filter stays a Kalman filter along the path of each state (the paper's conditional Gaussianity,
(8)-(9)). Hence, given the path, the error of every sensor is N(0, P) exactly.

Update in Joseph form (exactly symmetric, positive semidefinite under rounding); the covariances
are stacked per node and trial with the matrix indices leading (`small_matrix`).
"""
from __future__ import annotations

import numpy as np

from . import small_matrix as sm
from .link_models import LinkModel, StepLinks, step_permutation
from .network_step import StepContext, predict
from .protocol import BatchedFilter
from .sensor_network import SensorNetworkModel

__all__ = ["GossipSwapRun", "kalman_update", "TokenSampler", "token_chain_traces", "weak_consensus_conditions"]


def kalman_update(P: np.ndarray, H: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(gain K (n, m, *b), posterior P (n, n, *b)) for stacked priors P, H (m, n, *b), R (m, m, *b).

    Joseph form P⁺ = (I − K H) P (I − K H)ᵀ + K R Kᵀ. For one measurement row it is expanded in the
    rank-one terms (u = P hᵀ, c = h P hᵀ, k = u / (c + r)): P⁺_ij = P_ij − k_i u_j − u_i k_j + (c + r) k_i k_j,
    each entry computed once for i ≤ j (exactly symmetric)."""
    if H.shape[0] == 1:
        n = P.shape[0]
        h, r = H[0], R[0, 0]
        u = [sum(P[i, j] * h[j] for j in range(n)) for i in range(n)]
        c = sum(h[i] * u[i] for i in range(n))
        s_ = c + r
        k = [ui / s_ for ui in u]
        batch = np.broadcast_shapes(P.shape[2:], np.shape(h[0]), np.shape(r))
        post = np.empty((n, n) + batch)
        K = np.empty((n, 1) + batch)
        for i in range(n):
            K[i, 0] = k[i]
            for j in range(i, n):
                post[i, j] = post[j, i] = P[i, j] - k[i] * u[j] - u[i] * k[j] + s_ * k[i] * k[j]
        return K, post
    Ht = sm.transpose(H)
    PHt = sm.matmul(P, Ht)
    S = sm.matmul(H, PHt) + R
    K = PHt / S[0, 0] if S.shape[0] == 1 else sm.matmul(PHt, sm.spd_inverse(S))
    A = sm.identity(P.shape[0], P.ndim - 2) - sm.matmul(K, H)
    post = sm.sandwich(A, P) + sm.sandwich(K, R)
    return K, post


class GossipSwapRun(BatchedFilter):
    """A batch of B trials of the GIKF; `estimate` (N, n, B) and `cov` (n, n, N, B) hold x̂(k|k)
    and P(k|k) after each step, `xbar`, `Pbar` the predictions for the next."""

    def __init__(self, model: SensorNetworkModel, links: LinkModel, B: int):
        self.model, self.links, self.B = model, links, B
        N, n = model.N, model.n
        self.xbar = np.broadcast_to(model.x0[None, :, None], (N, n, B)).copy()
        self.Pbar = np.broadcast_to(model.P0[:, :, None, None], (n, n, N, B)).copy()
        self.H = sm.to_batched(model.H)[..., None]          # (m, n, N, 1)
        self.R = sm.to_batched(model.R)[..., None]          # (m, m, N, 1)
        self.estimate = self.xbar
        self.cov = self.Pbar
        self.hops = np.zeros((N, B), np.int64)

    def step(self, ctx: StepContext) -> np.ndarray:
        m = self.model
        src, hops = ctx.swap if ctx.swap is not None else step_permutation(self.links, ctx.links, self.B,
                                                                              ctx.gossip_priority)
        self.hops = hops
        x_in = np.take_along_axis(self.xbar, src[:, None, :], axis=0)
        P_in = np.take_along_axis(self.Pbar, src[None, None], axis=2)
        sigma = self.links.noise_std
        if sigma:
            moved = hops > 0
            x_in = x_in + sigma * np.sqrt(hops)[:, None, :] * ctx.node_noise
            P_in = P_in + (sigma ** 2 * hops) * np.eye(m.n)[:, :, None, None] * moved
        K, P = kalman_update(P_in, self.H, self.R)
        r = ctx.y - np.einsum("imn,inb->imb", m.H, x_in)                                # (N, m, B)
        corr = sum(K[:, j] * r[:, j][None] for j in range(m.m))                           # (n, N, B)
        est = x_in + np.moveaxis(corr, 0, 1)
        self.estimate, self.cov = est, P
        self.xbar = predict(m.F, est)
        self.Pbar = sm.const_sandwich(m.F, P) + m.Q[:, :, None, None]
        return est

    def shift(self, delta: np.ndarray) -> None:
        """Add delta (n, B) to every node's prediction (see `network_comparison`: error coordinates)."""
        self.xbar = self.xbar + delta[None]

    def nees(self, err: np.ndarray) -> np.ndarray:
        """(N, B): e_iᵀ P_i⁻¹ e_i with P the filter's own posterior covariance."""
        v = np.moveaxis(err, 1, 0)
        return sm.quad_form(sm.spd_inverse(self.cov), v)

    def prior_covariance(self) -> np.ndarray:
        """(n, n, N, B): the covariance of the state each node holds for the next step."""
        return self.Pbar


class TokenSampler:
    """Kar & Moura's auxiliary sequence (20): one state carried along the chain of locations of a
    token that starts at a uniformly random sensor and moves with an independent copy of the
    communication, corrected at every location by that sensor's Riccati map (with the noise of
    the hops it travelled). Its law at every step equals the law of P̂_q for a uniformly random
    sensor q independent of the communication (the identity behind weak consensus, Thm 10(i))."""

    def __init__(self, model: SensorNetworkModel, links: LinkModel, B: int, start: np.ndarray):
        self.model, self.links, self.B = model, links, B
        self.loc = np.asarray(start, np.int64)
        self.P = np.broadcast_to(model.P0[:, :, None], (model.n, model.n, B)).copy()
        self.H = sm.to_batched(model.H)
        self.R = sm.to_batched(model.R)

    def step(self, step_links: StepLinks, priority: np.ndarray | None) -> None:
        src, hops = step_permutation(self.links, step_links, self.B, priority)
        inv = np.empty_like(src)
        np.put_along_axis(inv, src, np.arange(src.shape[0])[:, None] + 0 * src, axis=0)
        cols = np.arange(self.B)
        self.loc = inv[self.loc, cols]
        h = hops[self.loc, cols]
        sigma = self.links.noise_std
        P = self.P
        if sigma:
            P = P + (sigma ** 2 * h) * np.eye(self.model.n)[:, :, None]
        _, post = kalman_update(P, self.H[:, :, self.loc], self.R[:, :, self.loc])
        self.P = sm.const_sandwich(self.model.F, post) + self.model.Q[:, :, None]


def token_chain_traces(model: SensorNetworkModel, links: LinkModel, n_steps: int, times: tuple[int, ...],
                       link_draws, gossip_draws) -> np.ndarray:
    """(len(times), B): tr P̃(t) of the token chain at `times`, for the B trials of the draws (the chain's
    start and the matchings' priorities from `gossip_draws`, its communication from `link_draws`)."""
    B = link_draws.n
    tok = TokenSampler(model, links, B, gossip_draws.integers(0, model.N))
    out = np.zeros((len(times), B))
    for k in range(n_steps):
        if k in times:
            out[times.index(k)] = np.trace(tok.P, axis1=0, axis2=1)
        step = links.draw(link_draws)
        greedy = links.synchronous and links.kind != "matchings"
        tok.step(step, gossip_draws.random((links.topology.E,)).T if greedy else None)
    return out


def weak_consensus_conditions(model: SensorNetworkModel, links: LinkModel) -> dict:
    """Kar & Moura's conditions for weak consensus, decided for the swaps of this filter on a link model.

    C.1 (``c1``): the mean swap permutation is irreducible (the token moves along every edge of the connected
    graph) and aperiodic (an odd cycle, or a node that can stay put, `LinkModel.stay_witness`); None when
    neither is found. D.1 (``d1``): weak detectability, decided by the Gramian along a covering walk (staying
    n steps at each node when nodes can stay put) repeated n times: True when invertible (λ_min/λ_max >
    1e-10, ``d1_ratio``), False when (F, H) of all sensors is not observable, else None. S.1
    (``stabilizable``): (F, Q^½) stabilizable."""
    from .sensor_network import observable, stabilizable, walk_gramian_ratio

    loops, why = links.stay_witness()
    bipartite = links.topology.is_bipartite()
    walk = links.topology.covering_walk(stay=model.n if loops else 1) * model.n
    ratio = walk_gramian_ratio(model, walk)
    observable_ = observable(model.F, model.H_all)
    return {"collective_observable": observable_, "stabilizable": stabilizable(model.F, model.Q),
            "c1": True if (not bipartite or loops) else (None if loops is None else False),
            "c1_detail": "the graph is connected (irreducible) and " + (
                "has an odd cycle (aperiodic)" if not bipartite else f"bipartite; self-loops: {why}"),
            "d1_ratio": ratio, "d1_walk_length": len(walk),
            "d1": True if ratio > 1e-10 else (False if not observable_ else None)}
