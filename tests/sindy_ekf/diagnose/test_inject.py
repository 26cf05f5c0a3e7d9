"""``inject``: effects hidden in a real campaign's recorded inputs (issue 15, item 3).

Independent references: the recorded inputs checked against numbers computed by hand from the
issue's definitions (stamps earlier by d, inverse deadband, steering minus a x throttle, inputs
divided by the decay), and against forward mechanisms written here from the same definitions
(not the diagnosis's families); the poses against the source files byte for byte.
"""

from __future__ import annotations

import filecmp
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from groundfloor.types import InputSeries
from identification.preprocessing.trajectory import read_trajectory_campaign
from sindy_ekf import cli
from sindy_ekf.diagnose.inject import inject_campaign, injected_path, parse_effect, read_injected, recorded_inputs

WHEELS = "warthog-drive-wheels"


@pytest.fixture(scope="module")
def wheels(shared_dir) -> Path:
    return shared_dir / "data" / WHEELS


def _series(t, u1, u2) -> InputSeries:
    return InputSeries(t=np.asarray(t, float), u1=np.asarray(u1, float), u2=np.asarray(u2, float))


def test_recorded_inputs_by_hand():
    s = _series([10.0, 10.5, 310.0], [0.5, -0.25, 0.0], [0.0, 0.4, -0.8])
    d = recorded_inputs(s, "input_delay", 0.15, 10.0)
    np.testing.assert_allclose(d.t, [9.85, 10.35, 309.85])
    np.testing.assert_array_equal(d.u1, s.u1)
    db = recorded_inputs(s, "deadband", 0.2, 10.0)  # sign(u) (0.2 + 0.8 |u|), 0 stays 0
    np.testing.assert_allclose(db.u1, [0.6, -0.4, 0.0])
    np.testing.assert_allclose(db.u2, [0.0, 0.52, -0.84])
    a = recorded_inputs(s, "asymmetry", 0.1, 10.0)  # u2 - 0.1 u1
    np.testing.assert_allclose(a.u2, [-0.05, 0.425, -0.8])
    np.testing.assert_array_equal(a.u1, s.u1)
    g = recorded_inputs(s, "time_dependence", 0.4, 10.0)  # gain 1, 1 - 0.4 * 0.5/600, 0.8 at 300 s
    np.testing.assert_allclose(g.u1, [0.5, -0.25 / (1 - 0.4 * 0.5 / 600), 0.0])
    np.testing.assert_allclose(g.u2[2], -0.8 / 0.8)


def test_forward_mechanisms_give_back_the_real_inputs():
    """A robot with the mechanism, driven by the recorded inputs, sees what was really driven."""
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.04, 0.06, 400)) + 100.0
    u1, u2 = rng.uniform(-0.9, 0.9, (2, 400))
    s = _series(t, u1, u2)
    v = 0.12
    rec = recorded_inputs(s, "deadband", v, t[0]).u1
    np.testing.assert_allclose(np.sign(rec) * np.maximum(np.abs(rec) - v, 0) / (1 - v), u1, atol=1e-12)
    rec = recorded_inputs(s, "asymmetry", 0.07, t[0])
    np.testing.assert_allclose(rec.u2 + 0.07 * rec.u1, u2, atol=1e-12)
    rec = recorded_inputs(s, "time_dependence", 0.5, t[0])
    np.testing.assert_allclose(rec.u2 * (1 - 0.5 * (t - t[0]) / 600), u2, atol=1e-12)
    rec = recorded_inputs(s, "input_delay", 0.2, t[0])  # motors see u_rec(t - 0.2)
    np.testing.assert_allclose(np.interp(t[50:] - 0.2, rec.t, rec.u1), u1[50:], atol=1e-12)


