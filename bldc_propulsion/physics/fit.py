"""A physics CONFIG fitted to recordings: its constants calibrated, effect strengths fitted with
them, and every fit checked for a quantity at a bound or implausibly far from what was stated.

The fit is least squares on the plant's predicted speed (``PhysicsConfig.predict``) against the
measured speed of a ``Data`` set: the constants a different motor, propeller or ESC changes most
(``config.CALIBRATED``: Kv, CP, the throttle map's exponent, the pack's series resistance),
log-parameterised within ranges around a start, and the strengths of the effects asked for
(``free``) with what they need along (``COMPANIONS``), and, where a caller asks (``linear``), plant
constants whose "off" is 0 on a linear scale (``config.LINEAR_RANGES``: the throttle map's origin
below the ESC's start threshold). ``train --kind physics`` fits a model so
(``fit_reference``, ``training/fit_physics.py``); the discrepancy workflow calibrates, scores
and names effects with the same fits (``discrepancy/physics.py``, ``physics_kind.py``).
``fit_flags`` says which fitted quantity is no basis for a verdict (``FitFlag``).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any, TypedDict

import numpy as np
from scipy.optimize import least_squares

from .. import contract as c
from .config import CALIBRATED, LINEAR_OPEN_ABOVE, LINEAR_RANGES, PhysicsConfig, Recorded, supply_tau_s
from .plant import full_drive_speeds

#: The ranges of ``config.CALIBRATED``, the constants calibrated on the measured data (log scale):
#: first within a factor e^LOG_RANGE_BASE of the CONFIG's (another motor and propeller: a 5 in propeller has
#: (5/12)^5 = 1/80 of the 12 in one's CP D^5), then, with effects switched on, within the span of
#: that calibration and the CONFIG's values widened by a factor e^LOG_RANGE_EFFECT: an effect may
#: shift the constants (back towards the CONFIG's, which the first calibration, made without the
#: effects, may have left to stand in for them: on the bundled bags CP 0.0026 vs 0.042), not
#: replace the propeller law (with CP -> 0 the speed becomes linear in duty and stands in for
#: missing effects).
#: The ESC's throttle-map exponent (duty = x**exponent) is the third: ESCs and their "throttle
#: curve" settings bend the map, and a model with a straight one fits the bend with the strengths
#: of the effects it has (tuning bench 104, map x**1.16: start level 1.12 and heating 2.85 for
#: 0.65 and 1.12 true; calibrated, 0.60 and 0.86); it is an ESC constant, not an effect, so it is
#: calibrated like Kv, within a factor 2 (never wider: a bend of x**2 is another ESC).
#: The pack's series resistance is the fourth, within a factor 4: a voltage filtered from the
#: battery ADC lags the terminal by the filter's 2 s, and the model puts back the drop the filter
#: has not passed yet, R_s (i - lowpass(i)) (``plant.Supply``), for seconds after every step. With
#: the nominal R_s on a pack of half of it, heating's strength took up the difference (randomized
#: benches 15 and 16, R_s 0.52x and 0.55x: 1.34x and 1.56x its truth; calibrated, 1.19x and 1.08x).
#: Without a filtered voltage it has no column and stays at the CONFIG's.
LOG_RANGE_BASE = np.array([math.log(1000.0), math.log(1000.0), math.log(2.0), math.log(4.0)])
#: The CALIBRATED constants that are the motor and the propeller: a reference fit with one of them
#: not physical is no base for a verdict.
MOTOR_AND_PROPELLER = ("motor_kv_rpm_per_v", "propeller_cp")
#: Constants that, once the reference fit has set them, the measured data may not move: the throttle
#: map is the ESC's setting, the same in every recording of a bench, and a model without an effect
#: the measured data have bends it to stand in for that effect (randomized bench 0, rotor lag hidden:
#: map x**1.84 with Kv 390000 rpm/V instead of any inertia). Without reference recordings it is
#: calibrated on the measured data like Kv and CP. The pack's series resistance likewise: the same
#: pack, and on the measured data it would otherwise stand in for a sag the battery_voltage effect
#: should be named for.
HELD_AFTER_REFERENCE = ("esc_throttle_exponent", "battery_series_resistance_ohm")
#: The throttle map's second shape constant, fitted (linear scale) with the CALIBRATED ones on the
#: reference and then held like the exponent: a foreign bench's ESC maps duty = a x + (1 - a) x^2,
#: which a power law meets at two levels only; the duty it missed between them (1-2 %) was taken
#: up by a start threshold or a dead time on the measured data (foreign seeds 0-3: esc_deadband
#: named on two heating benches, rotor_lag or nothing on the deadband ones). Not calibrated without
#: a reference: the measured data would bend it to stand in for the effect they have.
MAP_SHAPE = ("esc_throttle_curvature",)
LOG_RANGE_EFFECT = math.log(3.0)
#: Constants fitted along with an effect's strength whenever that strength is fitted (log scale, within
#: a factor e^COMPANION_LOG_RANGE of the value the effect was first fitted from: the CONFIG's).
#: Heating: how soon the winding gets hot is the motor's thermal time constant, another motor's and
#: another mount's (0.25-2.25x the nominal bench's on the randomized benches); with it held at the
#: CONFIG's, the strength stood in for it (randomized bench 2, 70 s against the CONFIG's 126 s:
#: strength 1.37x its truth). The thermal resistance is the one fitted, with the CONFIG's thermal
#: capacity kept: then the strength sets the resistance rise per joule of heat (the initial slope
#: of a hot run, which recordings of a few minutes show) and the thermal resistance where it levels
#: off (which they show only when the time constant is shorter than they are). Fitting the
#: capacity instead puts the level-off into the strength: bench 9 (253 s, 180 s recordings)
#: then gave 1.75x the truth with a 485 s time constant.
COMPANIONS: dict[str, str] = {"motor_heating": "motor_thermal_resistance_k_per_w"}
COMPANION_LOG_RANGE = math.log(4.0)
#: Constants fitted along with an effect wherever the discrepancy workflow switches it on, at a
#: grid strength as much as with its strength fitted (``recalibrate_with``), on a linear scale
#: (config.LINEAR_RANGES, from SWITCH_START). Without them an effect cannot fit what it is, so
#: its score says nothing.
#: Where the throttle map starts is the ESC's (``esc_map_origin_share``): an ESC may cut its map
#: off below the start threshold (share 1) or rescale the map from it (0, this project's
#: simulator). With it held at the CONFIG's 0 (foreign bench 1, start level 0.0577, map from
#: PWM_STOP) the threshold removed -0.5 % of the measured data's residual; fitted along, with the
#: friction of the base (BASE_COMPANIONS), the threshold was named at 0.0582 and the holdout RMSE
#: went from 6.0 to 1.6 rad/s. The friction is not a companion here: fitted along with the
#: threshold it wandered with every later effect (the demo's bags: 0.62 A, then 0.1 A at its
#: bound with the dead time, for the bench's 0.4 A), and the bound hit refused the dead time.
SWITCH_COMPANIONS: dict[str, tuple[str, ...]] = {"esc_deadband": ("esc_map_origin_share",)}
#: SWITCH_COMPANIONS of an effect completed into the base on the reference (``fit_reference``'s
#: ``with_companions``) only, then held like the map's shape. A pack sags over seconds after a step
#: (its polarisation), which a ~2 s battery filter passes only in part: with the series resistance
#: alone, the battery_voltage strength fitted 0.83-0.89 on foreign bench 102's reference (a 2.8 s
#: branch) for 0.99 with the branch removed, and the slow sag it left made a winding's heating remove
#: 20-30 % of a reference that had none. Not on the measured data: there the two constants stood in
#: for what a badly calibrated model lacked (the demo's bags, no reference, Kv 2.2x the nominal:
#: R_p at the top of its range, and battery_voltage no longer a basis for a verdict).
REFERENCE_COMPANIONS: dict[str, tuple[str, ...]] = {
    "battery_voltage": ("supply_polarisation_resistance_ohm", "supply_polarisation_time_constant_s")}
#: Constants of the base fitted on the reference in the discrepancy workflow along with the CALIBRATED
#: ones (log scale, within COMPANION_LOG_RANGE of the CONFIG's; ``fit_reference``'s ``base_companions``),
#: then held on the measured data like them: every real bench has friction, another motor's than
#: the CONFIG's, and below a start threshold the rotor coasts undriven, slowed by it (foreign bench
#: 1: 0.14 A fitted on the reference for the CONFIG's 0.4 A; with 0.4 A the threshold at its true
#: level left the holdout at 18.7 rad/s, with 0.15 A at 6.5 rad/s). As a companion of the
#: threshold on the measured data only, it stood in for the friction the reference needed: a
#: threshold below every commanded level scored 63 % of a reference that had none (foreign bench 2).
BASE_COMPANIONS = ("motor_no_load_current_a",)
#: Where a linear SWITCH_COMPANIONS constant starts its fit: the map from PWM_STOP, the threshold
#: only cutting the drive off below it, as training's origin fit starts (real ESCs: the esc_test
#: F80 maps from ~990 us and starts the rotor at 1100-1150 us).
#: The polarisation starts at half the nominal series resistance and a few seconds: at R_p 0 its
#: time constant would have no slope.
SWITCH_START = {"esc_map_origin_share": 1.0, "supply_polarisation_resistance_ohm": 0.0175,
                "supply_polarisation_time_constant_s": 3.0}
#: Upper bounds of a fitted strength: 6x nominal covers a bench with twice the nominal dead time,
#: inertia or start threshold and an effect twice as strong; spin-down's 1 is physical (all braking
#: removed), not a limit of the fit, so a fit there is no bound hit (PHYSICAL_MAX).
STRENGTH_MAX = {name: (1.0 if name == "spin_down_asymmetry" else 6.0) for name in c.EFFECTS}
PHYSICAL_MAX = frozenset({"spin_down_asymmetry"})
#: What every real bench has, in the base model whatever the CONFIG switches on, and fitted on the
#: reference with the constants: a rotor has inertia (the pack's resistance is calibrated with the
#: constants, friction is always in the plant). A base with an instantaneous rotor (this project's
#: simulator with every effect off) named rotor_lag first on benches written by someone else. On
#: the measured data its strength is held at the reference's, and it is a candidate all the same,
#: freed: refitted on the measured data, named when those need another inertia than the
#: reference. Zero is physical (a rotor the reference shows as instantaneous), not a bound.
#: An ESC brakes the rotor or lets it coast (spin-down's 0 and 1, both physical ESCs): a base that
#: can only brake fitted a coasting foreign bench's reference with an instantaneous rotor and Kv
#: 1.6e5 rpm/V (31 rad/s RMS, loaded speed 0.3 % of no-load; with the braking fitted: Kv 654 for the
#: bench's 669, 6.9 rad/s), so every effect was completed into the base and none could be named.
#: Not (yet) in the base: the dead time, which the reference fit then trades with the inertia
#: (randomized bench 1, no dead time in the reference: 12 ms fitted, and the measured data's
#: 20 ms no longer named); every effect, which kept Kv physical on benches whose reference has a
#: coasting ESC or heating but named second effects on the project's own randomized benches. (The
#: discrepancy workflow adds the other effects only when this base does not explain the reference:
#: ``discrepancy.physics_kind.PhysicsKind._complete_base``.)
BASE_EFFECTS = ("rotor_lag", "spin_down_asymmetry")
#: The strength a base effect the CONFIG has off starts its reference fit from: the CONFIG's inertia,
#: and half the braking removed (spin-down's 0 and 1 are both physical ESCs).
BASE_START = {"rotor_lag": 1.0, "spin_down_asymmetry": 0.5}
#: ... and the other start of that fit, the better of the two kept: inertia and dead time both lag
#: the response, and from the CONFIG's inertia on a reference whose rotor has a tenth of it (or
#: none) the fit settles on half the dead time and a tenth of the inertia with Kv and CP bent to
#: suit (5.7 rad/s RMS where the true split gives 1.5).
BASE_LOW_START = {"rotor_lag": 0.1}


# --- data, calibration -----------------------------------------------------------------------------
@dataclass
class Data:
    """Recordings and the rows (finite measured speed) of each that the residual uses."""

    signals: Sequence[Recorded]
    rows: list[np.ndarray]

    @classmethod
    def of(cls, signals: Sequence[Recorded]) -> Data:
        return cls(list(signals), [np.flatnonzero(np.isfinite(s.speed)) for s in signals])

    def residual(self, model: PhysicsConfig) -> np.ndarray:
        return np.concatenate([s.speed[r] - model.predict(s)[r] for s, r in zip(self.signals, self.rows, strict=True)])


@dataclass
class Fit:
    """A model with its constants calibrated on a data set: residual and its Jacobian there."""

    model: PhysicsConfig
    r: np.ndarray  #: measured - predicted on the data's rows
    J: np.ndarray  #: d r / d (log constant, free strength): one column per CALIBRATED, then free
    sse: float
    anchor: np.ndarray  #: constants the calibration stays within a factor exp(log_range) of
    log_range: np.ndarray  #: per constant (log scale)
    free: tuple[str, ...] = ()  #: effects whose strengths were fitted along (those added so far)
    #: the COMPANIONS of ``free`` effects: the value each one's range is centred on (the CONFIG's)
    companion_anchor: dict[str, float] = dataclasses.field(default_factory=dict)
    #: plant constants fitted on a linear scale within ``config.LINEAR_RANGES`` (their columns last)
    linear: tuple[str, ...] = ()

    def companions(self) -> dict[str, float]:
        """The fitted COMPANIONS (name: value) of the free effects."""
        return {n: float(getattr(self.model.params, n)) for n in self.companion_anchor}


#: ``least_squares``'s xtol in ``calibrate`` (scipy's default: 1e-8): the variables are log
#: constants, so 1e-4 is a step of 0.01 % in each, far inside what a Jacobian from forward
#: differences of 1e-3 (``difference_steps``) resolves; the iterations past it move no verdict.
#: Measured on the workflow's calibrations (both from the same starts: test_discrepancy_base's
#: completed-base case, 95 fits): cost above the default's by a median 4e-11, at most 1.2e-3, in
#: 76 % of the time. The cost's tolerance (ftol) stays scipy's: a weakly identified constant (the
#: throttle map's origin below a start threshold, test_start_threshold) still lowers the cost by
#: less than 1e-5 per step while 6 % from its value, and a looser ftol stops it there.
FIT_XTOL = 1e-4


def calibrate(model: PhysicsConfig, data: Data, anchor: np.ndarray, log_range: np.ndarray | float,
              free: Sequence[str] = (), max_nfev: int = 40,
              companion_anchor: dict[str, float] | None = None, linear: Sequence[str] = ()) -> Fit:
    """The CALIBRATED constants (log scale, within a factor exp(log_range) of ``anchor``; a
    constant with a zero range is held at ``model``'s value), the strengths of the effects
    ``free`` and their COMPANIONS (within COMPANION_LOG_RANGE of ``companion_anchor``, by default
    ``model``'s values), and the plant constants ``linear`` (within ``config.LINEAR_RANGES``: those
    whose "off" is 0) fitted by least squares from ``model``'s values: an effect added earlier
    gets its strength refitted with each later one, so it cannot keep standing in for a missing one."""
    nc = len(CALIBRATED)
    span = np.broadcast_to(np.asarray(log_range, dtype=float), (nc,)).copy()
    span[[j for j, n in enumerate(CALIBRATED) if n in inert_constants(model, data, free)]] = 0.0
    live = np.flatnonzero(span > 0.0)
    start = np.log(np.array([getattr(model.params, n) for n in CALIBRATED]) / anchor)
    # (and every constant ``companion_anchor`` names: a BASE_COMPANIONS one of a reference fit)
    comp = [COMPANIONS[n] for n in free if n in COMPANIONS]
    comp += [n for n in companion_anchor or {} if n not in comp]
    comp_anchor = {n: (companion_anchor or {}).get(n, float(getattr(model.params, n))) for n in comp}
    comp_start = np.array([math.log(getattr(model.params, n) / comp_anchor[n]) for n in comp])
    # The solver's variables are the log constants shifted by 1: scipy's 'trf' starts with a trust
    # radius of ||x0|| (1 only when x0 is exactly 0), so a start a rounding error away from the
    # anchor (log 1e-16) would never move; shifted, the radius is ~1 wherever the start is.
    shift = np.concatenate([np.ones(len(live)), np.zeros(len(free)), np.ones(len(comp)), np.zeros(len(linear))])
    n_before_linear = len(live) + len(free) + len(comp)

    def unpack(z: np.ndarray) -> PhysicsConfig:
        x = z - shift
        logs = start.copy()
        logs[live] = x[:len(live)]
        m = model.with_constants(anchor * np.exp(logs))
        for name, v in zip(free, x[len(live):len(live) + len(free)], strict=True):
            m = m.with_effect(name, v)
        if comp:
            # (untyped: replace(**) checks each field's type by name, which a name -> value dict cannot state)
            logs_comp = x[len(live) + len(free):n_before_linear]
            compensation: dict[str, Any] = {n: comp_anchor[n] * math.exp(v)
                                            for n, v in zip(comp, logs_comp, strict=True)}
            m = dataclasses.replace(m, params=dataclasses.replace(m.params, **compensation))
        if linear:
            values: dict[str, Any] = dict(zip(linear, map(float, x[n_before_linear:]), strict=True))
            m = dataclasses.replace(m, params=dataclasses.replace(m.params, **values))
        return m

    lo = np.concatenate([-span[live], np.zeros(len(free)), np.full(len(comp), -COMPANION_LOG_RANGE),
                         [LINEAR_RANGES[n][0] for n in linear]]) + shift
    hi = np.concatenate([span[live], [STRENGTH_MAX[n] for n in free], np.full(len(comp), COMPANION_LOG_RANGE),
                         [LINEAR_RANGES[n][1] for n in linear]]) + shift
    x0 = np.concatenate([start[live], [model.effects[n] for n in free], comp_start,
                         [getattr(model.params, n) for n in linear]]) + shift
    res = least_squares(lambda z: data.residual(unpack(z)), np.clip(x0, lo, hi), bounds=(lo, hi),
                        diff_step=difference_steps(model, len(live), free, len(comp) + len(linear)),
                        max_nfev=max_nfev, xtol=FIT_XTOL)
    # a parameter held at its bound is not refitted per fold (a linear step would leave the bounds),
    # nor is a held constant (a zero column: the per-fold ridge solve ignores it)
    n_fit = len(free) + len(comp) + len(linear)
    J = np.zeros((len(res.fun), nc + n_fit))
    J[:, np.concatenate([live, nc + np.arange(n_fit)]).astype(int)] = np.where(
        np.isclose(res.x, lo, atol=1e-6) | np.isclose(res.x, hi, atol=1e-6), 0.0, res.jac)
    return Fit(unpack(res.x), res.fun, J, float(res.fun @ res.fun), anchor, span, tuple(free), comp_anchor,
               tuple(linear))


def inert_constants(model: PhysicsConfig, data: Data, free: Sequence[str] = ()) -> set[str]:
    """CALIBRATED constants the residual of ``data`` does not depend on, held by ``calibrate``:
    a zero Jacobian column gives scipy's trust region no reason to stay, and the constant walked
    to its bound (R_s 3.9x the CONFIG's with battery_voltage off), where a later fit that switches
    the effect on found it. The pack's series resistance acts only with battery_voltage on (or
    being fitted) and a voltage filtered from the battery ADC (``plant.Supply``)."""
    rs_acts = ((model.effects.get("battery_voltage", 0.0) > 0.0 or "battery_voltage" in free)
               and any(supply_tau_s(s) > 0.0 for s in data.signals))
    return set() if rs_acts else {"battery_series_resistance_ohm"}


def difference_steps(model: PhysicsConfig, n_constants: int, free: Sequence[str], n_companions: int = 0) -> np.ndarray:
    """Relative finite-difference steps of ``calibrate``'s variables (scipy: step = rel * max(1, |x|)).
    A dead time acts on the simulation's grid (``sim_step_s``): the residual is a staircase in the
    input_delay strength, flat between grid steps, so its step spans one grid step; with 1e-3 the
    slope is 0 and the dead time stays where it started (randomized bench 0: the CONFIG's 40 ms for
    the bench's 58 ms, and the rotor-lag fit then took 0.19 of the true inertia to make up for it)."""
    rel = np.full(n_constants + len(free) + n_companions, 1e-3)
    for j, name in enumerate(free):
        if name == "input_delay" and model.params.esc_input_delay_s > 0.0:
            rel[n_constants + j] = max(1e-3, model.params.sim_step_s / model.params.esc_input_delay_s)
    return rel


def base_range(hold: Sequence[str] = ()) -> np.ndarray:
    """LOG_RANGE_BASE per CALIBRATED constant, 0 (held) for those in ``hold``."""
    return np.where([n in hold for n in CALIBRATED], 0.0, LOG_RANGE_BASE)


def base_window(model: PhysicsConfig, hold: Sequence[str] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(anchor, log half-width) of a first calibration per CALIBRATED constant: LOG_RANGE_BASE
    around ``model``'s value, or the model's own range (a stated prior's, ``PhysicsConfig.ranges``)
    wherever the fit starts from; 0 (held at ``model``'s value) for those in ``hold``."""
    anchor = np.array(list(model.constants().values()))
    span = base_range(hold)
    for j, n in enumerate(CALIBRATED):
        if n in model.ranges and n not in hold:
            lo, hi = model.ranges[n]
            anchor[j], span[j] = math.sqrt(lo * hi), 0.5 * math.log(hi / lo)
    return anchor, span


def calibrate_base(model: PhysicsConfig, data: Data, hold: Sequence[str] = ()) -> Fit:
    """The CONFIG's constants calibrated (wide range, ``base_window``); later fits stay between the
    result and the CONFIG's values, widened by LOG_RANGE_EFFECT (anchor at their geometric mean;
    a stated prior's constant also inside its own range: a stated Kv's +-30 % holds for every later
    fit too). The constants ``hold`` keep ``model``'s values (see HELD_AFTER_REFERENCE)."""
    centre, wide = base_window(model, hold)
    config = np.log(np.array(list(model.constants().values())))
    own = np.array([n in model.ranges and n not in hold for n in CALIBRATED])  # a stated prior's range
    fit = calibrate(model, data, np.where(own, centre, np.exp(config)), wide)
    cal = np.log(np.array(list(fit.model.constants().values())))
    anchor, span = 0.5 * (config + cal), np.minimum(0.5 * np.abs(config - cal) + LOG_RANGE_EFFECT, wide)
    lo = np.maximum(np.minimum(config, cal) - LOG_RANGE_EFFECT, np.log(centre) - wide)
    hi = np.minimum(np.maximum(config, cal) + LOG_RANGE_EFFECT, np.log(centre) + wide)
    return dataclasses.replace(fit, anchor=np.exp(np.where(own, 0.5 * (lo + hi), anchor)),
                               log_range=np.where(own, 0.5 * (hi - lo), span))


def with_base_effects(model: PhysicsConfig) -> tuple[PhysicsConfig, tuple[str, ...]]:
    """``model`` with every BASE_EFFECTS effect on (at BASE_START where the CONFIG has it off),
    and the effects it switched on."""
    switched = tuple(n for n in BASE_EFFECTS if model.effects[n] == 0.0)
    for name in switched:
        model = model.with_effect(name, BASE_START[name])
    return model, switched


def fit_reference(model: PhysicsConfig, data: Data, hold: Sequence[str] = (), switched: Sequence[str] = (),
                  held_effects: Sequence[str] = (), linear: Sequence[str] = (),
                  with_companions: Sequence[str] = (), base_companions: Sequence[str] = ()) -> Fit:
    """Reference first: the CALIBRATED constants (wide range, ``base_window``; those in ``hold``
    kept at ``model``'s values) and the strength of every effect the CONFIG switches on, fitted to
    the reference recordings: what the model needs to agree with its own data (structural), before
    the measured data are asked what they need beyond it. The base effects ``with_base_effects``
    ``switched`` on are fitted from two starts (BASE_LOW_START), the better fit kept. Effects in
    ``held_effects`` keep ``model``'s strength (one the recordings state, not fitted); the plant
    constants ``linear`` are fitted too (``calibrate``), and the SWITCH_COMPANIONS of the effects
    ``with_companions`` (``switch_companions``) and the constants ``base_companions`` (log scale,
    within COMPANION_LOG_RANGE of ``model``'s: BASE_COMPANIONS)."""
    on = tuple(n for n in c.EFFECTS if model.effects[n] > 0.0 and n not in held_effects)
    model, linear = switch_companions(model, with_companions, linear,
                                      table={**SWITCH_COMPANIONS, **REFERENCE_COMPANIONS})
    anchors = {n: float(getattr(model.params, n)) for n in base_companions}
    fit = calibrate(model, data, *base_window(model, hold), on, max_nfev=60, linear=linear,
                    companion_anchor=anchors)
    low = {n: v for n, v in BASE_LOW_START.items() if n in switched}
    if low:
        other = model
        for name, v in low.items():
            other = other.with_effect(name, v)
        alt = calibrate(other, data, *base_window(model, hold), on, max_nfev=60, linear=linear,
                        companion_anchor=anchors)
        fit = alt if alt.sse < fit.sse else fit
    return fit


#: A fitted constant (Kv, CP) or a strength the CONFIG sets is implausible when it ends more than this
#: factor above or below the CONFIG's value. A CONFIG names a motor and a propeller: a motor's Kv is
#: specified within ~10 %, a propeller's CP differs by ~20 % between makers of the same size; beyond
#: a factor 2 the fitted value describes another motor or propeller, or, far more often, stands in
#: for an effect the model lacks (on the bundled bags, with every effect off, CP 0.0026 against
#: 0.042). Such a fit is no basis for a verdict when the user GAVE the CONFIG; without one (the
#: package's nominal bench, which stands for a motor and propeller nobody stated: a real 10 in
#: propeller at 16.8 V is far from it) it is flagged all the same, not held against the verdict. The
#: strength of an effect the workflow switches on has no CONFIG value to be measured from (0 = off)
#: and is only checked against its bounds. A fit at a bound is never a basis for a verdict. A
#: constant the user stated through the priors options (``--motor-kv``, ``--prop-diameter-in`` with
#: ``--prop-pitch-in``; ``PhysicsConfig.stated``) is held against the verdict like a CONFIG's.
PLAUSIBLE_FACTOR = 2.0
#: A fit is physical only if its motor, on the recordings' supply at full drive, turns at this share
#: of its no-load speed (Kv x V), whatever motor it is: a loaded propeller motor runs at about
#: 60-90 % of it. Far below, the back-EMF no longer sets the speed and Kv stands in for something
#: the model lacks (Kv 1e6 rpm/V fitted to a bench's reference with an instantaneous rotor: the
#: speed then follows the propeller's load alone); at 1 the propeller does no work.
LOADED_SPEED_RANGE = (0.3, 0.98)


class FitFlagJson(TypedDict):
    """``FitFlag.as_json``: a flag as --json and the discrepancy report carry it."""

    fit: str
    quantity: str
    value: float
    config: float
    low: float
    high: float
    at_bound: bool
    config_given: bool
    basis: str
    not_a_basis_for_a_verdict: bool
    why: str
    text: str


@dataclass(frozen=True)
class FitFlag:
    """A fitted quantity at a bound of its range, or implausibly far (PLAUSIBLE_FACTOR) from the
    CONFIG's (or the stated prior's) value."""

    fit: str  #: which fit ("calibration on the measured data", "reference fit", "rotor_lag fit")
    quantity: str  #: a CALIBRATED constant, or "<effect> strength"
    value: float
    config: float  #: the CONFIG's value (an effect's strength: 0 when the CONFIG has it off)
    low: float  #: the fit's range
    high: float
    at_bound: bool  #: True: at a bound of the range; False: implausibly far from the CONFIG
    stated: bool = True  #: the value was stated (a CONFIG file, or a prior option), not the nominal bench's
    #: what ``config`` is, for people ("CONFIG", "stated (--motor-kv 1900)", ...); None: from ``stated``
    basis: str | None = None
    #: why it is flagged, when it is neither a bound nor the CONFIG's factor (LOADED_SPEED_RANGE)
    reason: str | None = None

    @property
    def label(self) -> str:
        return self.basis or ("CONFIG" if self.stated else "nominal (no CONFIG given)")

    @property
    def blocks(self) -> bool:
        """The fit is no basis for a verdict (see PLAUSIBLE_FACTOR)."""
        return self.at_bound or self.stated

    @property
    def why(self) -> str:
        if self.reason is not None:
            return self.reason
        if self.at_bound:
            return f"at a bound of its range {self.low:.4g}-{self.high:.4g}"
        whose = (f"{'CONFIG' if self.stated else 'nominal bench'}'s" if self.basis is None
                 else f"{self.basis.split(' (')[0]} value")
        return (f"implausible: {self.value / self.config:.2g}x the {whose}, "
                f"outside {1 / PLAUSIBLE_FACTOR:g}-{PLAUSIBLE_FACTOR:g}x; range {self.low:.4g}-{self.high:.4g}")

    def text(self) -> str:
        if self.reason is not None:
            return f"{self.fit}: {self.quantity} {self.value:.3g} ({self.why})"
        return f"{self.fit}: {self.quantity} fitted {self.value:.4g} vs {self.label} {self.config:.4g} ({self.why})"

    def consequence(self) -> str:
        return ("the fit is not a basis for a verdict on it" if self.blocks else
                "another motor or propeller than the one the fit started from, or the constant stands in for a "
                "missing effect: give --physics a CONFIG of the bench, or your motor's --motor-kv, "
                "--prop-diameter-in and --prop-pitch-in, to have it held against the verdicts")

    def as_json(self) -> FitFlagJson:
        return {"fit": self.fit, "quantity": self.quantity, "value": self.value, "config": self.config,
                "low": self.low, "high": self.high, "at_bound": self.at_bound, "config_given": self.stated,
                "basis": self.label, "not_a_basis_for_a_verdict": self.blocks, "why": self.why, "text": self.text()}


def implausible(value: float, config: float) -> bool:
    """``value`` more than PLAUSIBLE_FACTOR from the CONFIG's ``config`` (> 0), either way."""
    return config > 0 and not 1.0 / PLAUSIBLE_FACTOR <= value / config <= PLAUSIBLE_FACTOR


def fit_flags(fit: Fit, config: PhysicsConfig, what: str) -> list[FitFlag]:
    """The quantities of ``fit`` (named ``what``) that ended at a bound of their range or
    implausibly far from ``config`` (the CONFIG as given, or the start from the stated priors):
    Kv and CP, and the fitted strengths; a fitted COMPANION at a bound of its range. A CALIBRATED
    constant's flag is ``stated`` when a CONFIG was given or the user stated it (``PhysicsConfig.basis``)."""
    out = []
    stated = config.source is not None

    def log_range(value: float, a: float, span: float) -> tuple[float, float, bool]:
        """The range a * e^(+-span) and whether ``value`` ended on a bound of it."""
        return a * math.exp(-span), a * math.exp(span), abs(abs(math.log(value / a)) - span) < 1e-3

    for (name, value), a, span in zip(fit.model.constants().items(), fit.anchor, fit.log_range, strict=True):
        if span == 0.0:
            continue  # held, not fitted
        cfg = float(getattr(config.params, name))
        label, given = config.basis(name)
        basis = label if config.stated else None  # the texts of a CONFIG or nominal start stay as they were
        low, high, at_bound = log_range(value, a, span)
        if at_bound:
            out.append(FitFlag(what, name, value, cfg, low, high, True, given, basis))
        elif implausible(value, cfg):
            out.append(FitFlag(what, name, value, cfg, low, high, False, given, basis))
    # (a start from stated priors that is no CONFIG: its other values are a start, not the nominal bench)
    other = "start (not stated)" if config.stated and config.source is None else None
    for name, value in fit.companions().items():
        low, high, at_bound = log_range(value, fit.companion_anchor[name], COMPANION_LOG_RANGE)
        if at_bound:
            out.append(FitFlag(what, name, value, float(getattr(config.params, name)), low, high, True, stated, other))
    for name in fit.linear:  # their low end is "off", physical (as spin-down's 1), not a bound hit
        value, (low, high) = float(getattr(fit.model.params, name)), LINEAR_RANGES[name]
        if value >= high - 1e-3 and name not in LINEAR_OPEN_ABOVE:
            out.append(FitFlag(what, name, value, float(getattr(config.params, name)), low, high, True, stated, other))
    loaded = loaded_speed_flag(fit.model, what)
    if loaded is not None:
        out.append(loaded)
    for name in fit.free:
        value, cfg = fit.model.effects[name], config.effects[name]
        if strength_at_bound(name, value):
            out.append(FitFlag(what, f"{name} strength", value, cfg, 0.0, STRENGTH_MAX[name], True, stated, other))
        elif implausible(value, cfg):
            out.append(FitFlag(what, f"{name} strength", value, cfg, 0.0, STRENGTH_MAX[name], False, stated, other))
    return out


def loaded_speed_share(model: PhysicsConfig) -> float | None:
    """The model's full-drive speed on its supply as a share of its no-load speed Kv x V (the
    winding cold); None before ``with_supply``."""
    if model.supply_v is None:
        return None
    cold, _ = full_drive_speeds(model.params, model.effects, model.supply_v)
    return float(cold / (model.params.motor_kv_rpm_per_v / c.RAD_S_TO_RPM * model.supply_v))


def loaded_speed_flag(model: PhysicsConfig, what: str) -> FitFlag | None:
    """A FitFlag (never a basis for a verdict) when ``model``'s motor is not physical by
    LOADED_SPEED_RANGE."""
    share = loaded_speed_share(model)
    lo, hi = LOADED_SPEED_RANGE
    if share is None or lo <= share <= hi:
        return None
    return FitFlag(what, "full-drive speed / no-load speed (Kv x V)", share, float("nan"), lo, hi, False, True,
                   "physical range", reason=f"not physical: a loaded motor runs at {lo:g}-{hi:g} of it; Kv "
                   f"{model.params.motor_kv_rpm_per_v:.4g} rpm/V stands in for something the model lacks")


def strength_at_bound(name: str, strength: float) -> str | None:
    """'<name> strength s at its bound' when a fitted strength ended on 0 or STRENGTH_MAX (spin-down's
    1 is physical, not a bound of the fit)."""
    top = STRENGTH_MAX[name]
    if (strength <= 1e-3 and name not in BASE_EFFECTS) or (strength >= top - 1e-3 and name not in PHYSICAL_MAX):
        return f"{name} strength {strength:.3g} at its bound ({'0' if strength <= 1e-3 else f'{top:g}'})"
    return None


def recalibrate(fit: Fit, model: PhysicsConfig, data: Data, free: Sequence[str] | None = None) -> Fit:
    """``calibrate`` with ``fit``'s anchor and range (and free strengths unless given) and its linear
    constants."""
    return calibrate(model, data, fit.anchor, fit.log_range, fit.free if free is None else free,
                     companion_anchor=fit.companion_anchor, linear=fit.linear)


def recalibrate_with(fit: Fit, model: PhysicsConfig, data: Data, names: Sequence[str],
                     free: Sequence[str] | None = None, companions_from: PhysicsConfig | None = None) -> Fit:
    """``recalibrate`` with the effects ``names`` switched on in ``model``, their SWITCH_COMPANIONS
    fitted along (``switch_companions``)."""
    model, linear = switch_companions(model, names, fit.linear, companions_from)
    return calibrate(model, data, fit.anchor, fit.log_range, fit.free if free is None else free,
                     companion_anchor=fit.companion_anchor, linear=linear)


def switch_companions(model: PhysicsConfig, names: Sequence[str], linear: Sequence[str] = (),
                      companions_from: PhysicsConfig | None = None,
                      table: Mapping[str, tuple[str, ...]] = SWITCH_COMPANIONS,
                      ) -> tuple[PhysicsConfig, tuple[str, ...]]:
    """(``model``, linear constants) for ``calibrate`` with the companions (``table``:
    SWITCH_COMPANIONS) of the effects ``names`` added to ``linear``: those not there yet start from
    ``companions_from``'s values (a fit of the same bench on other recordings) or, without it,
    SWITCH_START."""
    lin = list(linear)
    values: dict[str, Any] = {}  # (untyped: see calibrate)
    for n in (n for name in names for n in table.get(name, ())):
        if n not in lin:
            lin.append(n)
            values[n] = float(getattr(companions_from.params, n)) if companions_from else SWITCH_START[n]
    if values:
        model = dataclasses.replace(model, params=dataclasses.replace(model.params, **values))
    return model, tuple(lin)
