"""Turning-hub eccentricity model (eq. 5.25) against synthetic truth (tests/tests.support.pose_synth.py)."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from identification.preprocessing.figures import plot_hub_model
from identification.preprocessing.hub import (
    HubModel,
    fit_hub_model,
    fit_hub_model_joint,
)
from tests.support.pose_synth import LEVER_FRONT, LEVER_REAR, measurements


def _fit(m) -> HubModel:
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    return fit_hub_model(m.t, length, m.az_front, m.az_rear)


def _wrap(a):
    return (np.asarray(a) + np.pi) % (2 * np.pi) - np.pi


@pytest.mark.parametrize("seed", [0, 1, 2, 3])
def test_radii_c_phases_recovered(seed):
    m = measurements(duration_s=90.0, seed=seed)
    hub = _fit(m)
    r_h = hub.radius_horizontal(LEVER_FRONT, LEVER_REAR)
    assert np.all(np.abs(r_h - m.radius_m) < 0.03e-3)  # the bar
    assert np.all(np.abs(r_h - m.radius_m) < 5e-6)  # what 10 um noise actually allows
    assert abs(hub.c_m - m.c_m) < 0.01e-3
    # errors consistent with the propagated uncertainties (white noise here)
    assert np.all(np.abs(hub.radius_m - m.radius_m * m.cos_elev) < 5 * hub.radius_std_m)
    assert abs(hub.c_m - m.c_m) < 5 * hub.c_std_m
    assert np.all(np.abs(_wrap(hub.phase_rad - m.phase_rad)) < 5 * hub.phase_std_rad + 1e-3)
    # the residual is the baseline noise of two prisms: sqrt(2) * 10 um
    assert hub.rms_after_m == pytest.approx(np.sqrt(2) * m.noise_m, rel=0.15)
    assert hub.rms_before_m > 3 * hub.rms_after_m


def test_thesis_magnitudes_table_7_5():
    """Table 7.5's radii (0.21, 0.12 mm) explain baseline RMS of the order of its 'before'."""
    m = measurements(duration_s=90.0, seed=5, radius_m=(0.21e-3, 0.12e-3))
    hub = _fit(m)
    assert hub.c_m * 100 == pytest.approx(77.46, abs=0.01)  # cm, table 7.5 mean 77.4629
    assert 0.05e-3 < hub.rms_before_m < 0.25e-3  # table 7.5: 0.09 .. 0.19 mm before
    assert hub.c_std_m < 5e-6 and np.all(hub.radius_std_m < 10e-6)  # table 7.5: 1 to 4 um


def test_joint_fit_shares_radii_across_short_runs():
    """Thesis 5.2.3's proposed improvement: one pair of radii, per-run c and phases."""
    runs = [measurements(duration_s=20.0, seed=20 + j) for j in range(5)]
    args = [(m.t, np.linalg.norm(m.p_front - m.p_rear, axis=1), m.az_front, m.az_rear) for m in runs]
    single = [fit_hub_model(*a) for a in args]
    joint = fit_hub_model_joint(args)
    r_true = runs[0].radius_m * runs[0].cos_elev
    assert np.allclose([j.radius_m for j in joint], joint[0].radius_m)  # shared
    assert np.all(np.abs(joint[0].radius_m - r_true) < 3 * joint[0].radius_std_m + 1e-6)
    assert np.all(np.abs(joint[0].radius_m - r_true) < 10e-6)
    assert np.all(joint[0].radius_std_m < np.min([s.radius_std_m for s in single], axis=0))
    for m, j, s in zip(runs, joint, single):
        assert abs(j.c_m - m.c_m) < 5 * j.c_std_m  # 20 s runs: c is only as good as its std
        assert np.all(np.abs(_wrap(j.phase_rad - m.phase_rad)) < 5 * j.phase_std_rad + 1e-3)
        assert j.rms_after_m == pytest.approx(s.rms_after_m, rel=0.1)


def test_eccentricity_body_reproduces_model_and_truth():
    m = measurements(duration_s=60.0, seed=7)
    hub = _fit(m)
    e_f, e_r = hub.eccentricity_body(m.az_front, m.az_rear, LEVER_FRONT, LEVER_REAR)
    # the simulator-convention offsets are recovered vector by vector (default sense = -1),
    # within what the radius and phase uncertainties allow
    vec_std = np.hypot(hub.radius_std_m, hub.radius_m * hub.phase_std_rad)
    assert np.sqrt(np.mean(np.sum((e_f - m.offset_front_body) ** 2, 1))) < 3 * vec_std[0]
    assert np.sqrt(np.mean(np.sum((e_r - m.offset_rear_body) ** 2, 1))) < 3 * vec_std[1]
    # the along-baseline part is eq. 5.25 itself
    d = LEVER_FRONT - LEVER_REAR
    length = np.linalg.norm(d + e_f - e_r, axis=1)
    np.testing.assert_allclose(length, hub.predict(m.az_front, m.az_rear), atol=3e-7)  # 2nd order: e^2/2c
    # the other sense flips the perpendicular part: clearly wrong here
    e_f_bad, _ = hub.eccentricity_body(m.az_front, m.az_rear, LEVER_FRONT, LEVER_REAR, sense=1)
    assert np.sqrt(np.mean(np.sum((e_f_bad - m.offset_front_body) ** 2, 1))) > 50e-6


