"""The sections of the report, one builder per stage of the chain.

Each ``section_*`` takes the finished :class:`~sindy_ekf.stages.chain.ChainResult` and returns
a :class:`~sindy_ekf.report.blocks.Section`: campaign overview, calibration, synchronisation,
poses, identification, evaluation, estimation, diagnosis. Each is written as the body that fills
its section, made a builder by :func:`_builds`, which names the stages it needs: a section that
does not apply (a trajectory campaign has no raw tracker data) or whose stage failed says so in
one line.
"""


from __future__ import annotations

import functools
import html
from typing import Callable

import numpy as np

from groundfloor.numbers import format_sig, format_with_std
from identification.preprocessing.figures import (
    plot_baseline,
    plot_baseline_vs_speed,
    plot_body_frame,
    plot_body_states,
    plot_clock_residuals,
    plot_gap_signal,
    plot_hub_model,
    plot_network,
    plot_offset_fit,
    plot_poses,
    plot_xcorr,
)
from identification.preprocessing.preprocess import DEFAULT_SMOOTHING
from identification.sindy.data import body_states, states_of_runs
from identification.sindy.figures import (
    plot_error_curves,
    plot_error_vs_complexity,
    plot_grid,
    plot_term_prevalence,
)
from simulation.gnss import PROFILES
from sindy_ekf.benchmark.figures import plot_error_bands, plot_nees, plot_outage_errors, plot_trajectories
from sindy_ekf.diagnose.figures import plot_gain_profile, plot_lag_profile, plot_residual_structure
from sindy_ekf.diagnose.gain_profile import named_profile, shown_estimate
from sindy_ekf.report.bag_facts import bag_notes, bag_words
from sindy_ekf.report.blocks import SECTIONS, Section, table_html
from sindy_ekf.report.figures import (
    plot_driven_paths,
    plot_family_gains,
    plot_input_coverage,
    run_overview,
)
from sindy_ekf.report.glossary import terms_html
from sindy_ekf.stages.chain import ChainResult
from sindy_ekf.stages.evaluation import CV_PREDICTION_LEVEL, cv_comparison


def _vec(v, k: float = 1.0, fmt: str = "{:+.3f}") -> str:
    return "[" + ", ".join(fmt.format(x * k) for x in np.asarray(v, float).ravel()) + "]"


def _absent_or_failed(sec: Section, chain: ChainResult, stages: tuple[str, ...]) -> bool:
    """Mark ``sec`` absent/failed (with its reason) if one of ``stages`` did not give a result."""
    for st in stages:
        if st in chain.errors:
            sec.status = "failed"
            sec.note(f"stage '{st}' failed: {chain.errors[st]}", "fail")
            return True
        if st in chain.skipped:
            sec.status = "absent"
            sec.note(f"not available: {chain.skipped[st]}.")
            return True
    return False


Fill = Callable[[Section, ChainResult], None]  # writes one stage's notes, tables and figures into its section
Builder = Callable[[ChainResult], Section]


def _builds(sid: str, needs: tuple[str, ...] = ()) -> Callable[[Fill], Builder]:
    """Return a decorator turning ``fill(sec, chain)`` into the builder of section ``sid``.

    The builder makes the section (titled as in :data:`SECTIONS`) and fills it only when every
    stage of ``needs`` gave a result; otherwise the section says which stage did not, and why.
    """
    def decorate(fill: Fill) -> Builder:
        @functools.wraps(fill)
        def build(chain: ChainResult) -> Section:
            sec = Section(sid, dict(SECTIONS)[sid])
            if not _absent_or_failed(sec, chain, needs):
                fill(sec, chain)
            return sec

        return build

    return decorate


def _counts(intervals) -> dict[float, int]:
    """Return outage length (s) -> how many outages of that length ``{run: (m, 2)}`` holds."""
    lengths = np.round(np.concatenate([o[:, 1] - o[:, 0] for o in intervals.values()] or [np.empty(0)]), 6)
    return {float(d): int(np.sum(lengths == d)) for d in np.unique(lengths)}


