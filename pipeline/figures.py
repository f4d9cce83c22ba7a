"""Matplotlib figures written atomically as PNG, one consistent style."""
from __future__ import annotations

import os

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402

from .atomic import atomic_path  # noqa: E402

STYLE = {"figure.dpi": 110, "savefig.dpi": 150, "axes.grid": True, "grid.alpha": 0.3, "font.size": 10,
         "legend.fontsize": 8, "axes.spines.top": False, "axes.spines.right": False}


def new_figure(ncols: int = 1, nrows: int = 1, width: float = 6.4, height: float = 4.2):
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False)
    return fig, axes


def save_figure(fig, path: str | os.PathLike) -> None:
    with plt.rc_context(STYLE):
        fig.tight_layout()
        with atomic_path(path) as tmp:
            fig.savefig(tmp, format="png")
    plt.close(fig)


def sequential_colors(n: int, cmap: str = "viridis"):
    cm = plt.get_cmap(cmap)
    return [cm(x) for x in ([0.0] if n == 1 else [0.9 * i / (n - 1) for i in range(n)])]


_JOBS: list = []


def _draw(index: int) -> None:
    _JOBS[index]()


def draw_all(jobs, workers: int = 1) -> None:
    """Run figure-drawing callables (each draws and saves one or more figures), in `workers`
    forked processes when there are several: the callables need not be picklable (workers
    inherit them through fork and receive only their index)."""
    global _JOBS
    jobs = list(jobs)
    if workers <= 1 or len(jobs) <= 1:
        for job in jobs:
            job()
        return
    from .simulate import parallel_map

    _JOBS = jobs
    try:
        parallel_map(_draw, range(len(jobs)), workers=min(workers, len(jobs)), desc="figures")
    finally:
        _JOBS = []
