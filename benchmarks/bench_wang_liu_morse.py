"""The hybrid observer: batched trials vs one trial at a time, the q-step estimator per
iteration, ρ by its exhaustive search, the cost model (`dse check`'s estimate) against measured
runs of small and large scenarios (and a long streamed run under a 300 MiB budget), and the
commands people wait on (`dse list`, `dse check`, `dse run --quick`, `dse reproduce`) with
wall and CPU time. Measurements, not tests.

    .venv/bin/python -m benchmarks.bench_wang_liu_morse --estimate     # the cost model's calibration
    .venv/bin/python -m benchmarks.bench_wang_liu_morse --commands     # where people wait
"""
from __future__ import annotations

import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

import dse.estimators.hybrid_observer as ho
import dse.estimators.jointly_observable_design as jd
from dse.families.wang_liu_morse import simulation
from dse.families.wang_liu_morse.scenario import paper_scenarios

ROOT = Path(__file__).resolve().parent.parent


def _simulate(sc, run, x0, w0, xh):
    timing = ho.Timing(sc.T, run.q, run.Delta, run.beta, np.asarray(run.offsets, float))
    return ho.simulate(sc.observer, timing, simulation.schedule_for(sc, run), x0=x0, w0=w0, xhat0=xh,
                       intervals=run.intervals, central_gain=sc.central_gain)


def bench_hybrid(trials: int = 256, repeats: int = 3) -> list[dict]:
    rows = []
    for sc in paper_scenarios():
        run = next(r for r in sc.runs if r.name == "sync")
        rng = np.random.default_rng(0)
        d = sc.observer
        x0 = rng.standard_normal((trials, sc.n))
        w0 = rng.standard_normal((trials, sum(d.n_i)))
        xh = rng.standard_normal((trials, sc.m, sc.n))
        batched, single = [], []
        for _ in range(repeats):
            t0 = time.perf_counter()
            _simulate(sc, run, x0, w0, xh)
            batched.append((time.perf_counter() - t0) / trials)
            t0 = time.perf_counter()
            for b in range(4):
                _simulate(sc, run, x0[b:b + 1], w0[b:b + 1], xh[b:b + 1])
            single.append((time.perf_counter() - t0) / 4)
        b, s = statistics.median(batched), statistics.median(single)
        rows.append({"name": f"hybrid observer {sc.name}/sync: m={sc.m}, q={run.q}, {run.intervals} intervals",
                     "trials": trials, "batched_ms_per_trial": 1e3 * b, "single_trial_ms": 1e3 * s,
                     "iterations_per_s_batched": run.q * run.intervals * trials / (b * trials), "ratio": s / b})
    P = paper_scenarios()[0].observer.P
    t0 = time.perf_counter()
    res = jd.rho_exact(P)
    rows.append({"name": "ρ by exhaustive search, m = 4", "words": res.words,
                 "wall_ms": 1e3 * (time.perf_counter() - t0)})
    return rows


def bench_hybrid_rows(quick: bool = False, repeats: int = 3) -> list[dict]:
    """Side-by-side rows: µs per trial-node-iteration (one iteration = one of the q estimator
    updates of an interval; nodes = the m agents), batched trials vs one trial per call."""
    from .common import estimator_row, timed

    rows = []
    paper, generic = paper_scenarios()
    sizes = [(paper, None, (64,) if quick else (64, 1024))]
    if not quick:   # generic: q = 786 iterations per interval; 8 of its 80 intervals keep the run short
        sizes.append((generic, 8, (256,)))
    for sc, intervals, trial_sizes in sizes:
        run = next(r for r in sc.runs if r.name == "sync")
        if intervals is not None:
            run = run.model_copy(update={"intervals": intervals})
        d = sc.observer
        for trials in trial_sizes:
            rng = np.random.default_rng(0)
            x0 = rng.standard_normal((trials, sc.n))
            w0 = rng.standard_normal((trials, sum(d.n_i)))
            xh = rng.standard_normal((trials, sc.m, sc.n))
            steps = run.q * run.intervals
            per = steps * sc.m
            batched = timed(lambda: _simulate(sc, run, x0, w0, xh), repeats, per=per * trials, warmup=True)
            loop_trials = 2 if quick else 4
            loop = timed(lambda: [_simulate(sc, run, x0[b:b + 1], w0[b:b + 1], xh[b:b + 1]) for b in range(loop_trials)],
                         repeats, per=per * loop_trials)
            rows.append(estimator_row(f"hybrid observer {sc.name}/sync, q={run.q}, {run.intervals} intervals",
                                      f"m={sc.m}, n={sc.n}, {trials:,} trials", nodes=sc.m, state_dim=sc.n, trials=trials,
                                      steps=steps, batched=batched, loop=loop, loop_what="same simulator, 1 trial per call",
                                      loop_trials=loop_trials, unit="µs/trial-node-iteration",
                                      note="hybrid: continuous flow + q discrete iterations per interval"))
    return rows


