"""Features and the thrust estimator against hand-computed values."""

from __future__ import annotations

import math

import numpy as np
import pytest

from bldc_propulsion.core.estimator import ThrustEstimator
from bldc_propulsion.core.features import (
    FEATURES,
    Feature,
    FeatureState,
    PwmLowpass,
    compute_features,
    register_feature,
)
from bldc_propulsion.core.status import OK, WARN
from bldc_propulsion.errors import BadInputError, ModelError
from bldc_propulsion.model import NetworkModel
from bldc_propulsion.physics.fallback import FallbackModel, fallback_model

NAMES = ("battery_voltage", "pwm", "pwm_filtered")


def small_model(**kw) -> NetworkModel:
    """A 3-2-1 network with chosen weights."""
    args = dict(
        input_names=NAMES,
        input_min=np.array([9.0, 0.0, 0.0]),
        input_max=np.array([12.6, 1.0, 1.0]),
        output_min=0.0,
        output_max=800.0,
        W1=np.array([[0.5, -0.3, 1.2], [-0.7, 0.9, 0.4]]),
        b1=np.array([0.1, -0.2]),
        W2=np.array([0.8, -0.6]),
        b2=0.05,
        pwm_tau_s=0.25,
        thrust_coefficient=3e-5,
    )
    args.update(kw)
    return NetworkModel(**args)


def by_hand(v, pwm, pwm_f):
    """The same network with math.tanh, written out."""
    x = [v, pwm, pwm_f]
    lo, hi = [9.0, 0.0, 0.0], [12.6, 1.0, 1.0]
    xs = [2 * (x[i] - lo[i]) / (hi[i] - lo[i]) - 1 for i in range(3)]
    h1 = math.tanh(0.5 * xs[0] - 0.3 * xs[1] + 1.2 * xs[2] + 0.1)
    h2 = math.tanh(-0.7 * xs[0] + 0.9 * xs[1] + 0.4 * xs[2] - 0.2)
    ys = 0.8 * h1 - 0.6 * h2 + 0.05
    return (ys + 1) / 2 * 800.0


def test_prediction_equals_network_by_hand():
    est = ThrustEstimator(small_model())
    assert not est.predict(0.0).ready
    est.update_pwm(0.0, 0.075)  # scaled 0.5
    assert not est.predict(0.0).ready  # voltage still missing
    est.update_voltage(0.0, 11.0)
    p = est.predict(0.0)
    assert p.ready and not p.clipped
    w = by_hand(11.0, 0.5, 0.5)
    assert p.speed_rad_s == pytest.approx(w, rel=1e-12)
    assert p.thrust_n == pytest.approx(3e-5 * w * w, rel=1e-12)
    # a step to 0.09 (scaled 0.8): pwm jumps, pwm_filtered follows exp(-t/tau)
    est.update_pwm(1.0, 0.09)
    p = est.predict(1.1)
    pf = 0.8 + (0.5 - 0.8) * math.exp(-0.1 / 0.25)
    assert p.speed_rad_s == pytest.approx(by_hand(11.0, 0.8, pf), rel=1e-12)
    # the network's own forward agrees
    assert small_model().forward(np.array([11.0, 0.8, pf])) == pytest.approx(p.speed_rad_s, rel=1e-12)


def test_thrust_coefficient_argument_overrides_model():
    est = ThrustEstimator(small_model(), thrust_coefficient=1e-5)
    est.update_pwm(0.0, 0.08)
    est.update_voltage(0.0, 11.5)
    p = est.predict(0.5)
    assert p.thrust_n == pytest.approx(1e-5 * p.speed_rad_s**2)
    with pytest.raises(BadInputError):
        ThrustEstimator(small_model(), thrust_coefficient=-1.0)


