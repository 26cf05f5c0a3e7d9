"""Reading, validating and writing trajectory campaigns (data contract, part 2).

A trajectory campaign is poses and inputs per run::

    CAMPAIGN/campaign.yaml            kind: trajectory; runs with split
    CAMPAIGN/runs/<run>/poses.csv     t,x,y,yaw required; z,pitch,*_std optional
                                      (without it, poses.tum: t x y z qx qy qz qw, TUM format)
    CAMPAIGN/runs/<run>/inputs.csv    t,u1,u2 on their own (irregular) stamps

It is what every stage after preprocessing reads, and what ``sindy-ekf preprocess`` writes
(plus ``poses.tum`` and ``states.csv``, see INTERFACES.md).

Validation policy (every repair is counted in :attr:`TrajectoryRun.repairs` and logged; the
expected ones, pose gaps, at INFO and once per command in :func:`groundfloor.repairs.summary`, the
others as warnings):

- a missing run folder, file or required column, unparsable CSV, fewer than two valid rows,
  and poses and inputs that do not overlap in time are :class:`InputError` (one line naming the
  file, run or key);
- rows with NaN in a required column are dropped (``nan_pose_rows``, ``nan_input_rows``);
- rows with the same stamp are merged (``duplicate_pose_stamps``: pose rows averaged, being two
  measurements of one pose; ``duplicate_input_stamps``: the last row kept, since a later
  command supersedes an earlier one received at the same instant);
- the checks of :mod:`identification.preprocessing.trajectory_checks`: poses more than
  ``MAX_POSE_INTERVAL_S`` apart (median) are an :class:`InputError` (a time unit other than the
  contract's seconds: milliseconds, nanoseconds);
- yaw turning faster than a ground robot can (``check_yaw_unit``, the same module) is an
  :class:`InputError`: yaw in degrees;
- stamps going backwards are an :class:`InputError` naming file and row: the contract says rows
  are in time order, and a backward step means concatenated or re-stamped recordings, which
  sorting would silently interleave;
- poses beyond the inputs' time span (by more than :func:`gap_threshold_s` of the input
  stamps: a recording that ends with only some topics present) are left out and counted
  (``poses_outside_inputs``): the inputs there were never recorded;
- holes in the inputs longer than ``INPUT_HOLE_S`` (the same module) while the poses go on are
  counted (``input_holes``) and named, the inputs held through them as recorded;
- holes in the poses are not an error but are counted (``gaps``: intervals longer than
  :func:`gap_threshold_s`); :func:`gap_segments` gives the stretches between them, which
  splines and windows must not bridge;
- wrapped yaw is unwrapped; yaw that is already unwrapped is left as it is.
"""

from __future__ import annotations

import io
import logging
import math
import os
from pathlib import Path
from typing import Sequence

import numpy as np
import yaml

from groundfloor import repairs as expected_repairs
from groundfloor.errors import InputError
from groundfloor.files import atomic_output_dir, csv_header, missing_column, no_numbers, unlisted_runs
from groundfloor.types import (
    BodyStates,
    InputSeries,
    PoseTrack,
    TrajectoryCampaign,
    TrajectoryRun,
    check_input_range,
    check_poses_move,
)
from identification.preprocessing.trajectory_checks import (  # noqa: F401 - the gap rule re-exported
    GAP_FACTOR,
    GAP_MIN_S,
    check_input_signs,
    check_time_unit,
    check_yaw_unit,
    gap_threshold_s,
    input_holes,
    within_inputs,
)

log = logging.getLogger(__name__)

POSE_REQUIRED = ("t", "x", "y", "yaw")
POSE_OPTIONAL = ("z", "pitch", "x_std", "y_std", "z_std", "pitch_std", "yaw_std")
POSE_COLUMNS = ("t", "x", "y", "z", "pitch", "yaw", "x_std", "y_std", "z_std", "pitch_std", "yaw_std")
INPUT_COLUMNS = ("t", "u1", "u2")
STATE_COLUMNS = ("t", "vx", "vy", "omega", "u1", "u2")

GAPS_NOTE = "pose gaps (a prism lost; never bridged)"  # how the command line's summary names them


# ---------------------------------------------------------------------------------------------
# gaps