def random_projections(rng: np.random.Generator, m: int, n: int) -> np.ndarray:
    """m orthogonal projections of R^n onto random subspaces of dimension 1..n-1 (non-commuting)."""
    out = []
    for _ in range(m):
        Qm, _ = np.linalg.qr(rng.standard_normal((n, int(rng.integers(1, n)))))
        out.append(Qm @ Qm.T)
    return np.array(out)


def bench_rho(repeats: int = 3) -> dict:
    """ρ of (17) for five random non-commuting projections of R^4 (N = 17 factors: 5·4^16 words of
    length 17 alone), exact."""
    from .common import bound_row, timed

    P = random_projections(np.random.default_rng(11), 5, 4)
    res = jd.rho_exact(P)
    t = timed(lambda: jd.rho_exact(P), repeats, per=1e3)
    return bound_row(f"wang-liu-morse ρ by exhaustive search, m = 5, n = 4 ({res.words:,} products evaluated, "
                     f"exact: {res.exact})", fast=t, fast_what="batched prefix products, pruned by their norms")


# -- the cost model against measured runs --------------------------------------------------------------

PAPER_A = [[-0.1, 0.4, 0.0, 0.0], [-0.1, -0.1, 0.0, 0.0], [0.0, 0.0, -0.2, 0.2], [0.0, 0.0, -2.0, 0.1]]


