"""Simulator variants (issue 13, item 6) through bags and preprocessing: what was drawn, and how
well preprocessing recovers the truth on each.

Usage: ``python -m bench.bench_variants [--variants 0-10] [--minutes M] [--out DIR] [--jobs J]
[--no-write]`` from the checkout; writes ``bench/results/variants.md``. Each variant ``N`` is a
default-size campaign (45.4 min, thesis table 6.4, unless ``--minutes``) simulated with
``simulate_campaign(seed=N, variant=N)`` into ``DIR/variant_NN/campaign`` and preprocessed into
``DIR/variant_NN/trajectory``; both are kept and reused when present (``DIR`` defaults to
``bench/_work/variants``, gitignored). Variant 0 is the simulator before variants, the reference.

The base other benches score identification and diagnosis on: :func:`variant_campaigns` yields
the :class:`VariantCampaign` of each index (simulating and preprocessing what is missing), e.g.::

    from bench.bench_variants import variant_campaigns
    for vc in variant_campaigns(range(1, 11)):
        identify(vc.trajectory) ...          # vc.variant: the drawn Variant, vc.campaign: truth/

Scored against ``truth/`` as ``bench.bench_preprocess`` does: pose position and yaw RMS, clock
drift and AT960 offset errors, body-velocity RMS at the default smoothing.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import sys
import time
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from bench.bench_preprocess import nearest
from groundfloor.files import atomic_write_text
from identification.preprocessing.preprocess import DEFAULT_SMOOTHING, preprocess_campaign
from simulation.campaign import check_effects, simulate_campaign
from simulation.effects import effect_from_dict
from simulation.truth import read_truth
from simulation.variant import Variant
from simulation.variants import draw_variant

ROOT = Path(__file__).resolve().parents[1]
DEFAULT_OUT = ROOT / "bench" / "_work" / "variants"


@dataclass(frozen=True)
class VariantCampaign:
    """One variant's campaign on disk: the tracker campaign (with truth/) and its preprocessing."""

    index: int
    variant: Variant
    campaign: Path  # tracker campaign, data contract part 1, plus truth/
    trajectory: Path  # preprocess --out of it (trajectory campaign)
    simulate_s: float  # wall seconds spent simulating now (0: reused)
    preprocess_s: float  # wall seconds spent preprocessing now (0: reused)


def _matches(campaign: Path, index: int, minutes: float | None, effects: tuple) -> bool:
    """Return whether ``campaign`` is a finished simulation of this variant, size and effects."""
    file = campaign / "truth" / "truth.yaml"
    if not file.is_file():
        return False
    doc = yaml.safe_load(file.read_text())
    variant = (doc.get("variant") or {}).get("index", 0)
    return variant == index and doc["minutes"] == minutes and doc["seed"] == index and \
        [effect_from_dict(e) for e in doc["effects"]] == list(effects)


def variant_campaigns(indices: Iterable[int] = range(1, 11), out: str | Path = DEFAULT_OUT,
                      minutes: float | None = None, jobs: int = 2, preprocess: bool = True,
                      effects: tuple = ()) -> Iterator[VariantCampaign]:
    """Yield the campaign of each variant index, simulating and preprocessing what is missing.

    Campaign ``N`` is ``simulate_campaign(seed=N, variant=N, minutes=minutes, effects=effects)``
    in ``out/variant_NN/campaign`` (with effects, ``out/variant_NN_<effect>/``; ``effects`` are
    :class:`simulation.effects.Effect` or ``NAME[:FORM]=VALUE`` texts); a folder holding exactly
    that is reused. ``preprocess=False`` skips the trajectory campaign.
    """
    effects = check_effects(effects)
    tag = "_".join(re.sub(r"[^A-Za-z0-9.]+", "-", e.label()) for e in effects)
    for index in indices:
        folder = Path(out) / (f"variant_{index:02d}" + (f"_{tag}" if tag else ""))
        campaign, trajectory = folder / "campaign", folder / "trajectory"
        sim_s = pre_s = 0.0
        if not _matches(campaign, index, minutes, effects):
            shutil.rmtree(trajectory, ignore_errors=True)
            tic = time.perf_counter()
            simulate_campaign(campaign, seed=index, minutes=minutes, variant=index, effects=effects, force=True)
            sim_s = time.perf_counter() - tic
        if preprocess and not (trajectory / "campaign.yaml").is_file():
            tic = time.perf_counter()
            preprocess_campaign(campaign, trajectory, jobs=jobs, force=True)
            pre_s = time.perf_counter() - tic
        yield VariantCampaign(index, draw_variant(index), campaign, trajectory, sim_s, pre_s)


