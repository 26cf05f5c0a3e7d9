"""``sindy-ekf simulate`` and ``demo``: a working run, and every kind of bad input ending with
exit code 2, one line naming the culprit, and nothing (half-)written."""

from __future__ import annotations

import json
import os

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from simulation import bags as bags_module
from simulation.campaign import simulate_campaign
from sindy_ekf.cli import main


def _listing(folder):
    return sorted(p.name for p in folder.iterdir())


def test_simulate_writes_a_campaign_and_json(tmp_path, capsys):
    out, js = tmp_path / "camp", tmp_path / "sim.json"
    assert main(["simulate", str(out), "--seed", "3", "--minutes", "2.25", "--effect", "heading_dependence=1.5",
                 "--json", str(js), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "9 runs" in printed and "run_09" in printed and "heading_dependence=1.5" in printed
    camp = yaml.safe_load((out / "campaign.yaml").read_text())
    assert "heading_dependence=1.5" in camp["notes"]
    truth = yaml.safe_load((out / "truth" / "truth.yaml").read_text())
    assert truth["effects"] == [{"name": "heading_dependence", "value": 1.5}]
    # the tilted floor (H1's mechanism) reaches the truth states: z follows the slope
    from simulation.truth import read_truth

    st = read_truth(out).runs[5].states
    slope = np.polyfit(st.x, st.z, 1)[0]
    assert slope == pytest.approx(-np.tan(np.radians(1.5)), rel=0.05)
    assert [r["split"] for r in camp["runs"]].count("test") == 3
    assert all(len(list((out / "runs" / r["name"]).glob("*.bag"))) == 2 for r in camp["runs"])
    summary = json.loads(js.read_text())
    assert summary["seed"] == 3 and set(summary["runs"]) == {r["name"] for r in camp["runs"]}
    run1 = summary["runs"]["run_01"]
    counts = bags_module.count_messages(out / "runs" / "run_01")
    assert counts["/at960/measurement"] == run1["at960"]["n_messages"]
    assert counts["/rpi/trigger"] == run1["n_trigger"]
    assert 16.0 < run1["clock"]["ltd800"]["drift_ppm"] < 16.5
    assert _listing(tmp_path) == ["camp", "sim.json"]  # no temporary siblings left


def _fails(argv, capsys, culprit):
    code = main(argv + ["--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2, err
    assert len(err.splitlines()) == 1 and culprit in err, err
    return err


def test_unknown_effect(tmp_path, capsys):
    _fails(["simulate", str(tmp_path / "o"), "--effect", "warp_drive=1", "--minutes", "2.25"], capsys, "warp_drive")
    assert _listing(tmp_path) == []


def test_effect_value_out_of_range(tmp_path, capsys):
    _fails(["simulate", str(tmp_path / "o"), "--effect", "input_delay=5", "--minutes", "2.25"], capsys, "input_delay")
    assert _listing(tmp_path) == []


def test_two_effects_are_refused(tmp_path, capsys):
    _fails(["simulate", str(tmp_path / "o"), "--effect", "input_delay=0.1", "--effect", "deadband=0.1",
            "--minutes", "2.25"], capsys, "deadband")
    assert _listing(tmp_path) == []


def test_minutes_out_of_range(tmp_path, capsys):
    _fails(["simulate", str(tmp_path / "o"), "--minutes", "1"], capsys, "minutes")
    assert _listing(tmp_path) == []


def test_non_empty_output_needs_force_and_is_left_alone(tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "keep.txt").write_text("precious")
    _fails(["simulate", str(out), "--minutes", "2.25"], capsys, str(out))
    assert _listing(out) == ["keep.txt"] and _listing(tmp_path) == ["o"]
    assert main(["simulate", str(out), "--minutes", "2.25", "--force", "--quiet"]) == 0
    assert "keep.txt" not in _listing(out) and "campaign.yaml" in _listing(out)


def test_unwritable_output(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    _fails(["simulate", str(blocker / "o"), "--minutes", "2.25"], capsys, str(blocker / "o"))
    if os.geteuid() != 0:  # root ignores permission bits
        ro = tmp_path / "ro"
        ro.mkdir()
        ro.chmod(0o500)
        try:
            _fails(["simulate", str(ro / "o"), "--minutes", "2.25"], capsys, str(ro / "o"))
        finally:
            ro.chmod(0o700)
    assert _listing(tmp_path) in (["file"], ["file", "ro"])


def test_failure_midway_leaves_nothing(tmp_path, monkeypatch):
    calls = []

    def broken(path, topics):
        calls.append(path)
        if len(calls) == 5:
            raise OSError(28, "No space left on device")
        return real(path, topics)

    real = bags_module.write_bag
    monkeypatch.setattr(bags_module, "write_bag", broken)
    with pytest.raises(InputError, match="No space left"):
        simulate_campaign(tmp_path / "o", seed=0, minutes=2.25)
    assert len(calls) == 5 and _listing(tmp_path) == []


def test_bad_seed(tmp_path):
    with pytest.raises(InputError, match="seed=-1"):
        simulate_campaign(tmp_path / "o", seed=-1, minutes=2.25)


def test_demo_prints_what_the_campaign_holds(tmp_path, capsys):
    out = tmp_path / "demo"
    # `make demo`'s chain on a shorter campaign (2.5 of 8 minutes, the same 9 runs): the default length
    # took 164 s of the suite's 20-minute budget, and `make demo` itself runs it at every landing
    assert main(["demo", "--out", str(out), "--minutes", "2.5", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("run_0") == 9 and "lost" in printed and (out / "truth" / "truth.yaml").is_file()
    # the demo is the README's main job: the whole chain ran and the report is where it says
    report = out / "report" / "report.html"
    assert report.is_file() and f"report written to {report}" in printed
    assert "5 s prediction error" in printed and "sindy_ekf" in printed
    assert "skipping run" not in printed


def test_simulate_command_takes_and_reports_jitter_and_reset(tmp_path, capsys):
    assert main(["simulate", str(tmp_path / "c"), "--minutes", "2.25", "--receive-jitter", "2,12",
                 "--clock-reset", "run_06:at960:0.5", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "receive latency 2-12 ms" in printed
    assert "run_06: at960 clock restarted (topic /at960/measurement, message" in printed
    assert "receive jitter 2-12 ms" in (tmp_path / "c" / "campaign.yaml").read_text()


def test_simulate_a_variant_with_an_effect_form(tmp_path, capsys):
    """``--variant N`` and ``--effect NAME:FORM=VALUE``: truth/ and the JSON say what was drawn."""
    out, js = tmp_path / "camp", tmp_path / "sim.json"
    assert main(["simulate", str(out), "--seed", "2", "--minutes", "2.25", "--variant", "2",
                 "--effect", "deadband:hysteresis=0.2", "--json", str(js), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "deadband:hysteresis=0.2" in printed and "simulator variant 2" in printed
    truth = yaml.safe_load((out / "truth" / "truth.yaml").read_text())
    assert truth["variant"]["index"] == 2 and truth["effects"][0]["form"] == "hysteresis"
    summary = json.loads(js.read_text())
    assert summary["variant"]["index"] == 2 and "motor_lag_s" in summary["variant"]["draws"]


def test_unknown_effect_form_and_bad_variant(tmp_path, capsys):
    _fails(["simulate", str(tmp_path / "o"), "--effect", "deadband:sticky=0.1", "--minutes", "2.25"], capsys, "sticky")
    _fails(["simulate", str(tmp_path / "o"), "--variant", "-3", "--minutes", "2.25"], capsys, "variant=-3")
    assert not (tmp_path / "o").exists()
