"""Synthetic prism measurements from a known, analytic pose trajectory (tests of hub/poses/states).

Independent of the code under test: rotations come from ``scipy.spatial.transform.Rotation``,
the hub azimuth from eqs. 4.1 to 4.6 written out here, the eccentricity geometry follows the
simulator's convention (``theta = beta + pi - phi - Phi`` in the body frame; eq. 4.6's azimuth
grows clockwise), and velocities are the analytic derivatives of the trajectory.
"""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np
from scipy.spatial.transform import Rotation

LEVER_FRONT = np.array([0.4671355, 0.0655364, 0.5167336])  # table 7.1
LEVER_REAR = np.array([-0.2600713, -0.1627405, 0.6546911])
TRACKER_FRONT = np.array([6.93, 5.73, 0.1])  # LTD800 position in the local frame (approx. lab)
TRACKER_REAR = np.zeros(3)  # AT960 = origin of the local frame


def trajectory(t: np.ndarray, seed: int) -> SimpleNamespace:
    """Return a smooth analytic pose trajectory and its time derivatives at ``t``."""
    rng = np.random.default_rng(seed)
    f = rng.uniform(0.05, 0.25, (3, 3))  # rad/s, three sines per component
    a = rng.uniform(0.3, 0.8, (3, 3)) * np.array([[1.0], [0.6], [1.3]])
    ph = rng.uniform(0, 2 * np.pi, (3, 3))
    comps, rates = [], []
    for k in range(3):
        arg = f[k][:, None] * t + ph[k][:, None]
        comps.append(np.sum(a[k][:, None] * np.sin(arg), 0))
        rates.append(np.sum(a[k][:, None] * f[k][:, None] * np.cos(arg), 0))
    x, y, yaw = 3.5 + comps[0], 2.9 + comps[1], rng.uniform(-np.pi, np.pi) + comps[2]
    pitch = 0.006 * np.sin(0.9 * t + rng.uniform(0, 6))  # about 0.35 deg
    z = -1.25 + 2e-4 * np.sin(0.7 * t)
    x_dot, y_dot, yaw_dot = rates
    c, s = np.cos(yaw), np.sin(yaw)
    return SimpleNamespace(t=t, x=x, y=y, z=z, pitch=pitch, yaw=yaw, x_dot=x_dot, y_dot=y_dot,
                           vx=c * x_dot + s * y_dot, vy=-s * x_dot + c * y_dot, omega=yaw_dot)


def azimuth_eq46(x_self: np.ndarray, x_other: np.ndarray) -> np.ndarray:
    """Return eq. 4.6's azimuth; points relative to the measuring tracker, shape (n, 3)."""
    b = (x_other - x_self)[:, :2]
    n = np.column_stack([-b[:, 1], b[:, 0]])
    nb = np.linalg.norm(b, axis=1)
    l_b = -np.sum(x_self[:, :2] * b, 1) / nb
    l_n = np.sum(x_self[:, :2] * n, 1) / nb
    return np.arctan2(l_n, l_b)


def measurements(duration_s: float = 60.0, rate_hz: float = 50.0, seed: int = 0, noise_m: float = 10e-6,
                 radius_m=(0.21e-3, 0.12e-3), phase_rad=None) -> SimpleNamespace:
    """Return truth, hub azimuths and noisy prism positions in the local frame."""
    rng = np.random.default_rng(1000 + seed)
    t = np.arange(0.0, duration_s, 1.0 / rate_hz)
    tr = trajectory(t, seed)
    R = Rotation.from_euler("ZY", np.column_stack([tr.yaw, tr.pitch])).as_matrix()  # Rz(yaw) Ry(pitch)
    origin = np.column_stack([tr.x, tr.y, tr.z])
    axis_f = origin + R @ LEVER_FRONT
    axis_r = origin + R @ LEVER_REAR
    az_f = azimuth_eq46(axis_f - TRACKER_FRONT, axis_r - TRACKER_FRONT)
    az_r = azimuth_eq46(axis_r - TRACKER_REAR, axis_f - TRACKER_REAR)
    if phase_rad is None:
        phase_rad = rng.uniform(-np.pi, np.pi, 2)
    offsets = []
    for lever, other, az, r, Phi in ((LEVER_FRONT, LEVER_REAR, az_f, radius_m[0], phase_rad[0]),
                                     (LEVER_REAR, LEVER_FRONT, az_r, radius_m[1], phase_rad[1])):
        beta = np.arctan2(other[1] - lever[1], other[0] - lever[0])
        theta = beta + np.pi - az - Phi
        offsets.append(r * np.column_stack([np.cos(theta), np.sin(theta), np.zeros_like(theta)]))
    p_f = axis_f + np.einsum("nij,nj->ni", R, offsets[0]) + rng.normal(0, noise_m, axis_f.shape)
    p_r = axis_r + np.einsum("nij,nj->ni", R, offsets[1]) + rng.normal(0, noise_m, axis_r.shape)
    d = LEVER_FRONT - LEVER_REAR
    cos_elev = np.hypot(d[0], d[1]) / np.linalg.norm(d)
    return SimpleNamespace(truth=tr, t=t, p_front=p_f, p_rear=p_r, axis_front=axis_f, axis_rear=axis_r,
                           az_front=az_f, az_rear=az_r, radius_m=np.asarray(radius_m), phase_rad=np.asarray(phase_rad),
                           c_m=float(np.linalg.norm(d)), cos_elev=cos_elev, noise_m=noise_m,
                           offset_front_body=offsets[0], offset_rear_body=offsets[1])
