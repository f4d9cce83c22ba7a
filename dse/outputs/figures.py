"""Matplotlib figures written atomically as PNG, one consistent style."""
from __future__ import annotations

import contextlib
import functools
import math
import os
import re
import struct
import zlib
from typing import Iterator

from dse.engine.atomic import atomic_write_bytes

#: zlib level of the PNGs (`png_bytes`): level 1 encodes a 1560x960 figure in 12 ms, level 6 in 21 ms (files 20% smaller)
PNG_COMPRESS_LEVEL = 1

STYLE = {"figure.dpi": 110, "savefig.dpi": 150, "axes.grid": True, "grid.alpha": 0.3, "font.size": 10,
         "legend.fontsize": 8, "axes.spines.top": False, "axes.spines.right": False}


@functools.lru_cache(maxsize=1)
def _pyplot():
    """matplotlib.pyplot on the Agg backend, imported on first use (about 0.5 s): a process that
    draws nothing, or leaves its figures to forked workers (`draw_all`), does not pay for it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def import_pyplot() -> None:
    """Import matplotlib.pyplot ahead of the first figure (see `dse.simulate.units.idle_work`)."""
    _pyplot()


def new_figure(ncols: int = 1, nrows: int = 1, width: float = 6.4, height: float = 4.2):
    plt = _pyplot()
    with plt.rc_context(STYLE):
        fig, axes = plt.subplots(nrows, ncols, figsize=(width * ncols, height * nrows), squeeze=False)
    return fig, axes


def save_figure(fig, path: str | os.PathLike, *, tight: bool = True) -> None:
    """Write `fig` as PNG and close it. `tight=False` keeps the figure's own margins (see
    `set_margins`): `tight_layout` measures every text of the figure in an extra draw, about a
    third of the time of a figure with a few axes."""
    import matplotlib

    plt = _pyplot()
    pixels = _Pixels()
    with plt.rc_context(STYLE):
        if tight:
            fig.tight_layout()
        fig.savefig(pixels, format="rgba")   # drawn as for format="png", at savefig.dpi
    plt.close(fig)
    software = f"Matplotlib version{matplotlib.__version__}, https://matplotlib.org/"   # as matplotlib's PNGs say
    atomic_write_bytes(path, png_bytes(pixels.rgba, STYLE["savefig.dpi"], software))


class _Pixels:
    """A file for `savefig(format="rgba")`, which writes the drawn canvas in one call: keeps it as an
    (height, width, 4) array."""

    def seek(self, *args) -> None:   # makes matplotlib take it for a file object
        pass

    def write(self, buffer) -> None:
        import numpy as np

        self.rgba = np.array(buffer, dtype=np.uint8)


def png_bytes(rgba, dpi: float, software: str) -> bytes:
    """8-bit RGBA pixels (height, width, 4) as a PNG file, with the resolution and the Software text
    that matplotlib's own PNGs carry. Every row is filtered by its difference from the row above
    (PNG filter 'Up'; a figure's rows are mostly repeats): half the time of Pillow's encoder, which
    tries the five filters on every row, for files within about 10% of its size; the decoded pixels
    are the same."""
    import numpy as np

    height, width, channels = rgba.shape
    if rgba.dtype != np.uint8 or channels != 4:
        raise ValueError(f"png_bytes takes 8-bit RGBA pixels, not {rgba.dtype} with {channels} channels")
    rows = rgba.reshape(height, 4 * width)
    data = np.empty((height, 4 * width + 1), dtype=np.uint8)
    data[:, 0] = 2                                   # filter type 'Up'
    data[0, 1:] = rows[0]                            # the row above the first is zeros
    np.subtract(rows[1:], rows[:-1], out=data[1:, 1:])   # modulo 256, as PNG defines it

    def chunk(kind: bytes, body: bytes) -> bytes:
        return struct.pack(">I", len(body)) + kind + body + struct.pack(">I", zlib.crc32(kind + body))

    per_metre = int(dpi / 0.0254 + 0.5)
    return b"".join([b"\x89PNG\r\n\x1a\n",
                     chunk(b"IHDR", struct.pack(">IIBBBBB", width, height, 8, 6, 0, 0, 0)),  # 8-bit RGBA
                     chunk(b"pHYs", struct.pack(">IIB", per_metre, per_metre, 1)),
                     chunk(b"tEXt", b"Software\0" + software.encode("latin-1")),
                     chunk(b"IDAT", zlib.compress(data.tobytes(), PNG_COMPRESS_LEVEL)),
                     chunk(b"IEND", b"")])


def set_margins(fig, *, left: float = 0.7, right: float = 0.15, bottom: float = 0.5, top: float = 0.35,
                wspace: float = 0.75, hspace: float = 0.7) -> None:
    """Fixed margins and gaps between the axes of a grid figure, in inches (whatever the figure's
    size), for `save_figure(fig, path, tight=False)`."""
    w, h = fig.get_size_inches()
    nrows, ncols = fig.axes[0].get_subplotspec().get_gridspec().get_geometry()
    axis_w = (w - left - right - (ncols - 1) * wspace) / ncols
    axis_h = (h - bottom - top - (nrows - 1) * hspace) / nrows
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=wspace / axis_w, hspace=hspace / axis_h)


_SUPERSCRIPT = str.maketrans("-0123456789", "⁻⁰¹²³⁴⁵⁶⁷⁸⁹")


def _decade_label(value: float, _pos=None) -> str:
    if not value > 0:
        return ""
    e = math.log10(value)
    return "10" + str(round(e)).translate(_SUPERSCRIPT) if abs(e - round(e)) < 1e-9 else f"{value:g}"


def plain_log_labels(fig) -> None:
    """Tick labels of every log-scale and symlog-scale axis of `fig` as plain text (10⁻⁵, 2×10⁻¹ in
    superscript digits) instead of mathtext, which matplotlib parses label by label (about 10 ms
    each): log axes' major labels by `_decade_label`; their minor labels (on an axis spanning about
    a decade or less) and symlog axes' labels are matplotlib's own, rewritten (`_plain`)."""
    from matplotlib.ticker import FuncFormatter

    PlainText = _plain_text_formatter()
    for ax in fig.axes:
        for axis in (ax.xaxis, ax.yaxis):
            scale = axis.get_scale()
            if scale == "log":
                axis.set_major_formatter(FuncFormatter(_decade_label))
            if scale == "symlog" and not isinstance(axis.get_major_formatter(), PlainText):
                axis.set_major_formatter(PlainText(axis.get_major_formatter()))
            if scale in ("log", "symlog") and not isinstance(axis.get_minor_formatter(), PlainText):
                axis.set_minor_formatter(PlainText(axis.get_minor_formatter()))


_MATHTEXT = re.compile(r"\$\\mathdefault\{(.*)\}\$")
_EXPONENT = re.compile(r"\^\{(-?\d+)\}")


def _plain(label: str) -> str:
    """A log formatter's mathtext label as plain text: $\\mathdefault{2\\times10^{-1}}$ as 2×10⁻¹,
    a leading minus as matplotlib's − (other labels unchanged)."""
    body = _MATHTEXT.fullmatch(label)
    if body is None:
        return label
    text = _EXPONENT.sub(lambda m: m.group(1).translate(_SUPERSCRIPT), body.group(1).replace("\\times", "×"))
    return "−" + text[1:] if text.startswith("-") else text


