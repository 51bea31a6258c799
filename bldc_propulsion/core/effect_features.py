"""Model inputs that the discrepancy workflow adds, online (streaming) and offline (batch).

Each added input is a function of the recorded command and battery voltage only, so that the
estimator can compute it on the vehicle exactly as the trainer does offline. The batch
functions run the same exact discretisation as the streaming classes (zero-order hold of the
command between its events, exact exponential between time points), so a model trained on a
recording predicts on replay what it predicted in training.

| input name | effect | parameters | meaning |
|---|---|---|---|
| ``pwm_lag`` | rotor_lag | ``tau_s`` (``delay_s``) | command through a first-order lag (from rest) |
| ``pwm_delayed`` | input_delay | ``delay_s`` | command as it was ``delay_s`` ago (dead time) |
| ``pwm_above_start`` | esc_deadband | ``threshold`` | max(pwm - threshold, 0) (ESC start level; see ``map_level``) |
| ``pwm_asymmetric_lag`` | spin_down_asymmetry | ``tau_up_s``, ``tau_down_s`` (``delay_s``) | lag: up, down |
| ``thermal_load`` | motor_heating | ``tau_s`` | first-order thermal state driven by an I^2 R proxy |
| ``pwm_delayed_filtered`` | input_delay | ``delay_s``, ``tau_s`` | delayed command, the model's low-pass |
| ``pwm_above_start_filtered`` | esc_deadband | ``threshold``, ``tau_s`` | the above, the model's low-pass |

The two ``*_filtered`` inputs exist because a dead time or a start level acts on the command
before everything the model derives from it: the model's ``pwm_filtered`` input (a 0.25 s
low-pass that stands for the rotor's inertia) must see the delayed / deadband-mapped command too,
or the network has to rebuild that lag from the undelayed one. Like ``pwm_filtered`` they start in
steady state at the first (mapped) command.

An ESC's start level takes one of two shapes. Some move the whole throttle map up to start there
(the drive grows from 0 at the start level: ``max(pwm - threshold, 0)``); others gate it: no drive
below the start level, and above it the map they would have had without one, which starts lower.
The optional ``map_level`` (at or below ``threshold``) is where that map starts: 0 below the
threshold, ``pwm - map_level`` from it. Without it the map starts at the threshold.

The two lags take an optional ``delay_s``: the command as it reaches the ESC after that dead
time, set where the model also has ``pwm_delayed`` (a rotor answers the command the ESC got).

The I^2 R proxy of ``thermal_load`` is ``(duty * V / 12 V)^4`` with ``duty = (pwm - 0.05) / 0.05``
clipped to [0, 1]: with a propeller load the motor current grows as the square of the speed and
the speed as the applied voltage ``duty * V``, so the copper loss grows as its fourth power. Its
state starts at 0 (a motor at ambient temperature when the recording starts).
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Mapping

import numpy as np

from .. import contract as c
from ..physics.lag import asymmetric_lag_on_times, lag_gain, lag_on_times, lag_step, switched_lag_on_times
from ..physics.plant import throttle

PWM_LAG = "pwm_lag"
PWM_DELAYED = "pwm_delayed"
PWM_ABOVE_START = "pwm_above_start"
PWM_ASYMMETRIC_LAG = "pwm_asymmetric_lag"
THERMAL_LOAD = "thermal_load"
PWM_DELAYED_FILTERED = "pwm_delayed_filtered"
PWM_ABOVE_START_FILTERED = "pwm_above_start_filtered"
#: Inputs that are the command mapped (dead time, start level) and then low-passed.
MAPPED_LAGS = (PWM_DELAYED_FILTERED, PWM_ABOVE_START_FILTERED)
#: The lags that may act on the command after a dead time (their optional ``delay_s``): in a
#: model with a dead time, a lag acts on the command as the ESC gets it.
DELAYABLE_LAGS = (PWM_LAG, PWM_ASYMMETRIC_LAG)

#: State of the command lags when a recording starts: the rotor at rest (PWM_STOP), as a bench
#: run starts; after a start mid-run the lag's state converges within a few time constants.
REST_PWM = c.PWM_STOP
#: Reference voltage of the thermal proxy (a 3S pack near nominal).
THERMAL_REFERENCE_V = 12.0

#: Parameters of each added input and the defaults used when a model does not give them.
DEFAULT_PARAMS: dict[str, dict[str, float]] = {
    PWM_LAG: {"tau_s": 0.1},
    PWM_DELAYED: {"delay_s": 0.04},
    PWM_ABOVE_START: {"threshold": 0.055},
    PWM_ASYMMETRIC_LAG: {"tau_up_s": 0.1, "tau_down_s": 0.3},
    THERMAL_LOAD: {"tau_s": 120.0},
    PWM_DELAYED_FILTERED: {"delay_s": 0.04, "tau_s": c.PAPER_PWM_TAU_S},
    PWM_ABOVE_START_FILTERED: {"threshold": 0.055, "tau_s": c.PAPER_PWM_TAU_S},
}

#: Parameters an input may carry beyond DEFAULT_PARAMS' (a model saved without them reads as
#: before): the start level's low-pass time constant while there is no drive.
OPTIONAL_PARAMS: dict[str, tuple[str, ...]] = {PWM_LAG: ("delay_s",), PWM_ASYMMETRIC_LAG: ("delay_s",),
                                                PWM_ABOVE_START: ("map_level",),
                                                PWM_ABOVE_START_FILTERED: ("coast_tau_s", "map_level")}


#: Which recorded streams each input needs ("pwm", "voltage").
NEEDS: dict[str, tuple[str, ...]] = {
    PWM_LAG: ("pwm",),
    PWM_DELAYED: ("pwm",),
    PWM_ABOVE_START: ("pwm",),
    PWM_ASYMMETRIC_LAG: ("pwm",),
    THERMAL_LOAD: ("pwm", "voltage"),
    PWM_DELAYED_FILTERED: ("pwm",),
    PWM_ABOVE_START_FILTERED: ("pwm",),
}


def _param(params: Mapping[str, float] | None, name: str, key: str) -> float:
    p = dict(DEFAULT_PARAMS[name])
    p.update(params or {})
    value = float(p[key])
    if not math.isfinite(value) or value < 0:
        raise ValueError(f"{name}.{key} = {value!r}: must be finite and >= 0")
    return value


def thermal_proxy(pwm: np.ndarray | float, volts: np.ndarray | float) -> np.ndarray | float:
    """I^2 R proxy (dimensionless, 1 at full throttle on 12 V) from command and battery voltage."""
    duty = throttle(np.asarray(pwm, dtype=float), c.PWM_STOP)
    out = (duty * np.asarray(volts, dtype=float) / THERMAL_REFERENCE_V) ** 4
    return float(out) if np.ndim(out) == 0 else out


# --- events on a time grid (the lag itself: physics/lag.py) ------------------------------------------
def _held(t_events: np.ndarray, values: np.ndarray, times: np.ndarray) -> np.ndarray:
    """Value of the last event at or before each time (the first value before the first event)."""
    idx = np.searchsorted(t_events, times, side="right") - 1
    return values[np.clip(idx, 0, len(values) - 1)]


def _merged(grid: np.ndarray, *event_times: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Sorted unique union of grid and event times, and the grid's positions in it."""
    allt = np.unique(np.concatenate([grid, *event_times]))
    return allt, np.searchsorted(allt, grid)


