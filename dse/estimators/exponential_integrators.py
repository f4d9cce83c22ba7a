"""Exponential integrators for stiff linear-plus-forcing systems u̇ = M u + N(t, u).

The stiff constant part M is integrated exactly through the φ-functions
φ0(Z) = e^Z, φ1(Z) = Σ Z^k/(k+1)!, φ2(Z) = Σ Z^k/(k+2)!, all read off one matrix
exponential of an augmented block matrix (Hochbruck & Ostermann, Acta Numerica 2010, §2;
Al-Mohy & Higham 2011 for the block trick). Schemes built on them:

* ETD2RK (Cox & Matthews 2002): a = φ0 u + h φ1 N(t, u);  u⁺ = a + h φ2 (N(t+h, a) − N(t, u)),
  second order, unconditionally stable for the linear part;
* stochastic exponential Euler (Lord & Rougemont 2004; Jentzen & Kloeden 2009):
  u⁺ = φ0 (u + G ΔW) + h φ1 N(t, u), strong order 1/2, weak order 1, stable for stiff M.
"""
from __future__ import annotations

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it


def phi_functions(M: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(φ0(hM), φ1(hM), φ2(hM)) from expm([[hM, I, 0], [0, 0, I], [0, 0, 0]])."""
    M = np.asarray(M, dtype=float)
    d = M.shape[0]
    big = np.zeros((3 * d, 3 * d))
    big[:d, :d] = h * M
    big[:d, d:2 * d] = np.eye(d)
    big[d:2 * d, 2 * d:] = np.eye(d)
    X = scipy.linalg.expm(big)
    return X[:d, :d], X[:d, d:2 * d], X[:d, 2 * d:]
