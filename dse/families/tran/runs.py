"""The simulation stages of the coestimation family: the deterministic runs (coestimation with
time-varying and fixed roles, each also at half the step; the comparison architecture) and the
stochastic Monte Carlo (time-varying roles, fixed roles, fixed roles at half the step).

Runs stream over time: the integrator evaluates the input a chunk of steps at a time and keeps only
the recorded samples (`simulation.record_dt`). The Monte Carlo streams over trials in RNG units of
1,000 (`dse.simulate.units.run_units`, as many units at a time as the memory budget allows; portable: on
the run's unit executor, a Dask cluster with `--scheduler local`) and
keeps, per recorded time, the moments of V = zᵀPz over the trials (merged unit by unit), the
per-trial late-window mean of ‖z‖, the projections on the exact law's principal directions at the
check times, the final-time moments of every node's error, and the first `stochastic.runs` trials
whole. Results do not depend on the budget.
"""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

import dse.estimators.input_state_coestimation as ce
import dse.estimators.observer_network_simulation as sim
from dse.contract.stages import stage
from dse.engine.progress import counter
from dse.simulate.seeding import stream_seed
from dse.simulate.stats import Moments
from dse.simulate.units import RNG_UNIT, LocalProgress, run_units

from .design import Design, coestimation, gains, input_signal, noise_of
from .law import step_operators
from .scenario import CoestimationFile

# a diverging run (an unstable error system: the hypotheses do not hold) is kept with its non-finite values
RUN_MAY_BE_NAN = ("x", "w", "e", "g", "V_mean", "V_m2", "V_max", "late_mean", "late_m2", "proj_mean", "proj_m2",
                  "final_mean", "final_m2", "final_sq_mean", "final_sq_m2", "xerr_mean", "werr_mean", "kept_x",
                  "kept_e", "kept_g")
#: the deterministic runs and their progress labels; the `_half` twins are the step-halving check, the `_sde`
#: ones the fixed-role noise-free run at the stochastic step (the exact mean of the SDE) when it has its own
DETERMINISTIC = {"coest": "coestimation", "coest_half": "coestimation, h/2", "fixed": "fixed roles",
                 "fixed_half": "fixed roles, h/2", "comparison": "comparison", "fixed_sde": "fixed roles, SDE step",
                 "fixed_sde_half": "fixed roles, SDE step / 2"}


@dataclass
class Results:
    scenario: CoestimationFile
    seed: int
    trials: int
    quick: bool
    design: Design
    runs: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def P(self) -> np.ndarray:
        return self.design.P

    def signal(self) -> sim.SinusoidalInput:
        return input_signal(self.scenario)

    def errors(self, run: str) -> np.ndarray:
        """z_i(t) = [x − x̂_i; ŵ_i − w] along a recorded run, (T, N, q)."""
        r = self.runs[run]
        return ce.errors_from_estimates(r["x"], r["w"], r["e"], self.scenario.n)


def mc_moments(r: dict, name: str) -> tuple[np.ndarray, np.ndarray, int]:
    """(mean, standard deviation (ddof = 1), trials) of a Monte Carlo statistic kept as moments."""
    R = int(r["trials"])
    return r[f"{name}_mean"], np.sqrt(np.maximum(r[f"{name}_m2"], 0.0) / max(R - 1, 1)), R


def role_law(sc: CoestimationFile, fixed: bool):
    if fixed:
        return sim.FixedRoles(np.asarray(sc.fixed_roles.active, float))
    roles = sc.roles
    if roles.mode == "fixed":
        return sim.FixedRoles(np.asarray(roles.active, float))
    return sim.ProximityRoles(sc.nodes.positions, roles.radius, roles.beta, tuple(roles.position_states))


def comparison(sc: CoestimationFile, P_b_types: np.ndarray) -> ce.NetworkObserver:
    G = gains(sc)
    sig_b = np.array([sc.types[t].comparison_sigma for t in sc.type_of])
    P_b = np.stack([P_b_types[t] for t in sc.type_of])
    return ce.estimation_network(sc.A, sc.B, G["C"], G["L"], G["J"], G["K"], sig_b, P_b, sc.lap, sc.comparison.alpha,
                                 sc.comparison.gamma)


def deterministic_runs(sc: CoestimationFile, core) -> list[str]:
    """The deterministic runs of the scenario (the comparison needs a certified P of (38)-(39))."""
    runs = ["coest", "coest_half", "fixed", "fixed_half"]
    runs += ["comparison"] if np.all(np.isfinite(core["P_comparison"])) else []
    return runs + (["fixed_sde", "fixed_sde_half"] if sc.stochastic.step != sc.simulation.step else [])


