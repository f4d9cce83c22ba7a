"""The `dse` command line: list, reproduce, run, check, verify, sweep, site.

Exit codes (also in `dse --help` and the README):

  0    done (with --strict: and no claim is `fail` or `error`)
  1    --strict and some claim is `fail` or `error`; `dse verify` found differences;
       a sweep has points that failed
  2    invalid input or unusable output: one line naming the field or the path, nothing written
  3    numerical failure of the run (a NaN or inf where a finite number is required, or a valid
       scenario that asks for a number float64 cannot hold): one line
  130  interrupted (Ctrl-C, SIGINT)
  141  the reader of the output went away (`dse list | head`)
  143  terminated (SIGTERM)
"""
from __future__ import annotations

import os

# The matrices here are tiny (N x N per step over many trials): BLAS threads only contend
# with the worker processes. Set before numpy is first imported by this program.
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

from dse.errors import CacheMiss, NumericalError, OutputError, ScenarioError  # noqa: E402
from dse.contract.cost import CHECK_DESIGN_BUDGET_S, parse_duration  # noqa: E402
from dse.contract.options import DEFAULT_MAX_TIME_S, DEFAULT_WORKERS, RunOptions  # noqa: E402
from dse.engine.driver import REVERIFY_RTOL, run  # noqa: E402
from dse.engine.reverify import verify_run  # noqa: E402
from dse.engine.outlock import output_lock  # noqa: E402
from dse.engine.progress import fresh_line  # noqa: E402
from dse.outputs.report import counts_line, hypothesis_status, verdict_counts, write_summary  # noqa: E402

EXIT_CODES = """exit codes:
  0    done (with --strict: and no claim is fail or error)
  1    --strict and some claim is fail or error; dse verify found differences; a sweep has failed points
       (an arena: a scenario that failed to run)
  2    invalid input or unusable output (one line naming the field or path; nothing written:
       an OUT the command created is removed; the lock file OUT/.dse.lock is removed after every command)
  3    numerical failure of the run (a NaN or inf where a finite number is required, or a number
       beyond float64, such as a gain below the rounding unit of 1): one line
  4    a plug-in filter broke its protocol (dse run, dse arena): one line each; it was left out and
       every other result was written, unchanged
  130  interrupted (SIGINT, Ctrl-C)
  141  the reader of the output went away (e.g. `dse list | head`)
  143  terminated (SIGTERM)"""


class Terminated(BaseException):
    """SIGTERM, turned into an exception so that the run unwinds like on Ctrl-C."""


def _strict_status(args, rows: list[dict]) -> int:
    return 1 if getattr(args, "strict", False) and any(r["fail"] or r["error"] for r in rows) else 0


def _registry():
    from dse import registry

    return registry


def cmd_list(args) -> int:
    """Every paper's (or family's) scenarios, hypotheses and claims, expanded on the declared scenarios
    (`Family.listing`): no scenario file is read and no scenario is built."""
    reg = _registry()
    families, papers = reg.families(), reg.papers()
    wanted = set(args.which)
    if wanted - set(papers) - set(families):
        raise ScenarioError("PAPER", f"unknown paper or family {', '.join(sorted(wanted - set(papers) - set(families)))} "
                                     f"(papers: {', '.join(papers)}; families: {', '.join(families)})")
    for pid, family in papers.items():
        if not wanted or wanted & {pid, family.id}:
            repro = family.listing()
            _print_claims(f"{pid} (family {family.id}): {repro.title}", repro)
    for fid, family in families.items():
        if family.paper is None and (not wanted or fid in wanted):
            _print_claims(f"{fid} (a family without a paper; claims as on its example {family.example})",
                          family.listing())
    if not wanted:
        print("\nscenario families for `dse run FILE.toml` (family = ...):", ", ".join(families))
    return 0


