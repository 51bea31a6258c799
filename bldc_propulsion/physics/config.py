"""The physics CONFIG: the bench's constants and a strength per effect, what ``--physics CONFIG``
and ``train --physics-config`` describe (``PhysicsConfig``), read from and written to JSON.

A CONFIG file is {"params": {BenchParams field: value}, "effects": {name: strength},
"supply_v": volts}: effects it does not list are OFF, ``supply_v`` (the stiff supply of
battery_voltage strength 0) defaults to the measured recordings' median battery voltage. No
CONFIG: the package's nominal bench with every effect off. Driven by a recording's command events
and its measured (filtered) battery voltage, a PhysicsConfig predicts the rotor's speed with the
plant itself (``plant.motor_response``); ``fit.py`` calibrates it on recordings.
"""

from __future__ import annotations

import dataclasses
import json
import math
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol, TypedDict

import numpy as np

from .. import contract as c
from ..atomic import OutputKind, atomic_output, recognised_by
from ..errors import BadInputError
from ..priors import MotorPriors
from .params import BenchParams, params_with_overrides, resolve_effects
from .plant import measured_start_speed, motor_response, motor_response_with_current
from .sizing import physics_start

#: The constants a fit calibrates on the measured data, log-parameterised (their ranges and why
#: these four: ``fit.LOG_RANGE_BASE``): the motor's Kv, the propeller's CP, the ESC's throttle-map
#: exponent and the pack's series resistance.
CALIBRATED = ("motor_kv_rpm_per_v", "propeller_cp", "esc_throttle_exponent", "battery_series_resistance_ohm")
#: Constants a fit may free on a linear scale (``fit.calibrate``'s ``linear``: their "off" is 0, which
#: a log scale cannot hold), with their plausible range. Only where the data identify them: none is
#: calibrated by default. ``esc_map_origin_share``: where the throttle map starts below the ESC's
#: start threshold (``plant.map_origin``), from the threshold itself (0) to as far below PWM_STOP as
#: the threshold is above it (2); the esc_test F80's BLHeli_32 ESC maps from ~990 us and starts the
#: rotor between 1100 and 1150 us (~1.1). ``esc_throttle_curvature``: the map's square-law share
#: (``plant.throttle``), from none (0) to the square law (1); the discrepancy workflow fits it on
#: the reference (``fit.MAP_SHAPE``).
#: ``supply_polarisation_*``: the pack's fast polarisation branch (``plant.Supply``), from none to
#: several times a LiPo's series resistance, its time constant from one that the series resistance
#: could stand for to one the battery filter passes (``fit.REFERENCE_COMPANIONS``: fitted where
#: battery_voltage is completed into the base on the reference).
LINEAR_RANGES: dict[str, tuple[float, float]] = {"esc_map_origin_share": (0.0, 2.0),
                                                 "esc_throttle_curvature": (0.0, 1.0),
                                                 "supply_polarisation_resistance_ohm": (0.0, 0.3),
                                                 "supply_polarisation_time_constant_s": (0.3, 30.0)}
#: LINEAR_RANGES constants whose upper end is no bound a fit can hit (``fit.fit_flags``): a polarisation
#: slower than the range is one the battery filter passes nearly whole, so the model hardly depends
#: on where beyond it the branch lies (the project's simulator's pack: 30 s, at the range's end).
LINEAR_OPEN_ABOVE = frozenset({"supply_polarisation_time_constant_s"})
#: Integration step of the physics model unless a CONFIG sets ``sim_step_s``: 5 ms keeps a 30 s
#: recording at ~6 ms of simulation (the implicit Euler is stable; against the 1 ms simulator
#: the error is ~0.5 rad/s RMS, 2.5 rad/s at most, below the tachometer's ~5 rad/s noise).
PHYSICS_STEP_S = 0.005
#: Top-level keys of a physics CONFIG file (``discrepancy``: provenance, written by -o, ignored).
CONFIG_KEYS = ("params", "effects", "supply_v", "discrepancy")


