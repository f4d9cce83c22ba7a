"""Coestimation simulator: ETD2RK (the stiff coupling integrated exactly) against scipy's Radau
on Example 5.1 with fixed roles, the batched stochastic simulator's cost per trial-step (time-varying
roles; fixed roles through the composed step operator), the LMIs and the design stage, and the
commands people wait on (`dse check`, `dse run --quick`, `dse reproduce tran`) with wall and CPU time."""
from __future__ import annotations

import time

import numpy as np
from scipy.integrate import solve_ivp

import dse.estimators.observer_network_simulation as sim
from dse.families.tran import design, law, runs


def paper_scenario():
    from dse import registry

    return registry.paper("tran").scenario


def bench_deterministic(t_end: float = 10.0) -> list[dict]:
    sc = paper_scenario()
    P = sc.per_node("P")
    net = design.coestimation(sc, P)
    roles = runs.role_law(sc, fixed=True)
    signal = design.input_signal(sc)
    e0 = np.zeros((sc.N, sc.n + sc.p))
    rows = []
    ref = None
    M = net.augmented_drift()
    g = np.asarray(sc.fixed_roles.active, float)

    def rhs(t, u):
        out = M @ u
        out[:sc.n] += sc.B @ signal(t)
        out[sc.n:] += net.injection(u[None, :sc.n], u[None, sc.n:].reshape(1, sc.N, -1), g[None])[0].reshape(-1)
        return out

    t0 = time.perf_counter()
    sol = solve_ivp(rhs, (0, t_end), np.r_[sc.process.x0, e0.ravel()], method="Radau", rtol=1e-10, atol=1e-12,
                    t_eval=np.arange(0, t_end + 1e-9, 0.01))
    radau = time.perf_counter() - t0
    ref = sol.y[sc.n:].T
    rows.append({"name": "scipy Radau rtol 1e-10 (reference)", "wall_s": radau, "max_err": 0.0})
    for h in (0.01, 0.005, 0.0025):
        t0 = time.perf_counter()
        tr = sim.simulate(net, roles, signal, sc.process.x0, e0, t_end=t_end, h=h, record_every=int(round(0.01 / h)))
        wall = time.perf_counter() - t0
        rows.append({"name": f"ETD2RK h={h}", "wall_s": wall,
                     "max_err": float(np.abs(tr.e[0].reshape(len(tr.t), -1) - ref).max())})
    return rows


def bench_stochastic(trials: int = 100, t_end: float = 4.0) -> dict:
    sc = paper_scenario()
    P = sc.per_node("P")
    noise = law.noise_model(sc, 0)
    t0 = time.perf_counter()
    runs.run_stochastic(sc, P, noise, fixed=False, trials=trials, seed=0, t_end=t_end, keep=0, h=sc.stochastic.step)
    wall = time.perf_counter() - t0
    steps = int(round(t_end / sc.stochastic.step))
    return {"name": f"SDE, {trials} trials x {steps} steps, 12 nodes", "wall_s": wall,
            "us_per_trial_step": wall / (trials * steps) * 1e6}


def bench_stochastic_rows(quick: bool = False, repeats: int = 3) -> list[dict]:
    """Side-by-side rows: µs per trial-node-step of the stochastic coestimation simulator
    (role switching, Euler-Maruyama noise on the exact ETD2RK drift; and fixed roles, where the
    whole step is one composed operator), batched trials vs one trial per call."""
    from .common import estimator_row, timed

    sc = paper_scenario()
    P = sc.per_node("P")
    t_end = 1.0 if quick else 4.0
    h = sc.stochastic.step
    steps = int(round(t_end / h))
    net = design.coestimation(sc, P)
    noise = law.noise_model(sc, 0)
    prepared = sim.prepare(net, h, noise)          # once per reproduction stage: not timed
    every = int(round(sc.simulation.record_dt / h))
    from dse.estimators.input_state_coestimation import block_diag, errors_from_estimates

    Pbig = block_diag(list(P))

    def reducer(t, x, w, e, g):             # V = zᵀPz of every trial, as the Monte Carlo computes it
        zf = errors_from_estimates(x, w, e, sc.n).reshape(len(x), -1)
        np.einsum("ri,ri->r", zf @ Pbig, zf)
    signal = design.input_signal(sc)
    e0 = np.zeros((sc.N, sc.n + sc.p))
    rows = []
    for fixed, trials in [(False, k) for k in ((100,) if quick else (100, 1000))] + [(True, 100 if quick else 1000)]:
        roles = runs.role_law(sc, fixed)
        loop_trials = 2 if quick else 5
        rng = np.random.Generator(np.random.SFC64(0))
        run = lambda k: sim.simulate(net, roles, signal, sc.process.x0, e0, t_end=t_end, h=h,  # noqa: E731
                                     record_every=every, n_trials=k, noise=noise, rng=rng, keep=0, reducer=reducer,
                                     prepared=prepared)
        batched = timed(lambda: run(trials), repeats, per=trials * steps * sc.N, warmup=True)
        loop = timed(lambda: [run(1) for _ in range(loop_trials)], repeats, per=loop_trials * steps * sc.N)
        rows.append(estimator_row(f"coestimation SDE (tran), {'fixed roles' if fixed else 'role switching'}, "
                                  f"h={h:g}",
                                  f"N={sc.N}, n+p={sc.n + sc.p}, {trials:,} trials, t≤{t_end:g}", nodes=sc.N,
                                  state_dim=sc.n + sc.p, trials=trials, steps=steps, batched=batched, loop=loop,
                                  loop_what="same simulator, 1 trial per call", loop_trials=loop_trials,
                                  target="<= 0.3 µs", met=batched[0] <= 0.3,
                                  note=("simulate(): one composed step operator (FixedRoleStep) + " if fixed else
                                        "simulate(): ETD2RK + ") + "exact noise factors (86 normals/trial-step) + V every 2 "
                                  "steps"))
    return rows


