"""The plant stepped as a stream: PWM commands and filtered battery voltage in, rotor speed out.

The online twin of ``plant.motor_response(..., hold_supply=True)``, the batch path of a physics
model: the same steps of ``sim_step_s`` and the same arithmetic (``plant.make_step``), with the
state carried between updates, so that a stream fed a recording's samples in time order gives
the batch path's numbers (tested to 1e-9). Plain floats throughout: a few microseconds per update.

Time rules (the batch path's, said causally):

* the rotor is at rest at the first command, t0 (or at the stream's ``initial_speed``, in the
  running state ``plant.motor_response`` describes: the first command counts as applied since
  before the dead time); steps at t0 + k dt;
* step k sees the latest command frame at or before t_k - dead time (PWM_STOP before the
  first) and the latest voltage sample at or before t_k (the first sample before it);
* a step is *committed* (its state kept) once an input stamped after it has arrived: inputs
  come in time order, so nothing can still change it (inputs stamped alike may come in any
  order);
* ``speed_at(t)`` interpolates between the steps around t; the steps between the last
  committed one and t are computed from the inputs received so far and not kept;
* an input stamped before a committed step (a late message, or one more than ``LATE_S`` older
  than a prediction that asked past it) cannot rewrite the past: it acts from the next step
  (counted in ``late_inputs``).

With rotor_lag 0 the speed at a step is that step's steady state, so a prediction between two
steps looks at the next step's inputs as known at t (the batch path sees the future there).
"""

from __future__ import annotations

import math
from collections.abc import Mapping

from ..contract import EFFECTS, PAPER_FILTER_TAU_S, PWM_STOP
from .lag import lag_step
from .params import PLANT_FIELDS, PlantParams, check_plant, plant_problem, resolve_effects, strength_problem
from .plant import (
    FRAME_TOLERANCE_S,
    Supply,
    check_initial_speed,
    dead_time_s,
    esc_map,
    make_step,
    running_supply_current,
    throttle,
)

#: The parameters of a stream as one flat {name: float} (a model input's parameters,
#: core/features.py): every plant constant, every effect's strength, the stiff supply (V) and the
#: voltage input's filter time constant (s; the paper's battery filter's by default).
STREAM_DEFAULTS: dict[str, float] = {
    **{n: float(getattr(PlantParams(), n)) for n in PLANT_FIELDS},
    **{n: 1.0 for n in EFFECTS},
    "supply_v": 12.0,
    "supply_tau_s": PAPER_FILTER_TAU_S,
}


def stream_params(params: PlantParams, effects: Mapping[str, float], supply_v: float,
                  supply_tau_s: float) -> dict[str, float]:
    """A stream's parameters as one flat dict (see STREAM_DEFAULTS)."""
    return {**{n: float(getattr(params, n)) for n in PLANT_FIELDS}, **{n: float(effects[n]) for n in EFFECTS},
            "supply_v": float(supply_v), "supply_tau_s": float(supply_tau_s)}


def split_params(d: Mapping[str, float]) -> tuple[PlantParams, dict[str, float], float, float]:
    """Flat parameters -> (plant constants, effect strengths, supply_v, supply_tau_s)."""
    return (PlantParams(**{n: d[n] for n in PLANT_FIELDS}), {n: d[n] for n in EFFECTS},
            d["supply_v"], d["supply_tau_s"])


def stream_problem(d: Mapping[str, float]) -> str | None:
    """Why the flat parameters ``d`` (complete, as STREAM_DEFAULTS) make no stream, or None."""
    bad = plant_problem(PlantParams(**{n: d[n] for n in PLANT_FIELDS}))
    if bad:
        return f"{bad[0]} {bad[1]}"
    for n in EFFECTS:
        why = strength_problem(n, d[n])
        if why:
            return f"{n} {why}"
    if not d["supply_v"] > 0.0:
        return f"supply_v {d['supply_v']!r} must be a voltage > 0"
    if not d["supply_tau_s"] >= 0.0:
        return f"supply_tau_s {d['supply_tau_s']!r} must be >= 0"
    return None


#: A prediction at t commits every step before t - LATE_S: inputs later than that are late.
LATE_S = 0.5
#: Inputs consumed by committed steps are dropped in batches of this many (amortised).
_TRIM = 64


