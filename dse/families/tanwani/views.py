"""The views of a random-comm-filter run: per scenario a recording `<scenario>.rrd` and the figures
F2-F7, then F1 on the main scenario and, for the paper, the topology sweep S4; all drawn from the
run's tables (`figures`, `recording`)."""
from __future__ import annotations

import numpy as np
import pandas as pd

from dse.contract.views import Outputs, View

PAPER_NOTE = "(scenario of this reproduction: the paper has no numerical example)"


class ScenarioTables:
    """One scenario's rows of every table (figures and recordings read only these), each selected once
    per process (a figure asks for the design's numbers a few times each: selecting the rows every time
    was a tenth of a figure's time)."""

    def __init__(self, tables, name: str, title: str):
        self.name, self.title = name, title
        self._tables = tables
        self._rows: dict[str, pd.DataFrame] = {}
        self._design: dict | None = None

    def __getitem__(self, table: str) -> pd.DataFrame:
        if table not in self._rows:
            if table not in self._tables:
                return pd.DataFrame()
            f = self._tables[table]
            self._rows[table] = f[f["scenario"] == self.name] if "scenario" in f.columns else f
        return self._rows[table]

    def design(self, quantity: str) -> float:
        if self._design is None:
            d = self["design"]
            self._design = {}
            for q, value in zip(d["quantity"], d["value"]):
                self._design.setdefault(q, value)   # the first row of a quantity, as before
        return float(self._design[quantity])

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


def _recording(out: Outputs, v: ScenarioTables):
    def draw(path):
        # rerun: a run imports it while its stages compute (`dse.engine.driver.import_output_libraries`)
        from . import recording

        recording.write(out, v, path)
    return draw


def views(out: Outputs) -> list[View]:
    """Every figure and recording (the recordings first: the longest to draw)."""
    from . import figures

    res, note = out.results, PAPER_NOTE if out.reproduction.is_paper else ""
    tabs = {name: ScenarioTables(out.tables, name, r.scenario.title) for name, r in res.scenarios.items()}
    found = [View(f"{name}.rrd", _recording(out, v)) for name, v in tabs.items()]
    found += [View(f"figures/{stem}_{name}.png", lambda path, f=draw, v=v: f(v, path, note))
              for stem, draw in figures.PER_SCENARIO for name, v in tabs.items()]
    found.append(View("figures/fig1_network_events.png", lambda path: figures.fig1(tabs[res.main], path, note)))
    if "topology" in out.tables:
        found.append(View("figures/fig_topology.png", lambda path: figures.fig_topology(out.tables, path, PAPER_NOTE)))
    return found
