"""Clock synchronisation of the two laser trackers with the trigger (thesis section 5.2.2).

Per run and tracker: the gap signal (eq. 5.6) with the 35 ms threshold, coarse alignment by
cross-correlation at 1 kHz (5.7, 5.8), gap matching within 4 ms (5.9), the linear clock model
with its uncertainty (5.10 to 5.12). Then the AT960's extra offset by minimising the spread of
the prism-to-prism distance (5.13 to 5.20) with its uncertainty by error propagation (5.21,
5.22), applied (5.23, 5.24), and both trackers interpolated at the trigger times.

Two steps go beyond the thesis, both because the data allow more than the gaps alone:

* the gap matching is iterated with the fitted clock model, so that gaps at the ends of a long
  run, which the drift carries beyond 4 ms of the coarse alignment, are matched too;
* every tracker sample is then matched to its trigger, and the clock model is refitted on all
  matched samples (hundreds per gap instead of one). This also gives the counts of matched,
  lost and spurious triggers that interference on the trigger cable causes (thesis 4.2.1).

The AT960 timing error (it measures on the falling trigger edge, thesis 4.2.2) is found from the
data, as the thesis found it: before correcting, the Pearson correlation of the baseline-length
variation with the forward speed is reported (:func:`timing_error_correlation`); a strong one
says that one tracker measures at another time than the other.

All times inside are relative: trigger times to the run's first trigger (UTC) and tracker times
to the tracker's first sample, so float64 keeps sub-microsecond precision.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field

import numpy as np
from scipy import signal

from identification.types import RawRun
from sindy_ekf.errors import InputError

log = logging.getLogger(__name__)

GAP_THRESHOLD_S = 0.035  # thesis 5.2.2: separates the skipped pulse (40 ms) from 20 ms steps
XCORR_RATE_HZ = 1000.0  # thesis eq. 5.8
GAP_MATCH_TOL_S = 0.004  # thesis 5.2.2
MAX_INTERP_GAP_S = 0.05  # interpolate across one missing sample at most, never across a dropout
MAX_LOST_STRETCH = 3  # longer stretches of unmatched triggers are a silent tracker, not lost pulses
MIN_CLOCK_GAPS = 3
AMBIGUOUS_RATIO = 0.9  # a second xcorr peak this high: the periodic gaps leave the shift open
RECEIVE_WINDOW_S = 1.0  # half the 3 s gap period: bag receive times pick the peak within this
MAX_BASELINE_SPREAD_M = 0.02  # above it after synchronisation the two trackers disagree


@dataclass(frozen=True)
class ClockModel:
    """Linear clock model of one tracker in one run (eqs. 5.10 to 5.12).

    ``s_trigger = k * (s_tracker - tau) + d`` with ``s_trigger = t_trigger_utc - t0_utc`` and
    ``s_tracker = t_tracker - t0_tracker``.
    """

    tracker: str
    k: float
    d: float  # s
    tau: float  # coarse shift from the cross-correlation, s (eq. 5.8)
    t0_tracker: float  # tracker clock at its first sample, s
    k_std: float
    d_std: float  # s
    residual_std: float  # s, of the samples the final fit used
    n_gaps_tracker: int  # gaps detected in the tracker's stamps
    n_gaps_matched: int  # of those matched to trigger gaps within 4 ms
    n_fit: int  # samples of the final fit (all matched samples)
    xcorr_peak_ratio: float  # second-highest peak (>0.5 s away) over the highest, of eq. 5.7

    @property
    def drift_ppm(self) -> float:
        """(k - 1) * 1e6, as INTERFACES.md defines it."""
        return (self.k - 1.0) * 1e6

    @property
    def drift_std_ppm(self) -> float:
        """Standard deviation of the drift, ppm."""
        return self.k_std * 1e6

    def s_trigger_from_tracker(self, t_tracker: np.ndarray) -> np.ndarray:
        """Return tracker stamps mapped to trigger time relative to t0 (implements eq. 5.12)."""
        return self.k * (np.asarray(t_tracker) - self.t0_tracker - self.tau) + self.d


@dataclass(frozen=True)
class OffsetEstimate:
    """The AT960's extra offset per run (eqs. 5.13 to 5.22), sign of eq. 5.24."""

    dt: float  # s, added to the AT960's clock-model times (eq. 5.24)
    dt_std: float  # s, by error propagation (eqs. 5.21, 5.22)
    coeffs: np.ndarray  # (3,) [a, b, c] of eq. 5.19
    cov: np.ndarray  # (3, 3) covariance of the coefficients
    dt_grid: np.ndarray  # offsets of the fine grid around the minimum, s
    spread_grid: np.ndarray  # baseline spread s_r at those offsets (eq. 5.16), m
    dt_fit: np.ndarray  # the ten samples of the quadratic fit (eq. 5.19)
    spread_fit: np.ndarray
    hub_terms: bool  # spread taken after removing the eq. 5.25 hub terms (joint estimate)
    dt_without_hub: float  # the thesis's estimate: spread of the raw baseline length, s