def test_clipping_flagged_and_counted():
    est = ThrustEstimator(small_model())
    est.update_pwm(0.0, 0.075)
    est.update_voltage(0.0, 14.0)  # above the training range 9..12.6 V
    p = est.predict(0.0)
    assert p.clipped and p.speed_rad_s == pytest.approx(by_hand(12.6, 0.5, 0.5), rel=1e-12)
    assert est.clipped == 1 and est.clipped_by_input["battery_voltage"] == 1
    st = est.status()[0]
    assert st.level == WARN and "clipped" in st.message and st.values["clipped_battery_voltage"] == "1"
    est.update_voltage(1.0, 11.0)
    assert not est.predict(1.0).clipped
    assert est.status()[0].level == OK


def test_speed_clamped_at_zero():
    m = small_model(b2=-5.0)  # output far below output_min
    est = ThrustEstimator(m)
    est.update_pwm(0.0, 0.05)
    est.update_voltage(0.0, 11.0)
    p = est.predict(0.0)
    assert p.speed_rad_s == 0.0 and p.thrust_n == 0.0


@pytest.mark.parametrize("t, pwm", [(1.0, math.nan), (1.0, math.inf), (1.0, -0.01), (1.0, 0.25),
                                    (math.nan, 0.07), (0.5, 0.07)])
def test_bad_pwm_rejected_state_untouched(t, pwm):
    est = ThrustEstimator(small_model())
    est.update_pwm(0.9, 0.06)
    est.update_voltage(0.9, 11.0)
    before = est.predict(1.0)
    assert est.update_pwm(t, pwm) is False
    assert est.predict(1.0) == before
    assert est.pwm_rejected_value + est.pwm_rejected_time == 1


@pytest.mark.parametrize("t, v", [(1.0, math.nan), (1.0, -1.0), (1.0, 61.0), (0.5, 11.0)])
def test_bad_voltage_rejected(t, v):
    est = ThrustEstimator(small_model())
    est.update_pwm(0.9, 0.06)
    est.update_voltage(0.9, 11.0)
    before = est.predict(1.0)
    assert est.update_voltage(t, v) is False
    assert est.predict(1.0) == before
    assert est.voltage_rejected_value + est.voltage_rejected_time == 1


def test_pwm_filter_step_response():
    fs = FeatureState(["pwm_filtered"], {"pwm_filtered": {"tau_s": 0.25}})
    fs.update_pwm(0.0, 0.05)  # steady state at stop
    fs.update_pwm(1.0, 0.10)  # step to full
    for dt in (0.0, 0.01, 0.1, 0.25, 0.5, 1.0, 2.0):
        assert fs.values_at(1.0 + dt)["pwm_filtered"] == pytest.approx(1 - math.exp(-dt / 0.25), abs=1e-14)
    # the same with the command repeated at 50 Hz (the ESC's frame rate): exact discretisation
    fs2 = FeatureState(["pwm_filtered"])
    fs2.update_pwm(0.0, 0.05)
    for k in range(1, 101):
        fs2.update_pwm(1.0 + (k - 1) * 0.02, 0.10)
        t = 1.0 + (k - 1) * 0.02
        assert fs2.values_at(t)["pwm_filtered"] == pytest.approx(1 - math.exp(-(t - 1.0) / 0.25), abs=1e-12)


def _streams(seed=0):
    rng = np.random.default_rng(seed)
    pwm_t = np.cumsum(rng.uniform(0.005, 0.04, 400))
    pwm = np.clip(0.075 + 0.02 * np.sin(pwm_t) + rng.normal(0, 0.005, 400), 0.05, 0.1)
    pwm[50] = np.nan  # rejected by both paths
    pwm[60] = 0.5
    pwm_t[70] = pwm_t[69] - 0.1  # backwards
    volt_t = np.arange(0.0, pwm_t.max() + 1, 0.001)
    volt = 11.8 - 0.1 * volt_t + rng.normal(0, 0.01, len(volt_t))
    volt[100] = 99.0
    grid = np.arange(-0.5, pwm_t.max() + 0.5, 0.01)
    return grid, pwm_t, pwm, volt_t, volt


