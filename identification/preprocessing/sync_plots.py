"""Figures of the synchronisation steps, drawn only on request (thesis figs. 5.1 to 5.7).

Each ``plot_*`` returns a matplotlib Figure (built without pyplot, so Agg and no global state)
and saves it when given ``path``. :func:`plot_run` draws them all for one preprocessed run,
plus the hub and pose figures of :mod:`identification.preprocessing.hub` and :mod:`identification.preprocessing.poses`
when those modules provide them.
"""

from __future__ import annotations

import logging
import sys
from pathlib import Path

import numpy as np

from groundfloor.types import RawRun
from identification.preprocessing.clock_sync import (
    GAP_THRESHOLD_S,
    detect_gaps,
    gap_signal,
    xcorr_gap_signals,
)
from identification.preprocessing.sync import SyncedRun

log = logging.getLogger(__name__)


def _figure(nrows: int = 1, height: float = 3.2):
    from matplotlib.figure import Figure

    fig = Figure(figsize=(8, height * nrows), layout="constrained")
    return fig, fig.subplots(nrows, 1, squeeze=False)[:, 0]


def _save(fig, path):
    if path is not None:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(path, dpi=110)
    return fig


def plot_gap_signal(raw: RawRun, tracker: str = "ltd800", path=None):
    """Return the gap signals (eq. 5.6) of a tracker (top) and the trigger (bottom) with the
    detected gaps, like thesis fig. 5.1."""
    fig, (ax_t, ax_r) = _figure(2)
    t_tr = getattr(raw, tracker).t_tracker
    for ax, t, label in ((ax_t, t_tr - t_tr[0], f"{tracker} clock"),
                         (ax_r, raw.t_trigger_utc - raw.t_trigger_utc[0], "trigger (UTC)")):
        t_i, dt = gap_signal(t)
        gaps = detect_gaps(t)
        ax.plot(t_i, dt * 1e3, lw=0.7)
        ax.plot(gaps, np.full(gaps.size, GAP_THRESHOLD_S * 1e3), "rv", ms=4, label="detected gap")
        ax.axhline(GAP_THRESHOLD_S * 1e3, color="r", lw=0.5, ls="--")
        ax.set_ylim(0, 60)
        ax.set_xlabel(f"{label} since first stamp [s]")
        ax.set_ylabel("time to next stamp [ms]")
        ax.legend(loc="upper right")
    ax_t.set_title(f"run {raw.name}: gap signals (eq. 5.6), threshold 35 ms")
    return _save(fig, path)


def plot_xcorr(raw: RawRun, synced: SyncedRun, path=None):
    """Return the cross-correlation of each tracker's gap signal with the trigger's (eq. 5.7)
    around the chosen shift, like thesis fig. 5.2."""
    fig, axes = _figure(2)
    s = raw.t_trigger_utc - raw.t_trigger_utc[0]
    for ax, tracker in zip(axes, ("ltd800", "at960")):
        t_tr = getattr(raw, tracker).t_tracker
        tau, corr = xcorr_gap_signals(s, t_tr - t_tr[0])
        tau0 = synced.clock[tracker].tau
        near = np.abs(tau - tau0) < 10
        ax.plot(tau[near], corr[near] / corr.max(), lw=0.7)
        ax.axvline(tau0, color="r", lw=0.8, label=f"tau = {tau0:.3f} s")
        ax.set_xlabel("shift tau [s]")
        ax.set_ylabel(f"{tracker} xcorr (norm.)")
        ax.legend(loc="upper right")
    axes[0].set_title(f"run {raw.name}: coarse alignment by cross-correlation (eqs. 5.7, 5.8)")
    return _save(fig, path)


