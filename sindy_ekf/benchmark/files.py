"""The benchmark's files: every estimate and the truth as TUM trajectories, and the JSON.

TUM (``t x y z qx qy qz qw``) is what the evo tools read, so every estimate can be checked
with them (``tests/sindy_ekf/benchmark``: our ATE equals evo's on these files).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from groundfloor.errors import InputError
from groundfloor.files import atomic_write_json, atomic_write_text
from sindy_ekf.benchmark.result import BenchmarkResult


def tum_text(t: np.ndarray, x: np.ndarray, y: np.ndarray, yaw: np.ndarray) -> str:
    """Return a TUM trajectory (``t x y z qx qy qz qw``, z = 0, rotation about z by ``yaw``)."""
    rows = np.column_stack([t, x, y, np.zeros_like(t), np.zeros_like(t), np.zeros_like(t),
                            np.sin(yaw / 2.0), np.cos(yaw / 2.0)])
    return "".join(f"{r[0]:.9f} " + " ".join(f"{v:.9f}" for v in r[1:]) + "\n" for r in rows)


def read_tum(path: str | Path) -> np.ndarray:
    """Return ``(n, 4)`` ``[t, x, y, yaw]`` from a TUM file (yaw from the quaternion, unwrapped)."""
    try:
        d = np.loadtxt(path, comments="#", ndmin=2)
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: not a readable TUM trajectory ({exc})") from None
    if d.shape[1] != 8:
        raise InputError(f"{path}: TUM rows need 8 columns, found {d.shape[1]}")
    qx, qy, qz, qw = d[:, 4], d[:, 5], d[:, 6], d[:, 7]
    yaw = np.arctan2(2.0 * (qw * qz + qx * qy), 1.0 - 2.0 * (qy ** 2 + qz ** 2))
    return np.column_stack([d[:, 0], d[:, 1], d[:, 2], np.unwrap(yaw)])


def write_benchmark(result: BenchmarkResult, out_dir: str | Path) -> Path:
    """Write TUM files of the truth and every estimate and the JSON; return the folder.

    The figures of the same folder are drawn by :func:`sindy_ekf.benchmark.figures.write_benchmark_figures`.
    """
    out = Path(out_dir)
    for run, tr in result.truth.items():
        atomic_write_text(out / "tum" / "truth" / f"{run}.tum", tum_text(*tr.T))
    for name, per_run in result.estimates.items():
        for run, e in per_run.items():
            atomic_write_text(out / "tum" / name / f"{run}.tum", tum_text(e.t, e.x[:, 0], e.x[:, 1], e.x[:, 2]))
    atomic_write_json(out / "benchmark.json", result.to_json())
    return out
