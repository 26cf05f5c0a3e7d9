"""A simulated laser-tracker campaign, written exactly as the data contract (part 1) says.

``simulate_campaign`` drives the simulated Husky (``simulation.robot.simulate_run``) through
the nine runs of thesis table 6.4 and records what the instruments of chapter 4 would have
recorded: the Raspberry Pi trigger, both trackers (their clocks, edges, lost and spurious
pulses, dropouts and noise: :mod:`simulation.clocks`, :mod:`simulation.measurement`), the
turning hubs (:mod:`simulation.hubs`) and the joystick, in two ROS1 bags per run
(:mod:`simulation.bags`: the robot's and the tracker server's), plus ``calibration.yaml`` (the
survey, tables 6.1-6.3) and ``truth/`` (:mod:`simulation.truth`).

The true geometry is the thesis's result from that survey, so survey and simulation agree to
the survey's precision: LTD800-to-AT960 transform from table 7.2, lever arms from table 7.1,
hub eccentricities from table 7.5, clock drifts from table 7.3 and AT960 offsets from table 7.4
(each run's value plus a small random deviation). The body origin (centre of the wheel hubs)
runs at ``BODY_ORIGIN_Z_LOCAL_M``: the mean of the table-6.3 hub screw heads, transformed into
the leveled AT960 frame with table 7.2 (-1.2505 m); the simulator's ``z`` is added to it.
"""

from __future__ import annotations

import logging
import os
import shutil
from dataclasses import asdict
from datetime import datetime, timezone
from pathlib import Path

import numpy as np
import yaml

from groundfloor.errors import InputError
from groundfloor.files import atomic_output_dir, check_output_dir
from groundfloor.progress import progress
from simulation import bags
from simulation import truth as truth_io
from simulation.clocks import NS, TRIGGER_PERIOD_S, simulate_tracker_clock
from simulation.effects import Effect, parse_effect
from simulation.gnss_topic import check_gnss_spec, gnss_truth, record_fixes, write_gnss_bag, write_gnss_truth
from simulation.hubs import baseline_geometry
from simulation.motion_sensors import (
    ImuSpec,
    OdometrySpec,
    motion_truth,
    record_imu,
    record_odometry,
    write_motion_bag,
    write_motion_truth,
)
from simulation.tracker_run import RunSetup, simulate_tracker_run
from simulation.variant import Variant
from simulation.variants import check_variant

log = logging.getLogger(__name__)

# thesis table 6.4: run, length (s), split
RUNS_TABLE_6_4 = (
    ("run_01", 100.0, "test"), ("run_02", 390.0, "train"), ("run_03", 340.0, "train"),
    ("run_04", 300.0, "train"), ("run_05", 100.0, "test"), ("run_06", 470.0, "train"),
    ("run_07", 125.0, "train"), ("run_08", 440.0, "train"), ("run_09", 460.0, "test"),
)
MIN_RUN_S = 15.0
MAX_MINUTES = 600.0
# thesis table 7.3: clock drifts per run (ppm)
DRIFT_PPM_TABLE_7_3 = {
    "ltd800": (16.2078, 16.2395, 16.2986, 16.2387, 16.2179, 16.2666, 16.2801, 16.2976, 16.3236),
    "at960": (-28.6908, -28.4536, -28.4882, -28.5271, -28.6187, -28.5428, -28.6317, -28.5384, -28.5425),
}
# thesis table 7.4: additional AT960 offset (mean duty cycle) per run (s)
AT960_OFFSET_TABLE_7_4 = tuple(v * 1e-3 for v in (1.3180, 1.3179, 1.3537, 1.3312, 1.3247, 1.3536, 1.4718, 1.3454, 1.3517))
# thesis table 7.2: x_at960 = R (x_ltd800 + t_table), R = Rz Ry Rx
T_TABLE_7_2_M = (-2.050360, -8.757229, -0.086725)
ROTATION_TABLE_7_2_DEG = (-0.374896, -0.180820, 142.749476)  # rx, ry, rz
# thesis table 7.1: lever arms in the body frame (m)
LEVER_ARMS_TABLE_7_1_M = {"front": (0.4671355, 0.0655364, 0.5167336), "rear": (-0.2600713, -0.1627405, 0.6546911)}
# thesis table 7.5 (means): eccentricity radii as eq. 5.25 sees them (m)
HUB_RADIUS_TABLE_7_5_M = {"front": 0.21e-3, "rear": 0.12e-3}
BODY_ORIGIN_Z_LOCAL_M = -1.2505  # table 6.3 hub screw heads through table 7.2 (module docstring)
CAMPAIGN_START = datetime(2022, 12, 21, 9, 30, tzinfo=timezone.utc)  # thesis 6: 21.12.2022
CALIBRATION_YAML = Path(__file__).resolve().parent / "data" / "calibration.yaml"
# independently generated campaigns: every message its own receive latency (issue 14)
DEFAULT_RECEIVE_JITTER_S = (2e-3, 12e-3)
MAX_RECEIVE_LATENCY_S = 1.0
# A wider spread of latencies stores a topic's messages a trigger period or more out of stamp
# order, which the data contract reads as a clock reset, not a reordering.
MAX_RECEIVE_SPREAD_S = 0.5 * TRIGGER_PERIOD_S
RESET_TRACKERS = ("at960", "ltd800")


