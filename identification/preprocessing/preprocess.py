"""The preprocessing chain of thesis section 5.2: a tracker campaign to a trajectory campaign.

``read -> calibrate -> per run: sync -> hub model -> poses -> states -> write``:

- reading and validating the bags: :mod:`identification.preprocessing.io_tracker`;
- calibration from the raw survey (5.1, 5.2.1): :mod:`identification.preprocessing.calibration`;
- clock synchronisation and the AT960 offset (5.2.2): :mod:`identification.preprocessing.sync`
  (with :mod:`identification.preprocessing.clock_sync` and :mod:`identification.preprocessing.extra_offset`);
- turning-hub eccentricity model (5.2.3, eq. 5.25): :mod:`identification.preprocessing.hub`;
- poses (5.2.4, eqs. 5.26 to 5.37): :mod:`identification.preprocessing.poses`;
- body-frame states (5.3.5, eqs. 5.64 to 5.68): :mod:`identification.preprocessing.states`;
- writing the trajectory campaign: :mod:`identification.preprocessing.trajectory`;
- the figures of each step, on request: :mod:`identification.preprocessing.figures`.

A run that cannot go on (a missing topic, no gaps, trackers that disagree) is skipped with a
warning and listed in the result, so that the other runs go on; a run cut at clock resets is
processed part by part (``<run>.1``, ``<run>.2``). Every count (matched, lost and spurious
triggers, dropped samples, trigger times with only one prism, messages stored out of stamp
order, NaN points, truncated bags) is in the result's JSON.

Where this departs from the thesis, and why (each measured on simulated campaigns against their
truth, see ``bench/results/preprocess.md``):

- the clock model is refitted on every matched sample, not only on the gaps (drift std of the
  LTD800 ~0.001 ppm instead of ~0.01 on short runs), which also counts lost/spurious pulses;
- the AT960 offset is estimated jointly with the eq. 5.25 hub terms: the eccentricity along the
  baseline correlates with the speed and biased the thesis's estimate by up to ~90 us; the
  hubs' delay behind their commands is estimated from the baseline too and used for the hub
  model (offset error RMS on 36 short simulated runs 3.4 us instead of 5.8 us without it);
- dropouts are neutral in the gap signal and the coarse shift is re-centred on the gap pairs
  before the 4 ms matching (short runs with a dropout were misaligned otherwise);
- tracker positions are interpolated with a cubic spline through the samples matched to
  triggers, not linearly (up to 0.7 mm error across a lost pulse in a turn);
- the prisms are referred to the hub axes with the eq. 5.25 model before the poses
  (``hub_correction``; without it the yaw RMS is ~0.018 deg instead of ~0.002 deg);
- the offset also gets a jackknife standard deviation, since eq. 5.21's only measures how well
  ten samples lie on a parabola (thesis 7.3.2).
"""

from __future__ import annotations

import logging
import time
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from groundfloor.adjustment import VarianceFactorTest
from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json, check_output_dir
from groundfloor.parallel import Workers, parallel_map
from groundfloor.types import BodyStates, InputSeries, PoseTrack, RawRun, TrajectoryRun, check_poses_move
from identification.preprocessing.calibration import Calibration, calibrate
from identification.preprocessing.extra_offset import azimuth_at
from identification.preprocessing.hub import HubModel, fit_hub_model
from identification.preprocessing.io_motion import write_run_motion
from identification.preprocessing.io_sensors import read_sensors_config, write_run_gnss
from identification.preprocessing.io_survey import read_survey
from identification.preprocessing.io_tracker import (
    BagRun,
    ReadFacts,
    check_point_units,
    read_campaign_yaml,
    read_run_groups,
    read_tracker_parts,
)
from identification.preprocessing.poses import fit_poses_full
from identification.preprocessing.states import body_states_from_poses
from identification.preprocessing.sync import SyncedRun, sync_run
from identification.preprocessing.trajectory import write_trajectory_campaign

log = logging.getLogger(__name__)

REPORT_FILE = "preprocess.json"  # in the output folder: the --json dict of the run
DEFAULT_SMOOTHING = 0.0005  # thesis table 5.1 tests 0, 0.0005, 0.005, 0.01 (eq. 5.68)
TIMING_ERROR_R = 0.5  # |r| of baseline variation vs speed above which a timing error is reported
HUB_CORRECTION = True  # refer the prisms to the hub axes with the eq. 5.25 model before poses

