"""The harness between a researcher's `NetworkFilter` and the arena's simulation (`network_comparison`).

`PluginRun` is the arena's side of one plug-in filter on a batch of trials (a `protocol.BatchedFilter`):
at each step it gives the filter read-only measurements and a `StepNetwork` whose `exchange` delivers
messages over the links the step drew (the same link draws and communication noise as every built-in:
common random numbers), counts what was sent, and checks what comes back. Whatever the filter does wrong
becomes one `PluginFault` naming the filter, the step and what it did; the simulation then drops that
filter and the others go on untouched.

Coordinates. An `equivariant` filter runs in error coordinates, like the built-ins: the state is 0, the
measurements are the noises, and its estimates are its errors (`protocol` module doc). Any other filter
runs on the true measurements y = H x + v (the harness keeps x for every trial) and its error is x̂ − x.
"""
from __future__ import annotations

import time

import numpy as np

from dse.estimators.protocol import BatchedFilter

from .interface import Inbox, Messages, Problem

#: a NaN is the filter's fault unless its previous estimates already overflowed past this size
DIVERGED = 1e150


class PluginFault(RuntimeError):
    """A plug-in filter did something the protocol forbids; the message is one line naming it."""

    def __init__(self, name: str, what: str):
        self.name, self.what = name, what
        super().__init__(f"estimator '{name}' {what}")

    def __reduce__(self):       # raised in a worker process, it must survive pickling
        return (PluginFault, (self.name, self.what))


def read_only(a: np.ndarray) -> np.ndarray:
    """A view of `a` that raises on assignment (what a filter is given may be shared with the others). It is
    built over a read-only buffer, so that setting its `writeable` flag back to True raises too (a plain view
    of a writeable array may be made writeable again, and then writes into the other filters' inputs)."""
    return np.asarray(memoryview(np.asarray(a)).toreadonly())


class Wiring:
    """The graph as the harness delivers over it: `neighbours` and `edge_of` (N, D), −1 on padding."""

    def __init__(self, topology):
        N, edges = topology.n_nodes, topology.edges
        D = max(int(topology.degrees.max(initial=0)), 1)
        self.neighbours = np.full((N, D), -1, dtype=np.int64)
        self.edge_of = np.full((N, D), -1, dtype=np.int64)
        fill = np.zeros(N, dtype=np.int64)
        for e, (a, b) in enumerate(edges):
            for i, j in ((a, b), (b, a)):
                self.neighbours[i, fill[i]], self.edge_of[i, fill[i]] = j, e
                fill[i] += 1
        self.valid = self.neighbours >= 0
        self.gather = np.where(self.valid, self.neighbours, 0)
        self.edges = edges


class StepNetwork:
    """`interface.Network` for one step of one batch: delivers, counts and polices the exchanges."""

    def __init__(self, run: "PluginRun", ctx):
        self.run, self.ctx, self.k = run, ctx, ctx.k
        self.calls = 0
        msg, links = run.messages, run.links
        if msg is None:
            self.exchanges = 0
        elif msg.per == "step" or links.synchronous:
            self.exchanges = msg.exchanges * (1 if msg.per == "step" else links.rounds)
        else:
            self.exchanges = msg.exchanges * int((ctx.links.events >= 0).any(axis=1).sum())

    def exchange(self, payload) -> Inbox:
        run, ctx = self.run, self.ctx
        if self.calls >= self.exchanges:
            raise PluginFault(run.name, f"sent more than it declared at step {self.k}: exchange number "
                                        f"{self.calls + 1} of a step that allows {self.exchanges} "
                                        f"({_declared(run.messages)})")
        payload = np.asarray(payload)
        N, B = run.problem.N, run.trials
        if payload.ndim != 3 or payload.shape[0] != N or payload.shape[2] != B:
            raise PluginFault(run.name, f"sent a payload of shape {payload.shape} at step {self.k}; expected "
                                        f"(N, s, B) = ({N}, s, {B})")
        if payload.shape[1] > run.messages.scalars:
            raise PluginFault(run.name, f"sent more than it declared at step {self.k}: messages of "
                                        f"{payload.shape[1]} numbers ({_declared(run.messages)})")
        r = self.calls // run.messages.exchanges          # the round (or Poisson exchange) it goes out in
        self.calls += 1
        delivered, noise = self._links(r, B)
        values = payload[run.wiring.gather] * delivered[:, :, None, :]
        count = delivered.sum(axis=1)
        run.sent_messages += count
        run.sent_scalars += count * payload.shape[1]
        return Inbox(read_only(values), read_only(delivered), read_only(count > 0), read_only(noise))

    def _links(self, r: int, B: int) -> tuple[np.ndarray, np.ndarray]:
        """(N, D, B) which messages arrive in round (or Poisson exchange) r, and (N, n, B) the noise of the
        fused estimates."""
        run, ctx, w = self.run, self.ctx, self.run.wiring
        sigma, N, n = run.links.noise_std, run.problem.N, run.problem.n
        if run.messages.per == "step" or run.links.synchronous:
            mask = ctx.links.step_mask if run.messages.per == "step" and not run.links.synchronous else (
                ctx.links.rounds[0] if run.messages.per == "step" else ctx.links.rounds[r])
            delivered = (w.valid[:, :, None] & (True if mask is None else mask[w.edge_of]))
            delivered = np.broadcast_to(delivered, w.valid.shape + (B,))
            z = (ctx.node_noise if run.messages.per == "step" else (ctx.noise[r] if ctx.noise else None))
            heard = delivered.any(axis=1)
            noise = sigma * z * heard[:, None, :] if (sigma and z is not None) else np.zeros((N, n, B))
            return delivered, noise
        ids = ctx.links.events[r]                                                # (B,), −1: none
        delivered = w.valid[:, :, None] & (w.edge_of[:, :, None] == ids[None, None, :])
        noise = np.zeros((N, n, B))
        if sigma:
            live = np.flatnonzero(ids >= 0)
            a, b = w.edges[ids[live], 0], w.edges[ids[live], 1]
            noise[a, :, live] = sigma * ctx.event_noise[r, 0][:, live].T
            noise[b, :, live] = sigma * ctx.event_noise[r, 1][:, live].T
        return delivered, noise


