"""Recorded GNSS of the simulator: only its own bag and declaration added to the campaign; its
fixes, decoded by rosbags and pymap3d directly, are the true antenna positions within the
profile's noise; spoilt fixes as truth/gnss.yaml counts them; ROS1 and ROS2 alike."""

from __future__ import annotations

import numpy as np
import pymap3d
import pytest
import yaml
from rosbags.highlevel import AnyReader
from rosbags.typesys import Stores, get_typestore

from groundfloor.errors import InputError
from identification.preprocessing.io_sensors import read_navsat
from simulation.gnss import PROFILES
from simulation.gnss_topic import GnssTopicSpec, check_gnss_spec, record_fixes, write_gnss_bag
from simulation.truth import read_truth
from tests.support.gnss_campaign import gnss_campaign


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    return gnss_campaign(tmp_path_factory)


def test_only_the_gnss_bag_and_its_declaration_are_added(camp, small_campaign):
    for run_dir in sorted((small_campaign / "runs").iterdir()):
        twin = {p.name: p.read_bytes() for p in run_dir.iterdir()}
        ours = {p.name: p.read_bytes() for p in (camp.tracker / "runs" / run_dir.name).iterdir()}
        added = set(ours) - set(twin)
        assert len(added) == 1 and next(iter(added)).startswith("gnss_") and set(twin) <= set(ours)
        assert all(ours[k] == v for k, v in twin.items())  # the tracker bags keep their bytes
    for name in ("calibration.yaml", "truth/truth.yaml"):
        assert (camp.tracker / name).read_bytes() == (small_campaign / name).read_bytes()
    ours = yaml.safe_load((camp.tracker / "campaign.yaml").read_text())
    assert ours.pop("sensors") == [{"name": "gnss", "topic": "/gnss/fix", "type": "sensor_msgs/NavSatFix",
                                    "lever_arm_body_m": [-0.2, 0.1, 0.5]}]
    ours.pop("geodetic_origin")
    assert ours == yaml.safe_load((small_campaign / "campaign.yaml").read_text())


def _decoded(run_dir):
    rows = []
    bags = sorted(run_dir.glob("gnss_*"))
    with AnyReader(bags, default_typestore=get_typestore(Stores.ROS1_NOETIC)) as reader:
        for conn, t_bag, raw in reader.messages():
            m = reader.deserialize(raw, conn.msgtype)
            rows.append([m.header.stamp.sec + m.header.stamp.nanosec * 1e-9, t_bag * 1e-9, m.latitude, m.longitude,
                         m.altitude, m.status.status, *m.position_covariance[[0, 4, 8]]])
    return np.array(rows)


def test_fixes_are_the_true_antenna_within_the_profile_noise(camp):
    truth = read_truth(camp.tracker)
    g = yaml.safe_load((camp.tracker / "truth" / "gnss.yaml").read_text())
    o, yaw, lever = g["origin"], np.radians(g["enu_to_local_yaw_deg"]), np.array(g["lever_arm_body_m"])
    prof = PROFILES["dgnss"]
    norms, n_fix = [], 0
    for r in truth.runs:
        a = _decoded(camp.tracker / "runs" / r.name)
        n_fix += len(a)
        assert np.sum(a[:, 5] == -1) == g["runs"][r.name]["n_no_fix"] >= 1
        assert np.sum(np.isnan(a[:, 2]) & (a[:, 5] == 0)) == g["runs"][r.name]["n_nan"] >= 1
        np.testing.assert_allclose(a[:, 6:], np.tile([prof.std_m ** 2, prof.std_m ** 2, prof.std_up_m ** 2],
                                                     (len(a), 1)))
        assert np.all(a[:, 1] - a[:, 0] >= prof.latency_s - 1e-6)  # received after validity
        np.testing.assert_allclose(np.diff(a[:, 0]), 1.0 / prof.rate_hz, atol=2e-6)
        ok = (a[:, 5] == 0) & np.isfinite(a[:, 2])
        e, n, u = pymap3d.geodetic2enu(a[ok, 2], a[ok, 3], a[ok, 4], o["lat_deg"], o["lon_deg"], o["alt_m"])
        c, s = np.cos(yaw), np.sin(yaw)
        local = np.column_stack([c * e - s * n, s * e + c * n, u])
        st = r.states
        t = st.t_utc_ns * 1e-9
        psi = np.interp(a[ok, 0], t, st.psi)
        true = np.column_stack([np.interp(a[ok, 0], t, st.x) + np.cos(psi) * lever[0] - np.sin(psi) * lever[1],
                                np.interp(a[ok, 0], t, st.y) + np.sin(psi) * lever[0] + np.cos(psi) * lever[1],
                                np.interp(a[ok, 0], t, st.z) + lever[2]])
        norms.append((local - true) / [prof.std_m, prof.std_m, prof.std_up_m])
    norms = np.concatenate(norms)
    assert n_fix == sum(v["n_fixes"] for v in g["runs"].values())
    inliers = np.abs(norms[:, :2]).max(1) < 5  # multipath outliers are metres off
    assert inliers.mean() > 0.97
    np.testing.assert_allclose(norms[inliers].std(0), 1.0, atol=0.1)
    np.testing.assert_allclose(norms[inliers].mean(0), 0.0, atol=0.1)


def test_ros2_bag_holds_the_same_fixes_as_ros1(tmp_path):
    t = 1_671_615_000_000_000_000 + np.arange(0, 20_000_000_000, 20_000_000)
    x = np.linspace(0, 10, t.size)
    fixes = record_fixes(t, x, 0.5 * x, np.zeros_like(x), np.full(t.size, 0.3), GnssTopicSpec(), seed=4)
    one = read_navsat([write_gnss_bag(tmp_path / "a.bag", fixes)], "/gnss/fix", "r")
    two = read_navsat([write_gnss_bag(tmp_path / "b", fixes, ros2=True)], "/gnss/fix", "r")
    for f in (one, two):
        np.testing.assert_array_equal(f.lla, fixes.lla)
        np.testing.assert_array_equal(f.status, fixes.status)
        np.testing.assert_allclose(f.t, fixes.t_valid_ns * 1e-9, atol=1e-6, rtol=0)
        np.testing.assert_allclose(f.t_arrival, fixes.t_arrival_ns * 1e-9, atol=1e-6, rtol=0)
        np.testing.assert_array_equal(f.cov_enu.reshape(-1, 9), fixes.cov_enu)


def test_unknown_profile_is_one_line_error():
    assert check_gnss_spec(None) is None and check_gnss_spec("rtk").profile == "rtk"
    with pytest.raises(InputError, match="gnss 'gps5': unknown GNSS profile"):
        check_gnss_spec("gps5")
