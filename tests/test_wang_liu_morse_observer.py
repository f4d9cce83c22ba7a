"""The exact hybrid-observer simulator: against an ODE solver, the error recursion (41) and
(61') on random systems and graphs, Lemma 3 / Theorem 2 (asynchronous = synchronous), a graph
switch inside a window (the negative case), leaving and joining, and round-off handling."""
from __future__ import annotations

import numpy as np
import pytest
import scipy.linalg as sla
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from scipy.integrate import solve_ivp

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.families.wang_liu_morse.claims.common import fit_rate
from dse.families.wang_liu_morse.figures import log10_safe
from dse.families.wang_liu_morse.scenario import paper_scenarios

from test_wang_liu_morse_design import random_jointly_observable

SETTINGS = settings(max_examples=12, deadline=None, suppress_health_check=[HealthCheck.too_slow])
RING = jd.neighbour_mask([[1, 3], [0, 2], [1, 3], [0, 2]], 4)
DRING = jd.neighbour_mask([[3], [0], [1], [2]], 4)


@pytest.fixture(scope="module")
def paper():
    sc = paper_scenarios()[0]
    return sc, sc.observer


def build(A, Cs, lam_bar=1.5):
    locs = [jd.local_design(A, C) for C in Cs]
    K = [jd.place_gain(l.Abar, l.Cbar, [-lam_bar * (1.25 + 0.25 * j) for j in range(l.n_i)]) for l in locs]
    return ho.ObserverDesign(A, tuple(Cs), tuple(l.L for l in locs), tuple(l.Abar for l in locs),
                             tuple(l.Cbar for l in locs), tuple(K), tuple(l.Q for l in locs), np.array([l.P for l in locs]))


def ics(d, B, seed):
    rng = np.random.default_rng(seed)
    return (rng.standard_normal((B, d.n)), rng.standard_normal((B, sum(d.n_i))), rng.standard_normal((B, d.m, d.n)))


def test_exact_propagation_matches_ode_solver(paper):
    """Plant with the harmonic input, local observers and open-loop estimates on [0, T): expm vs RK (rtol 1e-12)."""
    sc, d = paper
    sched = ho.GraphSchedule(np.array([RING, DRING]), kind="alternate_interval", T=1.0)
    x0, w0, xh0 = sc.x0[None], sc.w0[None], sc.xhat0[None]
    run = ho.simulate(d, ho.Timing(1.0, 5, 0.2, 0.0, np.zeros(4)), sched, x0=x0, w0=w0, xhat0=xh0, intervals=1,
                      noise_b=sc.noise_b, noise_omega=10.0, dt_plot=0.05)
    F = [d.F(i) for i in range(4)]

    def rhs(t, y):
        x, w = y[:4], y[4:12]
        dx = sc.A @ x + sc.noise_b * np.cos(10 * t)
        dw = np.concatenate([F[i] @ w[2 * i:2 * i + 2] - d.K[i] @ (d.C[i] @ x) for i in range(4)])
        return np.concatenate([dx, dw])

    t_eval = run.t_ns[run.t_ns < 1e9] / 1e9
    sol = solve_ivp(rhs, (0, 0.95), np.concatenate([sc.x0, sc.w0]), method="DOP853", rtol=1e-13, atol=1e-13,
                    t_eval=t_eval)
    assert np.abs(sol.y[:4].T - run.x0[: len(t_eval)]).max() < 1e-10
    xhat_ode = np.einsum("tab,ib->tia", np.array([sla.expm(sc.A * t) for t in t_eval]), sc.xhat0)
    assert np.abs(xhat_ode - run.xhat0[: len(t_eval)]).max() < 1e-13
    # ē(0) and w at t = 1⁻ through the recorded ē(1): w(1) - L x(1)
    sol1 = solve_ivp(rhs, (0, 1.0), np.concatenate([sc.x0, sc.w0]), method="DOP853", rtol=1e-13, atol=1e-13)
    w1 = sol1.y[4:, -1]
    x1 = sol1.y[:4, -1]
    ebar1 = np.concatenate([w1[2 * i:2 * i + 2] - d.L[i] @ x1 for i in range(4)])
    assert np.abs(ebar1 - run.ebar[1, 0]).max() < 1e-9


@SETTINGS
@given(st.integers(0, 10_000), st.sampled_from(["alternate_interval", "alternate_iteration"]),
       st.sampled_from(["mean", "symmetric"]))
