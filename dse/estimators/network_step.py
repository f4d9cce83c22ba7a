"""What every network filter sees in one time step, drawn once and shared (common random numbers).

Layout: node axis first, trials last. Estimates are (N, n, B); measurements (N, m, B);
communication noise (N, n, B) per synchronous round (standard normal, scaled by σ_c by the
filter that uses it) or (C, 2, n, B) for the C Poisson exchanges of the step (one draw per
endpoint).

Communication noise, one convention for every filter (Savas, Srivastava & Leonard 2017, (6)):
when a node fuses what it received in a round (it heard at least one neighbour), its fused
state estimate is corrupted by an independent N(0, σ_c² I_n) vector. Matrices (covariances,
information matrices) and measurements travel without noise.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from .link_models import StepLinks

__all__ = ["StepContext", "slice_context", "innovation", "apply_gain", "predict"]


@dataclass
class StepContext:
    k: int
    y: np.ndarray                       # (N, m, B)
    links: StepLinks
    heard: list = field(default_factory=list)          # per synchronous round: (N, B) bool
    step_heard: np.ndarray | None = None                # (N, B) bool for once-per-step exchanges
    step_count: np.ndarray | None = None                # (N, B) working links of every node in that exchange
    noise: list | None = None                           # per round (N, n, B) standard normals, or None
    event_noise: np.ndarray | None = None               # (C, 2, n, B) or None
    gossip_priority: np.ndarray | None = None           # (E, B) uniforms for the swap matching
    node_noise: np.ndarray | None = None                # (N, n, B) for once-per-step exchanges
    swap: tuple | None = None                           # (source, hops), each (N, B): the GIKF's permutation


def _cut(a, sl: slice):
    return None if a is None else a[..., sl]


def slice_context(ctx: StepContext, sl: slice) -> StepContext:
    """The same step for the trials `sl` only (every array's last axis is the trial axis)."""
    links = StepLinks(rounds=[_cut(m, sl) for m in ctx.links.rounds], events=_cut(ctx.links.events, sl),
                      step_mask=_cut(ctx.links.step_mask, sl))
    return StepContext(ctx.k, ctx.y[..., sl], links, heard=[h[..., sl] for h in ctx.heard],
                       step_heard=_cut(ctx.step_heard, sl), step_count=_cut(ctx.step_count, sl),
                       noise=None if ctx.noise is None else [u[..., sl] for u in ctx.noise],
                       event_noise=_cut(ctx.event_noise, sl), gossip_priority=_cut(ctx.gossip_priority, sl),
                       node_noise=_cut(ctx.node_noise, sl),
                       swap=None if ctx.swap is None else (ctx.swap[0][..., sl], ctx.swap[1][..., sl]))


def innovation(y: np.ndarray, H: np.ndarray, x: np.ndarray) -> np.ndarray:
    """y_i − H_i x_i for y (N, m, B), H (N, m, n), x (N, n, B)."""
    return y - np.einsum("imn,inb->imb", H, x)


def apply_gain(K: np.ndarray, r: np.ndarray) -> np.ndarray:
    """K_i r_i for gains (N, n, m) and residuals (N, m, B)."""
    if K.shape[2] == 1:
        return K[:, :, 0, None] * r[:, 0, None, :]
    return np.einsum("inm,imb->inb", K, r)


def predict(F: np.ndarray, x: np.ndarray) -> np.ndarray:
    """F x_i for every node and trial."""
    return np.matmul(F, x)
