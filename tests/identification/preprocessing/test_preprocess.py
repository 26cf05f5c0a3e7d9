"""The whole preprocessing chain against the simulator's truth, the command, the cache.

Scored against ``truth/`` of simulated campaigns (which the pipeline never reads): clock drifts,
the AT960's extra offset, hub radii, poses and body-frame velocities, on the shared small
campaign (seed 1) and on two more tiny campaigns with other seeds.
"""

from __future__ import annotations

import json
import os
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
import yaml

from groundfloor.errors import InputError
from tests.support import REPO
from tests.support.tracker_synth import synth_run, write_campaign

CALIBRATION = REPO / "simulation" / "data" / "calibration.yaml"
INTERFACE_RUN_KEYS = {"clock", "at960_extra_offset_s", "baseline_rms_m"}


def _report(out: Path) -> dict:
    return json.loads((out / "preprocess.json").read_text())


def _check_sync_against_truth(report: dict, truth) -> None:
    """Drift within 0.05 ppm (LTD800) and within its own 3 sigma (AT960); offset within 20 us;
    the timing error visible before the correction (|r| > 0.5) and gone after (|r| < 0.3)."""
    assert report["runs"], "no run preprocessed"
    for name, r in report["runs"].items():
        t = truth.run(name)
        ltd, at = r["clock"]["ltd800"], r["clock"]["at960"]
        assert abs(ltd["drift_ppm"] - t.clocks["ltd800"]["drift_ppm"]) < 0.05, name
        assert abs(at["drift_ppm"] - t.clocks["at960"]["drift_ppm"]) < 3 * at["drift_std_ppm"], name
        assert abs(r["at960_extra_offset_s"] - t.at960["offset_s"]) < 20e-6, name
        assert r["extra_offset_tracker"] == "at960"
        assert abs(r["timing_error"]["r_baseline_speed_before"]) > 0.5, name
        assert abs(r["timing_error"]["r_baseline_speed_after"]) < 0.3, name
        assert r["baseline_rms_m"]["after"] < r["baseline_rms_m"]["before"]


@pytest.fixture(scope="module")
def truth(small_campaign):
    from simulation.truth import read_truth

    return read_truth(small_campaign)


def test_sync_against_truth(small_trajectory, truth):
    _check_sync_against_truth(_report(small_trajectory), truth)


def test_counts_against_truth(small_trajectory, truth):
    for name, r in _report(small_trajectory)["runs"].items():
        t, c = truth.run(name), r["counts"]
        assert c["triggers"] == t.n_trigger
        assert c["at960"]["samples"] == t.at960["n_messages"]
        assert c["ltd800"]["samples"] == t.ltd800["n_messages"]
        # spurious pulses inside a dropout and lost ones next to it are counted with the dropout
        assert abs(c["at960"]["spurious"] - t.at960["n_spurious"]) <= max(2, 0.1 * t.at960["n_spurious"])
        assert abs(c["at960"]["lost"] - t.at960["n_lost"]) <= max(3, 0.1 * t.at960["n_lost"])
        for tr in ("at960", "ltd800"):
            silent = c[tr]["lost"] + c[tr]["out_of_view"]
            assert abs(silent - getattr(t, tr)["n_dropout_pulses"] - (t.at960["n_lost"] if tr == "at960" else 0)) \
                <= max(5, 0.05 * silent), (name, tr)
        assert c["poses"] + c["one_prism_only"] + c["no_prism"] == c["triggers"]


def test_hub_radii_against_truth(small_trajectory, truth):
    report = _report(small_trajectory)
    r1 = [r["hub"]["r1"] for r in report["runs"].values() if "hub" in r]
    r2 = [r["hub"]["r2"] for r in report["runs"].values() if "hub" in r]
    assert len(r1) == len(report["runs"])
    # per run, as the thesis estimated them (eq. 5.25); median over the runs
    assert abs(np.median(r1) - truth.hubs["front"]["radius_eq525_m"]) < 0.03e-3
    assert abs(np.median(r2) - truth.hubs["rear"]["radius_eq525_m"]) < 0.03e-3


