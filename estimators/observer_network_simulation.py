"""Simulation of a process and a network of role-weighted observers, batched over trials.

State u = [x; e_1; …; e_N] on a leading trial axis (R, D). The stiff constant part (the
process, the local drifts and the graph coupling α Γ (L ⊗ I), whose eigenvalues reach
−2850 in the 12-node example) is integrated exactly with φ-functions; the role-weighted
output injection g_i [L_i; J_i] C_i (x − x̂_i) and the input forcing B w(t) are the
explicit part:

* deterministic: ETD2RK (second order);
* stochastic, dx = (A x + B w) dt + G_v dW_v and y_i dt = C_i x dt + H_i dS_i (41): the
  Brownian increment is added first and the ETD2RK drift step follows (an exponential
  integrator with additive-noise splitting; weak order 1, exact for the stiff part); the
  observer increment of node i is g_i [L_i; J_i] (C_i (x − x̂_i) dt + H_i dS_i), i.e.
  continuous white measurement noise. The role weight g multiplying the noise is taken at
  the start of the step (Itô).

Roles: either fixed g ∈ [0, 1]^N or a proximity law ġ_i = β (a_i(t) − g_i) with
a_i = 1{‖(x_{k1}, x_{k2}) − c_i‖ ≤ r} (Sec. 5: g = e^{−βt} on leaving, 1 − e^{−βt} on
entering, t the time since the switch). The role ODE is solved exactly over each step, with
the crossing instant inside the step located by linear interpolation of the distance.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import numpy as np

from .exponential_integrators import phi_functions
from .input_state_coestimation import NetworkObserver


@dataclass(frozen=True)
class SinusoidalInput:
    """w_k(t) = offset_k + Σ_j amplitude_kj sin(frequency_kj t + phase_kj); arrays (p,), (p, J)."""

    offset: np.ndarray
    amplitude: np.ndarray
    frequency: np.ndarray
    phase: np.ndarray

    def __call__(self, t) -> np.ndarray:
        t = np.asarray(t, float)[..., None, None]
        return self.offset + (self.amplitude * np.sin(self.frequency * t + self.phase)).sum(-1)

    def rate(self, t) -> np.ndarray:
        t = np.asarray(t, float)[..., None, None]
        return (self.amplitude * self.frequency * np.cos(self.frequency * t + self.phase)).sum(-1)

    def sup_norms(self, t_end: float, samples: int = 200_001) -> tuple[float, float]:
        """(sup‖w‖₂, sup‖ẇ‖₂) on [0, max(t_end, longest period)] by dense sampling."""
        periods = 2 * np.pi / np.where(self.frequency > 0, self.frequency, np.inf)
        span = max(t_end, float(np.max(periods, initial=0.0)))
        t = np.linspace(0.0, span, samples)
        return float(np.linalg.norm(self(t), axis=-1).max()), float(np.linalg.norm(self.rate(t), axis=-1).max())


@dataclass(frozen=True)
class FixedRoles:
    g: np.ndarray  # (N,)

    def initial(self, pos: np.ndarray) -> np.ndarray:
        return np.broadcast_to(self.g, (pos.shape[0], len(self.g))).astype(float).copy()

    def advance(self, g, pos0, pos1, h):
        return g


@dataclass(frozen=True)
class ProximityRoles:
    """Sensing discs of radius r at centres (N, 2); positions are x[position_states]."""

    centers: np.ndarray
    radius: float
    beta: float
    position_states: tuple[int, int] = (0, 2)
    g0: np.ndarray | None = None  # None: g_i(0) = a_i(0)

    def distance(self, pos: np.ndarray) -> np.ndarray:
        """‖pos − c_i‖ − r: pos (R, 2) -> (R, N); ≤ 0 inside the disc."""
        return np.linalg.norm(pos[:, None, :] - self.centers[None], axis=-1) - self.radius

    def indicator(self, pos: np.ndarray) -> np.ndarray:
        return (self.distance(pos) <= 0).astype(float)

    def initial(self, pos: np.ndarray) -> np.ndarray:
        if self.g0 is not None:
            return np.broadcast_to(self.g0, (pos.shape[0], len(self.centers))).astype(float).copy()
        return self.indicator(pos)

    def advance(self, g, pos0, pos1, h):
        """Exact solution of ġ = β (a − g) over [t, t+h] with a switching at the interpolated crossing."""
        d0, d1 = self.distance(pos0), self.distance(pos1)
        a0, a1 = (d0 <= 0).astype(float), (d1 <= 0).astype(float)
        cross = a0 != a1
        theta = np.where(cross, d0 / np.where(cross, d0 - d1, 1.0), 1.0).clip(0.0, 1.0)
        mid = a0 + (g - a0) * np.exp(-self.beta * theta * h)
        return a1 + (mid - a1) * np.exp(-self.beta * (1.0 - theta) * h)


@dataclass(frozen=True)
class NoiseModel:
    """Process noise G_v (n, k_v) and measurement noise intensities H (N, m, k_s)."""

    process: np.ndarray
    measurement: np.ndarray


@dataclass
class Trajectory:
    """Samples every `record_every` steps: t (T,), w (T, p), and per kept trial x (K, T, n),
    e (K, T, N, q), g (K, T, N); `reduced[name]` (T, R, ...) from the reducer over all trials."""

    t: np.ndarray
    w: np.ndarray
    x: np.ndarray
    e: np.ndarray
    g: np.ndarray
    reduced: dict


def simulate(net: NetworkObserver, roles, signal: SinusoidalInput, x0, e0, *, t_end: float, h: float,
             record_every: int, n_trials: int = 1, noise: NoiseModel | None = None,
             rng: np.random.Generator | None = None, keep: int | None = None,
             reducer: Callable[..., dict] | None = None) -> Trajectory:
    """Integrate process + observers from (x0, e0) (e0 (N, q)) over [0, t_end] with step h.

    Deterministic (noise None): ETD2RK. Stochastic: noise increment then ETD2RK, all
    `n_trials` trials at once. `keep` trials (default all) are stored in full; `reducer(t, x, w,
    e, g)` is applied to every trial at each recorded time.
    """
    n, N, q = net.n, net.N, net.q
    steps = int(round(t_end / h))
    if abs(steps * h - t_end) > 1e-9 * max(1.0, t_end):
        raise ValueError(f"t_end = {t_end} is not a multiple of h = {h}")
    if steps % record_every:
        raise ValueError("the number of steps must be a multiple of record_every")
    if noise is not None and rng is None:
        raise ValueError("a stochastic simulation needs rng")
    R = n_trials
    keep = R if keep is None else min(keep, R)
    M = net.augmented_drift()
    E, Phi1, Phi2 = phi_functions(M, h)
    ET, P1T, P2T = E.T.copy(), Phi1.T.copy(), Phi2.T.copy()
    P2xx = Phi2[:n, :n].copy()
    D = n + N * q
    u = np.tile(np.concatenate([np.asarray(x0, float), np.asarray(e0, float).reshape(-1)]), (R, 1))
    ps = list(getattr(roles, "position_states", (0, 2)))
    g = roles.initial(u[:, ps])
    if noise is not None:
        LJH = np.einsum("iqm,imk->iqk", net.LJ, noise.measurement)
        Gv = np.asarray(noise.process, float)

    def drift_part(uu, gg, f):
        out = np.empty_like(uu)
        out[:, :n] = f
        out[:, n:] = net.injection(uu[:, :n], uu[:, n:].reshape(R, N, q), gg).reshape(R, N * q)
        return out

    n_rec = steps // record_every + 1
    t_rec = np.arange(n_rec) * record_every * h
    xs, es, gs = np.empty((keep, n_rec, n)), np.empty((keep, n_rec, N, q)), np.empty((keep, n_rec, N))
    reduced: dict[str, list] = {}

    def record(k_rec, t):
        xs[:, k_rec], es[:, k_rec], gs[:, k_rec] = u[:keep, :n], u[:keep, n:].reshape(keep, N, q), g[:keep]
        if reducer is not None:
            for name, val in reducer(t, u[:, :n], signal(t), u[:, n:].reshape(R, N, q), g).items():
                reduced.setdefault(name, []).append(val)

    B = net.B
    f_now = signal(0.0) @ B.T
    for k in range(steps):
        t = k * h
        if k % record_every == 0:
            record(k // record_every, t)
        f_next = signal(t + h) @ B.T
        if noise is not None:
            # additive increment first, then the deterministic ETD2RK step from the kicked state
            kick = np.zeros((R, D))
            kick[:, :n] = rng.standard_normal((R, Gv.shape[1])) @ Gv.T * np.sqrt(h)
            dS = rng.standard_normal((R, N, LJH.shape[2])) * np.sqrt(h)
            kick[:, n:] = (g[..., None] * np.einsum("iqk,rik->riq", LJH, dS)).reshape(R, N * q)
            x_before = u[:, ps]
            u = u + kick
        else:
            x_before = u[:, ps]
        N0 = drift_part(u, g, f_now)
        a = u @ ET + h * (N0 @ P1T)
        x1 = a[:, :n] + h * (f_next - f_now) @ P2xx.T
        g1 = roles.advance(g, x_before, x1[:, ps], h)
        Na = drift_part(a, g1, f_next)
        u = a + h * ((Na - N0) @ P2T)
        g = g1
        f_now = f_next
    record(n_rec - 1, steps * h)
    if not np.all(np.isfinite(u)):
        raise FloatingPointError("the simulation produced non-finite values")
    return Trajectory(t_rec, signal(t_rec), xs, es, gs, {k: np.stack(v) for k, v in reduced.items()})
