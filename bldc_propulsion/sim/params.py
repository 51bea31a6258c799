"""Physical constants of the simulated bench: 3S LiPo, ESC, AXI 2212/34, 12x4.5 propeller, IR tachometer.

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
from typing import Any

from ..errors import BadInputError
from ..plant import PLANT_FIELDS, PlantParams, check_plant, value_problem

# Resting open-circuit voltage of one LiPo cell vs state of charge. Shape compiled from typical
# hobby LiPo "voltage vs charge" charts (LiCoO2/graphite cells rested after a C/10 discharge):
# 4.20 V full, a long flat plateau around the 3.7 V nominal near mid charge, and the knee below
# 10 %. 3S: 12.6 V full, ~11.2 V at 50 %, 9.9 V empty. Approximate, not a measured pack.
_CELL_SOC = (0.00, 0.05, 0.10, 0.20, 0.30, 0.40, 0.50, 0.60, 0.70, 0.80, 0.90, 1.00)
_CELL_OCV_V = (3.30, 3.50, 3.60, 3.66, 3.69, 3.71, 3.73, 3.77, 3.82, 3.90, 4.02, 4.20)


@dataclass(frozen=True)
class BenchParams(PlantParams):
    """Every physical constant of the bench (SI units, the unit in each name): the plant's
    (``plant.PlantParams``: ESC, motor, propeller, the pack's series resistance, the step) and
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
#: others must be > 0 (the plant's rules: ``plant.plant_problem``).
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
    #: field -> value; the names are checked here, the values by check_params (hence Any: the
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
