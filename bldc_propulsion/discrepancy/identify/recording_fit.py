"""The rotor's response fitted over whole recordings: dead time, spin-up and spin-down time
constants (``identify_dynamics``) and the ESC start level (``identify_start_level``).

speed ~ cubic(x) + linear(V) + V * x, with x the command delayed and passed through an
asymmetric first-order lag: the parameters the network's added input gets unless the step
responses or the holds fixed them. Fitted over whole recordings, the three time quantities
trade off against each other and against the operating points each set visits, so which one
CHANGED is read from the step responses (``steps.py``) where there are enough of them.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ... import contract as c
from ...core import effect_features as ef
from ...physics.lag import asymmetric_lag_on_times, lag_gain, lag_step
from ...physics.plant import throttle
from ...physics.scales import centred_pwm, centred_voltage
from ...recordings import Signals

#: Grids of the direct identification of the rotor's response (s).
ID_DELAYS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1)
ID_TAU_UP = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3)
ID_TAU_DOWN = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)
#: ESC start levels tried (PWM level) when esc_deadband is a candidate (identify_start_level: the start
#: level goes in before the lag, since a rotor commanded below it coasts down to zero like one that is
#: not braked, so a coast to zero is not taken for a slower spin-down), and the rise that counts.
ID_START_LEVELS = tuple(round(0.05 + 0.001 * k, 3) for k in range(11))  # 0.050 ... 0.060
START_LEVEL_MARGIN = 0.002  #: PWM level: twice the grid step (0.001), so one step of noise is no change


@dataclass
class Dynamics:
    """The rotor's response identified from command to measured speed (not from a residual)."""

    delay_s: float
    tau_up_s: float
    tau_down_s: float
    rmse_rad_s: float
    start_level: float = c.PWM_STOP  #: ESC start level (PWM level), when it was identified

    def as_dict(self) -> dict[str, float]:
        return {"dead_time_s": self.delay_s, "start_level_pwm": self.start_level,
                "spin_up_time_constant_s": self.tau_up_s,
                "spin_down_time_constant_s": self.tau_down_s, "fit_rmse_rad_s": self.rmse_rad_s}


def identify_dynamics(signals: Sequence[Signals]) -> Dynamics:
    """Dead time and spin-up/spin-down time constants that best explain the measured speed.

    speed ~ cubic(x) + linear(V) + V * x, with x the command delayed by d and passed through a
    first-order lag of tau_up while rising and tau_down while falling (state from rest). The
    grid (d, tau_up, tau_down) is searched exhaustively; all lags are run at once, vectorised
    over the grid, on the recordings' 100 Hz grid.
    """
    combos = [(tu, td) for tu in ID_TAU_UP for td in ID_TAU_DOWN]
    tu = np.array([x[0] for x in combos])
    td = np.array([x[1] for x in combos])
    sse = np.zeros((len(ID_DELAYS), len(combos)))
    n_total = 0
    for s in signals:
        ok = np.isfinite(s.speed) & np.isfinite(s.voltage)
        dt = float(np.median(np.diff(s.t)))
        g_up, g_dn = lag_gain(dt, tu), lag_gain(dt, td)
        v = centred_voltage(s.voltage)
        y = s.speed[ok]
        n_total += len(y)
        pwm_t, pwm = s.pwm_events
        for i, d in enumerate(ID_DELAYS):
            u = ef._held(pwm_t, pwm, s.t - d)
            X = np.empty((len(s.t), len(combos)))
            state = np.full(len(combos), c.PWM_STOP)
            for k in range(len(s.t)):
                uk = u[k]
                state = lag_step(state, uk, np.where(uk > state, g_up, g_dn))
                X[k] = state
            X = centred_pwm(X[ok])
            vv = v[ok]
            for j in range(len(combos)):
                x = X[:, j]
                A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
                beta, *_ = np.linalg.lstsq(A, y, rcond=None)
                sse[i, j] += float(np.sum((y - A @ beta) ** 2))
    best_i, best_j = (int(k) for k in np.unravel_index(int(np.argmin(sse)), sse.shape))
    return Dynamics(float(ID_DELAYS[best_i]), float(tu[best_j]), float(td[best_j]),
                    float(np.sqrt(sse[best_i, best_j] / max(n_total, 1))))


def identify_start_level(signals: Sequence[Signals], dyn: Dynamics) -> float:
    """ESC start level that best explains the speed, the dead time and time constants held at
    ``dyn``'s (a scan of ID_START_LEVELS; one lag per level, so cheap next to identify_dynamics)."""
    sse = np.zeros(len(ID_START_LEVELS))
    for s in signals:
        ok = np.isfinite(s.speed) & np.isfinite(s.voltage)
        pwm_t, pwm = s.pwm_events
        u0 = ef._held(pwm_t, pwm, s.t - dyn.delay_s)
        vv = centred_voltage(s.voltage)[ok]
        for i, thr in enumerate(ID_START_LEVELS):
            u = c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * throttle(u0, thr)
            x = asymmetric_lag_on_times(s.t, u, dyn.tau_up_s, dyn.tau_down_s, c.PWM_STOP)
            x = centred_pwm(x[ok])
            A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
            beta, *_ = np.linalg.lstsq(A, s.speed[ok], rcond=None)
            sse[i] += float(np.sum((s.speed[ok] - A @ beta) ** 2))
    return float(ID_START_LEVELS[int(np.argmin(sse))])
