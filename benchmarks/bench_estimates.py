"""How good is `dse check`'s estimate? The estimated time of `dse run --quick` against the measured one,
for every shipped scenario file and for scenarios drawn by each family's generator (target: the ratio
estimate / measured within 2x both ways).

Each run is a fresh `python -m dse.cli run --quick FILE --workers W` (imports, figures and recordings
included, as a user waits for it), measured by its wall time and by its CPU time (the process and its
workers, RUSAGE_CHILDREN). With `--workers 1` the CPU time is what the cost models predict whatever the
machine's load (though not wholly: under a load average of 10 on 2 cores the same runs took up to 1.5x the
CPU time of a quiet machine; `load` is the 1-minute load average after the row); the wall time is also
reported (on a loaded machine it includes the waiting).
The estimate is computed in this process (`Reproduction.cost`), as `dse check` computes it.
"""
from __future__ import annotations

import os
import statistics
import sys
import tempfile
from pathlib import Path

from .bench_commands import REPRO, _dse, shipped_scenarios, timed_command
from .common import toml_text

#: the target of the ratio estimate / measured, both ways
TARGET_FACTOR = 2.0


def _generated(seeds: int) -> list[tuple[str, dict]]:
    """(label, scenario dict) drawn by every family's generator: `seeds` plain draws and one per edge case."""
    from dse import registry

    out = []
    for fid, family in registry.families().items():
        if fid == "template":
            continue
        for seed in range(seeds):
            out.append((f"{fid} generated seed {seed}", family.generate(seed, None)))
        for edge in family.edges[:seeds]:
            out.append((f"{fid} generated {edge}", family.generate(0, edge)))
    return out


def _larger() -> list[tuple[str, dict]]:
    """Users' scenarios larger than the generators draw (the sizes issue 21 measured): a hybrid observer of 64
    agents, a compare random geometric graph of 30 nodes with link failures and communication noise."""
    from .bench_wang_liu_morse import agents_scenario

    rgg = {"family": "compare", "name": "rgg30",
           "plant": {"F": [[1.0, 0.1], [0.0, 0.98]], "Q": [[0.01, 0.0], [0.0, 0.05]], "P0": [[1.0, 0.0], [0.0, 1.0]]},
           "sensors": {"types": [{"H": [[1.0, 0.0]], "R": [[0.5]]}, {"H": [[0.0, 1.0]], "R": [[0.5]]}]},
           "graph": {"kind": "random_geometric", "n": 30, "radius": 0.4, "seed": 1},
           "links": {"model": "failures", "p_fail": 0.3, "noise_std": 0.1}}
    return [("hybrid-observer, 64 agents", agents_scenario(64, intervals=15, trials=64)),
            ("compare, 30-node random geometric graph", rgg)]


def estimate_row(label: str, path: Path, workers: int, repeats: int) -> dict:
    """One scenario: the estimate, the measured wall and CPU seconds (medians), their ratios."""
    from dse import api
    from dse.contract.options import RunOptions

    repro = api.load(path)
    est = repro.cost(RunOptions(quick=True, workers=workers))
    times = []
    with tempfile.TemporaryDirectory(prefix="dse-est-") as tmp:
        for r in range(repeats):
            times.append(timed_command(_dse("run", "--quick", str(path), "--out", f"{tmp}/o{r}",
                                            "--workers", str(workers))))
    wall, cpu = statistics.median(t[0] for t in times), statistics.median(t[1] for t in times)
    ok = all(t[2] == 0 for t in times)
    ratio = est.seconds / cpu if workers == 1 else est.seconds / wall      # one worker: CPU time is what is modelled
    return {"scenario": label, "family": repro.family.id, "estimate_s": float(est.seconds), "wall_s": wall, "cpu_s": cpu,
            "est/cpu": float(est.seconds / cpu), "est/wall": float(est.seconds / wall), "ok": ok,
            "target": f"within {TARGET_FACTOR:g}x", "met": bool(ok and 1 / TARGET_FACTOR <= ratio <= TARGET_FACTOR),
            "load": os.getloadavg()[0],       # CPU time also grows on a loaded machine (shared caches, SMT)
            "stages": ", ".join(f"{k} {v:.3g}" for k, v in est.stages.items())}


def bench_estimates(repeats: int = 1, quick: bool = False, workers: int = 1, seeds: int = 2) -> list[dict]:
    """Every shipped scenario and the generated ones (fewer of each with `quick`)."""
    files = [(str(f.relative_to(REPRO)), f) for f in shipped_scenarios()]
    rows = []
    with tempfile.TemporaryDirectory(prefix="dse-gen-") as tmp:
        for label, data in _generated(1 if quick else seeds) + ([] if quick else _larger()):
            f = Path(tmp) / f"{label.replace(' ', '_')}.toml"
            f.write_text(toml_text(data))
            files.append((label, f))
        for label, f in files:
            try:
                rows.append(estimate_row(label, f, workers, repeats))
            except Exception as exc:      # a scenario that cannot be estimated is reported, not hidden
                rows.append({"scenario": label, "error": f"{type(exc).__name__}: {exc}"})
            print(f"[estimates] {rows[-1]}", file=sys.stderr, flush=True)
    return rows


if __name__ == "__main__":
    only = [a for a in sys.argv[1:] if not a.startswith("--")]
    if only:
        for a in only:
            print(estimate_row(a, Path(a), 1, 1))
    else:
        for row in bench_estimates(quick="--quick" in sys.argv):
            print(row)
