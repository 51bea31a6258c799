"""The command and the battery voltage centred and scaled for regressions on them.

The discrepancy workflow fits polynomials of the command and the supply (the speed's static map,
residual corrections); centred on the middle of their ranges and scaled to about [-1, 1] they
keep those least-squares problems well conditioned. One definition for every such regression
(discrepancy/effects.py, discrepancy/identify.py), so that their columns mean the same.
"""

from __future__ import annotations

from typing import TypeVar

import numpy as np

Value = TypeVar("Value", float, np.ndarray)

#: The middle of the command's range, PWM_STOP..PWM_FULL (PWM level), and half its width: the
#: centred command is -1 at stop and +1 at full.
PWM_MID = 0.075
PWM_HALF_RANGE = 0.025
#: The middle of a 3S pack's voltage (V): 12.6 V full, about 10.5 V sagging when low.
VOLTAGE_MID_V = 11.5


def centred_pwm(level: Value) -> Value:
    """PWM level -> the centred command (-1 at stop, 0 at mid range, +1 at full)."""
    return (level - PWM_MID) / PWM_HALF_RANGE


def centred_voltage(volts: Value) -> Value:
    """Battery voltage (V) -> its deviation from the middle of a 3S pack's range (V)."""
    return volts - VOLTAGE_MID_V