def bench_lmis(repeats: int = 3) -> list[dict]:
    """The design LMIs (28)-(29) (Clarabel, called directly) and the whole design stage."""
    from dse.estimators import common_lyapunov as cl

    from .common import bound_row, timed

    sc = paper_scenario()
    rows = []
    for t in range(len(sc.types)):
        v = design.vertices(sc, t)
        r = cl.common_lyapunov(v, sc.types[t].eps)
        rows.append(bound_row(f"tran LMIs (28)-(29), node type {t} ({len(v)} vertices, {v[0].shape[0]}x{v[0].shape[0]})",
                              fast=timed(lambda: cl.common_lyapunov(v, sc.types[t].eps), repeats, per=1e3),
                              fast_what="common Lyapunov LMI (Clarabel)", note=f"status {r.status}"))
    rows.append(bound_row("tran design stage (LMIs, sweeps, bounds: the design's core)", fast=timed(
        lambda: design.design_core(sc), 1, per=1e3), fast_what="design_core(scenario)"))
    return rows


def bench_deterministic_rows(t_end: float = 10.0) -> list[dict]:
    from .common import bound_row

    rows = bench_deterministic(t_end)
    ref = rows[0]
    return [bound_row(f"tran deterministic error system, t ≤ {t_end:g}", fast=(1e3 * r["wall_s"], (1e3 * r["wall_s"],) * 2),
                      fast_what=r["name"], naive=(1e3 * ref["wall_s"], (1e3 * ref["wall_s"],) * 2), naive_what=ref["name"],
                      max_diff=r["max_err"], note="max_rel_diff: max abs error vs Radau; one run each")
            for r in rows[1:]]


#: a user's small scenario: 4 nodes on a ring, LMI-designed P, proximity roles
SMALL_TOML = """family = "coestimation"
name = "ring4"
[process]
A = [[0.0, 1.0], [-2.0, -1.5]]
B = [[0.0], [2.0]]
x0 = [1.0, -0.5]
[input]
offset = [0.5]
amplitude = [[1.0]]
frequency = [[0.8]]
phase = [[0.0]]
[graph]
kind = "ring"
n = 4
[nodes]
positions = [[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [3.0, 0.0]]
type = ["pos", "vel", "pos", "vel"]
[node_type.pos]
C = [[1.0, 0.0]]
L = [[4.0], [2.0]]
J = [[3.0]]
K = [[2.0]]
sigma = 0.2
eps = 1e-4
[node_type.vel]
C = [[0.0, 1.0]]
L = [[0.5], [3.0]]
J = [[2.0]]
K = [[2.0]]
sigma = 0.2
eps = 1e-4
[coupling]
alpha = 10.0
P = "lmi"
[roles]
mode = "proximity"
radius = 1.2
beta = 3.0
position_states = [0, 1]
[fixed_roles]
active = [1, 1, 0, 0]
[simulation]
t_end = 6.0
step = 0.005
tail_start = 3.0
[stochastic]
trials = 40
quick_trials = 20
runs = 2
quick_t_end = 3.0
"""


if __name__ == "__main__":
    import sys

    for row in bench_stochastic_rows(True, 1) + bench_lmis(1):
        print(row)
    for row in bench_deterministic():
        print(row)
    print(bench_stochastic())