def run_step(sc: CoestimationFile, run: str) -> float:
    h = sc.stochastic.step if "_sde" in run else sc.simulation.step
    return h / 2 if run.endswith("_half") else h


@stage(name="det", allow_nonfinite=RUN_MAY_BE_NAN)
def deterministic_run(sc: CoestimationFile, core: dict, run: str) -> dict[str, np.ndarray]:
    """One noise-free run (`DETERMINISTIC`) at its step, recorded every `simulation.record_dt`."""
    net = comparison(sc, core["P_comparison"]) if run == "comparison" else coestimation(sc, core["P"])
    h, t_end = run_step(sc, run), sc.simulation.t_end
    every = int(round(sc.simulation.record_dt / h))
    with counter(int(round(t_end / h)), desc=f"{sc.name}: {DETERMINISTIC[run]}", unit="step") as bar:
        tr = sim.simulate(net, role_law(sc, run.startswith("fixed")), input_signal(sc), sc.process.x0, sc.e0,
                          t_end=t_end, h=h, record_every=every, allow_nonfinite=True,
                          progress=lambda k: bar.update(k - bar.n))
    return {"t": tr.t, "w": tr.w, "x": tr.x[0], "e": tr.e[0], "g": tr.g[0]}


def integration_error(runs: dict, run: str) -> dict[str, float]:
    """The step-halving estimate of a run: 2·max|Δ| between the run at h and at h/2 on the recorded samples
    (a first-order Richardson estimate, conservative for the second-order scheme and for role switches), the
    scale of the run, and the first time at which either is not finite (nan if none)."""
    a, b = runs[run], runs[f"{run}_half"]
    bad = ~np.isfinite(a["e"]).all(axis=(1, 2)) | ~np.isfinite(b["e"]).all(axis=(1, 2))
    if bad.any():
        return {"error": float("nan"), "scale": float("nan"), "t_bad": float(a["t"][np.argmax(bad)])}
    return {"error": 2.0 * float(np.abs(a["e"] - b["e"]).max()),
            "scale": max(1.0, float(np.abs(a["x"]).max()), float(np.abs(a["w"]).max()), float(np.abs(a["e"]).max())),
            "t_bad": float("nan")}


# -- the Monte Carlo ------------------------------------------------------------------------------------------

def sde_bytes_per_trial(sc: CoestimationFile, n_noise: int) -> int:
    """Memory of one trial in a chunk: the state, the integrator's and the reduction's temporaries, the
    noise draws and the per-trial accumulators."""
    D = sc.n + sc.N * sc.q
    return 8 * (12 * D + 3 * n_noise + 4 * sc.N + 8)


def _unit_moments(values: np.ndarray, edges: np.ndarray, outer: bool = False) -> list[Moments]:
    return [Moments.of(values[a:b], outer) for a, b in zip(edges[:-1], edges[1:])]