def _print_claims(header: str, repro) -> None:
    """A run's scenarios, hypotheses and claims, one per line."""
    print(header)
    print(f"  scenarios: {', '.join(repro.scenario_ids())}")
    for h in repro.hypotheses():
        print(f"  hypothesis {h.id}: {h.statement}")
    for claim in repro.claims():
        scope = " [paper example]" if claim.scope == "paper-example" else ""
        print(f"  {claim.id:<40} {claim.kind:<12} {claim.source}{scope}")


def cmd_check(args) -> int:
    from dse import api

    repro = api.load(args.file)
    cache = _check_cache(Path(args.out), repro.paper_id)
    result = api.check(repro, seed=args.seed, trials=args.trials, quick=args.quick, workers=args.workers,
                       max_memory=args.max_memory, max_time_s=args.max_time, max_design_s=args.max_design_time,
                       cache_dir=cache)
    print(f"{args.file}: valid scenario '{repro.paper_id}' ({repro.title})")
    if cache is not None and result.stages:
        if all(s["cached"] for s in result.stages):
            print(f"design: read back from the stage cache {cache} (stored by an earlier check or `dse run --out "
                  f"{args.out}`)")
        else:
            print(f"design: computed and stored in the stage cache {cache} (`dse run --out {args.out}` starts from it)")
    print("hypotheses:")
    for h in result.hypotheses:
        mark = "error" if h["error"] else hypothesis_status(h, {True: "holds", False: "does not hold", None: "undecided"})
        print(f"  {mark:<13} {h['id']}: {h['statement']}; value {h['value']}, threshold {h['threshold']}. {h['detail']}")
    print("design quantities:")
    print(result.design_text(cache), end="")
    est = result.estimate
    print(f"estimate: about {est['seconds']:.3g} s and {est['peak_memory_mib']:.0f} MiB peak memory "
          f"({est.get('detail', '')})")
    if result.refusal:
        print(f"dse: error: `dse run` would refuse this run: {result.refusal}", file=sys.stderr)
        return 2
    return 0


def _options(args) -> RunOptions:
    return RunOptions(seed=args.seed, trials=args.trials, quick=args.quick, workers=args.workers,
                      max_memory_mib=getattr(args, "max_memory", None), max_time_s=getattr(args, "max_time", None),
                      scheduler=getattr(args, "scheduler", "auto"))


def cmd_reproduce(args) -> int:
    reg = _registry()
    papers = reg.papers()
    unknown = [p for p in args.papers if p not in papers]
    if unknown:
        raise ScenarioError("PAPER", f"unknown paper {', '.join(unknown)} (known: {', '.join(papers)})")
    out_root = Path(args.out)
    rows = []
    ids, opts = list(args.papers or papers), _options(args)
    from dse.engine.driver import cache_for
    from dse.engine.prefetch import paper_stages, prefetching, worth_prefetching

    def ahead(i: int) -> None:      # in the prefetcher: paper i's stages only
        paper_stages(reg.paper(ids[i]), opts, cache_for(out_root, ids[i]).root)

    with output_lock(out_root) as guard, prefetching(len(ids), ahead, worth_prefetching(ids, opts, args.fresh)) as reach:
        for i, pid in enumerate(ids):
            reach(i)
            rows.append(run(reg.paper(pid), out_root, opts, figures=not args.no_figures, fresh=args.fresh))
            guard.wrote_results()   # a later paper's failure leaves this one's outputs
            r = rows[-1]
            print(f"{pid}: {counts_line(r)} ({r['wall_s']:.1f} s) -> {out_root / pid}")
        print(f"summary: {write_summary(out_root)}")
    return _strict_status(args, rows)


def _check_cache(out_root: Path, run_id: str) -> Path | None:
    """The stage cache `dse check` shares with `dse run --out OUT_ROOT` (OUT_ROOT/.cache/RUN_ID), or None
    (the design is kept in memory) when that directory cannot be created."""
    from dse.engine.driver import cache_for

    root = cache_for(out_root, run_id).root
    try:
        root.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        print(f"dse: note: the stage cache {root} is not usable ({exc.strerror or exc}); the design is kept in memory",
              file=sys.stderr)
        return None
    return root


