"""Every network filter on the same trials: one plant, one graph, one link model, common random numbers.

`simulate_units` runs B trials (a few RNG units of trials, trials on the last axis) of the plant
and of every estimator in lock step: at each step k the sensors measure x(k), every estimator
processes the same measurements and the same link draws (and communication noise), and the
error of every node's estimate of x(k) is accumulated into per-unit sums. The random numbers
come from separate streams (plant, links, noise, gossip), so adding or removing an estimator
does not change what the others see.

Estimators (by kind):

* ``central``: the centralized Kalman filter on all measurements (`estimators.kalman`);
* ``local``: every node's own Kalman filter, no communication;
* ``gossip``: `gossip_swap_kalman.GossipSwapRun`;
* a `constant_gain_fusion.FusionFilter` (Carli, re-injection, pairwise averaging);
* an `information_fusion.InformationFilter` (Kalman-consensus, diffusion, consensus on information).

Per-unit sums, each (U, K, N) unless stated: ``sq`` Σ‖e_i‖², ``sq2`` Σ‖e_i‖⁴, ``dist``
Σ‖x̂_i − x̂_c‖², ``dist2``, ``nees`` Σ e_iᵀP_i⁻¹e_i with the estimator's own covariance and ``nees2``,
``xnees`` the same with a given exact covariance, ``dis`` and ``dis2`` (U, K) the per-trial
disagreement (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖², ``msgs`` (U, N) messages sent over the run.
"""
from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from . import small_matrix as sm
from .constant_gain_fusion import FusionFilter, FusionRun
from .gossip_swap_kalman import GossipSwapRun
from .information_fusion import InformationFilter, InformationRun
from .link_models import LinkModel
from .network_mixing import heard
from .network_step import StepContext, apply_gain, innovation, predict
from .sensor_network import SensorNetworkModel

__all__ = ["Setup", "simulate_units", "STATS", "message_counts"]

STATS = ("sq", "sq2", "dist", "dist2", "nees", "nees2", "xnees")


class Draws(Protocol):
    sizes: list

    def standard_normal(self, tail: tuple[int, ...] = ()) -> np.ndarray: ...

    def random(self, tail: tuple[int, ...] = ()) -> np.ndarray: ...

    def integers(self, low: int, high: int, tail: tuple[int, ...] = ()) -> np.ndarray: ...


@dataclass(frozen=True, eq=False)
class Setup:
    model: SensorNetworkModel
    links: LinkModel
    n_steps: int
    estimators: dict[str, Any]                    # name -> "central" | "local" | "gossip" | filter object
    exact_cov: dict[str, np.ndarray] = field(default_factory=dict)   # name -> (K, N, n, n)
    token_times: tuple[int, ...] = ()
    nees_steps: tuple[int, ...] = ()              # steps at which NEES is accumulated (all if empty)
    n_paths: int = 1


class _Central:
    def __init__(self, model: SensorNetworkModel, K: int, B: int):
        self.model = model
        cov = model.central_covariances(K)
        self.gains, self.P_post = cov.gains, cov.P_post
        self.P_inv = np.linalg.inv(cov.P_post)
        self.xbar = np.broadcast_to(model.x0[:, None], (model.n, B)).copy()

    def step(self, ctx: StepContext) -> np.ndarray:
        m = self.model
        y = ctx.y.reshape(-1, ctx.y.shape[-1])
        est = self.xbar + self.gains[ctx.k] @ (y - m.H_all @ self.xbar)
        self.xbar = m.F @ est
        self.estimate = est[None]
        return self.estimate


class _Local:
    def __init__(self, model: SensorNetworkModel, K: int, B: int):
        self.model = model
        covs = model.local_covariances(K)
        self.gains = np.stack([c.gains for c in covs], axis=1)          # (K, N, n, m)
        self.P_post = np.stack([c.P_post for c in covs], axis=1)        # (K, N, n, n)
        self.P_inv = np.linalg.inv(self.P_post)
        self.xbar = np.broadcast_to(model.x0[None, :, None], (model.N, model.n, B)).copy()

    def step(self, ctx: StepContext) -> np.ndarray:
        m = self.model
        est = self.xbar + apply_gain(self.gains[ctx.k], innovation(ctx.y, m.H, self.xbar))
        self.xbar = predict(m.F, est)
        self.estimate = est
        return est


