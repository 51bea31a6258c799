"""A physics model from recordings: the plant's constants and effect strengths fitted by least
squares on the training recordings (``physics.fit.fit_reference``, the calibration the discrepancy
workflow runs too), the candidate the validation recordings prefer kept (``prefer``). Where a training
recording carries its motor's supply current (a thrust stand's log), the fit compares that too
(``SpeedAndCurrent``): the speed alone does not determine Kv.

Why least squares on the plant instead of a network: the plant carries the rotor's inertia, the
ESC's dead time and start level and the battery's sag as physics, so a handful of constants
(Kv, CP, six effect strengths) fitted on staircases and ramps extrapolate to commands and pack
charges the training never saw, where a static network interpolates only.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import TypedDict, cast

import numpy as np

from .. import __version__
from .. import contract as c
from ..errors import BadInputError
from ..model import HybridModel, NetworkModel
from ..physics import fit as pf
from ..physics.config import (
    CALIBRATED,
    PhysicsConfig,
    Recorded,
    median_voltage,
    start_model,
    supply_tau_s,
)
from ..physics.plant_model import PlantModel
from ..physics.sizing import physics_start
from ..priors import MotorPriors
from ..recordings import MIN_SAMPLES, Signals
from .band import band_metadata
from .evaluate import predict_speed
from .train import ThrustFit, TrainOutcome, _source, fit_thrust_coefficient, train_model

#: The throttle map held straight (the CONFIG's exponent) in one of each ESC's two fits: with
#: every effect's strength free as well, the exponent and Kv can trade against each other
#: (nominal bench recordings: Kv 834 rpm/V for the true 710), but an ESC whose map bends
#: (half the randomized benches) is misfitted straight (tuning bench 101, coasting: chirp 5.68 %
#: straight, 2.03 % bent). The validation recordings choose, as they choose the braking.
STRAIGHT_MAP = ("esc_throttle_exponent",)
#: Held in every training fit: the pack's series resistance (``physics.config.CALIBRATED``, which the
#: discrepancy workflow calibrates on a reference). Here battery_voltage's strength is fitted too,
#: and it scales the same term (the drop the battery filter has not passed, s R_s (i - lowpass(i))):
#: with both free, the nominal bench's validation RMSE went from 0.54 to 1.31 rad/s.
HELD = ("battery_series_resistance_ohm",)
#: A training recording's supply current (a stand's, or an ESC's telemetry of one motor) is compared
#: with the plant's (duty x motor current) on the rows where the command has been held this long (s).
#: Why the current at all: from speed, command and voltage alone Kv is not determined once the
#: throttle map's exponent is free (esc_test F80 log, split in three: Kv correlated 0.99 with the
#: exponent and CP in the LM Jacobian, training RMSE within 1.7 rad/s from 1462 to 2470 rpm/V), and
#: the fit sent it to a bound of its range; the supply current ties the drive to the motor's current
#: (an ESC draws duty x the motor current), which scales differently with Kv and the map (Kv then
#: 1962-2053 rpm/V on the three splits, rated 1900; 1642-1751 on the esc_test F40, rated 1600, where
#: the speed alone ended at the bound on two splits of three). Why settled rows only: a stand's current channel
#: is low-passed (same log: after a 1300 -> 1350 us step the speed settles within 0.1 s, the current
#: ~0.5 s later and without the rotor's acceleration current), so its transients would say the rotor
#: has no inertia (rotor_lag fitted 0 when every row counted).
CURRENT_SETTLED_S = 1.0
#: Held at strength 1 wherever the recordings say what the ESC is fed (``supply_held``): the ESC runs
#: on the voltage measured, so nothing is left to fit. Fitted, the strength scales the supply's
#: variation, and stands in for what else moves slowly or with the command:
#: - a voltage filtered from the battery ADC (``config.supply_tau_s`` > 0): on a 90 s flight the
#:   pack's run-down and a winding warming both slow the rotor, so the two trade. Randomized bench
#:   809 fitted the strength at 1.8e-6 (its bound) with motor_heating at 3.6x; the model then ignored
#:   the voltage, and the health monitor alarmed six times in 3.7 h of healthy flight as the pack ran
#:   down. Held at 1: on benches 808-811, 1 false alarm in 3.7 h instead of 7, none before a fault's
#:   onset instead of 2 (on 800-803, 2 and none). The pack's series resistance (HELD) stays held:
#:   fitted in its place, it traded with heating the same way (800-803: 5 false alarms, 4 before an
#:   onset);
#: - a recorded voltage with the supply current fitted: the strength scales the supply's sag, which on
#:   a staircase follows the command, and so stands in for losses the physics lacks (F80 splits: 0,
#:   0.54 and 1.31).
#: Not held for a recorded voltage without the current: the strength is then what absorbs those losses,
#: and held at 1 the F80 fits ended with Kv at a bound of its range on every split.
SUPPLY_HELD = ("battery_voltage",)


def supply_held(tau_s: float, with_current: bool) -> tuple[str, ...]:
    """The effects held at strength 1 in a training fit (SUPPLY_HELD): with a voltage filtered from the
    battery ADC (``tau_s`` > 0), or a recorded one with the supply current fitted; none otherwise."""
    return SUPPLY_HELD if tau_s > 0.0 or with_current else ()


#: The throttle map's origin below the ESC's start threshold (``plant.map_origin``), freed in one more
#: fit, from the better straight one, where the data can identify it: the supply current is fitted (an
#: ESC draws duty x the motor current, so the current at held levels shows the duty there, which the
#: speed alone trades with Kv, the exponent and CP) and the holds place the threshold
#: (``start_threshold``, on the training and validation recordings: a rotor at rest at a level is the
#: ESC's, as its braking is). Why: the esc_test F80's BLHeli_32 ESC drives a duty linear in the command
#: from ~990 us, yet its rotor does not run at 1100 us. From the straight map only: the origin and the
#: exponent both set the duty at low levels and trade when freed together (F80 split 0, training holds
#: all at or above 1300 us: origin 1073 us with x**0.87, or 1003 us straight; at 1150-1250 us the first
#: misses the held-out speed by -74 to -33 rad/s, the second by +29 to +8). Offered to the validation
#: recordings (which choose, as for the straight map) only when it fits the training recordings at
#: least as well as every fit without it: its threshold is placed by the holds, not by the least
#: squares, and the validation part of a staircase split in time may hold only the levels around it
#: (F80 split 1: preferred for its 1100 us hold, 25.4 vs 66.7 rad/s, while it fitted the training
#: recordings worse, 39.9 vs 35.5 rad/s, and the held-out part too, 33.9 vs 24.4 rad/s).
ORIGIN_FREE = ("esc_map_origin_share",)
#: Its fit starts from the map starting at PWM_STOP (the threshold only cuts the drive off below it).
ORIGIN_START_SHARE = 1.0
#: ``start_threshold``: a hold counts when the command was held this long (s); the rotor's speed at
#: its end is the median over its last HOLD_END_S.
THRESHOLD_HOLD_S = 1.0
HOLD_END_S = 0.5
#: ... and the rotor is at rest there below this share of the fastest hold's speed: the F80's rotor
#: at 1100 us reads 0-2000 rpm (the ESC's start attempts, ~0.15 A; its optical speed 0), its first
#: running hold (1150 us) 22 % of the top speed.
REST_SHARE = 0.1
#: The threshold is placed this far (PWM level, 0.02 us of pulse) above the highest level at rest:
#: the lowest start consistent with the holds (an ESC starts the motor as soon as it can; nothing in
#: the holds says how far above that level it starts).
THRESHOLD_MARGIN = 1e-6


class CandidateJson(TypedDict):
    """One training fit as the model's metadata and ``train --json`` record it."""

    fit: str  #: which ESC behaviour and throttle map
    extends: str | None  #: the fit it started from with one more constant freed (``prefer``), or None
    constants: dict[str, float]
    effects: dict[str, float]
    at_bound: list[str]
    fit_flags: list[pf.FitFlagJson]
    refused: list[str]
    train_rmse_rad_s: float
    validation_rmse_rad_s: float
    train_current_rmse_a: float | None  #: the supply current's on the settled rows, where it was fitted


