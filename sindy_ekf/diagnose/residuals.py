"""Where the model is wrong: structure of its residuals against states, inputs, pose, time and lags.

Two kinds of residual, the two ways the thesis judges a model:

- **window by window** (integral regression, eqs. 5.55 to 5.57): over each window of ``tau`` the
  mean acceleration residual ``(Delta v - int f(x, u) dt) / tau`` per equation;
- **multi-step** (evaluation, section 5.3.8): the signed along-track, cross-track and heading
  errors after 5 s of open-loop prediction from each window start.

Each residual is binned against every regressor (window means of ``vx, vy, omega, u1, u2``, the
heading, the position in the lab, the time since the run start, and the input rates ``du/dt``
that a delay would correlate with) and summarised by the bin means with standard errors and the
correlation ratio ``eta^2`` (share of the residual variance the binned means explain) with an F
test whose sample size is corrected for overlapping windows. Large ``eta^2`` with a small
p-value points at what the model is missing; :func:`lag_profile` adds the correlation of the
residual with the inputs shifted by candidate lags.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from identification.sindy.evaluate import (
    EvaluationResult,
    errors_from_rollout,
    make_windows,
    rms_over_windows,
    rollout,
)
from sindy_ekf.diagnose.data import Split
from sindy_ekf.diagnose.input_transforms import inputs_delayed

EQUATIONS = ("vx", "vy", "omega")


@dataclass(frozen=True)
class BinnedEffect:
    """Residual means per bin of one regressor, with standard errors and the correlation ratio."""

    regressor: str
    centers: np.ndarray  # (b,)
    mean: np.ndarray  # (b,) residual mean per bin
    se: np.ndarray  # (b,) standard error of the mean (effective sample size)
    count: np.ndarray  # (b,) windows per bin
    eta2: float  # share of variance explained by the bin means
    p_value: float  # F test of equal bin means, effective sample size


def regressors_of_windows(split: Split) -> dict[str, np.ndarray]:
    """Return ``{name: (p,)}`` regressors of every window (means over the window, pose at its middle)."""
    mean = split.integrate(np.concatenate([split.v_body, split.u], axis=-1)) / split.tau
    mid = (split.start + split.end) // 2
    # forward differences inside each run (dt_next is 0 at a run's last sample)
    step = split.dt_next > 0
    du = np.zeros_like(split.u)
    du[:-1][step[:-1]] = (np.diff(split.u, axis=0)[step[:-1]] / split.dt_next[:-1][step[:-1], None])
    du_mean = split.integrate(du) / split.tau
    return {"vx": mean[:, 0], "vy": mean[:, 1], "omega": mean[:, 2], "u1": mean[:, 3], "u2": mean[:, 4],
            "heading": np.angle(np.exp(1j * split.pose_local[split.start, 2])),
            "x": split.pose_local[mid, 0], "y": split.pose_local[mid, 1], "t_run": split.t_run[split.start],
            "du1_dt": du_mean[:, 0], "du2_dt": du_mean[:, 1]}


def window_residuals(model, split: Split) -> np.ndarray:
    """Return the mean acceleration residual ``(p, 3)`` of ``model`` over each window (eq. 5.57)."""
    pred = split.integrate(model.f(split.v_body, split.u))
    return (split.delta_v - pred) / split.tau


def binned_effect(residual: np.ndarray, regressor: np.ndarray, name: str, n_bins: int = 8,
                  overlap_factor: float = 1.0, circular: bool = False) -> BinnedEffect:
    """Return the residual binned by quantiles (or equal angles) of ``regressor``.

    ``overlap_factor`` divides the sample size (windows sharing samples are not independent:
    ``tau / stride`` for integral windows).
    """
    ok = np.isfinite(residual) & np.isfinite(regressor)
    r, x = residual[ok], regressor[ok]
    if circular:
        edges = np.linspace(-np.pi, np.pi, n_bins + 1)
    else:  # (no finite residual at all, every prediction of a diverging model: no bins)
        edges = np.unique(np.quantile(x, np.linspace(0, 1, n_bins + 1))) if len(x) else np.empty(0)
    if len(edges) < 2:  # a constant regressor (a model without a lateral law: vy = 0) explains nothing
        edges = np.array([x.min(), x.min() + 1.0]) if len(x) else np.array([0.0, 1.0])
    idx = np.clip(np.searchsorted(edges, x, side="right") - 1, 0, len(edges) - 2)
    nb = len(edges) - 1
    count = np.bincount(idx, minlength=nb).astype(float)
    sums = np.bincount(idx, weights=r, minlength=nb)
    sq = np.bincount(idx, weights=r * r, minlength=nb)
    with np.errstate(invalid="ignore", divide="ignore"):
        mean = sums / count
        var = np.maximum(sq / count - mean ** 2, 0.0)
        n_eff = count / overlap_factor
        se = np.sqrt(var / np.maximum(n_eff - 1, 1))
    grand = r.mean() if len(r) else 0.0
    ss_between = float(np.nansum(count * (mean - grand) ** 2))
    ss_total = float(np.sum((r - grand) ** 2))
    eta2 = ss_between / ss_total if ss_total > 0 else 0.0
    k = int(np.count_nonzero(count))
    n_total = len(r) / overlap_factor
    if k > 1 and n_total > k and eta2 < 1:
        f_stat = (eta2 / (k - 1)) / ((1 - eta2) / (n_total - k))
        p = float(stats.f.sf(f_stat, k - 1, n_total - k))
    else:
        p = 1.0
    return BinnedEffect(name, 0.5 * (edges[:-1] + edges[1:]), mean, se, count, float(eta2), p)


def residual_structure(model, split: Split, n_bins: int = 8, residuals: np.ndarray | None = None
                       ) -> dict[str, dict[str, BinnedEffect]]:
    """Return ``{equation: {regressor: BinnedEffect}}`` of the window residuals of ``model`` on ``split``
    (or of ``residuals (p, 3)`` when given)."""
    r = window_residuals(model, split) if residuals is None else residuals
    reg = regressors_of_windows(split)
    stride = np.median(np.diff(split.start)) * split.sample_interval_s
    overlap = max(split.tau / max(stride, 1e-9), 1.0)
    return {eq: {name: binned_effect(r[:, i], x, name, n_bins, overlap, circular=(name == "heading"))
                 for name, x in reg.items()} for i, eq in enumerate(EQUATIONS)}


def multistep_structure(evaluation, windows, states, n_bins: int = 6) -> dict[str, dict[str, BinnedEffect]]:
    """Return the 5 s multi-step errors (along-track, cross-track, heading) binned against window regressors.

    ``evaluation`` is an ``identification.sindy.evaluate.EvaluationResult`` over ``windows``
    (``identification.sindy.evaluate.Windows``) built from ``states``; the errors are resolved in the
    body frame at the window start (``x0``), so a heading-dependent push shows as a signed mean.
    """
    pred_end = evaluation.extra["pred_end"]  # kept by multistep_errors_by_window
    truth_end = windows.pose_truth[:, -1]
    d = pred_end[:, :2] - truth_end[:, :2]
    psi0 = windows.x0[:, 2]
    along = d[:, 0] * np.cos(psi0) + d[:, 1] * np.sin(psi0)
    cross = -d[:, 0] * np.sin(psi0) + d[:, 1] * np.cos(psi0)
    heading = np.angle(np.exp(1j * (pred_end[:, 2] - truth_end[:, 2])))
    t_rel = windows.t0 - np.array([states[i].t[0] for i in windows.run])
    reg = {"vx": windows.x0[:, 3], "omega": windows.x0[:, 5], "heading": np.angle(np.exp(1j * psi0)),
           "x": windows.x0[:, 0], "y": windows.x0[:, 1], "t_run": t_rel,
           "u1": windows.u_half[:, :, 0].mean(1), "u2": windows.u_half[:, :, 1].mean(1)}
    return {name: {k: binned_effect(err, x, k, n_bins, 2.0, circular=(k == "heading")) for k, x in reg.items()}
            for name, err in (("along_m", along), ("cross_m", cross), ("heading_rad", heading))}


def multistep_errors_by_window(model, states, names, window_s: float = 5.0, dt: float = 0.02):
    """Return ``(evaluation, windows)`` of a 5 s multi-step prediction with the end states kept."""
    windows = make_windows(list(states), window_s, 0.5, dt, list(names))
    pred = rollout(model, windows)
    eps_p, eps_h = errors_from_rollout(pred, windows)
    ev = EvaluationResult(windows.t_rel, rms_over_windows(eps_p), rms_over_windows(eps_h), eps_p, eps_h, "rk4",
                          extra={"pred_end": pred[:, -1, :3]})
    return ev, windows


def lag_profile(model, split: Split, lags_s: np.ndarray = np.arange(-0.3, 0.61, 0.02)) -> dict[str, np.ndarray]:
    """Return the correlation of the window residuals with the inputs shifted by each lag.

    For lag ``L`` the regressor is the window integral of ``u(t - L) - u(t)``: the input change the
    model misses when the motors see the input ``L`` late. A delay shows as a peak at ``L > 0``.
    Returns ``{"lags_s": (L,), "vx": (L,) corr with u1, "omega": (L,) corr with u2}``.
    """
    r = window_residuals(model, split)
    lags_s = np.asarray(lags_s, float)
    shifted = inputs_delayed(split.t_run, split.u, split.runs_slices(), lags_s)  # (L, N, 2)
    d_int = split.integrate(shifted - split.u[None])  # (L, p, 2)
    out = {"lags_s": lags_s}
    for eq, i, j in (("vx", 0, 0), ("omega", 2, 1)):
        a = d_int[..., j] - d_int[..., j].mean(-1, keepdims=True)
        b = r[:, i] - r[:, i].mean()
        with np.errstate(invalid="ignore", divide="ignore"):
            out[eq] = (a @ b) / np.sqrt(np.sum(a * a, -1) * np.sum(b * b))
    return out


def top_structure(structure: dict[str, dict[str, BinnedEffect]], n: int = 5) -> list[tuple[str, str, float, float]]:
    """Return the ``n`` strongest ``(equation, regressor, eta2, p_value)`` pairs, strongest first."""
    rows = [(eq, name, be.eta2, be.p_value) for eq, d in structure.items() for name, be in d.items()]
    return sorted(rows, key=lambda r: -r[2])[:n]


def residual_map(model, split: Split) -> dict[str, np.ndarray]:
    """Return window-middle positions and mean acceleration residuals ``{"x", "y", "vx", "vy", "omega"}``."""
    r = window_residuals(model, split)
    mid = (split.start + split.end) // 2
    return {"x": split.pose_local[mid, 0], "y": split.pose_local[mid, 1],
            **{eq: r[:, i] for i, eq in enumerate(EQUATIONS)}}
