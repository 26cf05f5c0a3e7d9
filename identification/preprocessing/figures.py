"""Figures of the preprocessing steps, drawn only on request (thesis figs. 5.1 to 5.7, 6.1, 7.1 to 7.3, 7.9).

Each ``plot_*`` takes a result of :mod:`identification.preprocessing` (raw and synchronised
run, calibration, hub model, poses, body states), returns a matplotlib Figure (or a list of
them) and saves it as PNG when given ``path``. :func:`plot_run` draws the figures of one
preprocessed run into a folder (``preprocess --plots``). Lines over time break where the
samples have a gap (:func:`~identification.preprocessing.trajectory.gap_threshold_s`: a prism
lost), rather than joining the two sides with a straight line.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundfloor.figures import WIDE_IN, WIDTH_IN, new_figure, plain_axis, plot_series, save_figure
from groundfloor.types import PoseTrack, RawRun, Survey
from identification.preprocessing.body_frame import BodyFrameFit
from identification.preprocessing.clock_sync import (
    GAP_THRESHOLD_S,
    detect_gaps,
    gap_signal,
    xcorr_gap_signals,
)
from identification.preprocessing.hub import HubModel
from identification.preprocessing.network_transform import TransformFit
from identification.preprocessing.sync import SyncedRun
from identification.preprocessing.trajectory import gap_threshold_s


def _column(nrows: int = 1, height: float = 2.6):
    """Return a figure of the report's column width and its ``nrows`` axes stacked in one column."""
    fig, axes = new_figure(WIDTH_IN, height * nrows, nrows)
    return fig, axes[:, 0]


def _run_axes(synced: SyncedRun, height: float, what: str, xlabel: str, ylabel: str):
    """Return a one-axes figure of the column width and its axes, titled ``run <name>: <what>`` and labelled."""
    fig, (ax,) = _column(1, height)
    ax.set(xlabel=xlabel, ylabel=ylabel, title=f"run {synced.name}: {what}")
    return fig, ax


# -- calibration (thesis 5.1, 5.2.1) -----------------------------------------------------------

def plot_network(survey: Survey, fit: TransformFit, exaggeration: float = 2e4, path=None):
    """Return a top view of the network like thesis fig. 6.1.

    Shows the network points in the AT960 frame with their ids, the axes of both tracker frames
    and the residual vectors ``x_at960 - (t + R x_ltd800)`` scaled by ``exaggeration``; a point
    flagged by the blunder test is drawn in red.
    """
    fig, ((ax,),) = new_figure(WIDTH_IN, 6)
    p = np.array([survey.network_at960[i][:3] for i in fit.point_ids])
    bad = np.array([i == fit.blunder_point for i in fit.point_ids])
    ax.scatter(p[~bad, 0], p[~bad, 1], c="k", s=20, label="network point")
    if bad.any():
        ax.scatter(p[bad, 0], p[bad, 1], c="r", s=40, label="blunder")
    r = fit.residuals_m * exaggeration
    ax.quiver(p[:, 0], p[:, 1], r[:, 0], r[:, 1], angles="xy", scale_units="xy", scale=1.0,
              color="tab:orange", label=f"residual x {exaggeration:g}")
    for pid, q in zip(fit.point_ids, p):
        ax.annotate(pid, q[:2], textcoords="offset points", xytext=(4, 4))
    axis_len = 0.1 * np.ptp(p[:, :2]).max()
    frames = {"AT960": (np.zeros(3), np.eye(3)),
              "LTD800": (fit.t_at960_ltd800, fit.R_at960_ltd800)}
    for name, (o, R) in frames.items():
        for k, col in enumerate(("r", "g")):
            ax.annotate("", o[:2] + axis_len * R[:2, k], o[:2],
                        arrowprops=dict(arrowstyle="->", color=col, lw=2))
        ax.annotate(name, o[:2], textcoords="offset points", xytext=(-10, -14))
    ax.set_xlabel("x AT960 [m]")
    ax.set_ylabel("y AT960 [m]")
    ax.set_aspect("equal")
    ax.legend(loc="best", fontsize="small")
    ax.set_title(f"network and tracker frames (s0^2 = {fit.variance_factor:.2f}, dof {fit.dof})")
    return save_figure(fig, path)