def test_poses_against_truth(small_trajectory, truth):
    """Position RMS <= 0.5 mm and yaw RMS <= 0.01 deg against the true body poses."""
    from identification.preprocessing.trajectory import read_trajectory_campaign

    camp = read_trajectory_campaign(small_trajectory)
    err_p, err_yaw = [], []
    for run in camp.runs:
        st = truth.run(run.name).states
        i = np.searchsorted(st.t_utc, run.poses.t)
        i = np.clip(i, 1, st.t_utc.size - 1)
        i -= np.abs(st.t_utc[i - 1] - run.poses.t) < np.abs(st.t_utc[i] - run.poses.t)
        assert np.abs(st.t_utc[i] - run.poses.t).max() < 1e-6  # poses are at trigger times
        p = np.column_stack([run.poses.x, run.poses.y, run.poses.z])
        q = np.column_stack([st.x[i], st.y[i], st.z[i]])
        err_p.append(np.linalg.norm(p - q, axis=1))
        err_yaw.append(np.angle(np.exp(1j * (run.poses.yaw - st.psi[i]))))
    rms_p = np.sqrt(np.mean(np.concatenate(err_p) ** 2))
    rms_yaw = np.degrees(np.sqrt(np.mean(np.concatenate(err_yaw) ** 2)))
    assert rms_p <= 0.5e-3, rms_p
    assert rms_yaw <= 0.01, rms_yaw


def test_body_velocities_against_truth(small_trajectory, truth):
    from identification.preprocessing.trajectory import read_trajectory_campaign

    states = {}
    for run_dir in (small_trajectory / "runs").iterdir():
        states[run_dir.name] = np.genfromtxt(run_dir / "states.csv", delimiter=",", names=True)
    assert set(states) == {r.name for r in read_trajectory_campaign(small_trajectory).runs}
    err = []
    for name, s in states.items():
        st = truth.run(name).states
        i = np.clip(np.searchsorted(st.t_utc, s["t"] - 1e-6), 0, st.t_utc.size - 1)
        err.append(np.column_stack([s["vx"] - st.vx[i], s["vy"] - st.vy[i], s["omega"] - st.omega[i]]))
    rms = np.sqrt(np.nanmean(np.concatenate(err) ** 2, axis=0))
    assert rms[0] < 0.02 and rms[1] < 0.02 and rms[2] < 0.05, rms  # m/s, m/s, rad/s


def test_tum_file_reads_with_evo(small_trajectory):
    # evo is GPL: a test-only dependency, imported here and never by the package
    from evo.tools import file_interface as evo_io

    run = next((small_trajectory / "runs").iterdir())
    traj = evo_io.read_tum_trajectory_file(str(run / "poses.tum"))
    poses = np.genfromtxt(run / "poses.csv", delimiter=",", names=True)
    np.testing.assert_allclose(traj.positions_xyz[:, 0], poses["x"], atol=1e-9)


def test_several_seeds(tmp_path):
    """Two more tiny campaigns with other seeds: the same criteria hold, not one tuned case."""
    from identification.preprocessing.preprocess import preprocess_campaign
    from simulation.campaign import simulate_campaign
    from simulation.truth import read_truth

    for seed in (2, 3):
        camp = tmp_path / f"c{seed}"
        simulate_campaign(camp, seed=seed, minutes=2.25)  # the shortest it allows
        out = tmp_path / f"t{seed}"
        preprocess_campaign(camp, out, jobs=1)
        _check_sync_against_truth(_report(out), read_truth(camp, states=False))


# --- the command, bad input, the cache (synthetic campaigns: fast) ---------------------------


@pytest.fixture(scope="module")
def synthetic_campaign(tmp_path_factory) -> Path:
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey

    tf = calibrate(read_survey(CALIBRATION)).transform
    raws = [synth_run(seed=30 + i, minutes=0.5, name=f"run_{i}", R_at960_ltd800=tf.R_at960_ltd800,
                      t_at960_ltd800=tf.t_at960_ltd800)[0] for i in (1, 2)]
    raws[1] = replace(raws[1], split="test")
    return write_campaign(tmp_path_factory.mktemp("synthetic") / "c", raws, CALIBRATION.read_text())


