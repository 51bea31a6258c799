"""One candidate per effect of the contract: a feature from recorded signals, and how to add it.

A candidate offers, for each value of its parameter grid, extra regression columns built from
the recorded command and battery voltage only (never from the measured speed) for the
residual-correction model of ``scoring.py``, and the model input (name + parameters) that the
network gets when the effect is added. The grids are chosen so the dynamic candidates are
specific: ``rotor_lag`` is a first-order lag judged on the spin-UP (command above the lagged
state), ``input_delay`` a pure dead time (no lag change), ``spin_down_asymmetry`` a lag whose
falling time constant is at least twice its rising one, judged on the spin-DOWN only. Which of
them CHANGED is decided from the step responses themselves (``identify.which_dynamic``; a
heavier rotor slows both directions, so ``rotor_lag`` comes before ``spin_down_asymmetry``).

Two effects change how the speed RESPONDS to something both data sets share, so a residual
correction fitted on the pooled sets cannot see them: the ESC start level (identified with the
rotor's dynamics, ``identify.identify_start_level``) and motor heating
(``identify.identify_heating``).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field

import numpy as np

from .. import contract as c
from ..core import effect_features as ef
from ..core.features import zero_order_hold
from ..physics.scales import PWM_HALF_RANGE, centred_pwm, centred_voltage
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
        return centred_pwm(self.sig.pwm)

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
    #: how a replaced input's values follow from its replacement's where the two agree (params ->
    #: (a, b): base = a * new + b): the base model's ``pwm`` is the scaled command (0 at stop, 1
    #: at full), the mapped inputs are PWM levels, so the carried weights need the conversion
    carried_as: Callable[[Params], tuple[float, float]] | None = None
    #: the reference recordings as the added input must see them when the effect's parameter was
    #: identified separately on the reference (signal, measured params, reference params): the
    #: network then learns one map from the input to the speed, not a compromise of two
    on_reference: Callable[[Signals, Params, Params], Signals] | None = None


def _scaled_from_level(offset: float) -> tuple[float, float]:
    """(a, b) with scale_pwm(level + offset) = a * level + b (the model's scaled command)."""
    span = c.PWM_FULL - c.PWM_STOP
    return 1.0 / span, (offset - c.PWM_STOP) / span


def _lag_columns(ctx: Context, params: Params) -> np.ndarray:
    # only while the command is above the lagged state (the rotor spinning UP): a rotor that is
    # slow to spin up lacks inertia in the model; a slow spin-down alone is spin_down_asymmetry
    d = (_feature(ctx, ef.PWM_LAG, params) - ctx.sig.pwm) / PWM_HALF_RANGE
    return _interacted(np.minimum(d, 0.0), ctx)


def _delay_columns(ctx: Context, params: Params) -> np.ndarray:
    d = (_feature(ctx, ef.PWM_DELAYED, params) - ctx.sig.pwm) / PWM_HALF_RANGE
    return _interacted(d, ctx)


def _asym_columns(ctx: Context, params: Params) -> np.ndarray:
    # only while the state is above the command (the rotor slowing DOWN)
    d = (_feature(ctx, ef.PWM_ASYMMETRIC_LAG, params) - ctx.sig.pwm) / PWM_HALF_RANGE
    return _interacted(np.maximum(d, 0.0), ctx)


def _deadband_columns(ctx: Context, params: Params) -> np.ndarray:
    thr = params["threshold"]
    below = (ctx.sig.pwm < thr).astype(float)
    above = np.maximum(ctx.sig.pwm - thr, 0.0) / PWM_HALF_RANGE
    # below the start level the speed is zero whatever the model predicts (-> -yhat);
    # above it the throttle map is compressed (a term in pwm - threshold)
    return np.column_stack([below, below * ctx.yhat, above, above**2])


def _reference_at_own_start_level(sig: Signals, meas: Params, ref: Params) -> Signals:
    """The reference's command re-expressed so that the measured start level's input is the drive
    its own (identified) start level gives: the same duty, on the measured data's scale. With a
    gated map (``map_level`` below the measured threshold) the reference's map is moved onto the
    measured one's start, not its gate: the lowest reference levels then read as no drive (one
    input for both sets cannot say both), the rest of the map as it is."""
    from_m, thr_r = _map_start(meas), float(ref["threshold"])
    gain = (c.PWM_FULL - from_m) / (c.PWM_FULL - thr_r)

    def remap(x: np.ndarray) -> np.ndarray:
        return from_m + (np.asarray(x, dtype=float) - thr_r) * gain

    pt, pv = sig.pwm_events
    return dataclasses.replace(sig, path=f"{sig.path}#start{thr_r:.3f}", sha256=f"{sig.sha256}#start{thr_r:.3f}",
                               pwm=remap(sig.pwm), pwm_events=(pt, remap(pv)))


def _map_start(p: Params) -> float:
    """Where a start level's throttle map starts: its ``map_level`` when gated, else its threshold."""
    return float(p.get("map_level", p["threshold"]))


def _reference_at_own_dead_time(sig: Signals, meas: Params, ref: Params) -> Signals:
    """The reference's command moved earlier by the dead time the measured data have beyond its
    own, so that the delayed inputs (delay = the measured change) give it its own timing: the
    network is not pulled towards a delay halfway between the two sets."""
    shift = float(meas["delay_s"]) - float(ref["delay_s"])
    pt, pv = sig.pwm_events
    pt, pv = np.asarray(pt, dtype=float) - shift, np.asarray(pv, dtype=float)
    tag = f"#earlier{1000 * shift:.0f}ms"
    return dataclasses.replace(sig, path=f"{sig.path}{tag}", sha256=f"{sig.sha256}{tag}",
                               pwm=zero_order_hold(pt, pv, sig.t), pwm_events=(pt, pv))


def _heating_columns(ctx: Context, params: Params) -> np.ndarray:
    # a hotter winding lowers the speed in proportion to the load: terms in theta * speed only
    th = _feature(ctx, ef.THERMAL_LOAD, params)
    return np.column_stack([th * ctx.yhat, th * ctx.yhat**2])


def _voltage_columns(ctx: Context, params: Params) -> np.ndarray:
    # the speed scales with the voltage the ESC chops: terms in V and V * speed
    v = centred_voltage(ctx.sig.voltage)
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
        replaces={c.INPUT_PWM: ef.PWM_DELAYED, c.INPUT_PWM_FILTERED: ef.PWM_DELAYED_FILTERED},
        carried_as=lambda p: _scaled_from_level(0.0),
        on_reference=_reference_at_own_dead_time,
    ),
    "esc_deadband": Candidate(
        "esc_deadband", ef.PWM_ABOVE_START,
        [{"threshold": x} for x in (0.052, 0.053, 0.054, 0.055, 0.056, 0.057, 0.058, 0.06)],
        _deadband_columns,
        lambda p: f"no drive below an ESC start level of PWM {p['threshold']:.3f}" + (
            f", its throttle map starting from PWM {p['map_level']:.4f} above it" if "map_level" in p else "") + (
            f" (the rotor slowing there with a time constant of {p['coast_tau_s']:.2f} s)"
            if "coast_tau_s" in p else ""),
        replaces={c.INPUT_PWM: ef.PWM_ABOVE_START, c.INPUT_PWM_FILTERED: ef.PWM_ABOVE_START_FILTERED},
        carried_as=lambda p: _scaled_from_level(_map_start(p)),  # above where the map starts
        on_reference=_reference_at_own_start_level,
        # the coast is the lag's
        model_params=lambda p: {k: float(v) for k, v in p.items() if k in ("threshold", "map_level")},
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


def summary(cand: Candidate, params: Params) -> dict[str, object]:
    return {"input": cand.input_name, "parameters": cand.model_params(params), "feature": cand.describe(params)}
