"""The building blocks of the report's page: sections with their notes, tables and figures.

A :class:`Section` collects HTML fragments; its figures are drawn on the spot and embedded as
base64 PNG at exactly their displayed width. Every section starts with a coloured band in the
left margin (:data:`SECTION_MARKERS`), which lets a screenshot test find each section's extent
without a browser API.
"""

from __future__ import annotations

import html
import logging
from dataclasses import dataclass, field
from typing import Callable

from sindy_ekf.report.figures import png_base64_from_figure

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
FIGURE_WIDTH_PX = 660  # displayed width of every figure; two side by side in a 1400 px window
FIGURE_GAP_PX = 12
WIDE_ASPECT = 2.2  # figures wider than this (width / height) span both columns
WIDE_FIGURE_WIDTH_PX = 2 * FIGURE_WIDTH_PX + FIGURE_GAP_PX
CONTENT_LEFT_PX = MARKER_WIDTH_PX + 24  # left edge of a section's content


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
                w, h = fig.get_size_inches()
                wide = ' class="wide"' if w / h > WIDE_ASPECT else ""
                # drawn at exactly its displayed width: the browser shows it pixel for pixel, unscaled
                b64 = png_base64_from_figure(fig, dpi=(WIDE_FIGURE_WIDTH_PX if wide else FIGURE_WIDTH_PX) / w)
                cap = caption if k == 0 else f"{caption} ({k + 1})"
                out.append(f'<figure{wide}><img alt="{html.escape(cap)}" src="data:image/png;base64,{b64}">'
                           f"<figcaption>{html.escape(cap)}</figcaption></figure>")
                self.n_figures += 1
        self.parts.append('<div class="figs">' + "".join(out) + "</div>")

    def to_html(self) -> str:
        """Return the section as HTML with its marker band."""
        r, g, b = SECTION_MARKERS[self.id]
        return (f'<section id="{self.id}" data-status="{self.status}" data-figures="{self.n_figures}" '
                f'style="border-left-color: rgb({r},{g},{b})">'
                f"<h2>{html.escape(self.title)}</h2>" + "".join(self.parts) + "</section>")


def table_html(header: list[str], rows: list[list], left: int = 1) -> str:
    """Return an HTML table; the first ``left`` columns are left-aligned text, floats are kept as given."""
    def cell(tag, i, v):
        return f'<{tag}{" class=l" if i < left else ""}>{html.escape(str(v))}</{tag}>'

    head = "<tr>" + "".join(cell("th", i, h) for i, h in enumerate(header)) + "</tr>"
    body = "".join("<tr>" + "".join(cell("td", i, v) for i, v in enumerate(row)) + "</tr>" for row in rows)
    return f"<table>{head}{body}</table>"