def test_batch_features_equal_streaming():
    grid, pwm_t, pwm, volt_t, volt = _streams()
    names = ["battery_voltage", "pwm", "pwm_filtered"]
    params = {"pwm_filtered": {"tau_s": 0.3}}
    X = compute_features(grid, pwm_t, pwm, volt_t, volt, names, params)
    est = ThrustEstimator(small_model(pwm_tau_s=0.3))
    fs = est.features
    # messages arrive in list order; a late (backwards-stamped) one arrives after its predecessor
    arrival = np.maximum.accumulate(np.nan_to_num(pwm_t, nan=-np.inf))
    events = sorted([(a, 0, i) for i, a in enumerate(arrival)] + [(t, 1, i) for i, t in enumerate(volt_t)]
                    + [(t, 2, k) for k, t in enumerate(grid)])
    S = np.full_like(X, np.nan)
    for _, kind, i in events:
        if kind == 0:
            est.update_pwm(pwm_t[i], pwm[i])
        elif kind == 1:
            est.update_voltage(volt_t[i], volt[i])
        else:
            S[i] = fs.vector_at(grid[i])
    np.testing.assert_allclose(X, S, rtol=0, atol=1e-12, equal_nan=True)
    assert np.isnan(X[0]).all() and np.isfinite(X[-1]).all()
    assert est.pwm_rejected_value == 2 and est.pwm_rejected_time == 1 and est.voltage_rejected_value == 1


def test_generic_registered_feature_batch_equals_streaming():
    @register_feature
    class PwmLagTest(PwmLowpass):
        name = "test_pwm_lag_2"
        defaults = {"tau_s": 0.1}

    class Generic(PwmLagTest):  # the base class's generic batch (runs the streaming code)
        batch = Feature.batch

    try:
        grid, pwm_t, pwm, volt_t, volt = _streams(1)
        X = compute_features(grid, pwm_t, pwm, volt_t, volt, ["test_pwm_lag_2"], {"test_pwm_lag_2": {"tau_s": 0.07}})
        ok = np.isfinite(pwm)
        ok &= (pwm >= 0) & (pwm <= 0.2)
        okt = np.concatenate(([True], pwm_t[1:] >= np.maximum.accumulate(np.where(ok, pwm_t, -np.inf))[:-1]))
        sel = ok & okt
        g = Generic(tau_s=0.07).batch(grid, pwm_t[sel], pwm[sel], volt_t, volt)
        np.testing.assert_allclose(X[:, 0], g, rtol=0, atol=1e-12, equal_nan=True)
    finally:
        FEATURES.pop("test_pwm_lag_2", None)


def test_unknown_feature_and_parameter_named():
    with pytest.raises(ModelError, match="no_such_input"):
        FeatureState(["pwm", "no_such_input"])
    with pytest.raises(ModelError, match="tau_ms"):
        FeatureState(["pwm_filtered"], {"pwm_filtered": {"tau_ms": 3.0}})
    with pytest.raises(ModelError, match="tau_s"):
        FeatureState(["pwm_filtered"], {"pwm_filtered": {"tau_s": 0.0}})
    with pytest.raises(ModelError):
        compute_features(np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), np.zeros(1), ["bogus"])


def test_not_ready_without_voltage_only_if_needed():
    m = NetworkModel(("pwm", "pwm_filtered"), [0.0, 0.0], [1.0, 1.0], 0.0, 700.0,
                     np.ones((2, 2)), np.zeros(2), np.ones(2), 0.0)
    est = ThrustEstimator(m)
    est.update_pwm(0.0, 0.08)
    assert est.predict(0.1).ready


def test_fallback_model_is_plausible():
    est = ThrustEstimator(fallback_model())
    est.update_voltage(0.0, 11.1)
    est.update_pwm(0.0, 0.05)
    assert est.predict(1.0).speed_rad_s == 0.0
    est.update_pwm(1.0, 0.10)
    full = est.predict(5.0)
    assert 450.0 < full.speed_rad_s < 700.0  # ~5000-6500 rpm at full throttle on 3S
    assert 3.0 < full.thrust_n < 15.0
    half = est.predict(1.25)  # one pwm_tau_s after the step: on the way up
    assert 0.0 < half.speed_rad_s < full.speed_rad_s
    est.update_voltage(5.0, 10.0)
    assert est.predict(5.0).speed_rad_s < full.speed_rad_s  # a lower battery gives less speed
    st = est.status()[0]
    assert st.level == WARN and "fallback" in st.message
    assert isinstance(fallback_model(), FallbackModel)


