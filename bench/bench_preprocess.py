"""Preprocessing the full default campaign: wall time per stage, and accuracy against truth.

Usage: ``.venv/bin/python -m bench.bench_preprocess [--minutes M] [--seed N] [--jobs J]``;
writes ``bench/results/preprocess.md``. The campaign (45.4 min of driving, table 6.4, unless
``--minutes``) is simulated once into ``bench/_work/`` (gitignored) and reused.

Scored against ``truth/`` (which the pipeline never reads): clock drifts, the AT960's extra
offset, hub radii, pose position/yaw RMS, and body-frame velocity RMS per smoothing factor of
eq. 5.68 (thesis table 5.1: 0, 0.0005, 0.005, 0.01).
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import sys
import time
from pathlib import Path

import numpy as np

from groundfloor.files import atomic_write_text
from identification.preprocessing.preprocess import preprocess_campaign

ROOT = Path(__file__).resolve().parents[1]

SMOOTHINGS = (0.0, 0.0005, 0.005, 0.01)


def nearest(t_ref: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Return the index of the nearest ``t_ref`` for each ``t`` (both sorted)."""
    i = np.clip(np.searchsorted(t_ref, t), 1, t_ref.size - 1)
    return i - (np.abs(t_ref[i - 1] - t) < np.abs(t_ref[i] - t))


def score(result, truth) -> dict:
    """Return accuracy figures of a preprocessing result against the simulator's truth."""
    from identification.preprocessing.states import body_states_from_poses

    rows, err_p, err_yaw, err_v = [], [], [], {s: [] for s in SMOOTHINGS}
    for name, r in result.runs.items():
        t = truth.run(name)
        s = r.synced
        rows.append({
            "run": name,
            "ltd_drift_err_ppm": s.clock["ltd800"].drift_ppm - t.clocks["ltd800"]["drift_ppm"],
            "at_drift_err_ppm": s.clock["at960"].drift_ppm - t.clocks["at960"]["drift_ppm"],
            "at_drift_std_ppm": s.clock["at960"].drift_std_ppm,
            "offset_err_us": (s.offset.dt - t.at960["offset_s"]) * 1e6,
            "offset_std_ns": s.offset.dt_std * 1e9,
            "offset_jack_us": s.offset.dt_std_jackknife * 1e6,
            "offset_nohub_err_us": (s.offset.dt_without_hub - t.at960["offset_s"]) * 1e6,
            "r_before": s.r_speed_before, "r_after": s.r_speed_after,
            "base_before_mm": s.baseline_rms_m("before") * 1e3,
            "base_after_mm": s.baseline_rms_m("after") * 1e3,
            "r1_mm": r.hub.radius_m[0] * 1e3 if r.hub is not None else np.nan,
            "r2_mm": r.hub.radius_m[1] * 1e3 if r.hub is not None else np.nan,
        })
        st = t.states
        i = nearest(st.t_utc, r.poses.t)
        err_p.append(np.linalg.norm(np.column_stack([r.poses.x - st.x[i], r.poses.y - st.y[i],
                                                     r.poses.z - st.z[i]]), axis=1))
        err_yaw.append(np.angle(np.exp(1j * (r.poses.yaw - st.psi[i]))))
        for sm in SMOOTHINGS:
            b = body_states_from_poses(r.poses, r.inputs, sm)
            j = nearest(st.t_utc, b.t)
            err_v[sm].append(np.column_stack([b.vx - st.vx[j], b.vy - st.vy[j], b.omega - st.omega[j]]))
    vel = {sm: np.sqrt(np.nanmean(np.concatenate(e) ** 2, axis=0)) for sm, e in err_v.items()}
    return {"rows": rows,
            "pos_rms_mm": float(np.sqrt(np.mean(np.concatenate(err_p) ** 2)) * 1e3),
            "yaw_rms_deg": float(np.degrees(np.sqrt(np.mean(np.concatenate(err_yaw) ** 2)))),
            "vel_rms": vel,
            "hub_truth_mm": (truth.hubs["front"]["radius_eq525_m"] * 1e3,
                             truth.hubs["rear"]["radius_eq525_m"] * 1e3)}


