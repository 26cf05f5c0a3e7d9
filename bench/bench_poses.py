"""Hub model, poses and body-frame states: speed on 30 000 samples and accuracy against truth.

Usage: ``.venv/bin/python -m bench.bench_poses [--seeds 0 2 3] [--minutes M]``; writes
``bench/results/poses.md``.

1. Speed: one synthetic 10-minute run at 50 Hz (30 000 samples, ``tests.support.pose_synth``),
   best of three wall-clock times per stage.
2. Accuracy on simulated campaigns (``simulation.campaign.simulate_campaign``; seed 0 is the
   full default campaign, 45.4 min, reused from ``bench/_work/campaign_default_seed0`` when
   present; other seeds are simulated with ``--minutes``): the bags are read and synchronised
   with helper H4's ``identification.preprocessing.io_tracker``/``identification.preprocessing.sync``, then this area's
   stages run and are scored against ``truth/`` (which the stages never read).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from pathlib import Path

import numpy as np

from groundfloor.errors import InputError
from groundfloor.files import atomic_write_text
from groundfloor.types import InputSeries
from identification.preprocessing.hub import fit_hub_model, fit_hub_model_joint
from identification.preprocessing.poses import fit_poses
from identification.preprocessing.states import body_states_from_poses

ROOT = Path(__file__).resolve().parents[1]

SMOOTHINGS = (0.0, 0.0005, 0.005, 0.01, 1.0, 10.0)
WORK = ROOT / "bench" / "_work"


def best_of(fn, repeat: int = 3) -> tuple[float, object]:
    """Return the best wall time of ``repeat`` calls and the last result."""
    best, out = np.inf, None
    for _ in range(repeat):
        tic = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - tic)
    return best, out


def bench_speed() -> list[str]:
    """Return markdown lines with the stage times on 30 000 synthetic samples."""
    from tests.support.pose_synth import LEVER_FRONT, LEVER_REAR, measurements

    m = measurements(duration_s=600.0, seed=0)
    n = m.t.size
    length = np.linalg.norm(m.p_front - m.p_rear, axis=1)
    t_hub, hub = best_of(lambda: fit_hub_model(m.t, length, m.az_front, m.az_rear))
    t_corr, _ = best_of(lambda: hub.correct(m.p_front, m.p_rear, m.az_front, m.az_rear))
    t_pose, poses = best_of(lambda: fit_poses(m.t, m.p_front, m.p_rear, LEVER_FRONT, LEVER_REAR, 10e-6, 10e-6))
    t_in = np.arange(0.0, 600.0, 0.05)
    inputs = InputSeries(t=t_in, u1=np.sin(t_in), u2=np.cos(t_in))
    lines = [f"Synthetic run of {n} samples (10 min at 50 Hz), best of 3:", "",
             "| stage | wall time [s] |", "|---|---|",
             f"| `fit_hub_model` (eq. 5.25) | {t_hub:.4f} |",
             f"| `HubModel.correct` | {t_corr:.4f} |",
             f"| `fit_poses` (2D start + 3D Gauss-Newton, 5.26-5.37) | {t_pose:.4f} |"]
    for s in SMOOTHINGS:
        t_st, _ = best_of(lambda: body_states_from_poses(poses, inputs, s))
        lines.append(f"| `body_states_from_poses`, s = {s:g} | {t_st:.4f} |")
    return lines


def _nearest(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    i = np.clip(np.searchsorted(t_ref, t), 1, t_ref.size - 1)
    return i - (np.abs(t_ref[i - 1] - t) < np.abs(t_ref[i] - t))


def campaign_dir(seed: int, minutes: float | None) -> Path:
    """Return a simulated campaign folder for ``seed``, simulating it once if missing."""
    from simulation.campaign import simulate_campaign

    name = "campaign_default_seed0" if seed == 0 and minutes is None else f"campaign_seed{seed}_{minutes:g}min"
    path = WORK / name
    if not (path / "truth" / "truth.yaml").is_file():
        simulate_campaign(path, seed=seed, minutes=minutes, force=True)
    return path


def bench_accuracy(root: Path) -> tuple[list[str], dict]:
    """Return markdown lines and figures of this area's stages on one campaign vs truth."""
    from identification.preprocessing.calibration import calibrate
    from identification.preprocessing.io_survey import read_survey
    from identification.preprocessing.io_tracker import read_tracker_run
    from identification.preprocessing.preprocess import point_std_m
    from identification.preprocessing.sync import azimuth_at, sync_run
    from simulation.truth import read_truth

    truth = read_truth(root)
    cal = calibrate(read_survey(root / "calibration.yaml"))
    tf = cal.transform
    lf, lr = cal.lever_arms_body["front"], cal.lever_arms_body["rear"]
    origin = {"at960": np.zeros(3), "ltd800": np.asarray(tf.t_at960_ltd800)}
    runs, n_total, sec, skipped = [], 0, {"hub": 0.0, "poses": 0.0, "states": 0.0}, []
    for rt in truth.runs:
        raw = read_tracker_run(root / "runs" / rt.name, rt.name, rt.split)
        try:
            sy = sync_run(raw, tf.R_at960_ltd800, tf.t_at960_ltd800, cal.prism_tracker)
        except InputError as exc:  # synchronisation is another area's; score the runs it delivers
            skipped.append(f"{rt.name} ({exc})")
            continue
        az = azimuth_at(sy.t_utc, raw.t_hub_utc, raw.hub_azimuth)
        both = sy.both_seen & np.isfinite(az).all(axis=1)
        runs.append(dict(rt=rt, sy=sy, az=az, both=both, raw=raw))
        n_total += int(both.sum())
    tic = time.perf_counter()
    args = [(r["sy"].s_trigger[r["both"]], r["sy"].baseline_after_m[r["both"]], r["az"][r["both"], 0],
             r["az"][r["both"], 1]) for r in runs]
    single = [fit_hub_model(*a) for a in args]
    joint = fit_hub_model_joint(args)
    sec["hub"] = time.perf_counter() - tic
    r_true = np.array([truth.hubs["front"]["radius_m"], truth.hubs["rear"]["radius_m"]])
    err_single = np.array([m.radius_horizontal(lf, lr) - r_true for m in single])
    err_joint = joint[0].radius_horizontal(lf, lr) - r_true
    pose_err = {"none": [], "single": [], "joint": [], "joint_cw": []}
    vel_err = {s: [] for s in SMOOTHINGS}
    yaw_std = []
    for r, m_single, m_joint in zip(runs, single, joint):
        sy, both, rt = r["sy"], r["both"], r["rt"]
        pf, pr = sy.p_front_local[both], sy.p_rear_local[both]
        std_f = point_std_m(cal.prism_tracker["front"], pf, origin[cal.prism_tracker["front"]])
        std_r = point_std_m(cal.prism_tracker["rear"], pr, origin[cal.prism_tracker["rear"]])
        st = rt.states
        i = _nearest(st.t_utc_ns * 1e-9, sy.t_utc[both])
        for key, model, sense in (("none", None, -1), ("single", m_single, -1), ("joint", m_joint, -1),
                                  ("joint_cw", m_joint, 1)):
            tic = time.perf_counter()
            if model is None:
                qf, qr = pf, pr
            else:
                qf, qr = model.correct(pf, pr, r["az"][both, 0], r["az"][both, 1], sense=sense)
            poses = fit_poses(sy.t_utc[both], qf, qr, lf, lr, std_f[:, None].repeat(3, 1), std_r[:, None].repeat(3, 1))
            if key == "joint":
                sec["poses"] += time.perf_counter() - tic
                yaw_std.append(poses.yaw_std)
                best = poses
            d_yaw = (poses.yaw - st.psi[i] + np.pi) % (2 * np.pi) - np.pi
            pose_err[key].append(np.column_stack([poses.x - st.x[i], poses.y - st.y[i], d_yaw]))
        inputs = InputSeries(t=r["raw"].t_joy_utc, u1=r["raw"].u_joy[:, 0], u2=r["raw"].u_joy[:, 1])
        for s in SMOOTHINGS:
            tic = time.perf_counter()
            b = body_states_from_poses(best, inputs, s)
            sec["states"] += time.perf_counter() - tic
            vel_err[s].append(np.column_stack([b.vx - st.vx[i], b.vy - st.vy[i], b.omega - st.omega[i]]))
    figures = {"err_single": err_single, "err_joint": err_joint, "n": n_total, "sec": sec}
    durations = "table 6.4 durations" if truth.minutes is None else f"{truth.minutes:g} min"
    lines = [f"Campaign `{root.name}` ({len(runs)} of {len(truth.runs)} runs, {n_total} poses; "
             f"truth seed {truth.seed}, {durations}):", "",
             f"- hub radii (horizontal, truth {r_true[0] * 1e3:.4f} / {r_true[1] * 1e3:.4f} mm): per-run fits "
             f"max |error| {np.abs(err_single[:, 0]).max() * 1e6:.1f} / {np.abs(err_single[:, 1]).max() * 1e6:.1f} um; "
             f"joint fit error {err_joint[0] * 1e6:+.1f} / {err_joint[1] * 1e6:+.1f} um "
             f"(+- {joint[0].radius_std_m[0] * 1e6:.1f} / {joint[0].radius_std_m[1] * 1e6:.1f} um)",
             f"- runs not synchronised by `identification.preprocessing.sync` (skipped): {'; '.join(skipped) or 'none'}",
             f"- baseline RMS before/after the joint model, mean over runs: "
             f"{np.mean([m.rms_before_m for m in joint]) * 1e3:.4f} / "
             f"{np.mean([m.rms_after_m for m in joint]) * 1e3:.4f} mm"]
    floor_deg = np.degrees(np.sqrt(np.mean(np.concatenate(yaw_std) ** 2)))
    lines += ["", "| hub correction before poses | position RMS [mm] | yaw RMS [deg] |", "|---|---|---|"]
    for key, label in (("none", "none (thesis)"), ("single", "per-run eq. 5.25"), ("joint", "joint eq. 5.25"),
                       ("joint_cw", "joint eq. 5.25, opposite turning sense (sense=+1, wrong)")):
        e = np.concatenate(pose_err[key])
        lines.append(f"| {label} | {np.sqrt(np.mean(e[:, 0] ** 2 + e[:, 1] ** 2)) * 1e3:.4f} | "
                     f"{np.degrees(np.sqrt(np.mean(e[:, 2] ** 2))):.5f} |")
    lines += ["", f"Yaw noise floor from the tracker sigmas (RMS of the a priori `yaw_std`): {floor_deg:.5f} deg.", "",
              "| s (eq. 5.68) | vx RMS [mm/s] | vy RMS [mm/s] | omega RMS [deg/s] |", "|---|---|---|---|"]
    for s in SMOOTHINGS:
        e = np.concatenate(vel_err[s])
        r = np.sqrt(np.nanmean(e**2, axis=0))
        lines.append(f"| {s:g} | {r[0] * 1e3:.3f} | {r[1] * 1e3:.3f} | {np.degrees(r[2]):.4f} |")
    lines += ["", f"Stage wall time over the campaign: hub models {sec['hub']:.2f} s, poses {sec['poses']:.2f} s, "
              f"states ({len(SMOOTHINGS)} smoothing factors) {sec['states']:.2f} s."]
    return lines, figures


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="*", default=[0, 2, 3])
    parser.add_argument("--minutes", type=float, default=8.0, help="length of the campaigns of seeds other than 0")
    args = parser.parse_args()
    cmd = "`.venv/bin/python -m bench.bench_poses " + " ".join(sys.argv[1:]) + "`"
    lines = ["## Hub model, poses, body-frame states (identification/hub.py, poses.py, states.py)", "",
             f"Command: {cmd}", "",
             f"Load average at start (2 cores shared with other work): {os.getloadavg()[0]:.1f}.", ""]
    lines += bench_speed()
    for seed in args.seeds:
        root = campaign_dir(seed, None if seed == 0 else args.minutes)
        more, _ = bench_accuracy(root)
        lines += [""] + more
        print(f"seed {seed} done", flush=True)
    out = ROOT / "bench" / "results" / "poses.md"
    atomic_write_text(out, "\n".join(lines) + "\n")
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