@dataclass(frozen=True)
class TrackerCounts:
    """What became of one tracker's samples and of the triggers it should have answered."""

    samples: int  # messages on the topic
    matched: int  # samples matched one-to-one to a trigger
    spurious: int  # samples matching no trigger (extra pulses on the cable)
    lost: int  # triggers without a sample inside short stretches (lost pulses)
    out_of_view: int  # triggers in long stretches without samples (prism lost, tracker silent)
    dropped_nan: int  # samples with non-finite coordinates, not used for positions

    def to_dict(self) -> dict[str, int]:
        """Return the counts as a plain dict for JSON."""
        return {k: int(v) for k, v in self.__dict__.items()}


@dataclass(frozen=True)
class SyncedRun:
    """One run with both trackers on the trigger time base (result of :func:`sync_run`).

    Positions are in the local (AT960) frame, at the trigger times, NaN where a tracker had no
    sample within ``MAX_INTERP_GAP_S``.
    """

    name: str
    split: str
    t0_utc: float  # UTC of the run's first trigger, s
    s_trigger: np.ndarray  # (n,) trigger times relative to t0, s
    p_front_local: np.ndarray  # (n, 3) m
    p_rear_local: np.ndarray  # (n, 3) m
    clock: dict[str, ClockModel]  # "at960", "ltd800"; the offset is folded into offset_tracker's d
    offset_tracker: str  # the tracker found to measure late (the AT960 in the thesis)
    offset: OffsetEstimate
    baseline_before_m: np.ndarray  # (n,) eq. 5.13 with the clock models only (NaN where unknown)
    baseline_after_m: np.ndarray  # (n,) after the AT960 offset (eq. 5.24)
    v_forward: np.ndarray  # (n,) forward speed from the prism positions, m/s (with sign)
    r_speed_before: float  # Pearson r of baseline variation with forward speed, before
    r_speed_after: float  # the same after the offset correction (and the hub terms, if joint)
    counts: dict[str, TrackerCounts]
    residuals: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    # tracker -> (s_trigger of matched samples, mapped tracker time - trigger time), fig. 5.4

    @property
    def t_utc(self) -> np.ndarray:
        """Absolute trigger times, UTC s."""
        return self.t0_utc + self.s_trigger

    @property
    def both_seen(self) -> np.ndarray:
        """(n,) True where both prisms have a position."""
        return np.isfinite(self.p_front_local[:, 0]) & np.isfinite(self.p_rear_local[:, 0])

    def baseline_rms_m(self, which: str = "after") -> float:
        """Return the RMS of the baseline length about its mean, before or after the offset."""
        base = self.baseline_before_m if which == "before" else self.baseline_after_m
        return float(np.nanstd(base))


# --- gaps and coarse alignment (eqs. 5.6 to 5.9) ------------------------------------------