def agents_scenario(m: int, *, intervals: int = 20, trials: int = 64, q: int = 30, step: float = 0.01,
                    name: str = "") -> dict:
    """m agents on the paper's plant (n = 4): agent i sees coordinate (2i + floor(i/2)) mod 4 (both
    modes are seen from m = 2 on); a directed ring with every third agent also hearing its second
    predecessor."""
    C = [[[1.0 if c == (2 * i + i // 2) % 4 else 0.0 for c in range(4)]] for i in range(m)]
    neighbors = [[((i - 1) % m) + 1] + ([((i - 2) % m) + 1] if i % 3 == 0 and m > 2 else []) for i in range(m)]
    return {"family": "hybrid-observer", "name": name or f"agents{m}",
            "system": {"A": PAPER_A, "C": C}, "design": {"T": 1.0, "q": q, "lambda": 0.5, "lambda_bar": 1.0},
            "graphs": {"neighbors": [neighbors]},
            "initial": {"x0": [3.0, 2.0, 4.0, 1.0], "xhat0": [[0.0] * 4 for _ in range(m)]},
            "monte_carlo": {"trials": trials, "quick_trials": min(trials, 16)}, "sampling": {"step": step},
            "runs": [{"name": "sync", "intervals": intervals, "monte_carlo": True}]}


def streaming_scenario(intervals: int = 2000, trials: int = 2100) -> dict:
    """Two agents, T = 0.02, q = 2, one sample per interval: the streamed run of
    tests/test_wang_liu_morse_pipeline.py (500 intervals there) over a longer horizon."""
    return {"family": "hybrid-observer", "name": "streaming",
            "system": {"A": [[-0.2, 0.3], [0.0, -0.1]], "C": [[[1.0, -1.0]], [[0.0, 1.0]]]},
            "design": {"T": 0.02, "q": 2, "lambda": 0.8, "lambda_bar": 1.2}, "graphs": {"neighbors": [[[2], [1]]]},
            "initial": {"x0": [1.0, -2.0], "xhat0": [[0.0, 0.0], [0.5, 0.5]]},
            "monte_carlo": {"trials": trials, "scale": 1.0}, "sampling": {"step": 0.02, "stored": 1001},
            "runs": [{"name": "sync", "intervals": intervals, "monte_carlo": True}]}


CASES = {
    "small": agents_scenario(4, intervals=15, trials=64),
    "long_horizon": agents_scenario(4, intervals=2000, trials=64, q=20, step=0.05, name="long"),
    "many_agents": agents_scenario(32, intervals=10, trials=256, q=20, name="agents32"),
    "many_trials": agents_scenario(4, intervals=15, trials=20_000, q=20, step=0.05, name="trials"),
    "long_streaming": streaming_scenario(),
}
#: memory budgets (MiB) of the cases measured under one: the streamed run (compute and tables) stays within it
BUDGETS = {"long_streaming": 300.0}


def measure(data: dict, max_memory_mib: float | None = None, write: bool = True) -> dict:
    """Run one scenario in a fresh process (compute and tables, then with `write` figures and
    recordings): wall time and peak resident memory, next to the estimate for the same options."""
    code = ("import json, resource, sys, time\n"
            "from dse import api\n"
            "from dse.contract.options import RunOptions\n"
            "data = json.loads(sys.argv[1]); mm = json.loads(sys.argv[2])\n"
            "repro = api.load(data)\n"
            "opts = RunOptions(max_memory_mib=mm)\n"
            "est = repro.cost(opts).as_dict()\n"
            "t0 = time.perf_counter()\n"
            "run = api.execute(repro, opts)\n"
            "t1 = time.perf_counter()\n"
            "if sys.argv[4] == '1': run.write(sys.argv[3])\n"
            "t2 = time.perf_counter()\n"
            "hwm = next(int(l.split()[1]) for l in open('/proc/self/status') if l.startswith('VmHWM'))\n"
            "peak = max(hwm, resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss) / 1024\n"
            "use = resource.getrusage(resource.RUSAGE_SELF)\n"
            "print(json.dumps({'estimate_s': est['seconds'], 'estimate_mib': est['peak_memory_mib'],\n"
            "                  'compute_s': t1 - t0, 'wall_s': t2 - t0, 'cpu_s': use.ru_utime + use.ru_stime,\n"
            "                  'peak_mib': peak, 'counts': run.counts}))\n")
    with tempfile.TemporaryDirectory() as tmp:
        proc = subprocess.run([sys.executable, "-c", code, json.dumps(data), json.dumps(max_memory_mib), tmp + "/out",
                               "1" if write else "0"],
                              capture_output=True, text=True, cwd=ROOT,
                              env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "DSE_PROGRESS": "0",
                                   "OPENBLAS_NUM_THREADS": "1", "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1"})
    if proc.returncode:
        raise RuntimeError(proc.stderr[-2000:])
    out = json.loads(proc.stdout.strip().splitlines()[-1])
    out["time_ratio"] = out["wall_s"] / out["estimate_s"]
    out["cpu_ratio"] = out["cpu_s"] / out["estimate_s"]          # the wall time of an unloaded machine
    out["memory_ratio"] = out["peak_mib"] / out["estimate_mib"]
    return out


def bench_estimate(cases: dict | None = None) -> list[dict]:
    rows = []
    for name, data in (cases or CASES).items():
        budget = BUDGETS.get(name)
        row = {"case": name, **measure(data, budget, write=budget is None)}
        if budget is not None:       # the computation within the budget (no figures or recordings)
            row.update(budget_mib=budget, met=row["peak_mib"] < budget)
        rows.append(row)
    return rows


# -- the commands people wait on ---------------------------------------------------------------------------

if __name__ == "__main__":
    if "--estimate" in sys.argv:
        for row in bench_estimate():
            print(row)
    else:
        for row in bench_hybrid_rows(True, 1) + [bench_rho(1)]:
            print(row)