def plot_body_frame(survey: Survey, body: BodyFrameFit, path=None):
    """Return a 3-D view like thesis fig. 7.1.

    Screw heads, fitted hub circles, the plane through the hub centres, the body axes and the
    prisms, all in the body frame.
    """
    fig, ((ax,),) = new_figure(WIDTH_IN, 6, subplot_kw={"projection": "3d"})
    phi = np.linspace(0.0, 2.0 * np.pi, 73)
    for hub, c, nrm, r in zip(body.hub_names, body.hub_centres_survey, body.hub_normals_survey,
                              body.hub_radii_m):
        pts = body.body_from_survey(survey.wheel_hubs[hub][:, :3])
        ax.scatter(*pts.T, c="k", s=8)
        e1 = np.cross(nrm, [0.0, 0.0, 1.0])
        e1 /= np.linalg.norm(e1)
        e2 = np.cross(nrm, e1)
        circle = c + r * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
        ax.plot(*body.body_from_survey(circle).T, c="tab:blue")
    centres = body.body_from_survey(body.hub_centres_survey)
    ax.scatter(*centres.T, c="tab:blue", marker="x")
    half = np.abs(centres[:, :2]).max(axis=0) * 1.2
    gx, gy = np.meshgrid([-half[0], half[0]], [-half[1], half[1]])
    ax.plot_surface(gx, gy, np.zeros_like(gx), alpha=0.15, color="tab:gray")
    for k, col in enumerate(("r", "g", "b")):
        ax.quiver(0, 0, 0, *(0.2 * np.eye(3)[k]), color=col)
    for name, arm in body.lever_arms_body.items():
        ax.scatter(*arm, c="tab:orange", s=40, marker="^")
        ax.text(*arm, f" {name} prism")
    span = np.vstack([centres, *body.lever_arms_body.values(), np.zeros(3)])
    ax.set_box_aspect(np.ptp(span, axis=0))  # true proportions, as in fig. 7.1
    ax.set_xlabel("x body [m]")
    ax.set_ylabel("y body [m]")
    ax.set_zlabel("z body [m]")
    ax.set_title("body frame from the wheel hubs")
    return save_figure(fig, path)


# -- synchronisation (thesis 5.2.2) ------------------------------------------------------------

def plot_gap_signal(raw: RawRun, tracker: str = "ltd800", path=None):
    """Return the gap signals (eq. 5.6) of a tracker (top) and the trigger (bottom) with the
    detected gaps, like thesis fig. 5.1."""
    fig, (ax_t, ax_r) = _column(2)
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
    return save_figure(fig, path)


def plot_xcorr(raw: RawRun, synced: SyncedRun, path=None):
    """Return the cross-correlation of each tracker's gap signal with the trigger's (eq. 5.7)
    around the chosen shift, like thesis fig. 5.2."""
    fig, axes = _column(2)
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
    return save_figure(fig, path)


def plot_clock_model(synced: SyncedRun, path=None):
    """Return trigger time minus tracker time at the matched samples with the fitted linear
    clock model (eqs. 5.10 to 5.12) for both trackers, like thesis fig. 5.3."""
    fig, ax = _run_axes(synced, 4.0, "linear clock models (eqs. 5.10-5.12)",
                        xlabel="tracker clock since its first sample [s]", ylabel="trigger minus tracker time [ms]")
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
    ax.legend(loc="best", markerscale=4)
    return save_figure(fig, path)


