"""Calibration from the raw survey: checked against the thesis tables and independent methods.

Only the survey numbers of ``simulation/data/calibration.yaml`` go in; tables 7.1 and 7.2 (the
thesis's own results, computed by Spatial Analyzer) are what comes out.
"""

from __future__ import annotations

import dataclasses
import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from groundfloor.errors import InputError
from identification.preprocessing.calibration import (
    ARCSEC_PER_RAD,
    _rotation_and_derivatives,
    angles_from_rotation,
    calibrate,
    fit_body_frame,
    fit_circle_3d,
    fit_transform,
    rotation_from_angles,
)
from identification.preprocessing.figures import plot_body_frame, plot_network
from identification.preprocessing.io_survey import read_survey, survey_from_mapping
from tests.support import REPO

YAML = REPO / "simulation" / "data" / "calibration.yaml"

# Thesis table 7.2: translation as R^T t (m), rotations (deg), and table 7.1 (m, um).
TABLE_7_2_T = np.array([-2.050360, -8.757229, -0.086725])
TABLE_7_2_ROT_DEG = np.array([-0.374896, -0.180820, 142.749476])
TABLE_7_1 = {"front": np.array([0.4671355, 0.0655364, 0.5167336]),
             "rear": np.array([-0.2600713, -0.1627405, 0.6546911])}
TABLE_7_1_STD_UM = {"front": np.array([17.7, 19.6, 19.1]), "rear": np.array([18.9, 22.0, 22.4])}


@pytest.fixture(scope="module")
def survey():
    return read_survey(YAML)


@pytest.fixture(scope="module")
def raw():
    return yaml.safe_load(YAML.read_text())


# ---------------------------------------------------------------- the data file itself

def test_yaml_holds_thesis_tables_6_1_to_6_3_verbatim(shared_dir, survey):
    """Every number of tables 6.1 to 6.3, parsed from the thesis text, is in the survey."""
    text = (shared_dir / "thesis" / "000_5587118689ad256f.txt").read_text().splitlines()

    def table(title, n_rows):
        start = next(i for i, line in enumerate(text) if line.startswith(title))
        rows = [line.split("\t") for line in text[start + 1:] if line.count("\t") >= 6]
        return [(r[0].strip(), np.array(r[-6:], float) * [1, 1, 1, 1e-6, 1e-6, 1e-6])
                for r in rows[1:n_rows + 1]]

    for title, net in (("Table 6.1", survey.network_at960), ("Table 6.2", survey.network_ltd800)):
        rows = table(title, 7)
        assert [pid for pid, _ in rows] == list(net)
        for pid, row in rows:
            np.testing.assert_allclose(net[pid], row, rtol=0, atol=1e-12)
    rows = [r for _, r in table("Table 6.3", 18)]
    hubs = np.concatenate([survey.wheel_hubs[h] for h in
                           ("front_left", "rear_left", "rear_right", "front_right")])
    np.testing.assert_allclose(hubs, np.array(rows[:16]), rtol=0, atol=1e-12)
    np.testing.assert_allclose(survey.prisms["front"], rows[16], rtol=0, atol=1e-12)
    np.testing.assert_allclose(survey.prisms["rear"], rows[17], rtol=0, atol=1e-12)
    assert survey.body_frame == "ltd800"
    assert survey.prism_tracker == {"front": "ltd800", "rear": "at960"}


# ---------------------------------------------------------------- table 7.2

def test_transform_reproduces_table_7_2(survey):
    fit = fit_transform(survey)
    dt_um = (fit.t_table - TABLE_7_2_T) * 1e6
    drot_arcsec = (fit.rotation_rad - np.radians(TABLE_7_2_ROT_DEG)) * ARCSEC_PER_RAD
    assert np.all(np.abs(dt_um) < 10.0), dt_um
    assert np.all(np.abs(drot_arcsec) < 0.5), drot_arcsec
    # The INTERFACES translation t is R t_table, not t_table: both conventions in one fit.
    np.testing.assert_allclose(fit.R_at960_ltd800 @ fit.t_table, fit.t_at960_ltd800, atol=1e-12)
    # The survey sigmas are pessimistic (USMN); no point is flagged on the real network.
    assert fit.blunder_point is None
    assert 0.05 < fit.variance_factor < 1.0
    # Uncertainties of the order of table 7.2's (20-36 um, 0.7-1.2 arcsec); USMN's own model
    # is not transparent (section 7.2), so only the magnitude is compared.
    assert np.all((fit.t_table_std > 10e-6) & (fit.t_table_std < 50e-6))
    assert np.all((fit.params_std[3:] * ARCSEC_PER_RAD > 0.4)
                  & (fit.params_std[3:] * ARCSEC_PER_RAD < 2.0))


