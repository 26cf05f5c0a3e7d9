"""The margins of the readers' and the benchmark's checks of a campaign against itself (2026-11-28).

Usage: ``.venv/bin/python -m bench.bench_input_checks [--variants 1-10] [--minutes 3]`` from the
checkout; writes ``bench/results/input_checks.md`` (about five minutes: one simulated campaign per
variant, with recorded GNSS, gyro and wheel odometry, preprocessed).

Each check compares data with the data's own ground truth; its threshold is named in the code and
must sit far from what clean data of every kind give, and far from what the fault it is for gives.
On data no check was written against (simulator variants with their own robot, tracker noise and
driver; the shared real Warthog runs), this bench measures both sides:

- **input signs** (:func:`identification.preprocessing.trajectory_checks.input_sign_correlations`):
  ``u1`` against the poses' forward speed, ``u2`` against their yaw rate, pooled over a campaign;
  refused below -0.3. Fault: the poses mirrored (y and yaw negated, a north-east-down frame).
- **tracker units** (:func:`identification.preprocessing.io_tracker.check_point_units`): a tracker's
  median point distance over its network points'; refused beyond 30 or below 1/30. Fault: the
  LTD800's points in millimetres.
- **gyro and odometry** (:func:`identification.preprocessing.io_motion.check_against_poses`): the
  correlation with the poses' rate (refused below -0.3), the slope (refused above 20 for rates, 5
  for speed), the best time shift (refused beyond 0.25 s when significantly better). Faults: the
  gyro negated, in degrees per second, stamped 0.5 s late.
- **GNSS** (:mod:`sindy_ekf.benchmark.gnss_source`): the mirror test, the best time shift of the
  fixes, the lever arm the fixes give against the simulator's. Faults: the poses mirrored, the fixes
  stamped 18 s late (GPS time), the lever arm undeclared. The lever arm and the ENU -> local
  transform also with the rtk and standalone receivers: their stated uncertainty against the truth.
"""

from __future__ import annotations

import argparse
import logging
import platform
import shutil
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import yaml

from bench.bench_variants import _indices
from bench.publish import publish
from groundfloor.errors import InputError
from groundfloor.types import PointSeries
from identification.preprocessing.io_motion import IMU, ODOMETRY, check_against_poses, load_run_motion, time_shift
from identification.preprocessing.io_tracker import check_point_units, read_tracker_campaign
from identification.preprocessing.preprocess import preprocess_campaign
from identification.preprocessing.trajectory import read_trajectory_campaign
from identification.preprocessing.trajectory_checks import input_sign_correlations, pose_motion
from simulation.campaign import simulate_campaign
from sindy_ekf.benchmark.gnss_source import load_recorded_gnss

HERE = Path(__file__).resolve().parent
SHARED = HERE.parent.parent / "shared" / "data"


def unit_ratios(tracker_dir: Path) -> tuple[float, float]:
    """Return the smallest and largest median point distance over the network points' (runs x trackers)."""
    c = read_tracker_campaign(tracker_dir)
    q = []
    for tr in ("at960", "ltd800"):
        net = np.median([np.linalg.norm(np.asarray(v, float)[:3]) for v in getattr(c.survey, f"network_{tr}").values()])
        q += [float(np.nanmedian(np.linalg.norm(getattr(r, tr).xyz, axis=1)) / net) for r in c.runs]
    return min(q), max(q)


def sensor_figures(traj) -> dict[str, tuple[float, float, float, float]]:
    """Return per column (wz, v, omega): the smallest correlation, the slope range and the largest
    |best shift| (the nearest of the near-best, as the check takes it) over the runs."""
    out: dict[str, list] = {}
    for run in traj.runs:
        mid, speed, rate = pose_motion(run.poses)
        for kind in (IMU, ODOMETRY):
            got = load_run_motion(traj.root / "runs" / run.name, kind, run.poses.t)
            if got is None:
                continue
            s = got[0]
            for col, truth in ((("wz", rate),) if kind == IMU else (("v", speed), ("omega", rate))):
                m = np.interp(s.t, mid, truth, left=np.nan, right=np.nan)
                a = s.columns[col]
                ok = np.isfinite(a) & np.isfinite(m)
                r = float(np.corrcoef(a[ok], m[ok])[0, 1])
                slope = float(np.sum(a[ok] * m[ok]) / np.sum(m[ok] ** 2))
                shift = time_shift([(s.t, a, mid, truth)])[0]  # the one the check takes, on this run alone
                out.setdefault(col, []).append((r, slope, abs(shift)))
    for kind in (IMU, ODOMETRY):  # clean data must pass the check itself, pooled over the runs as it is
        loaded = [(load_run_motion(traj.root / "runs" / r.name, kind, r.poses.t), r.poses) for r in traj.runs]
        check_against_poses([(got[0], poses) for got, poses in loaded if got is not None], kind)
    return {c: (min(v[0] for v in vals), min(v[1] for v in vals), max(v[1] for v in vals), max(v[2] for v in vals))
            for c, vals in out.items()}