def cmd_run(args) -> int:
    reg = _registry()
    from dse.scenario.fields import load_toml

    data = load_toml(args.file)
    repro = reg.from_dict(data)
    out_root = Path(args.out)
    out_dir = out_root / "run" / repro.paper_id
    with output_lock(out_root):
        r = run(repro, out_root, _options(args), out_dir=out_dir, source=data, figures=not args.no_figures,
                fresh=args.fresh, scenario_file=str(Path(args.file).resolve()))
    print(f"{repro.paper_id}: {counts_line(r)} ({r['wall_s']:.1f} s) -> {out_dir}")
    return _fault_status(r["faults"]) or _strict_status(args, [r])


def _fault_status(faults: list[str]) -> int:
    """One line per plug-in filter that failed (left out of the results, the others unchanged): exit 4."""
    for line in faults:
        print(f"dse: {line}; left out, the other estimators' results are unchanged", file=sys.stderr)
    return 4 if faults else 0


def cmd_verify(args) -> int:
    target = Path(args.out_dir)
    if not target.is_dir():
        raise OutputError(f"{target} is not a directory: give the output of `dse reproduce`, `dse run` or `dse sweep` "
                          "(e.g. out, out/savas, out/run/NAME or out/sweep/NAME)")
    runs = [target] if (target / "run.json").exists() else sorted(
        {p.parent for pattern in ("*/run.json", "run/*/run.json") for p in target.glob(pattern)})
    sweeps = [target] if (target / "sweep.json").exists() else sorted(p.parent for p in target.glob("sweep/*/sweep.json"))
    if not runs and not sweeps:
        raise OutputError(f"{target} holds no run.json and no sweep.json: nothing to verify (give the directory a "
                          "`dse reproduce`, `dse run` or `dse sweep` wrote)")
    status = 0
    for d in runs:
        status |= _verify_run(args, d)
    for d in sweeps:
        from dse.sweeps.run import verify_sweep

        diffs, n_points = verify_sweep(d)
        print(f"{d}: checked its files against the SHA-256 checksums in sweep.json and re-assembled {n_points} sweep "
              f"points from their stored results: {'identical' if not diffs else f'{len(diffs)} differences'}")
        for line in diffs:
            print(f"  differs: {line}")
        status |= bool(diffs)
    return status


def _verify_run(args, d: Path) -> int:
    reg = _registry()
    try:
        meta = json.loads((d / "run.json").read_text())
        out_root = meta["out_root"]
        meta["options"], json.loads((d / "report.json").read_text())["claims"]
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise OutputError(f"{d}: run.json or report.json is damaged ({type(exc).__name__}: {exc}); run the scenario "
                          "again to rewrite them") from None
    if out_root is None:
        raise OutputError(f"{d} was written without a stage cache (Python API without cache_dir): there is nothing "
                          "to re-check from; run it with `dse run` or with a cache_dir")
    repro = reg.from_dict(meta["scenario"]) if meta.get("scenario") else reg.paper(meta["paper"])
    root = (d / out_root).resolve()
    try:
        v = verify_run(repro, root, d, meta)
    except CacheMiss as exc:
        raise CacheMiss(f"{d}: {exc}") from None
    print(f"{d}:")
    print(f"  files: {v.files} checked against the SHA-256 checksums in run.json: "
          f"{len(v.file_diffs) or 'none'} differ" if v.files else
          "  files: not checked (run.json records no checksums: written by an older dse; run it again to add them)")
    print(f"  tables: {v.tables} recomputed from the stage cache ({v.cells:,} cells), compared with tables/*.parquet "
          f"exactly: {len(v.table_diffs) or 'none'} differ")
    print(f"  claims: {len(v.claims)} re-checked from the stage cache against report.json (numbers within a relative "
          f"{REVERIFY_RTOL:g}): {counts_line(verdict_counts(v.claims))}; {len(v.claim_diffs) or 'none'} differ")
    for line in v.diffs:
        print(f"  differs: {line}")
    print(f"  {'verified: no differences' if not v.diffs else f'NOT verified: {len(v.diffs)} differences'}")
    return int(bool(v.diffs)) | _strict_status(args, [verdict_counts(v.claims)])


