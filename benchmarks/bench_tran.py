"""Coestimation simulator: ETD2RK (the stiff coupling integrated exactly) against scipy's Radau
on Example 5.1 with fixed roles, and the batched stochastic simulator's cost per trial-step."""
from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

import estimators.observer_network_simulation as sim
from reproductions.tran import compute
from reproductions.tran.scenario import paper_scenario


def bench_deterministic(t_end: float = 10.0) -> list[dict]:
    sc = paper_scenario()
    P = np.stack([sc.types[t].P for t in sc.node_type])
    net = compute.coestimation(sc, P)
    roles = compute.role_law(sc, fixed=True)
    signal = compute.input_signal(sc)
    e0 = np.zeros((sc.N, sc.n + sc.p))
    rows = []
    ref = None
    M = net.augmented_drift()
    g = np.asarray(sc.fixed_active, float)

    def rhs(t, u):
        out = M @ u
        out[:sc.n] += sc.B @ signal(t)
        out[sc.n:] += net.injection(u[None, :sc.n], u[None, sc.n:].reshape(1, sc.N, -1), g[None])[0].reshape(-1)
        return out

    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0, t_end), np.r_[sc.x0, e0.ravel()], method="Radau", rtol=1e-10, atol=1e-12,
                    t_eval=np.arange(0, t_end + 1e-9, 0.01))
    radau = time.perf_counter() - t0
    ref = sol.y[sc.n:].T
    rows.append({"name": "scipy Radau rtol 1e-10 (reference)", "wall_s": radau, "max_err": 0.0})
    for h in (0.01, 0.005, 0.0025):
        t0 = time.perf_counter()
        tr = sim.simulate(net, roles, signal, sc.x0, e0, t_end=t_end, h=h, record_every=int(round(0.01 / h)))
        wall = time.perf_counter() - t0
        rows.append({"name": f"ETD2RK h={h}", "wall_s": wall,
                     "max_err": float(np.abs(tr.e[0].reshape(len(tr.t), -1) - ref).max())})
    return rows


def bench_stochastic(trials: int = 100, t_end: float = 4.0) -> dict:
    sc = paper_scenario()
    P = np.stack([sc.types[t].P for t in sc.node_type])
    t0 = time.perf_counter()
    compute.run_stochastic(sc, P, fixed=False, trials=trials, seed=0, t_end=t_end, keep=0)
    wall = time.perf_counter() - t0
    steps = int(round(t_end / sc.sde_step))
    return {"name": f"SDE, {trials} trials x {steps} steps, 12 nodes", "wall_s": wall,
            "us_per_trial_step": wall / (trials * steps) * 1e6}


if __name__ == "__main__":
    for row in bench_deterministic():
        print(row)
    print(bench_stochastic())