class _Candidate(CandidateJson):
    """A fit with its model and flags (not JSON: dropped from the record)."""

    model: PlantModel
    flags: list[pf.FitFlag]


@dataclass
class PhysicsOutcome:
    model: PlantModel
    train: list[Signals]
    validation: list[Signals]
    thrust: ThrustFit
    train_rmse_rad_s: float
    validation_rmse_rad_s: float
    candidates: list[CandidateJson]  #: every fit tried, with its figures; the kept one first
    #: one line each: the start point's (nominal bench, a CONFIG over stated priors) and every flag
    #: of the kept fit (``physics.fit.fit_flags``) that did not refuse it
    warnings: list[str] = dataclasses.field(default_factory=list)


def rmse(model: PlantModel, signals: Sequence[Signals]) -> float:
    """Speed RMSE (rad/s) of ``model`` on ``signals``, as ``evaluate`` computes it."""
    err = np.concatenate([predict_speed(model, s) - s.speed for s in signals])
    err = err[np.isfinite(err)]
    return float(np.sqrt(np.mean(err**2))) if len(err) else float("nan")


def own_supply_current(s: Signals) -> bool:
    """The recording carries its motor's own supply current: a current and no namespace (a bench:
    one motor on the supply). A vehicle's battery current feeds every motor, so it is no one
    motor's."""
    return s.current is not None and s.namespace is None