# Sections
# --------------------------------------------------------------------------------------------

@_builds("overview")
def section_overview(sec: Section, chain: ChainResult) -> None:
    """Write the campaign overview: runs, durations, driven paths, input coverage (fig. 6.3)."""
    traj = chain.trajectory
    rows = run_overview(traj)
    sec.note(f"{chain.campaign_path} ({chain.kind} campaign '{traj.name}'): {len(rows)} runs, "
             f"{sum(r['duration_s'] for r in rows) / 60:.1f} min, {sum(r['path_m'] for r in rows):.0f} m driven.")
    gaps = {run.name: run.repairs.get("gaps", 0) for run in traj.runs}
    sec.add(table_html(["run", "split", "duration s", "poses", "rate Hz", "gaps", "path m", "speed p99 m/s", "inputs"],
                       [[r["name"], r["split"], f"{r['duration_s']:.1f}", r["n_poses"], f"{r['rate_hz']:.1f}",
                         gaps[r["name"]], f"{r['path_m']:.1f}", f"{r['max_speed_m_s']:.2f}", r["n_inputs"]]
                        for r in rows], left=2))
    sec.note("gaps: holes in the poses longer than the gap threshold (10 median intervals, at least 0.5 s), mostly "
             "a prism lost by a tracker; expected, counted, and never bridged: splines, windows and figures stop "
             "at them. speed p99: 99th percentile of the speed.")
    skipped = (chain.preprocess or {}).get("skipped_runs") or {}
    for name, why in skipped.items():
        sec.note(f"run {name} skipped by preprocessing: {why}")
    states = chain.states.get("train", []) + chain.states.get("test", [])
    if not states:
        states = states_of_runs(traj.runs, DEFAULT_SMOOTHING)[0]
    sec.figures([(lambda: plot_driven_paths(traj.runs), "driven paths in the local frame"),
                 (lambda: plot_input_coverage(states), "density of control inputs and driving states (fig. 6.3)")])


@_builds("calibration", needs=("calibration",))
def section_calibration(sec: Section, chain: ChainResult) -> None:
    """Write the calibration: transform (eq. 5.1, table 7.2), lever arms (table 7.1), residuals, global test."""
    cal, tf = chain.calibration, chain.calibration.transform
    std = tf.params_std
    sec.note("x_at960 = t + R x_ltd800 with R = Rz(rz) Ry(ry) Rx(rx) (eqs. 5.1 to 5.5; Gauss-Helmert adjustment of "
             "the network points, both trackers' coordinates observed); table 7.2 lists t_table = R^T t. "
             "Standard deviations a priori, from the survey sigmas; values rounded to two digits of their std.")
    rows = [[f"t {a} [m]", format_with_std(v, e, sign=True)] for a, v, e in zip("xyz", tf.t_at960_ltd800, std[:3])]
    rows += [[f"t_table {a} [m]", format_with_std(v, e, sign=True)]
             for a, v, e in zip("xyz", tf.t_table, tf.t_table_std)]
    rows += [[f"{a} [deg]", format_with_std(np.degrees(v), np.degrees(e), sign=True)]
             for a, v, e in zip(("rx", "ry", "rz"), tf.rotation_rad, std[3:])]
    test = tf.variance_factor_test
    rows += [["global test of s0^2", test.sentence()], ["outlier test", tf.blunder_message()]]
    sec.add(table_html(["quantity", "value +- std"], rows))
    lever_std = cal.body.lever_arms_std
    sec.add(table_html(["prism", "tracker", "lever arm x, body frame [mm]", "y [mm]", "z [mm]"],
                       [[k, cal.prism_tracker[k], *[format_with_std(1e3 * a, 1e3 * e, sign=True)
                                                    for a, e in zip(v, lever_std[k])]]
                        for k, v in cal.lever_arms_body.items()], left=2))
    sec.add(table_html(["network point", "residual [um]", "normalised residual", "leave-one-out T"],
                       [[pid, _vec(tf.residuals_m[i], 1e6, "{:+.1f}"), _vec(tf.normalised_residuals[i], fmt="{:+.2f}"),
                         f"{tf.point_test[i]:.2f}"] for i, pid in enumerate(tf.point_ids)]))
    sec.add(terms_html(["s0^2", "dof", "normalised residual", "leave-one-out T"]))
    sec.figures([(lambda: plot_network(chain.survey, tf), "network points and tracker frames (fig. 6.1), "
                  "residuals exaggerated"),
                 (lambda: plot_body_frame(chain.survey, cal.body), "body frame from the wheel hubs (fig. 7.1)")])


