"""The first-principles fallback the estimator runs until a model is trained: rough, nominal
constants only, the same interface as a model file's model (``core.estimator.SpeedModel``).

Steady state of a DC motor driving a propeller: the ESC applies ``duty * V`` to the motor, the
back-EMF is ``ke w`` (ke = 1/Kv) and the current ``kQ w^2 / ke`` carries the propeller torque
``kQ w^2``, so

    duty V = R kQ w^2 / ke + ke w  ->  w = 2 duty V / (ke + sqrt(ke^2 + 4 R kQ duty V / ke)).

``duty`` is ``pwm_filtered`` (the paper's 0.25 s command lag standing in for the rotor's
inertia) above the ESC's start level (PWM 0.055 = 0.1 of the scaled range), rescaled to 0..1.
Nominal AXI 2212/34 (Kv 710 rpm/V) with a 12x4.5 propeller: R = 0.25 Ohm for the winding plus
ESC, kQ = 5.5e-7 N m s^2. No no-load current, no battery sag model beyond the measured voltage,
no temperature: expect errors of 10-20 %.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import contract as c

#: b of a 12x4.5 propeller, CT rho D^4 / (4 pi^2) with CT ~ 0.105: rough; the fallback's, and a
#: network model's when none is given (a trained model's b is measured, stated, or absent)
NOMINAL_THRUST_COEFFICIENT = 2.8e-5


@dataclass(frozen=True)
class FallbackModel:
    """First-principles stand-in for a trained model (see the module doc): inputs
    (battery_voltage, pwm, pwm_filtered), speed in rad/s."""

    kv_rpm_per_v: float = 710.0
    resistance_ohm: float = 0.25
    torque_coefficient: float = 5.5e-7  #: kQ, N m s^2/rad^2
    start_fraction: float = 0.1  #: scaled PWM where the ESC starts the motor (level 0.055)
    pwm_tau_s: float = c.PAPER_PWM_TAU_S
    thrust_coefficient: float = NOMINAL_THRUST_COEFFICIENT
    input_names: tuple[str, ...] = c.DEFAULT_INPUTS
    metadata: dict[str, Any] = field(default_factory=lambda: {"kind": "first-principles fallback"})
    is_fallback: bool = True

    @property
    def input_min(self) -> np.ndarray:
        return np.array([0.0, 0.0, 0.0])  # battery_voltage (V), pwm, pwm_filtered

    @property
    def input_max(self) -> np.ndarray:
        return np.array([60.0, 1.0, 1.0])

    def feature_params(self) -> dict[str, dict[str, float]]:
        return {c.INPUT_PWM_FILTERED: {"tau_s": self.pwm_tau_s}}

    def forward(self, X_raw: np.ndarray) -> np.ndarray:
        """Speed (rad/s) from rows of (battery_voltage, pwm, pwm_filtered): :meth:`forward_one`
        row by row (the estimator calls that on one row; a batch is rare and short)."""
        X = np.asarray(X_raw, dtype=float)
        rows = X.reshape(-1, X.shape[-1]).tolist()
        return np.array([self.forward_one(r) for r in rows], dtype=float).reshape(X.shape[:-1])

    def forward_one(self, x: list[float]) -> float:
        """Speed (rad/s) of one row of raw inputs, in plain floats (20x cheaper than numpy on
        one row); a NaN input gives NaN."""
        volts, pwm_f = x[0], x[2]
        ke = 60.0 / (2.0 * math.pi * self.kv_rpm_per_v)  # V s/rad
        duty = (pwm_f - self.start_fraction) / (1.0 - self.start_fraction)
        duty = min(max(duty, 0.0), 1.0) if duty == duty else duty  # clipped to 0..1; NaN stays NaN
        vm = duty * (volts if volts > 0.0 or volts != volts else 0.0)  # the voltage, >= 0; NaN stays NaN
        a = self.resistance_ohm * self.torque_coefficient / ke
        return 2.0 * vm / (ke + math.sqrt(ke * ke + 4.0 * a * vm))


def fallback_model() -> FallbackModel:
    """The documented first-principles fallback (see :class:`FallbackModel`): rough."""
    return FallbackModel()