def test_inject_rewrites_inputs_only(wheels, tmp_path):
    out = inject_campaign(wheels, tmp_path / "asym", "asymmetry", 0.06)
    src, dst = read_trajectory_campaign(wheels), read_trajectory_campaign(out)
    assert [r.name for r in dst.runs] == [r.name for r in src.runs]
    assert [r.split for r in dst.runs] == [r.split for r in src.runs]
    assert filecmp.cmp(wheels / "campaign.yaml", out / "campaign.yaml", shallow=False)
    for a, b in zip(src.runs, dst.runs):
        assert filecmp.cmp(wheels / "runs" / a.name / "poses.csv", out / "runs" / b.name / "poses.csv", shallow=False)
        np.testing.assert_array_equal(a.inputs.t, b.inputs.t)
        np.testing.assert_array_equal(a.inputs.u1, b.inputs.u1)
        np.testing.assert_allclose(b.inputs.u2, a.inputs.u2 - 0.06 * a.inputs.u1, rtol=0, atol=1e-15)
        assert not np.array_equal(a.inputs.u2, b.inputs.u2)
    # the truth beside OUT, never inside the campaign
    assert injected_path(out) == tmp_path / "asym.injected.yaml"
    assert not any("inject" in p.name for p in out.rglob("*"))
    truth = yaml.safe_load(injected_path(out).read_text())["injected"]
    assert truth["family"] == "asymmetry" and truth["coupling"] == 0.06
    assert read_injected(out) == truth


def test_inject_command(wheels, tmp_path, capsys):
    code = cli.main(["inject", str(wheels), str(tmp_path / "d"), "--effect", "input_delay=0.15", "--quiet"])
    assert code == 0
    assert "input_delay" in capsys.readouterr().out
    src, dst = read_trajectory_campaign(wheels), read_trajectory_campaign(tmp_path / "d")
    for a, b in zip(src.runs, dst.runs):
        np.testing.assert_allclose(b.inputs.t, a.inputs.t - 0.15, rtol=0, atol=2e-9)  # ns stamps in the CSV
        np.testing.assert_array_equal(a.inputs.u1, b.inputs.u1)
    assert read_injected(tmp_path / "d")["delay_s"] == 0.15


@pytest.mark.parametrize("effect, words", [
    ("wind=0.1", "unknown family 'wind'"),
    ("deadband=0.7", "out of range"),
    ("input_delay=-0.1", "out of range"),
    ("asymmetry=abc", "not a number"),
    ("deadband", "NAME=VALUE"),
    ("time_dependence=1.5", "motor gain below"),  # 1 - 1.5 t/600 falls under 0.2 in the 6 min run
])
def test_bad_effect_one_line_nothing_written(wheels, tmp_path, capsys, effect, words):
    out = tmp_path / "out"
    code = cli.main(["inject", str(wheels), str(out), "--effect", effect, "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and words in err and "\n" not in err and "Traceback" not in err
    assert list(tmp_path.iterdir()) == []


def test_non_empty_output_and_existing_truth_refused(wheels, tmp_path, capsys):
    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("mine")
    code = cli.main(["inject", str(wheels), str(out), "--effect", "deadband=0.1", "--quiet"])
    err = capsys.readouterr().err.strip()
    assert code == 2 and "not empty" in err and "\n" not in err
    assert [p.name for p in out.iterdir()] == ["keep.txt"] and not injected_path(out).exists()
    injected_path(tmp_path / "new").write_text("other")
    with pytest.raises(InputError, match="exists"):
        inject_campaign(wheels, tmp_path / "new", "deadband", 0.1)
    assert not (tmp_path / "new").exists()


def test_parse_effect():
    assert parse_effect("deadband=0.1") == ("deadband", 0.1)
    assert parse_effect(" asymmetry=-0.05") == ("asymmetry", -0.05)


def test_a_tracker_campaign_is_preprocessed_then_injected(small_campaign, small_trajectory, tmp_path):
    # INTERFACES.md: every command after preprocess also takes a tracker campaign and preprocesses
    # it first; inject writes the trajectory campaign with the effect (poses as preprocessed)
    import shutil
    tracker = shutil.copytree(small_campaign, tmp_path / "tracker")
    out = inject_campaign(tracker, tmp_path / "d", "input_delay", 0.15)
    ref, dst = read_trajectory_campaign(small_trajectory), read_trajectory_campaign(out)
    assert [r.name for r in dst.runs] == [r.name for r in ref.runs]
    for a, b in zip(ref.runs, dst.runs):
        assert filecmp.cmp(small_trajectory / "runs" / a.name / "poses.csv", out / "runs" / b.name / "poses.csv",
                           shallow=False)
        np.testing.assert_allclose(b.inputs.t, a.inputs.t - 0.15, rtol=0, atol=2e-9)
    assert read_injected(out)["source"] == str(tracker.resolve())
    assert not (out / "cache_key.json").exists()
    with pytest.raises(InputError, match="output folder inside the campaign"):
        inject_campaign(tracker, tracker / "inside", "input_delay", 0.15)
