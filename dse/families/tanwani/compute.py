"""Stages of the random-comm-filter family, each cached: the design per scenario (`design.py`),
the exact references of the checks per scenario, the gridded Monte Carlo per (scenario, λ), the
exact event-driven Monte Carlo and the frozen-clock-path Monte Carlo per scenario, and (paper
only) the topology sweep S4.

Monte Carlo is streamed: trials in RNG units of 1,000 (`dse.simulate.units.run_units`, as many
units per chunk as the memory budget allows; every reduction is made per unit and folded in unit
order, so the numbers do not depend on the budget), and time output by output (gridded) or window
by window (event-driven), accumulating second moments and the test-cell statistics as it goes:
only the moments per output time, the few sample trials and the paired trials are kept.
"""
from __future__ import annotations

import functools
import math
from dataclasses import dataclass, field

import numpy as np
import scipy  # scipy.linalg loads on first use (scipy imports submodules lazily): `dse list` skips it

import dse.estimators.gossip_covariance as gc
import dse.estimators.gossip_filter as gf
import dse.estimators.kalman_bucy as kb
from dse.estimators.linear_flows import van_loan
from dse.engine.cache import StageCache, code_fingerprint
from dse.scenario.graphs import GraphSpec
from dse.simulate.matrix_moments import MatrixMoments
from dse.engine.driver import RunOptions
from dse.simulate.seeding import stream_seed
from dse.simulate.units import BLOCK_MEMORY_BYTES, block_generator, parallel_map, run_units

from .design import Design, ScenarioDesign, joint_ok, kalman_bucy_transient, nonfinite_allowed, scenario_design
from .scenario import FilterNetworkScenario, with_graph

CODE_MODULES = ("dse.estimators.gossip_covariance", "dse.estimators.gossip_filter", "dse.estimators.kalman_bucy",
                "dse.estimators.linear_flows", "dse.simulate.matrix_moments", "dse.simulate.units", "dse.simulate.seeding",
                "dse.families.tanwani.compute", "dse.families.tanwani.design")
FILTERPY_FRACTIONS = (1.0, 0.5, 0.25, 0.125)
TOPOLOGIES = {"path": {"kind": "line", "n": 4}, "ring": {"kind": "ring", "n": 4},
              "star": {"kind": "edges", "n": 4, "edges": [[0, 1], [0, 2], [0, 3]]}, "complete": {"kind": "complete", "n": 4}}
QUICK_TOPOLOGY_POINTS = 8
MAX_TEST_TIMES = 10        # output times at which the Monte Carlo means are tested
MAX_SCHEME_DIM = 20        # N·n above which the gridded scheme's own mean covariance is not formed
PAIR_MAX = 5000            # trials kept one by one for the paired comparison of the two simulators
EPS = float(np.finfo(float).eps)


@dataclass
class ScenarioResults:
    scenario: FilterNetworkScenario
    design: ScenarioDesign
    refs: dict[str, np.ndarray]
    gridded: dict[float, dict[str, np.ndarray]]
    event: dict[str, np.ndarray]
    frozen: dict[str, np.ndarray]
    trials: int
    event_trials: int
    #: the design arrays and the references of the checks, in one dict
    bounds: dict[str, np.ndarray] = field(default_factory=dict)

    def __post_init__(self):
        if not self.bounds:
            self.bounds = {**self.design.bounds, **self.refs}

    @property
    def sys(self) -> gf.GossipSystem:
        return self.scenario.system

    def grid_moments(self, rate: float) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.gridded[rate], "e_")

    def event_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.event, "e_")

    def frozen_moments(self) -> MatrixMoments:
        return MatrixMoments.from_arrays(self.frozen, "e_")

    def bound(self, rate: float) -> np.ndarray:
        return self.bounds[f"bound_t_{self.scenario.rates.index(rate)}"]

    def joint(self, rate: float) -> np.ndarray | None:
        return self.bounds.get(f"joint_t_{self.scenario.rates.index(rate)}")


@dataclass
class Results:
    seed: int
    quick: bool
    is_paper: bool
    scenarios: dict[str, ScenarioResults]
    topology: dict[str, np.ndarray] | None = field(default=None)

    def design(self) -> Design:
        return Design({name: r.design for name, r in self.scenarios.items()})


