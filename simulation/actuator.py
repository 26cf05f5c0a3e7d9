"""What the motors see: the joystick messages through the input-side mechanisms, exact at any time.

The chain, for joystick messages ``u_j`` received at ``t_j`` (s since run start)::

    u_m(t) = clip(g(t) L[clip(P(u_zoh(t - d)))](t))

- ``u_zoh(t - d)``: zero-order hold of the messages (zero before the first), delayed by the
  transport delay ``d`` (``input_delay:transport``);
- ``P``: the static or switching input mechanisms (``deadband`` forms, the input forms of
  ``asymmetry``), then saturation to [-1, 1];
- ``L``: first-order lags ``tau y' = x - y`` in series: the variant's motor lag
  (:class:`simulation.variant.Variant`) and ``input_delay:motor_lag``. Their input is piecewise
  constant (it changes only at the messages), so they are integrated exactly: a closed form over
  each held message, their states carried from message to message, starting at rest on the
  value before the first message;
- ``g(t)``: the battery-sag gain of ``time_dependence`` (time since run start).

Without lags or hysteresis the chain has no state and is evaluated at once on numpy arrays
(the simulator's path before forms existed, float for float). With them, the states at the
messages are computed in message order; :class:`InputMemo` keeps them between the calls of one
simulated run, whose history only grows, so that each message is processed once.
"""

from __future__ import annotations

import math

import numpy as np

from simulation.effects import Effect

DECAY_REF_S = 600.0  # time_dependence: the loss v is reached 10 minutes after the run start


class InputMemo:
    """States of a stateful chain at the messages processed so far (one simulated run)."""

    def __init__(self):
        self.c: list[np.ndarray] = []  # (2,) held value after P at each message
        self.y: list[np.ndarray] = []  # (n_lags, 2) lag states just before each message acts
        self.engaged = np.zeros(2, dtype=bool)  # hysteresis: is each motor moving