def stress(work: Path, seeds: list[int], minutes: float) -> list[str]:
    """Return markdown lines: the criteria checked on campaigns of other seeds, run by run."""
    from simulation.campaign import simulate_campaign
    from simulation.truth import read_truth

    rows, n_runs, worst = [], 0, {"ltd": 0.0, "z_at": 0.0, "off": 0.0}
    for seed in seeds:
        camp = work / f"stress_{minutes:g}min_seed{seed}"
        if not (camp / "campaign.yaml").is_file():
            simulate_campaign(camp, seed=seed, minutes=minutes, force=True)
        out = work / f"stress_{minutes:g}min_seed{seed}_out"
        shutil.rmtree(out, ignore_errors=True)
        res = preprocess_campaign(camp, out, jobs=2)
        truth = read_truth(camp, states=False)
        bad = []
        for name, r in res.runs.items():
            t, s = truth.run(name), r.synced
            e_l = s.clock["ltd800"].drift_ppm - t.clocks["ltd800"]["drift_ppm"]
            z_a = (s.clock["at960"].drift_ppm - t.clocks["at960"]["drift_ppm"]) / s.clock["at960"].drift_std_ppm
            e_o = (s.offset.dt - t.at960["offset_s"]) * 1e6
            worst = {"ltd": max(worst["ltd"], abs(e_l)), "z_at": max(worst["z_at"], abs(z_a)),
                     "off": max(worst["off"], abs(e_o))}
            if abs(e_l) > 0.05 or abs(z_a) > 3 or abs(e_o) > 20:
                bad.append(f"{name} ({e_l:+.3f} ppm, {z_a:+.1f} sigma, {e_o:+.1f} us)")
        n_runs += len(res.runs)
        rows.append(f"| {seed} | {len(res.runs)} | {len(res.skipped)} | {'; '.join(bad) or 'none'} |")
        print(rows[-1], flush=True)
    return ["", f"### Robustness over seeds ({minutes:g} min campaigns, 9 runs each)", "",
            f"`--stress {','.join(map(str, seeds))} --stress-minutes {minutes:g}`: {n_runs} runs; "
            f"worst LTD800 drift error {worst['ltd']:.4f} ppm (criterion 0.05), worst AT960 drift "
            f"error {worst['z_at']:.2f} of its own sigma (criterion 3), worst offset error "
            f"{worst['off']:.1f} us (criterion 20).", "",
            "| seed | runs | skipped | runs missing a criterion |", "|---:|---:|---:|---|", *rows, ""]


