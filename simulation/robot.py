"""The simulated Husky A200: true body dynamics (thesis model B), effects, pitch, and a run.

Body dynamics (body frame, ``x = [vx, vy, omega]``, inputs ``u = [u1, u2]`` as the motors see
them):

- ``vx_dot`` and ``omega_dot``: the thesis's identified model B, eqs. 7.7 and 7.9, with its
  coefficients verbatim (including the ``vy omega^2`` and ``vy u1^2`` terms of 7.9). Over the
  input square its steady states reach 0.81 m/s and 1.15 rad/s (table 3.1: 1.0 m/s max).
- ``vy_dot = -k_y vy - c_y vx omega`` (eq. 7.8 says 0; a skid-steered body does slip sideways in
  turns): the rigid-body lateral equation ``vy_dot + vx omega = F_y / m`` with a linear lateral
  tyre force ``F_y = -m k_y vy`` (``c_y = 1``). With ``k_y = 15 1/s`` the outward drift is
  ``vx omega / k_y``, about 2 cm/s at 0.5 m/s and 0.6 rad/s.
- Limiters of the drive controller, outside fig. 6.3's envelope only: each track's speed
  ``|vx -+ b omega|`` (``b = 0.29 m``, half the hub distance across an axle, table 6.3) beyond
  0.9 m/s and the yaw rate beyond 1.2 rad/s are braked by ``-k relu(|s| - s_lim)^2 sign(s)``
  (``k = 2000``). Model B's steady states reach 0.876 m/s track speed and 1.149 rad/s, so the
  limiters are idle in normal driving and not part of :meth:`TrueDynamics.true_terms`. They
  are needed because model B, a fit to data near its steady states, turns unphysical beyond
  them: its cubic terms make friction fall with speed (a fold at about 0.9 m/s, where a 1.5 deg
  slope already tips it into runaway) and ``7.69 vx^2 omega``, ``2.896 omega^3`` and
  ``-4.349 omega^2 u2`` drive a fast-reversing robot into a spin against the command. A
  per-track limit (the motors' speed) cuts off exactly that corner of high speed and yaw rate.
- Process noise: Ornstein-Uhlenbeck accelerations (vibration, floor texture) added to the three
  body accelerations, std ``(0.06 m/s^2, 0.03 m/s^2, 0.15 rad/s^2)``, correlation time 50 ms
  (velocity jitter of about 4 mm/s, 1.3 mm/s and 0.011 rad/s).
- Pitch: a second-order suspension response to the longitudinal acceleration
  ``a_x = vx_dot - vy omega``: ``theta'' + 2 zeta w_n theta' + w_n^2 theta = -w_n^2 k_p a_x``,
  ``k_p = 0.5 deg per m/s^2``, 2 Hz, ``zeta = 0.5`` (positive pitch = nose down, eq. 5.34: the
  nose dips when braking). The body pitches about its origin, so ``z`` of the origin only follows
  the floor.
- Pose: eq. 5.75 kinematics ``x_dot = vx cos psi - vy sin psi``, ``y_dot = vx sin psi + vy cos
  psi``, ``psi_dot = omega`` in the local (AT960) frame.

The coefficients and constants are :class:`simulation.robot_params.RobotParams`. A simulator
variant (:class:`simulation.variant.Variant`) changes them and adds structure: another lateral
law (:mod:`simulation.lateral`), a first-order motor lag, another process-noise spectrum
(:mod:`simulation.process_noise`), another driver. Effects (:mod:`simulation.effects`) act
either on the motor inputs (:meth:`TrueDynamics.motor_inputs`, :mod:`simulation.actuator`) or
on :meth:`TrueDynamics.accel` (:mod:`simulation.body_effects`). Integration: classical RK4
at ``dt`` with the motor inputs and the noise held over each step (the motor controller updates
at ``1/dt``), through code generated on Python floats (:mod:`simulation.rk4_codegen`, which says
why); the driver (:mod:`simulation.driver`) closes the loop at each joystick message.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np
from scipy import signal

from groundfloor.dynamics import Dynamics
from groundfloor.errors import InputError
from simulation.actuator import InputChain, InputMemo
from simulation.body_effects import add_body_jacobians, effective_lateral, slope
from simulation.driver import DrivingArea, HumanDriver, simulate_joy_stamps
from simulation.effects import Effect
from simulation.lateral import LateralLaw, lateral_accel_and_jacobian, lateral_terms
from simulation.process_noise import simulate_ou_noise, simulate_process_noise  # noqa: F401 - re-export
from simulation.rk4_codegen import compile_acc, compile_stepper
from simulation.robot_params import RobotParams, exponents_from_name
from simulation.variant import Variant


class TrueDynamics(Dynamics):
    """The simulator's true body dynamics with an optional effect (the estimation oracle).

    A :class:`groundfloor.dynamics.Dynamics`: accelerations depend on the pose too (effects);
    the pose follows the inherited eq. 5.75 kinematics. (:func:`simulate_run` integrates the
    same accelerations through code generated on Python floats, :mod:`simulation.rk4_codegen`.)

    Inputs are always what the motors see. The actuator's state (the motor lag of a variant,
    an ``input_delay:motor_lag`` effect, the stiction of ``deadband:hysteresis``) lives in
    :meth:`motor_inputs` (``self.inputs``, a :class:`simulation.actuator.InputChain`), which
    integrates it exactly from the joystick messages since the run start; :meth:`accel` takes
    its output. So the six-state interface stays, and the oracle is exact: integrated with
    ``motor_inputs`` held over each step it reproduces :func:`simulate_run` (tested).

    Parameters
    ----------
    params
        Robot parameters; default :class:`RobotParams`.
    effect
        At most one :class:`simulation.effects.Effect`.
    lateral
        The robot's lateral law; default linear (:mod:`simulation.lateral`).
    motor_lag_s
        Time constant of the robot's first-order motor lag (0: none).
    """

    name = "oracle"

    def __init__(self, params: RobotParams | None = None, effect: Effect | None = None, *,
                 lateral: LateralLaw | None = None, motor_lag_s: float = 0.0):
        self.params = params or RobotParams()
        self.effect = effect
        self.lateral = lateral or LateralLaw()
        self.inputs = InputChain(effect, motor_lag_s)
        self._motor_lag_s = float(motor_lag_s)
        self._law, self._slip_gain = effective_lateral(self.lateral, effect)
        self._acc_np = compile_acc(self.params, effect, vectorised=True, lateral=self.lateral)
        terms = self.params.terms()
        if self._law.form != "linear":  # the law replaces the polynomial vy equation
            terms = {**terms, "vy": {}}
        self._eqs = [[(c, np.array(exponents_from_name(n))) for n, c in terms[k].items()]
                     for k in ("vx", "vy", "omega")]
        # one entry per (equation, monomial, variable it contains): the derivative's coefficient
        # c * e_v, its exponents e - 1_v and the Jacobian cell row * 5 + v it adds to
        entries = [(row, v, c * ex[v], ex - np.eye(5, dtype=int)[v])
                   for row, eq in enumerate(self._eqs) for c, ex in eq for v in np.flatnonzero(ex)]
        self._dexp = np.array([e[3] for e in entries], dtype=np.intp).reshape(-1, 5)  # (K, 5)
        self._dcoef = np.array([e[2] for e in entries], float)                       # (K,)
        self._dscatter = np.zeros((len(entries), 15))                                # (K, 15)
        self._dscatter[np.arange(len(entries)), [5 * e[0] + e[1] for e in entries]] = 1.0
        if self._dexp.size and self._dexp.max() > 3:
            raise ValueError("TrueDynamics: monomials of degree > 4 in one variable are not supported")

    @classmethod
    def of_variant(cls, variant: Variant, effect: Effect | None = None) -> TrueDynamics:
        """Return the true dynamics of a simulator variant with an optional effect."""
        return cls(variant.robot, effect, lateral=variant.lateral, motor_lag_s=variant.motor_lag_s)

    @property
    def motor_lag_s(self) -> float:
        """Time constant of the robot's own motor lag (0: none; an effect's lag is the effect's)."""
        return self._motor_lag_s

    # -- dynamics --------------------------------------------------------------------------
    def accel(self, x6, u, t=0.0) -> np.ndarray:
        """Return the body accelerations ``[vx_dot, vy_dot, omega_dot]``, shape ``(..., 3)``.

        Implements eqs. 7.7 and 7.9 (model B), the lateral law and the speed limiter of the
        module docstring, plus the effect's body-side mechanism. ``u`` is what the motors see
        (see :meth:`motor_inputs`); ``t`` (s since run start) is accepted for the interface,
        the time effect acting on the inputs. Deterministic part only.
        """
        x6, u = np.asarray(x6, float), np.asarray(u, float)
        a = self._acc_np(*(x6[..., i] for i in range(6)), u[..., 0], u[..., 1])
        return np.stack(np.broadcast_arrays(*a), axis=-1)

    def _poly_jacobian(self, z: np.ndarray) -> np.ndarray:
        """Return d(poly)/d[vx, vy, omega, u1, u2], shape ``(..., 3, 5)``, from the exponents.

        One numpy pass: the powers 0..3 of the five variables are gathered with the precomputed
        derivative exponents ``(K, 5)``, multiplied, scaled by ``c * e_v`` and summed into the
        15 Jacobian cells by a ``(K, 15)`` scatter matrix.
        """
        powers = np.stack([np.ones_like(z), z, z * z, z * z * z], axis=-1)  # (..., 5, 4)
        mono = np.prod(powers[..., np.arange(5), self._dexp], axis=-1)      # (..., K)
        return ((mono * self._dcoef) @ self._dscatter).reshape(z.shape[:-1] + (3, 5))

    def accel_and_jacobians(self, x6, u, t=0.0) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return :meth:`accel` and its analytic Jacobians ``J_a_x (..., 3, 6)``, ``J_a_u (..., 3, 2)``."""
        J_x, J_u = self._jacobians(x6, u)
        return self.accel(x6, u, t), J_x, J_u

    def _jacobians(self, x6, u) -> tuple[np.ndarray, np.ndarray]:
        """Return ``J_a_x`` and ``J_a_u``: polynomial, limiters and the effect's mechanism."""
        x6, u = np.asarray(x6, float), np.asarray(u, float)
        shape = np.broadcast_shapes(x6.shape[:-1], u.shape[:-1])
        x6 = np.broadcast_to(x6, shape + (6,))
        u = np.broadcast_to(u, shape + (2,))
        z = np.concatenate([x6[..., 3:6], u], axis=-1)
        Jp = self._poly_jacobian(z)
        J_x = np.zeros(shape + (3, 6))
        J_x[..., :, 3:6] = Jp[..., :, :3]
        J_u = Jp[..., :, 3:5].copy()
        p = self.params
        vx, om = x6[..., 3], x6[..., 5]
        # limiters: d/ds of -k relu(|s| - lim)^2 sign(s) = -2 k relu(|s| - lim)
        b = p.track_half_width_m
        d_l = -2 * p.guard_gain * np.maximum(np.abs(vx - b * om) - p.guard_track_speed_m_s, 0.0)
        d_r = -2 * p.guard_gain * np.maximum(np.abs(vx + b * om) - p.guard_track_speed_m_s, 0.0)
        J_x[..., 0, 3] += 0.5 * (d_l + d_r)
        J_x[..., 0, 5] += 0.5 * b * (d_r - d_l)
        J_x[..., 2, 3] += (d_r - d_l) * 0.5 / b
        J_x[..., 2, 5] += 0.5 * (d_l + d_r)
        J_x[..., 2, 5] -= 2 * p.guard_gain * np.maximum(np.abs(om) - p.guard_omega_rad_s, 0.0)
        if self._law.form != "linear":
            _, d = lateral_accel_and_jacobian(self._law, p.lateral_damping_1_s, self._slip_gain * p.lateral_coupling,
                                              vx, x6[..., 4], om)
            J_x[..., 1, 3:6] += d
        add_body_jacobians(p, self.effect, self.lateral, x6, J_x)
        return J_x, J_u

    # -- inputs ----------------------------------------------------------------------------
    def motor_inputs(self, t_query, t_joy, u_joy, memo: InputMemo | None = None) -> np.ndarray:
        """Return the ``(n, 2)`` inputs the motors see at ``t_query`` (s since run start).

        Zero-order hold of the joystick messages (zero before the first), the effect's
        input-side mechanism (delay, deadband, asymmetry, battery sag), the motor lags,
        saturation to [-1, 1]: :class:`simulation.actuator.InputChain`. ``memo`` lets
        :func:`simulate_run` extend one history without recomputing it.
        """
        return self.inputs.motor_inputs(t_query, t_joy, u_joy, memo)

    def true_terms(self) -> dict[str, dict[str, float]]:
        """Return ``{"vx"|"vy"|"omega": {feature: coefficient}}`` of the effect-free dynamics.

        Feature names follow pysindy's PolynomialLibrary with variables ``vx, vy, omega, u1,
        u2``; the speed limiter (zero in normal driving), noise, effects and the motor lag are
        excluded. The ``vy`` equation is exact for the polynomial lateral laws and the law's
        third-order Taylor expansion otherwise (:func:`simulation.lateral.lateral_terms`).
        """
        p = self.params
        return {**p.terms(), "vy": lateral_terms(self.lateral, p.lateral_damping_1_s, p.lateral_coupling)}