def plot_clock_residuals(synced: SyncedRun, path=None):
    """Return the mapped tracker stamps minus the trigger times for the AT960 (top) and LTD800
    (bottom) after the clock model, before the extra offset, like thesis fig. 5.4."""
    fig, axes = _column(2)
    for ax, tracker in zip(axes, ("at960", "ltd800")):
        s, r, _ = synced.residuals[tracker]
        c = synced.clock[tracker]
        ax.plot(s, r * 1e6, ".", ms=1.5)
        ax.set_ylabel(f"{tracker} [us]")
        ax.set_title(f"{tracker}: drift {c.drift_ppm:.4f} +- {c.drift_std_ppm:.4f} ppm, residual "
                     f"std {c.residual_std * 1e6:.2f} us\n{c.n_gaps_matched} gaps matched, {c.n_fit} samples",
                     fontsize=9)
    axes[-1].set_xlabel("time since first trigger [s]")
    return save_figure(fig, path)


def plot_baseline(synced: SyncedRun, path=None):
    """Return the baseline length over time before and after the extra offset (eq. 5.13), like
    thesis fig. 5.5."""
    fig, ax = _run_axes(synced, 3.6, f"{synced.offset_tracker} extra offset {synced.offset.dt * 1e3:.4f} ms",
                        xlabel="time since first trigger [s]", ylabel="baseline length - mean [mm]")
    mean = np.nanmean(synced.baseline_after_m)
    gap_s = gap_threshold_s(synced.s_trigger)
    for base, label in ((synced.baseline_before_m, "before"), (synced.baseline_after_m, "after")):
        plot_series(ax, synced.s_trigger, (base - mean) * 1e3, gap_s, lw=0.6,
                    label=f"{label} offset correction (RMS {np.nanstd(base) * 1e3:.3f} mm)")
    ax.legend(loc="best", fontsize=9)
    return save_figure(fig, path)


def plot_offset_fit(synced: SyncedRun, path=None):
    """Return the baseline spread against the trial offset with the quadratic of eq. 5.19 and
    its minimum (eq. 5.20), like thesis fig. 5.6."""
    o = synced.offset
    fig, ax = _run_axes(synced, 3.6, "offset by minimising the baseline spread",
                        xlabel="extra offset [ms]", ylabel="baseline spread [mm]")
    near = np.abs(o.dt_grid - o.dt) < 5e-4
    ax.plot(o.dt_grid[near] * 1e3, o.spread_grid[near] * 1e3, ".", label="s_r (eq. 5.16)")
    x = np.linspace(o.dt_fit[0], o.dt_fit[-1], 100)
    x0 = o.dt_fit.mean()
    a, b, c = o.coeffs
    ax.plot(x * 1e3, (a * (x - x0) ** 2 + b * (x - x0) + c) * 1e3, "r", label="quadratic (eq. 5.19)")
    ax.axvline(o.dt * 1e3, color="k", lw=0.6,
               label=f"minimum {o.dt * 1e3:.4f} ms +- {o.dt_std * 1e9:.1f} ns")
    ax.legend(loc="upper center", fontsize=9)
    return save_figure(fig, path)


def plot_baseline_vs_speed(synced: SyncedRun, path=None):
    """Return the baseline variation against the forward speed before and after the correction:
    the correlation that reveals the timing error (thesis 5.2.2, Pearson r about 0.9)."""
    fig, ax = _run_axes(synced, 4.0, "baseline variation vs forward speed",
                        xlabel="forward speed [m/s]", ylabel="baseline length - mean [mm]")
    after = "after correction" + (" (r with the hub terms removed)" if synced.offset.hub_terms else "")
    for base, label, r in ((synced.baseline_before_m, "before correction", synced.r_speed_before),
                           (synced.baseline_after_m, after, synced.r_speed_after)):
        ax.plot(synced.v_forward, (base - np.nanmean(base)) * 1e3, ".", ms=1.5, alpha=0.5,
                label=f"{label}: r = {r:.2f}")
    ax.legend(loc="best", markerscale=6, fontsize=9)
    return save_figure(fig, path)


