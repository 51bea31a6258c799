"""Motor heating: did the steady speed's response to the winding's thermal state change?

The thermal state is driven by the command, so it is the same feature on both sets and the pooled
residual score cannot see a changed response to it; it is identified on the speed directly, the
measured and the reference sets fitted together with one static map (``identify_heating``), and
judged with the holds as the independent units (``_clustered_se``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from ... import contract as c
from ...core import effect_features as ef
from ...physics.plant import throttle
from ...physics.scales import VOLTAGE_MID_V, centred_pwm, centred_voltage
from ...recordings import Signals

HEATING_TAU_S = 120.0  #: thermal time constant of the identification (s)
#: least extra speed loss at the measured data's hottest state, as a fraction of the fitted
#: full-drive speed: a loss of speed with the winding's resistance is in proportion to the speed
#: (5 rad/s on the nominal bench's 600 rad/s; an absolute figure would be another threshold on a
#: motor that spins twice as fast)
HEATING_MIN_DROP = 0.0083
#: ... and at least this many standard errors of the fit with the holds as the independent units
#: (one-sided p = 0.0013), so that a noisy motor's 5 rad/s is not taken for heating. Neither alone
#: suffices: with no heating anywhere, a measured load that runs hotter than the reference's (180 s
#: vs 120 s at load) can lose 3.5 rad/s at 3.6 standard errors, which only the drop stops; on the
#: simulated benches heating itself loses 9-32 rad/s at 9-39 standard errors, and the other effects
#: move the figure by -2.3 to 1.1 standard errors
HEATING_MIN_Z = 3.0
#: least thermal state the measured data must reach (~15 K above ambient on the bench): a
#: recording that barely warms the winding cannot show its heating, and a sensitivity fitted on
#: a tiny thermal range takes up whatever else differs at that range
HEATING_MIN_STATE = 0.15


@dataclass
class Heating:
    """Speed change per unit thermal state (rad/s at full drive), on the measured and the reference."""

    measured: float
    reference: float
    hottest: float  #: largest thermal state on the measured data
    #: standard error of reference - measured (rad/s per unit), clustered by hold
    se: float = math.inf
    #: the fitted steady speed at full command and the measured data's median voltage (rad/s)
    full_speed_rad_s: float = math.inf

    @property
    def drop_rad_s(self) -> float:
        """Extra speed lost on the measured data at its hottest, beyond what the reference shows."""
        return (self.reference - self.measured) * self.hottest

    @property
    def z(self) -> float:
        """The drop in standard errors (holds as the independent units)."""
        return (self.reference - self.measured) / self.se if self.se > 0 else 0.0

    @property
    def too_cool(self) -> bool:
        """The measured data never reach HEATING_MIN_STATE: they cannot show a winding's heating."""
        return self.hottest < HEATING_MIN_STATE

    @property
    def changed(self) -> bool:
        return (not self.too_cool and self.drop_rad_s >= HEATING_MIN_DROP * self.full_speed_rad_s
                and self.z >= HEATING_MIN_Z)

    def describe(self) -> str:
        # without a battery voltage (or too few settled samples) there is no static map, so no
        # full-drive speed to take the threshold from: said in words, never "inf rad/s"
        drop = (f"{HEATING_MIN_DROP * self.full_speed_rad_s:.1f} rad/s ({100 * HEATING_MIN_DROP:.2g} % of the "
                f"{self.full_speed_rad_s:.0f} rad/s at full drive)" if math.isfinite(self.full_speed_rad_s) else
                f"{100 * HEATING_MIN_DROP:.2g} % of the full-drive speed, not computed here: no battery voltage "
                "or too few settled samples, so heating is not named;")
        return (f"at the measured data's hottest thermal state ({self.hottest:.2f}, time constant "
                f"{HEATING_TAU_S:.0f} s) the steady speed is {self.drop_rad_s:.1f} rad/s lower than the "
                f"reference's response to the same state predicts ({self.z:.1f} standard errors; named from "
                f"{drop} and {HEATING_MIN_Z:g} standard errors at a thermal state from {HEATING_MIN_STATE:g})")

    def as_dict(self) -> dict[str, float | None]:
        """(The full-drive speed None when it could not be computed: JSON has no infinity.)"""
        return {"measured_rad_s_per_unit": self.measured, "reference_rad_s_per_unit": self.reference,
                "hottest_thermal_state": self.hottest, "extra_drop_rad_s": self.drop_rad_s,
                "extra_drop_z": self.z,
                "full_drive_speed_rad_s": self.full_speed_rad_s if math.isfinite(self.full_speed_rad_s) else None}


