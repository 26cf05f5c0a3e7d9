"""A damping that changes smoothly across the lab (issue 15, item 1: a smooth spatial field, not a
disc with the simulator's edge).

Reference: the simulator. A campaign on variant 2 whose floor damping rises across the lab in a
smooth step (``position_dependence`` in its ``gradient`` form, a tanh across the lab, which no disc
of the family's grid resembles), diagnosed against the variant's own lab model identified on an
effect-free campaign: the family is named with its smooth field (chosen on the train runs), and the
extended model predicts the test runs better over 5 s.
"""

from __future__ import annotations

import warnings

from simulation.effects import Effect
from simulation.short_campaign import simulate_states_campaign
from sindy_ekf.diagnose import diagnose_states
from tests.support.diagnose_synth import variant_reference


def test_a_smooth_damping_step_across_the_lab_is_named_with_the_smooth_field():
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        model = variant_reference(2, 45.0, 25.0)
        train, test, a, b = simulate_states_campaign(
            4242, Effect("position_dependence", 0.25, form="gradient", params={"seed": 7}),
            run_s=45.0, rate_hz=25.0, variant=2)
        d = diagnose_states(model, train, test, a, b, uncertainty=False)
    assert d.verdict == "position_dependence", [(c.name, round(c.gain, 3)) for c in d.ranked[:3]]
    assert d.ranked[0].score.estimate["mechanism"] == "smooth_field"
    assert d.ranked[0].score.estimate["damping_fraction_span"] > 0.1  # by the simulator: 0.25 across the lab
    assert d.after.pos_err_5s_m < 0.7 * d.before.pos_err_5s_m