@_builds("synchronisation", needs=("calibration",))
def section_synchronisation(sec: Section, chain: ChainResult) -> None:
    """Write the synchronisation: per-run clocks, offsets, baselines; figures of one run (5.2.2)."""
    runs = (chain.preprocess or {}).get("runs", {})
    rows = []
    for name, r in runs.items():
        b, hub = r["baseline_rms_m"], r.get("hub") or {}
        rows.append([name, r["split"], f"{r['clock']['ltd800']['drift_ppm']:+.3f}",
                     f"{r['clock']['at960']['drift_ppm']:+.3f}", f"{r['at960_extra_offset_s'] * 1e3:+.3f}",
                     f"{r['timing_error']['r_baseline_speed_before']:+.2f}",
                     f"{r['timing_error']['r_baseline_speed_after']:+.2f}",
                     f"{b['before'] * 1e3:.3f}", f"{b['after'] * 1e3:.3f}",
                     f"{b['after_hub_model'] * 1e3:.3f}" if "after_hub_model" in b else "-",
                     f"{hub['r1'] * 1e3:.3f} / {hub['r2'] * 1e3:.3f}" if hub else "-", bag_words(r)])
    sec.note("Clock model t_trigger = k t_tracker + d per tracker, the AT960's extra offset, the baseline length "
             "between the prisms (RMS about its mean) before and after the offset and after the turning-hub model, "
             "and what reading the bags found.")
    sec.add(table_html(["run", "split", "LTD800 drift ppm", "AT960 drift ppm", "AT960 offset ms", "r before",
                        "r after", "baseline RMS before mm", "after", "after hub", "hub r1/r2 mm", "bags"], rows, left=2))
    sec.add(terms_html(["drift", "r before / after", "hub r1/r2"]))
    for line in bag_notes(runs):
        sec.note(line)
    if _absent_or_failed(sec, chain, ("synchronisation",)):
        return
    raw, run = chain.showcase.raw, chain.showcase.run
    s = run.synced
    sec.note(f"Figures for test run {raw.name}.")
    if run.pose_test is not None:
        sec.note(f"Pose adjustment of run {raw.name} (eqs. 5.33 to 5.36, tracker sigmas a priori), global test over "
                 f"its epochs: {run.pose_test.sentence()}.")
    if run.hub is not None:
        sec.note("The turning-hub model is fitted with unit weights (no a-priori precision of the baseline length): "
                 f"its s0 = {run.hub.s0_m * 1e3:.3f} mm is an estimate, not tested.")
    items = [(lambda: plot_gap_signal(raw, "ltd800"), "gap signals and detected gaps (fig. 5.1)"),
             (lambda: plot_xcorr(raw, s), "cross-correlation of the gap signals (fig. 5.2)"),
             (lambda: plot_clock_residuals(s), "clock fit residuals (fig. 5.4)"),
             (lambda: plot_baseline(s), "baseline length before and after the offset (fig. 5.5)"),
             (lambda: plot_offset_fit(s), "AT960 extra offset fit (fig. 5.6)"),
             (lambda: plot_baseline_vs_speed(s), "baseline against forward speed")]
    if run.hub is not None:
        items.append((lambda: plot_hub_model(run.hub), "turning-hub model, eq. 5.25 (fig. 5.7)"))
    sec.figures(items)


