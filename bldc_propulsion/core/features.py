"""Model inputs computed from the raw signals: one implementation for the estimator and the trainer.

The paper's three inputs (section 4):

| name | value |
|---|---|
| ``battery_voltage`` | filtered battery voltage (V), held from its latest sample |
| ``pwm`` | PWM level shifted and scaled: (level - 0.05) / 0.05, so 0 = stop, 1 = full |
| ``pwm_filtered`` | ``pwm`` through a first-order low-pass, time constant ``tau_s`` (paper: 0.25 s) |

``pwm_filtered`` is discretised exactly for a zero-order-held command over any time step:
y += (1 - exp(-dt/tau)) (u - y) (``physics/lag.py``); it starts in steady state at the first command.

Inputs are a registry (name -> :class:`Feature` subclass with parameters), so the discrepancy
workflow can add its own (:func:`register_feature`); the inputs of ``core/effect_features.py``
are registered here too. A model's input names select features; an unknown name is a
``ModelError`` that names it.

Streaming (:class:`FeatureState`, used by the estimator) and batch (:func:`compute_features`,
used by the trainer) give the same numbers (tested to 1e-12): the batch path applies the same
sample rules (:func:`pwm_ok`, :func:`voltage_ok`, time not going backwards) and evaluates each
grid time after every event at or before it.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from typing import ClassVar, overload

import numpy as np

from .. import contract as c
from ..errors import BadInputError, ModelError
from ..physics.lag import lag_gain, lag_step
from ..physics.plant import measured_start_speed, motor_response
from ..physics.stream import STREAM_DEFAULTS, PlantStream, split_params, stream_problem
from . import effect_features as ef

#: Plausible raw inputs; samples outside are rejected (PWM level is pulse width / 20 ms).
PWM_LEVEL_MIN = 0.0
PWM_LEVEL_MAX = 0.2
VOLTAGE_MIN_V = 0.0
VOLTAGE_MAX_V = 60.0


def pwm_ok(level: float) -> bool:
    """A PWM level the estimator accepts (finite, 0.0..0.2)."""
    return math.isfinite(level) and PWM_LEVEL_MIN <= level <= PWM_LEVEL_MAX


def voltage_ok(volts: float) -> bool:
    """A battery voltage the estimator accepts (finite, 0..60 V)."""
    return math.isfinite(volts) and VOLTAGE_MIN_V <= volts <= VOLTAGE_MAX_V


@overload
def scale_pwm(level: float) -> float: ...
@overload
def scale_pwm(level: np.ndarray) -> np.ndarray: ...
def scale_pwm(level: float | np.ndarray) -> float | np.ndarray:
    """PWM level -> the paper's shifted and scaled command (0 at 0.05 = stop, 1 at 0.10 = full)."""
    return (level - c.PWM_STOP) / (c.PWM_FULL - c.PWM_STOP)