def _make(kind, setup: Setup, B: int):
    if isinstance(kind, FusionFilter):
        return FusionRun(kind, B)
    if isinstance(kind, InformationFilter):
        return InformationRun(kind, B)
    if kind == "central":
        return _Central(setup.model, setup.n_steps, B)
    if kind == "local":
        return _Local(setup.model, setup.n_steps, B)
    if kind == "gossip":
        return GossipSwapRun(setup.model, setup.links, B)
    raise ValueError(f"unknown estimator {kind!r}")


def _own_nees(run, err: np.ndarray, k: int) -> np.ndarray | None:
    if isinstance(run, _Central):
        return np.einsum("inb,nm,imb->ib", err, run.P_inv[k], err)
    if isinstance(run, _Local):
        return np.einsum("inb,inm,imb->ib", err, run.P_inv[k], err)
    if isinstance(run, (GossipSwapRun, InformationRun)):
        return run.nees(err)
    return None


def message_counts(kind, links: LinkModel, ctx: StepContext, run=None) -> tuple[np.ndarray, int]:
    """(messages sent per node in this step, (N, B) or (N,); scalars per message).

    A message is one transmission from a node to one neighbour. Payloads (n states, m rows):
    estimates n; GIKF estimate and covariance n + n(n+1)/2; Kalman-consensus measurement
    information u_j (n) and prior estimate (n), with U_j sent once (constant); diffusion the
    measurement information (n) and, in a second exchange, the intermediate estimate (n); CI the
    information pair n + n(n+1)/2 per round."""
    topo = links.topology
    n = run.model.n if hasattr(run, "model") else run.f.model.n
    half = n * (n + 1) // 2

    def active(mask):
        return topo.degrees if mask is None else topo.node_edges.astype(float) @ mask

    def events_per_node():
        ids = ctx.links.events
        count = np.zeros((topo.n_nodes, ids.shape[1]))
        live = ids >= 0
        cols = np.broadcast_to(np.arange(ids.shape[1]), ids.shape)[live]
        np.add.at(count, (topo.edges[ids[live], 0], cols), 1.0)
        np.add.at(count, (topo.edges[ids[live], 1], cols), 1.0)
        return count

    if kind in ("central", "local"):
        return np.zeros(topo.n_nodes), 0
    if kind == "gossip":
        return (run.hops > 0).astype(float) if links.synchronous else events_per_node(), n + half
    if isinstance(kind, FusionFilter) or (isinstance(kind, InformationFilter) and kind.kind == "information-consensus"):
        payload = n if isinstance(kind, FusionFilter) else n + half
        if not links.synchronous:
            return events_per_node(), payload
        return sum(active(mask) for mask in ctx.links.rounds), payload
    mask = ctx.links.step_mask if (links.random or not links.synchronous) else None
    per_edge = 2 if kind.kind == "diffusion" else 1
    return per_edge * active(mask), 2 * n if kind.kind == "kalman-consensus" else n