def _static_map_terms(pwm: np.ndarray, v: np.ndarray) -> np.ndarray:
    """``identify_heating``'s static map, one for both sets: cubic in the PWM level, voltage and
    voltage x level (levels and volts centred on the bench's middle for conditioning)."""
    p = centred_pwm(np.asarray(pwm, dtype=float))
    v = centred_voltage(np.asarray(v, dtype=float))
    return np.column_stack([np.ones_like(p), p, p**2, p**3, v, v * p])


def identify_heating(measured: Sequence[Signals], reference: Sequence[Signals]) -> Heating:
    """Thermal sensitivity on the measured and on the reference data, fitted together.

    speed ~ cubic(pwm) + V + V pwm (one static map for both) + k_set * theta * duty with theta the
    ``thermal_load`` state: a battery that sags over a long run lowers the speed on both sets
    alike, so the shared voltage terms take that, and only a response to the winding's heat that
    differs between the sets goes into k_measured - k_reference. Samples at least 0.7 s after a
    command change (the rotor's dynamics do not enter)."""
    rows, ys, holds_, volts = [], [], [], []
    hottest = 0.0
    n_holds = 0
    for which, sigs in ((0, measured), (1, reference)):
        for s in sigs:
            pwm_t, pwm = s.pwm_events
            vt, vv = s.voltage_events
            th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
            change = np.r_[pwm_t[0], pwm_t[1:][np.diff(pwm) != 0]] if len(pwm_t) else np.zeros(1)
            k = np.searchsorted(change, s.t, side="right") - 1
            ok = ((s.t - change[np.clip(k, 0, len(change) - 1)]) >= 0.7) & np.isfinite(s.speed) \
                & np.isfinite(s.voltage) & np.isfinite(th)
            duty = throttle(s.pwm[ok], c.PWM_STOP)
            t_d = th[ok] * duty
            rows.append(np.column_stack([_static_map_terms(s.pwm[ok], s.voltage[ok]),
                                         t_d * (which == 0), t_d * (which == 1)]))
            ys.append(s.speed[ok])
            holds_.append(n_holds + k[ok])  # the hold each sample belongs to: the unit of the test
            n_holds += len(change)
            if which == 0 and ok.any():
                hottest = max(hottest, float(np.max(th[ok])))
                volts.append(s.voltage[ok])
    A, y = np.vstack(rows), np.concatenate(ys)
    if len(y) < 20:
        return Heating(0.0, 0.0, 0.0)
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    v_med = float(np.median(np.concatenate(volts))) if volts else VOLTAGE_MID_V
    full = float(_static_map_terms(np.array([c.PWM_FULL]), np.array([v_med]))[0] @ beta[:6])
    return Heating(float(beta[6]), float(beta[7]), hottest,
                   _clustered_se(A, y - A @ beta, np.concatenate(holds_), np.array([0, 0, 0, 0, 0, 0, -1, 1])),
                   full if full > 0.0 else math.inf)


def _clustered_se(A: np.ndarray, resid: np.ndarray, cluster: np.ndarray, contrast: np.ndarray) -> float:
    """Standard error of ``contrast @ beta`` with residuals correlated within a cluster (CR1).

    By hand because the samples of one hold share a slow error (noise filtered by the rotor, the
    battery's drift), so the textbook standard error is far too small; scipy and numpy offer
    no cluster-robust covariance and statsmodels is not worth a dependency for one sandwich."""
    pinv = np.linalg.pinv(A.T @ A)
    _, inverse = np.unique(cluster, return_inverse=True)
    g = inverse.max() + 1
    if g < 3:
        return math.inf
    scores = np.zeros((g, A.shape[1]))
    np.add.at(scores, inverse, A * resid[:, None])
    n, k = A.shape
    meat = scores.T @ scores * (g / (g - 1)) * ((n - 1) / max(n - k, 1))
    var = float(contrast @ pinv @ meat @ pinv @ contrast)
    return math.sqrt(var) if var > 0 else math.inf
