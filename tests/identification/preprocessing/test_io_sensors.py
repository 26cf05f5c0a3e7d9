"""Recorded sensors in preprocessing: declared sensors read by name and type (an unknown type is a
one-line error before any work), NavSatFix fixes written to gnss.csv with NO_FIX and NaN fixes
dropped and counted as truth/gnss.yaml says, gnss.csv read in both forms, no overlap an error."""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from identification.preprocessing.io_sensors import (
    GNSS_CSV,
    GnssFixes,
    clean_fixes,
    overlapping,
    read_gnss_csv,
    read_sensors_config,
    write_gnss_csv,
)
from identification.preprocessing.preprocess import preprocess_campaign
from tests.support.gnss_campaign import gnss_campaign


@pytest.fixture(scope="module")
def camp(tmp_path_factory):
    return gnss_campaign(tmp_path_factory)


def test_gnss_csv_per_run_with_dropped_fixes_counted_as_simulated(camp):
    g = yaml.safe_load((camp.tracker / "truth" / "gnss.yaml").read_text())
    counts = camp.preprocessed.to_json_dict()["sensors"]["gnss"]
    assert set(counts) == set(g["runs"])
    for run, true in g["runs"].items():
        c = counts[run]
        assert (c["fixes"], c["no_fix_dropped"], c["nan_dropped"]) == (true["n_fixes"], true["n_no_fix"],
                                                                       true["n_nan"])
        f = read_gnss_csv(camp.trajectory / "runs" / run / GNSS_CSV)
        assert len(f.t) == c["written"] <= true["n_fixes"] - true["n_no_fix"] - true["n_nan"]
        assert np.all(f.status == 0) and np.all(np.isfinite(f.lla)) and np.all(np.diff(f.t) > 0)
        poses = np.loadtxt(camp.trajectory / "runs" / run / "poses.csv", delimiter=",", skiprows=1, usecols=0)
        assert poses.min() <= f.t.min() and f.t.max() <= poses.max()
    meta = yaml.safe_load((camp.trajectory / "campaign.yaml").read_text())
    assert meta["sensors"][0]["type"] == "sensor_msgs/NavSatFix" and meta["geodetic_origin"] == g["origin"]


def test_a_campaign_without_the_topic_gets_no_gnss_file(small_trajectory):
    assert not list(small_trajectory.glob("runs/*/gnss.csv"))
    assert "sensors" not in yaml.safe_load((small_trajectory / "campaign.yaml").read_text())


def _yaml(tmp_path, sensors, **more):
    (tmp_path / "campaign.yaml").write_text(yaml.safe_dump({"name": "c", "runs": [{"name": "r", "split": "train"}],
                                                            "sensors": sensors, **more}))
    return tmp_path


def test_sensors_declared_by_name_and_type(tmp_path):
    cfg = read_sensors_config(_yaml(tmp_path, {"gnss": "/gps/fix", "imu": "/imu/data"}, vendor_key=3))
    assert [(s.name, s.topic, s.kind) for s in cfg.sensors] == [("gnss", "/gps/fix", "gnss"), ("imu", "/imu/data", "imu")]
    cfg = read_sensors_config(_yaml(tmp_path, [{"name": "ant", "topic": "/fix", "type": "sensor_msgs/NavSatFix",
                                                "lever_arm_body_m": [0.1, 0.2, 0.3], "rate": 5}],
                                    geodetic_origin={"lat_deg": 48.0, "lon_deg": 16.0, "alt_m": 200.0},
                                    enu_to_local_yaw_deg=12.5))
    assert cfg.first("gnss").lever_arm_body_m == (0.1, 0.2, 0.3) and cfg.enu_to_local_yaw_deg == 12.5
    assert cfg.origin.lat_deg == 48.0 and read_sensors_config(tmp_path / "nowhere").sensors == ()


def test_unknown_sensor_type_is_one_line_error_before_the_work(tmp_path):
    _yaml(tmp_path, [{"name": "lidar", "topic": "/points", "type": "sensor_msgs/PointCloud2"}])
    with pytest.raises(InputError, match="sensor 'lidar': unknown type 'sensor_msgs/PointCloud2'") as err:
        read_sensors_config(tmp_path)
    assert "\n" not in str(err.value)
    # preprocess stops on it before reading the survey (there is none here) or a bag
    with pytest.raises(InputError, match="unknown type 'sensor_msgs/PointCloud2'"):
        preprocess_campaign(tmp_path, tmp_path / "out")
    with pytest.raises(InputError, match="lever_arm_body_m must be 3 finite numbers"):
        read_sensors_config(_yaml(tmp_path, [{"name": "gnss", "lever_arm_body_m": [1, 2]}]))