def cmd_sweep(args) -> int:
    from dse.sweeps.run import LocalClusters, run_sweep
    from dse.sweeps.spec import load_sweep, with_options

    # every file is read before any runs; several sweeps share one local Dask cluster
    specs = [with_options(load_sweep(f), seed=args.seed, trials=args.trials, quick=args.quick) for f in args.file]
    status = 0
    with output_lock(Path(args.out)), LocalClusters() as clusters:
        for spec in specs:
            r = run_sweep(spec, Path(args.out), scheduler=args.scheduler, workers=args.workers, retries=args.retries,
                          fresh=args.fresh, clusters=clusters)
            print(f"sweep {r['name']}: {r['points']} points ({r['ran']} run, {r['reused']} reused, {r['failed']} "
                  f"failed, {r['numerical_errors']} numerical failures) in {r['wall_s']:.1f} s -> {r['out_dir']}")
            if args.strict and r["claims_failed"]:
                print(f"sweep {r['name']}: {r['claims_failed']} (point, claim) verdicts are fail or error (--strict)")
            status |= 1 if r["failed"] or (args.strict and r["claims_failed"]) else 0
    return status


def cmd_site(args) -> int:
    from dse.site.build import build
    from dse.site.collect import require_root

    out_root = require_root(Path(args.out))
    with output_lock(out_root):
        print(build(out_root, Path(args.to) if args.to else None).line())
    return 0


class OneLineParser(argparse.ArgumentParser):
    """Usage errors in one line (the full usage is one `--help` away), exit code 2. A parser whose
    `epilog_head` is set prepends what that function returns to its epilog when help is shown (so that
    the list of papers is read from the registry only for `--help`)."""

    epilog_head = None

    def error(self, message: str):
        self.exit(2, f"{self.prog}: error: {message} (see `{self.prog} --help`)\n")

    def format_help(self) -> str:
        if self.epilog_head is not None:
            self.epilog = f"{self.epilog_head()}\n\n{EXIT_CODES}"
        return super().format_help()


def _papers_epilog() -> str:
    """The papers `dse reproduce` knows, by id and title, from the registry."""
    papers = _registry().papers()
    width = max((len(pid) for pid in papers), default=0)
    return "papers (PAPER):\n" + "\n".join(f"  {pid:<{width}}  {fam.paper.title}" for pid, fam in papers.items())


class VersionAction(argparse.Action):
    """`dse --version`: the installed version, looked up only when asked (it reads the package metadata)."""

    def __init__(self, option_strings, dest=argparse.SUPPRESS, default=argparse.SUPPRESS, help=None):
        super().__init__(option_strings, dest=dest, default=default, nargs=0,
                         help=help or "print the installed version and exit")

    def __call__(self, parser, namespace, values, option_string=None):
        print(_version())
        parser.exit()


def _version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return f"dse {version('dse')}"
    except PackageNotFoundError:
        return "dse (not installed: version unknown)"


QUICK_HELP = ("a smaller, faster run: each family's quick_* keys (fewer Monte Carlo trials, shorter horizons, "
              "coarser grids; see docs/scenarios.md); tolerances are unchanged, so statistical claims have less "
              "power and some may be not-checkable")
RUN_SCHEDULER_HELP = ("where the Monte Carlo runs: auto (default: the stages in --workers forked processes), inline "
                      "(everything in this process), local (the Monte Carlo units on a local Dask cluster of --workers "
                      "processes) or the address of a running Dask scheduler, e.g. tcp://HOST:8786; results are the "
                      "same bits whatever it is (README, 'One run on a cluster')")
FILE_HELP = "a scenario file (TOML) of a supported family: `family = \"...\"` and its keys (docs/scenarios.md)"