class Feature:
    """One model input, fed event by event; subclasses set ``name``, ``signals``, ``defaults``.

    ``value_at(t)`` is the input at time t >= the latest event, NaN while unknown. ``batch``
    computes it on a grid; the default runs the streaming code over the merged events, so a
    registered feature only needs the streaming part to be right.
    """

    name: ClassVar[str] = ""
    signals: ClassVar[tuple[str, ...]] = ("pwm",)  #: raw signals it needs: "pwm", "voltage"
    defaults: ClassVar[dict[str, float]] = {}
    optional: ClassVar[tuple[str, ...]] = ()  #: parameters with no default (absent: as before them)

    def __init__(self, **params: float) -> None:
        known = {*self.defaults, *self.optional}
        unknown = sorted(set(params) - known)
        if unknown:
            raise ModelError(f"model input '{self.name}': unknown parameter(s) {', '.join(unknown)} "
                             f"(known: {', '.join(sorted(known)) or 'none'})")
        self.params = {k: float(v) for k, v in {**self.defaults, **params}.items()}
        for k, v in self.params.items():
            if not math.isfinite(v):
                raise ModelError(f"model input '{self.name}': parameter {k} = {v!r} is not finite")
        self.check_params()
        self.reset()

    def check_params(self) -> None:
        """Raise ModelError for parameter values the feature cannot use."""

    def reset(self) -> None:
        """Forget all events."""

    def update_pwm(self, t: float, level: float) -> None:
        """A new PWM level (accepted sample) at t."""

    def update_voltage(self, t: float, volts: float) -> None:
        """A new filtered battery voltage (accepted sample) at t."""

    def value_at(self, t: float) -> float:
        raise NotImplementedError

    def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
        """Values at sorted grid times from accepted, time-ordered events (generic: streaming)."""
        self.reset()
        out = np.empty(len(grid_t))
        ip = iv = 0
        np_, nv = len(pwm_t), len(volt_t)
        for k, t in enumerate(grid_t.tolist()):
            while True:  # every event at or before t, in time order (PWM first on a tie)
                tp = pwm_t[ip] if ip < np_ else math.inf
                tv = volt_t[iv] if iv < nv else math.inf
                if tp <= t and tp <= tv:
                    self.update_pwm(float(tp), float(pwm[ip]))
                    ip += 1
                elif tv <= t:
                    self.update_voltage(float(tv), float(volt[iv]))
                    iv += 1
                else:
                    break
            out[k] = self.value_at(t)
        self.reset()
        return out


def zero_order_hold(t_events: np.ndarray, values: np.ndarray, grid_t: np.ndarray) -> np.ndarray:
    """Latest event value at or before each grid time; NaN before the first event."""
    idx = np.searchsorted(t_events, grid_t, side="right") - 1
    out = np.full(len(grid_t), np.nan)
    ok = idx >= 0
    out[ok] = values[idx[ok]]
    return out


class BatteryVoltage(Feature):
    """Filtered battery voltage (V), held from its latest sample."""

    name = c.INPUT_BATTERY_VOLTAGE
    signals = ("voltage",)

    def reset(self) -> None:
        self._v = math.nan

    def update_voltage(self, t: float, volts: float) -> None:
        self._v = volts

    def value_at(self, t: float) -> float:
        return self._v

    def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
        return zero_order_hold(volt_t, volt, grid_t)


class Pwm(Feature):
    """PWM level shifted and scaled to 0 (stop) .. 1 (full), held from the latest command."""

    name = c.INPUT_PWM

    def reset(self) -> None:
        self._u = math.nan

    def update_pwm(self, t: float, level: float) -> None:
        self._u = scale_pwm(level)

    def value_at(self, t: float) -> float:
        return self._u

    def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
        return zero_order_hold(pwm_t, scale_pwm(pwm), grid_t)


class PwmLowpass(Feature):
    """Scaled PWM through a first-order low-pass (time constant ``tau_s``), exact for a held command.

    Starts in steady state at the first command. Subclass with another ``name`` for a second
    lag with its own (e.g. fitted) time constant.
    """

    name = c.INPUT_PWM_FILTERED
    defaults = {"tau_s": c.PAPER_PWM_TAU_S}

    def check_params(self) -> None:
        if not self.params["tau_s"] > 0.0:
            raise ModelError(f"model input '{self.name}': tau_s must be > 0, got {self.params['tau_s']!r}")

    def reset(self) -> None:
        self._t: float | None = None  # time of the latest command
        self._y = math.nan  # filter output at self._t
        self._u = math.nan  # command held since self._t

    def update_pwm(self, t: float, level: float) -> None:
        u = scale_pwm(level)
        if self._t is None:
            self._y = u
        else:
            self._y = lag_step(self._y, self._u, lag_gain(t - self._t, self.params["tau_s"]))
        self._t, self._u = t, u

    def value_at(self, t: float) -> float:
        if self._t is None:
            return math.nan
        return lag_step(self._y, self._u, lag_gain(t - self._t, self.params["tau_s"]))

    def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
        n = len(pwm_t)
        if n == 0:
            return np.full(len(grid_t), np.nan)
        u = scale_pwm(np.asarray(pwm, dtype=float))
        y = np.empty(n)  # output at each command time (before the command acts)
        tau = self.params["tau_s"]
        yk = float(u[0])
        tl, ul = pwm_t.tolist(), u.tolist()
        y[0] = yk
        for k in range(1, n):  # the same scalar arithmetic as update_pwm
            yk = lag_step(yk, ul[k - 1], lag_gain(tl[k] - tl[k - 1], tau))
            y[k] = yk
        idx = np.searchsorted(pwm_t, grid_t, side="right") - 1
        out = np.full(len(grid_t), np.nan)
        ok = idx >= 0
        i = idx[ok]
        out[ok] = lag_step(y[i], u[i], lag_gain(grid_t[ok] - pwm_t[i], tau))
        return out


