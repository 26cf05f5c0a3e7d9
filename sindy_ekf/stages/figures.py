"""Figures of the stages that a command writes on request (``identify --plots``, ``evaluate --plots``)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from identification.sindy.figures import (
    plot_correlation,
    plot_error_curves,
    plot_error_vs_complexity,
    plot_grid,
    plot_term_prevalence,
)
from sindy_ekf.stages.evaluation import Evaluation
from sindy_ekf.stages.identification import Identification, coefficient_adjustment


def write_identification_figures(identification: Identification, out_dir: str | Path) -> Path:
    """Write the search figures (figs. 7.4-7.7, 7.10, 7.11) and the adjustment's correlations
    (7.12) as PNG into ``out_dir``; return the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    result = identification.search
    for s in np.unique(result.table["s"]):
        plot_grid(result, float(s), path=out / f"grid_s{s:g}.png")
    plot_error_vs_complexity(result, path=out / "error_vs_complexity.png")
    plot_term_prevalence(result.top_models, path=out / "term_prevalence.png")
    plot_correlation(coefficient_adjustment(identification), path=out / "correlation.png")
    return out


def write_evaluation_figures(evaluation: Evaluation, out_dir: str | Path) -> Path:
    """Write the 5 s error curves s_p(t), s_h(t) of the model (per window, figs. 5.11, 7.8) and of all
    models as PNG into ``out_dir``; return the folder."""
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    plot_error_curves([evaluation.model], path=out / "prediction_errors_sindy.png")
    plot_error_curves([r["rk4"] for r in evaluation.results.values()], path=out / "prediction_errors_all.png",
                      stacked=False)
    return out