def test_unknown_sensor_type_stops_preprocessing_of_a_whole_campaign(camp, tmp_path):
    root = tmp_path / "c"
    shutil.copytree(camp.tracker, root, ignore=shutil.ignore_patterns("*.bag", "truth"))
    doc = yaml.safe_load((root / "campaign.yaml").read_text())
    doc["sensors"][0]["type"] = "sensor_msgs/NavSatFixed"
    (root / "campaign.yaml").write_text(yaml.safe_dump(doc))
    with pytest.raises(InputError, match="sensor 'gnss': unknown type 'sensor_msgs/NavSatFixed'"):
        preprocess_campaign(root, tmp_path / "out")


def test_gnss_csv_in_std_form_and_the_drop_rule_by_hand(tmp_path):
    path = tmp_path / GNSS_CSV
    path.write_text("t,lat,lon,alt,std_e,std_n,std_u,status,extra\n"
                    "10.0,48.1,16.3,200.0,0.5,0.4,1.0,0,x\n"
                    "10.2,48.1,16.3,200.0,0.5,0.4,1.0,-1,x\n"
                    "10.4,nan,16.3,200.0,0.5,0.4,1.0,0,x\n"
                    "10.6,48.1,16.3,200.0,0.5,0.4,1.0,2,x\n"
                    "10.6,48.1,16.3,200.0,0.5,0.4,1.0,2,x\n")
    f = read_gnss_csv(path)
    np.testing.assert_allclose(f.cov_enu[0], np.diag([0.25, 0.16, 1.0]))
    kept, counts = clean_fixes(f, str(path))
    assert counts == {"fixes": 5, "no_fix_dropped": 1, "nan_dropped": 1, "duplicates_dropped": 1,
                      "unstamped_receive_time": 0}
    np.testing.assert_allclose(kept.t, [10.0, 10.6])
    np.testing.assert_allclose(kept.t_arrival, kept.t)  # no t_arrival column: received when valid
    path.write_text("t,lat,lon,alt\n1,2,3,4\n")
    with pytest.raises(InputError, match="needs columns cov_ee"):
        read_gnss_csv(path)
    path.write_text("t,lat,alt,std_e,std_n,std_u\n1,2,3,4,5,6\n")
    with pytest.raises(InputError, match=f"{GNSS_CSV}: required column 'lon' missing"):
        read_gnss_csv(path)


def test_gnss_csv_round_trip_keeps_full_covariance(tmp_path):
    cov = np.array([[[0.09, 0.01, 0.002], [0.01, 0.08, 0.003], [0.002, 0.003, 0.36]]] * 2)
    f = GnssFixes(np.array([1.5, 1.7]), np.array([1.6, 1.8]), np.array([[48.0, 16.0, 200.0], [48.1, 16.1, 201.5]]),
                  cov, np.array([0, 2]))
    g = read_gnss_csv(write_gnss_csv(tmp_path / GNSS_CSV, f))
    for a, b in zip((f.t, f.t_arrival, f.lla, f.cov_enu, f.status), (g.t, g.t_arrival, g.lla, g.cov_enu, g.status)):
        np.testing.assert_allclose(b, a, rtol=1e-9, atol=1e-9)


def test_no_overlap_with_the_poses_names_the_file():
    f = GnssFixes(np.array([1.0, 2.0]), np.array([1.0, 2.0]), np.zeros((2, 3)), np.zeros((2, 3, 3)), np.zeros(2, int))
    assert len(overlapping(f, np.array([1.5, 3.0]), "x/gnss.csv").t) == 1
    with pytest.raises(InputError, match=r"runs/r/gnss.csv: no GNSS fix inside the poses' time span"):
        overlapping(f, np.array([5.0, 9.0]), "runs/r/gnss.csv")


