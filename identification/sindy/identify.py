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
   (:mod:`identification.sindy.candidate_fit`); each is checked
   (:func:`identification.sindy.checks.run_checks`) and scored on the held-out group's reference
   windows. The one-standard-error rule over the folds picks the
   sparsest candidate that passes the checks in most folds (more than half): a fold's model is
   fitted on less data, and a structure whose refit on one fold's groups leans on a term the
   data barely excite fails there without being fragile on all train runs, which the final
   model is checked on (measured on simulator variant 2: every refined structure failed the
   dissipativity check in one fold of three, on ``vy omega^2`` with ``vy`` at 15 mm/s).
6. **Stepwise output error** (:mod:`identification.sindy.stepwise`): the structure the rule
   picks (a grid structure; the best grid structure by CV error when it picks the lag) is the
   start of a search that adds terms by their score on the output error and drops them by its t
   statistics; refitted in every fold the same way (from the start the candidate pass refined
   on that fold), it joins the candidates and the rule picks again. On simulator variants the
   regression's choice of terms, not the coefficients, kept the refined models at about twice
   the true dynamics' error on their own train windows.
7. **Final model**: the picked candidate refitted on all train runs the same way; if it fails
   the checks, the next candidate by CV error is taken (never a failing model). The stepwise
   candidate's refit, a search of its own, runs as a task of its folds' pass where the last
   round leaves a worker idle, so that it is ready when the rule picks it.
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
from identification.sindy.baselines import LagModel, fit_lag
from identification.sindy.candidate_fit import candidate_model, score_on, start_model
from identification.sindy.checks import excitation, measured_accel_max, not_excited, run_checks
from identification.sindy.data import pose_noise_std
from identification.sindy.evaluate import Windows
from identification.sindy.library import LIBRARY_VARIABLE_NAMES
from identification.sindy.model import SindyModel
from identification.sindy.output_error import OE_DT, OE_MAX_WINDOWS, OE_WINDOW_S, OutputErrorFit
from identification.sindy.regression import check_pose_spacing
from identification.sindy.reference import (
    Folds,
    Reference,
    blocks_of_single_run,
    cv_folds,
    reference,
    select_windows,
    thin_windows,
)
from identification.sindy.search import DEFAULT_GRID, SearchGrid, SearchResult, admissible, search
from identification.sindy.selection import Candidate, select_candidate
from identification.sindy.stepwise import STEPWISE

log = logging.getLogger(__name__)

#: distinct structures of the screening refined by output error and cross-validated (plus the lag)
N_CANDIDATES = 4
#: the fold of a pass's job that refits a candidate on all train runs (:func:`_refit_on_all`)
ALL_RUNS = "all train runs"


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


def _candidates(result: SearchResult, n: int) -> list[tuple[str, dict]]:
    """Return ``(label, hyperparameters)`` of the best ``n`` admissible rows with distinct structures.

    When no row is admissible (every regression model ran away on some held-out window), the
    best rows stable at rest, else the best rows, in the screening's order (fewest diverged
    windows first): pruning, output error, cross-validation and the checks decide on them."""
    ok = admissible(result.table)
    if not ok.any():
        ok = np.asarray(result.table["stable_at_rest"], bool)
        ok = ok if ok.any() else np.ones(len(ok), bool)
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


def _fold_job(job) -> tuple[dict, dict] | tuple | InputError:
    """Return the scores of some candidates on one fold, and those refined by output error
    (:func:`_fold_pass`); for a job ``("all train runs", ...)``, :func:`_refit_on_all`'s result
    (or its :class:`InputError`)."""
    # Small SVDs and least squares (the adjustments, the output-error steps): multi-threaded BLAS
    # on a loaded 2-core machine made each about 30 times slower (measured); parallelism is per process.
    with threadpool_limits(limits=1, user_api="blas"):
        if job[0] == ALL_RUNS:
            try:
                return _refit_on_all(*job[1:])
            except InputError as exc:
                return exc
        return _fold_job_serial(job)


