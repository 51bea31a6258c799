"""Every constant of the bench, and the checks of constants and effect strengths.

``PlantParams``: the plant's (ESC, motor, propeller, the pack's series resistance, the
integration step): what ``plant.py`` steps and a physics model file stores. ``BenchParams``
extends it with the battery and the sensors the simulator models: 3S LiPo, ESC, AXI 2212/34,
12x4.5 propeller, IR tachometer; a physics CONFIG (``config.py``) may set any of its fields.

Every number says where it comes from. Names carry their SI unit so that a ``--param NAME=VALUE``
override on the command line is unambiguous. The full-throttle operating point these values give
on a full pack is about 600 rad/s (5.8 krpm), 15 A and 10 N of thrust (checked by the tests).
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from dataclasses import dataclass
from itertools import pairwise
from typing import Any, TypeVar

from ..contract import EFFECTS
from ..errors import BadInputError


@dataclass(frozen=True)
class PlantParams:
    """Every constant of the plant (SI units, the unit in each name). ``BenchParams`` extends
    it with the battery and the sensors; a physics model file stores exactly these fields."""

    # --- the source as the ESC sees it ------------------------------------------------------
    # ~8 mOhm per cell (a fresh 20-25C 2 Ah pack) + XT60/deans connector + 15 cm of 14 AWG lead
    battery_series_resistance_ohm: float = 0.035
    # the pack's fast polarisation (charge transfer) as one RC branch behind the series resistance:
    # the sag that builds over seconds after a load step. A battery filter of ~2 s passes only part
    # of it in that time, so a model driven by the filtered voltage puts back the part it has not
    # passed (``plant.Supply``), as it does for the series resistance's drop. 0: no such branch
    # (the default; a branch far slower than the filter needs none: the filter passes it).
    supply_polarisation_resistance_ohm: float = 0.0
    supply_polarisation_time_constant_s: float = 3.0

    # --- ESC ------------------------------------------------------------------------------
    # MOSFET on-resistance (two of them conduct, ~2 x 10 mOhm), motor leads, bullet connectors
    # and the ESC's current path: sum chosen so that full throttle draws ~15 A
    esc_resistance_ohm: float = 0.06
    # start threshold above PWM_STOP at effect strength 1: paper 3.2, "motion starts when pwm
    # level reaches 0.055"
    esc_deadband_pwm: float = 0.005
    # dead time at effect strength 1: up to one 20 ms frame before the pulse is read, plus the
    # ESC's input averaging/throttle filtering (~1 frame) -> 40 ms
    esc_input_delay_s: float = 0.040
    # shape of the throttle map above the start threshold: duty = x ** exponent with x the
    # linear map in [0, 1]. 1 is the linear map of BLHeli's default; other ESCs (or a "throttle
    # curve" setting) bend it. Randomized benches draw it to give the ESC a structure of its own.
    esc_throttle_exponent: float = 1.0
    # the map's second shape constant: duty = x**exponent * ((1 - c) + c x), c in [0, 1]. 0 is the
    # power law alone; 1 with exponent 1 the square law. Real ESC curves and "throttle curve"
    # settings are a blend of a linear and a quadratic part (duty = a x + (1 - a) x^2, a = 1 - c):
    # a power law matches such a blend at two levels only, and the 1-2 % of the duty it misses
    # elsewhere is what a start threshold or a dead time is then fitted to stand in for.
    esc_throttle_curvature: float = 0.0
    # where the throttle map starts (duty 0 of its linear part), below the start threshold, as a
    # share of the threshold's distance above PWM_STOP: 0, the map starts where the drive starts
    # (the drive rises from 0 at the threshold); 1, at PWM_STOP (the threshold only cuts the drive
    # off below it, which jumps to the map's value there: an ESC that will not start a motor at a
    # low duty); above 1, below PWM_STOP. A real BLHeli_32 ESC (esc_test F80 log) drives a duty
    # linear in the command from ~990 us, yet starts the rotor only at ~1100-1150 us.
    esc_map_origin_share: float = 0.0

    # --- AXI 2212/34 outrunner (Model Motors datasheet) -----------------------------------
    motor_kv_rpm_per_v: float = 710.0  # datasheet: 710 rpm/V
    winding_resistance_ohm: float = 0.20  # datasheet Ri ~ 200 mOhm (phase-to-phase)
    motor_no_load_current_a: float = 0.4  # datasheet Io ~ 0.4 A at 10 V, as friction torque Kt*Io
    winding_reference_temperature_c: float = 25.0  # resistance above is at room temperature
    copper_temperature_coefficient_per_k: float = 0.00393  # annealed copper, IEC 60028
    # One thermal node: 57 g motor (~40 J/K at ~0.7 J/(g K) for its copper/steel/aluminium mix)
    # plus the part of the aluminium mount that follows it -> 70 J/K; the propeller wash cools
    # an outrunner well: ~1.8 K/W to ambient. Time constant ~2 min.
    motor_thermal_capacity_j_per_k: float = 70.0
    motor_thermal_resistance_k_per_w: float = 1.8
    ambient_temperature_c: float = 25.0
    # rotating bell (~20 g of steel/magnets at ~13 mm radius): m r^2 ~ 4e-6 kg m^2
    motor_rotor_inertia_kg_m2: float = 4.0e-6

    # --- 12x4.5 propeller -----------------------------------------------------------------
    propeller_diameter_m: float = 0.3048  # 12 in
    propeller_mass_kg: float = 0.020  # typical 12x4.5 slow-fly/CR propeller, 18-22 g
    # static coefficients of 12 in slow-fly propellers (UIUC propeller database style values for
    # APC 12x4.7SF / 12x3.8SF at ~5000-6000 rpm: CT ~0.10-0.11, CP ~0.04-0.05)
    propeller_ct: float = 0.105
    propeller_cp: float = 0.042
    air_density_kg_m3: float = 1.225  # ISA sea level, 15 C

    # --- integration ------------------------------------------------------------------------
    sim_step_s: float = 0.001  # 1 kHz: rotor time constant ~0.1 s, thermal/battery slower

    # --- derived quantities (properties, not overridable) ---------------------------------
    @property
    def back_emf_constant_v_s_per_rad(self) -> float:
        """Ke = 1/Kv in SI (V per rad/s); equals the torque constant Kt in N m/A."""
        return 60.0 / (2.0 * math.pi * self.motor_kv_rpm_per_v)

    @property
    def propeller_inertia_kg_m2(self) -> float:
        """Propeller as a thin rod about its centre: m D^2 / 12 (~1.5e-4 kg m^2)."""
        return self.propeller_mass_kg * self.propeller_diameter_m**2 / 12.0

    @property
    def rotor_inertia_kg_m2(self) -> float:
        """Propeller plus motor bell."""
        return self.propeller_inertia_kg_m2 + self.motor_rotor_inertia_kg_m2

    @property
    def thrust_coefficient(self) -> float:
        """b in thrust = b w^2 (N s^2/rad^2): CT rho D^4 / (4 pi^2), since n = w / (2 pi)."""
        return self.propeller_ct * self.air_density_kg_m3 * self.propeller_diameter_m**4 / (4.0 * math.pi**2)

    @property
    def torque_coefficient(self) -> float:
        """k in drag torque = k w^2 (N m s^2/rad^2): CP rho D^5 / (2 pi)^3."""
        rho_d5 = self.air_density_kg_m3 * self.propeller_diameter_m**5
        return self.propeller_cp * rho_d5 / (2.0 * math.pi) ** 3


#: The plant's constants, in order (a physics model file stores them by these names).
PLANT_FIELDS: tuple[str, ...] = tuple(f.name for f in dataclasses.fields(PlantParams))
#: Constants that may be zero (a switch-off of a small term); all others must be > 0.
PLANT_MAY_BE_ZERO = frozenset({
    "battery_series_resistance_ohm",
    "supply_polarisation_resistance_ohm",
    "esc_resistance_ohm",
    "esc_deadband_pwm",
    "esc_map_origin_share",
    "esc_throttle_curvature",
    "esc_input_delay_s",
    "motor_no_load_current_a",
    "copper_temperature_coefficient_per_k",
    "motor_rotor_inertia_kg_m2",
})
#: Constants a model file may lack, read at their default: added after model files were written
#: (a file written before holds the same model it held).
PLANT_OPTIONAL_FIELDS = frozenset({"esc_map_origin_share", "esc_throttle_curvature",
                                   "supply_polarisation_resistance_ohm", "supply_polarisation_time_constant_s"})
#: Constants whose value is a temperature (any finite value).
PLANT_ANY_FINITE = frozenset({"winding_reference_temperature_c", "ambient_temperature_c"})
#: Coarsest integration step the rotor tolerates (its time constant is ~0.1 s at nominal inertia).
MAX_STEP_S = 0.005


def value_problem(value: object, may_be_zero: bool = False, any_finite: bool = False,
                  integer: bool = False) -> str | None:
    """Why ``value`` is not a valid constant (a number, finite, > 0 unless told), or None."""
    if not isinstance(value, (int, float)) or isinstance(value, bool) or not math.isfinite(value):
        return f"{value!r} must be a finite number"
    if integer and value != int(value):
        return f"{value!r} must be a whole number"
    if any_finite:
        return None
    if may_be_zero:
        return f"{value!r} must be >= 0" if value < 0 else None
    return f"{value!r} must be > 0" if value <= 0 else None


def plant_problem(p: PlantParams) -> tuple[str, str] | None:
    """The first constant of ``p`` that makes no physical sense, as (field, why), or None."""
    for name in PLANT_FIELDS:
        why = value_problem(getattr(p, name), name in PLANT_MAY_BE_ZERO, name in PLANT_ANY_FINITE)
        if why:
            return name, why
    if p.esc_deadband_pwm >= 0.04:
        return "esc_deadband_pwm", f"{p.esc_deadband_pwm!r} leaves no throttle range (must be < 0.04)"
    if p.esc_throttle_curvature > 1.0:
        why = f"{p.esc_throttle_curvature!r} bends the map past the square law (must be <= 1)"
        return "esc_throttle_curvature", why
    if p.sim_step_s > MAX_STEP_S:
        return "sim_step_s", f"{p.sim_step_s!r} too coarse for the rotor (must be <= {MAX_STEP_S} s)"
    return None


P = TypeVar("P", bound=PlantParams)


def check_plant(p: P) -> P:
    """``p`` if its plant constants make physical sense, else BadInputError('--param NAME: why')."""
    bad = plant_problem(p)
    if bad:
        raise BadInputError(f"--param {bad[0]}: {bad[1]}")
    return p


# --- effect strengths ------------------------------------------------------------------------
def strength_problem(name: str, value: object) -> str | None:
    """Why ``value`` is not a strength of the effect ``name`` (finite, >= 0; spin-down's at most
    1, the fraction of braking removed), or None."""
    if name not in EFFECTS:
        return f"unknown effect (known: {', '.join(EFFECTS)})"
    try:
        s = float(value)  # type: ignore[arg-type]  # any JSON/CLI value: float() sorts it out, below
    except (TypeError, ValueError):
        return "not a number"
    if not math.isfinite(s) or s < 0.0:
        return "strength must be a finite number >= 0"
    if name == "spin_down_asymmetry" and s > 1.0:
        return "must be in [0, 1] (fraction of braking removed)"
    return None


def resolve_effects(effects: Mapping[str, float] | None) -> dict[str, float]:
    """All effects at 1.0, overridden by ``effects``; BadInputError naming a bad item."""
    out = {name: 1.0 for name in EFFECTS}
    for name, value in (effects or {}).items():
        why = strength_problem(name, value)
        if why:
            item = name if name not in EFFECTS else f"{name}={value!r}"
            raise BadInputError(f"--effect {item}: {why}")
        out[name] = float(value)
    return out


# Resting open-circuit voltage of one LiPo cell vs state of charge. Shape compiled from typical
# hobby LiPo "voltage vs charge" charts (LiCoO2/graphite cells rested after a C/10 discharge):
# 4.20 V full, a long flat plateau around the 3.7 V nominal near mid charge, and the knee below
# 10 %. 3S: 12.6 V full, ~11.2 V at 50 %, 9.9 V empty. Approximate, not a measured pack.
_CELL_SOC = (0.00, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.00)
_CELL_OCV_V = (3.30, 3.50, 3.60, 3.66, 3.69, 3.71, 3.73, 3.77, 3.82, 3.90, 4.02, 4.20)


@dataclass(frozen=True)
class BenchParams(PlantParams):
    """Every physical constant of the bench (SI units, the unit in each name): the plant's
    (``PlantParams``: ESC, motor, propeller, the pack's series resistance, the step) and
    the battery's and sensors' below."""

    # --- 3S 2000 mAh LiPo (its series resistance is the plant's) ----------------------------
    battery_cells: int = 3  # paper 2.5: "3 Cell 2000 mAh Lithium Polymer battery"
    battery_capacity_ah: float = 2.0  # paper 2.5
    battery_cell_soc: tuple[float, ...] = _CELL_SOC  # table above
    battery_cell_ocv_v: tuple[float, ...] = _CELL_OCV_V  # table above
    # one RC polarisation branch: the slow (tens of s) recovery of a LiPo after a load step
    battery_polarisation_resistance_ohm: float = 0.015
    battery_polarisation_time_constant_s: float = 30.0
    # an optional second, slower RC branch (0 ohm: the one-RC pack above); randomized benches
    # switch it on to give the pack a structure the one-RC model lacks
    battery_polarisation2_resistance_ohm: float = 0.0
    battery_polarisation2_time_constant_s: float = 300.0

    # --- battery voltage at the ADC -------------------------------------------------------
    # battery V per ADC V: the paper's filter (1) has DC gain 2*4.9975e-4/(1-0.9995) = 1.999
    adc_divider_ratio: float = 1.999
    # Switching modulation seen at the battery per ampere of battery current: the ESC chops the
    # motor current at ~8-16 kHz; pack + lead resistance and the lead inductance ringing against
    # the ESC's input capacitors make the terminal swing by ~+-1.8 V (3-4 V peak to peak) at
    # 15 A (paper Fig. 1).
    # Sampled asynchronously at 1 kHz this aliases into a broadband zero-mean disturbance.
    battery_modulation_ohm: float = 0.12
    adc_noise_v: float = 0.003  # at the ADC pin: DS1104 ADC noise plus pick-up (a few mV)
    adc_sample_rate_hz: float = 1000.0  # paper: filter (1) runs at 1 kHz
    adc_resolution_v: float = 20.0 / 65536  # DS1104 ADC: 16 bit over +-10 V

    # --- phototransistor tachometer (BPW76 + IR LED) --------------------------------------
    tach_sample_rate_hz: float = 20000.0  # contract default
    tach_blade_width_fraction: float = 0.10  # each blade blocks ~10 % of a turn at the beam radius
    # blade 2 is a few percent of the half-turn spacing off, and slightly wider (moulding)
    tach_blade_spacing_asymmetry_fraction: float = 0.03
    tach_blade_width_asymmetry_fraction: float = 0.05
    # signal levels as the contract states them (beam clear = high most of the time): ~0.5 V
    # below a 5 V supply when clear, ~0.3 V (a saturated transistor) while a blade blocks it
    tach_high_v: float = 4.5
    tach_low_v: float = 0.3
    tach_time_constant_s: float = 25e-6  # BPW76 rise/fall ~ 20-30 us with a few kOhm load
    tach_noise_v: float = 0.020  # cable pick-up and ADC noise
    tach_adc_bits: int = 12
    tach_adc_full_scale_v: float = 5.0

    @property
    def battery_capacity_c(self) -> float:
        """Capacity in coulombs."""
        return self.battery_capacity_ah * 3600.0


#: Battery and sensor fields that may be zero (a switch-off of a noise or a small term); all
#: others must be > 0 (the plant's rules: ``plant_problem``).
_MAY_BE_ZERO = frozenset({
    "battery_polarisation_resistance_ohm",
    "battery_polarisation2_resistance_ohm",
    "battery_modulation_ohm",
    "adc_noise_v",
    "adc_resolution_v",
    "tach_blade_spacing_asymmetry_fraction",
    "tach_blade_width_asymmetry_fraction",
    "tach_noise_v",
    "tach_low_v",
    "tach_time_constant_s",
})
#: Tables: not overridable from the command line.
_TABLES = frozenset({"battery_cell_soc", "battery_cell_ocv_v"})
_INTEGERS = frozenset({"battery_cells", "tach_adc_bits"})


def _bad(name: str, why: str) -> BadInputError:
    return BadInputError(f"--param {name}: {why}")


def check_params(p: BenchParams) -> BenchParams:
    """Reject constants that make no physical sense (raises BadInputError naming the field)."""
    check_plant(p)
    for f in dataclasses.fields(p):
        if f.name in _TABLES or f.name in PLANT_FIELDS:
            continue
        why = value_problem(getattr(p, f.name), f.name in _MAY_BE_ZERO, integer=f.name in _INTEGERS)
        if why:
            raise _bad(f.name, why)
    soc, ocv = p.battery_cell_soc, p.battery_cell_ocv_v
    if len(soc) != len(ocv) or len(soc) < 2 or soc[0] != 0.0 or soc[-1] != 1.0 or any(
        b <= a for a, b in pairwise(soc)
    ):
        raise _bad("battery_cell_soc", "table must rise strictly from 0 to 1, one voltage per entry")
    if p.tach_low_v >= p.tach_high_v or p.tach_high_v > p.tach_adc_full_scale_v:
        raise _bad("tach_high_v", "need tach_low_v < tach_high_v <= tach_adc_full_scale_v")
    width_2 = p.tach_blade_width_fraction * (1.0 + p.tach_blade_width_asymmetry_fraction)
    if width_2 + p.tach_blade_spacing_asymmetry_fraction * 0.5 >= 0.45:
        raise _bad("tach_blade_width_fraction", "blades too wide: the beam must be clear between them")
    if p.tach_adc_bits > 24:
        raise _bad("tach_adc_bits", f"{p.tach_adc_bits!r} must be <= 24")
    return p


def params_with_overrides(base: BenchParams, overrides: Mapping[str, float]) -> BenchParams:
    """``base`` with ``{name: value}`` replaced; BadInputError for unknown names or bad values."""
    known = [f.name for f in dataclasses.fields(base) if f.name not in _TABLES]
    #: field -> value; the names are checked here, the values by check_params (untyped: the
    #: fields have several types, which replace(**changes) cannot see per name)
    changes: dict[str, Any] = {}
    for name, value in overrides.items():
        if name not in known:
            if name in _TABLES:
                raise _bad(name, "is a table and cannot be overridden from the command line")
            raise _bad(name, f"unknown bench parameter (known: {', '.join(known)})")
        try:
            number = float(value)
        except (TypeError, ValueError):
            raise _bad(name, f"{value!r} is not a number") from None
        if name in _INTEGERS:
            if not math.isfinite(number) or number != int(number):
                raise _bad(name, f"{value!r} must be a whole number")
            changes[name] = int(number)
        else:
            changes[name] = number
    return check_params(dataclasses.replace(base, **changes))
