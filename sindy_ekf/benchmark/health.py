"""Estimators that fail alone: divergence detected from the innovations, recovery, a status per row.

Issue 14, item 2: one estimator diverging or raising must not take the benchmark down. Each run of
each estimator ends with a :class:`RunStatus`:

- ``ok``: finished (possibly after ``recoveries`` re-initialisations);
- ``diverged``: the innovations left their chi-square band for good, or the state or covariance
  became non-finite (:class:`groundfloor.errors.DivergenceError`); the estimate is kept up to
  the time of divergence ``t_s`` and scored there;
- ``failed``: the estimator raised anything else (no estimate of that run).

Divergence from the NIS (Bar-Shalom, Li and Kirubarajan 2001, sec. 5.4): over a consistent
filter the NIS of a 2-dof fix is chi-square with 2 degrees, so the sum over a sliding window of
:data:`NIS_WINDOW` fixes is chi-square with ``2 W`` degrees. Each NIS is clipped at the filter's
gate first, so that one outlier (which the gate rejects anyway) adds at most the gate value: a
window is an alarm only when most of its fixes are far outside, i.e. the filter no longer
follows the fixes. The bound is :data:`NIS_TOLERANCE` times the quantile of ``chi2(2 W)`` at
:data:`NIS_FALSE_ALARM`; clipping only lowers the sum, so the false-alarm rate of a consistent
filter stays below it, and the tolerance leaves room for time-correlated GNSS errors.

Step versus drift (:func:`sindy_ekf.benchmark.step_test.fixes_stepped`): an alarm is not yet a lost filter. When the GNSS fixes
jump (a multipath burst, a wrong ambiguity fix) the gate rejects them and the window alarms while
the state is fine. Before any reset the innovations of the alarm window and of the window before
it are weighed between two hypotheses (Basseville and Nikiforov 1993, ch. 2 and 4): levels of
the fixes with steps between them (up to ``step_test.MAX_LEVELS``, the fewest that pass the chi-square
bound of their covariances, change times by optimal partitioning), or a filter drifting along a
smooth curve (a quadratic in time); the levels must pass and win on the information criterion,
and the first alarm of an episode must hold a step inside its window. Then the fixes agree with
each other and with the filter's own dead reckoning over
8 s, only offset: the fixes stepped, the filter is not reset (counted as ``fix_steps``) and the
gate keeps rejecting them until they return or the state's growing covariance accepts them. A
lost filter drifts or scatters; only then is it re-initialised. A step that lasts longer than
:data:`MAX_COAST_S` (the longest GNSS outage the filters are specified to bridge on the model
alone) is taken as the fixes' new level (a wrong ambiguity fix cannot be told from a moved
antenna for ever): the filter is then re-initialised onto it, counted as a recovery.

Recovery (:func:`guarded_ekf_batch`): at the start of the alarming window the filter is
re-initialised from its last consistent state with the position of the next fix (lever arm
removed) and the covariance reset (:func:`reset_state`), then runs on; at most
:data:`MAX_RECOVERIES` times per run, each counted.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass, replace

import numpy as np
from scipy.stats import chi2

from groundfloor.errors import DivergenceError
from sindy_ekf.benchmark.result import Estimate, Score
from sindy_ekf.benchmark.scoring import pose_truth, score_estimator
from sindy_ekf.benchmark.step_test import fixes_stepped
from sindy_ekf.estimation.ekf import GATE_PROB, GRID_TOL_S, EkfResult, EkfRun, LateralConstraint, run_ekf_batch
from sindy_ekf.estimation.process_models import ProcessModel

log = logging.getLogger(__name__)

NIS_WINDOW = 20  # fixes (4 s of 5 Hz GNSS)
NIS_FALSE_ALARM = 1e-6  # per window of a consistent filter
# the simulated GNSS errors are correlated in time (bias random walk), so even the true model's NIS
# mean is 3.2 (dgnss) to 4.5 (rtk) instead of 2, and a baseline's window sum reaches 130 against
# the bound of 98 under rtk (bench mini campaign); a diverged filter, all fixes gated, sums to
# 20 x 13.8 = 276: twice the bound separates the two
NIS_TOLERANCE = 2.0
MAX_RECOVERIES = 3  # per run
RESET_INFLATION = 10.0  # heading and velocity std after a reset, times P0's
STATUS_ORDER = ("ok", "diverged", "failed")
# a test run shorter than this is named and skipped, not scored: the filters' start (P0 to steady
# state at 5 Hz fixes) takes a few seconds, so a 3 s run would score the transient alone
MIN_RUN_S = 10.0
MIN_RUN_POSES = 10


@dataclass(frozen=True)
class RunStatus:
    """How one estimator ended on one run."""

    status: str = "ok"  # ok | diverged | failed
    t_s: float = float("nan")  # seconds since the run's start where it diverged or failed
    reason: str = ""  # one line, empty when ok
    recoveries: int = 0
    fix_steps: int = 0  # alarms explained by a step of the fixes (no reset)
    pd_repairs: int = 0  # covariances repaired after losing positive definiteness (eigenvalues clipped)


def nis_alarm(nis: np.ndarray, gate_nis: float, window: int = NIS_WINDOW, dof: int = 2,
              false_alarm: float = NIS_FALSE_ALARM, tolerance: float = NIS_TOLERANCE
              ) -> tuple[int | None, float, float]:
    """Return the first fix index whose window of ``window`` fixes is an alarm, its sum and the bound.

    The sum of the NIS clipped at ``gate_nis`` over fixes ``[i, i + window)`` against the
    ``1 - false_alarm`` quantile of ``chi2(dof * window)`` times ``tolerance`` (module docstring); ``None`` and NaN
    when no window is an alarm (or there are fewer fixes than ``window``).
    """
    bound = tolerance * float(chi2.ppf(1.0 - false_alarm, dof * window))
    v = np.minimum(np.nan_to_num(np.asarray(nis, float), nan=gate_nis, posinf=gate_nis), gate_nis)
    if v.size < window:
        return None, float("nan"), bound
    c = np.concatenate([[0.0], np.cumsum(v)])
    sums = c[window:] - c[:-window]
    hit = np.flatnonzero(sums > bound)
    if hit.size == 0:
        return None, float("nan"), bound
    return int(hit[0]), float(sums[hit[0]]), bound


MAX_COAST_S = 60.0  # longest outage of simulation.gnss_faults, bridged on the model alone
def reset_state(x: np.ndarray, P0: np.ndarray, gnss, t_from: float) -> tuple[np.ndarray, np.ndarray] | None:
    """Return ``(x, P)`` re-initialised from the first fix valid after ``t_from``, or None if none.

    Position from the fix with the lever arm rotated by the state's heading removed (eq. 5.65),
    its variance the fix's; heading and velocities kept, their variances ``RESET_INFLATION^2``
    times ``P0``'s.
    """
    after = np.flatnonzero(gnss.t_valid > t_from + GRID_TOL_S)
    if after.size == 0 or not np.all(np.isfinite(x)):
        return None
    j = after[0]
    c, s = math.cos(x[2]), math.sin(x[2])
    lx, ly = np.asarray(gnss.lever_arm_body, float)[:2]
    x = x.copy()
    x[0] = gnss.p_local[j, 0] - (c * lx - s * ly)
    x[1] = gnss.p_local[j, 1] - (s * lx + c * ly)
    var = np.diag(P0).copy() * RESET_INFLATION ** 2
    var[:2] = gnss.std[j, :2] ** 2 + var[:2]
    return x, np.diag(var)


_PER_FIX = ("innovation", "innovation_cov", "r_scale")  # EkfResult's arrays with one row per fix
# per grid step beyond the six states, where the result has them (the seven-state EKF's gyro bias)
_PER_STEP_OPTIONAL = ("gyro_bias", "gyro_bias_std")


def _cut(res: EkfResult, t_end: float) -> EkfResult:
    """Return ``res`` up to (excluding) ``t_end`` on its grid."""
    n = int(np.searchsorted(res.t, t_end - GRID_TOL_S))
    keep = res.nis_t < t_end - GRID_TOL_S
    optional = {f: getattr(res, f)[:n] for f in _PER_STEP_OPTIONAL if getattr(res, f, None) is not None}
    return replace(res, t=res.t[:n], x=res.x[:n], P=res.P[:n], nis=res.nis[keep], nis_t=res.nis_t[keep],
                   accepted=res.accepted[keep], outside_envelope=res.outside_envelope[:n], **optional,
                   **{f: getattr(res, f)[keep] for f in _PER_FIX if len(getattr(res, f)) == len(keep)})


def _splice(head: EkfResult, tail: EkfResult) -> EkfResult:
    """Return ``head`` up to ``tail``'s first step followed by ``tail``."""
    h = _cut(head, tail.t[0])
    return replace(h, t=np.concatenate([h.t, tail.t]), x=np.concatenate([h.x, tail.x]),
                   P=np.concatenate([h.P, tail.P]), nis=np.concatenate([h.nis, tail.nis]),
                   nis_t=np.concatenate([h.nis_t, tail.nis_t]), accepted=np.concatenate([h.accepted, tail.accepted]),
                   outside_envelope=np.concatenate([h.outside_envelope, tail.outside_envelope]),
                   pd_repairs=h.pd_repairs + tail.pd_repairs, runtime_s=h.runtime_s + tail.runtime_s,
                   saturated_steps=h.saturated_steps + tail.saturated_steps,
                   **{f: np.concatenate([getattr(h, f), getattr(tail, f)]) for f in _PER_FIX})