class _ChunkStatistics:
    """The accumulators of one chunk of trials (several RNG units), fed at every recorded time by the
    simulator: per unit and recorded time the mean and M2 of V and the sums of the mean node errors ‖x̃_i‖,
    ‖w̃_i‖; per trial the late-window sum of ‖z‖; the projections at the probe times; the final moments."""

    def __init__(self, sc: CoestimationFile, streams, Pbig: np.ndarray, late: np.ndarray, probes: dict):
        self.sc, self.Pbig, self.late, self.probes = sc, Pbig, late, probes
        self.sizes, self.R = streams.sizes, streams.n
        self.edges = np.cumsum([0, *streams.sizes])
        U, n_rec = len(streams.sizes), len(late)
        self.acc = {"V_mean": np.zeros((U, n_rec)), "V_m2": np.zeros((U, n_rec)), "V_max": np.full(U, -np.inf),
                    "err_sums": np.zeros((U, 2, n_rec)), "late": np.zeros(self.R), "proj": {}, "final": None}

    def __call__(self, t_now, x, w, e, g) -> None:
        sc, acc, starts, n = self.sc, self.acc, self.edges[:-1], self.sc.n
        k = int(round(t_now / sc.simulation.record_dt))
        z = ce.errors_from_estimates(x, w, e, n)
        zf = z.reshape(self.R, -1)
        V = np.einsum("ri,ri->r", zf @ self.Pbig, zf)
        mean = np.add.reduceat(V, starts) / np.asarray(self.sizes, float)
        acc["V_mean"][:, k] = mean
        acc["V_m2"][:, k] = np.add.reduceat(np.square(V - np.repeat(mean, self.sizes)), starts)
        acc["V_max"] = np.maximum(acc["V_max"], np.maximum.reduceat(V, starts))
        sq = np.square(z)
        acc["err_sums"][:, 0, k] = np.add.reduceat(np.sqrt(sq[..., :n].sum(-1)).mean(-1), starts)
        acc["err_sums"][:, 1, k] = np.add.reduceat(np.sqrt(sq[..., n:].sum(-1)).mean(-1), starts)
        if self.late[k]:
            acc["late"] += np.sqrt(sq.reshape(self.R, -1).sum(-1))
        if k in self.probes:
            acc["proj"][k] = _unit_moments(zf @ self.probes[k].T, self.edges)
        if k == len(self.late) - 1:
            acc["final"] = (_unit_moments(z, self.edges, outer=True), _unit_moments(sq.sum(-1), self.edges))

    def parts(self) -> list[dict]:
        """The statistics of each unit (folded in unit order: results do not depend on the chunking)."""
        acc = self.acc
        late_mean = acc["late"] / max(int(self.late.sum()), 1)
        final, final_sq = acc["final"]
        return [{"V": Moments(int(b - a), acc["V_mean"][u], acc["V_m2"][u]), "V_max": float(acc["V_max"][u]),
                 "err_sums": acc["err_sums"][u], "late": Moments.of(late_mean[a:b]),
                 "proj": {k: v[u] for k, v in acc["proj"].items()}, "final": final[u], "final_sq": final_sq[u]}
                for u, (a, b) in enumerate(zip(self.edges[:-1], self.edges[1:]))]


def _fold(total: dict | None, part: dict) -> dict:
    if total is None:
        return part
    return {"V": total["V"].merge(part["V"]), "V_max": max(total["V_max"], part["V_max"]),
            "err_sums": total["err_sums"] + part["err_sums"], "late": total["late"].merge(part["late"]),
            "proj": {k: total["proj"][k].merge(part["proj"][k]) for k in total["proj"]},
            "final": total["final"].merge(part["final"]), "final_sq": total["final_sq"].merge(part["final_sq"]),
            "kept": total["kept"] + part["kept"]}


def run_stochastic(sc: CoestimationFile, P: np.ndarray, noise: sim.NoiseModel, *, fixed: bool, trials: int, seed: int,
                   t_end: float, keep: int, h: float, probes: dict[int, np.ndarray] | None = None,
                   budget_bytes: float = 2.0**27) -> dict[str, np.ndarray]:
    """All trials in RNG units of 1,000, as many units per chunk as `budget_bytes` allows; per recorded time
    the moments of V over the trials, the per-trial late-window mean of ‖z‖, the projections on `probes`
    ({record index: directions (k, Nq)}), the final-time moments of every node's error, mean node errors; the
    first `keep` trials whole."""
    net, prepared = coestimation(sc, P), step_operators(sc, P, noise, h)
    dt = sc.simulation.record_dt
    every, n_rec = int(round(dt / h)), int(round(t_end / dt)) + 1
    t = np.arange(n_rec) * dt
    late = t >= min(sc.simulation.tail_start, t[-1] / 2)
    Pbig, probes = ce.block_diag(list(P)), probes or {}
    roles, signal = role_law(sc, fixed), input_signal(sc)
    bar = LocalProgress(counter(int(round(t_end / h)) * trials, desc=f"{sc.name}: {'fixed' if fixed else 'time-varying'} "
                                f"roles, Monte Carlo at h = {h:g}", unit="trial-step"))

    def chunk(streams):
        stats = _ChunkStatistics(sc, streams, Pbig, late, probes)
        k_keep, last = max(0, min(keep - streams.first_unit * RNG_UNIT, streams.n)), [0]

        def advanced(steps_done):
            bar.update(streams.n * (steps_done - last[0]))
            last[0] = steps_done
        tr = sim.simulate(net, roles, signal, sc.process.x0, sc.e0, t_end=t_end, h=h, record_every=every,
                          n_trials=streams.n, noise=noise, rng=streams, keep=k_keep, reducer=stats, prepared=prepared,
                          allow_nonfinite=True, progress=advanced)
        parts, edges = stats.parts(), stats.edges
        for u, part in enumerate(parts):         # the kept trials, with the unit they belong to
            a, b = int(edges[u]), int(min(edges[u + 1], k_keep))
            part["kept"] = [{name: getattr(tr, name)[a:b] for name in ("x", "e", "g")}] if a < b else []
        return parts

    n_noise = 0 if prepared.factors is None else len(prepared.factors)
    with bar.bar:
        acc = run_units(chunk, _fold, trials, stream_seed(seed, "tran", "sde", ("fixed" if fixed else "roles", h)),
                        bytes_per_trial=sde_bytes_per_trial(sc, n_noise), budget_bytes=budget_bytes, portable=True)
    return _summary(acc, t, late, trials, signal, {name: [k[name] for k in acc["kept"]] for name in ("x", "e", "g")})


