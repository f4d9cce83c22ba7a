"""The site's pages: the context of each template, rendered with Jinja2 (templates in dse/site/templates)."""
from __future__ import annotations

import dataclasses
import functools
import json
import math
from pathlib import Path
from typing import Any

from dse.site.collect import VERDICTS, RunSource, SweepSource
from dse.site.links import Evidence, evidence
from dse.site.tables import TableView

HERE = Path(__file__).parent


@functools.lru_cache(maxsize=1)
def environment():
    import jinja2

    env = jinja2.Environment(loader=jinja2.FileSystemLoader(HERE / "templates"), autoescape=True,
                             undefined=jinja2.StrictUndefined, trim_blocks=True, lstrip_blocks=True)
    env.filters["num"] = number
    env.globals["verdicts"] = VERDICTS
    return env


def render(template: str, **context: Any) -> str:
    return environment().get_template(template).render(**context)


def number(value: Any) -> str:
    """A report number for people: 6 significant digits, lists shortened, nothing for a missing one."""
    if value is None:
        return ""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, float):
        return f"{value:.6g}" if math.isfinite(value) else str(value)
    if isinstance(value, (list, tuple)):
        text = json.dumps(value)
        return text if len(text) <= 80 else text[:77] + "..."
    return str(value)


def _order(claims: list[dict]) -> list[dict]:
    """Claims worst verdict first (fail, error, erratum, not-checkable, pass), in report order within a verdict."""
    rank = {v: i for i, v in enumerate(VERDICTS)}
    return sorted(claims, key=lambda c: rank.get(c.get("verdict"), len(VERDICTS)))


def claim_rows(run: RunSource, views: list[TableView]) -> list[dict[str, Any]]:
    """The run's claims, worst first, each with the evidence it links to."""
    scenarios = {v.name: v.scenarios for v in views}
    rows = []
    for claim in _order(run.report.get("claims", [])):
        rows.append({**claim, "paper": run.slug, "page": f"{run.slug}/index.html",
                     "evidence": evidence(claim, run.figures, run.recordings, scenarios)})
    return rows


def _leaderboard(run: RunSource, views: list[TableView]) -> TableView | None:
    """The compare family's `estimators` table, best network MSE first (None for other families)."""
    table = next((v for v in views if v.name == "estimators"), None)
    if run.family != "compare" or table is None:
        return None
    names = [c["name"] for c in table.columns]
    if "network_mse" not in names:
        return table
    i = names.index("network_mse")
    ranked = sorted(table.rows, key=lambda r: r[i] if isinstance(r[i], (int, float)) else math.inf)
    return TableView(table.name, table.row, table.description, table.columns, table.num_rows, ranked)


def run_page(run: RunSource, claims: list[dict[str, Any]], views: list[TableView], viewer: bool) -> str:
    return render("run.html", root="../", family=run.family, run=run, report=run.report, claims=claims,
                  failures=[c for c in claims if c["verdict"] in ("fail", "error")],
                  errata=[c for c in claims if c["verdict"] == "erratum"], tables=views,
                  leaderboard=_leaderboard(run, views), viewer=viewer, papers=[run.slug],
                  recordings=[p.name for p in run.recordings], figures=[p.name for p in run.figures])


def table_page(view: TableView, back: dict[str, str]) -> str:
    return render("table.html", root="../", table=view, back=back)


def _sweep_matrix(sweep: SweepSource) -> tuple[list[dict], list[dict]]:
    """The sweep's points (number and varied values) and one row per claim with its verdict at every point."""
    import pyarrow.parquet as pq

    varied = list((sweep.meta.get("sweep") or {}).get("grid", {}))
    results = pq.read_table(sweep.directory / "results.parquet").to_pylist()
    points = [{"point": r["point"], "values": {k: r.get(k) for k in varied}, "status": r.get("status", "")}
              for r in results]
    claims: dict[str, dict] = {}
    if (sweep.directory / "claims.parquet").exists():
        cols = ["point", "claim", "statement", "verdict", "margin", "detail"]
        for r in pq.read_table(sweep.directory / "claims.parquet", columns=cols).to_pylist():
            row = claims.setdefault(r["claim"], {"id": r["claim"], "statement": r["statement"], "cells": {},
                                                 "counts": dict.fromkeys(VERDICTS, 0)})
            row["cells"][r["point"]] = r
            row["counts"][r["verdict"]] = row["counts"].get(r["verdict"], 0) + 1
    worst = {v: i for i, v in enumerate(VERDICTS)}
    ordered = sorted(claims.values(), key=lambda c: min((worst.get(v, 9) for v, n in c["counts"].items() if n), default=9))
    return points, ordered


def sweep_page(sweep: SweepSource, viewer: bool) -> str:
    points, matrix = _sweep_matrix(sweep)
    files = {p.name for p in sweep.inputs}
    return render("sweep.html", root="../", family=sweep.meta.get("family", ""), sweep=sweep, meta=sweep.meta, spec=sweep.meta.get("sweep") or {},
                  points=points, matrix=matrix, viewer=viewer, papers=[sweep.slug],
                  tables=[p.stem for p in sweep.tables], has=files)


def evidence_json(claims: list[dict[str, Any]]) -> str:
    """The evidence of each claim of a run (by claim id), kept beside its page for the index."""
    return json.dumps({c["id"]: dataclasses.asdict(c["evidence"]) for c in claims})


def index_page(runs: list[RunSource], sweeps: list[SweepSource], evidence: dict[str, dict[str, dict]]) -> str:
    """The index; `evidence` is each run's `evidence_json` (by run slug), read back."""
    claims = [{**c, "paper": r.slug, "page": f"{r.slug}/index.html",
               "evidence": Evidence(**evidence[r.slug][c["id"]]) if c["id"] in evidence.get(r.slug, {}) else None}
              for r in runs for c in _order(r.report.get("claims", []))]
    return render("index.html", root="", runs=runs, sweeps=sweeps, claims=claims,
                  papers=[r.slug for r in runs], failing=[r for r in runs if r.report.get("counts", {}).get("fail")
                                                          or r.report.get("counts", {}).get("error")])
