"""Process noise of the simulated robot: random body accelerations of several spectra.

The accelerations ``vx_dot, vy_dot, omega_dot`` get additive noise (vibration, floor texture,
gusts of wheel slip) of per-axis std ``RobotParams.accel_noise_std`` and time scale
``RobotParams.noise_corr_time_s``, held over each integration step. Its spectrum is a
:class:`ProcessNoise` form:

``ou`` (the simulator's noise before variants existed)
    Stationary Ornstein-Uhlenbeck, correlation time ``tau``: a first-order low-pass of white noise.
``white``
    Independent per step, with the same low-frequency spectral density as the OU noise of the
    same std and ``tau`` (``q = 2 std^2 tau``, per-step std ``sqrt(q / dt)``), so that the
    velocities wander as much; all the power sits at high frequency instead.
``coloured``
    A resonance: white noise through ``w^2 / (s^2 + 2 zeta w s + w^2)`` (``w = 2 pi
    resonance_hz``, damping ratio ``zeta``), scaled to the std; a vibration mode of the chassis.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import signal

from groundfloor.errors import InputError

NOISE_FORMS = ("ou", "white", "coloured")


@dataclass(frozen=True)
class ProcessNoise:
    """Spectrum of the process noise: a form of ``NOISE_FORMS`` and the resonance of ``coloured``."""

    form: str = "ou"
    resonance_hz: float = 0.0
    damping_ratio: float = 0.0

    def __post_init__(self):
        if self.form not in NOISE_FORMS:
            raise InputError(f"process noise {self.form!r}: unknown (known: {', '.join(NOISE_FORMS)})")
        if self.form == "coloured" and not (self.resonance_hz > 0 and 0 < self.damping_ratio < 1):
            raise InputError(f"process noise coloured: resonance_hz={self.resonance_hz!r} must be > 0 and "
                             f"damping_ratio={self.damping_ratio!r} in (0, 1)")

    def to_dict(self) -> dict:
        """Return the spectrum as plain values for truth/."""
        extra = {"resonance_hz": self.resonance_hz, "damping_ratio": self.damping_ratio} if self.form == "coloured" else {}
        return {"form": self.form} | extra

    @classmethod
    def from_dict(cls, doc: dict) -> ProcessNoise:
        """Return the spectrum written by :meth:`to_dict`."""
        return cls(doc["form"], float(doc.get("resonance_hz", 0.0)), float(doc.get("damping_ratio", 0.0)))


def simulate_ou_noise(n: int, dt: float, std, corr_time_s: float, rng: np.random.Generator) -> np.ndarray:
    """Return ``(n, len(std))`` stationary Ornstein-Uhlenbeck samples on a grid of step ``dt``."""
    std = np.asarray(std, float)
    rho = math.exp(-dt / corr_time_s)
    eps = rng.standard_normal((n, std.size))
    eps[0] /= math.sqrt(1.0 - rho * rho)  # start in the stationary distribution
    return signal.lfilter([math.sqrt(1.0 - rho * rho)], [1.0, -rho], eps, axis=0) * std


def simulate_process_noise(noise: ProcessNoise, n: int, dt: float, std, corr_time_s: float,
                           rng: np.random.Generator) -> np.ndarray:
    """Return ``(n, len(std))`` process-noise accelerations of the spectrum ``noise`` (module docstring)."""
    std = np.asarray(std, float)
    if noise.form == "ou":
        return simulate_ou_noise(n, dt, std, corr_time_s, rng)
    if noise.form == "white":
        return rng.standard_normal((n, std.size)) * std * math.sqrt(2.0 * corr_time_s / dt)
    w = 2.0 * math.pi * noise.resonance_hz
    b, a, _ = signal.cont2discrete(([w * w], [1.0, 2.0 * noise.damping_ratio * w, w * w]), dt, method="zoh")
    b = b[0]
    n_settle = int(math.ceil(8.0 / (noise.damping_ratio * w * dt)))  # e^-8 of the start forgotten
    impulse = signal.lfilter(b, a, np.r_[1.0, np.zeros(4 * n_settle)])
    scale = 1.0 / math.sqrt(float(np.sum(impulse ** 2)))  # unit stationary std
    eps = rng.standard_normal((n + n_settle, std.size))
    return signal.lfilter(b, a, eps, axis=0)[n_settle:] * scale * std