def gap_segments(t: np.ndarray, max_gap_s: float | None = None) -> np.ndarray:
    """Return ``(k, 2)`` index bounds ``[start, stop)`` of the stretches between pose gaps.

    Parameters
    ----------
    t : (n,) increasing stamps, s.
    max_gap_s : an interval longer than this splits the track; default :func:`gap_threshold_s`.

    A track without gaps gives ``[[0, n]]``. Splines, differentiation and prediction windows
    work per segment, so nothing is interpolated across a hole.
    """
    t = np.asarray(t, dtype=float)
    if max_gap_s is None:
        max_gap_s = gap_threshold_s(t)
    cut = np.flatnonzero(np.diff(t) > max_gap_s) + 1
    starts = np.concatenate([[0], cut])
    stops = np.concatenate([cut, [t.size]])
    return np.column_stack([starts, stops]).astype(int)


# ---------------------------------------------------------------------------------------------
# reading


def _read_csv(path: Path, required: Sequence[str], optional: Sequence[str] = ()) -> dict[str, np.ndarray]:
    """Return the columns of CSV ``path`` as float arrays (optional ones NaN when absent)."""
    if not path.is_file():
        raise InputError(f"{path}: file missing")
    header = csv_header(path)
    missing = [c for c in required if c not in header]
    if missing:
        raise missing_column(path, missing[0], header)
    wanted = [c for c in (*required, *optional) if c in header]
    try:
        data = np.genfromtxt(path, delimiter=",", skip_header=1, usecols=[header.index(c) for c in wanted],
                             dtype=float, ndmin=2, invalid_raise=True)
    except ValueError as exc:
        raise InputError(f"{path}: unreadable CSV ({str(exc).splitlines()[-1].strip()})") from None
    if data.size == 0:
        data = np.empty((0, len(wanted)))
    for i, c in enumerate(wanted):
        if c in required and (err := no_numbers(path, header, c, data[:, i])) is not None:
            raise err
    out = {c: data[:, i].copy() for i, c in enumerate(wanted)}
    n = data.shape[0]
    for c in optional:
        out.setdefault(c, np.full(n, np.nan))
    return out


def read_tum(path: Path) -> dict[str, np.ndarray]:
    """Return the pose columns of a TUM trajectory file (``t x y z qx qy qz qw`` per line, spaces,
    ``#`` comments: what evo and the SLAM benchmarks read and write, and ``preprocess`` writes beside
    ``poses.csv``): yaw and pitch of ``R = Rz(yaw) Ry(pitch) Rx(roll)``, the stds NaN. A run without a
    ``poses.csv`` is read from it."""
    try:
        data = np.loadtxt(path, comments="#", ndmin=2, dtype=float)
    except ValueError as exc:
        raise InputError(f"{path}: not a TUM trajectory ({str(exc).splitlines()[-1].strip()})") from None
    if data.size and data.shape[1] != 8:
        raise InputError(f"{path}: a TUM trajectory has 8 columns (t x y z qx qy qz qw), this one {data.shape[1]}")
    data = data.reshape(-1, 8)
    q = data[:, 4:8] / np.linalg.norm(data[:, 4:8], axis=1, keepdims=True)
    qx, qy, qz, qw = q.T
    nan = np.full(len(data), np.nan)
    out = {"t": data[:, 0], "x": data[:, 1], "y": data[:, 2], "z": data[:, 3],
           "yaw": np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy * qy + qz * qz)),
           "pitch": np.arcsin(np.clip(2.0 * (qw * qy - qz * qx), -1.0, 1.0))}
    return out | {c: nan for c in POSE_OPTIONAL if c not in out}


def _drop_nan_rows(cols: dict[str, np.ndarray], required: Sequence[str]) -> tuple[dict, np.ndarray, int]:
    """Return the columns without rows that have NaN in a required column, file row numbers, count."""
    n = cols[required[0]].size
    bad = np.zeros(n, dtype=bool)
    for c in required:
        bad |= ~np.isfinite(cols[c])
    rows = np.arange(n) + 2  # 1-based file line numbers; line 1 is the header
    keep = ~bad
    return {c: v[keep] for c, v in cols.items()}, rows[keep], int(bad.sum())


def _check_order(t: np.ndarray, rows: np.ndarray, path: Path) -> None:
    """Raise InputError naming the first row whose stamp goes backwards."""
    back = np.flatnonzero(np.diff(t) < 0)
    if back.size:
        i = back[0] + 1
        raise InputError(f"{path}: stamps not in time order at row {rows[i]} "
                         f"(t={t[i]:.9f} after t={t[i - 1]:.9f})")