def refused(call) -> str:
    """Return the first words of the InputError ``call`` raises, or ``NOT refused``."""
    try:
        call()
    except InputError as exc:
        return "refused: " + str(exc).split(": ", 2)[-1][:160]
    return "NOT refused"


def _rewrite(path: Path, column: str, fn) -> None:
    head, *rows = path.read_text().splitlines()
    k = head.split(",").index(column)
    path.write_text("\n".join([head] + [",".join(repr(float(fn(float(v)))) if i == k else v
                                                 for i, v in enumerate(r.split(","))) for r in rows]) + "\n")


def undeclared_lever_fit(traj_dir: Path, copy: Path) -> dict:
    """Return the lever-arm fit of a copy of the campaign at ``copy`` without its ``sensors:`` (the
    antenna's lever arm undeclared, so zero)."""
    shutil.copytree(traj_dir, copy)
    meta = yaml.safe_load((copy / "campaign.yaml").read_text())
    meta.pop("sensors", None)
    (copy / "campaign.yaml").write_text(yaml.safe_dump(meta))
    return load_recorded_gnss(read_trajectory_campaign(copy)).lever_arm_fit


def fault_results(tracker: Path, traj_dir: Path, work: Path) -> dict[str, str]:
    """Return, per fault, what the checks say of a copy of the campaign with that fault (``refused: ...``
    or ``NOT refused``; for the gyro, the first refusal over its runs)."""
    work.mkdir(parents=True)
    out = {}
    mirrored = shutil.copytree(traj_dir, work / "mirrored")
    for p in mirrored.glob("runs/*/poses.csv"):
        _rewrite(p, "y", lambda x: -x)
        _rewrite(p, "yaw", lambda x: -x)
    r = input_sign_correlations(read_trajectory_campaign(mirrored).runs)
    out["poses mirrored (y, yaw negated): input signs"] = (f"refused: u2 r = {r['u2']:+.2f}" if r["u2"] < -0.3
                                                             else f"NOT refused: u2 r = {r['u2']:+.2f}")
    out["poses mirrored (y, yaw negated): GNSS frame"] = refused(
        lambda: load_recorded_gnss(read_trajectory_campaign(mirrored)))
    for what, column, fn in (("gyro negated (z-down IMU)", "wz", lambda x: -x),
                             ("gyro in degrees per second", "wz", np.degrees),
                             ("gyro stamped 0.5 s late", "t", lambda x: x + 0.5),
                             ("gyro stamped 2 s late", "t", lambda x: x + 2.0)):
        copy = shutil.copytree(traj_dir, work / what.replace(" ", "_"))
        for p in copy.glob("runs/*/imu.csv"):
            _rewrite(p, column, fn)
        c = read_trajectory_campaign(copy)
        out[what] = refused(lambda: check_against_poses(
            [(load_run_motion(c.root / "runs" / r.name, IMU, r.poses.t)[0], r.poses) for r in c.runs], "imu.csv"))
    for what, seconds in (("GNSS stamped in GPS time (18 s late)", 18.0), ("GNSS stamped 2 s early", -2.0)):
        gps = shutil.copytree(traj_dir, work / what.replace(" ", "_"))
        for p in gps.glob("runs/*/gnss.csv"):
            _rewrite(p, "t", lambda x, d=seconds: x + d)
        out[what] = refused(lambda: load_recorded_gnss(read_trajectory_campaign(gps)))
    fit = undeclared_lever_fit(traj_dir, work / "nolever")
    out["GNSS lever arm undeclared"] = (("refused" if fit["differs"] else "NOT refused")
                                        + f": named ({fit['estimated_m'][0]:+.2f}, {fit['estimated_m'][1]:+.2f}) m")
    camp = read_tracker_campaign(tracker)
    run = camp.runs[0]
    raw = replace(run, ltd800=PointSeries(run.ltd800.t_tracker, run.ltd800.xyz * 1000.0))
    out["LTD800 points in millimetres"] = refused(lambda: check_point_units(raw, camp.survey))
    return out


