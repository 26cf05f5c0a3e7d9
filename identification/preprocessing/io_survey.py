"""Reading and validating ``calibration.yaml`` (data contract, part 1) into a :class:`Survey`.

The file holds raw survey observations only (thesis tables 6.1 to 6.3); what is derived from
them lives in :mod:`identification.preprocessing.calibration`. Every problem is reported as one
:class:`~groundfloor.errors.InputError` whose message names the file and the key at fault.
Unknown keys are ignored, as the data contract asks of readers.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import yaml

from groundfloor.errors import InputError
from groundfloor.types import Survey

TRACKERS = ("at960", "ltd800")
HUBS = ("front_left", "rear_left", "rear_right", "front_right")
PRISMS = ("front", "rear")
MIN_NETWORK_POINTS = 3  # a 6-parameter rigid transform needs 3 non-collinear points
MIN_HUB_POINTS = 3  # a circle in 3D needs 3 points


def read_survey(path: str | os.PathLike) -> Survey:
    """Return the validated survey read from a ``calibration.yaml`` file.

    Parameters
    ----------
    path : path-like
        The campaign's ``calibration.yaml``.

    Raises
    ------
    InputError
        If the file is missing, is not YAML, or breaks the data contract (missing key, wrong
        row length, non-finite or non-positive sigma, point ids that differ between the two
        network lists, fewer than 3 screw heads on a hub, unknown tracker name).
    """
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise InputError(f"{path}: cannot read calibration file ({exc.strerror or exc})") from None
    try:
        data = yaml.safe_load(text)
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f" at line {mark.line + 1}" if mark is not None else ""
        raise InputError(f"{path}: not valid YAML{where}") from None
    return survey_from_mapping(data, source=str(path))


def survey_from_mapping(data: Any, source: str = "calibration.yaml") -> Survey:
    """Return the validated survey held by an already parsed ``calibration.yaml`` mapping.

    ``source`` is the file name quoted in error messages.
    """
    if not isinstance(data, Mapping):
        raise InputError(f"{source}: expected a mapping with keys network, body_survey, prisms")
    network = _mapping(data, "network", source)
    lists = {tr: _point_dict(_mapping(network, tr, source, f"network.{tr}"), source,
                             f"network.{tr}") for tr in TRACKERS}
    _check_same_ids(lists, source)
    if len(lists["at960"]) < MIN_NETWORK_POINTS:
        raise InputError(f"{source}: network has {len(lists['at960'])} common points, "
                         f"at least {MIN_NETWORK_POINTS} are needed for the transform")

    body = _mapping(data, "body_survey", source)
    frame = _tracker_name(body.get("frame"), source, "body_survey.frame")
    hubs_raw = _mapping(body, "wheel_hubs", source, "body_survey.wheel_hubs")
    wheel_hubs = {}
    for hub in HUBS:
        key = f"body_survey.wheel_hubs.{hub}"
        if hub not in hubs_raw:
            raise InputError(f"{source}: missing key '{key}'")
        rows = hubs_raw[hub]
        if not isinstance(rows, (list, tuple)) or len(rows) < MIN_HUB_POINTS:
            n = len(rows) if isinstance(rows, (list, tuple)) else 0
            raise InputError(f"{source}: '{key}' has {n} screw-head points, "
                             f"at least {MIN_HUB_POINTS} are needed for a circle")
        wheel_hubs[hub] = np.stack([_row(r, source, f"{key}[{i}]") for i, r in enumerate(rows)])
    prisms_raw = _mapping(body, "prisms", source, "body_survey.prisms")
    prisms = {}
    for name in PRISMS:
        if name not in prisms_raw:
            raise InputError(f"{source}: missing key 'body_survey.prisms.{name}'")
        prisms[name] = _row(prisms_raw[name], source, f"body_survey.prisms.{name}")

    tracker_of = _mapping(data, "prisms", source)
    prism_tracker = {}
    for name in PRISMS:
        if name not in tracker_of:
            raise InputError(f"{source}: missing key 'prisms.{name}'")
        prism_tracker[name] = _tracker_name(tracker_of[name], source, f"prisms.{name}")

    return Survey(network_at960=lists["at960"], network_ltd800=lists["ltd800"],
                  body_frame=frame, wheel_hubs=wheel_hubs, prisms=prisms,
                  prism_tracker=prism_tracker)


def _mapping(parent: Mapping, key: str, source: str, full_key: str | None = None) -> Mapping:
    """Return ``parent[key]`` if it is a mapping, else raise naming ``full_key``."""
    full_key = full_key or key
    if key not in parent or parent[key] is None:
        raise InputError(f"{source}: missing key '{full_key}'")
    value = parent[key]
    if not isinstance(value, Mapping):
        raise InputError(f"{source}: '{full_key}' must be a mapping, got {type(value).__name__}")
    return value


def _row(value: Any, source: str, key: str) -> np.ndarray:
    """Return one ``[x, y, z, sx, sy, sz]`` observation as a (6,) float array, validated."""
    if not isinstance(value, (list, tuple)) or len(value) != 6:
        n = len(value) if isinstance(value, (list, tuple)) else "not a list"
        raise InputError(f"{source}: '{key}' must be [x, y, z, sigma_x, sigma_y, sigma_z] "
                         f"(6 numbers), got {n}")
    try:
        row = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{source}: '{key}' holds a value that is not a number") from None
    if not np.all(np.isfinite(row)):
        raise InputError(f"{source}: '{key}' holds a NaN or infinite value")
    if np.any(row[3:] <= 0.0):
        raise InputError(f"{source}: '{key}' has a sigma <= 0 (sigmas are in metres and positive)")
    return row


def _point_dict(raw: Mapping, source: str, key: str) -> dict[str, np.ndarray]:
    """Return point id (as a string, YAML may give ints) -> validated (6,) row."""
    points = {}
    for pid, value in raw.items():
        sid = str(pid)
        if sid in points:
            raise InputError(f"{source}: '{key}' lists point '{sid}' twice")
        points[sid] = _row(value, source, f"{key}.{sid}")
    return points


def _check_same_ids(lists: dict[str, dict[str, np.ndarray]], source: str) -> None:
    """Raise naming the first point id that is in one network list but not the other."""
    for a, b in (TRACKERS, TRACKERS[::-1]):
        extra = [pid for pid in lists[a] if pid not in lists[b]]
        if extra:
            raise InputError(f"{source}: network point '{extra[0]}' is in {a} but not in {b}")


def _tracker_name(value: Any, source: str, key: str) -> str:
    """Return a known tracker name, else raise naming ``key``."""
    if value not in TRACKERS:
        raise InputError(f"{source}: '{key}' is {value!r}, expected one of {', '.join(TRACKERS)}")
    return str(value)