def trial_counts(sc: FilterNetworkScenario, opts: RunOptions) -> tuple[int, int]:
    if opts.trials is not None:
        return opts.trials, max(50, opts.trials // 5)
    return (sc.quick_trials, sc.quick_event_trials) if opts.quick else (sc.trials, sc.event_trials)


def directions(n: int) -> np.ndarray:
    """The test directions (q = n(n+1)/2, n): the axes e_a and (e_a + e_b)/√2 (a < b), in the
    order of `gc.vech_pairs`; the quadratic forms uᵀXu along them determine a symmetric X."""
    U = []
    for a, b in gc.vech_pairs(n):
        u = np.zeros(n)
        u[a] += 1.0
        u[b] += 1.0
        U.append(u / np.linalg.norm(u))
    return np.array(U)


def test_times(sc: FilterNetworkScenario) -> np.ndarray:
    """Indices (≥ 1) of at most MAX_TEST_TIMES output times spread evenly over (0, T]."""
    T = sc.n_outputs
    k = min(T, MAX_TEST_TIMES)
    return np.unique(np.round(np.linspace(T / k, T, k)).astype(int))


def quadratic_forms(U: np.ndarray, X: np.ndarray) -> np.ndarray:
    """uᵀXu for every direction: X (…, n, n) → (…, q)."""
    return np.einsum("da,...ab,db->...d", U, X, U)


# -- the exact references of the checks ----------------------------------------------------------------

def compute_references(sc: FilterNetworkScenario) -> dict[str, np.ndarray]:
    """What the claims compare the Monte Carlo and the references with, beyond the design: the test-cell
    references (with the second moments of the P-process), the gridded scheme's exact bias and filterpy's
    sampled filter."""
    s = sc.system
    Hs, Vs = np.vstack(s.H), scipy.linalg.block_diag(*s.V)
    base = {"bound_t_0": gc.bound_transient(s, sc.main_rate, sc.output_step, sc.n_outputs),
            "P_kb_t": kalman_bucy_transient(sc)}
    if joint_ok(s):
        base["joint_t_0"] = gc.joint_transient(s, sc.main_rate, sc.output_step, sc.n_outputs)
    out = test_cell_references(sc, base)
    out.update(scheme_bias(sc))
    try:
        P_kb, K_kb = kb.kalman_bucy_steady(s.A, s.B, Hs, Vs)
        stable = np.all(np.isfinite(P_kb)) and np.max(np.linalg.eigvals(s.A - K_kb @ Hs).real) < 0
    except (np.linalg.LinAlgError, ValueError):
        stable = False
    if stable:
        out.update(filterpy_reference(s, Hs, Vs, P_kb))
    return out


def test_cell_references(sc: FilterNetworkScenario, b: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Exact references of the Monte Carlo test cells (main rate, `test_times` × nodes ×
    `directions`): the mean and second moment over clock paths of uᵀP_i(t; τ)u (eq. 14), the
    mean uᵀ𝒫_i(t)u of (9), the exact uᵀE[e_ie_iᵀ](t)u, and uᵀP_KB(t)u."""
    s = sc.system
    U, idx = directions(s.n), test_times(sc)
    q = len(U)
    out = {"cell_times": idx, "cell_dirs": U,
           "cell_bound": quadratic_forms(U, b["bound_t_0"][idx]),
           "cell_kb": quadratic_forms(U, b["P_kb_t"][idx])}
    if "joint_t_0" in b:
        out["cell_joint"] = quadratic_forms(U, gc.diagonal_blocks(b["joint_t_0"][idx], s.N, s.n))
    w = gc.vech_weights(U)
    weights = np.zeros((s.N * q, s.N * q))
    for i in range(s.N):
        weights[i * q:(i + 1) * q, i * q:(i + 1) * q] = w
    mom = gc.bound_second_moments(s, sc.main_rate, sc.output_step, sc.n_outputs, weights, check=True)
    if mom is not None:
        out["cell_P_mean"] = mom[0][idx].reshape(len(idx), s.N, q)
        out["cell_P_second"] = mom[1][idx].reshape(len(idx), s.N, q)
        out["cell_P_accuracy"] = np.array(mom[2])
    return out


def scheme_bias(sc: FilterNetworkScenario) -> dict[str, np.ndarray]:
    """The gridded simulator's own exact mean covariance minus the model's (main rate), at the
    scenario's step h and at h/2, on the output grid: its discretisation bias."""
    s = sc.system
    if s.N * s.n > MAX_SCHEME_DIM:
        return {}
    lam, h = sc.main_rate, sc.grid_step
    every = int(round(sc.output_step / h))
    exact = gc.diagonal_blocks(gc.joint_transient(s, lam, sc.output_step, sc.n_outputs), s.N, s.n)
    b1 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h, every * sc.n_outputs, every), s.N, s.n) - exact
    b2 = gc.diagonal_blocks(gc.gridded_scheme_covariance(s, lam, h / 2, 2 * every * sc.n_outputs, 2 * every),
                            s.N, s.n) - exact
    return {"scheme_bias_h": b1, "scheme_bias_h2": b2}


