"""One candidate per effect of the contract: a feature from recorded signals, and how to add it.

A candidate offers, for each value of its parameter grid, extra regression columns built from
the recorded command and battery voltage only (never from the measured speed) for the
residual-correction model of ``scoring.py``, and the model input (name + parameters) that the
network gets when the effect is added. The grids are chosen so the dynamic candidates are
specific: ``rotor_lag`` is a first-order lag judged on the spin-UP (command above the lagged
state), ``input_delay`` a pure dead time (no lag change), ``spin_down_asymmetry`` a lag whose
falling time constant is at least twice its rising one, judged on the spin-DOWN only. Since an
asymmetry of the spin-down only means something for a rotor that lags at all, ``workflow``
names ``rotor_lag`` before ``spin_down_asymmetry`` when both are new.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import contract as c
from ..core import effect_features as ef
from ..training.dataset import Signals

Params = dict[str, float]


@dataclass
class Context:
    """What the columns of one recording are built from (all on the recording's grid)."""

    sig: Signals
    prediction: np.ndarray  #: the model's predicted speed (rad/s)
    speed_scale: float  #: rad/s that maps the prediction to ~[0, 1]

    @property
    def p(self) -> np.ndarray:
        """PWM level centred and scaled to about [-1, 1]."""
        return (self.sig.pwm - 0.075) / 0.025

    @property
    def yhat(self) -> np.ndarray:
        return self.prediction / self.speed_scale


def _feature(ctx: Context, name: str, params: Params) -> np.ndarray:
    s = ctx.sig
    pwm_t, pwm = s.pwm_events
    volt_t, volt = s.voltage_events
    return ef.compute(name, s.t, pwm_t, pwm, volt_t, volt, params)


def _interacted(x: np.ndarray, ctx: Context) -> np.ndarray:
    """x, x * pwm, x * prediction: the effect's size may depend on the operating point."""
    return np.column_stack([x, x * ctx.p, x * ctx.yhat])


@dataclass
class Candidate:
    """An effect as a hypothesis the data can confirm or reject."""

    effect: str
    input_name: str  #: model input added when the effect is added
    grid: list[Params]  #: parameter values tried (fitted by choosing the best on training blocks)
    columns: Callable[[Context, Params], np.ndarray]
    describe: Callable[[Params], str]  #: the fitted feature in words
    model_params: Callable[[Params], Params] = field(default=lambda p: dict(p))


def _lag_columns(ctx: Context, params: Params) -> np.ndarray:
    # only while the command is above the lagged state (the rotor spinning UP): a rotor that is
    # slow to spin up lacks inertia in the model; a slow spin-down alone is spin_down_asymmetry
    d = (_feature(ctx, ef.PWM_LAG, params) - ctx.sig.pwm) / 0.025
    return _interacted(np.minimum(d, 0.0), ctx)


def _delay_columns(ctx: Context, params: Params) -> np.ndarray:
    d = (_feature(ctx, ef.PWM_DELAYED, params) - ctx.sig.pwm) / 0.025
    return _interacted(d, ctx)


def _asym_columns(ctx: Context, params: Params) -> np.ndarray:
    # only while the state is above the command (the rotor slowing DOWN)
    d = (_feature(ctx, ef.PWM_ASYMMETRIC_LAG, params) - ctx.sig.pwm) / 0.025
    return _interacted(np.maximum(d, 0.0), ctx)


def _deadband_columns(ctx: Context, params: Params) -> np.ndarray:
    thr = params["threshold"]
    below = (ctx.sig.pwm < thr).astype(float)
    above = np.maximum(ctx.sig.pwm - thr, 0.0) / 0.025
    # below the start level the speed is zero whatever the model predicts (-> -yhat);
    # above it the throttle map is compressed (a term in pwm - threshold)
    return np.column_stack([below, below * ctx.yhat, above, above**2])


def _heating_columns(ctx: Context, params: Params) -> np.ndarray:
    # a hotter winding lowers the speed in proportion to the load: terms in theta * speed only
    th = _feature(ctx, ef.THERMAL_LOAD, params)
    return np.column_stack([th * ctx.yhat, th * ctx.yhat**2])


def _voltage_columns(ctx: Context, params: Params) -> np.ndarray:
    # the speed scales with the voltage the ESC chops: terms in V and V * speed
    v = (ctx.sig.voltage - 11.5) / 1.0
    return np.column_stack([v, v * ctx.yhat, v * ctx.yhat**2])


def _pct(x: float) -> str:
    return f"{x * 1000:.0f} ms"


CANDIDATES: dict[str, Candidate] = {
    "battery_voltage": Candidate(
        "battery_voltage", c.INPUT_BATTERY_VOLTAGE, [{}], _voltage_columns,
        lambda p: "the filtered battery voltage",
    ),
    "rotor_lag": Candidate(
        "rotor_lag", ef.PWM_LAG,
        [{"tau_s": t} for t in (0.03, 0.05, 0.07, 0.1, 0.14, 0.2, 0.3, 0.45)],
        _lag_columns,
        lambda p: f"the command through a first-order lag of {p['tau_s']:.2f} s",
    ),
    "input_delay": Candidate(
        "input_delay", ef.PWM_DELAYED,
        [{"delay_s": d} for d in (0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1, 0.12)],
        _delay_columns,
        lambda p: f"the command delayed by a dead time of {_pct(p['delay_s'])}",
    ),
    "esc_deadband": Candidate(
        "esc_deadband", ef.PWM_ABOVE_START,
        [{"threshold": x} for x in (0.052, 0.053, 0.054, 0.055, 0.056, 0.057, 0.058, 0.06)],
        _deadband_columns,
        lambda p: f"no drive below an ESC start level of PWM {p['threshold']:.3f}",
    ),
    "spin_down_asymmetry": Candidate(
        "spin_down_asymmetry", ef.PWM_ASYMMETRIC_LAG,
        [{"tau_up_s": u, "tau_down_s": d} for u in (0.05, 0.08, 0.12, 0.18) for d in (0.2, 0.3, 0.45, 0.7, 1.0)
         if d >= 2.0 * u],
        _asym_columns,
        lambda p: (f"a lag of {p['tau_up_s']:.2f} s when the command rises but "
                   f"{p['tau_down_s']:.2f} s when it falls"),
    ),
    "motor_heating": Candidate(
        "motor_heating", ef.THERMAL_LOAD,
        [{"tau_s": t} for t in (30.0, 60.0, 120.0, 240.0)],
        _heating_columns,
        lambda p: f"a thermal state (time constant {p['tau_s']:.0f} s) driven by the I^2R losses",
    ),
}


def null_columns(ctx: Context, model_inputs: np.ndarray | None) -> np.ndarray:
    """What the correction may use without any effect: the operating point and the model's own
    inputs, re-weighted. An effect scores only by what it adds beyond these, so a mere
    mis-scaling of the model (a gain, an offset, a bent static map) is not taken for an effect."""
    p = ctx.p
    y = ctx.yhat
    cols = [np.ones_like(p), p, p**2, p**3, y, y**2]
    if model_inputs is not None and model_inputs.size:
        for j in range(model_inputs.shape[1]):
            z = model_inputs[:, j]
            cols += [z, z * p]
    return np.column_stack(cols)


def candidates_for(model_inputs: Sequence[str], restrict: Sequence[str] | None = None) -> list[Candidate]:
    """The candidates that make sense for a model with ``model_inputs``.

    ``battery_voltage`` is a candidate only when the model lacks that input; an effect whose
    input is already in the model (with a name of its own) is not offered again.
    """
    names = list(restrict) if restrict else list(c.EFFECTS)
    out = []
    for name in names:
        cand = CANDIDATES[name]
        if cand.input_name in model_inputs:
            continue
        out.append(cand)
    return out


def summary(cand: Candidate, params: Params) -> dict[str, Any]:
    return {"input": cand.input_name, "parameters": cand.model_params(params), "feature": cand.describe(params)}


# --- the dynamic family: which of lag, dead time, spin-down changed ---------------------------------
#: Grids of the direct identification of the rotor's response (s).
ID_DELAYS = (0.0, 0.01, 0.02, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1)
ID_TAU_UP = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3)
ID_TAU_DOWN = (0.0, 0.02, 0.04, 0.07, 0.1, 0.15, 0.2, 0.3, 0.5, 0.8, 1.2, 2.0)
DYNAMIC_EFFECTS = ("rotor_lag", "input_delay", "spin_down_asymmetry")