@_builds("poses")
def section_poses(sec: Section, chain: ChainResult) -> None:
    """Write the poses of one test run with their sigmas (figs. 7.2, 7.3) and its body states (7.9)."""
    run = chain.trajectory.split("test")[0]
    poses = chain.showcase.run.poses if chain.showcase is not None else run.poses
    items = [(lambda: plot_poses(poses), f"run {run.name}: position, attitude and their sigmas (figs. 7.2, 7.3)")]
    if chain.model is not None:
        s = float(chain.model.hyperparameters.get("s") or 0.0)
        segments = body_states(run, s)
        if segments:
            items.append((lambda: plot_body_states({s: segments}),
                          f"run {run.name}: body-frame velocities, spline smoothing s = {s:g} (eqs. 5.64-5.68, "
                          "fig. 7.9)"))
    sec.figures(items)


def _hyperparameter(key: str, value) -> str:
    """Return a hyperparameter as a reader wants it: times (``*_s``) in ms, other numbers as %g."""
    if isinstance(value, (bool, str)):
        return str(value)
    if isinstance(value, (list, tuple)):
        if key.endswith("_s"):
            return "[" + ", ".join(f"{1e3 * float(v):.0f}" for v in value) + "] ms"
        return "[" + ", ".join(f"{float(v):g}" for v in value) + "]"
    if isinstance(value, (int, float)):
        return f"{1e3 * float(value):.0f} ms" if key.endswith("_s") else f"{value:g}"
    return str(value)


@_builds("identification", needs=("identification",))
def section_identification(sec: Section, chain: ChainResult) -> None:
    """Write the identification: grid search, selected model's equations, term prevalence."""
    model = chain.model
    hp = ", ".join(f"{k} = {_hyperparameter(k, v)}" for k, v in model.hyperparameters.items())
    src = f"loaded from {chain.model_path}" if chain.search is None else f"selected by the grid search ({hp})"
    sec.note(f"Integral SINDy (eqs. 5.55 to 5.59), library {model.library.name}, {model.complexity} active "
             f"terms, {src}.")
    sec.add(f"<pre>{html.escape(model.equations())}</pre>")
    if chain.search is None:
        return
    res = chain.search
    tb = res.table
    n, n_finite = len(tb["s"]), int(np.isfinite(tb["pos_err_5s_m"]).sum())
    chosen = res.row(res.selected) if res.selected < n else None
    kept = ("" if chosen is None or int(chosen["complexity"]) == model.complexity else
            f" The table counts the terms of each grid point's regression; the selected one's "
            f"{int(chosen['complexity'])} became the model's {model.complexity} after its refinement (terms "
            "without a significant coefficient dropped, docs/identification.md).")
    sec.note(f"{n} grid points, {n_finite} with a finite cross-validated 5 s error; the selected model is the "
             f"sparsest admissible one within one standard error of the best.{kept}")
    rows = [[i, f"{r['s']:g}", f"{r['tau']:g}", f"{r['alpha']:g}", f"{r['T']:g}", f"{r['complexity']:.0f}",
             f"{100 * r['pos_err_5s_m']:.2f}", f"{r['yaw_err_5s_deg']:.2f}", f"{100 * r.get('diverged_frac', 0.0):.0f}",
             "selected" if i - 1 == res.selected else ""] for i, r in enumerate(res.ranking(8), 1)]
    sec.add(table_html(["rank", "s", "tau s", "alpha", "T", "terms", "CV pos 5 s cm", "CV yaw 5 s deg",
                        "diverged %", ""], rows))
    if any(not np.isfinite(r["pos_err_5s_m"]) for r in res.ranking(8)):
        sec.note("inf: at least one held-out 5 s prediction of that model diverged (the diverged column), so its "
                 "RMS error is infinite; such models are ranked after every model that never diverged, sparsest first.")
    sec.add(terms_html(["s", "tau", "alpha", "T", "CV", "diverged"]))
    s = float(model.hyperparameters["s"])
    if s not in set(np.asarray(res.table["s"], float).tolist()):  # the lag structure: not a grid point
        s = float(res.table["s"][0])
    items = [(lambda: plot_grid(res, s), f"grid over alpha and T at s = {s:g} (figs. 7.4-7.7)"),
             (lambda: plot_error_vs_complexity(res), "5 s errors against complexity, models with a finite error "
              "(fig. 7.10)")]
    if res.top_models:
        items.append((lambda: plot_term_prevalence(res.top_models),
                      f"term prevalence in the {len(res.top_models)} best models (fig. 7.11)"))
    sec.figures(items)