def _start(grid: np.ndarray, pwm_t: np.ndarray) -> float:
    return float(min(grid[0], pwm_t[0])) if len(grid) else 0.0


# --- batch (offline) -------------------------------------------------------------------------------
def _at_the_esc(name: str, grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
                params: Mapping[str, float] | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A lag's input: the command as it reaches the ESC (after the optional ``delay_s``), at rest
    before the first, on the grid merged with its arrival times; and the grid's positions."""
    arrive = pwm_t + _optional(params or {}, name, "delay_s", 0.0)
    times, pos = _merged(grid, arrive)
    return times, pos, np.where(times < arrive[0], REST_PWM, _held(arrive, pwm, times))


def pwm_lag(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray, volt: np.ndarray,
            params: Mapping[str, float] | None = None) -> np.ndarray:
    """Command through a first-order lag of time constant ``tau_s``, at rest before the first
    command; with ``delay_s`` (optional) the command as it reaches the ESC after that dead time,
    so that a lag and a dead time in one model both act on the command the ESC acts on."""
    tau = _param(params, PWM_LAG, "tau_s")
    times, pos, u = _at_the_esc(PWM_LAG, grid, pwm_t, pwm, params)
    y: np.ndarray = lag_on_times(times, u, tau, REST_PWM)[pos]
    return y


def pwm_delayed(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray, volt: np.ndarray,
                params: Mapping[str, float] | None = None) -> np.ndarray:
    """Command as it was ``delay_s`` before each grid time (the first command before the first event)."""
    d = _param(params, PWM_DELAYED, "delay_s")
    return _held(pwm_t, pwm, np.asarray(grid, dtype=float) - d)


def pwm_above_start(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
                    volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """The part of the command above the ESC's start level: max(pwm - threshold, 0), or with
    ``map_level`` pwm - map_level from the threshold up (a gated map)."""
    return np.asarray(_map_level(_held(pwm_t, pwm, grid), _start_level(params or {}, PWM_ABOVE_START)), dtype=float)


def pwm_asymmetric_lag(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
                       volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """Command through a lag with ``tau_up_s`` when it rises and ``tau_down_s`` when it falls;
    with ``delay_s`` (optional) after that dead time, as ``pwm_lag``."""
    up = _param(params, PWM_ASYMMETRIC_LAG, "tau_up_s")
    down = _param(params, PWM_ASYMMETRIC_LAG, "tau_down_s")
    times, pos, u = _at_the_esc(PWM_ASYMMETRIC_LAG, grid, pwm_t, pwm, params)
    y: np.ndarray = asymmetric_lag_on_times(times, u, up, down, REST_PWM)[pos]
    return y


def thermal_load(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
                 volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """First-order thermal state (time constant ``tau_s``) driven by the I^2 R proxy; starts at 0."""
    tau = _param(params, THERMAL_LOAD, "tau_s")
    times, pos = _merged(grid, pwm_t, volt_t)
    q = np.asarray(thermal_proxy(_held(pwm_t, pwm, times), _held(volt_t, volt, times)))
    if len(volt_t):
        q = np.where((times < pwm_t[0]) | (times < volt_t[0]), 0.0, q)  # no loss known yet
    else:
        q = np.zeros_like(q)
    y: np.ndarray = lag_on_times(times, q, tau, 0.0)[pos]
    return y


#: An ESC start level: (threshold, map_level), the drive 0 below the first and pwm - map_level from it.
Start = tuple[float, float]


def _start_level(params: Mapping[str, float], name: str) -> Start:
    """(threshold, map_level) of a start-level input; the map starts at the threshold unless
    ``map_level`` says it starts lower (a gated map)."""
    thr = _param(params, name, "threshold")
    level = _optional(params, name, "map_level", thr)
    if level > thr:
        raise ValueError(f"{name}.map_level = {level!r}: must be at or below its threshold {thr!r} "
                         "(the map starts at the start level or below it)")
    return thr, level


def _mapping(name: str, params: Mapping[str, float]) -> tuple[float, Start | None, float, float]:
    """(dead time s, start level or None, low-pass time constant s, its time constant while the
    mapped command is 0, s) of a MAPPED_LAGS input. With no drive (below the start level) an ESC
    that does not brake leaves the rotor to coast down for seconds: ``coast_tau_s`` (optional;
    the low-pass's own when not given) lets the input say so."""
    if name == PWM_DELAYED_FILTERED:
        tau = _param(params, name, "tau_s")
        return _param(params, name, "delay_s"), None, tau, tau
    tau = _param(params, name, "tau_s")
    coast = _optional(params, name, "coast_tau_s", tau)
    return 0.0, _start_level(params, name), tau, coast


def _optional(params: Mapping[str, float], name: str, key: str, default: float) -> float:
    if key not in params:
        return default
    return _param(params, name, key)


def _map_level(level: np.ndarray | float, start: Start | None) -> np.ndarray | float:
    """The drive a command level gets past a start level (the level itself with none)."""
    if start is None:
        return level
    thr, from_level = start
    return np.where(np.asarray(level) >= thr, np.maximum(np.asarray(level) - from_level, 0.0), 0.0)


def _mapped_lag(name: str, grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray,
                params: Mapping[str, float] | None) -> np.ndarray:
    """The command delayed and/or deadband-mapped, through a first-order low-pass; the low-pass
    starts in steady state at the first mapped command (as the model's ``pwm_filtered``)."""
    d, thr, tau, coast = _mapping(name, params or {})
    et = pwm_t + d  # when each command reaches the ESC
    times, pos = _merged(grid, et)
    u = np.asarray(_map_level(_held(et, pwm, times), thr), dtype=float)
    y0 = float(u[0]) if len(u) else 0.0
    if coast == tau:
        y: np.ndarray = lag_on_times(times, u, tau, y0)[pos]
    else:
        y = switched_lag_on_times(times, u, tau, coast, y0)[pos]
    return y


def pwm_delayed_filtered(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
                         volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """Command delayed by ``delay_s`` through a low-pass of ``tau_s`` (a delayed ``pwm_filtered``)."""
    return _mapped_lag(PWM_DELAYED_FILTERED, grid, pwm_t, pwm, params)


def pwm_above_start_filtered(grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
                             volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """``pwm_above_start`` through a low-pass of ``tau_s`` (the drive the ESC gives, lagged)."""
    return _mapped_lag(PWM_ABOVE_START_FILTERED, grid, pwm_t, pwm, params)


BATCH: dict[str, Callable[..., np.ndarray]] = {
    PWM_LAG: pwm_lag,
    PWM_DELAYED: pwm_delayed,
    PWM_ABOVE_START: pwm_above_start,
    PWM_ASYMMETRIC_LAG: pwm_asymmetric_lag,
    THERMAL_LOAD: thermal_load,
    PWM_DELAYED_FILTERED: pwm_delayed_filtered,
    PWM_ABOVE_START_FILTERED: pwm_above_start_filtered,
}


# --- streaming (online) ------------------------------------------------------------------------------
class StreamingFeature:
    """One added input, fed event by event: ``update_pwm``, ``update_voltage``, ``value(t)``.

    Times must not go backwards (an older event is ignored, as the estimator ignores it).
    ``value(t)`` before any command returns NaN.
    """

    def __init__(self, name: str, params: Mapping[str, float] | None = None) -> None:
        if name not in BATCH:
            raise KeyError(name)
        self.name = name
        self.params = {**DEFAULT_PARAMS[name], **(params or {})}
        for key in self.params:
            _param(self.params, name, key)
        if name in (PWM_ABOVE_START, PWM_ABOVE_START_FILTERED):
            _start_level(self.params, name)
        self.t: float | None = None  # time the state refers to
        self.y = 0.0
        self.pwm: float | None = None
        self.volts: float | None = None
        self._history: deque[tuple[float, float]] = deque()  # (t, pwm) for the delay
        # MAPPED_LAGS and a delayed lag (``_queued``): commands not yet at the ESC (arrival time,
        # mapped level), the lag's state at time self._ts and the mapped level held since then
        self._pending: deque[tuple[float, float]] = deque()
        self._ts = -math.inf
        self._u_mapped = 0.0

    # input held since self.t
    def _u(self) -> float:
        if self.name == THERMAL_LOAD:
            if self.pwm is None or self.volts is None:
                return 0.0
            return float(thermal_proxy(self.pwm, self.volts))
        return float(self.pwm) if self.pwm is not None else 0.0

    def _advance(self, t: float) -> None:
        if self.t is None or t <= self.t:
            return
        h = t - self.t
        u = self._u()
        if self.name in (PWM_LAG, THERMAL_LOAD):
            self.y = lag_step(self.y, u, lag_gain(h, self.params["tau_s"]))
        elif self.name == PWM_ASYMMETRIC_LAG:
            tau = self.params["tau_up_s"] if u > self.y else self.params["tau_down_s"]
            self.y = lag_step(self.y, u, lag_gain(h, tau))
        self.t = t

    def _first_event(self, t: float) -> None:
        if self.t is None:
            self.t = t
            if self.name in (PWM_LAG, PWM_ASYMMETRIC_LAG):
                self.y = REST_PWM

    def _queued(self) -> bool:
        """Whether commands reach the lag through the queue: the mapped inputs, and a lag with a
        dead time (``delay_s``)."""
        return self.name in MAPPED_LAGS or (self.name in DELAYABLE_LAGS and self.params.get("delay_s", 0.0) > 0.0)

    def _enqueue(self, t: float, pwm: float) -> None:
        if self.name in MAPPED_LAGS:
            delay, thr, _, _ = _mapping(self.name, self.params)
            level = float(_map_level(float(pwm), thr))
            first = level  # steady state at the first mapped command
        else:
            delay, level, first = self.params["delay_s"], float(pwm), REST_PWM  # at rest until it arrives
        if self.pwm is None:
            self.y = first
            self._u_mapped = first
        self.pwm = float(pwm)
        self.t = t
        self._pending.append((t + delay, level))

    def _queue_taus(self) -> tuple[float, float]:
        """The queued lag's two time constants: the mapped inputs' low-pass and its time constant
        while the mapped command is 0 (``_mapping``), the asymmetric lag's up and down, the
        lag's own for both."""
        if self.name in MAPPED_LAGS:
            _, _, tau, coast = _mapping(self.name, self.params)
            return tau, coast
        if self.name == PWM_ASYMMETRIC_LAG:
            return self.params["tau_up_s"], self.params["tau_down_s"]
        return self.params["tau_s"], self.params["tau_s"]

    def _tau_towards(self, u: float, taus: tuple[float, float]) -> float:
        """The time constant towards the held level ``u`` from the state (``_queue_taus``)."""
        if self.name in MAPPED_LAGS:
            return taus[1] if u <= 0.0 else taus[0]
        return taus[0] if u > self.y else taus[1]

    def _queued_value(self, t: float) -> float:
        taus = self._queue_taus()
        while self._pending and self._pending[0][0] <= t:
            te, level = self._pending.popleft()
            if te > self._ts:
                if math.isfinite(self._ts):
                    g = lag_gain(te - self._ts, self._tau_towards(self._u_mapped, taus))
                    self.y = lag_step(self.y, self._u_mapped, g)
                self._ts = te
            self._u_mapped = level
        if t <= self._ts or not math.isfinite(self._ts):
            return float(self.y)
        g = lag_gain(t - self._ts, self._tau_towards(self._u_mapped, taus))
        return float(lag_step(self.y, self._u_mapped, g))

    def update_pwm(self, t: float, pwm: float) -> None:
        if self.t is not None and t < self.t:
            return
        if self._queued():
            self._enqueue(t, pwm)
            return
        if self.t is None:
            self.pwm = float(pwm)
            self._first_event(t)
        else:
            self._advance(t)
            self.pwm = float(pwm)
        self._history.append((float(t), float(pwm)))
        self._trim()

    def update_voltage(self, t: float, volts: float) -> None:
        if self.name != THERMAL_LOAD:
            return
        if self.t is not None and t < self.t:
            return
        if self.t is None:
            self.volts = float(volts)
            self.t = t
        else:
            self._advance(t)
            self.volts = float(volts)

    def _trim(self) -> None:
        if self.name != PWM_DELAYED:
            if len(self._history) > 1:
                self._history.popleft()
            return
        d = self.params["delay_s"]
        newest = self._history[-1][0]
        # keep the last event at or before (newest - delay) and everything after it
        while len(self._history) > 1 and self._history[1][0] <= newest - d - 1.0:
            self._history.popleft()

    def value(self, t: float) -> float:
        if self.pwm is None:
            return float("nan")
        if self._queued():
            return self._queued_value(t)
        if self.name == PWM_ABOVE_START:
            return float(_map_level(float(self.pwm), _start_level(self.params, self.name)))
        if self.name == PWM_DELAYED:
            target = t - self.params["delay_s"]
            out = self._history[0][1]
            for te, v in self._history:
                if te <= target:
                    out = v
                else:
                    break
            return float(out)
        self._advance(t)
        return float(self.y)


def compute(name: str, grid: np.ndarray, pwm_t: np.ndarray, pwm: np.ndarray, volt_t: np.ndarray,
            volt: np.ndarray, params: Mapping[str, float] | None = None) -> np.ndarray:
    """Batch value of added input ``name`` on ``grid`` (KeyError for an unknown name)."""
    return BATCH[name](np.asarray(grid, dtype=float), np.asarray(pwm_t, dtype=float),
                       np.asarray(pwm, dtype=float), np.asarray(volt_t, dtype=float),
                       np.asarray(volt, dtype=float), params)
