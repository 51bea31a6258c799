"""Health monitor: names a propulsion fault in flight from command, filtered voltage and rotor speed.

A physics model predicts the rotor speed from the command and the filtered battery voltage; when
the propeller, the pack or the motor changes, the measured speed (and the voltage) drift away
from what the model expects, each change in a shape of its own. The monitor tests, for every
candidate onset in the last few seconds and every fault of the contract
(interfaces.md, "Changes a vehicle meets in flight"), whether the data after the onset moved
along that fault's SIGNATURE, and names the one that explains the change best.

Why this design (a GLR per fault on two channels, with a nuisance fit) and not a CUSUM on the
speed residual alone:

* the faults differ in shape, not only in size: a damaged propeller speeds the rotor up (less
  drag) and lowers its current; a hotter winding slows it and lowers the current; more friction
  slows it and raises the current; more pack resistance barely moves the speed (the model is fed
  the measured voltage, sag included) but makes the pack sag more per ampere. So each fault gets
  a signature in the SPEED residual (d predicted speed / d theta, from the physics run with theta
  perturbed: :class:`PhysicsTwins`) and one in the PACK VOLTAGE (the sag its current change
  causes), and the GLR tests each signature on both channels at once;
* the battery filter (first order, 2 s) is undone on 0.1 s blocks (the terminal voltage's block
  mean follows exactly from the filtered voltage at the block ends), so the voltage channel is a
  static relation: terminal voltage = open-circuit part - R * model current;
* a fitted model is never exact: its error along a fault's direction, a slow drift (discharge,
  warming, polarisation) and an offset are NUISANCE, fitted on the whole window (reference
  seconds before the onset plus the seconds after it), so only a change AT the onset counts; the
  speed's drift and its curvature carry a Gaussian prior of the size the flight's windows show
  (empirical Bayes), so a step in the window's last seconds is not taken for bending;
* the residuals are autocorrelated (a model error lasts as long as the operating point), so the
  noise's variance and its correlation time (the variance of a sum of n blocks is
  n * sigma^2 * kappa) are estimated per channel from the reference part of the window; what is
  known of a block's noise is not left to that estimate, which sees only the speeds and currents
  the reference visited: a speed block is never taken quieter than its own samples' scatter says,
  and it carries the noise the filtered voltage feeds into the prediction (sized by the voltage
  channel's own noise); a voltage block where the current steps carries the model's timing error;
* the model undoes the battery filter with its fitted source resistance; the error that leaves
  after every current step (decaying with the filter) is taken out of the speed residual with
  the pack's sag per ampere the voltage channel shows;
* the threshold is the chi-square(1) tail at a false-alarm rate per hour divided by the number
  of tests (faults x onsets x evaluations per hour), Bonferroni;
* a change that no candidate explains (the best one's signature leaves a significant step in
  the residual, tested where some fault could show: not on a voltage block at rest, which only
  pins the open-circuit voltage) is reported as an unnamed change, never a wrong name; a name
  waits while two candidates explain the change about equally well; an unnamed change whose
  statistic has fallen back under the threshold by the end of that wait (or of the data) did not
  hold (a fault is a static change) and is no alarm; nor is one that shows only at currents the
  reference never held, where the voltage's nuisance extrapolates (``_unseen_currents``).

``HealthMonitor`` is numpy only (no physics, no ROS): it is fed, at each measured speed sample,
what the estimator knows (:class:`HealthSample`). ``PhysicsTwins`` computes the model's speed,
supply current and the signatures by stepping the plant (``plant.make_step``) once per fault with
its parameter perturbed. ``HealthStream`` feeds both from what an estimator accepts, one input at a
time: the node, ``replay --health``, ``evaluate --health`` and ``bldc-propulsion health`` all run it.
"""

from __future__ import annotations

import dataclasses
import functools
import math
from collections import deque
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Protocol, cast

import numpy as np

from ..contract import PWM_STOP
from ..errors import BadInputError
from ..physics.lag import lag_on_times
from ..physics.params import PlantParams, resolve_effects
from ..physics.plant import (
    FRAME_TOLERANCE_S,
    Step,
    Supply,
    dead_time_s,
    esc_map,
    full_drive_speeds,
    make_step,
    throttle,
)
from ..runs import true_run_pairs
from .status import ERROR, OK, WARN, CoreStatus, counters

if TYPE_CHECKING:
    from ..physics.plant_model import PlantModel
    from .estimator import Adapter, SpeedModel, ThrustEstimator

#: The contract's fault names, in the order the monitor reports them.
FAULTS: tuple[str, ...] = ("propeller_damage", "pack_resistance", "bearing_friction", "motor_heating")
#: Each fault's size unit: the propeller's fractional loss of CT and CP, the factor on the pack's
#: series resistance, the factor on the friction torque, kelvin the winding runs hotter
#: (sim/faults.py states the same sizes).
FAULT_UNITS: dict[str, str] = {"propeller_damage": "fraction", "pack_resistance": "factor",
                               "bearing_friction": "factor", "motor_heating": "K"}
#: The name of a change that no candidate explains.
UNNAMED = "unnamed change"

#: Perturbations the signatures are computed with (finite differences of the plant): small
#: enough to stay linear, large enough to stand above float rounding.
_PROPELLER_STEP = 0.05  #: fraction of CT and CP
_PACK_STEP = 0.5  #: fraction of the model's series resistance (speed channel; ohm-scaled)
_FRICTION_STEP = 0.5  #: fraction of the model's friction torque
_HEATING_STEP_K = 10.0
_VOLTAGE_STEP_V = 0.2
#: Copper's temperature coefficient (1/K) when the model states none: the winding is copper
#: whatever heating strength a fit gave the model.
_COPPER_PER_K = 0.00393
#: Friction reference when the model has none (A of no-load current): the nominal bench's.
_FRICTION_REFERENCE_A = 0.4
#: Series resistance reference when the model has none (ohm): the nominal bench's.
PACK_REFERENCE_OHM = 0.035


def heated(params: PlantParams, kelvin: float) -> PlantParams:
    """``params`` with the winding ``kelvin`` hotter: its resistance scaled by copper's (or the
    model's) temperature coefficient; what a ``motor_heating`` fault of that size is."""
    alpha = params.copper_temperature_coefficient_per_k or _COPPER_PER_K
    return dataclasses.replace(params, winding_resistance_ohm=params.winding_resistance_ohm * (1.0 + alpha * kelvin))


# --- the physics side: the model's speed, current and the faults' signatures ---------------------
@dataclass(frozen=True)
class TwinSample:
    """What the physics says at one time: the model's speed (rad/s) and supply current (A), and per
    fault the change of each per unit of the fault's parameter (``PhysicsTwins.units``)."""

    t: float
    speed_rad_s: float
    current_a: float
    speed_sensitivity: tuple[float, ...]  #: d speed / d theta per fault (FAULTS order)
    current_sensitivity: tuple[float, ...]  #: d supply current / d theta per fault
    voltage_sensitivity: float = 0.0  #: d speed / d supply voltage (rad/s per V)
    #: per fault, d steady speed / d theta at this command and voltage: what speed_sensitivity
    #: comes to once the rotors settle (empty unless PhysicsTwins was asked for it)
    static_sensitivity: tuple[float, ...] = ()


class PhysicsTwins:
    """The plant of a physics model stepped once as it is and once per fault with that fault's
    parameter perturbed, on the same inputs: the signatures are the differences.

    Fed the command frames and the filtered voltage in time order (``update_pwm``,
    ``update_voltage``), asked ``sample(t)`` at each measured speed sample; the time rules are
    ``physics.stream``'s (steps of the model's ``sim_step_s`` from the first command; a step
    sees the latest frame at or before it less the dead time and the latest voltage at or before
    it), so the nominal lane is the physics model's prediction. theta per fault, in the units the
    monitor estimates: the propeller's loss (fraction), the pack's added series resistance (ohm),
    the friction torque's added share of the model's (factor - 1) and the winding's added
    temperature (K). ``faults``: the lanes stepped (FAULTS order kept; the sensitivities come in
    that order) and ``voltage_lane``: whether d speed / d volt is stepped too (0 without it); an
    online adapter steps only what it adapts, each lane costing a plant step. ``static``: each
    sample also says what the speed sensitivities come to once the rotors settle (a steady
    solve per lane; the monitor's test of a settled block).
    """

    def __init__(self, params: PlantParams, effects: Mapping[str, float], supply_v: float,
                 supply_tau_s: float, faults: Sequence[str] = FAULTS, voltage_lane: bool = True,
                 static: bool = False) -> None:
        eff = resolve_effects(effects)
        self.params = params
        rs = params.battery_series_resistance_ohm
        #: the pack's series resistance the signatures are relative to (ohm)
        self.pack_resistance_ohm = rs if rs > 0.0 else PACK_REFERENCE_OHM
        i0 = params.motor_no_load_current_a
        #: the friction (no-load current, A) a factor is relative to
        self.friction_reference_a = i0 if i0 > 0.0 else _FRICTION_REFERENCE_A
        self._scale_of = (eff, supply_v)  # speed_scale_rad_s's
        d_pack = _PACK_STEP * self.pack_resistance_ohm
        per_fault = {
            "propeller_damage": (dataclasses.replace(
                params, propeller_ct=params.propeller_ct * (1.0 - _PROPELLER_STEP),
                propeller_cp=params.propeller_cp * (1.0 - _PROPELLER_STEP)), _PROPELLER_STEP),
            "pack_resistance": (dataclasses.replace(params, battery_series_resistance_ohm=rs + d_pack), d_pack),
            "bearing_friction": (dataclasses.replace(
                params, motor_no_load_current_a=i0 + _FRICTION_STEP * self.friction_reference_a), _FRICTION_STEP),
            "motor_heating": (heated(params, _HEATING_STEP_K), _HEATING_STEP_K),
        }
        unknown = sorted(set(faults) - set(FAULTS))
        if unknown:
            raise ValueError(f"PhysicsTwins: no lane for {', '.join(unknown)} (known: {', '.join(FAULTS)})")
        #: the faults whose lanes are stepped, in FAULTS order (the sensitivities' order)
        self.faults = tuple(f for f in FAULTS if f in faults)
        lanes = [(params, 1.0), *(per_fault[f] for f in self.faults)]
        lanes.append((params, _VOLTAGE_STEP_V))  # the supply _VOLTAGE_STEP_V higher: d speed / d volt
        self._lift = [0.0] * (len(lanes) - 1) + [_VOLTAGE_STEP_V]
        if not voltage_lane:
            del lanes[-1], self._lift[-1]
        self._steps: list[Step] = []
        #: per lane, its plant without the rotor's inertia: the steady speed it settles at
        self._equilibria: list[Step] = []
        self._rs: list[float] = []
        self._rp: list[float] = []  #: per lane, the polarisation's s R_p and its gain per step
        self._gp: list[float] = []
        self._inv: list[float] = []
        for p, delta in lanes:
            sp = Supply.of(p, eff, supply_v, supply_tau_s)
            self._steps.append(make_step(p, eff, sp.source_resistance_ohm))
            if static:
                self._equilibria.append(make_step(p, {**eff, "rotor_lag": 0.0}, sp.source_resistance_ohm))
            self._rs.append(sp.source_resistance_ohm)
            self._rp.append(sp.polarisation_ohm)
            self._gp.append(sp.polarisation_gain)
            self._inv.append(1.0 / delta)
        sp = Supply.of(params, eff, supply_v, supply_tau_s)
        self._v_ref, self._sbv, self._a_lp = sp.v_ref, sp.strength, sp.lowpass_gain
        #: the series resistance the model adds back when it undoes the battery filter (ohm)
        self.source_resistance_ohm = sp.source_resistance_ohm
        self._dt = params.sim_step_s
        self._delay = dead_time_s(params, eff)
        self._map = esc_map(params, eff)  #: throttle's (threshold, exponent, origin, curvature), as the stream's
        self._t0: float | None = None
        self._pt: list[float] = []
        self._pv: list[float] = []
        self._vt: list[float] = []
        self._vv: list[float] = []
        self._pi = 0
        self._vi = 0
        self._k = 0
        self._level = PWM_STOP
        self._duty = throttle(PWM_STOP, *self._map)
        n = len(lanes)
        self._w = [0.0] * n
        self._temp = [params.ambient_temperature_c] * n
        self._ib_lp = [0.0] * n
        self._vp = [0.0] * n  #: the pack's polarisation voltage per lane, and its low-passed value
        self._vp_lp = [0.0] * n
        self._ib = [0.0] * n
        self._w_now = [0.0] * n

    @functools.cached_property
    def speed_scale_rad_s(self) -> float:
        """The model's cold full-drive speed on its supply (rad/s): the monitor's speed scale.
        Solved when first asked (~0.1 ms): an online adapter rebuilding its lanes never asks."""
        return float(full_drive_speeds(self.params, *self._scale_of)[0])

    def update_pwm(self, t: float, level: float) -> None:
        """A command frame (PWM level) stamped t (s)."""
        if self._t0 is None:
            self._t0 = float(t)
        self._pt.append(float(t))
        self._pv.append(float(level))

    def update_voltage(self, t: float, volts: float) -> None:
        """A filtered battery voltage (V) stamped t (s)."""
        self._vt.append(float(t))
        self._vv.append(float(volts))

    def sample(self, t: float) -> TwinSample | None:
        """Step every lane up to t (s) and say what they give there; None before a command and a
        voltage have arrived."""
        t0 = self._t0
        if t0 is None or not self._vt or t < t0:
            return None
        dt, lead = self._dt, self._delay
        k_end = int((t - t0) / dt + 1e-9) + 1
        pt, pv, vt, vv = self._pt, self._pv, self._vt, self._vv
        pi, vi, k = self._pi, self._vi, self._k
        level, duty = self._level, self._duty
        threshold, exponent, origin, curvature = self._map
        v_ref, sbv, a_lp = self._v_ref, self._sbv, self._a_lp
        steps, rs, rp, gp, lift = self._steps, self._rs, self._rp, self._gp, self._lift
        w, temp, ib_lp, ib, w_now = self._w, self._temp, self._ib_lp, self._ib, self._w_now
        vp, vp_lp = self._vp, self._vp_lp
        lanes = range(len(steps))
        while k < k_end:
            ts = t0 + k * dt
            x = ts - lead + FRAME_TOLERANCE_S
            if pi < len(pt) and pt[pi] <= x:
                held = level
                while pi < len(pt) and pt[pi] <= x:
                    level = pv[pi]
                    pi += 1
                if level != held:
                    duty = throttle(level, threshold, exponent, origin, curvature)
            while vi + 1 < len(vt) and vt[vi + 1] <= ts:
                vi += 1
            source = v_ref + sbv * (vv[vi] - v_ref)
            for j in lanes:
                w_now[j], w[j], i, temp[j] = steps[j](w[j], temp[j], duty,
                                                      source + lift[j] + (rs[j] * ib_lp[j] + (vp_lp[j] - vp[j])))
                ib[j] = duty * i
                ib_lp[j] += a_lp * (ib[j] - ib_lp[j])
                if rp[j]:  # (plant.Supply.advance)
                    vp_lp[j] += a_lp * (vp[j] - vp_lp[j])
                    vp[j] += gp[j] * (rp[j] * ib[j] - vp[j])
            k += 1
        self._k, self._level, self._duty = k, level, duty
        if pi > 64:  # inputs consumed: dropped in batches (amortised)
            del pt[:pi], pv[:pi]
            pi = 0
        if vi > 64:
            del vt[:vi], vv[:vi]
            vi = 0
        self._pi, self._vi = pi, vi
        inv = self._inv
        nf = len(self.faults)  # the nominal lane, a lane per fault, the voltage lane (if stepped)
        static: tuple[float, ...] = ()
        if self._equilibria:  # at the latest step's inputs (vv[vi]: its voltage, kept by the trim above)
            source = v_ref + sbv * (vv[vi] - v_ref)
            eq = [self._equilibria[j](0.0, temp[j], duty, source + lift[j] + rs[j] * ib_lp[j] + (vp_lp[j] - vp[j]))[0]
                  for j in range(nf + 1)]
            static = tuple((eq[j] - eq[0]) * inv[j] for j in range(1, nf + 1))
        return TwinSample(float(t), w_now[0], ib[0],
                          tuple((w_now[j] - w_now[0]) * inv[j] for j in range(1, nf + 1)),
                          tuple((ib[j] - ib[0]) * inv[j] for j in range(1, nf + 1)),
                          (w_now[-1] - w_now[0]) * inv[-1] if len(steps) > nf + 1 else 0.0, static)


