#!/bin/bash
# issue 14 item 3: python-free mutation check of the fault mechanisms (run from the worktree root);
# result recorded in bench/results/monte_carlo.md
# each mechanism mutated in turn; the tests named must fail (exit non-zero)
PY=/work/main/.venv/bin/python
run() {  # file sed-expr tests...
  f=$1; e=$2; shift 2
  cp $f /tmp/mut_backup.py
  sed -i "$e" $f
  if cmp -s $f /tmp/mut_backup.py; then echo "MUTATION NOT APPLIED: $f $e"; return; fi
  timeout 900 $PY -m pytest -q -x -p no:randomly "$@" > /tmp/mut.log 2>&1
  rc=$?
  cp /tmp/mut_backup.py $f
  echo "$(basename $f) [$e]: $(tail -1 /tmp/mut.log) -> $([ $rc -ne 0 ] && echo KILLED || echo SURVIVED)"
}
T=tests/sindy_ekf
run sindy_ekf/estimation/adaptive.py 's/            return lam$/            return 1.0 \/ lam/' $T/estimation/test_adaptive.py
run sindy_ekf/estimation/adaptive.py 's/d\[p, i\] = (y\[a, i\] - y\[b, i\])/d[p, i] = (y[a, i] + 0.0 * y[b, i])/' $T/estimation/test_adaptive.py
run sindy_ekf/benchmark/health.py 's/    return best <= float(chi2.ppf(1.0 - false_alarm, 2 \* n - 6))/    return False/' $T/benchmark/test_health.py -k "step"
run sindy_ekf/benchmark/health.py 's/total = rss\[0\]\[c1\] + rss\[c1, c2\] + rss\[c2, n\]/total = rss[0][c1] + rss[c1, n] + 0 * c2/' $T/benchmark/test_health.py -k "step"
run sindy_ekf/estimation/process_models.py 's/        if not any(v in env for v in ("vx", "vy", "omega")):/        if True:/' $T/estimation/test_ekf.py -k "envelope"
run sindy_ekf/estimation/process_models.py 's/mean_reverting: bool = True) -> ProcessModel:/mean_reverting: bool = False) -> ProcessModel:/' $T/estimation/test_process_models.py -k "mean_reversion or stationary"
run sindy_ekf/estimation/process_models.py 's/            phi = np.exp(-np.asarray(dt, dtype=float) \/ tau)/            phi = np.exp(-np.asarray(dt, dtype=float) * tau)/' $T/estimation/test_process_models.py -k "mean_reversion or stationary"
