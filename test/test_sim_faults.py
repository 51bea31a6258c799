"""Faults injected mid-recording by the simulator (sim/faults.py): each against known truth.

Truth here: the healthy run (before an onset, number for number), a healthy run on a bench
whose constants are the faulted ones, the plant's steady state computed by hand from the
constants (stiff supply, constant winding resistance: no history can blur it), and the battery
model's series resistance. Short held-command runs of a few seconds.
"""

from __future__ import annotations

import dataclasses
import json
import math

import numpy as np
import pytest

from bldc_propulsion import cli
from bldc_propulsion.bagio import open_recording
from bldc_propulsion.contract import PWM_FULL, TOPIC_TRUTH_SPEED, TOPIC_TRUTH_THRUST
from bldc_propulsion.errors import BadInputError
from bldc_propulsion.physics.params import BenchParams
from bldc_propulsion.sim import Fault, SimResult, parse_fault, simulate
from bldc_propulsion.sim.faults import FAULT_DOCS, apply_fault, format_faults, parse_faults

#: A command held from the start (PWM 0.08: about two thirds of the throttle range).
HELD = (np.array([0.0]), np.array([0.08]))
#: Stiff supply (the pack's open-circuit voltage, no sag) and a winding whose resistance does not
#: follow its temperature: the rotor's steady state then depends on the constants alone.
STIFF = {"battery_voltage": 0.0, "motor_heating": 0.0}
ARRAYS = [f.name for f in dataclasses.fields(SimResult) if f.type == "np.ndarray"]


def arrays_equal(a: SimResult, b: SimResult) -> list[str]:
    """Names of the arrays that differ (values or dtype)."""
    return [n for n in ARRAYS if not (getattr(a, n).dtype == getattr(b, n).dtype
                                      and np.array_equal(getattr(a, n), getattr(b, n)))]


def steady_speed(p: BenchParams, duty: float, volts: float) -> float:
    """The rotor's torque balance by hand: Kt i = Kt I0 + k w^2 with i = (duty V - Ke w) / R,
    R = winding + ESC (stiff supply, cold winding)."""
    ke = 60.0 / (2.0 * math.pi * p.motor_kv_rpm_per_v)
    r = p.winding_resistance_ohm + p.esc_resistance_ohm
    k = p.propeller_cp * p.air_density_kg_m3 * p.propeller_diameter_m**5 / (2.0 * math.pi) ** 3
    a, b, c = k, ke * ke / r, ke * p.motor_no_load_current_a - ke * duty * volts / r
    return (-b + math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)


def held_duty(p: BenchParams, level: float) -> float:
    """The ESC's linear throttle map above its start level (0.055 at nominal strength)."""
    start = 0.05 + p.esc_deadband_pwm
    return (level - start) / (PWM_FULL - start)


# --- no faults: today's simulator, bit for bit ----------------------------------------------------
@pytest.mark.parametrize("kwargs", [
    {"profile": "random_steps", "duration_s": 3.0, "seed": 5},
    {"profile": "chirp", "duration_s": 2.0, "seed": 2, "soc": 0.6, "effects": {"spin_down_asymmetry": 0.0}},
])
def test_no_faults_is_bit_identical_to_no_argument(kwargs):
    plain = simulate(**kwargs)
    empty = simulate(**kwargs, faults=())
    assert arrays_equal(plain, empty) == []
    assert plain.faults == () and empty.faults == ()
    assert plain.params == empty.params


def test_a_fault_that_changes_no_constant_leaves_the_run_bit_identical():
    """A bench without friction (I0 = 0): bearing_friction multiplies nothing, so the split run
    (state handed from one stretch to the next) must be the healthy run number for number: the
    speed, temperature, charge and polarisation are carried across the onset exactly."""
    p = BenchParams(motor_no_load_current_a=0.0)
    healthy = simulate("random_steps", 3.0, 7, params=p)
    split = simulate("random_steps", 3.0, 7, params=p, faults=[Fault("bearing_friction", 5.0, 1.234)])
    assert arrays_equal(healthy, split) == []
    assert split.faults == (Fault("bearing_friction", 5.0, 1.234),)


