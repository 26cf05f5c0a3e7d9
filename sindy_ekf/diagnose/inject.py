"""Effects hidden in real measured data: recorded inputs rewritten, motion left as it was (issue 15, item 3).

A real robot's motion answers the inputs its motors saw. If the recorded inputs are rewritten
so that an input-side mechanism ``T`` maps them back to what was really driven
(``T(u_recorded) = u_real``), the unchanged motion looks exactly as if the robot had that
mechanism between its recorder and its motors. The diagnosis can then be scored on real
dynamics, noise and timing that no simulator shaped, with a known truth:

- ``input_delay=d`` (s): the motors see ``u(t - d)``; the recorded stamps are moved earlier by
  ``d`` (``t_recorded = t - d``), so the motion follows the recorded inputs ``d`` late;
- ``deadband=v``: the motors see ``sign(u) max(|u| - v, 0) / (1 - v)``; the recorded inputs are
  its inverse, ``sign(u) (v + (1 - v) |u|)`` (0 stays 0);
- ``asymmetry=a``: the motors turn by ``u2 + a u1`` (throttle-to-turn coupling); the recorded
  steering is ``u2 - a u1``;
- ``time_dependence=r`` (per 10 min): the motor gain decays as ``1 - r t / 600 s`` with ``t``
  since the run's first pose; the recorded inputs are divided by it.

Poses are never touched (copied byte for byte, as is every other file of the campaign); the
injected truth goes beside the campaign, to ``OUT.injected.yaml`` (INTERFACES.md: beside OUT,
not inside; nothing that reads the campaign can see it). A ``states.csv`` of a preprocessed
campaign carries the clean inputs and is therefore left out of the copy. A tracker campaign is
preprocessed first (cached, as every later command does) and its trajectory campaign rewritten.
"""

from __future__ import annotations

import logging
import math
import shutil
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import yaml

from groundfloor.errors import InputError
from groundfloor.files import atomic_output_dir, atomic_write_text, check_output_dir
from groundfloor.types import InputSeries, TrajectoryRun
from identification.preprocessing.campaigns import KEY_FILE, campaign_kind, preprocessed_dir
from identification.preprocessing.trajectory import read_trajectory_campaign

log = logging.getLogger(__name__)

INJECTED_SUFFIX = ".injected.yaml"
MIN_GAIN = 0.2  # a decayed motor gain below this would multiply the recorded inputs by more than 5


@dataclass(frozen=True)
class Injectable:
    """An input-side mechanism that can be hidden in recorded inputs: its parameter and allowed range."""

    family: str
    mechanism: str
    parameter: str
    low: float
    high: float  # inclusive unless high_open
    high_open: bool = False

    def check(self, value: float) -> float:
        """Return ``value`` if it lies in the allowed range, else raise InputError naming it."""
        ok = math.isfinite(value) and self.low <= value and (value < self.high if self.high_open else value <= self.high)
        if not ok:
            close = ")" if self.high_open else "]"
            raise InputError(f"--effect {self.family}={value:g}: {self.parameter} out of range "
                             f"[{self.low:g}, {self.high:g}{close}")
        return value


INJECTABLE: dict[str, Injectable] = {
    "input_delay": Injectable("input_delay", "transport_delay", "delay_s", 0.0, 2.0),
    "deadband": Injectable("deadband", "hard_deadband", "threshold", 0.0, 0.5),
    "asymmetry": Injectable("asymmetry", "throttle_to_turn_coupling", "coupling", -0.5, 0.5),
    "time_dependence": Injectable("time_dependence", "linear_gain_decay", "decay_per_10min", 0.0, 1.5),
}


def parse_effect(text: str) -> tuple[str, float]:
    """Return ``(family, value)`` of ``NAME=VALUE``, checked against :data:`INJECTABLE`.

    Raises
    ------
    InputError
        Not ``NAME=VALUE``, an unknown family, a value that is no number or out of range.
    """
    name, sep, value = str(text).partition("=")
    name = name.strip()
    if not sep:
        raise InputError(f"--effect {text}: expected NAME=VALUE, e.g. input_delay=0.15")
    if name not in INJECTABLE:
        raise InputError(f"--effect {text}: unknown family '{name}', expected one of {', '.join(INJECTABLE)}")
    try:
        v = float(value)
    except ValueError:
        raise InputError(f"--effect {text}: value '{value}' is not a number") from None
    return name, INJECTABLE[name].check(v)


