"""The stages of the chain as library functions, shared by the commands and the report.

Each stage takes typed values and returns a frozen result with ``to_json()`` where a command
writes one: :mod:`~sindy_ekf.stages.calibration` (survey calibration and one run's
synchronisation, thesis 5.1, 5.2), :mod:`~sindy_ekf.stages.identification` (the grid search,
5.3.6), :mod:`~sindy_ekf.stages.evaluation` (5 s prediction errors of the model, the baselines
and the simulator's oracle, 5.3.8), :mod:`~sindy_ekf.stages.estimation` (the estimators under
degraded GNSS). :mod:`~sindy_ekf.stages.chain` runs them in turn on one campaign, each failure
recorded, for the report (:mod:`sindy_ekf.report`) and the demo. A command (``sindy-ekf
evaluate`` ...) parses its arguments, calls one of these, prints and writes what it returns.
"""