def simulate_units(setup: Setup, plant: Draws, links: Draws, noise: Draws, gossip: Draws) -> dict[str, Any]:
    """Simulate the trials of a few RNG units (`plant.sizes`) and return per-unit sums (module doc)."""
    m, lm, K = setup.model, setup.links, setup.n_steps
    sizes = list(plant.sizes)
    B, U = sum(sizes), len(sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    N, n = m.N, m.n
    topo = lm.topology
    runs = {name: _make(kind, setup, B) for name, kind in setup.estimators.items()}
    kinds = setup.estimators
    has_gossip = any(isinstance(k, str) and k == "gossip" for k in kinds.values())
    nees_at = set(range(K)) if not setup.nees_steps else set(setup.nees_steps)

    def per_unit(a):                                   # (..., B) -> (U, ...)
        return np.moveaxis(np.add.reduceat(a, offsets, axis=-1), -1, 0)

    acc = {name: {s: np.zeros((U, K, N if kinds[name] != "central" else 1)) for s in STATS} for name in runs}
    for name in runs:
        acc[name]["dis"] = np.zeros((U, K))
        acc[name]["dis2"] = np.zeros((U, K))
        acc[name]["msgs"] = np.zeros((U, N))
        acc[name]["scalars"] = np.zeros((U, N))
    q_node = gossip.integers(0, N) if has_gossip else None
    token = {name: np.zeros((len(setup.token_times), B)) for name, kd in kinds.items() if kd == "gossip"}
    P = min(setup.n_paths, B)
    paths = {"x": np.zeros((K, n, P))}
    paths.update({name: np.zeros((K, N if kinds[name] != "central" else 1, n, P)) for name in runs})

    x = m.x0[:, None] + _factor(m.P0) @ plant.standard_normal((n,)).T
    Lq = _factor(m.Q)
    sigma = lm.noise_std
    for k in range(K):
        v = _measurement_noise(m, plant.standard_normal((N, m.m)))
        y = np.einsum("imn,nb->imb", m.H, x) + v
        step_links = lm.draw(links)
        ctx = StepContext(k, y, step_links)
        if lm.synchronous:
            ctx.heard = [heard(topo, mask, B) for mask in step_links.rounds]
            ctx.step_heard = ctx.heard[0]
        else:
            ctx.step_heard = heard(topo, step_links.step_mask, B)
        if sigma:
            if lm.synchronous:
                ctx.noise = [np.moveaxis(noise.standard_normal((N, n)), 0, -1) for _ in range(lm.rounds)]
                ctx.node_noise = ctx.noise[0]
            else:
                ctx.event_noise = np.moveaxis(noise.standard_normal((lm.max_events, 2, n)), 0, -1)
                ctx.node_noise = np.moveaxis(noise.standard_normal((N, n)), 0, -1)
        if has_gossip and lm.synchronous and lm.kind != "matchings":
            ctx.gossip_priority = gossip.random((topo.E,)).T
        if P:
            paths["x"][k] = x[:, :P]
        e_c = None
        for name, run in runs.items():
            if kinds[name] == "gossip" and k in setup.token_times:
                tr = sm.trace(run.Pbar)                               # (N, B) prior traces before the step
                token[name][setup.token_times.index(k)] = tr[q_node, np.arange(B)]
            est = run.step(ctx)
            err = x[None] - est                                       # (N, n, B)
            if kinds[name] == "central":
                e_c = err
            sq = np.einsum("inb,inb->ib", err, err)
            a = acc[name]
            a["sq"][:, k] = per_unit(sq)
            a["sq2"][:, k] = per_unit(sq * sq)
            if e_c is not None:
                d = err - e_c
                dd = np.einsum("inb,inb->ib", d, d)
                a["dist"][:, k] = per_unit(dd)
                a["dist2"][:, k] = per_unit(dd * dd)
            if err.shape[0] > 1:
                dev = err - err.mean(axis=0, keepdims=True)
                dis = np.einsum("inb,inb->b", dev, dev) / N
                a["dis"][:, k] = per_unit(dis)
                a["dis2"][:, k] = per_unit(dis * dis)
            if k in nees_at:
                own = _own_nees(run, err, k)
                if own is not None:
                    a["nees"][:, k] = per_unit(own)
                    a["nees2"][:, k] = per_unit(own * own)
                if name in setup.exact_cov:
                    inv = np.linalg.inv(setup.exact_cov[name][k])
                    xn = np.einsum("inb,inm,imb->ib", err, inv, err)
                    a["xnees"][:, k] = per_unit(xn)
            count, payload = message_counts(kinds[name], lm, ctx, run)
            count = np.broadcast_to(np.asarray(count, float).reshape(N, -1), (N, B))
            a["msgs"] += per_unit(count)
            a["scalars"] += per_unit(count * payload)
            if P:
                paths[name][k] = est[:, :, :P]
        x = m.F @ x + Lq @ plant.standard_normal((n,)).T
    if "central" not in kinds.values():
        for name in runs:
            acc[name].pop("dist"), acc[name].pop("dist2")
    return {"sums": acc, "token": token, "paths": paths, "sizes": np.array(sizes)}


def _factor(Q: np.ndarray) -> np.ndarray:
    """A factor L with L Lᵀ = Q for a positive semidefinite Q (eigenvalues clipped at 0)."""
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def _measurement_noise(m: SensorNetworkModel, z: np.ndarray) -> np.ndarray:
    """v (N, m, B) from standard normals z (B, N, m): v_i = R_chol[i] z_i."""
    return np.einsum("iab,cib->iac", m.R_chol, z)