def rotation_from_deg(rx: float, ry: float, rz: float) -> np.ndarray:
    """Return ``Rz(rz) Ry(ry) Rx(rx)`` (eqs. 5.2 to 5.5) for angles in degrees."""
    a, b, c = np.radians([rx, ry, rz])
    Rx = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    Ry = np.array([[np.cos(b), 0, np.sin(b)], [0, 1, 0], [-np.sin(b), 0, np.cos(b)]])
    Rz = np.array([[np.cos(c), -np.sin(c), 0], [np.sin(c), np.cos(c), 0], [0, 0, 1]])
    return Rz @ Ry @ Rx


def true_transform() -> dict:
    """Return the true LTD800-to-AT960 transform (table 7.2) in both conventions."""
    R = rotation_from_deg(*ROTATION_TABLE_7_2_DEG)
    t_table = np.array(T_TABLE_7_2_M)
    return {"translation_m": (R @ t_table).tolist(), "rotation_deg": list(ROTATION_TABLE_7_2_DEG),
            "t_table_m": list(T_TABLE_7_2_M), "R": R.tolist()}


def run_durations(minutes: float | None) -> np.ndarray:
    """Return the nine run durations (s): table 6.4, or scaled to ``minutes`` in total.

    Scaling keeps the proportions of table 6.4 with every run at least ``MIN_RUN_S`` long
    (the short runs are lifted to the minimum and the others share the rest).
    """
    base = np.array([r[1] for r in RUNS_TABLE_6_4])
    if minutes is None:
        return base
    low = len(base) * MIN_RUN_S / 60.0
    if not np.isfinite(minutes) or not low <= minutes <= MAX_MINUTES:
        raise InputError(f"minutes={minutes}: out of range [{low}, {MAX_MINUTES}] (nine runs of at least {MIN_RUN_S:g} s)")
    total = minutes * 60.0
    fixed = np.zeros(len(base), dtype=bool)
    while not fixed.all():  # water-filling: at most nine passes
        scale = (total - MIN_RUN_S * fixed.sum()) / base[~fixed].sum()
        newly = ~fixed & (base * scale < MIN_RUN_S)
        if not newly.any():
            return np.where(fixed, MIN_RUN_S, base * scale)
        fixed |= newly
    return np.full(len(base), total / len(base))


def check_effects(effects) -> tuple:
    """Return ``effects`` as a tuple of ``simulation.effects.Effect``; parse ``NAME=VALUE`` strings."""
    out = []
    for e in effects or ():
        out.append(parse_effect(e) if isinstance(e, str) else e)
        if not isinstance(out[-1], Effect):
            raise InputError(f"effect {e!r}: not a simulation.effects.Effect or NAME=VALUE text")
    if len(out) > 1:
        raise InputError(f"effects {[f'{e.name}={e.value}' for e in out]}: only one effect per campaign")
    return tuple(out)