def _magnitude(est: np.ndarray) -> float:
    """max |x| over the estimates, or below DIVERGED an upper bound of it (all `_checked` asks), NaN when one of
    them is NaN: in one pass without a temporary (√Σ x², NaN exactly when an entry is, since inf² = inf) unless that
    bound reaches DIVERGED."""
    if est.flags.c_contiguous:
        flat = est.reshape(-1)
        with np.errstate(over="ignore"):
            bound = float(np.sqrt(flat @ flat))
        if not bound >= DIVERGED:                    # below it, or NaN
            return bound                             # (a bound of max |x| is enough below DIVERGED)
    lo, hi = float(est.min()), float(est.max())
    return float("nan") if np.isnan(lo) or np.isnan(hi) else max(-lo, hi)


def _declared(messages: Messages | None) -> str:
    if messages is None:
        return "it declared that it sends nothing"
    return (f"declared: messages of {messages.scalars} number{'s' if messages.scalars > 1 else ''}, "
            f"{messages.exchanges} per {messages.per}")


class LastInverse:
    """P⁻¹ of the last covariance P (N, n, n) it was given, kept while P's numbers stay the same (compared, not
    trusted): the sub-batches of a step, and the steps of a filter whose covariance has converged, invert once."""

    def __init__(self):
        self.P: np.ndarray | None = None
        self.inv: np.ndarray | None = None

    def __call__(self, P: np.ndarray) -> np.ndarray:
        if self.P is None or self.P.shape != P.shape or not np.array_equal(self.P, P):
            inv = np.linalg.inv(P)
            self.P, self.inv = P.copy(), inv
        return self.inv


