"""Three standard distributed Kalman filters, batched over trials, with their exact moments on
reliable links.

Notation: node i's neighbourhood in a step is J_i = {i} ∪ (neighbours whose link works);
u_j = H_jᵀ R_j⁻¹ y_j and U_j = H_jᵀ R_j⁻¹ H_j are sensor j's information vector and matrix
(`sensor_network.SensorNetworkModel.info_weight`, `.info_matrix`);
S_i = Σ_{j∈J_i} U_j, ȳ_i = Σ_{j∈J_i} u_j.

* **Kalman-consensus filter** (Olfati-Saber 2007, Table 1; 2009, Algorithm 1): each node sends
  (u_i, U_i, x̄_i) to its neighbours and computes
      M_i = (P̄_i⁻¹ + S_i)⁻¹,
      x̂_i = x̄_i + M_i (ȳ_i − S_i x̄_i) + γ_i M_i Σ_{j∈J_i∖i} (x̄_j − x̄_i),   γ_i = ε / (1 + ‖M_i‖_F),
      P̄_i ← F M_i Fᵀ + Q,   x̄_i ← F x̂_i.
  M_i is the filter's own covariance of x̂_i; it ignores the consensus term and the correlation
  between neighbours' errors, so it is not the true error covariance.
* **Diffusion Kalman filter, adapt then combine** (Cattivelli & Sayed 2010, Algorithm 1): the
  incremental update processes the measurements of J_i one after another, which for linear
  Gaussian models is the information form
      P_i = (P̄_i⁻¹ + S_i)⁻¹,   ψ_i = x̄_i + P_i (ȳ_i − S_i x̄_i),
  then the diffusion step combines the neighbours' intermediate estimates with convex weights,
  x̂_i = Σ_{l∈J_i} c_{l,i} ψ_l, and P̄_i ← F P_i Fᵀ + Q, x̄_i ← F x̂_i (P_i stays the filter's
  covariance of its estimate, as in the paper).
* **Consensus on information** (Battistelli & Chisci 2014, the CI algorithm): information pairs
  (Ω_i, q_i), q_i = Ω_i x̂_i; local correction Ω_i ← Ω̄_i + U_i, q_i ← q̄_i + u_i; L rounds of
  consensus (Ω_i, q_i) ← Σ_j π_ij (Ω_j, q_j); prediction Ω̄_i = (F Ω_i⁻¹ Fᵀ + Q)⁻¹,
  q̄_i = Ω̄_i F Ω_i⁻¹ q_i. A convex combination of information pairs is a covariance
  intersection, which is conservative whatever the correlation of the errors: with noiseless
  links E[e_i e_iᵀ] ⪯ Ω_i⁻¹ at every step (by induction: the correction of a conservative prior
  with an independent measurement is conservative, (Σ π_j a_j)(Σ π_j a_j)ᵀ ⪯ Σ π_j a_j a_jᵀ for
  a convex combination, and the prediction preserves ⪯).

Random links: a node uses the neighbours it heard in the step (the links of the first round, or
every edge that rang during the step); the consensus weights of failed links fall back on the
node (`network_mixing`). CI runs one consensus round per synchronous round, and under Poisson
exchanges averages the two endpoints' pairs at each exchange. Communication noise enters each
node's fused estimate (`network_step`): KCF's received estimates, the diffusion combination, and
CI's fused pair (q_i ← q_i + Ω_i σ_c u_i, i.e. the fused estimate moves by σ_c u_i).

Exact moments (reliable links): the gains M_i, P_i, Ω_i then do not depend on the data or on
the links, the errors are linear in the noises, and the joint second moment follows exactly
(`exact_moments`).
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from . import joint_moments as jm
from . import small_matrix as sm
from .link_models import LinkModel
from .network_mixing import Mixer
from .network_step import StepContext, predict
from .protocol import BatchedFilter
from .sensor_network import SensorNetworkModel

__all__ = ["KINDS", "InformationFilter", "InformationRun", "exact_moments"]

KINDS = ("kalman-consensus", "diffusion", "information-consensus")


@dataclass(frozen=True, eq=False)
class InformationFilter:
    model: SensorNetworkModel
    links: LinkModel
    kind: str
    weights: np.ndarray          # (E,) consensus / combination weights q_e
    epsilon: float = 0.1         # KCF consensus gain ε

    def __post_init__(self):
        if self.kind not in KINDS:
            raise ValueError(f"unknown filter {self.kind!r}")

    @cached_property
    def mixer(self) -> Mixer:
        return Mixer(self.links.topology, np.asarray(self.weights, float))

    @cached_property
    def adjacency(self) -> np.ndarray:
        inc = self.links.topology.incidence
        A = -(inc @ inc.T)
        np.fill_diagonal(A, 0.0)
        return A

    @property
    def exact_available(self) -> tuple[bool, str]:
        if self.links.random or not self.links.synchronous:
            return False, ("with random links the filter's gains depend on which links worked, so the mean "
                           "over link patterns has no closed form (Monte Carlo only)")
        return True, ""

    def neighbour_sum(self, V: np.ndarray) -> np.ndarray:
        """Σ over all neighbours j of V_j, for per-node values V (N, ...) (every link working)."""
        N = V.shape[0]
        return (self.adjacency @ V.reshape(N, -1)).reshape(V.shape)


class InformationRun(BatchedFilter):
    """B trials of an `InformationFilter`: `estimate` (N, n, B) after each step; `cov` the filter's
    own covariance of it ((n, n, N, 1) when it does not depend on the trial) or, for CI, `info`."""

    def __init__(self, f: InformationFilter, B: int, twin: "InformationRun | None" = None):
        """`twin`: a Kalman-consensus run on the same trials and links, whose covariance recursion a
        diffusion run shares (the two filters' M_i and P_i are the same function of the link draws)."""
        self.f, self.B = f, B
        self.twin = twin if (twin is not None and f.kind == "diffusion" and twin.f.kind == "kalman-consensus"
                             and twin.f.links is f.links) else None
        self._k = None
        m = f.model
        N, n = m.N, m.n
        self.xbar = np.broadcast_to(m.x0[None, :, None], (N, n, B)).copy()
        self.Pbar = np.broadcast_to(m.P0[:, :, None, None], (n, n, N, 1)).copy()
        self.U = sm.to_batched(m.info_matrix)[..., None]                     # (n, n, N, 1)
        if f.kind == "information-consensus":
            self.Obar = sm.spd_inverse(self.Pbar)
            self.qbar = np.moveaxis(sm.matvec(self.Obar, np.moveaxis(self.xbar, 1, 0)), 0, 1)
        self.estimate = self.xbar
        self.cov = self.Pbar

    # -- shared: what a node gathers from the neighbours it heard ------------------------------------
    def _gather(self, ctx: StepContext, mask):
        f, m = self.f, self.f.model
        u = np.einsum("inm,imb->inb", m.info_weight, ctx.y)                    # (N, n, B)
        if mask is None:
            ybar = u + f.neighbour_sum(u)
            S = self.U + sm.to_batched(f.neighbour_sum(m.info_matrix))[..., None]
        else:
            ybar = u + _heard_sum(f, u, mask, ctx.step_count)
            S = self.U + _heard_information(f, mask)
        return ybar, S

    def step(self, ctx: StepContext) -> np.ndarray:
        kind = self.f.kind
        if kind == "information-consensus":
            return self._ci_step(ctx)
        f, m = self.f, self.f.model
        mask = ctx.links.step_mask if self.f.links.random or not self.f.links.synchronous else None
        ybar, S = self._gather(ctx, mask)
        if self.twin is not None and self.twin._k == ctx.k:
            Om, M = self.twin.info, self.twin.cov
        else:
            Om = sm.spd_inverse(self.Pbar) + S
            M = sm.spd_inverse(Om)
        resid = np.moveaxis(ybar, 1, 0) - sm.matvec(S, np.moveaxis(self.xbar, 1, 0))      # (n, N, B)
        psi = self.xbar + np.moveaxis(sm.matvec(M, resid), 0, 1)
        sigma = f.links.noise_std
        heard = ctx.step_heard
        if kind == "kalman-consensus":
            lap = _laplacian_apply(f, self.xbar, mask)                                    # Σ_j (x̄_i − x̄_j)
            cons = -lap
            if sigma:
                cons = cons + sigma * ctx.node_noise * heard[:, None, :]
            gamma = f.epsilon / (1.0 + np.sqrt(np.sum(M * M, axis=(0, 1))))               # (N, *)
            est = psi + gamma[:, None, :] * np.moveaxis(sm.matvec(M, np.moveaxis(cons, 1, 0)), 0, 1)
        else:
            est = f.mixer.mix(psi, mask)
            if sigma:
                est = est + sigma * ctx.node_noise * heard[:, None, :]
        self.estimate, self.cov, self.info, self._k = est, M, Om, ctx.k
        self.xbar = predict(m.F, est)
        if self.twin is not None and self.twin._k == ctx.k:
            self.Pbar = self.twin.Pbar
        else:
            self.Pbar = sm.const_sandwich(m.F, M) + m.Q[:, :, None, None]
        return est

    def _ci_step(self, ctx: StepContext) -> np.ndarray:
        f, m = self.f, self.f.model
        O = self.Obar + self.U
        q = self.qbar + np.einsum("inm,imb->inb", m.info_weight, ctx.y)
        sigma = f.links.noise_std
        if f.links.synchronous:
            n = m.n
            Op = np.moveaxis(sm.pack(O), 1, 0)                                  # (N, p, *) packed, node first
            for r, mask in enumerate(ctx.links.rounds):
                Op = f.mixer.mix(Op, mask)
                q = f.mixer.mix(q, mask)
                if sigma:
                    kick = sigma * ctx.noise[r] * ctx.heard[r][:, None, :]
                    q = q + np.moveaxis(sm.matvec(sm.unpack(np.moveaxis(Op, 0, 1), n), np.moveaxis(kick, 1, 0)), 0, 1)
            O = sm.unpack(np.moveaxis(Op, 0, 1), n)
        else:
            O, q = _ci_exchanges(f, O, q, ctx, self.B)
        P = sm.spd_inverse(O)
        x = np.moveaxis(sm.matvec(P, np.moveaxis(q, 1, 0)), 0, 1)                        # (N, n, B)
        self.estimate, self.info = x, O
        self.cov = P
        self.Obar = sm.spd_inverse(sm.const_sandwich(m.F, P) + m.Q[:, :, None, None])
        self.xbar = predict(m.F, x)
        self.qbar = np.moveaxis(sm.matvec(self.Obar, np.moveaxis(self.xbar, 1, 0)), 0, 1)
        return x

    def shift(self, delta: np.ndarray) -> None:
        """Add delta (n, B) to every node's prediction (see `network_comparison`: error coordinates);
        for CI the information vector moves by Ω̄ delta."""
        self.xbar = self.xbar + delta[None]
        if self.f.kind == "information-consensus":
            self.qbar = self.qbar + np.moveaxis(sm.matvec(self.Obar, delta[:, None, :]), 0, 1)

    def nees(self, err: np.ndarray) -> np.ndarray:
        """(N, B): e_iᵀ P_i⁻¹ e_i with the filter's own covariance, through its information matrix."""
        return sm.quad_form(self.info, np.moveaxis(err, 1, 0))


def _unit_mixer(f: InformationFilter) -> Mixer:
    cache = f.__dict__.setdefault("_unit_mixer", [])
    if not cache:
        cache.append(Mixer(f.links.topology, np.ones(f.links.topology.E)))
    return cache[0]


def _heard_sum(f: InformationFilter, V: np.ndarray, mask: np.ndarray, count: np.ndarray) -> np.ndarray:
    """Σ over the neighbours j that node i heard of V_j, for V (N, r, B), working edges (E, B) and the
    number of working links of every node (N, B): count_i V_i − (L V)_i, L the Laplacian of the
    working links."""
    return count[:, None, :] * V - _laplacian_apply(f, V, mask)


def _heard_information(f: InformationFilter, mask: np.ndarray) -> np.ndarray:
    """(n, n, N, B): Σ over heard neighbours of U_j, as one sparse product: row (entry, i), column
    e holds the packed entry of U at the other end of e when i is an end of e."""
    topo, m = f.links.topology, f.model
    cache = f.__dict__.setdefault("_heard_info_matrix", {})
    if "M" not in cache:
        import scipy.sparse as sp

        n, N, E = m.n, topo.n_nodes, topo.E
        packed = sm.pack(sm.to_batched(m.info_matrix))                        # (p, N)
        p = packed.shape[0]
        a, b = topo.edges[:, 0], topo.edges[:, 1]
        rows, cols, vals = [], [], []
        for x in range(p):
            rows += [x * N + a, x * N + b]
            cols += [np.arange(E), np.arange(E)]
            vals += [packed[x, b], packed[x, a]]
        cache["M"] = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))),
                                   shape=(p * N, E))
        cache["p"] = p
    out = (cache["M"] @ mask.astype(float)).reshape(cache["p"], topo.n_nodes, mask.shape[1])
    return sm.unpack(out, m.n)