# --- the statistics side -------------------------------------------------------------------------
@dataclass(frozen=True)
class HealthConfig:
    """How the monitor decides (times in s). Defaults: see each field."""

    #: residuals, signatures and the voltage are averaged over blocks of this length
    block_s: float = 0.1
    #: the tests run every this many blocks
    evaluate_every: int = 2
    #: longest time after an onset that is tested (the goal: named within 5 s)
    window_s: float = 5.0
    #: shortest time after an onset that is tested
    min_post_s: float = 0.4
    #: candidate onsets are this far apart
    onset_step_s: float = 0.2
    #: data before the onset that the nuisance (offset, drift, the model's own error) and the
    #: noise are fitted on: as much as the flight has, up to reference_s, at least
    #: min_reference_s (the monitor arms once it has that, window_s and learn_s). Why up to 40 s:
    #: the speed channel tests only where its reference holds steady blocks of a turning rotor
    #: (_MIN_REFERENCE_BLOCKS in _MIN_REFERENCE_STRETCHES stretches), and 20 s of random steps
    #: often hold fewer, leaving the voltage channel alone (on tuning benches 1-9, 73 % of the
    #: faults found within 5 s and named right against 62 % with 20 s; docs/results.md has fresh ones)
    reference_s: float = 40.0
    min_reference_s: float = 20.0
    #: false alarms per hour the threshold allows (Bonferroni over every test run in an hour)
    false_alarms_per_hour: float = 0.01
    #: a name is given once the best candidate's statistic exceeds the next one's by this much
    #: (a likelihood ratio of e^(margin/2)), or by _UNEXPLAINED_SHARE of its own statistic when
    #: that is more (a signature is never exact), else it waits, at most name_within_s after the onset
    #: (a second operating point usually tells the candidates apart); the size is refined until
    #: refine_within_s after the onset
    name_margin: float = 9.0
    name_within_s: float = 25.0
    #: a named change is reported (its size refined until then) this long after its onset, or at
    #: once if named later. Why the name may wait longer than this: heating and friction slow the
    #: rotor alike at one load (their speed signatures differ only in how they scale with the
    #: current: cos^2 0.98 over a hover's steady blocks on tuning bench 2), and the pack voltage,
    #: where their currents part (-0.17 A and +0.3 A, 4-8 mV of sag), carries the ESC's
    #: modulation (~50 mV a block at 5 A): 15 s tell them apart only once the flight has held
    #: another load, and on tuning benches 1-9 the one 30 K winding rise left unnamed after 15 s
    #: (and a 3x friction at the same onset) was named right by 23 s. Reports of the changes named
    #: within 15 s keep their time and size.
    refine_within_s: float = 15.0
    #: blocks whose predicted speed is below this share of the highest predicted so far carry no
    #: speed test (a rotor at rest or in the dead band shows no fault and its noise differs)
    min_speed_fraction: float = 0.15
    #: memory of the noise estimates (s): they follow the flight's regime, slowly
    noise_memory_s: float = 60.0
    #: after the window first fills (and after each change), the noise is learned this long
    #: before a test may alarm: one window's estimate alone is too rough
    learn_s: float = 10.0
    #: the noise variance is taken this many times what the residuals show: the model's error
    #: has heavier tails than a Gaussian's and its variance is estimated on a short reference
    #: (tuned on healthy flights of tuning benches, see benchmarks/bench_health.py)
    noise_inflation: float = 2.0
    #: a data gap longer than this restarts the window (s)
    max_gap_s: float = 1.0
    #: the smallest change of each fault worth an alarm, in its unit (FAULT_UNITS: a fraction of
    #: CT and CP lost, a factor on the pack's or the friction's resistance, kelvin): a third of
    #: the sizes a vehicle must be warned of (issue 34: a 10 % propeller loss, a 2x pack
    #: resistance, a 30 K winding rise; friction 1.5x). A named change whose size could, at two
    #: sigma, be below it is a minor change: kept in ``HealthMonitor.minor``, never an alarm. Why:
    #: on clean data a change of a few per mille is significant (a real stand log's supply
    #: stiffening by 5 %; a propeller 0.7 % weaker on a healthy simulated flight), and an alarm
    #: for it is a false one to whoever flies; an alarm says a fault, so it waits until its size
    #: is sure (a healthy flight's winding read 12.7 +- 1.9 K warmer: no fault a flight needs)
    min_size: tuple[tuple[str, float], ...] = (
        ("propeller_damage", 0.03), ("pack_resistance", 1.3), ("bearing_friction", 1.5),
        ("motor_heating", 10.0))

    def __post_init__(self) -> None:
        sizes = dict(self.min_size)
        if set(sizes) != set(FAULTS) or len(sizes) != len(self.min_size):
            raise ValueError(f"health min_size: {self.min_size!r} must give each of {', '.join(FAULTS)} once")
        for name, v in sizes.items():
            neutral = 1.0 if FAULT_UNITS[name] == "factor" else 0.0
            if not (math.isfinite(v) and v >= neutral):
                raise ValueError(f"health min_size {name}: {v!r} must be a finite size >= {neutral:g}")

    @property
    def arming_reference_s(self) -> float:
        """The reference the monitor arms with (s): min_reference_s, or reference_s if less."""
        return min(self.min_reference_s, self.reference_s)

    def threshold(self, n_faults: int) -> float:
        """The alarm level h: chi-square(1) exceeded with probability false_alarms_per_hour / M,
        M = faults x onsets x evaluations per hour (the tests are correlated, so this is
        conservative)."""
        onsets = int(round((self.window_s - self.min_post_s) / self.onset_step_s)) + 1
        per_hour = 3600.0 / (self.block_s * self.evaluate_every)
        p = self.false_alarms_per_hour / (n_faults * onsets * per_hour)
        return chi2_1_isf(p)


def chi2_1_isf(p: float) -> float:
    """x with P(chi-square(1) > x) = p: (the normal's two-sided quantile)^2, by bisection on erfc."""
    lo, hi = 0.0, 80.0
    for _ in range(100):
        mid = 0.5 * (lo + hi)
        if math.erfc(math.sqrt(mid / 2.0)) > p:
            lo = mid
        else:
            hi = mid
    return 0.5 * (lo + hi)


@dataclass(frozen=True)
class HealthSample:
    """What the monitor is fed at one measured speed sample (SI units)."""

    t: float
    measured_speed_rad_s: float
    predicted_speed_rad_s: float
    voltage_v: float  #: the filtered battery voltage the estimator has now
    twin: TwinSample  #: the physics' current and signatures at t


@dataclass
class HealthEvent:
    """One change found: when it began and was found, what it is and how large."""

    onset_s: float
    detected_s: float
    name: str  #: a contract fault name, or UNNAMED
    size: float | None  #: in ``unit``; None for an unnamed change
    unit: str
    statistic: float  #: the GLR statistic (chi-square(1) under no change)
    named_s: float | None = None  #: when the name was given (None: unnamed)
    candidates: dict[str, float] = field(default_factory=dict)  #: every fault's statistic then
    note: str = ""
    #: what a factor ``size`` is relative to, in the fault's own unit: the pack's healthy sag per
    #: ampere the monitor sized it against (ohm; ``(size - 1) * reference`` is the resistance added);
    #: None for the other faults
    reference: float | None = None
    #: the name the status showed first, when the change was named again while sized (None: never
    #: renamed): whoever judges the monitor counts what it said first, not only what it settled on
    first_name: str | None = None

    def as_dict(self) -> dict[str, object]:
        return {"onset_s": self.onset_s, "detected_s": self.detected_s, "named_s": self.named_s,
                "name": self.name, "size": self.size, "unit": self.unit, "statistic": self.statistic,
                "candidates": dict(self.candidates), "note": self.note, "reference": self.reference,
                "first_name": self.first_name}

    @classmethod
    def from_dict(cls, d: Mapping[str, object]) -> HealthEvent:
        """The event ``as_dict`` gave (a summary's JSON read back, to print it as ``text``)."""
        size, named, ref, first = d.get("size"), d.get("named_s"), d.get("reference"), d.get("first_name")
        candidates = d.get("candidates") or {}
        assert isinstance(candidates, dict)
        return cls(float(cast(float, d["onset_s"])), float(cast(float, d["detected_s"])), str(d["name"]),
                   None if size is None else float(cast(float, size)), str(d["unit"]),
                   float(cast(float, d["statistic"])), None if named is None else float(cast(float, named)),
                   {str(k): float(v) for k, v in candidates.items()}, str(d.get("note", "")),
                   None if ref is None else float(cast(float, ref)), None if first is None else str(first))

    def text(self) -> str:
        size = "" if self.size is None else f", size {_size_text(self.size, self.unit)}"
        return (f"{self.onset_s:8.2f} s  {self.name}{size} (statistic {self.statistic:.0f}, "
                f"found at {self.detected_s:.2f} s)" + (f"; {self.note}" if self.note else ""))


def seconds_tested_text(tested_s: Mapping[str, float]) -> str:
    """Each channel's seconds tested (``HealthRun.tested_s``) as the health summaries print them,
    each followed by ', '."""
    return "".join(f"{name} tested {secs:.1f} s, " for name, secs in tested_s.items())


def _size_text(size: float, unit: str) -> str:
    if unit == "fraction":
        return f"{100.0 * size:.1f} %"
    if unit == "factor":
        return f"{size:.2f}x"
    return f"{size:.1f} {unit}"


