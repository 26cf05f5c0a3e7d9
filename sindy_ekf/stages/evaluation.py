"""Evaluation stage: the 5 s prediction error of a model, the baselines and the oracle on the test runs.

Thesis section 5.3.8: 5 s windows with 50 % overlap on the test runs, RMS over the windows at
5 s (eqs. 5.76 to 5.78). Beside the identified model (``sindy``) the same windows score, from the
same start states, the constant-velocity and unicycle baselines (the unicycle's gains fitted on
the train runs) and, on a simulated campaign, the simulator's true dynamics (``oracle``: the
best any model can do). ``sindy-ekf evaluate`` prints and writes :meth:`Evaluation.to_json`;
the report's chain keeps the RK4 results for its figures.
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from groundfloor.results import PredictionError
from groundfloor.types import BodyStates, InputSeries, TrajectoryCampaign, TrajectoryRun
from identification.preprocessing.campaigns import open_campaign
from identification.sindy.baselines import ConstantVelocityModel, UnicycleModel
from identification.sindy.data import states_of_runs
from identification.sindy.evaluate import EvaluationResult, evaluate_on_runs
from identification.sindy.model import SindyModel
from simulation.robot import TrueDynamics
from simulation.truth import true_dynamics_of

MODEL = "sindy"
ORACLE = "oracle"
MOTOR_INPUT_DT_S = 0.005  # sampling of the motor inputs handed to the oracle (a tenth of the 50 Hz step)


def prediction_error(evaluation: EvaluationResult) -> PredictionError:
    """Return the 5 s triple (``pos_err_5s_m``, ``yaw_err_5s_deg``, ``n_windows``) of an evaluation."""
    return PredictionError(evaluation.pos_err_5s_m, evaluation.yaw_err_5s_deg, int(evaluation.n_windows))


def model_smoothing(model: SindyModel) -> float:
    """Return the spline smoothing ``s`` the model was identified at (0 when it does not say)."""
    s = model.hyperparameters.get("s")
    return 0.0 if s is None else float(s)


@dataclass(frozen=True)
class Evaluation:
    """The evaluation of a model beside the baselines (and the oracle) on one campaign's test runs."""

    campaign: str  # the campaign's name
    n_test_runs: int
    results: dict[str, dict[str, EvaluationResult]]  # model name -> integration method -> result
    train_states: list[BodyStates]  # the train runs' segments at the model's smoothing

    @property
    def model(self) -> EvaluationResult:
        """The identified model's RK4 evaluation."""
        return self.results[MODEL]["rk4"]

    def errors(self, method: str = "rk4") -> dict[str, PredictionError]:
        """Return each model's 5 s errors with ``method`` (the models evaluated with it)."""
        return {n: prediction_error(r[method]) for n, r in self.results.items() if method in r}

    def to_json(self) -> dict:
        """Return the ``evaluate --json`` content: the model's triple, then ``euler2``, ``baselines``
        and (simulated campaigns) ``oracle`` with the same keys (INTERFACES.md)."""
        rk4 = self.errors("rk4")
        out = rk4[MODEL].to_json()
        if "euler2" in self.results[MODEL]:
            out["euler2"] = prediction_error(self.results[MODEL]["euler2"]).to_json()
        out["baselines"] = {n: e.to_json() for n, e in rk4.items() if n not in (MODEL, ORACLE)}
        if ORACLE in rk4:
            out[ORACLE] = rk4[ORACLE].to_json()
        return out


def evaluation_stage(campaign: TrajectoryCampaign, model: SindyModel, oracle: Dynamics | None = None,
                     methods: tuple[str, ...] = ("rk4",)) -> Evaluation:
    """Return the model, the baselines and ``oracle`` (when given) evaluated on the test runs.

    Every model sees the same windows of the test runs' body states at the model's smoothing
    ``s``; the unicycle is fitted on the train runs' (left out without train runs). ``methods``
    are integration methods of :func:`identification.sindy.evaluate.evaluate_on_runs`.
    """
    s = model_smoothing(model)
    models: dict[str, Dynamics] = {MODEL: model, "constant_velocity": ConstantVelocityModel()}
    train = campaign.split("train")
    train_states = states_of_runs(train, s)[0] if train else []
    if train_states:
        models["unicycle"] = UnicycleModel().fit(train_states)
    test = campaign.split("test")
    results = evaluate_on_runs(models, test, s, methods=methods)
    if oracle is not None:  # same windows and start states (from the poses), its own inputs
        driven = [as_driven(run, oracle) for run in test] if isinstance(oracle, TrueDynamics) else test
        results[ORACLE] = evaluate_on_runs({ORACLE: oracle}, driven, s, methods=methods)[ORACLE]
    return Evaluation(campaign.name, len(campaign.split("test")), results, train_states)


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
                   methods: tuple[str, ...] = ("rk4", "euler2")) -> Evaluation:
    """Return the evaluation of the model file on a campaign (``sindy-ekf evaluate``).

    A tracker campaign is preprocessed first (cached); on a simulated campaign the simulator's
    true dynamics (:func:`simulation.truth.true_dynamics_of`) are scored beside the model.

    Raises
    ------
    InputError
        Unreadable model, not a campaign, or no run marked ``test``.
    """
    model = SindyModel.load(model_path)
    traj = open_campaign(campaign)
    if not traj.split("test"):
        raise InputError(f"{campaign}: campaign.yaml marks no run as test")
    return evaluation_stage(traj, model, true_dynamics_of(campaign), methods)
