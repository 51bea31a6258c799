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

Two effects change how the speed RESPONDS to something both data sets share, so a residual
correction fitted on the pooled sets cannot see them: the ESC start level (identified with the
rotor's dynamics, ``identify_start_level``) and motor heating (``identify_heating``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from .. import contract as c
from ..core import effect_features as ef
from ..plant import throttle
from ..recordings import Signals

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
    #: base-model inputs that the effect's own inputs replace when it is added (base -> new): an
    #: effect that acts on the command before the ESC (a start level) acts on everything the model
    #: derives from the command, so the network keeps its map with the mapped command fed in
    replaces: dict[str, str] = field(default_factory=dict)
    #: the reference recordings as the added input must see them when the effect's parameter was
    #: identified separately on the reference (signal, measured params, reference params): the
    #: network then learns one map from the input to the speed, not a compromise of two
    on_reference: Callable[[Signals, Params, Params], Signals] | None = None


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


def _reference_at_own_start_level(sig: Signals, meas: Params, ref: Params) -> Signals:
    """The reference's command re-expressed so that max(pwm - measured start level, 0) is the
    drive its own (identified) start level gives: the same duty, on the measured data's scale."""
    thr_m, thr_r = float(meas["threshold"]), float(ref["threshold"])
    gain = (c.PWM_FULL - thr_m) / (c.PWM_FULL - thr_r)

    def remap(x: np.ndarray) -> np.ndarray:
        return thr_m + (np.asarray(x, dtype=float) - thr_r) * gain

    pt, pv = sig.pwm_events
    return dataclasses.replace(sig, path=f"{sig.path}#start{thr_r:.3f}", sha256=f"{sig.sha256}#start{thr_r:.3f}",
                               pwm=remap(sig.pwm), pwm_events=(pt, remap(pv)))


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
        replaces={c.INPUT_PWM: ef.PWM_ABOVE_START, c.INPUT_PWM_FILTERED: ef.PWM_ABOVE_START_FILTERED},
        on_reference=_reference_at_own_start_level,
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
#: ESC start levels tried (PWM level) when esc_deadband is a candidate (identify_start_level: the start
#: level goes in before the lag, since a rotor commanded below it coasts down to zero like one that is
#: not braked, so a coast to zero is not taken for a slower spin-down), and the rise that counts.
ID_START_LEVELS = tuple(round(0.05 + 0.001 * k, 3) for k in range(11))  # 0.050 ... 0.060
START_LEVEL_MARGIN = 0.004  #: PWM level: twice the grid step, so one step of noise is no change
DYNAMIC_EFFECTS = ("rotor_lag", "input_delay", "spin_down_asymmetry")


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


def identify_start_level(signals: Sequence[Signals], dyn: Dynamics) -> float:
    """ESC start level that best explains the speed, the dead time and time constants held at
    ``dyn``'s (a scan of ID_START_LEVELS; one lag per level, so cheap next to identify_dynamics)."""
    sse = np.zeros(len(ID_START_LEVELS))
    for s in signals:
        ok = np.isfinite(s.speed) & np.isfinite(s.voltage)
        pwm_t, pwm = s.pwm_events
        u0 = ef._held(pwm_t, pwm, s.t - dyn.delay_s)
        vv = (s.voltage - 11.5)[ok]
        for i, thr in enumerate(ID_START_LEVELS):
            u = c.PWM_STOP + (c.PWM_FULL - c.PWM_STOP) * throttle(u0, thr)
            x = ef.asymmetric_lag_on_times(s.t, u, dyn.tau_up_s, dyn.tau_down_s, c.PWM_STOP)
            x = (x[ok] - 0.075) / 0.025
            A = np.column_stack([np.ones_like(x), x, x**2, x**3, vv, vv * x])
            beta, *_ = np.linalg.lstsq(A, s.speed[ok], rcond=None)
            sse[i] += float(np.sum((s.speed[ok] - A @ beta) ** 2))
    return float(ID_START_LEVELS[int(np.argmin(sse))])


# --- motor heating: did the speed's response to the thermal state change --------------------------
HEATING_TAU_S = 120.0  #: thermal time constant of the identification (s)
HEATING_MIN_DROP = 5.0  #: rad/s: least extra speed loss at the measured data's hottest state
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

    @property
    def drop_rad_s(self) -> float:
        """Extra speed lost on the measured data at its hottest, beyond what the reference shows."""
        return (self.reference - self.measured) * self.hottest

    @property
    def changed(self) -> bool:
        return self.hottest >= HEATING_MIN_STATE and self.drop_rad_s >= HEATING_MIN_DROP

    def describe(self) -> str:
        return (f"at the measured data's hottest thermal state ({self.hottest:.2f}, time constant "
                f"{HEATING_TAU_S:.0f} s) the steady speed is {self.drop_rad_s:.1f} rad/s lower than the "
                f"reference's response to the same state predicts (margin {HEATING_MIN_DROP:g} rad/s)")

    def as_dict(self) -> dict[str, float]:
        return {"measured_rad_s_per_unit": self.measured, "reference_rad_s_per_unit": self.reference,
                "hottest_thermal_state": self.hottest, "extra_drop_rad_s": self.drop_rad_s}


def identify_heating(measured: Sequence[Signals], reference: Sequence[Signals]) -> Heating:
    """Thermal sensitivity on the measured and on the reference data, fitted together.

    speed ~ cubic(pwm) + V + V pwm (one static map for both) + k_set * theta * duty with theta the
    ``thermal_load`` state: a battery that sags over a long run lowers the speed on both sets
    alike, so the shared voltage terms take that, and only a response to the winding's heat that
    differs between the sets goes into k_measured - k_reference. Samples at least 0.7 s after a
    command change (the rotor's dynamics do not enter)."""
    rows, ys = [], []
    hottest = 0.0
    for which, sigs in ((0, measured), (1, reference)):
        for s in sigs:
            pwm_t, pwm = s.pwm_events
            vt, vv = s.voltage_events
            th = ef.compute(ef.THERMAL_LOAD, s.t, pwm_t, pwm, vt, vv, {"tau_s": HEATING_TAU_S})
            change = np.r_[pwm_t[0], pwm_t[1:][np.diff(pwm) != 0]] if len(pwm_t) else np.zeros(1)
            k = np.searchsorted(change, s.t, side="right") - 1
            ok = ((s.t - change[np.clip(k, 0, len(change) - 1)]) >= 0.7) & np.isfinite(s.speed) \
                & np.isfinite(s.voltage) & np.isfinite(th)
            p = (s.pwm[ok] - 0.075) / 0.025
            v = s.voltage[ok] - 11.5
            duty = throttle(s.pwm[ok], c.PWM_STOP)
            t_d = th[ok] * duty
            rows.append(np.column_stack([np.ones_like(p), p, p**2, p**3, v, v * p,
                                         t_d * (which == 0), t_d * (which == 1)]))
            ys.append(s.speed[ok])
            if which == 0 and ok.any():
                hottest = max(hottest, float(np.max(th[ok])))
    A, y = np.vstack(rows), np.concatenate(ys)
    if len(y) < 20:
        return Heating(0.0, 0.0, 0.0)
    beta, *_ = np.linalg.lstsq(A, y, rcond=None)
    return Heating(float(beta[6]), float(beta[7]), hottest)


def which_dynamic(meas: Dynamics, ref: Dynamics | None, exclude: Sequence[str] = ()) -> tuple[str | None, str]:
    """The dynamic effect whose parameter changed from reference to measured, and why.

    Margins: spin-up time constant up by 50 % and at least 50 ms; dead time up by 15 ms;
    spin-down time constant up by 0.1 s more than the spin-up one; ESC start level (when
    identified, else PWM_STOP on both) up by START_LEVEL_MARGIN."""
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
    changes["esc_deadband"] = (meas.start_level - ref.start_level, START_LEVEL_MARGIN - 1e-9,
                               f"the rotor gets no drive below PWM {meas.start_level:.3f} on the measured data vs "
                               f"{ref.start_level:.3f} on the reference (with the identified dead time and "
                               f"spin-up/spin-down time constants)")
    # in order of precedence: a start level that rose explains a coast to zero (no drive) and a
    # compressed throttle map, which the lags would otherwise take for a slower spin-down; a rotor
    # that lags at all comes before an asymmetry of its lag
    for name in ("esc_deadband", "rotor_lag", "input_delay", "spin_down_asymmetry"):
        if name in exclude:
            continue
        change, margin, why = changes[name]
        if change >= margin:
            return name, why
    return None, "the identified dead time and time constants did not change beyond their margins"