def _one_line(exc: BaseException) -> str:
    """Return ``exc`` as one line naming its type unless it is a ``DivergenceError``."""
    text = " ".join(str(exc).split()) or type(exc).__name__
    return text if isinstance(exc, DivergenceError) else f"{type(exc).__name__}: {text}"


def _run_alone(model: ProcessModel, run: EkfRun, gate_prob: float,
               lateral: LateralConstraint | None) -> tuple[EkfResult | None, RunStatus]:
    """Return one run's EKF result and status; a non-finite state keeps the estimate before it."""
    with np.errstate(over="ignore", invalid="ignore"):  # a diverging model overflows: expected here
        return _run_alone_raw(model, run, gate_prob, lateral)


def _run_alone_raw(model: ProcessModel, run: EkfRun, gate_prob: float,
                   lateral: LateralConstraint | None) -> tuple[EkfResult | None, RunStatus]:
    """:func:`_run_alone` without the floating-point warnings silenced."""
    kw = {"lateral": lateral, "gate_prob": gate_prob}
    try:
        return run_ekf_batch(model, [run], **kw)[0], RunStatus()
    except DivergenceError as exc:
        status = RunStatus("diverged", exc.t_s, _one_line(exc))
        t_end = run.t[0] + exc.t_s
        n = int(np.searchsorted(run.t, t_end - GRID_TOL_S))
        if n < 2:
            return None, status
        try:  # the same filter on the steps before: deterministic, so finite
            return run_ekf_batch(model, [replace(run, t=run.t[:n], u=run.u[:n])], **kw)[0], status
        except Exception:  # noqa: BLE001 - the status already says what went wrong
            return None, status
    except Exception as exc:  # noqa: BLE001 - an estimator failing must not stop the others
        return None, RunStatus("failed", 0.0, _one_line(exc))


