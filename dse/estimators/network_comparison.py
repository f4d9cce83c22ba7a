"""Every network filter on the same trials: one plant, one graph, one link model, common random numbers.

`simulate_units` runs B trials (a few RNG units of trials, trials on the last axis) of the plant
and of every estimator in lock step: at each step k the sensors measure x(k), every estimator
processes the same measurements and the same link draws (and communication noise), and the
error of every node's estimate of x(k) is accumulated into per-unit sums. The random numbers
come from separate streams (plant, links, noise, gossip), so adding or removing an estimator
does not change what the others see.

Estimators (by kind):

* ``central``: the centralized Kalman filter on all measurements (`dse.estimators.kalman`);
* ``local``: every node's own Kalman filter, no communication;
* ``gossip``: `gossip_swap_kalman.GossipSwapRun`;
* a `constant_gain_fusion.FusionFilter` (Carli, re-injection, pairwise averaging);
* an `information_fusion.InformationFilter` (Kalman-consensus, diffusion, consensus on information).

Per-unit sums over trials, each (U, S, N) at the S recorded steps unless stated: ``sq`` Σ‖e_i‖²,
``sq2`` Σ‖e_i‖⁴, ``dist`` Σ‖x̂_i − x̂_c‖², ``dist2``, ``cross`` Σ (x − x̂_c)ᵀ(x̂_c − x̂_i) and
``cross2`` (the orthogonality of the centralized error to every other estimate), ``nees``
Σ e_iᵀP_i⁻¹e_i with the estimator's own covariance and ``nees2``, ``xnees`` the same with a given
exact covariance, ``dis`` and ``dis2`` (U, S) the per-trial disagreement (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖²,
``dis_node`` (U, S, N) its terms ‖x̂_i − mean_j x̂_j‖² per node,
``net`` and ``net2`` (U, S) the per-trial node average of ‖e_i‖²,
``msgs`` and ``scalars`` (U, N) messages and scalars sent over the whole run (every step).
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from . import small_matrix as sm
from .constant_gain_fusion import FusionFilter, FusionRun
from .gossip_swap_kalman import GossipSwapRun, step_permutation
from .information_fusion import InformationFilter, InformationRun
from .link_models import LinkModel
from .network_mixing import link_count
from .network_step import StepContext, apply_gain, innovation, predict, slice_context
from .sensor_network import SensorNetworkModel

__all__ = ["Setup", "simulate_units", "STATS", "communication", "record_steps"]

STATS = ("sq", "sq2", "dist", "dist2", "cross", "cross2", "nees", "nees2", "xnees")


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
    n_paths: int = 1
    record_steps: tuple[int, ...] = ()            # steps whose statistics are kept (all if empty)
    sub_batch: int = 250                          # trials an estimator steps at once (cache-sized arrays)


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

    def shift(self, delta: np.ndarray) -> None:
        self.xbar = self.xbar + delta


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

    def shift(self, delta: np.ndarray) -> None:
        self.xbar = self.xbar + delta[None]


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


def communication(kind, links: LinkModel, n: int) -> tuple[str, int, int]:
    """(pattern, messages per contact, scalars per message) of an estimator.

    A message is one transmission from a node to one neighbour; a contact is one working link
    seen from one of its ends (a node sends one message per contact). Patterns: ``none``;
    ``rounds`` (every synchronous round, or every Poisson exchange); ``step`` (the links an
    estimator uses once per step); ``swap`` (the GIKF's matched links or exchanges). Payloads,
    n states: estimates n; GIKF estimate and covariance n + n(n+1)/2; Kalman-consensus the
    measurement information u_j and the prior estimate (2n; U_j is constant and sent once);
    diffusion the measurement information and, in a second exchange, the intermediate estimate
    (two messages of n); CI the information pair n + n(n+1)/2 per round."""
    half = n * (n + 1) // 2
    if isinstance(kind, str) and kind in ("central", "local"):
        return "none", 0, 0
    if isinstance(kind, str) and kind == "gossip":
        return "swap", 1, n + half
    if isinstance(kind, FusionFilter):
        return "rounds", 1, n
    if kind.kind == "information-consensus":
        return "rounds", 1, n + half
    if kind.kind == "diffusion":
        return "step", 2, n
    return "step", 1, 2 * n


def _contacts(topo, mask, offsets, sizes) -> np.ndarray:
    """(U, N): contacts per node summed over the trials of each unit."""
    if mask is None:
        return np.outer(sizes, topo.degrees).astype(float)
    per_unit = np.add.reduceat(mask.astype(float), offsets, axis=1)          # (E, U)
    return (topo.node_edges.astype(float) @ per_unit).T


def _event_contacts(topo, ids, offsets, U) -> np.ndarray:
    unit = np.searchsorted(offsets, np.arange(ids.shape[1]), side="right") - 1
    live = ids >= 0
    uu = np.broadcast_to(unit, ids.shape)[live]
    out = np.zeros((U, topo.n_nodes))
    np.add.at(out, (uu, topo.edges[ids[live], 0]), 1.0)
    np.add.at(out, (uu, topo.edges[ids[live], 1]), 1.0)
    return out


def record_steps(n_steps: int, every: int | None = None, extra=()) -> tuple[int, ...]:
    """The steps whose statistics are kept: all of them up to 100 steps, else about 100 evenly
    spaced ones (always the first and the last) and `extra`."""
    if n_steps <= 100 and every is None:
        return tuple(range(n_steps))
    stride = every or int(np.ceil(n_steps / 100))
    return tuple(sorted(set(range(0, n_steps, stride)) | {n_steps - 1} | {int(e) for e in extra if 0 <= e < n_steps}))


def simulate_units(setup: Setup, plant: Draws, links: Draws, noise: Draws, gossip: Draws) -> dict[str, Any]:
    """Simulate the trials of a few RNG units (`plant.sizes`) and return per-unit sums (module doc).

    Statistics are kept at `setup.record_steps` (all steps when empty); message counts at every step."""
    m, lm, K = setup.model, setup.links, setup.n_steps
    sizes = np.array(plant.sizes)
    B, U = int(sizes.sum()), len(sizes)
    offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
    N, n = m.N, m.n
    topo = lm.topology
    kinds = setup.estimators
    cuts = [slice(a, min(a + setup.sub_batch, B)) for a in range(0, B, setup.sub_batch)]
    runs = {name: [_make(kind, setup, c.stop - c.start) for c in cuts] for name, kind in kinds.items()}
    kcf = next((name for name, kd in kinds.items() if isinstance(kd, InformationFilter) and kd.kind == "kalman-consensus"),
               None)
    for name, kd in kinds.items():      # diffusion shares the Kalman-consensus filter's covariance recursion
        if kcf is not None and isinstance(kd, InformationFilter) and kd.kind == "diffusion" and \
                list(kinds).index(kcf) < list(kinds).index(name):
            runs[name] = [InformationRun(kd, c.stop - c.start, twin=t) for c, t in zip(cuts, runs[kcf])]
    comm = {name: communication(kind, lm, n) for name, kind in kinds.items()}
    has_gossip = any(isinstance(k, str) and k == "gossip" for k in kinds.values())
    steps = setup.record_steps or tuple(range(K))
    where = {k: i for i, k in enumerate(steps)}
    S = len(steps)

    def per_unit(a):                                   # (..., B) -> (U, ...)
        return np.moveaxis(np.add.reduceat(a, offsets, axis=-1), -1, 0)

    acc = {}
    for name in runs:
        width = 1 if kinds[name] == "central" else N
        acc[name] = {s: np.zeros((U, S, width)) for s in STATS}
        acc[name].update(dis=np.zeros((U, S)), dis2=np.zeros((U, S)), dis_node=np.zeros((U, S, width)),
                         net=np.zeros((U, S)), net2=np.zeros((U, S)),
                         msgs=np.zeros((U, N)), scalars=np.zeros((U, N)))
    q_node = gossip.integers(0, N) if has_gossip else None
    token = {name: np.zeros((len(setup.token_times), B)) for name, kd in kinds.items() if kd == "gossip"}
    P = min(setup.n_paths, B)
    paths = {"x": np.zeros((K, n, P))}
    paths.update({name: np.zeros((K, 1 if kinds[name] == "central" else N, n, P)) for name in runs})

    seconds = dict.fromkeys(runs, 0.0)
    # Error coordinates: every estimator is equivariant under adding the same vector to the state, its
    # prediction and all its estimates (gains act on innovations, fusion weights sum to one, CI's q = Ω x̂),
    # so the filters run on x ≡ 0 with measurements y = v, initial estimates x0 − x(0), and each
    # prediction shifted by −w: their estimates are then the errors x̂ − x exactly, without the
    # cancellation of x − x̂ when an unstable plant makes x huge. The true state is kept for the sample
    # trials only (recordings).
    x0_draw = _factor(m.P0) @ plant.standard_normal((n,)).T
    for parts in runs.values():
        for r, c in zip(parts, cuts):
            r.shift(-x0_draw[:, c])
    x_true = m.x0[:, None] + x0_draw[:, :setup.n_paths]
    Lq = _factor(m.Q)
    sigma = lm.noise_std
    cols = np.arange(B)
    for k in range(K):
        y = _measurement_noise(m, plant.standard_normal((N, m.m)))          # H x + v with x ≡ 0
        step_links = lm.draw(links)
        ctx = StepContext(k, y, step_links)
        contacts = {}
        if lm.synchronous:
            counts = [link_count(topo, mask, B) for mask in step_links.rounds]
            ctx.heard = [c > 0 for c in counts]
            ctx.step_heard, ctx.step_count = ctx.heard[0], counts[0]
            contacts["rounds"] = sum(_contacts(topo, mask, offsets, sizes) for mask in step_links.rounds)
            contacts["step"] = _contacts(topo, step_links.rounds[0], offsets, sizes)
        else:
            ctx.step_count = link_count(topo, step_links.step_mask, B)
            ctx.step_heard = ctx.step_count > 0
            contacts["rounds"] = _event_contacts(topo, step_links.events, offsets, U)
            contacts["step"] = _contacts(topo, step_links.step_mask, offsets, sizes)
        if sigma:
            if lm.synchronous:
                ctx.noise = [np.moveaxis(noise.standard_normal((N, n)), 0, -1) for _ in range(lm.rounds)]
                ctx.node_noise = ctx.noise[0]
            else:
                ctx.event_noise = np.moveaxis(noise.standard_normal((lm.max_events, 2, n)), 0, -1)
                ctx.node_noise = np.moveaxis(noise.standard_normal((N, n)), 0, -1)
        if has_gossip and lm.synchronous and lm.kind != "matchings":
            ctx.gossip_priority = gossip.random((topo.E,)).T
        if has_gossip:
            ctx.swap = step_permutation(lm, step_links, B, ctx.gossip_priority)
        if P:
            paths["x"][k] = x_true
        record = k in where
        e_c = None
        ctxs = [slice_context(ctx, c) for c in cuts] if len(cuts) > 1 else [ctx]
        for name, parts in runs.items():
            if name in token and k in setup.token_times:
                token[name][setup.token_times.index(k)] = np.concatenate(
                    [sm.trace(r.Pbar)[q_node[c], np.arange(c.stop - c.start)] for r, c in zip(parts, cuts)])
            t0 = time.process_time()
            est = np.concatenate([r.step(cx) for r, cx in zip(parts, ctxs)], axis=-1)
            seconds[name] += time.process_time() - t0
            pattern, per_contact, payload = comm[name]
            a = acc[name]
            if pattern != "none":
                c = (per_unit(np.concatenate([(r.hops > 0) for r in parts], axis=-1).astype(float))
                     if (pattern == "swap" and lm.synchronous)
                     else contacts["rounds" if pattern in ("rounds", "swap") else "step"]) * per_contact
                a["msgs"] += c
                a["scalars"] += c * payload
            if P:
                paths[name][k] = x_true[None] + est[:, :, :P]
            if not record:
                continue
            i = where[k]
            err = -est                                                # x − x̂ in error coordinates (N, n, B)
            if kinds[name] == "central":
                e_c = err
            sq = np.einsum("inb,inb->ib", err, err)
            a["sq"][:, i] = per_unit(sq)
            a["sq2"][:, i] = per_unit(sq * sq)
            net = sq.mean(axis=0)
            a["net"][:, i] = per_unit(net)
            a["net2"][:, i] = per_unit(net * net)
            if e_c is not None:
                d = err - e_c
                dd = np.einsum("inb,inb->ib", d, d)
                a["dist"][:, i] = per_unit(dd)
                a["dist2"][:, i] = per_unit(dd * dd)
                cr = np.einsum("inb,nb->ib", d, e_c[0])               # (x − x̂_c)ᵀ (x̂_c − x̂_i)
                a["cross"][:, i] = per_unit(cr)
                a["cross2"][:, i] = per_unit(cr * cr)
            if err.shape[0] > 1:
                dev = err - err.mean(axis=0, keepdims=True)
                dn = np.einsum("inb,inb->ib", dev, dev)                 # ‖x̂_i − mean_j x̂_j‖² per node
                dis = dn.mean(axis=0)
                a["dis"][:, i] = per_unit(dis)
                a["dis2"][:, i] = per_unit(dis * dis)
                a["dis_node"][:, i] = per_unit(dn)
            own = [_own_nees(r, err[..., c], k) for r, c in zip(parts, cuts)]
            own = None if own[0] is None else np.concatenate(own, axis=-1)
            if own is not None:
                a["nees"][:, i] = per_unit(own)
                a["nees2"][:, i] = per_unit(own * own)
            if name in setup.exact_cov:
                inv = np.linalg.inv(setup.exact_cov[name][k])
                a["xnees"][:, i] = per_unit(np.einsum("inb,inm,imb->ib", err, inv, err))
        w = Lq @ plant.standard_normal((n,)).T
        for parts in runs.values():
            for r, c in zip(parts, cuts):
                r.shift(-w[:, c])
        x_true = m.F @ x_true + w[:, :P]
    return {"sums": acc, "token": token, "paths": paths, "sizes": sizes, "steps": np.array(steps), "seconds": seconds}


def _factor(Q: np.ndarray) -> np.ndarray:
    """A factor L with L Lᵀ = Q for a positive semidefinite Q (eigenvalues clipped at 0)."""
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def _measurement_noise(m: SensorNetworkModel, z: np.ndarray) -> np.ndarray:
    """v (N, m, B) from standard normals z (B, N, m): v_i = R_chol[i] z_i."""
    return np.einsum("iab,cib->iac", m.R_chol, z)
