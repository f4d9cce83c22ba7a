"""Every network filter on the same trials: one plant, one graph, one link model, common random numbers.

`simulate` runs any number of trials, chunk by chunk of RNG units (as many per chunk as the memory budget
allows) and, with several workers, with the estimators split over forked processes; every chunk and every
worker draws the same random numbers for a trial, so the results are the same bits whatever the budget and
the workers.

`simulate_units` runs B trials (a few RNG units of trials, trials on the last axis) of the plant and of
every estimator it is given (`protocol.DesignedEstimator`s: whatever the registry holds) in lock step: at
each step k the sensors measure x(k), and every filter steps on the same measurements, the same link draws
and the same communication noise (`protocol.BatchedFilter`). The random numbers come from separate streams
(plant, links, noise, gossip), so adding or removing an estimator does not change what the others see.
The filters run in error coordinates (`protocol`): their estimates are their errors.

An `Accumulator` beside the filters' steps keeps what the claims and tables read, as per-unit sums over
trials, each (U, S, W) at the S recorded steps unless stated (W = the filter's number of estimates):
``sq`` Σ‖e_i‖², ``sq2`` Σ‖e_i‖⁴, ``dist`` Σ‖x̂_i − x̂_c‖² and ``dist2`` (x̂_c the reference estimator's),
``cross`` Σ (x − x̂_c)ᵀ(x̂_c − x̂_i) and ``cross2`` (the orthogonality of the reference error to every other
estimate), ``gap`` Σ (‖e_i‖² − ‖e_c‖²) and ``gap2`` (the paired excess over the reference), ``nees``
Σ e_iᵀP_i⁻¹e_i with the filter's own covariance and ``nees2``, ``xnees`` the same with a given exact covariance,
``dis`` and ``dis2`` (U, S) the per-trial disagreement (1/N) Σ_i ‖x̂_i − mean_j x̂_j‖², ``dis_node`` (U, S, W)
its terms ‖x̂_i − mean_j x̂_j‖² per node, ``net`` and ``net2`` (U, S) the per-trial node average of ‖e_i‖²,
``msgs`` and ``scalars`` (U, N) messages and real numbers sent over the whole run (every step, counted from the
links and the filter's `Communication`); ``token`` (times, B): tr P̄_q at a uniformly random node q of the
filters that swap states; ``paths``: sample trials kept whole.

A plug-in filter (`dse.plugin`) that does something the protocol forbids raises a `PluginFault`: it is
dropped from the simulation at once (and from every later chunk), its sums are discarded, and ``faults``
says what it did; the other filters' numbers are the same bits as without it.
"""
from __future__ import annotations

import dataclasses
import functools
import time
from dataclasses import dataclass, field
from typing import Any, Iterator, Protocol

import numpy as np

from dse.simulate.seeding import block_seeds, stream_seed
from dse.simulate.units import RNG_UNIT, UnitStreams, run_jobs, run_units, units_per_chunk

from . import small_matrix as sm
from .link_models import LinkModel, StepLinks, step_permutation
from .network_mixing import link_count
from .network_step import StepContext, slice_context
from .protocol import DesignedEstimator
from .sensor_network import SensorNetworkModel

__all__ = ["Setup", "simulate", "simulate_units", "unit_chunks", "worker_groups", "Stats", "stats", "nees_band",
           "ks_test", "effective_sample_size", "STATS", "PER_TRIAL_SUMS", "record_steps"]

