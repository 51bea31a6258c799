"""The first-order lag dy/dt = (u - y) / tau of an input held between time points, exactly.

Over a step of h seconds with u held, y covers the share g = 1 - exp(-h / tau) of its way to u:
y <- y + g (u - y). ``lag_gain`` computes g (as 1 - exp(-h / tau): the digits -expm1 would keep
on short steps are far below what the models resolve, and this form keeps every fitted constant
and published figure what it was; 1 for tau <= 0: no lag, 0 for h <= 0), ``lag_step``
takes the step; both work on floats and on arrays alike. ``lag_on_times`` runs a whole input
sequence at once (vectorised), ``asymmetric_lag_on_times`` with one time constant while y rises
and another while it falls.

One implementation for everything that lags: the model input ``pwm_filtered``
(core/features.py), the inputs the discrepancy workflow adds (core/effect_features.py), the
identification of the rotor's response (discrepancy/identify.py) and the supply current the
battery filter has already passed (``plant.Supply``).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import TypeVar, overload

import numpy as np

Value = TypeVar("Value", float, np.ndarray)


@overload
def lag_gain(h: float, tau: float) -> float: ...
@overload
def lag_gain(h: np.ndarray, tau: float | np.ndarray) -> np.ndarray: ...
@overload
def lag_gain(h: float, tau: np.ndarray) -> np.ndarray: ...
def lag_gain(h: float | np.ndarray, tau: float | np.ndarray) -> float | np.ndarray:
    """Share of the way to a held input a lag of time constant ``tau`` covers in ``h`` (s)."""
    if isinstance(h, np.ndarray) or isinstance(tau, np.ndarray):
        taus = np.asarray(tau, dtype=float)
        g = 1.0 - np.exp(-np.maximum(h, 0.0) / np.where(taus > 0.0, taus, 1.0))
        out: np.ndarray = np.where(np.asarray(h) > 0.0, np.where(taus > 0.0, g, 1.0), 0.0)
        return out
    if not h > 0.0:
        return 0.0
    return 1.0 - math.exp(-h / tau) if tau > 0.0 else 1.0


def lag_step(y: Value, u: Value | float, g: Value | float) -> Value:
    """The lag's state after a step that covers the share ``g`` (``lag_gain``) of the way to ``u``."""
    return y + g * (u - y)


def lag_on_times(times: np.ndarray, u: np.ndarray, tau_s: float, y0: float) -> np.ndarray:
    """y at ``times`` of dy/dt = (u - y)/tau where u[k] is held on [times[k], times[k+1]).

    y[0] = y0. Exact for a piecewise-constant input: y[k+1] = u[k] + (y[k] - u[k]) exp(-h/tau).
    Vectorised with cumulative products in chunks (so they never underflow); tau = 0 gives y = u
    held (y[k] = u[k-1]: the value reached at the end of each interval).
    """
    n = len(times)
    y = np.empty(n)
    if n == 0:
        return y
    y[0] = y0
    if n == 1:
        return y
    h = np.diff(times)
    if tau_s <= 0.0:
        y[1:] = u[:-1]
        return y
    x = h / tau_s  # decay exponent of each interval
    start = 0  # interval index where the current chunk begins
    y_start = y0
    m = n - 1
    while start < m:
        # chunk: as many intervals as keep the cumulative exponent below 300
        cum = np.cumsum(x[start:])
        stop = start + max(1, int(np.searchsorted(cum, 300.0, side="right")))
        stop = min(stop, m)
        xs = x[start:stop]
        us = u[start:stop]
        L = np.cumsum(xs)  # exponent from chunk start to the end of each interval
        # y_end[j] = e^{-L_j} y_start + sum_{i<=j} e^{-(L_j - L_i)} (1 - e^{-x_i}) u_i
        w = np.exp(L) * (-np.expm1(-xs)) * us  # e^{L_i} (1 - e^{-x_i}) u_i
        acc = np.cumsum(w)
        y[start + 1: stop + 1] = np.exp(-L) * (y_start + acc)
        y_start = y[stop]
        start = stop
    return y


def asymmetric_lag_on_times(times: np.ndarray, u: np.ndarray, tau_up: float, tau_down: float,
                            y0: float) -> np.ndarray:
    """Like ``lag_on_times`` with tau_up while u > y and tau_down while u < y (exact per interval:
    with a held input the state moves monotonically towards it, so the direction is fixed)."""
    return _two_rate_lag(times, u, tau_up, tau_down, y0, lambda uk, yk: uk <= yk)


def switched_lag_on_times(times: np.ndarray, u: np.ndarray, tau_s: float, tau_zero_s: float,
                          y0: float) -> np.ndarray:
    """Like ``lag_on_times`` with ``tau_zero_s`` while the held input is 0 (no drive: a rotor the
    ESC does not brake coasts) and ``tau_s`` otherwise (exact per interval of a held input)."""
    return _two_rate_lag(times, u, tau_s, tau_zero_s, y0, lambda uk, _yk: uk <= 0.0)


def _two_rate_lag(times: np.ndarray, u: np.ndarray, tau_a: float, tau_b: float, y0: float,
                  use_b: Callable[[float, float], bool]) -> np.ndarray:
    """A first-order lag on held inputs whose time constant is ``tau_b`` over an interval where
    ``use_b(u, y)`` at its start, else ``tau_a``. A loop: the choice depends on the state, which
    no vectorised recurrence (``lag_on_times``, scipy.signal.lfilter) can follow."""
    n = len(times)
    y = np.empty(n)
    if n == 0:
        return y
    h = np.diff(times)
    g_a = lag_gain(h, tau_a).tolist()
    g_b = lag_gain(h, tau_b).tolist()
    yk = float(y0)
    ul = u.tolist()
    out = [yk]
    for k in range(n - 1):
        uk = ul[k]
        yk = lag_step(yk, uk, g_b[k] if use_b(uk, yk) else g_a[k])
        out.append(yk)
    y[:] = out
    return y
