"""Figures of the diagnosis: residual structure, lag correlation, family profiles, residual map, gain profile.

Each ``plot_*`` takes numbers of :mod:`sindy_ekf.diagnose.residuals` or the family scores,
returns a matplotlib Figure and saves it as PNG when given ``path``;
:func:`write_diagnosis_figures` writes all of a :class:`~sindy_ekf.diagnose.pipeline.Diagnosis`
into a folder (``diagnose --plots``).
"""

from __future__ import annotations

from dataclasses import replace
from pathlib import Path

import numpy as np
from matplotlib.patches import Circle

from groundfloor.figures import WIDE_IN, WIDTH_IN, new_figure, save_figure
from identification.sindy.figures import plot_error_curves
from sindy_ekf.diagnose.gain_profile import named_profile
from sindy_ekf.diagnose.pipeline import Diagnosis
from sindy_ekf.diagnose.residuals import BinnedEffect


def plot_residual_structure(structure: dict[str, dict[str, BinnedEffect]], path=None, title: str = "",
                            groups: int = 2):
    """Return a grid of binned residual means +- 2 standard errors against each regressor.

    One column per equation, one row per regressor; the regressors are split into ``groups``
    blocks side by side, so that the panels stay large enough to read on a page.
    """
    eqs = list(structure)
    regs = list(structure[eqs[0]])
    nrows = -(-len(regs) // groups)
    fig, axes = new_figure(WIDE_IN, 1.55 * nrows + 0.6, nrows, groups * len(eqs))
    for j, name in enumerate(regs):
        row, block = j % nrows, j // nrows
        for e, eq in enumerate(eqs):
            be = structure[eq][name]
            ax = axes[row, block * len(eqs) + e]
            ax.axhline(0.0, color="0.6", lw=0.8)
            ax.errorbar(be.centers, be.mean, yerr=2 * be.se, fmt="o-", ms=3, lw=1,
                        color="C3" if be.p_value < 1e-3 and be.eta2 > 0.05 else "C0")
            ax.text(0.02, 0.95, f"eta2 {be.eta2:.2f}", transform=ax.transAxes, va="top", fontsize=8)
            ax.set_xlabel(name, fontsize=9, labelpad=1)
            if row == 0:
                ax.set_title(f"{eq} residual", fontsize=10)
            ax.tick_params(labelsize=7)
    for k in range(len(regs), nrows * groups):  # empty cells of the last block
        for e in range(len(eqs)):
            axes[k % nrows, (k // nrows) * len(eqs) + e].axis("off")
    fig.suptitle(title or "residual structure: bin means +- 2 standard errors; red: eta2 > 0.05 and p < 1e-3",
                 fontsize=10)
    return save_figure(fig, path)


def plot_lag_profile(profile: dict[str, np.ndarray], path=None, delay_s: float | None = None):
    """Return the residual-input lag correlation curves, with an estimated delay marked."""
    fig, ((ax,),) = new_figure(WIDTH_IN, 3.6)
    for eq in ("vx", "omega"):
        ax.plot(profile["lags_s"], profile[eq], label=f"{eq} residual vs shifted {'u1' if eq == 'vx' else 'u2'}")
    if delay_s is not None:
        ax.axvline(delay_s, color="k", ls="--", lw=1, label=f"estimated delay {delay_s:.3f} s")
    ax.set(xlabel="lag L [s]", ylabel="correlation", title="residual against the input shifted by L")
    ax.legend(fontsize=9)
    return save_figure(fig, path)


def plot_family_profiles(scores, path=None):
    """Return the train residual profiles of the 1-D families (delay, deadband, time, asymmetry).

    ``scores`` are :class:`~sindy_ekf.diagnose.fitting.FamilyScore`; those without a profile
    are left out.
    """
    prof = [s for s in scores if s.profile]
    fig, axes = new_figure(3.2 * max(len(prof), 1), 3, ncols=max(len(prof), 1))
    for ax, s in zip(axes[0], prof):
        sse = np.asarray(s.profile["train_sse"])
        ax.plot(s.profile["theta"], sse / sse.min(), "o-", ms=3)
        ax.axvline(s.theta[0], color="k", ls="--", lw=1)
        ax.set(xlabel=s.family, ylabel="train SSE / min", title=f"test gain {100 * s.gain:.1f} %")
    return save_figure(fig, path)


def plot_gain_profile(estimate: dict, path=None):
    """Return the input gain over time since the run start of a named ``time_dependence``: the bins'
    gains +- 2 jackknife standard deviations, their monotone fit and the linear form's decay, each
    relative to the monotone fit's first bin (``estimate`` of :mod:`sindy_ekf.diagnose.gain_profile`)."""
    t = np.asarray(estimate["gain_profile_t_s"], float)
    mono = np.asarray(estimate["gain_profile_monotone"], float)
    g = np.asarray(estimate["gain_profile"], float) / mono[0]
    std = np.array([np.nan if v is None else v for v in estimate["gain_profile_std"]], float) / mono[0]
    fig, ((ax,),) = new_figure(WIDTH_IN, 3.6)
    ax.errorbar(t, g, yerr=2 * std, fmt="o", ms=4, capsize=3, label="bins: gain +- 2 std (jackknife over runs)")
    ax.plot(t, mono / mono[0], "-", lw=1.5, label=f"monotone fit: {100 * estimate['loss_over_runs']:.1f} % lost")
    if estimate.get("decay_per_10min") is not None:
        tt = np.linspace(t[0], t[-1], 50)
        r = float(estimate["decay_per_10min"])
        ax.plot(tt, (1 - r * tt / 600) / (1 - r * t[0] / 600), "--", lw=1,
                label=f"linear form: {r:.3g} per 10 min")
    ax.set(xlabel="time since the run start [s]", ylabel="input gain / first bin",
           title="input gain over time (time_dependence)")
    ax.legend(fontsize=8)
    return save_figure(fig, path)


def plot_residual_map(rmap: dict[str, np.ndarray], path=None, patch: dict | None = None):
    """Return the vx and omega window residuals over the lab floor, a found patch circled.

    ``rmap`` is :func:`sindy_ekf.diagnose.residuals.residual_map`; ``patch`` the estimate of the
    position-dependence family (``patch_center_local_m``, ``patch_radius_m``).
    """
    fig, axes = new_figure(10, 4.2, ncols=2)
    for ax, eq in zip(axes[0], ("vx", "omega")):
        lim = np.percentile(np.abs(rmap[eq]), 98) or 1.0
        hb = ax.hexbin(rmap["x"], rmap["y"], C=rmap[eq], gridsize=25, cmap="RdBu_r", vmin=-lim, vmax=lim)
        fig.colorbar(hb, ax=ax, label=f"{eq} residual [{'m/s^2' if eq == 'vx' else 'rad/s^2'}]")
        if patch and "patch_center_local_m" in patch:  # a disc to circle (not the smooth field)
            (cx, cy), r = patch["patch_center_local_m"], patch["patch_radius_m"]
            ax.add_patch(Circle((cx, cy), r, fill=False, color="k", lw=1.5, ls="--"))
        ax.set(xlabel="x local [m]", ylabel="y local [m]", aspect="equal", title=f"mean {eq} residual per window")
    return save_figure(fig, path)


def write_diagnosis_figures(d: Diagnosis, out_dir: str | Path) -> list[Path]:
    """Return the figure files of a diagnosis written to ``out_dir``.

    Window-residual and 5 s multi-step structure, lag profile (with the estimated delay),
    family profiles, residual map (with the patch when position dependence is significant), the
    5 s error curves before and after the extension, and the gain over time when time_dependence
    is significant.
    """
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plot_residual_structure(d.structure, out / "residual_structure.png")
    plot_residual_structure(d.multistep_structure, out / "multistep_structure.png",
                            title="5 s multi-step errors (along, cross, heading) against window regressors")
    delay = next((c.score.theta[0] for c in d.ranked if c.name == "input_delay"), None)
    plot_lag_profile(d.lag, out / "lag_profile.png", delay)
    plot_family_profiles([c.score for c in d.ranked], out / "family_profiles.png")
    patch = next((c.score.estimate for c in d.ranked if c.name == "position_dependence" and c.significant), None)
    plot_residual_map(d.residual_map, out / "residual_map.png", patch)
    ev = [replace(d.evaluations["before"], name="model")]
    if d.extended is not None:
        ev.append(replace(d.evaluations["after"], name=f"extended ({d.verdict})"))
    plot_error_curves(ev, path=out / "before_after.png", stacked=False)
    names = ["residual_structure", "multistep_structure", "lag_profile", "family_profiles", "residual_map",
             "before_after"]
    decay = named_profile(d.ranked)
    if decay is not None:  # a named gain decay: its shape over time
        plot_gain_profile(decay, out / "gain_profile.png")
        names.append("gain_profile")
    return [out / f"{n}.png" for n in names]
