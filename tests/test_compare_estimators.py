"""The estimators of the comparison family against independent implementations.

Oracles: the project's scalar implementations of Savas et al. (Carli's two-stage filter and the
re-injection filter, simulation and exact covariance recursion) where the vector forms reduce to
them; the project's GIKF slot (`gossip_kalman`) on the same matchings; filterpy for the
centralized filter; per-trial textbook loops (explicit inverses, the diffusion filter's
sequential incremental update) for the Kalman-consensus, diffusion and consensus-on-information
filters; enumeration of every link pattern (and every Poisson exchange sequence) for the exact
mean recursions; numpy.linalg for the stacked small-matrix kernels.
"""
from __future__ import annotations

import itertools

import numpy as np
import pytest

import dse.estimators.consensus_covariance as cc
import dse.estimators.consensus_filter as cf
import dse.estimators.joint_moments as jm
import dse.estimators.small_matrix as sm
from dse.estimators.constant_gain_fusion import FusionFilter, FusionRun, exact_moments, steady_state
from dse.estimators.gossip_swap_kalman import GossipSwapRun
from dse.estimators.information_fusion import InformationFilter, InformationRun
from dse.estimators.information_fusion import exact_moments as information_exact
from dse.estimators.link_models import LinkModel, StepLinks, Topology, greedy_matching
from dse.estimators.network_mixing import heard, link_count
from dse.estimators.network_step import StepContext
from dse.estimators.sensor_network import SensorNetworkModel, split_gains


def small_model(N=4, seed=0, m=1):
    rng = np.random.default_rng(seed)
    dt = 0.4
    F = np.array([[1.0, dt], [0.0, 0.98]])
    Q = 0.2 * np.array([[dt ** 3 / 3, dt ** 2 / 2], [dt ** 2 / 2, dt]])
    H, R = [], []
    for i in range(N):
        h = rng.standard_normal((m, 2))
        H.append(h)
        a = rng.standard_normal((m, m))
        R.append(a @ a.T + np.eye(m))
    return SensorNetworkModel.build(F, Q, H, R, np.diag([2.0, 1.0]), [0.5, -0.2])


def ring(N):
    return Topology.from_edges(N, [(i, (i + 1) % N) for i in range(N)] + ([(0, 2)] if N > 3 else []))


def contexts(model, links, K, B, seed, rounds=1):
    """Step contexts with explicit draws, and the true states they measure."""
    rng = np.random.default_rng(seed)
    N, n, m = model.N, model.n, model.m
    x = model.x0[:, None] + np.linalg.cholesky(model.P0) @ rng.standard_normal((n, B))
    out, xs = [], []
    topo = links.topology
    for k in range(K):
        v = np.einsum("iab,ibc->iac", model.R_chol, rng.standard_normal((N, m, B)))
        y = np.einsum("imn,nb->imb", model.H, x) + v
        if links.kind == "reliable":
            sl = StepLinks(rounds=[None] * rounds)
        elif links.kind == "failures":
            sl = StepLinks(rounds=[rng.random((topo.E, B)) >= links.p_fail for _ in range(rounds)])
            sl.step_mask = sl.rounds[0]
        else:
            sl = StepLinks(rounds=[greedy_matching(topo, rng.random((topo.E, B))) for _ in range(rounds)])
            sl.step_mask = sl.rounds[0]
        ctx = StepContext(k, y, sl, heard=[heard(topo, mk, B) for mk in sl.rounds])
        ctx.step_heard = ctx.heard[0]
        ctx.step_count = link_count(topo, sl.rounds[0], B)
        ctx.noise = [rng.standard_normal((N, n, B)) for _ in range(rounds)]
        ctx.node_noise = ctx.noise[0]
        ctx.gossip_priority = rng.random((topo.E, B))
        out.append(ctx)
        xs.append(x)
        x = model.F @ x + np.linalg.cholesky(model.Q) @ rng.standard_normal((n, B))
    return out, xs


# -- small matrices ----------------------------------------------------------------------------------------