def build_parser() -> argparse.ArgumentParser:
    parser = OneLineParser(prog="dse", description="Reproductions of distributed state estimation papers.",
                                     epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action=VersionAction)
    sub = parser.add_subparsers(dest="command", required=True)
    lst = sub.add_parser("list", help="papers, scenarios, hypotheses and claims (a family without a paper: as on "
                                      "its example scenario)")
    lst.add_argument("which", nargs="*", metavar="PAPER|FAMILY", help="only these papers or scenario families")
    lst.set_defaults(func=cmd_list)

    def run_flags(p):
        p.add_argument("--quick", action="store_true", help=QUICK_HELP)
        p.add_argument("--trials", type=_positive_int, default=None,
                       help="Monte Carlo trials per cell, within the bounds of the scenario file's trials key")
        p.add_argument("--seed", type=_nonnegative_int, default=0, help="root random seed (default 0)")
        p.add_argument("--out", default="out", help="output root directory (default out/)")
        _budget_flags(p)
        p.add_argument("--scheduler", type=_scheduler, default="auto", help=RUN_SCHEDULER_HELP)
        p.add_argument("--no-figures", action="store_true",
                       help="write the report and the tables only (no figures, no recordings): for fast iteration")
        p.add_argument("--fresh", action="store_true",
                       help="ignore the run memo and the stage cache under OUT/.cache: recompute every stage, "
                            "overwrite its cache entry, redraw every figure and recording")
        strict_flag(p)

    def strict_flag(p):
        p.add_argument("--strict", action="store_true", help="exit 1 when any claim is fail or error (for CI)")

    def sub_parser(name, **kw):
        return sub.add_parser(name, epilog=EXIT_CODES, formatter_class=argparse.RawDescriptionHelpFormatter, **kw)

    rep = sub_parser("reproduce", help="regenerate papers' claims, figures and recordings")
    rep.add_argument("papers", nargs="*", metavar="PAPER", help="the papers to reproduce (default: all; listed below)")
    rep.epilog_head = _papers_epilog
    run_flags(rep)
    rep.set_defaults(func=cmd_reproduce)
    user = sub_parser("run", help="run a scenario file of a supported family")
    user.add_argument("file", metavar="FILE.toml", help=FILE_HELP)
    run_flags(user)
    user.set_defaults(func=cmd_run)
    chk = sub_parser("check", help="validate a scenario; print its hypotheses, design quantities and the run's "
                                   "estimated time and memory, without simulating")
    _check_parser(chk)
    ver = sub_parser("verify", help="check a run's files against the checksums in its run.json, recompute its tables "
                                    "and re-check its claims from cached results (or re-assemble a sweep's), "
                                    "without simulating; exit 1 on any difference")
    ver.add_argument("out_dir", metavar="OUT_DIR")
    strict_flag(ver)
    ver.set_defaults(func=cmd_verify)
    _sweep_parser(sub_parser("sweep", help="run a scenario family over a grid or random sample of fields, on Dask"))
    from dse.arena.command import add_parser as arena_parser

    arena_parser(sub_parser, _nonnegative_int, _task_flags)
    _site_parser(sub_parser("site", help="build (or bring up to date) the static report site of an output root: "
                                         "every paper, run and sweep, browsable offline (docs/site.md)"))
    return parser


def _task_flags(p: argparse.ArgumentParser, tiny: str) -> None:
    """Where the tasks of a sweep or an arena run: --scheduler and --workers."""
    p.add_argument("--scheduler", default="auto",
                   help=f"auto (default: in process for {tiny}, else a local Dask cluster), inline, local, "
                        "or the address of a running Dask scheduler, e.g. tcp://HOST:8786")
    p.add_argument("--workers", type=_positive_int, default=os.cpu_count() or 1,
                   help="worker processes of the local cluster (default: one per core)")