def _laplacian_apply(f: InformationFilter, x: np.ndarray, mask) -> np.ndarray:
    """Σ_{j heard} (x_i − x_j) with unit weights, for x (N, r, B)."""
    return x - _unit_mixer(f).mix(x, mask)


def _ci_exchanges(f: InformationFilter, O: np.ndarray, q: np.ndarray, ctx: StepContext, B: int):
    """Poisson exchanges on information pairs: both endpoints move towards each other by q_e."""
    topo, w, sigma = f.links.topology, f.weights, f.links.noise_std
    if O.shape[-1] != B:
        O = np.broadcast_to(O, O.shape[:-1] + (B,)).copy()
    else:
        O = O.copy()
    q = q.copy()
    cols = np.arange(B)
    for c, ids in enumerate(ctx.links.events):
        live = ids >= 0
        if not live.any():
            break
        bb, e = cols[live], ids[live]
        i, j = topo.edges[e, 0], topo.edges[e, 1]
        a = w[e]
        Oi, Oj = O[:, :, i, bb], O[:, :, j, bb]
        qi, qj = q[i, :, bb], q[j, :, bb]
        nOi, nOj = Oi + a * (Oj - Oi), Oj + a * (Oi - Oj)
        nqi, nqj = qi + a[:, None] * (qj - qi), qj + a[:, None] * (qi - qj)
        if sigma:
            ki = sigma * ctx.event_noise[c, 0][:, bb]                  # (n, L)
            kj = sigma * ctx.event_noise[c, 1][:, bb]
            nqi = nqi + np.einsum("abl,bl->la", nOi, ki)
            nqj = nqj + np.einsum("abl,bl->la", nOj, kj)
        O[:, :, i, bb], O[:, :, j, bb] = nOi, nOj
        q[i, :, bb], q[j, :, bb] = nqi, nqj
    return O, q