#: The ``physics_speed`` input's parameter that starts the rotor turning: its speed (rad/s) at the
#: first command, 0 at rest. Not a model constant but where one recording or stream starts: set
#: per recording from its measured speed (``physics.plant.measured_start_speed``; training.train.features_of)
#: and by the estimator from a measured speed (core/estimator.py); never stored in a model file.
INITIAL_SPEED = "initial_speed_rad_s"


def start_params(params: Mapping[str, Mapping[str, float]], initial_speed: float) -> dict[str, dict[str, float]]:
    """Feature parameters with the ``physics_speed`` input starting at ``initial_speed`` (rad/s);
    the others as given (a copy)."""
    out = {k: dict(v) for k, v in params.items()}
    out.setdefault(c.INPUT_PHYSICS_SPEED, {})[INITIAL_SPEED] = float(initial_speed)
    return out


def with_measured_start(names: Sequence[str], params: Mapping[str, Mapping[str, float]], t: np.ndarray,
                        speed: np.ndarray, pwm_t: np.ndarray) -> Mapping[str, Mapping[str, float]]:
    """``params`` with a ``physics_speed`` among ``names`` starting where a recording (grid
    ``t``, measured ``speed``, command times ``pwm_t``) starts (:func:`measured_start_speed`),
    unless they set its initial speed already; ``params`` itself for any other inputs."""
    if c.INPUT_PHYSICS_SPEED not in names or INITIAL_SPEED in params.get(c.INPUT_PHYSICS_SPEED, {}) \
            or not len(pwm_t):
        return params
    return start_params(params, measured_start_speed(t, speed, float(pwm_t[0])))


class PhysicsSpeed(Feature):
    """The plant's speed (rad/s) under a physics model's constants (physics/stream.py): the
    whole of a ``physics`` model, an input of a ``hybrid`` one. Parameters: ``STREAM_DEFAULTS``
    (the model file's physics arrays give them: ``physics.plant_model.PlantModel.feature_params``) and
    ``INITIAL_SPEED`` (0: the rotor at rest at the first command)."""

    name = c.INPUT_PHYSICS_SPEED
    signals = ("pwm", "voltage")
    defaults = {**STREAM_DEFAULTS, INITIAL_SPEED: 0.0}

    def check_params(self) -> None:
        why = stream_problem(self.params)
        if not why and not self.params[INITIAL_SPEED] >= 0.0:
            why = f"{INITIAL_SPEED} {self.params[INITIAL_SPEED]!r} must be a speed >= 0"
        if why:
            raise ModelError(f"model input '{self.name}': {why}")

    def reset(self) -> None:
        self._stream = PlantStream.of(self.params, initial_speed=self.params[INITIAL_SPEED])

    def set_initial_speed(self, w: float) -> None:
        """Start the rotor at ``w`` (rad/s) at the first command, which must not have arrived
        yet (the estimator's measured speed; the parameter stays as given)."""
        self._stream.set_initial_speed(w)

    def update_pwm(self, t: float, level: float) -> None:
        self._stream.update_pwm(t, level)

    def update_voltage(self, t: float, volts: float) -> None:
        self._stream.update_voltage(t, volts)

    def value_at(self, t: float) -> float:
        return self._stream.speed_at(t)

    def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
        """The batch twin (``physics.plant.motor_response`` with the supply held: equal to the stream)."""
        out = np.full(len(grid_t), np.nan)
        if len(pwm_t) == 0 or len(volt_t) == 0:
            return out
        ok = grid_t >= max(pwm_t[0], volt_t[0])  # as streaming: unknown before both signals
        if ok.any():
            params, effects, supply_v, tau = split_params(self.params)
            out[ok] = motor_response(params, effects, (pwm_t, pwm), (volt_t, volt), grid_t[ok], supply_v,
                                     tau, hold_supply=True, initial_speed=self.params[INITIAL_SPEED])
        return out


