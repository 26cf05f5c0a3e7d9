"""Time ``TrueDynamics``' polynomial Jacobian: the vectorised pass against the former per-monomial loop.

Usage: ``python -m bench.bench_robot_jacobian`` from the checkout (prints a markdown table).
"""
from __future__ import annotations

import timeit

import numpy as np

from simulation.robot import TrueDynamics
from tests.support.robot_synth import loop_poly_jacobian


def main() -> int:
    dyn = TrueDynamics()
    rng = np.random.default_rng(0)
    print("| batch (states) | loop us | vectorised us | speed-up | accel_and_jacobians() us |")
    print("|---|---|---|---|---|")
    for n in (1, 9, 100, 1000):
        z = rng.uniform(-1, 1, (n, 5))
        x6 = np.zeros((n, 6))
        x6[:, 3:] = z[:, :3]
        u = z[:, 3:]
        t = {}
        for name, fn in (("loop", lambda: loop_poly_jacobian(dyn, z)),
                         ("vec", lambda: dyn._poly_jacobian(z)),
                         ("full", lambda: dyn.accel_and_jacobians(x6, u))):
            t[name] = min(timeit.repeat(fn, number=200, repeat=5)) / 200 * 1e6
        print(f"| {n} | {t['loop']:.0f} | {t['vec']:.0f} | {t['loop'] / t['vec']:.1f} | {t['full']:.0f} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