class Recorded(Protocol):
    """What the physics reads of a recording (``recordings.Signals`` is one): the grid, the measured
    speed and the filtered battery voltage on it, the command events, and where the voltage came
    from."""

    @property
    def path(self) -> str: ...
    @property
    def t(self) -> np.ndarray: ...
    @property
    def speed(self) -> np.ndarray: ...
    @property
    def voltage(self) -> np.ndarray: ...
    @property
    def pwm_events(self) -> tuple[np.ndarray, np.ndarray]: ...
    @property
    def voltage_source(self) -> str: ...


def supply_tau_s(s: Recorded) -> float:
    """Time constant of the low-pass between the battery terminal and ``s.voltage``: the battery
    filter's (the paper's) when the voltage was filtered from the ADC here; 0 for a recorded
    voltage (an imported thrust-stand log measures the supply directly)."""
    return c.PAPER_FILTER_TAU_S if s.voltage_source.startswith(c.bare(c.TOPIC_BATTERY_ADC)) else 0.0


def median_voltage(signals: Sequence[Recorded]) -> float | None:
    """The recordings' median battery voltage (V), None without a valid one: the stiff supply of
    a physics model (``PhysicsConfig.with_supply``) and the pack a stated motor is sized at."""
    v = np.concatenate([s.voltage[np.isfinite(s.voltage)] for s in signals]) if signals else np.zeros(0)
    return float(np.median(v)) if len(v) else None


class ConfigJson(TypedDict):
    """``PhysicsConfig.config``: what a CONFIG file holds (``load_config`` reads it back)."""

    params: dict[str, object]  #: BenchParams field -> value, where it differs from the package's bench
    effects: dict[str, float]
    supply_v: float | None