# --- registry --------------------------------------------------------------------------------

FEATURES: dict[str, type[Feature]] = {}


def register_feature(cls: type[Feature]) -> type[Feature]:
    """Add a model input to the registry (usable as a class decorator); the name must be new."""
    if not cls.name:
        raise ValueError(f"{cls.__name__}: a feature needs a name")
    if cls.name in FEATURES and FEATURES[cls.name] is not cls:
        raise ValueError(f"model input '{cls.name}' is already registered")
    FEATURES[cls.name] = cls
    return cls


for _cls in (BatteryVoltage, Pwm, PwmLowpass, PhysicsSpeed):
    register_feature(_cls)


def _register_effect_features() -> None:
    """Register the inputs of core/effect_features.py (discrepancy workflow)."""

    def make(name: str) -> type[Feature]:
        needs = tuple("voltage" if s == "voltage" else "pwm" for s in ef.NEEDS.get(name, ("pwm",)))

        class EffectFeature(Feature):
            __doc__ = f"Discrepancy-workflow input '{name}' (see core/effect_features.py)."
            defaults = dict(ef.DEFAULT_PARAMS.get(name, {}))
            optional = ef.OPTIONAL_PARAMS.get(name, ())
            signals = needs

            def check_params(self) -> None:
                try:
                    self._stream = ef.StreamingFeature(self.name, self.params)
                except (ValueError, KeyError) as exc:
                    raise ModelError(f"model input '{self.name}': {exc}") from None

            def reset(self) -> None:
                if hasattr(self, "_stream"):
                    self._stream = ef.StreamingFeature(self.name, self.params)

            def update_pwm(self, t: float, level: float) -> None:
                self._stream.update_pwm(t, level)

            def update_voltage(self, t: float, volts: float) -> None:
                self._stream.update_voltage(t, volts)

            def value_at(self, t: float) -> float:
                return float(self._stream.value(t))

            def batch(self, grid_t: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
              volt_t: np.ndarray, volt: np.ndarray) -> np.ndarray:
                if len(pwm_t) == 0:
                    return np.full(len(grid_t), np.nan)
                out: np.ndarray = np.array(ef.compute(self.name, grid_t, pwm_t, pwm, volt_t, volt, self.params), float)
                out[grid_t < pwm_t[0]] = np.nan  # as streaming: unknown before the first command
                return out

        EffectFeature.name = name
        EffectFeature.__name__ = EffectFeature.__qualname__ = f"EffectFeature_{name}"
        return EffectFeature

    for name in ef.BATCH:
        if name not in FEATURES:
            register_feature(make(name))


_register_effect_features()


def known_features() -> list[str]:
    return sorted(FEATURES)


def feature_class(name: str) -> type[Feature]:
    """The registered class of a model input; ModelError naming it if unknown."""
    try:
        return FEATURES[name]
    except KeyError:
        raise ModelError(f"unknown model input '{name}' (known: {', '.join(known_features())})") from None


def make_features(names: Sequence[str], params: Mapping[str, Mapping[str, float]] | None = None) -> list[Feature]:
    """Feature objects for ``names``; ``params[name]`` overrides that feature's defaults."""
    params = params or {}
    if isinstance(names, str):
        raise BadInputError(f"model inputs must be a list of names, got the string {names!r}")
    if len(set(names)) != len(names):
        raise ModelError(f"model inputs repeat a name: {', '.join(names)}")
    return [feature_class(n)(**dict(params.get(n, {}))) for n in names]


# --- streaming -------------------------------------------------------------------------------