def check_receive_jitter(value) -> tuple[float, float] | None:
    """Return ``(lo, hi)`` receive latencies in seconds, or None; raise InputError if invalid.

    ``True`` is :data:`DEFAULT_RECEIVE_JITTER_S`; text is ``"LO,HI"`` in milliseconds (the
    command line's form).
    """
    if value is None or value is False:
        return None
    if value is True:
        return DEFAULT_RECEIVE_JITTER_S
    if isinstance(value, str):
        try:
            lo, hi = (float(v) * 1e-3 for v in value.split(","))
        except ValueError:
            raise InputError(f"receive jitter {value!r}: expected LO,HI in milliseconds, e.g. 2,12") from None
    else:
        lo, hi = (float(v) for v in value)
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 <= lo <= hi <= MAX_RECEIVE_LATENCY_S):
        raise InputError(f"receive jitter ({lo * 1e3:g}, {hi * 1e3:g}) ms: need 0 <= lo <= hi <= "
                         f"{MAX_RECEIVE_LATENCY_S * 1e3:g} ms")
    if hi - lo > MAX_RECEIVE_SPREAD_S + 1e-12:
        raise InputError(f"receive jitter ({lo * 1e3:g}, {hi * 1e3:g}) ms: a spread of {(hi - lo) * 1e3:g} ms "
                         f"stores messages more than half a trigger period out of stamp order, which the "
                         f"data contract reads as a clock reset; the spread may be at most "
                         f"{MAX_RECEIVE_SPREAD_S * 1e3:g} ms")
    return (lo, hi)


def check_clock_resets(value) -> dict[str, tuple[str, float]]:
    """Return ``{run: (tracker, fraction)}``: where a tracker clock restarts, checked.

    Accepts that dict or texts ``RUN[:TRACKER[:FRACTION]]`` (tracker ``at960`` and fraction 0.5
    of the run's trigger span by default); raises InputError naming what is wrong.
    """
    names = [r[0] for r in RUNS_TABLE_6_4]
    items = value.items() if isinstance(value, dict) else [(v, None) for v in value or ()]
    out = {}
    for key, spec in items:
        if spec is None:
            parts = str(key).split(":")
            if len(parts) > 3:
                raise InputError(f"clock reset {key!r}: expected RUN[:TRACKER[:FRACTION]]")
            run, tracker, fraction = parts + ["at960", "0.5"][len(parts) - 1:]
        else:
            run, (tracker, fraction) = key, spec
        try:
            fraction = float(fraction)
        except ValueError:
            raise InputError(f"clock reset {key!r}: fraction {fraction!r} is not a number") from None
        if run not in names:
            raise InputError(f"clock reset {key!r}: no run {run!r} (runs: {', '.join(names)})")
        if tracker not in RESET_TRACKERS:
            raise InputError(f"clock reset {key!r}: tracker {tracker!r} is not one of {', '.join(RESET_TRACKERS)}")
        if not 0.0 < fraction < 1.0:
            raise InputError(f"clock reset {key!r}: fraction {fraction:g} not inside (0, 1)")
        out[run] = (tracker, fraction)
    return out


def _robot_summary(variant: Variant) -> dict:
    """Return the robot's parameters as plain values for truth/ (``RobotParams`` as a dict)."""
    return truth_io._plain(asdict(variant.robot))


def _umask() -> int:
    mask = os.umask(0)
    os.umask(mask)
    return mask