@dataclass(frozen=True)
class PhysicsConfig:
    """Bench constants and effect strengths: what ``--physics CONFIG`` describes (see the module doc)."""

    params: BenchParams
    effects: dict[str, float]
    #: the stiff supply's voltage (V) that battery_voltage strength 0 gives; None: not yet set
    #: (``with_supply`` sets the measured recordings' median)
    supply_v: float | None = None
    #: the CONFIG file it was read from; None: the package's nominal bench (no CONFIG given), whose
    #: constants stand for an unknown motor and propeller (see ``fit.PLAUSIBLE_FACTOR``)
    source: str | None = None
    #: CALIBRATED constants the user stated through ``priors`` options (name: the options, e.g.
    #: "--motor-kv 1900"; ``start_model``): judged against like a CONFIG's, whatever ``source``
    stated: dict[str, str] = dataclasses.field(default_factory=dict)
    #: per CALIBRATED constant, the range (low, high) every fit may search where it is not
    #: ``fit.LOG_RANGE_BASE`` around the start (``sizing.physics_start``: a stated Kv +-30 %, a stated
    #: propeller's CP x3), whatever a fit starts from
    ranges: dict[str, tuple[float, float]] = dataclasses.field(default_factory=dict)
    #: the constants (BenchParams names) ``source`` states in its 'params'; the rest are ``base``'s
    listed: frozenset[str] = frozenset()

    def predict(self, s: Recorded) -> np.ndarray:
        """Speed (rad/s) on the recording's grid; the rotor starts at the recording's measured
        speed when it is already turning there (``plant.measured_start_speed``): a fit
        to a log cut mid-run that started it at rest would bend every constant to explain the
        spin-up it never made."""
        return motor_response(*self._drive(s))

    def predict_with_current(self, s: Recorded) -> tuple[np.ndarray, np.ndarray]:
        """``predict``'s speed (rad/s) and the supply current (A) on the recording's grid, from
        one run of the plant (``plant.motor_response_with_current``)."""
        return motor_response_with_current(*self._drive(s))

    def _drive(self, s: Recorded) -> tuple[Any, ...]:
        """The plant's arguments for the recording ``s`` (``plant.motor_response``'s, in order)."""
        ok = np.isfinite(s.voltage)
        if not ok.any():
            raise BadInputError(f"{s.path}: no valid battery voltage for the physics model")
        assert self.supply_v is not None, "with_supply first"
        w0 = measured_start_speed(s.t, s.speed, float(s.pwm_events[0][0])) if len(s.pwm_events[0]) else 0.0
        return (self.params, self.effects, s.pwm_events, (s.t[ok], s.voltage[ok]), s.t, self.supply_v,
                supply_tau_s(s), False, w0)

    def with_supply(self, signals: Sequence[Recorded]) -> PhysicsConfig:
        """The model with its stiff-supply voltage set to the median battery voltage of
        ``signals`` if the CONFIG did not set it. One voltage for every recording: a supply that
        knew each recording's own voltage would already hold most of the battery_voltage effect."""
        if self.supply_v is not None:
            return self
        v = median_voltage(signals)
        if v is None:
            raise BadInputError(f"{signals[0].path}: no valid battery voltage for the physics model")
        return dataclasses.replace(self, supply_v=v)

    def with_effect(self, name: str, strength: float) -> PhysicsConfig:
        return dataclasses.replace(self, effects={**self.effects, name: float(strength)})

    def with_constants(self, values: Sequence[float]) -> PhysicsConfig:
        # (untyped: replace(**) checks each field's type by name, which a name -> value dict cannot state)
        calibrated: dict[str, Any] = dict(zip(CALIBRATED, map(float, values), strict=True))
        return dataclasses.replace(self, params=dataclasses.replace(self.params, **calibrated))

    def constants(self) -> dict[str, float]:
        return {n: float(getattr(self.params, n)) for n in CALIBRATED}

    def basis(self, name: str) -> tuple[str, bool]:
        """What this model's value of the constant ``name`` is (a fit is measured from it), and
        whether the user stated it: a CONFIG's value, a stated prior, or the nominal bench's."""
        if name in self.stated:
            return f"stated ({self.stated[name]})", True
        if self.source is not None:
            return "CONFIG", True
        return ("start (not stated)" if self.stated else "nominal (no CONFIG given)"), False

    def config(self) -> ConfigJson:
        """JSON-able CONFIG: the constants that differ from the package's bench, all strengths."""
        base = BenchParams()
        params = {f.name: getattr(self.params, f.name) for f in dataclasses.fields(base)
                  if getattr(self.params, f.name) != getattr(base, f.name)}
        return {"params": params, "effects": dict(self.effects), "supply_v": self.supply_v}


# --- CONFIG files -----------------------------------------------------------------------------------
def load_config(path: str | None, base: BenchParams | None = None, option: str = "--physics") -> PhysicsConfig:
    """The package's nominal bench (or ``base``) with every effect OFF (``path`` None or empty), or
    a CONFIG file {"params": {field: value}, "effects": {name: strength}, "supply_v": volts} over
    it: effects it does not list are OFF, ``sim_step_s`` defaults to PHYSICS_STEP_S, ``supply_v``
    (the stiff supply of battery_voltage strength 0) to the measured recordings' median battery
    voltage. BadInputError naming the ``option``, the file and the key."""
    base = base or BenchParams()
    if not path:
        return PhysicsConfig(dataclasses.replace(base, sim_step_s=PHYSICS_STEP_S), {name: 0.0 for name in c.EFFECTS})
    cfg = _config_file(path, option)
    try:
        p = params_with_overrides(base, {"sim_step_s": PHYSICS_STEP_S, **cfg.get("params", {})})
        eff = resolve_effects({**{name: 0.0 for name in c.EFFECTS}, **cfg.get("effects", {})})
    except BadInputError as exc:
        raise BadInputError(f"{option} {path}: {exc}") from None
    supply = cfg.get("supply_v")
    if supply is not None and (isinstance(supply, bool) or not isinstance(supply, (int, float))
                               or not math.isfinite(supply) or supply <= 0):
        raise BadInputError(f"{option} {path}: supply_v {supply!r} must be a voltage > 0 (or null)")
    return PhysicsConfig(p, eff, None if supply is None else float(supply), str(path),
                         listed=frozenset(cfg.get("params", {})))


