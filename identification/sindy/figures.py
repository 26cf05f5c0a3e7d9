"""Figures of the identification (thesis chapter 7): grid search, errors, terms, correlations.

Each ``plot_*`` takes a result of :mod:`identification.sindy` (search, evaluation, models,
adjustment), returns a matplotlib Figure and saves it as PNG when given ``path``; nothing is
drawn unless asked for.
"""

from __future__ import annotations

from pathlib import Path
from typing import Sequence

import numpy as np

from groundfloor.figures import WIDE_IN, new_figure, save_figure
from identification.sindy.adjust import Adjustment
from identification.sindy.evaluate import EvaluationResult
from identification.sindy.library import LIBRARY_STATE_NAMES
from identification.sindy.model import SindyModel, term_prevalence
from identification.sindy.search import SearchResult


def plot_grid(result: SearchResult, s: float, tau: float | None = None, library: str | None = None, path=None):
    """Return the grid over ``alpha`` x ``T`` for one ``s`` (figs. 7.4 to 7.7).

    Panels: body-frame MAE, R2, complexity, R2 per complexity, and the local-frame 5 s position
    error the search ranks by; each cell says its value. A cell without a finite 5 s error (the
    model's predictions diverged on some held-out window) is marked "diverged".
    """
    tb = result.table
    tau = tau if tau is not None else float(result.model.hyperparameters["tau"])
    library = library or result.model.library.name
    sel = (tb["s"] == s) & (tb["tau"] == tau) & (tb["library"] == library)
    alphas, Ts = np.unique(tb["alpha"][sel]), np.unique(tb["T"][sel])
    panels = {"MAE of Delta x": tb["mae"], "R2": tb["r2"], "complexity": tb["complexity"],
              "R2 / complexity": tb["r2"] / np.maximum(tb["complexity"], 1), "pos. error 5 s [m]": tb["pos_err_5s_m"]}
    fig, axes = new_figure(WIDE_IN, 1.2 + 0.55 * max(len(alphas), 3), ncols=len(panels))
    for ax, (title, col) in zip(axes[0], panels.items()):
        img = np.full((len(alphas), len(Ts)), np.nan)
        for i in np.flatnonzero(sel):
            img[np.searchsorted(alphas, tb["alpha"][i]), np.searchsorted(Ts, tb["T"][i])] = col[i]
        shown = np.where(np.isfinite(img), img, np.nan)
        ax.imshow(shown, origin="lower", aspect="auto")
        for (r, c), v in np.ndenumerate(img):
            text = f"{v:.3g}" if np.isfinite(v) else ("diverged" if np.isinf(v) else "")
            ax.text(c, r, text, ha="center", va="center", fontsize=7,
                    color="w" if np.isfinite(v) and v < np.nanmean(shown) else "k")  # viridis: dark below the mean
        ax.set(xticks=range(len(Ts)), xticklabels=[f"{t:g}" for t in Ts], yticks=range(len(alphas)),
               yticklabels=[f"{a:g}" for a in alphas], xlabel="T", title=title)
        if ax is axes[0][0]:
            ax.set_ylabel("alpha")
    fig.suptitle(f"grid search, s = {s:g}, tau = {tau:g} s, {library}")
    return save_figure(fig, path)


def plot_error_vs_complexity(result: SearchResult, path=None):
    """Return fig. 7.10: 5 s position and heading errors against complexity, coloured by ``s``."""
    tb = result.table
    fig, ((ax_p, ax_h),) = new_figure(WIDE_IN, 4, ncols=2)
    for i, s in enumerate(np.unique(tb["s"])):
        sel = (tb["s"] == s) & np.isfinite(tb["pos_err_5s_m"]) & (tb["pos_err_5s_m"] < 10 * tb["pos_err_5s_m"][0])
        ax_p.scatter(tb["complexity"][sel], 100 * tb["pos_err_5s_m"][sel], s=12, color=f"C{i}", label=f"s = {s:g}")
        ax_h.scatter(tb["complexity"][sel], tb["yaw_err_5s_deg"][sel], s=12, color=f"C{i}")
    ax_p.set(xlabel="model complexity (active terms)", ylabel="position error after 5 s [cm]")
    ax_h.set(xlabel="model complexity (active terms)", ylabel="heading error after 5 s [deg]")
    ax_p.legend()
    return save_figure(fig, path)


def plot_term_prevalence(models: list[SindyModel], path: str | Path | None = None, top: int = 15):
    """Return a bar chart of the ``top`` most prevalent terms per equation (fig. 7.11)."""
    prev = term_prevalence(models)
    eqs = [eq for eq in LIBRARY_STATE_NAMES if prev[eq]]
    fig, axes = new_figure(WIDE_IN, 4.5, ncols=max(len(eqs), 1))
    for ax, eq in zip(axes[0], eqs):
        items = list(prev[eq].items())[:top]
        ax.barh([n for n, _ in items][::-1], [100 * f for _, f in items][::-1])
        ax.set_xlabel("models using the term [%]")
        ax.set_title(f"d{eq}/dt ({len(models)} models)")
    return save_figure(fig, path)


def plot_error_curves(results: Sequence[EvaluationResult], path=None, stacked: bool = True):
    """Return figs. 5.11 / 7.8: stacked per-window errors and ``s_p(t)``, ``s_h(t)``."""
    fig, ((ax_p, ax_h),) = new_figure(WIDE_IN, 4, ncols=2)
    for i, r in enumerate(results):
        color = f"C{i % 10}"
        if stacked and len(results) == 1:
            ax_p.plot(r.t_rel, r.eps_p[np.isfinite(r.eps_p).all(1)].T, color="0.75", lw=0.5)
            ax_h.plot(r.t_rel, np.degrees(np.abs(r.eps_h[np.isfinite(r.eps_h).all(1)])).T, color="0.75", lw=0.5)
        label = f"{r.name or r.method}: {100 * r.pos_err_5s_m:.1f} cm, {r.yaw_err_5s_deg:.2f} deg"
        ax_p.plot(r.t_rel, r.s_p, color=color, lw=2, label=label)
        ax_h.plot(r.t_rel, np.degrees(r.s_h), color=color, lw=2)
    ax_p.set(xlabel="integration time [s]", ylabel="position error [m]", title="s_p(t), eq. 5.77")
    ax_h.set(xlabel="integration time [s]", ylabel="heading error [deg]", title="s_h(t), eq. 5.78")
    ax_p.legend(fontsize=9)
    return save_figure(fig, path)


def plot_correlation(adj: Adjustment, path=None):
    """Return the correlation matrix of the adjusted coefficients per equation (fig. 7.12)."""
    eqs = [eq for eq in LIBRARY_STATE_NAMES if any(t[0] == eq for t in adj.terms)]
    fig, axes = new_figure(6 * len(eqs), 5.5, ncols=len(eqs))
    for ax, eq in zip(axes[0], eqs):
        idx = [i for i, t in enumerate(adj.terms) if t[0] == eq]
        im = ax.imshow(adj.corr[np.ix_(idx, idx)], vmin=-1, vmax=1, cmap="RdBu_r")
        labels = [adj.terms[i][1] for i in idx]
        ax.set(xticks=range(len(idx)), yticks=range(len(idx)), title=f"d{eq}/dt")
        ax.set_xticklabels(labels, rotation=90, fontsize=7)
        ax.set_yticklabels(labels, fontsize=7)
        fig.colorbar(im, ax=ax, shrink=0.8)
    return save_figure(fig, path)