#: A block whose predicted speed moved by more than this share of the speed scale since the block
#: before is a transient (it, the block before it, where the step began, and the next
#: _SETTLE_BLOCKS carry no test). The model's error in a transient grows with the rate (a dead
#: time or inertia off by a few % is several rad/s while the speed moves tens per block), so a
#: slow spin-down or a step's tail is a transient too: 1 % (6 rad/s per block) let both through
#: as steady on tuning benches, 0.3 % does not.
_STEADY_FRACTION = 0.003
_SETTLE_BLOCKS = 3
#: A multirotor's motor never holds its command: the attitude loop moves it every frame, and the
#: predicted speed's block means move by ~1-2 % of the scale from one block to the next while the
#: vehicle hovers (the simulator's ``flight`` profile). With _STEADY_FRACTION alone no block of a
#: flight is steady and the speed channel tests nothing (tuning bench 3: 1.3 % of a flight's
#: blocks, no fault found). So a block is a transient only where its change also stands out of
#: the flight's own dither: above _DITHER_FACTOR times the 25th percentile of the last
#: _DITHER_BLOCKS changes (7 x 0.32 sigma: 2.2 sigma of a Gaussian dither; a flight of random holds
#: has a 25th percentile near 0, and _STEADY_FRACTION decides as before).
_DITHER_FACTOR = 7.0
_DITHER_BLOCKS = 200
#: Where the dither sets the threshold, a sustained move (a spin-down's tail, each block below the
#: threshold) is a transient too: the change over this many blocks is held to the same threshold
#: (dither does not add up over blocks, a spin-down does; tuning bench 7: a spin-down to idle
#: passed for a 9 % propeller loss).
_DRIFT_BLOCKS = 4
#: A block is steady only once the model's rotor and its propeller twin have settled: the twin's
#: speed sensitivity (d speed / d propeller loss along the flight) within _SETTLED_SHARE of its
#: static value (the same derivative of the steady speed at the block's command and voltage) plus
#: _SETTLED_FLOOR of the speed scale. Why: a rotor coasting down to a low command slows slowly
#: (drag and friction alone brake it at low speed), each block's change within the flight's
#: dither, and there a model whose spin-down is off by a little looks just like a lighter
#: propeller (its twin coasts slower too): on tuning bench 3 two healthy 100 s flights were named
#: propeller_damage 4.3 % and 6.2 % from the tails of such coasts (sensitivity 39.7 rad/s per unit
#: loss where the settled one is 5.1); on tuning benches 1-9 no detection moved.
_SETTLED_SHARE = 1.0
_SETTLED_FLOOR = 0.005
#: The share of a block the model's timing of a dithered speed may be off by: a speed block
#: carries this share of its predicted change as extra noise (the voltage's is _TIMING_SHARE).
_SPEED_TIMING_SHARE = 0.1
#: The model's speed error is learned as a function of the predicted speed (``_terms``),
#: known after _ERROR_MIN_BLOCKS steady blocks, with a memory of _ERROR_MEMORY_S of steady data,
#: and trusted up to _ERROR_MARGIN (share of the speed scale) beyond the speeds it was learned
#: on, but below the slowest only to tell the candidates of a change apart, never to find one.
#: Why: toward low speeds the model's error bends fastest (a healthy flight's first low holds,
#: 1-5 % of the scale under the slowest learned speed, were 3-4 rad/s slower than the extrapolated
#: error said on two fresh benches, and were named bearing_friction), while a change already found
#: where the error is known is told apart best at another load (heating and friction part at low
#: speed: without those blocks a 30 K rise was named 16 s after its onset instead of 4 s).
#: The learned error is piecewise linear in the predicted speed, its knots _ERROR_MARGIN of the
#: scale apart, its curvature penalised as much as _ERROR_SMOOTH_BLOCKS blocks weigh (a penalised
#: spline: between and beyond the speeds learned it runs straight). Why not a polynomial: one fit
#: over all speeds lets the speeds visited most set its shape at the others; a cubic missed its own
#: lowest bins by 2.6-3.6 rad/s on a healthy flight of a fresh bench whose error bent fast toward
#: low speeds, and that flight's low holds were named bearing_friction. Written by hand: the fit is
#: recursive with a memory, which scipy's smoothing splines (batch fits) do not keep.
_ERROR_SMOOTH_BLOCKS = 10.0
_ERROR_MIN_BLOCKS = 20
_ERROR_MEMORY_S = 60.0
_ERROR_MARGIN = 0.05
#: The learned speeds are those of the bins (_ERROR_MARGIN of the scale wide) that hold at least
#: this many learned blocks with the error's memory: a speed the fit has forgotten is
#: not known (tuning bench 1: a dip to idle, last visited minutes before, passed for a change).
_SPAN_BLOCKS = 2.0
#: The pack's polarisation, as the voltage's nuisance: the current through lags of these time
#: constants (s), whose combinations follow an RC branch of any time constant between them (a
#: LiPo's ~10-60 s); a slower branch (minutes) moves with the charge drawn, a column of its own.
_POLARISATION_S = (15.0, 45.0)
#: Lags (s) over which the residual's autocorrelation is summed (truncated at its first zero).
_CORRELATION_LAGS_S = 0.5
#: The model is fed the FILTERED battery voltage, whose noise (the ESC's modulation and the ADC's,
#: through the 2 s battery filter) wanders with the filter's time constant and moves the
#: prediction by s * d speed / d volt times it: at 12 A about 0.02 V, 1-2 rad/s, in the middle of
#: a steady hold, where it passed for a change (false alarms on tuning benches). The monitor knows
#: its size from its own voltage channel (a block's terminal-voltage noise a + b i^2 is the raw
#: noise over a block; the filter keeps block_s / (2 tau) of it, the current squared taken
#: through a lag of tau / 2 as the filter's output variance follows it), and adds it to each speed
#: block's own noise as white noise of _INPUT_NOISE_WHITE times its variance: the filter's noise is
#: correlated over seconds, and that many times its variance makes a white noise give the same
#: variance to the difference of two one-second means, the scale of a step test within a hold.
_INPUT_NOISE_WHITE = 3.0
#: The share of a block the model's timing of a current step may be off by (its dead time and
#: rotor lag are fitted): the voltage block's extra noise where the current steps.
_TIMING_SHARE = 0.5
#: Least noise (one sigma of a block) per channel: a share of the speed scale, volts; a quiet
#: reference never makes it zero.
_SPEED_NOISE_FLOOR = 1e-3
_VOLTAGE_NOISE_FLOOR_V = 3e-3
#: The voltage's noise is learned only from a reference whose quiet blocks reach this share of
#: the current its moving blocks mostly hold (their 90th percentile): see ``_quiet_reach_tested``.
_NOISE_CURRENT_SHARE = 0.5
#: Fewest valid blocks in a channel's reference for its tests to run (and at least 4 per
#: nuisance column): fewer say too little of its noise and the model's error.
_MIN_REFERENCE_BLOCKS = 40
_MIN_REFERENCE_STRETCHES = 3
#: Steady stretches after the onset a name needs: the shapes differ across operating points.
_NAME_STRETCHES = 2
#: A name may leave unexplained at most this share of its own statistic (or the threshold).
_UNEXPLAINED_SHARE = 0.1
#: One sigma of the model's error from one visit of an operating point to the next, before the
#: flight has shown it: a share of the speed scale (a physics fit's error is ~0.5-1 % of its
#: range), volts. Replaced by the flight's first estimate, then followed with the noise's memory.
_VISIT_PRIOR = {"speed": 0.01, "voltage": 0.02}
#: A steady stretch whose mean square is more than _VISIT_OUTLIER times the mean of the others'
#: is left out of the visit error's estimate (the farthest out first, while more than _VISIT_KEEP
#: stretches remain). Why: a stretch early in a flight, or at the edge of the speeds the learned
#: error holds, is off by what the learned error did not know yet (one stretch 3.3 rad/s off where
#: a dozen agree within 0.5), and through the noise's memory that one visit set the error every
#: later visit was allowed for a minute (a variance ~10x what the stretches since showed): a 10 %
#: propeller loss in flight read 3.8 against the threshold 34 (17 without it). Where the visits'
#: errors are Gaussian the rule drops one in 1.5 % of references of ten stretches (5 % of five) and
#: the estimate's mean stays within 1-5 % of unbiased; at 10x it dropped one in 11-17 % and
#: read 5-13 % low.
_VISIT_OUTLIER = 20.0
_VISIT_KEEP = 4
#: A block's current is one its reference held if within this share of the span of the currents
#: the reference's steady blocks held, up to window_s before the onset (_unseen_currents).
_CURRENT_MARGIN = 0.05
#: The nuisance columns whose coefficients get a prior (per channel): the speed's drift and
#: curvature in time (columns 1 and 2 of its nuisance), with the flight's own typical size
#: (_learn_bending), at least the visit error's. Free, the curvature takes part of a step in the
#: window's last seconds for bending (a 30 K winding rise on tuning bench 1: statistic 67 against
#: the offset alone, 45 with the drift, 21 with the curvature, under the threshold 34: never found).
_BENDING_COLUMNS = {"speed": (1, 2)}
#: The channels, in the order the tests take them.
CHANNELS: tuple[str, ...] = ("speed", "voltage")
#: Changes of a channel's testing state kept (``HealthMonitor.testing_log``): a few per minute of
#: flight, so hours; the running totals (``tested_s``) are kept for all time.
_TESTING_LOG = 10_000


def _lag_of_blocks(t: np.ndarray, values: np.ndarray, tau_s: float) -> np.ndarray:
    """A first-order lag (physics.lag) of block values, each block's value held over the interval
    that ends at its time: y[0] = values[0], y[k] = lag of values[k] over t[k-1]..t[k]."""
    if len(values) == 0:
        return np.empty(0)
    return lag_on_times(t, np.append(values[1:], values[-1]), tau_s, float(values[0]))


def _change_beside(x: np.ndarray) -> np.ndarray:
    """Per block after the first of ``x`` (a window's column, its first block only the starting
    point), the larger change from the block before or to the block after (0 after the last)."""
    return np.maximum(np.abs(np.diff(x)), np.abs(np.diff(np.append(x[1:], x[-1]))))


@dataclass(frozen=True)
class _Channel:
    """One measured quantity over the window's blocks: what is tested on it."""

    name: str
    y: np.ndarray  #: the residual (speed) or the terminal voltage (voltage)
    valid: np.ndarray  #: 1 where a block carries the test, else 0
    level: np.ndarray  #: what its noise grows with (predicted speed, model current)
    floor: np.ndarray  #: least noise variance of each block: what the samples' own scatter says
    extra: np.ndarray  #: noise variance each block carries beyond its learned noise (the input's)
    nuisance: np.ndarray  #: columns fitted along (offset, drift, the model's error)
    tests: np.ndarray  #: onsets x blocks x faults: each fault's change per unit of its size
    #: steady stretches its reference needs (the speed's: its visits tell the model's error; the
    #: voltage's blocks are all valid, one stretch)
    min_stretches: int = _MIN_REFERENCE_STRETCHES
    #: the blocks its noise is learned on (None: the valid ones); the voltage's are the steady
    #: ones: a transient's block carries its own timing noise (``extra``), not the pack's
    quiet: np.ndarray | None = None
    #: the blocks an unstructured step is tested on (None: all): where some fault could show
    stepped: np.ndarray | None = None

    @property
    def noise_blocks(self) -> np.ndarray:
        """The blocks its noise is learned on (``quiet``, else the valid ones)."""
        return self.valid if self.quiet is None else self.quiet

    def step_column(self, post: np.ndarray) -> np.ndarray:
        """An unstructured step from the onset(s) ``post`` marks, on the blocks it is tested on."""
        return post if self.stepped is None else post * self.stepped


# block columns (means over the block's samples unless said): time, samples, speed residual (the
# filter-undo error taken out, _filter_error), predicted speed, model current, the filtered voltage
# last and its time, its mean and samples, steady, the residual less the learned error, known
# speed, d speed / d volt, the residual mean's own variance (from its samples' scatter), the model
# current squared lagged (_current_squared), the current's polarisation lags and its filter lag
# less itself (_current_lags), the propeller twin's static sensitivity (_SETTLED_SHARE), whether
# the speed lies just under the learned ones (known only to name a change: _ERROR_MARGIN)
_T, _N, _R, _W, _IB, _VLAST, _TVLAST, _VMEAN, _NV, _STEADY, _RC, _KNOWN, _SV, _R2, _I2, _PF, _PS, _LAG, _SPS, \
    _BELOW = range(20)
_S0 = 20  #: speed sensitivities (one per fault), then current sensitivities
_PROPELLER = FAULTS.index("propeller_damage")
_ARMING, _ARMED, _NAMING, _REFINING = "arming", "armed", "naming", "refining"
#: what a named change too small to be a fault is, after "below" or "could be below"
_MIN_SIZE_NOTE = "the smallest change worth an alarm at two sigma (HealthConfig.min_size)"


