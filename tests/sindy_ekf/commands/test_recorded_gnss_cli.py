"""The command line end to end through ROS2 GNSS bags: simulate --gnss --gnss-ros2, preprocess
(gnss.csv and the dropped fixes in its JSON, as truth/gnss.yaml counts them), benchmark --gnss
recorded (scores against truth); bad flags are one-line errors."""

from __future__ import annotations

import json

import yaml

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf import cli


def test_ros2_gnss_through_simulate_preprocess_and_benchmark(tmp_path, capsys):
    camp, traj, model = tmp_path / "c", tmp_path / "t", tmp_path / "model.json"
    assert cli.main(["simulate", str(camp), "--seed", "4", "--minutes", "2.25", "--gnss", "rtk", "--gnss-ros2"]) == 0
    bags = sorted(p.name for p in (camp / "runs" / "run_01").iterdir())
    assert bags[0].startswith("gnss_") and (camp / "runs" / "run_01" / bags[0] / "metadata.yaml").is_file()
    assert cli.main(["preprocess", str(camp), "--out", str(traj), "--json", str(tmp_path / "p.json")]) == 0
    counts = json.loads((tmp_path / "p.json").read_text())["sensors"]["gnss"]
    truth = yaml.safe_load((camp / "truth" / "gnss.yaml").read_text())["runs"]
    for run, t in truth.items():
        assert (counts[run]["no_fix_dropped"], counts[run]["nan_dropped"]) == (t["n_no_fix"], t["n_nan"])
        assert (traj / "runs" / run / "gnss.csv").is_file()
    model_from_terms(RobotParams().terms()).to_json(model)
    capsys.readouterr()
    assert cli.main(["benchmark", str(traj), "--model", str(model), "--gnss", "recorded", "--estimators",
                     "sindy_ekf,cv_ekf", "--json", str(tmp_path / "b.json")]) == 0
    out = capsys.readouterr().out
    assert "GNSS recorded" in out and "recorded GNSS: ENU -> local yaw" in out
    doc = json.loads((tmp_path / "b.json").read_text())
    scores, rec = doc["estimators"], doc["recorded_gnss"]
    true_yaw = yaml.safe_load((camp / "truth" / "gnss.yaml").read_text())["enu_to_local_yaw_deg"]
    assert abs(rec["enu_to_local"]["enu_to_local_yaw_deg"] - true_yaw) < 4 * rec["enu_to_local"]["yaw_std_deg"]
    assert scores["sindy_ekf"]["ate_pos_m"] < 0.05  # rtk: 2 cm fixes
    assert scores["cv_ekf"]["ate_pos_m"] > scores["sindy_ekf"]["ate_pos_m"]


def test_gnss_ros2_without_a_profile_is_one_line_error(tmp_path, capsys):
    assert cli.main(["simulate", str(tmp_path / "c"), "--gnss-ros2"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--gnss-ros2: needs --gnss PROFILE" in err[0]