def test_error_recursion_identity_random(seed, switching, rule):
    A, Cs = random_jointly_observable(seed, n=3, m=3)
    d = build(A, Cs)
    rng = np.random.default_rng(seed)
    graphs = []
    while len(graphs) < 2:
        N = rng.random((3, 3)) < 0.6
        N = N | N.T if rule == "symmetric" else N
        N |= np.eye(3, dtype=bool)
        if jd.is_strongly_connected(N):
            graphs.append(N)
    q = int(rng.integers(2, 12))
    sched = ho.GraphSchedule(np.array(graphs), kind=switching, T=0.5, Delta=0.5 / q, beta=0.0, q=q)
    x0, w0, xh0 = ics(d, 5, seed)
    run = ho.simulate(d, ho.Timing(0.5, q, 0.5 / q, 0.0, np.zeros(3)), sched, x0=x0, w0=w0, xhat0=xh0, intervals=6,
                      rule=rule)
    for s in range(1, 7):
        As, Bs, G = ho.error_recursion(d, run.W[s - 1], 0.5)
        pred = run.e_post[s - 1].reshape(5, -1) @ As.T + run.ebar[s - 1] @ Bs.T
        scale = max(1.0, np.abs(run.x_event[s]).max(), np.abs(run.e_post[s - 1]).max())
        assert np.abs(pred - run.e_post[s].reshape(5, -1)).max() < 1e-12 * scale
        assert np.abs(G).max() == 0.0
        # the weights are row stochastic and supported on the source sets
        assert np.allclose(run.W[s - 1].sum(axis=-1), 1.0) and not (run.W[s - 1][~run.sources[s - 1]] != 0).any()


@SETTINGS
@given(st.integers(0, 10_000))
def test_async_reproduces_sync_bitwise(seed):
    """Theorem 2 via Lemma 3: jitter within (10) and graphs constant on the windows (23)."""
    A, Cs = random_jointly_observable(seed, n=3, m=3)
    d = build(A, Cs)
    rng = np.random.default_rng(seed + 1)
    q, T, beta = 8, 1.0, 0.03
    Delta = (T - 0.01) / q
    eps = rng.uniform(0, 0.015, 3)
    graphs = np.array([jd.neighbour_mask([[2], [0], [1]], 3), jd.neighbour_mask([[1, 2], [0], [0]], 3)])
    sched = ho.GraphSchedule(graphs, kind="alternate_iteration", T=T, Delta=Delta, beta=beta, q=q)
    x0, w0, xh0 = ics(d, 3, seed)
    sync = ho.simulate(d, ho.Timing(T, q, Delta, beta, np.zeros(3)), sched, x0=x0, w0=w0, xhat0=xh0, intervals=4)
    jit = rng.uniform(-1, 1, (4, 3, q + 1)) * eps[None, :, None]
    asy = ho.simulate(d, ho.Timing(T, q, Delta, beta, np.zeros(3), jit), sched, x0=x0, w0=w0, xhat0=xh0, intervals=4)
    assert asy.reception_violations == 0 and np.array_equal(asy.sources, asy.nominal)
    assert np.array_equal(asy.z0, sync.z0) and np.array_equal(asy.e_post, sync.e_post)


def test_switch_inside_a_window_breaks_lemma3(paper):
    """Negative case: a graph switch at the nominal broadcast time with jitter makes senders see different graphs."""
    sc, d = paper
    q, Delta, beta = 10, 0.09, 0.02
    switch = [0.0] + [k * Delta + beta for k in range(1, q)]
    sched = ho.GraphSchedule(np.array([RING, DRING]), kind="sequence", times=tuple(switch),
                             indices=tuple(k % 2 for k in range(q)))
    jit = np.random.default_rng(3).uniform(-0.005, 0.005, (2, 4, q + 1))
    run = ho.simulate(d, ho.Timing(1.0, q, Delta, beta, np.zeros(4), jit), sched, x0=sc.x0[None], w0=sc.w0[None],
                      xhat0=sc.xhat0[None], intervals=2)
    assert not np.array_equal(run.sources, run.nominal)


def test_offset_recursion_sign(paper):
    """(61'): e(s) = A e(s-1) + B ē(s-1) - G x((s-1)T); the printed +G is off by 2 G x."""
    sc, d = paper
    offsets = np.array([0.002, -0.001, 0.0, -0.002])
    sched = ho.GraphSchedule(np.array([RING, DRING]), kind="alternate_interval", T=1.0)
    run = ho.simulate(d, ho.Timing(1.0, 50, 0.0199, 0.005, offsets), sched, x0=sc.x0[None], w0=sc.w0[None],
                      xhat0=sc.xhat0[None], intervals=5)
    for s in range(1, 6):
        As, Bs, G = ho.error_recursion(d, run.W[s - 1], 1.0, offsets)
        base = run.e_post[s - 1, 0].ravel() @ As.T + run.ebar[s - 1, 0] @ Bs.T
        xg = G @ run.x_nominal[s - 1, 0]
        cur = run.e_post[s, 0].ravel()
        assert np.abs(cur - (base - xg)).max() < 1e-13 * max(1, np.abs(run.x_event).max())
        assert np.abs(cur - (base + xg)).max() > 1e3 * np.abs(cur - (base - xg)).max()
    assert np.all(run.event_ns[:, 1] == 1_000_000_000 + np.round(offsets * 1e9).astype(np.int64))


