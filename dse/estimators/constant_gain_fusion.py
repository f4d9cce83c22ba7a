"""Constant-gain local filters whose estimates are fused over the network, and their exact moments.

Three fusion rules share one local stage: every node corrects its prediction with its own
measurement through a constant gain,

    x̂_i(k|k) = x̄_i(k) + K_i (y_i(k) − H_i x̄_i(k)),                              (L)

and predicts x̄_i(k+1) = F x̂_i^fused(k) after the fusion of the step:

* ``consensus``: Carli, Chiuso, Schenato & Zampieri (2008), as written by Savas, Srivastava &
  Leonard (2017), (7)-(9): m rounds z ← W z (+ noise) from z = x̂(k|k); the fused estimate is z.
  The papers' scalar state (a random walk seen by identical sensors, x̂ ← (1 − ℓ) x̂ + ℓ y) is (L)
  with n = 1, F = 1, H_i = 1, K_i = ℓ; in vector form every node keeps an n-vector, the gains are
  n x m matrices and W acts on the node index (W ⊗ I_n), which is Savas's (9) for each state
  coordinate (the noise vector has independent coordinates, each Savas's σ_c u).
* ``reinjection``: Savas et al. (2017), (11)-(13): z ← W z + x̂(k|k) (+ noise) for m rounds, then
  x̂^fused = ζ x̂(k|k) + (1 − ζ) z / (m + 1). Vector form as above.
* ``pairwise``: Tanwani's constant-gain filters with pairwise averaging, (5)-(6), in discrete
  time: (L) is the discrete analogue of the flow (5) (the gain K_i plays L_i dt over one sample);
  at every exchange the active nodes move to x̂_i + α Σ_{j active} (x̂_j − x̂_i) (6), with
  Π = I − α L (3). Poisson-clocked edges exchange one pair at a time, in time order; a synchronous
  round lets every working edge exchange at once, which is (6) with several active neighbours.

With random links the working edges of each round (or the Poisson exchanges) are drawn afresh
(pipeline of `link_models`); the weight of a failed link falls back on the node itself
(`network_mixing`). With every link working and the Laplacian weights q_e = α, ``pairwise`` and
``consensus`` coincide (a test checks it).

Exact moments: the errors are linear in (x(0), w, v, u) with gains that do not depend on the
data, so the joint error second moment Σ (`joint_moments`) follows an exact recursion. With
random links the mean of Σ over the link draws is exact when the edges of a round are
independent (reliable links, independent failures: `joint_moments.mean_random_round`) and for
Poisson exchanges (the mean map of one exchange on a uniform edge, composed over the truncated
Poisson count); for matchings the edges of a round are dependent and no closed form is used.

Re-injection, with ε_h = (h + 1) x 1 − z_h the error of the consensus variable: ε_0 = e(k|k),
ε_h = W_h ε_{h−1} + e(k|k) − σ_c u_h (using W 1 = 1), and the fused error is
ζ e(k|k) + (1 − ζ) ε_m / (m + 1). Its exact mean recursion carries Z = E[ε εᵀ], C = E[ε eᵀ] and
X = E[e eᵀ]: Z' = E[W Z Wᵀ] + W̄ C + (W̄ C)ᵀ + X + σ_c² E[noise mask], C' = W̄ C + X.
"""
from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
import scipy.linalg as sla

from . import joint_moments as jm
from .link_models import LinkModel
from .network_mixing import Mixer, heard
from .network_step import StepContext, apply_gain, innovation, predict
from .protocol import BatchedFilter
from .sensor_network import SensorNetworkModel

__all__ = ["RULES", "FusionFilter", "FusionRun", "exact_moments", "steady_state", "mean_square_radius",
           "tune_scale", "tune_reinjection"]

RULES = ("consensus", "reinjection", "pairwise")
#: terms of the steady-state series summed per candidate gain while tuning (ρ ≈ 0.99 needs ~2,300)
TUNING_TERMS = 1500
#: relative accuracy of the steady states compared while tuning (the chosen gains' are then computed to 1e-10)
TUNING_RTOL = 1e-7


