"""Every network filter on the same trials: one plant, one graph, one link model, common random numbers.

`simulate_units` runs B trials (a few RNG units of trials, trials on the last axis) of the plant and of
every estimator it is given (`protocol.DesignedEstimator`s: whatever the registry holds) in lock step: at
each step k the sensors measure x(k), and every filter steps on the same measurements, the same link draws
and the same communication noise (`protocol.NetworkFilter`). The random numbers come from separate streams
(plant, links, noise, gossip), so adding or removing an estimator does not change what the others see.
The filters run in error coordinates (`protocol`): their estimates are their errors.

An `Accumulator` beside the filters' steps keeps what the claims and tables read, as per-unit sums over
trials, each (U, S, W) at the S recorded steps unless stated (W = the filter's number of estimates):
``sq`` Σ‖e_i‖², ``sq2`` Σ‖e_i‖⁴, ``dist`` Σ‖x̂_i − x̂_c‖² and ``dist2`` (x̂_c the reference estimator's),
``cross`` Σ (x − x̂_c)ᵀ(x̂_c − x̂_i) and ``cross2`` (the orthogonality of the reference error to every other
estimate), ``nees`` Σ e_iᵀP_i⁻¹e_i with the filter's own covariance and ``nees2``, ``xnees`` the same with a
given exact covariance, ``dis`` and ``dis2`` (U, S) the per-trial disagreement (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖²,
``dis_node`` (U, S, W) its terms ‖x̂_i − mean_j x̂_j‖² per node, ``net`` and ``net2`` (U, S) the per-trial
node average of ‖e_i‖², ``msgs`` and ``scalars`` (U, N) messages and real numbers sent over the whole run
(every step, counted from the links and the filter's `Communication`); ``token`` (times, B): tr P̄_q at a
uniformly random node q of the filters that swap states; ``paths``: sample trials kept whole.
"""
from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from . import small_matrix as sm
from .link_models import LinkModel, StepLinks, step_permutation
from .network_mixing import link_count
from .network_step import StepContext, slice_context
from .protocol import DesignedEstimator
from .sensor_network import SensorNetworkModel

__all__ = ["Setup", "simulate_units", "STATS", "PER_TRIAL_SUMS", "record_steps"]

STATS = ("sq", "sq2", "dist", "dist2", "cross", "cross2", "nees", "nees2", "xnees")
#: the per-trial sums beside `STATS` (a diverging filter may make any of them infinite: a result, not a failure)
PER_TRIAL_SUMS = ("dis", "dis2", "dis_node", "net", "net2", "msgs", "scalars")


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
    estimators: dict[str, DesignedEstimator]      # name -> designed estimator, in the order they step
    exact_cov: dict[str, np.ndarray] = field(default_factory=dict)   # name -> (K, N, n, n)
    token_times: tuple[int, ...] = ()
    n_paths: int = 1
    record_steps: tuple[int, ...] = ()            # steps whose statistics are kept (all if empty)
    sub_batch: int = 250                          # trials a filter steps at once (cache-sized arrays)


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


