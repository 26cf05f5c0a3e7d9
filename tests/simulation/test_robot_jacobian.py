"""The vectorised polynomial Jacobian of ``TrueDynamics`` against the per-monomial loop it replaced."""
import numpy as np
import pytest

from simulation.effects import EFFECTS, Effect
from simulation.robot import TrueDynamics
from tests.support.robot_synth import loop_poly_jacobian

ALL_EFFECTS = [None] + [Effect(n, s.moderate) for n, s in EFFECTS.items()]


@pytest.mark.parametrize("effect", ALL_EFFECTS, ids=lambda e: e.name if e else "none")
def test_vectorised_jacobian_equals_the_loop(effect):
    rng = np.random.default_rng(5)
    dyn = TrueDynamics(effect=effect)
    x6 = np.column_stack([rng.uniform(-20, 20, (200, 2)), rng.uniform(-7, 7, 200),
                          rng.uniform(-1.5, 1.5, (200, 3))])
    u = rng.uniform(-1, 1, (200, 2))
    z = np.concatenate([x6[:, 3:], u], axis=-1)
    J_ref = loop_poly_jacobian(dyn, z)
    np.testing.assert_allclose(dyn._poly_jacobian(z), J_ref, rtol=1e-13, atol=1e-13)
    # the full Jacobians carry the polynomial part where no limiter or effect adds to it
    _, J_x, J_u = dyn.accel_and_jacobians(x6, u)
    np.testing.assert_allclose(J_u, J_ref[..., 3:], rtol=1e-13, atol=1e-13)
    assert J_x.shape == (200, 3, 6) and np.abs(J_ref).max() > 0.1
    # leading axes and broadcasting of one input against many states
    np.testing.assert_allclose(dyn._poly_jacobian(z.reshape(4, 50, 5)), J_ref.reshape(4, 50, 3, 5),
                               rtol=1e-13, atol=1e-13)


def test_accelerations_with_jacobians_equal_the_accelerations_alone():
    from simulation.effects import Effect

    rng = np.random.default_rng(8)
    dyn = TrueDynamics(effect=Effect("heading_dependence", EFFECTS["heading_dependence"].moderate))
    x6, u = rng.uniform(-1, 1, (30, 6)), rng.uniform(-1, 1, (30, 2))
    a, J_x, J_u = dyn.accel_and_jacobians(x6, u, 1.0)
    np.testing.assert_array_equal(a, dyn.accel(x6, u, 1.0))
    assert J_x.shape == (30, 3, 6) and J_u.shape == (30, 3, 2)
