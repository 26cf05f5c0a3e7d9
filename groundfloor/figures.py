"""Figure creation and saving, shared by every plot module (the ``figures`` modules).

Figures are :class:`matplotlib.figure.Figure` objects made without pyplot: no global registry
of open figures to leak, and no backend needed, since saving renders with Agg whatever the
backend is. So drawing a figure never changes a notebook user's backend (a notebook shows a
returned Figure as it is); only the command line and the report choose one.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
from matplotlib.figure import Figure

SAVE_DPI = 150  # an 8-inch figure becomes 1200 px: tick labels stay legible when zoomed in


def new_figure(width_in: float, height_in: float, nrows: int = 1, ncols: int = 1,
               **subplots_kw) -> tuple[Figure, np.ndarray]:
    """Return a figure of ``width_in`` x ``height_in`` inches and its axes as an ``(nrows, ncols)`` array.

    The layout is matplotlib's constrained layout (labels and colour bars never overlap);
    ``subplots_kw`` go to :meth:`~matplotlib.figure.Figure.subplots` (``sharex``,
    ``gridspec_kw``, ``subplot_kw={"projection": "3d"}``, ...).
    """
    fig = Figure(figsize=(width_in, height_in), layout="constrained")
    return fig, fig.subplots(nrows, ncols, squeeze=False, **subplots_kw)


def save_figure(fig: Figure, path: str | Path | None) -> Figure:
    """Return ``fig``, saved as PNG at ``path`` (folders made as needed) unless ``path`` is None."""
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=SAVE_DPI, format="png")
    return fig