def gap_signal(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Return the gap signal ``(t_i, t_{i+1} - t_i)`` of a stamp series (implements eq. 5.6)."""
    t = np.asarray(t, dtype=float)
    return t[:-1], np.diff(t)


def detect_gaps(t: np.ndarray, threshold_s: float = GAP_THRESHOLD_S) -> np.ndarray:
    """Return the stamps after which the next one comes more than ``threshold_s`` later (5.2.2)."""
    t_i, dt = gap_signal(t)
    return t_i[dt > threshold_s]


def _gap_grid(t: np.ndarray, rate_hz: float) -> np.ndarray:
    """Gap signal resampled at ``rate_hz`` from the series' first stamp (thesis: numpy interp).

    The median (the nominal period) is removed so that the correlation is made by the gaps, not
    by the overlap length, and dropouts are clipped to twice a gap so one long silence cannot
    outweigh many gaps.
    """
    t_i, dt = gap_signal(t)
    grid = np.arange(0.0, t_i[-1] - t_i[0], 1.0 / rate_hz) + t_i[0]
    f = np.interp(grid, t_i, dt)
    f -= np.median(dt)
    return np.clip(f, -GAP_THRESHOLD_S, 2 * GAP_THRESHOLD_S)


def xcorr_gap_signals(s_trigger: np.ndarray, s_tracker: np.ndarray,
                      rate_hz: float = XCORR_RATE_HZ) -> tuple[np.ndarray, np.ndarray]:
    """Return ``(tau_candidates_s, correlation)`` of the two gap signals (implements eq. 5.7).

    ``tau`` is the shift such that ``s_tracker - tau`` is on the trigger's time base; both
    inputs are relative times starting at 0.
    """
    f_rpi = _gap_grid(s_trigger, rate_hz)
    f_tr = _gap_grid(s_tracker, rate_hz)
    corr = signal.correlate(f_rpi, f_tr, mode="full", method="fft")
    lags = signal.correlation_lags(f_rpi.size, f_tr.size, mode="full")
    # corr[lag] = sum_n f_rpi[n + lag] f_tr[n]: the tracker's sample n is trigger sample n + lag
    tau = -(lags / rate_hz + s_trigger[0] - s_tracker[0])
    return tau, corr


def coarse_shift(s_trigger: np.ndarray, s_tracker: np.ndarray, s_receive: np.ndarray | None = None,
                 rate_hz: float = XCORR_RATE_HZ) -> tuple[float, float]:
    """Return ``(tau, peak_ratio)``: the shift at the correlation maximum (eq. 5.8) and the ratio
    of the best peak more than 0.5 s away to it (near 1 means the alignment is ambiguous).

    The gaps repeat every 3 s, so when a tracker covers only part of the run, shifts 3 s apart
    correlate equally well. Then, if given, the bag receive times of the tracker messages
    (``s_receive``, relative to the run's first trigger, good to a fraction of a second) choose
    the peak: the maximum within ``RECEIVE_WINDOW_S`` of the shift they imply.
    """
    tau, corr = xcorr_gap_signals(s_trigger, s_tracker, rate_hz)
    best = int(np.argmax(corr))
    far = np.abs(tau - tau[best]) > 0.5
    ratio = float(corr[far].max() / corr[best]) if far.any() and corr[best] > 0 else 0.0
    if ratio > AMBIGUOUS_RATIO and s_receive is not None and np.size(s_receive):
        # receive times lag the measurement by the latency, so this shift is a lower bound
        tau_rx = float(np.median(s_tracker - s_receive))
        near = np.abs(tau - tau_rx) <= RECEIVE_WINDOW_S
        if near.any():
            best = int(np.flatnonzero(near)[np.argmax(corr[near])])
    return float(tau[best]), ratio


def match_nearest(a: np.ndarray, b: np.ndarray, tol: float) -> tuple[np.ndarray, np.ndarray]:
    """Return index pairs ``(ia, ib)`` matching sorted ``a`` to its nearest in sorted ``b`` within
    ``tol``, one-to-one (where two ``a`` claim one ``b``, the closer keeps it)."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    if a.size == 0 or b.size == 0:
        return np.empty(0, int), np.empty(0, int)
    j = np.clip(np.searchsorted(b, a), 1, b.size - 1) if b.size > 1 else np.zeros(a.size, int)
    if b.size > 1:
        j = np.where(np.abs(a - b[j - 1]) < np.abs(a - b[j]), j - 1, j)
    err = np.abs(a - b[j])
    ok = np.flatnonzero(err <= tol)
    order = ok[np.argsort(err[ok], kind="stable")]
    _, first = np.unique(j[order], return_index=True)
    ia = np.sort(order[first])
    return ia, j[ia]


def fit_linear_clock(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float, float]:
    """Return ``(k, d, k_std, d_std, residual_std)`` of ``y = k x + d`` by least squares (5.11).

    Fitted as ``y - x = (k - 1) x + d`` so that the drift keeps its digits.
    """
    x, y = np.asarray(x, float), np.asarray(y, float)
    A = np.column_stack([x, np.ones_like(x)])
    sol, *_ = np.linalg.lstsq(A, y - x, rcond=None)
    res = y - x - A @ sol
    dof = max(x.size - 2, 1)
    s0 = float(np.sqrt(res @ res / dof))
    cov = s0**2 * np.linalg.inv(A.T @ A)
    return 1.0 + sol[0], float(sol[1]), float(np.sqrt(cov[0, 0])), float(np.sqrt(cov[1, 1])), s0


def fit_clock_model(tracker: str, s_trigger: np.ndarray, t_tracker: np.ndarray, run: str = "?",
                    s_receive: np.ndarray | None = None) -> tuple[ClockModel, np.ndarray, np.ndarray]:
    """Return the tracker's clock model and the matched ``(trigger, sample)`` index pairs.

    Implements eqs. 5.6 to 5.12: gaps (35 ms), coarse shift by cross-correlation, gap matching
    within 4 ms, linear model on the gaps (iterated with the model so that drift at the ends of
    long runs does not exceed the tolerance), then every sample matched to its trigger and the
    model refitted on all matched samples.

    Raises
    ------
    InputError
        If fewer than 3 gaps of the trigger pattern can be matched (names run and tracker).
    """
    topic = f"/{tracker}/measurement"
    t0_tr = float(t_tracker[0])
    s_tr = np.asarray(t_tracker, float) - t0_tr
    gaps_rpi = detect_gaps(s_trigger)
    gaps_tr = detect_gaps(s_tr)
    if gaps_rpi.size < MIN_CLOCK_GAPS or gaps_tr.size < MIN_CLOCK_GAPS:
        which = "/rpi/trigger" if gaps_rpi.size < MIN_CLOCK_GAPS else topic
        raise InputError(f"run {run}: topic {which}: no detectable gaps of the trigger pattern "
                         f"(need {MIN_CLOCK_GAPS} steps > {GAP_THRESHOLD_S * 1e3:.0f} ms)")
    tau, ratio = coarse_shift(s_trigger, s_tr, s_receive)
    if ratio > AMBIGUOUS_RATIO and s_receive is None:
        log.warning("run %s: topic %s: gap cross-correlation ambiguous (peaks 3 s apart, ratio "
                    "%.3f) and no bag receive times to decide", run, topic, ratio)
    k, d = 1.0, 0.0
    for _ in range(3):  # eq. 5.9 and matching; then again with the fitted drift
        mapped = k * (gaps_tr - tau) + d
        ig, jt = match_nearest(gaps_rpi, mapped, GAP_MATCH_TOL_S)
        if ig.size < MIN_CLOCK_GAPS:
            raise InputError(f"run {run}: topic {topic}: only {ig.size} gaps match the trigger's "
                             f"within {GAP_MATCH_TOL_S * 1e3:.0f} ms")
        k, d, *_ = fit_linear_clock(gaps_tr[jt] - tau, gaps_rpi[ig])
    n_gaps = ig.size
    # every sample to its trigger: tolerance from the spread of the gap residuals (the AT960's
    # falling-edge stamps scatter by the varying duty cycle, the LTD800's by microseconds)
    res_gap = gaps_rpi[ig] - (k * (gaps_tr[jt] - tau) + d)
    spread = 1.4826 * np.median(np.abs(res_gap - np.median(res_gap)))
    tol = float(np.clip(10 * spread, 1e-3, 5e-3))
    for _ in range(2):
        i_trig, j_tr = match_nearest(s_trigger, k * (s_tr - tau) + d, tol)
        k, d, k_std, d_std, res_std = fit_linear_clock(s_tr[j_tr] - tau, s_trigger[i_trig])
    model = ClockModel(tracker=tracker, k=k, d=d, tau=tau, t0_tracker=t0_tr, k_std=k_std,
                       d_std=d_std, residual_std=res_std, n_gaps_tracker=int(gaps_tr.size),
                       n_gaps_matched=int(n_gaps), n_fit=int(i_trig.size), xcorr_peak_ratio=ratio)
    return model, i_trig, j_tr


def count_samples(n_trigger: int, n_samples: int, i_trig: np.ndarray, n_nan: int) -> TrackerCounts:
    """Return the counts of one tracker: matched, spurious, lost and out-of-view triggers."""
    answered = np.zeros(n_trigger, bool)
    answered[i_trig] = True
    # stretches of unanswered triggers: short ones are lost pulses, long ones a silent tracker
    edges = np.diff(np.concatenate([[0], (~answered).astype(np.int8), [0]]))
    starts, stops = np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)
    length = stops - starts
    short = length <= MAX_LOST_STRETCH
    inner = (starts > 0) & (stops < n_trigger)  # a run starting/ending without the tracker
    lost = int(length[short & inner].sum())
    return TrackerCounts(samples=n_samples, matched=int(i_trig.size),
                         spurious=int(n_samples - i_trig.size), lost=lost,
                         out_of_view=int(length.sum() - lost), dropped_nan=n_nan)


# --- interpolation, baseline, AT960 offset (eqs. 5.13 to 5.24) -----------------------------


def track_interpolator(s_samples: np.ndarray, xyz: np.ndarray, max_gap_s: float = MAX_INTERP_GAP_S,
                       method: str = "cubic"):
    """Return ``f(s_query) -> (..., 3)`` interpolating a tracker's positions, NaN across gaps.

    The thesis (5.2.2) interpolated linearly. Its error is ``a * t1 * t2 / 2`` for an
    acceleration ``a`` between samples ``t1`` before and ``t2`` after the query: some 20 um at
    the AT960's 1.3 ms offset and up to ~0.5 mm across a lost pulse (40 ms) when the prism
    swings round a turn. ``"cubic"`` (default) uses a not-a-knot cubic spline per stretch of
    samples without a gap over ``max_gap_s`` (exact for cubic motion); ``"linear"`` is the
    thesis's. Queries outside the samples or in a gap give NaN.
    """
    from scipy.interpolate import CubicSpline, PPoly

    s_samples = np.asarray(s_samples, float)
    xyz = np.asarray(xyz, float)
    cut = np.flatnonzero(np.diff(s_samples) > max_gap_s) + 1
    knots, coefs = [], []
    for seg in np.split(np.arange(s_samples.size), cut):  # one spline per stretch, not per sample
        if seg.size < 2:
            continue
        x, y = s_samples[seg], xyz[seg]
        if method == "cubic" and seg.size >= 4:
            c = CubicSpline(x, y, bc_type="not-a-knot").c
        else:  # linear, or too few samples for a cubic: as the thesis did
            c = np.zeros((4, seg.size - 1, 3))
            c[2], c[3] = np.diff(y, axis=0) / np.diff(x)[:, None], y[:-1]
        if knots:  # the gap since the previous stretch: NaN polynomial
            coefs.append(np.full((4, 1, 3), np.nan))
        knots.append(x)
        coefs.append(c)
    if not knots:
        return lambda q: np.full(np.shape(q) + (3,), np.nan)
    pp = PPoly(np.concatenate(coefs, axis=1), np.concatenate(knots), extrapolate=False)
    return lambda q: pp(np.asarray(q, float))


def interpolate_at(s_query: np.ndarray, s_samples: np.ndarray, xyz: np.ndarray,
                   max_gap_s: float = MAX_INTERP_GAP_S, method: str = "cubic") -> np.ndarray:
    """Return positions interpolated at ``s_query`` (any shape, + (3,)), NaN where the samples
    around it are more than ``max_gap_s`` apart or outside them (see :func:`track_interpolator`)."""
    return track_interpolator(s_samples, xyz, max_gap_s, method)(s_query)


def forward_speed(s: np.ndarray, p_front: np.ndarray, p_rear: np.ndarray) -> np.ndarray:
    """Return the signed forward speed (m/s) from the prisms: midpoint velocity along rear->front."""
    mid = 0.5 * (p_front[:, :2] + p_rear[:, :2])
    v = np.gradient(mid, s, axis=0)
    head = p_front[:, :2] - p_rear[:, :2]
    head /= np.linalg.norm(head, axis=1, keepdims=True)
    return np.einsum("ij,ij->i", v, head)


def pearson_r(a: np.ndarray, b: np.ndarray) -> float:
    """Return the Pearson correlation of two series over the samples where both are finite."""
    ok = np.isfinite(a) & np.isfinite(b)
    if ok.sum() < 3 or np.std(a[ok]) == 0 or np.std(b[ok]) == 0:
        return float("nan")
    return float(np.corrcoef(a[ok], b[ok])[0, 1])


def timing_error_correlation(baseline_m: np.ndarray, v_forward: np.ndarray) -> float:
    """Return Pearson r of the baseline-length variation with the forward speed (thesis 5.2.2).

    A prism measured at another time than the other one moves by ``v * dt`` along the baseline,
    so ``|r|`` near 1 reveals a timing error (the thesis saw about 0.9, which is how it found the
    AT960's wrong trigger edge); after a correct synchronisation ``|r|`` is small.
    """
    return pearson_r(baseline_m - np.nanmean(baseline_m), v_forward)


def hub_design(t_query: np.ndarray, t_cmd: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Return the (n, 5) design of eq. 5.25 in linear form at the query times, NaN rows before
    the first command: ``[1, cos phi_f, sin phi_f, cos phi_r, sin phi_r]``.

    The hub set points are commands, constant until the next one: a zero-order hold.
    """
    az = azimuth_at(t_query, t_cmd, azimuth)
    return np.column_stack([np.ones(len(az)), np.cos(az[:, 0]), np.sin(az[:, 0]),
                            np.cos(az[:, 1]), np.sin(az[:, 1])])


def azimuth_at(t_query: np.ndarray, t_cmd: np.ndarray, azimuth: np.ndarray) -> np.ndarray:
    """Return the (n, 2) commanded azimuths held since the last command before each query time
    (NaN before the first one)."""
    if len(t_cmd) == 0:
        return np.full((len(t_query), 2), np.nan)
    i = np.searchsorted(t_cmd, t_query, side="right") - 1
    az = np.unwrap(np.asarray(azimuth, float), axis=0)[np.clip(i, 0, None)]
    az[i < 0] = np.nan
    return az


def _spread(dt: np.ndarray, s: np.ndarray, p_ref: np.ndarray, late_at,
            A_hub: np.ndarray | None = None) -> np.ndarray:
    """Return the baseline spread s_r(dt) for each offset in ``dt`` (eqs. 5.15 to 5.17).

    With ``A_hub`` (the eq. 5.25 design at the trigger times) the spread is that of the
    baseline length after the least-squares hub terms are removed at each trial offset.
    """
    p_late = late_at(s[None, :] - np.asarray(dt)[:, None])
    length = np.linalg.norm(p_ref[None] - p_late, axis=-1)
    ok = np.isfinite(length).all(axis=0)  # the same triggers for every offset
    if A_hub is None:
        return length[:, ok].std(axis=1, ddof=1)
    ok &= np.isfinite(A_hub).all(axis=1)
    # orthonormal basis of the hub terms (SVD: rank-revealing if an azimuth barely moves)
    U, sv, _ = np.linalg.svd(A_hub[ok], full_matrices=False)
    U = U[:, sv > sv[0] * 1e-8]
    L = length[:, ok]
    res = L - (L @ U) @ U.T
    return np.sqrt((res**2).sum(axis=1) / (ok.sum() - U.shape[1]))


def fit_extra_offset(s: np.ndarray, p_ref: np.ndarray, s_late: np.ndarray, xyz_late: np.ndarray,
                     search_s: float = 0.01, run: str = "?", A_hub: np.ndarray | None = None,
                     max_gap_s: float = MAX_INTERP_GAP_S) -> OffsetEstimate:
    """Return the extra offset of one tracker's times that minimises the baseline spread.

    Implements eqs. 5.13 to 5.22: ``s_r`` is sampled over ``[-search_s, search_s]`` (coarse,
    then finer around the minimum), a quadratic (5.19) is fitted to ten samples around the
    minimum, its vertex is the offset (5.20) and its standard deviation follows by error
    propagation of the coefficients' covariance (5.21, 5.22). The sign is that of eq. 5.24:
    the shifted tracker's positions at trigger time ``t`` are its samples at ``t - dt`` on its
    clock model; ``p_ref`` are the other tracker's positions at the trigger times ``s``.

    Beyond the thesis: with ``A_hub`` (:func:`hub_design`) the spread is measured after the
    turning-hub terms of eq. 5.25 are removed at every trial offset, i.e. offset and hub
    eccentricity are estimated jointly. The eccentricity seen along the baseline follows the
    hub azimuths, which follow the robot's motion; left in, it correlates with the speed and
    pulls the thesis's estimate by tens of microseconds (``dt_without_hub`` keeps that one).
    """
    late_at = track_interpolator(s_late, xyz_late, max_gap_s)
    est = _fit_offset(s, p_ref, late_at, search_s, run, None)
    if A_hub is None or not np.isfinite(A_hub).all(axis=1).any():
        return est
    joint = _fit_offset(s, p_ref, late_at, search_s, run, A_hub)
    from dataclasses import replace

    return replace(joint, dt_without_hub=est.dt)


def _fit_offset(s, p_ref, late_at, search_s, run, A_hub) -> OffsetEstimate:
    """Grid, quadratic and vertex of :func:`fit_extra_offset` for one spread definition."""
    if np.sum(np.isfinite(p_ref[:, 0])) < 50:
        raise InputError(f"run {run}: fewer than 50 trigger times with both prisms seen; "
                         "cannot estimate the AT960 offset")
    coarse = np.arange(-search_s, search_s + 1e-12, 2.5e-4)
    # the coarse grid only brackets the minimum: every 4th trigger is plenty for that
    sub = np.s_[::4]
    spread_c = _spread(coarse, s[sub], p_ref[sub], late_at, None if A_hub is None else A_hub[sub])
    best = coarse[np.argmin(spread_c)]
    fine = best + np.arange(-3e-4, 3e-4 + 1e-12, 2e-5)
    spread_f = _spread(fine, s, p_ref, late_at, A_hub)
    c = int(np.clip(np.argmin(spread_f), 5, fine.size - 5))
    dt_fit, spread_fit = fine[c - 5:c + 5], spread_f[c - 5:c + 5]
    x0 = dt_fit.mean()  # centre for conditioning; the vertex is shifted back below
    A = np.column_stack([(dt_fit - x0) ** 2, dt_fit - x0, np.ones(10)])
    coef, *_ = np.linalg.lstsq(A, spread_fit, rcond=None)
    res = spread_fit - A @ coef
    cov = (res @ res / (10 - 3)) * np.linalg.inv(A.T @ A)
    a, b, _ = coef
    dt = x0 - b / (2 * a) if a > 0 else np.inf  # eq. 5.20
    if not dt_fit[0] - 1e-4 <= dt <= dt_fit[-1] + 1e-4:
        raise InputError(f"run {run}: baseline spread has no minimum near {best * 1e3:.3f} ms; "
                         "cannot estimate the AT960 offset")
    F = np.array([b / (2 * a**2), -1 / (2 * a), 0.0])  # eq. 5.22
    return OffsetEstimate(dt=float(dt), dt_std=float(np.sqrt(F @ cov @ F)), coeffs=coef, cov=cov,
                          dt_grid=fine, spread_grid=spread_f,
                          dt_fit=dt_fit, spread_fit=spread_fit, hub_terms=A_hub is not None,
                          dt_without_hub=float(dt))


# --- the run ------------------------------------------------------------------------------


def sync_run(raw: RawRun, R_at960_ltd800: np.ndarray, t_at960_ltd800: np.ndarray,
             prism_tracker: dict[str, str] | None = None,
             max_interp_gap_s: float = MAX_INTERP_GAP_S, joint_hub: bool = True) -> SyncedRun:
    """Return the run with both prisms in the local frame at the trigger times (thesis 5.2.2).

    Parameters
    ----------
    raw : RawRun
        The run as read from the bags.
    R_at960_ltd800, t_at960_ltd800 : ndarray
        Transform of eq. 5.1, ``x_at960 = t + R x_ltd800`` (the local frame is the AT960's).
    prism_tracker : dict, optional
        Which tracker follows which prism, ``{"front": "ltd800", "rear": "at960"}`` by default.
    joint_hub : bool
        Estimate the extra offset jointly with the hub terms of eq. 5.25 (see
        :func:`fit_extra_offset`) when the run has hub azimuths; False is the thesis's way.

    Raises
    ------
    InputError
        If a tracker's clock cannot be synchronised (no gaps) or the offset has no minimum.
    """
    prism_tracker = prism_tracker or {"front": "ltd800", "rear": "at960"}
    t0 = float(raw.t_trigger_utc[0])
    s = raw.t_trigger_utc - t0
    series = {"at960": raw.at960, "ltd800": raw.ltd800}
    clock, counts, resid, mapped, xyz_local = {}, {}, {}, {}, {}
    receive = getattr(raw, "t_receive_utc", {})  # BagRun: bag times break xcorr ties
    for tracker, ps in series.items():
        s_rx = receive[tracker] - t0 if tracker in receive else None
        model, i_trig, j_tr = fit_clock_model(tracker, s, ps.t_tracker, run=raw.name, s_receive=s_rx)
        s_tr = model.s_trigger_from_tracker(ps.t_tracker)
        finite = np.isfinite(ps.xyz).all(axis=1)
        clock[tracker] = model
        counts[tracker] = count_samples(s.size, ps.t_tracker.size, i_trig, int((~finite).sum()))
        resid[tracker] = (s[i_trig], s_tr[j_tr] - s[i_trig])
        xyz = ps.xyz[finite]
        if tracker == "ltd800":
            xyz = xyz @ np.asarray(R_at960_ltd800).T + np.asarray(t_at960_ltd800)
        mapped[tracker], xyz_local[tracker] = s_tr[finite], xyz
        if counts[tracker].dropped_nan:
            log.warning("run %s: topic /%s/measurement: %d samples with NaN coordinates dropped",
                        raw.name, tracker, counts[tracker].dropped_nan)

    # The extra offset goes to the tracker whose stamps scatter more about the trigger times
    # (a varying duty cycle shows there, thesis fig. 5.4): found from the data, not assumed.
    late = max(clock, key=lambda k: clock[k].residual_std)
    ref = "ltd800" if late == "at960" else "at960"
    late_at = track_interpolator(mapped[late], xyz_local[late], max_interp_gap_s)
    p_ref = interpolate_at(s, mapped[ref], xyz_local[ref], max_interp_gap_s)
    p_late_0 = late_at(s)
    A_hub = hub_design(raw.t_trigger_utc, raw.t_hub_utc, raw.hub_azimuth) if joint_hub else None
    offset = fit_extra_offset(s, p_ref, mapped[late], xyz_local[late], run=raw.name, A_hub=A_hub,
                              max_gap_s=max_interp_gap_s)
    p_late = late_at(s - offset.dt)
    base_0 = np.linalg.norm(p_ref - p_late_0, axis=1)
    base_1 = np.linalg.norm(p_ref - p_late, axis=1)
    if np.nanstd(base_1) > MAX_BASELINE_SPREAD_M:
        raise InputError(f"run {raw.name}: the trackers disagree after synchronisation (baseline "
                         f"spread {np.nanstd(base_1) * 1e3:.1f} mm); clock alignment failed")
    p = {ref: p_ref, late: p_late}
    p_front, p_rear = p[prism_tracker["front"]], p[prism_tracker["rear"]]
    v_fwd = forward_speed(s, p_front, p_rear)
    # after the correction, what is left of the baseline once the hub terms are explained
    r0, r1 = timing_error_correlation(base_0, v_fwd), timing_error_correlation(
        _without_hub_terms(base_1, A_hub) if A_hub is not None else base_1, v_fwd)
    log.info("run %s: baseline vs forward speed r = %.2f before, %.2f after the %s offset of "
             "%.4f ms", raw.name, r0, r1, late, offset.dt * 1e3)
    clock[late] = _with_offset(clock[late], offset.dt)
    return SyncedRun(name=raw.name, split=raw.split, t0_utc=t0, s_trigger=s, p_front_local=p_front,
                     p_rear_local=p_rear, clock=clock, offset_tracker=late, offset=offset,
                     baseline_before_m=base_0, baseline_after_m=base_1, v_forward=v_fwd,
                     r_speed_before=r0, r_speed_after=r1, counts=counts, residuals=resid)


def _without_hub_terms(length: np.ndarray, A_hub: np.ndarray) -> np.ndarray:
    """Return the baseline length minus its least-squares eq. 5.25 hub terms (NaN elsewhere)."""
    ok = np.isfinite(length) & np.isfinite(A_hub).all(axis=1)
    out = np.full_like(length, np.nan)
    if ok.sum() > A_hub.shape[1]:
        coef, *_ = np.linalg.lstsq(A_hub[ok], length[ok], rcond=None)
        out[ok] = length[ok] - A_hub[ok] @ coef + coef[0]
    return out


def _with_offset(model: ClockModel, dt: float) -> ClockModel:
    """Return the clock model with the extra offset folded into ``d`` (eq. 5.24)."""
    from dataclasses import replace

    return replace(model, d=model.d + dt)
