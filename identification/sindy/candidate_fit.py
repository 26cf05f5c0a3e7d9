"""How one candidate of ``identify`` is made on some train runs: started, refined, scored.

A candidate is a grid structure of the screening (its hyperparameters) or the lag. On the runs of
a fold (or on all train runs) :func:`start_model` refits it by the integral regression, with the
lag's core terms active and the excluded variables' terms left out, and drops the terms that are
not significant in the least-squares adjustment (thesis 5.3.9); :func:`candidate_model` then
refines it by output error (:func:`refine`), keeps the regression's coefficients, or chooses its
terms by the stepwise output-error search; :func:`score_on` scores it on held-out reference
windows. :mod:`identification.sindy.identify` runs these per fold and picks among the candidates.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from identification.sindy.adjust import Adjustment, prune_insignificant
from identification.sindy.baselines import LagModel
from identification.sindy.checks import MIN_T_STAT, lag_core, self_terms
from identification.sindy.evaluate import Windows, errors_from_rollout, rollout
from identification.sindy.model import SindyModel, envelope_from_data, model_from_terms
from identification.sindy.output_error import OutputErrorFit, SindyStructure, fit_output_error
from identification.sindy.search import SearchResult, refit
from identification.sindy.stepwise import STEPWISE, stepwise_output_error


def lag_as_sindy(lag: LagModel, envelope: dict, library: str = "poly1") -> SindyModel:
    """Return the lag as a sparse SINDy model of ``library`` (its dead times, frozen extrapolation)."""
    terms = {"vx": {"vx": -1.0 / lag.tau_v_, "u1": lag.k_v_ / lag.tau_v_}, "vy": {"vy": -1.0 / lag.tau_v_},
             "omega": {"omega": -1.0 / lag.tau_w_, "u2": lag.k_w_ / lag.tau_w_}}
    return model_from_terms(terms, library, envelope=envelope, dead_time_s=lag.dead_time_s, extrapolation="frozen",
                            hyperparameters={"structure": "lag"})


def with_lag_core(model: SindyModel, lag: LagModel) -> SindyModel:
    """Return ``model`` with the lag's terms active (:func:`~identification.sindy.checks.lag_core`),
    seeded from the lag where the regression left them out."""
    core = lag_as_sindy(lag, model.envelope)
    coef = model.coef.copy()
    for e, j in zip(*np.nonzero(lag_core(model))):
        if coef[e, j] == 0.0:
            coef[e, j] = core.coef[e, core.library.feature_names.index(model.library.feature_names[j])]
    return model.with_coefficients(coef)


def excluded_terms(model: SindyModel, excluded) -> np.ndarray:
    """Return the mask ``(3, k)`` of the terms of the ``excluded`` variables: every feature
    containing one, and every term of an excluded state's equation."""
    return np.array([any(v in excluded for v, _ in atoms) for atoms in model.library.atoms])[None, :] | \
        np.array([e in excluded for e in range(3)])[:, None]


def without_excluded(model: SindyModel, excluded) -> SindyModel:
    """Return ``model`` without the terms of the ``excluded`` variables: no feature containing one,
    and an excluded state's equation reduced to its own damping (its data are noise)."""
    if not excluded:
        return model
    return model.with_coefficients(np.where(excluded_terms(model, excluded) & ~self_terms(model), 0.0, model.coef))


def fixed_terms(model: SindyModel, excluded) -> np.ndarray:
    """Return the mask of the terms no fit may move: the damping of the states in ``excluded``."""
    return self_terms(model) & np.array([e in excluded for e in range(3)])[:, None]


#: splits of the start's dead time ``d0`` into a dead time and a first-order input lag tried before
#: the output-error fit: (dead time, lag) = (d0 (1 - f), d0 f) for each ``f``. A motor lag ``T``
#: fitted by a dead time alone reads as ``d0`` of about ``T``; the fit is local, and from
#: ``(d0, 0)`` shortening the dead time first makes the error worse, so the start is chosen here
INPUT_LAG_SPLITS = (0.0, 0.5, 1.0)


def input_chain_start(model: SindyModel, windows: Windows) -> tuple[tuple[float, float], tuple[float, float]]:
    """Return the ``(dead_time_s, input_lag_s)`` of :data:`INPUT_LAG_SPLITS` with the smallest pose error."""
    d0 = np.asarray(model.dead_time_s, dtype=float)
    best, best_sse = (model.dead_time_s, model.input_lag_s), np.inf
    for f in INPUT_LAG_SPLITS:
        trial = model.with_coefficients(model.coef, tuple(d0 * (1.0 - f)), tuple(d0 * f))
        with np.errstate(over="ignore", invalid="ignore"):
            eps_p, eps_h = errors_from_rollout(rollout(trial, windows), windows)
        sse = float(np.sum(eps_p**2) + np.sum(eps_h**2))
        if np.isfinite(sse) and sse < best_sse:
            best, best_sse = (trial.dead_time_s, trial.input_lag_s), sse
    return best


