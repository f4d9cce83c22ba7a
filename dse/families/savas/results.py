"""What the claims and the tables of a noisy-consensus-filter run read: the design and the Monte Carlo
sums of every cell, and how the Monte Carlo groups of a run are computed through the stage cache."""
from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from dse.contract.context import StageContext
from dse.simulate.stats import ErrorMoments

from .cells import Cell
from .design import Design
from .monte_carlo import cell_groups, simulate_group
from .scenario import NoisyConsensusFile


@dataclass
class Results:
    """The design and the Monte Carlo sums of every cell (`mc[label][name]`)."""

    scenario: NoisyConsensusFile
    seed: int
    trials: int
    design: Design
    mc: dict[str, dict[str, np.ndarray]] = field(default_factory=dict)

    @property
    def bounds(self) -> dict[str, np.ndarray]:
        return self.design.arrays

    @property
    def cells(self) -> list[Cell]:
        return self.design.cells

    @property
    def long_cell(self) -> Cell | None:
        return self.design.long_cell

    def moments(self, cell: Cell, which: str = "pred") -> ErrorMoments:
        """Monte Carlo sums of the cell's errors at its recorded steps (axis 0 of every array)."""
        a = self.mc[cell.label]
        return ErrorMoments.from_arrays({k.removeprefix(which + "_"): v for k, v in a.items() if k.startswith(which + "_")})

    def paths(self, cell: Cell) -> dict[str, np.ndarray]:
        return {k.removeprefix("path_"): v for k, v in self.mc[cell.label].items() if k.startswith("path_")}


def simulate(ctx: StageContext, sc: NoisyConsensusFile, design: Design, seed: int, trials: int, *, workers: int,
             budget_bytes: float) -> Results:
    """Every group of cells through the stage cache, in `workers` processes. The group of the first cell
    also runs filterpy's reference filter on its sample paths: first, so that importing filterpy overlaps
    the other groups; then the longest first."""
    first = design.cells[0]
    groups = cell_groups(design.all_cells())
    # in one process, each group shows its chunks (with the time left); with workers, the groups are counted
    calls = [(simulate_group, (sc, seed, trials, design.steps_of(g[0]), budget_bytes, g),
              {"desc": f"{sc.name}: {g[0].alg} m = {g[0].m}, {trials:,} trials" if workers <= 1 else "",
               "reference": g[0] == first}) for g in groups]
    weights = [(np.inf if g[0] == first else 0.0) + (g[0].m + 2) * g[0].n_steps for g in groups]
    outputs = ctx.run_many(calls, workers=workers, weights=weights, desc=f"{sc.name}: Monte Carlo (algorithm, m) groups")
    mc: dict[str, dict[str, np.ndarray]] = {}
    for out in outputs:
        for k, value in out.items():
            label, name = k.split("__", 1)
            mc.setdefault(label, {})[name] = value
    return Results(sc, seed, trials, design, mc)