@dataclass(frozen=True)
class TrueRun:
    """True states of one simulated run on a uniform time grid, plus the joystick messages."""

    t: np.ndarray  # (n,) s since run start, uniform step dt
    x: np.ndarray  # local (AT960) frame, m
    y: np.ndarray
    psi: np.ndarray  # heading, unwrapped, rad
    vx: np.ndarray  # body velocities, m/s and rad/s
    vy: np.ndarray
    omega: np.ndarray
    pitch: np.ndarray  # rad, positive nose down (eq. 5.34)
    z: np.ndarray  # body-origin height change from the level floor at the local origin, m
    ax: np.ndarray  # longitudinal acceleration vx_dot - vy omega, m/s^2
    u_motor: np.ndarray  # (n, 2) inputs as the motors saw them
    t_joy: np.ndarray  # (m,) joystick message times, s since run start
    u_joy: np.ndarray  # (m, 2) joystick messages [u1, u2] as the robot received them
    noise: np.ndarray | None = None  # (n, 3) process-noise accelerations held over each step


def pitch_from_accel(ax: np.ndarray, dt: float, params: RobotParams) -> np.ndarray:
    """Return the suspension pitch (rad, nose down positive) excited by ``ax`` (m/s^2).

    Second-order response ``theta'' + 2 zeta w theta' + w^2 theta = -w^2 k_p a_x``,
    discretised exactly for a zero-order-held input.
    """
    w = 2.0 * math.pi * params.pitch_freq_hz
    zeta = params.pitch_damping_ratio
    num, den = [-w * w * params.pitch_per_accel_rad], [1.0, 2.0 * zeta * w, w * w]
    b, a, _ = signal.cont2discrete((num, den), dt, method="zoh")
    zi = signal.lfilter_zi(b[0], a) * ax[0] if len(ax) else None
    return signal.lfilter(b[0], a, ax, zi=zi)[0] if len(ax) else ax.copy()


