"""Figures (PNG) and Rerun recordings of the random-comm-filter family, drawn from the run's tables."""
from __future__ import annotations

import functools
from pathlib import Path

import numpy as np
import pandas as pd


class View:
    """One scenario's rows of every table (figures and recordings read only these)."""

    def __init__(self, tables, name: str, title: str, seed: int):
        self.name, self.title, self.seed = name, title, seed
        self._tables = tables

    def __getitem__(self, table: str) -> pd.DataFrame:
        if table not in self._tables:
            return pd.DataFrame()
        f = self._tables[table]
        return f[f["scenario"] == self.name] if "scenario" in f.columns else f

    def design(self, quantity: str) -> float:
        d = self["design"]
        return float(d.loc[d["quantity"] == quantity, "value"].iloc[0])

    @property
    def rates(self) -> list[float]:
        return [float(x) for x in self["rates"]["rate"]]

    @property
    def main_rate(self) -> float:
        r = self["rates"]
        return float(r.loc[r["main"], "rate"].iloc[0])

    @property
    def N(self) -> int:
        return int(self.design("N"))

    @property
    def n(self) -> int:
        return int(self.design("n"))

    def by_node(self, frame: pd.DataFrame, column: str, index: str = "t") -> np.ndarray:
        """A (len(index values), N) array of `column` from a frame with one row per (index, node)."""
        return frame.pivot(index=index, columns="node", values=column).to_numpy()

    def node_events(self, path: int, node: int) -> np.ndarray:
        """Ring times of `path` at which `node` updated (receiver, or either end with edge clocks)."""
        ev = self["path_events"]
        ev = ev[ev["path"] == path]
        hit = ev["i"] == node
        if self.design("edge_mode") == 1:
            hit |= ev["j"] == node
        return ev.loc[hit, "t"].to_numpy()


def _record(v: View, path: Path, claims: list[dict], prov: dict, paper: bool) -> None:
    from . import recordings     # rerun: imported by the worker that writes a recording only

    recordings.write_scenario(v, path, claims, prov, paper)


def write_outputs(res, tables, out_dir: Path, claims: list[dict], prov: dict, *, main: str, paper: bool = False) -> None:
    """Every figure and recording, drawn in `prov["workers"]` forked workers (the recordings first: the longest)."""
    from dse.outputs.figures import draw_all

    from . import figures

    views = {name: View(tables, name, r.scenario.title, res.seed) for name, r in res.scenarios.items()}
    records = [functools.partial(_record, v, out_dir / f"{name}.rrd", claims, prov, paper) for name, v in views.items()]
    jobs = records + figures.figure_jobs(views, tables, out_dir / "figures", main=main, paper=paper)
    draw_all(jobs, workers=int(prov.get("workers", 1) or 1))
