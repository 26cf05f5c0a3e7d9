"""Find an effect hidden in driving data that the identified model does not know about.

Problem: a SINDy model of the Husky's body dynamics (thesis eqs. 5.53, 7.7 to 7.9) was
identified on an effect-free campaign. New runs were recorded, and something has changed: the
motors might see the inputs late, the floor might be tilted, a carpet might brake the robot in
one place, the battery might sag, the tracks might be unbalanced, the controller might have a
deadband, or the tyres might slip more sideways. Which is it, how large, and how much better
does the model predict once it knows?

Model: the diagnosis keeps the model fixed and tries one physical mechanism per family (an
input transform such as ``u(t - d)``, or additive columns such as ``g sin(tilt) cos(psi)``),
fitted on the new train runs and scored out of sample on the new test runs on the integral
regression of eqs. 5.55 to 5.57; families are ranked by the gain, with significance thresholds
calibrated on effect-free campaigns; the winner's model is then compared with the original over
5 s open-loop predictions (thesis 5.3.8).

Runs in a few seconds: short simulated runs straight to body states (no bags).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests"))

from simulation.effects import EFFECTS, Effect  # noqa: E402
from sindy_ekf.diagnose import diagnose_states  # noqa: E402
from tests.support.diagnose_synth import (  # noqa: E402
    fit_reference_with_lateral_law,
    simulate_states_campaign,
)


def main(seed: int = 4, family: str | None = None) -> dict:
    """Hide one effect (random family unless given), diagnose it, print and return the outcome."""
    rng = np.random.default_rng(seed)
    family = family or str(rng.choice(list(EFFECTS)))
    value = EFFECTS[family].moderate
    model = fit_reference_with_lateral_law(n_runs=4, run_s=45.0, rate_hz=25.0)
    train, test, a, b = simulate_states_campaign(seed, Effect(family, value), run_s=45.0, rate_hz=25.0)
    d = diagnose_states(model, train, test, a, b, uncertainty=False)
    print(f"hidden: {family} = {value:g} {EFFECTS[family].unit}; diagnosed: {d.verdict}")
    for c in d.ranked[:3]:
        print(f"  {c.name:20s} out-of-sample gain {100 * c.gain:6.2f} % (threshold {100 * c.threshold:.2f} %) "
              f"{c.score.estimate}")
    print(f"5 s position error on the test runs: {100 * d.before.pos_err_5s_m:.1f} cm -> "
          f"{100 * d.after.pos_err_5s_m:.1f} cm with the extended model")
    return {"hidden": family, "value": value, "verdict": d.verdict, "before": d.before.to_json(),
            "after": d.after.to_json()}


if __name__ == "__main__":
    main()
