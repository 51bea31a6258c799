"""A physics model from recordings: the plant's constants and effect strengths fitted by least
squares on the training recordings (``physics.fit.fit_reference``, the calibration the discrepancy
workflow runs too), the candidate with the least validation error kept.

Why least squares on the plant instead of a network: the plant carries the rotor's inertia, the
ESC's dead time and start level and the battery's sag as physics, so a handful of constants
(Kv, CP, six effect strengths) fitted on staircases and ramps extrapolate to commands and pack
charges the training never saw, where a static network interpolates only.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import TypedDict, cast

import numpy as np

from .. import __version__
from .. import contract as c
from ..errors import BadInputError
from ..model import HybridModel, NetworkModel
from ..physics import fit as pf
from ..physics.config import CALIBRATED, PhysicsConfig, median_voltage, start_model, supply_tau_s
from ..physics.plant_model import PlantModel
from ..priors import MotorPriors
from ..recordings import Signals
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


class CandidateJson(TypedDict):
    """One training fit as the model's metadata and ``train --json`` record it."""

    fit: str  #: which ESC behaviour and throttle map
    constants: dict[str, float]
    effects: dict[str, float]
    at_bound: list[str]
    fit_flags: list[pf.FitFlagJson]
    refused: list[str]
    train_rmse_rad_s: float
    validation_rmse_rad_s: float


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
    supply of battery_voltage strength 0: their median).

    The kept fit is checked (``physics.fit.fit_flags``): a fit whose Kv or CP ended at a bound of its
    range or implausibly far from a value the user stated (a prior, or the CONFIG) is no model of
    that motor: among the four, one without such a flag is kept, and when every one has it the
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
    data = pf.Data.of(train)
    t0 = time.perf_counter()
    candidates = _candidate_fits(base, data, train, validation, tau, say)
    # a fit that is no model of the stated motor is kept only when every fit is one: then refused
    candidates.sort(key=lambda d: (bool(d["refused"]), d["validation_rmse_rad_s"]))
    best = candidates[0]
    if best["refused"]:
        f = next(f for f in best["flags"] if refuses(f))
        who = base.stated.get(f.quantity) or f"--physics-config {config}"
        raise BadInputError(f"{who}: the training recordings do not support it, so no model is written: {f.text()}; "
                            f"all {len(candidates)} fits contradict it (a wrong rating or propeller, or an effect "
                            "the physics lacks)")
    warnings += [f.text() for f in best["flags"]]
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
        "thrust_fit": thrust.as_metadata(),  # with the assumption of a b derived from stated numbers
        **band,  # the speed's one-sigma band, from the validation residuals
    })
    return PhysicsOutcome(model, list(train), list(validation), thrust, best["train_rmse_rad_s"],
                          best["validation_rmse_rad_s"],
                          cast("list[CandidateJson]", [{k: v for k, v in d.items() if k not in ("model", "flags")}
                                                       for d in candidates]), warnings)


def _candidate_fits(base: PhysicsConfig, data: pf.Data, train: Sequence[Signals], validation: Sequence[Signals],
                    tau: float, say: Callable[[str], None]) -> list[_Candidate]:
    """``train_physics``'s four fits from ``base``: for each ESC (braking actively, letting the
    rotor coast) the throttle map held straight, then bent from the straight fit. Each as its
    JSON metadata record, plus its model and flags (``data``: ``train`` as the fit reads it)."""
    candidates: list[_Candidate] = []
    for esc, braking_removed in (("ESC braking actively", 0.0), ("ESC letting the rotor coast", 1.0)):
        effects = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": braking_removed}
        start = dataclasses.replace(base, effects=effects).with_supply(train)
        init = start  # the bent map starts from the straight fit
        for name, hold in ((f"{esc}, throttle map straight", (*STRAIGHT_MAP, *HELD)),
                           (f"{esc}, throttle map bent", HELD)):
            say(f"fitting Kv, CP and the effects' strengths, {name}")
            fit = pf.fit_reference(init, data, hold=hold)
            init = fit.model
            m = _plant_model(fit.model, tau)
            flags = training_flags(fit, start)
            candidates.append({"fit": name, "constants": fit.model.constants(), "effects": dict(fit.model.effects),
                               "at_bound": [f.text() for f in flags if f.at_bound],
                               "fit_flags": [f.as_json() for f in flags],
                               "refused": [f.text() for f in flags if refuses(f)],
                               "train_rmse_rad_s": rmse(m, train),
                               "validation_rmse_rad_s": rmse(m, validation), "model": m, "flags": flags})
            say(f"  RMSE training {candidates[-1]['train_rmse_rad_s']:.2f} rad/s, "
                f"validation {candidates[-1]['validation_rmse_rad_s']:.2f} rad/s"
                + "".join(f"; {f.quantity} {f.why}" for f in flags if refuses(f)))
    return candidates


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


def refuses(flag: pf.FitFlag) -> bool:
    """The flag makes the fit no model of the stated motor: Kv or CP at a bound of its range or
    implausibly far from a value the user stated (a prior or the CONFIG)."""
    return flag.quantity in REFUSING and flag.stated


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
