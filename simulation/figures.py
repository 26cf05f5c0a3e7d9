"""Figures of the simulated driving (thesis section 6.3): input density and driven path.

Each ``plot_*`` takes what the simulator produced, returns a matplotlib Figure and saves it as
PNG when given ``path``; nothing is drawn unless asked for.
"""

from __future__ import annotations

import math

import numpy as np
from matplotlib.colors import LogNorm
from matplotlib.patches import Circle, Ellipse

from groundfloor.figures import new_figure, save_figure
from simulation.driver import DrivingArea


def plot_input_density(runs, path=None, bins: int = 40):
    """Return a matplotlib Figure like thesis fig. 6.3: density of (u1, u2) and of (vx, omega).

    ``runs`` are :class:`simulation.robot.TrueRun`; the inputs are the joystick messages, the
    states the true body velocities.
    """
    u = np.concatenate([r.u_joy for r in runs])
    vx = np.concatenate([r.vx for r in runs])
    om = np.concatenate([r.omega for r in runs])
    fig, ((ax1, ax2),) = new_figure(10, 4.2, ncols=2)
    h1 = ax1.hist2d(u[:, 1], u[:, 0], bins=bins, range=[[-1, 1], [-1, 1]], norm=LogNorm(), cmap="viridis")
    ax1.set(xlabel="steering $u_2$", ylabel="throttle $u_1$", title="control inputs", aspect="equal")
    fig.colorbar(h1[3], ax=ax1, label="messages")
    h2 = ax2.hist2d(om, vx, bins=bins, range=[[-1.3, 1.3], [-0.9, 0.9]], norm=LogNorm(), cmap="viridis")
    ax2.set(xlabel=r"yaw rate $\omega$ [rad/s]", ylabel=r"forward velocity $v_x$ [m/s]",
            title="driving states")
    fig.colorbar(h2[3], ax=ax2, label="samples")
    return save_figure(fig, path)


def plot_driving_path(run, area: DrivingArea | None = None, path=None):
    """Return a matplotlib Figure like thesis fig. 6.4: the path in the local frame, the area
    and the trackers."""
    area = area or DrivingArea()
    fig, ((ax,),) = new_figure(7, 6)
    ax.add_patch(Ellipse(area.center_local_m, 2 * area.semi_axes_m[0], 2 * area.semi_axes_m[1],
                         angle=math.degrees(area.axis_angle_rad), fill=False, ls="--", color="grey",
                         label="driving area"))
    for (tx, ty), name in zip(area.trackers_local_m, ("AT960", "LTD800")):
        ax.add_patch(Circle((tx, ty), area.min_tracker_distance_m, fill=False, ls=":", color="tab:red"))
        ax.plot(tx, ty, "^", color="tab:red")
        ax.annotate(name, (tx, ty), textcoords="offset points", xytext=(6, -12))
    ax.plot(run.x, run.y, lw=0.8, label="path")
    ax.plot(run.x[0], run.y[0], "o", color="tab:green", label="start")
    ax.set(xlabel="x local [m]", ylabel="y local [m]", aspect="equal")
    ax.legend(loc="upper left")
    return save_figure(fig, path)
