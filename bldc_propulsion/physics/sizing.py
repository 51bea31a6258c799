"""The user's motor as the start point of a physics fit: the nominal bench resized to the Kv,
propeller and pack the user stated (``priors.MotorPriors``), by the relations a motor and a
propeller of another size follow, with the ranges a fit may search around what was stated.
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass

from .. import contract as c
from ..priors import INCH_M, MotorPriors
from .params import BenchParams
from .plant import full_drive_speeds

#: The nominal bench's propeller is a 12x4.5 (``params.PlantParams``: 12 in, CT 0.105, CP 0.042).
NOMINAL_PITCH_M = 4.5 * INCH_M
#: A LiPo cell's voltage between its 3.7 V nominal and 4.2 V full: a stated cell count is sized at
#: the middle (the fit itself runs on the recordings' measured voltage).
CELL_VOLTAGE_RANGE_V = (3.7, 4.2)
#: Resting voltage below which a LiPo cell is empty (and above 4.25 V one is overcharged): a
#: recording's median voltage outside cells x this range is another pack than the one stated.
CELL_VOLTAGE_PLAUSIBLE_V = (3.0, 4.25)
#: Range a fit may search around a stated Kv (a factor, either way): a datasheet's Kv is within
#: ~10 %, and what a speed-vs-command fit sees through the ESC's timing advance and the winding's
#: resistance (which the fit does not calibrate) moves it further, but not by more than this.
KV_RANGE_FACTOR = 1.3
#: Range around a CP from a stated diameter and pitch (or CT): the relations below are +-26 % in
#: CT and ~+-20 % in the figure of merit, and CP also takes up the error of the sized winding
#: resistance (a speed recording fixes only their product, see ``plant``), so a factor 3; beyond
#: ``fit.PLAUSIBLE_FACTOR`` (2) the fit is flagged all the same.
CP_RANGE_FACTOR = 3.0


def propeller_ct_from_geometry(diameter_m: float, pitch_m: float, nominal_ct: float,
                               nominal_diameter_m: float) -> float:
    """Static CT of a propeller from its pitch / diameter ratio: CT grows as sqrt(pitch / diameter).

    The relation is the static case of G. Staples' propeller thrust equation (T proportional to
    RPM^2 d^3.5 sqrt(pitch), from momentum theory with the pitch speed as the exit velocity and an
    empirical fit to published static thrust data: within +-26 % for 95 % of propellers;
    "Propeller Static & Dynamic Thrust Calculation", electricrcaircraftguy.com, 2013-2015), i.e.
    CT = T / (rho n^2 D^4) proportional to sqrt(pitch / D); anchored at the nominal bench's 12x4.5
    (UIUC-style static CT 0.105) rather than at Staples' own constant (0.131 sqrt(P/D), 0.080 for a
    12x4.5), so that the nominal propeller stated as such gives exactly the nominal bench."""
    return nominal_ct * math.sqrt((pitch_m / diameter_m) / (NOMINAL_PITCH_M / nominal_diameter_m))


def figure_of_merit(ct: float, cp: float) -> float:
    """Hover figure of merit FM = ideal (momentum-theory) power / actual power of a propeller with
    static coefficients CT, CP: ``propeller_cp_from_ct`` solved for FM."""
    return float(ct**1.5 / (cp * math.sqrt(math.pi / 2.0)))


def propeller_cp_from_ct(ct: float, fm: float) -> float:
    """Static CP from CT by momentum theory: the ideal (actuator-disk) power to make a thrust T is
    T^1.5 / sqrt(2 rho A) with A = pi D^2 / 4 (Rankine-Froude; e.g. Leishman, Principles of
    Helicopter Aerodynamics, ch. 2), the actual power that over the figure of merit FM (0.5-0.7 for
    small rotors in practice), so with T = CT rho n^2 D^4 and P = CP rho n^3 D^5:
    CP = CT^1.5 / (FM sqrt(pi / 2))."""
    return float(ct**1.5 / (fm * math.sqrt(math.pi / 2.0)))


@dataclass(frozen=True)
class PhysicsStart:
    """The physics constants a fit starts from for the stated motor, and what it may search."""

    params: BenchParams
    #: the range (low, high) a fit may search, per constant the priors narrow (Kv, CP)
    ranges: dict[str, tuple[float, float]]
    #: constant -> the options it was stated by (a fit is judged against these)
    stated: dict[str, str]
    #: one line per constant, how it was derived (for the model's provenance and the console)
    notes: list[str]
    warnings: list[str]


def physics_start(priors: MotorPriors, voltage_v: float | None = None) -> PhysicsStart | None:
    """The nominal bench resized to the stated motor, propeller and pack; None when nothing that
    sizes it (Kv, cells, diameter, pitch, CT) was stated.

    Kv, diameter and CT (from the pitch, ``propeller_ct_from_geometry``, or stated) and CP
    (``propeller_cp_from_ct`` with the nominal propeller's figure of merit) are taken as stated.
    The rest is sized as a motor and pack of that class are built (the rules of
    ``sim.random_bench.draw_far_bench``): with the full-drive speed the nominal bench's share of
    the no-load speed Kv V (a motor is matched to its propeller) and the shaft power P there
    from the propeller's CP, the winding and ESC resistance go as V^2 / P (the copper loss the same
    share of the power), the no-load current as P / V, the pack's series resistance as V / P; the
    motor's size (rotating bell inertia, thermal capacity; its thermal time constant kept) goes
    with its torque P / w (torque per rotor volume); the propeller's mass as D^3. V is the stated
    cells at the middle of CELL_VOLTAGE_RANGE_V, else ``voltage_v`` (the recordings' median),
    else the nominal pack's. Unstated items keep the nominal bench's values."""
    if all(v is None for v in (priors.motor_kv_rpm_per_v, priors.cells, priors.propeller_diameter_m,
                                priors.propeller_pitch_m, priors.propeller_ct)):
        return None
    nom = BenchParams()
    notes: list[str] = []
    warnings: list[str] = []
    stated: dict[str, str] = {}
    volts = _supply_volts(priors, voltage_v, notes, warnings)
    kv = priors.motor_kv_rpm_per_v or nom.motor_kv_rpm_per_v
    if priors.motor_kv_rpm_per_v is not None:
        stated["motor_kv_rpm_per_v"] = f"--motor-kv {kv:g}"
    diameter = priors.propeller_diameter_m or nom.propeller_diameter_m
    if abs(diameter / nom.propeller_diameter_m - 1.0) < 1e-9:  # 12 in x 0.0254 is not 0.3048 in floats
        diameter = nom.propeller_diameter_m
    ct, cp = _propeller_coefficients(priors, diameter, notes, stated)
    p = dataclasses.replace(nom, motor_kv_rpm_per_v=float(kv), propeller_diameter_m=float(diameter),
                            propeller_ct=float(ct), propeller_cp=float(cp),
                            propeller_mass_kg=nom.propeller_mass_kg * (diameter / nom.propeller_diameter_m) ** 3)
    if priors.cells is not None:
        p = dataclasses.replace(p, battery_cells=int(priors.cells))
    p = _resized_by_power(p, kv, volts, notes)
    factors = {"motor_kv_rpm_per_v": KV_RANGE_FACTOR, "propeller_cp": CP_RANGE_FACTOR}
    ranges = {n: (getattr(p, n) / f, getattr(p, n) * f) for n, f in factors.items() if n in stated}
    return PhysicsStart(p, ranges, stated, notes, warnings)


def _supply_volts(priors: MotorPriors, voltage_v: float | None, notes: list[str], warnings: list[str]) -> float:
    """The supply ``physics_start`` sizes the bench for (V): the stated cells at the middle of
    CELL_VOLTAGE_RANGE_V (warned when the recordings' median ``voltage_v`` is no such pack), else
    ``voltage_v``, else the nominal pack's."""
    cell_v = 0.5 * sum(CELL_VOLTAGE_RANGE_V)
    if priors.cells is not None:
        volts = priors.cells * cell_v
        notes.append(f"supply sized at {volts:.1f} V ({priors.cells} cells x {cell_v:g} V)")
        lo, hi = (priors.cells * v for v in CELL_VOLTAGE_PLAUSIBLE_V)
        if voltage_v is not None and not lo <= voltage_v <= hi:
            warnings.append(f"--cells {priors.cells}: the recordings' median battery voltage {voltage_v:.2f} V is "
                            f"outside {lo:.1f}-{hi:.1f} V ({CELL_VOLTAGE_PLAUSIBLE_V[0]:g}-"
                            f"{CELL_VOLTAGE_PLAUSIBLE_V[1]:g} V per cell): another pack than the one stated?")
        return volts
    if voltage_v is not None:
        notes.append(f"supply sized at the recordings' median {voltage_v:.2f} V (no --cells)")
        return voltage_v
    return BenchParams().battery_cells * cell_v


def _propeller_coefficients(priors: MotorPriors, diameter: float, notes: list[str],
                            stated: dict[str, str]) -> tuple[float, float]:
    """(CT, CP) of the stated propeller of ``diameter`` (m): CT stated, else from the pitch, else
    the nominal propeller's; CP from CT by momentum theory. CP counts as stated (``stated``) when
    the diameter and the pitch or CT were."""
    nom = BenchParams()
    if priors.propeller_ct is not None:
        ct, ct_how = priors.propeller_ct, f"--propeller-ct {priors.propeller_ct:g}"
    elif priors.propeller_pitch_m is not None:
        ct = propeller_ct_from_geometry(diameter, priors.propeller_pitch_m, nom.propeller_ct, nom.propeller_diameter_m)
        ct_how = f"pitch/diameter {priors.propeller_pitch_m / diameter:.3g} (CT ~ sqrt(P/D))"
    else:
        ct, ct_how = nom.propeller_ct, "the nominal 12x4.5's (no --prop-pitch-in)"
    cp = propeller_cp_from_ct(ct, figure_of_merit(nom.propeller_ct, nom.propeller_cp))
    notes.append(f"propeller {diameter / INCH_M:.3g} in, CT {ct:.3g} from {ct_how}, CP {cp:.3g} by momentum theory")
    pitch_in = None if priors.propeller_pitch_m is None else priors.propeller_pitch_m / INCH_M
    if priors.propeller_diameter_m is not None and (pitch_in is not None or priors.propeller_ct is not None):
        stated["propeller_cp"] = " ".join(
            [f"--prop-diameter-in {diameter / INCH_M:g}"]
            + ([f"--prop-pitch-in {pitch_in:g}"] if pitch_in is not None else [])
            + ([f"--propeller-ct {priors.propeller_ct:g}"] if priors.propeller_ct is not None else []))
    return ct, cp


def _resized_by_power(p: BenchParams, kv: float, volts: float, notes: list[str]) -> BenchParams:
    """``p``'s motor and pack sized for its shaft power at full drive (``physics_start``'s rules:
    resistances as V^2 / P, no-load current as P / V, the motor's size with its torque)."""
    nom = BenchParams()
    cell_v = 0.5 * sum(CELL_VOLTAGE_RANGE_V)
    v_nom = nom.battery_cells * cell_v
    # full drive as on the nominal bench: the same share of the no-load speed, every effect off
    rpm_v = 2.0 * math.pi / 60.0
    off = {n: 0.0 for n in c.EFFECTS}
    share = full_drive_speeds(nom, off, v_nom)[0] / (nom.motor_kv_rpm_per_v * rpm_v * v_nom)
    w_nom = share * nom.motor_kv_rpm_per_v * rpm_v * v_nom
    w_full = share * kv * rpm_v * volts
    def snap(x: float) -> float:
        """1 for a ratio a rounding error from 1: the nominal bench stated as itself stays bit for bit."""
        return 1.0 if abs(x - 1.0) < 1e-9 else x

    power = snap((p.torque_coefficient * w_full**3) / (nom.torque_coefficient * w_nom**3))
    torque = snap(power * w_nom / w_full)
    v = snap(volts / v_nom)
    p = dataclasses.replace(
        p,
        winding_resistance_ohm=nom.winding_resistance_ohm * v**2 / power,
        esc_resistance_ohm=nom.esc_resistance_ohm * v**2 / power,
        motor_no_load_current_a=nom.motor_no_load_current_a * power / v,
        battery_series_resistance_ohm=nom.battery_series_resistance_ohm * v / power,
        motor_rotor_inertia_kg_m2=nom.motor_rotor_inertia_kg_m2 * torque,
        motor_thermal_capacity_j_per_k=nom.motor_thermal_capacity_j_per_k * torque,
        motor_thermal_resistance_k_per_w=nom.motor_thermal_resistance_k_per_w / torque,
    )
    notes.append(f"full drive ~{w_full:.0f} rad/s, {power * nom.torque_coefficient * w_nom**3:.0f} W shaft power "
                 f"({power:.2g}x the nominal bench's): winding {p.winding_resistance_ohm * 1e3:.3g} mOhm, "
                 f"no-load current {p.motor_no_load_current_a:.2g} A, rotor inertia {p.rotor_inertia_kg_m2:.3g} kg m^2")
    return p