FILTERPY_MAX_STEPS = 6000


def _dare_residual(F, Qd, Hs, R, X) -> np.ndarray:
    Inn = Hs @ X @ Hs.T + R
    return F @ X @ F.T - F @ X @ Hs.T @ np.linalg.solve(Inn, Hs @ X @ F.T) + Qd - X


def filterpy_reference(s, Hs: np.ndarray, Vs: np.ndarray, P_kb: np.ndarray) -> dict[str, np.ndarray]:
    """filterpy's discrete filter on the sampled model at four sampling steps h, each run until its
    covariance stops changing (at most FILTERPY_MAX_STEPS steps; `filterpy_steady` says whether it
    did), with scipy's DARE solution X and what their difference may be: to first order an
    approximate solution Y of the DARE differs from the exact one by 𝒮⁻¹(R(Y)), 𝒮(Z) = Z − F_cZF_cᵀ
    (F_c the closed loop) and R the residual, so two approximate solutions differ by at most
    ‖𝒮⁻¹‖(‖R(X)‖ + ‖R(Y)‖), doubled for second-order terms, plus rounding (`filterpy_allow`).

    The steps scale with the fastest mode ν of the Kalman–Bucy closed loop A − P_KB HᵀV⁻¹H:
    h = min(0.1, 0.5/ν)·(1, 1/2, 1/4, 1/8), so that hν ≤ 1/2 (the first-order regime of
    the sampled filter)."""
    Ac = s.A - P_kb @ Hs.T @ np.linalg.solve(Vs, Hs)
    nu = float(np.abs(np.linalg.eigvals(Ac)).max())
    hs = min(0.1, 0.5 / max(nu, 1e-12)) * np.array(FILTERPY_FRACTIONS)
    pri, post, dare, steady, allow = [], [], [], [], []
    for h in hs:
        F, Qd = van_loan(s.A, s.B @ s.B.T, h)
        X = scipy.linalg.solve_discrete_are(F.T, Hs.T, Qd, Vs / h)
        Kd = X @ Hs.T @ np.linalg.inv(Hs @ X @ Hs.T + Vs / h)
        Fc = F @ (np.eye(s.n) - Kd @ Hs)
        inv_norm = 1.0 / float(np.linalg.svd(np.eye(s.n * s.n) - np.kron(Fc, Fc), compute_uv=False)[-1])
        prior, posterior = kb.discretised_kalman_covariances(s.A, s.B, Hs, Vs, s.P0, h, FILTERPY_MAX_STEPS,
                                                             until_steady=True)
        res = [float(np.linalg.norm(_dare_residual(F, Qd, Hs, Vs / h, Y), 2)) for Y in (X, prior[-1])]
        allow.append(2 * inv_norm * sum(res) + 10 * 4 * s.n * EPS * float(np.linalg.norm(X, 2)))
        pri.append(prior[-1]), post.append(posterior[-1]), dare.append(X)
        steady.append(len(prior) < FILTERPY_MAX_STEPS)
    return {"filterpy_h": hs, "filterpy_prior": np.array(pri), "filterpy_post": np.array(post),
            "dare_prior": np.array(dare), "filterpy_steady": np.array(steady), "filterpy_allow": np.array(allow),
            "kb_fastest_mode": np.array(nu)}


