"""Identification that holds on data it was not tuned on: the pipeline of ``sindy-ekf identify``.

1. **Reference and folds** (:mod:`identification.sindy.reference`): reference states of the
   train runs (the discrepancy-principle smoothing), windows from them with the measured poses
   as truth, and cross-validation folds that leave one group (day, session) out, falling back
   to runs when there is one group.
2. **Excitation**: variables the train runs do not excite (:func:`identification.sindy.checks.not_excited`)
   are named and every feature containing one is left out.
3. **The lag** (:func:`identification.sindy.baselines.fit_lag`): first-order lag per axis with
   input dead time, by output error; its dead times are the regression's starting dead time.
4. **Screening** (:func:`identification.sindy.search.search`): the integral-regression grid,
   every grid point scored on the held-out groups' reference windows.
5. **Candidates refined by output error, cross-validated**: the best :data:`N_CANDIDATES`
   distinct admissible structures of the screening, each twice (refined by output error, and
   with the regression's coefficients: refining a dense model can buy fit with terms that fail
   the checks), and the lag as a sparse SINDy model
   (``vx' = a vx + b u1``, ``vy' = e vy``, ``omega' = c omega + d u2``). In every fold each is
   refitted on the fold's train groups: the regression picks the terms (the lag's own always
   among them), the terms that are not significant in the least-squares adjustment of thesis
   5.3.9 are dropped one by one (:func:`identification.sindy.adjust.prune_insignificant`, over
   non-overlapping windows), then output error fits the coefficients and the dead times
   (:func:`refine`); each is checked (:func:`identification.sindy.checks.run_checks`) and scored
   on the held-out group's reference windows. The one-standard-error rule over the folds picks the
   sparsest candidate that passes the checks in most folds (more than half): a fold's model is
   fitted on less data, and a structure whose refit on one fold's groups leans on a term the
   data barely excite fails there without being fragile on all train runs, which the final
   model is checked on (measured on simulator variant 2: every refined structure failed the
   dissipativity check in one fold of three, on ``vy omega^2`` with ``vy`` at 15 mm/s).
6. **Stepwise output error** (:mod:`identification.sindy.stepwise`): the structure the rule
   picks (a grid structure; the best grid structure by CV error when it picks the lag) is the
   start of a search that adds terms by their score on the output error and drops them by its t
   statistics; refitted in every fold the same way, it joins the candidates and the rule picks
   again. On simulator variants the regression's choice of terms, not the coefficients, kept the
   refined models at about twice the true dynamics' error on their own train windows.
7. **Final model**: the picked candidate refitted on all train runs the same way; if it fails
   the checks, the next candidate by CV error is taken (never a failing model).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from typing import Sequence

import numpy as np
from threadpoolctl import threadpool_limits

from groundfloor.errors import InputError
from groundfloor.parallel import Workers, parallel_map
from groundfloor.types import TrajectoryRun
from identification.sindy.adjust import Adjustment, prune_insignificant
from identification.sindy.baselines import LagModel, fit_lag
from identification.sindy.checks import (
    MIN_T_STAT,
    excitation,
    lag_core,
    measured_accel_max,
    not_excited,
    run_checks,
    self_terms,
)
from identification.sindy.data import pose_noise_std
from identification.sindy.evaluate import Windows, errors_from_rollout, rollout
from identification.sindy.library import LIBRARY_VARIABLE_NAMES
from identification.sindy.model import SindyModel, envelope_from_data, model_from_terms
from identification.sindy.output_error import (
    OE_DT,
    OE_MAX_WINDOWS,
    OE_WINDOW_S,
    OutputErrorFit,
    SindyStructure,
    fit_output_error,
)
from identification.sindy.reference import Folds, Reference, cv_folds, reference, select_windows, thin_windows
from identification.sindy.search import DEFAULT_GRID, SearchGrid, SearchResult, admissible, refit, search
from identification.sindy.selection import Candidate, select_candidate
from identification.sindy.stepwise import STEPWISE, stepwise_output_error

log = logging.getLogger(__name__)

#: distinct structures of the screening refined by output error and cross-validated (plus the lag)
N_CANDIDATES = 4


@dataclass(frozen=True)
class Identification:
    """The identified model with everything that went into choosing it."""

    model: SindyModel
    lag: LagModel  # the lag baseline fitted on all train runs
    search: SearchResult
    candidates: tuple[Candidate, ...]
    selected: int  # index into candidates
    folds: Folds
    lag_cv: Candidate  # the lag baseline's own CV score on the same folds
    not_excited: tuple[str, ...] = ()
    notes: tuple[str, ...] = field(default_factory=tuple)

    @property
    def beats_lag(self) -> bool:
        """Return whether the selected model's CV error is below the lag baseline's."""
        return self.candidates[self.selected].cv_pos_err_5s_m < self.lag_cv.cv_pos_err_5s_m


def lag_as_sindy(lag: LagModel, envelope: dict) -> SindyModel:
    """Return the lag as a sparse SINDy model of library ``poly1`` (its dead times, frozen extrapolation)."""
    terms = {"vx": {"vx": -1.0 / lag.tau_v_, "u1": lag.k_v_ / lag.tau_v_}, "vy": {"vy": -1.0 / lag.tau_v_},
             "omega": {"omega": -1.0 / lag.tau_w_, "u2": lag.k_w_ / lag.tau_w_}}
    return model_from_terms(terms, "poly1", envelope=envelope, dead_time_s=lag.dead_time_s, extrapolation="frozen",
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


def _excluded_terms(model: SindyModel, excluded) -> np.ndarray:
    """Return the mask ``(3, k)`` of the terms of the ``excluded`` variables: every feature
    containing one, and every term of an excluded state's equation."""
    return np.array([any(v in excluded for v, _ in atoms) for atoms in model.library.atoms])[None, :] | \
        np.array([e in excluded for e in range(3)])[:, None]


