"""Calibration from the raw survey: the data file, the JSON numbers, figures and bad surveys.

Only the survey numbers of ``simulation/data/calibration.yaml`` go in; tables 7.1 and 7.2 (the
thesis's own results, computed by Spatial Analyzer) are what comes out. The transform and the
body frame are tested on their own in ``test_network_transform.py`` and ``test_body_frame.py``.
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import yaml
from scipy.spatial.transform import Rotation

from groundfloor.errors import InputError
from identification.preprocessing.calibration import calibrate
from identification.preprocessing.figures import plot_body_frame, plot_network
from identification.preprocessing.io_survey import read_survey
from identification.preprocessing.network_transform import fit_transform
from simulation.truth import read_truth
from tests.support.survey_tables import TABLE_7_1, TABLE_7_2_ROT_DEG, TABLE_7_2_T

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


# ---------------------------------------------------------------- the JSON transform

def test_transform_maps_network_onto_at960(survey):
    """The JSON numbers (t and degrees, via scipy's Euler angles) map LTD800 onto AT960."""
    out = calibrate(survey).to_json_dict()["transform"]
    R = Rotation.from_euler("xyz", out["rotation_deg"], degrees=True).as_matrix()  # extrinsic
    x_ltd = np.array([survey.network_ltd800[i][:3] for i in survey.network_at960])
    x_at = np.array([v[:3] for v in survey.network_at960.values()])
    err = x_at - (np.asarray(out["translation_m"]) + x_ltd @ R.T)
    assert np.max(np.linalg.norm(err, axis=1)) < 60e-6  # largest residual on point 43 is 46 um


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


# ---------------------------------------------------------------- a simulated campaign's survey

def test_pipeline_calibration_of_the_survey_reproduces_the_truth(small_campaign):
    """identification.preprocessing.calibration (H3's Gauss-Helmert fit and body frame) on the campaign's
    calibration.yaml gives the simulator's transform and lever arms to the micrometre."""
    truth = read_truth(small_campaign, states=False)
    cal = calibrate(read_survey(small_campaign / "calibration.yaml"))
    assert np.allclose(cal.transform.t_at960_ltd800, truth.t_at960_ltd800, atol=5e-6)
    assert np.allclose(np.degrees(cal.transform.rotation_rad), truth.transform["rotation_deg"], atol=0.5 / 3600)
    for prism in ("front", "rear"):
        assert np.allclose(cal.body.lever_arms_body[prism], truth.lever_arms_m[prism], atol=2e-6)


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
