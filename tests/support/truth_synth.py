"""A ``truth/`` folder written beside any campaign: what makes it a simulated campaign to readers."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from simulation.truth import CampaignTruth, write_truth


def write_bare_truth(campaign_dir: Path, effects: tuple = ()) -> Path:
    """Write ``truth/truth.yaml`` with ``effects`` ``((name, value), ...)`` and no runs; return the truth folder."""
    truth = CampaignTruth(seed=0, minutes=1.0, effects=tuple(effects),
                          transform={"translation_m": [0.0, 0.0, 0.0], "rotation_deg": [0.0, 0.0, 0.0],
                                     "t_table_m": [0.0, 0.0, 0.0], "R": np.eye(3).tolist()},
                          lever_arms_m={"front": [0.4, 0.0, 0.5], "rear": [-0.4, 0.0, 0.5]},
                          body_origin_z_local_m=-1.25, baseline_length_m=0.8, hubs={}, noise={}, robot={})
    return write_truth(campaign_dir, truth)