# Per-coordinate point noise std ``a + b * range`` from the repeatability of thesis table 3.2,
# read as 2 sigma (AT960 7.5 um + 3 um/m; LTD800 12 um near, 5 um/m far): the instruments'
# specification, the only a priori the pose adjustment (5.2.4) has.
REPEATABILITY_STD = {"at960": (3.75e-6, 1.5e-6), "ltd800": (3.0e-6, 2.5e-6)}


@dataclass(frozen=True)
class RunResult:
    """Everything preprocessing found for one run."""

    synced: SyncedRun
    hub: HubModel | None  # None without hub azimuths
    poses: PoseTrack
    states: BodyStates
    inputs: InputSeries
    n_one_prism: int  # trigger times where only one prism was seen (no pose)
    n_no_prism: int  # trigger times where neither was seen
    seconds: dict[str, float]  # stage -> wall time
    facts: ReadFacts | None = None  # what reading found, of a bag run
    pose_test: VarianceFactorTest | None = None  # global test of the pose adjustment over the run's epochs


@dataclass(frozen=True)
class PreprocessResult:
    """The outcome of :func:`preprocess_campaign`: calibration, runs, skipped runs, timings."""

    out_dir: Path
    name: str
    calibration: Calibration
    runs: dict[str, RunResult]
    skipped: dict[str, str]  # run -> one-line reason
    smoothing: float
    hub_correction: bool = HUB_CORRECTION
    seconds: dict[str, float] = field(default_factory=dict)  # stage -> total wall time
    sensors: dict = field(default_factory=dict)  # recorded sensors: kind -> run -> counts (issue 16)

    def to_json_dict(self) -> dict:
        """Return the ``preprocess --json`` dict: the INTERFACES.md keys and more."""
        out = self.calibration.to_json_dict()
        out["runs"] = {name: run_json(r) for name, r in self.runs.items()}
        out["skipped_runs"] = dict(self.skipped)
        out["smoothing"] = self.smoothing
        out["hub_correction"] = self.hub_correction
        out["out_dir"] = str(self.out_dir)
        out["seconds"] = {k: round(v, 3) for k, v in self.seconds.items()}
        if self.sensors:
            out["sensors"] = self.sensors
        return out


def run_json(r: RunResult) -> dict:
    """Return the JSON dict of one run (clock, offset, baseline, timing error, counts, hub)."""
    s = r.synced
    clock = {k: {"drift_ppm": c.drift_ppm, "drift_std_ppm": c.drift_std_ppm, "offset_std_s": c.d_std,
                 "residual_std_s": c.residual_std, "n_gaps": c.n_gaps_tracker,
                 "n_gaps_matched": c.n_gaps_matched, "n_fit": c.n_fit,
                 "xcorr_peak_ratio": c.xcorr_peak_ratio}
             for k, c in s.clock.items()}
    out = {
        "split": s.split,
        "t0_utc": s.t0_utc,
        "clock": clock,
        "at960_extra_offset_s": s.offset.dt if s.offset_tracker == "at960" else -s.offset.dt,
        "at960_extra_offset_std_s": s.offset.dt_std,
        "at960_extra_offset_std_jackknife_s": s.offset.dt_std_jackknife,
        "at960_extra_offset_without_hub_s": (s.offset.dt_without_hub if s.offset_tracker == "at960"
                                             else -s.offset.dt_without_hub),
        "offset_joint_with_hub": s.offset.hub_terms,
        "hub_delay_s": s.offset.hub_delay_s,
        "extra_offset_tracker": s.offset_tracker,
        "baseline_rms_m": {"before": s.baseline_rms_m("before"), "after": s.baseline_rms_m("after")},
        "timing_error": {"r_baseline_speed_before": s.r_speed_before,
                         "r_baseline_speed_after": s.r_speed_after,
                         "detected": bool(abs(s.r_speed_before) > TIMING_ERROR_R),
                         "late_tracker": s.offset_tracker},
        "counts": {"triggers": int(s.s_trigger.size), "poses": int(r.poses.t.size),
                   "one_prism_only": r.n_one_prism, "no_prism": r.n_no_prism,
                   **{k: c.to_dict() for k, c in s.counts.items()}},
        "seconds": {k: round(v, 4) for k, v in r.seconds.items()},
        **reading_json(r),
    }
    if r.pose_test is not None:
        out["pose_variance_factor_test"] = r.pose_test.to_json()
    if r.hub is not None:
        out["hub"] = hub_json(r.hub)
        rms_after = out["hub"].get("rms_after_m")
        if rms_after is not None:
            out["baseline_rms_m"]["after_hub_model"] = rms_after
    return out