def watch_nis(model: ProcessModel, run: EkfRun, res: EkfResult, gate_prob: float,
             lateral: LateralConstraint | None, recover: bool, step_test: bool = True
             ) -> tuple[EkfResult | None, RunStatus]:
    """Return the run's result after NIS monitoring (and re-initialisations), with its status."""
    recoveries, checked_from, steps, step_since = 0, 0, 0, None
    while True:
        i, total, bound = nis_alarm(res.nis[checked_from:], res.gate_nis)
        if i is None:
            return res, RunStatus(recoveries=recoveries, fix_steps=steps)
        j = checked_from + i
        if i > 0 or step_since is None:  # not the window right after a step's: a new episode
            step_since = float(res.nis_t[j])
        coasting_s = float(res.nis_t[j]) - step_since
        span = slice(max(0, j - NIS_WINDOW), j + NIS_WINDOW)
        if step_test and coasting_s <= MAX_COAST_S and len(res.innovation) == len(res.nis) and fixes_stepped(
                res.innovation[span], res.innovation_cov[span], res.nis_t[span], need_step=coasting_s == 0.0):
            steps += 1  # the fixes stepped, the filter is not lost: no reset (module docstring)
            log.info("%s: NIS alarm at t=%.2f s explained by a step of the fixes; not reset", run.name,
                     res.nis_t[j] - run.t[0])
            checked_from = j + NIS_WINDOW
            continue
        step_since = None
        # divergence began at the window's first fix outside the gate (its start if none is)
        gated = np.flatnonzero(~np.isfinite(res.nis[j:j + NIS_WINDOW]) | (res.nis[j:j + NIS_WINDOW] > res.gate_nis))
        t_alarm = float(res.nis_t[j + (gated[0] if gated.size else 0)])
        k = int(np.searchsorted(res.t, t_alarm - GRID_TOL_S))
        reason = (f"NIS over {NIS_WINDOW} fixes {total:.0f} above its chi-square bound {bound:.0f} "
                  f"from t={t_alarm - run.t[0]:.2f} s")
        lam = float(res.r_scale[j - 1]) if 0 < j <= len(res.r_scale) else 1.0
        reset = reset_state(res.x[k], run.P0, replace(run.gnss, std=run.gnss.std * math.sqrt(lam)),
                            t_alarm) if recover else None
        if reset is None or recoveries >= MAX_RECOVERIES or k >= len(res.t) - 2:
            why = reason if recoveries == 0 else f"{reason} after {recoveries} re-initialisation(s)"
            return _cut(res, t_alarm), RunStatus("diverged", t_alarm - run.t[0], why, recoveries, steps)
        log.warning("%s: %s; re-initialised from the next fix", run.name, reason)
        gnss = run.gnss
        after = gnss.t_valid > t_alarm + GRID_TOL_S
        gnss = replace(gnss, **{f: getattr(gnss, f)[after] for f in ("t_valid", "t_arrival", "p_local", "std", "flags")})
        # the variance factor learnt so far carries over (the tail's own NoiseScaler starts at 1)
        lam = float(res.r_scale[j - 1]) if 0 < j <= len(res.r_scale) else 1.0
        gnss = replace(gnss, std=gnss.std * math.sqrt(lam))
        tail_run = EkfRun(run.name, res.t[k:], run.u[k:], reset[0], reset[1], gnss)
        tail, status = _run_alone(model, tail_run, gate_prob, lateral)
        recoveries += 1
        if tail is None or status.status != "ok":
            head = _cut(res, t_alarm) if tail is None else _splice(res, tail)
            t_s = status.t_s + (res.t[k] - run.t[0]) if status.status == "diverged" else t_alarm - run.t[0]
            return head, RunStatus(status.status if tail is not None else "diverged", t_s,
                                   status.reason or reason, recoveries, steps)
        checked_from = int(np.sum(res.nis_t < res.t[k] - GRID_TOL_S))
        res = _splice(res, tail)


