"""A rollout with sensitivities spoilt in one window: what a candidate that runs away gives the fits."""

from __future__ import annotations


def spoilt_rollout(real, window: int, value: float):
    """Return ``real`` (a ``rollout_with_sensitivities``) with the last 5 steps of ``window`` set to
    ``value`` in the pose states and in every sensitivity."""
    def spoilt(*args, **kwargs):
        pred, sens = real(*args, **kwargs)
        pred, sens = pred.copy(), sens.copy()
        pred[window, -5:, :3] = value
        sens[window, -5:] = value
        return pred, sens

    return spoilt
