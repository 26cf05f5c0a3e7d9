"""Runs too short to benchmark (health.split_short_runs): spans and pose counts at their bounds,
by hand (MIN_RUN_S = 10 s and MIN_RUN_POSES = 10 of the module docstring)."""

from __future__ import annotations

from types import SimpleNamespace

import numpy as np

from sindy_ekf.benchmark.health import split_short_runs


def _run(name: str, t: np.ndarray) -> SimpleNamespace:
    t = np.asarray(t, float)
    poses = SimpleNamespace(t=t, x=np.cos(t), y=np.sin(t), yaw=0.1 * t, z=None)
    return SimpleNamespace(name=name, poses=poses)


def test_runs_are_kept_from_ten_seconds_and_ten_poses_on():
    exact = _run("exact", 1000.0 + np.linspace(0.0, 10.0, 501))  # spans exactly 10 s
    short = _run("short", 1000.0 + np.linspace(0.0, 9.5, 476))
    sparse = _run("sparse", 1000.0 + np.linspace(0.0, 20.0, 9))  # 9 poses
    ten = _run("ten", 1000.0 + np.linspace(0.0, 20.0, 10))
    gappy = _run("gappy", 1000.0 + np.linspace(0.0, 10.0, 501))
    gappy.poses.x[0] = np.nan  # the first pose is not usable: 9.98 s remain
    empty = _run("empty", np.empty(0))
    kept, skipped = split_short_runs([exact, short, sparse, ten, gappy, empty])
    assert [r.name for r in kept] == ["exact", "ten"]
    assert set(skipped) == {"short", "sparse", "gappy", "empty"}
    assert "9.5 s with 476 usable poses" in skipped["short"]
    assert "20.0 s with 9 usable poses" in skipped["sparse"]
    assert "with 500 usable poses" in skipped["gappy"]  # 9.98 s (printed 10.0)
    assert "0.0 s with 0 usable poses" in skipped["empty"]
    kept, skipped = split_short_runs([short], min_s=9.5)
    assert [r.name for r in kept] == ["short"] and not skipped
