"""Figures and tables of the report that no pipeline stage draws itself.

Campaign overview (thesis section 6.3): the driven paths of every run, and the density of the
control inputs and of the driving states (fig. 6.3); the diagnosis's family gains. Each
``plot_*`` returns a matplotlib Figure (:mod:`groundfloor.figures`), saved when given ``path``;
nothing is drawn unless asked for.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
from matplotlib.colors import LogNorm

from groundfloor.figures import WIDE_IN, WIDTH_IN, break_at_gaps, new_figure, save_figure
from groundfloor.types import BodyStates, TrajectoryCampaign, TrajectoryRun
from identification.sindy.data import gap_threshold_s


def path_length_m(x: np.ndarray, y: np.ndarray) -> float:
    """Return the length of the polyline through ``(x, y)`` in metres (NaN samples skipped)."""
    ok = np.isfinite(x) & np.isfinite(y)
    return float(np.hypot(np.diff(x[ok]), np.diff(y[ok])).sum())


def run_overview(campaign: TrajectoryCampaign) -> list[dict]:
    """Return one row per run: name, split, duration, poses, pose rate, driven path, top speed.

    ``duration_s`` is first to last pose; ``path_m`` the length of the pose polyline (at 50 Hz
    and millimetre pose noise the noise adds well under 0.1 % to a driven metre);
    ``max_speed_m_s`` the 99th percentile of the finite-difference speed (robust to a gap).
    """
    rows = []
    for run in campaign.runs:
        p = run.poses
        dt = np.diff(p.t)
        step = np.hypot(np.diff(p.x), np.diff(p.y))
        speed = step[dt > 0] / dt[dt > 0]
        rows.append({"name": run.name, "split": run.split, "duration_s": float(p.t[-1] - p.t[0]),
                     "n_poses": int(p.t.size), "rate_hz": float(1.0 / np.median(dt)) if dt.size else 0.0,
                     "path_m": path_length_m(p.x, p.y),
                     "max_speed_m_s": float(np.percentile(speed, 99)) if speed.size else 0.0,
                     "n_inputs": int(run.inputs.t.size)})
    return rows


def plot_driven_paths(runs: Sequence[TrajectoryRun], path=None):
    """Return a figure of every run's path in the local frame (train solid, test dashed)."""
    fig, ((ax,),) = new_figure(WIDTH_IN, 5.6)
    for i, run in enumerate(runs):
        p = run.poses
        _, x, y = break_at_gaps(p.t, p.x, p.y, gap_s=gap_threshold_s(p.t))
        ax.plot(x, y, lw=0.9, color=f"C{i % 10}", ls="-" if run.split == "train" else "--",
                label=f"{run.name} ({run.split})")
        ax.plot(p.x[:1], p.y[:1], "o", ms=4, color=f"C{i % 10}")
    ax.set_aspect("equal", adjustable="datalim")
    ax.set(xlabel="x local [m]", ylabel="y local [m]",
           title="driven paths (train solid, test dashed; o = start)")
    fig.legend(fontsize=8, ncols=3, loc="outside lower center")
    return save_figure(fig, path)


def plot_input_coverage(states: Sequence[BodyStates], bins: int = 41, path=None):
    """Return fig. 6.3: density of the control inputs ``(u2, u1)`` and of the states ``(omega, vx)``.

    Densities are sample counts at the pose times (log colour scale), so a run's share is its
    driving time, as in the thesis's heat maps.
    """
    u = np.vstack([np.column_stack([s.u1, s.u2]) for s in states])
    v = np.vstack([np.column_stack([s.vx, s.omega]) for s in states])
    fig, ((ax_u, ax_v),) = new_figure(WIDE_IN, 5.2, ncols=2)
    h_u = ax_u.hist2d(u[:, 1], u[:, 0], bins=bins, range=[[-1.05, 1.05], [-1.05, 1.05]], norm=LogNorm(),
                      cmap="viridis")
    ax_u.set(xlabel="u2 steering (left +)", ylabel="u1 throttle (forward +)", title="control inputs")
    fig.colorbar(h_u[3], ax=ax_u, label="samples")
    lim_w = max(float(np.nanmax(np.abs(np.degrees(v[:, 1])))), 1.0)
    lim_v = max(float(np.nanmax(np.abs(v[:, 0]))), 0.1)
    h_v = ax_v.hist2d(np.degrees(v[:, 1]), v[:, 0], bins=bins, range=[[-lim_w, lim_w], [-lim_v, lim_v]],
                      norm=LogNorm(), cmap="viridis")
    ax_v.set(xlabel="omega yaw rate [deg/s]", ylabel="vx forward velocity [m/s]", title="driving states")
    fig.colorbar(h_v[3], ax=ax_v, label="samples")
    return save_figure(fig, path)


def plot_family_gains(ranked, path=None):
    """Return a bar chart of each diagnosis family's out-of-sample gain against its threshold.

    ``ranked`` are :class:`sindy_ekf.diagnose.rank.RankedCause` (most likely first); a family
    counts as a cause only where its bar passes its threshold mark.
    """
    fig, ((ax,),) = new_figure(WIDTH_IN, 3.6)
    names = [c.name for c in ranked]
    gain = 100 * np.array([c.gain for c in ranked])
    thr = 100 * np.array([c.threshold for c in ranked])
    y = np.arange(len(names))[::-1]
    ax.barh(y, gain, color=np.where([c.significant for c in ranked], "C3", "C0"))
    ax.plot(thr, y, "k|", ms=14, mew=2, label="threshold")
    ax.set_yticks(y, names)
    ax.set(xlabel="gain on the test runs [% of weighted residual SSE]", title="diagnosis: families")
    ax.legend(loc="lower right", fontsize=8)
    return save_figure(fig, path)