class Accumulator:
    """The per-unit sums of the module doc, from the filters' estimates after each step."""

    def __init__(self, setup: Setup, sizes: np.ndarray, cuts: list[slice]):
        self.setup, self.sizes, self.cuts = setup, sizes, cuts
        self.offsets = np.concatenate([[0], np.cumsum(sizes)[:-1]])
        B, K, n = int(sizes.sum()), setup.n_steps, setup.model.n
        self.steps = setup.record_steps or tuple(range(K))
        self.where = {k: i for i, k in enumerate(self.steps)}
        self.comm = {name: est.communication() for name, est in setup.estimators.items()}
        self.reference = next((name for name, est in setup.estimators.items() if est.spec.reference), None)
        self.sums: dict[str, dict[str, np.ndarray]] = {}
        self.token = {name: np.zeros((len(setup.token_times), B)) for name, est in setup.estimators.items()
                      if est.spec.swaps}
        self.P = min(setup.n_paths, B)
        self.paths = {"x": np.zeros((K, n, self.P))}
        self.reference_error = None

    def per_unit(self, a: np.ndarray) -> np.ndarray:
        """(..., B) -> (U, ...): sums over the trials of each unit."""
        return np.moveaxis(np.add.reduceat(a, self.offsets, axis=-1), -1, 0)

    def link_contacts(self, step_links: StepLinks) -> dict[str, np.ndarray]:
        """(U, N) contacts of the step per pattern: every round (or exchange), the step's links."""
        lm, topo, sizes = self.setup.links, self.setup.links.topology, self.sizes
        if lm.synchronous:
            return {"rounds": sum(_contacts(topo, mask, self.offsets, sizes) for mask in step_links.rounds),
                    "step": _contacts(topo, step_links.rounds[0], self.offsets, sizes)}
        return {"rounds": _event_contacts(topo, step_links.events, self.offsets, len(sizes)),
                "step": _contacts(topo, step_links.step_mask, self.offsets, sizes)}

    def begin(self, k: int, x_true: np.ndarray) -> None:
        self.reference_error = None
        if self.P:
            self.paths["x"][k] = x_true
        self.x_true = x_true

    def record_token(self, name: str, parts: list, q_node: np.ndarray, k: int) -> None:
        """tr P̄_q of the state a uniformly random node q holds before step k."""
        self.token[name][self.setup.token_times.index(k)] = np.concatenate(
            [sm.trace(r.prior_covariance())[q_node[c], np.arange(c.stop - c.start)] for r, c in zip(parts, self.cuts)])

    def _allocate(self, name: str, width: int) -> dict[str, np.ndarray]:
        U, S, N = len(self.sizes), len(self.steps), self.setup.model.N
        a = {s: np.zeros((U, S, width)) for s in STATS}
        a.update(dis=np.zeros((U, S)), dis2=np.zeros((U, S)), dis_node=np.zeros((U, S, width)),
                 net=np.zeros((U, S)), net2=np.zeros((U, S)), msgs=np.zeros((U, N)), scalars=np.zeros((U, N)))
        self.sums[name] = a
        self.paths[name] = np.zeros((self.setup.n_steps, width, self.setup.model.n, self.P))
        return a

    def add(self, name: str, parts: list, est: np.ndarray, k: int, contacts: dict[str, np.ndarray]) -> None:
        """The statistics of filter `name` after step k: its estimates `est` (W, n, B) are its errors."""
        a = self.sums.get(name) or self._allocate(name, est.shape[0])
        comm = self.comm[name]
        if comm.pattern != "none":
            c = (self.per_unit(np.concatenate([(r.hops > 0) for r in parts], axis=-1).astype(float))
                 if (comm.pattern == "swap" and self.setup.links.synchronous)
                 else contacts["rounds" if comm.pattern in ("rounds", "swap") else "step"]) * comm.messages_per_contact
            a["msgs"] += c
            a["scalars"] += c * comm.scalars_per_message
        if self.P:
            self.paths[name][k] = self.x_true[None] + est[:, :, :self.P]
        if k in self.where:
            self._record(name, a, parts, -est, k)            # x − x̂ in error coordinates (W, n, B)

    def _record(self, name: str, a: dict, parts: list, err: np.ndarray, k: int) -> None:
        i, per_unit = self.where[k], self.per_unit
        if name == self.reference:
            self.reference_error = err
        sq = np.einsum("inb,inb->ib", err, err)
        a["sq"][:, i] = per_unit(sq)
        a["sq2"][:, i] = per_unit(sq * sq)
        net = sq.mean(axis=0)
        a["net"][:, i] = per_unit(net)
        a["net2"][:, i] = per_unit(net * net)
        e_c = self.reference_error
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
        own = [r.nees(err[..., c]) for r, c in zip(parts, self.cuts)]
        own = None if own[0] is None else np.concatenate(own, axis=-1)
        if own is not None:
            a["nees"][:, i] = per_unit(own)
            a["nees2"][:, i] = per_unit(own * own)
        if name in self.setup.exact_cov:
            inv = np.linalg.inv(self.setup.exact_cov[name][k])
            a["xnees"][:, i] = per_unit(np.einsum("inb,inm,imb->ib", err, inv, err))


def _deliveries(ctx: StepContext, lm: LinkModel, B: int) -> None:
    """Which nodes heard a neighbour in the step (per round, or over its exchanges), over how many links."""
    topo = lm.topology
    if lm.synchronous:
        counts = [link_count(topo, mask, B) for mask in ctx.links.rounds]
        ctx.heard = [c > 0 for c in counts]
        ctx.step_heard, ctx.step_count = ctx.heard[0], counts[0]
    else:
        ctx.step_count = link_count(topo, ctx.links.step_mask, B)
        ctx.step_heard = ctx.step_count > 0


