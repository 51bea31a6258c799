"""Benches drawn per seed: the test protocol of the discrepancy workflow.

A workflow tuned on one bench can pass on that bench for the wrong reasons (thresholds that
happen to fit its constants). ``draw_bench(seed)`` gives another motor, propeller, pack, ESC and
sensor set for every seed, within the spread of real hobby hardware (issue 11):

- constants: Kv +-15 %, winding resistance +-30 %, rotor inertia +-30 % (propeller and bell
  together), CT and CP +-20 % each, dead time 20-60 ms, ESC start level 0.052-0.058, pack series
  resistance and polarisation RC +-50 %, the OCV curve's shape, tachometer and ADC noise, blade
  spacing/width asymmetry; and, beyond the issue's list (an independent bench differs there
  too), the motor's thermal capacity and thermal resistance +-50 % each (its thermal time
  constant 0.25-2.25x) and its no-load (friction) current +-50 %;
- structure: half of the benches get a bent ESC throttle map (duty = x^0.8 ... x^1.25), half a
  second, slower RC branch in the pack (a two-RC battery);

and ``draw_strength(effect, seed)`` the hidden effect's strength (0.5-2x nominal, log-uniform;
the spin-down braking removed 50-100 %, since 1 is all of it). Physics stays in ``bench.py``:
these are only parameter draws. ``model_strength`` converts a hidden effect's true size on a drawn
bench into the strength of the nominal bench's physics (what ``discrepancy --physics`` fits).
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np

from ..physics.params import BenchParams, check_params

#: Seed offset of the bench draw, so a bench seed and the recordings' seeds are independent streams.
_BENCH_STREAM = 7_919


def _rng(seed: int, what: str) -> np.random.Generator:
    return np.random.default_rng([_BENCH_STREAM, int(seed), sum(map(ord, what))])


def draw_bench(seed: int, base: BenchParams | None = None) -> BenchParams:
    """The bench of ``seed`` (see the module docstring); ``base`` defaults to the nominal one."""
    b = base or BenchParams()
    r = _rng(seed, "bench")

    def scale(x: float, rel: float) -> float:
        return float(x * r.uniform(1.0 - rel, 1.0 + rel))

    inertia = r.uniform(0.7, 1.3)
    # OCV shape: the distance below full charge stretched, plus a smooth bump on the plateau
    soc = np.asarray(b.battery_cell_soc)
    ocv = np.asarray(b.battery_cell_ocv_v)
    top = ocv[-1]
    bent = top - (top - ocv) * r.uniform(0.85, 1.15) + r.uniform(-0.03, 0.03) * np.sin(np.pi * soc)
    bent = np.maximum.accumulate(bent + 1e-4 * np.arange(len(bent)))  # still rising with charge
    two_rc = r.uniform() < 0.5
    bent_map = r.uniform() < 0.5
    p = dataclasses.replace(
        b,
        motor_kv_rpm_per_v=scale(b.motor_kv_rpm_per_v, 0.15),
        winding_resistance_ohm=scale(b.winding_resistance_ohm, 0.30),
        propeller_mass_kg=b.propeller_mass_kg * inertia,
        motor_rotor_inertia_kg_m2=b.motor_rotor_inertia_kg_m2 * inertia,
        propeller_ct=scale(b.propeller_ct, 0.20),
        propeller_cp=scale(b.propeller_cp, 0.20),
        esc_input_delay_s=float(r.uniform(0.020, 0.060)),
        esc_deadband_pwm=float(r.uniform(0.002, 0.008)),
        esc_throttle_exponent=float(math.exp(r.uniform(math.log(0.8), math.log(1.25)))) if bent_map else 1.0,
        battery_series_resistance_ohm=scale(b.battery_series_resistance_ohm, 0.5),
        battery_polarisation_resistance_ohm=scale(b.battery_polarisation_resistance_ohm, 0.5),
        battery_polarisation_time_constant_s=scale(b.battery_polarisation_time_constant_s, 0.5),
        battery_polarisation2_resistance_ohm=float(r.uniform(0.005, 0.02)) if two_rc else 0.0,
        battery_polarisation2_time_constant_s=float(r.uniform(100.0, 400.0)),
        battery_cell_ocv_v=tuple(float(v) for v in bent),
        tach_noise_v=float(r.uniform(0.01, 0.04)),
        adc_noise_v=float(r.uniform(0.001, 0.006)),
        tach_blade_spacing_asymmetry_fraction=float(r.uniform(0.0, 0.06)),
        tach_blade_width_asymmetry_fraction=float(r.uniform(0.0, 0.10)),
    )
    # drawn after the others, so that every constant above is the same bench's as before
    p = dataclasses.replace(
        p,
        motor_thermal_capacity_j_per_k=scale(b.motor_thermal_capacity_j_per_k, 0.5),
        motor_thermal_resistance_k_per_w=scale(b.motor_thermal_resistance_k_per_w, 0.5),
        motor_no_load_current_a=scale(b.motor_no_load_current_a, 0.5),
    )
    return check_params(p)


def draw_far_bench(seed: int, base: BenchParams | None = None) -> BenchParams:
    """``draw_bench(seed)`` moved to another motor class: a probe of scale, not the issue's protocol.

    An independent bench need not be a 12 in propeller on 3S: this one draws the pack (3S or
    4S), the no-load speed (0.7-1.4x, Kv set from it and the pack), the shaft power at full
    speed (0.5-2x, the propeller's diameter from it: P ~ w^3 D^5, its mass ~ D^3) and sizes the
    rest with the power, as a motor and pack of that class are built: winding resistance ~ V^2/P,
    rotor inertia, thermal capacity and pack capacity ~ P, thermal resistance ~ 1/P. The rotor's
    time constant then scales as 1/speed and every figure in rad/s with the speed, which is
    what catches a threshold that is absolute where it should be relative."""
    p = draw_bench(seed, base)
    nominal = base or BenchParams()
    r = _rng(seed, "far")
    cells = int(r.choice([3, 4]))
    volts = cells / nominal.battery_cells
    speed = float(math.exp(r.uniform(math.log(0.7), math.log(1.4))))
    power = float(math.exp(r.uniform(math.log(0.5), math.log(2.0))))
    diameter = (power / speed**3) ** 0.2
    p = dataclasses.replace(
        p,
        battery_cells=cells,
        battery_capacity_ah=p.battery_capacity_ah * power * float(r.uniform(0.7, 1.4)),
        battery_series_resistance_ohm=p.battery_series_resistance_ohm * volts / power,
        battery_polarisation_resistance_ohm=p.battery_polarisation_resistance_ohm * volts / power,
        battery_polarisation2_resistance_ohm=p.battery_polarisation2_resistance_ohm * volts / power,
        motor_kv_rpm_per_v=p.motor_kv_rpm_per_v * speed / volts,
        winding_resistance_ohm=p.winding_resistance_ohm * volts**2 / power,
        motor_no_load_current_a=p.motor_no_load_current_a * power / volts,
        motor_rotor_inertia_kg_m2=p.motor_rotor_inertia_kg_m2 * power,
        motor_thermal_capacity_j_per_k=p.motor_thermal_capacity_j_per_k * power,
        motor_thermal_resistance_k_per_w=p.motor_thermal_resistance_k_per_w / power,
        propeller_diameter_m=p.propeller_diameter_m * diameter,
        propeller_mass_kg=p.propeller_mass_kg * diameter**3,
    )
    return check_params(p)


#: The bench draws by name (experiments' --far-bench).
DRAWS = {"random": draw_bench, "far": draw_far_bench}


def draw_strength(effect: str, seed: int) -> float:
    """The hidden effect's strength for ``seed``: log-uniform 0.5-2 (spin-down: 0.5-1)."""
    r = _rng(seed, "strength:" + effect)
    if effect == "spin_down_asymmetry":
        return float(r.uniform(0.5, 1.0))
    return float(math.exp(r.uniform(math.log(0.5), math.log(2.0))))


def model_strength(effect: str, strength: float, bench: BenchParams, model: BenchParams | None = None) -> float:
    """The strength the physics model with constants ``model`` (default nominal) needs to
    reproduce ``effect`` at ``strength`` on ``bench``: the effects scale bench constants (dead
    time, start level, inertia), so a drawn bench's truth is in the model's units only after this.

    ``battery_voltage``: 1 whenever the effect is on. The bench's strength scales the sag the
    motor sees AND the terminal voltage the battery ADC records (``bench._integrate``), so the
    recorded voltage is exactly what the motor saw; the model's strength scales the recorded
    voltage's deviation from a stiff supply, and 1 reproduces the bench at any true strength
    (test_sim.py::test_the_recorded_voltage_is_what_the_motor_sees_at_any_battery_strength)."""
    if effect == "battery_voltage":
        return 1.0 if strength > 0.0 else 0.0
    m = model or BenchParams()
    ratio = {
        "input_delay": bench.esc_input_delay_s / m.esc_input_delay_s,
        "esc_deadband": bench.esc_deadband_pwm / m.esc_deadband_pwm,
        "rotor_lag": bench.rotor_inertia_kg_m2 / m.rotor_inertia_kg_m2,
        # the winding's resistance rises at alpha * losses / C_th under a load: a lighter motor heats
        # faster per unit of the copper coefficient (where it levels off, alpha * R_th * losses, is
        # the thermal resistance's, which discrepancy --physics fits along: physics.COMPANIONS)
        "motor_heating": (bench.copper_temperature_coefficient_per_k / bench.motor_thermal_capacity_j_per_k)
        / (m.copper_temperature_coefficient_per_k / m.motor_thermal_capacity_j_per_k),
    }.get(effect, 1.0)
    return float(strength * ratio)


def describe(bench: BenchParams) -> dict[str, object]:
    """The drawn constants that differ from the nominal bench (for experiment logs)."""
    nominal = BenchParams()
    return {f.name: getattr(bench, f.name) for f in dataclasses.fields(bench)
            if getattr(bench, f.name) != getattr(nominal, f.name) and f.name != "battery_cell_ocv_v"}