def _fold_job_serial(job) -> tuple[dict, dict]:
    """Return :func:`_fold_job`'s scores (label -> RMS 5 s error, windows, heading error,
    complexity, failed checks; ``"lag baseline"`` when ``baseline``) and the models refined by
    output error (label -> model, the stepwise search's start in :func:`_fold_pass`)."""
    f, specs, baseline, started, ref, fold, result, excluded, oe_windows, score_windows, accel_max = job
    train = np.flatnonzero(fold != f)
    keep_held = ~np.isin(score_windows.run, train)
    held = select_windows(score_windows, keep_held) if keep_held.any() else None
    fold_oe = thin_windows(select_windows(oe_windows, np.isin(oe_windows.run, train)), OE_MAX_WINDOWS)
    fold_ref = Reference(states=tuple(ref.states[i] for i in train), names=tuple(ref.names[i] for i in train),
                         run_index=ref.run_index[train], runs=ref.runs, smoothing=ref.smoothing)
    fold_lag = fit_lag(fold_ref)  # deterministic: every task of the fold fits the same lag
    out = {"lag baseline": score_on(fold_lag, held)} if baseline else {}
    refined: dict = {}
    cache: dict = {}
    for label, hp in specs:
        if started.get(label) is not None:
            start, adj = None, None
        else:
            try:
                start, adj = start_model(label, hp, result, cache, excluded, train, fold_lag, fold_ref.states)
            except InputError as exc:  # more active terms than independent windows: significance unjudgeable
                log.info("fold %d, %s: %s; not admissible", f, label, exc)
                out[label] = (float("nan"), 0, float("nan"), float("nan"), ["significance"])
                continue
        model, fit, significance = candidate_model(start, adj, hp, fold_oe, excluded, started.get(label))
        if fit is not None and (hp or {}).get("output_error", True) is True:
            refined[label] = model
        checks = run_checks(model, fold_ref.states, *significance, accel_max)
        out[label] = score_on(model, held) + (model.complexity, [k for k, v in checks.items()
                                                                    if isinstance(v, dict) and not v["passed"]])
    return out, refined


#: tasks each fold's candidates are split into (:func:`_fold_pass`): with 5 folds on 2 workers,
#: one task per fold leaves a worker idle for a third of the last round
TASKS_PER_FOLD = 2


def _split(specs: Sequence[tuple[str, dict | None]], n: int) -> list[list[tuple[str, dict | None]]]:
    """Return ``specs`` in at most ``n`` chunks of about equal work (greedily, in order), a
    structure's variants (refined by output error, as regressed), which share their start, in one
    chunk. An output-error refinement counts 1, the lag and a regression's coefficients 0.1."""
    groups: dict[str, list] = {}
    for label, hp in specs:
        groups.setdefault(label.split(",")[0], []).append((label, hp))
    chunks: list[list] = [[] for _ in range(min(n, len(groups)))]
    work = [0.0] * len(chunks)
    for g in groups.values():
        i = int(np.argmin(work))
        chunks[i].extend(g)
        work[i] += sum(0.1 if hp is None or hp.get("output_error") is False else 1.0 for _, hp in g)
    return chunks


def _fold_pass(specs, shared: tuple, n_folds: int, n_jobs, what: str, started=None, on_all: tuple | None = None
               ) -> tuple[list[tuple[dict, dict]], tuple | InputError | None]:
    """Return, per fold, the merged :func:`_fold_job` results of ``specs``, :data:`TASKS_PER_FOLD`
    tasks per fold (``started``: per fold, label -> the model to start the stepwise search from),
    and the result of :func:`_refit_on_all` of the arguments ``on_all`` computed beside them (None without)."""
    chunks = _split(specs, TASKS_PER_FOLD)
    jobs, names, where = [], [], []
    if on_all is not None:
        jobs.append((ALL_RUNS,) + on_all)
        names.append(f"{what}, all train runs")
        where.append(-1)
    for f in range(n_folds):
        for i, chunk in enumerate(chunks):
            jobs.append((f, tuple(chunk), i == 0, (started or [{}] * n_folds)[f]) + shared)
            names.append(f"{what}, fold {f}" + (f", part {i + 1}" if len(chunks) > 1 else ""))
            where.append(f)
    per_fold: list[tuple[dict, dict]] = [({}, {}) for _ in range(n_folds)]
    ready = None
    for f, out in zip(where, parallel_map(_fold_job, jobs, n_jobs, desc=what, names=names)):
        if f < 0:
            ready = out
            continue
        per_fold[f][0].update(out[0])
        per_fold[f][1].update(out[1])
    return per_fold, ready


