"""Figure creation, time-series lines and saving, shared by every plot module (the ``figures`` modules).

Figures are :class:`matplotlib.figure.Figure` objects made without pyplot: no global registry
of open figures to leak, and no backend needed, since saving renders with Agg (PNG) or the SVG
writer whatever the backend is. So drawing a figure never changes a notebook user's backend (a
notebook shows a returned Figure as it is); only the command line and the report choose one.

Sizes: a figure's width in inches is its displayed width (the report shows figures at their
natural size, 96 px per inch), so text of the same point size reads the same in every figure.
:data:`WIDTH_IN` is the width of a figure that stands beside another in the report,
:data:`WIDE_IN` of one that spans the page.

Time series are drawn with :func:`plot_series`, which breaks the line where the samples have a
gap (a prism lost, an outage): a straight line across a gap would show data that was never
measured. The gap threshold is the caller's (the project's rule is
:func:`identification.sindy.data.gap_threshold_s`; this module imports nothing of the project).
"""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
from matplotlib.figure import Figure
from matplotlib.ticker import ScalarFormatter

SAVE_DPI = 200  # a 6.8-inch figure becomes 1360 px: tick labels stay legible when zoomed in
WIDTH_IN = 6.8  # a figure beside another on a 1400 px page
WIDE_IN = 13.8  # a figure across the page


def new_figure(width_in: float, height_in: float, nrows: int = 1, ncols: int = 1,
               **subplots_kw) -> tuple[Figure, np.ndarray]:
    """Return a figure of ``width_in`` x ``height_in`` inches and its axes as an ``(nrows, ncols)`` array.

    The layout is matplotlib's constrained layout (labels and colour bars never overlap);
    ``subplots_kw`` go to :meth:`~matplotlib.figure.Figure.subplots` (``sharex``,
    ``gridspec_kw``, ``subplot_kw={"projection": "3d"}``, ...).
    """
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    return fig, fig.subplots(nrows, ncols, squeeze=False, **subplots_kw)


def break_at_gaps(t: np.ndarray, *values: np.ndarray, gap_s: float) -> tuple[np.ndarray, ...]:
    """Return ``t`` and ``values`` with a NaN sample inserted inside every step of ``t`` longer than ``gap_s``.

    A line drawn through the result stops at each gap and starts again after it. ``values`` are
    arrays whose first axis matches ``t``.
    """
    t = np.asarray(t, dtype=float)
    cut = np.flatnonzero(np.diff(t) > gap_s) + 1
    if cut.size == 0:
        return (t, *(np.asarray(v) for v in values))
    mid = 0.5 * (t[cut - 1] + t[cut])
    out = [np.insert(t, cut, mid)]
    for v in values:
        v = np.asarray(v, dtype=float)
        out.append(np.insert(v, cut, np.nan, axis=0))
    return tuple(out)


def plot_series(ax, t: np.ndarray, y: np.ndarray, gap_s: float | None, *args, **kwargs):
    """Draw ``y`` against ``t`` on ``ax`` as a line broken at gaps longer than ``gap_s`` (None: never).

    ``args`` and ``kwargs`` go to :meth:`~matplotlib.axes.Axes.plot`; returns its lines.
    """
    if gap_s is not None:
        t, y = break_at_gaps(t, y, gap_s=gap_s)
    return ax.plot(t, y, *args, **kwargs)


def plain_axis(ax, which: str = "y") -> None:
    """Show the tick labels of ``ax``'s ``which`` axis as plain numbers, without an offset or
    scale written at the axis's end (which hides the values: "1e-5 - 1.25")."""
    fmt = ScalarFormatter(useOffset=False)
    fmt.set_scientific(False)
    (ax.yaxis if which == "y" else ax.xaxis).set_major_formatter(fmt)


def save_figure(fig: Figure, path: str | Path | None) -> Figure:
    """Return ``fig``, saved at ``path`` (folders made as needed) unless ``path`` is None.

    The format follows the suffix: ``.svg`` (vector) or ``.png`` (at :data:`SAVE_DPI`).
    """
    if path is not None:
        path = Path(path)
        path.parent.mkdir(parents=True, exist_ok=True)
        if path.suffix.lower() == ".svg":
            fig.savefig(path, format="svg")
        else:
            fig.savefig(path, dpi=SAVE_DPI, format="png")
    return fig


def svg_from_figure(fig: Figure) -> bytes:
    """Return the figure as an SVG document (text as paths: it looks the same in every browser)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="svg", metadata={"Date": None})
    return buf.getvalue()


def png_from_figure(fig: Figure, dpi: float) -> bytes:
    """Return the figure as PNG bytes at ``dpi``."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi)
    return buf.getvalue()
