"""A campaign of test runs only, scored with a model identified elsewhere (INTERFACES.md: evaluate,
benchmark and diagnose score "of the same campaign or of another one given a model trained
elsewhere"): ``--train CAMPAIGN`` fits the baselines and the process noise on another campaign's
train runs. Checked against the same test run scored inside the campaign it came from."""

from __future__ import annotations

import json
import shutil

import pytest
import yaml

from identification.sindy.model import model_from_terms
from simulation.robot import RobotParams
from sindy_ekf.cli import main
from tests.support.trajectory_synth import write_mini_campaign

RUNS = (("run_a", 20.0, "train"), ("run_b", 20.0, "train"), ("run_c", 25.0, "test"))


@pytest.fixture(scope="module")
def camps(tmp_path_factory):
    """The campaign A (two train runs, one test run), B (A's test run alone) and the true model's file."""
    tmp = tmp_path_factory.mktemp("train_elsewhere")
    a = write_mini_campaign(tmp / "a", runs=RUNS)
    b = shutil.copytree(a, tmp / "b")
    meta = yaml.safe_load((b / "campaign.yaml").read_text())
    meta["runs"] = [r for r in meta["runs"] if r["split"] == "test"]
    (b / "campaign.yaml").write_text(yaml.safe_dump(meta))
    for name in ("run_a", "run_b"):
        shutil.rmtree(b / "runs" / name)
    return a, b, model_from_terms(RobotParams().terms()).to_json(tmp / "model.json")


def test_evaluate_with_train_elsewhere_scores_the_baselines_as_inside_their_campaign(camps, tmp_path, caplog):
    a, b, model = camps
    ja, jb, jn = tmp_path / "a.json", tmp_path / "b.json", tmp_path / "n.json"
    assert main(["evaluate", str(a), "--model", str(model), "--json", str(ja), "--quiet"]) == 0
    assert main(["evaluate", str(b), "--model", str(model), "--train", str(a), "--json", str(jb), "--quiet"]) == 0
    da, db = json.loads(ja.read_text()), json.loads(jb.read_text())
    assert set(db["baselines"]) == set(da["baselines"]) >= {"lag", "unicycle"}
    for name in ("lag", "unicycle"):
        assert db["baselines"][name]["pos_err_5s_m"] == da["baselines"][name]["pos_err_5s_m"]
    assert db["pos_err_5s_m"] == da["pos_err_5s_m"]
    # without it the baselines that need train runs are left out, and said so
    assert main(["evaluate", str(b), "--model", str(model), "--json", str(jn)]) == 0
    assert "lag" not in json.loads(jn.read_text())["baselines"]
    assert "no train run to fit the unicycle and lag baselines on: they are left out (give --train" in caplog.text


def test_benchmark_with_train_elsewhere_equals_the_benchmark_inside_the_campaign(camps, tmp_path, capsys):
    a, b, model = camps
    ja, jb = tmp_path / "a.json", tmp_path / "b.json"
    flags = ["--model", str(model), "--estimators", "lag_ekf,sindy_ekf", "--quiet"]
    assert main(["benchmark", str(a), *flags, "--json", str(ja)]) == 0
    assert main(["benchmark", str(b), *flags, "--train", str(a), "--json", str(jb)]) == 0
    ea, eb = json.loads(ja.read_text())["estimators"], json.loads(jb.read_text())["estimators"]
    for name in ("lag_ekf", "sindy_ekf"):
        assert eb[name]["ate_pos_m"] == ea[name]["ate_pos_m"] and eb[name]["nees_mean"] == ea[name]["nees_mean"]
    capsys.readouterr()
    assert main(["benchmark", str(b), *flags]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "no run marked train to fit process noise on (give --train CAMPAIGN" in err
    assert main(["benchmark", str(b), *flags, "--train", str(b)]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "campaign.yaml marks no run as train (--train needs runs to fit on)" in err


def test_diagnose_and_the_report_chain_with_train_elsewhere_as_inside_the_campaign(camps, tmp_path, capsys):
    from sindy_ekf.stages.chain import run_chain
    a, b, model = camps
    ja, jb = tmp_path / "a.json", tmp_path / "b.json"
    assert main(["diagnose", str(a), "--model", str(model), "--no-ekf", "--json", str(ja), "--quiet"]) == 0
    assert main(["diagnose", str(b), "--model", str(model), "--no-ekf", "--train", str(a), "--json", str(jb),
                 "--quiet"]) == 0
    ca, cb = json.loads(ja.read_text())["causes"], json.loads(jb.read_text())["causes"]
    assert [c["name"] for c in cb] == [c["name"] for c in ca]
    assert [c["pos_err_5s_m"] for c in cb] == [c["pos_err_5s_m"] for c in ca]
    capsys.readouterr()
    assert main(["diagnose", str(b), "--model", str(model), "--no-ekf", "--quiet"]) == 2
    assert "nothing to fit a mechanism on (give --train CAMPAIGN" in capsys.readouterr().err
    inside = run_chain(a, model=model, stages=("identification", "evaluation"))
    elsewhere = run_chain(b, model=model, stages=("identification", "evaluation"), train=a)
    assert not elsewhere.errors and elsewhere.evaluation["lag"].pos_err_5s_m == inside.evaluation["lag"].pos_err_5s_m
