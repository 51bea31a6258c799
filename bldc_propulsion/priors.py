"""What the user says of their motor, propeller, pack and vehicle: the priors of a fit.

A recording without current or thrust cannot tell the package's nominal bench (a 12 in
propeller on an AXI 2212 at 3S) from a 5 in quad propeller on a 2300 kv motor at 6S: without
these numbers a physics fit starts from the nominal bench and a thrust law has no b. Every
command that fits a model (``train``, ``discrepancy``) takes the same options, read here once;
what is not given stays unknown (None), never silently the nominal bench's.
"""

from __future__ import annotations

import argparse
import math
from dataclasses import dataclass

from .errors import BadInputError

INCH_M = 0.0254
#: ISA sea level, 15 C: the density a stated CT is taken at.
AIR_DENSITY_KG_M3 = 1.225
STANDARD_GRAVITY_M_S2 = 9.80665


@dataclass(frozen=True)
class MotorPriors:
    """What the user stated (SI; None: not stated)."""

    motor_kv_rpm_per_v: float | None = None
    pole_count: int | None = None  #: magnet poles (14 on most quad outrunners): eRPM = RPM x poles / 2
    cells: int | None = None  #: LiPo cells in series
    propeller_diameter_m: float | None = None
    propeller_pitch_m: float | None = None
    propeller_ct: float | None = None  #: static thrust coefficient T = CT rho n^2 D^4 (n in rev/s)
    thrust_coefficient: float | None = None  #: b in T = b w^2 (N s^2/rad^2), stated directly
    vehicle_mass_kg: float | None = None  #: with motor_count: b from the hover condition
    motor_count: int | None = None

    def motor_options(self) -> list[str]:
        """The options of the motor and propeller (not of b) the user gave, as spelled on the
        command line: what a command that has no motor to size names when it refuses them."""
        names = {"motor_kv_rpm_per_v": "--motor-kv", "pole_count": "--pole-count", "cells": "--cells",
                 "propeller_diameter_m": "--prop-diameter-in", "propeller_pitch_m": "--prop-pitch-in"}
        return [opt for name, opt in names.items() if getattr(self, name) is not None]

    @property
    def stated(self) -> bool:
        """Anything was stated."""
        return any(v is not None for v in vars(self).values())

    def thrust_coefficient_from_ct(self) -> float | None:
        """b = CT rho D^4 / (4 pi^2) from a stated CT and diameter (T = CT rho n^2 D^4, w = 2 pi n)."""
        if self.propeller_ct is None or self.propeller_diameter_m is None:
            return None
        return self.propeller_ct * AIR_DENSITY_KG_M3 * self.propeller_diameter_m**4 / (4.0 * math.pi**2)

    def hover_thrust_n(self) -> float | None:
        """Thrust per motor at hover, m g / n, from a stated mass and motor count."""
        if self.vehicle_mass_kg is None or self.motor_count is None:
            return None
        return self.vehicle_mass_kg * STANDARD_GRAVITY_M_S2 / self.motor_count


def _positive(kind: type, hi: float):  # noqa: ANN202 - an argparse type
    def parse(text: str) -> float | int:
        try:
            value = kind(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not {'an integer' if kind is int else 'a number'}") from None
        if not (math.isfinite(value) and 0 < value <= hi):
            raise argparse.ArgumentTypeError(f"{text!r} must be > 0 and <= {hi:g}")
        return value
    parse.__name__ = kind.__name__
    return parse


def add_prior_arguments(p: argparse.ArgumentParser, thrust: bool = True) -> None:
    """The options of ``MotorPriors`` (inches where propellers are named in inches)."""
    g = p.add_argument_group("your motor, propeller and vehicle (priors of the fit; default: not stated)")
    g.add_argument("--motor-kv", type=_positive(float, 1e5), metavar="RPM_PER_V",
                   help="the motor's rated Kv (rpm/V)")
    g.add_argument("--pole-count", type=_positive(int, 100), metavar="N",
                   help="magnet poles of the motor (e.g. 14); electrical RPM = RPM x N / 2")
    g.add_argument("--cells", type=_positive(int, 24), metavar="N", help="LiPo cells in series (e.g. 4 for 4S)")
    g.add_argument("--prop-diameter-in", type=_positive(float, 100.0), metavar="IN",
                   help="propeller diameter (inches, e.g. 5 for a 5x4.3)")
    g.add_argument("--prop-pitch-in", type=_positive(float, 100.0), metavar="IN",
                   help="propeller pitch (inches, e.g. 4.3 for a 5x4.3)")
    if thrust:
        g.add_argument("--thrust-coefficient", type=_positive(float, 1e-2), metavar="B",
                       help="b in thrust = b w^2 (N s^2/rad^2), when no recording has /thrust/measured")
        g.add_argument("--propeller-ct", type=_positive(float, 1.0), metavar="CT",
                       help="static thrust coefficient CT (T = CT rho n^2 D^4); with --prop-diameter-in gives b")
        g.add_argument("--vehicle-mass-kg", type=_positive(float, 1e4), metavar="KG",
                       help="take-off mass; with --motor-count gives b from hover (mean thrust = m g / n)")
        g.add_argument("--motor-count", type=_positive(int, 64), metavar="N", help="motors lifting the vehicle")


def priors_from_args(args: argparse.Namespace) -> MotorPriors:
    """``MotorPriors`` from parsed ``add_prior_arguments`` options; options that go together
    are checked together (BadInputError naming them)."""
    get = lambda name: getattr(args, name, None)  # noqa: E731
    inch = lambda v: None if v is None else v * INCH_M  # noqa: E731
    priors = MotorPriors(
        motor_kv_rpm_per_v=get("motor_kv"), pole_count=get("pole_count"), cells=get("cells"),
        propeller_diameter_m=inch(get("prop_diameter_in")), propeller_pitch_m=inch(get("prop_pitch_in")),
        propeller_ct=get("propeller_ct"), thrust_coefficient=get("thrust_coefficient"),
        vehicle_mass_kg=get("vehicle_mass_kg"), motor_count=get("motor_count"),
    )
    if (priors.vehicle_mass_kg is None) != (priors.motor_count is None):
        raise BadInputError("--vehicle-mass-kg and --motor-count go together (b from hover needs both)")
    if priors.propeller_ct is not None and priors.propeller_diameter_m is None:
        raise BadInputError("--propeller-ct: needs --prop-diameter-in (b = CT rho D^4 / 4 pi^2)")
    if priors.pole_count is not None and priors.pole_count % 2:
        raise BadInputError(f"--pole-count {priors.pole_count}: a motor has an even number of magnet poles")
    return priors