# -- exact moments on reliable links ---------------------------------------------------------------------

def exact_moments(f: InformationFilter, n_steps: int) -> dict[str, np.ndarray]:
    """Exact second moment of the errors of x̂_i(k|k) with every link working (gains deterministic).

    Returns ``blocks`` (K, N, n, n), ``mse`` (K, N), ``disagreement`` (K,), ``network`` (K,), and
    ``own_cov`` (K, N, n, n), the filter's own covariance (M_i, P_i or Ω_i⁻¹)."""
    ok, why = f.exact_available
    if not ok:
        raise ValueError(why)
    m = f.model
    N, n = m.N, m.n
    U = m.info_matrix
    A = f.adjacency
    J = A + np.eye(N)
    S_nodes = np.einsum("ij,jab->iab", J, U)
    meas = np.einsum("ij,kj,jab->iakb", J, J, U)                       # Σ_{j∈J_i∩J_k} U_j
    W = f.mixer.matrix
    sigma2 = f.links.noise_std ** 2
    heard = (f.links.topology.degrees > 0).astype(float)
    L = f.links.topology.laplacian()
    S = jm.common_start(N, m.P0)
    Pbar = np.broadcast_to(m.P0, (N, n, n)).copy()
    Obar = np.linalg.inv(Pbar)
    blocks = np.empty((n_steps, N, n, n))
    own = np.empty((n_steps, N, n, n))
    dis = np.empty(n_steps)
    eye = np.eye(n)
    for k in range(n_steps):
        if f.kind == "information-consensus":
            O = Obar + U
            Oinv = np.linalg.inv(O)
            S = jm.node_wise(Oinv @ Obar, S)                                   # Ω⁻¹ Ω̄ e
            S = jm.add_block_diagonal(S, Oinv @ U @ Oinv)                       # − Ω⁻¹ u-noise
            S = jm.node_wise(O, S)                                              # ε = Ω e
            for _ in range(f.links.rounds):
                O = np.einsum("ij,jab->iab", W, O)
                S = jm.node_mix(W, S)
                if sigma2:
                    S = jm.add_block_diagonal(S, sigma2 * heard[:, None, None] * (O @ O))
            Oinv = np.linalg.inv(O)
            Oinv = 0.5 * (Oinv + np.swapaxes(Oinv, 1, 2))
            S = jm.node_wise(Oinv, S)
            cov = Oinv
            Obar = np.linalg.inv(m.F @ Oinv @ m.F.T + m.Q)
        else:
            M = np.linalg.inv(np.linalg.inv(Pbar) + S_nodes)
            M = 0.5 * (M + np.swapaxes(M, 1, 2))
            G = eye - M @ S_nodes
            if f.kind == "kalman-consensus":
                gamma = f.epsilon / (1.0 + np.sqrt(np.sum(M * M, axis=(1, 2))))
                C = gamma[:, None, None] * M                                     # (N, n, n)
                big = np.zeros((N, n, N, n))
                idx = np.arange(N)
                big[idx, :, idx, :] = G
                big -= np.einsum("iab,ij->iajb", C, L)                          # + γ M Σ (e_j − e_i)
                S = np.einsum("iajb,jbkc,ldkc->iald", big, S, big, optimize=True)
                S += jm.node_wise(M, meas)
                if sigma2:
                    S = jm.add_block_diagonal(S, sigma2 * heard[:, None, None] * (C @ np.swapaxes(C, 1, 2)))
            else:
                S = jm.node_wise(G, S) + jm.node_wise(M, meas)
                S = jm.node_mix(W, S)
                if sigma2:
                    S = jm.add_block_diagonal(S, sigma2 * heard[:, None, None] * eye)
            cov = M
            Pbar = m.F @ M @ m.F.T + m.Q
        blocks[k] = jm.node_blocks(S)
        own[k] = cov
        dis[k] = jm.disagreement(S)
        S = jm.state_wise(m.F, S, m.Q)
    mse = np.einsum("kiaa->ki", blocks)
    return {"blocks": blocks, "mse": mse, "disagreement": dis, "network": mse.mean(axis=1), "own_cov": own}

