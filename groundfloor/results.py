"""Result values shared by stages: what a multi-step prediction scored."""

from __future__ import annotations

import math
from dataclasses import dataclass


@dataclass(frozen=True)
class PredictionError:
    """The 5 s multi-step prediction error of a model on a set of windows (thesis 5.3.8).

    RMS over the windows at the window's end (eqs. 5.77, 5.78); ``inf`` when a prediction
    diverged. ``to_json`` gives the ``evaluate --json`` keys of INTERFACES.md.
    """

    pos_err_5s_m: float
    yaw_err_5s_deg: float
    n_windows: int

    def to_json(self) -> dict:
        """Return ``{"pos_err_5s_m", "yaw_err_5s_deg", "n_windows"}`` (non-finite errors as None)."""
        return {"pos_err_5s_m": _finite_or_none(self.pos_err_5s_m),
                "yaw_err_5s_deg": _finite_or_none(self.yaw_err_5s_deg),
                "n_windows": int(self.n_windows)}


def _finite_or_none(v: float) -> float | None:
    """Return ``v`` as a float, or None when it is not finite (JSON has no inf)."""
    v = float(v)
    return v if math.isfinite(v) else None