def settled_rows(s: Signals, settled_s: float = CURRENT_SETTLED_S) -> np.ndarray:
    """Indices of the grid rows of ``s`` with a finite current where the command has not changed
    for at least ``settled_s`` (the events' level, from the first event on)."""
    if s.current is None or len(s.pwm_events[0]) == 0:
        return np.zeros(0, dtype=int)
    t_ev, level = (np.asarray(a, dtype=float) for a in s.pwm_events)
    changes = t_ev[np.r_[True, np.diff(level) != 0.0]]
    k = np.searchsorted(changes, s.t, side="right") - 1
    since = np.where(k >= 0, s.t - changes[np.maximum(k, 0)], -np.inf)
    return np.flatnonzero((since >= settled_s) & np.isfinite(s.current))


@dataclass
class SpeedAndCurrent(pf.Data):
    """Training data whose residual is the speed's and, on ``current_rows``, the supply current's
    (measured - plant), the latter times ``current_weight`` (rad/s per A: the measured speed's
    range over the measured current's, so 1 % of either range weighs alike)."""

    current_rows: list[np.ndarray] = dataclasses.field(default_factory=list)
    current_weight: float = 0.0

    @classmethod
    def with_current(cls, signals: Sequence[Signals]) -> SpeedAndCurrent | None:
        """The data of ``signals`` with the settled supply current of those that carry their own
        (``own_supply_current``); None when none does, or on fewer than MIN_SAMPLES rows, or
        when the speed or the current does not vary."""
        base = pf.Data.of(signals)
        current_rows = [settled_rows(s) if own_supply_current(s) else np.zeros(0, dtype=int) for s in signals]
        if sum(map(len, current_rows)) < MIN_SAMPLES:
            return None
        speed = np.concatenate([s.speed[r] for s, r in zip(signals, base.rows, strict=True)])
        current = np.concatenate([s.current[r] for s, r in zip(signals, current_rows, strict=True)
                                  if s.current is not None])
        span_w, span_i = float(np.ptp(speed)) if len(speed) else 0.0, float(np.ptp(current))
        if not (span_w > 0.0 and span_i > 0.0):
            return None
        return cls(base.signals, base.rows, current_rows, span_w / span_i)

    def residual(self, model: PhysicsConfig) -> np.ndarray:
        parts = []
        current_rows = self.current_rows or [np.zeros(0, dtype=int)] * len(self.signals)  # (made by ``of``)
        for s, rows, crows in zip(self.signals, self.rows, current_rows, strict=True):
            if len(crows):
                speed, current = model.predict_with_current(s)
                parts += [s.speed[rows] - speed[rows], self.current_weight * (_current(s)[crows] - current[crows])]
            else:
                parts.append(s.speed[rows] - model.predict(s)[rows])
        return np.concatenate(parts)

    def users(self) -> list[str]:
        """The recordings whose current is compared."""
        return [s.path for s, r in zip(self.signals, self.current_rows, strict=True) if len(r)]

    def summary(self, held: Sequence[str]) -> str:
        """One progress line: whose current, how many rows, what is held for it."""
        return (f"fitting the supply current of {len(self.users())} recording(s) too "
                f"({sum(map(len, self.current_rows))} rows {CURRENT_SETTLED_S:g} s after a command change)"
                + "".join(f"; {n} held at 1 (the supply recorded)" for n in held))

    def as_metadata(self, held: Sequence[str]) -> dict[str, object]:
        """What the model's metadata records of the current in its fit."""
        return {"recordings": self.users(), "rows": int(sum(map(len, self.current_rows))),
                "settled_s": CURRENT_SETTLED_S, "weight_rad_s_per_a": self.current_weight,
                "held_effects": list(held)}

    def current_rmse(self, model: PhysicsConfig) -> float:
        """RMSE (A) of the plant's supply current on the settled rows."""
        err = [_current(s)[r] - model.predict_with_current(s)[1][r]
               for s, r in zip(self.signals, self.current_rows, strict=True) if len(r)]
        return float(np.sqrt(np.mean(np.concatenate(err) ** 2)))