def test_correct_refers_prisms_to_hub_axes():
    m = measurements(duration_s=60.0, seed=8)
    hub = _fit(m)
    pf, pr = hub.correct(m.p_front, m.p_rear, m.az_front, m.az_rear)
    for p_meas, p_corr, axis in ((m.p_front, pf, m.axis_front), (m.p_rear, pr, m.axis_rear)):
        before = np.sqrt(np.mean(np.sum((p_meas - axis) ** 2, 1)))
        after = np.sqrt(np.mean(np.sum((p_corr - axis) ** 2, 1)))
        assert after < 0.25 * before
        assert after < 2.5 * m.noise_m  # only the tracker noise (3D: sqrt(3) * 10 um) remains
    corrected_length = np.linalg.norm(pf - pr, axis=1)
    assert np.std(corrected_length) == pytest.approx(hub.rms_after_m, rel=0.1)


def test_nonfinite_samples_are_left_out():
    m = measurements(duration_s=30.0, seed=9)
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    length[::7] = np.nan
    hub = fit_hub_model(m.t, length, m.az_front, m.az_rear)
    assert hub.n == np.isfinite(length).sum()
    assert abs(hub.c_m - m.c_m) < 0.01e-3


def test_plot_hub_model(tmp_path):
    m = measurements(duration_s=10.0, seed=1)
    fig = plot_hub_model(_fit(m), tmp_path / "hub.png")
    assert (tmp_path / "hub.png").stat().st_size > 10_000
    # baseline over time, against the azimuth, the azimuths, and the one legend in a panel of its own
    assert len(fig.axes) == 4
    legend_panel = fig.axes[3]
    assert not legend_panel.axison and len(legend_panel.get_legend().get_texts()) == 5
    assert all(ax.get_legend() is None for ax in fig.axes[:3])  # no legend over the data


# ------------------------------------------------------------------------------- bad inputs

def test_bad_length_mismatch_names_argument():
    m = measurements(duration_s=5.0)
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    with pytest.raises(InputError, match="azimuth_rear"):
        fit_hub_model(m.t, length, m.az_front, m.az_rear[:-3])


def test_bad_constant_azimuth_names_it():
    m = measurements(duration_s=20.0)
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    with pytest.raises(InputError, match="azimuth_front.*vary"):
        fit_hub_model(m.t, length, np.full_like(m.az_front, 0.3), m.az_rear)


def test_bad_azimuths_in_lockstep():
    m = measurements(duration_s=20.0)
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    with pytest.raises(InputError, match="azimuth_rear.*lockstep"):
        fit_hub_model(m.t, length, m.az_front, m.az_front + 0.3)


def test_bad_too_few_samples():
    with pytest.raises(InputError, match="baseline_length_m.*usable"):
        fit_hub_model(np.arange(5.0), np.full(5, 0.77), np.arange(5.0), np.arange(5.0))


def test_bad_sense():
    m = measurements(duration_s=10.0)
    with pytest.raises(InputError, match="sense"):
        _fit(m).eccentricity_body(m.az_front, m.az_rear, LEVER_FRONT, LEVER_REAR, sense=0)


# ------------------------------------------------------------------------ simulated campaign

def test_simulated_campaign_radii_and_phases(small_campaign):
    """On the simulator's bags (4 minutes, nine ~27 s runs): radii within 0.03 mm of truth/."""
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey
    from identification.preprocessing.io_tracker import read_tracker_run
    from identification.preprocessing.sync import azimuth_at, sync_run
    from simulation.truth import read_truth

    truth = read_truth(small_campaign)
    cal = calibrate(read_survey(small_campaign / "calibration.yaml"))
    args, phases = [], []
    for rt in truth.runs:
        raw = read_tracker_run(small_campaign / "runs" / rt.name, rt.name, rt.split)
        sy = sync_run(raw, cal.transform.R_at960_ltd800, cal.transform.t_at960_ltd800, cal.prism_tracker)
        az = azimuth_at(sy.t_utc, raw.t_hub_utc, raw.hub_azimuth)
        ok = sy.both_seen & np.isfinite(az).all(axis=1)
        args.append((sy.s_trigger[ok], sy.baseline_after_m[ok], az[ok, 0], az[ok, 1]))
        phases.append([rt.hubs["front"]["phase_rad"], rt.hubs["rear"]["phase_rad"]])
    joint = fit_hub_model_joint(args)
    r_true = np.array([truth.hubs["front"]["radius_m"], truth.hubs["rear"]["radius_m"]])
    r_h = joint[0].radius_horizontal(cal.lever_arms_body["front"], cal.lever_arms_body["rear"])
    assert np.all(np.abs(r_h - r_true) < 0.03e-3)
    assert abs(joint[0].c_m - truth.baseline_length_m) < 0.01e-3
    for model, phase in zip(joint, phases):
        assert np.all(np.abs(_wrap(model.phase_rad - phase)) < 0.3)
        assert model.rms_after_m < 0.5 * model.rms_before_m