def _merge_duplicates(cols: dict[str, np.ndarray], how: str) -> tuple[dict, int]:
    """Return columns with equal stamps merged (``how`` = 'mean' or 'last') and the rows merged."""
    t = cols["t"]
    new = np.concatenate([[True], np.diff(t) > 0])
    n_dup = int((~new).sum())
    if n_dup == 0:
        return cols, 0
    group = np.cumsum(new) - 1
    if how == "last":
        last = np.concatenate([np.flatnonzero(new)[1:] - 1, [t.size - 1]])
        return {c: v[last] for c, v in cols.items()}, n_dup
    merged = {}
    for c, v in cols.items():
        # nanmean per group: optional columns may be NaN in some duplicates only
        finite = np.isfinite(v)
        s = np.bincount(group, weights=np.where(finite, v, 0.0))
        k = np.bincount(group, weights=finite.astype(float))
        with np.errstate(invalid="ignore", divide="ignore"):
            merged[c] = np.where(k > 0, s / np.maximum(k, 1), np.nan)
    merged["t"] = t[new]
    return merged, n_dup


def unwrap_yaw(yaw: np.ndarray) -> np.ndarray:
    """Return ``yaw`` unwrapped if it looks wrapped (all within [-pi, pi]), else unchanged.

    Unwrapped yaw is left alone so that a true turn of more than pi across a pose gap survives.
    """
    yaw = np.asarray(yaw, dtype=float)
    if yaw.size and np.all(np.abs(yaw) <= math.pi + 1e-6):
        return np.unwrap(yaw)
    return yaw


def _read_run(run_dir: Path, name: str, split: str, group: str = "") -> TrajectoryRun:
    """Return one validated run of a trajectory campaign (see the module docstring)."""
    repairs: dict[str, int] = {}
    poses_path, inputs_path = run_dir / "poses.csv", run_dir / "inputs.csv"
    if not poses_path.is_file() and (run_dir / "poses.tum").is_file():
        poses_path = run_dir / "poses.tum"
        log.info("run %s: poses from %s (TUM: t x y z qx qy qz qw; no poses.csv)", name, poses_path)
        pc = read_tum(poses_path)
    else:
        pc = _read_csv(poses_path, POSE_REQUIRED, POSE_OPTIONAL)
    pc, p_rows, n_nan = _drop_nan_rows(pc, POSE_REQUIRED)
    repairs["nan_pose_rows"] = n_nan
    _check_order(pc["t"], p_rows, poses_path)
    pc["yaw"] = unwrap_yaw(pc["yaw"])  # before merging, so duplicates average on one branch
    pc, repairs["duplicate_pose_stamps"] = _merge_duplicates(pc, "mean")
    if pc["t"].size < 2:
        raise InputError(f"{poses_path}: fewer than 2 valid pose rows")
    check_time_unit(pc["t"], poses_path)
    check_yaw_unit(pc["t"], pc["yaw"], poses_path)

    ic = _read_csv(inputs_path, INPUT_COLUMNS)
    ic, i_rows, repairs["nan_input_rows"] = _drop_nan_rows(ic, INPUT_COLUMNS)
    _check_order(ic["t"], i_rows, inputs_path)
    ic, repairs["duplicate_input_stamps"] = _merge_duplicates(ic, "last")
    if ic["t"].size < 1:
        raise InputError(f"{inputs_path}: no valid input rows")
    for column in ("u1", "u2"):
        check_input_range(ic[column], str(inputs_path), column, ic["t"])

    t_p, t_i = pc["t"], ic["t"]
    overlap_s = min(t_p[-1], t_i[-1]) - max(t_p[0], t_i[0])
    if overlap_s <= 0:
        span_p, span_i = t_p[-1] - t_p[0], t_i[-1] - t_i[0]
        # about as long as each other: the same recording on two time bases (one counted from its start)
        hint = ("; they last about as long (%.1f s and %.1f s): one file counted from the run's start, the "
                "other on a clock? both must be on the same time base" % (span_p, span_i)
                if 0.0 < span_i and abs(span_p - span_i) < 0.1 * max(span_p, span_i) else "")
        raise InputError(f"run {name}: poses ({t_p[0]:.3f} to {t_p[-1]:.3f} s) and inputs "
                         f"({t_i[0]:.3f} to {t_i[-1]:.3f} s) do not overlap in time{hint}")
    pc, repairs["poses_outside_inputs"] = within_inputs(pc, t_i, name, poses_path)
    repairs["input_holes"] = input_holes(t_i, pc["t"], name, inputs_path)
    check_poses_move(pc["x"], pc["y"], pc["yaw"], f"run {name} ({poses_path})")
    repairs["gaps"] = int(gap_segments(pc["t"]).shape[0] - 1)

    repairs = {k: int(v) for k, v in repairs.items() if v}
    # a hole in the poses is a prism lost for a moment, part of normal tracker data: counted and
    # summarised once per command; the other repairs mean the files hold something wrong
    expected_repairs.note(GAPS_NOTE, name, repairs.get("gaps", 0))
    named = ("gaps", "poses_outside_inputs", "input_holes")  # said in their own lines above
    problems = {k: v for k, v in repairs.items() if k not in named}
    if problems:
        log.warning("run %s: %s", name, ", ".join(f"{k}={v}" for k, v in problems.items()))
    poses = PoseTrack(**{c: np.ascontiguousarray(pc[c]) for c in POSE_COLUMNS})
    inputs = InputSeries(t=ic["t"], u1=ic["u1"], u2=ic["u2"])
    return TrajectoryRun(name=name, split=split, poses=poses, inputs=inputs, repairs=repairs, group=group)


