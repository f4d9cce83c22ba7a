"""The contract between the pipeline and a paper's reproduction, and the driver.

A reproduction (one per paper, or one built from a user's scenario file) provides its
claims, a `compute` that runs the scenario -> simulate -> bounds stages through the
stage cache, and a `write_outputs` for figures and recordings. The driver below runs
verify and writes the report; it knows nothing of any one paper.
"""
from __future__ import annotations

import importlib
import json
import os
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, Sequence

from dse.engine.cache import StageCache
from dse.errors import OutputError
from dse.verify.rules import Claim, Evaluation, Hypothesis, evaluate


def machine_memory_mib() -> float:
    """Physical memory of this machine, in MiB."""
    return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES") / 2**20


#: Default memory budget of a run: this fraction of the machine's physical memory.
DEFAULT_MEMORY_FRACTION = 0.5


@dataclass(frozen=True)
class RunOptions:
    """User-level knobs of a run. `trials=None` keeps the scenario's own count;
    `max_memory_mib=None` is DEFAULT_MEMORY_FRACTION of the machine's memory."""

    seed: int = 0
    trials: int | None = None
    quick: bool = False
    workers: int = 1
    max_memory_mib: float | None = None

    @property
    def memory_budget_mib(self) -> float:
        return self.max_memory_mib if self.max_memory_mib is not None else DEFAULT_MEMORY_FRACTION * machine_memory_mib()

    def chunk_budget_bytes(self, concurrent_arrays: int = 4) -> float:
        """Bytes one Monte Carlo chunk may use in one worker: the budget shared by the workers,
        with room for `concurrent_arrays` arrays of that size (temporaries, accumulators) and
        200 MiB per process for the interpreter and libraries. Never affects results (RNG units
        are fixed; see dse.simulate.units.run_units)."""
        per_worker = self.memory_budget_mib / max(self.workers, 1) - 200.0
        return max(per_worker, 16.0) * 2**20 / max(concurrent_arrays, 1)


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


class FamilyReproduction:
    """What every family's reproduction shares. A family package holds modules `claims` and
    `hypotheses` (each with `catalogue()`) and `tables` (`design_tables(design)`,
    `run_tables(results)`); they are imported on first use, so that `dse list` loads only what it
    prints. A family whose modules differ overrides the method."""

    def _part(self, module: str):
        package = type(self).__module__.rsplit(".", 1)[0]
        return importlib.import_module(f"{package}.{module}")

    def scenario_ids(self) -> list[str]:
        scenarios = getattr(self, "scenarios", None)
        if scenarios is None:
            return [self.scenario.name]
        return [sc.name for sc in (scenarios.values() if isinstance(scenarios, dict) else scenarios)]

    def claims(self) -> Sequence[Claim]:
        return self._part("claims").catalogue()

    def hypotheses(self) -> Sequence[Hypothesis]:
        return self._part("hypotheses").catalogue()

    @staticmethod
    def design_of(results: Any) -> Any:
        return results.design

    def design_tables(self, design: Any):
        return self._part("tables").design_tables(design)

    def tables(self, results: Any):
        return self._part("tables").run_tables(results)

    def table_set(self, results: Any, tables: Any = None):
        """The run's tables as given, or built from the results (outputs drawn without a run's tables)."""
        if tables is None:
            from dse.outputs.tables import Tables

            tables = Tables()
            for table_spec, frame in self.tables(results):
                tables.add(table_spec, frame)
        return tables


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
        source: dict[str, Any] | None = None, figures: bool = True) -> dict[str, Any]:
    """Compute, verify, write tables, figures, recordings and the report; return the summary counts."""
    from dse.api import execute

    out_dir = out_dir or out_root / repro.paper_id
    check_output_dir(out_root)
    result = execute(repro, opts, cache_dir=cache_for(out_root, repro.paper_id).root, source=source)
    start = time.perf_counter()
    result.write(out_dir, out_root=out_root, figures=figures)
    return {"paper": repro.paper_id, **result.counts, "wall_s": result.provenance["compute_s"] + time.perf_counter() - start}


def evaluate_claims(repro: Reproduction, results: Any, **confidence) -> Evaluation:
    """The hypotheses and claims of one computed run (the paper's own example claims only in
    the paper's reproduction); `confidence`: see `dse.verify.rules.evaluate`."""
    design_of = getattr(repro, "design_of", None)
    return evaluate(repro.claims(), repro.hypotheses(), results, paper_run=repro.is_paper,
                    design=design_of(results) if design_of is not None else None, **confidence)


#: relative tolerance of `dse verify` on re-computed numbers: the cached stage results are the same
#: bits, so a claim's numbers differ only if the checking code changed (or BLAS reorders a sum)
REVERIFY_RTOL = 1e-9


def reverify(repro: Reproduction, out_root: Path, out_dir: Path) -> tuple[list[dict], list[str]]:
    """Re-check every claim from cached stage results only; list every difference from report.json
    in verdict, measured, reference or margin (numbers within REVERIFY_RTOL)."""
    opts = RunOptions(**json.loads((out_dir / "run.json").read_text())["options"])
    results = repro.compute(opts, cache_for(out_root, repro.paper_id, read_only=True))
    rows = evaluate_claims(repro, results).claims
    stored = {r["id"]: r for r in json.loads((out_dir / "report.json").read_text())["claims"]}
    diffs = []
    for r in rows:
        old = stored.pop(r["id"], None)
        if old is None:
            diffs.append(f"{r['id']}: not in report.json (re-check gives {r['verdict']})")
            continue
        if old["verdict"] != r["verdict"]:
            diffs.append(f"{r['id']}: report says {old['verdict']}, re-check gives {r['verdict']}")
        for key in ("measured", "reference", "margin"):
            if not same_number(old.get(key), r.get(key)):
                diffs.append(f"{r['id']}: {key} {old.get(key)!r} in report.json, {r.get(key)!r} re-checked")
    diffs += [f"{cid}: in report.json, not re-checked" for cid in stored]
    return rows, diffs


def same_number(a: Any, b: Any, rtol: float = REVERIFY_RTOL) -> bool:
    """Equal numbers (within rtol), lists of them elementwise, anything else by equality."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_number(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return a == b or abs(a - b) <= rtol * max(abs(a), abs(b))
    return a == b
