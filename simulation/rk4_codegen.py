"""The simulator's inner loop: RK4 of the true dynamics generated as Python source from the term table.

Why generated code: :func:`simulation.robot.simulate_run` takes 1.36 million RK4 steps of six
states for the default campaign (table 6.4, 45.4 min at 2 ms), and each step evaluates the 32
terms of the dynamics four times. Numpy pays its call overhead on six-element arrays (and the
driver closes the loop at every joystick message, so the steps cannot be batched), and a plain
Python loop over the term table costs some 25 to 40 times more than the straight-line float code
generated here, which regroups the polynomial by state monomial and recomputes its
input-dependent coefficients only when the motor input changes: measured by
``bench/bench_simulate.py`` (``bench/results/simulate.md``: 236 us against 6 us per step under
load, 321 s of CPU for the campaign's steps against 8 s; the target for the whole campaign is
60 s).

:func:`compile_stepper` returns the RK4 loop on floats, :func:`compile_acc` the accelerations
alone (on floats, or vectorised on numpy arrays for :meth:`simulation.robot.TrueDynamics.accel`).
Both are generated from :class:`simulation.robot_params.RobotParams` and the effect, so the
numbers live in one place; the tests check the generated code against the numpy dynamics and
scipy's ODE solver.
"""

from __future__ import annotations

import math

import numpy as np

from simulation.body_effects import body_source, effective_lateral
from simulation.effects import Effect
from simulation.lateral import LateralLaw, lateral_source
from simulation.robot_params import RobotParams, exponents_from_name


def _horner(poly: dict, names: tuple) -> str:
    """Return a nested (Horner) expression of ``{exponents: coefficient source}`` in ``names``."""
    if not poly:
        return "0.0"
    counts = [sum(1 for ex in poly if ex[v]) for v in range(len(names))]
    v = int(np.argmax(counts))
    if counts[v] == 0:
        return " + ".join(poly.values())
    rest = {ex: c for ex, c in poly.items() if not ex[v]}
    inner = {ex[:v] + (ex[v] - 1,) + ex[v + 1:]: c for ex, c in poly.items() if ex[v]}
    head = f"{_horner(rest, names)} + " if rest else ""
    return f"({head}{names[v]}*{_horner(inner, names)})"


def _acc_lines(params: RobotParams, effect: Effect | None, coef: dict, sv: tuple, indent: str,
               vectorised: bool = False, lateral: LateralLaw | None = None) -> list[str]:
    """Return source lines computing ``ax, ay, aw`` from the states named ``sv`` (x, y, psi, vx,
    vy, om) and the per-input coefficients ``coef`` (state monomial -> variable name); the
    limiters branch on floats and use ``relu(s) = (s + |s|) / 2`` on arrays. A non-linear
    lateral law replaces the polynomial ``vy`` equation; the effect's body mechanism follows
    the limiters (:mod:`simulation.body_effects`)."""
    vx, vy, om = sv[3:]
    names = (vx, vy, om)
    law, gain = effective_lateral(lateral or LateralLaw(), effect)
    lines = []
    for key, out in (("vx", "ax"), ("vy", "ay"), ("omega", "aw")):
        if key == "vy" and law.form != "linear":
            k_y, c_y = params.lateral_damping_1_s, gain * params.lateral_coupling
            lines.append(f"{indent}ay = {lateral_source(law, k_y, c_y, vx, vy, om)}")
        else:
            lines.append(f"{indent}{out} = {_horner(coef[key], names)}")
    g, gw, kg = params.guard_track_speed_m_s, params.guard_omega_rad_s, params.guard_gain
    b = params.track_half_width_m
    if vectorised:
        relu2 = "((e1 + abs(e1))**2 - (e2 + abs(e2))**2)"  # 4 sign(s) relu(|s| - lim)^2
        lines += [f"{indent}e1 = {vx} - {b!r}*{om} - {g!r}; e2 = -{vx} + {b!r}*{om} - {g!r}",
                  f"{indent}al = -{kg / 4!r}*{relu2}",
                  f"{indent}e1 = {vx} + {b!r}*{om} - {g!r}; e2 = -{vx} - {b!r}*{om} - {g!r}",
                  f"{indent}ar = -{kg / 4!r}*{relu2}",
                  f"{indent}ax = ax + 0.5*(al + ar)",
                  f"{indent}aw = aw + (ar - al)*{0.5 / b!r}",
                  f"{indent}e1 = {om} - {gw!r}; e2 = -{om} - {gw!r}",
                  f"{indent}aw = aw - {kg / 4!r}*{relu2}"]
    else:
        lines += [f"{indent}vt = abs({vx}) + {b!r}*abs({om})",  # the faster track's speed
                  f"{indent}if vt > {g!r}:",
                  f"{indent}    vl = {vx} - {b!r}*{om}; vr = {vx} + {b!r}*{om}",
                  f"{indent}    al = -{kg!r}*(abs(vl) - {g!r})**2 if vl > {g!r} or vl < {-g!r} else 0.0",
                  f"{indent}    ar = -{kg!r}*(abs(vr) - {g!r})**2 if vr > {g!r} or vr < {-g!r} else 0.0",
                  f"{indent}    al = al if vl > 0 else -al; ar = ar if vr > 0 else -ar",
                  f"{indent}    ax += 0.5*(al + ar); aw += (ar - al)*{0.5 / b!r}",
                  f"{indent}if {om} > {gw!r}: aw -= {kg!r}*({om} - {gw!r})**2",
                  f"{indent}elif {om} < {-gw!r}: aw += {kg!r}*({om} + {gw!r})**2"]
    return lines + body_source(params, effect, lateral or LateralLaw(), sv, indent)