@_builds("evaluation", needs=("identification", "evaluation"))
def section_evaluation(sec: Section, chain: ChainResult) -> None:
    """Write the multi-step evaluation on the test runs: s_p(t), s_h(t) (eqs. 5.76-5.78, fig. 7.8)."""
    ev = chain.evaluation
    sindy = ev["sindy"]
    errors = chain.prediction_errors()
    sec.note(f"{errors['sindy'].n_windows} windows of 5 s (50 % overlap) on the test runs, each model integrated "
             "from the window's first state with the recorded inputs (RK4 on eq. 5.75); RMS over the windows at 5 s "
             "(eqs. 5.76 to 5.78). Thesis (model B, real data): 14.0 cm and 4.2 deg after 5 s.")
    sec.add(table_html(["model", "pos. error 5 s cm", "heading error 5 s deg"],
                       [[n, f"{100 * e.pos_err_5s_m:.2f}", f"{e.yaw_err_5s_deg:.2f}"] for n, e in errors.items()]))
    sec.add(terms_html(errors))
    if "lag" in errors:  # the hand-written model to beat (first-order lag per axis with input dead time)
        model_m, lag_m = errors["sindy"].pos_err_5s_m, errors["lag"].pos_err_5s_m
        sec.note(f"The identified model beats the lag baseline ({model_m / lag_m:.2f}x its 5 s position error)."
                 if model_m < lag_m else
                 f"The identified model does NOT beat the lag baseline (first-order lag per axis with input dead "
                 f"time, fitted on the train runs): {100 * model_m:.2f} cm against {100 * lag_m:.2f} cm.")
    note = cv_note(chain.model, errors["sindy"].pos_err_5s_m)
    if note:
        sec.note(note)
    sec.figures([(lambda: plot_error_curves([sindy]), "SINDy model: per-window errors (grey) and s_p(t), s_h(t)"),
                 (lambda: plot_error_curves(list(ev.values()), stacked=False), "all models: s_p(t), s_h(t)")])


def cv_note(model, test_pos_err_5s_m: float) -> str:
    """Return the model file's cross-validation estimate beside the test score, and whether the score
    lies inside the prediction interval of one more held-out group (``""`` without an estimate)."""
    cv = cv_comparison(model, test_pos_err_5s_m) if model is not None else None
    if cv is None:
        return ""
    where = f" ({cv.kind}, {cv.n_folds} folds)" if cv.kind else f" ({cv.n_folds} folds)"
    head = (f"Cross-validation on the train runs{where} estimated {100 * cv.cv_pos_err_5s_m:.2f} cm at 5 s; the test "
            f"runs gave {100 * cv.test_pos_err_5s_m:.2f} cm")
    if not np.isfinite(cv.interval_m):
        return head + " (one fold: no spread to compare them by)."
    inside = (f", inside the {100 * CV_PREDICTION_LEVEL:.0f} % prediction interval of one more held-out group "
              f"(+- {100 * cv.interval_m:.2f} cm)")
    if not cv.disagree:
        wide = (f"; with {cv.n_folds} folds the interval is wider than the estimate itself, so the comparison says "
                "little" if cv.interval_m > cv.cv_pos_err_5s_m else "")
        return head + inside + ": nothing says the test runs are unlike the train groups" + wide + "."
    return (head + inside.replace(", inside", ", outside") + ": the test runs are NOT like the train groups (another "
            "day, ground or way of driving), and neither number speaks for the other.")


