"""The Python entry point: load a scenario, run it, read hypotheses, claims and tables.

    import dse                                   # the same functions as dse.api
    run = dse.run("ring8.toml", trials=5000, seed=1)      # or a dict, or dse.paper("savas")
    run.counts                                   # {'pass': 30, 'fail': 0, ...}
    run.hypotheses                               # DataFrame: id, statement, holds, value, threshold, detail
    run.claims                                   # DataFrame: id, verdict, measured, reference, margin, ...
    run.tables["nodes"]                          # DataFrame; run.tables.describe("nodes") gives units
    run.write("out/run/ring8")                   # report, tables, figures, recordings (only when asked)

Nothing is written unless `write` is called or a `cache_dir` is given (the stage cache
that lets a later run resume). The `dse` command line is a thin layer over these functions,
and they fail as it does, in one line: `dse.errors.UsageError` for a bad argument
(`dse.run("ring8.toml", trials=-3)`: "trials: must be >= 1, got -3"), `ScenarioError` for a
bad scenario (naming the field), `OutputError` for an unusable directory, `NumericalError`
(and `NumericalLimit`) for a run whose numbers are not finite or beyond float64.
"""
from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import shutil
import tempfile
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any, Mapping

from dse.contract.context import StageContext
from dse.contract.cost import (CHECK_DESIGN_BUDGET_S, CHECK_NOTE_AFTER_S, human_seconds, refuse_if_too_large,
                               refuse_if_too_long, refuse_long_design, refuse_options, run_refusal)
from dse.contract.family import Reproduction
from dse.contract.options import DEFAULT_WORKERS, RunOptions
from dse.engine.atomic import atomic_write_text
from dse.engine.cache import MemoryCache, StageCache
from dse.engine.driver import evaluate_claims
from dse.engine.memo import load_memo, manifest, save_memo, sha256_file
from dse.engine.progress import note_if_slow
from dse.engine.provenance import provenance
from dse.errors import OutputError, UsageError
from dse.outputs.report import verdict_counts, write_report
from dse.outputs.tables import Tables, spec
from dse.simulate.executor import executor_for, stderr_log, using
from dse.simulate.units import peak_memory_mib
from dse.verify.rules import Evaluation


def load(source: str | os.PathLike | Mapping[str, Any]) -> Reproduction:
    """A validated scenario of a supported family.

    Args:
        source: the path of a TOML scenario file, or a dict of its contents (with its `family` key).

    Raises `ScenarioError` (one line naming the field) on invalid input, `UsageError` when
    `source` is neither a path nor a dict."""
    from dse import registry

    from dse.scenario.fields import load_toml

    _check_source(source, reproduction=False)
    data = dict(source) if isinstance(source, Mapping) else load_toml(source)
    return registry.from_dict(data)


def paper(paper_id: str) -> Reproduction:
    """A paper's own reproduction.

    Args:
        paper_id: the paper's id, as `dse list` shows it (e.g. "savas").

    Raises `ScenarioError` for an unknown id, `UsageError` for one that is not a string."""
    from dse import registry

    if not isinstance(paper_id, str):
        raise UsageError("paper_id", f"must be a paper id such as 'savas' (a string), got {type(paper_id).__name__}")
    return registry.paper(paper_id)