def start_threshold(signals: Sequence[Signals]) -> float | None:
    """The ESC's start threshold (PWM level) the recordings' holds place: just above (THRESHOLD_MARGIN)
    the highest level above PWM_STOP held THRESHOLD_HOLD_S at which the rotor is at rest (REST_SHARE),
    provided every hold above it runs and one does; None when no hold rests above PWM_STOP, none runs
    above the highest that rests, or one runs at or below it (a threshold the holds contradict)."""
    rows = []
    for s in signals:
        if len(s.pwm_events[0]) == 0:
            continue
        t_ev, level = (np.asarray(a, dtype=float) for a in s.pwm_events)
        first = np.r_[0, np.flatnonzero(np.diff(level) != 0.0) + 1]
        starts, levels = t_ev[first], level[first]
        ends = np.r_[starts[1:], s.t[-1]]
        for t0, t1, lv in zip(starts, ends, levels, strict=True):
            end = (s.t >= t1 - HOLD_END_S) & (s.t <= t1) & np.isfinite(s.speed)
            if t1 - t0 >= THRESHOLD_HOLD_S and end.sum() >= 3:
                rows.append((float(lv), float(np.median(s.speed[end]))))
    if not rows:
        return None
    lv, w = np.array(rows).T
    rest = w < REST_SHARE * float(np.max(w))
    above = rest & (lv > c.PWM_STOP)
    if not above.any():
        return None
    top_rest = float(np.max(lv[above]))
    running = lv[~rest]
    if not len(running) or np.min(running) <= top_rest:
        return None
    return top_rest + THRESHOLD_MARGIN


def _current(s: Recorded) -> np.ndarray:
    """The measured supply current of a recording ``SpeedAndCurrent`` compares (it has one)."""
    current = getattr(s, "current", None)
    assert current is not None, "only recordings with a current have settled rows"
    return np.asarray(current)


def _plant_model(m: PhysicsConfig, tau_s: float) -> PlantModel:
    assert m.supply_v is not None, "a fit on recordings has their supply (with_supply)"
    return PlantModel(m.params, m.effects, m.supply_v, supply_tau_s=tau_s)


