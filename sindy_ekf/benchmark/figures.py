"""Figures of the benchmark: trajectories with GNSS and outages, errors with their 3-sigma bands,
error growth in outages, pose NEES.

Each ``plot_*`` takes a :class:`~sindy_ekf.benchmark.result.BenchmarkResult`, returns a matplotlib
Figure and saves it as PNG when given ``path``; :func:`write_benchmark_figures` writes them
beside the files of :func:`~sindy_ekf.benchmark.files.write_benchmark` (``benchmark --out``).
Lines over time break where the poses have a gap (a prism lost), outages are shaded.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from groundfloor.figures import WIDE_IN, break_at_gaps, new_figure, plot_series, save_figure
from identification.sindy.data import gap_threshold_s
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.benchmark.scoring import pose_error, pose_nees

TRUTH_STYLE = {"color": "k", "lw": 2.2}
GNSS_STYLE = {"color": "0.45", "marker": ".", "ls": "none", "ms": 2.5}
OUTAGE_COLOR = "#ffd9a0"


def _colors(result: BenchmarkResult) -> dict[str, str]:
    """Return one colour per estimator, the same in every figure."""
    return {name: f"C{i % 10}" for i, name in enumerate(result.estimates)}


def _shade_outages(ax, outages: np.ndarray, t0: float, label: bool = True) -> None:
    """Shade the scheduled outages ``[begin, end]`` (times since ``t0``) on a time axis."""
    for k, (a, b) in enumerate(outages):
        ax.axvspan(a - t0, b - t0, color=OUTAGE_COLOR, lw=0, zorder=0,
                   label="GNSS outage" if label and k == 0 else None)


def gnss_at_body_origin(result: BenchmarkResult, run: str) -> tuple[np.ndarray, np.ndarray]:
    """Return the fixes of ``run`` moved from the antenna to the body origin with the true heading:
    times ``(k,)`` and ``(k, 2)`` positions (empty without GNSS)."""
    g = result.gnss.get(run)
    if g is None or g.t_valid.size == 0:
        return np.empty(0), np.empty((0, 2))
    tr = result.truth[run]
    yaw = np.interp(g.t_valid, tr[:, 0], tr[:, 3])
    lever = np.asarray(g.lever_arm_body, float)
    offset = np.column_stack([np.cos(yaw) * lever[0] - np.sin(yaw) * lever[1],
                              np.sin(yaw) * lever[0] + np.cos(yaw) * lever[1]])
    return g.t_valid, g.p_local[:, :2] - offset


def plot_trajectories(result: BenchmarkResult, path: str | Path | None = None):
    """Return a figure of each test run's trajectories with the GNSS fixes, outages marked on the truth.

    The axes frame the truth (estimates that wander far off leave the frame; their errors are
    in the tables).
    """
    runs = list(result.truth)
    colors = _colors(result)
    fig, axes = new_figure(WIDE_IN, 5.4, ncols=len(runs))
    for ax, run in zip(axes[0], runs):
        tr = result.truth[run]
        gap_s = gap_threshold_s(tr[:, 0])
        _, x, y = break_at_gaps(tr[:, 0], tr[:, 1], tr[:, 2], gap_s=gap_s)
        ax.plot(x, y, label="laser tracker (truth)", **TRUTH_STYLE)
        for k, (a, b) in enumerate(result.outages[run]):
            m = (tr[:, 0] >= a) & (tr[:, 0] <= b)
            ax.plot(tr[m, 1], tr[m, 2], "-", color=OUTAGE_COLOR, lw=9, zorder=0,
                    label="GNSS outage" if k == 0 else None, solid_capstyle="butt")
        t_g, p_g = gnss_at_body_origin(result, run)
        ax.plot(p_g[:, 0], p_g[:, 1], label="GNSS fixes", zorder=1, **GNSS_STYLE)
        for name, per_run in result.estimates.items():
            e = per_run[run]
            _, ex, ey = break_at_gaps(e.t, e.x[:, 0], e.x[:, 1], gap_s=gap_s)
            ax.plot(ex, ey, lw=1, color=colors[name], label=name)
        pad = 0.15 * max(np.ptp(tr[:, 1]), np.ptp(tr[:, 2]), 0.5)
        ax.set_xlim(tr[:, 1].min() - pad, tr[:, 1].max() + pad)
        ax.set_ylim(tr[:, 2].min() - pad, tr[:, 2].max() + pad)
        ax.set(title=run, xlabel="x local [m]", aspect="equal")
    axes[0][0].set_ylabel("y local [m]")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=min(len(labels), 5), fontsize=9)
    return save_figure(fig, path)


def plot_error_bands(result: BenchmarkResult, run: str | None = None,
                     estimators: Sequence[str] = ("sindy_ekf", "sindy_graph"), path: str | Path | None = None):
    """Return the errors of ``estimators`` on one test run with their 3-sigma bands and the GNSS fixes' errors.

    Rows: x, y and heading error against the truth; the band is +-3 standard deviations of the
    estimator's own covariance (a consistent estimator stays inside it almost always), the dots
    the fixes' errors (moved to the body origin), outages shaded.
    """
    run = run or next(iter(result.truth))
    # an estimator that diverged at once has no estimate to draw: the first that has one stands in
    reached = [n for n, runs in result.estimates.items() if run in runs and len(runs[run].t) > 1]
    names = [n for n in estimators if n in reached] or reached[:1] or list(result.estimates)[:1]
    tr = result.truth[run]
    t0, gap_s = tr[0, 0], gap_threshold_s(tr[:, 0])
    colors = _colors(result)
    fig, axes = new_figure(WIDE_IN, 6.6, 3, len(names), sharex=True, sharey="row")
    t_g, p_g = gnss_at_body_origin(result, run)
    g_err = p_g - np.column_stack([np.interp(t_g, tr[:, 0], tr[:, 1]), np.interp(t_g, tr[:, 0], tr[:, 2])])
    rows = (("x error [m]", 1.0), ("y error [m]", 1.0), ("heading error [deg]", np.degrees(1.0)))
    for j, name in enumerate(names):
        e = result.estimates[name][run]
        err = pose_error(e, tr)
        std = np.sqrt(np.stack([e.P[:, i, i] for i in range(3)], axis=1))
        t = e.t - t0
        for i, (ylabel, k) in enumerate(rows):
            ax = axes[i, j]
            _shade_outages(ax, result.outages[run], t0, label=(i == 0))
            tb, lo, hi = break_at_gaps(t, -3 * std[:, i] * k, 3 * std[:, i] * k, gap_s=gap_s)
            ax.fill_between(tb, lo, hi, color=colors[name], alpha=0.2, lw=0, label="+-3 sigma (own covariance)")
            if i < 2 and t_g.size:
                ax.plot(t_g - t0, g_err[:, i], label="GNSS fix error", **GNSS_STYLE)
            plot_series(ax, t, err[:, i] * k, gap_s, color=colors[name], lw=1, label=f"{name} error")
            ax.axhline(0.0, color="k", lw=0.5)
            if j == 0:
                ax.set_ylabel(ylabel)
        axes[0, j].set_title(f"{run}: {name}")
        axes[-1, j].set_xlabel("time since the run's first pose [s]")
        # the band sets the scale: fixes far outside it are clipped, not allowed to flatten the errors
        lim = np.nanpercentile(np.abs(np.concatenate([3 * std[:, :2].ravel(), err[:, :2].ravel()])), 99)
        if np.isfinite(lim) and lim > 0:
            axes[0, j].set_ylim(-1.3 * lim, 1.3 * lim)
    handles, labels = axes[0, 0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside lower center", ncols=len(labels), fontsize=9)
    return save_figure(fig, path)


def plot_outage_errors(result: BenchmarkResult, path: str | Path | None = None):
    """Return a figure of RMS position error against time since the outage began, per length."""
    keys = sorted({k for c in result.outage_curves.values() for k in c}, key=float)
    counts = {k: sum(int(np.isclose(b - a, float(k))) for o in result.outages.values() for a, b in o) for k in keys}
    colors = _colors(result)
    fig, axes = new_figure(WIDE_IN, 4.2, ncols=max(len(keys), 1), sharey=True)
    for ax, key in zip(axes[0], keys):
        for name, c in result.outage_curves.items():
            if key in c:
                ax.plot(c[key][:, 0], c[key][:, 1], color=colors[name], lw=1.5, label=name)
        ax.set(title=f"{key} s outages (RMS over {counts[key]})", xlabel="time since the outage began [s]",
               yscale="log")
    axes[0][0].set_ylabel("RMS position error [m]")
    handles, labels = axes[0][0].get_legend_handles_labels()
    fig.legend(handles, labels, loc="outside right center", fontsize=9)
    return save_figure(fig, path)


def plot_nees(result: BenchmarkResult, path: str | Path | None = None, run: str | None = None):
    """Return a figure of the pose NEES over time of one run, with the 95 % chi-square bounds."""
    run = run or next(iter(result.truth))
    t0 = result.truth[run][0, 0]
    gap_s = gap_threshold_s(result.truth[run][:, 0])
    colors = _colors(result)
    fig, ((ax,),) = new_figure(WIDE_IN, 3.8)
    _shade_outages(ax, result.outages[run], t0)
    for name, (t, nees) in pose_nees(result, run).items():
        plot_series(ax, t, nees, gap_s, lw=0.9, color=colors[name], label=name)
    for k, b in enumerate(result.nees_bounds_95):
        ax.axhline(b, color="k", ls="--", lw=0.8, label="95 % bounds, chi2(3)" if k == 0 else None)
    ax.set(title=f"{run}: pose NEES (3 dof)", xlabel="time since the run's first pose [s]", ylabel="NEES",
           yscale="log")
    values = np.concatenate([n for _, n in pose_nees(result, run).values()] or [np.ones(1)])
    # the first steps from the initial covariance can reach 1e-8: they would squash the rest
    ax.set_ylim(bottom=max(min(np.nanpercentile(values, 1), result.nees_bounds_95[0] / 3), 1e-3))
    fig.legend(loc="outside right upper", fontsize=9)
    return save_figure(fig, path)


def write_benchmark_figures(result: BenchmarkResult, out_dir: str | Path) -> list[Path]:
    """Return the figure files written to ``out_dir``: trajectories, error bands, outage errors, NEES."""
    out = Path(out_dir)
    draws = {"trajectories.png": plot_trajectories, "error_bands.png": plot_error_bands,
             "outage_errors.png": plot_outage_errors, "nees.png": plot_nees}
    for name, draw in draws.items():
        draw(result, path=out / name)
    return [out / name for name in draws]