def test_command_writes_interface_files_and_json(synthetic_campaign, tmp_path, capsys):
    from sindy_ekf.cli import main

    out, js = tmp_path / "out", tmp_path / "pre.json"
    assert main(["preprocess", str(synthetic_campaign), "--out", str(out), "--json", str(js),
                 "--jobs", "1"]) == 0
    printed = capsys.readouterr().out
    assert "run_1" in printed and "run_2" in printed
    assert "timing error found" in printed and "the AT960 measures 1.4" in printed  # duty 1.3-1.5
    report = json.loads(js.read_text())
    assert all(r["timing_error"]["detected"] for r in report["runs"].values())
    assert {"transform", "lever_arms_m", "runs"} <= set(report)
    assert set(report["transform"]) >= {"translation_m", "rotation_deg"}
    for r in report["runs"].values():
        assert INTERFACE_RUN_KEYS <= set(r)
        assert set(r["clock"]) == {"at960", "ltd800"} and "drift_ppm" in r["clock"]["at960"]
        assert set(r["baseline_rms_m"]) >= {"before", "after"}
    meta = yaml.safe_load((out / "campaign.yaml").read_text())
    assert meta["kind"] == "trajectory" and [r["split"] for r in meta["runs"]] == ["train", "test"]
    for f in ("poses.csv", "inputs.csv", "poses.tum", "states.csv"):
        assert (out / "runs" / "run_1" / f).is_file()
    header = (out / "runs" / "run_1" / "poses.csv").read_text().splitlines()[0].split(",")
    assert header[:6] == ["t", "x", "y", "z", "pitch", "yaw"]


def test_bad_run_is_skipped_and_listed(synthetic_campaign, tmp_path):
    import shutil

    from identification.preprocessing.preprocess import preprocess_campaign

    camp = tmp_path / "c"
    shutil.copytree(synthetic_campaign, camp)
    (camp / "runs" / "run_2" / "trackers.bag").unlink()
    result = preprocess_campaign(camp, tmp_path / "out")
    assert list(result.runs) == ["run_1"]
    assert "run run_2: topic /at960/measurement missing or empty" == result.skipped["run_2"]
    assert _report(tmp_path / "out")["skipped_runs"] == result.skipped


def test_failure_leaves_nothing_half_written(synthetic_campaign, tmp_path, capsys):
    import shutil

    from sindy_ekf.cli import main

    camp = tmp_path / "c"
    shutil.copytree(synthetic_campaign, camp)
    for bag in camp.glob("runs/*/trackers.bag"):
        bag.unlink()
    out = tmp_path / "out"
    assert main(["preprocess", str(camp), "--out", str(out), "--quiet"]) == 2
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "run run_1: topic /at960/measurement missing" in err
    assert not out.exists() and not list(tmp_path.glob(".out.*"))


def test_existing_output_needs_force(synthetic_campaign, tmp_path):
    from identification.preprocessing.preprocess import preprocess_campaign

    out = tmp_path / "out"
    out.mkdir()
    (out / "keep.txt").write_text("x")
    with pytest.raises(InputError, match="not empty"):
        preprocess_campaign(synthetic_campaign, out)
    assert (out / "keep.txt").read_text() == "x"


def test_open_campaign_preprocesses_once_and_reuses(synthetic_campaign, tmp_path, monkeypatch):
    import shutil

    from identification.preprocessing import campaigns

    camp = tmp_path / "c"
    shutil.copytree(synthetic_campaign, camp)
    first = campaigns.open_campaign(camp)
    assert (camp / campaigns.CACHE_SUBDIR / campaigns.KEY_FILE).is_file()

    def boom(*a, **k):
        raise AssertionError("preprocessed twice")

    monkeypatch.setattr(campaigns, "preprocess_campaign", boom)
    again = campaigns.open_campaign(camp)
    assert [r.name for r in again.runs] == [r.name for r in first.runs]
    np.testing.assert_array_equal(again.runs[0].poses.x, first.runs[0].poses.x)
    # a changed bag invalidates the cache
    bag = camp / "runs" / "run_1" / "robot.bag"
    os.utime(bag, ns=(bag.stat().st_atime_ns, bag.stat().st_mtime_ns + 10**9))
    with pytest.raises(AssertionError, match="preprocessed twice"):
        campaigns.open_campaign(camp)
    # a trajectory campaign is read as it is
    traj = campaigns.open_campaign(camp / campaigns.CACHE_SUBDIR)
    assert [r.name for r in traj.runs] == ["run_1", "run_2"]