def _sweep_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("file", metavar="SWEEP.toml", nargs="+",
                   help="a sweep file (TOML): a base scenario and the fields to vary (README, 'Sweeps'; examples in "
                        "dse/families/sweeps/); several run one after the other on one local Dask cluster")
    p.add_argument("--out", default="out", help="output root directory; results go to OUT/sweep/NAME/ (default out/)")
    _task_flags(p, "a tiny sweep")
    p.add_argument("--retries", type=_nonnegative_int, default=2, help="retries of a failed task (default 2)")
    p.add_argument("--fresh", action="store_true", help="recompute every point, ignoring points already done")
    p.add_argument("--seed", type=_nonnegative_int, default=None,
                   help="root seed of the sweep (each point's seed is derived from it); default: the file's seed")
    p.add_argument("--trials", type=_positive_int, default=None,
                   help="Monte Carlo trials per cell of every point; default: the file's trials, else each scenario's")
    p.add_argument("--quick", action="store_true", help="every point as a --quick run (as the file's quick = true)")
    p.add_argument("--strict", action="store_true",
                   help="exit 1 when any claim of any point is fail or error (for CI)")
    p.set_defaults(func=cmd_sweep)


def _check_parser(chk: argparse.ArgumentParser) -> None:
    """The arguments of `dse check`."""
    chk.add_argument("file", metavar="FILE.toml", help=FILE_HELP)
    chk.add_argument("--quick", action="store_true", help="estimate for a --quick run")
    chk.add_argument("--trials", type=_positive_int, default=None,
                     help="estimate for this many trials per cell (within the bounds of the file's trials key)")
    chk.add_argument("--seed", type=_nonnegative_int, default=0, help="root random seed (default 0)")
    chk.add_argument("--out", default="out", help="output root whose stage cache (OUT/.cache/NAME/) the design is "
                                                  "read from or stored in, shared with `dse run --out OUT` "
                                                  "(default out/)")
    _budget_flags(chk)
    chk.add_argument("--max-design-time", type=_duration, default=CHECK_DESIGN_BUDGET_S, metavar="DURATION",
                     help="the most design work check computes: a design estimated longer is refused before it "
                          f"starts (default {CHECK_DESIGN_BUDGET_S:g}s; `dse run` computes it as its first stage)")
    chk.set_defaults(func=cmd_check)


def _site_parser(p: argparse.ArgumentParser) -> None:
    p.add_argument("out", nargs="?", default="out", metavar="OUT", help="output root (default out/)")
    p.add_argument("--to", default=None, metavar="DIR", help="where the site goes (default OUT/site/)")
    p.set_defaults(func=cmd_site)


def _budget_flags(p: argparse.ArgumentParser) -> None:
    """The resources of a run (dse run, reproduce and check): workers, memory budget, time limit."""
    p.add_argument("--workers", type=_positive_int, default=DEFAULT_WORKERS,
                   help=f"worker processes (default {DEFAULT_WORKERS}; at most this machine's CPUs)")
    p.add_argument("--max-memory", type=_memory_mib, default=None, metavar="SIZE",
                   help="memory budget of the run, e.g. 4G or 800M (default: half of this machine's memory; at "
                        "most all of it); Monte Carlo streams within it, results do not depend on it")
    p.add_argument("--max-time", type=_duration, default=None, metavar="DURATION",
                   help="refuse a run estimated (`dse check`) to take longer, e.g. 90m, 36h, 3d or inf (default "
                        f"{DEFAULT_MAX_TIME_S / 3600:g}h); results do not depend on it")


MAX_COUNT = 10**12


def _count(text: str, low: int) -> int:
    """An integer option: 5000, 5_000 or 5e3 (a float that is a whole number); one clear message otherwise."""
    try:
        value = int(text.replace("_", ""))
    except ValueError:
        try:
            number = float(text)
        except ValueError:
            number = float("nan")
        if not (number == number and abs(number) < float("inf") and number == int(number)):
            raise argparse.ArgumentTypeError(f"must be a whole number (e.g. 5000 or 5e3), got {text!r}") from None
        value = int(number)
    if value < low:
        raise argparse.ArgumentTypeError(f"must be >= {low}, got {text}")
    if value > MAX_COUNT:
        raise argparse.ArgumentTypeError(f"must be at most {MAX_COUNT:.0e}, got {text}")
    return value