PROFILES = ("rtk", "dgnss", "standalone")


def gnss_figures(tracker: Path, traj_dir: Path) -> dict:
    """Return what the recorded-GNSS checks say of a clean campaign and of a copy without its declared
    lever arm: ``differs`` (clean, must be False), ``named`` (undeclared: should be True where the data
    can tell 0.22 m), the lever arm and the ENU -> local yaw against the simulator's truth in their
    stated stds (``lever_z``, ``yaw_z``: how honest the stated uncertainties are)."""
    truth = yaml.safe_load((tracker / "truth" / "gnss.yaml").read_text())
    rec = load_recorded_gnss(read_trajectory_campaign(traj_dir))
    fit, lever = rec.lever_arm_fit, np.asarray(truth["lever_arm_body_m"][:2], float)
    d = np.asarray(fit["estimated_m"]) - lever
    yaw_err = float(np.degrees(rec.transform.yaw_rad) - truth["enu_to_local_yaw_deg"])
    named = undeclared_lever_fit(traj_dir, traj_dir.parent / (traj_dir.name + "_nolever"))["differs"]
    return {"differs": fit["differs"], "named": named, "lever_z": float(np.max(np.abs(d) / np.asarray(fit["std_m"]))),
            "yaw_z": abs(yaw_err) / float(np.degrees(np.sqrt(rec.transform.cov[0, 0]))),
            "correlated": rec.transform.correlated_over_runs}