def plot_hub_model(model: HubModel, path=None):
    """Return a figure of the baseline variation, the model and the azimuths (like fig. 5.7).

    Top: measured baseline length minus c, the eq. 5.25 model and the residual over time;
    middle: the two hub azimuths used as independent variables; bottom: the baseline variation
    against the front azimuth before and after removing the model (the circle the model
    explains).
    """
    t = model.t - model.t[0]
    gap_s = gap_threshold_s(t)
    fig, axes = new_figure(WIDE_IN, 6.4, 2, 2, gridspec_kw={"height_ratios": [2, 1], "width_ratios": [2, 1]})
    (ax1, ax3), (ax2, ax_legend) = axes
    dl_mm = (model.baseline_length_m - model.c_m) * 1e3
    ax1.plot(t, dl_mm, ".", ms=2, color="0.6", label=f"observed baseline - c (RMS {model.rms_before_m * 1e3:.3f} mm)")
    plot_series(ax1, t, (model.predict(model.azimuth_front, model.azimuth_rear) - model.c_m) * 1e3, gap_s, "-",
                lw=1.2, color="C0", label="eq. 5.25 model")
    plot_series(ax1, t, model.residual() * 1e3, gap_s, "-", lw=0.6, color="C3",
                label=f"residual (RMS {model.rms_after_m * 1e3:.3f} mm)")
    r = model.radius_m * 1e3
    fig.suptitle(f"turning-hub model (eq. 5.25): c = {model.c_m:.6f} m, r1 = {r[0]:.3f} mm, r2 = {r[1]:.3f} mm")
    ax1.set_ylabel("baseline - c [mm]")
    ax1.set_title("baseline length over time")
    ax1.tick_params(labelbottom=False)
    for az, label in ((model.azimuth_front, "front hub"), (model.azimuth_rear, "rear hub")):
        plot_series(ax2, t, np.degrees(np.unwrap(az)), gap_s, label=label)
    ax2.sharex(ax1)
    ax2.set_ylabel("azimuth [deg]")
    ax2.set_xlabel("time since start [s]")
    az_deg = np.degrees(np.mod(model.azimuth_front, 2 * np.pi))
    ax3.plot(az_deg, dl_mm, ".", ms=2, color="0.6")
    ax3.plot(az_deg, model.residual() * 1e3, ".", ms=2, color="C3")
    ax3.sharey(ax1)
    ax3.set_xlabel("front hub azimuth [deg]")
    ax3.set_title("against the front hub's azimuth")
    # one legend for all panels, in a panel of its own: none of them hides data
    handles = [h for ax in (ax1, ax2) for h in ax.get_legend_handles_labels()[0]]
    labels = [lab for ax in (ax1, ax2) for lab in ax.get_legend_handles_labels()[1]]
    ax_legend.axis("off")
    ax_legend.legend(handles, labels, loc="center", markerscale=5, frameon=False)
    return save_figure(fig, path)


# -- poses and body-frame states (thesis 5.2.3, 5.3.3) -----------------------------------------

def plot_poses(poses: PoseTrack, path_prefix=None):
    """Return two figures: position and attitude components with their sigmas (figs. 7.2, 7.3).

    Each component is drawn over time with its standard deviation in a panel below. Saved as
    ``<path_prefix>_position.png`` and ``<path_prefix>_attitude.png`` when given.
    """
    t = poses.t - poses.t[0]
    gap_s = gap_threshold_s(t)
    figs = []
    deg, arcsec = np.degrees(1.0), 3600.0 * np.degrees(1.0)
    z_mean = float(np.nanmean(poses.z)) if np.isfinite(poses.z).any() else 0.0
    # z varies by tens of micrometres about a height of metres: drawn about its mean, in mm, so
    # that the tick labels say the variation (an axis offset label would hide it)
    groups = (("position", [("x", poses.x, poses.x_std, 1.0, 0.0, "x [m]", 1e3, "mm"),
                            ("y", poses.y, poses.y_std, 1.0, 0.0, "y [m]", 1e3, "mm"),
                            ("z", poses.z, poses.z_std, 1e3, z_mean, f"z - ({z_mean:.4f} m) [mm]", 1e3, "mm")]),
              ("attitude", [(k, getattr(poses, k), getattr(poses, f"{k}_std"), deg, 0.0, f"{k} [deg]", arcsec,
                             "arcsec") for k in ("pitch", "yaw")]))
    for name, comps in groups:
        fig, axes = new_figure(WIDE_IN if len(comps) > 2 else WIDTH_IN, 4.6, 2, len(comps), sharex=True)
        for j, (label, val, std, k, ref, ylabel, k_std, unit_std) in enumerate(comps):
            plot_series(axes[0, j], t, (val - ref) * k, gap_s, lw=0.8)
            axes[0, j].set_title(label)
            axes[0, j].set_ylabel(ylabel)
            plot_series(axes[1, j], t, std * k_std, gap_s, lw=0.8, color="C1")
            axes[1, j].set_ylabel(f"sigma {label} [{unit_std}]")
            axes[1, j].set_xlabel("time since start [s]")
            for ax in axes[:, j]:
                plain_axis(ax)
        figs.append(save_figure(fig, None if path_prefix is None else f"{path_prefix}_{name}.png"))
    return figs