def plot_clock_model(synced: SyncedRun, path=None):
    """Return trigger time minus tracker time at the matched samples with the fitted linear
    clock model (eqs. 5.10 to 5.12) for both trackers, like thesis fig. 5.3."""
    fig, (ax,) = _figure(1, 4.0)
    for tracker, color in (("ltd800", "C0"), ("at960", "C1")):
        s, _, s_tr = synced.residuals[tracker]
        c = synced.clock[tracker]
        d = c.d - (synced.offset.dt if tracker == synced.offset_tracker else 0.0)  # eq. 5.12 only
        step = max(1, s.size // 2000)
        y0 = s[0] - s_tr[0]  # common reference so that both lines start near zero
        ax.plot(s_tr[::step], (s[::step] - s_tr[::step] - y0) * 1e3, ".", ms=2, color=color,
                label=f"{tracker} matched samples")
        x = np.array([s_tr[0], s_tr[-1]])
        ax.plot(x, (c.k * (x - c.tau) + d - x - y0) * 1e3, "-", color=color, lw=1,
                label=f"{tracker}: drift {c.drift_ppm:.3f} ppm")
    ax.set_xlabel("tracker clock since its first sample [s]")
    ax.set_ylabel("trigger minus tracker time [ms]")
    ax.set_title(f"run {synced.name}: linear clock models (eqs. 5.10-5.12)")
    ax.legend(loc="best", markerscale=4)
    return _save(fig, path)


def plot_clock_residuals(synced: SyncedRun, path=None):
    """Return the mapped tracker stamps minus the trigger times for the AT960 (top) and LTD800
    (bottom) after the clock model, before the extra offset, like thesis fig. 5.4."""
    fig, axes = _figure(2)
    for ax, tracker in zip(axes, ("at960", "ltd800")):
        s, r, _ = synced.residuals[tracker]
        c = synced.clock[tracker]
        ax.plot(s, r * 1e6, ".", ms=1.5)
        ax.set_ylabel(f"{tracker} [us]")
        ax.set_title(f"{tracker}: drift {c.drift_ppm:.4f} +- {c.drift_std_ppm:.4f} ppm, residual "
                     f"std {c.residual_std * 1e6:.2f} us, {c.n_gaps_matched} gaps, {c.n_fit} samples",
                     fontsize=9)
    axes[-1].set_xlabel("time since first trigger [s]")
    return _save(fig, path)


def plot_baseline(synced: SyncedRun, path=None):
    """Return the baseline length over time before and after the extra offset (eq. 5.13), like
    thesis fig. 5.5."""
    fig, (ax,) = _figure(1, 3.6)
    mean = np.nanmean(synced.baseline_after_m)
    for base, label in ((synced.baseline_before_m, "before"), (synced.baseline_after_m, "after")):
        ax.plot(synced.s_trigger, (base - mean) * 1e3, lw=0.6,
                label=f"{label} offset correction (RMS {np.nanstd(base) * 1e3:.3f} mm)")
    ax.set_xlabel("time since first trigger [s]")
    ax.set_ylabel("baseline length - mean [mm]")
    ax.set_title(f"run {synced.name}: {synced.offset_tracker} extra offset "
                 f"{synced.offset.dt * 1e3:.4f} ms")
    ax.legend(loc="upper right")
    return _save(fig, path)


def plot_offset_fit(synced: SyncedRun, path=None):
    """Return the baseline spread against the trial offset with the quadratic of eq. 5.19 and
    its minimum (eq. 5.20), like thesis fig. 5.6."""
    o = synced.offset
    fig, (ax,) = _figure(1, 3.6)
    near = np.abs(o.dt_grid - o.dt) < 5e-4
    ax.plot(o.dt_grid[near] * 1e3, o.spread_grid[near] * 1e3, ".", label="s_r (eq. 5.16)")
    x = np.linspace(o.dt_fit[0], o.dt_fit[-1], 100)
    x0 = o.dt_fit.mean()
    a, b, c = o.coeffs
    ax.plot(x * 1e3, (a * (x - x0) ** 2 + b * (x - x0) + c) * 1e3, "r", label="quadratic (eq. 5.19)")
    ax.axvline(o.dt * 1e3, color="k", lw=0.6,
               label=f"minimum {o.dt * 1e3:.4f} ms +- {o.dt_std * 1e9:.1f} ns")
    ax.set_xlabel("extra offset [ms]")
    ax.set_ylabel("baseline spread [mm]")
    ax.set_title(f"run {synced.name}: offset by minimising the baseline spread")
    ax.legend(loc="upper right")
    return _save(fig, path)


def plot_baseline_vs_speed(synced: SyncedRun, path=None):
    """Return the baseline variation against the forward speed before and after the correction:
    the correlation that reveals the timing error (thesis 5.2.2, Pearson r about 0.9)."""
    fig, (ax,) = _figure(1, 4.0)
    after = "after correction" + (" (r with the hub terms removed)" if synced.offset.hub_terms else "")
    for base, label, r in ((synced.baseline_before_m, "before correction", synced.r_speed_before),
                           (synced.baseline_after_m, after, synced.r_speed_after)):
        ax.plot(synced.v_forward, (base - np.nanmean(base)) * 1e3, ".", ms=1.5, alpha=0.5,
                label=f"{label}: r = {r:.2f}")
    ax.set_xlabel("forward speed [m/s]")
    ax.set_ylabel("baseline length - mean [mm]")
    ax.set_title(f"run {synced.name}: baseline variation vs forward speed")
    ax.legend(loc="upper left", markerscale=6)
    return _save(fig, path)


def plot_run(raw: RawRun, run, out_dir) -> list[Path]:
    """Return the figure files of one preprocessed run (a ``RunResult``), saved in ``out_dir``."""
    out_dir, s = Path(out_dir), run.synced
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = {"fig5_1_gap_signal.png": lambda p: plot_gap_signal(raw, "ltd800", p),
            "fig5_2_xcorr.png": lambda p: plot_xcorr(raw, s, p),
            "fig5_3_clock_model.png": lambda p: plot_clock_model(s, p),
            "fig5_4_clock_residuals.png": lambda p: plot_clock_residuals(s, p),
            "fig5_5_baseline.png": lambda p: plot_baseline(s, p),
            "fig5_6_offset_fit.png": lambda p: plot_offset_fit(s, p),
            "baseline_vs_speed.png": lambda p: plot_baseline_vs_speed(s, p)}
    figs.update(_other_figures(run))
    for fname, draw in figs.items():
        draw(out_dir / fname)
    if "matplotlib.pyplot" in sys.modules:  # other modules' figures may live in pyplot's registry
        sys.modules["matplotlib.pyplot"].close("all")
    return sorted(out_dir.glob("*.png"))


def _other_figures(run) -> dict:
    """Hub (fig. 5.7) and pose (figs. 7.2, 7.3) figures from H5's modules, if they offer them."""
    out = {}
    try:
        from identification.preprocessing import hub as hub_mod
        from identification.preprocessing import poses as poses_mod
    except ImportError:
        return out
    if run.hub is not None and hasattr(hub_mod, "plot_hub_model"):
        out["fig5_7_hub_model.png"] = lambda p: hub_mod.plot_hub_model(run.hub, path=p)
    if hasattr(poses_mod, "plot_poses"):  # writes <prefix>_position.png and _attitude.png
        out["fig7_2_7_3_poses"] = lambda p: poses_mod.plot_poses(run.poses, path_prefix=str(p))
    return out