def reading_json(r: RunResult) -> dict:
    """Return what reading the bags found: reorderings, NaN points, truncation, clock resets.

    ``reordered`` (topic -> messages stored right after one with a later stamp, sorted),
    ``nan_points_dropped`` (topic -> tracker samples with NaN coordinates, kept for the clock
    only), ``repeated_stamps_dropped``, ``truncated`` (bags read up to their damage),
    ``clock_resets`` (of the run a part was cut from), ``part_of`` (that run, or null),
    ``parts_dropped`` (why a part too short was dropped) and ``unstamped_receive_time`` (topic ->
    header stamps never set, timed by their bag time).
    """
    out = {"nan_points_dropped": {f"/{k}/measurement": int(c.dropped_nan)
                                  for k, c in r.synced.counts.items()}}
    if r.facts is not None:
        out.update(r.facts.to_json_dict())
    return out


def hub_json(hub: HubModel) -> dict:
    """Return the JSON dict of a turning-hub model (eq. 5.25): c, radii, phases, stds, RMS."""
    r, r_std = hub.radius_m, hub.radius_std_m
    phi, phi_std = hub.phase_rad, hub.phase_std_rad
    # r1, r2 (and their stds) in metres, as eq. 5.25 names them; sindy_ekf.report.html reads them
    return {"c_m": hub.c_m, "c_std_m": hub.c_std_m, "r1": float(r[0]), "r2": float(r[1]),
            "r1_std": float(r_std[0]), "r2_std": float(r_std[1]),
            "phi1_rad": float(phi[0]), "phi2_rad": float(phi[1]),
            "phi1_std_rad": float(phi_std[0]), "phi2_std_rad": float(phi_std[1]),
            "rms_before_m": hub.rms_before_m, "rms_after_m": hub.rms_after_m, "n": int(hub.n)}


def point_std_m(tracker: str, p_local: np.ndarray, origin_local: np.ndarray) -> np.ndarray:
    """Return the (n,) per-coordinate std of a tracker's points from its range (table 3.2)."""
    a, b = REPEATABILITY_STD[tracker]
    return a + b * np.linalg.norm(p_local - origin_local, axis=1)


def inputs_from_raw(raw: RawRun) -> InputSeries:
    """Return the joystick inputs as recorded (UTC stamps, u1 throttle, u2 steering)."""
    return InputSeries(t=raw.t_joy_utc.copy(), u1=raw.u_joy[:, 0].copy(), u2=raw.u_joy[:, 1].copy())