def test_status_waiting_and_counters():
    est = ThrustEstimator(small_model())
    st = est.status()[0]
    assert st.level == WARN and "waiting" in st.message
    assert st.values["model"] == "network"
    est.update_pwm(0.0, 0.07)
    est.update_voltage(0.0, 11.0)
    est.predict(0.0)
    est.predict(-1.0)  # before the latest input: evaluated at the latest input time
    st = est.status()[0]
    assert st.level == OK and st.values["predictions"] == "2" and st.values["predict_time_clamped"] == "1"


def test_update_predict_cost():
    import time

    est = ThrustEstimator(small_model(W1=np.random.default_rng(0).normal(size=(25, 3)),
                                      b1=np.zeros(25), W2=np.ones(25) / 25))
    est.update_voltage(0.0, 11.0)
    n = 5000
    t0 = time.perf_counter()
    for i in range(n):
        est.update_pwm(i * 1e-3, 0.07)
        est.predict(i * 1e-3)
    us = (time.perf_counter() - t0) / n * 1e6
    print(f"estimator update+predict: {us:.1f} us")
    assert us < 200.0  # generous: the benchmark reports the real figure (goal < 20 us)


def test_every_registered_feature_batch_equals_streaming():
    """Including the discrepancy workflow's inputs (core/effect_features.py)."""
    from bldc_propulsion.core.features import known_features, pwm_ok, voltage_ok

    grid, pwm_t, pwm, volt_t, volt = _streams(3)
    names = known_features()
    X = compute_features(grid, pwm_t, pwm, volt_t, volt, names)
    fs = FeatureState(names)
    arrival = np.maximum.accumulate(np.nan_to_num(pwm_t, nan=-np.inf))
    events = sorted([(a, 0, i) for i, a in enumerate(arrival)] + [(t, 1, i) for i, t in enumerate(volt_t)]
                    + [(t, 2, k) for k, t in enumerate(grid)])
    lp = lv = None
    S = np.full_like(X, np.nan)
    for _, kind, i in events:  # the estimator's acceptance rules
        if kind == 0:
            if pwm_ok(pwm[i]) and (lp is None or pwm_t[i] >= lp):
                fs.update_pwm(pwm_t[i], pwm[i])
                lp = pwm_t[i]
        elif kind == 1:
            if voltage_ok(volt[i]) and (lv is None or volt_t[i] >= lv):
                fs.update_voltage(volt_t[i], volt[i])
                lv = volt_t[i]
        else:
            S[i] = fs.vector_at(grid[i])
    for j, name in enumerate(names):
        np.testing.assert_allclose(X[:, j], S[:, j], rtol=0, atol=1e-12, equal_nan=True, err_msg=name)


def test_fallback_forward_one_is_forward_bit_for_bit():
    """The estimator's per-prediction fallback (plain floats) = FallbackModel.forward (numpy)."""
    import struct

    from bldc_propulsion.physics.fallback import fallback_model

    m = fallback_model()
    rng = np.random.default_rng(0)
    volts = np.concatenate([rng.uniform(0, 60, 20000), [0.0, -0.0, 60.0, 12.0, -0.0, 1e-300, -3.0]])
    pwm = np.concatenate([rng.uniform(0, 1, 20000), [0.1, 0.5, 1.0, 0.0, 0.1000000001, 0.5, 0.7]])
    for v, p in zip(volts.tolist(), pwm.tolist(), strict=True):
        x = [v, p, p]
        want = float(m.forward(np.asarray(x, dtype=float)))
        assert struct.pack("<d", m.forward_one(x)) == struct.pack("<d", want), x