@dataclass(frozen=True, eq=False)
class FusionFilter:
    """A constant-gain network filter: model, links, gains (N, n, m), edge weights q_e (E,)."""

    model: SensorNetworkModel
    links: LinkModel
    gains: np.ndarray
    weights: np.ndarray
    rule: str = "consensus"
    zeta: float = 1.0

    def __post_init__(self):
        if self.rule not in RULES:
            raise ValueError(f"unknown fusion rule {self.rule!r}")
        if self.rule != "pairwise" and not self.links.synchronous:
            raise ValueError(f"the {self.rule} rule needs synchronous rounds")

    @cached_property
    def mixer(self) -> Mixer:
        return Mixer(self.links.topology, np.asarray(self.weights, float))

    @property
    def rounds(self) -> int:
        return self.links.n_rounds

    def with_gains(self, gains=None, zeta=None) -> "FusionFilter":
        return FusionFilter(self.model, self.links, self.gains if gains is None else gains, self.weights, self.rule,
                            self.zeta if zeta is None else zeta)

    @property
    def exact_available(self) -> tuple[bool, str]:
        if self.links.kind == "matchings" and self.links.random:
            return False, ("the edges of a random matching are dependent: the mean of the second moment over "
                           "matchings has no closed form here (Monte Carlo only)")
        return True, ""


class FusionRun(BatchedFilter):
    """One batch of trials of a `FusionFilter` (state x̄ (N, n, B))."""

    def __init__(self, f: FusionFilter, B: int):
        self.f = f
        self.B = B
        self.xbar = np.broadcast_to(f.model.x0[None, :, None], (f.model.N, f.model.n, B)).copy()
        self.estimate = self.xbar

    def step(self, ctx: StepContext) -> np.ndarray:
        f, m = self.f, self.f.model
        sigma = f.links.noise_std
        xh = self.xbar + apply_gain(f.gains, innovation(ctx.y, m.H, self.xbar))
        if f.links.synchronous:
            z = xh
            for r, mask in enumerate(ctx.links.rounds):
                z = f.mixer.mix(z, mask)
                if f.rule == "reinjection":
                    z = z + xh
                if sigma:
                    z = z + sigma * ctx.noise[r] * ctx.heard[r][:, None, :]
            if f.rule == "reinjection":
                est = f.zeta * xh + (1.0 - f.zeta) / (self.f.rounds + 1) * z
            else:
                est = z
        else:
            est = self._exchanges(xh, ctx)
        self.estimate = est
        self.xbar = predict(m.F, est)
        return est

    def shift(self, delta: np.ndarray) -> None:
        """Add delta (n, B) to every node's prediction (see `network_comparison`: error coordinates)."""
        self.xbar = self.xbar + delta[None]

    def _exchanges(self, x: np.ndarray, ctx: StepContext) -> np.ndarray:
        """Poisson exchanges in time order: both endpoints move towards each other by q_e (6)."""
        x = x.copy()
        topo, q, sigma = self.f.links.topology, self.f.weights, self.f.links.noise_std
        cols = np.arange(self.B)
        for c, ids in enumerate(ctx.links.events):
            live = ids >= 0
            if not live.any():
                break
            b, e = cols[live], ids[live]
            i, j = topo.edges[e, 0], topo.edges[e, 1]
            xi, xj = x[i, :, b], x[j, :, b]
            a = q[e][:, None]
            ni, nj = xi + a * (xj - xi), xj + a * (xi - xj)
            if sigma:
                ni = ni + sigma * ctx.event_noise[c, 0][:, b].T
                nj = nj + sigma * ctx.event_noise[c, 1][:, b].T
            x[i, :, b], x[j, :, b] = ni, nj
        return x


# -- exact moments ----------------------------------------------------------------------------------------

