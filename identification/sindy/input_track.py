"""The recorded inputs of one run as a function of time, for any input dead time and lag.

The multi-step evaluation's windows (:class:`identification.sindy.evaluate.Windows`) carry one
track per run, so that a model with input dead time or first-order input lags
(:mod:`groundfloor.input_chain`) is fed what its motors see, including the history before a
window's start. The tables that depend on the samples alone are cached on the track: an
output-error fit asks for the inputs at new dead times and lags a few hundred times.
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from functools import cached_property

import numpy as np

from groundfloor.input_chain import first_order_lags, lag_grid

#: lagged channels a track remembers (a fit's inputs, their lag sensitivities and the step before)
_LAG_MEMO = 16


@dataclass(frozen=True)
class InputTrack:
    """The recorded inputs of one run as a function of time, for any input dead time.

    ``hold="zoh"``: each sample holds until the next (what a robot does with its command
    messages; before the first sample the first one holds), averaged over ``width_s`` around
    the query time, so that a prediction is continuous, and differentiable, in the dead time
    (the average over the integration step of what the motors see). ``hold="linear"``: straight
    lines between the samples, the thesis's choice and the right one for inputs that are
    themselves samples at the pose times (:class:`~groundfloor.types.BodyStates`: a change
    between two samples happened on average half-way). Times ``t`` are relative to the start of
    the window's run (the windows' ``t0_run`` base).
    """

    t: np.ndarray  # (m,) strictly increasing sample times, s
    u: np.ndarray  # (m, 2)
    hold: str = "linear"
    width_s: float = 0.02

    # The tables below depend on the samples only: cached, since an output-error fit asks for the
    # inputs at new dead times and lags a few hundred times (cached_property writes the instance's
    # __dict__ directly, which a frozen dataclass allows).
    @cached_property
    def _cumulative(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Return knots, the integral of the held inputs at the knots (both padded far out) and the held values."""
        pad = 1e4  # seconds beyond both ends: the end values hold there
        knots = np.concatenate([[self.t[0] - pad], self.t, [self.t[-1] + pad]])
        held = np.vstack([self.u[:1], self.u])  # value on [knots[i], knots[i + 1])
        integral = np.vstack([np.zeros((1, 2)), np.cumsum(held * np.diff(knots)[:, None], axis=0)])
        return knots, integral, held

    def lagged(self, lag_s) -> "InputTrack":
        """Return the track of what the motors see through first-order lags ``lag_s (2,)``
        (:func:`groundfloor.input_chain.first_order_lag` of this track's held inputs on a uniform
        grid, joined by straight lines); the track itself when both lags are zero."""
        lag = np.asarray(lag_s, dtype=float)
        if not np.any(lag > 0.0) or len(self.t) < 2:
            return self
        key = (float(lag[0]), float(lag[1]))
        memo = self.__dict__.setdefault("_lagged_memo", {})  # the inputs and their rates ask in turn
        if key not in memo:
            if len(memo) >= 4:
                memo.clear()
            grid = self._on_lag_grid[0]
            memo[key] = InputTrack(grid, np.column_stack(self.lag_channels([(0, key[0]), (1, key[1])])), "linear")
        return memo[key]

    def lag_channels(self, keys) -> list[np.ndarray]:
        """Return input ``i`` on the lag grid through a first-order lag ``T`` for each ``(i, T)`` of
        ``keys``, remembered (a fit asks for each channel's lag again with the other channel's
        perturbed, the lag sensitivities); those not remembered computed side by side in one pass
        (:func:`groundfloor.input_chain.first_order_lags`)."""
        memo = self.__dict__.setdefault("_lag_memo", {})
        keys = [(int(i), float(T)) for i, T in keys]
        found = {k: memo[k] for k in keys if k in memo}
        missing = [k for k in dict.fromkeys(keys) if k not in found]
        if missing:
            grid, _ = self._on_lag_grid
            rows = first_order_lags(self._grid_channels, float(grid[1] - grid[0]), [i for i, _ in missing],
                                    [T for _, T in missing])
            if len(memo) + len(missing) > _LAG_MEMO:
                memo.clear()
            for k, row in zip(missing, rows):
                memo[k] = found[k] = row
        return [found[k] for k in keys]

    def lagged_at(self, i: int, lag_s, t_query: np.ndarray, delay_s) -> np.ndarray:
        """Return input ``i`` of ``self.lagged(lag_s).at(t_query, delay_s)``, the other input not evaluated."""
        lag = np.asarray(lag_s, dtype=float)
        if not np.any(lag > 0.0) or len(self.t) < 2:
            return self.at(t_query, delay_s)[..., i]
        return np.interp(np.asarray(t_query, float) - float(np.asarray(delay_s, float)[i]), self._on_lag_grid[0],
                         self.lag_channels([(i, lag[i])])[0])

    def __getstate__(self) -> dict:
        """Return the fields alone (what is pickled): the cached tables are rebuilt where needed."""
        return {f.name: getattr(self, f.name) for f in fields(self)}

    @cached_property
    def _on_lag_grid(self) -> tuple[np.ndarray, np.ndarray]:
        """Return the uniform grid of :meth:`lagged` and the inputs on it (before any lag)."""
        grid = lag_grid(self.t)
        return grid, self.at(grid)

    @cached_property
    def _grid_channels(self) -> np.ndarray:
        """Return the inputs on the lag grid as rows ``(2, m)`` (each contiguous: what the lags filter)."""
        return np.ascontiguousarray(self._on_lag_grid[1].T)

    def at(self, t_query: np.ndarray, delay_s=(0.0, 0.0)) -> np.ndarray:
        """Return the inputs ``u_i(t - d_i)`` ``(*t_query.shape, 2)``; ``delay_s`` is ``(2,)`` or
        ``(M, 2)`` (then ``(M, *t_query.shape, 2)``)."""
        return self._eval(t_query, delay_s, rate=False)

    def rate(self, t_query: np.ndarray, delay_s=(0.0, 0.0)) -> np.ndarray:
        """Return the time derivative of :meth:`at` (same shape): what a dead time's sensitivity needs."""
        return self._eval(t_query, delay_s, rate=True)

    def _eval(self, t_query, delay_s, rate: bool) -> np.ndarray:
        d = np.asarray(delay_s, dtype=float)
        tq = np.asarray(t_query, dtype=float)
        if d.ndim == 2:
            return np.stack([self._eval(tq, row, rate) for row in d])
        out = np.empty(tq.shape + (2,))
        if self.hold == "linear":
            for i in range(2):
                q = tq - d[i]
                if rate and len(self.t) < 2:
                    out[..., i] = 0.0
                elif rate:  # the slope of the line the query falls on (taken at the queries alone: a
                    # lagged track is new at every step of a fit, and far longer than its queries)
                    k = np.searchsorted(self.t, q, side="right") - 1
                    inside = (k >= 0) & (k < len(self.t) - 1)
                    k = np.clip(k, 0, len(self.t) - 2)
                    slope = (self.u[k + 1, i] - self.u[k, i]) / (self.t[k + 1] - self.t[k])
                    out[..., i] = np.where(inside, slope, 0.0)
                else:
                    out[..., i] = np.interp(q, self.t, self.u[:, i])
            return out
        knots, integral, held = self._cumulative
        h = 0.5 * self.width_s
        for i in range(2):
            q = tq - d[i]
            if rate:
                k_hi = np.clip(np.searchsorted(knots, q + h, side="right") - 1, 0, len(held) - 1)
                k_lo = np.clip(np.searchsorted(knots, q - h, side="right") - 1, 0, len(held) - 1)
                out[..., i] = (held[k_hi, i] - held[k_lo, i]) / self.width_s
            else:
                out[..., i] = (_integral_at(q + h, knots, integral[:, i], held[:, i])
                               - _integral_at(q - h, knots, integral[:, i], held[:, i])) / self.width_s
        return out


def _integral_at(q: np.ndarray, knots: np.ndarray, integral: np.ndarray, held: np.ndarray) -> np.ndarray:
    """Return the integral of the held input at ``q``: interpolated between the knots, and beyond the
    padded ends continued with the end values (``np.interp`` alone would hold the integral constant
    there, so an input queried more than the padding past the track would read 0)."""
    out = np.interp(q, knots, integral)
    out = np.where(q > knots[-1], integral[-1] + held[-1] * (q - knots[-1]), out)
    return np.where(q < knots[0], integral[0] - held[0] * (knots[0] - q), out)
