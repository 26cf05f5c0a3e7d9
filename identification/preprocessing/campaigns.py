"""Opening any campaign as a trajectory campaign, preprocessing tracker campaigns once.

Every command after ``preprocess`` takes a trajectory campaign (data contract part 2) or a
tracker campaign (part 1), which :func:`open_campaign` preprocesses into
``<campaign>/.sindy-ekf/preprocessed/`` and reuses as long as the bags, the YAML files and the
preprocessing code are unchanged (a hash of their sizes, mtimes and source), so that nothing is
computed twice.
"""

from __future__ import annotations

import hashlib
import json
import logging
import os
import shutil
import tempfile
from pathlib import Path

import yaml

from groundfloor import __version__
from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json
from groundfloor.types import TrajectoryCampaign
from identification.preprocessing.io_tracker import find_bags
from identification.preprocessing.preprocess import (
    DEFAULT_SMOOTHING,
    preprocess_campaign,
)
from identification.preprocessing.trajectory import read_trajectory_campaign

log = logging.getLogger(__name__)

CACHE_SUBDIR = Path(".sindy-ekf") / "preprocessed"
KEY_FILE = "cache_key.json"
# modules whose source decides what preprocessing writes: a change invalidates the cache
_CODE_MODULES = ("io_tracker", "io_bags", "io_bag_salvage", "stamp_order", "io_survey", "calibration",
                 "network_transform", "body_frame", "sync", "clock_sync", "extra_offset", "hub", "poses",
                 "smoothing_spline", "states", "preprocess", "trajectory", "trajectory_checks", "io_sensors",
                 "io_motion")


def campaign_kind(path: str | Path) -> str:
    """Return ``"trajectory"`` or ``"tracker"`` for a campaign folder, else raise InputError."""
    root = Path(path)
    if root.name == "campaign.yaml":
        root = root.parent
    meta_file = root / "campaign.yaml"
    if not meta_file.is_file():
        raise InputError(f"{path}: not a campaign (no campaign.yaml)")
    try:
        meta = yaml.safe_load(meta_file.read_text())
    except yaml.YAMLError:
        raise InputError(f"{meta_file}: not valid YAML") from None
    if isinstance(meta, dict) and meta.get("kind") == "trajectory":
        return "trajectory"
    runs = root / "runs"
    if runs.is_dir() and (any(runs.glob("*/poses.csv")) or any(runs.glob("*/poses.tum"))):
        return "trajectory"
    if runs.is_dir() and any(find_bags(d) for d in runs.iterdir() if d.is_dir()):
        return "tracker"
    raise InputError(f"{path}: neither a trajectory campaign (no runs/*/poses.csv or poses.tum) nor a tracker "
                     "campaign (no bags under runs/)")


def _code_hash() -> str:
    h = hashlib.sha256(__version__.encode())
    for name in _CODE_MODULES:
        source = Path(__file__).with_name(f"{name}.py")
        h.update(source.read_bytes() if source.is_file() else name.encode())
    return h.hexdigest()[:16]


def cache_key(path: str | Path, smoothing: float) -> str:
    """Return the hash that identifies a preprocessing of the tracker campaign at ``path``.

    Covers every bag file's relative path, size and mtime, the bytes of campaign.yaml and
    calibration.yaml, the smoothing factor and the preprocessing code.
    """
    root = Path(path)
    h = hashlib.sha256()
    for name in ("campaign.yaml", "calibration.yaml"):
        f = root / name
        h.update(f.read_bytes() if f.is_file() else b"-")
    for f in sorted(p for p in (root / "runs").rglob("*") if p.is_file()):
        st = f.stat()
        h.update(f"{f.relative_to(root)}|{st.st_size}|{st.st_mtime_ns}\n".encode())
    h.update(f"smoothing={smoothing!r}|code={_code_hash()}".encode())
    return h.hexdigest()


def _cache_dir(root: Path) -> Path:
    """Return the cache folder: inside the campaign, or under ~/.cache when that is read-only."""
    inside = root / CACHE_SUBDIR
    probe = inside
    while not probe.exists():
        probe = probe.parent
    if os.access(probe, os.W_OK):
        return inside
    digest = hashlib.sha256(str(root.resolve()).encode()).hexdigest()[:16]
    return Path.home() / ".cache" / "sindy-ekf" / digest / "preprocessed"


def preprocessed_dir(path: str | Path, smoothing: float | None = None,
                     jobs: int | None = None) -> Path:
    """Return the folder of the trajectory campaign preprocessed from a tracker campaign,
    preprocessing it first (runs in ``jobs`` processes, default up to 2) unless a valid cached
    one exists."""
    root = Path(path)
    smoothing = DEFAULT_SMOOTHING if smoothing is None else smoothing
    out = _cache_dir(root)
    key = cache_key(root, smoothing)
    key_file = out / KEY_FILE
    if key_file.is_file():
        try:
            if json.loads(key_file.read_text()).get("key") == key:
                log.info("%s: using the cached preprocessing in %s", root, out)
                return out
        except (json.JSONDecodeError, OSError):
            pass
        log.info("%s: cached preprocessing is stale; preprocessing again", root)
    jobs = min(2, os.cpu_count() or 1) if jobs is None else jobs
    preprocess_campaign(root, out, smoothing=smoothing, force=True, jobs=jobs)  # + preprocess.json
    atomic_write_json(key_file, {"key": key})  # written last: its presence marks a valid cache
    return out


def open_campaign(path: str | Path, cache: bool = True,
                  smoothing: float | None = None) -> TrajectoryCampaign:
    """Return any campaign as a trajectory campaign (data contract part 2).

    A trajectory campaign is read as it is; a tracker campaign is preprocessed (thesis 5.2),
    into its cache folder when ``cache`` (reused while valid), else into a temporary folder.

    Raises
    ------
    InputError
        ``"PATH: not a campaign (no campaign.yaml)"``, or whatever reading or preprocessing
        finds wrong, in one line.
    """
    root = Path(path)
    if campaign_kind(root) == "trajectory":
        return read_trajectory_campaign(root)
    if cache:
        return read_trajectory_campaign(preprocessed_dir(root, smoothing))
    tmp = Path(tempfile.mkdtemp(prefix="sindy-ekf-preprocess-"))
    try:
        preprocess_campaign(root, tmp / "out",
                            smoothing=DEFAULT_SMOOTHING if smoothing is None else smoothing)
        return read_trajectory_campaign(tmp / "out")
    finally:
        shutil.rmtree(tmp, ignore_errors=True)


def train_campaign_of(path: str | Path | None) -> TrajectoryCampaign | None:
    """Return the campaign at ``path`` whose train runs fit what a command needs beside a model
    (``--train``: the baselines' gains, the lag, the filters' process noise), None for None.

    Raises
    ------
    InputError
        Naming the campaign when it marks no run as train, or whatever :func:`open_campaign` finds.
    """
    if path is None:
        return None
    camp = open_campaign(path)
    if not camp.split("train"):
        raise InputError(f"{path}: campaign.yaml marks no run as train (--train needs runs to fit on)")
    return camp