def _load_yaml(path: Path) -> dict:
    """Return campaign.yaml of a trajectory campaign, checked for kind, runs and splits."""
    if not path.is_file():
        raise InputError(f"{path}: campaign.yaml missing")
    try:
        meta = yaml.safe_load(path.read_text())
    except yaml.YAMLError as exc:
        where = getattr(exc, "problem_mark", None)
        line = f" at line {where.line + 1}" if where is not None else ""
        raise InputError(f"{path}: not valid YAML{line}") from None
    if not isinstance(meta, dict):
        raise InputError(f"{path}: expected a mapping with 'runs', got {type(meta).__name__}")
    kind = meta.get("kind")
    if kind is not None and kind != "trajectory":
        raise InputError(f"{path}: key 'kind' is '{kind}', expected 'trajectory'")
    runs = meta.get("runs")
    if not isinstance(runs, list) or not runs:
        raise InputError(f"{path}: key 'runs' missing or not a non-empty list")
    seen = set()
    for i, r in enumerate(runs):
        if not isinstance(r, dict) or not isinstance(r.get("name"), str) or not r["name"]:
            raise InputError(f"{path}: runs[{i}] has no 'name'")
        if r.get("split") not in ("train", "test"):
            raise InputError(f"{path}: run {r['name']}: key 'split' is {r.get('split')!r}, "
                             "expected 'train' or 'test'")
        if r["name"] in seen:
            raise InputError(f"{path}: run {r['name']} listed twice")
        if r.get("group") is not None and not isinstance(r["group"], (str, int)):
            raise InputError(f"{path}: run {r['name']}: key 'group' is {r['group']!r}, expected a name")
        seen.add(r["name"])
    return meta


def read_trajectory_campaign(path: str | os.PathLike) -> TrajectoryCampaign:
    """Return the validated trajectory campaign at ``path`` (folder or its campaign.yaml).

    Implements the reader of data contract part 2; see the module docstring for what is an
    error and what is a counted repair.

    Raises
    ------
    InputError
        one line naming the file, run, column or key at fault.
    """
    root = Path(path)
    if root.name == "campaign.yaml":
        root = root.parent
    if not root.is_dir():
        raise InputError(f"{root}: campaign folder missing")
    yaml_path = root / "campaign.yaml"
    meta = _load_yaml(yaml_path)
    if meta.get("kind") is None:
        if (root / "calibration.yaml").exists():
            raise InputError(f"{yaml_path}: a tracker campaign (no 'kind: trajectory'); preprocess it first")
        log.warning("%s: no 'kind' key; reading it as a trajectory campaign", yaml_path)
    extra = unlisted_runs(root, (r["name"] for r in meta["runs"]))
    if extra:
        log.warning("%s: run folder%s %s not listed in campaign.yaml; not read", root / "runs",
                    "s" if len(extra) > 1 else "", ", ".join(extra) + (" are" if len(extra) > 1 else " is"))
    runs = []
    for r in meta["runs"]:
        run_dir = root / "runs" / r["name"]
        if not run_dir.is_dir():
            raise InputError(f"{yaml_path}: run {r['name']}: folder {run_dir} missing")
        runs.append(_read_run(run_dir, r["name"], r["split"], str(r.get("group") or "")))
    check_input_signs(runs, yaml_path)
    return TrajectoryCampaign(root=root, name=str(meta.get("name") or root.name), runs=tuple(runs))