def test_before_the_onset_a_faulted_run_is_the_healthy_run():
    onset = 1.5
    faults = [Fault("propeller_damage", 0.2, onset), Fault("pack_resistance", 3.0, 2.0),
              Fault("motor_heating", 40.0, 2.5), Fault("bearing_friction", 4.0, onset)]
    healthy = simulate("random_steps", 3.0, 11)
    faulted = simulate("random_steps", 3.0, 11, faults=faults)
    k = int(round(onset / healthy.params.sim_step_s))
    for name in ("truth_speed", "truth_thrust", "truth_current", "truth_voltage",
                 "truth_temperature", "truth_soc"):
        h, f = getattr(healthy, name), getattr(faulted, name)
        assert np.array_equal(h[:k], f[:k]), name
        assert not np.array_equal(h[k + 50:], f[k + 50:]), name  # and it does change after
    # what the sensors saw before the onset (their samples interpolate the truth before it)
    before_adc = healthy.battery_t < onset - healthy.params.sim_step_s
    assert np.array_equal(healthy.battery_adc[before_adc], faulted.battery_adc[before_adc])
    n_tach = int((onset - healthy.params.sim_step_s) * healthy.tach_rate_hz)
    assert np.array_equal(healthy.tach[:n_tach], faulted.tach[:n_tach])
    assert np.array_equal(healthy.pwm, faulted.pwm)
    assert [f.onset_s for f in faulted.faults] == [1.5, 1.5, 2.0, 2.5]  # kept, by onset


# --- each fault against its truth ----------------------------------------------------------------
def test_propeller_damage_runs_as_a_bench_with_the_damaged_coefficients():
    p = BenchParams()
    onset = 1.0
    healthy = simulate("held", 4.0, 0, effects=STIFF, pwm=HELD)
    damaged = simulate("held", 4.0, 0, effects=STIFF, pwm=HELD,
                       faults=[Fault("propeller_damage", 0.1, onset)])
    truth_p = dataclasses.replace(p, propeller_ct=0.9 * p.propeller_ct, propeller_cp=0.9 * p.propeller_cp)
    assert apply_fault(p, Fault("propeller_damage", 0.1, onset)) == truth_p
    truth = simulate("held", 4.0, 0, effects=STIFF, pwm=HELD, params=truth_p)
    # after the transient: the rotor's time constant near 400 rad/s is J / (Ke^2/R + 2 k w) ~
    # 0.14 s, so 2 s after the onset e^-14 of the ~13 rad/s change is left: < 1e-5 rad/s
    late = damaged.truth_t >= onset + 2.0
    assert np.allclose(damaged.truth_speed[late], truth.truth_speed[late], rtol=1e-7, atol=0.0)
    # and both are the torque balance of the damaged propeller, by hand (full pack, 12.6 V)
    volts = 3 * p.battery_cell_ocv_v[-1]
    w_damaged = steady_speed(truth_p, held_duty(p, 0.08), volts)
    w_healthy = steady_speed(p, held_duty(p, 0.08), volts)
    assert damaged.truth_speed[-1] == pytest.approx(w_damaged, rel=1e-9)
    assert healthy.truth_speed[-1] == pytest.approx(w_healthy, rel=1e-9)
    assert np.all(damaged.truth_speed[late] > healthy.truth_speed[late] + 0.5 * (w_damaged - w_healthy))
    # thrust: b w^2 with the healthy b before the onset, 0.9 b after it
    k = int(round(onset / p.sim_step_s))
    b = p.thrust_coefficient
    assert np.allclose(damaged.truth_thrust[:k], b * damaged.truth_speed[:k] ** 2, rtol=1e-12, atol=0.0)
    assert np.allclose(damaged.truth_thrust[k:], 0.9 * b * damaged.truth_speed[k:] ** 2, rtol=1e-12, atol=0.0)


