"""Training runs checked by hand (regression.check_states): an input is constant, and its terms
cannot be identified, when its range over all training runs is below 1e-6 (0.5e-6 is refused naming
the input, 1.5e-6 is not, and an input named in ``allow_constant`` passes either way); a run of two
or more samples must have strictly increasing times (a single sample has none to order)."""

from __future__ import annotations

import numpy as np
import pytest

from groundfloor.errors import InputError
from groundfloor.types import BodyStates
from identification.sindy.regression import check_states


def _run(t0: float, u1: np.ndarray) -> BodyStates:
    t = t0 + np.arange(len(u1)) * 0.02
    z = np.zeros_like(t)
    return BodyStates(t=t, vx=z, vy=z, omega=z, u1=u1, u2=np.linspace(-1.0, 1.0, len(t)), x=z, y=z, yaw=z)


@pytest.mark.parametrize("range_u1, constant", [(0.0, True), (0.5e-6, True), (0.9e-6, True), (1.5e-6, False),
                                                (1e-3, False)])
def test_an_input_whose_range_over_all_runs_is_below_1e_6_is_constant(range_u1, constant):
    # the range spans two runs: each alone is constant, together they differ by range_u1
    runs = [_run(0.0, np.full(10, 0.3)), _run(5.0, np.full(10, 0.3 + range_u1))]
    if constant:
        with pytest.raises(InputError, match="input u1: constant"):
            check_states(runs, ["a", "b"])
    else:
        check_states(runs, ["a", "b"])
    check_states(runs, ["a", "b"], allow_constant=("u1",))  # its terms left out: no error


@pytest.mark.parametrize("t", [[0.0, 0.0], [0.1, 0.0], [0.0, 0.1, 0.1]])
def test_a_run_of_two_or_more_samples_must_have_strictly_increasing_times(t):
    t = np.asarray(t)
    z = np.zeros_like(t)
    bad = BodyStates(t=t, vx=z, vy=z, omega=z, u1=np.arange(len(t), dtype=float), u2=np.arange(len(t), dtype=float),
                     x=z, y=z, yaw=z)
    with pytest.raises(InputError, match="run b: times are not strictly increasing"):
        check_states([_run(0.0, np.linspace(0.0, 1.0, 10)), bad], ["a", "b"])
    check_states([_run(0.0, np.linspace(0.0, 1.0, 10)), _run(5.0, np.array([0.5]))], ["a", "b"])  # one sample: fine
