"""``train --kind physics`` with the supply current a stand (or one ESC's telemetry) records: known
truth from the plant itself. From speed, command and voltage alone Kv trades with the throttle
map's exponent and CP (a motor 30 % off its Kv fits the speed as well); the supply current, which
an ESC draws as duty x the motor current, tells them apart."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from bldc_propulsion import contract as c
from bldc_propulsion.physics import fit as pf
from bldc_propulsion.physics.config import start_model
from bldc_propulsion.physics.lag import lag_gain
from bldc_propulsion.physics.plant import motor_response, motor_response_with_current
from bldc_propulsion.physics.sizing import physics_start
from bldc_propulsion.priors import INCH_M, MotorPriors
from bldc_propulsion.recordings import Signals
from bldc_propulsion.training.fit_physics import (
    HELD,
    SUPPLY_HELD,
    SpeedAndCurrent,
    own_supply_current,
    settled_rows,
    train_physics,
)

#: What the user states: a 1900 kv motor on a 7x5.6 propeller (the esc_test F80's rating).
PRIORS = MotorPriors(motor_kv_rpm_per_v=1900.0, propeller_diameter_m=7 * INCH_M, propeller_pitch_m=5.6 * INCH_M)
SUPPLY_V = 16.0
#: The truth: the stated motor resized, but 1700 kv behind an ESC whose map bends (x^0.85).
TRUE_KV, TRUE_EXPONENT = 1700.0, 0.85
EFFECTS = {**{n: 1.0 for n in c.EFFECTS}, "spin_down_asymmetry": 0.0}
#: The bench: a supply that sags 40 mV/A, a current channel low-passed at 0.3 s (as a stand's is).
SAG_OHM, CURRENT_TAU_S = 0.04, 0.3
SPEED_NOISE, CURRENT_NOISE = 5.0, 0.05


def truth():
    start = physics_start(PRIORS, SUPPLY_V)
    assert start is not None
    return dataclasses.replace(start.params, motor_kv_rpm_per_v=TRUE_KV, esc_throttle_exponent=TRUE_EXPONENT,
                               sim_step_s=0.005)


def recording(name: str, levels_us: list[float], seed: int, hold_s: float = 3.0) -> Signals:
    """A staircase on the true plant: speed and low-passed supply current with noise, the supply's
    voltage recorded as the ESC sees it (``battery/voltage``: no battery filter)."""
    p = truth()
    t_ev = np.arange(0.0, len(levels_us) * hold_s, 0.02)
    level = np.repeat(np.asarray(levels_us) / c.PWM_PERIOD_US, round(hold_s / 0.02))[:len(t_ev)]
    t = np.arange(0.0, t_ev[-1], 0.01)
    v = np.full_like(t, SUPPLY_V)
    for _ in range(3):  # the supply's sag under the current it feeds
        w, i = motor_response_with_current(p, EFFECTS, (t_ev, level), (t, v), t, SUPPLY_V)
        v = SUPPLY_V - SAG_OHM * i
    a, measured = lag_gain(0.01, CURRENT_TAU_S), np.zeros_like(i)
    for k in range(1, len(i)):
        measured[k] = measured[k - 1] + a * (i[k] - measured[k - 1])
    rng = np.random.default_rng(seed)
    speed = w + rng.normal(0.0, SPEED_NOISE, len(t))
    return Signals(path=name, sha256=name, t=t, pwm=np.interp(t, t_ev, level), voltage=v, speed=speed, thrust=None,
                   current=measured + rng.normal(0.0, CURRENT_NOISE, len(t)), speed_source="rotor/speed",
                   voltage_source=c.bare(c.TOPIC_BATTERY_VOLTAGE), pwm_events=(t_ev, level), voltage_events=(t, v),
                   speed_events=(t, speed))


@pytest.fixture(scope="module")
def recordings() -> tuple[list[Signals], list[Signals]]:
    train = [recording("a", [1150, 1250, 1350, 1450, 1550, 1650, 1400, 1200], 0),
             recording("b", [1300, 1500, 1700, 1600, 1350, 1200], 1)]
    return train, [recording("v", [1250, 1600, 1450, 1200, 1550], 2)]


def test_the_plant_current_is_duty_times_the_motor_current():
    """Hand check at steady state: the supply current times the supply voltage is the motor's
    electrical input, back-EMF x current plus the resistive loss, i.e. what the speed path runs."""
    p = dataclasses.replace(truth(), esc_throttle_exponent=1.0)
    eff = {n: 0.0 for n in c.EFFECTS}  # no dead time, no heating, no inertia: a plain steady state
    t = np.arange(0.0, 2.0, 0.01)
    cmd = (np.array([0.0]), np.array([1500.0 / c.PWM_PERIOD_US]))
    w, i_supply = motor_response_with_current(p, eff, cmd, (t, np.full_like(t, SUPPLY_V)), t, SUPPLY_V)
    np.testing.assert_array_equal(w, motor_response(p, eff, cmd, (t, np.full_like(t, SUPPLY_V)), t, SUPPLY_V))
    duty = 0.5  # 1500 us on the straight map from 1000 to 2000 us (no deadband)
    ke = p.back_emf_constant_v_s_per_rad
    i_motor = (duty * SUPPLY_V - ke * w[-1]) / (p.winding_resistance_ohm + p.esc_resistance_ohm)
    assert i_supply[-1] == pytest.approx(duty * i_motor, rel=1e-9)
    # the torque balance the speed settled at: Kt i = friction + propeller drag
    assert ke * i_motor == pytest.approx(ke * p.motor_no_load_current_a + p.torque_coefficient * w[-1] ** 2, rel=1e-6)


def test_settled_rows_by_hand():
    t = np.arange(0.0, 5.0, 0.5)
    s = Signals(path="x", sha256="x", t=t, pwm=np.zeros_like(t), voltage=np.ones_like(t), speed=np.ones_like(t),
                thrust=None, current=np.where(t == 4.0, np.nan, 1.0),
                pwm_events=(np.array([0.0, 0.02, 1.0, 2.2, 2.4]), np.array([0.06, 0.06, 0.07, 0.07, 0.08])))
    # changes at 0 (first), 1.0 and 2.4 (2.2 repeats the level): held >= 1 s at 2.0 and from 3.5 on;
    # 4.0 has no current
    assert settled_rows(s, 1.0).tolist() == [4, 7, 9]
    assert own_supply_current(s) and not own_supply_current(dataclasses.replace(s, namespace="motor0"))
    assert SpeedAndCurrent.with_current([dataclasses.replace(s, current=None)]) is None


def test_the_supply_current_recovers_kv_and_the_map(recordings):
    """Known truth, stated Kv 12 % high: with the current the kept fit has the true Kv, exponent and
    CP; the supply's strength is held at 1 (its voltage is the one recorded); the model says so."""
    train, validation = recordings
    out = train_physics(train, validation, thrust_coefficient=None, priors=PRIORS)
    p, m = out.model.params, out.model
    assert p.motor_kv_rpm_per_v == pytest.approx(TRUE_KV, rel=0.02)  # measured 1700
    assert p.esc_throttle_exponent == pytest.approx(TRUE_EXPONENT, abs=0.02)  # measured 0.848
    assert p.propeller_cp == pytest.approx(truth().propeller_cp, rel=0.03)
    assert out.validation_rmse_rad_s < 1.3 * SPEED_NOISE
    assert all(d["effects"]["battery_voltage"] == 1.0 for d in out.candidates)
    meta = m.metadata["supply_current"]
    assert meta["held_effects"] == list(SUPPLY_HELD) and meta["recordings"] == ["a", "b"]
    kept = out.candidates[0]
    assert kept["train_current_rmse_a"] is not None and kept["train_current_rmse_a"] < 0.2  # A; noise 0.05