def train_physics(
    train: Sequence[Signals],
    validation: Sequence[Signals],
    *,
    thrust_coefficient: ThrustFit | float | None,
    priors: MotorPriors | None = None,
    config: str | None = None,
    progress: Callable[[str], None] | None = None,
) -> PhysicsOutcome:
    """Fit the plant to ``train`` (Kv, CP and every effect's strength, least squares) from the
    user's motor (``physics.config.start_model``: the stated ``priors`` under a ``config`` file, which wins
    where both are given; neither: the simulator's nominal bench, with a warning) for two ESCs,
    each with its throttle map held straight and then with its exponent
    fitted too (from the straight fit), and keep the one ``validation`` prefers: an ESC that
    brakes actively (spin_down_asymmetry 0, held: BLHeli's default) and one that lets the rotor
    coast (its strength fitted from 1). Staircases and ramps rarely show how the rotor slows
    down after a large step, or tell a bent map from Kv, so the training data alone cannot
    choose; random steps do. The supply is the recordings' filtered battery voltage (the stiff
    supply of battery_voltage strength 0: their median). Training recordings that carry their
    motor's supply current add it to the least squares where the command has settled
    (``SpeedAndCurrent``, CURRENT_SETTLED_S); with it, a fifth fit may free the throttle map's
    origin below the ESC's start threshold (ORIGIN_FREE). battery_voltage's strength is held at 1
    wherever the recordings say what the ESC is fed (``supply_held``: a voltage filtered from the
    battery ADC, or a recorded one with the current).

    The kept fit is checked (``physics.fit.fit_flags``): a fit whose Kv or CP ended at a bound of its
    range or implausibly far from a value the user stated (a prior, or the CONFIG) is no model of
    that motor: among the fits, one without such a flag is kept, and when every one has it the
    training is refused (BadInputError naming the constant, its value, the range and the stated
    value). Other flags (constants or strengths at a bound, Kv or CP far from a start nobody
    stated) are warnings (``PhysicsOutcome.warnings``)."""
    if not train or not validation:
        raise BadInputError("training needs at least one training and one validation recording")
    say = progress or (lambda text: None)
    taus = {supply_tau_s(s) for s in [*train, *validation]}
    if len(taus) > 1:
        raise BadInputError(f"{train[0].path}: the recordings' battery voltages come from different sources "
                            "(filtered from battery/adc and recorded): a physics model takes one kind")
    tau = taus.pop()
    base, notes, warnings = start_model(config, priors, median_voltage(train), option="--physics-config")
    for line in notes:
        say(f"start: {line}")
    current = SpeedAndCurrent.with_current(train)
    held = supply_held(tau, current is not None)
    if current is not None:
        say(current.summary(held))
    t0 = time.perf_counter()
    candidates = _candidate_fits(base, current or pf.Data.of(train), train, validation, tau, say, held)
    candidates = prefer(candidates)
    best = candidates[0]
    if best["refused"]:
        f = next(f for f in best["flags"] if refuses(f, base.stated))
        # a flag on what the user stated names it; an unstated CP refuses only beside a stated Kv
        who = (base.stated.get(f.quantity) or (f"--physics-config {config}" if f.stated
                                               else base.stated["motor_kv_rpm_per_v"]))
        raise BadInputError(f"{who}: the training recordings do not support it, so no model is written: {f.text()}; "
                            f"all {len(candidates)} fits contradict it (a wrong rating or propeller, or an effect "
                            "the physics lacks)")
    warnings += [f.text() for f in best["flags"]]
    warnings += held_unstated(best["model"], base, tau, priors)
    thrust = fit_thrust_coefficient(train, thrust_coefficient)
    band = band_metadata([predict_speed(best["model"], s) for s in validation], validation)
    model = dataclasses.replace(best["model"], thrust_coefficient=thrust.coefficient, metadata={
        "package_version": __version__,
        "sources": {"train": [_source(s) for s in train], "validation": [_source(s) for s in validation]},
        "fit": best["fit"],
        "start": {"config": config, "stated": dict(base.stated), "notes": notes,
                  "ranges": {n: list(r) for n, r in base.ranges.items()}},
        "warnings": list(warnings),
        "candidates": [{k: v for k, v in d.items() if k not in ("model", "flags")} for d in candidates],
        "training_seconds": time.perf_counter() - t0,
        "supply_current": None if current is None else current.as_metadata(held),
        "thrust_fit": thrust.as_metadata(),  # with the assumption of a b derived from stated numbers
        **band,  # the speed's one-sigma band, from the validation residuals
    })
    return PhysicsOutcome(model, list(train), list(validation), thrust, best["train_rmse_rad_s"],
                          best["validation_rmse_rad_s"],
                          cast("list[CandidateJson]", [{k: v for k, v in d.items() if k not in ("model", "flags")}
                                                       for d in candidates]), warnings)