def refine(model: SindyModel, windows: Windows, excluded=frozenset(),
           fit_dead_time: bool = True, fit_input_lag: bool = True) -> tuple[SindyModel, OutputErrorFit]:
    """Return ``model``'s active coefficients, dead times and first-order input lags
    (:mod:`groundfloor.input_chain`) refitted by output error on ``windows``.

    The damping of a state the data do not excite (in ``excluded``) keeps its value. The fit
    starts from the best split of the dead time into dead time and lag
    (:func:`input_chain_start`).
    """
    spec = SindyStructure(model, fixed_terms(model, excluded))
    dead0, lag0 = input_chain_start(model, windows) if fit_input_lag else (model.dead_time_s, model.input_lag_s)
    fit = fit_output_error(spec, spec.theta0, windows, dead0, fit_dead_time, input_lag0=lag0,
                           fit_input_lag=fit_input_lag)
    return spec.build(fit.theta, fit.dead_time_s, fit.input_lag_s), fit


def significance_of(adj: Adjustment | None) -> tuple[tuple[str, ...], np.ndarray | None]:
    """Return the term names and t statistics of an adjustment (none for the lag)."""
    if adj is None:
        return (), None
    return tuple(f"{e}: {f}" for e, f in adj.terms), np.abs(adj.coef) / adj.coef_std


def score_on(model, windows: Windows | None) -> tuple[float, int, float]:
    """Return the RMS 5 s position error of ``model`` on ``windows``, their number and the RMS
    5 s heading error in degrees."""
    if windows is None:
        return float("nan"), 0, float("nan")
    eps_p, eps_h = errors_from_rollout(rollout(model, windows)[..., -1:, :],
                                       replace(windows, pose_truth=windows.pose_truth[:, -1:],
                                               t_rel=windows.t_rel[-1:]))
    with np.errstate(over="ignore"):
        return (float(np.sqrt(np.mean(eps_p[:, 0] ** 2))), windows.n_windows,
                float(np.degrees(np.sqrt(np.mean(eps_h[:, 0] ** 2)))))


def start_model(label: str, hp: dict | None, search_result: SearchResult, cache: dict, excluded, runs, lag: LagModel,
             states) -> tuple[SindyModel, Adjustment | None]:
    """Return a candidate's starting model on the segments ``runs`` (all when None) and the
    adjustment its non-significant terms were dropped by (None for the lag)."""
    x = np.vstack([st.state for st in states])
    u = np.vstack([st.inputs for st in states])
    envelope = envelope_from_data(x, u)
    if hp is None:
        return without_excluded(lag_as_sindy(lag, envelope), excluded), None
    model = refit(search_result.states_by_s, search_result.names, hp, cache, excluded, runs=runs)
    model = replace(model, envelope=envelope, extrapolation="frozen", dead_time_s=lag.dead_time_s)
    model = without_excluded(with_lag_core(model, lag), excluded)
    problem = cache[(float(hp["s"]), float(hp["tau"]), str(hp["library"]))][0]
    rows = None if runs is None else np.isin(problem.run_index, runs)
    return prune_insignificant(model, problem, lag_core(model), MIN_T_STAT, rows, fixed=fixed_terms(model, excluded))


def candidate_model(start: SindyModel, adj: Adjustment | None, hp: dict | None, windows: Windows,
             excluded, refined: SindyModel | None = None) -> tuple[SindyModel, OutputErrorFit | None, tuple]:
    """Return the candidate from its start, its output-error fit and its terms' significance
    (names and t statistics for :func:`~identification.sindy.checks.run_checks`): refined by
    output error (:func:`refine`) unless its hyperparameters say ``output_error: False`` (the
    regression's coefficients kept), or its terms chosen by the stepwise output-error search
    (:func:`~identification.sindy.stepwise.stepwise_output_error`) for ``output_error: "stepwise"``,
    from ``refined`` when given (``start`` refined on the same ``windows`` already)."""
    how = True if hp is None else hp.get("output_error", True)
    if how is False:
        return start, None, significance_of(adj)
    if how == STEPWISE and refined is not None:
        model, fit = refined, None
    else:
        model, fit = refine(start, windows, excluded)
    if how != STEPWISE:
        return model, fit, significance_of(adj)
    allowed = ~excluded_terms(model, excluded)
    step = stepwise_output_error(model, windows, allowed, lag_core(model), fixed_terms(model, excluded))
    return step.model, step.fit, (step.names, step.t_stat)