def test_small_matrix_kernels_match_numpy():
    rng = np.random.default_rng(3)
    A = rng.standard_normal((7, 5, 4, 4))
    S = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    b = rng.standard_normal((7, 5, 4, 2))
    Sb = sm.to_batched(S)
    assert np.allclose(sm.from_batched(sm.spd_inverse(Sb)), np.linalg.inv(S), rtol=1e-12, atol=1e-12)
    assert np.allclose(sm.from_batched(sm.spd_solve(Sb, sm.to_batched(b))), np.linalg.solve(S, b), atol=1e-11)
    assert np.allclose(sm.from_batched(sm.matmul(sm.to_batched(A), Sb)), A @ S, atol=1e-12)
    L = sm.from_batched(sm.cholesky(Sb))
    assert np.allclose(L, np.linalg.cholesky(S), atol=1e-12)
    F = rng.standard_normal((4, 4))
    assert np.allclose(sm.from_batched(sm.const_sandwich(F, Sb)), F @ S @ F.T, atol=1e-11)


# -- Savas et al.'s scalar filters are the vector forms with n = 1 ------------------------------------------

@pytest.mark.parametrize("reinjection,zeta", [(False, 1.0), (True, 0.3)])
@pytest.mark.parametrize("m,sigma_c", [(1, 0.0), (3, 1.5)])
def test_vector_forms_reduce_to_the_scalar_filters(reinjection, zeta, m, sigma_c):
    N, q, r, s0, ell, eps = 3, 1.0, 25.0, 1.0, 0.25, 0.4
    topo = Topology.from_edges(3, [(0, 1), (1, 2)])
    Q = np.eye(3) - eps * topo.laplacian()
    model = SensorNetworkModel.build([[1.0]], [[q]], [[[1.0]]] * N, [[[r]]] * N, [[s0]], [0.0])
    links = LinkModel(topo, "reliable", rounds=m, noise_std=sigma_c)
    f = FusionFilter(model, links, np.full((N, 1, 1), ell), np.full(2, eps),
                     "reinjection" if reinjection else "consensus", zeta)
    ref = cc.predictive_covariance_sequence(Q, ell=ell, m=m, sigma_c=sigma_c, q=q, r=r, sigma0=s0, n_steps=9,
                                            reinjection=reinjection, zeta=zeta)
    ex = exact_moments(f, 8)["blocks"][:, :, 0, 0]
    # the fused error at the end of step k is the prediction error of k + 1 less the process noise
    assert np.allclose(ex, np.einsum("kii->ki", ref[1:]) - q, rtol=1e-13, atol=0)
    run = cf.simulate_consensus_filter(Q, ell=ell, m=m, sigma_c=sigma_c, q=q, r=r, sigma0=s0, x0_mean=0.0,
                                       n_steps=6, n_trials=4, rng=np.random.default_rng(1),
                                       reinjection=reinjection, zeta=zeta, n_paths=4)
    fr = FusionRun(f, 4)
    for k in range(5):
        ctx = StepContext(k, run.y[:, k, :].T[:, None, :], StepLinks(rounds=[None] * m),
                          heard=[heard(topo, None, 4)] * m, noise=[run.u[:, k, h, :].T[:, None, :] for h in range(m)])
        est = fr.step(ctx)
        assert np.allclose(est[:, 0, :], run.xhat_pred[:, k + 1, :].T, rtol=0, atol=1e-13)


def test_pairwise_averaging_on_reliable_links_is_consensus_with_laplacian_weights():
    model = small_model(5)
    topo = ring(5)
    links = LinkModel(topo, "reliable", rounds=2, noise_std=0.3)
    G = 0.4 * split_gains(model)
    a = FusionRun(FusionFilter(model, links, G, np.full(topo.E, 0.2), "pairwise"), 3)
    b = FusionRun(FusionFilter(model, links, G, np.full(topo.E, 0.2), "consensus"), 3)
    for ctx in contexts(model, links, 6, 3, 0, rounds=2)[0]:
        assert np.array_equal(a.step(ctx), b.step(ctx))


# -- exact mean recursions against enumeration of every link pattern ---------------------------------------

