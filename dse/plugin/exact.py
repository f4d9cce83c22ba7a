"""Exact second moments of a plug-in filter that declares itself linear (`interface.LinearStep`).

With every link working, a linear filter's step maps the stacked prediction errors ē (N n), the
measurement noises v (N m) and the communication noises σ_c ξ to the estimation errors,
ê = A ē + B v + σ_c C ξ, and ē(k+1) = (I ⊗ F) ê − 1 ⊗ w. The noises are independent of ē and of each
other, so the joint second moment follows exactly:

    Σ̂(k) = A Σ̄(k) Aᵀ + B R Bᵀ + σ_c² C Cᵀ,    Σ̄(k+1) = (I ⊗ F) Σ̂(k) (I ⊗ F)ᵀ + 1 1ᵀ ⊗ Q,

from Σ̄(0) = 1 1ᵀ ⊗ P0 (every node starts from x0), R = diag(R_i). The recursion is in error coordinates,
which needs the filter to be unbiased: A (1 ⊗ I) + B H = 1 ⊗ I, H the stacked H_i (checked to round-off at
every step: otherwise its error depends on the state and these are not its moments).
"""
from __future__ import annotations

import numpy as np
import scipy.linalg

from dse.estimators import joint_moments as jm

from .interface import LinearStep

#: unbiasedness is checked to this many units of round-off per operation of the product (scaled by ‖A‖, ‖B H‖)
ROUNDOFF_UNITS = 10


def reason(est) -> str:
    """Why a designed plug-in filter has no exact moments ("" when it has)."""
    cls, net = est.config.cls, est.network
    if not cls.linear:
        return "it does not declare itself linear (Monte Carlo only)"
    if net.links.random or not net.links.synchronous:
        return ("its matrices depend on which links worked; exact moments are computed with every link working "
                "(reliable links) only")
    return net.joint_size_reason()


def moments(est, n_steps: int) -> dict[str, np.ndarray]:
    """``blocks`` (K, N, n, n), ``mse`` (K, N) and ``disagreement`` (K,) of the filter's errors (module doc).
    Raises `PluginFault` when `matrices` fails, its matrices are malformed or the filter is not unbiased."""
    from .harness import PluginRun

    cfg, net = est.config, est.network
    p = cfg.problem
    N, n, m = p.N, p.n, p.m
    run = PluginRun(est.name, cfg.cls, p, cfg.params, net.links, cfg.messages, 1, 1, float("inf"))
    H = p.H.reshape(N * m, n)
    ones = np.kron(np.ones((N, 1)), np.eye(n))
    R = scipy.linalg.block_diag(*p.R)
    F = np.kron(np.eye(N), p.F)
    Sbar = jm.as_matrix(jm.common_start(N, p.P0))
    Qall = np.kron(np.ones((N, N)), p.Q)
    sigma2 = p.noise_std ** 2
    out = {"blocks": np.empty((n_steps, N, n, n)), "disagreement": np.empty(n_steps)}
    for k in range(n_steps):
        step = _checked(run._call(f"failed in matrices({k})", run.inner.matrices, k), k, N, n, m, est.name)
        _check_unbiased(step, H, ones, k, est.name)
        S = step.A @ Sbar @ step.A.T + step.B @ R @ step.B.T
        if sigma2 and step.C is not None:
            S = S + sigma2 * step.C @ step.C.T
        S4 = jm.from_matrix(S, N)
        out["blocks"][k] = jm.node_blocks(S4)
        out["disagreement"][k] = jm.disagreement(S4)
        Sbar = F @ S @ F.T + Qall
    out["mse"] = np.einsum("kiaa->ki", out["blocks"])
    return out


def _checked(step, k: int, N: int, n: int, m: int, name: str) -> LinearStep:
    from .harness import PluginFault

    if not isinstance(step, LinearStep):
        raise PluginFault(name, f"matrices({k}) returned {type(step).__name__}, not a LinearStep")
    A, B = np.asarray(step.A, float), np.asarray(step.B, float)
    if A.shape != (N * n, N * n) or B.shape != (N * n, N * m):
        raise PluginFault(name, f"matrices({k}) gave A {A.shape} and B {B.shape}; expected "
                         f"({N * n}, {N * n}) and ({N * n}, {N * m})")
    C = None if step.C is None else np.asarray(step.C, float)
    if C is not None and (C.ndim != 2 or C.shape[0] != N * n or C.shape[1] % (N * n)):
        raise PluginFault(name, f"matrices({k}) gave C {C.shape}; expected ({N * n}, exchanges·{N * n})")
    return LinearStep(A, B, C)


def _check_unbiased(step: LinearStep, H: np.ndarray, ones: np.ndarray, k: int, name: str) -> None:
    """A (1 ⊗ I) + B H = 1 ⊗ I to round-off: each entry is a sum of N n + N m products."""
    from .harness import PluginFault

    gap = step.A @ ones + step.B @ H - ones
    scale = np.abs(step.A).sum(axis=1).max() + (np.abs(step.B) @ np.abs(H)).sum(axis=1).max() + 1.0
    tol = ROUNDOFF_UNITS * (step.A.shape[1] + step.B.shape[1]) * np.finfo(float).eps * scale
    if np.abs(gap).max() > tol:
        raise PluginFault(name, f"declares linear matrices that are not unbiased at step {k} (A (1 ⊗ I) + B H − 1 ⊗ I "
                         f"has an entry {np.abs(gap).max():.3g} > {tol:.3g}): the exact moments in error coordinates "
                         "would not be its moments")
