"""The building blocks of the report's page: sections with their notes, tables and figures.

A :class:`Section` collects HTML fragments; its figures are drawn on the spot and embedded as
SVG (``<img src="data:image/svg+xml;base64,...">``: vector, so they stay sharp at any zoom, and
each in its own document, so the ids matplotlib writes never clash) at their natural size,
:data:`PX_PER_IN` pixels per inch of the figure, so that text of one point size reads the same
in every figure; a figure wider than the page shrinks to fit (the report's test checks that none
is). Why SVG and not PNG: see :data:`FIGURE_FORMAT`. Every section starts
with a coloured band in the left margin (:data:`SECTION_MARKERS`), which lets a screenshot be
cut into sections.
"""

from __future__ import annotations

import base64
import html
import logging
from dataclasses import dataclass, field
from typing import Callable

from groundfloor.figures import png_from_figure, svg_from_figure

log = logging.getLogger(__name__)

SECTIONS = (("overview", "Campaign overview"), ("calibration", "Calibration"),
            ("synchronisation", "Synchronisation"), ("poses", "Poses and body-frame states"),
            ("identification", "Identification"), ("evaluation", "Evaluation"),
            ("estimation", "Estimation"), ("diagnosis", "Diagnosis"))
# Left-margin band colour per section: saturated, pairwise distinct, never used by a figure's
# background (a screenshot test locates sections by them).
SECTION_MARKERS = {"overview": (230, 25, 75), "calibration": (60, 180, 75), "synchronisation": (0, 130, 200),
                   "poses": (245, 130, 48), "identification": (145, 30, 180), "evaluation": (70, 240, 240),
                   "estimation": (240, 50, 230), "diagnosis": (128, 128, 0)}
MARKER_WIDTH_PX = 14
FIGURE_GAP_PX = 12
CONTENT_LEFT_PX = MARKER_WIDTH_PX + 24  # left edge of a section's content
PX_PER_IN = 96  # CSS pixels per inch: a figure is shown at its size in inches
# "svg" or "png". SVG stays sharp at any zoom, where a PNG blurs beyond its resolution; the
# demo's report with SVG figures is 5.0 MB (bench/results/demo.md). PNG_SCALE applies to "png".
FIGURE_FORMAT = "svg"
PNG_SCALE = 2  # PNG pixels per CSS pixel when FIGURE_FORMAT is "png" (sharp at 200 % zoom)


@dataclass
class Section:
    """One section of the report: its id, title and HTML body, and whether it has content."""

    id: str
    title: str
    parts: list[str] = field(default_factory=list)
    status: str = "ok"  # "ok", "absent" (does not apply) or "failed"
    n_figures: int = 0

    def add(self, text: str) -> None:
        """Append an HTML fragment."""
        self.parts.append(text)

    def note(self, text: str, css: str = "note") -> None:
        """Append a one-line remark (escaped)."""
        self.parts.append(f'<p class="{css}">{html.escape(text)}</p>')

    def figures(self, items: list[tuple[Callable, str]]) -> None:
        """Draw and embed figures ``[(draw, caption)]``; a figure that fails is named, not fatal."""
        out = []
        for draw, caption in items:
            try:
                figs = draw()
            except Exception as exc:  # noqa: BLE001 - one broken figure must not lose the section
                log.warning("report: figure '%s' failed: %s: %s", caption, type(exc).__name__, exc)
                why = f"{type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
                out.append(f'<p class="fail">figure "{html.escape(caption)}" could not be drawn: {html.escape(why)}</p>')
                continue
            for k, fig in enumerate(figs if isinstance(figs, (list, tuple)) else [figs]):
                cap = caption if k == 0 else f"{caption} ({k + 1})"
                out.append(figure_html(fig, cap))
                self.n_figures += 1
        self.parts.append('<div class="figs">' + "".join(out) + "</div>")

    def to_html(self) -> str:
        """Return the section as HTML with its marker band."""
        r, g, b = SECTION_MARKERS[self.id]
        return (f'<section id="{self.id}" data-status="{self.status}" data-figures="{self.n_figures}" '
                f'style="border-left-color: rgb({r},{g},{b})">'
                f"<h2>{html.escape(self.title)}</h2>" + "".join(self.parts) + "</section>")


def figure_html(fig, caption: str) -> str:
    """Return a ``<figure>`` with ``fig`` embedded (:data:`FIGURE_FORMAT`) at its natural size and its caption."""
    w_in, h_in = fig.get_size_inches()
    if FIGURE_FORMAT == "svg":
        mime, data = "image/svg+xml", svg_from_figure(fig)
    else:
        mime, data = "image/png", png_from_figure(fig, dpi=PNG_SCALE * PX_PER_IN)
    b64 = base64.b64encode(data).decode("ascii")
    w_px, h_px = round(w_in * PX_PER_IN), round(h_in * PX_PER_IN)
    return (f'<figure style="width: {w_px}px"><img alt="{html.escape(caption)}" width="{w_px}" height="{h_px}" '
            f'src="data:{mime};base64,{b64}"><figcaption>{html.escape(caption)}</figcaption></figure>')


def table_html(header: list[str], rows: list[list], left: int = 1) -> str:
    """Return an HTML table; the first ``left`` columns are left-aligned text, floats are kept as given."""
    def cell(tag, i, v):
        return f'<{tag}{" class=l" if i < left else ""}>{html.escape(str(v))}</{tag}>'

    head = "<tr>" + "".join(cell("th", i, h) for i, h in enumerate(header)) + "</tr>"
    body = "".join("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(row)) + "</tr>" for row in rows)
    return f"<table>{head}{body}</table>"
