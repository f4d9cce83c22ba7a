"""The driver: runs a `dse.contract.Reproduction` (compute, verify, tabulate, draw, report) and
re-checks a finished run from the stage cache. It knows nothing of any one family: it calls
only the members the contract declares.
"""
from __future__ import annotations

import contextlib
import functools
import time
from pathlib import Path
from typing import Any

from dse.contract.options import DEFAULT_MEMORY_FRACTION, RunOptions, machine_memory_mib  # noqa: F401 (re-exported)
from dse.engine.cache import StageCache
from dse.errors import OutputError
from dse.verify.rules import Evaluation, evaluate


def check_output_dir(path: Path) -> None:
    """Fail before any long computation if `path` cannot take our outputs."""
    probe = path / ".dse-write-probe"
    try:
        path.mkdir(parents=True, exist_ok=True)
        probe.write_bytes(b"0" * 65536)
        probe.unlink()
    except OSError as exc:
        try:
            probe.unlink(missing_ok=True)   # a probe half-written on a full disk is not left behind
        except OSError:
            pass
        raise OutputError(f"output directory {path} is not usable: {exc.strerror or exc}") from None


def cache_for(out_root: Path, paper_id: str, *, read_only: bool = False) -> StageCache:
    return StageCache(out_root / ".cache" / paper_id, read_only=read_only)


def run(repro, out_root: Path, opts: RunOptions, *, out_dir: Path | None = None,
        source: dict[str, Any] | None = None, figures: bool = True, fresh: bool = False,
        scenario_file: str | None = None) -> dict[str, Any]:
    """Compute, verify, write tables, figures, recordings and the report; return the summary counts.
    `fresh`: ignore the run memo and the stage cache (recompute every stage, overwrite its entry,
    redraw every view); `scenario_file`: the file the scenario was read from, kept in run.json so
    that `dse verify` can name the command that recomputes the run."""
    from dse.api import execute

    out_dir = out_dir or out_root / repro.paper_id
    check_output_dir(out_root)
    from dse.simulate.units import idle_work

    with idle_work(functools.partial(import_output_libraries, figures)) if opts.workers > 1 else contextlib.nullcontext():
        result = execute(repro, opts, cache_dir=cache_for(out_root, repro.paper_id).root, source=source, fresh=fresh,
                         defer_memo=True)
    result.source_file = scenario_file
    start = time.perf_counter()
    result.write(out_dir, out_root=out_root, figures=figures)
    return {"paper": repro.paper_id, **result.counts, "faults": result.faults,
            "wall_s": result.provenance["compute_s"] + time.perf_counter() - start}


def import_output_libraries(figures: bool) -> None:
    """The libraries every run imports after its Monte Carlo, imported while its stage workers compute
    (`dse.simulate.units.idle_work`), on a core they often leave idle (stages of unequal length), rather
    than one after the other after the claims: pandas and pyarrow for the tables (0.3 s), matplotlib
    for the figures (0.3 s) and rerun for the recordings (0.25 s). The view workers fork with them: each
    worker that wrote a recording imported rerun itself, several per paper (`dse.api.view_jobs`), while this
    process, which runs every paper of a `dse reproduce`, imports it once."""
    import pandas  # noqa: F401
    import pyarrow.parquet  # noqa: F401

    if figures:
        import dse.outputs.record  # noqa: F401 (rerun)
        from dse.outputs.figures import import_pyplot

        import_pyplot()


def evaluate_claims(repro, computed: Any, **confidence) -> Evaluation:
    """The hypotheses (on the design) and claims (on the results) of one computed run (`Computed`; the
    paper's own example claims only in the paper's reproduction); `confidence`: see `dse.verify.rules.evaluate`."""
    return evaluate(repro.claims(), repro.hypotheses(), computed.results, paper_run=repro.is_paper,
                    design=computed.design, **confidence)


#: relative tolerance of `dse verify` on re-computed numbers: the cached stage results are the same
#: bits, so a claim's numbers differ only if the checking code changed (or BLAS reorders a sum)
REVERIFY_RTOL = 1e-9


def reverify(repro, out_root: Path, out_dir: Path) -> tuple[list[dict], list[str]]:
    """Re-check every claim and recompute every table from cached stage results only; the claim rows
    and every difference from what `out_dir` holds (see `dse.engine.reverify.verify_run`)."""
    from dse.engine.reverify import verify_run

    v = verify_run(repro, out_root, out_dir)
    return v.claims, v.diffs


def same_number(a: Any, b: Any, rtol: float = REVERIFY_RTOL) -> bool:
    """Equal numbers (within rtol), lists of them elementwise, anything else by equality."""
    if isinstance(a, list) and isinstance(b, list):
        return len(a) == len(b) and all(same_number(x, y, rtol) for x, y in zip(a, b))
    if isinstance(a, (int, float)) and isinstance(b, (int, float)) and not isinstance(a, bool):
        return a == b or abs(a - b) <= rtol * max(abs(a), abs(b))
    return a == b