def _summary(acc: dict, t: np.ndarray, late: np.ndarray, trials: int, signal, kept: dict) -> dict[str, np.ndarray]:
    order = sorted(acc["proj"])
    out = {"t": t, "w": signal(t), "trials": np.array(acc["V"].count), "V_mean": acc["V"].mean, "V_m2": acc["V"].m2,
           "V_max": np.array(acc["V_max"]), "late_mean": np.array(acc["late"].mean), "late_m2": np.array(acc["late"].m2),
           "late_start": np.array(t[late][0]), "xerr_mean": acc["err_sums"][0] / trials,
           "werr_mean": acc["err_sums"][1] / trials, "final_mean": acc["final"].mean, "final_m2": acc["final"].m2,
           "final_sq_mean": acc["final_sq"].mean, "final_sq_m2": acc["final_sq"].m2,
           "probe_index": np.array(order, dtype=int)}
    if order:
        out["proj_mean"] = np.stack([acc["proj"][k].mean for k in order])
        out["proj_m2"] = np.stack([acc["proj"][k].m2 for k in order])
    for name in ("x", "e", "g"):
        out[f"kept_{name}"] = np.concatenate(kept[name]) if kept[name] else np.zeros((0,))
    return out


@stage(name="monte-carlo", unkeyed=("budget_bytes",), allow_nonfinite=RUN_MAY_BE_NAN)
def monte_carlo(sc: CoestimationFile, core: dict, law: dict, fixed: bool, trials: int, seed: int, t_end: float,
                h: float, budget_bytes: float) -> dict[str, np.ndarray]:
    """One stochastic run (`run_stochastic`) of the Monte Carlo; a fixed-role run is projected on the exact
    law's principal directions at the check times within its horizon."""
    probes = {int(k): u for k, u in zip(law["probe_index"], law["probe_dirs"])
              if k * sc.simulation.record_dt <= t_end + 1e-9} if fixed else None
    return run_stochastic(sc, core["P"], noise_of(law), fixed=fixed, trials=trials, seed=seed, t_end=t_end,
                          keep=sc.stochastic.runs, h=h, probes=probes, budget_bytes=budget_bytes)


def fixed_means(sc: CoestimationFile, d: Design, runs: dict) -> dict[str, np.ndarray]:
    """The exact mean part of the fixed-role law: the noise-free run at the stochastic step is the SDE's exact
    mean m(t), so E{V(t)} = m(t)ᵀPm(t) + tr(PΣ(t)) at every record time of the stochastic horizon; the means
    u_jᵀm of the projections at the check times, at h and h/2; m at the end of the horizon per node."""
    law = d.law
    own = sc.stochastic.step != sc.simulation.step
    names = {"h": "fixed_sde" if own else "fixed", "half": "fixed_sde_half" if own else "fixed_half"}
    n_law = len(law["tr_PSigma"])
    zf = {k: ce.errors_from_estimates(runs[r]["x"][:n_law], runs[r]["w"][:n_law], runs[r]["e"][:n_law], sc.n)
          for k, r in names.items()}
    Pbig = ce.block_diag(list(d.P))
    flat = {k: z.reshape(len(z), -1) for k, z in zf.items()}
    idx = law["probe_index"]
    return {"t": runs[names["h"]]["t"][:n_law],
            "EV": np.einsum("ti,ij,tj->t", flat["h"], Pbig, flat["h"]) + law["tr_PSigma"],
            **{f"mean_proj_{k}": np.einsum("ckd,cd->ck", law["probe_dirs"], z[idx]) for k, z in flat.items()},
            "mean_final": zf["h"][-1]}