@dataclass
class Dynamics:
    """The rotor's response identified from command to measured speed (not from a residual)."""

    delay_s: float
    tau_up_s: float
    tau_down_s: float
    rmse_rad_s: float

    def as_dict(self) -> dict[str, float]:
        return {"dead_time_s": self.delay_s, "spin_up_time_constant_s": self.tau_up_s,
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
        a_up = np.where(tu > 0, np.exp(-dt / np.maximum(tu, 1e-9)), 0.0)
        a_dn = np.where(td > 0, np.exp(-dt / np.maximum(td, 1e-9)), 0.0)
        v = (s.voltage - 11.5)
        y = s.speed[ok]
        n_total += len(y)
        pwm_t, pwm = s.pwm_events
        for i, d in enumerate(ID_DELAYS):
            u = ef._held(pwm_t, pwm, s.t - d)
            X = np.empty((len(s.t), len(combos)))
            state = np.full(len(combos), c.PWM_STOP)
            for k in range(len(s.t)):
                uk = u[k]
                a = np.where(uk > state, a_up, a_dn)
                state = uk + (state - uk) * a
                X[k] = state
            X = (X[ok] - 0.075) / 0.025
            vv = v[ok]
            for j in range(len(combos)):
                x = X[:, j]
                A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
                beta, *_ = np.linalg.lstsq(A, y, rcond=None)
                sse[i, j] += float(np.sum((y - A @ beta) ** 2))
    i, j = np.unravel_index(int(np.argmin(sse)), sse.shape)
    return Dynamics(float(ID_DELAYS[i]), float(tu[j]), float(td[j]), float(np.sqrt(sse[i, j] / max(n_total, 1))))


def which_dynamic(meas: Dynamics, ref: Dynamics | None, exclude: Sequence[str] = ()) -> tuple[str | None, str]:
    """The dynamic effect whose parameter changed from reference to measured, and why.

    Margins: spin-up time constant up by 50 % and at least 50 ms; dead time up by 15 ms;
    spin-down time constant up by 0.1 s more than the spin-up one."""
    if ref is None:
        return None, "no reference data to compare the identified dynamics with"
    changes = {
        "rotor_lag": (meas.tau_up_s - max(1.5 * ref.tau_up_s, ref.tau_up_s + 0.05), 0.0,
                      f"the spin-up time constant is {meas.tau_up_s:.2f} s on the measured data vs "
                      f"{ref.tau_up_s:.2f} s on the reference"),
        "spin_down_asymmetry": (meas.tau_down_s - ref.tau_down_s - max(meas.tau_up_s - ref.tau_up_s, 0.0), 0.1,
                                f"the spin-down time constant is {meas.tau_down_s:.2f} s on the measured data "
                                f"vs {ref.tau_down_s:.2f} s on the reference while the spin-up one is "
                                f"{meas.tau_up_s:.2f} s vs {ref.tau_up_s:.2f} s"),
        "input_delay": (meas.delay_s - ref.delay_s, 0.015,
                        f"the dead time is {1000 * meas.delay_s:.0f} ms on the measured data vs "
                        f"{1000 * ref.delay_s:.0f} ms on the reference"),
    }
    # in order of precedence: a rotor that lags at all comes before an asymmetry of its lag
    for name in ("rotor_lag", "input_delay", "spin_down_asymmetry"):
        if name in exclude:
            continue
        change, margin, why = changes[name]
        if change >= margin:
            return name, why
    return None, "the identified dead time and time constants did not change beyond their margins"