class FeatureState:
    """Streaming model inputs for the estimator: feed accepted samples, read values at any time."""

    def __init__(self, names: Sequence[str], params: Mapping[str, Mapping[str, float]] | None = None) -> None:
        self.names = tuple(names)
        self.features = make_features(self.names, params)
        self.needs_voltage = any("voltage" in f.signals for f in self.features)
        self.needs_pwm = any("pwm" in f.signals for f in self.features)
        self.reset()

    def reset(self) -> None:
        for f in self.features:
            f.reset()
        self.pwm_t: float | None = None  # time of the latest PWM sample
        self.voltage_t: float | None = None

    def update_pwm(self, t: float, level: float) -> None:
        """An accepted PWM level at t (the caller checks pwm_ok and time order)."""
        for f in self.features:
            f.update_pwm(t, level)
        self.pwm_t = t

    def update_voltage(self, t: float, volts: float) -> None:
        """An accepted filtered battery voltage at t."""
        for f in self.features:
            f.update_voltage(t, volts)
        self.voltage_t = t

    def ready(self) -> bool:
        """Every needed signal has arrived at least once."""
        return (self.pwm_t is not None or not self.needs_pwm) and \
            (self.voltage_t is not None or not self.needs_voltage)

    def vector_at(self, t: float) -> np.ndarray:
        """Inputs at t in model order (NaN where unknown)."""
        return np.array([f.value_at(t) for f in self.features])

    def values_at(self, t: float) -> dict[str, float]:
        return {f.name: f.value_at(t) for f in self.features}


# --- batch -----------------------------------------------------------------------------------


def _accepted(t: np.ndarray, v: np.ndarray, lo: float, hi: float) -> np.ndarray:
    """Mask of samples the streaming estimator would accept (finite, in range, time not backwards)."""
    with np.errstate(invalid="ignore"):
        ok = np.isfinite(t) & np.isfinite(v) & (v >= lo) & (v <= hi)
    tv = np.where(ok, t, -np.inf)
    prev = np.maximum.accumulate(np.concatenate(([-np.inf], tv)))[:-1]
    mask: np.ndarray = ok & (t >= prev)
    return mask


def compute_features(
    grid_t: np.ndarray,
    pwm_t: np.ndarray,
    pwm: np.ndarray,
    volt_t: np.ndarray,
    volt: np.ndarray,
    names: Sequence[str],
    params: Mapping[str, Mapping[str, float]] | None = None,
) -> np.ndarray:
    """Model inputs (len(grid_t), len(names)) on sorted grid times from the raw event streams.

    pwm: PWM levels (0.05..0.10) at pwm_t; volt: filtered battery volts at volt_t. Samples the
    estimator would reject are dropped the same way; NaN where an input is not yet known.
    """
    grid_t = np.asarray(grid_t, dtype=float)
    arrays = [np.asarray(a, dtype=float) for a in (pwm_t, pwm, volt_t, volt)]
    for a, what in zip(arrays, ("pwm_t", "pwm", "volt_t", "volt"), strict=True):
        if a.ndim != 1:
            raise BadInputError(f"features: {what} must be 1-D, got shape {a.shape}")
    pwm_t, pwm, volt_t, volt = arrays
    if grid_t.ndim != 1 or len(pwm_t) != len(pwm) or len(volt_t) != len(volt):
        raise BadInputError("features: grid must be 1-D and each time array as long as its values")
    if len(grid_t) > 1 and not np.all(np.diff(grid_t) >= 0):
        raise BadInputError("features: grid times must be sorted")
    feats = make_features(names, params)
    okp = _accepted(pwm_t, pwm, PWM_LEVEL_MIN, PWM_LEVEL_MAX)
    okv = _accepted(volt_t, volt, VOLTAGE_MIN_V, VOLTAGE_MAX_V)
    pwm_t, pwm, volt_t, volt = pwm_t[okp], pwm[okp], volt_t[okv], volt[okv]
    out = np.empty((len(grid_t), len(feats)))
    for j, f in enumerate(feats):
        out[:, j] = f.batch(grid_t, pwm_t, pwm, volt_t, volt)
    return out
