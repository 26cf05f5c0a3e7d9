"""Identification from measured data, in two wings that meet at one module.

- :mod:`identification.preprocessing`: a tracker campaign to a trajectory campaign (thesis 5.1,
  5.2: survey, clock synchronisation, timing error, hubs, poses) and the body-frame states of
  eqs. 5.64 to 5.68 (smoothing splines);
- :mod:`identification.sindy`: integral SINDy with control, its search, evaluation and
  baselines (thesis 5.3).

The wings meet only in :mod:`identification.sindy.data`, which takes the body-frame states and
the data-gap rule from :mod:`identification.preprocessing` (``tests/test_architecture.py``).
"""
