"""Evaluation stage: the 5 s prediction error of a model, the baselines and the oracle on the test runs.

Thesis section 5.3.8: 5 s windows with 50 % overlap on the test runs, RMS over the windows at
5 s (eqs. 5.76 to 5.78). Scoring does not depend on the candidate (``docs/identification.md``):
every model starts from the same start states, the test runs' reference states
(:mod:`identification.sindy.reference`, the discrepancy-principle smoothing chosen from the
data's own noise, not the model's ``s``), and is compared with the measured poses. Beside the
identified model (``sindy``) the same windows score the constant-velocity and kinematic unicycle
baselines (gains fitted on the train runs), the ``lag`` baseline (first-order lag per axis with
input dead time, output-error fit on the train runs: the hand-written model to beat) and, on a
simulated campaign, the simulator's true dynamics (``oracle``: the best any model can do).

Beside the test score: the model's cross-validation estimate from its file (with a warning when
the test score lies outside the 95 % prediction interval the CV folds give for one more group) and
the sensitivity of the score to the
start-state smoothing (the same windows started from states at the reference smoothing x 0.1 and
x 10). ``sindy-ekf evaluate`` prints and writes :meth:`Evaluation.to_json`; the report's chain
keeps the RK4 results for its figures.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np
from scipy.stats import t as student_t

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from groundfloor.numbers import finite_or_none
from groundfloor.results import PredictionError
from groundfloor.types import BodyStates, InputSeries, TrajectoryCampaign, TrajectoryRun
from identification.preprocessing.campaigns import open_campaign, train_campaign_of
from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel, fit_lag
from identification.sindy.checks import require_checks_passed
from identification.sindy.data import states_of_runs
from identification.sindy.evaluate import EvaluationResult, evaluate_model
from identification.sindy.model import SindyModel
from identification.sindy.reference import REFERENCE_SMOOTHING, Reference, reference
from simulation.robot import TrueDynamics
from simulation.truth import true_dynamics_of

log = logging.getLogger(__name__)

MODEL = "sindy"
ORACLE = "oracle"
MOTOR_INPUT_DT_S = 0.005  # sampling of the motor inputs handed to the oracle (a tenth of the 50 Hz step)


LAG = "lag"
#: start-state smoothings of the sensitivity check, as multiples of the reference smoothing
SENSITIVITY_FACTORS = (0.1, 10.0)


def prediction_error(evaluation: EvaluationResult) -> PredictionError:
    """Return the 5 s triple (``pos_err_5s_m``, ``yaw_err_5s_deg``, ``n_windows``) of an evaluation."""
    return PredictionError(evaluation.pos_err_5s_m, evaluation.yaw_err_5s_deg, int(evaluation.n_windows))


def model_smoothing(model: SindyModel) -> float:
    """Return the spline smoothing ``s`` the model was identified at (0 when it does not say)."""
    s = model.hyperparameters.get("s")
    return 0.0 if s is None else float(s)


#: probability that the test runs' 5 s error falls inside the interval of :attr:`CvComparison.interval_m`
#: when they are one more group like the train groups (the warning's false-alarm rate is one minus it)
CV_PREDICTION_LEVEL = 0.95


@dataclass(frozen=True)
class CvComparison:
    """The model's cross-validation estimate (from its file) beside its test score."""

    cv_pos_err_5s_m: float
    spread_m: float  # standard deviation of the fold errors (nan with fewer than two folds)
    test_pos_err_5s_m: float
    kind: str  # how the folds were made ("leave-one-group-out", ...)
    n_folds: int = 0

    @property
    def interval_m(self) -> float:
        """Return the half-width of the prediction interval of one more held-out group's 5 s error,
        ``t_((1 + p) / 2, k - 1) s sqrt(1 + 1 / k)`` for ``k`` folds of standard deviation ``s`` at
        :data:`CV_PREDICTION_LEVEL` ``p`` (nan with fewer than two folds).

        The test score is itself one draw: a new group like the train groups lies further than one
        fold standard deviation from the folds' mean in 41 to 48 % of cases with 3 to 5 folds (the
        rule this replaces), and further than this half-width in 5 %.
        """
        k = self.n_folds
        if k < 2 or not np.isfinite(self.spread_m):
            return float("nan")
        return float(student_t.ppf(0.5 + 0.5 * CV_PREDICTION_LEVEL, k - 1) * self.spread_m * np.sqrt(1.0 + 1.0 / k))

    @property
    def disagree(self) -> bool:
        """Return whether the test score lies outside the prediction interval of :attr:`interval_m`."""
        return bool(np.isfinite(self.interval_m)
                    and abs(self.test_pos_err_5s_m - self.cv_pos_err_5s_m) > self.interval_m)

    def to_json(self) -> dict:
        """Return ``{"pos_err_5s_m", "spread_m", "n_folds", "interval_m", "level", "kind", "disagrees"}``."""
        return {"pos_err_5s_m": self.cv_pos_err_5s_m, "spread_m": finite_or_none(self.spread_m),
                "n_folds": self.n_folds, "interval_m": finite_or_none(self.interval_m), "level": CV_PREDICTION_LEVEL,
                "kind": self.kind,
                "disagrees": self.disagree}