def _bag_stamp(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns // NS, tz=timezone.utc).strftime("%Y-%m-%d-%H-%M-%S")


def _run_setup(r: int, duration_s: float, t0_ns: int, t_boot_ns: dict, rng: np.random.Generator,
               effect, receive_jitter_s=None, clock_reset=None, variant: Variant | None = None) -> RunSetup:
    """Return the true parameters of run ``r``: thesis tables 7.1-7.5 plus small deviations."""
    name, _, split = RUNS_TABLE_6_4[r]
    levers = {k: np.array(v) for k, v in LEVER_ARMS_TABLE_7_1_M.items()}
    transform = true_transform()
    return RunSetup(
        name=name, split=split, duration_s=float(duration_s), t0_ns=t0_ns,
        clocks={k: simulate_tracker_clock(DRIFT_PPM_TABLE_7_3[k][r] + rng.normal(0.0, 0.01), t_boot_ns[k], rng)
                for k in ("at960", "ltd800")},
        at960_duty_mean_s=AT960_OFFSET_TABLE_7_4[r] + rng.normal(0.0, 5e-6),
        lost_fraction=rng.uniform(0.002, 0.01), spurious_fraction=rng.uniform(0.001, 0.005),
        hub_radius_m=hub_radii_m(), hub_phase_rad={k: rng.uniform(-np.pi, np.pi) for k in ("front", "rear")},
        lever_arms_m=levers, R_at960_ltd800=np.array(transform["R"]),
        t_at960_ltd800=np.array(transform["translation_m"]), body_origin_z_m=BODY_ORIGIN_Z_LOCAL_M,
        ntp_offset_s=rng.choice([-1, 1]) * rng.uniform(1e-4, 1e-3), effect=effect,
        receive_jitter_s=receive_jitter_s, clock_reset=clock_reset, variant=variant or Variant(),
    )


def hub_radii_m() -> dict:
    """Return the physical eccentricity radii: table 7.5's eq.-5.25 radii over cos(elevation)."""
    cos_elev = baseline_geometry(np.array(LEVER_ARMS_TABLE_7_1_M["front"]), np.array(LEVER_ARMS_TABLE_7_1_M["rear"]))[1]
    return {k: v / cos_elev for k, v in HUB_RADIUS_TABLE_7_5_M.items()}


def _campaign_truth(seed, minutes, effects, runs, variant: Variant) -> truth_io.CampaignTruth:
    levers = {k: list(v) for k, v in LEVER_ARMS_TABLE_7_1_M.items()}
    radius = hub_radii_m()
    forms = any(not e.is_default_form for e in effects)
    return truth_io.CampaignTruth(
        seed=int(seed), minutes=None if minutes is None else float(minutes),
        effects=tuple((e.name, float(e.value)) for e in effects), transform=true_transform(),
        lever_arms_m=levers, body_origin_z_local_m=BODY_ORIGIN_Z_LOCAL_M,
        baseline_length_m=float(np.linalg.norm(np.subtract(levers["front"], levers["rear"]))),
        hubs={k: {"radius_m": radius[k], "radius_eq525_m": HUB_RADIUS_TABLE_7_5_M[k]} for k in radius},
        noise={s.name: {"a_m": s.noise_a_m, "b": s.noise_b, "timing_std_s": s.timing_std_s,
                        "resolution_s": s.resolution_s} for s in variant.trackers().values()},
        robot=_robot_summary(variant), runs=tuple(runs),
        effect_specs=tuple(e.to_dict() for e in effects) if forms else (),
        variant=None if variant.is_default else truth_io._plain(variant.to_dict()),
    )


def _campaign_yaml(seed, minutes, effects, receive_jitter_s=None, clock_resets=None,
                   variant: Variant | None = None, gnss=None, motion=()) -> str:
    what = "table 6.4 durations" if minutes is None else f"{minutes:g} min"
    effect = f", simulator variant {variant.index}" if variant is not None and not variant.is_default else ""
    effect += "".join(f", effect {e.label()}" for e in effects)
    if receive_jitter_s is not None:
        effect += f", receive jitter {receive_jitter_s[0] * 1e3:g}-{receive_jitter_s[1] * 1e3:g} ms"
    effect += "".join(f", {tr} clock reset in {run}" for run, (tr, _) in (clock_resets or {}).items())
    doc = {
        "name": f"husky-lab-sim-2022-12-21-seed{seed}",
        "runs": [{"name": n, "split": s} for n, _, s in RUNS_TABLE_6_4],
        "notes": (f"Simulated by sindy-ekf (simulation.campaign, seed {seed}, {what}{effect}). Mirrors the "
                  "thesis campaign of 21.12.2022; truth/ holds the true values."),
    }
    if gnss is not None:  # recorded GNSS (issue 16): declared, origin given, ENU -> local left to estimate
        doc["sensors"] = [gnss.campaign_entry()]
        doc["geodetic_origin"] = gnss.origin.to_yaml()
    if any(m is not None for m in motion):  # recorded IMU / wheel odometry (issue 16)
        doc.setdefault("sensors", []).extend(m.campaign_entry() for m in motion if m is not None)
    return yaml.safe_dump(doc, sort_keys=False, width=100)


def simulate_campaign(
    out: str | Path, seed: int = 0, minutes: float | None = None, effects=(), force: bool = False,
    receive_jitter_s=None, clock_resets=None, variant: int | Variant | None = None, gnss=None,
    imu: ImuSpec | bool | None = None, odometry: OdometrySpec | bool | None = None,
) -> truth_io.CampaignTruth:
    """Return the truth of a simulated tracker campaign written to ``out``.

    Parameters
    ----------
    out
        Campaign folder to create (data contract part 1 plus ``truth/``); built in a temporary
        sibling and renamed at the end, so a failure leaves nothing behind.
    seed
        Seed of the random generators; the same seed gives the same bytes.
    minutes
        Total driving time; ``None`` is table 6.4 (45.4 min), otherwise the nine runs are
        scaled to it (each at least 15 s) with the same split.
    effects
        At most one ``simulation.effects.Effect`` (or ``NAME=VALUE`` text) for the dynamics.
    force
        Replace an existing non-empty ``out``.
    receive_jitter_s
        ``(lo, hi)`` seconds, ``True`` for :data:`DEFAULT_RECEIVE_JITTER_S`, or ``"LO,HI"`` in
        ms: every message gets its own receive latency, uniform in it, and the bags store each
        topic in receive order, so messages closer than the spread (a spurious AT960 pulse
        next to a real one) are stored out of stamp order. The spread ``hi - lo`` is at most
        half a trigger period (:data:`MAX_RECEIVE_SPREAD_S`): a wider one stores messages a
        period apart swapped, which the data contract reads as a clock reset. ``None``: each
        topic in order.
        Everything else about the campaign is the same as without it.
    clock_resets
        ``{run: (tracker, fraction)}`` or texts ``RUN[:TRACKER[:FRACTION]]``: that tracker's
        clock restarts at that fraction of the run (a backward jump of hours in its stamps).
    variant
        A simulator variant (:mod:`simulation.variants`): its index (drawn by
        :func:`simulation.variants.draw_variant`) or a :class:`simulation.variant.Variant`.
        ``None`` or 0: the simulator before variants, byte for byte. truth/ records the variant
        whole (``variant``), so that its true dynamics are rebuilt from truth/.
    gnss
        ``None`` (no GNSS recorded), a profile name of :data:`simulation.gnss.PROFILES` or a
        :class:`simulation.gnss_topic.GnssTopicSpec`: each run also gets a bag of recorded
        ``sensor_msgs/NavSatFix`` fixes, declared under ``sensors:`` in ``campaign.yaml``, the
        true origin and ENU -> local transform in ``truth/gnss.yaml``. The other files keep
        their bytes (the fixes draw from their own random stream).
    imu, odometry
        ``None``/False (not recorded), True (the default spec) or a
        :class:`simulation.motion_sensors.ImuSpec` / ``OdometrySpec``: each run also gets a bag
        ``motion_<stamp>`` of ``sensor_msgs/Imu`` (gyro with bias and noise) and/or
        ``nav_msgs/Odometry`` (wheel odometry with slip), declared under ``sensors:``, the true
        bias and slip in ``truth/motion_sensors.yaml``; own random streams, other files unchanged.

    Raises
    ------
    InputError
        Unknown effect, form or value out of range, ``minutes``, ``seed`` or ``variant`` out of
        range, a bad receive jitter or clock reset, output folder not empty (without ``force``)
        or not writable. Nothing is left behind.
    """
    effects = check_effects(effects)
    variant = check_variant(variant)
    receive_jitter_s = check_receive_jitter(receive_jitter_s)
    clock_resets = check_clock_resets(clock_resets)
    gnss = check_gnss_spec(gnss)
    imu = ImuSpec() if imu is True else (imu or None)
    odometry = OdometrySpec() if odometry is True else (odometry or None)
    durations = run_durations(minutes)
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
        raise InputError(f"seed={seed!r}: must be a non-negative integer")
    check_output_dir(out, force=force)
    if not CALIBRATION_YAML.is_file():
        raise InputError(f"{CALIBRATION_YAML}: package data missing")

    # one independent stream per run, so a run's data do not depend on the others' lengths
    root = np.random.SeedSequence(int(seed))
    seeds = root.spawn(len(RUNS_TABLE_6_4) + 1)
    rng_campaign = np.random.default_rng(seeds[0])
    start_ns = int(CAMPAIGN_START.timestamp()) * NS
    t_boot_ns = {k: start_ns - int(rng_campaign.uniform(2, 8) * 3600 * NS) for k in ("at960", "ltd800")}
    effect = effects[0] if effects else None

    t0_ns, runs, fixes, motion = start_ns, [], {}, {}
    try:
        with atomic_output_dir(out, force=force) as tmp:
            tmp.chmod(0o777 & ~_umask())  # mkdtemp makes it 0700; a campaign is a normal folder
            for r in progress(range(len(RUNS_TABLE_6_4)), desc="simulate runs"):
                rng = np.random.default_rng(seeds[r + 1])
                setup = _run_setup(r, durations[r], t0_ns, t_boot_ns, rng, effect, receive_jitter_s,
                                   clock_resets.get(RUNS_TABLE_6_4[r][0]), variant)
                husky, server, run_truth = simulate_tracker_run(setup, rng)
                run_dir = tmp / "runs" / setup.name
                run_dir.mkdir(parents=True)
                stamp = _bag_stamp(t0_ns)
                bags.write_bag(run_dir / f"husky_{stamp}.bag", husky)
                bags.write_bag(run_dir / f"server_{stamp}.bag", server)
                runs.append(run_truth)
                if gnss is not None:
                    st = run_truth.states
                    fixes[setup.name] = record_fixes(st.t_utc_ns, st.x, st.y, st.z, st.psi,
                                                     gnss, seed=int(seed) * 100 + r)
                    bag = run_dir / (f"gnss_{stamp}" + ("" if gnss.ros2 else ".bag"))
                    write_gnss_bag(bag, fixes[setup.name], gnss.topic, gnss.ros2)
                if imu is not None or odometry is not None:
                    st = run_truth.states  # own streams per sensor: one does not move the other
                    rng_imu, rng_odo = (np.random.default_rng([int(seed), r, 16, k]) for k in (2, 3))
                    motion[setup.name] = (
                        None if imu is None else record_imu(st.t_utc_ns, st.vx, st.vy, st.omega, imu, rng_imu),
                        None if odometry is None else record_odometry(st.t_utc_ns, st.vx, st.omega, odometry,
                                                                      rng_odo))
                    ros2 = (imu or odometry).ros2
                    write_motion_bag(run_dir / (f"motion_{stamp}" + ("" if ros2 else ".bag")), *motion[setup.name],
                                     (imu or ImuSpec()).topic, (odometry or OdometrySpec()).topic, ros2)
                t0_ns += int((run_truth.duration_s + 3.0 + rng.uniform(120.0, 480.0)) * NS)
            (tmp / "campaign.yaml").write_text(_campaign_yaml(seed, minutes, effects, receive_jitter_s,
                                                              clock_resets, variant, gnss, (imu, odometry)))
            shutil.copyfile(CALIBRATION_YAML, tmp / "calibration.yaml")
            truth = _campaign_truth(seed, minutes, effects, runs, variant)
            truth_io.write_truth(tmp, truth)
            if gnss is not None:
                write_gnss_truth(tmp, gnss_truth(gnss, fixes))
            if motion:
                write_motion_truth(tmp, motion_truth(imu, odometry, motion))
    except OSError as exc:  # unwritable or vanished output, full disk: one line, nothing left
        raise InputError(f"{out}: cannot write the campaign there ({exc.strerror or exc})") from None
    log.info("simulated campaign %s: %d runs, %.1f min", out, len(runs), durations.sum() / 60)
    return truth