def test_propeller_damage_speeds_the_realistic_bench_up():
    healthy = simulate("held", 3.0, 0, pwm=HELD)
    damaged = simulate("held", 3.0, 0, pwm=HELD, faults=[Fault("propeller_damage", 0.1, 1.0)])
    late = healthy.truth_t >= 1.5
    assert np.all(damaged.truth_speed[late] > healthy.truth_speed[late] + 5.0)  # ~+3.5 % of ~330


def test_pack_resistance_doubles_the_sag_per_ampere():
    """Across the command step (a current jump of ~12 A in one 1 ms step) the terminal voltage
    moves by the series resistance times the current: the polarisation (30 s) and the open-circuit
    voltage move by < 1e-4 V in that step, 1e-5 of the drop: the measured slope is R_s to 1e-4."""
    p = BenchParams()
    cmd = (np.array([0.0, 2.0]), np.array([0.07, 0.09]))  # two load levels, after the onset
    onset = 1.0

    def sag_per_ampere(res: SimResult) -> float:
        di, dv = np.diff(res.truth_current), np.diff(res.truth_voltage)
        j = int(np.argmax(np.abs(di)))
        assert res.truth_t[j] > onset + 0.5 and abs(di[j]) > 5.0  # the step's current jump
        return float(-dv[j] / di[j])

    healthy = simulate("held", 3.0, 0, pwm=cmd)
    worn = simulate("held", 3.0, 0, pwm=cmd, faults=[Fault("pack_resistance", 2.0, onset)])
    assert sag_per_ampere(healthy) == pytest.approx(p.battery_series_resistance_ohm, rel=1e-4)
    assert sag_per_ampere(worn) == pytest.approx(2.0 * p.battery_series_resistance_ohm, rel=1e-4)
    late = worn.truth_t > 2.2
    assert np.all(worn.truth_voltage[late] < healthy.truth_voltage[late] - 0.2)  # ~12 A x 35 mOhm


def test_bearing_friction_slows_the_rotor_by_the_friction_torque():
    p = BenchParams()
    onset = 1.0
    healthy = simulate("held", 3.0, 0, pwm=HELD)
    worn = simulate("held", 3.0, 0, pwm=HELD, faults=[Fault("bearing_friction", 5.0, onset)])
    late = healthy.truth_t >= 1.3
    assert np.all(worn.truth_speed[late] < healthy.truth_speed[late] - 5.0)
    # stiff supply: the steady speed is the torque balance with five times the friction torque
    # (3 s after the onset: ~20 time constants of the rotor)
    stiff = simulate("held", 4.0, 0, effects=STIFF, pwm=HELD, faults=[Fault("bearing_friction", 5.0, onset)])
    five = dataclasses.replace(p, motor_no_load_current_a=5.0 * p.motor_no_load_current_a)
    volts = 3 * p.battery_cell_ocv_v[-1]
    assert stiff.truth_speed[-1] == pytest.approx(steady_speed(five, held_duty(p, 0.08), volts), rel=1e-9)


