"""The benchmark of the estimators against the campaign's truth under degraded GNSS.

:mod:`~sindy_ekf.benchmark.run` runs the estimators on the test runs,
:mod:`~sindy_ekf.benchmark.scoring` scores them (ATE, error through outages, NEES, NIS),
:mod:`~sindy_ekf.benchmark.result` holds what was measured, :mod:`~sindy_ekf.benchmark.files`
writes the TUM files and the JSON, :mod:`~sindy_ekf.benchmark.figures` draws the figures.
"""