def test_mean_random_round_equals_enumeration():
    rng = np.random.default_rng(0)
    topo = Topology.from_edges(4, [(0, 1), (1, 2), (2, 3), (0, 2)])
    n = 2
    A = rng.standard_normal((8, 8))
    S = jm.from_matrix(A @ A.T, 4)
    q = np.array([0.3, 0.25, 0.2, 0.15])
    s = np.array([0.9, 0.5, 0.7, 0.2])
    want = np.zeros_like(S)
    for bits in itertools.product([0, 1], repeat=4):
        b = np.array(bits)
        p = np.prod(np.where(b, s, 1 - s))
        W = np.eye(4) - (topo.incidence * (b * q)) @ topo.incidence.T
        want += p * jm.node_mix(W, S)
    got = jm.mean_random_round(S, topo.incidence, topo.edges, q, s)
    assert np.allclose(got, want, rtol=0, atol=1e-13 * np.abs(want).max())
    assert n == S.shape[1]


def test_poisson_exchange_moment_equals_enumeration_of_exchange_sequences():
    model = small_model(3)
    topo = Topology.from_edges(3, [(0, 1), (1, 2)])
    links = LinkModel(topo, "poisson", rate=0.02, noise_std=0.4)
    f = FusionFilter(model, links, 0.3 * split_gains(model), np.array([0.3, 0.45]), "pairwise")
    law = links.poisson_count_law()
    rng = np.random.default_rng(1)
    A = rng.standard_normal((6, 6))
    X = jm.from_matrix(A @ A.T, 3)
    want = np.zeros_like(X)
    noise = 0.4 ** 2 * np.eye(2)
    for c, p in enumerate(law):
        for seq in itertools.product(range(topo.E), repeat=c):
            Y = X
            for e in seq:
                W = np.eye(3) - f.weights[e] * np.outer(topo.incidence[:, e], topo.incidence[:, e])
                Y = jm.node_mix(W, Y)
                a, b = topo.edges[e]
                Y = jm.add_block_diagonal(Y, np.stack([noise if i in (a, b) else 0 * noise for i in range(3)]))
            want += p * Y / topo.E ** c
    from dse.estimators.constant_gain_fusion import _fusion_moment

    got = _fusion_moment(f, X)
    assert np.allclose(got, want, rtol=0, atol=1e-12 * np.abs(want).max())


def test_steady_state_is_the_limit_of_the_exact_recursion():
    model = small_model(4)
    topo = ring(4)
    for links in (LinkModel(topo, "reliable", rounds=2, noise_std=0.2),
                  LinkModel(topo, "failures", rounds=2, p_fail=0.3, noise_std=0.2)):
        f = FusionFilter(model, links, 0.5 * split_gains(model), topo.metropolis_weights(), "reinjection", 0.4)
        ss = steady_state(f)
        ex = exact_moments(f, 400)
        assert ss["rho"] < 1
        assert abs(ex["network"][-1] - ss["network"]) <= 1e-9 * ss["network"]


# -- GIKF against the project's Kar & Moura slot -------------------------------------------------------------

def test_gossip_swap_filter_matches_the_gikf_slot_on_the_same_matchings():
    from dse.estimators.gossip_kalman import GossipSystem, gikf_covariance_step

    model = small_model(5)
    topo = ring(5)
    links = LinkModel(topo, "matchings", rounds=1)
    B = 3
    run = GossipSwapRun(model, links, B)
    sys_ = GossipSystem.build(model.F, model.Q, list(model.H), list(model.R), model.P0)
    P = np.broadcast_to(model.P0, (B, 5, 2, 2)).copy()
    ctxs, _ = contexts(model, links, 6, B, 2)
    for ctx in ctxs:
        run.step(ctx)
        partners = np.tile(np.arange(5), (B, 1))
        e, b = np.nonzero(ctx.links.rounds[0])
        partners[b, topo.edges[e, 0]] = topo.edges[e, 1]
        partners[b, topo.edges[e, 1]] = topo.edges[e, 0]
        P = gikf_covariance_step(P, partners, sys_)
        assert np.allclose(sm.from_batched(run.Pbar).transpose(1, 0, 2, 3), P, rtol=1e-12, atol=1e-12)