def test_motor_heating_runs_the_winding_30_k_hot_from_the_onset():
    onset = 1.0
    k = int(round(onset / BenchParams().sim_step_s))
    # resistance independent of temperature: nothing feeds back, so exactly +30 K throughout
    healthy = simulate("held", 4.0, 0, effects={"motor_heating": 0.0}, pwm=HELD)
    hot = simulate("held", 4.0, 0, effects={"motor_heating": 0.0}, pwm=HELD,
                   faults=[Fault("motor_heating", 30.0, onset)])
    rise = hot.truth_temperature - healthy.truth_temperature
    assert np.all(rise[:k] == 0.0)
    assert np.allclose(rise[k:], 30.0, rtol=0.0, atol=1e-9)
    assert np.array_equal(hot.truth_speed, healthy.truth_speed)
    # the realistic winding: its resistance rises 11.8 % (copper, 30 K), which changes the copper
    # loss, so the rise drifts from 30 K by the loss change integrated over the thermal capacity:
    # at this command the loss is < 50 W (full throttle, 15 A^2 x 0.2 Ohm, is 45 W), its change
    # < 11.8 % of it, ~6 W, over 3 s / 70 J/K: < 0.26 K. Tolerance 0.3 K.
    healthy = simulate("held", 4.0, 0, pwm=HELD)
    hot = simulate("held", 4.0, 0, pwm=HELD, faults=[Fault("motor_heating", 30.0, onset)])
    rise = hot.truth_temperature - healthy.truth_temperature
    assert rise[k] == pytest.approx(30.0, abs=1e-9)  # the jump, at the onset's step
    assert np.all(np.abs(rise[k:] - 30.0) < 0.3)
    late = hot.truth_t >= 1.3
    assert np.all(hot.truth_speed[late] < healthy.truth_speed[late] - 1.0)  # hotter copper, slower


def test_onsets_between_steps_and_several_faults():
    """A fault at an onset between two steps begins at the next step; a second fault later on
    leaves the stretch before it as the first fault alone made it."""
    one = simulate("random_steps", 2.0, 3, faults=[Fault("propeller_damage", 0.3, 0.5004)])
    two = simulate("random_steps", 2.0, 3, faults=[Fault("pack_resistance", 4.0, 1.2),
                                                   Fault("propeller_damage", 0.3, 0.5004)])
    healthy = simulate("random_steps", 2.0, 3)
    assert np.array_equal(one.truth_speed[:501], healthy.truth_speed[:501])
    assert not np.array_equal(one.truth_thrust[501:], healthy.truth_thrust[501:])
    assert np.array_equal(two.truth_speed[:1200], one.truth_speed[:1200])
    assert not np.array_equal(two.truth_voltage[1200:], one.truth_voltage[1200:])


# --- the specs ------------------------------------------------------------------------------------
def test_parse_fault_reads_what_format_writes():
    f = parse_fault("propeller_damage=0.1@20")
    assert f == Fault("propeller_damage", 0.1, 20.0) and f.spec == "propeller_damage=0.1@20"
    many = [f, Fault("motor_heating", 30, 2.5), Fault("pack_resistance", 1.5, 0)]
    assert format_faults(many) == "propeller_damage=0.1@20,motor_heating=30@2.5,pack_resistance=1.5@0"
    assert parse_faults(format_faults(many), "x") == many
    assert parse_faults("", "x") == []
    assert parse_fault(" bearing_friction = 3 @ 1e1 ") == Fault("bearing_friction", 3.0, 10.0)
    assert set(FAULT_DOCS) == {"propeller_damage", "pack_resistance", "bearing_friction", "motor_heating"}


@pytest.mark.parametrize("text, needle", [
    ("wear=1@2", "unknown fault 'wear' (known: propeller_damage, pack_resistance"),
    ("propeller_damage=0.95@2", "outside (0, 0.9]"),
    ("propeller_damage=0@2", "outside (0, 0.9]"),
    ("pack_resistance=1@2", "outside (1, 20]"),
    ("bearing_friction=51@2", "outside (1, 50]"),
    ("motor_heating=151@2", "outside (0, 150]"),
    ("motor_heating=nan@2", "SIZE nan is not a finite number"),
    ("motor_heating=30@-1", "TIME -1 is negative"),
    ("motor_heating=30@soon", "TIME soon is not a finite number"),
    ("motor_heating=30", "expected NAME=SIZE@TIME"),
    ("motor_heating@30", "expected NAME=SIZE@TIME"),
])
def test_bad_specs_name_the_option_the_text_and_the_problem(text, needle):
    with pytest.raises(BadInputError) as err:
        parse_fault(text, "--fault")
    msg = str(err.value)
    assert msg.startswith(f"--fault {text}: ") and needle in msg and "\n" not in msg