def preprocess_run(raw: RawRun, calibration: Calibration, smoothing: float = DEFAULT_SMOOTHING,
                   hub_correction: bool = HUB_CORRECTION) -> RunResult:
    """Return one run preprocessed: synchronised, hub model, poses and body-frame states.

    With ``hub_correction`` the prism positions are referred to the hub axes with the fitted
    eccentricity model (:meth:`identification.preprocessing.hub.HubModel.correct`) before the poses; the
    thesis (5.2.3) only used the model to explain the baseline variation.

    Raises
    ------
    InputError
        If the run cannot be synchronised or has too few poses (names the run).
    """
    sec = {}
    tic = time.perf_counter()
    tf = calibration.transform
    synced = sync_run(raw, tf.R_at960_ltd800, tf.t_at960_ltd800, calibration.prism_tracker)
    sec["sync"] = time.perf_counter() - tic

    tic = time.perf_counter()
    both = synced.both_seen
    seen = np.isfinite(synced.p_front_local[:, 0]).astype(int) + np.isfinite(synced.p_rear_local[:, 0])
    hub = None
    if raw.t_hub_utc.size:
        # the hubs' angles: their commands delayed as the offset estimate found (sync)
        az = azimuth_at(synced.t_utc - synced.offset.hub_delay_s, raw.t_hub_utc, raw.hub_azimuth)
        ok = both & np.isfinite(az).all(axis=1)
        try:
            hub = fit_hub_model(synced.s_trigger[ok], synced.baseline_after_m[ok],
                                az[ok, 0], az[ok, 1])
        except InputError as exc:
            log.warning("run %s: no hub model: %s", raw.name, exc)
    sec["hub"] = time.perf_counter() - tic

    tic = time.perf_counter()
    if both.sum() < 100:
        raise InputError(f"run {raw.name}: only {int(both.sum())} trigger times with both "
                         "prisms seen")
    origin = {"at960": np.zeros(3), "ltd800": np.asarray(tf.t_at960_ltd800)}
    p_front, p_rear = synced.p_front_local[both], synced.p_rear_local[both]
    if hub is not None and hub_correction:
        az_b = az[both]
        ok = np.isfinite(az_b).all(axis=1)
        pf, pr = hub.correct(p_front[ok], p_rear[ok], az_b[ok, 0], az_b[ok, 1])
        p_front, p_rear = p_front.copy(), p_rear.copy()
        p_front[ok], p_rear[ok] = pf, pr
    std = {}
    for prism, p in (("front", p_front), ("rear", p_rear)):
        tracker = calibration.prism_tracker[prism]
        std[prism] = np.repeat(point_std_m(tracker, p, origin[tracker])[:, None], 3, axis=1)
    levers = calibration.lever_arms_body
    pose_fit = fit_poses_full(synced.t_utc[both], p_front, p_rear, levers["front"], levers["rear"],
                              std["front"], std["rear"])
    poses = pose_fit.track
    sec["poses"] = time.perf_counter() - tic
    check_poses_move(poses.x, poses.y, poses.yaw, f"run {raw.name}")

    tic = time.perf_counter()
    inputs = inputs_from_raw(raw)
    states = body_states_from_poses(poses, inputs, smoothing)
    sec["states"] = time.perf_counter() - tic
    return RunResult(synced=synced, hub=hub, poses=poses, states=states, inputs=inputs,
                     n_one_prism=int((seen == 1).sum()), n_no_prism=int((seen == 0).sum()),
                     seconds=sec, facts=raw.facts if isinstance(raw, BagRun) else None,
                     pose_test=pose_fit.variance_factor_test)


def _read_and_process(job: tuple) -> list[tuple[str, RunResult | None, str | None]]:
    """Read one run's bags and preprocess it, or each of its parts between clock resets (a
    worker: one run per call, in any process); return ``(name, result, reason)`` per part."""
    root, name, split, survey, calibration, smoothing, hub_correction, plots_dir = job
    tic = time.perf_counter()
    try:
        parts = read_tracker_parts(Path(root) / "runs" / name, name, split)
    except InputError as exc:
        return [(name, None, str(exc))]
    t_read = (time.perf_counter() - tic) / len(parts)
    done = []
    for raw in parts:
        try:
            check_point_units(raw, survey)
            result = preprocess_run(raw, calibration, smoothing, hub_correction)
        except InputError as exc:
            done.append((raw.name, None, str(exc)))
            continue
        seconds = {**result.seconds, "read": t_read}
        if plots_dir is not None:
            tic = time.perf_counter()
            # local: the figures module loads matplotlib, a heavy import only --plots needs
            from identification.preprocessing.figures import plot_run

            plot_run(raw, result, Path(plots_dir) / raw.name)
            seconds["plots"] = time.perf_counter() - tic
        done.append((raw.name, replace(result, seconds=seconds), None))
    return done


def _run_group(name: str, r: RunResult, given: dict[str, str]) -> str:
    """Return a preprocessed run's group: as given in campaign.yaml for the run (or the run a part
    was cut from), else that run's name for a part, else "" (the run alone)."""
    whole = r.facts.part_of if r.facts is not None and r.facts.part_of else None
    return given.get(whole or name, whole or "")


