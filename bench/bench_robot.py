"""Robot simulator: speed of ``simulate_run`` and visibility of every effect in 5 s predictions.

Usage: ``.venv/bin/python -m bench.bench_robot``; writes ``bench/results/robot.md``.

Speed: the nine run lengths of thesis table 6.4 (45.4 min), CPU and wall time (wall time depends
on what else shares the two cores). Visibility: for each effect at its moderate magnitude, a run
with the effect (same seed as a plain run) is predicted open loop for 5 s (windows every 2.5 s,
thesis section 5.3.8) with the *effect-free* true dynamics from the true state at each window
start and the recorded joystick inputs; the RMS position error at 5 s against the plain run's
(process noise only) says how visible the effect is to a model identified without it.
"""

from __future__ import annotations

import platform
import sys
import time
from pathlib import Path

import numpy as np

from groundfloor.files import atomic_write_text
from simulation.effects import EFFECTS, Effect
from simulation.robot import TrueDynamics, simulate_run

ROOT = Path(__file__).resolve().parents[1]

TABLE_6_4_S = (100, 390, 340, 300, 100, 470, 125, 440, 460)


def predict_5s_error(run, horizon_s=5.0, step_s=2.5, dt=0.01):
    """Return (RMS position error m, RMS yaw error deg) at ``horizon_s`` of open-loop predictions."""
    dyn = TrueDynamics()
    stride = int(round(step_s / (run.t[1] - run.t[0])))
    k0 = np.arange(0, run.t.size - int(horizon_s / (run.t[1] - run.t[0])) - 1, stride)
    x = np.column_stack([run.x, run.y, run.psi, run.vx, run.vy, run.omega])[k0]
    t0 = run.t[k0]
    n = int(round(horizon_s / dt))
    for i in range(n):  # RK4 over all windows at once, inputs held per step
        u = dyn.motor_inputs(t0 + i * dt, run.t_joy, run.u_joy)

        def rhs(s):
            return dyn.derivative(s, u)

        k1 = rhs(x)
        k2 = rhs(x + 0.5 * dt * k1)
        k3 = rhs(x + 0.5 * dt * k2)
        k4 = rhs(x + dt * k3)
        x = x + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    k_end = k0 + int(round(horizon_s / (run.t[1] - run.t[0])))
    pos = np.hypot(x[:, 0] - run.x[k_end], x[:, 1] - run.y[k_end])
    yaw = np.degrees(x[:, 2] - run.psi[k_end])
    return float(np.sqrt(np.mean(pos ** 2))), float(np.sqrt(np.mean(yaw ** 2))), len(k0)


def main() -> int:
    lines = ["## robot: simulated Husky (simulation/robot.py, driver.py, effects.py)", "",
             f"Command: `{Path(sys.executable).relative_to(ROOT) if sys.executable.startswith(str(ROOT)) else sys.executable} "
             f"-m bench.bench_robot` (Python {platform.python_version()}, 2 cores shared with other jobs)", ""]
    # --- speed
    cpu0, wall0 = time.process_time(), time.perf_counter()
    steps = 0
    for i, d in enumerate(TABLE_6_4_S):
        r = simulate_run(float(d), np.random.default_rng(100 + i))
        steps += r.t.size
    cpu, wall = time.process_time() - cpu0, time.perf_counter() - wall0
    lines += ["| speed (9 runs of table 6.4, 45.4 min, dt = 2 ms, closed-loop driver) | value |",
              "|---|---|",
              f"| RK4 steps | {steps:,} |",
              f"| CPU time, all runs | **{cpu:.1f} s** ({cpu / steps * 1e6:.1f} us per step incl. driver and inputs) |",
              f"| wall time, all runs | {wall:.1f} s |", ""]
    # --- visibility of the effects
    seed, dur = 5, 150.0
    plain = simulate_run(dur, np.random.default_rng(seed))
    base = predict_5s_error(plain)
    lines += ["| effect (moderate value) | 5 s position error RMS, m | 5 s yaw error RMS, deg | ratio to plain |",
              "|---|---|---|---|",
              f"| none (process noise only) | {base[0]:.3f} | {base[1]:.2f} | 1.0 |"]
    for name, spec in EFFECTS.items():
        d = 470.0 if name == "time_dependence" else dur
        run = simulate_run(d, np.random.default_rng(seed), effect=Effect(name, spec.moderate))
        err = predict_5s_error(run)
        ref = base if d == dur else predict_5s_error(simulate_run(d, np.random.default_rng(seed)))
        lines.append(f"| {name}={spec.moderate} {spec.unit}{' (470 s run)' if d != dur else ''} | "
                     f"{err[0]:.3f} | {err[1]:.2f} | {err[0] / ref[0]:.1f} |")
    lines += ["", f"Plain runs: {base[2]} windows of 5 s every 2.5 s over {dur:.0f} s (seed {seed}); "
              "predictions use the effect-free `TrueDynamics` and the recorded joystick inputs, "
              "RK4 at 10 ms, all windows vectorised.", ""]
    out = ROOT / "bench" / "results" / "robot.md"
    atomic_write_text(out, "\n".join(lines))
    print("\n".join(lines))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