def guarded_ekf_batch(model: ProcessModel, runs: list[EkfRun], lateral: LateralConstraint | None = None,
                      recover: bool = True, gate_prob: float = GATE_PROB, step_test: bool = True
                      ) -> list[tuple[EkfResult | None, RunStatus]]:
    """Return each run's EKF result (None if it failed) and :class:`RunStatus`.

    The runs go through :func:`sindy_ekf.estimation.ekf.run_ekf_batch` together; if the batch
    raises, each run is filtered alone so that one run's divergence costs only that run. Runs
    with GNSS are then watched by :func:`nis_alarm` and, with ``recover``, re-initialised
    (module docstring); ``step_test`` first asks :func:`fixes_stepped` whether an alarm is a step
    of the fixes rather than a lost filter.
    """
    kw = {"lateral": lateral, "gate_prob": gate_prob}
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model overflows: expected here
            out = [(res, RunStatus()) for res in run_ekf_batch(model, runs, **kw)]
    except Exception:  # noqa: BLE001 - find the culprit run by run
        out = [_run_alone(model, r, gate_prob, lateral) for r in runs]
    final = []
    for run, (res, status) in zip(runs, out):
        if res is not None and status.status == "ok" and run.gnss is not None:
            res, status = watch_nis(model, run, res, gate_prob, lateral, recover, step_test)
        if status.status != "ok":
            log.warning("%s: %s at t=%.2f s: %s", run.name, status.status, status.t_s, status.reason)
        final.append((res, status))
    return final


