"""The body frame and the prism lever arms from the wheel-hub survey: table 7.1, invariances.

Only the survey numbers of ``simulation/data/calibration.yaml`` go in; table 7.1 (the thesis's
own result, computed by Spatial Analyzer) is what comes out.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from groundfloor.errors import InputError
from identification.preprocessing.body_frame import fit_body_frame, fit_circle_3d
from identification.preprocessing.io_survey import survey_from_mapping
from tests.support.survey_tables import TABLE_7_1, TABLE_7_1_STD_UM

# ---------------------------------------------------------------- table 7.1

def test_lever_arms_reproduce_table_7_1(survey):
    body = fit_body_frame(survey)
    for name, table in TABLE_7_1.items():
        np.testing.assert_allclose(body.lever_arms_body[name], table, rtol=0, atol=1e-5)
        # rotated CCR sigmas of table 6.3 vs table 7.1's sigmas (rounded to 0.1 um there)
        np.testing.assert_allclose(body.lever_arms_std[name] * 1e6, TABLE_7_1_STD_UM[name],
                                   atol=0.15)
    R = body.R_survey_body
    np.testing.assert_allclose(R.T @ R, np.eye(3), atol=1e-14)
    assert np.linalg.det(R) > 0
    # Section 6.2: the robot stood about 5 m from the LTD800 with its x axis pointing at it,
    # so the tracker lies ahead of the robot on body x.
    assert body.body_from_survey(np.zeros(3))[0] > 3.0
    # Hub radii: the screw circle of the Husky hub (about 17.5 mm), all four alike.
    np.testing.assert_allclose(body.hub_radii_m, 0.0175, atol=1e-4)


def test_section_5_1_wording_misses_table_7_1(survey):
    """x along the left wheels (section 5.1's wording) misses table 7.1 by about 0.5 mm."""
    body = fit_body_frame(survey)
    c = dict(zip(body.hub_names, body.hub_centres_survey))
    z = body.R_survey_body[:, 2]
    x = c["front_left"] - c["rear_left"]
    x -= (x @ z) * z
    x /= np.linalg.norm(x)
    R = np.column_stack([x, np.cross(z, x), z])
    arm = R.T @ (survey.prisms["front"][:3] - body.origin_survey)
    assert np.linalg.norm(arm - TABLE_7_1["front"]) > 1e-4


def test_body_frame_is_invariant_to_the_survey_frame(survey):
    """Moving the whole body survey rigidly leaves every lever arm where it was."""
    rng = np.random.default_rng(3)
    R = Rotation.from_euler("z", rng.uniform(-np.pi, np.pi)).as_matrix()  # keep z up
    R = R @ Rotation.from_rotvec(rng.normal(size=3) * 0.02).as_matrix()  # and a small tilt
    t = rng.normal(size=3) * 5.0

    def move(rows):
        return np.hstack([rows[..., :3] @ R.T + t, rows[..., 3:]])

    moved = dataclasses.replace(
        survey, wheel_hubs={k: move(v) for k, v in survey.wheel_hubs.items()},
        prisms={k: move(v) for k, v in survey.prisms.items()})
    a, b = fit_body_frame(survey), fit_body_frame(moved)
    for name in a.lever_arms_body:
        np.testing.assert_allclose(b.lever_arms_body[name], a.lever_arms_body[name], atol=1e-10)


def test_circle_fit_recovers_a_known_circle():
    rng = np.random.default_rng(11)
    normal = rng.normal(size=3)
    normal /= np.linalg.norm(normal)
    e1 = np.cross(normal, [1.0, 0.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    centre, r = np.array([1.2, 4.1, -1.19]), 0.0175
    phi = np.array([0.1, 1.7, 3.3, 4.6])
    p = centre + r * (np.cos(phi)[:, None] * e1 + np.sin(phi)[:, None] * e2)
    c, n, radius, rms = fit_circle_3d(p)
    np.testing.assert_allclose(c, centre, atol=1e-12)
    assert abs(radius - r) < 1e-12 and rms < 1e-12
    assert abs(abs(n @ normal) - 1.0) < 1e-12


def test_swapped_hub_labels_are_reported(raw):
    data = yaml.safe_load(yaml.safe_dump(raw))
    hubs = data["body_survey"]["wheel_hubs"]
    hubs["front_left"], hubs["rear_left"] = hubs["rear_left"], hubs["front_left"]
    hubs["front_right"], hubs["rear_right"] = hubs["rear_right"], hubs["front_right"]
    with pytest.raises(InputError, match="wheel_hubs.*front hubs lie behind"):
        fit_body_frame(survey_from_mapping(data))