#: the key of the true state's sample paths beside the estimators' (a name no estimator can take: a plug-in filter
#: named "x" used to overwrite it)
TRUE_STATE = "@x"
STATS = ("sq", "sq2", "dist", "dist2", "cross", "cross2", "gap", "gap2", "nees", "nees2", "xnees")
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
        self.paths = {TRUE_STATE: np.zeros((K, n, self.P))}
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
            self.paths[TRUE_STATE][k] = x_true
        self.x_true = x_true

    def record_token(self, name: str, parts: list, q_node: np.ndarray, k: int) -> None:
        """tr P̄_q of the state a uniformly random node q holds before step k."""
        self.token[name][self.setup.token_times.index(k)] = np.concatenate(
            [sm.trace(r.prior_covariance())[q_node[c], np.arange(c.stop - c.start)] for r, c in zip(parts, self.cuts)])

    def drop(self, name: str) -> None:
        """Forget a filter that failed (its sums and sample paths)."""
        self.sums.pop(name, None)
        self.paths.pop(name, None)
        self.token.pop(name, None)

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
        if comm.pattern == "sent":                          # counted by the harness from what it sent
            a["msgs"] += self.per_unit(np.concatenate([r.sent_messages for r in parts], axis=-1))
            a["scalars"] += self.per_unit(np.concatenate([r.sent_scalars for r in parts], axis=-1))
        elif comm.pattern != "none":
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
            gap = sq - np.einsum("nb,nb->b", e_c[0], e_c[0])       # ‖e_i‖² − ‖e_c‖², paired by trial
            a["gap"][:, i] = per_unit(gap)
            a["gap2"][:, i] = per_unit(gap * gap)
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
            inv = _inverse_or_nan(self.setup.exact_cov[name][k])
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


def _build(setup: Setup, cuts: list[slice], faults: dict[str, str]) -> dict[str, list]:
    """Every filter for every sub-batch, each built knowing the filters built before it (shares_with); a
    plug-in filter that fails when built is left out (`faults`)."""
    from dse.plugin.harness import PluginFault

    runs: dict[str, list] = {}
    for name, est in setup.estimators.items():
        try:
            runs[name] = [est.build(c.stop - c.start, {p: parts[j] for p, parts in runs.items()})
                          for j, c in enumerate(cuts)]
        except PluginFault as fault:
            faults[name] = str(fault)
    return runs


def simulate_units(setup: Setup, plant: Draws, links: Draws, noise: Draws, gossip: Draws) -> dict[str, Any]:
    """Simulate the trials of a few RNG units (`plant.sizes`) and return per-unit sums (module doc).

    Statistics are kept at `setup.record_steps` (all steps when empty); message counts at every step."""
    from dse.plugin.harness import PluginFault

    m, lm, K = setup.model, setup.links, setup.n_steps
    sizes = np.array(plant.sizes)
    B = int(sizes.sum())
    N, n = m.N, m.n
    topo = lm.topology
    cuts = [slice(a, min(a + setup.sub_batch, B)) for a in range(0, B, setup.sub_batch)]
    faults: dict[str, str] = {}
    runs = _build(setup, cuts, faults)
    swaps = any(est.spec.swaps for est in setup.estimators.values())
    tracked = [name for name in runs if setup.estimators[name].spec.true_coordinates]
    acc = Accumulator(setup, sizes, cuts)
    q_node = gossip.integers(0, N) if swaps else None
    seconds = dict.fromkeys(runs, 0.0)
    # error coordinates (`protocol`): x ≡ 0, y = v, first prediction x0 − x(0), predictions shifted by −w;
    # the true state is kept for the sample trials (recordings), and for every trial when a filter runs on
    # the true measurements
    x0_draw = _factor(m.P0) @ plant.standard_normal((n,)).T             # x(0) − x0
    for name, parts in list(runs.items()):
        try:
            for r, c in zip(parts, cuts):
                _start_at_error(r, m.x0, x0_draw[:, c])
        except PluginFault as fault:
            faults[name] = str(fault)
            del runs[name]
    kept = B if tracked else setup.n_paths
    x_true = m.x0[:, None] + x0_draw[:, :kept]
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
        acc.begin(k, x_true[:, :setup.n_paths])
        ctxs = [slice_context(ctx, c) for c in cuts] if len(cuts) > 1 else [ctx]
        for name in list(runs):
            parts = runs[name]
            if name in tracked:
                for r, c in zip(parts, cuts):
                    r.track(x_true[:, c])
            if name in acc.token and k in setup.token_times:
                acc.record_token(name, parts, q_node, k)
            t0 = time.process_time()
            try:
                est = np.concatenate([r.step(cx) for r, cx in zip(parts, ctxs)], axis=-1)
                seconds[name] += time.process_time() - t0
                acc.add(name, parts, est, k, contacts)
            except PluginFault as fault:
                faults[name] = str(fault)
                del runs[name]
                acc.drop(name)
        w = Lq @ plant.standard_normal((n,)).T
        for name, parts in runs.items():
            for r, c in zip(parts, cuts):
                try:
                    r.shift(-w[:, c])
                except PluginFault as fault:
                    faults[name] = str(fault)
        for name in faults:
            runs.pop(name, None)
            acc.drop(name)
        x_true = m.F @ x_true + w[:, :kept]
    return {"sums": acc.sums, "token": acc.token, "paths": acc.paths, "sizes": sizes, "steps": np.array(acc.steps),
            "seconds": {e: t for e, t in seconds.items() if e not in faults}, "faults": faults}