def test_gossip_swap_estimates_are_kalman_filters_along_the_swap_path():
    """One trial, by hand: each node's state is the state it received, corrected by its own sensor."""
    model = small_model(4)
    topo = ring(4)
    links = LinkModel(topo, "failures", p_fail=0.3, noise_std=0.5)
    run = GossipSwapRun(model, links, 2)
    xs = np.tile(model.x0, (4, 1))
    Ps = np.tile(model.P0, (4, 1, 1))
    ctxs, _ = contexts(model, links, 5, 2, 4)
    for ctx in ctxs:
        run.step(ctx)
        chosen = greedy_matching(topo, ctx.gossip_priority, ctx.links.rounds[0])[:, 0]
        src = np.arange(4)
        for e in np.nonzero(chosen)[0]:
            a, b = topo.edges[e]
            src[a], src[b] = b, a
        new_x, new_P = np.empty_like(xs), np.empty_like(Ps)
        for i in range(4):
            x_in, P_in = xs[src[i]].copy(), Ps[src[i]].copy()
            if src[i] != i:
                x_in += 0.5 * ctx.node_noise[i, :, 0]
                P_in += 0.25 * np.eye(2)
            H, R = model.H[i], model.R[i]
            K = P_in @ H.T @ np.linalg.inv(H @ P_in @ H.T + R)
            xh = x_in + K @ (ctx.y[i, :, 0] - H @ x_in)
            Pp = (np.eye(2) - K @ H) @ P_in
            assert np.allclose(run.estimate[i, :, 0], xh, atol=1e-12)
            new_x[i], new_P[i] = model.F @ xh, model.F @ Pp @ model.F.T + model.Q
        xs, Ps = new_x, new_P


# -- Kalman-consensus, diffusion and CI against per-trial textbook loops ---------------------------------------

def _reference(model, topo, weights, kind, ctxs, B, eps=0.1, sigma=0.0, rounds=1):
    N, n = model.N, model.n
    inv = np.linalg.inv
    xbar = np.tile(model.x0, (B, N, 1))
    P = np.tile(model.P0, (B, N, 1, 1))
    Om = inv(P)
    out = []
    for ctx in ctxs:
        est = np.empty((B, N, n))
        newP = np.empty_like(P)
        for b in range(B):
            mask = np.ones(topo.E, bool) if ctx.links.step_mask is None else ctx.links.step_mask[:, b]
            nb = [[] for _ in range(N)]
            for e in np.nonzero(mask)[0]:
                i, j = topo.edges[e]
                nb[i].append(j)
                nb[j].append(i)
            y = ctx.y[:, :, b]
            if kind == "information-consensus":
                Oi = [Om[b, i] + model.info_matrix[i] for i in range(N)]
                qi = [Om[b, i] @ xbar[b, i] + model.info_weight[i] @ y[i] for i in range(N)]
                for r in range(rounds):
                    mk = None if ctx.links.rounds[r] is None else ctx.links.rounds[r][:, b]
                    W = np.eye(N) - (topo.incidence * (weights * (1 if mk is None else mk))) @ topo.incidence.T
                    Oi = [sum(W[i, j] * Oi[j] for j in range(N)) for i in range(N)]
                    qi = [sum(W[i, j] * qi[j] for j in range(N)) for i in range(N)]
                for i in range(N):
                    est[b, i] = np.linalg.solve(Oi[i], qi[i])
                    Pn = model.F @ inv(Oi[i]) @ model.F.T + model.Q
                    Om[b, i] = inv(Pn)
                continue
            psi = np.empty((N, n))
            for i in range(N):
                if kind == "diffusion":      # sequential incremental update over J_i (Cattivelli & Sayed)
                    x_, P_ = xbar[b, i].copy(), P[b, i].copy()
                    for l in [i] + nb[i]:
                        H, R = model.H[l], model.R[l]
                        Re = R + H @ P_ @ H.T
                        x_ = x_ + P_ @ H.T @ inv(Re) @ (y[l] - H @ x_)
                        P_ = P_ - P_ @ H.T @ inv(Re) @ H @ P_
                    psi[i], newP[b, i] = x_, P_
                else:
                    S = sum(model.info_matrix[j] for j in [i] + nb[i])
                    u = sum(model.info_weight[j] @ y[j] for j in [i] + nb[i])
                    M = inv(inv(P[b, i]) + S)
                    g = eps / (1 + np.linalg.norm(M))
                    cons = sum((xbar[b, j] - xbar[b, i] for j in nb[i]), np.zeros(n))
                    est[b, i] = xbar[b, i] + M @ (u - S @ xbar[b, i]) + g * M @ cons
                    newP[b, i] = M
            if kind == "diffusion":
                W = np.eye(N) - (topo.incidence * (weights * mask)) @ topo.incidence.T
                est[b] = W @ psi
        if kind != "information-consensus":
            P = model.F @ newP @ model.F.T + model.Q
        xbar = est @ model.F.T
        out.append(est)
    return out


