"""A held (zero-order) input track queried far beyond its ends reads its end values, by hand.

The zero-order hold integrates the held inputs over knots padded 1e4 s beyond both ends; queries past the
padding used to read 0 (the integral held constant by ``np.interp``).
"""

from __future__ import annotations

import numpy as np

from identification.sindy.input_track import InputTrack


def test_held_inputs_far_beyond_both_ends_are_the_end_values():
    track = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[0.3, -0.2], [0.5, 0.1], [-0.4, 0.7]]), hold="zoh")
    far = np.array([-5e4, -2e4, 3.0, 2e4, 5e4])
    u = track.at(far)
    # before the first sample the first value holds, after the last the last (by hand: the samples)
    np.testing.assert_allclose(u[:2], [[0.3, -0.2], [0.3, -0.2]], atol=1e-9)
    np.testing.assert_allclose(u[2:], [[-0.4, 0.7]] * 3, atol=1e-9)


def test_inside_the_track_nothing_changes():
    track = InputTrack(np.array([0.0, 1.0, 2.0]), np.array([[0.3, -0.2], [0.5, 0.1], [-0.4, 0.7]]), hold="zoh")
    # at 0.5 s the held value is the sample at 0 s; the 0.02 s average around it sees nothing else
    np.testing.assert_allclose(track.at(np.array([0.5, 1.5])), [[0.3, -0.2], [0.5, 0.1]], atol=1e-12)