def gnss_lines(per_profile: dict[str, list[dict]]) -> list[str]:
    """Return the table of :func:`gnss_figures` per receiver profile over the variants."""
    out = ["Recorded GNSS of three receivers (`simulation/gnss.py` profiles: rtk 10 Hz, 2 cm; dgnss 5 Hz, 0.3 m; "
           "standalone 1 Hz, 1 m white and a 1.1 m bias wandering over 300 s), each variant's campaign simulated "
           "with each (the same seed): the lever arm called different from the declared one (false alarms), the "
           "undeclared one (0.22 m) named, and the estimates' distance from the simulator's truth in their own "
           "stated stds (the largest over the variants; about 3 or less when the stated uncertainty is honest).",
           "", "| receiver | clean: lever arm called different | undeclared lever arm named | lever arm off truth, "
           "stds (largest) | ENU -> local yaw off truth, stds (largest) | errors said correlated over runs |",
           "|---|---|---|---|---|---|"]
    for prof, rows in per_profile.items():
        n = len(rows)
        out.append(f"| {prof} | {sum(r['differs'] for r in rows)} of {n} | {sum(r['named'] for r in rows)} of {n} | "
                   f"{max(r['lever_z'] for r in rows):.1f} | {max(r['yaw_z'] for r in rows):.1f} | "
                   f"{sum(r['correlated'] for r in rows)} of {n} |")
    return out + ["", "The stated uncertainties count the fixes of a run by blocks as long as the residuals' correlation "
                  "time in the run (`groundfloor.geodetic.block_covariance`). Before (2026-11-28, the same campaigns, "
                  "one fix a second taken as independent): standalone lever arm up to 3.6 stds off, yaw 10.9, no false "
                  "alarm here; on simulator variant 23 (12 min, standalone) the declared antenna was called wrong "
                  "((0.05, 0.56) +- 0.08 m against (-0.20, 0.10)), now not (stds 0.25, 0.20; "
                  "`tests/sindy_ekf/benchmark/test_gnss_source.py`). The standalone yaw stays up to 10.6 of its stds off: "
                  "the bias wanders over 300 s, longer than these campaigns, so it is common to every run and no block "
                  "of the data sees it vary. The benchmark says so where the residuals' correlation time spans half a run or "
                  "more (`groundfloor.geodetic.correlated_over_runs`, last column): the transform may be off by more than "
                  "its stated uncertainty; `enu_to_local_yaw_deg` in campaign.yaml gives the transform instead."]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default="1-10")
    ap.add_argument("--minutes", type=float, default=3.0)
    a = ap.parse_args(argv)
    logging.basicConfig(level=logging.ERROR)
    tic = time.perf_counter()
    rows, work = [], Path(tempfile.mkdtemp(prefix="input_checks_"))
    try:
        for name in ("warthog-drive-wheels", "warthog-drive-cmd"):
            r = input_sign_correlations(read_trajectory_campaign(SHARED / name).runs)
            rows.append(f"| {name} (real) | {r['u1']:+.2f} | {r['u2']:+.2f} | - | - | - | - | - |")
        faults: list[dict[str, str]] = []
        gnss: dict[str, list[dict]] = {p: [] for p in PROFILES}
        for v in _indices(a.variants):
            tracker, traj_dir = work / f"v{v}", work / f"v{v}_traj"
            simulate_campaign(tracker, seed=v, minutes=a.minutes, variant=v, gnss="dgnss", imu=True, odometry=True)
            preprocess_campaign(tracker, traj_dir)
            traj = read_trajectory_campaign(traj_dir)
            r = input_sign_correlations(traj.runs)
            lo, hi = unit_ratios(tracker)
            f = sensor_figures(traj)
            rec = load_recorded_gnss(traj)
            lever = yaml.safe_load((tracker / "truth" / "gnss.yaml").read_text())["lever_arm_body_m"][:2]
            fit = rec.lever_arm_fit
            rows.append(f"| variant {v} ({a.minutes:g} min) | {r['u1']:+.2f} | {r['u2']:+.2f} | {lo:.2f} to {hi:.2f} | "
                        + " / ".join(f"{f[c][0]:.2f}" for c in ("wz", "v", "omega")) + " | "
                        + " / ".join(f"{f[c][1]:.2f}-{f[c][2]:.2f}" for c in ("wz", "v", "omega")) + " | "
                        + " / ".join(f"{f[c][3]:.2f}" for c in ("wz", "v", "omega")) + " | "
                        + f"({fit['estimated_m'][0]:+.2f}, {fit['estimated_m'][1]:+.2f}) against ({lever[0]:+.2f}, "
                          f"{lever[1]:+.2f}), differs: {fit['differs']} |")
            faults.append(fault_results(tracker, traj_dir, work / f"faults_{v}"))
            for prof in PROFILES:
                t_dir, j_dir = (tracker, traj_dir) if prof == "dgnss" else (work / f"v{v}_{prof}", work / f"v{v}_{prof}_traj")
                if prof != "dgnss":
                    simulate_campaign(t_dir, seed=v, minutes=a.minutes, variant=v, gnss=prof)
                    preprocess_campaign(t_dir, j_dir)
                gnss[prof].append(gnss_figures(t_dir, j_dir))
    finally:
        shutil.rmtree(work, ignore_errors=True)
    lines = ["## The input checks against clean data of several kinds and against the faults they are for",
             "",
             f"Command: `.venv/bin/python -m bench.bench_input_checks --variants {a.variants} --minutes {a.minutes:g}` "
             f"(Python {platform.python_version()}, {time.perf_counter() - tic:.0f} s). Each simulated campaign: "
             "`simulate_campaign(seed=N, variant=N, gnss='dgnss', imu=True, odometry=True)`, preprocessed.",
             "",
             "Clean data (every one must pass):",
             "",
             "| campaign | u1 vs speed r | u2 vs yaw rate r | tracker points / network (distance) | gyro, odometry "
             "v, omega: smallest r (per run) | slopes (per run) | largest best shift s (per run) | GNSS lever arm the fixes give (m) against the true |",
             "|---|---|---|---|---|---|---|---|",
             *rows, "",
             "Thresholds: input signs r below -0.3 (warned); tracker distance ratio beyond 30 or below 1/30; gyro and "
             "odometry r below -0.3, slope above 20 (wz, omega) or 5 (v), best shift beyond 0.25 s significantly "
             "better; GNSS lever arm more than 0.1 m off and significant.",
             "",
             *gnss_lines(gnss), "",
             "Faults, each on a copy of every variant's campaign (the gyro's evidence pooled over its runs, as "
             "the benchmark pools it):",
             "",
             "| fault | refused in | what the first refusal says |",
             "|---|---|---|",
             *[f"| {name} | {sum(f[name].startswith('refused') for f in faults)} of {len(faults)} campaigns | "
               + next((f[name] for f in faults if f[name].startswith("refused")), faults[0][name]) + " |"
               for name in faults[0]]]
    publish(HERE / "results" / "input_checks.md", lines)
    return 0


if __name__ == "__main__":
    sys.exit(main())