def test_without_the_current_kv_is_not_determined_by_the_speed(recordings):
    """Why the current: Kv held 30 % above the truth, the rest of the bent-map fit makes up for it
    on the speed (RMSE within 1 rad/s of the true Kv's, at the 5 rad/s noise), while the current
    then misses by far more than its noise. Calibrated from the true model, Kv held each time."""
    train, _ = recordings
    base, _, _ = start_model(None, PRIORS, SUPPLY_V)
    sizes = {}
    for kv in (TRUE_KV, 1.3 * TRUE_KV):
        model = dataclasses.replace(base, params=dataclasses.replace(truth(), motor_kv_rpm_per_v=kv),
                                    effects=EFFECTS).with_supply(train)
        hold = ("motor_kv_rpm_per_v", *HELD)
        speed_only = pf.fit_reference(model, pf.Data.of(train), hold=hold, held_effects=SUPPLY_HELD)
        both = SpeedAndCurrent.with_current(train)
        assert both is not None
        sizes[kv] = (np.sqrt(np.mean(pf.Data.of(train).residual(speed_only.model) ** 2)),
                     both.current_rmse(speed_only.model))
    (w_true, i_true), (w_off, i_off) = sizes[TRUE_KV], sizes[1.3 * TRUE_KV]
    assert w_off - w_true < 1.0 and w_off < 1.3 * SPEED_NOISE  # the speed cannot tell
    assert i_off > 5.0 * i_true and i_off > 10 * CURRENT_NOISE  # the current can