def _collect_by_state(terms: dict) -> tuple[dict, list[str]]:
    """Return ``({eq: {state exps: coefficient name}}, lines computing the coefficients from
    u1, u2)``: the polynomial ``terms`` regrouped by state monomial, its coefficients
    polynomials in u."""
    coef, lines, powers = {}, [], set()
    for key in ("vx", "vy", "omega"):
        groups: dict[tuple, list[str]] = {}
        for n, c in terms[key].items():
            ex = exponents_from_name(n)
            u_part = "*".join(f"u{i + 1}" + (f"_{ex[3 + i]}" if ex[3 + i] > 1 else "")
                              for i in range(2) if ex[3 + i])
            powers |= {(i + 1, p) for i in range(2) for p in range(2, ex[3 + i] + 1)}
            groups.setdefault(ex[:3], []).append(f"({c!r})" + (f"*{u_part}" if u_part else ""))
        coef[key] = {}
        for j, (ex, parts) in enumerate(groups.items()):
            if len(parts) == 1 and "*" not in parts[0]:  # constant: inline the literal
                coef[key][ex] = parts[0]
                continue
            cn = f"C_{key}_{j}"
            coef[key][ex] = cn
            lines.append(f"{cn} = " + " + ".join(parts))
    pre = [f"u{i}_{p} = u{i}" + f"*u{i}" * (p - 1) for i, p in sorted(powers)]
    return coef, pre + lines


def compile_stepper(params: RobotParams, effect: Effect | None, lateral: LateralLaw | None = None):
    """Return ``(integrate, acc)`` compiled from the term table for the float RK4 loop.

    ``integrate(k0, k1, state, U, N1, N2, N3, out, h)`` advances ``state`` (6 floats) over the
    steps ``k0..k1-1`` with RK4, the inputs ``U[k - k0]`` and noise ``N*[k]`` held per step,
    appending the state at each step start to ``out``; ``acc`` is the same code as a function
    of floats (for tests). The polynomial is regrouped by state monomial with coefficients recomputed
    only when the motor input changes (it is constant over a joystick message), which makes a
    stage about three times cheaper than the expanded form. ``lateral`` is the robot's lateral
    law (default linear, part of the polynomial).
    """
    coef, coef_lines = _collect_by_state(params.terms())
    src = ["def integrate(k0, k1, state, U, N1, N2, N3, out, h):",
            "    x, y, psi, vx, vy, om = state",
            "    h2 = 0.5*h; h6 = h/6.0; u1p = u2p = None",
            "    for k in range(k0, k1):",
            "        u1, u2 = U[k - k0]",
            "        if u1 != u1p or u2 != u2p:",
            "            u1p, u2p = u1, u2"]
    src += ["            " + ln for ln in coef_lines]
    src += ["        out.append((x, y, psi, vx, vy, om))",
            "        a1 = N1[k]; a2 = N2[k]; a3 = N3[k]"]
    stage_in = [("x", "y", "psi", "vx", "vy", "om")] + [("xb", "yb", "pb", "vb", "wb", "ob")] * 3
    step = ["h2", "h2", "h", None]
    for i in range(4):
        sv = stage_in[i]
        src += _acc_lines(params, effect, coef, sv, "        ", lateral=lateral)
        src += [f"        c = cos({sv[2]}); s = sin({sv[2]})",
                f"        kx{i} = {sv[3]}*c - {sv[4]}*s; ky{i} = {sv[3]}*s + {sv[4]}*c; kp{i} = {sv[5]}",
                f"        kv{i} = ax + a1; kw{i} = ay + a2; ko{i} = aw + a3"]
        if step[i]:
            hh = step[i]
            src += [f"        xb = x + {hh}*kx{i}; yb = y + {hh}*ky{i}; pb = psi + {hh}*kp{i}",
                    f"        vb = vx + {hh}*kv{i}; wb = vy + {hh}*kw{i}; ob = om + {hh}*ko{i}"]
    for var, kn in (("x", "kx"), ("y", "ky"), ("psi", "kp"), ("vx", "kv"), ("vy", "kw"), ("om", "ko")):
        src.append(f"        {var} += h6*({kn}0 + 2.0*({kn}1 + {kn}2) + {kn}3)")
    src.append("    return x, y, psi, vx, vy, om")
    namespace = {"cos": math.cos, "sin": math.sin, "tanh": math.tanh, "sqrt": math.sqrt, "exp": math.exp}
    exec("\n".join(src), namespace)  # noqa: S102 - source generated from the numeric term table
    return namespace["integrate"], compile_acc(params, effect, vectorised=False, lateral=lateral)


def compile_acc(params: RobotParams, effect: Effect | None, vectorised: bool, lateral: LateralLaw | None = None):
    """Return ``acc(x, y, psi, vx, vy, om, u1, u2) -> (ax, ay, aw)`` generated from the term
    table: on numpy arrays (``vectorised``, for :meth:`TrueDynamics.accel`) or on floats."""
    coef, coef_lines = _collect_by_state(params.terms())
    src = ["def acc(x, y, psi, vx, vy, om, u1, u2):"]
    src += ["    " + ln for ln in coef_lines]
    src += _acc_lines(params, effect, coef, ("x", "y", "psi", "vx", "vy", "om"), "    ", vectorised, lateral)
    src.append("    return ax, ay, aw")
    lib = np if vectorised else math
    namespace = {"cos": lib.cos, "sin": lib.sin, "tanh": lib.tanh, "sqrt": lib.sqrt, "exp": lib.exp}
    exec("\n".join(src), namespace)  # noqa: S102 - source generated from the numeric term table
    return namespace["acc"]
