"""Online speed and thrust prediction from the PWM command and the filtered battery voltage.

A model of every kind (model.py): a network, a physics model (its one input, ``physics_speed``, is
the plant stepped as a stream, physics/stream.py) or a hybrid (the physics speed plus a
network's correction). The model's inputs are computed by core/features.py (the trainer and
evaluate use the same code). Inputs
outside the training range are clipped to it and the prediction is flagged: the network was
never fitted there, so its output is an extrapolation guard, not a measurement. The predicted
speed is clamped at >= 0 (the rotor does not turn backwards) and thrust = b w^2; a model
without b (nothing measured or stated when it was trained) predicts no thrust, and its status
says why, rather than a thrust from another propeller's b.

Samples are checked at the door, as the PX4 battery estimator does: non-finite values, PWM
levels outside 0.0..0.2, voltages outside 0..60 V and timestamps older than the previous
sample of the same signal are rejected and counted; they do not touch the state.

A measured rotor speed (``update_speed``: ``rotor/speed``), when there is one, is never a model
input (the prediction stays a prediction): it only says where a physics stream starts. At its
first command (after construction, ``reset`` or ``restart_physics``) the physics starts from the
latest measured speed, instead of at rest, so a node started on a turning rotor is not wrong by
the whole speed for the rotor's time constant. A network model ignores it.

A model with an uncertainty band (its metadata's ``band``, ``core/uncertainty.py``) gives each
prediction a one-sigma of the speed and of the thrust; one without publishes none, and its status
value ``band`` says why.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import NamedTuple, Protocol, cast

import numpy as np

from ..contract import HYBRID, NETWORK, PHYSICS
from ..errors import BadInputError
from ..physics.fallback import FallbackModel
from ..physics.plant import REST_SPEED_RAD_S
from .features import FeatureState, PhysicsSpeed, pwm_ok, voltage_ok
from .status import OK, WARN, CoreStatus, counters
from .uncertainty import CommandChange, band_of, thrust_sigma

#: A measured speed (``update_speed``) is where the physics starts only if it was taken at most
#: this long (s) before the start: the rotor's time constant is ~0.1 s, so an older one says
#: little of the speed now (and a tachometer gone silent nothing).
MEASURED_SPEED_MAX_AGE_S = 0.25
#: A physics stream started at rest with no measured speed yet is started again from the first
#: measured speed taken within this (s) of its first command (rebuilt from the inputs since):
#: the tachometer's first speed needs a batch and a revolution (~20-30 ms at speed), so after a
#: node or a recording starts on a turning rotor a command often comes first. Predictions made
#: before it came were from rest (replay of a bag cut at speed: the first grid time).
START_WINDOW_S = 0.1
#: Highest measured speed taken (rad/s); faster is a fault of the measurement (the tachometer's
#: own limit is 2000 rad/s).
MEASURED_SPEED_MAX_RAD_S = 1.0e5
_PWM, _VOLTAGE = 0, 1  # kinds of the inputs kept in the start window


class SpeedModel(Protocol):
    """What the estimator needs from a model: any kind of model.py's, or the first-principles
    fallback (physics/fallback.py)."""

    # read-only (properties): a model may compute them (PlantModel, the fallback) or store them
    @property
    def input_names(self) -> tuple[str, ...]: ...
    @property
    def input_min(self) -> np.ndarray: ...
    @property
    def input_max(self) -> np.ndarray: ...
    @property
    def thrust_coefficient(self) -> float | None:
        """b (N s^2/rad^2); None: the model has no b (speed only)."""

    def feature_params(self) -> dict[str, dict[str, float]]: ...

    def forward(self, X_raw: np.ndarray) -> np.ndarray: ...


class Adapter(Protocol):
    """What the estimator needs of an online adaptation of its model's parameters
    (core/adaptation.py's PhysicsAdapter; a protocol, so that the estimator imports none of it)."""

    note: str  #: "on", or why the latest measured speed did not update it
    in_use: bool  #: whether ``correction`` applies (else the offline model scores better lately)
    heating_k: float  #: the winding's rise a named change set (K; ``take_named``), 0 without

    @property
    def provisional(self) -> bool: ...  #: whether heating_k holds a change still being named

    @property
    def applied_thrust_factor(self) -> float: ...
    @property
    def pack_ohm(self) -> float: ...  #: the series resistance the adapted model uses (ohm)
    def update_pwm(self, t: float, level: float) -> None: ...
    def update_voltage(self, t: float, volts: float) -> None: ...
    def update(self, t: float, measured_rad_s: float, offline_rad_s: float) -> bool: ...
    def correction(self, t: float, offline_rad_s: float | None = None) -> tuple[float, float]: ...
    def values(self) -> dict[str, tuple[float, float]]: ...
    def take_named(self, name: str, size: float, onset_s: float, provisional: bool = False,
                   reference: float | None = None) -> bool: ...
    def drop_provisional(self) -> bool: ...
    def reset(self) -> None: ...
    def restart(self) -> None: ...


class _NetworkWeights(SpeedModel, Protocol):
    """What :func:`_fast_forward` reads from a network model (model.NetworkModel)."""

    W1: np.ndarray  #: (H, n)
    b1: np.ndarray  #: (H,)
    W2: np.ndarray  #: (H,)
    b2: float
    output_min: float  #: rad/s
    output_max: float  #: rad/s


class _HybridParts(SpeedModel, Protocol):
    """What :func:`_fast_forward` reads from a hybrid model (model.HybridModel)."""

    network: SpeedModel
    physics_index: int  #: column of ``physics_speed`` among the inputs


class Prediction(NamedTuple):
    """One prediction; speed/thrust are NaN when not ready (no PWM or needed voltage yet).

    Immutable, and a NamedTuple rather than a frozen dataclass: one is made per prediction, and a
    frozen dataclass of these six fields took 1.4 us to build where this takes 0.5 us."""

    speed_rad_s: float
    thrust_n: float | None  #: None: no thrust coefficient, so no thrust at all
    clipped: bool  #: some input was outside the training range and clipped to it
    ready: bool
    #: one-sigma band of the speed (rad/s, ``core.uncertainty``); None: the model has no band
    speed_sigma_rad_s: float | None = None
    #: one-sigma of the thrust, 2 b w sigma_w to first order (N); None: no band or no b
    thrust_sigma_n: float | None = None


_NOT_READY = Prediction(math.nan, math.nan, False, False)
#: Why a model predicts no thrust, on diagnostics (the nodes) and in replay's recording.
NO_THRUST_MESSAGE = ("model has no thrust coefficient: train with measured thrust or "
                     "--thrust-coefficient / --vehicle-mass-kg")


def _fast_forward(model: SpeedModel) -> Callable[[list[float]], float]:
    """x (list of raw inputs) -> speed (rad/s); the network's scaling folded into its weights.

    Same function as ``model.forward`` (equal to ~1e-13), at a third of the cost per call, which
    is what a 100 Hz estimator on a small computer pays. A physics model's speed is its one
    input; a hybrid's is that plus its network's.
    """
    kind = getattr(model, "kind", NETWORK)
    if kind == PHYSICS:
        return lambda x: x[0]
    if kind == HYBRID:
        hybrid = cast(_HybridParts, model)
        net, k = _fast_forward(hybrid.network), hybrid.physics_index
        return lambda x: x[k] + net(x)
    W1 = getattr(model, "W1", None)
    if isinstance(model, FallbackModel):
        return model.forward_one
    if W1 is None or getattr(model, "is_fallback", False):
        return lambda x: float(model.forward(np.asarray(x, dtype=float)))
    net_w = cast(_NetworkWeights, model)  # it has W1: a network's weights and scaling
    lo = np.asarray(net_w.input_min, dtype=float)
    hi = np.asarray(net_w.input_max, dtype=float)
    g = 2.0 / (hi - lo)  # xs = g x - (g lo + 1)
    W1s = np.ascontiguousarray(W1 * g)
    b1s = net_w.b1 - W1 @ (g * lo + 1.0)
    half = 0.5 * (net_w.output_max - net_w.output_min)
    W2s = net_w.W2 * half
    b2s = (net_w.b2 + 1.0) * half + net_w.output_min
    dot, tanh = np.dot, np.tanh

    def f(x: list[float]) -> float:
        return float(dot(W2s, tanh(dot(W1s, x) + b1s))) + b2s

    return f


class ThrustEstimator:
    """Streaming estimator: ``update_pwm``, ``update_voltage``, ``predict(t)``."""

    def __init__(self, model: SpeedModel, thrust_coefficient: float | None = None,
                 adapter: Adapter | None = None) -> None:
        """``thrust_coefficient``: b overriding the model's (None: the model's, which may be None:
        no thrust predicted). ``adapter``: adapt the model's parameters to the measured speed
        (``core.adaptation.adapter_for(model)``); None (default): the offline model as it is."""
        b = model.thrust_coefficient if thrust_coefficient is None else float(thrust_coefficient)
        if b is not None and not (math.isfinite(b) and b >= 0.0):
            raise BadInputError(f"thrust_coefficient must be finite and >= 0, got {b!r}")
        self.model = model
        self.thrust_coefficient: float | None = b
        self.is_fallback = bool(getattr(model, "is_fallback", False))
        self.features = FeatureState(model.input_names, model.feature_params())
        self._lo = [float(v) for v in model.input_min]
        self._hi = [float(v) for v in model.input_max]
        self._names = tuple(model.input_names)
        self._forward = _fast_forward(model)
        #: the speed's one-sigma band and the command changes it reads; None: no band (and why)
        self.band, self.band_note = band_of(model)
        self._changes = CommandChange(self.band) if self.band is not None else None
        #: (rad/s)^2 the online adaptation's parameter covariance adds to the band's variance
        #: (issue 34 item 1 sets it; 0 without adaptation): the two are independent, so in quadrature
        self.adaptation_speed_variance = 0.0
        self.adapter = adapter
        self._predicted_t = -math.inf  #: the latest prediction's time (the adaptation's status)
        self.pwm_accepted = 0
        self.pwm_rejected_value = 0
        self.pwm_rejected_time = 0
        self.voltage_accepted = 0
        self.voltage_rejected_value = 0
        self.voltage_rejected_time = 0
        self.predictions = 0
        self.not_ready = 0
        self.clipped = 0
        self.clipped_by_input = dict.fromkeys(self._names, 0)
        self.predict_time_clamped = 0  #: predict(t) asked for a time before the latest input
        self._reported = (0, 0, 0)
        self._last = _NOT_READY
        # the measured speed's part (physics_speed inputs only; see the module doc)
        self._physics = [f for f in self.features.features if isinstance(f, PhysicsSpeed)]
        self.speed_accepted = 0
        self.speed_rejected = 0  #: not finite, negative, implausible, or older than the latest
        self.physics_starts_measured = 0  #: physics streams started from a measured speed
        self._measured: tuple[float, float] | None = None  #: latest measured (t, rad/s)
        self._restart_physics_state()

    def _restart_physics_state(self) -> None:
        """No physics stream started: the next command starts one."""
        self._start_t: float | None = None  #: the physics stream's first command
        #: inputs since a start at rest, while a measured speed may still start it (START_WINDOW_S),
        #: from the latest voltage before it: (kind, t, value)
        self._start_log: list[tuple[int, float, float]] | None = None
        self._volt_last: tuple[float, float] | None = None  #: latest accepted voltage (t, V)

    def reset(self) -> None:
        """Forget the inputs (counters stay; the latest measured speed too: it starts the next
        physics stream if it is recent then)."""
        self.features.reset()
        if self._changes is not None:
            self._changes.reset()
        if self.adapter is not None:  # back to the offline model
            self.adapter.reset()
            self.adaptation_speed_variance = 0.0
        self._last = _NOT_READY
        self._restart_physics_state()

    def restart_physics(self) -> None:
        """Start the physics again at the next command, from the latest measured speed (the
        other inputs keep their state): after a stall of the commands, what the rotor did
        meanwhile is not known to the model but is to the measurement."""
        if not self._physics:
            return
        volt = self._volt_last
        for f in self._physics:
            f.reset()
            if volt is not None:
                f.update_voltage(*volt)
        self._restart_physics_state()
        self._volt_last = volt
        if self.adapter is not None:  # its lanes too (what it adapted stays)
            self.adapter.restart()
            if volt is not None:
                self.adapter.update_voltage(*volt)

    # --- inputs ------------------------------------------------------------------------------

    def update_pwm(self, t: float, pwm: float) -> bool:
        """ESC command as PWM level (0.05 stop .. 0.10 full) at t (s); False if rejected."""
        t, pwm = float(t), float(pwm)
        if not (math.isfinite(t) and pwm_ok(pwm)):
            self.pwm_rejected_value += 1
            return False
        last = self.features.pwm_t
        if last is not None and t < last:
            self.pwm_rejected_time += 1
            return False
        if self._physics and (self._start_t is None or self._start_log is not None):
            self._physics_command(t, pwm)
        self.features.update_pwm(t, pwm)
        if self._changes is not None:
            self._changes.update_pwm(t, pwm)
        if self.adapter is not None:
            self.adapter.update_pwm(t, pwm)
        self.pwm_accepted += 1
        return True

    def update_voltage(self, t: float, volts: float) -> bool:
        """Filtered battery voltage (V, at the battery) at t (s); False if rejected."""
        t, volts = float(t), float(volts)
        if not (math.isfinite(t) and voltage_ok(volts)):
            self.voltage_rejected_value += 1
            return False
        last = self.features.voltage_t
        if last is not None and t < last:
            self.voltage_rejected_time += 1
            return False
        self.features.update_voltage(t, volts)
        self.voltage_accepted += 1
        if self.adapter is not None:
            self.adapter.update_voltage(t, volts)
        if self._physics:
            self._volt_last = (t, volts)
            if self._start_log is not None:
                self._keep(_VOLTAGE, t, volts)
        return True

    def update_speed(self, t: float, speed_rad_s: float) -> bool:
        """A measured rotor speed (rad/s, ``rotor/speed``) at t (s); False if rejected (not
        finite, negative, above MEASURED_SPEED_MAX_RAD_S, or older than the latest). Never a
        model input: it only says where a physics stream starts (module doc)."""
        t, w = float(t), float(speed_rad_s)
        if not (math.isfinite(t) and 0.0 <= w <= MEASURED_SPEED_MAX_RAD_S) or \
                (self._measured is not None and t < self._measured[0]):
            self.speed_rejected += 1
            return False
        self._measured = (t, w)
        self.speed_accepted += 1
        log, start_t = self._start_log, self._start_t
        if log is not None and start_t is not None:  # the physics started at rest, nothing measured yet
            self._start_log = None
            since = t - start_t
            if w >= REST_SPEED_RAD_S and -MEASURED_SPEED_MAX_AGE_S <= since <= START_WINDOW_S:
                self._start_from(w, log)
        if self.adapter is not None:
            self.adapter.update(t, w, self.offline_speed(t))
        return True

    def offline_speed(self, t: float) -> float:
        """The offline model's speed (rad/s) at t, NaN if not ready: what ``predict`` gives
        without adaptation, counting nothing. Inputs held from their latest value (a hybrid's
        network) are taken as they are now, the physics' speed at t itself. Public for the health
        monitor (core/health.py), which tests the measured speed against the offline model."""
        if not self.features.ready():
            return math.nan
        x = [min(max(f.value_at(t), lo), hi) for f, lo, hi in zip(self.features.features, self._lo, self._hi,
                                                                  strict=True)]
        return max(self._forward(x), 0.0)

    def measured_speed_at(self, t: float) -> float | None:
        """The latest measured speed (rad/s; 0 below REST_SPEED_RAD_S: rest) if it was taken at
        most MEASURED_SPEED_MAX_AGE_S before t (s), else None."""
        m = self._measured
        if m is None or not t - m[0] <= MEASURED_SPEED_MAX_AGE_S:
            return None
        return m[1] if m[1] >= REST_SPEED_RAD_S else 0.0

    def _physics_command(self, t: float, level: float) -> None:
        """A command while the physics has not started, or may still start from a measurement."""
        if self._start_t is None:  # this command starts it
            self._start_t = t
            w = self.measured_speed_at(t)
            if w is None:  # nothing measured (recently): at rest unless a measurement follows soon
                self._start_log = [(_VOLTAGE, *self._volt_last)] if self._volt_last else []
            elif w > 0.0:
                for f in self._physics:
                    f.set_initial_speed(w)
                self.physics_starts_measured += 1
        if self._start_log is not None:
            self._keep(_PWM, t, level)

    def _keep(self, kind: int, t: float, value: float) -> None:
        """Keep an input for a start from a measured speed, while START_WINDOW_S lasts."""
        log, start_t = self._start_log, self._start_t
        if log is None or start_t is None or t - start_t > START_WINDOW_S:
            self._start_log = None
        else:
            log.append((kind, t, value))

    def _start_from(self, w: float, log: list[tuple[int, float, float]]) -> None:
        """Start the physics again from ``w`` (rad/s) at its first command, over the inputs it
        has had since (the same order)."""
        for f in self._physics:
            f.reset()
            f.set_initial_speed(w)
            for kind, t, x in log:
                if kind == _PWM:
                    f.update_pwm(t, x)
                else:
                    f.update_voltage(t, x)
        self.physics_starts_measured += 1

    # --- output ------------------------------------------------------------------------------

    def predict(self, t: float) -> Prediction:
        """Predicted speed (rad/s) and thrust (N) at t (s), from the inputs received so far."""
        t = float(t)
        fs = self.features
        if not (math.isfinite(t) and fs.ready()):
            self.not_ready += 1
            return _NOT_READY
        latest = max(x for x in (fs.pwm_t, fs.voltage_t) if x is not None)
        if t < latest:  # e.g. a message stamped slightly ahead of the caller's clock
            self.predict_time_clamped += 1
            t = latest
        x = [f.value_at(t) for f in fs.features]
        clipped = False
        for i, v in enumerate(x):  # a few inputs: plain Python is faster than numpy here
            if not math.isfinite(v):
                self.not_ready += 1
                return _NOT_READY
            if v < self._lo[i] or v > self._hi[i]:
                x[i] = self._lo[i] if v < self._lo[i] else self._hi[i]
                self.clipped_by_input[self._names[i]] += 1
                clipped = True
        if clipped:
            self.clipped += 1
        w = self._forward(x)
        if not math.isfinite(w):  # pragma: no cover - finite weights and inputs
            self.not_ready += 1
            return _NOT_READY
        b = self.thrust_coefficient
        if self.adapter is not None:
            w, b = self._adapted(t, w, b)
        w = max(w, 0.0)
        self.predictions += 1
        sigma_w = sigma_thrust = None
        if self.band is not None and self._changes is not None:
            sigma_w = self.band.sigma(w, *self._changes.at(t))
            if self.adaptation_speed_variance:
                sigma_w = math.sqrt(sigma_w * sigma_w + self.adaptation_speed_variance)
            if b is not None:
                sigma_thrust = thrust_sigma(b, w, sigma_w)
        self._last = Prediction(w, None if b is None else b * w * w, clipped, True, sigma_w, sigma_thrust)
        return self._last

    def _adapted(self, t: float, w: float, b: float | None) -> tuple[float, float | None]:
        """The speed and b with the adapted parameters; the band's share of their uncertainty."""
        assert self.adapter is not None
        dw, var = self.adapter.correction(t, w)
        self.adaptation_speed_variance = var
        self._predicted_t = t
        return w + dw, None if b is None else b * self.adapter.applied_thrust_factor

    # --- diagnostics -------------------------------------------------------------------------

    def adaptation_state(self) -> str:
        """"on", or why the adaptation is frozen (a stale measured speed is the estimator's to
        see: no sample within MEASURED_SPEED_MAX_AGE_S of the latest prediction); "off" without."""
        if self.adapter is None:
            return "off"
        m = self._measured
        if m is None or self._predicted_t - m[0] > MEASURED_SPEED_MAX_AGE_S:
            return f"frozen: no measured speed within {MEASURED_SPEED_MAX_AGE_S:g} s"
        return self.adapter.note

    def _adaptation_values(self) -> dict[str, object]:
        """Status values: ``adaptation`` (its state), each adapted parameter and its one sigma, the
        winding's rise a named heating set (K) and whether it is still a lead only, the series
        resistance the model uses (ohm)."""
        assert self.adapter is not None
        out: dict[str, object] = {"adaptation": self.adaptation_state(),
                                  "adapted_in_use": self.adapter.in_use}
        for name, (value, sigma) in self.adapter.values().items():
            out[f"adapted_{name}"] = value
            out[f"adapted_{name}_sigma"] = sigma
        out["adapted_motor_heating"] = self.adapter.heating_k  # set by a name only (health on)
        out["adapted_motor_heating_provisional"] = self.adapter.provisional  # a lead, not yet a name
        # the series resistance in use (ohm): the model's, moved by the voltage's change or a named pack
        out["adapted_pack_resistance_in_use"] = self.adapter.pack_ohm
        return out

    def status(self) -> list[CoreStatus]:
        """Model in use, inputs received/rejected, predictions clipped since the last report."""
        rejected = (self.pwm_rejected_value + self.pwm_rejected_time
                    + self.voltage_rejected_value + self.voltage_rejected_time)
        now = (rejected, self.clipped, self.predictions)
        d_rej, d_clip, d_pred = (a - b for a, b in zip(now, self._reported, strict=True))
        self._reported = now
        fs = self.features
        if self.is_fallback:
            level, msg = WARN, "no trained model: first-principles fallback (rough)"
        else:
            level, msg = OK, "predicting"
        if not fs.ready():
            missing = [s for s, t, need in (("pwm", fs.pwm_t, fs.needs_pwm),
                                             ("battery/voltage", fs.voltage_t, fs.needs_voltage))
                       if need and t is None]
            level, msg = WARN, f"waiting for {', '.join(missing)}"
        elif d_clip:
            level, msg = WARN, f"inputs outside the training range (clipped) in {d_clip} of {d_pred} predictions"
        elif d_rej:
            level, msg = WARN, f"{d_rej} input samples rejected since last report"
        values: dict[str, object] = dict(
            model="fallback" if self.is_fallback else getattr(self.model, "kind", NETWORK),
            inputs=",".join(self._names),
            speed_rad_s=self._last.speed_rad_s,
            thrust_n=math.nan if self._last.thrust_n is None else self._last.thrust_n,
            thrust_coefficient="none" if self.thrust_coefficient is None else self.thrust_coefficient,
            predictions=self.predictions,
            not_ready=self.not_ready,
            clipped_predictions=self.clipped,
            pwm_accepted=self.pwm_accepted,
            pwm_rejected_value=self.pwm_rejected_value,
            pwm_rejected_time=self.pwm_rejected_time,
            voltage_accepted=self.voltage_accepted,
            voltage_rejected_value=self.voltage_rejected_value,
            voltage_rejected_time=self.voltage_rejected_time,
            predict_time_clamped=self.predict_time_clamped,
        )
        for name, k in self.clipped_by_input.items():
            values[f"clipped_{name}"] = k
        # the speed's one-sigma band, or why there is none (then no sigma topics are published)
        values["band"] = self.band_note if self.band is not None else f"none: {self.band_note}"
        if self.band is not None:
            last = self._last.speed_sigma_rad_s
            values["speed_sigma_rad_s"] = math.nan if last is None else last
        if self.speed_accepted or self.speed_rejected:  # only where a measured speed comes
            values.update(speed_accepted=self.speed_accepted, speed_rejected=self.speed_rejected,
                          physics_starts_measured=self.physics_starts_measured)
        if self.adapter is not None:
            values.update(self._adaptation_values())
        out = [CoreStatus("thrust estimator", level, msg, counters(**values))]
        if self.thrust_coefficient is None:  # a status of its own: the speed's may say more
            out.append(CoreStatus("thrust", WARN, NO_THRUST_MESSAGE, {"thrust_coefficient": "none"}))
        return out
