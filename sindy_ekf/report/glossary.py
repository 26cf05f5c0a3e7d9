"""What the report's names mean: every model, estimator and term explained once, where it first appears.

Each section lists the names it uses under its table (:func:`terms_html`); a name that has no
entry here is a test failure (``tests/sindy_ekf/report``), so a new estimator or family cannot
reach the report unexplained.
"""

from __future__ import annotations

import html

# the models scored in the evaluation section (keys of identification's evaluation)
MODELS = {
    "sindy": "the identified SINDy model: sparse polynomial dynamics of (vx, vy, omega) from integral SINDy "
             "(eqs. 5.55 to 5.59), integrated with RK4 through eq. 5.75",
    "constant_velocity": "baseline: the body velocities stay at their values at the start of the window",
    "unicycle": "baseline: a kinematic unicycle, vx = k1 u1 and omega = k2 u2 with the gains fitted on the train runs, "
                "no lateral velocity",
    "lag": "baseline, the hand-written model to beat: a first-order lag per axis toward gain x input with an input "
           "dead time (6 parameters, output-error fit on the train runs, DRIVE-style)",
    "oracle": "the simulator's true dynamics (only on a simulated campaign): the best any model can do from the same "
              "start states; the gap between sindy and oracle is what identification leaves on the table",
}

# the estimators of the benchmark (sindy_ekf.benchmark.run.ESTIMATORS)
ESTIMATORS = {
    "dead_reckoning": "the SINDy model integrated from the initial state, no GNSS at all: how far the model alone goes",
    "cv_ekf": "EKF with a constant-velocity process model (the inputs unused)",
    "unicycle_ekf": "EKF with the kinematic unicycle: vx and omega are the inputs times gains fitted on the train runs",
    "lag_ekf": "EKF with the lag baseline, the hand-written model to beat: vx and omega follow the inputs with one "
               "gain, one time constant and one input dead time each, fitted by output error on the train runs",
    "sindy_ekf": "EKF with the identified SINDy model as process model",
    "sindy_ekf_lateral": "sindy_ekf plus the pseudo-measurement v_y = 0 of a skid-steered robot (5 Hz)",
    "oracle_ekf": "EKF with the simulator's true dynamics as process model (simulated campaigns only): the reference "
                  "sindy_ekf is measured against",
    "sindy_graph": "factor graph (gtsam) over the whole run with the SINDy model between states, smoothed in one batch "
                   "(uses the fixes after each instant too, unlike a filter)",
    "sindy_graph_lateral": "sindy_graph plus v_y = 0 factors",
    "sindy_isam2": "the same factor graph solved incrementally by iSAM2 with a 3 s fixed lag (real time)",
}

TERMS = {
    # calibration and synchronisation
    "s0^2": "a-posteriori variance factor of an adjustment, v^T P v / dof: 1 when the a-priori standard deviations "
            "are right; its global test compares dof s0^2 with a chi-square distribution (two-sided, 95 %)",
    "dof": "degrees of freedom (redundancy) of an adjustment: observations minus unknowns",
    "normalised residual": "a residual divided by its own standard deviation; N(0, 1) without a blunder",
    "leave-one-out T": "the point compared with the transform fitted without it, T ~ chi2(3) without a blunder; the "
                       "largest is tested against its Bonferroni-corrected 0.1 % level",
    "drift": "clock rate error of a tracker against the trigger, (k - 1) 10^6 ppm (eqs. 5.10 to 5.12)",
    "r before / after": "correlation of the baseline length with the forward speed before and after the extra offset: "
                        "a late tracker makes the baseline depend on the speed",
    "hub r1/r2": "radii of the prisms' circles about the turning hubs' axes (eq. 5.25)",
    # identification
    "s": "smoothing factor of the spline through the poses (eq. 5.68)",
    "tau": "length of the integration windows of integral SINDy, s",
    "alpha": "ridge regularisation of the sparse regression (normalised columns)",
    "T": "sequential thresholding: the smallest share of its equation's signal a term must carry to stay",
    "CV": "cross-validated: each model fitted without one fold of train runs and scored on it, RMS over the folds",
    "diverged": "share of the held-out 5 s predictions that left three times the training velocities or became "
                "non-finite; one such window makes the RMS error infinite (inf)",
    # estimation
    "ATE": "absolute trajectory error: RMS over every test-run pose of the estimate minus the laser-tracker pose, no "
           "alignment (both in the local frame)",
    "end of outage": "RMS over the outages of one length of the position error at the instant GNSS returns; each "
                     "estimator enters the outage from its own state",
    "NEES": "normalised estimation error squared of (x, y, heading): the error weighted by the estimator's own "
            "covariance, chi2(3) for a consistent estimator (mean 3)",
    "NIS": "normalised innovation squared of the accepted fixes, chi2(2) for a consistent filter",
    "x real time": "seconds of data processed per second of computing",
    "status": "how the estimator ended: ok, diverged (its innovations stayed beyond their chi-square bound, or its "
              "state became non-finite) or failed (it raised an error), at the time given; it is scored up to there. "
              "re-init counts re-initialisations from the next fix after an NIS alarm, covariance repairs the "
              "covariances that lost positive definiteness and had their eigenvalues clipped",
    # diagnosis
    "test gain": "how much the family, fitted on the train runs, lowers the weighted residual sum of squares of the "
                 "test runs; a family counts only above its threshold",
    "threshold": "the largest gain the family reaches on effect-free campaigns, twice (bench/results/diagnose.md)",
    "eta2": "share of the residual variance that the bins of one regressor explain (correlation ratio)",
}

# the diagnosis's families (sindy_ekf.diagnose.families.FAMILIES) and its verdicts "none" and "unexplained"
FAMILIES = {
    "input_delay": "the motors act on the inputs a constant time late",
    "heading_dependence": "an acceleration that depends on the heading (a sloped floor)",
    "position_dependence": "a patch of the floor where the robot is damped (different ground)",
    "time_dependence": "the response to the inputs changes over the campaign (battery, warming up)",
    "asymmetry": "one track side stronger than the other",
    "deadband": "small inputs do not move the robot",
    "lateral_slip": "lateral slip the model's vy equation lacks",
    "none": "no family passes its threshold and the residuals hold no structure: nothing is worth a model change",
    "unexplained": "no family passes its threshold, but the residuals hold structure out of sample against one "
                   "regressor (eta2 above its calibrated threshold): a mechanism the diagnosis does not know; or the "
                   "model's own terms, re-identified on the train runs, predict far better (and better beyond chance "
                   "than the extension of a family that passes): its coefficients do not hold on this campaign "
                   "(another ground, another robot state)",
}

GLOSSARIES = (MODELS, ESTIMATORS, TERMS, FAMILIES)


def meaning(name: str) -> str:
    """Return what ``name`` means; KeyError when the report would show it unexplained."""
    for table in GLOSSARIES:
        if name in table:
            return table[name]
    raise KeyError(f"report glossary: no explanation of {name!r}")


def terms_html(names) -> str:
    """Return a definition list explaining ``names`` (each once, in the order given)."""
    seen = list(dict.fromkeys(names))
    items = "".join(f"<dt>{html.escape(n)}</dt><dd>{html.escape(meaning(n))}</dd>" for n in seen)
    return f'<dl class="terms">{items}</dl>'