@pytest.mark.parametrize("kind", ["kalman-consensus", "diffusion", "information-consensus"])
@pytest.mark.parametrize("link_kind", ["reliable", "failures"])
def test_information_filters_match_textbook_loops(kind, link_kind):
    model = small_model(5, seed=1)
    topo = ring(5)
    rounds = 2 if kind == "information-consensus" else 1
    links = LinkModel(topo, link_kind, rounds=rounds, p_fail=0.4 if link_kind == "failures" else 0.0)
    w = topo.metropolis_weights()
    f = InformationFilter(model, links, kind, w, epsilon=0.3)
    ctxs, _ = contexts(model, links, 5, 3, 7, rounds=rounds)
    run = InformationRun(f, 3)
    ref = _reference(model, topo, w, kind, ctxs, 3, eps=0.3, rounds=rounds)
    for ctx, want in zip(ctxs, ref):
        got = run.step(ctx)
        assert np.allclose(np.moveaxis(got, 2, 0), want, rtol=1e-10, atol=1e-10)


@pytest.mark.parametrize("kind", ["kalman-consensus", "diffusion", "information-consensus"])
def test_information_exact_moments_match_monte_carlo(kind):
    """With reliable links the error is Gaussian with the exact covariance: the mean NEES against
    it is χ²_n / n over the trials (checked at 6 standard errors, fixed seed)."""
    model = small_model(4, seed=2)
    topo = ring(4)
    links = LinkModel(topo, "reliable", rounds=2, noise_std=0.3)
    f = InformationFilter(model, links, kind, topo.metropolis_weights(), epsilon=0.2)
    K, B = 8, 4000
    ex = information_exact(f, K)
    ctxs, xs = contexts(model, links, K, B, 11, rounds=2)
    run = InformationRun(f, B)
    for ctx, x in zip(ctxs, xs):
        err = x[None] - run.step(ctx)
        nees = np.einsum("inb,inm,imb->i", err, np.linalg.inv(ex["blocks"][ctx.k]), err) / B
        assert np.all(np.abs(nees - model.n) < 6 * np.sqrt(2 * model.n / B))


def test_centralized_reference_matches_filterpy():
    from filterpy.kalman import KalmanFilter

    from dse.estimators.network.central import CentralizedKalman

    model = small_model(3, m=2)
    links = LinkModel(ring(3), "reliable")
    ctxs, _ = contexts(model, links, 6, 2, 5)
    c = CentralizedKalman(model, 6, 2)
    kf = KalmanFilter(dim_x=2, dim_z=6)
    kf.F, kf.H, kf.Q, kf.R, kf.P, kf.x = model.F, model.H_all, model.Q, model.R_all, model.P0.copy(), model.x0.copy()
    for ctx in ctxs:
        est = c.step(ctx)
        kf.update(ctx.y[:, :, 0].reshape(-1))
        assert np.allclose(est[0, :, 0], kf.x, rtol=1e-12, atol=1e-12)
        assert np.allclose(c.P_post[ctx.k], kf.P, rtol=1e-12, atol=1e-12)
        kf.predict()


def test_greedy_matching_is_a_maximal_matching_of_the_allowed_edges():
    topo = ring(7)
    rng = np.random.default_rng(0)
    allowed = rng.random((topo.E, 200)) > 0.3
    chosen = greedy_matching(topo, rng.random((topo.E, 200)), allowed)
    assert not np.any(chosen & ~allowed)
    cover = topo.node_edges.astype(int) @ chosen
    assert cover.max() <= 1
    free = cover == 0
    both_free = free[topo.edges[:, 0]] & free[topo.edges[:, 1]] & allowed
    assert not both_free.any()