#: A fit that frees one more constant than the fit it started from (the throttle map's exponent, its
#: origin) is kept only when the validation recordings prefer it by at least this share of the other's
#: RMSE: where they cannot tell the two apart, the model does not claim a shape the data do not show
#: (the nominal bench's straight map came back "bent" at exponent 1.0001 for 0.04 % less validation
#: error).
EXTENSION_MARGIN = 0.01


def prefer(candidates: Sequence[_Candidate]) -> list[_Candidate]:
    """``candidates`` in the order of preference, the kept fit first: by validation RMSE, a fit that
    is no model of the stated motor behind every one that is (kept only when every fit is one:
    then refused), and a fit that extends another (``extends``) behind it unless it validates
    EXTENSION_MARGIN better."""
    order = sorted(candidates, key=lambda d: (bool(d["refused"]), d["validation_rmse_rad_s"]))
    by_name = {d["fit"]: d for d in order}
    best = order[0]
    while best["extends"] is not None:
        base = by_name[best["extends"]]
        if bool(base["refused"]) > bool(best["refused"]) or \
                best["validation_rmse_rad_s"] < (1.0 - EXTENSION_MARGIN) * base["validation_rmse_rad_s"]:
            break
        best = base
    return [best, *(d for d in order if d is not best)]


def _candidate_fits(base: PhysicsConfig, data: pf.Data, train: Sequence[Signals], validation: Sequence[Signals],
                    tau: float, say: Callable[[str], None], held: Sequence[str] = ()) -> list[_Candidate]:
    """``train_physics``'s fits from ``base``: for each ESC (braking actively, letting the rotor
    coast) the throttle map held straight, then bent from the straight fit; and, where the data
    identify it (ORIGIN_FREE), the better straight fit by validation with the map's origin freed
    below the start threshold the holds place. Each as its JSON metadata record, plus its model and
    flags (``data``: ``train`` as the fit reads it; ``held``: effects whose strength stays at 1)."""
    candidates: list[_Candidate] = []
    fits: list[tuple[pf.Fit, PhysicsConfig, tuple[str, ...]]] = []  #: per candidate: fit, its start, hold

    def record(name: str, fit: pf.Fit, start: PhysicsConfig, extends: str | None = None) -> None:
        m = _plant_model(fit.model, tau)
        flags = training_flags(fit, start)
        constants = {**fit.model.constants(), **{n: float(getattr(fit.model.params, n)) for n in fit.linear}}
        candidates.append({"fit": name, "extends": extends, "constants": constants, "effects": dict(fit.model.effects),
                           "at_bound": [f.text() for f in flags if f.at_bound],
                           "fit_flags": [f.as_json() for f in flags],
                           "refused": [f.text() for f in flags if refuses(f, start.stated)],
                           "train_rmse_rad_s": rmse(m, train),
                           "validation_rmse_rad_s": rmse(m, validation),
                           "train_current_rmse_a": (data.current_rmse(fit.model)
                                                    if isinstance(data, SpeedAndCurrent) else None),
                           "model": m, "flags": flags})
        say(f"  RMSE training {candidates[-1]['train_rmse_rad_s']:.2f} rad/s, "
            f"validation {candidates[-1]['validation_rmse_rad_s']:.2f} rad/s"
            + "".join(f"; {f.quantity} {f.why}" for f in flags if refuses(f, start.stated)))

    for esc, braking_removed in (("ESC braking actively", 0.0), ("ESC letting the rotor coast", 1.0)):
        effects = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": braking_removed}
        start = dataclasses.replace(base, effects=effects).with_supply(train)
        init, extends = start, None  # the bent map starts from the straight fit
        shapes: tuple[tuple[str, tuple[str, ...]], ...] = ((f"{esc}, throttle map straight", (*STRAIGHT_MAP, *HELD)),
                                                           (f"{esc}, throttle map bent", HELD))
        for name, hold in shapes:
            say(f"fitting Kv, CP and the effects' strengths, {name}")
            fit = pf.fit_reference(init, data, hold=hold, held_effects=held)
            init = fit.model
            fits.append((fit, start, hold))
            record(name, fit, start, extends)
            extends = name
    # the holds of every recording: where a rotor rests is the ESC's, as its braking is, and a
    # staircase's low end may be in the validation part only (esc_test F80, split 0)
    threshold = start_threshold([*train, *validation]) if isinstance(data, SpeedAndCurrent) else None
    if threshold is not None and base.params.esc_deadband_pwm > 0.0:
        j = min((k for k, (_, _, hold) in enumerate(fits) if STRAIGHT_MAP[0] in hold),
                key=lambda k: (bool(candidates[k]["refused"]), candidates[k]["validation_rmse_rad_s"]))
        fit, start, hold = fits[j]
        strength = (threshold - c.PWM_STOP) / base.params.esc_deadband_pwm
        if strength <= pf.STRENGTH_MAX["esc_deadband"]:
            name = f"{candidates[j]['fit']}, map from below the start threshold (PWM {threshold:.4f}, from the holds)"
            say(f"fitting Kv, CP, the effects' strengths and the map's origin, {name}")
            init = fit.model.with_effect("esc_deadband", strength)
            init = dataclasses.replace(init, params=dataclasses.replace(init.params,
                                                                        esc_map_origin_share=ORIGIN_START_SHARE))
            record(name, pf.fit_reference(init, data, hold=hold, held_effects=(*held, "esc_deadband"),
                                          linear=ORIGIN_FREE), start, candidates[j]["fit"])
            best_train = min(d["train_rmse_rad_s"] for d in candidates[:-1])
            if not candidates[-1]["train_rmse_rad_s"] <= best_train:
                say(f"  not offered to the validation: it fits the training recordings worse than a fit without "
                    f"it ({candidates[-1]['train_rmse_rad_s']:.2f} vs {best_train:.2f} rad/s)")
                candidates.pop()
    return candidates


