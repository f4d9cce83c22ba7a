"""Figures (PNG) and Rerun recordings of the random-comm-filter family."""
from __future__ import annotations


def write_outputs(res, out_dir, claims, prov, *, main: str, paper: bool = False) -> None:
    from . import figures, recordings

    figures.write_figures(res, out_dir / "figures", main=main, paper=paper)
    recordings.write_recordings(res, out_dir, claims, prov, paper=paper)
