"""``sindy-ekf config`` and ``benchmark --config`` (issue 16 item 3): the defaults printed are the
shipped file, a benchmark with them equals one without, the command line wins over the file, and
a bad file ends in one line on stderr, exit 2 and no output written."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import yaml

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf.cli import main
from sindy_ekf.config import config_from_dict, load_config
from tests.support.trajectory_synth import write_mini_campaign

SHIPPED = Path(__file__).resolve().parents[3] / "sindy_ekf" / "data" / "filters.yaml"
SHORT_RUNS = (("run_a", 20.0, "train"), ("run_b", 20.0, "train"), ("run_c", 25.0, "test"))
FAST = "dead_reckoning,cv_ekf,sindy_ekf,sindy_ekf_lateral"


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    """A short trajectory campaign of the simulator and the true model's file."""
    tmp = tmp_path_factory.mktemp("config_cli")
    root = write_mini_campaign(tmp / "mini", runs=SHORT_RUNS)
    return root, model_from_terms(RobotParams().terms()).to_json(tmp / "model.json")


def _without_runtimes(doc: dict) -> dict:
    for row in doc["estimators"].values():
        row.pop("runtime_s")
        row.pop("realtime_factor")
    return doc


def test_config_defaults_prints_the_shipped_file(capsys):
    assert main(["config", "--defaults"]) == 0
    assert capsys.readouterr().out == SHIPPED.read_text()


def test_config_file_prints_the_merged_settings_as_a_settings_file(tmp_path, capsys):
    path = tmp_path / "f.yaml"
    path.write_text("estimators:\n  cv_ekf:\n    gate_prob: 0.99\n")
    assert main(["config", str(path)]) == 0
    printed = yaml.safe_load(capsys.readouterr().out)
    assert config_from_dict(printed, "printed").to_dict() == load_config(path).to_dict()
    assert printed["estimators"]["cv_ekf"]["gate_prob"] == 0.99


def test_benchmark_with_the_printed_defaults_equals_without(small, tmp_path, capsys):
    root, model = small
    assert main(["config", "--defaults"]) == 0
    defaults = tmp_path / "filters.yaml"
    defaults.write_text(capsys.readouterr().out)
    args = ["benchmark", str(root), "--model", str(model), "--estimators", FAST, "--quiet"]
    assert main([*args, "--json", str(tmp_path / "plain.json")]) == 0
    assert main([*args, "--config", str(defaults), "--json", str(tmp_path / "cfg.json")]) == 0
    plain = json.loads((tmp_path / "plain.json").read_text())
    with_file = json.loads((tmp_path / "cfg.json").read_text())
    assert _without_runtimes(plain) == _without_runtimes(with_file)
    assert plain["config"]["gnss"] == load_config().to_dict()["gnss"]


def test_the_command_line_wins_over_the_file(small, tmp_path, capsys):
    root, model = small
    path = tmp_path / "f.yaml"
    path.write_text("gnss: {profile: standalone, seed: 5}\n"
                    "estimators:\n  sindy_ekf: {enabled: false}\n  cv_ekf: {gate_prob: 0.9}\n")
    out = tmp_path / "b.json"
    assert main(["benchmark", str(root), "--model", str(model), "--config", str(path), "--gnss", "rtk",
                 "--seed", "2", "--estimators", "cv_ekf,sindy_ekf", "--json", str(out), "--quiet"]) == 0
    doc = json.loads(out.read_text())
    assert doc["profile"] == "rtk" and set(doc["estimators"]) == {"cv_ekf", "sindy_ekf"}
    cfg = doc["config"]
    assert cfg["gnss"]["profile"] == "rtk" and cfg["gnss"]["seed"] == 2
    assert cfg["estimators"]["cv_ekf"]["gate_prob"] == 0.9  # the file, where the command line is silent
    assert "GNSS rtk" in capsys.readouterr().out


BAD = [  # (file text or None for a missing file, what the message must name)
    ("estimators:\n  sindy_ekf:\n    gate_prob: high\n", "estimators.sindy_ekf.gate_prob"),
    ("estimators:\n  sindy_ekf:\n    gating: 0.9\n", "estimators.sindy_ekf.gating"),
    ("estimators:\n  sindy_ekf:\n    sensors: [gnss, lidar]\n", "estimators.sindy_ekf.sensors"),  # imu is a sensor now
    ("gnss:\n  profile: galileo\n", "gnss.profile"),
    ("gnss: [\n", "not valid YAML"),
    (None, "not found"),
]


@pytest.mark.parametrize("command", ["benchmark", "report"])
@pytest.mark.parametrize("text, key", BAD, ids=[b[1] for b in BAD])
def test_a_bad_config_is_one_line_and_no_output(small, tmp_path, capsys, command, text, key):
    root, model = small
    path = tmp_path / "bad_filters.yaml"
    if text is not None:
        path.write_text(text)
    out, js = tmp_path / "out", tmp_path / "r.json"
    code = main([command, str(root), "--model", str(model), "--config", str(path), "--out", str(out),
                 "--json", str(js), "--quiet"])
    captured = capsys.readouterr()
    err = captured.err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert err.startswith(f"sindy-ekf {command}: error: {path}: ") and key in err, err
    assert not out.exists() and not js.exists() and captured.out == ""


def test_config_of_a_bad_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "f.yaml"
    path.write_text("estimators:\n  sindy_graph:\n    gate_prob: 0.9\n")
    assert main(["config", str(path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err == (f"sindy-ekf config: error: {path}: estimators.sindy_graph.gate_prob: unknown key "
                   "(sindy_graph takes enabled, process_noise, initial_std, lateral, sensors, imu, odometry)")