def _indices(text: str) -> list[int]:
    """Return the indices of ``"0-10"`` or ``"1,4,7"`` (ranges inclusive)."""
    out = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out += list(range(int(lo), int(hi or lo) + 1))
    return out


def _csv(path: Path) -> dict[str, np.ndarray]:
    """Return the columns of a trajectory campaign's CSV file by header name."""
    names = path.open().readline().strip().split(",")
    data = np.loadtxt(path, delimiter=",", skiprows=1, ndmin=2)
    return {n: data[:, i] for i, n in enumerate(names)}


def scores(vc: VariantCampaign) -> dict:
    """Return the accuracy of ``vc``'s preprocessing against its truth, from the files alone.

    The figures of ``bench.bench_preprocess`` (pose RMS, worst drift and offset errors, body
    velocities at the default smoothing), read from the trajectory campaign (``poses.csv``,
    ``states.csv``, ``preprocess.json``) so that reused campaigns are scored without preprocessing.
    """
    report = json.loads((vc.trajectory / "preprocess.json").read_text())
    truth = read_truth(vc.campaign)
    err_p, err_yaw, err_v, ltd, at_sigma, offset, n_poses = [], [], [], [], [], [], 0
    for name, r in report["runs"].items():
        t = truth.run(name)
        ltd.append(abs(r["clock"]["ltd800"]["drift_ppm"] - t.clocks["ltd800"]["drift_ppm"]))
        at = r["clock"]["at960"]
        at_sigma.append(abs(at["drift_ppm"] - t.clocks["at960"]["drift_ppm"]) / at["drift_std_ppm"])
        offset.append(abs(r["at960_extra_offset_s"] - t.at960["offset_s"]) * 1e6)
        poses, states = _csv(vc.trajectory / "runs" / name / "poses.csv"), _csv(vc.trajectory / "runs" / name / "states.csv")
        st = t.states
        i = nearest(st.t_utc, poses["t"])
        err_p.append(np.linalg.norm(np.column_stack([poses["x"] - st.x[i], poses["y"] - st.y[i], poses["z"] - st.z[i]]), axis=1))
        err_yaw.append(np.angle(np.exp(1j * (poses["yaw"] - st.psi[i]))))
        j = nearest(st.t_utc, states["t"])
        err_v.append(np.column_stack([states["vx"] - st.vx[j], states["vy"] - st.vy[j], states["omega"] - st.omega[j]]))
        n_poses += poses["t"].size
    return {"pos_rms_mm": float(np.sqrt(np.mean(np.concatenate(err_p) ** 2)) * 1e3),
            "yaw_rms_deg": float(np.degrees(np.sqrt(np.mean(np.concatenate(err_yaw) ** 2)))),
            "ltd_drift_ppm": max(ltd), "at_drift_sigma": max(at_sigma), "offset_us": max(offset),
            "vel": np.sqrt(np.nanmean(np.concatenate(err_v) ** 2, axis=0)),
            "n_runs": len(report["runs"]), "skipped": len(report.get("skipped_runs", {})), "n_poses": n_poses}


