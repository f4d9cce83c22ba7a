"""The colours of the estimators and series that figures and recordings share, without importing a drawing
library: a view module that picks its colours here imports rerun only where it writes a recording (a quarter
of a second, in the worker that draws the recording, not before the workers fork)."""
from __future__ import annotations

PALETTE = [(31, 119, 180), (255, 127, 14), (44, 160, 44), (214, 39, 40), (148, 103, 189),
           (140, 86, 75), (227, 119, 194), (127, 127, 127), (188, 189, 34), (23, 190, 207)]


def color(i: int) -> tuple[int, int, int]:
    return PALETTE[i % len(PALETTE)]
