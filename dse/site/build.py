"""Build the static site of an output root: `build(out_root, site_dir)`.

Pages (Jinja2 templates in dse/site/templates): `index.html` (every run and sweep with verdict counts,
times and provenance, and every claim with the claim filter), `<run>/index.html` per paper or run,
`<run>/table-<name>.html` per table, `sweep-<name>/index.html` per sweep. The run's figures, tables
and recordings are placed beside its pages (hard links). See docs/site.md.
"""
from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

from dse.errors import OutputError
from dse.site import pages
from dse.site.collect import RunSource, SweepSource, collect
from dse.site.staging import MANIFEST, Staging, file_key
from dse.site.tables import TableView, read_view
from dse.site.viewer import viewer_assets

HERE = Path(__file__).parent
#: each run's claim evidence, written with its page and read by the index (which is built after the runs)
EVIDENCE = "evidence.json"
STATIC = HERE / "static"


@dataclass
class BuildResult:
    site: Path
    written: list[str]
    skipped: list[str]
    seconds: float
    viewer_note: str

    def line(self) -> str:
        note = f"; {self.viewer_note}" if self.viewer_note else ""
        return (f"site: {len(self.written)} pages written, {len(self.skipped)} unchanged ({self.seconds:.1f} s) "
                f"-> {self.site / 'index.html'}{note}")


def code_key() -> str:
    """A hash of the site's own code, templates and static files: a change rebuilds every page."""
    h = hashlib.sha256()
    for p in sorted(HERE.rglob("*")):
        if p.is_file() and p.suffix in {".py", ".html", ".js", ".css"} and "vendor" not in p.parts \
                and p.name != "browser_check.py":
            h.update(p.read_bytes())
    return h.hexdigest()


def _copy_static(stage: Staging, viewer: dict[str, Path]) -> None:
    for p in sorted(STATIC.rglob("*")):
        if p.is_file():
            stage.copy(p, f"static/{p.relative_to(STATIC).as_posix()}")
    for name, path in viewer.items():
        stage.copy(path, f"static/viewer/{name}")


def _run_files(stage: Staging, run: RunSource) -> None:
    for p in run.figures:
        stage.copy(p, f"{run.slug}/figures/{p.name}")
    for p in run.tables:
        stage.copy(p, f"{run.slug}/tables/{p.name}")
        if p.with_suffix(".csv").exists():
            stage.copy(p.with_suffix(".csv"), f"{run.slug}/tables/{p.stem}.csv")
    for p in run.recordings:
        stage.copy(p, f"{run.slug}/{p.name}")


def _table_pages(stage: Staging, slug: str, tables: list[tuple[str, Path, str]], root: Path,
                 back: dict[str, str]) -> dict[str, TableView]:
    """Write the page of each table (page name, Parquet file, folder of its files relative to the page) whose
    file changed; return the views read (by page name)."""
    views: dict[str, TableView] = {}
    for page, p, folder in tables:
        csv = [p.with_suffix(".csv")] if p.with_suffix(".csv").exists() else []
        rel = f"{slug}/table-{page}.html"
        if stage.needs(rel, file_key([p, *csv], root, folder)):
            views[page] = read_view(p)
            views[page].folder = folder
            stage.write(rel, pages.table_page(views[page], back))
    return views


def _run(stage: Staging, run: RunSource, root: Path, viewer: bool) -> None:
    _run_files(stage, run)
    back = {"href": "index.html", "title": run.report.get("paper", run.slug)}
    views = _table_pages(stage, run.slug, [(p.stem, p, "tables/") for p in run.tables], root, back)
    rel = f"{run.slug}/index.html"
    stage.kept.add(f"{run.slug}/{EVIDENCE}")
    if stage.needs(rel, file_key(run.inputs, root, str(viewer))):
        for p in run.tables:
            if p.stem not in views:
                views[p.stem] = read_view(p)
        ordered = [views[p.stem] for p in run.tables]
        claims = pages.claim_rows(run, ordered)
        stage.write(f"{run.slug}/{EVIDENCE}", pages.evidence_json(claims))
        stage.write(rel, pages.run_page(run, claims, ordered, viewer))


def _sweep(stage: Staging, sweep: SweepSource, root: Path, viewer: bool) -> None:
    for p in sweep.inputs:
        if p.suffix in (".parquet", ".png", ".rrd"):
            stage.copy(p, f"{sweep.slug}/{p.relative_to(sweep.directory).as_posix()}")
    back = {"href": "index.html", "title": sweep.meta.get("name", sweep.slug)}
    tables = [(n, sweep.directory / f"{n}.parquet", "") for n in ("results", "claims")
              if (sweep.directory / f"{n}.parquet").exists()]
    stacked = [(f"stacked-{p.stem}", p, "tables/") for p in sweep.tables]
    _table_pages(stage, sweep.slug, tables + stacked, root, back)
    rel = f"{sweep.slug}/index.html"
    if stage.needs(rel, file_key(sweep.inputs, root, str(viewer))):
        stage.write(rel, pages.sweep_page(sweep, viewer))


def _evidence(stage: Staging, runs: list[RunSource]) -> dict[str, dict]:
    out = {}
    for run in runs:
        path = stage.root / run.slug / EVIDENCE
        out[run.slug] = json.loads(path.read_text()) if path.exists() else {}
    return out


def _refuse_a_directory_that_is_not_a_site(site: Path, out_root: Path) -> None:
    """The site directory is replaced as a whole: never one that holds something else (the output root, say)."""
    if out_root.resolve().is_relative_to(site.resolve()):
        raise OutputError(f"--to {site} would replace the output root {out_root}: give a directory of its own "
                          f"(default {out_root / 'site'})")
    if site.is_dir() and any(site.iterdir()) and not (site / MANIFEST).exists():
        raise OutputError(f"{site} is not empty and is not a site `dse site` built (no {MANIFEST}): the site "
                          "replaces its directory as a whole, so give a new or empty directory")


def build(out_root: Path, site: Path | None = None) -> BuildResult:
    """Build (or bring up to date) the site of `out_root` in `site` (default `<out_root>/site`)."""
    start = time.perf_counter()
    out_root = Path(out_root)
    site = Path(site) if site else out_root / "site"
    _refuse_a_directory_that_is_not_a_site(site, out_root)
    runs, sweeps = collect(out_root)
    viewer, note = viewer_assets()
    stage = Staging(site, code_key())
    try:
        _copy_static(stage, viewer)
        for run in runs:
            _run(stage, run, out_root, bool(viewer))
        for sweep in sweeps:
            _sweep(stage, sweep, out_root, bool(viewer))
        inputs = [p for r in runs for p in r.inputs] + [s.directory / "sweep.json" for s in sweeps]
        stage.page("index.html", file_key(inputs, out_root), lambda: pages.index_page(runs, sweeps, _evidence(stage, runs)))
        stage.commit()
    except BaseException:
        stage.abandon()
        raise
    return BuildResult(site, stage.written, stage.skipped, time.perf_counter() - start, note)