class InputChain:
    """The input side of the true dynamics: an effect's input mechanism and the motor lags.

    Parameters
    ----------
    effect
        At most one :class:`simulation.effects.Effect` (body-side effects leave the chain plain).
    motor_lag_s
        The robot's own motor lag (0: none).
    """

    def __init__(self, effect: Effect | None = None, motor_lag_s: float = 0.0):
        name, form = (effect.name, effect.form) if effect is not None else (None, None)
        self.effect = effect
        self.delay_s = effect.value if (name, form) == ("input_delay", "transport") else 0.0
        lags = [float(motor_lag_s)] if motor_lag_s > 0 else []
        if (name, form) == ("input_delay", "motor_lag"):
            lags.append(float(effect.value))
        self.lags_s = tuple(lags)
        self.hysteresis = (name, form) == ("deadband", "hysteresis")
        self.stateful = bool(self.lags_s) or self.hysteresis

    def motor_inputs(self, t_query, t_joy, u_joy, memo: InputMemo | None = None) -> np.ndarray:
        """Return the ``(n, 2)`` inputs the motors see at ``t_query`` (s since run start).

        ``t_joy (m,)`` increasing and ``u_joy (m, 2)`` are the joystick messages so far. A
        ``memo`` caches the states at the messages between calls whose histories extend one
        another (the simulator's loop); without it they are computed from the first message.
        """
        t_query = np.atleast_1d(np.asarray(t_query, float))
        t_joy, u_joy = np.asarray(t_joy, float), np.asarray(u_joy, float).reshape(-1, 2)
        t_eff = t_query - self.delay_s if self.delay_s else t_query
        idx = np.searchsorted(t_joy, t_eff, side="right") - 1
        if self.stateful:
            u = self._lagged(t_eff, idx, t_joy, u_joy, memo if memo is not None else InputMemo())
        else:
            u = np.zeros((t_query.size, 2))
            if len(u_joy):
                u = np.where((idx >= 0)[:, None], u_joy[np.maximum(idx, 0)], 0.0)
            u = np.clip(self._pre_map(u), -1.0, 1.0)
        return np.clip(self._decay(u, t_query), -1.0, 1.0)

    # -- P: static input mechanisms -------------------------------------------------------
    def _pre_map(self, u: np.ndarray) -> np.ndarray:
        """Return the static input mechanism of the effect applied to held inputs ``(n, 2)``."""
        eff = self.effect
        if eff is None:
            return u
        v = eff.value
        if (eff.name, eff.form) == ("deadband", "hard"):
            return np.sign(u) * np.maximum(np.abs(u) - v, 0.0) / (1.0 - v)
        if (eff.name, eff.form) == ("deadband", "soft"):
            return (u - v * np.tanh(u / v)) / (1.0 - v * math.tanh(1.0 / v))
        if (eff.name, eff.form) == ("asymmetry", "gain"):
            h = v / 2.0
            return np.column_stack([u[:, 0] + h * u[:, 1], u[:, 1] + h * u[:, 0]])
        if (eff.name, eff.form) == ("asymmetry", "steering_offset"):
            return np.column_stack([u[:, 0], u[:, 1] + v])
        if (eff.name, eff.form) == ("asymmetry", "coupling"):
            return np.column_stack([u[:, 0], u[:, 1] + v * u[:, 0]])
        return u

    def _hysteresis(self, u: np.ndarray, engaged: np.ndarray) -> np.ndarray:
        """Return the stiction output of one held input ``(2,)``, updating ``engaged`` in place."""
        v = self.effect.value
        r = self.effect.param("release_ratio") * v
        a = np.abs(u)
        engaged[:] = np.where(engaged, a > r, a >= v)
        return np.where(engaged, np.sign(u) * (a - r) / (1.0 - r), 0.0)

    def _held_value(self, u: np.ndarray, memo: InputMemo) -> np.ndarray:
        """Return ``clip(P(u))`` of one message ``(2,)`` (hysteresis state in ``memo``)."""
        if self.hysteresis:
            return np.clip(self._hysteresis(u, memo.engaged), -1.0, 1.0)
        return np.clip(self._pre_map(u[None, :])[0], -1.0, 1.0)

    # -- L: lags ------------------------------------------------------------------------------
    def _propagate(self, y0: np.ndarray, c: np.ndarray, s: np.ndarray) -> np.ndarray:
        """Return the lag states ``(..., n_lags, 2)`` a time ``s (...)`` after ``y0`` with input ``c (..., 2)``.

        Exact for a held input: one lag relaxes as ``c + (y - c) e^{-s/tau}``; the second, fed
        by the first, as ``c + e2 e^{-b s} + b e1 (e^{-a s} - e^{-b s}) / (b - a)`` with
        ``a, b = 1/tau1, 1/tau2`` and ``e = y - c`` (its limit ``b e1 s e^{-b s}`` when
        ``a = b``, used where ``|b - a| s`` is tiny so that the difference does not cancel).
        """
        s = np.asarray(s, float)[..., None]
        e1 = y0[..., 0, :] - c
        a = 1.0 / self.lags_s[0]
        ea = np.exp(-a * s)
        out = [c + e1 * ea]
        if len(self.lags_s) == 2:
            e2 = y0[..., 1, :] - c
            b = 1.0 / self.lags_s[1]
            eb = np.exp(-b * s)
            d = b - a
            small = np.abs(d * s) < 1e-3
            ds = np.where(small, 0.0, d)
            frac = np.where(small, s * eb * (1.0 + 0.5 * d * s + (d * s) ** 2 / 6.0),
                            (ea - eb) / np.where(small, 1.0, ds))
            out.append(c + e2 * eb + b * e1 * frac)
        return np.stack(out, axis=-2)

    def _lagged(self, t_eff: np.ndarray, idx: np.ndarray, t_joy: np.ndarray, u_joy: np.ndarray,
                memo: InputMemo) -> np.ndarray:
        """Return ``L[clip(P(u_zoh))]`` at ``t_eff``: states at the messages, then the closed form."""
        n_lag = len(self.lags_s)
        if not memo.c:  # before the first message: at rest on the value of a zero input
            memo.c_before = self._held_value(np.zeros(2), memo)
            memo.engaged[:] = False
        c_before = memo.c_before
        need = int(idx.max()) + 1 if idx.size else 0
        for j in range(len(memo.c), need):
            if j == 0:
                y = np.repeat(c_before[None, :], n_lag, axis=0)
            else:
                y = self._propagate(memo.y[j - 1], memo.c[j - 1], t_joy[j] - t_joy[j - 1]) if n_lag else None
            memo.y.append(y)
            memo.c.append(self._held_value(u_joy[j], memo))
        out = np.repeat(c_before[None, :], t_eff.size, axis=0)
        after = idx >= 0
        if after.any():
            j = idx[after]
            c = np.array([memo.c[i] for i in j])
            if n_lag:
                y0 = np.array([memo.y[i] for i in j])
                out[after] = self._propagate(y0, c, t_eff[after] - t_joy[j])[..., -1, :]
            else:
                out[after] = c
        return out

    # -- g: battery sag -----------------------------------------------------------------------
    def _decay(self, u: np.ndarray, t: np.ndarray) -> np.ndarray:
        """Return ``u`` times the time_dependence gain of the effect's form at ``t``."""
        eff = self.effect
        if eff is None or eff.name != "time_dependence":
            return u
        return u * decay_gain(eff, t)[:, None]


def decay_gain(effect: Effect, t) -> np.ndarray:
    """Return the input gain ``g(t)`` of a ``time_dependence`` effect at ``t`` (s since run start)."""
    t = np.asarray(t, float)
    v = effect.value
    if effect.form == "exponential":
        return np.exp(t / DECAY_REF_S * math.log1p(-v))
    if effect.form == "late":
        t_on = effect.param("onset_s")
        return np.maximum(1.0 - v * np.maximum(t - t_on, 0.0) / (DECAY_REF_S - t_on), 0.0)
    if effect.form == "early":
        tau = effect.param("tau_s")
        return 1.0 - v * -np.expm1(-np.maximum(t, 0.0) / tau) / -math.expm1(-DECAY_REF_S / tau)
    return np.maximum(1.0 - v * t / DECAY_REF_S, 0.0)
