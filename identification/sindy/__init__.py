"""Integral SINDy with control (thesis 5.3): feature libraries, the integral regression, the
model and its file, the hyperparameter search, multi-step evaluation and the baselines.

Its one door to preprocessing is :mod:`identification.sindy.data` (body-frame states of runs).
"""