def recorded_inputs(inputs: InputSeries, family: str, value: float, t_start: float) -> InputSeries:
    """Return the recorded inputs that the mechanism ``family`` with ``value`` maps back to ``inputs``.

    ``t_start`` is the run's first pose time (the origin of the gain decay).
    """
    t = np.asarray(inputs.t, float)
    u1, u2 = np.asarray(inputs.u1, float), np.asarray(inputs.u2, float)
    if family == "input_delay":
        return InputSeries(t=t - value, u1=u1.copy(), u2=u2.copy())
    if family == "deadband":
        def inverse(u):
            return np.where(u == 0.0, 0.0, np.sign(u) * (value + (1.0 - value) * np.abs(u)))
        return InputSeries(t=t.copy(), u1=inverse(u1), u2=inverse(u2))
    if family == "asymmetry":
        return InputSeries(t=t.copy(), u1=u1.copy(), u2=u2 - value * u1)
    if family == "time_dependence":
        gain = 1.0 - value * (t - t_start) / 600.0
        return InputSeries(t=t.copy(), u1=u1 / gain, u2=u2 / gain)
    raise InputError(f"unknown family '{family}', expected one of {', '.join(INJECTABLE)}")


def _check_decay(runs: tuple[TrajectoryRun, ...], value: float, what: str) -> None:
    """Raise InputError when a gain decay of ``value`` would fall below :data:`MIN_GAIN` in a run."""
    for run in runs:
        t0 = float(run.poses.t[0])
        span_s = float(max(run.inputs.t[-1], run.poses.t[-1]) - min(run.inputs.t[0], t0))
        if 1.0 - value * span_s / 600.0 < MIN_GAIN:
            raise InputError(f"{what}: run {run.name}: decay_per_10min={value:g} takes the motor gain below "
                             f"{MIN_GAIN:g} within its {span_s:.0f} s")


def _csv(inputs: InputSeries) -> str:
    """Return ``inputs.csv`` text (``t`` at ns resolution, values at round-trip precision)."""
    rows = [f"{t:.9f},{a!r},{b!r}" for t, a, b in zip(inputs.t.tolist(), inputs.u1.tolist(), inputs.u2.tolist())]
    return "t,u1,u2\n" + "".join(r + "\n" for r in rows)


def inject_campaign(campaign, out, family: str, value: float) -> Path:
    """Return ``out`` after writing ``campaign`` there with ``family`` hidden in its recorded inputs.

    Parameters
    ----------
    campaign : a trajectory campaign folder (data contract part 2).
    out : a missing or empty folder; receives the campaign with rewritten ``inputs.csv`` files.
        The truth (family, mechanism, parameter, value, source) goes to :func:`injected_path`.
    family, value : one of :data:`INJECTABLE` and its parameter.

    Raises
    ------
    InputError
        Unknown family, value out of range, output folder not empty or truth file existing,
        campaign unreadable; all checked before anything is written.
    """
    if family not in INJECTABLE:
        raise InputError(f"--effect {family}: unknown family, expected one of {', '.join(INJECTABLE)}")
    spec = INJECTABLE[family]
    value = spec.check(float(value))
    out = check_output_dir(out)
    truth_path = injected_path(out)
    if truth_path.exists():
        raise InputError(f"{truth_path}: exists (the injected truth of another campaign?); remove it or choose another OUT")
    src = Path(campaign)
    if src.resolve() == out.resolve() or src.resolve() in out.resolve().parents:
        raise InputError(f"{out}: output folder inside the campaign {src}")
    if campaign_kind(src) == "tracker":  # preprocessed first (cached), as every later command does
        log.info("%s: a tracker campaign, preprocessed first; its trajectory campaign gets the effect", src)
        camp = read_trajectory_campaign(preprocessed_dir(src))
    else:
        camp = read_trajectory_campaign(src)
    root = camp.root
    if family == "time_dependence":
        _check_decay(camp.runs, value, str(root))
    truth = {"family": family, "mechanism": spec.mechanism, spec.parameter: value,
             "source": str(src.resolve()),
             "note": "recorded inputs rewritten so that this mechanism maps them back to the inputs recorded "
                     "in the source; poses copied unchanged"}
    with atomic_output_dir(out) as tmp:
        shutil.copytree(root, tmp, dirs_exist_ok=True, ignore=shutil.ignore_patterns("states.csv", KEY_FILE))
        for run in camp.runs:
            rec = recorded_inputs(run.inputs, family, value, float(run.poses.t[0]))
            (tmp / "runs" / run.name / "inputs.csv").write_text(_csv(rec))
        atomic_write_text(truth_path, yaml.safe_dump({"injected": truth}, sort_keys=False))
    log.info("%s: %s=%g hidden in the inputs of %d runs", out, family, value, len(camp.runs))
    return out


def injected_path(out) -> Path:
    """Return the file beside the campaign folder ``out`` that holds its injected truth."""
    out = Path(out)
    return out.parent / (out.name + INJECTED_SUFFIX)


def read_injected(campaign) -> dict | None:
    """Return the injected truth of a campaign written by :func:`inject_campaign`, or None."""
    path = injected_path(campaign)
    if not path.is_file():
        return None
    return (yaml.safe_load(path.read_text()) or {}).get("injected")