class PlantStream:
    """``update_pwm(t, level)``, ``update_voltage(t, volts)``, ``speed_at(t)``; see the module doc.

    ``v_ref``, ``supply_tau_s``: how the voltage drives the plant (``plant.Supply``).
    ``initial_speed`` (rad/s): the rotor's speed at the first command (0: at rest); equal to
    ``plant.motor_response(..., initial_speed=...)`` as at rest.
    The caller checks the samples (finite, plausible, time not going backwards per signal).
    """

    @classmethod
    def of(cls, d: Mapping[str, float], initial_speed: float = 0.0) -> PlantStream:
        """From flat, checked parameters (``stream_params``), the rotor at ``initial_speed``."""
        return cls(*split_params(d), initial_speed=initial_speed)

    def __init__(self, params: PlantParams, effects: Mapping[str, float], v_ref: float,
                 supply_tau_s: float, initial_speed: float = 0.0) -> None:
        eff = resolve_effects(effects)
        p = check_plant(params)
        sp = Supply.of(p, eff, v_ref, supply_tau_s)
        self.params = p
        self.effects = eff
        self._step = make_step(p, eff, sp.source_resistance_ohm)
        self._dt = p.sim_step_s
        self._delay = dead_time_s(p, eff)
        self._map = esc_map(p, eff)  #: throttle's (threshold, exponent, origin, curvature)
        self._supply = (sp.v_ref, sp.strength, sp.source_resistance_ohm, sp.lowpass_gain, sp.polarisation_ohm,
                        sp.polarisation_gain)
        self._supply_start = sp.start  #: the correction's state of a running start
        self.late_inputs = 0
        self.reset(initial_speed)

    def reset(self, initial_speed: float | None = None) -> None:
        """Forget the inputs and the state: the rotor at ``initial_speed`` (rad/s; None: the
        one given last, 0 at first) again at the next command."""
        if initial_speed is not None:
            self.initial_speed = check_initial_speed(initial_speed)
        self._t0: float | None = None
        self._horizon = -math.inf  #: latest input time: steps before it are final
        self._pt: list[float] = []  #: command frames from the first not yet applied (index _pi)
        self._pv: list[float] = []
        self._vt: list[float] = []  #: voltage samples from the one the committed steps hold
        self._vv: list[float] = []
        # committed state: next step, speed, winding temperature, low-passed supply current,
        # command applied and its duty, input indices, speed output of the step before
        self._k = 0
        self._w = self.initial_speed
        self._temp = self.params.ambient_temperature_c
        self._ib_lp = 0.0
        self._vp = self._vp_lp = 0.0  #: the pack's polarisation voltage and its low-passed value
        self._level = PWM_STOP
        self._duty = throttle(PWM_STOP, *self._map)
        self._pi = 0
        self._vi = 0
        self._w_last = self.initial_speed

    def set_initial_speed(self, w: float) -> None:
        """The rotor's speed (rad/s) at the first command, while none has arrived (the inputs
        received so far are kept); ValueError after it: the stream has started."""
        if self._t0 is not None:
            raise ValueError("initial speed: the stream has started (reset it first)")
        self.initial_speed = check_initial_speed(w)
        self._w = self._w_last = self.initial_speed

    @property
    def ready(self) -> bool:
        """A command and a voltage have arrived."""
        return self._t0 is not None and bool(self._vt)

    # --- inputs ------------------------------------------------------------------------------
    def update_pwm(self, t: float, level: float) -> None:
        """A command frame (PWM level) stamped t (s)."""
        t, level = float(t), float(level)  # numpy scalars would make every step 3x slower
        if self._t0 is None:
            self._t0 = t
            if self.initial_speed > 0.0:  # running: this command held since before the dead time
                self._level, self._duty = level, throttle(level, *self._map)
        elif self._k and t <= self._t0 + (self._k - 1) * self._dt - self._delay + FRAME_TOLERANCE_S:
            self.late_inputs += 1  # a committed step should have seen it
        self._pt.append(t)
        self._pv.append(level)
        self._advance(t)

    def update_voltage(self, t: float, volts: float) -> None:
        """A filtered battery voltage (V) stamped t (s)."""
        t, volts = float(t), float(volts)
        if self._t0 is not None and self._vt and t <= self._committed_t():
            self.late_inputs += 1
        self._vt.append(t)
        self._vv.append(volts)
        self._advance(t)

    # --- output ------------------------------------------------------------------------------
    def speed_at(self, t: float) -> float:
        """Rotor speed (rad/s) at t (s); NaN until ready; the initial speed (0: at rest) before
        the first command. A time before the last committed step is answered at that step."""
        t0, t = self._t0, float(t)
        if t0 is None or not self._vt or not math.isfinite(t):
            return math.nan
        if t < t0:
            return self.initial_speed
        self._advance(t - LATE_S)
        dt = self._dt
        j = int((t - t0) // dt)
        while t0 + (j + 1) * dt <= t:
            j += 1
        while j > 0 and t0 + j * dt > t:
            j -= 1
        if j < self._k - 1:
            j = self._k - 1
            t = t0 + j * dt
        prev, last = self._march(j + 2, commit=False)
        tj = t0 + j * dt
        if t == tj:
            return prev
        return (last - prev) / (t0 + (j + 1) * dt - tj) * (t - tj) + prev

    # --- stepping ----------------------------------------------------------------------------
    def _committed_t(self) -> float:
        """Time of the last committed step (-inf before the first)."""
        return self._t0 + (self._k - 1) * self._dt if self._k and self._t0 is not None else -math.inf

    def _final(self, k: int) -> bool:
        """Whether no input still to come can change step k (its inputs are stamped before the horizon)."""
        assert self._t0 is not None, "steps exist only after the first command"
        ts = self._t0 + k * self._dt
        return ts < self._horizon and ts - self._delay + FRAME_TOLERANCE_S < self._horizon

    def _advance(self, t: float) -> None:
        """Move the horizon to t (if later) and commit every step that is final."""
        if t <= self._horizon:
            return
        self._horizon = t
        if self._t0 is None or not self._vt:
            return
        bound = min(t, t + self._delay - FRAME_TOLERANCE_S)
        k_end = max(self._k, math.ceil((bound - self._t0) / self._dt))
        while k_end > self._k and not self._final(k_end - 1):
            k_end -= 1
        while self._final(k_end):
            k_end += 1
        if k_end > self._k:
            self._march(k_end, commit=True)

    def _march(self, k_end: int, commit: bool) -> tuple[float, float]:
        """Steps from the committed state up to (not including) ``k_end``; keeps the state if
        ``commit``. Returns the speed outputs of steps k_end - 2 and k_end - 1."""
        k, w, temp, ib_lp, vp, vp_lp = self._k, self._w, self._temp, self._ib_lp, self._vp, self._vp_lp
        level, duty, pi, vi = self._level, self._duty, self._pi, self._vi
        prev = last = self._w_last
        pt, pv, vt, vv = self._pt, self._pv, self._vt, self._vv
        n_p, n_v = len(pt), len(vt)
        t0, dt, lead = self._t0, self._dt, self._delay
        threshold, exponent, origin, curvature = self._map
        v_ref, sbv, rs, a_lp, rp, g_p = self._supply
        step = self._step
        assert t0 is not None, "steps exist only after the first command"
        while k < k_end:
            ts = t0 + k * dt
            x = ts - lead + FRAME_TOLERANCE_S
            if pi < n_p and pt[pi] <= x:
                held = level
                while pi < n_p and pt[pi] <= x:
                    level = pv[pi]
                    pi += 1
                if level != held:  # a 50 Hz command repeats its level most of the time
                    duty = throttle(level, threshold, exponent, origin, curvature)
            while vi + 1 < n_v and vt[vi + 1] <= ts:
                vi += 1
            if k == 0 and w > 0.0:  # started running: the supply current already filtered
                ib_lp, vp, vp_lp = self._supply_start(
                    running_supply_current(step, w, temp, duty, v_ref + sbv * (vv[vi] - v_ref), rs))
            prev = last
            last, w, i, temp = step(w, temp, duty, v_ref + sbv * (vv[vi] - v_ref) + (rs * ib_lp + (vp_lp - vp)))
            ib_lp = lag_step(ib_lp, duty * i, a_lp)
            if rp:  # (plant.Supply.advance)
                vp_lp = lag_step(vp_lp, vp, a_lp)
                vp = lag_step(vp, rp * duty * i, g_p)
            k += 1
        if commit:
            self._k, self._w, self._temp, self._ib_lp, self._vp, self._vp_lp = k, w, temp, ib_lp, vp, vp_lp
            self._level, self._duty, self._w_last = level, duty, last
            if pi > _TRIM:
                del pt[:pi], pv[:pi]
                pi = 0
            if vi > _TRIM:
                del vt[:vi], vv[:vi]
                vi = 0
            self._pi, self._vi = pi, vi
        return prev, last