def cv_comparison(model: SindyModel, test_pos_err_5s_m: float) -> CvComparison | None:
    """Return the model file's CV estimate beside the test score (None when the file has none).

    The spread is the standard deviation of the per-fold errors: the test runs are one more
    held-out group, so their score should fall within the prediction interval the folds give
    (:attr:`CvComparison.interval_m`).
    """
    cv = model.training.get("cv") or {}
    if not isinstance(cv, dict) or cv.get("pos_err_5s_m") is None:
        return None
    folds = np.asarray([v for v in cv.get("fold_pos_err_5s_m") or () if v is not None], float)
    folds = folds[np.isfinite(folds)]
    spread = float(np.std(folds, ddof=1)) if len(folds) >= 2 else float("nan")
    return CvComparison(float(cv["pos_err_5s_m"]), spread, float(test_pos_err_5s_m), str(cv.get("kind", "")),
                        len(folds))


@dataclass(frozen=True)
class Evaluation:
    """The evaluation of a model beside the baselines (and the oracle) on one campaign's test runs."""

    campaign: str  # the campaign's name
    n_test_runs: int
    results: dict[str, dict[str, EvaluationResult]]  # model name -> integration method -> result
    train_states: list[BodyStates]  # the train runs' segments at the model's smoothing
    reference_smoothing: float = REFERENCE_SMOOTHING
    cv: CvComparison | None = None
    # start-state smoothing -> model name -> 5 s position error on the same windows (sensitivity)
    sensitivity: dict[float, dict[str, float]] = field(default_factory=dict)

    @property
    def model(self) -> EvaluationResult:
        """The identified model's RK4 evaluation."""
        return self.results[MODEL]["rk4"]

    @property
    def beats_lag(self) -> bool | None:
        """Return whether the model's 5 s position error is below the lag baseline's (None without it)."""
        if LAG not in self.results:
            return None
        return self.model.pos_err_5s_m < self.results[LAG]["rk4"].pos_err_5s_m

    def errors(self, method: str = "rk4") -> dict[str, PredictionError]:
        """Return each model's 5 s errors with ``method`` (the models evaluated with it)."""
        return {n: prediction_error(r[method]) for n, r in self.results.items() if method in r}

    def to_json(self) -> dict:
        """Return the ``evaluate --json`` content: the model's triple, then ``euler2``, ``baselines``
        and (simulated campaigns) ``oracle`` with the same keys (INTERFACES.md); then the
        reference smoothing of the start states, ``start_state_sensitivity`` and (model files
        with a CV estimate) ``cv``."""
        rk4 = self.errors("rk4")
        out = rk4[MODEL].to_json()
        if "euler2" in self.results[MODEL]:
            out["euler2"] = prediction_error(self.results[MODEL]["euler2"]).to_json()
        out["baselines"] = {n: e.to_json() for n, e in rk4.items() if n not in (MODEL, ORACLE)}
        if ORACLE in rk4:
            out[ORACLE] = rk4[ORACLE].to_json()
        out["reference_smoothing"] = self.reference_smoothing
        out["start_state_sensitivity"] = {"smoothing": list(self.sensitivity),
                                          "pos_err_5s_m": {n: [self.sensitivity[s][n] for s in self.sensitivity]
                                                           for n in (MODEL, LAG) if n in rk4}}
        if self.beats_lag is not None:
            out["beats_lag"] = self.beats_lag
        if self.cv is not None:
            out["cv"] = self.cv.to_json()
        return out


def _score(models: dict[str, Dynamics], windows, methods=("rk4",)) -> dict[str, dict[str, EvaluationResult]]:
    """Return ``{name: {method: result}}`` of ``models`` on ``windows`` (every method for the
    identified model, RK4 for the others)."""
    return {name: {m: evaluate_model(model, windows, method=m, name=name)
                   for m in (methods if name == MODEL else ("rk4",))} for name, model in models.items()}