def _config_file(path: str, option: str) -> dict[str, Any]:
    """The CONFIG file's JSON object, its keys and the types of 'params' and 'effects' checked (the
    values are the file's, checked where they are used)."""
    try:
        with open(path, encoding="utf-8") as fh:
            cfg = json.load(fh)
    except OSError as exc:
        raise BadInputError(f"{option} {path}: cannot read: {exc.strerror or exc}") from None
    except (json.JSONDecodeError, UnicodeDecodeError) as exc:
        raise BadInputError(f"{option} {path}: not valid JSON: {exc}") from None
    if not isinstance(cfg, dict):
        raise BadInputError(f"{option} {path}: expected a JSON object with keys {', '.join(CONFIG_KEYS)}")
    for key in cfg:
        if key not in CONFIG_KEYS:
            raise BadInputError(f"{option} {path}: unknown key '{key}' (known: {', '.join(CONFIG_KEYS)})")
    for key in ("params", "effects"):
        if not isinstance(cfg.get(key, {}), dict):
            raise BadInputError(f"{option} {path}: '{key}' must be an object of name: number")
    return cfg


#: Said when a physics fit starts from the simulator's bench because nothing of the motor was stated.
NOMINAL_START_WARNING = ("no --motor-kv/--prop-diameter-in: starting from the simulator's 12 in bench "
                         "(a 12x4.5 on a 710 kv motor at 3S); its constants stand for a motor nobody stated")


def start_model(config: str | None, priors: MotorPriors | None, voltage_v: float | None = None,
                option: str = "--physics") -> tuple[PhysicsConfig, list[str], list[str]]:
    """The model a physics fit starts from, (model, notes, warnings): the user's motor
    (``sizing.physics_start``: the nominal bench resized to the stated Kv, propeller and pack, with
    the narrower ranges of the stated constants) under a CONFIG file, which wins for every constant
    it lists (a warning names each stated prior it overrides). Neither given: the nominal bench, and
    a warning that says so (NOMINAL_START_WARNING). ``voltage_v``: the recordings' median battery
    voltage (sizes the motor when no --cells is given)."""
    start = physics_start(priors, voltage_v) if priors is not None else None
    if start is None:
        model = load_config(config, option=option)
        return model, [], ([] if config else [NOMINAL_START_WARNING])
    model = load_config(config, base=start.params, option=option)
    warnings = list(start.warnings)
    listed = model.listed
    stated = {}
    for name, how in start.stated.items():
        if name in listed:
            warnings.append(f"{how}: {option} {config} sets {name} {getattr(model.params, name):.4g}, which wins "
                            f"over the stated {getattr(start.params, name):.4g}")
        else:
            stated[name] = how
    ranges = {n: r for n, r in start.ranges.items() if n in stated}
    return dataclasses.replace(model, stated=stated, ranges=ranges), list(start.notes), warnings


def save_config(model: PhysicsConfig, path: str, force: bool, provenance: Mapping[str, object]) -> None:
    """Write the model as a CONFIG that ``load_config`` reads back (atomically)."""
    with atomic_output(path, force=force, kind=CONFIG) as tmp:
        tmp.write_text(json.dumps({**model.config(), "discrepancy": provenance}, indent=2) + "\n",
                       encoding="utf-8")


def _read_config(p: Path) -> PhysicsConfig:
    return load_config(str(p))


#: A CONFIG file as an output (``atomic.check_outputs``): an existing one is what ``load_config`` reads.
CONFIG = OutputKind("physics CONFIG", "a physics CONFIG file (.json)", (".json",), recognised_by(_read_config))