def without_excluded(model: SindyModel, excluded) -> SindyModel:
    """Return ``model`` without the terms of the ``excluded`` variables: no feature containing one,
    and an excluded state's equation reduced to its own damping (its data are noise)."""
    if not excluded:
        return model
    return model.with_coefficients(np.where(_excluded_terms(model, excluded) & ~self_terms(model), 0.0, model.coef))


def _fixed(model: SindyModel, excluded) -> np.ndarray:
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
    spec = SindyStructure(model, _fixed(model, excluded))
    dead0, lag0 = input_chain_start(model, windows) if fit_input_lag else (model.dead_time_s, model.input_lag_s)
    fit = fit_output_error(spec, spec.theta0, windows, dead0, fit_dead_time, input_lag0=lag0,
                           fit_input_lag=fit_input_lag)
    return spec.build(fit.theta, fit.dead_time_s, fit.input_lag_s), fit


def _significance(adj: Adjustment | None) -> tuple[tuple[str, ...], np.ndarray | None]:
    """Return the term names and t statistics of an adjustment (none for the lag)."""
    if adj is None:
        return (), None
    return tuple(f"{e}: {f}" for e, f in adj.terms), np.abs(adj.coef) / adj.coef_std


def _fold_score(model, windows: Windows | None) -> tuple[float, int, float]:
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