# -- Monte Carlo ------------------------------------------------------------------------------------

def _spans(streams) -> list[tuple[int, int]]:
    edges = np.cumsum([0, *streams.sizes])
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:])]


def _errors(z: np.ndarray, N: int, n: int) -> np.ndarray:
    """The errors e_i of sampled states z (…, (N+1)n) as (…, N, n)."""
    return z[..., n:].reshape(*z.shape[:-1], N, n)


def gridded_bytes_per_trial(sc: FilterNetworkScenario) -> float:
    """Memory of one gridded trial in a chunk: the state and its copies, the noise draws, the ring counts."""
    s = sc.system
    d = (s.N + 1) * s.n
    return 8.0 * (8 * d + 2 * d + 2 * len(s.clocks)) + 64.0


def simulate_gridded_rate(sc: FilterNetworkScenario, seed: int, trials: int, rate: float, pair: int = 0,
                          budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """The gridded simulator at one rate: second-moment sums of the errors at every output time
    (MatrixMoments), the first sample trials whole, and (`pair` > 0, main rate) the test-cell values
    (uᵀe_i)² of the first `pair` trials one by one, for the paired comparison with the event-driven
    simulator."""
    s = sc.system
    n, N = s.n, s.N
    T = sc.n_outputs + 1
    n_steps = sc.grid_steps
    every = int(round(sc.output_step / sc.grid_step))
    U, cells = directions(n), test_times(sc)
    cell_at = {int(k): c for c, k in enumerate(cells)}
    keep_n = min(sc.sample_trials, trials)
    samples = np.zeros((keep_n, T, (N + 1) * n))
    pair_n = min(pair, trials)
    pairs = np.zeros((pair_n, len(cells), N, len(U)))
    start = [0]                                            # first trial of the chunk

    def chunk(streams):
        spans = _spans(streams)
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]
        first = start[0]

        def record(k, z):
            e = _errors(z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add([k], e[a:b, None])
            rows = min(keep_n - first, len(z))
            if rows > 0:
                samples[first:first + rows, k] = z[:rows]
            rows = min(pair_n - first, len(z))
            if rows > 0 and k in cell_at:
                pairs[first:first + rows, cell_at[k]] = np.square(e[:rows] @ U.T)

        gf.simulate_gridded(s, rate, sc.grid_step, n_steps, every, streams.n, streams, on_record=record)
        start[0] += streams.n
        return parts

    mom = run_units(chunk, lambda acc, part: part if acc is None else MatrixMoments.combine([acc, part]), trials,
                    stream_seed(seed, "gridded", sc.name, rate), bytes_per_trial=gridded_bytes_per_trial(sc),
                    budget_bytes=budget_bytes)
    out = {**mom.arrays("e_"), "sample_z": samples}
    if pair:
        out["pair_values"] = pairs
    return out


def event_bytes_per_trial(sc: FilterNetworkScenario, *, sample: bool = True) -> float:
    """Memory of one event-driven trial in a chunk: its window of outputs (and the copies the reductions
    make), the window's events, the joint covariance and the per-event temporaries (flows, noise
    covariances, jump matrices)."""
    s = sc.system
    N, n = s.N, s.n
    d = (N + 1) * n
    L = event_window(sc)
    per_output = ((d if sample else 0) + 2 * N * n * n) * 8.0
    events = 3 * (gf.EVENTS_PER_WINDOW + 8 * math.sqrt(gf.EVENTS_PER_WINDOW)) * 16.0
    return 1.5 * L * per_output + events + 8.0 * (9 * d * d + 6 * N * n * n + 4 * d) + 256.0


def event_window(sc: FilterNetworkScenario) -> int:
    return gf.default_window(sc.system, sc.main_rate, sc.output_step, sc.n_outputs)


def simulate_event_rate(sc: FilterNetworkScenario, seed: int, trials: int,
                        budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """The exact event-driven simulator at the main rate. Besides the second-moment sums of the
    sampled errors and a few sample paths, it accumulates per test cell (`test_times` × node ×
    `directions`): sums of uᵀP_i(t; τ)u, uᵀΣ_ii(t; τ)u, (uᵀe_i)² and their squares; the sampled
    errors whitened by their own path's exact covariance (squared coordinates, summed, with
    their count); node event counts (sums and number of paths without event); the smallest
    eigenvalue of P_i − Σ_ii seen along every path; the first PAIR_MAX values of (uᵀe_i)²."""
    s = sc.system
    n, N = s.n, s.N
    rate = sc.main_rate
    times = sc.output_times
    T = len(times)
    U, cells = directions(n), test_times(sc)
    q, C = len(U), len(cells)
    pairs = gc.vech_pairs(n)
    cell_of = np.full(T, -1)
    cell_of[cells] = np.arange(C)
    keep_n = min(sc.sample_trials, trials)
    kept = {"z": np.zeros((keep_n, T, (N + 1) * n)), "sigma": np.zeros((keep_n, T, N, n, n)),
            "pbound": np.zeros((keep_n, T, N, n, n)), "t": [[] for _ in range(keep_n)], "c": [[] for _ in range(keep_n)]}
    pair_n = min(PAIR_MAX, trials)
    pair_values = np.zeros((pair_n, C, N, q))
    start = [0]

    def chunk(streams):
        spans = _spans(streams)
        K = streams.n
        first = start[0]
        parts = [{"mom": MatrixMoments.zeros(b - a, T, N, n), **{k: np.zeros((C, N, q)) for k in
                 ("qP1", "qP2", "qS1", "qS2", "qE1", "qE2", "white", "white_n")}} for a, b in spans]
        counts = np.zeros((K, N))
        events = np.zeros(K, dtype=np.int64)
        last = np.full(K, -np.inf)
        spacing = np.full(K, np.inf)

        def on_window(w: gf.EventWindow):
            e = _errors(w.z, N, n)
            sel = cell_of[w.index] >= 0
            ci, wi = cell_of[w.index][sel], np.flatnonzero(sel)
            for part, (a, b) in zip(parts, spans):
                part["mom"].add(w.index, e[a:b])
                if ci.size:
                    qP = quadratic_forms(U, w.pbound[a:b, wi])
                    qS = quadratic_forms(U, w.sigma[a:b, wi])
                    qE = np.square(e[a:b, wi] @ U.T)
                    for key, v in (("qP", qP), ("qS", qS), ("qE", qE)):
                        part[f"{key}1"][ci] = v.sum(0)
                        part[f"{key}2"][ci] = np.square(v).sum(0)
                    part["white"][ci], part["white_n"][ci] = whitened_squares(w.sigma[a:b, wi], e[a:b, wi], pairs)
            if ci.size:
                rows = min(pair_n - first, K)
                if rows > 0:
                    pair_values[first:first + rows, ci] = np.square(e[:rows, wi] @ U.T)
            valid = w.event_clocks >= 0
            if valid.size:
                for c, (i, j) in enumerate(s.clocks):
                    hits = ((w.event_clocks == c) & valid).sum(axis=1)
                    counts[:, i] += hits
                    if s.mode == "edge":
                        counts[:, j] += hits
                events[:] += valid.sum(axis=1)
                t_all = np.concatenate([last[:, None], np.where(valid, w.event_times, np.inf)], axis=1)
                with np.errstate(invalid="ignore"):
                    gaps = np.diff(t_all, axis=1)
                spacing[:] = np.minimum(spacing, np.min(np.where(np.isfinite(gaps), gaps, np.inf), axis=1))
                has = valid.any(axis=1)
                last[has] = np.max(np.where(valid, w.event_times, -np.inf), axis=1)[has]
            rows = min(keep_n - first, K)
            if rows > 0:
                g = slice(first, first + rows)
                kept["z"][g, w.index], kept["sigma"][g, w.index] = w.z[:rows], w.sigma[:rows]
                kept["pbound"][g, w.index] = w.pbound[:rows]
                for r in range(rows):
                    ok = valid[r] if valid.size else np.zeros(0, bool)
                    kept["t"][first + r].append(w.event_times[r][ok])
                    kept["c"][first + r].append(w.event_clocks[r][ok])

        run = gf.simulate_event_driven(s, rate, times, K, streams, window=event_window(sc), on_window=on_window)
        start[0] += K
        for part, (a, b) in zip(parts, spans):
            part.update(c1=counts[a:b].sum(0), c0=(counts[a:b] == 0).sum(0), spacing=float(spacing[a:b].min()),
                        min_gap=float(run.min_gap[a:b].min()),
                        min_rel_gap=float((run.min_gap[a:b] / np.maximum(1.0, run.scale[a:b])).min()),
                        max_scale=float(run.scale[a:b].max()), max_events=int(events[a:b].max(initial=0)),
                        condition=float(run.condition), n=b - a)
        return parts

    def fold(acc, part):
        if acc is None:
            return part
        out = {"mom": MatrixMoments.combine([acc["mom"], part["mom"]])}
        for key in ("qP1", "qP2", "qS1", "qS2", "qE1", "qE2", "white", "white_n", "c1", "c0", "n"):
            out[key] = acc[key] + part[key]
        for key in ("spacing", "min_gap", "min_rel_gap"):
            out[key] = min(acc[key], part[key])
        for key in ("max_scale", "max_events", "condition"):
            out[key] = max(acc[key], part[key])
        return out

    res = run_units(chunk, fold, trials, stream_seed(seed, "event", sc.name, rate),
                    bytes_per_trial=event_bytes_per_trial(sc), budget_bytes=budget_bytes)
    arrays = res.pop("mom").arrays("e_")
    arrays.update({k: np.asarray(v) for k, v in res.items()})
    width = max([1] + [sum(len(x) for x in ts) for ts in kept["t"]])
    ev_t, ev_c = np.full((keep_n, width), np.inf), np.full((keep_n, width), -1, dtype=np.int64)
    for r in range(keep_n):
        t, c = np.concatenate(kept["t"][r] or [np.zeros(0)]), np.concatenate(kept["c"][r] or [np.zeros(0, int)])
        ev_t[r, :len(t)], ev_c[r, :len(c)] = t, c
    arrays.update(sample_z=kept["z"], sample_sigma=kept["sigma"], sample_pbound=kept["pbound"],
                  sample_event_times=ev_t, sample_event_clocks=ev_c, pair_values=pair_values)
    return arrays


WHITEN_RTOL = 1e-9      # eigenvalues of Σ_ii(t; τ) below this fraction of the largest are not whitened


def whitened_squares(sigma: np.ndarray, e: np.ndarray, pairs) -> tuple[np.ndarray, np.ndarray]:
    """Errors whitened by their own path's covariance: with Σ_ii(t; τ) = V diag(w) Vᵀ, the
    coordinates y = diag(w)^(-1/2) Vᵀ e_i are independent N(0, 1) given the clock path when the
    sampler is exact. Returns, per (time, node, cell), the sum over trials of y_a² (cells (a, a))
    and of (y_a + y_b)²/2 (cells (a, b), a < b; also N(0, 1)), and the number of terms (the
    coordinates with w ≤ WHITEN_RTOL·max w are left out: the errors there are rounding)."""
    w, V = np.linalg.eigh((sigma + np.swapaxes(sigma, -1, -2)) / 2)
    ok = w > WHITEN_RTOL * np.maximum(w[..., -1:], 1e-300)
    y = np.einsum("...ab,...a->...b", V, e) / np.sqrt(np.where(ok, w, 1.0))
    sq = np.stack([np.where(ok[..., a], y[..., a] ** 2, 0.0) if a == b
                   else np.where(ok[..., a] & ok[..., b], (y[..., a] + y[..., b]) ** 2 / 2, 0.0) for a, b in pairs], -1)
    cnt = np.stack([ok[..., a] if a == b else ok[..., a] & ok[..., b] for a, b in pairs], -1)
    return sq.sum(0), cnt.sum(0)


def frozen_path(sc: FilterNetworkScenario, seed: int) -> tuple[np.ndarray, np.ndarray]:
    """The one clock path of the frozen-path Monte Carlo (main rate, whole horizon), drawn from the seed."""
    rng = block_generator(stream_seed(seed, "frozen-path", sc.name))
    t, c = gf.sample_clock_events(len(sc.system.clocks), sc.main_rate, sc.horizon, 1, rng)
    return t[0][np.isfinite(t[0])], c[0][c[0] >= 0]


def simulate_frozen(sc: FilterNetworkScenario, seed: int, trials: int,
                    budget_bytes: float = BLOCK_MEMORY_BYTES) -> dict[str, np.ndarray]:
    """One clock path, drawn once, shared by every trial: Monte Carlo over (x0, ω, v) only."""
    s = sc.system
    n, N = s.n, s.N
    T = sc.n_outputs + 1
    path = frozen_path(sc, seed)
    keep = {"path_sigma": np.zeros((T, N, n, n)), "path_pbound": np.zeros((T, N, n, n))}
    start = [0]

    def chunk(streams):
        spans = _spans(streams)
        parts = [MatrixMoments.zeros(b - a, T, N, n) for a, b in spans]
        first = start[0]

        def on_window(w: gf.EventWindow):
            e = _errors(w.z, N, n)
            for part, (a, b) in zip(parts, spans):
                part.add(w.index, e[a:b])
            if first == 0:
                keep["path_sigma"][w.index], keep["path_pbound"][w.index] = w.sigma[0], w.pbound[0]

        run = gf.simulate_event_driven(s, sc.main_rate, sc.output_times, streams.n, streams, clock_path=path,
                                       window=event_window(sc), on_window=on_window)
        if first == 0:
            keep["path_min_gap"] = run.min_gap.min(axis=0)
        start[0] += streams.n
        return parts

    mom = run_units(chunk, lambda acc, part: part if acc is None else MatrixMoments.combine([acc, part]), trials,
                    stream_seed(seed, "frozen", sc.name), bytes_per_trial=event_bytes_per_trial(sc),
                    budget_bytes=budget_bytes)
    return {**mom.arrays("e_"), **keep, "path_times": path[0], "path_clocks": path[1]}


def compute_topology(sc: FilterNetworkScenario, quick: bool = False) -> dict[str, np.ndarray]:
    """S4: S2's plant and sensors on the path, ring, star and complete graphs of 4 nodes."""
    lams = np.geomspace(0.3, 1e4, QUICK_TOPOLOGY_POINTS if quick else 20)
    out: dict[str, np.ndarray] = {"lams": lams}
    for name, g in TOPOLOGIES.items():
        s = with_graph(sc, GraphSpec.from_dict(g), name)
        fied = float(np.sort(np.linalg.eigvalsh(s.laplacian))[1])
        out[f"{name}_alpha_fiedler"] = np.array(s.alpha * fied)
        S = gc.lyapunov_S(s)
        d, tr = np.full((len(lams), s.N), np.nan), np.full((len(lams), s.N), np.nan)
        gap = np.full(len(lams), np.nan)
        for k, lam in enumerate(lams):
            P = gc.bound_steady(s, lam)
            if P is not None:
                d[k] = np.linalg.norm(P - S, axis=(1, 2))
            Jm = gc.joint_steady(s, lam)
            if Jm is not None:
                Jd = gc.diagonal_blocks(Jm, s.N, s.n)
                tr[k] = np.trace(Jd, axis1=1, axis2=2)
                if P is not None:
                    gap[k] = np.linalg.eigvalsh(P - Jd)[:, 0].min()
        out[f"{name}_d"], out[f"{name}_trace_joint"], out[f"{name}_gap"] = d, tr, gap
        out[f"{name}_crit_bound"] = np.array(gc.critical_rate_bound(s))
    return out


# -- the driver --------------------------------------------------------------------------------------

def _nonfinite_allowed(stage: str, sc: FilterNetworkScenario) -> tuple[str, ...]:
    """Arrays where inf/NaN is a result, not a failure: a bound that diverges below the critical
    rate, an explicit bound below its threshold, the inf padding of event lists, Monte Carlo
    states that overflow on a strongly unstable scenario over a long horizon (the claims then
    say that nothing finite was compared)."""
    mc = ("e_s2", "e_s4_trace", "e_s4_entry", "sample_z", "pair_values")
    if stage == "design":
        return nonfinite_allowed(sc)
    if stage == "references":
        return ("cell_bound", "cell_joint", "cell_P_mean", "cell_P_second", "cell_P_accuracy", "cell_kb",
                "scheme_bias_h", "scheme_bias_h2")
    if stage == "event":
        return mc + ("sample_event_times", "spacing", "sample_sigma", "sample_pbound", "qP1", "qP2", "qS1", "qS2",
                     "qE1", "qE2", "white", "min_gap", "min_rel_gap", "max_scale", "condition")
    if stage in ("gridded", "frozen"):
        return mc + ("path_sigma", "path_pbound", "path_min_gap")
    if stage == "topology":
        return tuple(f"{g}_{k}" for g in TOPOLOGIES for k in ("d", "trace_joint", "crit_bound", "gap"))
    return ()


def _work(item):
    cache, stage, params, fn, sc = item
    return cache.get_or_compute(stage, params, fn, scenario=sc.name, allow_nonfinite=_nonfinite_allowed(stage, sc))


def design(scenarios: list[FilterNetworkScenario], opts: RunOptions) -> Design:
    """Every scenario's design, in memory (a run caches it as the stage `design`)."""
    return Design({sc.name: ScenarioDesign(sc, scenario_design(sc, opts.quick, opts.seed)) for sc in scenarios})


def compute(scenarios: list[FilterNetworkScenario], opts: RunOptions, cache: StageCache, *, is_paper: bool) -> Results:
    code = code_fingerprint(CODE_MODULES)
    budget = opts.chunk_budget_bytes()
    items, index = [], []
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        base = {"scenario": sc.key(), "code": code}
        mc = {**base, "seed": opts.seed}
        items.append((cache, "design", {**mc, "quick": opts.quick},
                      functools.partial(scenario_design, sc, opts.quick, opts.seed), sc))
        index.append((sc.name, "design", None))
        items.append((cache, "references", base, functools.partial(compute_references, sc), sc))
        index.append((sc.name, "references", None))
        for rate in sc.rates:
            pair = min(ev_trials, trials, PAIR_MAX) if rate == sc.main_rate else 0
            items.append((cache, "gridded", {**mc, "trials": trials, "rate": rate, "samples": sc.sample_trials,
                                             "pair": pair},
                          functools.partial(simulate_gridded_rate, sc, opts.seed, trials, rate, pair, budget), sc))
            index.append((sc.name, "gridded", rate))
        items.append((cache, "event", {**mc, "trials": ev_trials, "samples": sc.sample_trials},
                      functools.partial(simulate_event_rate, sc, opts.seed, ev_trials, budget), sc))
        index.append((sc.name, "event", None))
        items.append((cache, "frozen", {**mc, "trials": ev_trials},
                      functools.partial(simulate_frozen, sc, opts.seed, ev_trials, budget), sc))
        index.append((sc.name, "frozen", None))
    if is_paper:
        s2 = next(sc for sc in scenarios if sc.name == "s2")
        items.append((cache, "topology", {"scenario": s2.key(), "code": code, "quick": opts.quick},
                      functools.partial(compute_topology, s2, opts.quick), s2))
        index.append(("s2", "topology", None))
    # the longest stages first, so that two workers finish together
    order = sorted(range(len(items)), key=lambda k: {"event": 0, "gridded": 1, "frozen": 2}.get(index[k][1], 3))
    done = parallel_map(_work, [items[k] for k in order], workers=opts.workers, desc="random-comm-filter stages")
    got = {index[k]: v for k, v in zip(order, done)}
    results: dict[str, ScenarioResults] = {}
    for sc in scenarios:
        trials, ev_trials = trial_counts(sc, opts)
        results[sc.name] = ScenarioResults(sc, ScenarioDesign(sc, got[(sc.name, "design", None)]),
                                           got[(sc.name, "references", None)],
                                           {r: got[(sc.name, "gridded", r)] for r in sc.rates},
                                           got[(sc.name, "event", None)], got[(sc.name, "frozen", None)],
                                           trials, ev_trials)
    topo = got.get(("s2", "topology", None)) if is_paper else None
    return Results(opts.seed, opts.quick, is_paper, results, topo)
