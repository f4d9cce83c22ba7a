"""Calibration of the statistical claims: how often does each one fail on valid scenarios?

Every registered family's generator (`dse.families`) draws `seeds` random valid
scenarios; each is computed at quick sample sizes (the smallest a user gets) and every
claim evaluated twice:

- at a fixed per-claim level of 0.95 (α = 0.05), where a claim whose test keeps its level
  fails on at most 5 % of the seeds: the observed rate, with its exact (Clopper-Pearson)
  95 % interval, shows whether the test is calibrated at this sample size, heavy tails
  included; a claim is flagged when the interval lies wholly above 0.05;
- at the report's own family-wise confidence, where no valid scenario should fail at all.

A claim that is `not-checkable` on a seed (too few samples, a hypothesis that does not
hold) is counted apart: it is not a test that ran. Claim ids are made comparable across
seeds by replacing the scenario's name with `<scenario>`.
"""
from __future__ import annotations

import multiprocessing as mp
import sys
import tempfile
import time
from collections import defaultdict
from pathlib import Path

NOMINAL_ALPHA = 0.05


def _one(task: tuple[str, int]) -> dict:
    from dse import registry
    from dse.contract.options import RunOptions
    from dse.contract.context import StageContext
    from dse.engine.cache import StageCache
    from dse.engine.driver import evaluate_claims

    family, seed = task
    t0 = time.perf_counter()
    data = registry.family(family).generate(seed, None)
    repro = registry.from_dict(data)
    names = sorted([repro.paper_id, *repro.scenario_ids()], key=len, reverse=True)

    def key(cid: str) -> str:
        for n in names:
            cid = cid.replace(n, "<scenario>")
        return cid

    try:
        with tempfile.TemporaryDirectory(prefix="dse-calib-") as tmp:
            results = repro.compute(RunOptions(seed=seed, quick=True, workers=1), StageContext(StageCache(Path(tmp))))
    except Exception as exc:  # a run that cannot compute is reported, not hidden
        return {"family": family, "seed": seed, "error": f"{type(exc).__name__}: {exc}", "wall_s": time.perf_counter() - t0}
    at_level = evaluate_claims(repro, results, per_claim_confidence=1 - NOMINAL_ALPHA).claims
    at_report = {r["id"]: r["verdict"] for r in evaluate_claims(repro, results).claims}
    rows = [{"claim": key(r["id"]), "at_level": r["verdict"], "at_report": at_report[r["id"]]}
            for r in at_level if r["kind"] == "statistical"]
    return {"family": family, "seed": seed, "rows": rows, "error": "", "wall_s": time.perf_counter() - t0}


def bench_calibration(seeds: int = 200, workers: int = 2, families: list[str] | None = None) -> list[dict]:
    from dse import registry
    from dse.simulate.stats import clopper_pearson

    families = families or list(registry.families())
    tasks = [(f, s) for f in families for s in range(seeds)]
    outcomes = []
    start = time.perf_counter()
    ctx = mp.get_context("fork")
    with ctx.Pool(workers, maxtasksperchild=20) as pool:
        for i, res in enumerate(pool.imap_unordered(_one, tasks), 1):
            outcomes.append(res)
            if i % 20 == 0 or i == len(tasks):
                el = time.perf_counter() - start
                print(f"[calibration] {i}/{len(tasks)} runs, {el:.0f} s, about {el / i * (len(tasks) - i):.0f} s left",
                      file=sys.stderr, flush=True)
    tally: dict[tuple[str, str], dict[str, int]] = defaultdict(lambda: defaultdict(int))
    errors = defaultdict(list)
    for res in outcomes:
        if res["error"]:
            errors[res["family"]].append(f"seed {res['seed']}: {res['error']}")
            continue
        for r in res["rows"]:
            t = tally[(res["family"], r["claim"])]
            t["runs"] += 1
            t[f"level_{r['at_level']}"] += 1
            t[f"report_{r['at_report']}"] += 1
    rows = []
    for (family, claim), t in sorted(tally.items()):
        tested = t["level_pass"] + t["level_fail"]
        lo, hi = clopper_pearson(t["level_fail"], tested, 0.95) if tested else (float("nan"), float("nan"))
        rows.append({"family": family, "claim": claim, "seeds": t["runs"], "tested": tested,
                     "not_checkable": t["level_not-checkable"], "errors": t["level_error"],
                     "fails_at_0.05": t["level_fail"], "rate": t["level_fail"] / tested if tested else float("nan"),
                     "rate_95ci": (lo, hi), "fails_at_report_level": t["report_fail"],
                     "calibrated": bool(tested) and lo <= NOMINAL_ALPHA and not t["level_error"]})
    for family, errs in errors.items():
        rows.append({"family": family, "claim": "(runs that raised)", "seeds": len(errs), "error": "; ".join(errs[:5])})
    return rows
