"""Views: the figures and recordings of a run, drawn from its tables after it is checked.

A family's `views(outputs)` returns a list of `View`s, each one file of the run directory and
the function that writes it. The driver draws them in forked worker processes (each imports
only what it draws with: matplotlib or rerun), after the tables and the report's claims exist.

`recording(...)` is the one recording scaffold every family fills: a default layout made of the
family's tabs and a last tab with the claims (one document: the verdict table, then each claim in full), the
timeline the viewer opens on, the run's properties (seed, trials, versions, git and the family's
own), and the report's verdict counts as the `/report` header.

Legends of time-series views (`place_legends`, applied to every family's tabs): rerun draws a plot's
legend inside it, by default in the lower left corner, where it hid 30-40 % of the plots. A view that
sets its own `plot_legend` keeps it; in a grid of the same plot per node (view names equal but for
their numbers) the legend is shown once, in the first view's upper right corner, and hidden in the
others (the same colours and names; hovering a curve names it); every other view has it in the upper
right corner, which the decaying errors and covariances drawn here usually leave free.
"""
from __future__ import annotations

import json
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence


@dataclass(frozen=True)
class View:
    """One output file (`file`, relative to the run directory) and `draw(path)`, which writes it."""

    file: str
    draw: Callable[[Path], None]


@dataclass
class Outputs:
    """What views are drawn from: the run's reproduction, stage results, tables, checked claims
    (rows as in report.json) and provenance."""

    reproduction: Any
    results: Any
    tables: Any
    claims: list[dict[str, Any]]
    provenance: dict[str, Any] = field(default_factory=dict)

    @property
    def run_prefix(self) -> str:
        """What a recording is named after: the paper's id in its reproduction, else the family's id (a user's
        run is never named after a paper)."""
        repro = self.reproduction
        return repro.family.paper.id if repro.is_paper and repro.family.paper else repro.family.id

    @property
    def seed(self) -> int:
        return int(self.provenance.get("seed", 0) or 0)

    @property
    def trials(self) -> int:
        return int(self.provenance.get("trials", 0) or 0)

    @property
    def workers(self) -> int:
        return int(self.provenance.get("workers", 1) or 1)

    def summary(self, name: str | None = None, extra: str = "") -> str:
        """The `/report` header of a recording: the verdict counts of the run (one counting for every family)."""
        from dse.outputs.report import counts_line, verdict_counts

        name = name or self.reproduction.paper_id
        text = f"# {name}: {counts_line(verdict_counts(self.claims))}\n\nseed {self.seed}"
        return text + (f", {extra}" if extra else "")

    def properties(self, **family: Any) -> dict[str, Any]:
        """A recording's properties: the family's own, then seed, trials, versions and git."""
        return {**family, "seed": self.seed, "trials": self.trials,
                "versions": json.dumps(self.provenance.get("versions", {})), "git": self.provenance.get("git", "")}


def claims_tab():
    """The last tab of every recording's layout: one view of `/report`, the verdict table and then every claim
    in full (a second view of one document per claim showed only rerun's "one text document at a time" error)."""
    import rerun.blueprint as rrb

    return rrb.TextDocumentView(origin="/report", name="claims")


def recording(path: Path, outputs: Outputs, *, recording_id: str, tabs: Callable[[], Sequence[Any]], timeline: str,
              log: Callable[[Any], None], properties: dict[str, Any] | None = None, summary: str | None = None,
              claims: Sequence[dict] | None = None, application_id: str | None = None) -> None:
    """Write one recording: the family's `tabs()` (rerun blueprint containers) and the claims tab as
    its default layout, opened on `timeline`; `log(rec)` logs the family's data; then the claims
    (`claims`, default every claim of the run) under `/report`. Its application id
    (the name the viewer shows) is `dse-<run_prefix>` unless given."""
    import rerun.blueprint as rrb

    from dse.outputs import record

    repro = outputs.reproduction
    blueprint = rrb.Blueprint(rrb.Tabs(*place_legends(tabs()), claims_tab()),
                              rrb.TimePanel(timeline=timeline, expanded=False),
                              collapse_panels=True)
    app = application_id or f"dse-{outputs.run_prefix}"
    with record.recording(path, application_id=app, recording_id=recording_id, blueprint=blueprint,
                          properties=outputs.properties(**(properties or {}))) as rec:
        log(rec)
        record.log_claims(rec, outputs.claims if claims is None else claims, summary or outputs.summary())


def place_legends(items: Sequence[Any]) -> list[Any]:
    """`items` (rerun blueprint containers and views) with every time-series view's legend placed as the module
    docstring says; views that set their own legend are left alone. Returns the same objects."""
    import rerun.blueprint as rrb

    def series_views(container) -> list[Any]:
        return [v for v in getattr(container, "contents", []) if isinstance(v, rrb.TimeSeriesView)]

    def walk(item, in_uniform_grid: bool, first: bool) -> None:
        if isinstance(item, rrb.TimeSeriesView):
            if "PlotLegend" not in item.properties:
                shown = first or not in_uniform_grid
                item.properties["PlotLegend"] = rrb.PlotLegend(rrb.Corner2D.RightTop, visible=shown)
            return
        views = series_views(item)
        uniform = isinstance(item, rrb.Grid) and len(views) > 1 and len(
            {re.sub(r"\d+", "#", str(v.name)) for v in views}) == 1
        for child in getattr(item, "contents", []):
            walk(child, uniform, child is (views[0] if views else None))

    for item in items:
        walk(item, False, True)
    return list(items)