def test_transform_maps_network_onto_at960(survey):
    """The JSON numbers (t and degrees, via scipy's Euler angles) map LTD800 onto AT960."""
    out = calibrate(survey).to_json_dict()["transform"]
    R = Rotation.from_euler("xyz", out["rotation_deg"], degrees=True).as_matrix()  # extrinsic
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in survey.network_at960])
    x_at = np.array([v[:3] for v in survey.network_at960.values()])
    err = x_at - (np.asarray(out["translation_m"]) + x_ltd @ R.T)
    assert np.max(np.linalg.norm(err, axis=1)) < 60e-6  # largest residual on point 43 is 46 um


# ---------------------------------------------------------------- second implementations

def _horn_quaternion(x_from, x_to, w):
    """Horn's (1987) closed-form absolute orientation with unit quaternions (weighted)."""
    w = w / w.sum()
    a, b = x_from - w @ x_from, x_to - w @ x_to
    S = np.einsum("n,ni,nj->ij", w, a, b)
    N = np.array([
        [S[0, 0] + S[1, 1] + S[2, 2], S[1, 2] - S[2, 1], S[2, 0] - S[0, 2], S[0, 1] - S[1, 0]],
        [S[1, 2] - S[2, 1], S[0, 0] - S[1, 1] - S[2, 2], S[0, 1] + S[1, 0], S[2, 0] + S[0, 2]],
        [S[2, 0] - S[0, 2], S[0, 1] + S[1, 0], -S[0, 0] + S[1, 1] - S[2, 2], S[1, 2] + S[2, 1]],
        [S[0, 1] - S[1, 0], S[2, 0] + S[0, 2], S[1, 2] + S[2, 1], -S[0, 0] - S[1, 1] + S[2, 2]]])
    q = np.linalg.eigh(N)[1][:, -1]  # (w, x, y, z)
    R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
    return R, w @ x_to - R @ (w @ x_from)


def test_wls_equals_horn_when_sigmas_are_isotropic_and_equal(survey):
    """With one isotropic sigma everywhere the Gauss-Helmert fit IS Horn's closed form."""
    same = {k: np.r_[v[:3], 30e-6, 30e-6, 30e-6] for k, v in survey.network_ltd800.items()}
    same_at = {k: np.r_[v[:3], 30e-6, 30e-6, 30e-6] for k, v in survey.network_at960.items()}
    fit = fit_transform(dataclasses.replace(survey, network_ltd800=same, network_at960=same_at))
    x_ltd = np.array([same[i][:3] for i in fit.point_ids])
    x_at = np.array([same_at[i][:3] for i in fit.point_ids])
    R, t = _horn_quaternion(x_ltd, x_at, np.ones(len(x_at)))
    np.testing.assert_allclose(fit.R_at960_ltd800, R, atol=1e-12)
    np.testing.assert_allclose(fit.t_at960_ltd800, t, atol=1e-10)


def test_wls_and_horn_differ_only_by_the_weighting(survey):
    """On the real sigmas WLS and unweighted Horn differ by a few um / tenths of an arcsec."""
    fit = fit_transform(survey)
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in fit.point_ids])
    x_at = np.array([survey.network_at960[i][:3] for i in fit.point_ids])
    R, t = _horn_quaternion(x_ltd, x_at, np.ones(len(x_at)))
    d_rot = Rotation.from_matrix(R.T @ fit.R_at960_ltd800).magnitude() * ARCSEC_PER_RAD
    d_t_table = np.linalg.norm(R.T @ t - fit.t_table)
    assert 0.01 < d_rot < 2.0  # weights matter, but only within the parameter uncertainty
    assert d_t_table < 30e-6


