"""One self-contained HTML report that walks the whole chain on a campaign.

:func:`build_report` runs the chain (:mod:`sindy_ekf.report.chain`) and :func:`render_report`
writes ``report.html``: figures embedded as base64 PNG, CSS inline, no script and no network,
so the file can be mailed or archived as it is. Sections: campaign overview, calibration,
synchronisation, poses, identification, evaluation, estimation, diagnosis. A section that does
not apply (a trajectory campaign has no raw tracker data) or whose stage failed says so in one
line. Every section starts with a coloured band in the left margin (:data:`SECTION_MARKERS`),
which lets a screenshot test find each section's extent without a browser API.
"""

from __future__ import annotations

import html
import logging
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable

import numpy as np

from groundfloor.errors import InputError
from groundfloor.files import atomic_write_text
from groundfloor.progress import progress
from identification.preprocessing.figures import (
    plot_baseline,
    plot_baseline_vs_speed,
    plot_body_frame,
    plot_body_states,
    plot_clock_residuals,
    plot_gap_signal,
    plot_hub_model,
    plot_network,
    plot_offset_fit,
    plot_poses,
    plot_xcorr,
)
from identification.sindy.figures import (
    plot_error_curves,
    plot_error_vs_complexity,
    plot_grid,
    plot_term_prevalence,
)
from sindy_ekf.benchmark.figures import plot_nees, plot_outage_errors, plot_trajectories
from sindy_ekf.diagnose.figures import plot_lag_profile, plot_residual_structure
from sindy_ekf.report.bag_facts import bag_notes, bag_words
from sindy_ekf.report.chain import QUICK, STAGES, ChainResult, run_chain
from sindy_ekf.report.figures import (
    plot_driven_paths,
    plot_family_gains,
    plot_input_coverage,
    png_base64_from_figure,
    run_overview,
)

log = logging.getLogger(__name__)