def held_unstated(model: PlantModel, start: PhysicsConfig, tau_s: float, priors: MotorPriors | None) -> list[str]:
    """A warning line when the pack's series resistance, HELD in every fit, is not one the
    ``start``'s CONFIG states: its value is then the simulator's bench's (resized to the stated
    motor when ``priors`` size one), not the user's.
    Only where it acts (``tau_s`` > 0): with a voltage filtered from the battery ADC it sets the
    sag the filter has not yet passed after a current step (the model undoes the filter with it).
    Randomized benches 300-303: true 0.019-0.041 ohm against the 0.035 held; with the pack's
    resistance doubled in flight, the model holding 2x 0.035 came back to the healthy flight's
    RMSE on two of them (2.09 -> 0.63 rad/s against 0.63; 5.32 -> 2.06 against 1.79)."""
    name = "battery_series_resistance_ohm"
    if tau_s <= 0.0 or name not in HELD or name in start.listed:
        return []
    sized = priors is not None and physics_start(priors) is not None
    whose = "the simulator's 12 in bench's, resized to the stated motor" if sized else "the simulator's 12 in bench's"
    return [f"{name} held at {getattr(model.params, name):.4g} ({whose}), not fitted: it trades with the supply's "
            "strength and the winding's heating; it sets the sag the battery filter has not yet passed after a "
            "current step; state your pack's in a --physics-config CONFIG"]