def test_covariance_matches_monte_carlo(survey):
    """200 noisy copies of a consistent network: spread of the fits = reported std (20 %)."""
    fit = fit_transform(survey)
    ids = fit.point_ids
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in ids])
    std_ltd = np.array([survey.network_ltd800[i][3:] for i in ids])
    std_at = np.array([survey.network_at960[i][3:] for i in ids])
    x_at_true = fit.t_at960_ltd800 + x_ltd @ fit.R_at960_ltd800.T
    rng = np.random.default_rng(7)
    params, s0, T = [], [], []
    for _ in range(200):  # one fit per draw: each fit is one batched solve
        noisy_ltd = x_ltd + rng.normal(size=x_ltd.shape) * std_ltd
        noisy_at = x_at_true + rng.normal(size=x_ltd.shape) * std_at
        s = dataclasses.replace(
            survey, network_ltd800=dict(zip(ids, np.hstack([noisy_ltd, std_ltd]))),
            network_at960=dict(zip(ids, np.hstack([noisy_at, std_at]))))
        f = fit_transform(s)
        params.append(np.r_[f.t_at960_ltd800, f.rotation_rad])
        s0.append(f.variance_factor)
        T.append(f.point_test)
    mc_std = np.std(params, axis=0, ddof=1)
    ratio = mc_std / fit.params_std
    assert np.all(np.abs(ratio - 1.0) < 0.2), ratio
    assert abs(np.mean(s0) - 1.0) < 0.15  # sigma0^2 = 1 when the sigmas are right
    # Without blunders the leave-one-out statistic is chi2(3): mean 3, variance 6.
    assert abs(np.mean(T) - 3.0) < 0.3
    assert abs(np.var(T) - 6.0) < 1.5


def test_rotation_convention_and_derivatives():
    """R = Rz Ry Rx (eq. 5.5) equals scipy's extrinsic xyz; dR/dangles = numerical."""
    angles = np.array([[-0.0065, -0.0032, 2.49], [0.3, -1.2, -2.0]])
    R, dR = _rotation_and_derivatives(angles)
    np.testing.assert_allclose(R, Rotation.from_euler("xyz", angles).as_matrix(), atol=1e-14)
    np.testing.assert_allclose(angles_from_rotation(R), angles, atol=1e-13)
    np.testing.assert_allclose(rotation_from_angles(angles), R, atol=0)
    h = 1e-6
    for k in range(3):
        step = np.zeros(3)
        step[k] = h
        num = (rotation_from_angles(angles + step) - rotation_from_angles(angles - step)) / (2 * h)
        np.testing.assert_allclose(dR[..., k], num, atol=1e-9)


# ---------------------------------------------------------------- blunders

@pytest.mark.parametrize("pid", ["31", "41", "43", "53", "63", "61", "51"])
def test_swapped_coordinates_are_flagged_and_named(survey, pid):
    net = {k: v.copy() for k, v in survey.network_ltd800.items()}
    net[pid][[0, 1]] = net[pid][[1, 0]]
    bad = dataclasses.replace(survey, network_ltd800=net)
    fit = fit_transform(bad)
    assert fit.blunder_point == pid
    assert fit.global_test_p < 1e-6
    with pytest.raises(InputError, match=f"network point '{pid}' fails the outlier test"):
        fit_transform(bad, strict=True)


@pytest.mark.parametrize("pid", ["31", "53", "61"])
def test_one_millimetre_blunder_in_at960_is_named(survey, pid):
    """A small blunder (1 mm in z, about 15 sigma) on the other tracker's list is found too."""
    net = {k: v.copy() for k, v in survey.network_at960.items()}
    net[pid][2] += 1e-3
    fit = fit_transform(dataclasses.replace(survey, network_at960=net))
    assert fit.blunder_point == pid
    assert pid in fit.blunder_message()


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


# ---------------------------------------------------------------- JSON and figures

def test_json_keys_follow_interfaces(survey):
    out = calibrate(survey).to_json_dict()
    assert len(out["transform"]["translation_m"]) == 3
    assert len(out["transform"]["rotation_deg"]) == 3
    np.testing.assert_allclose(out["transform"]["rotation_deg"], TABLE_7_2_ROT_DEG, atol=1e-4)
    np.testing.assert_allclose(out["transform"]["translation_table_m"], TABLE_7_2_T, atol=1e-5)
    for name in ("front", "rear"):
        np.testing.assert_allclose(out["lever_arms_m"][name], TABLE_7_1[name], atol=1e-5)


