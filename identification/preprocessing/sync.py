"""Clock synchronisation of the two laser trackers with the trigger (thesis section 5.2.2).

Per run: each tracker's clock model (:mod:`identification.preprocessing.clock_sync`, eqs. 5.6 to 5.12),
then the AT960's extra offset by minimising the spread of the prism-to-prism distance
(:mod:`identification.preprocessing.extra_offset`, eqs. 5.13 to 5.22), applied (5.23, 5.24), and both
trackers interpolated at the trigger times; counts of matched, lost and spurious pulses.

The AT960 timing error (it measures on the falling trigger edge, thesis 4.2.2) is found from the
data, as the thesis found it: before correcting, the Pearson correlation of the baseline-length
variation with the forward speed is reported (:func:`timing_error_correlation`); a strong one
says that one tracker measures at another time than the other.

All times inside are relative: trigger times to the run's first trigger (UTC) and tracker times
to the tracker's first sample, so float64 keeps sub-microsecond precision.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace

import numpy as np

from groundfloor.errors import InputError

# azimuth_at is re-exported: the hub tests and bench (H5) import it from here
from groundfloor.types import RawRun
from identification.preprocessing.clock_sync import ClockModel, fit_clock_model
from identification.preprocessing.extra_offset import (  # noqa: F401
    MAX_INTERP_GAP_S,
    OffsetEstimate,
    azimuth_at,
    fit_extra_offset,
    hub_design,
    interpolate_at,
    track_interpolator,
)

log = logging.getLogger(__name__)

MAX_LOST_STRETCH = 3  # longer stretches of unmatched triggers are a silent tracker, not lost pulses
MAX_BASELINE_SPREAD_M = 0.02  # above it after synchronisation the two trackers disagree


@dataclass(frozen=True)
class TrackerCounts:
    """What became of one tracker's samples and of the triggers it should have answered."""

    samples: int  # messages on the topic
    matched: int  # samples matched one-to-one to a trigger
    spurious: int  # samples within the trigger train matching no trigger (extra pulses; unused)
    outside: int  # samples before the first or after the last trigger
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
    residuals: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)
    # tracker -> matched samples' (trigger time, mapped tracker time - trigger time, tracker
    # time since its first sample), before the extra offset: figs. 5.3 and 5.4

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


def count_samples(s_trigger: np.ndarray, s_samples: np.ndarray, i_trig: np.ndarray,
                  n_nan: int) -> TrackerCounts:
    """Return the counts of one tracker: matched, spurious, outside, lost and out-of-view.

    ``s_samples`` are the tracker's stamps on the trigger time base, ``i_trig`` the triggers
    they matched one-to-one. Unmatched samples within the trigger train are spurious pulses,
    those before or after it (a tracker recording longer than the trigger) are "outside".
    """
    n_trigger, n_samples = s_trigger.size, s_samples.size
    half = 0.5 * float(np.median(np.diff(s_trigger)))
    outside = int(np.sum((s_samples < s_trigger[0] - half) | (s_samples > s_trigger[-1] + half)))
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
                         spurious=int(n_samples - i_trig.size - outside), outside=outside, lost=lost,
                         out_of_view=int(length.sum() - lost), dropped_nan=n_nan)


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
    AT960's wrong trigger edge); after a correct synchronisation ``|r|`` is small. The sign
    tells which prism is late: a rear prism measured later than its time stamp says has already
    moved on when driving forward, which shortens the baseline, so ``r < 0``; a late front
    prism gives ``r > 0``.
    """
    return pearson_r(baseline_m - np.nanmean(baseline_m), v_forward)


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
        counts[tracker] = count_samples(s, s_tr, i_trig, int((~finite).sum()))
        resid[tracker] = (s[i_trig], s_tr[j_tr] - s[i_trig], ps.t_tracker[j_tr] - model.t0_tracker)
        # positions from the samples matched to a trigger: a spurious pulse's sample is a true
        # measurement, but a cubic spline through two noisy samples a few ms apart swings wide
        use = np.zeros(finite.size, bool)
        use[j_tr] = True
        use &= finite
        xyz = ps.xyz[use]
        if tracker == "ltd800":
            xyz = xyz @ np.asarray(R_at960_ltd800).T + np.asarray(t_at960_ltd800)
        mapped[tracker], xyz_local[tracker] = s_tr[use], xyz
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
    hub = (raw.t_trigger_utc, raw.t_hub_utc, raw.hub_azimuth) if joint_hub else None
    offset = fit_extra_offset(s, p_ref, mapped[late], xyz_local[late], run=raw.name, hub=hub,
                              max_gap_s=max_interp_gap_s)
    A_hub = hub_design(raw.t_trigger_utc - offset.hub_delay_s, raw.t_hub_utc, raw.hub_azimuth)
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
        _without_hub_terms(base_1, A_hub) if offset.hub_terms else base_1, v_fwd)
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
    return replace(model, d=model.d + dt)