class HealthMonitor:
    """The sequential test; see the module doc. ``update(sample)`` returns the events it
    completed at that sample (usually none); ``events`` holds them all."""

    def __init__(self, supply_tau_s: float, speed_scale_rad_s: float, pack_resistance_ohm: float,
                 config: HealthConfig | None = None, voltage_strength: float = 1.0,
                 source_resistance_ohm: float | None = None) -> None:
        """``supply_tau_s``: the battery filter's time constant the voltage came through (0: the
        terminal's own); ``voltage_strength``: how much of the measured voltage's change the model
        passes to its motor (its battery_voltage strength); ``speed_scale_rad_s``: the model's
        full-drive speed (what 'steady' and 'turning' are relative to); ``pack_resistance_ohm``:
        what the pack's factor is relative to where the data cannot say (PhysicsTwins gives it);
        ``source_resistance_ohm``: the series resistance the model adds back when it undoes the
        battery filter (PhysicsTwins gives it; default voltage_strength * pack_resistance_ohm)."""
        self.config = cfg = config or HealthConfig()
        if not (math.isfinite(speed_scale_rad_s) and speed_scale_rad_s > 0.0):
            raise ValueError(f"speed_scale_rad_s {speed_scale_rad_s!r} must be a speed > 0")
        self.speed_scale = float(speed_scale_rad_s)
        self.tau_s = float(supply_tau_s)
        self.voltage_strength = float(voltage_strength)
        self.pack_reference_ohm = float(pack_resistance_ohm)
        self._sag = self.pack_reference_ohm  #: the pack's sag per ampere the latest window showed (ohm)
        self._steady = np.zeros(0)  #: the latest window's steady blocks (a name needs stretches of them)
        #: the series resistance the model adds back when it undoes the battery filter (ohm)
        self.source_resistance_ohm = (self.voltage_strength * self.pack_reference_ohm
                                      if source_resistance_ohm is None else float(source_resistance_ohm))
        self.n_faults = len(FAULTS)
        self.threshold = cfg.threshold(self.n_faults)
        #: candidate onsets while armed, as blocks before the newest (min_post_s to window_s)
        self._detect_post = np.arange(int(round(cfg.min_post_s / cfg.block_s)),
                                      int(round(cfg.window_s / cfg.block_s)) + 1,
                                      max(1, int(round(cfg.onset_step_s / cfg.block_s))))
        self._post = self._detect_post  #: the onsets of the evaluation under way
        self._name_blocks = int(round(max(cfg.name_within_s, cfg.window_s) / cfg.block_s))
        #: blocks after the onset a named change is sized over before it is reported
        self._refine_blocks = int(round(max(min(cfg.refine_within_s, cfg.name_within_s), cfg.window_s) / cfg.block_s))
        #: blocks in a detection window: the reference and window_s
        self._max_ref_blocks = int(round(cfg.reference_s / cfg.block_s))
        #: the reference of the evaluation under way (blocks): what the window holds, up to the most
        self._ref_blocks = int(round(cfg.arming_reference_s / cfg.block_s))
        self._detect_blocks = self._ref_blocks + int(self._detect_post[-1])
        self.window_blocks = self._max_ref_blocks + self._name_blocks
        self._cols = _S0 + 2 * self.n_faults
        self._buf = np.zeros((self.window_blocks + 1, self._cols))
        self.events: list[HealthEvent] = []
        #: changes that are no alarm: named ones below the config's min_size at two sigma (seen,
        #: sized), and unnamed ones that did not hold (``_set_aside``)
        self.minor: list[HealthEvent] = []
        self.blocks = 0  #: blocks closed since the start
        self.evaluations = 0
        self.state = _ARMING
        #: channel -> whether its tests ran at the latest evaluation: not while its reference holds too
        #: few valid blocks (the speed's: steady, at speeds whose model error is learned) or its noise is
        #: not learned, whatever ``state`` says (a flight that never holds a speed: for a minute)
        self.testing: dict[str, bool] = dict.fromkeys(CHANNELS, False)
        #: (time, channel, testing) at each change of ``testing``, the latest _TESTING_LOG of them
        self.testing_log: deque[tuple[float, str, bool]] = deque(maxlen=_TESTING_LOG)
        #: channel -> seconds its tests ran (from each evaluation to the next that found it testing)
        self.tested_s: dict[str, float] = dict.fromkeys(CHANNELS, 0.0)
        self._tested_since: float | None = None  #: the latest evaluation's time
        self._last_t: float | None = None
        #: channel -> (a, b, visit, kappa): a block's noise variance a + b level^2, the variance of
        #: the model's error from one steady stretch to the next, the short correlation factor
        self.noise: dict[str, tuple[float, float, float, float]] = {}
        self._visit_learned: set[str] = set()  #: channels whose visit error the flight has shown
        #: channel -> (mean square of its bending coefficients net of their estimates' variance,
        #: evaluations seen): _learn_bending
        self._bending: dict[str, tuple[np.ndarray, int]] = {}
        self._since_jump = 0  #: blocks since the predicted speed last jumped
        #: the predicted speed's latest block-to-block changes (rad/s), a ring: the flight's dither
        self._dither = np.zeros(_DITHER_BLOCKS)
        self._dither_n = 0
        self._row = 0  #: blocks written to the ring since the start (a row's index is this mod its length)
        self._reset_window()
        self._block: list[float] | None = None
        self._block_index = 0
        self._pending: HealthEvent | None = None
        self._lead: tuple[str, float] | None = None  #: ``leading``'s, set by each naming test
        self._pending_onset_block = 0
        #: the named pending change's latest (statistic, theta) of its fault: what decides, when
        #: it is reported, whether it could be below the smallest worth an alarm (None: not sized)
        self._named_fit: tuple[float, float] | None = None
        self._t_origin: float | None = None
        self._lags: tuple[float, float, float, float] | None = None  #: (_current_lags' lags, their time)

    # --- input ---------------------------------------------------------------------------
    def update(self, s: HealthSample) -> list[HealthEvent]:
        """One measured speed sample; returns the events completed at it."""
        t = float(s.t)
        if not all(math.isfinite(x) for x in (t, s.measured_speed_rad_s, s.predicted_speed_rad_s, s.voltage_v)):
            return []
        if self._last_t is not None and t < self._last_t:
            return []
        if self._t_origin is None:
            self._t_origin = t
        out: list[HealthEvent] = []
        if self._last_t is not None and t - self._last_t > self.config.max_gap_s:
            # the window restarts, so a change still being named cannot be followed across the gap
            # (its onset block would be gone): it is reported as it stands, as at the end of data
            out += self.finish()
            self._reset_window()
        self._last_t = t
        k = int((t - self._t_origin) / self.config.block_s)
        if self._block is not None and k != self._block_index:
            out += self._close_block()
        if self._block is None:
            self._block_index = k
            self._block = [0.0] * self._cols
        b = self._block
        tw = s.twin
        nf = self.n_faults
        b[_T] += t
        b[_N] += 1.0
        r = s.measured_speed_rad_s - s.predicted_speed_rad_s
        b[_R] += r
        b[_R2] += r * r
        b[_W] += s.predicted_speed_rad_s
        b[_IB] += tw.current_a
        b[_VLAST] = s.voltage_v
        b[_TVLAST] = t
        b[_VMEAN] += s.voltage_v
        b[_NV] += 1.0
        for j in range(nf):
            b[_S0 + j] += tw.speed_sensitivity[j]
            b[_S0 + nf + j] += tw.current_sensitivity[j]
        b[_SV] += tw.voltage_sensitivity
        b[_SPS] += tw.static_sensitivity[_PROPELLER] if tw.static_sensitivity else math.nan
        return out

    def finish(self) -> list[HealthEvent]:
        """The end of the data (or a gap): close the open block and report a change still being
        named or sized as it stands, unless it is named and could be too small to be a fault, or
        unnamed and did not hold or shows only at currents never held (the same rules as at the
        end of its sizing or naming: flights end, and data stop, mid-change)."""
        out = self._close_block()
        if self._last_t is not None:  # the seconds tested up to the last sample
            self._note_testing(self._last_t, dict(self.testing))
        if self._pending is not None:
            if self.state == _REFINING:
                return out + self._report_named()
            out += self._close_unnamed(self._pending, 0, "the end of the data", self._pending.note)
        return out

    @property
    def leading(self) -> tuple[str, float] | None:
        """The change being named's leading candidate: its name and size (``FAULT_UNITS``) at the
        latest test, if it would be named but for its lead over the next (it passes the threshold,
        is seen at two operating points and leaves nothing significant unexplained); None
        otherwise and once named."""
        ev = self._pending
        return self._lead if ev is not None and ev.name == UNNAMED else None

    @property
    def pending(self) -> HealthEvent | None:
        """The change being named or sized now (reported only once settled, up to
        name_within_s after its onset): what a live status shows before then; None if none."""
        return self._pending

    # --- blocks ----------------------------------------------------------------------------
    def _reset_window(self) -> None:
        """Forget the window and the model's learned error (after a gap; after a change,
        ``_restart_from`` keeps what followed its onset); no channel tests until it refills."""
        if self._last_t is not None:
            self._note_testing(self._last_t, dict.fromkeys(CHANNELS, False))
        self._filled = 0  #: blocks in the window since the last restart
        #: the learned blocks per speed bin (_ERROR_MARGIN of the scale wide), with the error's memory
        self._error_hist = np.zeros(int(math.ceil(1.5 / _ERROR_MARGIN)))
        #: the model's speed error at the bins' edges (``_terms``), learned (penalised least squares
        #: with a memory of _ERROR_MEMORY_S) from steady blocks older than the test window: what is
        #: known of the model before a change can have entered it; known between the slowest and
        #: the fastest speed learned and a little beyond (_ERROR_MARGIN: a fit does not extrapolate
        #: far; below the slowest only to name a change)
        knots = len(self._error_hist) + 1
        self._error_gram = np.zeros((knots, knots))
        self._error_rhs = np.zeros(knots)
        self._error_coef: np.ndarray = np.zeros(knots)
        curvature = np.diff(np.eye(knots), 2, axis=0)
        self._error_smooth = _ERROR_SMOOTH_BLOCKS * curvature.T @ curvature
        self._error_n = 0.0
        self._error_span = (math.inf, -math.inf)
        self._i2_lag: tuple[float, float] | None = None  #: (lagged current squared, its time)

    def _close_block(self) -> list[HealthEvent]:
        b = self._block
        self._block = None
        if b is None or b[_N] == 0:
            return []
        n = b[_N]
        row = np.array(b)
        for j in (_T, _R, _W, _IB, _SV, _SPS, *range(_S0, self._cols)):
            row[j] /= n
        row[_VMEAN] /= b[_NV]
        # the block mean's own noise from the samples' scatter about it (the tachometer's noise at
        # this very speed: no noise model extrapolated from the speeds the reference visited)
        row[_R2] = max(b[_R2] - n * row[_R] ** 2, 0.0) / (n * (n - 1.0)) if n >= 3 else 0.0
        row[_I2] = self._current_squared(row)
        row[_PF], row[_PS], row[_LAG] = self._current_lags(row)
        row[_R] -= self._filter_error(row)
        prev = self._buf[(self._row - 1) % len(self._buf)] if self._filled else row
        dw = abs(row[_W] - prev[_W])
        drift = abs(row[_W] - self._buf[(self._row - _DRIFT_BLOCKS) % len(self._buf), _W]) \
            if self._filled >= _DRIFT_BLOCKS else 0.0
        floor = _STEADY_FRACTION * self.speed_scale
        dither = self._dither_threshold()
        jump = dw > max(floor, dither) or (dither > floor and drift > dither)
        self._dither[self._dither_n % _DITHER_BLOCKS] = dw
        self._dither_n += 1
        self._since_jump = 0 if jump else self._since_jump + 1
        if jump and self._filled:  # the step began in the block before: its mean is part transient
            self._buf[(self._row - 1) % len(self._buf), _STEADY] = 0.0
        turning = row[_W] >= self.config.min_speed_fraction * self.speed_scale
        sps = row[_SPS]  # NaN: the twins give no static sensitivity, so no settling is asked
        settled = sps != sps or \
            abs(row[_S0 + _PROPELLER] - sps) <= _SETTLED_SHARE * abs(sps) + _SETTLED_FLOOR * self.speed_scale
        row[_STEADY] = float(self._since_jump > _SETTLE_BLOCKS and turning and settled)
        self._against_learned(row)
        self._buf[self._row % len(self._buf)] = row
        self._row += 1
        self._filled += 1
        self.blocks += 1
        if self.state not in (_NAMING, _REFINING):
            self._learn_error()
        if (self._filled > self._detect_blocks or self._pending is not None) \
                and self.blocks % self.config.evaluate_every == 0:
            return self._evaluate()
        return []

    def _against_learned(self, row: np.ndarray) -> None:
        """Set a block's residual less the learned error (_RC) and whether its speed is known
        (_KNOWN), or known only to name a change found elsewhere (_BELOW: _ERROR_MARGIN)."""
        lo, hi = self._learned_span()
        margin = _ERROR_MARGIN * self.speed_scale
        learned = self._error_n >= _ERROR_MIN_BLOCKS
        row[_KNOWN] = float(learned and lo <= row[_W] <= hi + margin)
        row[_BELOW] = float(learned and lo - margin <= row[_W] < lo)
        row[_RC] = row[_R] - float(self._terms(row[_W]) @ self._error_coef)

    def _restart_from(self, onset_block: int) -> None:
        """A fresh window after a change that began at ``onset_block`` (the change is the new
        normal): the blocks since the onset are kept as the new window's first, and the model's
        error is learned again over them as if the window had started there; the noise estimates
        are kept. Why: a window started empty when the change was settled (up to name_within_s
        after its onset) left the monitor blind for its whole reference and learn_s after that,
        up to 60 s after the onset: on tuning bench 3 a 1.16x pack sag seen before any fault, set
        aside as minor at 51 s (13 s after its onset), left it blind until 86 s, over a 10 %
        propeller loss at 59 s; from the onset it watches again at 74 s."""
        keep = min(max(self._row - onset_block, 0), self._filled)
        self._reset_window()
        start = self._row - keep
        back = int(self._detect_post[-1]) + 1
        n = len(self._buf)
        for filled, q in enumerate(range(start, self._row), 1):  # as _close_block did, block by block
            self._against_learned(self._buf[q % n])
            if filled > back:
                self._learn_block(self._buf[(q + 1 - back) % n])
        self._filled = keep

    def _speed_bin(self, w: float) -> int:
        """The learned-error histogram's bin of speed w."""
        return min(max(int(w / (_ERROR_MARGIN * self.speed_scale)), 0), len(self._error_hist) - 1)

    def _learned_span(self) -> tuple[float, float]:
        """The slowest and fastest speeds the learned error still holds (rad/s): the edges of the
        bins with _SPAN_BLOCKS learned blocks or more, with the memory; (inf, -inf) if none."""
        bins = np.flatnonzero(self._error_hist >= _SPAN_BLOCKS)
        if len(bins) == 0:
            return math.inf, -math.inf
        width = _ERROR_MARGIN * self.speed_scale
        return max(float(bins[0]) * width, self._error_span[0]), min(float(bins[-1] + 1) * width, self._error_span[1])

    def _dither_threshold(self) -> float:
        """The change of the predicted speed the flight's dither explains (rad/s, _DITHER_FACTOR):
        0 until a quarter of _DITHER_BLOCKS is seen."""
        if self._dither_n < _DITHER_BLOCKS // 4:
            return 0.0
        return _DITHER_FACTOR * float(np.percentile(self._dither[:min(self._dither_n, _DITHER_BLOCKS)], 25.0))

    def _current_squared(self, row: np.ndarray) -> float:
        """The model current squared through a lag of tau / 2 (A^2), carried from block to block:
        what the filtered voltage's noise variance follows (_INPUT_NOISE_WHITE)."""
        i2, t = float(row[_IB]) ** 2, float(row[_T])
        if self._i2_lag is not None and self.tau_s > 0.0:
            last, t_prev = self._i2_lag
            i2 = last + (1.0 - math.exp(-2.0 * max(t - t_prev, 0.0) / self.tau_s)) * (i2 - last)
        self._i2_lag = (i2, t)
        return i2

    def _current_lags(self, row: np.ndarray) -> tuple[float, float, float]:
        """The model current through lags of _POLARISATION_S (A), and through the battery filter
        less the current itself (A, 0 without a filter), carried from block to block over the
        whole flight (a window's first block knows nothing of the current before it)."""
        ib, t = float(row[_IB]), float(row[_T])
        taus = (*_POLARISATION_S, self.tau_s if self.tau_s > 0.0 else 1.0)
        if self._lags is None:
            self._lags = (ib, ib, ib, t)
        else:
            *lags, t_prev = self._lags
            dt = max(t - t_prev, 0.0)
            x = [lag + (1.0 - math.exp(-dt / tau)) * (ib - lag) for lag, tau in zip(lags, taus, strict=True)]
            self._lags = (x[0], x[1], x[2], t)
        return self._lags[0], self._lags[1], (self._lags[2] - ib) if self.tau_s > 0.0 else 0.0

    def _filter_error(self, row: np.ndarray) -> float:
        """The model's speed error at a block from undoing the battery filter with its own
        source resistance (s R_m) where the pack's is the sag its voltage shows (R): the model's
        motor voltage V_f + s R_m (lowpass(i) - i) against the terminal's V_f + R (lowpass(i) - i),
        of which it passes s; the lagged part, s (R - R_m) (lowpass(i) - i) times d speed / d volt,
        decays with the filter after every current step, which passed for a change on tuning
        benches; the rest is static in the current, and the learned error takes it."""
        return float(row[_SV]) * (self.voltage_strength * self._sag - self.source_resistance_ohm) * float(row[_LAG])

    def _input_noise(self, cur: np.ndarray) -> np.ndarray:
        """Each speed block's variance from the filtered voltage's noise (_INPUT_NOISE_WHITE):
        0 until the voltage channel's noise is learned, and without a battery filter."""
        volt = self.noise.get("voltage")
        if volt is None or self.tau_s <= 0.0:
            return np.zeros(len(cur))
        filtered = (volt[0] + volt[1] * cur[:, _I2]) * self.config.block_s / (2.0 * self.tau_s)
        return _INPUT_NOISE_WHITE * (self.voltage_strength * cur[:, _SV]) ** 2 * filtered

    def _terms(self, w: float) -> np.ndarray:
        """The learned error's basis at speed w: the two knots about it, weighted linearly."""
        out = np.zeros(len(self._error_coef))
        k = self._speed_bin(w)  # the knots are the bins' edges
        f = min(max(w / (_ERROR_MARGIN * self.speed_scale), 0.0) - k, 1.0)
        out[k], out[k + 1] = 1.0 - f, f
        return out

    def _learn_error(self) -> None:
        """Add the block that just left the test window (older than window_s) to the model's
        learned error (the caller: if no change is being named)."""
        back = int(self._detect_post[-1]) + 1
        if self._filled > back:
            self._learn_block(self._buf[(self._row - back) % len(self._buf)])

    def _learn_block(self, old: np.ndarray) -> None:
        """Add one block to the model's learned error if it is steady."""
        if old[_STEADY] <= 0:
            return
        keep = math.exp(-self.config.block_s / _ERROR_MEMORY_S)
        x = self._terms(old[_W])
        self._error_gram = keep * self._error_gram + np.outer(x, x)
        self._error_rhs = keep * self._error_rhs + x * old[_R]
        self._error_n = keep * self._error_n + 1.0
        self._error_span = (min(self._error_span[0], old[_W]), max(self._error_span[1], old[_W]))
        self._error_hist *= keep
        self._error_hist[self._speed_bin(old[_W])] += 1.0
        knots = len(self._error_coef)
        ridge = 1e-6 * max(float(np.trace(self._error_gram)), 1e-9) / knots
        self._error_coef = np.linalg.solve(self._error_gram + self._error_smooth + ridge * np.eye(knots),
                                           self._error_rhs)

    def _window(self, n: int) -> np.ndarray:
        """The last n + 1 blocks, oldest first (the first gives the voltage's starting point)."""
        idx = (np.arange(self._row - n - 1, self._row)) % len(self._buf)
        return self._buf[idx]

    # --- the tests -------------------------------------------------------------------------
    def _channels(self, win: np.ndarray) -> list[_Channel]:
        """The speed and voltage channels over the window's blocks (its first block only gives
        the voltage's starting point)."""
        cfg, nf = self.config, self.n_faults
        cur = win[1:]
        m = len(cur)
        t_rel = (cur[:, _T] - cur[-1, _T]) / (cfg.reference_s + cfg.window_s)
        ones = np.ones(m)
        w = cur[:, _W]
        # only steady blocks of a turning rotor carry a test: a fault is a static change, and the
        # model's errors in dead time, inertia and coasting are largest in transients
        valid = cur[:, _STEADY]
        # speed: the residual less the model's learned error at that speed (blocks at a speed
        # not yet learned carry no test); nuisance: offset, drift and the drift's curvature (over
        # a reference of up to 40 s the model's error bends as the winding and the pack warm: a
        # straight drift left a healthy flight of tuning bench 7 over the threshold). Fitting more
        # here (the error along each signature) would fit the reference's few operating points
        # exactly and leave a noise far below what the model's error does between visits of one speed
        post = self._post_masks(m)  # (onsets, blocks): 1 from each candidate onset on
        speed_tests = post[:, :, None] * cur[None, :, _S0:_S0 + nf]
        # the pack's added sag dR * i after the onset slows the motor; the model sees it only as
        # far as its voltage input passes it: through the battery filter's lag, times its
        # battery_voltage strength s. So the motor gets dR (s lowpass(i after the onset) - i) less
        # than the model thinks, times d speed / d volt
        ib = cur[:, _IB]
        seen = self._lowpass_after_onsets(ib, cur[:, _T]) if self.tau_s > 0.0 else post * ib[None, :]
        speed_tests[:, :, FAULTS.index("pack_resistance")] = (
            cur[None, :, _SV] * (self.voltage_strength * seen - post * ib[None, :]))
        # voltage: the terminal voltage's block mean, the battery filter undone
        if self.tau_s > 0.0:
            dtv = cur[:, _TVLAST] - win[:-1, _TVLAST]
            a = np.exp(-np.maximum(dtv, 1e-6) / self.tau_s)
            v = (cur[:, _VLAST] - a * win[:-1, _VLAST]) / (1.0 - a)
        else:
            v = cur[:, _VMEAN]
        # the open-circuit voltage follows the charge drawn (A, the window's mean current to date)
        charge = np.cumsum(ib * np.diff(win[:, _T])) / (cfg.reference_s + cfg.window_s)
        volt_nuisance = np.column_stack([ones, charge, ib, cur[:, _PF], cur[:, _PS]])
        sag = self._sag_per_ampere(v, volt_nuisance)
        # a dithered block's timing error (_SPEED_TIMING_SHARE)
        known = cur[:, _KNOWN] + (cur[:, _BELOW] if self._pending is not None else 0.0)
        speed = _Channel("speed", cur[:, _RC], valid * known, w, cur[:, _R2],
                         self._input_noise(cur) + (_SPEED_TIMING_SHARE * _change_beside(win[:, _W])) ** 2,
                         np.column_stack([ones, t_rel, t_rel**2]), speed_tests)
        dib = cur[:, _S0 + nf:_S0 + 2 * nf]
        # each fault's voltage signature: the sag its current change causes; the pack's: its own
        volt_static = -sag * dib
        volt_static[:, FAULTS.index("pack_resistance")] = -ib
        none = np.zeros(m)
        # where the current steps, the model's current is off by its timing (a dead time or a
        # rotor lag off by a share of a block): the voltage's block carries that much more noise
        timing = (_TIMING_SHARE * sag * _change_beside(win[:, _IB])) ** 2
        # every block carries the voltage's test, transients and rest included: the sag is static in
        # the current (block means of v and i obey it as samples do), a current step is where a
        # pack's change shows most, and a rotor at rest pins the open-circuit voltage down
        # no fault changes the voltage of a block at rest (no current, no sag: its signatures
        # are all zero there), which only pins the open-circuit voltage; an unstructured step is
        # not tested on it. Why: the rest after a burst is where the pack's polarisation and charge,
        # fitted along from the reference's few rests, are least exact (a few mV after a burst
        # longer than the reference's), on blocks whose own noise is 3 mV: on two fresh benches
        # a healthy flight's rest after a burst passed for an unnamed change
        at_rest = np.abs(ib) * sag < _VOLTAGE_NOISE_FLOOR_V
        volt = _Channel("voltage", v, ones, ib, none, timing, volt_nuisance,
                        post[:, :, None] * volt_static[None, :, :], min_stretches=1, quiet=valid,
                        stepped=(~at_rest).astype(float))
        self._sag = sag
        self._steady = valid
        return [speed, volt]

    def _post_masks(self, m: int) -> np.ndarray:
        """(onsets, m): 1 on the blocks from each candidate onset to the end, else 0."""
        return (np.arange(m)[None, :] >= (m - self._post)[:, None]).astype(float)

    def _lowpass_after_onsets(self, ib: np.ndarray, t: np.ndarray) -> np.ndarray:
        """(onsets, blocks): the current from each candidate onset on (0 before) through the
        battery filter: lowpass(i) - exp(-(t - t0)/tau) lowpass(i)(t0), the filter being linear."""
        m = len(ib)
        a = np.exp(-np.diff(t, prepend=t[0]) / self.tau_s)
        x = _lag_of_blocks(t, ib, self.tau_s)
        starts = m - self._post
        out = np.zeros((len(starts), m))
        for o, k0 in enumerate(starts.tolist()):
            decay = np.exp(-(t[k0:] - t[k0]) / self.tau_s)
            before = x[k0 - 1] if k0 > 0 else x[0]
            # the filter's state at the onset is the pre-onset part; what follows is new
            out[o, k0:] = x[k0:] - decay * a[k0] * before
        return out

    def _sag_per_ampere(self, v: np.ndarray, nuisance: np.ndarray) -> float:
        """The pack's healthy instantaneous sag per ampere (ohm) over the reference part of the
        window: the voltage's slope against the current (``nuisance``'s column 2), the open-circuit
        voltage and the polarisation fitted along; the model's series resistance when the current
        hardly varied or the slope is out of any plausible range."""
        ref = slice(0, self._ref_blocks)
        ib = nuisance[ref, 2]
        if np.ptp(ib) < 0.5:
            return self.pack_reference_ohm
        r = -float(np.linalg.lstsq(nuisance[ref], v[ref], rcond=None)[0][2])
        return r if 0.2 * self.pack_reference_ohm < r < 10.0 * self.pack_reference_ohm else self.pack_reference_ohm

    def _stats(self, ch: _Channel, tests: np.ndarray, learn: bool = False) -> tuple[np.ndarray, np.ndarray]:
        """For every onset and test column (``tests``: onsets x blocks x columns): z'S^-1 r and
        z'S^-1 z with the channel's nuisance projected out, S the residual's covariance (each
        block's own noise, plus the visit error shared by the blocks of a steady stretch), times
        kappa and the inflation: (z'S^-1 r)^2 / z'S^-1 z is chi-square(1) under no change.
        ``learn``: first update the channel's noise model from the reference part of the window.
        A channel with fewer than _MIN_REFERENCE_BLOCKS valid blocks in its reference (or no noise
        learned yet, even after ``learn``: too few quiet blocks) tests nothing: zeros."""
        N = ch.nuisance
        empty = np.zeros(tests.shape[::2])
        if not self._reference_holds(ch):
            return empty, empty
        if not learn and ch.name not in self.noise:
            return empty, empty
        if learn:
            flat = self._fit(ch, N)
            self._learn_noise(ch, flat[3], N.shape[1])
            if ch.name not in self.noise:  # too few quiet blocks to learn it from: nothing tested yet
                return empty, empty
            scale = self.noise[ch.name][3] * self.config.noise_inflation
            self._learn_bending(ch.name, flat[6], np.diag(flat[4]) * scale)
        kappa = self.noise[ch.name][3] * self.config.noise_inflation
        w, P, c, res, Ginv, PWN, _ = self._fit(ch, N, self._bending_precision(ch.name, N.shape[1], kappa))
        Zw = tests * w[None, :, None]
        PZw = np.einsum("jm,omf->ojf", P, Zw)
        zr = np.einsum("omf,m->of", Zw, res) - np.einsum("ojf,j->of", PZw, c * (P @ (w * res)))
        zz = np.einsum("omf,omf->of", Zw, tests) - np.einsum("ojf,j,ojf->of", PZw, c, PZw)
        zN = np.einsum("omf,mi->ofi", Zw, N) - np.einsum("ojf,j,ji->ofi", PZw, c, PWN)
        den = np.maximum(zz - np.einsum("ofi,ij,ofj->of", zN, Ginv, zN), 0.0)
        return zr / kappa, den / kappa

    def _reference_holds(self, ch: _Channel) -> bool:
        """Whether the channel's reference holds enough valid blocks (and stretches) to test."""
        ref = ch.valid[:self._ref_blocks]
        return bool(ref.sum() >= max(_MIN_REFERENCE_BLOCKS, 4 * ch.nuisance.shape[1])
                    and len(true_run_pairs(ref > 0)) >= ch.min_stretches)

    def _note_testing(self, t: float, now: Mapping[str, bool]) -> None:
        """Each channel's testing state from time t on (``testing``, ``testing_log``, ``tested_s``)."""
        if self._tested_since is not None:
            for name, on in self.testing.items():
                if on:
                    self.tested_s[name] += max(t - self._tested_since, 0.0)
        self._tested_since = t
        for name, on in now.items():
            if on != self.testing[name]:
                self.testing[name] = on
                self.testing_log.append((t, name, on))

    def _visit_prior(self, name: str) -> float:
        """The visit error's variance before the flight has shown it (_VISIT_PRIOR)."""
        return (_VISIT_PRIOR[name] * (self.speed_scale if name == "speed" else 1.0)) ** 2

    @property
    def _memory_gain(self) -> float:
        """The weight one evaluation's estimate gets in a running mean of noise_memory_s."""
        return min(1.0, self.config.block_s * self.config.evaluate_every / self.config.noise_memory_s)

    def _learn_bending(self, name: str, beta: np.ndarray, variance: np.ndarray) -> None:
        """The flight's typical drift and curvature of the model's error over a window (only the
        channels with a prior: _BENDING_COLUMNS), by empirical Bayes: a coefficient fitted without
        a prior (``beta``) has mean square tau^2 + the variance of its estimate (``variance``, the
        fit's), so tau^2 is their mean difference: over every fit so far, then with the noise's
        memory. Why net, and not the first fit taken whole: on a short reference of random steps
        the drift and curvature are nearly collinear with the offset, and their scatter (a mean
        square of ~500 (rad/s)^2 on tuning bench 1, where the later fits show none beyond it) left
        the prior so loose for minutes that the curvature took a 10 % propeller loss's step."""
        cols = _BENDING_COLUMNS.get(name)
        if cols is None:
            return
        net = np.asarray(beta)[list(cols)] ** 2 - np.asarray(variance)[list(cols)]
        old = self._bending.get(name)
        if old is None:
            self._bending[name] = (net, 1)
            return
        g = max(self._memory_gain, 1.0 / (old[1] + 1))
        self._bending[name] = (old[0] + g * (net - old[0]), old[1] + 1)

    def _bending_precision(self, name: str, n_columns: int, kappa: float) -> np.ndarray | None:
        """The prior precision of each nuisance column in the fit's unscaled units (the fit's S is
        scaled by ``kappa`` afterwards): kappa / the typical square of its coefficient for the
        bending columns once the flight has shown it for learn_s, 0 (free) for the others; None
        before then (every column free). The typical square is taken at least the visit error's
        variance (times the inflation, as the fit takes it): a bending smaller than one visit's
        error is not told apart from the visits, and a net estimate at or below zero (no bending
        seen beyond the fits' scatter) would otherwise pin the drift and curvature to zero."""
        cols = _BENDING_COLUMNS.get(name)
        seen = self._bending.get(name)
        if cols is None or seen is None \
                or seen[1] * self.config.block_s * self.config.evaluate_every < self.config.learn_s:
            return None
        lam = np.zeros(n_columns)
        floor = max((_SPEED_NOISE_FLOOR * self.speed_scale) ** 2,
                    self.noise[name][2] * self.config.noise_inflation if name in self.noise else 0.0)
        lam[list(cols)] = kappa / np.maximum(seen[0], floor)
        return lam

    def _fit(self, ch: _Channel, N: np.ndarray, precision: np.ndarray | None = None
             ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """The nuisance fitted by generalised least squares. The covariance of a steady stretch's
        blocks is D + visit 11' (D: their own noise), whose inverse is D^-1 - c (D^-1 1)(D^-1 1)'
        with c = visit / (1 + visit 1'D^-1 1): so x'S^-1 y = sum(w x y) - sum over stretches of
        c (sum w x)(sum w y), w = 1/D. Returns (w, stretches x blocks indicator, c, residual,
        (N'S^-1 N)^-1, stretch sums of w N). The caller scales S by kappa (and the inflation);
        the visit error is a stretch MEAN's variance beyond its own noise, learned net of kappa
        (_learn_noise), so it enters here divided by kappa: scaled by kappa again it would count
        the blocks' short correlation twice. ``precision``: a Gaussian prior's precision per
        nuisance column (0: free), added to N'S^-1 N: the GLR then tests against the nuisance
        marginalised over its prior (S + N Lambda^-1 N'), and the returned inverse and residual
        are the prior's; also returned: the coefficients (of the prior's fit)."""
        a, b, visit, kappa = self.noise.get(ch.name, (1.0, 0.0, 0.0, 1.0))
        visit /= kappa
        # S is scaled by kappa and the inflation later: the floor and the input's noise are known
        # at their size, so they enter divided by that scale
        scale = kappa * self.config.noise_inflation
        w = ch.valid / (np.maximum(a + b * ch.level**2, ch.floor / scale) + ch.extra / scale)
        runs = true_run_pairs(ch.valid > 0)
        P = np.zeros((len(runs), len(w)))
        for j, (i, k) in enumerate(runs):
            P[j, i:k] = 1.0
        c = visit / (1.0 + visit * (P @ w))
        WN = N * w[:, None]
        PWN = P @ WN
        G = N.T @ WN - PWN.T @ (c[:, None] * PWN)
        Ginv = np.linalg.pinv(G if precision is None else G + np.diag(precision))
        rhs = WN.T @ ch.y - PWN.T @ (c * (P @ (w * ch.y)))
        beta = Ginv @ rhs
        res = ch.y - N @ beta
        return w, P, c, res, Ginv, PWN, beta

    def _single(self, ch: _Channel, N: np.ndarray, z: np.ndarray) -> float:
        """The chi-square(1) statistic of one test column z against the nuisance N (0 if the
        channel tests nothing now: ``_stats`` gives it zeros)."""
        stat, den = self._stats(dataclasses.replace(ch, nuisance=N), z[None, :, None])
        return float(stat[0, 0] ** 2 / den[0, 0]) if den[0, 0] > 0 else 0.0

    def _learn_noise(self, ch: _Channel, res: np.ndarray, n_nuisance: int) -> None:
        """The channel's noise from the reference part of the window, in two parts: a block's
        own noise, a + b level^2 (the tachometer's error grows with the speed, the ESC's ripple on
        the voltage with the current), seen within each steady stretch, with its short correlation
        kappa; and the model's error that changes from one visit of an operating point to the
        next (variance ``visit`` per stretch, shared by its blocks), seen between the stretches'
        means. Exponential memory ``noise_memory_s``; the first estimate is taken whole."""
        ref = slice(0, self._ref_blocks)
        valid = ch.noise_blocks[ref] > 0
        if valid.sum() < 20:
            return
        r, lv = res[ref], ch.level[ref]
        if not self._quiet_reach_tested(ch, valid):
            return
        runs = true_run_pairs(valid)
        dev = np.zeros(len(r))
        means: list[tuple[float, int, float]] = []
        for i, j in runs:
            if j - i < 2:
                continue
            mu = float(r[i:j].mean())
            dev[i:j] = (r[i:j] - mu) * math.sqrt((j - i) / (j - i - 1.0))
            means.append((mu, j - i, float(np.mean(lv[i:j] ** 2))))
        ok = dev != 0.0
        if ok.sum() < 10:
            return
        floor = (_SPEED_NOISE_FLOOR * self.speed_scale) ** 2 if ch.name == "speed" else _VOLTAGE_NOISE_FLOOR_V**2
        r2, x2 = dev[ok] ** 2, lv[ok] ** 2
        coef = np.linalg.lstsq(np.column_stack([np.ones(len(r2)), x2]), r2, rcond=None)[0]
        a = max(float(coef[0]), floor)
        b = max(float(coef[1]), 0.0)
        if coef[0] < floor:  # refit b with a at its floor
            b = max(float(np.sum(x2 * (r2 - a)) / max(float(np.sum(x2 * x2)), 1e-300)), 0.0)
        z = np.where(ok, dev / np.sqrt(a + b * lv**2), 0.0)
        n = float(ok.sum())
        var = float(np.sum(z * z) / n)
        kappa = 1.0
        for lag in range(1, int(round(_CORRELATION_LAGS_S / self.config.block_s)) + 1):
            rho = float(np.sum(z[lag:] * z[:-lag]) / (n * var)) if var > 0 else 0.0
            if rho <= 0.0:
                break
            kappa += 2.0 * rho
        a, b = a * var, b * var
        old = self.noise.get(ch.name)
        visit = old[2] if old else self._visit_prior(ch.name)
        dof = 0.0
        if len(means) >= 3:  # the stretches' means scatter by the visit error plus their own noise
            # (the nuisance took n_nuisance of the window's stretches' freedom: about its share)
            dof = max(len(means) - n_nuisance * len(means) / max(len(true_run_pairs(ch.valid > 0)), len(means)), 1.0)
            kept = sorted(means, key=lambda x: x[0] * x[0])  # the farthest-out stretch last
            while len(kept) > _VISIT_KEEP and \
                    kept[-1][0] ** 2 > _VISIT_OUTLIER * float(np.mean([x[0] ** 2 for x in kept[:-1]])):
                kept.pop()
                dof = max(dof - 1.0, 1.0)
            visit = max(sum(mu * mu - kappa * (a + b * l2) / k for mu, k, l2 in kept) / dof, 0.0)
        # the visit error's prior stands in only until a reference shows enough stretches for an
        # estimate; then the flight's own estimate is taken whole, as a, b and kappa are. Blended
        # in with the noise's memory instead, the prior (1 % of the speed scale) outweighed the
        # flight for minutes: every stretch was allowed a model error of that size, so a change
        # that begins at a stretch's start (a 10 % propeller loss moves the speed ~1-2 %) passed
        # for a visit error even with an exact model whose stretches agree within 0.1 %
        first_visit = dof > 0.0 and ch.name not in self._visit_learned
        if first_visit:
            self._visit_learned.add(ch.name)
        if old is None or self._ref_blocks < self._max_ref_blocks:
            # while the reference grows to its full length each estimate sees more than the last:
            # it is taken whole, so an estimate from the shortest reference does not linger
            # with the noise's memory once a longer one is there
            self.noise[ch.name] = (a, b, visit if dof > 0.0 else old[2] if old else self._visit_prior(ch.name),
                                   kappa)
        else:
            g = self._memory_gain
            self.noise[ch.name] = (old[0] + g * (a - old[0]), old[1] + g * (b - old[1]),
                                   visit if first_visit else old[2] + g * (visit - old[2]),
                                   old[3] + g * (kappa - old[3]))

    def _quiet_reach_tested(self, ch: _Channel, quiet: np.ndarray) -> bool:
        """Whether the reference's quiet blocks (``quiet``) reach the currents the voltage's test
        sees (always true for the speed, whose untested speeds carry no test). Why: the voltage's
        noise grows with the current (the ESC's ripple through the battery filter, undone), so
        quiet blocks at rest or idle say nothing of it where the test looks: a flight's first
        steady seconds at 0.1-0.3 A gave 2 mV where its blocks at 3 A carry 25 mV, and a healthy
        flight's first burst read as a change."""
        if ch.stepped is None:
            return True
        ref = slice(0, self._ref_blocks)
        moving = np.abs(ch.level[ref][ch.stepped[ref] > 0])
        if len(moving) == 0:
            return True
        return float(np.abs(ch.level[ref][quiet]).max()) >= _NOISE_CURRENT_SHARE * float(np.percentile(moving, 90))

    def _evaluate(self) -> list[HealthEvent]:
        """The tests over the window: while armed, every candidate onset of the last window_s;
        while a change is named and sized, its own onset only (up to name_within_s after it)."""
        self.evaluations += 1
        if self._pending is not None:
            back = self._row - self._pending_onset_block
            if back > self._name_blocks:
                return [self._settle(self._pending)]
            self._post = np.array([back])
        else:
            self._post = self._detect_post
        self._ref_blocks = min(self._max_ref_blocks, self._filled - 1 - int(self._post.max()))
        win = self._window(self._ref_blocks + int(self._post.max()))
        chans = self._channels(win)
        stat, theta, generic = self._test(chans, slice(None), learn=self._pending is None)
        self._last = (stat, theta, generic, chans)
        t_now = float(win[-1, _T])
        self._note_testing(t_now, {ch.name: self._reference_holds(ch) and ch.name in self.noise for ch in chans})
        h = self.threshold
        if self.state == _REFINING:
            return self._refine(t_now, 0)
        if self.state == _NAMING:
            return self._try_name(t_now, 0)
        if self._filled - self._detect_blocks < self.config.learn_s / self.config.block_s:
            return []  # still learning the noise
        self.state = _ARMED
        best_generic = max(float(g.max()) for g in generic)
        if stat.max() < h and best_generic < h:
            return []
        o = int(np.unravel_index(int(np.argmax(stat)), stat.shape)[0])
        if stat.max() < h:  # a change, but no candidate's signature fits it
            o = int(np.argmax(np.max(np.stack(generic), axis=0)))
        onset_block = self._row - int(self._post[o])
        onset_t = float(self._buf[onset_block % len(self._buf), _T] - 0.5 * self.config.block_s)
        self._pending = HealthEvent(onset_t, t_now, UNNAMED, None, "", float(max(stat.max(), best_generic)))
        self._pending_onset_block = onset_block
        self.state = _NAMING
        return self._try_name(t_now, o)

    def _test(self, chans: Sequence[_Channel], onsets: slice, learn: bool = False
              ) -> tuple[np.ndarray, np.ndarray, list[np.ndarray]]:
        """Every fault's GLR over both channels at once and each channel's unstructured step, at
        the candidate onsets ``onsets`` selects: (statistic, theta: onsets x faults; per channel
        the step's statistic per onset). ``learn``: each channel's noise learned first."""
        steps = self._post_masks(len(chans[0].y))[onsets]
        num = np.zeros((len(steps), self.n_faults))
        den = np.zeros_like(num)
        generic = []
        for ch in chans:
            zr, zz = self._stats(ch, ch.tests[onsets], learn=learn)
            num += zr
            den += zz
            # an unstructured step in this channel: the test of "something changed"
            gr, gd = self._stats(ch, ch.step_column(steps)[:, :, None])
            generic.append(np.where(gd[:, 0] > 0, gr[:, 0] ** 2 / np.maximum(gd[:, 0], 1e-300), 0.0))
        theta = num / np.maximum(den, 1e-300)
        stat = np.where((den > 0) & (theta > 0), num * num / np.maximum(den, 1e-300), 0.0)
        return stat, theta, generic

    # --- naming ----------------------------------------------------------------------------
    def _try_name(self, t_now: float, o: int) -> list[HealthEvent]:
        """Name the pending change at onset index o if one candidate explains it clearly best and
        leaves nothing significant unexplained; report it unnamed once name_within_s is over."""
        ev = self._pending
        assert ev is not None
        stat, theta, generic, _ = self._last
        row = stat[o]
        order = np.argsort(row)[::-1]
        best, second = int(order[0]), int(order[1])
        ev.candidates = {FAULTS[j]: float(row[j]) for j in range(self.n_faults)}
        ev.statistic = float(max(row[best], max(float(g[o]) for g in generic)))
        margin = row[best] - row[second] >= self._name_margin(float(row[best]))
        # seen at one operating point only, a change fits any shape: a name needs two
        post = self._steady[len(self._steady) - int(self._post[o]):] > 0
        # a name but for its lead over the next: the ``leading`` candidate
        fits = row[best] >= self.threshold and len(true_run_pairs(post)) >= _NAME_STRETCHES \
            and self._leaves_little(o, best, float(row[best]))
        self._lead = (FAULTS[best], self._size(best, float(theta[o, best]))) if fits else None
        if fits and margin:
            ev.name = FAULTS[best]
            ev.named_s = t_now
            self._set_size(ev, best, float(theta[o, best]))
            ev.unit = FAULT_UNITS[FAULTS[best]]
            ev.statistic = float(row[best])
            self._named_fit = (float(row[best]), float(theta[o, best]))
            if self._size_at(best, float(theta[o, best]), float(row[best]), 2.0) < self._min_size(best):
                return self._set_aside(ev, f"below {_MIN_SIZE_NOTE}")  # sure already: no need to wait
            self.state = _REFINING
            return []
        if self._post[o] + self.config.evaluate_every > self._name_blocks:
            return self._close_unnamed(ev, o, f"{self.config.name_within_s:g} s after its onset",
                                       self._why_unnamed(row, best, second, o))
        return []

    def _close_unnamed(self, ev: HealthEvent, o: int, by: str, note: str) -> list[HealthEvent]:
        """The unnamed change ``ev`` (onset index o) at the end of its naming wait or of the data
        (``by``): no alarm if its statistic has fallen under the threshold (it did not hold: a fault
        is a static change; the window is kept) or if it shows only at currents its reference never
        held (_unseen_currents; a fresh window from its onset, as after an alarm); else reported
        with ``note``."""
        if ev.statistic < self.threshold:
            return self._set_aside(ev, f"did not hold: its statistic fell to {ev.statistic:.0f}, under the "
                                       f"threshold {self.threshold:.0f}, by {by}", fresh_window=False)
        unseen = self._unseen_currents(o)
        if unseen is not None:
            return self._set_aside(ev, unseen)
        ev.note = note
        return [self._settle(ev)]

    def _unseen_currents(self, o: int) -> str | None:
        """Why an unnamed change at onset o is no alarm, if it shows only at currents its reference
        never held (None if it shows where the reference knows the pack): the tests again, the
        voltage's blocks after the onset kept only at currents within _CURRENT_MARGIN of the span
        the reference's steady blocks held up to window_s before the onset (a level first held
        in the seconds before the onset is hardly in the nuisance fit: the best onset of a
        staircase's new level is often a second into it). Why: the voltage's nuisance (a line in
        the current, its polarisation lags) is exact on no real pack, and beyond the currents it
        was fitted on it extrapolates; on a stand's slow staircase every new level is such a
        current, and its first seconds read as a step (the F40 stand log: 16 mV off at the next
        level against 0.6 mV of noise, an unnamed alarm in every split where nothing changed).
        A fault the model's signatures fit is named as before (a pack's sag shows at every
        current); only a change no fault explains is judged here, and the speed channel's
        tests (at the speeds its learned error knows) count as they are."""
        _, _, _, chans = self._last
        speed, volt = chans
        m = len(volt.y)
        first = m - int(self._post[o])
        learned = max(first - int(round(self.config.window_s / self.config.block_s)), 0)
        held = volt.level[:learned][volt.noise_blocks[:learned] > 0]
        if len(held) == 0:
            return None
        lo, hi = float(held.min()), float(held.max())
        known = (volt.level >= lo * (1.0 - _CURRENT_MARGIN)) & (volt.level <= hi * (1.0 + _CURRENT_MARGIN))
        known[:first] = True
        if known.all():
            return None
        kept = dataclasses.replace(volt, valid=volt.valid * known,
                                   stepped=known.astype(float) * (1.0 if volt.stepped is None else volt.stepped))
        stat, _, generic = self._test((speed, kept), slice(o, o + 1))
        best = max(float(stat.max()), *(float(g.max()) for g in generic))
        if best >= self.threshold:
            return None
        note = f"seen only at currents its reference never held (it held {lo:.1f}-{hi:.1f} A)"
        if (volt.valid[first:] * known[first:]).any():
            note += f"; at those it held, its statistic is {best:.0f}, under the threshold {self.threshold:.0f}"
        return note

    def _name_margin(self, best_statistic: float) -> float:
        """The lead the best candidate needs over the next for a name: the configured margin, or
        a share of its own statistic when that is more, for the reason the unexplained part may
        (``_unexplained``): a signature off by a few % reorders candidates whose statistics are in
        the thousands."""
        return max(self.config.name_margin, _UNEXPLAINED_SHARE * best_statistic)

    def _why_unnamed(self, row: np.ndarray, best: int, second: int, o: int) -> str:
        if row[best] < self.threshold:
            return "no candidate's signature fits the change"
        if row[best] - row[second] < self._name_margin(float(row[best])):
            return f"{FAULTS[best]} and {FAULTS[second]} explain it about equally"
        return f"{FAULTS[best]} leaves part of the change unexplained"

    def _leaves_little(self, o: int, f: int, statistic: float) -> bool:
        """Whether fault f's change at onset o, of this statistic, leaves little unexplained: less
        than the threshold or a share of its own statistic, whichever is more (the model's
        signature is never exact, so a large change always leaves a little)."""
        return self._unexplained(o, f) < max(self.threshold, _UNEXPLAINED_SHARE * statistic)

    def _unexplained(self, o: int, f: int) -> float:
        """The largest step left in either channel once fault f's change at onset o is fitted."""
        chans = self._last[3]
        worst = 0.0
        for ch in chans:
            post = np.zeros(len(ch.y))
            post[len(ch.y) - int(self._post[o]):] = 1.0
            worst = max(worst, self._single(ch, np.column_stack([ch.nuisance, ch.tests[o, :, f]]),
                                            ch.step_column(post)))
        return worst

    def _size_at(self, f: int, theta: float, statistic: float, k: float) -> float:
        """Fault f's size (its unit) at theta + k sigma, for its statistic (theta / sigma)^2."""
        sigma = theta / math.sqrt(statistic) if statistic > 0.0 else math.inf
        return self._size(f, theta + k * sigma)

    def _min_size(self, f: int) -> float:
        return dict(self.config.min_size)[FAULTS[f]]

    def _minor(self, f: int, theta: float, statistic: float) -> bool:
        """Whether fault f's change of theta (its statistic: (theta / sigma)^2) could, at two
        sigma, be below the smallest worth an alarm (``HealthConfig.min_size``)."""
        return self._size_at(f, theta, statistic, -2.0) < self._min_size(f)

    def _set_aside(self, ev: HealthEvent, note: str, fresh_window: bool = True) -> list[HealthEvent]:
        """A change that is no alarm, kept in ``minor`` with ``note``: a named one that is or
        could be too small to be a fault, after which, as after a reported one, a new window
        from its onset (the change is the new normal: ``_restart_from``); or (``fresh_window``
        False) an unnamed one whose statistic fell back under the threshold by name_within_s
        after its onset: it did not hold, nothing changed, and a fresh window would leave the
        monitor blind for its reference and learn_s (such a disturbance of a few seconds was the
        only false alarm in 10.4 h of flights on fresh benches). Returns no event."""
        ev.note = note
        self.minor.append(ev)
        self._pending = None
        self.state = _ARMING
        if fresh_window:
            self._restart_from(self._pending_onset_block)
        return []

    def _size(self, f: int, theta: float) -> float:
        name = FAULTS[f]
        if name == "pack_resistance":
            return 1.0 + theta / self._sag
        if name == "bearing_friction":
            return 1.0 + theta
        return theta

    def _set_size(self, ev: HealthEvent, f: int, theta: float) -> None:
        """``ev``'s size from the fit's theta, with what a pack's factor is relative to (the sag per
        ampere of this window: an adapter adds the same ohms the monitor sized)."""
        ev.size = self._size(f, theta)
        ev.reference = self._sag if FAULTS[f] == "pack_resistance" else None

    def _refine(self, t_now: float, o: int) -> list[HealthEvent]:
        """While the named change's data grow to refine_within_s after its onset: its size from
        the most data, and its name again by the naming rule (a candidate that now leads the named
        one by the margin and leaves nothing significant unexplained takes the name: more data
        separate signatures that 5 s could not); then (or at once, if it was named later) it is
        reported."""
        ev = self._pending
        assert ev is not None
        stat, theta, _, _ = self._last
        f = FAULTS.index(ev.name)
        best = int(np.argmax(stat[o]))
        lead = float(stat[o, best])
        if best != f and lead >= self.threshold and lead - float(stat[o, f]) >= self._name_margin(lead) \
                and self._leaves_little(o, best, lead):
            f = best
            ev.note = f"first named {ev.name} at {ev.named_s:.2f} s"  # what the status showed till now
            ev.first_name = ev.first_name or ev.name
            ev.name, ev.unit, ev.named_s = FAULTS[f], FAULT_UNITS[FAULTS[f]], t_now
            ev.candidates = {FAULTS[j]: float(stat[o, j]) for j in range(self.n_faults)}
        self._named_fit = None
        if stat[o, f] > 0:
            self._set_size(ev, f, float(theta[o, f]))
            ev.statistic = max(ev.statistic, float(stat[o, f]))
            self._named_fit = (float(stat[o, f]), float(theta[o, f]))
        elif theta[o, f] < 0.0:
            # the latest fit finds the named change reversed: none of it holds, so it is judged
            # as a change of no size (minor), not reported with the size an earlier fit gave (a
            # healthy flight of bench 897: a propeller loss reported at 0.03 %, its fit -1.4 % by the
            # report, was an alarm)
            self._named_fit = (0.0, float(theta[o, f]))
        if self._post[o] + self.config.evaluate_every > self._refine_blocks:
            return self._report_named()
        return []

    def _report_named(self) -> list[HealthEvent]:
        """The named pending change reported, or set aside as minor if its size could, at two
        sigma, be below the smallest worth an alarm (by its latest fit)."""
        ev = self._pending
        assert ev is not None and ev.name in FAULTS
        fit = self._named_fit
        if fit is not None and self._minor(FAULTS.index(ev.name), fit[1], fit[0]):
            return self._set_aside(ev, f"could be below {_MIN_SIZE_NOTE}")
        return [self._settle(ev)]

    def _settle(self, ev: HealthEvent) -> HealthEvent:
        """Report ``ev`` and start a new window at its onset (the change is the new normal)."""
        self._pending = None
        self.events.append(ev)
        self.state = _ARMING
        self._restart_from(self._pending_onset_block)
        return ev


# --- a recording's streams, in time order ------------------------------------------------------------
@dataclass
class HealthRun:
    """What the monitor found on one recording's streams."""

    events: list[HealthEvent]
    duration_s: float  #: from the first to the last measured speed sample
    monitored_s: float  #: the part after the first full window, where changes can be found
    threshold: float
    noise: dict[str, tuple[float, float, float, float]]  #: channel -> HealthMonitor.noise at the end
    #: changes that are no alarm (named below HealthConfig.min_size, unnamed that did not hold), in time order
    minor: list[HealthEvent] = field(default_factory=list)
    #: channel -> seconds its tests ran (``HealthMonitor.tested_s``): what the monitor could find
    #: a change in, where monitored_s says only how long it was armed
    tested_s: dict[str, float] = field(default_factory=dict)
    #: channel -> the (start, end) times its tests ran (:func:`channel_intervals`)
    tested: dict[str, list[tuple[float, float]]] = field(default_factory=dict)


def channel_intervals(log: Sequence[tuple[float, str, bool]], end_s: float) -> dict[str, list[tuple[float, float]]]:
    """Per channel, the (start, end) times its tests ran, from ``HealthMonitor.testing_log`` (a
    channel still testing at the end runs to ``end_s``; an end with no start, where the log's
    oldest entries were dropped, is left out)."""
    out: dict[str, list[tuple[float, float]]] = {name: [] for name in CHANNELS}
    since: dict[str, float] = {}
    for t, name, on in log:
        if on:
            since[name] = t
        elif name in since:
            out[name].append((since.pop(name), t))
    for name, t in since.items():
        out[name].append((t, max(end_s, t)))
    return out


class _Hybrid(Protocol):
    """A hybrid model (``model.HybridModel``): its physics part."""

    @property
    def plant(self) -> PlantModel: ...


def physics_part(model: object) -> PlantModel | None:
    """The physics model a model of any kind carries (a hybrid's plant), or None (a network)."""
    kind = getattr(model, "kind", None)
    if kind == "physics":
        return cast("PlantModel", model)  # (its kind says what it is)
    if kind == "hybrid":
        return cast(_Hybrid, model).plant
    return None


def require_physics(model: object, what: str, where: str) -> PlantModel:
    """The physics part of ``model``, or the one-line BadInputError every refusal of a model
    without physics (a network, the first-principles fallback) gives: ``what`` (the feature that
    needs the physics, e.g. "the health monitor (--health)") and ``where`` (the file, option or
    parameter the model came from, first in the line; "" for none). The adaptation and the health
    monitor both work on a fitted physics (the faults' signatures, the adapted parameters), so
    the CLI, replay and the node refuse alike."""
    plant = physics_part(model)
    if plant is not None:
        return plant
    kind = getattr(model, "kind", None)
    this = f"a {kind} model" if kind else "the first-principles fallback (no model file)"
    raise BadInputError(f"{where + ': ' if where else ''}{what} needs a physics or hybrid model; this one is "
                        f"{this}, which has no fitted physics (train --kind physics makes one)")


#: How long (s of the caller's clock) a candidate must lead a change being named before the
#: adapter takes it provisionally (``HealthStream``): a lead of a second or two can be the change's
#: first, transient, shape (tuning bench 2, flight 20001: a tripled friction led as a 157 K heating
#: for 1.2 s, then named; taken, its RMSE after the change went 1.51 -> 1.87x the twin's).
_LEAD_HOLD_S = 2.0


class HealthStream:
    """The monitor fed one input at a time, as the estimator is: the code the node (parameter
    ``health``), ``replay --health`` and the offline driver (:func:`run_health`) share, so the
    three find the same events on the same inputs.

    Feed it what ``estimator`` accepted, right after it did (``update_pwm`` when
    ``ThrustEstimator.update_pwm`` returned True, and so on). The prediction tested is the
    estimator's OFFLINE model at each measured speed's time (``ThrustEstimator.offline_speed``):
    an online adaptation, if on, follows the very change the monitor is there to name. Times are
    the caller's clock (the node's, or seconds from a recording's start), and so are the events'.

    With the estimator adapting (``estimator.adapter``), a change named is passed to the adapter
    (``PhysicsAdapter.take_named``) the moment it is named and again with its size refined, and
    while a change is being named, its leading candidate (``HealthMonitor.leading``), taken
    provisionally (a hot winding only) and undone if it leaves unnamed; the
    adapter takes what it has no parameter for (a hot winding), which it would otherwise learn
    only in part, in its other parameters' place, a pack, which the monitor sizes sooner than
    the adapter's own estimate from the voltage, and a propeller or a friction, which it tells
    apart and sizes sooner than the adapter's two parameters learn them."""

    def __init__(self, estimator: ThrustEstimator, config: HealthConfig | None = None) -> None:
        """BadInputError for a model without physics (a network, the first-principles fallback):
        it has no physics to give the faults' signatures."""
        plant = require_physics(estimator.model, "the health monitor (--health / parameter health)", "")
        assert plant.supply_tau_s is not None, "PlantModel.__post_init__ resolves None"
        self.estimator = estimator
        self.config = config or HealthConfig()
        self._plant = plant
        self._last_voltage: tuple[float, float] | None = None
        self.twins = self._twins()
        tau = float(plant.supply_tau_s)
        self.monitor = HealthMonitor(tau, self.twins.speed_scale_rad_s, self.twins.pack_resistance_ohm,
                                     self.config, voltage_strength=float(plant.effects.get("battery_voltage", 1.0)),
                                     source_resistance_ohm=self.twins.source_resistance_ohm)
        self.first_s = math.nan  #: the first measured speed the monitor took (s)
        self.last_s = math.nan  #: the latest
        #: per named change passed to the adapter (by its detection time), the name and size passed
        self._passed: dict[float, tuple[str, float]] = {}
        #: the change being named as last passed to the adapter: its onset (s), lead's name and size
        self._led: tuple[float, str, float] | None = None
        #: the change being named: its onset, its leading candidate's name and since when it leads (s)
        self._lead_since: tuple[float, str, float] | None = None

    def _twins(self) -> PhysicsTwins:
        p = self._plant
        assert p.supply_tau_s is not None
        return PhysicsTwins(p.params, p.effects, p.supply_v, float(p.supply_tau_s), static=True)

    @property
    def events(self) -> list[HealthEvent]:
        """Every change reported so far (settled), in order."""
        return self.monitor.events

    def update_pwm(self, t: float, level: float) -> None:
        """A command frame (PWM level) the estimator accepted at t (s)."""
        self.twins.update_pwm(t, level)

    def update_voltage(self, t: float, volts: float) -> None:
        """A filtered battery voltage (V) the estimator accepted at t (s)."""
        self.twins.update_voltage(t, volts)
        self._last_voltage = (t, volts)

    def update_speed(self, t: float, measured_rad_s: float) -> list[HealthEvent]:
        """A measured speed (rad/s) the estimator accepted at t (s); returns the changes
        reported at it (usually none). Nothing is tested before a command and a voltage came."""
        predicted = self.estimator.offline_speed(t)
        tw = self.twins.sample(t)
        if tw is None or not math.isfinite(predicted) or self._last_voltage is None:
            return []
        if self.first_s != self.first_s:
            self.first_s = t
        self.last_s = t
        events = self.monitor.update(HealthSample(t, measured_rad_s, predicted, self._last_voltage[1], tw))
        adapter = self.estimator.adapter
        if adapter is not None:
            self._pass_on(adapter, events, t)
        return events

    def _pass_on(self, adapter: Adapter, events: list[HealthEvent], t: float) -> None:
        """The changes named (settled, or named and being sized) to the adapter, each once per size;
        the one being named as its leading candidate (provisionally) once the lead has held
        ``_LEAD_HOLD_S``, undone when another candidate leads or the change leaves unnamed."""
        pending = self.monitor.pending
        for ev in (*events, pending):
            if ev is not None and ev.name != UNNAMED and ev.size is not None \
                    and self._passed.get(ev.detected_s) != (ev.name, ev.size):
                self._passed[ev.detected_s] = (ev.name, ev.size)
                adapter.take_named(ev.name, ev.size, ev.onset_s, reference=ev.reference)
        if pending is None or (self._lead_since is not None and pending.onset_s != self._lead_since[0]):
            self._lead_since = None
            self._drop_lead(adapter)  # nothing to undo once the change was named (``take_named``)
        lead = self.monitor.leading
        if pending is None or lead is None:
            return
        if self._lead_since is None or self._lead_since[:2] != (pending.onset_s, lead[0]):
            self._lead_since = (pending.onset_s, lead[0], t)
            self._drop_lead(adapter)  # another candidate leads now
        if t - self._lead_since[2] >= _LEAD_HOLD_S and self._led != (pending.onset_s, *lead):
            self._led = (pending.onset_s, *lead)
            adapter.take_named(lead[0], lead[1], pending.onset_s, provisional=True)

    def _drop_lead(self, adapter: Adapter) -> None:
        if self._led is not None:
            self._led = None
            adapter.drop_provisional()

    def restart_physics(self) -> None:
        """The twins start again at the next command (the estimator's ``restart_physics``: after a
        stall of the commands the held command says nothing of what the rotor did); the monitor
        keeps its window (a gap in the speed restarts it by its own rule)."""
        self.twins = self._twins()
        if self._last_voltage is not None:
            self.twins.update_voltage(*self._last_voltage)

    def finish(self) -> list[HealthEvent]:
        """The end of the data: a change still being named is reported as it stands (a named one
        that could be too small to be a fault kept as minor: ``HealthMonitor.finish``); the adapter
        keeps no lead of a change left unnamed."""
        events = self.monitor.finish()
        adapter = self.estimator.adapter
        if adapter is not None:
            self._pass_on(adapter, events, self.last_s)
        return events

    def run(self) -> HealthRun:
        """What was found so far, as :func:`run_health` returns it."""
        duration = self.last_s - self.first_s if self.last_s == self.last_s else 0.0
        cfg = self.monitor.config
        armed = max(0.0, duration - cfg.arming_reference_s - cfg.window_s)
        mon = self.monitor
        return HealthRun(list(mon.events), duration, armed, mon.threshold, dict(mon.noise), list(mon.minor),
                         dict(mon.tested_s), channel_intervals(mon.testing_log, self.last_s))

    def status(self) -> CoreStatus:
        """The health status ("health"): OK while no change was seen; WARN while a change is being
        named, or when the latest change is unnamed; ERROR once a fault is named, which stays
        (the latest named) until the stream is made anew (a node's model reload). Values: effect,
        size and unit, onset_s and detected_s (the caller's clock) of the change shown."""
        mon = self.monitor
        pending = mon.pending
        named = [e for e in mon.events if e.name != UNNAMED]
        if pending is not None and pending.name != UNNAMED:
            named.append(pending)  # named, its size still being refined
        values: dict[str, object] = {"state": mon.state, "changes": len(mon.events),
                                     "minor_changes": len(mon.minor), "threshold": mon.threshold,
                                     **{f"{name}_tested": on for name, on in mon.testing.items()}}
        if named:
            ev, level = named[-1], ERROR
            msg = f"{ev.name} {_size_text(cast(float, ev.size), ev.unit)} since {ev.onset_s:.2f} s"
            if pending is not None and pending is not ev:
                msg += f"; another change since {pending.onset_s:.2f} s being named"
        elif pending is not None:
            ev, level = pending, WARN
            msg = f"a change since {ev.onset_s:.2f} s (found at {ev.detected_s:.2f} s), being named"
        elif mon.events:
            ev, level = mon.events[-1], WARN
            msg = f"{UNNAMED} since {ev.onset_s:.2f} s" + (f": {ev.note}" if ev.note else "")
        else:
            return CoreStatus("health", OK, "no change" + _watching(mon), counters(**values))
        values.update(effect=ev.name, size=math.nan if ev.size is None else ev.size, unit=ev.unit or "none",
                      onset_s=ev.onset_s, detected_s=ev.detected_s,
                      named_s=math.nan if ev.named_s is None else ev.named_s, statistic=ev.statistic)
        return CoreStatus("health", level, msg, counters(**values))


def _watching(mon: HealthMonitor) -> str:
    """What an OK status leaves out: still learning, or a channel not tested (its reference holds
    too few valid blocks), so that 'no change' is never read as 'nothing could have changed'."""
    if mon.state == _ARMING:
        return " (learning the healthy reference)"
    if not mon.testing["speed"]:
        return (" seen in the voltage; the speed is not tested yet (too few steady seconds at speeds whose "
                "model error is learned)") if mon.testing["voltage"] else " (neither channel is tested yet)"
    return "" if mon.testing["voltage"] else " (the voltage is not tested yet)"


def run_health(model: SpeedModel, pwm: tuple[np.ndarray, np.ndarray], voltage: tuple[np.ndarray, np.ndarray],
               speed: tuple[np.ndarray, np.ndarray], config: HealthConfig | None = None) -> HealthRun:
    """Feed a recording's command frames, filtered voltages and measured speeds, merged in time
    order (at equal times the inputs before the speed), to the estimator (``ThrustEstimator``:
    the prediction) and its :class:`HealthStream`, as a node receives them. ``model``: a physics
    or hybrid model (model.py); BadInputError for one without physics (a network)."""
    from .estimator import ThrustEstimator

    est = ThrustEstimator(model)
    stream = HealthStream(est, config)
    kinds = [np.zeros(len(pwm[0])), np.ones(len(voltage[0])), np.full(len(speed[0]), 2.0)]
    t_all = np.concatenate([np.asarray(pwm[0], float), np.asarray(voltage[0], float), np.asarray(speed[0], float)])
    x_all = np.concatenate([np.asarray(pwm[1], float), np.asarray(voltage[1], float), np.asarray(speed[1], float)])
    k_all = np.concatenate(kinds)
    order = np.lexsort((k_all, t_all))  # by time; at equal times inputs before the speed
    for t, kind, x in zip(t_all[order].tolist(), k_all[order].tolist(), x_all[order].tolist(), strict=True):
        if kind == 0.0:
            if est.update_pwm(t, x):
                stream.update_pwm(t, x)
        elif kind == 1.0:
            if est.update_voltage(t, x):
                stream.update_voltage(t, x)
        elif est.update_speed(t, x):
            stream.update_speed(t, x)
    stream.finish()
    return stream.run()