REPORT_FILE = "report.html"
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
figure {{ margin: 0; width: {FIGURE_WIDTH_PX}px; }}
figure.wide {{ width: {WIDE_FIGURE_WIDTH_PX}px; }}
figure img {{ width: 100%; height: auto; display: block; }}
figcaption {{ font-size: 12px; color: #444; margin-top: 2px; }}
table {{ border-collapse: collapse; font-size: 13px; margin: 6px 0 10px 0; }}
th, td {{ border: 1px solid #ccc; padding: 2px 7px; text-align: right; }}
th {{ background: #f1f1f1; }}
td.l, th.l {{ text-align: left; }}
pre {{ background: #f6f6f6; padding: 8px; font-size: 12px; overflow-x: auto; }}
"""


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


def _vec(v, k: float = 1.0, fmt: str = "{:+.3f}") -> str:
    return "[" + ", ".join(fmt.format(x * k) for x in np.asarray(v, float).ravel()) + "]"


def _absent_or_failed(sec: Section, chain: ChainResult, stages: tuple[str, ...]) -> bool:
    """Mark ``sec`` absent/failed (with its reason) if one of ``stages`` did not give a result."""
    for st in stages:
        if st in chain.errors:
            sec.status = "failed"
            sec.note(f"stage '{st}' failed: {chain.errors[st]}", "fail")
            return True
        if st in chain.skipped:
            sec.status = "absent"
            sec.note(f"not available: {chain.skipped[st]}.")
            return True
    return False


# Sections
# --------------------------------------------------------------------------------------------

def section_overview(chain: ChainResult) -> Section:
    """Return the campaign overview: runs, durations, driven paths, input coverage (fig. 6.3)."""
    sec = Section("overview", "Campaign overview")
    traj = chain.trajectory
    rows = run_overview(traj)
    sec.note(f"{chain.campaign_path} ({chain.kind} campaign '{traj.name}'): {len(rows)} runs, "
             f"{sum(r['duration_s'] for r in rows) / 60:.1f} min, {sum(r['path_m'] for r in rows):.0f} m driven.")
    sec.add(table_html(["run", "split", "duration s", "poses", "rate Hz", "path m", "speed p99 m/s", "inputs"],
                       [[r["name"], r["split"], f"{r['duration_s']:.1f}", r["n_poses"], f"{r['rate_hz']:.1f}",
                         f"{r['path_m']:.1f}", f"{r['max_speed_m_s']:.2f}", r["n_inputs"]] for r in rows], left=2))
    skipped = (chain.preprocess or {}).get("skipped_runs") or {}
    for name, why in skipped.items():
        sec.note(f"run {name} skipped by preprocessing: {why}")
    states = chain.states.get("train", []) + chain.states.get("test", [])
    if not states:
        from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
        from identification.sindy.data import states_of_runs

        states = states_of_runs(traj.runs, DEFAULT_SMOOTHING)[0]
    sec.figures([(lambda: plot_driven_paths(traj.runs), "driven paths in the local frame"),
                 (lambda: plot_input_coverage(states), "density of control inputs and driving states (fig. 6.3)")])
    return sec


def section_calibration(chain: ChainResult) -> Section:
    """Return the calibration: transform (eq. 5.1, table 7.2), lever arms (table 7.1), residuals."""
    sec = Section("calibration", "Calibration")
    if _absent_or_failed(sec, chain, ("calibration",)):
        return sec
    from identification.preprocessing.network_transform import ARCSEC_PER_RAD

    cal, tf = chain.calibration, chain.calibration.transform
    std = tf.params_std
    sec.note("x_at960 = t + R x_ltd800 with R = Rz(rz) Ry(ry) Rx(rx) (eqs. 5.1 to 5.5); table 7.2 lists "
             "t_table = R^T t. Standard deviations a priori, from the survey sigmas.")
    sec.add(table_html(["quantity", "value", "std"], [
        ["t [m]", _vec(tf.t_at960_ltd800, fmt="{:+.6f}"), _vec(std[:3], 1e6, "{:.1f}") + " um"],
        ["t_table = R^T t [m]", _vec(tf.t_table, fmt="{:+.6f}"), _vec(tf.t_table_std, 1e6, "{:.1f}") + " um"],
        ["(rx, ry, rz) [deg]", _vec(np.degrees(tf.rotation_rad), fmt="{:+.6f}"),
         _vec(std[3:], ARCSEC_PER_RAD, "{:.2f}") + " arcsec"],
        ["a posteriori variance factor s0^2", f"{tf.variance_factor:.3f} (dof {tf.dof})", ""],
        ["outlier test", tf.blunder_message(), ""]]))
    lever_std = cal.body.lever_arms_std
    sec.add(table_html(["prism", "tracker", "lever arm, body frame [m]", "std [um]"],
                       [[k, cal.prism_tracker[k], _vec(v, fmt="{:+.5f}"), _vec(lever_std[k], 1e6, "{:.1f}")]
                        for k, v in cal.lever_arms_body.items()], left=2))
    sec.add(table_html(["network point", "residual [um]", "normalised", "leave-one-out T"],
                       [[pid, _vec(tf.residuals_m[i], 1e6, "{:+.1f}"), _vec(tf.normalised_residuals[i], fmt="{:+.2f}"),
                         f"{tf.point_test[i]:.2f}"] for i, pid in enumerate(tf.point_ids)]))
    sec.figures([(lambda: plot_network(chain.survey, tf), "network points and tracker frames (fig. 6.1), "
                  "residuals exaggerated"),
                 (lambda: plot_body_frame(chain.survey, cal.body), "body frame from the wheel hubs (fig. 7.1)")])
    return sec


def section_synchronisation(chain: ChainResult) -> Section:
    """Return the synchronisation: per-run clocks, offsets, baselines; figures of one run (5.2.2)."""
    sec = Section("synchronisation", "Synchronisation")
    if _absent_or_failed(sec, chain, ("calibration",)):
        return sec
    runs = (chain.preprocess or {}).get("runs", {})
    rows = []
    for name, r in runs.items():
        b, hub = r["baseline_rms_m"], r.get("hub") or {}
        rows.append([name, r["split"], f"{r['clock']['ltd800']['drift_ppm']:+.3f}",
                     f"{r['clock']['at960']['drift_ppm']:+.3f}", f"{r['at960_extra_offset_s'] * 1e3:+.3f}",
                     f"{r['timing_error']['r_baseline_speed_before']:+.2f}",
                     f"{r['timing_error']['r_baseline_speed_after']:+.2f}",
                     f"{b['before'] * 1e3:.3f}", f"{b['after'] * 1e3:.3f}",
                     f"{b['after_hub_model'] * 1e3:.3f}" if "after_hub_model" in b else "-",
                     f"{hub['r1'] * 1e3:.3f} / {hub['r2'] * 1e3:.3f}" if hub else "-", bag_words(r)])
    sec.note("Clock model t_trigger = k t_tracker + d per tracker (drift = (k - 1) 1e6), the AT960's "
             "extra offset, the correlation r of the baseline length with forward speed before and after "
             "it, the baseline RMS and the turning-hub model of eq. 5.25; what reading the bags found.")
    sec.add(table_html(["run", "split", "LTD800 ppm", "AT960 ppm", "AT960 offset ms", "r before", "r after",
                        "baseline RMS before mm", "after", "after hub", "hub r1/r2 mm", "bags"], rows, left=2))
    for line in bag_notes(runs):
        sec.note(line)
    if _absent_or_failed(sec, chain, ("synchronisation",)):
        return sec
    raw, run = chain.showcase
    s = run.synced
    sec.note(f"Figures for test run {raw.name}.")
    items = [(lambda: plot_gap_signal(raw, "ltd800"), "gap signals and detected gaps (fig. 5.1)"),
             (lambda: plot_xcorr(raw, s), "cross-correlation of the gap signals (fig. 5.2)"),
             (lambda: plot_clock_residuals(s), "clock fit residuals (fig. 5.4)"),
             (lambda: plot_baseline(s), "baseline length before and after the offset (fig. 5.5)"),
             (lambda: plot_offset_fit(s), "AT960 extra offset fit (fig. 5.6)"),
             (lambda: plot_baseline_vs_speed(s), "baseline against forward speed")]
    if run.hub is not None:
        items.append((lambda: plot_hub_model(run.hub), "turning-hub model, eq. 5.25 (fig. 5.7)"))
    sec.figures(items)
    return sec


def section_poses(chain: ChainResult) -> Section:
    """Return the poses of one test run with their sigmas (figs. 7.2, 7.3) and its body states (7.9)."""
    sec = Section("poses", "Poses and body-frame states")
    run = chain.trajectory.split("test")[0]
    poses = chain.showcase[1].poses if chain.showcase is not None else run.poses
    items = [(lambda: plot_poses(poses), f"run {run.name}: position, attitude and their sigmas (figs. 7.2, 7.3)")]
    test_states = chain.states.get("test")
    if test_states:
        s = float(chain.model.hyperparameters.get("s") or 0.0)
        items.append((lambda: plot_body_states({s: test_states[0]}, t_range=(0.0, 40.0)),
                      f"body-frame velocities of the first test segment, s = {s:g} (eqs. 5.64-5.68, fig. 7.9)"))
    sec.figures(items)
    return sec


def section_identification(chain: ChainResult) -> Section:
    """Return the identification: grid search, selected model's equations, term prevalence."""
    sec = Section("identification", "Identification")
    if _absent_or_failed(sec, chain, ("identification",)):
        return sec
    model = chain.model
    hp = ", ".join(f"{k} = {v:g}" for k, v in model.hyperparameters.items())
    src = f"loaded from {chain.model_path}" if chain.search is None else f"selected by the grid search ({hp})"
    sec.note(f"Integral SINDy (eqs. 5.55 to 5.59), library {model.library.name}, {model.complexity} active "
             f"terms, {src}.")
    sec.add(f"<pre>{html.escape(model.equations())}</pre>")
    if chain.search is None:
        return sec
    res = chain.search
    rows = [[i, f"{r['s']:g}", f"{r['tau']:g}", f"{r['alpha']:g}", f"{r['T']:g}", f"{r['complexity']:.0f}",
             f"{100 * r['pos_err_5s_m']:.2f}", f"{r['yaw_err_5s_deg']:.2f}"] for i, r in enumerate(res.ranking(8), 1)]
    sec.add(table_html(["rank", "s", "tau s", "alpha", "T", "terms", "CV pos 5 s cm", "CV yaw 5 s deg"], rows))
    s = float(model.hyperparameters["s"])
    items = [(lambda: plot_grid(res, s), f"grid over alpha and T at s = {s:g} (figs. 7.4-7.7)"),
             (lambda: plot_error_vs_complexity(res), "5 s errors against complexity (fig. 7.10)")]
    if res.top_models:
        items.append((lambda: plot_term_prevalence(res.top_models),
                      f"term prevalence in the {len(res.top_models)} best models (fig. 7.11)"))
    sec.figures(items)
    return sec


def section_evaluation(chain: ChainResult) -> Section:
    """Return the multi-step evaluation on the test runs: s_p(t), s_h(t) (eqs. 5.76-5.78, fig. 7.8)."""
    sec = Section("evaluation", "Evaluation")
    if _absent_or_failed(sec, chain, ("identification", "evaluation")):
        return sec
    ev = chain.evaluation
    sindy = ev["sindy"]
    sec.note(f"{sindy.n_windows} windows of 5 s (50 % overlap) on the test runs, RK4 on eq. 5.75. "
             "Thesis (model B, real data): 14.0 cm and 4.2 deg after 5 s.")
    sec.add(table_html(["model", "pos. error 5 s cm", "heading error 5 s deg"],
                       [[n, f"{100 * r.pos_err_5s_m:.2f}", f"{r.yaw_err_5s_deg:.2f}"] for n, r in ev.items()]))
    sec.figures([(lambda: plot_error_curves([sindy]), "SINDy model: per-window errors and s_p(t), s_h(t)"),
                 (lambda: plot_error_curves(list(ev.values()), stacked=False), "all models: s_p(t), s_h(t)")])
    return sec


def section_estimation(chain: ChainResult) -> Section:
    """Return the estimator benchmark: trajectories with outages, error against outage time, NEES."""
    sec = Section("estimation", "Estimation")
    if _absent_or_failed(sec, chain, ("identification", "estimation")):
        return sec
    b = chain.benchmark
    lo, hi = b.nees_bounds_95
    sec.note(f"GNSS profile {b.profile} on the test runs, outages as scheduled; the laser-tracker poses are the "
             f"truth (alignment: {b.alignment}). NEES of the pose (3 dof): a consistent filter has mean 3 and "
             f"95 % of the samples inside [{lo:.2f}, {hi:.2f}].")
    durations = sorted({k for sc in b.scores.values() for k in sc.outage_pos_err_m}, key=float)
    rows = [[n, f"{sc.ate_pos_m:.3f}", f"{sc.ate_yaw_deg:.2f}",
             *[f"{sc.outage_pos_err_m[d]:.3f}" if d in sc.outage_pos_err_m else "-" for d in durations],
             f"{sc.nees_mean:.2f}", f"{100 * sc.nees_inside_95:.0f}", f"{sc.runtime_s:.2f}",
             f"{sc.realtime_factor:.0f}"] for n, sc in b.scores.items()]
    sec.add(table_html(["estimator", "ATE pos m", "ATE yaw deg", *[f"end of {d} s outage m" for d in durations],
                        "NEES mean", "NEES in 95 % %", "runtime s", "x real time"], rows))
    sec.figures([(lambda: plot_trajectories(b), "trajectories of the test runs, outages shaded"),
                 (lambda: plot_outage_errors(b), "RMS position error against time since the outage began"),
                 (lambda: plot_nees(b), "pose NEES of the first test run with the 95 % bounds (consistency)")])
    return sec


def section_diagnosis(chain: ChainResult) -> Section:
    """Return the diagnosis: ranked causes with gain and threshold, verdict, gain of the extension."""
    sec = Section("diagnosis", "Diagnosis")
    if _absent_or_failed(sec, chain, ("identification", "diagnosis")):
        return sec
    d = chain.diagnosis
    b, a = d.before, d.after
    sec.note(f"Most likely cause: {d.verdict}. 5 s position error on the test runs {100 * b['pos_err_5s_m']:.2f} cm "
             f"before, {100 * a['pos_err_5s_m']:.2f} cm with the extended model.")
    if d.outage:
        sec.note(f"EKF error at the end of {d.outage['outage_s']:g} s GNSS outages (RMS over {d.outage['n']}): "
                 f"{d.outage['before_m']:.3f} m before, {d.outage['after_m']:.3f} m after.")
    rows = [[c.name, f"{100 * c.gain:.2f}", f"{100 * c.threshold:.2f}", "yes" if c.significant else "no",
             ", ".join(f"{k} = {v:.4g}" if isinstance(v, float) else f"{k} = {v}"
                       for k, v in (c.score.estimate or {}).items())] for c in d.ranked]
    sec.add(table_html(["family", "test gain %", "threshold %", "significant", "estimate"], rows))
    for f in getattr(d, "measurement", []) or []:
        sec.note(f"measurement finding '{f.name}' ({f.runs} runs): {f.cause}; correction: {f.correction}")
    items = [(lambda: plot_family_gains(d.ranked), "out-of-sample gain of each family against its threshold")]
    if getattr(d, "structure", None):
        items.insert(0, (lambda: plot_residual_structure(d.structure, title="test runs"),
                         "residual structure: binned window residuals (eq. 5.56) against each regressor"))
    if getattr(d, "lag", None):
        items.insert(1, (lambda: plot_lag_profile(d.lag), "residual-input lag correlation"))
    sec.figures(items)
    return sec


SECTION_BUILDERS = {"overview": section_overview, "calibration": section_calibration,
                    "synchronisation": section_synchronisation, "poses": section_poses,
                    "identification": section_identification, "evaluation": section_evaluation,
                    "estimation": section_estimation, "diagnosis": section_diagnosis}


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


def build_report(campaign: str | Path, out_dir: str | Path, model: str | Path | None = None, quick: bool = False,
                 grid=None, stages=STAGES) -> Path:
    """Return the path of the HTML report written for ``campaign`` into ``out_dir``.

    Parameters
    ----------
    campaign : tracker or trajectory campaign (data contract parts 1 and 2).
    out_dir : folder for ``report.html`` (and ``model.json`` when a model is identified).
    model : a model file of ``identify``; without it one is identified on the train runs.
    quick : identify with the search's quick grid instead of the full one (``grid`` overrides).
    stages : the chain's stages to run (see :data:`sindy_ekf.report.chain.STAGES`).

    Raises
    ------
    InputError
        Not a campaign, no test runs (no train runs without ``model``), unwritable ``out_dir``.
    """
    check_report_dir(out_dir)  # fail before the work, not after it
    grid = grid if grid is not None else (QUICK if quick else None)
    chain = run_chain(campaign, out_dir, model=model, grid=grid, stages=stages)
    return render_report(chain, out_dir)