def plot_body_states(states_by_smoothing: dict, path=None, t_range=None):
    """Return a figure of vx, vy and omega over time for several smoothing factors (fig. 7.9).

    ``states_by_smoothing`` maps ``s`` to the :class:`~groundfloor.types.BodyStates` computed
    with it, or to a list of them (the gap-free segments of one run: drawn with the gaps left
    open); ``t_range`` (seconds since the first sample) zooms in.
    """
    fig, axes = new_figure(WIDTH_IN, 6, 3, sharex=True)
    axes = axes[:, 0]
    labels = (("vx", "v_x [m/s]", 1.0), ("vy", "v_y [m/s]", 1.0), ("omega", "omega [deg/s]", np.degrees(1.0)))
    t0 = None
    for i, (s, states) in enumerate(states_by_smoothing.items()):
        segments = states if isinstance(states, (list, tuple)) else [states]
        t0 = min(st.t[0] for st in segments) if t0 is None else t0
        for k_seg, st in enumerate(segments):
            t = st.t - t0
            sel = np.ones(t.shape, bool) if t_range is None else (t >= t_range[0]) & (t <= t_range[1])
            for ax, (key, ylabel, k) in zip(axes, labels):
                plot_series(ax, t[sel], getattr(st, key)[sel] * k, gap_threshold_s(st.t), lw=0.8, color=f"C{i}",
                            label=f"s = {s:g}" if k_seg == 0 else None)
                ax.set_ylabel(ylabel)
    if len(states_by_smoothing) > 1:
        axes[0].legend(loc="upper right", fontsize=9)
    axes[-1].set_xlabel("time since start [s]")
    return save_figure(fig, path)


def plot_run(raw: RawRun, run, out_dir) -> list[Path]:
    """Return the figure files of one preprocessed run (a ``RunResult``), saved in ``out_dir``.

    Figs. 5.1 to 5.6, the baseline against speed, fig. 5.7 when the run has a hub model, and
    figs. 7.2, 7.3 (``fig7_2_7_3_poses_position.png``, ``..._attitude.png``).
    """
    out_dir, s = Path(out_dir), run.synced
    out_dir.mkdir(parents=True, exist_ok=True)
    figs = {"fig5_1_gap_signal.png": lambda p: plot_gap_signal(raw, "ltd800", p),
            "fig5_2_xcorr.png": lambda p: plot_xcorr(raw, s, p),
            "fig5_3_clock_model.png": lambda p: plot_clock_model(s, p),
            "fig5_4_clock_residuals.png": lambda p: plot_clock_residuals(s, p),
            "fig5_5_baseline.png": lambda p: plot_baseline(s, p),
            "fig5_6_offset_fit.png": lambda p: plot_offset_fit(s, p),
            "baseline_vs_speed.png": lambda p: plot_baseline_vs_speed(s, p)}
    if run.hub is not None:
        figs["fig5_7_hub_model.png"] = lambda p: plot_hub_model(run.hub, path=p)
    figs["fig7_2_7_3_poses"] = lambda p: plot_poses(run.poses, path_prefix=str(p))
    for fname, draw in figs.items():
        draw(out_dir / fname)
    return sorted(out_dir.glob("*.png"))
