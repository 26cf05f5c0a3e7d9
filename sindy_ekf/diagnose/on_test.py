"""How the extended model does on the test runs against the given one, and what to tell the user.

The extension is fitted and confirmed on the train runs; the test runs can still disagree (another day,
another ground, a robot that answers its inputs faster there), and then the user should hear it rather
than read it off two numbers. But an RMS over 5 s windows can rise for another reason: a window or two
where a prediction runs far, which outweigh every other window. On the default simulator with a floor
tilted 1.5 deg (8 minutes, `identify --quick`), the slope was estimated at 1.494 deg and the extension
was better in 30 of the 31 test windows (median 17.6 -> 2.0 cm), yet the RMS rose from 68.2 to 70.0 cm:
one window of the model itself ran to 3.66 m (3.59 m with the slope), another to 1.50 m with it. "Does
not hold on the test runs" was then the wrong thing to say; the windows that run far are what to check.

The reverse holds too: an RMS can fall through a few windows while most get worse. On the same simulator
with more lateral slip, the lateral law's extension lowered the RMS from 8.96 to 8.17 cm, better in 10 of
31 windows, the median rising from 5.38 to 7.00 cm. Said nothing, that reads as a better model; the user
should hear that its gain sits in a few windows and check what those share before relying on it.
"""

from __future__ import annotations

import numpy as np

from groundfloor.results import PredictionError
from identification.sindy.evaluate import EvaluationResult
from sindy_ekf.diagnose.extend import common_windows


def errors_5s(before: EvaluationResult, after: EvaluationResult) -> tuple[PredictionError, PredictionError]:
    """Return the 5 s RMS errors of two evaluations over the windows where neither diverged.

    A model that leaves its envelope may blow up in a few windows (``inf``); comparing on the
    common finite windows keeps the numbers meaningful (:func:`sindy_ekf.diagnose.pipeline.n_diverged` says how
    many each left out).
    """
    ok = common_windows(before, after)
    return tuple(PredictionError(
        pos_err_5s_m=float(np.sqrt(np.mean(r.eps_p[ok, -1] ** 2))) if ok.any() else float("nan"),
        yaw_err_5s_deg=float(np.degrees(np.sqrt(np.mean(r.eps_h[ok, -1] ** 2)))) if ok.any() else float("nan"),
        n_windows=int(ok.sum())) for r in (before, after))


def extension_on_test(before: EvaluationResult, after: EvaluationResult) -> dict:
    """Return ``{lowers, windows_better, n_windows, median_5s_m, most_worsened_5s_m, most_improved_5s_m}`` of the
    extension ``after`` against the model ``before`` on the test runs' 5 s windows where neither prediction diverged.

    ``lowers``: its RMS position error at 5 s is the smaller; ``windows_better``: in how many of the
    ``n_windows`` its error is smaller; ``median_5s_m``: ``[model, extension]``; ``most_worsened_5s_m``: the
    window whose error the extension raises the most, ``[model, extension]`` there (None when it raises none);
    ``most_improved_5s_m``: the same for the window it lowers the most.
    """
    ok = common_windows(before, after)
    b, a = before.eps_p[ok, -1], after.eps_p[ok, -1]
    rms = [e.pos_err_5s_m for e in errors_5s(before, after)]
    k = int(np.argmax(a - b)) if a.size else -1
    j = int(np.argmin(a - b)) if a.size else -1
    return {"lowers": bool(rms[1] < rms[0]), "windows_better": int(np.count_nonzero(a < b)), "n_windows": int(ok.sum()),
            "median_5s_m": [float(np.median(v)) if v.size else float("nan") for v in (b, a)],
            "most_worsened_5s_m": [float(b[k]), float(a[k])] if k >= 0 and a[k] > b[k] else None,
            "most_improved_5s_m": [float(b[j]), float(a[j])] if j >= 0 and a[j] < b[j] else None}


def extension_warning(e: dict | None, verdict: str, before_m: float, after_m: float) -> str | None:
    """Return one line when the extension predicts the test runs worse (RMS at 5 s) or worse in most windows,
    or None.

    When its RMS is the larger but it is better in most windows and in the median, the RMS is carried by
    the few windows that run far, and the line says so; otherwise the mechanism the train runs show does
    not hold on the test runs. When its RMS is the smaller but it is worse in most windows and in the
    median, its gain sits in a few windows, and the line says that.
    """
    if e is None:
        return None
    med = e["median_5s_m"]
    if e["lowers"]:
        if not (e["windows_better"] < e["n_windows"] / 2 and med[1] > med[0]):
            return None
        best = e["most_improved_5s_m"]
        return (f"the extended model lowers the 5 s position error ({100 * before_m:.2f} -> {100 * after_m:.2f} cm) "
                f"but predicts most test windows worse (better in {e['windows_better']} of {e['n_windows']}, median "
                f"{100 * med[0]:.2f} -> {100 * med[1]:.2f} cm): its gain sits in the few windows it improves (the "
                f"best {best[0]:.2f} -> {best[1]:.2f} m); check what those windows share (a state, a place, a run) "
                f"before relying on the {verdict} extension elsewhere")
    head = (f"the extended model predicts the test runs worse (5 s position error {100 * before_m:.2f} -> "
            f"{100 * after_m:.2f} cm, better in {e['windows_better']} of {e['n_windows']} windows)")
    worst = e["most_worsened_5s_m"]
    if e["windows_better"] > e["n_windows"] / 2 and med[1] < med[0]:
        return (f"{head}, but better in most windows (median {100 * med[0]:.2f} -> {100 * med[1]:.2f} cm): the RMS is "
                f"carried by the few it predicts worse, where a prediction runs far (the worst {worst[0]:.2f} -> "
                f"{worst[1]:.2f} m); check those windows (states outside the model's envelope?) before using the "
                "extended model")
    return (f"{head}: the {verdict} the train runs show does not hold on the test runs as fitted; check that both "
            f"were recorded under the same conditions (day, ground, robot) before using the extended model")
