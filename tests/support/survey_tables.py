"""The survey of ``simulation/data/calibration.yaml`` and what the thesis computed from it.

Tables 7.1 and 7.2 are the thesis's own results (Spatial Analyzer); the calibration tests
reproduce them from the survey numbers alone.
"""

from __future__ import annotations

import numpy as np

from tests.support import REPO

SURVEY_YAML = REPO / "simulation" / "data" / "calibration.yaml"

# Thesis table 7.2: translation as R^T t (m), rotations (deg).
TABLE_7_2_T = np.array([-2.050360, -8.757229, -0.086725])
TABLE_7_2_ROT_DEG = np.array([-0.374896, -0.180820, 142.749476])
# Thesis table 7.1: lever arms (m) and their standard deviations (um).
TABLE_7_1 = {"front": np.array([0.4671355, 0.0655364, 0.5167336]),
             "rear": np.array([-0.2600713, -0.1627405, 0.6546911])}
TABLE_7_1_STD_UM = {"front": np.array([17.7, 19.6, 19.1]), "rear": np.array([18.9, 22.0, 22.4])}
