"""The lateral law scored by what it changes in the pose: the 5 s prediction of the test runs.

A skid-steered body's lateral velocity settles within ``1 / k_y`` (0.05 to 0.1 s on the
simulator and its variants, less than two samples at 25 Hz) at the drift its lateral law
balances, ``vy`` with ``f_y(vx, vy, omega) = 0``. The window residual of the ``vy`` equation
(:func:`sindy_ekf.diagnose.fitting.score_family`) measures the lateral *acceleration* over 2 s:
in a settled turn ``vy`` hardly changes, so the data's ``delta vy`` is noise, and any law whose
acceleration is small there leaves a small residual whatever drift it balances. A model whose
identified lateral stiffness is far too small (integral SINDy cannot separate the damping from the
coupling, and the noise on ``vy`` shrinks both) has such a law, and a drift that is wrong by a
factor two or more shows in the window residual as a few per cent, below its threshold, while it
moves the predicted position by centimetres over 5 s (measured on the forms suite's hidden slip
of saturating, hardening and speed-dependent laws: window gains 0.000 to 0.05, 5 s errors on
the test runs 4.5 -> 1.5, 5.0 -> 3.2, 11.2 -> 3.9 cm; on effect-free variant campaigns the
same extension changes them by less than 10 %).

:func:`drift_score` therefore scores the lateral law a second way: the model plus the law fitted
on the train runs (:meth:`ExtendedModel.added`, the extension ``diagnose`` writes) against the
model as given, by the relative drop of the squared 5 s position errors on the test runs. A window
where a prediction diverged is charged :data:`~sindy_ekf.diagnose.extend.DIVERGED_5S_M`, as
:func:`~sindy_ekf.diagnose.pipeline.choose_extension` charges it: a law that runs away on the hard
windows is not scored on the easy ones alone. Its null is calibrated like the others (``rank.NULL_MAX_GAIN``
under ``"multistep"``).
"""

from __future__ import annotations

import dataclasses
from typing import Sequence

import numpy as np

from groundfloor.types import BodyStates
from sindy_ekf.diagnose.extend import DIVERGED_5S_M, ExtendedModel, diverged, multistep
from sindy_ekf.diagnose.fitting import FamilyScore

SCORING = "multistep"


def squared_errors(model, states: Sequence[BodyStates], names: Sequence[str]) -> np.ndarray:
    """Return the squared position errors ``(W,)`` at the end of the 5 s windows, a diverged one
    charged ``DIVERGED_5S_M ** 2``."""
    e = np.asarray(multistep(model, states, names).eps_p[:, -1], float)
    return np.where(diverged(e), DIVERGED_5S_M, e) ** 2


def drift_gain(model, extended, states: Sequence[BodyStates], names: Sequence[str]) -> float:
    """Return ``1 - SSE_extended / SSE_model`` of the squared 5 s position errors on ``states``, every
    window counted, a diverged one charged (:func:`squared_errors`; ``nan`` without any window)."""
    before, after = squared_errors(model, states, names), squared_errors(extended, states, names)
    if not len(before) or before.sum() <= 0:
        return float("nan")
    return float(1.0 - after.sum() / before.sum())


def drift_score(score: FamilyScore, model, test: Sequence[BodyStates], test_names: Sequence[str]) -> FamilyScore:
    """Return ``score`` (the lateral law fitted on the train runs with the model kept fixed, scored by the window
    residual or by its lateral velocity's output error, :func:`sindy_ekf.diagnose.lateral.output_error_score`) with its
    5 s scoring on the test runs beside it (``by_scoring["multistep"]``, the better of the two the
    score, the other its ``alternative``, as :func:`sindy_ekf.diagnose.fitting.score_family` does
    with the refit)."""
    extended = ExtendedModel.added(model, score.family, score.theta, score.beta, dict(score.estimate), score.uniform)
    gain = drift_gain(model, extended, test, test_names)
    by = {**(score.by_scoring or {"fixed": score.gain}), SCORING: gain}
    fixed = dataclasses.replace(score, by_scoring=by, alternative=None)
    if not np.isfinite(gain):
        return fixed
    drift = dataclasses.replace(fixed, gain=gain, gain_per_run={}, train_gain=float("nan"),
                                estimate={**score.estimate, "scored_with": SCORING})
    better, other = (drift, fixed) if gain > score.gain else (fixed, drift)
    return dataclasses.replace(better, alternative=other)
