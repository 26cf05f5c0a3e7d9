"""The lateral non-holonomic pseudo-measurement ``v_y = 0`` of the EKF (moved out of ``ekf.py``).

A skid-steered robot barely slides sideways, so ``v_y = 0`` is applied as a measurement with a
standard deviation fitted from the train runs' ``v_y`` (:func:`fit_lateral_constraint`, 2 x its
RMS) every ``every`` steps (:class:`LateralConstraint`, off by default in the filters).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundfloor.errors import InputError
from sindy_ekf.estimation.process_models import N_X


@dataclass(frozen=True)
class LateralConstraint:
    """The ``v_y = 0`` pseudo-measurement: its standard deviation and rate.

    Attributes
    ----------
    vy_std_m_s : standard deviation of the body lateral velocity about zero, m/s (> 0).
    every : applied after every ``every``-th prediction step (1 = every step).
    """

    vy_std_m_s: float
    every: int = 1

    def __post_init__(self):
        if not (np.isfinite(self.vy_std_m_s) and self.vy_std_m_s > 0):
            raise InputError(f"lateral constraint: vy_std_m_s must be finite and > 0, got {self.vy_std_m_s}")
        if int(self.every) != self.every or self.every < 1:
            raise InputError(f"lateral constraint: every must be an integer >= 1, got {self.every}")


def fit_lateral_constraint(vy_body_m_s, every: int = 1, inflation: float = 2.0,
                           min_std_m_s: float = 1e-3) -> LateralConstraint:
    """Return a :class:`LateralConstraint` whose std is ``inflation`` x the RMS of the train ``v_y``.

    ``vy_body_m_s``: one array of body lateral velocities (m/s) or a list of them (one per run
    or segment; non-finite samples ignored). The RMS about zero (not the std about the mean)
    since the constraint says ``v_y = 0``; floored at ``min_std_m_s``. ``inflation`` (default 2)
    because the error of ``v_y = 0`` is not white: it is mostly the slowly varying deterministic
    lateral motion (e.g. ``v_x omega`` coupling), so repeated applications treated as independent
    are over-confident; with the plain RMS the oracle's ``v_y`` NEES is about 1.8 instead of 1 at
    5 Hz on simulated data, with 2 x RMS about 1.1 (``tests/test_ekf_lateral.py``).
    """
    if not (np.isfinite(inflation) and inflation > 0):
        raise InputError(f"lateral constraint: inflation must be finite and > 0, got {inflation}")
    parts = [np.ravel(np.asarray(v, float)) for v in
             (vy_body_m_s if isinstance(vy_body_m_s, (list, tuple)) else [vy_body_m_s])]
    vy = np.concatenate(parts) if parts else np.empty(0)
    vy = vy[np.isfinite(vy)]
    if vy.size == 0:
        raise InputError("lateral constraint: no finite train v_y sample to fit the std on")
    return LateralConstraint(max(inflation * float(np.sqrt(np.mean(vy * vy))), min_std_m_s), every)


def lateral_update(x: np.ndarray, P: np.ndarray,
                   vy_std_m_s: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Return ``(x, P, I - K H)`` after the ``v_y = 0`` pseudo-measurement, batched over ``(m,)``.

    Joseph-form Kalman update with ``H = e_vy`` (state index 4) and
    ``R = vy_std_m_s^2``, vectorised over the leading axis of ``x (m, 6)``, ``P (m, 6, 6)``.
    """
    r = vy_std_m_s ** 2
    S = P[:, 4, 4] + r                                  # (m,)
    K = P[:, :, 4] / S[:, None]                         # (m, 6)
    x = x - K * x[:, 4:5]
    IKH = np.broadcast_to(np.eye(N_X), P.shape).copy()
    IKH[:, :, 4] -= K
    P = IKH @ P @ np.swapaxes(IKH, -1, -2) + r * K[:, :, None] * K[:, None, :]
    return x, 0.5 * (P + np.swapaxes(P, -1, -2)), IKH