#: The constants whose flag against a stated value refuses a training fit: what the priors state.
REFUSING = ("motor_kv_rpm_per_v", "propeller_cp")


def training_flags(fit: pf.Fit, start: PhysicsConfig) -> list[pf.FitFlag]:
    """``physics.fit.fit_flags`` of a training fit: CALIBRATED constants at a bound or implausible,
    strengths and companions at a bound only (every strength starts at 1 here, a start of the
    procedure, not a value anybody stated). The coasting ESC's spin-down strength at 0 is no bound
    hit: it is the braking ESC (a physical end, as 1 is), which the other candidates fit as such."""
    return [f for f in pf.fit_flags(fit, start, "training fit")
            if (f.at_bound or f.quantity in CALIBRATED) and not (f.quantity == "spin_down_asymmetry strength"
                                                                     and f.value <= 1e-3)]


def refuses(flag: pf.FitFlag, stated: Mapping[str, str]) -> bool:
    """The flag makes the fit no model of the stated motor: Kv or CP at a bound of its range or
    implausibly far from a value the user stated (a prior or the CONFIG, ``stated``: the
    constants a prior option gave); or, with Kv stated, CP at a bound or implausible from any
    start: CP is then what absorbs a wrong Kv (the 710 kv bench trained as a 2000 kv motor: Kv
    1552 at the edge of the stated range with CP 22x its start)."""
    kv_held = "motor_kv_rpm_per_v" in stated
    return flag.quantity in REFUSING and (flag.stated or (kv_held and flag.quantity == "propeller_cp"))


def residual_signals(model: PlantModel, signals: Sequence[Signals]) -> list[Signals]:
    """The recordings with the speed replaced by what ``model`` gets wrong (measured - physics):
    the target of a hybrid's network."""
    return [dataclasses.replace(s, speed=s.speed - predict_speed(model, s)) for s in signals]


def train_hybrid(
    physics: PhysicsOutcome,
    *,
    inputs: Sequence[str] = c.DEFAULT_INPUTS,
    hidden: int = c.PAPER_HIDDEN,
    seed: int = 0,
    restarts: int = 1,
    max_epochs: int = 1000,
    patience: int = 6,
    progress: Callable[[int, float, float, float], None] | None = None,
) -> TrainOutcome:
    """A hybrid on top of a fitted physics model: a network (inputs ``physics_speed`` and
    ``inputs``) trained on what the physics gets wrong on the same recordings, starting from a
    zero output (the physics alone) so early stopping keeps a correction only where it helps on
    validation. One function for ``train --kind hybrid`` and the accuracy benchmark, which
    reuses one physics fit for both kinds. The outcome's RMSEs are the hybrid's on the speed."""
    plant = physics.model
    names = [c.INPUT_PHYSICS_SPEED, *inputs]
    outcome = train_model(
        residual_signals(plant, physics.train), residual_signals(plant, physics.validation),
        inputs=names, hidden=hidden, seed=seed, thrust_coefficient=plant.thrust_coefficient,
        max_epochs=max_epochs, patience=patience, progress=progress, restarts=restarts,
        feature_params=plant.feature_params(), start_at_zero=True, band=False,
    )
    network = outcome.model
    assert isinstance(network, NetworkModel), "train_model trains a network"
    meta = network.metadata  # the physics part's parameters live in its own arrays; b was
    meta["feature_params"].pop(c.INPUT_PHYSICS_SPEED, None)  # fitted on the speed, not its residual
    meta["physics"] = plant.metadata
    meta["thrust_fit"] = plant.metadata["thrust_fit"]
    network.thrust_coefficient = plant.thrust_coefficient
    hybrid = HybridModel(plant, network)  # its band: of the hybrid's speed, not of the correction's
    meta.update(band_metadata([predict_speed(hybrid, s) for s in physics.validation], physics.validation))
    return dataclasses.replace(outcome, model=hybrid, train=physics.train,
                               validation=physics.validation, thrust=physics.thrust)
