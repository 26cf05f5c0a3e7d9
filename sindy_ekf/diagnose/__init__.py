"""Diagnosis: what a model gets wrong on measured data, its cause, the extended model and its gain.

Modules: :mod:`~sindy_ekf.diagnose.data` (runs stacked with integration windows),
:mod:`~sindy_ekf.diagnose.residuals` (residual structure and its numbers),
:mod:`~sindy_ekf.diagnose.families` (one mechanism per family),
:mod:`~sindy_ekf.diagnose.fitting` (each family fitted on train runs, scored on test runs),
:mod:`~sindy_ekf.diagnose.rank` (calibrated thresholds, ranking),
:mod:`~sindy_ekf.diagnose.extend` (extended model, re-identification, gains),
:mod:`~sindy_ekf.diagnose.measurement` (preprocessing findings),
:mod:`~sindy_ekf.diagnose.pipeline` (end to end), and :mod:`~sindy_ekf.diagnose.figures`
(its figures, drawn on request).
"""

from sindy_ekf.diagnose.families import FAMILIES
from sindy_ekf.diagnose.pipeline import (
    Diagnosis,
    diagnose_campaign,
    diagnose_states,
    load_model,
)

__all__ = ["FAMILIES", "Diagnosis", "diagnose_campaign", "diagnose_states", "load_model"]