STREAMS = ("plant", "links", "noise", "gossip")


def unit_chunks(seed: int, label: str, streams: tuple[str, ...], trials: int, bytes_per_trial: float,
                budget_bytes: float) -> Iterator[tuple[UnitStreams, ...]]:
    """The `streams` (named under `label`) of `trials` trials in RNG units, as many units per chunk as
    `budget_bytes` allows: a trial's draws depend only on the seed and its index."""
    n_units = -(-trials // RNG_UNIT)
    sizes = [min(RNG_UNIT, trials - u * RNG_UNIT) for u in range(n_units)]
    seeds = {s: block_seeds(stream_seed(seed, label, s), n_units) for s in streams}
    per_chunk = units_per_chunk(bytes_per_trial, budget_bytes)
    for start in range(0, n_units, per_chunk):
        stop = min(start + per_chunk, n_units)
        yield tuple(UnitStreams(seeds[s][start:stop], sizes[start:stop]) for s in streams)


def bytes_per_trial(setup: Setup) -> float:
    """Memory of one trial in a chunk: estimates, covariances per node where they depend on the trial, and
    the temporaries of one step (about eight arrays of the largest size)."""
    N, n, lm = setup.model.N, setup.model.n, setup.links
    per = sum(N * n + (3 * N * n * n if est.trialwise_covariance() else 0) for est in setup.estimators.values())
    events = lm.max_events * 2 * n if not lm.synchronous else 0
    return 8.0 * (8 * per + N * n * 4 + lm.topology.E * 4 + events)


def simulate_chunk(setup: Setup, seed: int, label: str, plant: UnitStreams,
                   skip: frozenset[str] = frozenset()) -> list[dict[str, Any]]:
    """`run_units`' chunk function: every estimator of `setup` (but those in `skip`) on the units of `plant`, the
    plant stream of `label`; the link, noise and gossip streams of the same units are derived here from the seed,
    so the result is a function of the units alone (portable: it may run on a Dask worker). One partial per
    unit, in unit order: its sums ``sums`` and token draws ``token``; the first partial also carries what the chunk
    says as a whole (``paths`` when the chunk starts at unit 0, CPU ``seconds`` per estimator, ``faults``,
    ``steps``, the chunk's CPU ``cpu_s``)."""
    cpu0 = time.process_time()
    first, stop = plant.first_unit, plant.first_unit + len(plant.sizes)
    others = [UnitStreams(block_seeds(stream_seed(seed, label, s), stop, first), plant.sizes, first_unit=first)
              for s in STREAMS[1:]]
    alive = dataclasses.replace(setup, estimators={e: d for e, d in setup.estimators.items() if e not in skip})
    out = simulate_units(alive, plant, *others)
    edges = np.cumsum([0, *plant.sizes])
    parts = [{"sums": {e: {k: v[u] for k, v in acc.items()} for e, acc in out["sums"].items()},
              "token": {e: v[:, edges[u]:edges[u + 1]] for e, v in out["token"].items()}} for u in range(len(edges) - 1)]
    parts[0].update(paths=out["paths"] if first == 0 else None, seconds=out["seconds"], faults=out["faults"],
                    steps=out["steps"], cpu_s=time.process_time() - cpu0)
    return parts


class _Gathered:
    """The per-unit partials of `simulate_chunk`, gathered in unit order (`add`) and summed over the units at the
    end (`result`: the sums of every unit stacked and reduced along the unit axis at once, which numpy does unit
    after unit, so the numbers do not depend on how the units were chunked or where they ran)."""

    def __init__(self):
        self.sums: dict[str, dict[str, list]] = {}
        self.token: dict[str, list] = {}
        self.paths: dict[str, np.ndarray] = {}
        self.steps, self.cpu_s = None, 0.0
        self.seconds: dict[str, float] = {}
        #: estimator -> what it did wrong, the first fault in unit order
        self.faults: dict[str, str] = {}

    def add(self, part: dict[str, Any]) -> "_Gathered":
        """The next unit's partial (`simulate_chunk`), in unit order."""
        for est, sums in part["sums"].items():
            for name, arr in sums.items():
                self.sums.setdefault(est, {}).setdefault(name, []).append(arr)
        for est, arr in part["token"].items():
            self.token.setdefault(est, []).append(arr)
        if "steps" in part:                         # the first unit of a chunk: what the chunk says as a whole
            for est, what in part["faults"].items():
                self.faults.setdefault(est, what)
            for est, t in part["seconds"].items():
                self.seconds[est] = self.seconds.get(est, 0.0) + t
            if part["paths"] is not None:
                self.paths = part["paths"]
            self.steps, self.cpu_s = part["steps"], self.cpu_s + part["cpu_s"]
        return self

    def result(self) -> dict[str, Any]:
        ok = [e for e in self.sums if e not in self.faults]
        return {"mc": {e: {name: np.stack(parts).sum(axis=0) for name, parts in self.sums[e].items()} for e in ok},
                "token": {e: np.concatenate(v, axis=1) for e, v in self.token.items() if e not in self.faults},
                "paths": {e: v for e, v in self.paths.items() if e not in self.faults}, "steps": self.steps,
                "seconds": {e: t for e, t in self.seconds.items() if e not in self.faults}, "faults": self.faults,
                "cpu_s": self.cpu_s}


def simulate_group(setup: Setup, seed: int, trials: int, budget_bytes: float, label: str,
                   portable: bool = False) -> dict[str, Any]:
    """Every estimator of `setup` on `trials` trials, chunk by chunk (`run_units`), folded in unit order.

    `portable=True` hands the chunks to the run's unit executor (this process or a Dask cluster; finished units
    are stored while the stage runs); each chunk then runs every estimator, and a plug-in that failed in one is
    dropped at the end. Otherwise the chunks run here, and a plug-in that failed is left out of the next ones."""
    gathered = _Gathered()
    if portable:
        chunk = functools.partial(simulate_chunk, setup, seed, label)
    else:
        def chunk(plant: UnitStreams) -> list[dict[str, Any]]:
            return simulate_chunk(setup, seed, label, plant, frozenset(gathered.faults))
    run_units(chunk, lambda _, part: gathered.add(part), trials, stream_seed(seed, label, STREAMS[0]),
              bytes_per_trial=bytes_per_trial(setup), budget_bytes=budget_bytes, portable=portable)
    return gathered.result()


def worker_groups(estimators: dict[str, DesignedEstimator], workers: int) -> list[list[str]]:
    """The estimators split into at most `workers` groups of similar cost (`cost_weight`, heaviest first),
    each with the reference (the distances are to its estimates); an estimator that reuses another's
    recursion (`shares_with`) stays with it."""
    head = [name for name, est in estimators.items() if est.spec.reference]
    names = [name for name in estimators if name not in head]
    if workers <= 1 or len(names) < 2:
        return [list(estimators)]
    units: list[list[str]] = []
    for name in names:
        home = next((u for u in units if estimators[name].spec.shares_with in u), None)
        home.append(name) if home is not None else units.append([name])

    def weight(unit):
        return sum(estimators[e].spec.cost_weight for e in unit)

    units.sort(key=lambda u: -weight(u))
    groups: list[list[str]] = [[] for _ in range(min(workers, len(units)))]
    load = [0.0] * len(groups)
    for u in units:
        g = int(np.argmin(load))
        groups[g] += u
        load[g] += weight(u)
    return [head + [e for e in estimators if e in g] for g in groups if g]


def simulate(setup: Setup, seed: int, trials: int, budget_bytes: float, workers: int = 1,
             label: str = "compare") -> dict[str, Any]:
    """Every estimator on `trials` trials (module doc): ``mc`` the folded sums per estimator, ``token``,
    ``paths``, the recorded ``steps``, CPU ``seconds`` per estimator, ``faults`` (name -> what a plug-in
    filter did wrong) and ``group_cpu_s`` per worker. The workers are forked: the estimators' declarations are
    inherited, not pickled. With one worker, the chunks are portable (`simulate_group`): they go to the run's unit
    executor, a Dask cluster with ``--scheduler local``."""
    groups = worker_groups(setup.estimators, workers)
    jobs = [(sum(setup.estimators[e].spec.cost_weight for e in g), functools.partial(
        simulate_group, dataclasses.replace(setup, estimators={e: setup.estimators[e] for e in g}), seed, trials,
        budget_bytes, label, portable=len(groups) == 1)) for g in groups]
    parts = run_jobs(jobs, workers=len(groups))
    out = {"mc": {}, "token": {}, "paths": {}, "seconds": {}, "faults": {}, "steps": parts[0]["steps"],
           "group_cpu_s": [p["cpu_s"] for p in parts]}
    for p in parts:
        for what in ("mc", "token", "paths", "seconds", "faults"):
            out[what].update({e: v for e, v in p[what].items() if e not in out[what]})
    out["mc"] = {e: out["mc"][e] for e in setup.estimators if e in out["mc"]}
    return out


# -- the estimates the sums give ------------------------------------------------------------------------------

@dataclass
class Stats:
    """Means over trials and their standard errors from the folded sums, (S, W) at the recorded steps."""

    mse: np.ndarray
    mse_se: np.ndarray
    excess: np.ndarray | None          # mean ‖x̂_i − x̂_c‖² (None for the reference itself)
    excess_se: np.ndarray | None
    cross: np.ndarray | None
    cross_se: np.ndarray | None
    nees: np.ndarray | None            # None for a filter without its own covariance
    nees_se: np.ndarray | None
    disagreement: np.ndarray           # (S,)
    disagreement_se: np.ndarray
    disagreement_node: np.ndarray      # (S, W) mean of ‖x̂_i − mean_j x̂_j‖²
    network: np.ndarray                # (S,) node average of the MSE
    network_se: np.ndarray
    messages: np.ndarray               # (N,) per node and step
    scalars: np.ndarray


def mean_and_se(s1, s2, B: int) -> tuple[np.ndarray, np.ndarray]:
    """The mean over B trials and its standard error (sample standard deviation / √B) from Σ a and Σ a²."""
    with np.errstate(invalid="ignore", over="ignore"):      # a diverging filter's sums may be infinite
        mean = s1 / B
        var = np.maximum(s2 / B - mean * mean, 0.0)
        return mean, np.sqrt(var * B / max(B - 1, 1) / B)


def stats(sums: dict[str, np.ndarray], trials: int, n_steps: int, reference: bool) -> Stats:
    """The estimates of one estimator's folded sums over `trials` trials of `n_steps` steps."""
    s, B = sums, trials
    mse, mse_se = mean_and_se(s["sq"], s["sq2"], B)
    excess = excess_se = cross = cross_se = None
    if not reference:
        excess, excess_se = mean_and_se(s["dist"], s["dist2"], B)
        cross, cross_se = mean_and_se(s["cross"], s["cross2"], B)
    nees = nees_se = None
    if np.any(s["nees"] != 0):
        nees, nees_se = mean_and_se(s["nees"], s["nees2"], B)
    dis, dis_se = mean_and_se(s["dis"], s["dis2"], B)
    net, net_se = mean_and_se(s["net"], s["net2"], B)
    return Stats(mse, mse_se, excess, excess_se, cross, cross_se, nees, nees_se, dis, dis_se, s["dis_node"] / B,
                 net, net_se, s["msgs"] / (B * n_steps), s["scalars"] / (B * n_steps))


def effective_sample_size(s1, s2) -> np.ndarray:
    """(Σ a)² / Σ a² of nonnegative per-trial values a (the trials' count when they are equal)."""
    s1, s2 = np.asarray(s1, float), np.asarray(s2, float)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(s2 > 0, s1 * s1 / np.where(s2 > 0, s2, 1.0), 0.0)


#: the confidence of the NEES band of a consistent filter
NEES_BAND = 0.99


def nees_band(trials: int, n: int, level: float = NEES_BAND) -> tuple[float, float]:
    """If a filter's covariance is the covariance of its Gaussian error, the sum of B independent NEES values
    is χ²(B n): the mean NEES lies in [χ²_{Bn}(α/2), χ²_{Bn}(1 − α/2)] / B with probability 1 − α = level."""
    from scipy.stats import chi2

    a = (1 - level) / 2
    return float(chi2.ppf(a, trials * n) / trials), float(chi2.ppf(1 - a, trials * n) / trials)


def ks_test(x, y):
    """Two-sample Kolmogorov-Smirnov test: scipy's exact p-value where it can compute it, else the
    asymptotic one (accurate at the sample sizes here, and conservative where the laws have atoms)."""
    import warnings

    from scipy.stats import ks_2samp

    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        return ks_2samp(x, y, method="exact" if max(len(x), len(y)) <= 2000 else "asymp")


def _inverse_or_nan(covs: np.ndarray) -> np.ndarray:
    """The inverses of a stack of covariances; NaN for one that is not finite or singular (a diverging
    filter's exact covariance overflows): its NEES is then not finite, which the claims report."""
    if np.isfinite(covs).all():
        try:
            return np.linalg.inv(covs)
        except np.linalg.LinAlgError:
            pass
    out = np.full_like(covs, np.nan)
    for i in np.flatnonzero(np.isfinite(covs).all(axis=(-2, -1))):
        try:
            out[i] = np.linalg.inv(covs[i])
        except np.linalg.LinAlgError:
            pass
    return out


def _start_at_error(run, x0: np.ndarray, x0_draw: np.ndarray) -> None:
    """Move a filter that starts at its prior mean x0 to the first prediction of error coordinates,
    x0 − x(0) = −x0_draw: first by −x0 (x0 − x0 is exactly 0), then by −x0_draw, so that the error carries no
    rounding of x0 + x0_draw."""
    if np.any(x0 != 0):
        run.shift(np.broadcast_to(-x0[:, None], x0_draw.shape))
    run.shift(-x0_draw)


def _factor(Q: np.ndarray) -> np.ndarray:
    """A factor L with L Lᵀ = Q for a positive semidefinite Q (eigenvalues clipped at 0)."""
    lam, V = np.linalg.eigh(0.5 * (Q + Q.T))
    return V * np.sqrt(np.maximum(lam, 0.0))


def _measurement_noise(m: SensorNetworkModel, z: np.ndarray) -> np.ndarray:
    """v (N, m, B) from standard normals z (B, N, m): v_i = R_chol[i] z_i."""
    return np.einsum("iab,cib->iac", m.R_chol, z)
