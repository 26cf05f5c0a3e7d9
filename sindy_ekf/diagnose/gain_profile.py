"""The input gain over time since the run start, of any monotone shape (issue 15, item 1: time_dependence).

The ``time_dependence`` family is detected and scored with one mechanism: a gain falling linearly with
time since the run start, one rate for both inputs. That keeps the choice of form and the calibrated
thresholds as they are. A battery sag need not be linear: most of it may come in the first minute,
or only after a while. Once the family is significant, :func:`gain_profile` measures the shape
without assuming one:

- the windows of the train runs are binned by their start time since the run start (:data:`N_BINS`
  equal bins over the time the runs cover, a bin with fewer than :data:`MIN_WINDOWS` windows
  merged into the one before it);
- in each bin, one gain ``g`` for both inputs scales the model's inputs (the model with its input
  gains recalibrated on all train runs, the null the family was scored against). ``g`` minimises
  the weighted window residual (eq. 5.55) in that bin, on a grid of ``log g`` refined by the
  parabola through the best point and its neighbours (:func:`sindy_ekf.diagnose.grids.parabolic_argmin`);
- a monotone sequence (non-increasing or non-decreasing, whichever fits the bins better) is fitted to
  the bins' ``log g`` by weighted isotonic regression (pool adjacent violators, weights the bins'
  window counts);
- the loss over the runs is ``1 - g_last / g_first`` of the monotone fit, between the first and the
  last bin's centre. It is the quantity the data measure whatever the shape. The linear mechanism's
  ``decay_per_10min`` extrapolates to 600 s, which only the linear shape supports;
- the standard deviations come from leaving one train run out at a time (jackknife), the
  bins' residual sums recomputed without the run and the monotone fit redone. A run whose removal
  empties a bin gives no replicate: where the late bins rest on the longest run alone
  (``gain_profile_runs``), their spread between runs is not measured and the deviations understate it.

The model's degree in the inputs makes the window prediction at a common gain a polynomial in ``g``:
``sum_d g^d P_d`` with ``P_d`` the window integrals of the active terms of input degree ``d``. Every
bin, grid point and left-out run is then one vectorised evaluation.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from groundfloor.numbers import finite_or_none
from sindy_ekf.diagnose.data import Split
from sindy_ekf.diagnose.design import INPUT_GAIN_BOUNDS, ActiveTerms, input_degrees
from sindy_ekf.diagnose.grids import parabolic_argmin

#: bins of time since the run start the train windows are sorted into
N_BINS = 6
#: fewest windows a bin is fitted on (equal bins are pooled in order until each holds this many)
MIN_WINDOWS = 12
#: points of the ``log g`` grid over :data:`sindy_ekf.diagnose.design.INPUT_GAIN_BOUNDS`
GRID_POINTS = 801


def isotonic(y: np.ndarray, w: np.ndarray, increasing: bool) -> np.ndarray:
    """Return the weighted least-squares monotone fit of ``y (n,)`` (pool adjacent violators)."""
    y, w = np.asarray(y, float), np.asarray(w, float)
    if not increasing:
        return -isotonic(-y, w, True)
    blocks: list[list[float]] = []  # [mean, weight, count]
    for yi, wi in zip(y, w):
        blocks.append([yi, wi, 1])
        while len(blocks) > 1 and blocks[-2][0] > blocks[-1][0]:
            m2, w2, n2 = blocks.pop()
            m1, w1, n1 = blocks.pop()
            blocks.append([(m1 * w1 + m2 * w2) / (w1 + w2), w1 + w2, n1 + n2])
    return np.concatenate([np.full(n, m) for m, _, n in blocks])


def monotone(y: np.ndarray, w: np.ndarray) -> np.ndarray:
    """Return the better (weighted SSE) of the non-increasing and the non-decreasing fit of ``y``."""
    fits = [isotonic(y, w, inc) for inc in (False, True)]
    return min(fits, key=lambda f: float(np.sum(w * (y - f) ** 2)))


def time_bins(t_start: np.ndarray, n_bins: int = N_BINS, min_windows: int = MIN_WINDOWS) -> np.ndarray:
    """Return the bin ``(p,)`` of windows starting at ``t_start (p,)`` (s since the run start):
    ``n_bins`` equal bins over ``[0, max]``, pooled in order until each holds ``min_windows``
    windows (a short remainder joins the last full bin); all 0 when the windows fill one bin only."""
    t = np.asarray(t_start, float)
    edges = np.linspace(0.0, float(t.max()) + 1e-9, n_bins + 1)
    idx = np.clip(np.searchsorted(edges, t, side="right") - 1, 0, n_bins - 1)
    counts = np.bincount(idx, minlength=n_bins)
    label, cur, filled = np.zeros(n_bins, int), 0, 0
    for b in range(n_bins):
        if filled >= min_windows:  # the current bin is full: a new one starts here
            cur, filled = cur + 1, 0
        label[b], filled = cur, filled + counts[b]
    if filled < min_windows and cur > 0:  # a short remainder joins the bin before
        label[label == cur] = cur - 1
    return label[idx]


def gain_profile(model, split: Split, weights: np.ndarray, n_bins: int = N_BINS) -> dict | None:
    """Return the input gain's profile over time since the run start on ``split`` (train runs).

    ``model`` is the null the family was scored against (input gains recalibrated); ``weights``
    ``(3,)`` the equation weights. Returns None without at least two bins. Otherwise the keys are
    ``gain_profile_t_s`` (the bins' mean window start, s), ``gain_profile_runs`` (how many runs reach
    each bin), ``gain_profile`` (the bins' gains),
    ``gain_profile_std``, ``gain_profile_monotone`` (the monotone fit), ``loss_over_runs`` (``1 -
    g_last / g_first`` of the fit), ``loss_over_runs_std``, and ``loss_from_s`` and ``loss_to_s``
    (the first and last bin's time). None as well for a model without input terms (no gain to fit).
    """
    bins = time_bins(split.t_run[split.start], n_bins)
    n_b = int(bins.max()) + 1
    if n_b < 2:
        return None
    act = ActiveTerms(model)
    deg = input_degrees(act.library).sum(axis=1)  # (k,) degree of each feature in the inputs
    feats = split.integrate(act.library.transform(np.concatenate([split.v_body, split.u], axis=-1)))  # (p, k)
    degrees = np.unique(deg[np.any(act.coef != 0, axis=0)])
    if not np.any(degrees > 0):
        return None
    P = np.stack([feats @ (act.coef * (deg == d)).T for d in degrees])  # (D, p, 3)
    log_g = np.linspace(*np.log(INPUT_GAIN_BOUNDS), GRID_POINTS)
    scale = np.exp(np.outer(log_g, degrees))  # (G, D)
    sw = np.asarray(weights, float)
    runs = split.window_run
    n_runs = len(split.names)
    # residual sums per (grid point, bin, run): every bin, jackknife replicate and grid point at once
    sse = np.zeros((len(log_g), n_b, n_runs))
    dv = split.delta_v
    member = np.zeros((len(dv), n_b * n_runs))  # window -> its (bin, run): the sums as one product
    member[np.arange(len(dv)), bins * n_runs + runs] = 1.0
    for chunk in np.array_split(np.arange(len(log_g)), max(1, len(log_g) * len(dv) // 2_000_000)):
        pred = np.einsum("gd,dpe->gpe", scale[chunk], P)
        r2 = ((dv[None] - pred) ** 2 * sw).sum(axis=-1)  # (g, p)
        sse[chunk] = (r2 @ member).reshape(len(chunk), n_b, n_runs)
    counts = np.bincount(bins, minlength=n_b).astype(float)
    per_run = np.bincount(bins * n_runs + runs, minlength=n_b * n_runs).reshape(n_b, n_runs)
    n_runs_bin = (per_run > 0).sum(axis=1)  # how many runs reach each bin (a late bin may rest on the longest)
    t_bin = np.bincount(bins, weights=split.t_run[split.start], minlength=n_b) / counts

    def fit(total: np.ndarray, w: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
        lg = np.array([parabolic_argmin(log_g[:, None], total[:, b])[0] for b in range(n_b)])
        mono = monotone(lg, w)
        return lg, mono, float(1.0 - np.exp(mono[-1] - mono[0]))

    lg, mono, loss = fit(sse.sum(axis=2), counts)
    reps = []
    for r in range(n_runs):
        left = sse.sum(axis=2) - sse[:, :, r]
        w_r = counts - np.bincount(bins[runs == r], minlength=n_b)
        if np.all(w_r > 0):
            reps.append(fit(left, w_r))
    std_g, std_loss = np.full(n_b, np.nan), float("nan")
    if len(reps) > 1:  # jackknife: (n - 1) / n x the sum of squared deviations
        n = len(reps)
        g_reps = np.exp(np.array([x[0] for x in reps]))
        std_g = np.sqrt((n - 1) / n * np.sum((g_reps - g_reps.mean(0)) ** 2, axis=0))
        l_reps = np.array([x[2] for x in reps])
        std_loss = float(np.sqrt((n - 1) / n * np.sum((l_reps - l_reps.mean()) ** 2)))
    return {"gain_profile_t_s": t_bin.tolist(), "gain_profile_runs": n_runs_bin.tolist(),
            "gain_profile": np.exp(lg).tolist(),
            "gain_profile_std": [finite_or_none(x) for x in std_g], "gain_profile_monotone": np.exp(mono).tolist(),
            "loss_over_runs": loss, "loss_over_runs_std": finite_or_none(std_loss),
            "loss_from_s": float(t_bin[0]), "loss_to_s": float(t_bin[-1])}


def shown_estimate(estimate: dict) -> dict:
    """Return ``estimate`` without the profile's per-bin lists (``gain_profile*``), for tables and the
    terminal: the lists go to the JSON and the figure, ``loss_over_runs`` and its times stay."""
    return {k: v for k, v in estimate.items() if not k.startswith("gain_profile")}


def named_profile(ranked) -> dict | None:
    """Return the estimate of a significant ``time_dependence`` holding a profile in ``ranked`` (the
    diagnosis's causes), or None: what the figures draw."""
    return next((c.score.estimate for c in ranked if c.name == "time_dependence" and c.significant
                 and "gain_profile" in c.score.estimate), None)


def with_gain_profile(score, null_model, train: Split, weights: np.ndarray):
    """Return ``score`` with the gain profile in its estimate when its family is ``time_dependence``
    (unchanged otherwise, or when the train runs hold fewer than two bins)."""
    if score.family != "time_dependence":
        return score
    prof = gain_profile(null_model, train, weights)
    return dataclasses.replace(score, estimate={**score.estimate, **prof}) if prof else score