def test_plots_render(survey, tmp_path):
    cal = calibrate(survey)
    for fig_fn, args in ((plot_network, (survey, cal.transform)),
                         (plot_body_frame, (survey, cal.body))):
        path = tmp_path / f"{fig_fn.__name__}.png"
        fig = fig_fn(*args, path=path)
        assert path.stat().st_size > 10_000
        assert fig.axes and fig.axes[0].has_data()


# ---------------------------------------------------------------- bad input

def _write(tmp_path, data) -> Path:
    path = tmp_path / "calibration.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def _edit(raw, fn):
    data = yaml.safe_load(yaml.safe_dump(raw))
    fn(data)
    return data


@pytest.mark.parametrize("edit, culprit", [
    (lambda d: d["network"]["ltd800"].pop("43"),
     "network point '43' is in at960 but not in ltd800"),
    (lambda d: d["network"]["ltd800"].__setitem__("99", [0, 0, 0, 1e-5, 1e-5, 1e-5]),
     "network point '99' is in ltd800 but not in at960"),
    (lambda d: d["network"]["at960"]["41"].__setitem__(1, float("nan")),
     "'network.at960.41' holds a NaN"),
    (lambda d: d["body_survey"]["wheel_hubs"].__setitem__(
        "rear_left", d["body_survey"]["wheel_hubs"]["rear_left"][:2]),
     "'body_survey.wheel_hubs.rear_left' has 2 screw-head points"),
    (lambda d: d["body_survey"]["prisms"].__setitem__("front", [1.0, 2.0, 3.0]),
     "'body_survey.prisms.front' must be"),
    (lambda d: d["prisms"].__setitem__("rear", "at901"), "'prisms.rear' is 'at901'"),
    (lambda d: d["body_survey"].__setitem__("frame", "total_station"),
     "'body_survey.frame' is 'total_station'"),
    (lambda d: d.pop("body_survey"), "missing key 'body_survey'"),
    (lambda d: d["network"]["at960"]["53"].__setitem__(4, 0.0), "'network.at960.53' has a sigma"),
    (lambda d: d["body_survey"]["wheel_hubs"].pop("front_right"),
     "missing key 'body_survey.wheel_hubs.front_right'"),
], ids=["missing-id", "extra-id", "nan", "hub-2-points", "row-length", "tracker-name",
        "frame-name", "missing-block", "zero-sigma", "missing-hub"])
def test_bad_survey_names_the_culprit(raw, tmp_path, edit, culprit):
    path = _write(tmp_path, _edit(raw, edit))
    with pytest.raises(InputError, match=re.escape(culprit)) as info:
        read_survey(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


def test_unreadable_files_are_named(tmp_path):
    with pytest.raises(InputError, match=re.escape(f"{tmp_path / 'nope.yaml'}: cannot read")):
        read_survey(tmp_path / "nope.yaml")
    bad = tmp_path / "calibration.yaml"
    bad.write_text("network: [unclosed\n")
    with pytest.raises(InputError, match="not valid YAML at line"):
        read_survey(bad)


def test_unknown_keys_are_ignored_and_integer_ids_accepted(raw, tmp_path):
    def edit(d):
        d["operator"] = "someone"
        d["network"]["at901"] = {"1": [0, 0, 0]}
        d["body_survey"]["temperature_c"] = 21.0
        for tr in ("at960", "ltd800"):  # unquoted YAML ids arrive as ints
            d["network"][tr] = {int(k): v for k, v in d["network"][tr].items()}
    s = read_survey(_write(tmp_path, _edit(raw, edit)))
    assert set(s.network_at960) == {"31", "41", "43", "53", "63", "61", "51"}
    np.testing.assert_allclose(fit_transform(s).t_table, TABLE_7_2_T, atol=1e-5)


def test_collinear_network_is_rejected(survey):
    ids = ("a", "b", "c", "d")
    line = {i: np.r_[k * 1.0, 2 * k, 0.0, 1e-5, 1e-5, 1e-5] for k, i in enumerate(ids)}
    with pytest.raises(InputError, match="network points a, b, c, d are collinear"):
        fit_transform(dataclasses.replace(survey, network_at960=line, network_ltd800=line))
