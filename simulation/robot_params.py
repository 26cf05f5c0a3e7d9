"""Parameters of the simulated Husky A200: thesis model B's coefficients and the simulator's additions.

:class:`RobotParams` holds the term tables of eqs. 7.7 and 7.9 (pysindy feature names over
``VARS``), the lateral law, the drive controller's limiters, the process noise and the pitch
response; :mod:`simulation.robot` states the equations they enter and integrates them.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

VARS = ("vx", "vy", "omega", "u1", "u2")  # order of the exponents of a monomial

# Thesis model B, eq. 7.7 (vx_dot) and eq. 7.9 (omega_dot), pysindy feature names.
MODEL_B_VX = (
    ("vx", -7.770), ("u1", 7.190), ("vx omega", -0.369), ("omega u1", 0.312), ("vx^3", 6.780),
    ("vx^2 u1", -6.357), ("vx omega^2", 7.730), ("vx omega u2", -5.104), ("vx u1^2", 3.459),
    ("omega^2 u1", -3.752), ("omega u1 u2", 1.125), ("u1^3", -3.129), ("u1 u2^2", -0.435),
)
MODEL_B_OMEGA = (
    ("omega", -6.951), ("u2", 7.900), ("vx^2 omega", 7.690), ("vx^2 u2", -3.251),
    ("vx omega^2", 1.394), ("vx u1 u2", -0.817), ("vx u2^2", -0.907), ("vy omega^2", 2.315),
    ("vy u1^2", -4.976), ("omega^3", 2.896), ("omega^2 u1", -1.409), ("omega^2 u2", -4.349),
    ("omega u1^2", -3.143), ("omega u2^2", 3.226), ("u1^2 u2", -0.795), ("u1 u2^2", 0.838),
    ("u2^3", -2.322),
)


@dataclass(frozen=True)
class RobotParams:
    """Parameters of the simulated Husky A200 (SI units, radians)."""

    terms_vx: tuple = MODEL_B_VX  # eq. 7.7
    terms_omega: tuple = MODEL_B_OMEGA  # eq. 7.9
    lateral_damping_1_s: float = 15.0  # k_y
    lateral_coupling: float = 1.0  # c_y (rigid-body value)
    max_speed_m_s: float = 1.0  # table 3.1
    track_half_width_m: float = 0.29  # half the hub-to-hub distance across an axle (table 6.3)
    guard_track_speed_m_s: float = 0.9  # per-track speed limit (model B's steady states: 0.876)
    guard_omega_rad_s: float = 1.2  # yaw-rate limit (model B's steady states: 1.149)
    guard_gain: float = 2000.0  # 1/m resp. s/rad^2: 0.8 m/s^2 at 2 cm/s beyond the limit
    accel_noise_std: tuple = (0.06, 0.03, 0.15)  # vx_dot m/s^2, vy_dot m/s^2, omega_dot rad/s^2
    noise_corr_time_s: float = 0.05
    pitch_per_accel_rad: float = math.radians(0.5)  # rad per m/s^2
    pitch_freq_hz: float = 2.0
    pitch_damping_ratio: float = 0.5
    g_m_s2: float = 9.81

    def terms(self) -> dict[str, dict[str, float]]:
        """Return ``{equation: {feature: coefficient}}`` of the effect-free polynomial dynamics."""
        return {"vx": dict(self.terms_vx),
                "vy": {"vy": -self.lateral_damping_1_s, "vx omega": -self.lateral_coupling},
                "omega": dict(self.terms_omega)}


def exponents_from_name(name: str) -> tuple[int, ...]:
    """Return the exponents over ``VARS`` of a pysindy-style monomial name like ``"vx^2 u1"``."""
    exps = [0] * len(VARS)
    for factor in name.split():
        var, _, power = factor.partition("^")
        exps[VARS.index(var)] += int(power) if power else 1
    return tuple(exps)