class PluginRun(BatchedFilter):
    """B trials of a plug-in filter, seen by the simulation as a built-in (module doc). `time_limit`: CPU
    seconds the filter may take over the whole run (`total_trials` trials); it is stopped as soon as its
    pace projects past it."""

    def __init__(self, name: str, cls, problem: Problem, params, links, messages: Messages | None, trials: int,
                 total_trials: int, time_limit: float, inverse: "LastInverse | None" = None):
        self.name, self.problem, self.links, self.messages, self.trials = name, problem, links, messages, trials
        self.error_coordinates = bool(cls.equivariant)
        self.wiring = Wiring(links.topology)
        self.total_trials, self.time_limit = max(total_trials, trials), time_limit
        self.cpu, self.steps_done, self.scale = 0.0, 0, DIVERGED
        self.sent_messages = np.zeros((problem.N, trials))
        self.sent_scalars = np.zeros((problem.N, trials))
        self.x = None                               # the true state (true coordinates only)
        self.inverse = inverse or LastInverse()
        self.inner = self._call("failed when constructed", cls, problem, params, trials)

    def _call(self, doing: str, fn, *args):
        start = time.process_time()
        try:
            return fn(*args)
        except PluginFault:
            raise
        except Exception as exc:                    # noqa: BLE001 (any error of the filter's is its fault)
            what = ("wrote into its inputs" if isinstance(exc, ValueError) and _is_write_refusal(exc)
                    else f"raised {type(exc).__name__}")
            raise PluginFault(self.name, f"{doing}: {what}: {_one_line(exc)}") from None
        finally:
            self.cpu += time.process_time() - start

    def step(self, ctx) -> np.ndarray:
        k, p = ctx.k, self.problem
        if self.messages is not None:               # a filter that sends nothing cannot exchange: its counts stay 0
            self.sent_messages = np.zeros((p.N, self.trials))
            self.sent_scalars = np.zeros((p.N, self.trials))
        y = ctx.y if self.error_coordinates else ctx.y + np.einsum("imn,nb->imb", p.H, self.x)
        network = StepNetwork(self, ctx)
        est = self._call(f"failed at step {k}", self.inner.step, k, read_only(y), network)
        est = self._checked(np.asarray(est) if est is not None else est, k)
        self.steps_done += 1
        self._check_pace(k)
        return est if self.error_coordinates else est - self.x

    def _checked(self, est, k: int) -> np.ndarray:
        p = self.problem
        want = (p.N, p.n, self.trials)
        if not isinstance(est, np.ndarray) or est.shape != want:
            got = f"shape {est.shape}" if isinstance(est, np.ndarray) else type(est).__name__
            raise PluginFault(self.name, f"returned {got} at step {k}; expected (N, n, B) = {want}")
        if not np.issubdtype(est.dtype, np.floating):
            raise PluginFault(self.name, f"returned {est.dtype} estimates at step {k}; expected floats")
        est = est.astype(float, copy=False)     # not copied: the simulation concatenates the batches at once
        scale = _magnitude(est)
        if np.isnan(scale):
            if self.scale < DIVERGED:
                raise PluginFault(self.name, f"returned NaN at step {k} (its estimates were finite before)")
            with np.errstate(invalid="ignore"):      # once diverged it stays so (an all-NaN step has no size)
                scale = max(self.scale, float(np.nanmax(np.abs(est), initial=0.0)))
        self.scale = scale
        return est

    def _check_pace(self, k: int) -> None:
        projected = self.cpu / self.steps_done * self.problem.steps * self.total_trials / self.trials
        if self.steps_done >= 2 and projected > self.time_limit:
            raise PluginFault(self.name, f"is too slow: {self.cpu / self.steps_done * 1e3:.3g} ms of CPU per step "
                                         f"for {self.trials} trials projects to {projected:.3g} s over the run, "
                                         f"beyond its time limit of {self.time_limit:.3g} s (stopped at step {k})")

    def shift(self, delta: np.ndarray) -> None:
        if self.error_coordinates:
            self._call("failed in shift", self.inner.shift, read_only(delta))

    def track(self, x: np.ndarray) -> None:
        """The true state of every trial of the batch at the coming step (true coordinates)."""
        self.x = x

    def nees(self, err: np.ndarray) -> np.ndarray | None:
        P = self._call("failed in covariance()", self.inner.covariance)
        if P is None:
            return None
        P = np.asarray(P, float)
        p = self.problem
        if P.shape not in ((p.N, p.n, p.n), (p.N, p.n, p.n, self.trials)):
            raise PluginFault(self.name, f"covariance() returned shape {P.shape}; expected (N, n, n) or "
                                         f"(N, n, n, B) = ({p.N}, {p.n}, {p.n}, {self.trials})")
        try:
            if P.ndim == 3:                         # shared by the trials: the built-ins' arithmetic (local)
                return np.einsum("inb,inm,imb->ib", err, self.inverse(P), err)
            sol = np.linalg.solve(np.moveaxis(P, -1, 1), np.moveaxis(err, -1, 1)[..., None])[..., 0]   # (N, B, n)
        except np.linalg.LinAlgError:
            raise PluginFault(self.name, "returned a singular covariance()") from None
        return np.einsum("inb,ibn->ib", err, sol)


def _is_write_refusal(exc: ValueError) -> bool:
    """Whether numpy refused a write into a read-only input (an assignment, or making it writeable)."""
    text = str(exc)
    return "read-only" in text or "WRITEABLE" in text


def _one_line(exc: BaseException) -> str:
    text = " ".join(str(exc).split())
    return text[:300] + ("…" if len(text) > 300 else "")