def _initial(label: str, hp: dict | None, search_result: SearchResult, cache: dict, excluded, runs, lag: LagModel,
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
    return prune_insignificant(model, problem, lag_core(model), MIN_T_STAT, rows, fixed=_fixed(model, excluded))


def _candidates(result: SearchResult, n: int) -> list[tuple[str, dict]]:
    """Return ``(label, hyperparameters)`` of the best ``n`` admissible rows with distinct structures."""
    ok = admissible(result.table)
    seen, out = set(), []
    for i, m in enumerate(result.top_models):
        key = (m.library.name, (m.coef != 0).tobytes())
        if not ok[i] or key in seen:
            continue
        seen.add(key)
        hp = {k: result.table[k][i].item() if hasattr(result.table[k][i], "item") else result.table[k][i]
              for k in ("s", "tau", "alpha", "T", "library")} | {"normalize": bool(m.hyperparameters.get("normalize", False))}
        # each structure twice: refined by output error, and as the regression fitted it (the
        # refinement of a dense model can trade well-posedness for fit; CV and the checks decide)
        out += [(f"grid rank {i + 1}", hp | {"output_error": True}),
                (f"grid rank {i + 1}, regression", hp | {"output_error": False})]
        if len(seen) == n:
            break
    return out


def _stepwise_spec(candidates: Sequence[Candidate]) -> tuple[str, dict] | None:
    """Return ``(label, hyperparameters)`` of the stepwise output-error search's candidate: from
    the structure the one-standard-error rule picks among ``candidates``, or from the grid
    candidate of smallest CV error that passed when it picks the lag (None without one)."""
    grid = [i for i, c in enumerate(candidates) if c.hyperparameters is not None and c.passed
            and np.isfinite(c.cv_pos_err_5s_m)]
    if not grid:
        return None
    try:
        first = select_candidate(candidates)
    except InputError:
        first = None
    start = first if first in grid else min(grid, key=lambda i: candidates[i].cv_pos_err_5s_m)
    c = candidates[start]
    return f"{c.label.split(',')[0]}, stepwise", c.hyperparameters | {"output_error": STEPWISE}


def _refined(start: SindyModel, adj: Adjustment | None, hp: dict | None, windows: Windows,
             excluded) -> tuple[SindyModel, OutputErrorFit | None, tuple]:
    """Return the candidate from its start, its output-error fit and its terms' significance
    (names and t statistics for :func:`~identification.sindy.checks.run_checks`): refined by
    output error (:func:`refine`) unless its hyperparameters say ``output_error: False`` (the
    regression's coefficients kept), or its terms chosen by the stepwise output-error search
    (:func:`~identification.sindy.stepwise.stepwise_output_error`) for ``output_error: "stepwise"``."""
    how = True if hp is None else hp.get("output_error", True)
    if how is False:
        return start, None, _significance(adj)
    model, fit = refine(start, windows, excluded)
    if how != STEPWISE:
        return model, fit, _significance(adj)
    allowed = ~_excluded_terms(model, excluded)
    step = stepwise_output_error(model, windows, allowed, lag_core(model), _fixed(model, excluded))
    return step.model, step.fit, (step.names, step.t_stat)


def _fold_job(job) -> dict:
    """Return the scores of every candidate (and of the lag baseline) on one fold."""
    # Small SVDs and least squares (the adjustments, the output-error steps): multi-threaded BLAS
    # on a loaded 2-core machine made each about 30 times slower (measured); parallelism is per process.
    with threadpool_limits(limits=1, user_api="blas"):
        return _fold_job_serial(job)


def _fold_job_serial(job) -> dict:
    """Return :func:`_fold_job`'s scores."""
    f, ref, fold, specs, result, excluded, oe_windows, score_windows, accel_max = job
    train = np.flatnonzero(fold != f)
    keep_held = ~np.isin(score_windows.run, train)
    held = select_windows(score_windows, keep_held) if keep_held.any() else None
    fold_oe = thin_windows(select_windows(oe_windows, np.isin(oe_windows.run, train)), OE_MAX_WINDOWS)
    fold_ref = Reference(states=tuple(ref.states[i] for i in train), names=tuple(ref.names[i] for i in train),
                         run_index=ref.run_index[train], runs=ref.runs, smoothing=ref.smoothing)
    fold_lag = fit_lag(fold_ref)
    out = {"lag baseline": _fold_score(fold_lag, held)}
    cache: dict = {}
    for label, hp in specs:
        try:
            start, adj = _initial(label, hp, result, cache, excluded, train, fold_lag, fold_ref.states)
        except InputError as exc:  # more active terms than independent windows: significance unjudgeable
            log.info("fold %d, %s: %s; not admissible", f, label, exc)
            out[label] = (float("nan"), 0, float("nan"), float("nan"), ["significance"])
            continue
        model, _, significance = _refined(start, adj, hp, fold_oe, excluded)
        checks = run_checks(model, fold_ref.states, *significance, accel_max)
        out[label] = _fold_score(model, held) + (model.complexity, [k for k, v in checks.items()
                                                                    if isinstance(v, dict) and not v["passed"]])
    return out


def _final(candidates, chosen: int, order, result: SearchResult, excluded, lag: LagModel, ref: Reference,
           oe_windows: Windows, accel_max) -> tuple[int, SindyModel, OutputErrorFit | None, dict]:
    """Return the index, model, output-error fit and checks of the first candidate (``chosen``,
    then the others that passed by CV error) that passes the checks refitted on all train runs."""
    all_oe = thin_windows(oe_windows, OE_MAX_WINDOWS)
    cache: dict = {}
    for i in [chosen] + [j for j in order if j != chosen and candidates[j].passed]:
        c = candidates[i]
        try:
            start, adj = _initial(c.label, c.hyperparameters, result, cache, excluded, None, lag, ref.states)
        except InputError as exc:  # more active terms than independent windows: significance unjudgeable
            log.warning("identification: candidate %s refitted on all train runs: %s; trying the next", c.label, exc)
            continue
        model, fit, significance = _refined(start, adj, c.hyperparameters, all_oe, excluded)
        checks = run_checks(model, ref.states, *significance, accel_max)
        if checks["passed"]:
            return i, model, fit, checks
        log.warning("identification: candidate %s refitted on all train runs fails the checks (%s); trying the next",
                    c.label, ", ".join(k for k, v in checks.items() if isinstance(v, dict) and not v["passed"]))
    raise InputError("identification: every candidate refitted on all train runs fails the well-posedness checks")


def identify(runs: Sequence[TrajectoryRun], grid: SearchGrid = DEFAULT_GRID, n_jobs: Workers | int = 1,
             n_candidates: int = N_CANDIDATES) -> Identification:
    """Return the identified model of ``runs`` (train runs) by the pipeline of the module docstring.

    ``n_jobs`` (a number of local processes or :class:`groundfloor.parallel.Workers`) share the
    screening's grid and the folds of the output-error stage.
    """
    ref = reference(runs)
    folds = cv_folds(ref.groups, ref.run_index, grid.n_folds)
    stds = excitation(ref.states)
    quiet = not_excited(ref.states, [pose_noise_std(ref.runs[i]) for i in ref.run_index])
    notes = [f"cross-validation: {folds.note}"]
    if quiet:
        msg = ("train runs do not excite " + ", ".join(f"{v} (std {stds[v]:.3g})" for v in quiet)
               + ": every term containing them is left out")
        log.warning(msg)
        notes.append(msg)
    excluded = frozenset(LIBRARY_VARIABLE_NAMES.index(v) for v in quiet)
    with threadpool_limits(limits=1, user_api="blas"):  # as in _fold_job
        lag = fit_lag(ref)
    result = search(runs=runs, grid=grid, n_jobs=n_jobs, ref=ref, folds=folds, dead_time_s=lag.dead_time_s,
                    excluded=excluded)
    oe_windows = ref.windows(OE_WINDOW_S, 0.0, OE_DT)
    score_windows = ref.windows(grid.window_s, grid.overlap, grid.dt_eval)
    accel_max = measured_accel_max(ref.states)
    specs = [("lag", None)] + _candidates(result, n_candidates)
    n_f = folds.n_folds
    slim = replace(result, top_models=[], model=result.model)  # what the folds need of the screening

    def fold_pass(these, what):
        jobs = [(f, ref, folds.fold, these, slim, excluded, oe_windows, score_windows, accel_max) for f in range(n_f)]
        return parallel_map(_fold_job, jobs, n_jobs, desc=what, names=[f"{what}, fold {f}" for f in range(n_f)])

    per_fold = fold_pass(specs, "output-error candidates")

    def collect(label, complexity=None):
        rms = np.array([p[label][0] for p in per_fold])
        n = np.array([p[label][1] for p in per_fold], int)
        yaw = np.array([p[label][2] for p in per_fold])
        if complexity is not None:
            return Candidate(label, None, rms, n, yaw, complexity, True)
        failed = [k for p in per_fold for k in p[label][4]]
        n_failing = sum(1 for p in per_fold if p[label][4])
        return (rms, n, yaw, float(np.mean([p[label][3] for p in per_fold])), 2 * n_failing < len(per_fold),
                tuple(dict.fromkeys(failed)))

    candidates = tuple(Candidate(label, hp, *collect(label)) for label, hp in specs)
    step = _stepwise_spec(candidates)
    if step is not None:  # the stepwise search from the structure the rule picks, cross-validated the same way
        for p, q in zip(per_fold, fold_pass([step], "stepwise output error")):
            p.update({k: v for k, v in q.items() if k != "lag baseline"})
        candidates += (Candidate(step[0], step[1], *collect(step[0])),)
    lag_cv = collect("lag baseline", complexity=6.0)
    order = sorted(range(len(candidates)), key=lambda i: candidates[i].cv_pos_err_5s_m)
    chosen = select_candidate(candidates)
    with threadpool_limits(limits=1, user_api="blas"):  # as in _fold_job
        chosen, model, fit, checks = _final(candidates, chosen, order, result, excluded, lag, ref, oe_windows,
                                            accel_max)
    c = candidates[chosen]
    training = {**model.training, "runs": list(ref.names), "reference_smoothing": ref.smoothing,
                "cv": {"kind": folds.kind, "note": folds.note, "held_out": [list(h) for h in folds.held_out],
                       "pos_err_5s_m": c.cv_pos_err_5s_m, "se_m": c.cv_se_m,
                       "fold_pos_err_5s_m": [float(v) for v in c.fold_rms_m],
                       "lag_pos_err_5s_m": lag_cv.cv_pos_err_5s_m, "lag_se_m": lag_cv.cv_se_m},
                "candidates": [k.summary() for k in candidates], "selected": c.label,
                "selection": "sparsest candidate passing the checks in most folds within one standard error "
                             "(over folds) of the best CV error",
                "excitation_std": stds, "not_excited": quiet, "lag_baseline": lag.to_dict(),
                "output_error": None if fit is None else {
                    "names": list(fit.names), "std": [float(v) for v in fit.std], "rms_pos_m": fit.rms_pos_m,
                    "n_windows": fit.n_windows, "window_s": OE_WINDOW_S}}
    hyper = dict(c.hyperparameters or {"structure": "lag", "s": ref.smoothing}) | {
        "dead_time_s": list(model.dead_time_s), "input_lag_s": list(model.input_lag_s)}
    model = replace(model, checks=checks, training=training, hyperparameters=hyper)
    ident = Identification(model=model, lag=lag, search=result, candidates=candidates, selected=chosen, folds=folds,
                           lag_cv=lag_cv, not_excited=tuple(quiet), notes=tuple(notes))
    if not ident.beats_lag:
        log.warning("identification: the selected model (CV %.3f m) does not beat the lag baseline (CV %.3f m)",
                    c.cv_pos_err_5s_m, lag_cv.cv_pos_err_5s_m)
    return ident
