"""``sindy-ekf simulate OUT``: write a simulated tracker campaign (data contract part 1) + truth/."""

from __future__ import annotations

import argparse
from pathlib import Path

from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json, check_outputs
from simulation.campaign import simulate_campaign
from simulation.effects import EFFECTS
from simulation.gnss import PROFILES
from simulation.gnss_topic import GnssTopicSpec
from simulation.motion_sensors import ImuSpec, OdometrySpec
from simulation.truth import CampaignTruth, campaign_summary

_FORMS = "; ".join(f"{name}: {', '.join(spec.forms)}" for name, spec in EFFECTS.items())


def add_arguments(p: argparse.ArgumentParser) -> None:
    """Add the ``simulate`` arguments to its parser."""
    p.add_argument("out", type=Path, help="campaign folder to create")
    p.add_argument("--seed", type=int, default=0, help="random seed (same seed, same bytes)")
    p.add_argument("--minutes", type=float, default=None,
                   help="total driving time (default: thesis table 6.4, 45.4 min)")
    p.add_argument("--effect", action="append", default=[], metavar="NAME[:FORM]=VALUE[,KEY=VALUE]",
                   help="a dynamics effect of simulation.effects, e.g. input_delay=0.1, "
                        "input_delay:motor_lag=0.15, heading_dependence=1.5,azimuth_deg=120 or "
                        "position_dependence:bumps=0.4,seed=3 (seed draws the form's geometry); "
                        f"forms, the family's default first: {_FORMS}. truth/ records the form "
                        "and every parameter")
    p.add_argument("--variant", type=int, default=0, metavar="N",
                   help="simulator variant N (simulation.variants): perturbed model B "
                        "coefficients, lateral law, motor lag, process-noise spectrum, driver "
                        "style and joystick rate, tracker noise, drawn from N; recorded whole in "
                        "truth/ (default 0: the simulator before variants, byte for byte)")
    p.add_argument("--receive-jitter", nargs="?", const="2,12", default=None, metavar="MS_LO,MS_HI",
                   help="give every message its own receive latency, uniform in [MS_LO, MS_HI] ms "
                        "(2,12 without a value), and store each topic in receive order, as "
                        "independently generated campaigns do: a spurious AT960 pulse a few ms from "
                        "a real one is then stored out of stamp order; the spread MS_HI - MS_LO "
                        "is at most 10 ms, half a trigger period, beyond which the data contract "
                        "reads a reordering as a clock reset (default: every topic received in "
                        "stamp order)")
    p.add_argument("--clock-reset", action="append", default=[], metavar="RUN[:TRACKER[:FRACTION]]",
                   help="restart a tracker's clock in that run (a backward jump of hours in its "
                        "stamps), e.g. run_05 or run_05:ltd800:0.3 (default tracker at960, at 0.5 of "
                        "the run); repeatable")
    p.add_argument("--gnss", default=None, choices=sorted(PROFILES), metavar="PROFILE",
                   help="also record GNSS: a sensor_msgs/NavSatFix bag per run from that profile "
                        f"({', '.join(PROFILES)}) around a geodetic origin, declared under sensors: in "
                        "campaign.yaml, the true ENU -> local transform in truth/gnss.yaml "
                        "(default: none; the other files keep their bytes)")
    p.add_argument("--gnss-ros2", action="store_true", help="write the GNSS bags as ROS2 folders")
    p.add_argument("--imu", action="store_true",
                   help="also record an IMU (sensor_msgs/Imu on /imu/data, 100 Hz): gyro z with a bias "
                        "(constant per run plus a random walk) and white noise, body accelerations; the "
                        "true bias in truth/motion_sensors.yaml (default: none)")
    p.add_argument("--odometry", action="store_true",
                   help="also record wheel odometry (nav_msgs/Odometry on /wheel_odom, 50 Hz): v and omega "
                        "from the track speeds with slip and a track-width error (default: none)")
    p.add_argument("--sensors-ros2", action="store_true", help="write the IMU / odometry bags as ROS2 folders")
    p.add_argument("--force", action="store_true", help="replace a non-empty OUT")
    p.add_argument("--json", type=Path, default=None, metavar="PATH", help="also write a JSON summary")


def format_table(truth: CampaignTruth) -> str:
    """Return a short human summary: one line per run."""
    lines = [f"{'run':8} {'split':5} {'dur s':>7} {'trigger':>7} {'at960':>6} {'lost':>4} {'spur':>4} "
             f"{'ltd800':>6} {'drop a/l':>8} {'joy':>5} {'hub':>5}"]
    for r in truth.runs:
        lines.append(f"{r.name:8} {r.split:5} {r.duration_s:7.1f} {r.n_trigger:7d} {r.at960['n_messages']:6d} "
                     f"{r.at960['n_lost']:4d} {r.at960['n_spurious']:4d} {r.ltd800['n_messages']:6d} "
                     f"{len(r.at960['dropouts_utc']):>4d}/{len(r.ltd800['dropouts_utc']):<3d} "
                     f"{r.joy['n_messages']:5d} {r.hubs['n_messages']:5d}")
    return "\n".join(lines)


def run(args) -> int:
    """Simulate the campaign, print a summary, write ``--json``; return the exit code."""
    check_outputs(args)
    if args.json is not None and args.json.resolve().is_relative_to(args.out.resolve()):
        raise InputError(f"--json {args.json}: must not be inside the output folder {args.out}")
    if args.gnss_ros2 and args.gnss is None:
        raise InputError("--gnss-ros2: needs --gnss PROFILE")
    if args.sensors_ros2 and not (args.imu or args.odometry):
        raise InputError("--sensors-ros2: needs --imu or --odometry")
    truth = simulate_campaign(args.out, seed=args.seed, minutes=args.minutes, effects=args.effect,
                              force=args.force, receive_jitter_s=args.receive_jitter,
                              clock_resets=args.clock_reset, variant=args.variant,
                              gnss=None if args.gnss is None else GnssTopicSpec(args.gnss, ros2=args.gnss_ros2),
                              imu=ImuSpec(ros2=args.sensors_ros2) if args.imu else None,
                              odometry=OdometrySpec(ros2=args.sensors_ros2) if args.odometry else None)
    total = sum(r.duration_s for r in truth.runs) / 60.0
    effect = truth.effect().label() if truth.effects else "none"
    print(f"simulated campaign {args.out}: {len(truth.runs)} runs, {total:.1f} min, seed {truth.seed}, "
          f"effect {effect}")
    if truth.variant:
        print(f"simulator variant {truth.variant['index']}: " + ", ".join(
            f"{k} {v:.3g}" if isinstance(v, float) else f"{k} {v}" for k, v in truth.variant["draws"].items()))
    for r in truth.runs:
        jitter = r.bags.get("receive_jitter_s")
        if jitter:
            stored = ", ".join(f"{t} {n}" for t, n in r.bags["reordered"].items() if n)
            print(f"{r.name}: receive latency {jitter[0] * 1e3:g}-{jitter[1] * 1e3:g} ms; stored out of "
                  f"stamp order: {stored or 'none'}")
        if r.clock_reset:
            c = r.clock_reset
            print(f"{r.name}: {c['tracker']} clock restarted (topic {c['topic']}, message {c['message']}, "
                  f"stamps jump {c['jump_s']:+.3f} s)")
    print(format_table(truth))
    if args.json is not None:
        atomic_write_json(args.json, campaign_summary(truth))
    return 0