def _room_beside(n_tasks: int, n_jobs) -> bool:
    """Return whether one task more runs beside ``n_tasks`` without another round: local processes
    whose last round leaves one idle, or a Dask cluster (its concurrency is its own). One process
    has no room: a refit that may not be needed would only add its time."""
    workers = Workers.of(n_jobs)
    if workers.dask is not None:
        return True
    return workers.jobs > 1 and -(-(n_tasks + 1) // workers.jobs) == -(-n_tasks // workers.jobs)


def _refit_on_all(label: str, hp: dict | None, result: SearchResult, cache: dict, excluded, lag: LagModel,
                  ref: Reference, all_oe: Windows, accel_max) -> tuple[SindyModel, OutputErrorFit | None, dict]:
    """Return a candidate refitted on all train runs as in the folds, its output-error fit and its checks.

    Raises
    ------
    InputError
        More active terms than independent windows (its significance cannot be judged).
    """
    start, adj = start_model(label, hp, result, cache, excluded, None, lag, ref.states)
    model, fit, significance = candidate_model(start, adj, hp, all_oe, excluded)
    return model, fit, run_checks(model, ref.states, *significance, accel_max)


def _final(candidates, chosen: int, order, result: SearchResult, excluded, lag: LagModel, ref: Reference,
           all_oe: Windows, accel_max, ready: dict | None = None
           ) -> tuple[int, SindyModel, OutputErrorFit | None, dict]:
    """Return the index, model, output-error fit and checks of the first candidate (``chosen``,
    then the others that passed by CV error) that passes the checks refitted on all train runs
    (``all_oe``: their output-error windows, thinned; ``ready``: label -> :func:`_refit_on_all`'s
    result or its :class:`InputError`, computed already)."""
    cache: dict = {}
    ready = ready or {}
    for i in [chosen] + [j for j in order if j != chosen and candidates[j].passed]:
        c = candidates[i]
        try:
            got = ready.get(c.label)
            if isinstance(got, InputError):
                raise got
            model, fit, checks = got if got is not None else _refit_on_all(
                c.label, c.hyperparameters, result, cache, excluded, lag, ref, all_oe, accel_max)
        except InputError as exc:  # more active terms than independent windows: significance unjudgeable
            log.warning("identification: candidate %s refitted on all train runs: %s; trying the next", c.label, exc)
            continue
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
    check_pose_spacing([r.poses.t for r in runs], [r.name for r in runs], "train runs")
    runs, blocked = blocks_of_single_run(runs, grid.n_folds)
    ref = reference(runs)
    folds = cv_folds(ref.groups, ref.run_index, grid.n_folds)
    if blocked:  # each block its own group: leave-one-block-out
        log.warning("cross-validation: %s", blocked)
        folds = replace(folds, kind="leave-one-block-out", note=blocked)
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

    shared = (ref, folds.fold, slim, excluded, oe_windows, score_windows, accel_max)
    all_oe = thin_windows(oe_windows, OE_MAX_WINDOWS)  # the refits on all train runs
    passes, _ = _fold_pass(specs, shared, n_f, n_jobs, "output-error candidates")
    per_fold = [scores for scores, _ in passes]

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
    ready = {}
    if step is not None:  # the stepwise search from the structure the rule picks, cross-validated the same way
        # each fold's search starts from that structure as the candidate pass refined it on the fold
        origin = step[0].split(",")[0]
        started = [{step[0]: refined.get(origin)} for _, refined in passes]
        # and its search on all train runs, which the final model needs if the rule picks it, runs
        # beside them where a slot is free: with 5 folds on 2 workers the one the last fold leaves
        # idle (on simulator variants the stepwise candidate is picked in 7 of 10), instead of after
        on_all = (step[0], step[1], slim, {}, excluded, lag, ref, all_oe, accel_max)
        steps, got = _fold_pass([step], shared, n_f, n_jobs, "stepwise output error", started,
                                on_all if _room_beside(n_f, n_jobs) else None)
        if got is not None:
            ready[step[0]] = got
        for p, (q, _) in zip(per_fold, steps):
            p.update(q)
        candidates += (Candidate(step[0], step[1], *collect(step[0])),)
    lag_cv = collect("lag baseline", complexity=6.0)
    order = sorted(range(len(candidates)), key=lambda i: candidates[i].cv_pos_err_5s_m)
    chosen = select_candidate(candidates)
    with threadpool_limits(limits=1, user_api="blas"):  # as in _fold_job
        chosen, model, fit, checks = _final(candidates, chosen, order, result, excluded, lag, ref, all_oe,
                                            accel_max, ready)
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