@dataclass
class Run:
    """A computed and checked run: its evaluation (hypotheses and claims), its tables, and the
    stage results behind them (loaded from the stage cache on first use when the run was
    answered from a memo of an identical earlier run)."""

    reproduction: Reproduction
    options: RunOptions
    _results: Any = field(repr=False)
    evaluation: Evaluation = field(repr=False)
    tables: Tables = field(repr=False)
    provenance: dict[str, Any] = field(repr=False)
    source: dict[str, Any] | None = field(default=None, repr=False)
    run_key: str | None = field(default=None, repr=False)
    #: whether `write` may reuse the figures and recordings of an identical earlier run (not after `fresh`)
    reuse_outputs: bool = field(default=True, repr=False)
    #: the file the scenario was read from, if any (run.json keeps it for `dse verify`'s advice)
    source_file: str | None = field(default=None, repr=False)
    #: the memo's saving, left by `execute(..., defer_memo=True)` to `write`, which does it while the figures draw
    _pending_memo: Any = field(default=None, repr=False)

    @property
    def computed(self) -> Any:
        """The design and the results (`dse.contract.Computed`), from the stage cache when the run was a memo."""
        if callable(self._results):
            self._results = self._results()
        return self._results

    @property
    def results(self) -> Any:
        """The family's results object (what the claims are evaluated on)."""
        return self.computed.results

    @property
    def counts(self) -> dict[str, int]:
        return verdict_counts(self.evaluation.claims)

    @property
    def faults(self) -> list[str]:
        """One line per plug-in component that broke its protocol (a family's `faults` table): it was left out
        and every other number is unchanged."""
        if "faults" not in self.tables:
            return []
        return [f"{row.what}" for row in self.tables["faults"].itertuples()]

    @property
    def claims(self):
        return self.tables["claims"]

    @property
    def hypotheses(self):
        return self.tables["hypotheses"]

    def write(self, out_dir: str | os.PathLike, *, out_root: str | os.PathLike | None = None,
              figures: bool = True) -> Path:
        """Write report.json/md, tables/, figures and recordings into `out_dir`, replacing what a
        previous run left there in one step (a fresh directory renamed into place).

        Args:
            out_dir: the run's directory (created; a previous run there is replaced).
            out_root: the output root whose `.cache/` holds this run's stage cache (what `dse verify`
                re-checks from), or None.
            figures: False writes the report and the tables only (no figures, no recordings).

        Raises `UsageError` for an argument that is not a path, `OutputError` for a directory that
        cannot be used."""
        _check_dir(out_dir, "out_dir", optional=False)
        _check_dir(out_root, "out_root")
        out_dir = Path(out_dir)
        staging = _staging_dir(out_dir)
        try:
            start = time.perf_counter()
            outputs = _reuse_outputs(out_dir, staging, self.run_key if self.reuse_outputs else None) if figures else {}
            with self._drawing(staging) if outputs is None else contextlib.nullcontext():
                if self._pending_memo is not None:   # while the figures draw
                    self._pending_memo()
                    self._pending_memo = None
                self.tables.write(staging / "tables")
            if outputs is None:
                outputs = manifest(staging)
            write_s = time.perf_counter() - start
            prov = {**self.provenance, "write_s": write_s, "wall_s": self.provenance["compute_s"] + write_s,
                    "peak_memory_mib": peak_memory_mib()}
            write_report(staging, paper=self.reproduction.paper_id, title=self.reproduction.title,
                         evaluation=self.evaluation, provenance=prov, notes=self.reproduction.notes())
            root = Path(out_root) if out_root is not None else None
            atomic_write_text(staging / "run.json", json.dumps({
                "paper": self.reproduction.paper_id, "options": asdict(self.options),
                "out_root": os.path.relpath(root, out_dir) if root is not None else None,
                "scenario": self.source, "scenario_file": self.source_file, "run_key": self.run_key, "outputs": outputs,
                "checksums": manifest(staging, everything=True)}, indent=1))
            _replace_dir(staging, out_dir)
        finally:
            shutil.rmtree(staging, ignore_errors=True)
        return out_dir

    def _drawing(self, staging: Path):
        """The family's views (figures and recordings) drawn while the `with` block runs, in forked workers
        when there are several (`dse.outputs.figures.drawing`)."""
        from dse.contract.views import Outputs
        from dse.outputs.figures import drawing

        views = self.reproduction.views(Outputs(self.reproduction, self.results, self.tables, self.evaluation.claims,
                                                self.provenance))
        jobs = view_jobs(views, self.options.workers)
        return drawing([lambda g=g: [v.draw(staging / v.file) for v in g] for g in jobs], workers=self.options.workers,
                       shared_pyplot=sum(any(Path(v.file).suffix == ".png" for v in g) for g in jobs) > 1)


