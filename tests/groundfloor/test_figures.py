"""Lines stop at data gaps; figures saved as SVG or PNG by suffix; axes without a hiding offset label."""

from __future__ import annotations

import numpy as np
from PIL import Image

from groundfloor.figures import (
    SAVE_DPI,
    break_at_gaps,
    new_figure,
    plain_axis,
    plot_series,
    save_figure,
    svg_from_figure,
)


def test_a_nan_is_put_in_every_gap_and_nowhere_else():
    t = np.array([0.0, 0.1, 0.2, 1.2, 1.3, 3.0])
    y = t ** 2
    tb, yb = break_at_gaps(t, y, gap_s=0.5)
    # gaps after 0.2 (1.0 s) and after 1.3 (1.7 s): one NaN in each, at the middle of the gap
    np.testing.assert_allclose(tb, [0.0, 0.1, 0.2, 0.7, 1.2, 1.3, 2.15, 3.0])
    assert np.flatnonzero(np.isnan(yb)).tolist() == [3, 6]
    np.testing.assert_array_equal(yb[~np.isnan(yb)], y)
    # no gap: unchanged; two-column values keep their columns
    same_t, same_y = break_at_gaps(t, y, gap_s=5.0)
    np.testing.assert_array_equal(same_t, t)
    np.testing.assert_array_equal(same_y, y)
    _, xy = break_at_gaps(t, np.column_stack([t, y]), gap_s=0.5)
    assert xy.shape == (8, 2) and np.isnan(xy[3]).all()


def test_plotted_line_has_as_many_pieces_as_the_data_between_gaps():
    fig, ((ax,),) = new_figure(4, 3)
    t = np.concatenate([np.arange(10) * 0.1, 5 + np.arange(10) * 0.1])
    (line,) = plot_series(ax, t, np.sin(t), 0.5)
    y = line.get_ydata()
    pieces = np.count_nonzero(np.diff(np.r_[0, np.isfinite(y).astype(int)]) == 1)
    assert pieces == 2
    (joined,) = plot_series(ax, t, np.sin(t), None)  # None: never broken
    assert np.isfinite(joined.get_ydata()).all()


def test_save_by_suffix(tmp_path):
    fig, ((ax,),) = new_figure(3, 2)
    ax.plot([0, 1], [100.0000125, 100.0000250])
    svg_from_figure(fig)  # draws the figure (ticks and their labels are made when drawn)
    assert ax.yaxis.get_major_formatter().get_offset() != ""  # matplotlib's default: "1e-5 + 1e2" at the axis's end
    plain_axis(ax)
    svg_from_figure(fig)  # draws the figure (ticks and their labels are made when drawn)
    # the values are on the ticks themselves, no offset written apart
    assert ax.yaxis.get_major_formatter().get_offset() == ""
    ticks = [float(t.get_text()) for t in ax.get_yticklabels() if t.get_text()]
    np.testing.assert_allclose(ticks, ax.get_yticks()[:len(ticks)], atol=1e-9)
    save_figure(fig, tmp_path / "a.svg")
    save_figure(fig, tmp_path / "b" / "a.png")
    assert (tmp_path / "a.svg").read_text().lstrip().startswith("<?xml")
    assert Image.open(tmp_path / "b" / "a.png").size == (3 * SAVE_DPI, 2 * SAVE_DPI)
    assert b"<svg" in svg_from_figure(fig)