@pytest.mark.parametrize("link_kind", ["reliable", "failures", "matchings"])
def test_every_filter_is_equivariant_so_error_coordinates_are_exact(link_kind):
    """The simulation runs the filters on x ≡ 0 with y = v and predictions shifted by −w
    (dse.estimators.protocol): the estimate it gets must be x̂ − x of the same filter run on the
    true states, to round-off (relative to the state's size)."""
    from dse.estimators.network.central import CentralizedKalman
    from dse.estimators.network.local import LocalKalman

    model = small_model(4, seed=3)
    topo = ring(4)
    links = LinkModel(topo, link_kind, rounds=2, p_fail=0.3 if link_kind != "reliable" else 0.0, noise_std=0.2)
    w = topo.metropolis_weights()
    G = 0.5 * split_gains(model)
    B = 3
    makers = [lambda: FusionRun(FusionFilter(model, links, G, w, "consensus"), B),
              lambda: FusionRun(FusionFilter(model, links, G, w, "reinjection", 0.4), B),
              lambda: FusionRun(FusionFilter(model, links, G, np.full(topo.E, 0.3), "pairwise"), B),
              lambda: GossipSwapRun(model, links, B), lambda: CentralizedKalman(model, 6, B),
              lambda: LocalKalman(model, 6, B)]
    makers += [lambda kind=kind: InformationRun(InformationFilter(model, links, kind, w, 0.2), B)
               for kind in ("kalman-consensus", "diffusion", "information-consensus")]
    ctxs, xs = contexts(model, links, 6, B, 9, rounds=2)
    rng = np.random.default_rng(9)
    x0 = model.x0[:, None] + np.linalg.cholesky(model.P0) @ rng.standard_normal((model.n, B))   # as `contexts` draws
    for make in makers:
        plain, err = make(), make()
        err.shift(-x0)
        for k, (ctx, x) in enumerate(zip(ctxs, xs)):
            v_ctx = StepContext(ctx.k, ctx.y - np.einsum("imn,nb->imb", model.H, x), ctx.links, heard=ctx.heard,
                                step_heard=ctx.step_heard, step_count=ctx.step_count, noise=ctx.noise,
                                node_noise=ctx.node_noise, gossip_priority=ctx.gossip_priority)
            a = plain.step(ctx)
            b = err.step(v_ctx)
            assert np.allclose(a - x[None], b, rtol=0, atol=1e-10 * (1 + np.abs(x).max())), type(plain).__name__
            if k + 1 < len(xs):
                err.shift(-(xs[k + 1] - model.F @ x))                 # −w(k)


def test_local_filters_exact_disagreement_matches_the_augmented_state_recursion():
    """The local filters' exact disagreement (`network.local.joint_disagreement`, through the stacked errors)
    against an independent computation: the uncentred second moment of (x, x̄_0, …, x̄_{N−1}) (state and
    every node's prediction, with the prior mean x0 ≠ 0) propagated through the filters' affine steps, and
    the disagreement read from the estimates' block through the centring projector I − 11ᵀ/N."""
    from dse.estimators.network.local import joint_disagreement

    model = small_model(4, seed=2, m=2)
    N, n, K = model.N, model.n, 7
    covs = model.local_covariances(K)
    D = (N + 1) * n
    z0 = np.concatenate([model.x0] * (N + 1))
    M = np.outer(z0, z0)
    M[:n, :n] += model.P0                                       # only x(0) is random; every x̄_i(0) = x0
    center = np.eye(N) - np.ones((N, N)) / N
    expected = []
    for k in range(K):
        A = np.zeros((D, D))                                    # (x, x̄_i) -> (x, x̂_i), plus Σ_i K_i v_i
        A[:n, :n] = np.eye(n)
        noise = np.zeros((D, D))
        for i in range(N):
            G, H, r = covs[i].gains[k], model.H[i], slice((i + 1) * n, (i + 2) * n)
            A[r, :n] = G @ H
            A[r, r] = np.eye(n) - G @ H
            noise[r, r] = G @ model.R[i] @ G.T
        M = A @ M @ A.T + noise
        est = M[n:, n:].reshape(N, n, N, n)
        expected.append(np.einsum("ij,iaja->", center, est) / N)
        P = np.kron(np.eye(N + 1), model.F)                     # x ← F x + w, x̄_i ← F x̂_i
        M = P @ M @ P.T
        M[:n, :n] += model.Q
    got = joint_disagreement(model, covs, K)
    assert np.allclose(got, expected, rtol=1e-10, atol=1e-12 * np.max(np.abs(M)))