def test_simulate_refuses_an_onset_outside_the_run():
    with pytest.raises(BadInputError, match=r"--fault motor_heating=30@2: onset 2 s is not inside"):
        simulate("constant", 2.0, 0, faults=[Fault("motor_heating", 30.0, 2.0)])
    with pytest.raises(BadInputError, match="outside"):
        Fault("propeller_damage", 1.5, 1.0)  # checked when made, not only when parsed


# --- the command line and the recording -----------------------------------------------------------
def test_fault_round_trip_through_a_bag(tmp_path, capsys):
    for out in (tmp_path / "bag", tmp_path / "one.mcap"):
        code = cli.main(["simulate", "--profile", "constant", "--duration", "3", "--seed", "2",
                         "--fault", "propeller_damage=0.1@1.5", "--fault", "motor_heating=30@0.5",
                         "-o", str(out), "--json"])
        assert code == 0
        info = json.loads(capsys.readouterr().out)
        assert info["faults"] == ["motor_heating=30@0.5", "propeller_damage=0.1@1.5"]
        with open_recording(out) as rec:
            assert rec.faults == [Fault("motor_heating", 30.0, 0.5), Fault("propeller_damage", 0.1, 1.5)]
            ts, speed = rec.scalars(TOPIC_TRUTH_SPEED)
            _, thrust = rec.scalars(TOPIC_TRUTH_THRUST)
        b = BenchParams().thrust_coefficient
        running = speed > 100.0
        ratio = thrust[running] / (b * speed[running] ** 2)
        assert np.allclose(ratio[ts[running] < 1.5], 1.0, rtol=1e-12)  # the recorded truth
        assert np.allclose(ratio[ts[running] >= 1.5], 0.9, rtol=1e-12)
    assert "faults: motor_heating=30@0.5,propeller_damage=0.1@1.5" in (tmp_path / "bag" / "metadata.yaml").read_text()


def test_a_healthy_bag_has_no_faults_and_no_faults_key(tmp_path, capsys):
    out = tmp_path / "bag"
    assert cli.main(["simulate", "--profile", "constant", "--duration", "1", "-o", str(out)]) == 0
    with open_recording(out) as rec:
        assert rec.faults == []
    assert "faults" not in (out / "metadata.yaml").read_text()  # healthy bags: bytes as before


def test_a_bag_with_unreadable_faults_says_which_bag(tmp_path):
    from bldc_propulsion.bagio import BagWriter

    out = tmp_path / "odd"
    with BagWriter(out, custom_data={"faults": "gremlin=1@2"}) as bag:
        bag.write_float64("/pwm", 0.0, 0.05)
    with open_recording(out) as rec, pytest.raises(BadInputError, match=f"{out}: .*unknown fault 'gremlin'"):
        rec.faults  # noqa: B018  (the property reads the metadata)


@pytest.mark.parametrize("spec, needle", [
    ("gremlin=1@1", "--fault gremlin=1@1: unknown fault 'gremlin'"),
    ("pack_resistance=25@1", "--fault pack_resistance=25@1: SIZE 25 is outside (1, 20]"),
    ("pack_resistance=2@2", "--fault pack_resistance=2@2: onset 2 s is not inside the recording (0 to 2 s)"),
    ("pack_resistance=2@9", "onset 9 s is not inside"),
    ("pack_resistance:2@1", "--fault pack_resistance:2@1: expected NAME=SIZE@TIME"),
])
def test_bad_fault_is_one_line_exit_2_and_no_bag(tmp_path, capsys, spec, needle):
    out = tmp_path / "bag"
    code = cli.main(["simulate", "--profile", "constant", "--duration", "2", "--fault", spec, "-o", str(out)])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and needle in err[0]
    assert not out.exists()


def test_help_documents_every_fault(capsys):
    with pytest.raises(SystemExit):
        cli.main(["simulate", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "--fault NAME=SIZE@TIME" in text
    for name, doc in FAULT_DOCS.items():
        assert f"{name}: {' '.join(doc.split())}" in text
