"""One self-contained HTML report that walks the whole chain on a campaign.

:func:`build_report` runs the chain (:mod:`sindy_ekf.stages.chain`) and :func:`render_report`
writes ``report.html``: the sections of :mod:`sindy_ekf.report.sections` in one page with
figures embedded as base64 PNG, CSS inline, no script and no network, so the file can be mailed
or archived as it is.
"""

from __future__ import annotations

import html
import logging
import time
from dataclasses import dataclass
from pathlib import Path

from groundfloor.errors import InputError
from groundfloor.files import atomic_write_text
from groundfloor.parallel import Workers
from groundfloor.progress import progress
from sindy_ekf.config import FilterConfig
from sindy_ekf.report.blocks import (
    CONTENT_LEFT_PX,
    FIGURE_GAP_PX,
    MARKER_WIDTH_PX,
    SECTIONS,
    Section,
)
from sindy_ekf.report.sections import SECTION_BUILDERS
from sindy_ekf.stages.chain import QUICK, STAGES, ChainResult, run_chain

log = logging.getLogger(__name__)

REPORT_FILE = "report.html"

CSS = f"""
body {{ font-family: DejaVu Sans, Helvetica, Arial, sans-serif; margin: 0; color: #222; background: #fff; }}
header {{ padding: 16px 24px 8px {MARKER_WIDTH_PX + 24}px; }}
h1 {{ margin: 0 0 4px 0; font-size: 24px; }}
nav a {{ margin-right: 14px; color: #225; }}
section {{ border-left: {MARKER_WIDTH_PX}px solid; padding: 4px 24px 12px {CONTENT_LEFT_PX - MARKER_WIDTH_PX}px;
           margin: 0 0 18px 0; }}
h2 {{ margin: 8px 0; font-size: 20px; }}
.note {{ color: #555; font-style: italic; }}
.fail {{ color: #a00; }}
.figs {{ display: flex; flex-wrap: wrap; gap: {FIGURE_GAP_PX}px; align-items: flex-start; }}
figure {{ margin: 0; max-width: 100%; }}
figure img {{ width: 100%; height: auto; display: block; }}
figcaption {{ font-size: 12px; color: #444; margin-top: 2px; }}
table {{ border-collapse: collapse; font-size: 13px; margin: 6px 0 10px 0; }}
th, td {{ border: 1px solid #ccc; padding: 2px 7px; text-align: right; }}
th {{ background: #f1f1f1; }}
td.l, th.l {{ text-align: left; }}
pre {{ background: #f6f6f6; padding: 8px; font-size: 12px; overflow-x: auto; }}
dl.terms {{ font-size: 13px; color: #333; margin: 4px 0 12px 0; display: grid;
            grid-template-columns: max-content auto; column-gap: 12px; row-gap: 2px; max-width: 1300px; }}
dl.terms dt {{ font-weight: bold; }}
dl.terms dd {{ margin: 0; }}
"""


def render_sections(chain: ChainResult, sections=tuple(SECTION_BUILDERS)) -> list[Section]:
    """Return the report's sections built from ``chain`` (a section that raises is marked failed)."""
    out = []
    titles = dict(SECTIONS)
    for sid in progress(list(sections), desc="report sections"):
        try:
            out.append(SECTION_BUILDERS[sid](chain))
        except Exception as exc:  # noqa: BLE001 - a broken section must not lose the report
            log.warning("report: section %s failed: %s: %s", sid, type(exc).__name__, exc)
            log.debug("section %s", sid, exc_info=True)
            sec = Section(sid, titles[sid], status="failed")
            sec.note(f"section could not be built: {type(exc).__name__}: {exc}".splitlines()[0], "fail")
            out.append(sec)
    return out


def html_from_sections(chain: ChainResult, sections: list[Section]) -> str:
    """Return the complete HTML document (inline CSS, embedded figures, no script)."""
    nav = " ".join(f'<a href="#{s.id}">{html.escape(s.title)}</a>' for s in sections)
    when = time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())
    return ("<!DOCTYPE html><html lang=en><head><meta charset=utf-8>"
            f"<title>sindy-ekf report: {html.escape(chain.trajectory.name)}</title><style>{CSS}</style></head><body>"
            f"<header><h1>sindy-ekf report: {html.escape(chain.trajectory.name)}</h1>"
            f'<p class="note">{html.escape(str(chain.campaign_path))}, {when}</p><nav>{nav}</nav></header>'
            + "".join(s.to_html() for s in sections) + "</body></html>\n")


def check_report_dir(out_dir: str | Path) -> Path:
    """Return ``out_dir`` created and writable, else raise InputError naming it."""
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputError(f"{out}: output exists and is not a folder")
    try:
        out.mkdir(parents=True, exist_ok=True)
        probe = out / ".sindy-ekf-write-probe"
        probe.write_text("")
        probe.unlink()
    except OSError as exc:
        raise InputError(f"{out}: output folder is not writable ({exc.strerror or exc})") from None
    return out


def render_report(chain: ChainResult, out_dir: str | Path, sections=tuple(SECTION_BUILDERS)) -> Path:
    """Return the path of ``out_dir/report.html`` written (atomically) from a finished chain."""
    out = check_report_dir(out_dir)
    return atomic_write_text(out / REPORT_FILE, html_from_sections(chain, render_sections(chain, sections)))


@dataclass(frozen=True)
class Report:
    """A report written: where it is and the chain it shows."""

    path: Path
    chain: ChainResult

    def to_json(self) -> dict:
        """Return the ``report --json`` content: the report's path and the chain's headline figures."""
        return {"report": str(self.path), **self.chain.headline()}


def build_report(campaign: str | Path, out_dir: str | Path, model: str | Path | None = None, quick: bool = False,
                 grid=None, stages=STAGES, config: FilterConfig | None = None,
                 workers: Workers | int = 1, train: str | Path | None = None) -> Report:
    """Return the report written for ``campaign`` into ``out_dir`` (``report.html``) and its chain.

    Parameters
    ----------
    campaign : tracker or trajectory campaign (data contract parts 1 and 2).
    out_dir : folder for ``report.html`` (and ``model.json`` when a model is identified).
    model : a model file of ``identify``; without it one is identified on the train runs.
    quick : identify with the search's quick grid instead of the full one (``grid`` overrides).
    stages : the chain's stages to run (see :data:`sindy_ekf.stages.chain.STAGES`).
    config : the benchmark's filter settings (:func:`sindy_ekf.config.load_config`; default the shipped ones).
    workers : where the chain's parallel tasks go (:mod:`groundfloor.parallel`).
    train : a campaign whose train runs the chain fits on instead of ``campaign``'s own.

    Raises
    ------
    InputError
        Not a campaign, no test runs (no train runs without ``model``), unwritable ``out_dir``.
    """
    check_report_dir(out_dir)  # fail before the work, not after it
    grid = grid if grid is not None else (QUICK if quick else None)
    chain = run_chain(campaign, out_dir, model=model, grid=grid, stages=stages, config=config, n_jobs=workers,
                      train=train)
    return Report(render_report(chain, out_dir), chain)
