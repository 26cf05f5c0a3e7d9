"""Reference models for the diagnosis tests and bench, identified on short simulated campaigns.

The campaigns themselves (simulator -> 50 Hz BodyStates, no bags) are library functionality:
:mod:`simulation.short_campaign`.
"""

from __future__ import annotations

import functools

import numpy as np

from identification.preprocessing.campaigns import open_campaign
from identification.sindy.data import states_of_runs
from identification.sindy.reference import delayed_inputs
from identification.sindy.regression import fit_sindy
from simulation.short_campaign import simulate_states_campaign
from simulation.variants import draw_variant
from sindy_ekf.diagnose.data import model_split, split_from_states
from sindy_ekf.diagnose.design import gain_recalibrated
from sindy_ekf.diagnose.extend import ExtendedModel, reidentify
from sindy_ekf.diagnose.families import mechanism_spec
from sindy_ekf.diagnose.fitting import FamilyScore, equation_weights, score_family
from sindy_ekf.diagnose.lateral import with_settled_drift
from sindy_ekf.diagnose.pipeline import load_model


def fit_reference_model(seed: int = 12345, n_runs: int = 6, run_s: float = 60.0):
    """Return a SINDy model (poly3, tau 2 s) identified on an effect-free simulated campaign."""
    train, test, a, b = simulate_states_campaign(seed, None, n_train=n_runs, n_test=0, run_s=run_s)
    return fit_sindy(train, "poly3", tau=2.0, alpha=1.0, threshold=0.2, names=a)


def fit_lab_model(train, names, variant: int | None = None):
    """Return a SINDy model (poly3, tau 2 s) of ``train`` that knows the variant's motor lag.

    A simulator variant's motors follow the inputs through a first-order lag (0.05 to 0.3 s,
    ``simulation.variants``); the lab's model carries it as its input lag, as `identify` identifies
    one (issue 13). A model blind to it is rightly diagnosed ``input_delay`` on every variant.
    """
    lag = draw_variant(variant).motor_lag_s if variant else 0.0
    seen = delayed_inputs(train, (0.0, 0.0), (lag, lag)) if lag else train
    model = fit_sindy(seen, "poly3", tau=2.0, alpha=1.0, threshold=0.2, names=names)
    return model.with_coefficients(model.coef, input_lag_s=(lag, lag)) if lag else model


def fit_reference_with_lateral_law(seed: int = 12345, n_runs: int = 6, run_s: float = 60.0, rate_hz: float = 50.0,
                                   variant: int | None = None):
    """Return the reference model with a lateral law: identified, then extended by ``lateral_slip``.

    Integral SINDy cannot separate the lateral damping from the coupling (vy settles within
    0.07 s), so the identified lateral equation is empty (as the thesis's eq. 7.8); a model
    without one is, rightly, always diagnosed with ``lateral_slip``. The lab's model here is the
    identified one after that first diagnosis: the lateral law re-identified with the mechanism, then
    settled as the extension ``diagnose`` writes (:func:`settled_lateral_law`; the regression's damping
    alone was 0.1 to 4 1/s on variants 21 to 30, whose lateral velocity settles at 11 to 19 1/s).
    ``variant``: the simulator variant whose effect-free campaign the model is identified on.
    """
    train, _, names, _ = simulate_states_campaign(seed, None, n_train=n_runs, n_test=0, run_s=run_s,
                                                  rate_hz=rate_hz, variant=variant)
    model = fit_lab_model(train, names, variant)
    lag = model.input_lag_s
    split = split_from_states(delayed_inputs(train, (0.0, 0.0), lag) if any(lag) else train, names, 2.0)
    out = reidentify(model, "lateral_slip", [], split, equation_weights(model, split)).as_sindy()
    settled = settled_lateral_law(out, split)
    return settled.with_coefficients(settled.coef, input_lag_s=model.input_lag_s)


def settled_lateral_law(model, split):
    """Return ``model`` with its lateral law as ``diagnose`` writes a lateral_slip extension: its ``vx omega``
    coupling anchored at the drift the runs ``split`` show in turns and the whole ``vy`` equation on the time
    scale the measured ``vy`` settles on (:func:`sindy_ekf.diagnose.lateral.with_settled_drift`, the law added
    with nothing, ``beta = 0``). The forward and yaw equations were identified on these runs: they keep what
    they see (no ``vy_scale``)."""
    score = FamilyScore("lateral_slip", np.zeros(0), np.zeros(2), 0.0, {}, 0.0, {"model_has_lateral_law": True})
    est = with_settled_drift(score, model, split)
    ext = ExtendedModel(model, "lateral_slip", np.zeros(0), est.beta, vy_rate=est.estimate.get("settling_scale", 1.0))
    return ext.as_sindy()


@functools.lru_cache(maxsize=None)
def variant_reference(variant: int, run_s: float = 45.0, rate_hz: float = 25.0):
    """Return the lab model of simulator variant ``variant`` (cached per process): identified, with the
    variant's motor lag, on an effect-free campaign of 4 runs of ``run_s`` at ``rate_hz``."""
    return fit_reference_with_lateral_law(n_runs=4, run_s=run_s, rate_hz=rate_hz, variant=variant)


def own_coupling(campaign, model_path) -> float:
    """Return the throttle-to-turn coupling a clean campaign's train runs hold relative to the model in
    ``model_path``, scored as the diagnosis scores it (the model with its input gains fitted on the train
    runs, the gain nuisance, the model kept fixed): what an injected coupling adds to."""
    model = load_model(model_path)
    return _coupling_of(model, open_campaign(campaign).split("train"))


def own_coupling_per_run(campaign, model_path) -> list[tuple[str, str, float]]:
    """Return ``(run, split, coupling)`` per run of a clean campaign: :func:`own_coupling` of each run
    alone (its gains fitted on that run). How much a robot's own coupling varies from run to run is
    what an injected coupling has to stand out of when it is scored on other runs than it was fitted on."""
    model = load_model(model_path)
    camp = open_campaign(campaign)
    return [(r.name, split, _coupling_of(model, [r])) for split in ("train", "test") for r in camp.split(split)]


def own_gain_profile(campaign, model_path) -> dict | None:
    """Return the gain profile (:func:`sindy_ekf.diagnose.gain_profile.gain_profile`) of a clean campaign's
    train runs relative to the model in ``model_path``, as the diagnosis computes it for a named decay:
    the robot's own gain over time since the run start, which an injected decay multiplies."""
    from sindy_ekf.diagnose.gain_profile import gain_profile

    null, tr, w = _null_split(load_model(model_path), open_campaign(campaign).split("train"))
    return gain_profile(null, tr, w)


def _null_split(model, runs):
    """Return ``(null, split, weights)`` of ``runs`` as the diagnosis scores the input-side families:
    the model with its input gains fitted on the runs, the runs' windows and the equation weights."""
    st, names, _ = states_of_runs(runs, float(model.hyperparameters.get("s") or 0.0))
    tr = model_split(model, st, names, float(model.hyperparameters.get("tau") or 2.0))
    w = equation_weights(model, tr)
    return gain_recalibrated(model, tr, w)[0], tr, w


def _coupling_of(model, runs) -> float:
    null, tr, w = _null_split(model, runs)
    spec = mechanism_spec("asymmetry", "throttle_to_turn_coupling")
    return float(score_family(spec, null, tr, tr, w, uncertainty=False, refit=False).estimate["coupling"])
