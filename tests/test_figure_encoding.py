"""The figures' own PNG encoder and plain-text log labels (dse.outputs.figures), and how a run's views are split
into jobs for the figure workers (dse.api.view_jobs)."""
from __future__ import annotations

import io
from types import SimpleNamespace

import numpy as np
import pytest
from PIL import Image

from dse.api import view_jobs
from dse.outputs.figures import _plain, new_figure, plain_log_labels, png_bytes, save_figure


@pytest.mark.parametrize("shape", [(1, 1), (3, 7), (64, 33)])
def test_png_bytes_decodes_to_the_same_pixels(shape):
    rgba = np.random.default_rng(0).integers(0, 256, size=(*shape, 4), dtype=np.uint8)
    rgba[0, 0] = (0, 255, 0, 255)                      # differences of both signs wrap modulo 256
    image = Image.open(io.BytesIO(png_bytes(rgba, 150, "test")))
    assert image.mode == "RGBA" and image.info["Software"] == "test"
    assert image.info["dpi"] == pytest.approx((150, 150), abs=0.05)   # stored in pixels per metre
    assert np.array_equal(np.asarray(image), rgba)


def test_png_bytes_refuses_other_pixels():
    with pytest.raises(ValueError):
        png_bytes(np.zeros((2, 2, 3), dtype=np.uint8), 150, "test")


def test_save_figure_has_matplotlibs_pixels_and_metadata(tmp_path):
    """The same pixels, size, resolution and Software text as matplotlib's own PNG of the figure."""
    import matplotlib.pyplot as plt

    from dse.outputs.figures import STYLE

    def figure():
        fig, axes = new_figure()
        axes[0, 0].semilogy([0, 1, 2], [1e-3, 2e-2, 1.0], "o-", label="a")
        axes[0, 0].set_title("title")
        axes[0, 0].legend()
        return fig

    save_figure(figure(), tmp_path / "ours.png")
    fig = figure()
    with plt.rc_context(STYLE):
        fig.tight_layout()
        fig.savefig(tmp_path / "theirs.png", format="png")
    plt.close(fig)
    ours, theirs = Image.open(tmp_path / "ours.png"), Image.open(tmp_path / "theirs.png")
    assert (ours.mode, ours.size, ours.info["Software"]) == (theirs.mode, theirs.size, theirs.info["Software"])
    assert ours.info["dpi"] == pytest.approx(theirs.info["dpi"], abs=0.01)
    assert np.array_equal(np.asarray(ours), np.asarray(theirs))


def test_plain_rewrites_log_formatters_mathtext():
    assert _plain(r"$\mathdefault{2\times10^{-1}}$") == "2×10⁻¹"
    assert _plain(r"$\mathdefault{10^{12}}$") == "10¹²"
    assert _plain(r"$\mathdefault{-10^{1}}$") == "−10¹"
    assert _plain(r"$\mathdefault{0}$") == "0"
    assert _plain("") == "" and _plain("plain") == "plain"


def test_plain_log_labels_label_the_same_ticks_without_mathtext():
    """Minor labels of a short log axis and a symlog axis's labels: the ticks matplotlib labels, as plain text."""
    import matplotlib.pyplot as plt

    fig, axes = new_figure(ncols=2)
    ax, bx = axes[0, 0], axes[0, 1]
    ax.semilogy([0, 1], [0.15, 0.7])
    bx.plot([0, 20], [0, 1])
    bx.set_xscale("symlog", linthresh=1.0)
    fig.canvas.draw()
    before = [[t.get_text() for t in axis.get_ticklabels(which="both")] for axis in (ax.yaxis, bx.xaxis)]
    plain_log_labels(fig)
    plain_log_labels(fig)                               # twice: the formatters are not wrapped twice
    fig.canvas.draw()
    after = [[t.get_text() for t in axis.get_ticklabels(which="both")] for axis in (ax.yaxis, bx.xaxis)]
    plt.close(fig)
    assert any("\\times" in label for label in before[0]) and any("$" in label for label in before[1])
    assert [[bool(label) for label in labels] for labels in before] == [[bool(label) for label in labels]
                                                                        for labels in after]
    assert not any("$" in label for labels in after for label in labels)
    assert "2×10⁻¹" in after[0]


def test_view_jobs_recordings_together_first_then_each_figure():
    views = [SimpleNamespace(file=f) for f in ("figures/a.png", "x.rrd", "figures/b.png", "y.rrd", "figures/c.png")]
    jobs = view_jobs(views, workers=2)
    assert [[v.file for v in job] for job in jobs] == [["x.rrd", "y.rrd"], ["figures/a.png"], ["figures/b.png"],
                                                       ["figures/c.png"]]
    many = [SimpleNamespace(file=f"r{i}.rrd") for i in range(9)]
    assert [len(job) for job in view_jobs(many, workers=2)] == [3, 3, 3]