def _drawn(v: Variant) -> str:
    """Return one table cell of what the variant drew."""
    if v.is_default:
        return "model B, linear lateral law, no lag, OU noise, thesis driver 20 Hz, table 3.2 trackers"
    d = dict(v.draws)
    lat = v.lateral.form + (f" {v.lateral.shape:.3g}" if v.lateral.form != "linear" else "")
    noise = v.noise.form + (f" {v.noise.resonance_hz:.1f} Hz" if v.noise.form == "coloured" else
                            f" {v.robot.noise_corr_time_s * 1e3:.0f} ms")
    return (f"time x{d['time_scale_vx']:.2f}/{d['time_scale_omega']:.2f}, speed x{d['speed_scale']:.2f}/"
            f"{d['yaw_rate_scale']:.2f}, spread {d['coefficient_spread']:g} (max change {d['max_coefficient_change']:.0%}); "
            f"{lat}; lag {v.motor_lag_s * 1e3:.0f} ms; {noise}; {v.driver.style} {v.driver.joy_rate_hz:.0f} Hz; "
            f"trackers x{v.tracker_noise_scale[0]:.2f}/{v.tracker_noise_scale[1]:.2f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--variants", default="0-10", help="indices, e.g. 0-10 or 1,4,7 (0: the reference)")
    ap.add_argument("--minutes", type=float, default=None, help="driving minutes per campaign (default 45.4)")
    ap.add_argument("--out", type=Path, default=DEFAULT_OUT, help="where the campaigns are kept")
    ap.add_argument("--jobs", type=int, default=2)
    ap.add_argument("--no-write", action="store_true", help="do not write bench/results/variants.md")
    args = ap.parse_args()
    load0 = os.getloadavg()[0]
    rows = []
    for vc in variant_campaigns(_indices(args.variants), args.out, args.minutes, args.jobs):
        sc = scores(vc)
        d = dict(vc.variant.draws)
        rows.append((vc, sc))
        print(f"variant {vc.index}: simulated {vc.simulate_s:.0f} s, preprocessed {vc.preprocess_s:.0f} s, "
              f"pose {sc['pos_rms_mm']:.3f} mm / {sc['yaw_rms_deg']:.4f} deg, offset {sc['offset_us']:.1f} us, "
              f"top speed {d.get('top_speed_m_s', 0.81):.2f} m/s", flush=True)
    cmd = "`python -m bench.bench_variants " + " ".join(sys.argv[1:]) + "`"
    vel = ["{:.2f} / {:.2f} / {:.2f}".format(*(sc["vel"] * 1e3)) for _, sc in rows]
    others = [sc for vc, sc in rows if vc.index > 0]
    lines = [
        "## Simulator variants (issue 13, item 6): structure drawn from an index, through bags and preprocessing", "",
        f"Command: {cmd.strip()} (campaigns `simulate_campaign(seed=N, variant=N, minutes={args.minutes})`, "
        f"{'45.4 min, thesis table 6.4' if args.minutes is None else f'{args.minutes:g} min'} each, preprocessed "
        f"with `jobs={args.jobs}`; load average {load0:.1f} before, {os.getloadavg()[0]:.1f} after). Variant 0 "
        "is the simulator before variants (the reference); `simulate --variant 0` writes the same bytes as "
        "main (checked on 4-minute campaigns with every default-form effect, see docs/variants.md).", "",
        "What each variant drew (model B's coefficient scales per equation, the independent spread that "
        "passed the envelope check and the largest change of a coefficient; lateral law and shape; motor lag; "
        "process-noise spectrum; driver style and joystick rate; tracker noise scales):", "",
        "| variant | drawn | top speed m/s, yaw rad/s | simulate s |", "|---:|---|---|---:|",
        *[f"| {vc.index} | {_drawn(vc.variant)} | {dict(vc.variant.draws).get('top_speed_m_s', 0.811):.2f}, "
          f"{dict(vc.variant.draws).get('top_omega_rad_s', 1.149):.2f} | "
          + (f"{vc.simulate_s:.0f} |" if vc.simulate_s else "(reused) |") for vc, _ in rows],
        "", "Preprocessing against truth (errors = estimate - truth; worst run for drifts and offsets; body "
        f"velocities at the default smoothing s = {DEFAULT_SMOOTHING:g}):", "",
        "| variant | runs (skipped) | poses | pose RMS mm | yaw RMS deg | LTD800 drift ppm | AT960 drift sigma "
        "| offset us | vx / vy / omega RMS mm/s, mrad/s | preprocess s |",
        "|---:|---:|---:|---:|---:|---:|---:|---:|---|---:|",
        *[f"| {vc.index} | {sc['n_runs']} ({sc['skipped']}) | {sc['n_poses']} | {sc['pos_rms_mm']:.3f} | "
          f"{sc['yaw_rms_deg']:.4f} | {sc['ltd_drift_ppm']:.4f} | {sc['at_drift_sigma']:.2f} | "
          f"{sc['offset_us']:.1f} | {v} | " + (f"{vc.preprocess_s:.0f} |" if vc.preprocess_s else "(reused) |")
          for (vc, sc), v in zip(rows, vel)],
        "",
    ]
    if others:
        lines += [
            f"Over the {len(others)} variants: pose RMS at most **{max(s['pos_rms_mm'] for s in others):.3f} mm** "
            f"(target 0.5 mm), yaw RMS at most **{max(s['yaw_rms_deg'] for s in others):.4f} deg** (target "
            f"0.01 deg), worst LTD800 drift error {max(s['ltd_drift_ppm'] for s in others):.4f} ppm "
            f"(criterion 0.05), worst AT960 drift error {max(s['at_drift_sigma'] for s in others):.2f} sigma "
            f"(criterion 3), worst offset error {max(s['offset_us'] for s in others):.1f} us (criterion 20); "
            f"{sum(s['skipped'] for s in others)} runs skipped.", ""]
    if not args.no_write:
        path = ROOT / "bench" / "results" / "variants.md"
        atomic_write_text(path, "\n".join(lines))
        print(path)
    else:
        print("\n".join(lines))
    return 0


if __name__ == "__main__":
    sys.exit(main())