def view_jobs(views: list, workers: int) -> list[list]:
    """The views in jobs for `workers` forked processes, which take the next job when done: the recordings
    first, together (a worker starting on them imports rerun, a quarter of a second, unless this process imported
    it already: `dse.engine.driver.import_output_libraries`; with many views, in chunks of about a 2·workers-th
    of them), then every figure as a job of its own. Matplotlib is imported
    before the workers fork (`dse.outputs.figures.drawing`), so any worker draws any figure at no extra
    cost, and the figures fill in around the recordings and each other: grouped by count, a few heavy
    figures left one worker drawing while the other waited (compare's three, a third of its run)."""
    kinds: dict[str, list] = {}
    for v in sorted(views, key=lambda v: Path(v.file).suffix != ".rrd"):
        kinds.setdefault(Path(v.file).suffix, []).append(v)
    size = -(-len(views) // (2 * workers)) if len(views) >= 4 * workers else len(views)
    jobs = []
    for suffix, group in kinds.items():
        step = 1 if suffix == ".png" else size
        jobs += [group[i:i + step] for i in range(0, len(group), step)]
    return jobs


def execute(repro: Reproduction, opts: RunOptions, *, cache_dir: str | os.PathLike | None = None,
            source: dict[str, Any] | None = None, fresh: bool = False, defer_memo: bool = False) -> Run:
    """Compute (through the stage cache when `cache_dir` is given), verify and tabulate.

    With a `cache_dir`, the evaluation and the tables are also kept as a memo keyed by
    everything that determines them (the paper or the scenario as given, seed, trials, quick,
    and a fingerprint of the project's code and scenario files): an identical later run reads
    them back instead of re-checking (unless a stage entry it stands on changed since), and
    loads the stage results only if it needs them. `fresh=True` ignores the memo and the stage
    cache: every stage is recomputed and its entry overwritten, and `write` redraws every view.

    Args:
        repro: the reproduction to run (`load`, `paper`).
        opts: the run's options (`run_options` checks them as `run` does).
        cache_dir: the stage cache's directory, or None (in memory).
        source: the scenario as given (a parsed file), kept in run.json; None for a paper.
        fresh: recompute every stage and ignore the memo (like `--fresh`).
        defer_memo: leave saving the memo to the run's `write` (which the caller then calls), where it
            overlaps the drawing of the figures."""
    if not isinstance(repro, Reproduction) or not isinstance(opts, RunOptions):
        raise UsageError("repro" if not isinstance(repro, Reproduction) else "opts",
                         "must be a Reproduction (dse.load, dse.paper) and a RunOptions (dse.api.run_options)")
    _check_dir(cache_dir, "cache_dir")

    start = time.perf_counter()
    refuse_options(repro, opts)
    key = run_key(repro, opts, source)
    memo = load_memo(Path(cache_dir), key) if cache_dir is not None and not fresh else None
    pending = None
    if memo is not None:
        ev, tables, stages = memo
        computed: Any = lambda: repro.compute(opts, StageContext(StageCache(Path(cache_dir))))  # noqa: E731 - when needed
        stages = [{**s, "cached": True} for s in stages]
    else:
        refuse_beyond_limits(repro, opts)
        ctx = StageContext(MemoryCache() if cache_dir is None else StageCache(Path(cache_dir), fresh=fresh))
        with using(executor_for(opts.scheduler, opts.workers, log=stderr_log)):
            computed = repro.compute(opts, ctx)
        ev = evaluate_claims(repro, computed)
        tables = evaluation_tables(ev)
        for table_spec, frame in repro.tables(computed.results):
            tables.add(table_spec, frame)
        stages = ctx.ran
        if cache_dir is not None:
            pending = functools.partial(save_memo, Path(cache_dir), key, ev, tables, stages)
            if not defer_memo:
                pending()
                pending = None
    prov = provenance(seed=opts.seed, trials=repro.trials(opts), quick=opts.quick, workers=opts.workers)
    prov["compute_s"] = time.perf_counter() - start
    prov["wall_s"] = prov["compute_s"]
    prov["peak_memory_mib"] = peak_memory_mib()
    prov["memo"] = memo is not None
    prov["stages"] = stages
    return Run(repro, opts, computed, ev, tables, prov, source, key, reuse_outputs=not fresh, _pending_memo=pending)


def refuse_beyond_limits(repro: Reproduction, opts: RunOptions) -> None:
    """Refuse (ScenarioError, one line) a run whose cost estimate is beyond its memory budget or its --max-time,
    before it computes anything: what `execute`, a sweep's point and the prefetcher of `dse reproduce` all check."""
    estimate = repro.cost(opts)
    refuse_if_too_large(estimate, opts)
    refuse_if_too_long(estimate, opts, trials_field(repro, opts))


def trials_field(repro: Reproduction, opts: RunOptions) -> str:
    """What sets the run's trials (named when the run is refused as too long): the option, or the scenario key."""
    return "--trials" if opts.trials is not None else (repro.family.trials_key or "scenario")


def run_key(repro: Reproduction, opts: RunOptions, source: dict[str, Any] | None) -> str:
    """What determines a run's evaluation, tables, figures and recordings (the number of workers
    and the memory budget do not: results are identical whatever they are)."""
    from dse.engine.cache import canonical_json, project_fingerprint

    what = {"paper": repro.paper_id, "is_paper": repro.is_paper, "source": source, "seed": opts.seed,
            "trials": opts.trials, "quick": opts.quick, "external_code": repro.external_code()}
    ident = hashlib.sha256(canonical_json(what).encode()).hexdigest()[:16]
    return f"{ident}-{hashlib.sha256((ident + project_fingerprint()).encode()).hexdigest()[:16]}"


def _reuse_outputs(out_dir: Path, staging: Path, key: str | None) -> dict[str, str] | None:
    """Figures and recordings of the previous run in `out_dir`, hard-linked (or copied) into
    `staging`, when that run had the same run key and its files are intact; else None."""
    if key is None:
        return None
    try:
        meta = json.loads((out_dir / "run.json").read_text())
        if meta.get("run_key") != key or not isinstance(meta.get("outputs"), dict) or not meta["outputs"]:
            return None
        for rel, digest in meta["outputs"].items():
            if sha256_file(out_dir / rel) != digest:
                return None
        for rel in meta["outputs"]:
            target = staging / rel
            target.parent.mkdir(parents=True, exist_ok=True)
            try:
                os.link(out_dir / rel, target)
            except OSError:
                shutil.copy2(out_dir / rel, target)
        return dict(meta["outputs"])
    except (OSError, ValueError, TypeError):
        return None


def run(source: str | os.PathLike | Mapping[str, Any] | Reproduction, *, seed: int = 0, trials: int | None = None,
        quick: bool = False, workers: int = DEFAULT_WORKERS, max_memory: int | float | str | None = None,
        cache_dir: str | os.PathLike | None = None, max_time_s: float | None = None, scheduler: str = "auto") -> Run:
    """Load (unless given a reproduction), compute, verify and tabulate one scenario; nothing is written.

    Args:
        source: a scenario file's path, a dict of its contents, or a reproduction (`paper(...)`, `load(...)`).
        seed: root random seed (an integer >= 0), like `--seed`.
        trials: Monte Carlo trials per cell (an integer >= 1), like `--trials`; None keeps the scenario's.
        quick: fewer trials and coarser grids, like `--quick`.
        workers: worker processes (an integer >= 1; the command line's default). Results do not depend on it.
        max_memory: the memory budget, in MiB (a number) or as on the command line ("4G", "800M"); None is
            half of this machine's memory. Results do not depend on it.
        cache_dir: a directory for the stage cache (a later identical run resumes from it); None keeps
            everything in memory.
        max_time_s: a run estimated to take longer than this many seconds is refused before it starts,
            like `--max-time` (None: a day; `math.inf`: no limit).
        scheduler: where the Monte Carlo runs, like `--scheduler`: "auto" (the stages in `workers` forked
            processes), "inline" (all in this process), "local" (the units on a local Dask cluster of
            `workers` processes) or the address of a running Dask scheduler ("tcp://HOST:8786"). Results do
            not depend on it.

    Raises `UsageError` for an invalid argument and `ScenarioError` for an invalid scenario or a refused
    run (both one line, as the command line prints them), `NumericalError` (and its `NumericalLimit`)
    for a run whose numbers are not finite or beyond float64."""
    opts = run_options(seed=seed, trials=trials, quick=quick, workers=workers, max_memory=max_memory,
                       max_time_s=max_time_s, scheduler=scheduler)
    _check_source(source)
    _check_dir(cache_dir, "cache_dir")
    if isinstance(source, (str, os.PathLike, Mapping)):
        data = dict(source) if isinstance(source, Mapping) else None
        repro = load(source)
        if data is None:
            from dse.scenario.fields import load_toml

            data = load_toml(source)
    else:
        repro, data = source, None
    return execute(repro, opts, cache_dir=cache_dir, source=data)


# -- the arguments of the public functions, checked as the command line checks its options ----------------

#: the largest seed and trial count accepted (as on the command line)
MAX_COUNT = 10**12


def run_options(*, seed: Any = 0, trials: Any = None, quick: Any = False, workers: Any = DEFAULT_WORKERS,
                max_memory: Any = None, max_time_s: Any = None, scheduler: Any = "auto") -> RunOptions:
    """`RunOptions` from the arguments of `run` and `check` (see `run`); `UsageError` naming the first bad one."""
    from dse.simulate.cluster import check_scheduler

    if not isinstance(quick, bool):
        raise UsageError("quick", f"must be True or False, got {quick!r}")
    return RunOptions(seed=_count(seed, "seed", 0), trials=None if trials is None else _count(trials, "trials", 1),
                      quick=quick, workers=_count(workers, "workers", 1), max_memory_mib=_memory_mib(max_memory),
                      max_time_s=_seconds(max_time_s, "max_time_s"),
                      scheduler=check_scheduler(scheduler, "scheduler", UsageError))


def _seconds(value: Any, name: str) -> float | None:
    """None, or a positive number of seconds (`math.inf`: no limit)."""
    if value is None:
        return None
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not value > 0:
        raise UsageError(name, f"must be a positive number of seconds (math.inf: no limit), got {value!r}")
    return float(value)


def _count(value: Any, name: str, low: int) -> int:
    import numbers

    if isinstance(value, bool) or not isinstance(value, numbers.Integral):
        raise UsageError(name, f"must be a whole number, got {value!r}")
    if not low <= value <= MAX_COUNT:
        raise UsageError(name, f"must be >= {low}, got {value}" if value < low else
                         f"must be at most {MAX_COUNT:.0e}, got {value}")
    return int(value)


def _memory_mib(value: Any) -> float | None:
    """A memory budget in MiB: None, a number of MiB, or a size such as "800M", "4G", "4GiB"."""
    if value is None:
        return None
    mib = float("nan")
    if isinstance(value, str):
        text = value.strip().upper().removesuffix("IB").removesuffix("B")
        scale = {"K": 1 / 1024, "M": 1.0, "G": 1024.0, "T": 1024.0**2}.get(text[-1:])
        try:
            mib = float(text[:-1] if scale else text) * (scale or 1.0)
        except ValueError:
            pass
    elif isinstance(value, (int, float)) and not isinstance(value, bool):
        mib = float(value)
    if not 256 <= mib < float("inf"):
        raise UsageError("max_memory", f"must be a size of at least 256 MiB (a number of MiB, or e.g. '800M', "
                                       f"'4G'), got {value!r}")
    return mib


def _check_source(source: Any, reproduction: bool = True) -> None:
    if isinstance(source, (str, os.PathLike, Mapping)) or (reproduction and isinstance(source, Reproduction)):
        return
    what = "a scenario file's path or a dict of its contents" + (", or dse.paper(...)" if reproduction else "")
    raise UsageError("source", f"must be {what}; got {type(source).__name__}")


def _check_dir(value: Any, name: str, optional: bool = True) -> None:
    if (value is None and optional) or isinstance(value, (str, os.PathLike)):
        return
    raise UsageError(name, f"must be a directory path (str or pathlib.Path), got {type(value).__name__}")


# -- the tables every run has ---------------------------------------------------------------------------

HYPOTHESES = spec("hypotheses", "hypothesis a claim of this run rests on", [
    ("id", "", "hypothesis id"), ("statement", "", "what must hold"),
    ("holds", "", "true / false; empty when it could not be decided"),
    ("value", "as stated", "the number that decides it (JSON when not a single number)"),
    ("threshold", "as stated", "what the value is compared with (JSON when not a single number)"),
    ("detail", "", "how it was decided"), ("error", "", "non-empty when the check raised (a defect of ours)"),
    ("expected", "", "true / false as the scenario declares it (false: a negative control built to break it); "
                     "empty when it declares nothing")])

CLAIMS = spec("claims", "claim of the paper checked on this run", [
    ("id", "", "claim id"), ("source", "", "where the paper states it"), ("statement", "", "the claim"),
    ("kind", "", "identity, inequality, statistical or qualitative"),
    ("scope", "", "family (any scenario) or paper-example"),
    ("hypotheses", "", "ids of the hypotheses the conclusion rests on, comma-separated"),
    ("verdict", "", "pass, fail, erratum, not-checkable or error"),
    ("measured", "as stated", "the headline measured number (worst case); NaN when not a single number"),
    ("reference", "as stated", "what it is compared with; NaN when not a single number"),
    ("tolerance", "as stated", "the tolerance or threshold the check derived"),
    ("margin", "as stated", "slack left (positive: holds); for statistical checks the z or log10 p budget left"),
    ("confidence", "1", "confidence of a statistical check (its share of the report's family-wise confidence)"),
    ("trials", "1", "Monte Carlo trials behind a statistical check"),
    ("printed", "as stated", "for an erratum: what the printed statement gives"),
    ("corrected", "as stated", "for an erratum: what the documented correction gives"),
    ("measured_json", "", "the measured value as JSON when it is not a single number"),
    ("reference_json", "", "the reference value as JSON when it is not a single number"),
    ("detail", "", "how the check was done and what it found")])


def _scalar(x: Any) -> float:
    if isinstance(x, bool):
        return float(x)
    if isinstance(x, (int, float)):
        return float(x)
    if isinstance(x, str) and x in ("nan", "inf", "-inf"):
        return float(x)
    return float("nan")


def _json(x: Any) -> str:
    return "" if x is None or isinstance(x, (int, float)) else json.dumps(x, ensure_ascii=False)


def evaluation_tables(ev: Evaluation) -> Tables:
    import pandas as pd

    t = Tables()
    t.add(HYPOTHESES, pd.DataFrame([{
        "id": h["id"], "statement": h["statement"], "holds": h["holds"],
        "value": _scalar(h["value"]) if not isinstance(h["value"], (list, dict)) else float("nan"),
        "threshold": _scalar(h["threshold"]) if not isinstance(h["threshold"], (list, dict)) else float("nan"),
        "detail": h["detail"] + (f" value = {_json(h['value'])}" if isinstance(h["value"], (list, dict)) else ""),
        "error": h["error"], "expected": h.get("expected")} for h in ev.hypotheses],
        columns=HYPOTHESES.column_names).astype({"holds": "boolean", "expected": "boolean"}))
    t.add(CLAIMS, pd.DataFrame([{
        "id": r["id"], "source": r["source"], "statement": r["statement"], "kind": r["kind"], "scope": r["scope"],
        "hypotheses": ",".join(r["hypotheses"]), "verdict": r["verdict"],
        "measured": _scalar(r.get("measured")), "reference": _scalar(r.get("reference")),
        "tolerance": _scalar(r.get("tolerance")), "margin": _scalar(r.get("margin")),
        "confidence": _scalar(r.get("confidence")), "trials": _scalar(r.get("trials")),
        "printed": _scalar(r.get("printed")), "corrected": _scalar(r.get("corrected")),
        "measured_json": _json(r.get("measured")), "reference_json": _json(r.get("reference")),
        "detail": r.get("detail", "")} for r in ev.claims], columns=CLAIMS.column_names))
    return t


# -- output directories replaced in one step ---------------------------------------------------------------

def _staging_dir(out_dir: Path) -> Path:
    try:
        out_dir.parent.mkdir(parents=True, exist_ok=True)
        return Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.staging-", dir=out_dir.parent))
    except OSError as exc:
        raise OutputError(f"output directory {out_dir.parent} is not usable: {exc.strerror or exc}") from None


def _replace_dir(staging: Path, out_dir: Path) -> None:
    """Move `staging` to `out_dir`; a previous `out_dir` is moved aside first and then removed,
    so that at no moment does `out_dir` hold a mix of two runs."""
    old = None
    if out_dir.exists():
        old = Path(tempfile.mkdtemp(prefix=f".{out_dir.name}.old-", dir=out_dir.parent))
        os.replace(out_dir, old / "x")
    os.replace(staging, out_dir)
    if old is not None:
        shutil.rmtree(old, ignore_errors=True)


# -- `dse check`: hypotheses, design quantities and the cost of a run, without simulating -----------------

@dataclass
class Check:
    """What `check` found: the hypotheses (rows as in report.json), the design tables, the
    estimated wall time (s) and peak memory (MiB) of the run with these options, and `refusal`: the
    one line `dse run` would refuse that run with ("" when it would start)."""

    reproduction: Reproduction
    options: RunOptions
    hypotheses: list[dict[str, Any]]
    design: Any = field(repr=False)
    estimate: dict[str, Any]
    refusal: str = ""
    stages: list[dict[str, Any]] = field(default_factory=list)

    @functools.cached_property
    def tables(self) -> Tables:
        """The design tables (DataFrames), built on first use: `dse check` prints them from the text it
        stored beside a cached design (`design_text`) without building them, or importing pandas."""
        tables = Tables()
        for table_spec, frame in self.reproduction.design_tables(self.design):
            tables.add(table_spec, frame)
        return tables

    def design_text(self, cache_dir: str | os.PathLike | None = None) -> str:
        """The design tables as `dse check` prints them (each table's row count, and the table itself when it
        has at most 40 rows). With `cache_dir` (the stage cache the design came from), the text is kept there
        under a key derived from everything the text depends on (`_text_key`), and read back the next time."""
        key = self._text_key() if cache_dir is not None else None
        path = Path(cache_dir) / f"check-text-{key}.txt" if key else None
        if path is not None and path.is_file():
            return path.read_text()
        text = render_design_tables(self.tables)
        if path is not None:
            try:
                atomic_write_text(path, text)
            except OSError:
                pass                    # a read-only cache: the text is rendered again next time
        return text

    def _text_key(self) -> str | None:
        """The key of `design_text`'s stored text: the design stages' keys, the scenarios, the options, the source
        of every module of the family's package and of the project modules they import (whatever code builds
        the design object and its tables), and pandas's version (the rendering); None for a family outside the
        project, whose code these do not follow."""
        from importlib.metadata import version

        from dse.contract.stages import code_hash, module_file

        family_module = type(self.reproduction.family).__module__
        family_file = module_file(family_module)
        if family_file is None:
            return None
        package = family_module.rpartition(".")[0]
        modules = sorted({f"{package}." + ".".join(p.relative_to(family_file.parent).with_suffix("").parts)
                          for p in family_file.parent.rglob("*.py")})
        parts = ([s["key"] for s in self.stages], [sc.key() for sc in self.reproduction.scenarios],
                 asdict(self.options), version("pandas"), [code_hash(m.removesuffix(".__init__")) for m in modules])
        return hashlib.sha256(json.dumps(parts, sort_keys=True, default=str).encode()).hexdigest()[:24]


def render_design_tables(tables: Tables, max_rows: int = 40) -> str:
    """Each design table's name, row count and what a row is, then the table itself when it has at most
    `max_rows` rows (10 significant digits), indented for `dse check`."""
    import pandas as pd

    lines = []
    with pd.option_context("display.max_rows", max_rows, "display.width", 160, "display.precision", 10):
        for name in tables:
            frame = tables[name]
            lines.append(f"  [{name}] {len(frame)} rows: one per {tables.specs[name].row}")
            if len(frame) <= max_rows:
                lines.append("    " + frame.to_string(index=False).replace("\n", "\n    "))
    return "".join(line + "\n" for line in lines)


def check(source: str | os.PathLike | Mapping[str, Any] | Reproduction, *, seed: int = 0, trials: int | None = None,
          quick: bool = False, workers: int = DEFAULT_WORKERS, max_memory: int | float | str | None = None,
          max_time_s: float | None = None, max_design_s: float = CHECK_DESIGN_BUDGET_S,
          cache_dir: str | os.PathLike | None = None) -> Check:
    """Validate a scenario and compute only its deterministic design stage (no Monte Carlo):
    the hypotheses are evaluated on the design, the design tables built, and the run's cost estimated.
    The arguments and the errors raised are those of `run` (`max_memory`, `max_time_s`: the budgets
    the run would be held to; the result's `refusal` says whether it would be refused), and:

    Args:
        max_design_s: a design estimated above this many seconds is refused (ScenarioError naming the
            key that sizes it) before it is computed; one that takes longer than a second is announced
            on stderr.
        cache_dir: the stage cache's directory, or None (in memory). `run` with the same `cache_dir`
            computes the same design stages under the same keys: a check after a run reads the design
            back, and a run after a check starts from the design the check stored. The result's
            `stages` lists the stages with their keys and whether they were read back."""
    opts = run_options(seed=seed, trials=trials, quick=quick, workers=workers, max_memory=max_memory,
                       max_time_s=max_time_s)
    max_design_s = _seconds(max_design_s, "max_design_s")
    _check_source(source)
    _check_dir(cache_dir, "cache_dir")
    repro = load(source) if isinstance(source, (str, os.PathLike, Mapping)) else source
    refuse_options(repro, opts)
    estimate = repro.cost(opts)
    refuse_long_design(estimate, max_design_s)
    design_s = estimate.design_s if estimate.design_s is not None else estimate.stages.get("design")
    guess = f" (estimated about {human_seconds(design_s)})" if design_s is not None else ""
    with note_if_slow(CHECK_NOTE_AFTER_S, f"dse check: computing the design of '{repro.paper_id}'{guess} ..."):
        ctx = StageContext(MemoryCache() if cache_dir is None else StageCache(Path(cache_dir)))
        design = repro.design(opts, ctx)
    hyps = [h.evaluate(design) for h in repro.hypotheses()]
    return Check(repro, opts, hyps, design, estimate.as_dict(),
                 run_refusal(estimate, opts, trials_field(repro, opts)), ctx.ran)