def gnss_note(b) -> str:
    """Return what the estimators of the benchmark ``b`` fused: the GNSS (a profile simulated from the
    truth, or the campaign's own recorded fixes with their ENU -> local transform) and the other
    sensors, with the estimators that fused them."""
    if b.recorded_gnss:
        tr = b.recorded_gnss["enu_to_local"]
        how = (f"estimated from the fixes against the truth: {tr['enu_to_local_yaw_deg']:.3f} +- "
               f"{tr['yaw_std_deg']:.3f} deg" if tr.get("estimated") else f"given: {tr['enu_to_local_yaw_deg']:.3f} deg")
        text = (f"GNSS: the campaign's own recorded fixes, mapped into the local frame by the ENU -> local rotation "
                f"{how}; the ground-truth poses of the {len(b.truth)} test runs are the truth")
        if tr.get("errors_correlated_over_runs"):
            text += (". The fixes' errors stay correlated over most of every run (a receiver bias wandering for "
                     "minutes), likely across runs too: the estimated rotation may be off by more than its stated std")
        lever = b.recorded_gnss.get("lever_arm_fit") or {}
        if lever.get("differs"):
            (x, y), (sx, sy), (dx, dy) = lever["estimated_m"], lever["std_m"], lever["declared_m"]
            text += (f". The fixes put the antenna at ({x:.2f} +- {sx:.2f}, {y:.2f} +- {sy:.2f}) m in the body frame, "
                     f"not at the declared ({dx:.2f}, {dy:.2f}) m: the filters took it there, so part of their GNSS "
                     "error is the antenna swinging around the body origin in turns")
    else:
        prof = PROFILES.get(b.profile)
        what = (f" ({prof.std_m:g} m per axis at {prof.rate_hz:g} Hz, {100 * prof.outlier_prob:g} % of the fixes "
                "multipath outliers)") if prof is not None else ""
        text = (f"GNSS profile {b.profile}{what}, simulated from the ground-truth poses of the {len(b.truth)} test "
                "runs, which are also the truth")
    settings = (b.config or {}).get("estimators", {})
    fused: dict[str, list[str]] = {}
    for name in b.scores:
        for sensor in (settings.get(name) or {}).get("sensors") or ():
            if sensor != "gnss":
                fused.setdefault(sensor, []).append(name)
    for sensor, names in fused.items():
        text += f"; {'the gyro (imu.csv)' if sensor == 'imu' else 'the wheel odometry (odometry.csv)'} fused by {', '.join(names)}"
    return text


@_builds("estimation", needs=("identification", "estimation"))
def section_estimation(sec: Section, chain: ChainResult) -> None:
    """Write the estimator benchmark: trajectories with GNSS, errors with 3-sigma bands, outages, NEES."""
    b = chain.benchmark
    lo, hi = b.nees_bounds_95
    counts = _counts(b.outages)
    held = ", ".join(f"{k} of {d:g} s" for d, k in counts.items()) or "none (the test runs are too short)"
    sec.note(f"{gnss_note(b)} (alignment: {b.alignment}). Scheduled GNSS outages: {held}. A consistent "
             f"estimator has a mean NEES of 3 with 95 % of the samples inside [{lo:.2f}, {hi:.2f}].")
    durations = sorted({k for sc in b.scores.values() for k in sc.outage_pos_err_m}, key=float)
    rows = [[n, f"{sc.ate_pos_m:.3f}", f"{sc.ate_yaw_deg:.2f}",
             *[f"{sc.outage_pos_err_m[d]:.3f}" if d in sc.outage_pos_err_m else "-" for d in durations],
             f"{sc.nees_mean:.2f}", f"{100 * sc.nees_inside_95:.0f}", f"{sc.runtime_s:.2f}",
             f"{sc.realtime_factor:.0f}", sc.status_text()] for n, sc in b.scores.items()]
    sec.add(table_html(["estimator", "ATE pos m", "ATE yaw deg", *[f"end of {d} s outage m" for d in durations],
                        "NEES mean", "NEES in 95 % %", "runtime s", "x real time", "status"], rows))
    for n, sc in b.scores.items():  # a row not ok is scored up to its end: say why it ended
        if sc.status != "ok":
            sec.note(f"{n} {sc.status} at {sc.t_s:.2f} s: {sc.reason}; its scores cover the time before.")
    sec.add(terms_html([*b.scores, "ATE", "end of outage", "NEES", "x real time", "status"]))
    first = next(iter(b.truth))
    sec.figures([(lambda: plot_trajectories(b), "trajectories of the test runs with the GNSS fixes, outages marked"),
                 (lambda: plot_error_bands(b), f"run {first}: errors against the truth with each estimator's "
                  "+-3 sigma band, the GNSS fixes' errors, outages shaded"),
                 (lambda: plot_outage_errors(b), "RMS position error against the time since the outage began"),
                 (lambda: plot_nees(b), f"run {first}: pose NEES with the 95 % bounds (consistency), outages shaded")])