def simulate_units(setup: Setup, plant: Draws, links: Draws, noise: Draws, gossip: Draws) -> dict[str, Any]:
    """Simulate the trials of a few RNG units (`plant.sizes`) and return per-unit sums (module doc).

    Statistics are kept at `setup.record_steps` (all steps when empty); message counts at every step."""
    m, lm, K = setup.model, setup.links, setup.n_steps
    sizes = np.array(plant.sizes)
    B = int(sizes.sum())
    N, n = m.N, m.n
    topo = lm.topology
    cuts = [slice(a, min(a + setup.sub_batch, B)) for a in range(0, B, setup.sub_batch)]
    runs: dict[str, list] = {}
    for name, est in setup.estimators.items():     # each built knowing the filters built before it (shares_with)
        runs[name] = [est.build(c.stop - c.start, {p: parts[j] for p, parts in runs.items()})
                      for j, c in enumerate(cuts)]
    swaps = any(est.spec.swaps for est in setup.estimators.values())
    acc = Accumulator(setup, sizes, cuts)
    q_node = gossip.integers(0, N) if swaps else None
    seconds = dict.fromkeys(runs, 0.0)
    # error coordinates (`protocol`): x ≡ 0, y = v, first prediction x0 − x(0), predictions shifted by −w;
    # the true state is kept for the sample trials only (recordings)
    x0_draw = _factor(m.P0) @ plant.standard_normal((n,)).T
    for parts in runs.values():
        for r, c in zip(parts, cuts):
            r.shift(-x0_draw[:, c])
    x_true = m.x0[:, None] + x0_draw[:, :setup.n_paths]
    Lq = _factor(m.Q)
    sigma = lm.noise_std
    for k in range(K):
        y = _measurement_noise(m, plant.standard_normal((N, m.m)))          # H x + v with x ≡ 0
        step_links = lm.draw(links)
        ctx = StepContext(k, y, step_links)
        _deliveries(ctx, lm, B)
        contacts = acc.link_contacts(step_links)
        if sigma:
            if lm.synchronous:
                ctx.noise = [np.moveaxis(noise.standard_normal((N, n)), 0, -1) for _ in range(lm.rounds)]
                ctx.node_noise = ctx.noise[0]
            else:
                ctx.event_noise = np.moveaxis(noise.standard_normal((lm.max_events, 2, n)), 0, -1)
                ctx.node_noise = np.moveaxis(noise.standard_normal((N, n)), 0, -1)
        if swaps and lm.synchronous and lm.kind != "matchings":
            ctx.gossip_priority = gossip.random((topo.E,)).T
        if swaps:
            ctx.swap = step_permutation(lm, step_links, B, ctx.gossip_priority)
        acc.begin(k, x_true)
        ctxs = [slice_context(ctx, c) for c in cuts] if len(cuts) > 1 else [ctx]
        for name, parts in runs.items():
            if name in acc.token and k in setup.token_times:
                acc.record_token(name, parts, q_node, k)
            t0 = time.process_time()
            est = np.concatenate([r.step(cx) for r, cx in zip(parts, ctxs)], axis=-1)
            seconds[name] += time.process_time() - t0
            acc.add(name, parts, est, k, contacts)
        w = Lq @ plant.standard_normal((n,)).T
        for parts in runs.values():
            for r, c in zip(parts, cuts):
                r.shift(-w[:, c])
        x_true = m.F @ x_true + w[:, :acc.P]
    return {"sums": acc.sums, "token": acc.token, "paths": acc.paths, "sizes": sizes, "steps": np.array(acc.steps),
            "seconds": seconds}


def _factor(Q: np.ndarray) -> np.ndarray:
    """A factor L with L Lᵀ = Q for a positive semidefinite Q (eigenvalues clipped at 0)."""
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def _measurement_noise(m: SensorNetworkModel, z: np.ndarray) -> np.ndarray:
    """v (N, m, B) from standard normals z (B, N, m): v_i = R_chol[i] z_i."""
    return np.einsum("iab,cib->iac", m.R_chol, z)