def _scheduler(text: str) -> str:
    """auto, inline, local or a Dask scheduler's address."""
    from dse.simulate.cluster import SCHEDULER_HELP, check_scheduler

    try:
        return check_scheduler(text)
    except ScenarioError:
        raise argparse.ArgumentTypeError(f"must be {SCHEDULER_HELP}, got {text!r}") from None


def _positive_int(text: str) -> int:
    return _count(text, 1)


def _nonnegative_int(text: str) -> int:
    return _count(text, 0)


def _memory_mib(text: str) -> float:
    """A memory size: 800M, 4G, 4GiB or a number of MiB."""
    t = text.strip().upper().removesuffix("IB").removesuffix("B")
    scale = {"K": 1 / 1024, "M": 1.0, "G": 1024.0, "T": 1024.0**2}.get(t[-1:], None)
    try:
        value = float(t[:-1] if scale else t) * (scale or 1.0)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a size such as 800M or 4G, got {text!r}") from None
    if not value >= 256:
        raise argparse.ArgumentTypeError(f"must be at least 256M, got {text}")
    return value


def _duration(text: str) -> float:
    """A duration: 90 (seconds), 30m, 12h, 2d, or inf."""
    try:
        return parse_duration(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a positive duration such as 90, 30m, 12h, 2d or inf, "
                                         f"got {text!r}") from None


_positive_int.__name__ = "positive integer"  # argparse names the type in its messages
_nonnegative_int.__name__ = "nonnegative integer"


def _on_sigterm(signum, frame):
    raise Terminated()


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    import signal

    previous = signal.signal(signal.SIGTERM, _on_sigterm)
    try:
        return args.func(args)
    except ScenarioError as exc:
        print(f"dse: error: {exc}", file=sys.stderr)
        return 2
    except OutputError as exc:
        print(f"dse: error: {exc}", file=sys.stderr)
        return 2
    except CacheMiss as exc:
        print(f"dse: {exc}", file=sys.stderr)
        return 1
    except NumericalError as exc:
        print(f"dse: numerical failure: {exc}", file=sys.stderr)
        return 3
    except BrokenPipeError:  # the reader of our output went away (`dse list | head`): stop quietly, as SIGPIPE would
        sys.stdout = open(os.devnull, "w")      # nothing more to flush at exit
        return 141
    except OSError as exc:  # disk full, permissions, a file replaced under us: one line, like any input fault
        where = f": {exc.filename}" if getattr(exc, "filename", None) else ""
        print(f"dse: error: cannot use the file system ({exc.strerror or exc}){where}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print(f"{fresh_line()}dse: interrupted", file=sys.stderr)
        return 130
    except Terminated:
        print(f"{fresh_line()}dse: terminated", file=sys.stderr)
        return 143
    finally:
        signal.signal(signal.SIGTERM, previous)
        _forget_interrupts_inside_exec()
        if argv is None:      # the `dse` program itself (not a call from Python): what is left is its exit
            _freeze_for_exit()


def _forget_interrupts_inside_exec() -> None:
    """CPython (3.11) marks a KeyboardInterrupt that leaves code run by `exec` of a string (dataclasses and
    namedtuple build their methods so, as a library is imported, say) as unhandled, even when `main` catches it
    later; under `python -m dse.cli` the interpreter then ends by killing itself with SIGINT (exit status -2)
    instead of exiting with main's code (130 after Ctrl-C). Each `exec` of a string clears that mark before it runs
    its code: this one runs nothing else."""
    exec("pass")


def _freeze_for_exit() -> None:
    """Exempt every object alive at the end of the command from the garbage collector's passes at interpreter
    exit (`gc.freeze`): with pandas, matplotlib and scipy loaded, those passes over their millions of objects took
    about 0.2 s of every command's exit; the exit itself is unchanged (atexit handlers, worker processes joined,
    files closed, each object released as its module is cleared; cyclic garbage left is freed with the process)."""
    import gc

    gc.freeze()


if __name__ == "__main__":
    sys.exit(main())