def _round_mean(f: FusionFilter) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(W̄, edge activity s, P(node heard)) of one synchronous round."""
    topo = f.links.topology
    s = f.links.edge_activity()
    inc = topo.incidence
    Wbar = np.eye(topo.n_nodes) - (inc * (s * f.weights)) @ inc.T
    miss = np.ones(topo.n_nodes)
    for (a, b), se in zip(topo.edges, s):
        miss[a] *= 1.0 - se
        miss[b] *= 1.0 - se
    return Wbar, s, 1.0 - miss


def _noise_blocks(prob: np.ndarray, n: int, var: float) -> np.ndarray:
    return (var * prob)[:, None, None] * np.eye(n)


def _parts(f: FusionFilter) -> dict:
    """The constant pieces of the exact step (computed once per filter)."""
    cache = f.__dict__.get("_moment_parts")
    if cache is not None:
        return cache
    m, topo = f.model, f.links.topology
    out = {"A": np.eye(m.n) - f.gains @ m.H, "KRK": f.gains @ m.R @ np.swapaxes(f.gains, 1, 2),
           "var": f.links.noise_std ** 2}
    if f.links.synchronous:
        Wbar, s, p_heard = _round_mean(f)
        v = s * (1.0 - s) * f.weights ** 2
        out.update(Wbar=Wbar, noise=_noise_blocks(p_heard, m.n, out["var"]),
                   pattern=(jm.edge_pattern_matrix(topo.n_nodes, topo.edges) * v) if np.any(v > 0) else None)
    f.__dict__["_moment_parts"] = out
    return out


def _mean_round(parts: dict, Z: np.ndarray, edges: np.ndarray) -> np.ndarray:
    out = jm.node_mix(parts["Wbar"], Z)
    if parts["pattern"] is not None:
        out = out + jm.apply_edge_pattern(parts["pattern"], Z, edges)
    return out


def _fusion_moment(f: FusionFilter, X: np.ndarray) -> np.ndarray:
    """E[ê ê ᵀ] of the fused error from X = E[e eᵀ] of e(k|k) (one step's communication)."""
    if not f.links.synchronous:
        return _poisson_exchanges_moment(f, X)
    p = _parts(f)
    edges = f.links.topology.edges
    var, noise = p["var"], p["noise"]
    if f.rule != "reinjection":
        Z = X
        for _ in range(f.rounds):
            Z = _mean_round(p, Z, edges)
            if var:
                Z = jm.add_block_diagonal(Z, noise)
        return Z
    N = X.shape[0]
    Z, C = X, X
    for _ in range(f.rounds):
        WC = (p["Wbar"] @ C.reshape(N, -1)).reshape(C.shape)
        Z = _mean_round(p, Z, edges) + WC + _swap(WC) + X
        if var:
            Z = jm.add_block_diagonal(Z, noise)
        C = WC + X
    c = (1.0 - f.zeta) / (f.rounds + 1)
    return f.zeta ** 2 * X + f.zeta * c * (C + _swap(C)) + c * c * Z


def _swap(C: np.ndarray) -> np.ndarray:
    """The transposed second moment: (E[a bᵀ])ᵀ = E[b aᵀ] in the (N, n, N, n) layout."""
    return np.transpose(C, (2, 3, 0, 1))


def _poisson_exchanges_moment(f: FusionFilter, X: np.ndarray) -> np.ndarray:
    """Mean over the step's Poisson exchanges: Σ_c P(count = c) T^c(X) with T the mean map of one
    exchange on a uniformly random edge, T(X) = X − (L X + X L)/E + Σ_e q_e² D_e X D_e / E
    (+ σ_c² diag(degree)/E ⊗ I), L = Σ_e q_e D_e."""
    topo, n = f.links.topology, f.model.n
    E = topo.E
    Lq = topo.laplacian(f.weights)
    var = f.links.noise_std ** 2
    noise = _noise_blocks(topo.degrees / E, n, var)
    law = f.links.poisson_count_law()
    N = topo.n_nodes

    def T(Y):
        LY = (Lq @ Y.reshape(N, -1)).reshape(Y.shape)
        out = Y - (LY + _swap(LY)) / E + jm.edge_pattern_sum(Y, topo.edges, f.weights ** 2 / E)
        return jm.add_block_diagonal(out, noise) if var else out

    acc = np.zeros_like(X)
    cur = X
    for c, p in enumerate(law):
        acc += p * cur
        if c + 1 < len(law):
            cur = T(cur)
    return acc


def _local_update_moment(f: FusionFilter, S: np.ndarray) -> np.ndarray:
    p = _parts(f)
    return jm.add_block_diagonal(jm.node_wise(p["A"], S), p["KRK"])


def exact_moments(f: FusionFilter, n_steps: int) -> dict[str, np.ndarray]:
    """The exact mean second moment of the fused errors at the end of each step k < n_steps.

    Returns ``blocks`` (K, N, n, n) = E[e_i e_iᵀ], ``mse`` (K, N), ``disagreement`` (K,), and
    ``network`` (K,) the node average of ``mse``."""
    ok, why = f.exact_available
    if not ok:
        raise ValueError(why)
    m = f.model
    S = jm.common_start(m.N, m.P0)
    blocks = np.empty((n_steps, m.N, m.n, m.n))
    dis = np.empty(n_steps)
    for k in range(n_steps):
        fused = _fusion_moment(f, _local_update_moment(f, S))
        blocks[k] = jm.node_blocks(fused)
        dis[k] = jm.disagreement(fused)
        S = jm.state_wise(m.F, fused, m.Q)
    mse = np.einsum("kiaa->ki", blocks)
    return {"blocks": blocks, "mse": mse, "disagreement": dis, "network": mse.mean(axis=1)}


# -- steady state and gain tuning -----------------------------------------------------------------------

def _affine_step(f: FusionFilter):
    """The mean map of one step on the prior moment S ↦ fused, and S ↦ next prior."""
    m = f.model

    def fused(S):
        return _fusion_moment(f, _local_update_moment(f, S))

    def step(S):
        return jm.state_wise(m.F, fused(S), m.Q)

    return fused, step


def mean_square_radius(f: FusionFilter, iterations: int = 400, tol: float = 1e-4) -> float:
    """Spectral radius of the linear part of the mean second-moment step (ρ < 1: the mean-square
    error converges): exact eigenvalues on reliable links, else Arnoldi iteration (ARPACK) on the map,
    or the midpoint of the Collatz–Wielandt bounds of `radius_bounds` if it does not converge."""
    m = f.model
    if not f.links.random and f.links.synchronous:
        A = _transition_matrix(f)
        return float(np.max(np.abs(np.linalg.eigvals(A)))) ** 2
    lin = _linear_part(f)
    shape = (m.N, m.n, m.N, m.n)
    try:
        from scipy.sparse.linalg import LinearOperator, eigs

        size = int(np.prod(shape))
        op = LinearOperator((size, size), matvec=lambda v: lin(v.reshape(shape)).ravel(), dtype=float)
        lam = eigs(op, k=1, which="LM", tol=1e-10, maxiter=5000, return_eigenvectors=False,
                   v0=np.eye(m.N * m.n).ravel())
        return float(np.abs(lam[0]))
    except Exception:       # ARPACK did not converge: the midpoint of the certified bounds
        lo, hi = radius_bounds(lin, shape, iterations=iterations, gap=tol, decide=False)
        return 0.5 * (lo + hi) if np.isfinite(hi) else lo


def _linear_part(f: FusionFilter):
    """The linear part of the mean step: the same step on the model without any noise (which then
    maps 0 to 0)."""
    m = f.model
    quiet = FusionFilter(_noiseless(m), LinkModel(f.links.topology, f.links.kind, f.links.rounds, f.links.p_fail,
                                                  f.links.rate, 0.0), f.gains, f.weights, f.rule, f.zeta)
    _, qstep = _affine_step(quiet)
    return qstep


def _noiseless(m: SensorNetworkModel) -> SensorNetworkModel:
    return SensorNetworkModel(m.F, np.zeros_like(m.Q), m.H, np.zeros_like(m.R), m.P0, m.x0, m.rows)


def _transition_matrix(f: FusionFilter) -> np.ndarray:
    """Reliable links: the prior-to-prior error transition (I ⊗ F) M (diag(I − K_i H_i)) ⊗, (N n, N n)."""
    m = f.model
    W = f.mixer.matrix
    M = _reliable_fusion_matrix(f, W)
    A = sla.block_diag(*(np.eye(m.n) - f.gains @ m.H))
    return np.kron(np.eye(m.N), m.F) @ np.kron(M, np.eye(m.n)) @ A


def _reliable_fusion_matrix(f: FusionFilter, W: np.ndarray) -> np.ndarray:
    mr = f.rounds
    if f.rule == "reinjection":
        powers = [np.linalg.matrix_power(W, h) for h in range(mr + 1)]
        return f.zeta * np.eye(len(W)) + (1.0 - f.zeta) / (mr + 1) * sum(powers)
    return np.linalg.matrix_power(W, mr)


def steady_state(f: FusionFilter, *, radius: bool = True, max_iter: int = 20_000, rtol: float = 1e-10
                 ) -> dict[str, float | np.ndarray]:
    """Steady state of the exact mean recursion: the fused second moment Σ∞ and its network MSE
    (node average of tr), or inf when the mean-square recursion is unstable.

    Reliable links: the discrete Lyapunov equation S = A S Aᵀ + W on N n x N n (`stein_doubling`), stable
    iff the transition's spectral radius is < 1. Random links: (I − L) S = W solved by GMRES, L the linear
    part of the mean step, a positive map; stability is certified by solving once more with
    W + δ I ≻ 0: a positive definite solution X with X − L(X) ≻ 0 exists iff ρ(L) < 1. `radius`:
    also compute ρ(L) (an eigenvalue problem; the tuning skips it). `max_iter` bounds the terms summed
    on random links (the tuning uses fewer: a gain whose recursion converges that slowly is not a
    candidate)."""
    m = f.model
    fused, step = _affine_step(f)
    zero = np.zeros((m.N, m.n, m.N, m.n))
    rho = np.nan
    if not f.links.random and f.links.synchronous:
        A = _transition_matrix(f)
        rho = float(np.max(np.abs(np.linalg.eigvals(A)))) ** 2
        if not rho < 1.0:
            return {"rho": rho, "network": np.inf, "fused": None}
        S = jm.from_matrix(stein_doubling(A, jm.as_matrix(step(zero))), m.N)
    else:
        S = _solve_random(f, step(zero), _linear_part(f), max_iter=max_iter, rtol=rtol)
        if S is None:
            return {"rho": mean_square_radius(f) if radius else np.nan, "network": np.inf, "fused": None}
        if radius:
            rho = mean_square_radius(f)
    F_ = fused(S)
    return {"rho": rho, "network": float(jm.mean_square_per_node(F_).mean()), "fused": F_}


def radius_bounds(lin, shape, iterations: int = 300, gap: float = 1e-3, decide: bool = True) -> tuple[float, float]:
    """Bounds lo <= ρ(L) <= hi for a positive linear map L on symmetric (N, n, N, n) moments, by the
    Collatz–Wielandt inequalities of the PSD cone: for X ≻ 0, λ_min(X^{-½} L(X) X^{-½}) <= ρ(L) <=
    λ_max(X^{-½} L(X) X^{-½}). Iterates X ← L(X) + small·I from X = I (power iteration, kept positive
    definite) until the bounds are within `gap` (or, with `decide`, as soon as they decide ρ against 1)."""
    Nn = shape[0] * shape[1]
    X = np.eye(Nn)
    lo, hi = 0.0, np.inf
    for _ in range(iterations):
        Y = jm.as_matrix(lin(jm.from_matrix(X, shape[0])))
        Y = 0.5 * (Y + Y.T)
        try:
            L = np.linalg.cholesky(X)
        except np.linalg.LinAlgError:
            break
        Li = sla.solve_triangular(L, np.eye(Nn), lower=True)
        ev = np.linalg.eigvalsh(Li @ Y @ Li.T)
        lo, hi = max(lo, float(ev[0])), min(hi, float(ev[-1]))
        if (decide and (hi < 1.0 or lo >= 1.0)) or hi - lo <= gap * max(hi, 1e-300):
            break
        nrm = float(np.abs(Y).max())
        if not np.isfinite(nrm) or nrm == 0:
            break
        X = Y / nrm + 1e-12 * np.eye(Nn)
    return lo, hi


def stein_doubling(A: np.ndarray, W: np.ndarray, max_doublings: int = 64) -> np.ndarray:
    """S = Σ_k A^k W (A^k)ᵀ for ρ(A) < 1 by doubling (Smith): S ← S + A S Aᵀ, A ← A², until A is
    negligible (each term is PSD, so the partial sums increase to S)."""
    S = 0.5 * (W + W.T)
    Ak = A.copy()
    for _ in range(max_doublings):
        S = S + Ak @ S @ Ak.T
        S = 0.5 * (S + S.T)
        Ak = Ak @ Ak
        if float(np.abs(Ak).max()) < 1e-18:
            break
    return S


def _solve_random(f: FusionFilter, W: np.ndarray, lin, *, rtol: float = 1e-10, max_iter: int = 5000
                  ) -> np.ndarray | None:
    """S = Σ_k L^k(W) summed term by term (each term is PSD, L being a positive map), or None when the
    terms stop shrinking: the mean-square recursion is unstable (or converges too slowly to use).

    Stops when the last term is below `rtol` of the sum and shrinking; the remainder is then at most
    that term times ρ/(1 − ρ), ρ estimated from the last terms' decay."""
    S = W.copy()
    D = W
    norms = []
    for k in range(max_iter):
        D = lin(D)
        S = S + D
        d = float(np.abs(D).max())
        norms.append(d)
        if not np.isfinite(d):
            return None
        scale = float(np.abs(S).max())
        if k >= 20:
            rate = (norms[-1] / max(norms[-11], 1e-300)) ** 0.1
            if rate >= 1.0 and k >= 60:
                return None
            if rate < 1.0 and d * rate / (1.0 - rate) <= rtol * scale:
                return S
        if d == 0.0:
            return S
    return None


def _golden(fun, lo: float, hi: float, iters: int = 30) -> tuple[float, float]:
    g = (np.sqrt(5) - 1) / 2
    a, b = lo, hi
    c, d = b - g * (b - a), a + g * (b - a)
    fc, fd = fun(c), fun(d)
    for _ in range(iters):
        if fc <= fd:
            b, d, fd = d, c, fc
            c = b - g * (b - a)
            fc = fun(c)
        else:
            a, c, fc = c, d, fd
            d = a + g * (b - a)
            fd = fun(d)
    return (c, fc) if fc <= fd else (d, fd)


def tune_scale(f: FusionFilter, base_gains: np.ndarray, *, lo: float = 1e-3, hi: float = 2.0, grid: int = 25,
               iters: int = 25) -> tuple[float, float]:
    """ℓ minimising the steady network MSE of the filter with gains ℓ·base (Carli et al.'s choice of
    the constant gain, for gains of a given shape): a log grid on [lo, hi], then golden-section
    search in log ℓ between the neighbours of the best grid point. Returns (ℓ, MSE)."""
    def J(log_ell):
        return steady_state(f.with_gains(np.exp(log_ell) * base_gains), radius=False, max_iter=TUNING_TERMS,
                            rtol=TUNING_RTOL)["network"]

    xs = np.linspace(np.log(lo), np.log(hi), grid)
    vals = np.array([J(x) for x in xs])
    if not np.isfinite(vals).any():
        return float("nan"), float("inf")
    k = int(np.argmin(vals))
    a, b = xs[max(k - 1, 0)], xs[min(k + 1, grid - 1)]
    x, v = _golden(J, a, b, iters)
    if vals[k] < v:
        x, v = xs[k], vals[k]
    return float(np.exp(x)), float(v)


def tune_reinjection(f: FusionFilter, base_gains: np.ndarray, *, ell0: float, sweeps: int = 2,
                     zeta_grid: int = 11, iters: int = 20) -> tuple[float, float, float]:
    """(ℓ, ζ) minimising the steady network MSE of the re-injection filter (Savas et al. §V-B), by
    coordinate search from (ℓ0, ζ = 1): ζ on a grid of [0, 1] then golden section, then ℓ by golden section
    in log ℓ around the current value. The start, ζ = 1, is the same local filters without fusion, so the
    result is never worse than not communicating. Returns (ℓ, ζ, MSE)."""
    ell, zeta = ell0, 1.0      # the start is the local filters without fusion: the optimum is never worse

    def J(l, z):
        return steady_state(f.with_gains(l * base_gains, z), radius=False, max_iter=TUNING_TERMS,
                            rtol=TUNING_RTOL)["network"]

    best = J(ell, zeta)
    for _ in range(sweeps):
        zs = np.linspace(0.0, 1.0, zeta_grid)
        vals = np.array([J(ell, z) for z in zs])
        k = int(np.argmin(vals))
        z, v = _golden(lambda t: J(ell, t), zs[max(k - 1, 0)], zs[min(k + 1, zeta_grid - 1)], iters)
        if vals[k] < v:
            z, v = zs[k], vals[k]
        if v <= best:
            zeta, best = z, v
        x, v = _golden(lambda t: J(np.exp(t), zeta), np.log(ell) - 1.0, np.log(ell) + 1.0, iters)
        if v <= best:
            ell, best = float(np.exp(x)), v
    return float(ell), float(zeta), float(best)
