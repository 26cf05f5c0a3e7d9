"""What the benchmark measured: each estimator's estimates and scores, as frozen values.

:class:`Estimate` is one estimator's estimate of one run at the pose times, :class:`Score` one
estimator's scores over all test runs (:mod:`sindy_ekf.benchmark.scoring`), and
:class:`BenchmarkResult` everything together (:func:`sindy_ekf.benchmark.run.benchmark_campaign`),
written by :mod:`sindy_ekf.benchmark.files` and drawn by :mod:`sindy_ekf.benchmark.figures`.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from groundfloor.gnss import GnssSeries


@dataclass(frozen=True)
class Estimate:
    """One estimator's estimate of one run at the pose times."""

    t: np.ndarray  # (n,) pose times, s
    x: np.ndarray  # (n, 6)
    P: np.ndarray  # (n, 6, 6), NaN where the estimator gives none
    nis: np.ndarray = field(default_factory=lambda: np.empty(0))


@dataclass(frozen=True)
class Score:
    """Scores of one estimator over all test runs."""

    ate_pos_m: float
    ate_yaw_deg: float
    outage_pos_err_m: dict[str, float]  # duration (s, as text) -> RMS error at the outage's end
    outage_yaw_err_deg: dict[str, float]
    nees_mean: float  # pose NEES (3 dof), mean over poses with a covariance
    nees_inside_95: float  # fraction of samples inside the per-sample 95 % chi-square bounds
    nis_mean: float  # NaN for estimators without innovations
    nis_inside_95: float
    runtime_s: float
    realtime_factor: float  # seconds of data per second of computing
    # issue 14: how the estimator ended (sindy_ekf.benchmark.health); metrics cover the time before
    status: str = "ok"  # ok | diverged | failed
    t_s: float = float("nan")  # s since the run's start where it diverged or failed (NaN when ok)
    reason: str = ""  # one line naming the run, empty when ok
    recoveries: int = 0  # covariance re-initialisations after a NIS alarm, over all runs
    pd_repairs: int = 0  # covariances repaired after losing positive definiteness, over all runs

    def status_text(self) -> str:
        """Return how the estimator ended in a few words: ``ok``, ``diverged at 12.30 s``, with its
        re-initialisations and covariance repairs when it had any (the reason is :attr:`reason`)."""
        text = self.status + (f" at {self.t_s:.2f} s" if self.status != "ok" else "")
        text += f" ({self.recoveries} re-init)" if self.recoveries else ""
        return text + (f" ({self.pd_repairs} covariance repairs)" if self.pd_repairs else "")


@dataclass(frozen=True)
class BenchmarkResult:
    """Everything the benchmark measured; files are written by :func:`sindy_ekf.benchmark.files.write_benchmark`."""

    profile: str
    alignment: str
    scores: dict[str, Score]
    estimates: dict[str, dict[str, Estimate]]  # estimator -> run -> estimate
    truth: dict[str, np.ndarray]  # run -> (n, 4) [t, x, y, yaw] at the pose times
    outages: dict[str, np.ndarray]  # run -> (m, 2)
    outage_curves: dict[str, dict[str, np.ndarray]]  # estimator -> duration -> (k, 3) tau, pos, yaw
    nees_bounds_95: tuple[float, float]  # per-sample, 3 dof
    nis_bounds_95: tuple[float, float]  # per-sample, 2 dof
    campaign: str = ""  # the campaign's name
    skipped_runs: dict[str, str] = field(default_factory=dict)  # test run -> why not scored (too short)
    gnss: dict[str, GnssSeries] = field(default_factory=dict)  # run -> the fixes the estimators had
    recorded_gnss: dict | None = None  # --gnss recorded: origin, ENU -> local (with std), counts per run
    config: dict | None = None  # the effective filter settings (sindy_ekf.config.FilterConfig.to_dict)

    def to_json(self) -> dict:
        """Return the ``benchmark --json`` content (INTERFACES.md keys and more)."""
        return {"profile": self.profile, "alignment": self.alignment,
                "nees_bounds_95": list(self.nees_bounds_95), "nis_bounds_95": list(self.nis_bounds_95),
                "estimators": {n: {k: (v if not isinstance(v, float) or np.isfinite(v) else None)
                                   for k, v in s.__dict__.items()} for n, s in self.scores.items()},
                "skipped_runs": dict(self.skipped_runs),
                **({"recorded_gnss": self.recorded_gnss} if self.recorded_gnss else {}),
                **({"config": self.config} if self.config else {})}
