"""Survey to calibration: the LTD800-to-AT960 transform, the body frame and the prism lever arms.

Implements thesis sections 5.1 and 5.2.1 from the raw survey of ``calibration.yaml`` (tables 6.1
to 6.3) and reproduces tables 7.1 and 7.2 (see ``docs/conventions.md`` for the conventions and
the measured agreement):

* :func:`identification.preprocessing.network_transform.fit_transform`: rigid 6-parameter
  transform ``x_at960 = t + R x_ltd800`` (eqs. 5.1 to 5.5) in the Gauss-Helmert model (eqs.
  2.17 to 2.26), with a test that names a blundered network point;
* :func:`identification.preprocessing.body_frame.fit_body_frame`: circle per wheel hub, plane
  through the four hub centres, body axes and the prism lever arms;
* :func:`calibrate`: both, as one :class:`Calibration`.

Its figures (``plot_network``, ``plot_body_frame``) are in :mod:`identification.preprocessing.figures`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from groundfloor.types import Survey
from identification.preprocessing.body_frame import BodyFrameFit, fit_body_frame
from identification.preprocessing.network_transform import TransformFit, fit_transform


@dataclass(frozen=True)
class Calibration:
    """Everything derived from the survey: tracker transform, body frame, lever arms."""

    transform: TransformFit
    body: BodyFrameFit
    prism_tracker: dict[str, str]  # front -> "ltd800", rear -> "at960"

    @property
    def lever_arms_body(self) -> dict[str, np.ndarray]:
        """Return front/rear -> (3,) prism lever arm in the body frame, m."""
        return self.body.lever_arms_body

    def to_json_dict(self) -> dict:
        """Return the ``preprocess --json`` keys ``transform`` and ``lever_arms_m`` (and more).

        ``translation_m`` is the INTERFACES translation ``t`` of ``x_at960 = t + R x_ltd800``,
        not the ``R^T t`` of table 7.2 (given as ``translation_table_m``).
        """
        tf, std = self.transform, self.body.lever_arms_std
        return {
            "transform": {
                "translation_m": tf.t_at960_ltd800.tolist(),
                "rotation_deg": np.degrees(tf.rotation_rad).tolist(),
                "translation_table_m": tf.t_table.tolist(),
                "translation_std_m": tf.params_std[:3].tolist(),
                "rotation_std_deg": np.degrees(tf.params_std[3:]).tolist(),
                "variance_factor": tf.variance_factor,
                "variance_factor_test": tf.variance_factor_test.to_json(),
                "worst_point": tf.worst_point,
                "blunder_point": tf.blunder_point,
            },
            "lever_arms_m": {k: v.tolist() for k, v in self.body.lever_arms_body.items()},
            "lever_arms_std_m": {k: v.tolist() for k, v in std.items()},
        }


def calibrate(survey: Survey, alpha: float = 0.001, strict: bool = False) -> Calibration:
    """Return the transform (:func:`fit_transform`) and body frame (:func:`fit_body_frame`).

    ``alpha`` and ``strict`` go to the network blunder test of :func:`fit_transform`.
    """
    return Calibration(transform=fit_transform(survey, alpha=alpha, strict=strict),
                       body=fit_body_frame(survey), prism_tracker=dict(survey.prism_tracker))
