"""The motorised prism turning hubs: commanded azimuth (eqs. 4.1-4.6) and their eccentricity.

Thesis section 4.3: a ROS node on the robot's Raspberry Pi receives both trackers' measurements
in real time and computes, for each prism, the azimuth that keeps it facing its tracker
(eqs. 4.1 to 4.6, in the measuring tracker's frame). Section 5.2.3 / table 7.5: the prism
reference point is off the hub axis by ~0.2 mm, so the prism-to-prism distance varies as
(eq. 5.25) ``l = c + r1 cos(phi1 + Phi1) + r2 cos(phi2 + Phi2)``.

Eccentricity model. The hub turns the prism by its azimuth ``phi`` (eq. 4.6 measures it from
the baseline towards the prism-to-tracker direction, clockwise); the reference point sits at
radius ``r`` in the hub plane (body xy) at the body-frame angle

    theta_i = beta_i + pi - phi_i - Phi_i,

with ``beta_i`` the body-frame azimuth of the baseline from prism ``i`` to the other prism and
``Phi_i`` the run's phase (how the prism was seated, thesis 5.2.3). To first order the baseline
length then changes by ``r_i * cos(elev) * cos(phi_i + Phi_i)``, ``elev`` the baseline's
elevation in the body frame: eq. 5.25 holds exactly with ``r_eq525 = r * cos(elev)`` and
``c`` the distance between the lever arms.

The hub's true angle is the last command it received (zero-order hold after an actuation
delay); before its first command it stands at the first command (thesis 6.3: the first
computed azimuth initialises the hub).
"""

from __future__ import annotations

import numpy as np


def azimuth_from_points(x_self: np.ndarray, x_other: np.ndarray) -> np.ndarray:
    """Return the turning-hub azimuth (rad) of the prism at ``x_self`` (eqs. 4.1 to 4.6).

    Both points are in the frame of the tracker measuring ``x_self`` (origin at that tracker),
    shape (..., 3). Implements eqs. 4.1-4.6: baseline ``b = x_other - x_self`` projected on
    the xy-plane, its normal ``n = -b x e_z``, ``l_b = -x_self . b/|b|``,
    ``l_n = x_self . n/|n|``, ``phi = atan2(l_n, l_b)``.
    """
    b = np.asarray(x_other, float)[..., :2] - np.asarray(x_self, float)[..., :2]  # 4.1, 4.2
    n = np.stack([-b[..., 1], b[..., 0]], axis=-1)  # 4.3: -(b x e_z) = (-b_y, b_x)
    norm = np.linalg.norm(b, axis=-1)
    l_b = -np.einsum("...i,...i->...", x_self[..., :2], b) / norm  # 4.4
    l_n = np.einsum("...i,...i->...", x_self[..., :2], n) / norm  # 4.5
    return np.arctan2(l_n, l_b)  # 4.6


def hub_commands(
    t_publish: np.ndarray,
    t_arrive_self: np.ndarray,
    x_self: np.ndarray,
    t_arrive_other: np.ndarray,
    x_other_in_self: np.ndarray,
) -> np.ndarray:
    """Return the azimuth commanded at each ``t_publish`` from the latest arrived measurements.

    ``x_self`` (n, 3) are the measuring tracker's points of its prism and ``x_other_in_self``
    (m, 3) the other prism transformed into that tracker's frame (thesis 4.3), each with its
    arrival time at the node; the node uses the newest sample of each (stale during a
    dropout). Times with no sample of one of them yet give NaN.
    """
    i = np.searchsorted(t_arrive_self, t_publish, side="right") - 1
    j = np.searchsorted(t_arrive_other, t_publish, side="right") - 1
    ok = (i >= 0) & (j >= 0)
    phi = np.full(np.shape(t_publish), np.nan)
    phi[ok] = azimuth_from_points(x_self[i[ok]], x_other_in_self[j[ok]])
    return phi


def hub_angle(t: np.ndarray, t_effective: np.ndarray, phi_cmd: np.ndarray) -> np.ndarray:
    """Return the hub's true azimuth at ``t``: zero-order hold of the commands.

    ``t_effective`` (sorted) are the instants each command took effect; before the first one
    the hub stands at the first command.
    """
    i = np.searchsorted(t_effective, t, side="right") - 1
    return phi_cmd[np.clip(i, 0, None)]


def baseline_geometry(lever_self: np.ndarray, lever_other: np.ndarray) -> tuple[float, float]:
    """Return ``(beta, cos_elev)``: body azimuth and elevation cosine of the baseline self->other."""
    b = np.asarray(lever_other, float) - np.asarray(lever_self, float)
    return float(np.arctan2(b[1], b[0])), float(np.hypot(b[0], b[1]) / np.linalg.norm(b))


def eccentric_offset_body(
    phi: np.ndarray, radius_m: float, phase: float, beta: float
) -> np.ndarray:
    """Return (n, 3) body-frame offsets of the prism reference point from the hub axis.

    ``theta = beta + pi - phi - phase``; see the module docstring for why this makes eq. 5.25
    hold with ``r_eq525 = radius_m * cos(elev)``.
    """
    theta = beta + np.pi - np.asarray(phi, float) - phase
    return radius_m * np.stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)], axis=-1)
