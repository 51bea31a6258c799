"""The propulsion plant: ESC throttle map and dead time, motor electrics, rotor + propeller, and
the winding's temperature. One implementation for everything that predicts the rotor's speed.

The simulator (``sim/bench.py``) drives it with its battery model and writes bags with it; a
physics model (``motor_response`` here, the batch path; ``stream.py``, the online twin the
estimator runs) drives it with the measured, filtered battery voltage. Its constants are
``params.PlantParams``; the supply is an input (nothing here knows the simulator's battery or
sensors).

Model (SI units throughout):

* ESC: the PWM level held from each frame, delayed by a dead time, mapped to a duty cycle between
  the start threshold (no drive below it) and PWM_FULL (``throttle``: a power law blended with a
  square law), applied to the supply. The map's linear part may start below the threshold
  (``map_origin``, ``esc_map_origin_share``): an ESC whose duty follows the command from about
  PWM_STOP but that starts the motor only higher up.
  Averaged (quasi-static) electrics: the winding's L/R (~30 uH / 0.26 Ohm ~ 0.1 ms) is far below
  the 1 ms step and the ~0.1 s rotor time constant, so i = (duty V - Ke w) / R_total, with the
  source's series resistance seen through the duty (R_s duty^2). The motor current is continuous
  (it freewheels through the low-side switch in the off-time); the source supplies it only during
  the on-time, so i_supply = duty * i. With active braking (synchronous rectification) i may go
  negative (regenerative braking torque); without it the ESC cannot reverse the current and i is
  clamped at 0, so the rotor coasts down on propeller drag.
* Motor: Kt = Ke = 1/Kv, friction torque Kt*I0 (no-load current), winding resistance rising with
  temperature (copper) through a one-node thermal model (I^2 R + friction heat, R_th, C_th).
* Propeller: drag torque CP rho n^2 D^5 / (2 pi), thrust CT rho n^2 D^4 = b w^2.
* Rotor: J dw/dt = Kt i - Kt I0 - k w^2, linearly implicit Euler at the fixed step (stable for
  any J); with no inertia (rotor_lag 0) the speed is the torque balance's steady state.

Effect strengths (contract names; 0 = off, 1 = the realistic nominal strength) scale the
physics as ``sim.bench.EFFECT_DOCS`` says; ``battery_voltage`` is the supply's business (the
caller's), every other one is applied here.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import TypeVar

import numpy as np

from ..contract import PWM_FULL, PWM_STOP
from ..errors import BadInputError
from .lag import lag_gain, lag_step
from .params import PlantParams, check_plant, resolve_effects

# --- ESC ---------------------------------------------------------------------------------------
Level = TypeVar("Level", float, np.ndarray)


def _clip(x: Level, lo: float, hi: float) -> Level:
    """np.clip for arrays; min/max for one float (a stream's step: 20x faster, same value)."""
    if isinstance(x, np.ndarray):
        clipped: np.ndarray = np.clip(x, lo, hi)
        return clipped
    return min(max(x, lo), hi)


def throttle(level: Level, threshold: float, exponent: float = 1.0, origin: float | None = None,
             curvature: float = 0.0) -> Level:
    """ESC throttle map, PWM level -> duty (0..1): no drive at or below the start threshold, then
    x**exponent * ((1 - curvature) + curvature x) to full duty at PWM_FULL, x the linear map
    (exponent 1 and curvature 0: linear). The linear map runs from ``origin`` (None: the threshold
    itself, so the drive rises from 0 there); an origin below the threshold makes the drive jump
    to the map's value just above it. Arrays or one float."""
    lv = _clip(level, PWM_STOP, PWM_FULL)
    if origin is None or origin == threshold:
        x = _clip((lv - threshold) / (PWM_FULL - threshold), 0.0, 1.0)
    else:
        x = _clip((lv - origin) / (PWM_FULL - origin), 0.0, 1.0)
        if isinstance(x, np.ndarray):
            x = np.where(lv <= threshold, 0.0, x)
        elif lv <= threshold:
            x = 0.0
    duty = x if exponent == 1.0 else x**exponent
    return duty if curvature == 0.0 else duty * ((1.0 - curvature) + curvature * x)


def start_level(p: PlantParams, eff: Mapping[str, float]) -> float:
    """PWM level where the ESC starts to drive (esc_deadband scales its distance from PWM_STOP)."""
    return PWM_STOP + eff["esc_deadband"] * p.esc_deadband_pwm


def map_origin(p: PlantParams, eff: Mapping[str, float]) -> float:
    """PWM level where the throttle map's linear part starts: ``esc_map_origin_share`` of the start
    threshold's distance from PWM_STOP below the threshold (the threshold itself at share 0). Scaled
    with the threshold so that an ESC without one (esc_deadband 0) never drives at PWM_STOP."""
    start = start_level(p, eff)
    return start - p.esc_map_origin_share * (start - PWM_STOP)


def esc_map(p: PlantParams, eff: Mapping[str, float]) -> tuple[float, float, float, float]:
    """``throttle``'s (threshold, exponent, origin, curvature) for the plant ``p`` under the
    strengths ``eff``: what the batch path and the stream map a level with."""
    return start_level(p, eff), p.esc_throttle_exponent, map_origin(p, eff), p.esc_throttle_curvature


def dead_time_s(p: PlantParams, eff: Mapping[str, float]) -> float:
    """Dead time between a command frame and the ESC's response (s)."""
    return eff["input_delay"] * p.esc_input_delay_s


#: A frame time within this of a step time counts as arrived at that step (float rounding).
FRAME_TOLERANCE_S = 1e-9


def esc_duty(p: PlantParams, eff: Mapping[str, float], cmd_t: np.ndarray, cmd: np.ndarray,
             t: np.ndarray) -> np.ndarray:
    """Duty cycle at the step times ``t``: the command held from each frame (PWM_STOP before the
    first), after the dead time, through the throttle map."""
    idx = np.searchsorted(cmd_t, t - dead_time_s(p, eff) + FRAME_TOLERANCE_S, side="right") - 1
    level = np.where(idx >= 0, cmd[np.maximum(idx, 0)], PWM_STOP)
    return throttle(level, *esc_map(p, eff))


def check_command(pwm: tuple[np.ndarray, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """A caller's (t, level) command: 1-D, same length, finite, time non-decreasing."""
    try:
        t, lv = (np.asarray(a, dtype=float) for a in pwm)
    except (TypeError, ValueError):
        raise BadInputError("pwm: expected a pair of numeric arrays (t, level)") from None
    if t.ndim != 1 or lv.shape != t.shape or len(t) == 0:
        raise BadInputError("pwm: t and level must be 1-D arrays of the same, non-zero length")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(lv))):
        raise BadInputError("pwm: times and levels must be finite")
    if np.any(np.diff(t) < 0):
        raise BadInputError("pwm: times must not decrease")
    return t, lv


# --- motor, rotor, thermal: one step ------------------------------------------------------------
#: ``step(w, temp, duty, v_source) -> (w_now, w_next, i_motor, temp_next)``: speed at this step
#: (rad/s; the steady state when the rotor has no inertia), speed at the next step, motor current
#: (A; the source supplies duty * i) and winding temperature at the next step (deg C).
Step = Callable[[float, float, float, float], "tuple[float, float, float, float]"]


def make_step(p: PlantParams, eff: Mapping[str, float], source_resistance_ohm: float) -> Step:
    """One step of ``p.sim_step_s`` of the motor, rotor and winding temperature, driven by a duty
    and the source's open-circuit voltage behind ``source_resistance_ohm``.

    A closure over plain floats: every caller (simulator, batch model, stream) runs the same
    arithmetic, and a step costs about a microsecond in CPython.
    """
    dt = p.sim_step_s
    ke = p.back_emf_constant_v_s_per_rad
    kt = ke
    kq = p.torque_coefficient
    tf = kt * p.motor_no_load_current_a  # friction torque; friction power = tf * w
    rw0 = p.winding_resistance_ohm
    alpha = eff["motor_heating"] * p.copper_temperature_coefficient_per_k
    t_ref = p.winding_reference_temperature_c
    resc = p.esc_resistance_ohm
    rs = float(source_resistance_ohm)
    keep = 1.0 - eff["spin_down_asymmetry"]  # fraction of negative (braking) current allowed
    jr = eff["rotor_lag"] * p.rotor_inertia_kg_m2
    t_amb = p.ambient_temperature_c
    heat = dt * (1.0 / p.motor_thermal_capacity_j_per_k)  # as dt * (1/C): the simulator's bits
    inv_rth = 1.0 / p.motor_thermal_resistance_k_per_w
    sqrt = math.sqrt

    def lagged(w: float, temp: float, d: float, veff: float) -> tuple[float, float, float, float]:
        rw = rw0 * (1.0 + alpha * (temp - t_ref))
        rd = rw + resc + rs * d * d
        i = (d * veff - ke * w) / rd
        didw = -ke / rd
        if i < 0.0:
            i *= keep
            didw *= keep
        f = kt * i - tf - kq * w * w
        wn = w + dt * f / (jr - dt * (kt * didw - 2.0 * kq * w))
        if wn < 0.0:
            wn = 0.0
        return w, wn, i, temp + heat * (i * i * rw + tf * w - (temp - t_amb) * inv_rth)

    def steady(w: float, temp: float, d: float, veff: float) -> tuple[float, float, float, float]:
        rw = rw0 * (1.0 + alpha * (temp - t_ref))
        rd = rw + resc + rs * d * d
        # kq w^2 + (kt ke / rd) w + (tf - kt d veff / rd) = 0
        c = tf - kt * d * veff / rd
        if c >= 0.0:
            w = 0.0
        else:
            b = kt * ke / rd
            w = (-b + sqrt(b * b - 4.0 * kq * c)) / (2.0 * kq)
        i = (d * veff - ke * w) / rd
        if i < 0.0:
            i *= keep
        return w, w, i, temp + heat * (i * i * rw + tf * w - (temp - t_amb) * inv_rth)

    return lagged if jr > 0.0 else steady


# --- what recordings identify: the rotor's time constant and the warm winding's speed loss -----------
# Without a current measurement the static map fixes only the product of the winding resistance and
# the propeller's torque coefficient (duty V = Ke w + R k w^2 / Kt + R I0), so two benches with the
# same map may split it differently: a rotor inertia or a copper coefficient fitted with the CONFIG's
# split is in the CONFIG's terms. The rotor's time constant at a speed and the speed lost once the
# winding is warm are what the recordings show, on any split.
def spin_up_time_constant_s(p: PlantParams, eff: Mapping[str, float], w: float) -> float:
    """The rotor's small-signal time constant at speed ``w`` (rad/s): J over the slope of the net
    torque (the back-EMF's Kt Ke / R and the propeller's 2 k w), cold winding, stiff supply: the
    linearisation of ``make_step``'s rotor."""
    ke = p.back_emf_constant_v_s_per_rad
    damping = ke * ke / (p.winding_resistance_ohm + p.esc_resistance_ohm) + 2.0 * p.torque_coefficient * w
    return float(eff["rotor_lag"] * p.rotor_inertia_kg_m2 / damping)


def full_drive_speeds(p: PlantParams, eff: Mapping[str, float], v: float) -> tuple[float, float]:
    """(cold, warm) steady speed at full duty on a stiff ``v``: the winding at ambient, and at the
    temperature where its losses and the thermal resistance balance (``make_step``'s arithmetic,
    stepped at a fifth of the thermal time constant until it levels off)."""
    tau_th = p.motor_thermal_capacity_j_per_k * p.motor_thermal_resistance_k_per_w
    step = make_step(dataclasses.replace(p, sim_step_s=0.2 * tau_th), {**eff, "rotor_lag": 0.0}, 0.0)
    temp = p.ambient_temperature_c
    cold = w = step(0.0, temp, 1.0, v)[0]
    for _ in range(200):  # 0.8^200: converged
        w, _, _, temp = step(w, temp, 1.0, v)
    return cold, w


# --- driven by a measured supply --------------------------------------------------------------
@dataclass(frozen=True)
class Supply:
    """How a measured battery voltage drives the plant (what the batch model and the stream share).

    ``battery_voltage`` strength s makes the motor see v_ref + s (V - v_ref): 0 is a stiff supply
    at ``v_ref``, 1 the measured voltage. The measured voltage already carries the series
    resistance's drop; if it was measured through a first-order low-pass of ``tau_s`` > 0 (the
    battery filter), the part of the drop the filter has not yet passed, R_s (i - lowpass(i)), is
    taken off again: the source voltage is V + R_s lowpass(i_supply), behind R_s. Likewise the
    pack's polarisation branch (R_p, tau_p: its voltage v_p follows R_p i_supply with tau_p), whose
    sag the filter has passed only in part: the motor sees V + lowpass(v_p) - v_p more.
    (``correction``: what the caller adds to the scaled voltage, and how its state moves.)
    """

    v_ref: float
    strength: float
    source_resistance_ohm: float  #: s R_s with a filtered voltage, 0 with the terminal's own
    lowpass_gain: float  #: per step, 1 - exp(-dt / tau_s) (0 without a filter)
    polarisation_ohm: float = 0.0  #: s R_p with a filtered voltage, else 0
    polarisation_gain: float = 0.0  #: per step, 1 - exp(-dt / tau_p)

    @classmethod
    def of(cls, p: PlantParams, eff: Mapping[str, float], v_ref: float, tau_s: float) -> Supply:
        s = eff["battery_voltage"]
        rs = s * p.battery_series_resistance_ohm if tau_s > 0.0 else 0.0
        gain = lag_gain(p.sim_step_s, tau_s) if tau_s > 0.0 else 0.0
        rp = s * p.supply_polarisation_resistance_ohm if tau_s > 0.0 else 0.0
        gp = lag_gain(p.sim_step_s, p.supply_polarisation_time_constant_s) if rp > 0.0 else 0.0
        return cls(float(v_ref), s, rs, gain, rp, gp)

    def start(self, ib: float) -> tuple[float, float, float]:
        """The correction's state (lowpass(i_supply), v_p, lowpass(v_p)) of a pack that has
        supplied ``ib`` (A) for long: the filter has passed all of its drop."""
        vp = self.polarisation_ohm * ib
        return ib, vp, vp

    def advance(self, state: tuple[float, float, float], ib: float) -> tuple[float, float, float]:
        """The state after a step that drew ``ib`` (A) from the supply."""
        ib_lp, vp, vp_lp = state
        ib_lp = lag_step(ib_lp, ib, self.lowpass_gain)
        if self.polarisation_ohm == 0.0:
            return ib_lp, vp, vp_lp
        # the filter has seen the branch as it stood during the step, before the step's current moved it
        vp_lp = lag_step(vp_lp, vp, self.lowpass_gain)
        return ib_lp, lag_step(vp, self.polarisation_ohm * ib, self.polarisation_gain), vp_lp

    def correction(self, state: tuple[float, float, float]) -> float:
        """What the motor sees (V) beyond the scaled measured voltage, before the series
        resistance's own drop (``make_step`` takes R_s duty^2 off): R_s lowpass(i) + lowpass(v_p) - v_p."""
        ib_lp, vp, vp_lp = state
        return self.source_resistance_ohm * ib_lp + (vp_lp - vp)


def held(sample_t: np.ndarray, sample_v: np.ndarray, t: np.ndarray) -> np.ndarray:
    """The latest sample at or before each time ``t`` (the first sample before it)."""
    return sample_v[np.maximum(np.searchsorted(sample_t, t, side="right") - 1, 0)]


def check_initial_speed(w: object) -> float:
    """``w`` as the rotor speed a run starts from (rad/s: finite, >= 0), else BadInputError."""
    try:
        x = float(w)  # type: ignore[arg-type]  # any JSON/CLI value: float() sorts it out, below
    except (TypeError, ValueError):
        raise BadInputError(f"initial_speed: {w!r} is not a number") from None
    if not (math.isfinite(x) and x >= 0.0):
        raise BadInputError(f"initial_speed: {w!r} must be a finite rotor speed >= 0 (rad/s)")
    return x


#: A measured speed below this (rad/s) is rest: about the tachometer's slowest measurable speed
#: (its 0.3 s timeout is a revolution at ~5 rad/s), and a start from it differs from one at rest
#: by less than the tachometer's noise.
REST_SPEED_RAD_S = 5.0
#: ``measured_start_speed`` looks at a recording's first START_SAMPLES measured samples (50 ms
#: on the 100 Hz grid) and trusts them when START_AGREE of them lie within START_TOLERANCE of
#: their median: a lone spike (or two) is outvoted, and a rotor still spinning up after a step
#: (~10 % of its speed per 10 ms on the nominal bench) still agrees.
START_SAMPLES = 5
START_AGREE = 3
START_TOLERANCE = 0.2
#: The measured speed is the physics' start only when it starts within this (s) of the first
#: command, where the physics starts: the tachometer's first speed needs a batch and a revolution
#: (~10-30 ms at speed). A recording whose speed starts later (a part of a longer one, cut after
#: its commands began) runs the physics from its first command at rest, as before.
START_GAP_S = 0.1


def measured_start_speed(t: np.ndarray, speed: np.ndarray, first_command_t: float) -> float:
    """The rotor's speed (rad/s) where a recording starts, from its measured speed ``speed`` on
    the grid ``t``: the earliest of the first START_SAMPLES samples that agrees with the others
    (see START_AGREE), 0 (rest, as a recording starting from rest) when the rotor is at rest
    (REST_SPEED_RAD_S), when the samples do not agree or are not all finite, or when they start
    more than START_GAP_S from ``first_command_t`` (where the physics starts)."""
    t, speed = np.asarray(t, dtype=float), np.asarray(speed, dtype=float)
    if len(t) < START_SAMPLES or not abs(float(t[0]) - float(first_command_t)) <= START_GAP_S:
        return 0.0
    x = speed[:START_SAMPLES]
    if not np.all(np.isfinite(x)):
        return 0.0
    m = float(np.median(x))
    near = np.abs(x - m) <= START_TOLERANCE * m
    if m < REST_SPEED_RAD_S or int(near.sum()) < START_AGREE:
        return 0.0
    return float(x[int(np.argmax(near))])


#: Most rounds of ``running_supply_current``'s fixed point: each shrinks its error by
#: R_s duty^2 / (R_s duty^2 + R_winding + R_esc), below 0.15 on the nominal bench and below 0.5
#: unless the pack's resistance exceeds the motor circuit's.
_SUPPLY_ROUNDS = 60


def running_supply_current(step: Step, w: float, temp: float, duty: float, source_v: float,
                           source_resistance_ohm: float) -> float:
    """The low-passed supply current (A) of a rotor already running at ``w`` under ``duty``.

    A battery filter started on a running motor starts on the loaded terminal voltage: it has
    already passed the drop of the present current, so the part :class:`Supply` puts back is the
    present supply current, ib = duty * i(source_v + R_s ib) (a fixed point; i as ``step``
    computes it). Starting it at 0 instead would take that drop off the motor a second time and
    decay only with the filter's 2 s. The batch path and the stream call this with the same
    floats, so they start alike.
    """
    ib = 0.0
    for _ in range(_SUPPLY_ROUNDS):
        last, ib = ib, duty * step(w, temp, duty, source_v + source_resistance_ohm * ib)[2]
        if ib == last:
            break
    return ib


def motor_response(
    params: PlantParams,
    effects: Mapping[str, float],
    pwm_events: tuple[np.ndarray, np.ndarray],
    supply: tuple[np.ndarray, np.ndarray],
    t_out: np.ndarray,
    v_ref: float,
    supply_tau_s: float = 0.0,
    hold_supply: bool = False,
    initial_speed: float = 0.0,
) -> np.ndarray:
    """Rotor speed (rad/s) at the times ``t_out``, driven by a recording's command events
    (t, level) and a measured supply voltage (t, V): the batch path of the physics model.

    The rotor starts at ``initial_speed`` (rad/s; 0: at rest) at the first command (or
    ``t_out[0]`` if earlier), steps of ``params.sim_step_s``; the speed is linearly interpolated
    onto ``t_out``. A recording that begins with the rotor turning starts in its running state:
    the first command counts as applied since before the dead time (a rotor at rest counts
    PWM_STOP before it, which would brake a turning one for the dead time), the low-passed supply
    current is the running one (:func:`running_supply_current`), and the winding is at ambient
    temperature (nothing in a recording says how warm it is). The supply is
    linearly interpolated onto the steps (held before the first and after the last sample), or
    with ``hold_supply`` held from the latest sample at or before each step: what a stream knows
    then, so ``stream.PlantStream`` gives the same numbers sample by sample.
    ``v_ref`` and ``supply_tau_s``: see :class:`Supply`.
    """
    return motor_response_with_current(params, effects, pwm_events, supply, t_out, v_ref, supply_tau_s, hold_supply,
                                       initial_speed)[0]


def motor_response_with_current(
    params: PlantParams,
    effects: Mapping[str, float],
    pwm_events: tuple[np.ndarray, np.ndarray],
    supply: tuple[np.ndarray, np.ndarray],
    t_out: np.ndarray,
    v_ref: float,
    supply_tau_s: float = 0.0,
    hold_supply: bool = False,
    initial_speed: float = 0.0,
) -> tuple[np.ndarray, np.ndarray]:
    """``motor_response``'s speed (rad/s) and the supply current (A) at ``t_out``, from the same
    steps: duty x the motor current, what a stand (or an ESC's telemetry) measures on the supply
    side of the ESC, so a fit can compare it with a measured one."""
    eff = resolve_effects(effects)
    p = check_plant(params)
    cmd_t, cmd = check_command(pwm_events)
    w0 = check_initial_speed(initial_speed)
    t_out = np.asarray(t_out, dtype=float)
    t0 = min(float(cmd_t[0]), float(t_out[0]))
    if w0 > 0.0:  # running: the first command held since long before (no PWM_STOP before it)
        cmd_t, cmd = np.concatenate(([-np.inf], cmd_t)), np.concatenate((cmd[:1], cmd))
    dt = p.sim_step_s
    n = int(math.ceil((float(t_out[-1]) - t0) / dt - 1e-9)) + 1
    step_t = t0 + np.arange(n) * dt
    sup_t, sup_v = (np.asarray(a, dtype=float) for a in supply)
    sp = Supply.of(p, eff, v_ref, float(supply_tau_s))
    volts = held(sup_t, sup_v, step_t) if hold_supply else np.interp(step_t, sup_t, sup_v)
    source = (sp.v_ref + sp.strength * (volts - sp.v_ref)).tolist()
    duty = esc_duty(p, eff, cmd_t, cmd, step_t).tolist()
    step = make_step(p, eff, sp.source_resistance_ohm)
    w = w0
    temp = p.ambient_temperature_c
    ib0 = running_supply_current(step, w0, temp, duty[0], source[0], sp.source_resistance_ohm) if w0 > 0.0 else 0.0
    ib_lp, vp, vp_lp = sp.start(ib0)
    rs, a_lp, rp, g_p = sp.source_resistance_ohm, sp.lowpass_gain, sp.polarisation_ohm, sp.polarisation_gain
    speed = [0.0] * n
    current = [0.0] * n
    for k in range(n):  # Supply.correction and Supply.advance, inlined: the fits' innermost loop
        d = duty[k]
        speed[k], w, i, temp = step(w, temp, d, source[k] + (rs * ib_lp + (vp_lp - vp)))
        current[k] = ib = d * i
        ib_lp = lag_step(ib_lp, ib, a_lp)
        if rp:
            vp_lp = lag_step(vp_lp, vp, a_lp)
            vp = lag_step(vp, rp * ib, g_p)
    return np.interp(t_out, step_t, speed), np.interp(t_out, step_t, current)