def test_cache_key_covers_every_module_preprocessing_runs():
    """A module split off the chain must not leave its source out of the cache key (a stale cache)."""
    from identification.preprocessing import campaigns

    modules = {p.stem for p in Path(campaigns.__file__).parent.glob("*.py")}
    assert modules - {"__init__", "campaigns", "figures"} <= set(campaigns._CODE_MODULES)


def test_open_campaign_not_a_campaign(tmp_path):
    from identification.preprocessing.campaigns import open_campaign

    with pytest.raises(InputError, match=rf"^{tmp_path}: not a campaign \(no campaign.yaml\)$"):
        open_campaign(tmp_path)


def test_figures_only_on_request(synthetic_campaign, tmp_path, monkeypatch):
    """No figure without ``plots_dir``; with it, one folder per run with figs. 5.1-5.7, 7.2/7.3,
    drawn without touching matplotlib's backend (a notebook user's stays as it is)."""
    import shutil

    import matplotlib

    from identification.preprocessing.preprocess import preprocess_campaign

    camp = tmp_path / "c"  # one run: figures are slow to draw
    shutil.copytree(synthetic_campaign, camp)
    meta = yaml.safe_load((camp / "campaign.yaml").read_text())
    (camp / "campaign.yaml").write_text(yaml.safe_dump({**meta, "runs": meta["runs"][:1]}))
    preprocess_campaign(camp, tmp_path / "a")
    assert not list(tmp_path.rglob("*.png"))
    backend = dict.__getitem__(matplotlib.rcParams, "backend")  # as set, without resolving it

    def no_switch(*args, **kwargs):
        raise AssertionError("the library switched matplotlib's backend")

    monkeypatch.setattr(matplotlib, "use", no_switch)
    preprocess_campaign(camp, tmp_path / "b", plots_dir=tmp_path / "plots")
    assert dict.__getitem__(matplotlib.rcParams, "backend") == backend
    names = {p.name for p in (tmp_path / "plots" / "run_1").glob("*.png")}
    assert {"fig5_1_gap_signal.png", "fig5_2_xcorr.png", "fig5_3_clock_model.png",
            "fig5_4_clock_residuals.png",
            "fig5_5_baseline.png", "fig5_6_offset_fit.png", "baseline_vs_speed.png",
            "fig5_7_hub_model.png"} <= names
    assert {"fig7_2_7_3_poses_position.png", "fig7_2_7_3_poses_attitude.png"} <= names


def test_parallel_runs_give_the_same_result(synthetic_campaign, tmp_path):
    from identification.preprocessing.preprocess import preprocess_campaign

    one = preprocess_campaign(synthetic_campaign, tmp_path / "one", jobs=1)
    two = preprocess_campaign(synthetic_campaign, tmp_path / "two", jobs=2)
    assert list(one.runs) == list(two.runs)
    for name in one.runs:
        np.testing.assert_array_equal(one.runs[name].poses.x, two.runs[name].poses.x)
        assert one.runs[name].synced.offset.dt == two.runs[name].synced.offset.dt
    assert (tmp_path / "one" / "runs" / "run_1" / "poses.csv").read_text() == \
        (tmp_path / "two" / "runs" / "run_1" / "poses.csv").read_text()


def test_run_without_gaps_is_skipped_and_named(tmp_path):
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey
    from identification.preprocessing.preprocess import preprocess_campaign

    tf = calibrate(read_survey(CALIBRATION)).transform
    good, bad = (synth_run(seed=50 + i, minutes=0.5, name=f"run_{i}", R_at960_ltd800=tf.R_at960_ltd800,
                           t_at960_ltd800=tf.t_at960_ltd800)[0] for i in (1, 2))
    bad = replace(bad, t_trigger_utc=bad.t_trigger_utc[0] + 0.02 * np.arange(bad.t_trigger_utc.size))
    camp = write_campaign(tmp_path / "c", [good, bad], CALIBRATION.read_text())
    result = preprocess_campaign(camp, tmp_path / "out")
    assert list(result.runs) == ["run_1"]
    assert result.skipped["run_2"].startswith("run run_2: topic /rpi/trigger: no detectable gaps")