def simulate_run(duration_s: float, rng: np.random.Generator, params: RobotParams | None = None,
                 effect: Effect | None = None, dt: float = 0.002,
                 start_pose: tuple[float, float, float] | None = None, variant: Variant | None = None) -> TrueRun:
    """Return the true states of a run of ``duration_s`` driven by the human-like driver.

    The driver (:class:`simulation.driver.HumanDriver`) decides a command at each joystick
    message from the state then; the motors see it through :meth:`TrueDynamics.motor_inputs`;
    the body dynamics (:meth:`TrueDynamics.accel` plus process noise) and the eq. 5.75 pose
    kinematics are integrated by RK4 at ``dt``.

    Parameters
    ----------
    duration_s
        Run length, s.
    rng
        Seeded generator; same seed, same run (driver, joystick clock, noise and start pose
        draw from independent children of it).
    params, effect
        Robot parameters (default: the variant's) and at most one effect.
    dt
        Integration and output step, s (the motor controller's update period).
    start_pose
        ``(x, y, psi)`` in the local frame; default: near the area centre, heading along the
        line between the trackers (either way) with some scatter.
    variant
        Simulator variant (:class:`simulation.variant.Variant`): robot, lateral law, motor lag,
        process-noise spectrum and driver; default ``Variant()``, the simulator before variants.

    Returns
    -------
    TrueRun
        States on the grid ``t = k dt``; the pose follows eq. 5.75, the pitch
        :func:`pitch_from_accel` (plus the floor's tilt with ``heading_dependence``).
    """
    if not (np.isfinite(duration_s) and duration_s > 0):
        raise InputError(f"simulate_run: duration_s={duration_s!r} must be a positive number of seconds")
    if not (np.isfinite(dt) and 0 < dt <= 0.02):
        raise InputError(f"simulate_run: dt={dt!r} must lie in (0, 0.02] s")
    if effect is not None and not isinstance(effect, Effect):
        raise InputError(f"simulate_run: effect={effect!r} is not a simulation.effects.Effect")
    if variant is not None and not isinstance(variant, Variant):
        raise InputError(f"simulate_run: variant={variant!r} is not a simulation.variant.Variant")
    variant = variant or Variant()
    if params is not None:
        variant = replace(variant, robot=params)
    params, drv = variant.robot, variant.driver
    dyn = TrueDynamics.of_variant(variant, effect)
    rng_drv, rng_joy, rng_noise, rng_start = rng.spawn(4)
    area = DrivingArea()
    if start_pose is None:
        cx, cy = area.center_local_m
        psi_start = area.axis_angle_rad + (math.pi if rng_start.random() < 0.5 else 0.0)
        start_pose = (cx + rng_start.normal(0, 0.3), cy + rng_start.normal(0, 0.2),
                      psi_start + rng_start.normal(0, 0.3))
    n = int(round(duration_s / dt)) + 1
    t = np.arange(n) * dt
    t_joy = simulate_joy_stamps(duration_s, rng_joy, rate_hz=drv.joy_rate_hz, jitter_std_s=drv.joy_jitter_std_s,
                                min_step_s=drv.joy_min_step_s)
    u_joy = np.zeros((t_joy.size, 2))
    noise = simulate_process_noise(variant.noise, n, dt, params.accel_noise_std, params.noise_corr_time_s, rng_noise)
    n1, n2, n3 = (noise[:, i].tolist() for i in range(3))
    latency = dyn.inputs.delay_s + sum(dyn.inputs.lags_s)  # a driver gets used to a slow robot
    driver = HumanDriver(rng_drv, start_pose[2], area, params=drv, latency_s=latency)
    u_motor = np.empty((n, 2))
    integrate, _ = compile_stepper(params, effect, variant.lateral)
    memo = InputMemo() if dyn.inputs.stateful else None
    state = tuple(float(v) for v in start_pose) + (0.0, 0.0, 0.0)
    rows: list[tuple] = []
    k_msg = np.minimum(np.ceil(t_joy / dt - 1e-9).astype(int), n)  # first step a message acts on
    bounds = np.concatenate([[0], k_msg, [n]])
    for m in range(t_joy.size + 1):
        k0, k1 = int(bounds[m]), int(bounds[m + 1])
        if m > 0:
            u_joy[m - 1] = driver.command(t_joy[m - 1], *state)
        if k1 <= k0:
            continue
        um = dyn.motor_inputs(t[k0:k1], t_joy[:m], u_joy[:m], memo)
        u_motor[k0:k1] = um
        state = integrate(k0, k1, state, um.tolist(), n1, n2, n3, rows, dt)
    out = np.array(rows)
    xs, ys, psis, vxs, vys, oms = out.T
    a_body = dyn.accel(out, u_motor, t) + noise
    ax = a_body[:, 0] - vys * oms
    pitch = pitch_from_accel(ax, dt, params)
    z = np.zeros(n)
    floor = slope(effect)
    if floor is not None:
        tilt, pd = floor
        pitch = pitch + tilt * np.cos(psis - pd)
        z = -math.tan(tilt) * (xs * math.cos(pd) + ys * math.sin(pd))
    return TrueRun(t=t, x=xs.copy(), y=ys.copy(), psi=psis.copy(), vx=vxs.copy(), vy=vys.copy(),
                   omega=oms.copy(), pitch=pitch, z=z, ax=ax, u_motor=u_motor, t_joy=t_joy,
                   u_joy=u_joy, noise=noise)
