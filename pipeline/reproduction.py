"""The contract between the pipeline and a paper's reproduction, and the driver.

A reproduction (one per paper, or one built from a user's scenario file) provides its
claims, a `compute` that runs the scenario -> simulate -> bounds stages through the
stage cache, and a `write_outputs` for figures and recordings. The driver below runs
verify and writes the report; it knows nothing of any one paper.
"""
from __future__ import annotations

import json
import os
import time
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

from .atomic import atomic_write_text
from .cache import StageCache
from .errors import OutputError
from .provenance import provenance
from .report import verdict_counts, write_report
from .simulate import peak_memory_mib
from .verify import Claim, Evaluation, Hypothesis, evaluate


@dataclass(frozen=True)
class RunOptions:
    """User-level knobs of a run. `trials=None` keeps the scenario's own count."""

    seed: int = 0
    trials: int | None = None
    quick: bool = False
    workers: int = 1


class Reproduction(Protocol):
    paper_id: str
    title: str

    def scenario_ids(self) -> list[str]: ...

    def claims(self) -> Sequence[Claim]: ...

    def hypotheses(self) -> Sequence[Hypothesis]: ...

    #: True for the paper's own reproduction: claims of scope "paper-example" are evaluated
    is_paper: bool

    def compute(self, opts: RunOptions, cache: StageCache) -> Any: ...

    def trials(self, opts: RunOptions) -> int: ...

    def write_outputs(self, results: Any, out_dir: Path, claims: list[dict], prov: dict) -> None: ...

    def notes(self) -> str: ...


def check_output_dir(path: Path) -> None:
    """Fail before any long computation if `path` cannot take our outputs."""
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe = path / ".dse-write-probe"
        probe.write_bytes(b"0" * 65536)
        probe.unlink()
    except OSError as exc:
        raise OutputError(f"output directory {path} is not usable: {exc.strerror or exc}") from None


def cache_for(out_root: Path, paper_id: str, *, read_only: bool = False) -> StageCache:
    return StageCache(out_root / ".cache" / paper_id, read_only=read_only)


def run(repro: Reproduction, out_root: Path, opts: RunOptions, *, out_dir: Path | None = None,
        source: dict[str, Any] | None = None) -> dict[str, Any]:
    """Compute, verify, write figures, recordings and the report; return the summary counts."""
    out_dir = out_dir or out_root / repro.paper_id
    check_output_dir(out_dir)
    start = time.perf_counter()
    results = repro.compute(opts, cache_for(out_root, repro.paper_id))
    ev = evaluate_claims(repro, results)
    prov = provenance(seed=opts.seed, trials=repro.trials(opts), quick=opts.quick, workers=opts.workers)
    repro.write_outputs(results, out_dir, ev.claims, prov)
    prov["wall_s"] = time.perf_counter() - start
    prov["peak_memory_mib"] = peak_memory_mib()
    write_report(out_dir, paper=repro.paper_id, title=repro.title, evaluation=ev, provenance=prov, notes=repro.notes())
    atomic_write_text(out_dir / "run.json", json.dumps({"paper": repro.paper_id, "options": asdict(opts),
                                                         "out_root": os.path.relpath(out_root, out_dir), "scenario": source}, indent=1))
    return {"paper": repro.paper_id, **verdict_counts(ev.claims), "wall_s": prov["wall_s"]}


def evaluate_claims(repro: Reproduction, results: Any, **confidence) -> Evaluation:
    """The hypotheses and claims of one computed run (the paper's own example claims only in
    the paper's reproduction); `confidence`: see `pipeline.verify.evaluate`."""
    return evaluate(repro.claims(), repro.hypotheses(), results, paper_run=repro.is_paper, **confidence)


def reverify(repro: Reproduction, out_root: Path, out_dir: Path) -> tuple[list[dict], list[str]]:
    """Re-check every claim from cached stage results only; list differences from report.json."""
    opts = RunOptions(**json.loads((out_dir / "run.json").read_text())["options"])
    results = repro.compute(opts, cache_for(out_root, repro.paper_id, read_only=True))
    rows = evaluate_claims(repro, results).claims
    stored = {r["id"]: r["verdict"] for r in json.loads((out_dir / "report.json").read_text())["claims"]}
    diffs = [f"{r['id']}: report says {stored.get(r['id'])}, re-check gives {r['verdict']}"
             for r in rows if stored.get(r["id"]) != r["verdict"]]
    return rows, diffs
