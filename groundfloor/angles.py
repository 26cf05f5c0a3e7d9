"""Angle wrapping, written once for the whole project."""

from __future__ import annotations

import numpy as np


def wrap_angle(a):
    """Return ``a`` (rad, any shape) wrapped into ``[-pi, pi)``."""
    return (np.asarray(a, dtype=float) + np.pi) % (2.0 * np.pi) - np.pi