def _cpu_s() -> float:
    """Return the CPU seconds (user + system) of this process and its finished children."""
    import resource

    own, kids = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    return own.ru_utime + own.ru_stime + kids.ru_utime + kids.ru_stime


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--minutes", type=float, default=None, help="driving minutes (default 45.4)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--stress", default="", help="comma-separated seeds of extra campaigns "
                    "(``--stress-minutes`` long) checked against the criteria")
    ap.add_argument("--stress-minutes", type=float, default=2.25)
    args = ap.parse_args()
    from simulation.campaign import simulate_campaign
    from simulation.truth import read_truth

    tag = "default" if args.minutes is None else f"{args.minutes:g}min"
    work = ROOT / "bench" / "_work"
    camp = work / f"campaign_{tag}_seed{args.seed}"
    if not (camp / "campaign.yaml").is_file():
        tic = time.perf_counter()
        simulate_campaign(camp, seed=args.seed, minutes=args.minutes, force=True)
        print(f"simulated {camp} in {time.perf_counter() - tic:.1f} s", flush=True)
    out = work / f"preprocessed_{tag}_seed{args.seed}"
    shutil.rmtree(out, ignore_errors=True)
    load = os.getloadavg()
    cpu0 = _cpu_s()
    tic = time.perf_counter()
    result = preprocess_campaign(camp, out, jobs=args.jobs)
    wall = time.perf_counter() - tic
    cpu = _cpu_s() - cpu0
    print(f"preprocessed in {wall:.1f} s", flush=True)
    sc = score(result, read_truth(camp))
    n_poses = sum(r.poses.t.size for r in result.runs.values())
    minutes = sum(r.synced.s_trigger[-1] for r in result.runs.values()) / 60

    cmd = "   ".join(["`.venv/bin/python -m bench.bench_preprocess", *sys.argv[1:]]).replace("   ", " ") + "`"
    sec = result.seconds
    lines = [
        "## Preprocessing (issue 3): tracker campaign to poses and body-frame states", "",
        f"Command: {cmd} (campaign: `simulate_campaign(seed={args.seed}, minutes={args.minutes})`, "
        f"{len(result.runs)} runs, {minutes:.1f} min of triggers, {n_poses} poses; "
        f"{len(result.skipped)} runs skipped).", "",
        f"**Wall time: {wall:.1f} s** with `jobs={args.jobs}` on 2 cores (target: at most 60 s for "
        f"the full default campaign); load average {load[0]:.1f} before and "
        f"{os.getloadavg()[0]:.1f} after (the machine is shared by other jobs). CPU time "
        f"{cpu:.1f} s in all (this process and its workers), i.e. about {cpu / 2:.1f} s of wall "
        "time on 2 otherwise idle cores.", "",
        "| stage | seconds |", "|---|---:|",
        *[f"| {k} | {v:.2f} |" for k, v in sec.items()],
        "", "Stages `read` to `plots` are summed over runs (CPU time across the workers); "
        "`runs_wall` is their wall time.", "",
        "### Accuracy against truth", "",
        f"- pose position RMS **{sc['pos_rms_mm']:.3f} mm** (target 0.5 mm), yaw RMS "
        f"**{sc['yaw_rms_deg']:.4f} deg** (target 0.01 deg). Noise floor from the tracker noise "
        "(table 3.2, 8-20 um per coordinate): about 0.01-0.02 mm in position and "
        "sqrt(2)*15 um / 0.77 m = 0.0016 deg in yaw per pose, so the figures are at the noise "
        "floor. They need the hub-axis correction with the eq. 5.25 model (default; the thesis did "
        "not correct): without it (`hub_correction=False`) the yaw RMS on the 4-minute seed-1 "
        "campaign is 0.018 deg, above the target; with the thesis's linear interpolation instead "
        "of the cubic one the position RMS there is 0.046 mm instead of 0.026 mm.",
        f"- hub radii (eq. 5.25), median over runs: r1 {np.nanmedian([r['r1_mm'] for r in sc['rows']]):.4f} mm, "
        f"r2 {np.nanmedian([r['r2_mm'] for r in sc['rows']]):.4f} mm; truth "
        f"{sc['hub_truth_mm'][0]:.4f} / {sc['hub_truth_mm'][1]:.4f} mm.", "",
        "Body-frame velocity RMS against truth per smoothing factor s (eq. 5.68):", "",
        "| s | vx [mm/s] | vy [mm/s] | omega [mrad/s] |", "|---:|---:|---:|---:|",
        *[f"| {sm:g} | {v[0] * 1e3:.2f} | {v[1] * 1e3:.2f} | {v[2] * 1e3:.2f} |" for sm, v in sc["vel_rms"].items()],
        "", "Per run (errors = estimate - truth; r = Pearson correlation of the baseline-length "
        "variation with forward speed before/after the offset correction):", "",
        "Offset: the joint estimate with the eq. 5.25 hub terms (default), its eq. 5.21 std and its "
        "jackknife std over ten time blocks; and the error of the thesis's estimate without the "
        "hub terms.", "",
        "| run | LTD800 drift err [ppm] | AT960 drift err [ppm] (std) | offset err [us] "
        "(eq. 5.21 std ns, jackknife std us) | thesis offset err [us] | "
        "r before | r after | baseline RMS before/after [mm] |",
        "|---|---:|---:|---:|---:|---:|---:|---:|",
        *[f"| {r['run']} | {r['ltd_drift_err_ppm']:+.4f} | {r['at_drift_err_ppm']:+.3f} "
          f"({r['at_drift_std_ppm']:.3f}) | {r['offset_err_us']:+.2f} ({r['offset_std_ns']:.0f} ns, "
          f"{r['offset_jack_us']:.2f} us) | {r['offset_nohub_err_us']:+.2f} | "
          f"{r['r_before']:+.2f} | {r['r_after']:+.2f} | {r['base_before_mm']:.3f} / "
          f"{r['base_after_mm']:.3f} |" for r in sc["rows"]],
        "",
    ]
    if args.stress:
        lines += stress(work, [int(x) for x in args.stress.split(",")], args.stress_minutes)
    path = ROOT / "bench" / "results" / "preprocess.md"
    atomic_write_text(path, "\n".join(lines))
    print(json.dumps({"wall_s": wall, "pos_rms_mm": sc["pos_rms_mm"], "yaw_rms_deg": sc["yaw_rms_deg"]}))
    print(path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