@_builds("diagnosis", needs=("identification", "diagnosis"))
def section_diagnosis(sec: Section, chain: ChainResult) -> None:
    """Write the diagnosis: ranked causes with gain and threshold, verdict, gain of the extension."""
    d = chain.diagnosis
    sec.note(f"Most likely cause: {d.verdict}. 5 s position error on the test runs {100 * d.before.pos_err_5s_m:.2f} "
             f"cm before, {100 * d.after.pos_err_5s_m:.2f} cm with the extended model.")
    for line in d.unexplained_notes():
        sec.note(line[0].upper() + line[1:] + ".")
    if d.extension_warning():
        sec.note(f"Warning: {d.extension_warning()}.")
    if d.missing_law_warning():
        sec.note(f"Warning: {d.missing_law_warning()}.")
    if d.outage:
        sec.note(f"EKF error at the end of {d.outage['outage_s']:g} s GNSS outages (RMS over {d.outage['n']}): "
                 f"{d.outage['before_m']:.3f} m before, {d.outage['after_m']:.3f} m after.")
    rows = [[c.name, f"{100 * c.gain:.2f}", f"{100 * c.threshold:.2f}", "yes" if c.significant else "no",
             ", ".join(f"{k} = {format_sig(v)}" for k, v in shown_estimate(c.score.estimate or {}).items())]
            for c in d.ranked]
    sec.add(table_html(["family", "test gain %", "threshold %", "significant", "estimate"], rows))
    sec.add(terms_html([*(c.name for c in d.ranked), d.verdict, "test gain", "threshold", "eta2"]))
    for f in d.measurement:
        sec.note(f"measurement finding '{f.name}' ({f.runs} runs): {f.cause}; correction: {f.correction}")
    items = [(lambda: plot_family_gains(d.ranked), "out-of-sample gain of each family against its threshold")]
    if d.structure:
        items.insert(0, (lambda: plot_residual_structure(d.structure, title="test runs: window residuals (eq. 5.56), "
                                                         "bin means +- 2 SE against each regressor"),
                         "residual structure: binned window residuals (eq. 5.56) against each regressor"))
    if d.lag:
        items.insert(1, (lambda: plot_lag_profile(d.lag), "residual-input lag correlation"))
    decay = named_profile(d.ranked)
    if decay is not None:
        items.append((lambda: plot_gain_profile(decay), "input gain over time since the run start of the named "
                       "gain decay: bins +- 2 jackknife standard deviations, their monotone fit and the linear form"))
    sec.figures(items)


SECTION_BUILDERS = {"overview": section_overview, "calibration": section_calibration,
                    "synchronisation": section_synchronisation, "poses": section_poses,
                    "identification": section_identification, "evaluation": section_evaluation,
                    "estimation": section_estimation, "diagnosis": section_diagnosis}