def guarded(fn, *args, **kwargs):
    """Return ``(fn(*args, **kwargs), RunStatus())``, or ``(None, failed status)`` if it raises
    (a non-finite state is ``diverged`` at its time)."""
    try:
        with np.errstate(over="ignore", invalid="ignore"):  # a diverging model overflows: expected here
            value = fn(*args, **kwargs)
    except DivergenceError as exc:
        return None, RunStatus("diverged", exc.t_s, _one_line(exc))
    except Exception as exc:  # noqa: BLE001 - an estimator failing must not stop the others
        return None, RunStatus("failed", 0.0, _one_line(exc))
    x = getattr(value, "x", None)
    if x is not None and not np.all(np.isfinite(x)):
        bad = np.flatnonzero(~np.all(np.isfinite(np.asarray(x).reshape(len(x), -1)), axis=1))[0]
        t = np.asarray(value.t)
        return None, RunStatus("diverged", float(t[bad] - t[0]), "estimate became non-finite")
    return value, RunStatus()


def combined_status(statuses: dict[str, RunStatus]) -> RunStatus:
    """Return one estimator's status over its runs: the worst run's, the reason naming the run."""
    worst = max(statuses.items(), key=lambda kv: STATUS_ORDER.index(kv[1].status), default=(None, RunStatus()))
    recoveries = sum(s.recoveries for s in statuses.values())
    steps = sum(s.fix_steps for s in statuses.values())
    repairs = sum(s.pd_repairs for s in statuses.values())
    run, s = worst
    if s.status == "ok":
        return RunStatus(recoveries=recoveries, fix_steps=steps, pd_repairs=repairs)
    others = sum(1 for v in statuses.values() if v.status != "ok") - 1
    more = f" (and {others} other run(s))" if others > 0 else ""
    reason = s.reason if s.reason.startswith(run) else f"{run}: {s.reason}"
    return RunStatus(s.status, s.t_s, f"{reason}{more}", recoveries, steps, repairs)


def empty_score(runtime_s: float) -> Score:
    """Return the scores of an estimator without any estimate (all NaN)."""
    nan = float("nan")
    return Score(nan, nan, {}, {}, nan, nan, nan, nan, float(runtime_s), nan)


def score_partial(estimates: dict[str, Estimate], truth: dict[str, np.ndarray], outages: dict[str, np.ndarray],
                  runtime_s: float, status: RunStatus) -> tuple[Score, dict[str, np.ndarray]]:
    """Return :func:`sindy_ekf.benchmark.scoring.score_estimator` over the time each run has an
    estimate (truth cut to the same poses, outages ended by then), with ``status`` in the score."""
    cut_truth, cut_out, kept = {}, {}, {}
    for run, tr in truth.items():
        e = estimates.get(run)
        if e is None or len(e.t) < 2:
            continue
        tr = tr[:len(e.t)]
        cut_truth[run], kept[run] = tr, e
        o = np.asarray(outages[run]).reshape(-1, 2)
        cut_out[run] = o[o[:, 1] <= tr[-1, 0] + GRID_TOL_S]
    if cut_truth:
        score, curves = score_estimator(kept, cut_truth, cut_out, runtime_s)
    else:
        score, curves = empty_score(runtime_s), {}
    return replace(score, status=status.status, t_s=status.t_s, reason=status.reason,
                   recoveries=status.recoveries, pd_repairs=status.pd_repairs), curves


def split_short_runs(runs, min_s: float = MIN_RUN_S) -> tuple[list, dict[str, str]]:
    """Return the runs long enough to benchmark and ``{run: why}`` of those skipped.

    A run needs :data:`MIN_RUN_POSES` finite poses spanning at least ``min_s`` seconds.
    """
    kept, skipped = [], {}
    for run in runs:
        t = pose_truth(run.poses)[0][:, 0]
        span = float(t[-1] - t[0]) if t.size else 0.0
        if t.size < MIN_RUN_POSES or span < min_s:
            skipped[run.name] = (f"run {run.name}: {span:.1f} s with {t.size} usable poses, shorter than "
                                 f"the {min_s:g} s a benchmark run needs; skipped")
            log.warning("%s", skipped[run.name])
        else:
            kept.append(run)
    return kept, skipped
