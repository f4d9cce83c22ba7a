"""What a site is built from: the runs and sweeps of an output root, read from their files.

An output root (docs/output.md) holds paper reproductions (`OUT/<paper>/report.json`), user runs
(`OUT/run/<name>/report.json`) and sweeps (`OUT/sweep/<name>/sweep.json`). Each is read into a plain
record (`RunSource`, `SweepSource`) with the list of files a page is built from, so that a page can
be skipped when none of them changed.
"""
from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from dse.errors import OutputError

#: the verdict words in the order a page lists them (the worst first)
VERDICTS = ("fail", "error", "erratum", "not-checkable", "pass")
#: directories of an output root that are not runs
NOT_RUNS = {"run", "sweep", ".cache", "site"}


@dataclass
class RunSource:
    """One run directory: its report, its family, and the figures, tables and recordings beside it."""

    slug: str                      # the page's name in the site: the paper id, or run-<name>
    kind: str                      # "paper" or "run"
    directory: Path
    report: dict[str, Any]
    family: str
    figures: list[Path] = field(default_factory=list)
    tables: list[Path] = field(default_factory=list)
    recordings: list[Path] = field(default_factory=list)

    @property
    def inputs(self) -> list[Path]:
        """Every file the run's pages are made of."""
        extra = [self.directory / n for n in ("report.json", "tables/schema.json") if (self.directory / n).exists()]
        return extra + self.figures + self.tables + self.recordings


@dataclass
class SweepSource:
    """One sweep directory: sweep.json, its results and claims tables, figure and recording."""

    slug: str
    directory: Path
    meta: dict[str, Any]
    tables: list[Path] = field(default_factory=list)

    @property
    def inputs(self) -> list[Path]:
        names = ("sweep.json", "sweep.png", "sweep.rrd", "results.parquet", "claims.parquet")
        return [self.directory / n for n in names if (self.directory / n).exists()] + self.tables


def _read_json(path: Path) -> dict[str, Any]:
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        raise OutputError(f"{path}: unreadable ({exc}); run the reproduction again or delete the directory") from exc


def _paper_families() -> dict[str, str]:
    """Paper id -> family id, from the registry (empty when a family cannot be loaded)."""
    try:
        from dse import registry

        return {pid: fam.id for pid, fam in registry.papers().items()}
    except Exception:      # the site of an output root must not depend on every family importing
        return {}


def _run_family(directory: Path, paper_id: str, families: dict[str, str]) -> str:
    run_json = directory / "run.json"
    if run_json.exists():
        scenario = _read_json(run_json).get("scenario") or {}
        if isinstance(scenario, dict) and scenario.get("family"):
            return str(scenario["family"])
    return families.get(paper_id, "")


def read_run(directory: Path, slug: str, kind: str, families: dict[str, str]) -> RunSource:
    report = _read_json(directory / "report.json")
    return RunSource(slug=slug, kind=kind, directory=directory, report=report,
                     family=_run_family(directory, str(report.get("paper", slug)), families),
                     figures=sorted((directory / "figures").glob("*.png")),
                     tables=sorted((directory / "tables").glob("*.parquet")),
                     recordings=sorted(directory.glob("*.rrd")))


def read_sweep(directory: Path) -> SweepSource:
    meta = _read_json(directory / "sweep.json")
    return SweepSource(slug=f"sweep-{directory.name}", directory=directory, meta=meta,
                       tables=sorted((directory / "tables").glob("*.parquet")))


def require_root(out_root: Path) -> Path:
    """`out_root`, or a one-line error when it is not a directory."""
    if not out_root.is_dir():
        raise OutputError(f"{out_root} is not a directory: give the output root of `dse reproduce`, `dse run` "
                          "or `dse sweep` (e.g. out)")
    return out_root


def collect(out_root: Path) -> tuple[list[RunSource], list[SweepSource]]:
    """Every run and sweep of `out_root`: papers first (by id), then user runs, then sweeps."""
    require_root(out_root)
    families = _paper_families()
    papers = [read_run(d, d.name, "paper", families) for d in sorted(out_root.iterdir())
              if d.is_dir() and d.name not in NOT_RUNS and (d / "report.json").exists()]
    runs = [read_run(d, f"run-{d.name}", "run", families) for d in sorted((out_root / "run").glob("*"))
            if (d / "report.json").exists()]
    sweeps = [read_sweep(d) for d in sorted((out_root / "sweep").glob("*")) if (d / "sweep.json").exists()]
    if not papers and not runs and not sweeps:
        raise OutputError(f"{out_root} holds no run or sweep (no */report.json, run/*/report.json or "
                          f"sweep/*/sweep.json): run `dse reproduce --out {out_root}` first")
    return papers + runs, sweeps
