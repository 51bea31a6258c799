"""Hand-made health-monitor data shared by the monitor's tests: flights of holds whose residual,
voltage and fault signatures are known exactly (no plant, no model error)."""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from bldc_propulsion.core.health import HealthConfig, HealthEvent, HealthMonitor, HealthSample, TwinSample

TAU_S = 2.0  #: the battery filter's time constant in the hand-made data


Change = tuple[float, np.ndarray, float, float]  #: (theta, speed signature weights, dv ohm, onset s)


def synthetic_flight(duration_s: float, seed: int, change: Change | list[Change] | None = None, *,
                     speeds: Callable[[float], tuple[float, float]] = lambda t: (150.0, 600.0),
                     noise_rad_s: Callable[[float], float] = lambda level: 1.0,
                     dither_rad_s: float = 0.0, ocv_visit_v: float = 0.0,
                     voltage_noise_v: Callable[[float], float] = lambda amps: 0.02,
                     terminal_v: Callable[[float, float], float] = lambda t, amps: 0.0) -> list[HealthSample]:
    """A flight of holds at random speeds, 100 speed samples a second: measured = predicted +
    noise (one-sigma ``noise_rad_s(speed)``; + ``change``: from onset t0, theta * the speed
    signature and dv volts of extra sag per ampere; a list of changes adds up, each from its own
    onset), the terminal voltage 12 V - 0.04 ohm * i through a first-order filter of TAU_S. Each
    hold (1-4 s) is at a speed drawn from ``speeds(t)``. The signatures: each fault's speed change
    per unit grows with the speed, in its own way. ``dither_rad_s``: the predicted speed also
    moves by a new N(0, dither) every 20 ms frame, as a multirotor's motor does under its
    attitude loop (the model follows it exactly). ``ocv_visit_v``: each hold's open-circuit
    voltage is off the 12 V by a new N(0, ocv_visit_v) (a pack's polarisation and charge, which the
    monitor fits along, predicted only to a few mV from one visit to the next);
    ``voltage_noise_v(current)``: the terminal voltage's noise per sample (one sigma);
    ``terminal_v(t, current)``: volts added to the terminal voltage (a pack's curve in the current
    that no line fits, a step no fault explains)."""
    rng = np.random.default_rng(seed)
    out = []
    level, hold_end, dt, ocv = 300.0, 0.0, 0.01, 12.0
    v_f = None
    wobble = 0.0
    changes = [] if change is None else change if isinstance(change, list) else [change]
    for k in range(int(duration_s / dt)):
        t = k * dt
        if t >= hold_end:
            level = float(rng.uniform(*speeds(t)))
            hold_end = t + float(rng.uniform(1.0, 4.0))
            ocv = 12.0 + (float(rng.normal(0.0, ocv_visit_v)) if ocv_visit_v > 0.0 else 0.0)
        if k % 2 == 0:
            wobble = float(rng.normal(0.0, dither_rad_s)) if dither_rad_s > 0.0 else 0.0
        speed = level + wobble
        u = speed / 600.0
        current = 12.0 * u**2
        sens = (60.0 * u**2, -400.0 * u**2 * current / 12.0, -20.0 * (1.2 - u), -0.6 * u**2)
        dcur = (-1.0 * u**2, 0.0, 0.8, -0.02 * u**2)
        on = [c for c in changes if t >= c[3]]
        v_term = (ocv - 0.04 * current - sum(dv * current for _, _, dv, _ in on) + terminal_v(t, current)
                  + rng.normal(0.0, voltage_noise_v(current)))
        v_f = v_term if v_f is None else v_f + (1.0 - math.exp(-dt / TAU_S)) * (v_term - v_f)
        measured = (speed + rng.normal(0.0, noise_rad_s(speed))
                    + sum(theta * float(np.dot(shape, sens)) for theta, shape, _, _ in on))
        out.append(HealthSample(t, measured, speed, v_f, TwinSample(t, speed, current, sens, dcur, 40.0)))
    return out


def monitor_over(samples: list[HealthSample], config: HealthConfig | None = None) -> HealthMonitor:
    """A monitor of the hand-made data's constants, run over ``samples``."""
    mon = HealthMonitor(TAU_S, speed_scale_rad_s=650.0, pack_resistance_ohm=0.04, config=config)
    for s in samples:
        mon.update(s)
    mon.finish()
    return mon


def monitor_events(samples: list[HealthSample]) -> list[HealthEvent]:
    """The events a monitor of the hand-made data's constants reports over ``samples``."""
    return monitor_over(samples).events