@functools.lru_cache(maxsize=1)
def _plain_text_formatter():
    """The formatter class of `plain_log_labels` (defined on first use: matplotlib is imported then)."""
    from matplotlib.ticker import Formatter

    class PlainText(Formatter):
        """Another formatter's labels, with their mathtext as plain text (`_plain`): the same ticks
        labelled, with the same numbers."""

        def __init__(self, inner):
            self.inner = inner

        def set_axis(self, axis):
            self.axis = axis
            self.inner.set_axis(axis)

        def set_locs(self, locs):
            self.locs = locs
            self.inner.set_locs(locs)

        def format_ticks(self, values):
            return [_plain(label) for label in self.inner.format_ticks(values)]

        def __call__(self, x, pos=None):
            return _plain(self.inner(x, pos))

        def get_offset(self):
            return _plain(self.inner.get_offset())

    return PlainText


def sequential_colors(n: int, cmap: str = "viridis"):
    """n colours of a colormap (without pyplot: recordings take their colours from here too)."""
    import matplotlib

    cm = matplotlib.colormaps[cmap]
    return [cm(x) for x in ([0.0] if n == 1 else [0.9 * i / (n - 1) for i in range(n)])]


_JOBS: list = []


def _draw(index: int) -> None:
    _JOBS[index]()


def draw_all(jobs, workers: int = 1, *, shared_pyplot: bool = False) -> None:
    """Run figure-drawing callables (each draws and saves one or more figures), in `workers`
    forked processes when there are several (see `drawing`)."""
    with drawing(jobs, workers, shared_pyplot=shared_pyplot):
        pass


@contextlib.contextmanager
def drawing(jobs, workers: int = 1, *, shared_pyplot: bool = False) -> Iterator[None]:
    """Run figure-drawing callables while the body of the `with` block runs (the tables and the
    report are written meanwhile): in `workers` forked processes when there are several, which the
    block's end waits for; else here, at the block's end. The callables need not be picklable
    (workers inherit them through fork and receive only their index). `shared_pyplot`: several
    jobs draw with matplotlib, which is then imported here before the workers fork (once, not once
    per worker)."""
    global _JOBS
    jobs = list(jobs)
    if workers > 1 and len(jobs) > 1 and shared_pyplot:
        _pyplot()
    from dse.simulate.units import forked_map

    _JOBS = jobs
    try:
        with forked_map(_draw, range(len(jobs)), workers=min(workers, len(jobs)), desc="figures") as done:
            yield
            for _ in done:
                pass
    finally:
        _JOBS = []