# ---------------------------------------------------------------------------------------------
# writing


def quaternion_from_yaw_pitch(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Return ``(n, 4)`` quaternions ``[qx, qy, qz, qw]`` of ``R = Rz(yaw) Ry(pitch)`` (roll 0)."""
    cy, sy = np.cos(0.5 * yaw), np.sin(0.5 * yaw)
    cp, sp = np.cos(0.5 * pitch), np.sin(0.5 * pitch)
    # Hamilton product qz(yaw) * qy(pitch)
    return np.column_stack([-sy * sp, cy * sp, sy * cp, cy * cp])


def _csv_text(columns: Sequence[str], arrays: Sequence[np.ndarray], t_fmt: str = "%.9f") -> str:
    """Return CSV text with a header, ``t`` at ns resolution and values at round-trip precision."""
    body = np.column_stack([np.asarray(a, dtype=float) for a in arrays])
    lines = [",".join(columns)]
    if body.shape[0]:
        buf = io.StringIO()
        np.savetxt(buf, body, delimiter=",", fmt=[t_fmt] + ["%.17g"] * (body.shape[1] - 1))
        lines.append(buf.getvalue().rstrip("\n"))
    return "\n".join(lines) + "\n"


def write_trajectory_campaign(out_dir: str | os.PathLike, name: str,
                              runs: Sequence[tuple[TrajectoryRun, BodyStates | None]],
                              force: bool = False, **provenance) -> Path:
    """Return ``out_dir`` after writing a trajectory campaign there atomically.

    Writes ``campaign.yaml`` (``kind: trajectory``, name, runs with splits, any ``provenance``
    keys such as ``source``), and per run ``poses.csv`` (all eleven pose columns, NaN where
    unknown), ``inputs.csv``, ``poses.tum`` (``t x y z qx qy qz qw``, rotation Rz(yaw) Ry(pitch),
    unknown z and pitch written as 0 so that evo can read it) and, when the BodyStates is not
    None, ``states.csv`` (``t,vx,vy,omega,u1,u2``). Either the whole folder appears or nothing
    changes (:func:`groundfloor.files.atomic_output_dir`).
    """
    names = [r.name for r, _ in runs]
    if len(set(names)) != len(names):
        raise InputError(f"{out_dir}: duplicate run names {sorted(n for n in set(names) if names.count(n) > 1)}")
    for r, s in runs:
        if r.split not in ("train", "test"):
            raise InputError(f"run {r.name}: split {r.split!r}, expected 'train' or 'test'")
        if len({getattr(r.poses, c).size for c in POSE_COLUMNS}) != 1:
            raise InputError(f"run {r.name}: pose arrays differ in length")
        if len({getattr(r.inputs, c).size for c in INPUT_COLUMNS}) != 1:
            raise InputError(f"run {r.name}: input arrays differ in length")
        if s is not None and len({getattr(s, c).size for c in STATE_COLUMNS}) != 1:
            raise InputError(f"run {r.name}: BodyStates arrays differ in length")
    meta = {"name": name, "kind": "trajectory", **provenance,
            "runs": [{"name": r.name, "split": r.split} | ({"group": r.group} if r.group else {})
                     for r, _ in runs]}
    with atomic_output_dir(out_dir, force=force) as tmp:
        (tmp / "campaign.yaml").write_text(yaml.safe_dump(meta, sort_keys=False))
        for run, states in runs:
            d = tmp / "runs" / run.name
            d.mkdir(parents=True)
            p = run.poses
            (d / "poses.csv").write_text(_csv_text(POSE_COLUMNS, [getattr(p, c) for c in POSE_COLUMNS]))
            i = run.inputs
            (d / "inputs.csv").write_text(_csv_text(INPUT_COLUMNS, [i.t, i.u1, i.u2]))
            z = np.nan_to_num(p.z, nan=0.0)
            q = quaternion_from_yaw_pitch(p.yaw, np.nan_to_num(p.pitch, nan=0.0))
            tum = _csv_text(("#t", "x", "y", "z", "qx", "qy", "qz", "qw"),
                            [p.t, p.x, p.y, z, *q.T]).replace(",", " ")
            (d / "poses.tum").write_text(tum)
            if states is not None:
                (d / "states.csv").write_text(_csv_text(STATE_COLUMNS, [getattr(states, c) for c in STATE_COLUMNS]))
    log.info("wrote trajectory campaign %s (%d runs) to %s", name, len(runs), out_dir)
    return Path(out_dir)
