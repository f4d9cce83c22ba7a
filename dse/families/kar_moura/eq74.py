"""The stage of claim eq74: the Riccati sequences of eqs (71)-(74), P_n(t) ⪯ P^s_n(t) for t ≥ s along token n's
own switching, where P^s_n restarts at slot s from the Lyapunov iterate f_0^s(P0) (72). Run on the scenarios
with the structural checks, beside the Monte Carlo.
"""
from __future__ import annotations

import math

import numpy as np

from dse.contract.stages import stage
from dse.estimators.gikf_maps import error_norm
from dse.estimators.gikf_roundoff import compose_with_error, loewner_slack, spectral_norm

from .assumptions import accurate_range
from .bounds import envelope_error, envelope_matrix
from .scenario import GossipKalmanFile
from .theorem8 import chain_sampler

#: restart slots s of (72)
EQ74_S = (1, 2, 5, 10, 20, 50)


@stage(allow_nonfinite=("slack", "raw", "gap"))
def eq74(sc: GossipKalmanFile, b: dict, slots: int) -> dict[str, np.ndarray]:
    """(72)-(74) along 500 chain paths of tokens 0 and 1: the Loewner margins of P^s_n(t) − P_n(t) for t ≥ s (with
    their round-off allowance) and the median relative gap at T (its own fixed random stream)."""
    sys_ = sc.system
    T = min(slots, 120)
    limit = accurate_range(sc)
    s_list = [s for s in EQ74_S if s < T and float(b["envelope_log"][s]) <= math.log(limit)]
    out = {"T": np.array(T), "limit": np.array(limit), "s_list": np.array(s_list, dtype=np.int64)}
    if not s_list:
        return out
    chain = chain_sampler(sc, b)
    rng = np.random.default_rng(74)
    B = 500
    slack, raw = [], []
    gap: dict[int, float] = {}
    tokens = sorted({0, min(1, sc.N - 1)})
    M = sc.M
    for n in tokens:
        path = chain(B, T, rng, start=n)
        # P_n(t) (row 0) and P^s_n(t) of the restarts s reached so far (rows 1, 2, ...), mapped together
        X, E = np.broadcast_to(sc.P0, (1, B, M, M)).copy(), np.zeros((1, B, M, M))
        for t in range(T + 1):
            if t in s_list:
                X = np.concatenate([X, np.broadcast_to(envelope_matrix(b, t), (1, B, M, M))])
                E = np.concatenate([E, np.broadcast_to(envelope_error(b, t) * np.eye(M), (1, B, M, M))])
            started = [s_ for s_ in s_list if s_ <= t]
            if started:
                sl, m = loewner_slack(X[0], X[1:], error_norm(E[0]) + error_norm(E[1:]))
                slack.extend(sl)
                raw.extend(m)
            if t == T:
                for k, s_ in enumerate(started, start=1):
                    gap[s_] = max(gap.get(s_, 0.0), float(np.median(spectral_norm(X[k] - X[0]) / spectral_norm(X[0]))))
                break
            rows = len(X)
            Y, EY = compose_with_error(sys_, X.reshape(-1, M, M), [np.tile(path[:, t], rows)], E.reshape(-1, M, M))  # (69), (72)
            X, E = Y.reshape(rows, B, M, M), EY.reshape(rows, B, M, M)
    out.update(slack=np.concatenate(slack), raw=np.concatenate(raw), tokens=np.array(tokens, dtype=np.int64),
               paths=np.array(B), gap_s=np.array(list(gap), dtype=np.int64), gap=np.array(list(gap.values())))
    return out
