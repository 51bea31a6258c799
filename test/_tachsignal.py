"""Synthetic phototransistor signal from a known rotor angle, for the tachometer tests.

The rotor angle theta(t) is integrated from a speed function on a grid ``oversample`` times
finer than the ADC, the beam is blocked while a blade covers it, the phototransistor follows
with a first-order lag, and the ADC samples it with Gaussian noise.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np
from scipy import signal


@dataclass
class TachSignal:
    t0: float  #: time of the first ADC sample
    rate_hz: float
    x: np.ndarray  #: ADC samples (V)
    t_fine: np.ndarray
    theta_fine: np.ndarray

    def theta(self, t: np.ndarray) -> np.ndarray:
        """True rotor angle (rad) at times t."""
        return np.interp(t, self.t_fine, self.theta_fine)

    def mean_speed(self, ta: np.ndarray, tb: np.ndarray) -> np.ndarray:
        """True mean speed (rad/s) over [ta, tb]: what a one-revolution estimate measures."""
        return (self.theta(tb) - self.theta(ta)) / (tb - ta)


def make_signal(
    speed: Callable[[np.ndarray], np.ndarray] | float,
    duration_s: float,
    *,
    rate_hz: float = 20000.0,
    blades: int = 2,
    blade_width: float = 0.05,  # fraction of a revolution each blade blocks (2 blades: 10 %)
    spacing_asym: float = 0.0,  # blade 2 offset, as a fraction of the blade spacing
    width_asym: float = 0.0,  # blade 2 wider by this fraction
    high_v: float = 4.5,
    low_v: float = 0.3,
    tau_s: float = 25e-6,
    noise_v: float = 0.02,
    seed: int = 0,
    oversample: int = 16,
    t0: float = 0.0,
    theta0: float = 0.3,
) -> TachSignal:
    n = int(round(duration_s * rate_hz))
    fine_rate = rate_hz * oversample
    t_fine = t0 + np.arange(n * oversample) / fine_rate
    w = np.full(len(t_fine), float(speed)) if np.isscalar(speed) else np.asarray(speed(t_fine), float)
    theta = theta0 + np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) / fine_rate)))
    blocked = np.zeros(len(t_fine), dtype=bool)
    spacing = 2 * np.pi / blades
    for j in range(blades):
        width = blade_width * 2 * np.pi * (1.0 + (width_asym if j == 1 else 0.0))
        centre = j * spacing + (spacing_asym * spacing if j == 1 else 0.0)
        blocked |= np.mod(theta - centre + width / 2, 2 * np.pi) < width
    ideal = np.where(blocked, low_v, high_v)
    alpha = 1.0 - np.exp(-1.0 / (fine_rate * tau_s))
    lagged, _ = signal.lfilter([alpha], [1.0, alpha - 1.0], ideal, zi=[(1.0 - alpha) * ideal[0]])
    rng = np.random.default_rng(seed)
    x = lagged[::oversample] + rng.normal(0.0, noise_v, n)
    return TachSignal(t0, rate_hz, x, t_fine, theta)


def first_order_steps(w0: float, steps: list[tuple[float, float]], tau_s: float = 0.1):
    """Speed function: w0, then at each (t_step, new speed) a first-order move (tau_s) to it."""

    def f(t: np.ndarray) -> np.ndarray:
        w = np.full(len(t), float(w0))
        prev = float(w0)
        for ts, target in steps:
            after = t >= ts
            w[after] += (target - prev) * (1.0 - np.exp(-(t[after] - ts) / tau_s))
            prev = target
        return w

    return f