def test_leave_and_rejoin(paper):
    sc, d = paper
    sched = ho.GraphSchedule(np.array([RING]), kind="fixed")
    mb = ho.Membership(3, 5.0, 7.0, "reinit", sc.xhat0[3][None], sc.w0[6:8][None])
    run = ho.simulate(d, ho.Timing(1.0, 50, 0.02, 0.0, np.zeros(4)), sched, x0=sc.x0[None], w0=sc.w0[None],
                      xhat0=sc.xhat0[None], intervals=10, membership=(mb,))
    assert run.participating[:, 3].tolist() == [True] * 5 + [False, False] + [True] * 3
    assert not run.sources[5:7, :, :3, 3].any()                         # nobody hears agent 4 while it is out
    assert run.sources[7:, :, 0, 3].all()
    t = run.t_ns / 1e9
    frozen = (t >= 5.0) & (t < 7.0)
    assert np.ptp(run.xhat0[frozen, 3], axis=0).max() == 0.0            # frozen while absent
    e7 = run.e_post[7, 0, 3]
    assert np.allclose(e7 + run.x_event[7, 0, 3], sc.xhat0[3])          # re-initialised at t = 7
    assert np.allclose(run.ebar[7, 0, 6:8] + d.L[3] @ run.x_event[7, 0, 3], sc.w0[6:8])


def test_roundoff_floor_and_rate_fit():
    t = np.arange(40, dtype=float)
    v = np.maximum(50 * np.exp(-1.7 * t), 1e-13 * (1 + 0.3 * np.sin(t)))
    v[-3] = 0.0                                                        # an exact zero must not break anything
    floor = np.full_like(t, 1e3 * np.finfo(float).eps)
    rate, first, stop = fit_rate(t, v, floor)
    assert rate == pytest.approx(1.7, rel=1e-9) and stop == int(np.argmax(v <= floor))
    assert np.isfinite(log10_safe(v)).all() and log10_safe(np.array([0.0]))[0] == -300.0


def test_idealised_run_errors_reach_roundoff(paper):
    """With ē(0) = 0 and ρ = 0 the error after reset s is |A(s)| ≈ 5e-9 times the one before: from the
    second reset on it sits at round-off, and is recorded there (no log of zero)."""
    sc, d = paper
    sched = ho.GraphSchedule(np.array([RING, DRING]), kind="alternate_interval", T=1.0)
    w0 = np.concatenate([d.L[i] @ sc.x0 for i in range(4)])[None]
    run = ho.simulate(d, ho.Timing(1.0, 50, 0.02, 0.0, np.zeros(4)), sched, x0=sc.x0[None], w0=w0,
                      xhat0=sc.xhat0[None], intervals=3)
    post = np.linalg.norm(run.e_post[1:, 0], axis=-1).max(axis=-1)
    As, _, _ = ho.error_recursion(d, run.W[0], 1.0)
    e0 = np.linalg.norm(run.e_post[0, 0], axis=-1).max()
    assert post[0] <= jd.mixed_norm(As, [4] * 4, [4] * 4) * e0 * (1 + 1e-6)
    assert post[1:].max() < 1e3 * np.finfo(float).eps * np.abs(run.x_event).max()
    assert np.all(np.isfinite(np.log10(np.maximum(run.err, 1e-300))))


def test_trial_zero_does_not_depend_on_the_batch(paper):
    """Every product is summed in a fixed order per trial: one trial alone reproduces trial 0 of a batch bit for bit."""
    sc, d = paper
    sched = ho.GraphSchedule(np.array([RING, DRING]), kind="alternate_interval", T=1.0)
    x0, w0, xh0 = ics(d, 33, 4)
    tim = ho.Timing(1.0, 50, 0.02, 0.0, np.zeros(4))
    many = ho.simulate(d, tim, sched, x0=x0, w0=w0, xhat0=xh0, intervals=3, noise_b=sc.noise_b)
    one = ho.simulate(d, tim, sched, x0=x0[:1], w0=w0[:1], xhat0=xh0[:1], intervals=3, noise_b=sc.noise_b)
    assert np.array_equal(many.x0, one.x0) and np.array_equal(many.e_post[:, :1], one.e_post)
    assert np.array_equal(many.err[:, :1], one.err) and np.array_equal(many.z0, one.z0)
