"""The command line end to end with a recorded IMU and wheel odometry (ROS1 bags): simulate --gnss
--imu --odometry, preprocess (imu.csv / odometry.csv and their counts in its JSON), benchmark --gnss
recorded --config with sensors [gnss, imu, odometry] for sindy_ekf and sindy_graph (scored against
truth), and the one-line errors: --sensors-ros2 alone, a gyro noise of 0, imu asked for without imu.csv."""

from __future__ import annotations

import json

import yaml

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf import cli


def test_imu_and_odometry_through_simulate_preprocess_and_benchmark(tmp_path, capsys):
    camp, traj, model, cfg = tmp_path / "c", tmp_path / "t", tmp_path / "model.json", tmp_path / "f.yaml"
    assert cli.main(["simulate", str(camp), "--seed", "6", "--minutes", "2.25", "--gnss", "rtk", "--imu",
                     "--odometry"]) == 0
    assert (camp / "truth" / "motion_sensors.yaml").is_file()
    assert cli.main(["preprocess", str(camp), "--out", str(traj), "--json", str(tmp_path / "p.json")]) == 0
    sensors = json.loads((tmp_path / "p.json").read_text())["sensors"]
    truth = yaml.safe_load((camp / "truth" / "motion_sensors.yaml").read_text())["runs"]
    for run, t in truth.items():
        assert sensors["imu"][run]["samples"] == t["imu"]["n_samples"]
        assert sensors["odometry"][run]["samples"] == t["odometry"]["n_samples"]
        assert (traj / "runs" / run / "imu.csv").is_file() and (traj / "runs" / run / "odometry.csv").is_file()
    model_from_terms(RobotParams().terms()).to_json(model)
    cfg.write_text("estimators:\n  sindy_ekf:\n    sensors: [gnss, imu, odometry]\n"
                   "  sindy_graph:\n    sensors: [gnss, imu, odometry]\n")
    capsys.readouterr()
    assert cli.main(["benchmark", str(traj), "--model", str(model), "--gnss", "recorded", "--estimators",
                     "sindy_ekf,sindy_graph", "--config", str(cfg), "--json", str(tmp_path / "b.json")]) == 0
    doc = json.loads((tmp_path / "b.json").read_text())
    for name in ("sindy_ekf", "sindy_graph"):
        assert doc["config"]["estimators"][name]["sensors"] == ["gnss", "imu", "odometry"]
        assert doc["estimators"][name]["ate_pos_m"] < 0.05  # rtk: 2 cm fixes
        assert doc["estimators"][name]["status"] == "ok"
    # a gyro in a z-down frame, wheel speeds in rpm: one line naming the file before any filter runs
    import numpy as np

    for name, column, factor, said in (("imu.csv", "wz", -1.0, "column wz runs against the poses' yaw rate"),
                                       ("odometry.csv", "v", 60 / (2 * np.pi), "column v is 10.")):  # rpm: 9.55 x its slip
        files = sorted(traj.glob(f"runs/*/{name}"))
        saved = [f.read_text() for f in files]
        for f in files:
            head, *rows = f.read_text().splitlines()
            k = head.split(",").index(column)
            rows = [",".join(repr(float(v) * factor) if i == k else v for i, v in enumerate(r.split(","))) for r in rows]
            f.write_text("\n".join([head, *rows]) + "\n")
        capsys.readouterr()
        assert cli.main(["benchmark", str(traj), "--model", str(model), "--gnss", "recorded", "--estimators",
                         "sindy_ekf", "--config", str(cfg)]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and f"/{name}: {said}" in err[0], err
        for f, text in zip(files, saved):
            f.write_text(text)
    # the same campaign without imu.csv: an error naming the file
    for p in traj.glob("runs/*/imu.csv"):
        p.unlink()
    capsys.readouterr()
    assert cli.main(["benchmark", str(traj), "--model", str(model), "--gnss", "recorded", "--estimators",
                     "sindy_ekf", "--config", str(cfg)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "imu.csv: missing; sensors: [imu] needs it" in err[0]


def test_bad_flags_and_settings_are_one_line_errors(tmp_path, capsys):
    assert cli.main(["simulate", str(tmp_path / "c"), "--sensors-ros2"]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--sensors-ros2: needs --imu or --odometry" in err[0]
    cfg = tmp_path / "f.yaml"
    cfg.write_text("estimators:\n  sindy_isam2:\n    sensors: [gnss, imu]\n    imu: {rate_std_rad_s: 0}\n")
    assert cli.main(["config", str(cfg)]) != 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "estimators.sindy_isam2.imu.rate_std_rad_s: expected a number > 0, got 0" in err[0]