def evaluation_stage(campaign: TrajectoryCampaign, model: SindyModel, oracle: Dynamics | None = None,
                     methods: tuple[str, ...] = ("rk4",), train_runs=None) -> Evaluation:
    """Return the model, the baselines and ``oracle`` (when given) evaluated on the test runs.

    Every model sees the same windows of the test runs' reference states (start states) and
    measured poses (truth); the unicycle and the lag are fitted on the train runs (``train_runs``,
    default the campaign's own; left out, with a warning, without any). ``methods`` are
    integration methods of :func:`identification.sindy.evaluate.rollout` for the identified model
    (the others RK4).
    """
    models: dict[str, Dynamics] = {MODEL: model, "constant_velocity": ConstantVelocityModel()}
    train = campaign.split("train") if train_runs is None else tuple(train_runs)
    if not train:
        log.warning("%s: no train run to fit the unicycle and lag baselines on: they are left out (give "
                    "--train CAMPAIGN, e.g. the campaign the model was identified on)", campaign.name)
    test = campaign.split("test")
    train_states = states_of_runs(train, model_smoothing(model))[0] if train else []
    if train:
        train_ref = reference(train)
        models["unicycle"] = UnicycleModel().fit(train_ref.states)
        models[LAG] = fit_lag(train_ref)
    test_ref = reference(test)
    for name, m in models.items():
        m.warn_outside_envelope(*_six_states(test_ref), name=f"test runs ({name})")
    results = _score(models, test_ref.windows(), methods)
    if oracle is not None:  # the same windows and start states (from the poses), its own inputs
        driven = [as_driven(run, oracle) for run in test] if isinstance(oracle, TrueDynamics) else test
        results[ORACLE] = _score({ORACLE: oracle}, reference(driven).windows(), methods)[ORACLE]
    sensitivity = {REFERENCE_SMOOTHING: {n: results[n]["rk4"].pos_err_5s_m for n in (MODEL, LAG) if n in results}}
    for factor in SENSITIVITY_FACTORS:
        s = REFERENCE_SMOOTHING * factor
        windows = reference(test, s).windows()
        sensitivity[s] = {n: evaluate_model(models[n], windows, name=n).pos_err_5s_m for n in (MODEL, LAG)
                          if n in models}
    sensitivity = dict(sorted(sensitivity.items()))
    cv = cv_comparison(model, results[MODEL]["rk4"].pos_err_5s_m)
    if cv is not None and cv.disagree:
        log.warning("the test score (%.3f m) lies outside the %.0f %% prediction interval of the model's "
                    "cross-validation estimate (%.3f +- %.3f m from %d folds): the test runs are not like the "
                    "train groups", cv.test_pos_err_5s_m, 100 * CV_PREDICTION_LEVEL, cv.cv_pos_err_5s_m,
                    cv.interval_m, cv.n_folds)
    ev = Evaluation(campaign.name, len(test), results, train_states, REFERENCE_SMOOTHING, cv, sensitivity)
    if ev.beats_lag is False:
        log.warning("the identified model (%.3f m) does not beat the lag baseline (%.3f m) on the test runs",
                    ev.model.pos_err_5s_m, results[LAG]["rk4"].pos_err_5s_m)
    return ev


def _six_states(ref: Reference) -> tuple[np.ndarray, np.ndarray]:
    """Return the six states ``(n, 6)`` and inputs ``(n, 2)`` of all samples of ``ref``."""
    x6 = np.vstack([np.column_stack([st.x, st.y, st.yaw, st.vx, st.vy, st.omega]) for st in ref.states])
    return x6, np.vstack([st.inputs for st in ref.states])


def as_driven(run: TrajectoryRun, oracle: TrueDynamics) -> TrajectoryRun:
    """Return ``run`` with its recorded inputs replaced by what the oracle's motors saw.

    The motor inputs are sampled every ``MOTOR_INPUT_DT_S`` over the run's poses, time counted
    from the run's first pose (as the benchmark does). A run is returned unchanged when the
    motors saw exactly the recorded inputs (no motor lag, no input-side effect).
    """
    t0 = float(run.poses.t[0])
    t_joy = np.asarray(run.inputs.t, float) - t0
    u_joy = np.column_stack([run.inputs.u1, run.inputs.u2])
    if np.allclose(oracle.motor_inputs(t_joy, t_joy, u_joy), u_joy, rtol=0.0, atol=1e-12):
        return run
    t = np.arange(0.0, float(run.poses.t[-1]) - t0 + MOTOR_INPUT_DT_S, MOTOR_INPUT_DT_S)
    u = oracle.motor_inputs(t, t_joy, u_joy)
    return replace(run, inputs=InputSeries(t=t + t0, u1=u[:, 0], u2=u[:, 1]))


def evaluate_files(campaign: str | Path, model_path: str | Path,
                   methods: tuple[str, ...] = ("rk4", "euler2"), train: str | Path | None = None) -> Evaluation:
    """Return the evaluation of the model file on a campaign (``sindy-ekf evaluate``).

    A tracker campaign is preprocessed first (cached); on a simulated campaign the simulator's
    true dynamics (:func:`simulation.truth.true_dynamics_of`) are scored beside the model.
    ``train``: the campaign whose train runs fit the baselines (default ``campaign``'s own).

    Raises
    ------
    InputError
        Unreadable model, a model whose recorded well-posedness checks failed, not a campaign,
        or no run marked ``test``.
    """
    model = SindyModel.load(model_path)
    require_checks_passed(model, str(model_path))
    traj = open_campaign(campaign)
    if not traj.split("test"):
        raise InputError(f"{campaign}: campaign.yaml marks no run as test")
    train_campaign = train_campaign_of(train)
    return evaluation_stage(traj, model, true_dynamics_of(campaign), methods,
                            None if train_campaign is None else train_campaign.split("train"))
