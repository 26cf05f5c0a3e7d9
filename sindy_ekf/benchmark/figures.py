"""Figures of the benchmark: trajectories with outages, error growth in outages, pose NEES.

Each ``plot_*`` takes a :class:`~sindy_ekf.benchmark.result.BenchmarkResult`, returns a matplotlib
Figure and saves it as PNG when given ``path``; :func:`write_benchmark_figures` writes all three
beside the files of :func:`~sindy_ekf.benchmark.files.write_benchmark` (``benchmark --out``).
"""

from __future__ import annotations

from pathlib import Path

from groundfloor.figures import new_figure, save_figure
from sindy_ekf.benchmark.result import BenchmarkResult
from sindy_ekf.benchmark.scoring import pose_nees


def plot_trajectories(result: BenchmarkResult, path: str | Path | None = None):
    """Return a figure of each test run's trajectories, with the pose track in outages shaded."""
    runs = list(result.truth)
    fig, axes = new_figure(5 * len(runs), 5, ncols=len(runs))
    for ax, run in zip(axes[0], runs):
        tr = result.truth[run]
        ax.plot(tr[:, 1], tr[:, 2], "k-", lw=2, label="laser tracker (truth)")
        for a, b in result.outages[run]:
            m = (tr[:, 0] >= a) & (tr[:, 0] <= b)
            ax.plot(tr[m, 1], tr[m, 2], "-", color="0.8", lw=8, zorder=0,
                    label="GNSS outage" if a == result.outages[run][0, 0] else None)
        for name, per_run in result.estimates.items():
            if name != "dead_reckoning":
                ax.plot(per_run[run].x[:, 0], per_run[run].x[:, 1], lw=1, label=name)
        ax.set(title=run, xlabel="x local [m]", ylabel="y local [m]", aspect="equal")
    axes[0][0].legend(fontsize=7)
    return save_figure(fig, path)


def plot_outage_errors(result: BenchmarkResult, path: str | Path | None = None):
    """Return a figure of RMS position error against time since the outage began, per length."""
    keys = sorted({k for c in result.outage_curves.values() for k in c}, key=float)
    fig, axes = new_figure(4 * max(len(keys), 1), 3.5, ncols=max(len(keys), 1))
    for ax, key in zip(axes[0], keys):
        for name, c in result.outage_curves.items():
            if key in c:
                ax.plot(c[key][:, 0], c[key][:, 1], label=name)
        ax.set(title=f"{key} s outages", xlabel="time since outage began [s]",
               ylabel="RMS position error [m]", yscale="log")
    axes[0][0].legend(fontsize=7)
    return save_figure(fig, path)


def plot_nees(result: BenchmarkResult, path: str | Path | None = None, run: str | None = None):
    """Return a figure of the pose NEES over time of one run, with the 95 % chi-square bounds."""
    run = run or next(iter(result.truth))
    fig, ((ax,),) = new_figure(9, 3.5)
    for name, (t, nees) in pose_nees(result, run).items():
        ax.semilogy(t, nees, lw=0.8, label=name)
    for b in result.nees_bounds_95:
        ax.axhline(b, color="k", ls="--", lw=0.8)
    for a, b in result.outages[run]:
        ax.axvspan(a - result.truth[run][0, 0], b - result.truth[run][0, 0], color="0.9")
    ax.set(title=f"{run}: pose NEES (3 dof), 95 % bounds dashed, outages shaded",
           xlabel="time [s]", ylabel="NEES")
    ax.legend(fontsize=7)
    return save_figure(fig, path)


def write_benchmark_figures(result: BenchmarkResult, out_dir: str | Path) -> list[Path]:
    """Return the figure files written to ``out_dir``: trajectories, outage errors, NEES."""
    out = Path(out_dir)
    files = [out / "trajectories.png", out / "outage_errors.png", out / "nees.png"]
    for draw, path in zip((plot_trajectories, plot_outage_errors, plot_nees), files):
        draw(result, path)
    return files
