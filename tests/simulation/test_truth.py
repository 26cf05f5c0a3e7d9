"""The true dynamics of a simulated campaign, read from its ``truth/`` in one place."""

from __future__ import annotations

import numpy as np

from simulation.effects import Effect
from simulation.robot import TrueDynamics
from simulation.truth import is_simulated, true_dynamics_of
from tests.support.truth_synth import write_bare_truth


def _accelerations(dynamics, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    x6 = np.column_stack([rng.uniform(-3, 3, (50, 2)), rng.uniform(-np.pi, np.pi, 50),
                          rng.uniform(-0.5, 1.0, 50), rng.uniform(-0.1, 0.1, 50), rng.uniform(-1, 1, 50)])
    return dynamics.accel(x6, rng.uniform(-1, 1, (50, 2)))


def test_a_measured_campaign_has_no_true_dynamics(tmp_path):
    assert not is_simulated(tmp_path)
    assert true_dynamics_of(tmp_path) is None


def test_true_dynamics_carry_the_campaigns_effect(tmp_path):
    write_bare_truth(tmp_path, effects=(("heading_dependence", 1.5),))
    oracle = true_dynamics_of(tmp_path)
    assert is_simulated(tmp_path) and oracle.effect == Effect("heading_dependence", 1.5)
    # the same accelerations as the simulator's dynamics with that effect, not those without it
    with_effect = TrueDynamics(effect=Effect("heading_dependence", 1.5))
    assert np.array_equal(_accelerations(oracle), _accelerations(with_effect))
    assert not np.allclose(_accelerations(oracle), _accelerations(TrueDynamics()))


def test_true_dynamics_without_an_effect(tmp_path):
    write_bare_truth(tmp_path)
    assert true_dynamics_of(tmp_path).effect is None