def test_gnss_under_its_default_name_is_read_without_a_declaration(camp, tmp_path):
    # data contract part 1: /gnss/fix is the optional topic's default name, to be used where a run
    # has it; the same bags without the sensors: key give the same gnss.csv as with it
    from identification.preprocessing.io_sensors import write_run_gnss
    root = tmp_path / "c"
    root.mkdir()
    (root / "runs").symlink_to(camp.tracker / "runs")
    doc = yaml.safe_load((camp.tracker / "campaign.yaml").read_text())
    assert doc.pop("sensors")[0]["topic"] == "/gnss/fix"
    (root / "campaign.yaml").write_text(yaml.safe_dump(doc))
    run = sorted(p.name for p in (camp.trajectory / "runs").iterdir())[0]
    t_pose = np.loadtxt(camp.trajectory / "runs" / run / "poses.csv", delimiter=",", skiprows=1, usecols=0)
    out = tmp_path / "out"
    (out / "runs" / run).mkdir(parents=True)
    counts = write_run_gnss(root, out, {run: t_pose})
    assert counts[run] == camp.preprocessed.to_json_dict()["sensors"]["gnss"][run]
    assert (out / "runs" / run / GNSS_CSV).read_text() == (camp.trajectory / "runs" / run / GNSS_CSV).read_text()


def test_a_gnss_csv_with_a_byte_order_mark_reads_as_without(camp, tmp_path):
    run = sorted(p.name for p in (camp.trajectory / "runs").iterdir())[0]
    src = camp.trajectory / "runs" / run / GNSS_CSV
    bom = tmp_path / GNSS_CSV
    bom.write_text("\ufeff" + src.read_text())
    a, b = read_gnss_csv(src), read_gnss_csv(bom)
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.lla, b.lla)


def test_gnss_fixes_whose_header_stamp_was_never_set_take_their_bag_time(tmp_path):
    # a NavSatFix bag written with rosbags directly: fixes 1 and 3 of 5 never stamped (zero)
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    from identification.preprocessing.io_sensors import clean_fixes, read_navsat

    ts = get_typestore(Stores.ROS1_NOETIC)
    NF, H, T, ST = (ts.types[k] for k in ("sensor_msgs/msg/NavSatFix", "std_msgs/msg/Header",
                                          "builtin_interfaces/msg/Time", "sensor_msgs/msg/NavSatStatus"))
    t = 1.7e9 + np.arange(5) * 1.0
    with Writer(tmp_path / "g.bag") as w:
        c = w.add_connection("/gnss/fix", NF.__msgtype__, typestore=ts)
        for i, ti in enumerate(t):
            ns = int(round(ti * 1e9)) - 100_000_000  # stamped 0.1 s before it was received
            hs = 0 if i in (1, 3) else ns
            msg = NF(header=H(seq=i, stamp=T(sec=hs // 10**9, nanosec=hs % 10**9), frame_id="gps"),
                     status=ST(status=0, service=1), latitude=48.2, longitude=16.37, altitude=200.0,
                     position_covariance=np.eye(3).ravel() * 0.04, position_covariance_type=2)
            w.write(c, int(round(ti * 1e9)), ts.serialize_ros1(msg, NF.__msgtype__))
    fixes, counts = clean_fixes(read_navsat([tmp_path / "g.bag"], "/gnss/fix", "run_01"), "run_01")
    np.testing.assert_allclose(fixes.t, t - np.array([0.1, 0, 0.1, 0, 0.1]), rtol=0, atol=1e-6)
    assert counts["unstamped_receive_time"] == 2 and counts["fixes"] == 5


def test_a_gnss_csv_with_date_times_in_t_is_named(tmp_path):
    from identification.preprocessing.io_sensors import read_gnss_csv

    path = tmp_path / "gnss.csv"
    path.write_text("t,lat,lon,alt,std_e,std_n,std_u\n"
                    "2024-07-29T18:45:51.2Z,48.1,16.3,200.0,0.5,0.4,1.0\n2024-07-29T18:45:52.2Z,48.1,16.3,200.0,0.5,0.4,1.0\n")
    with pytest.raises(InputError, match=r"gnss.csv: column t holds no numbers \(first value '2024-07-29T18:45:51.2Z'\); a date"):
        read_gnss_csv(path)


def test_a_gnss_csv_with_quoted_column_names_reads_as_without(tmp_path):
    # R's write.csv quotes every column name
    from identification.preprocessing.io_sensors import read_gnss_csv

    body = "10.0,48.1,16.3,200.0,0.5,0.4,1.0\n11.0,48.1,16.3,200.0,0.5,0.4,1.0\n"
    (tmp_path / "a.csv").write_text("t,lat,lon,alt,std_e,std_n,std_u\n" + body)
    (tmp_path / "b.csv").write_text('"t","lat","lon","alt","std_e","std_n","std_u"\n' + body)
    a, b = read_gnss_csv(tmp_path / "a.csv"), read_gnss_csv(tmp_path / "b.csv")
    np.testing.assert_array_equal(a.t, b.t)
    np.testing.assert_array_equal(a.lla, b.lla)
    np.testing.assert_array_equal(a.cov_enu, b.cov_enu)
