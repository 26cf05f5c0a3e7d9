"""Result values shared by stages: what a multi-step prediction scored."""

from __future__ import annotations

from dataclasses import dataclass

from groundfloor.numbers import finite_or_none


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
        return {"pos_err_5s_m": finite_or_none(self.pos_err_5s_m),
                "yaw_err_5s_deg": finite_or_none(self.yaw_err_5s_deg),
                "n_windows": int(self.n_windows)}