def preprocess_campaign(campaign_dir: str | Path, out_dir: str | Path,
                        smoothing: float = DEFAULT_SMOOTHING, force: bool = False,
                        plots_dir: str | Path | None = None, jobs: Workers | int = 1,
                        hub_correction: bool = HUB_CORRECTION) -> PreprocessResult:
    """Return the preprocessing of a tracker campaign, written as a trajectory campaign.

    Parameters
    ----------
    campaign_dir : path
        A tracker campaign (data contract part 1).
    out_dir : path
        Where the trajectory campaign goes (INTERFACES.md, files of ``preprocess --out``);
        written atomically: either all of it appears or nothing changes.
    smoothing : float
        Spline smoothing factor ``s`` of eq. 5.68 for the body-frame states.
    force : bool
        Replace a non-empty ``out_dir``.
    plots_dir : path, optional
        If given, the figures of each step (thesis figs. 5.1 to 5.7, 7.2, 7.3) are saved there,
        one folder per run.
    jobs : int or groundfloor.parallel.Workers
        Runs processed in parallel (local processes, or a Dask scheduler); runs are independent
        after calibration.
    hub_correction : bool
        Refer the prisms to the hub axes with each run's eq. 5.25 model before the poses.

    Raises
    ------
    InputError
        On bad input that stops the whole campaign (no campaign.yaml, bad calibration, output
        folder not writable, no usable run). Single bad runs are skipped, logged and listed.
    """
    check_output_dir(out_dir, force=force)  # fail before the work, not after it
    root = Path(campaign_dir)
    seconds: dict[str, float] = {}
    tic = time.perf_counter()
    name, run_list = read_campaign_yaml(root)
    sensors_config = read_sensors_config(root)  # an unknown sensor type fails before the work
    if not (root / "calibration.yaml").is_file():
        if any((root / "runs").glob("*/poses.csv")) or any((root / "runs").glob("*/poses.tum")):
            raise InputError(f"{root}: a trajectory campaign (runs/*/poses.csv): preprocessed already; identify, "
                             "evaluate, benchmark and diagnose take it as it is")
        raise InputError(f"{root}: calibration.yaml missing")
    survey = read_survey(root / "calibration.yaml")
    calibration = calibrate(survey)
    seconds["calibrate"] = time.perf_counter() - tic

    jobs_args = [(root, n, split, survey, calibration, smoothing, hub_correction, plots_dir)
                 for n, split in run_list]
    tic = time.perf_counter()
    done = [part for parts in parallel_map(_read_and_process, jobs_args, jobs, desc="preprocess",
                                           names=[f"run {n}" for n, _ in run_list])
            for part in parts]
    seconds["runs_wall"] = time.perf_counter() - tic
    runs: dict[str, RunResult] = {}
    skipped: dict[str, str] = {}
    for run_name, result, reason in done:
        if result is None:
            log.warning("skipping %s", reason)
            skipped[run_name] = reason
        else:
            runs[run_name] = result
    if not runs:
        raise InputError(f"{campaign_dir}: no run could be preprocessed "
                         f"(first: {next(iter(skipped.values()), 'none')})")
    for stage in ("read", "sync", "hub", "poses", "states", "plots"):
        seconds[stage] = sum(r.seconds.get(stage, 0.0) for r in runs.values())

    tic = time.perf_counter()
    # a part of a run cut at a clock reset is of that run's group: cross-validation by group
    # never trains on one part and scores the other (campaign.yaml `group`)
    given = read_run_groups(root)
    traj = [(TrajectoryRun(name=n, split=r.synced.split, poses=r.poses, inputs=r.inputs,
                           group=_run_group(n, r, given)), r.states)
            for n, r in runs.items()]
    write_trajectory_campaign(out_dir, name, traj, force=force,
                              source=f"sindy-ekf preprocess {root.resolve()}",
                              ground_truth="laser trackers AT960 + LTD800 (thesis 5.2)",
                              skipped_runs=dict(skipped), **sensors_config.to_yaml())
    gnss = write_run_gnss(root, Path(out_dir), {n: r.poses.t for n, r in runs.items()})
    motion = write_run_motion(root, Path(out_dir), {n: r.poses.t for n, r in runs.items()})
    seconds["write"] = time.perf_counter() - tic
    result = PreprocessResult(out_dir=Path(out_dir), name=name, calibration=calibration,
                              runs=runs, skipped=skipped, smoothing=smoothing,
                              hub_correction=hub_correction, seconds=seconds,
                              sensors={**({"gnss": gnss} if gnss else {}), **motion})
    # the report beside the data (readers ignore unknown files); the data folder is complete
    # before it, so a crash in between loses only the report, never half the data
    atomic_write_json(Path(out_dir) / REPORT_FILE, result.to_json_dict())
    return result
