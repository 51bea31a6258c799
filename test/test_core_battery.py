"""Battery filter: the paper's H(z), rediscretisation, irregular samples, rejection rules."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
from scipy import signal

from bldc_propulsion.contract import PAPER_DIVIDER_RATIO, PAPER_FILTER_TAU_S, paper_filter_prototype
from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig, _tustin_step, discretise
from bldc_propulsion.core.status import OK, WARN
from bldc_propulsion.errors import BadInputError

PAPER_B = [4.9975e-4, 4.9975e-4]
PAPER_A = [1.0, -0.9995]


def modulated_adc(n, fs=1000.0, seed=0):
    """ADC volts: a slowly sagging ~5.6 V (11.2 V / 1.999) with strong ESC modulation."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / fs
    return t, 5.6 - 0.05 * t + 0.8 * np.sin(2 * np.pi * 37.0 * t) + rng.normal(0, 0.3, n)


def test_prototype_from_paper_coefficients():
    K, tau = paper_filter_prototype()
    assert K == pytest.approx(1.999, abs=1e-12)
    assert tau == pytest.approx(1.9995, abs=1e-12)
    # the unit-gain low-pass at 1 kHz, times 1.999, is the paper's H(z)
    b, a = discretise(PAPER_FILTER_TAU_S, 1000.0)
    np.testing.assert_allclose(b * PAPER_DIVIDER_RATIO, PAPER_B, rtol=1e-12)
    np.testing.assert_allclose(a, PAPER_A, rtol=1e-12)
    assert b.sum() / a.sum() == pytest.approx(1.0, abs=1e-12)  # lowpass part: unit DC gain


def test_closed_form_step_equals_scipy_bilinear():
    for dt in (1e-4, 1e-3, 3.7e-3, 0.05):
        b, a = discretise(PAPER_FILTER_TAU_S, 1.0 / dt)
        b0, b1, a1 = _tustin_step(PAPER_FILTER_TAU_S, dt)
        np.testing.assert_allclose([b0, b1, a1], [b[0], b[1], a[1]], rtol=1e-12)


def test_clean_1khz_equals_paper_lfilter():
    t, adc = modulated_adc(20000)
    f = BatteryFilter(BatteryFilterConfig(divider_ratio=1.999))
    out = np.array([f.update(ti, xi) for ti, xi in zip(t, adc, strict=True)])
    # paper's H(z) (DC gain 1.999 = divider 1.999 x unit-gain low-pass), started in steady state
    zi = signal.lfilter_zi(PAPER_B, PAPER_A) * adc[0]
    ref, _ = signal.lfilter(PAPER_B, PAPER_A, adc, zi=zi)
    np.testing.assert_allclose(out, ref, rtol=0, atol=1e-9)
    assert out[0] == pytest.approx(1.999 * adc[0], abs=1e-12)  # no climb from 0 V
    assert f.irregular_steps == 0 and f.resets == 0


def test_divider_ratio_is_a_parameter():
    t, adc = modulated_adc(3000)
    a = BatteryFilter(BatteryFilterConfig(divider_ratio=1.999)).process(t, adc)
    b = BatteryFilter(BatteryFilterConfig(divider_ratio=3.0)).process(t, adc)
    np.testing.assert_allclose(b, a * 3.0 / 1.999, rtol=1e-12)
    # constant input: output = ratio x input at once
    f = BatteryFilter(BatteryFilterConfig(divider_ratio=3.0))
    assert f.update(0.0, 4.0) == pytest.approx(12.0)
    assert f.update(0.001, 4.0) == pytest.approx(12.0)


def test_process_equals_update_per_sample():
    t, adc = modulated_adc(5000, seed=1)
    t = t.copy()
    t[1000:] += 0.0003  # one irregular step
    t[2000:] += 0.9  # a gap: reset
    t[3000:3100] += np.random.default_rng(2).uniform(0, 0.0004, 100)  # jitter
    adc = adc.copy()
    adc[10] = np.nan
    adc[11] = 50.0  # out of range
    adc[12] = -1.0
    t[4000] = t[3999]  # duplicate time
    a = BatteryFilter()
    per_sample = np.array([np.nan if (v := a.update(ti, xi)) is None else v for ti, xi in zip(t, adc, strict=True)])
    b = BatteryFilter()
    batch = np.concatenate([b.process(t[:1500], adc[:1500]), b.process(t[1500:], adc[1500:])])
    np.testing.assert_allclose(batch, per_sample, rtol=0, atol=1e-12, equal_nan=True)
    for k in ("accepted", "rejected_nonfinite", "rejected_range", "rejected_time", "resets", "irregular_steps"):
        assert getattr(a, k) == getattr(b, k), k
    assert a.rejected_nonfinite == 1 and a.rejected_range == 2 and a.rejected_time == 1 and a.resets == 1


def test_rediscretised_500hz_matches_1khz_step_response():
    def step(fs, T=6.0):
        n = int(T * fs) + 1
        t = np.arange(n) / fs
        x = np.where(t > 0.0, 1.0, 0.0)
        return t, BatteryFilter(BatteryFilterConfig(sample_rate_hz=fs, divider_ratio=1.0)).process(t, x)

    t1, y1 = step(1000.0)
    t2, y2 = step(500.0)
    common = y1[::2]
    # both follow the continuous 1 - exp(-t/tau); Tustin treats the jump as a ramp over one
    # sample, so the two differ by at most ~dt/(2 tau) right after the step
    np.testing.assert_allclose(y2, common, atol=3e-4)
    cont = 1.0 - np.exp(-(t2 - 0.5 / 500.0) / PAPER_FILTER_TAU_S)
    np.testing.assert_allclose(y2[1:], cont[1:], atol=1e-3)
    # smooth input: the two discretisations agree to second order
    t_a = np.arange(0, 8.0, 1e-3)
    t_b = t_a[::2]
    u = lambda t: 5.0 + np.sin(2 * np.pi * 0.2 * t)  # noqa: E731
    ya = BatteryFilter(BatteryFilterConfig(sample_rate_hz=1000.0, divider_ratio=1.0)).process(t_a, u(t_a))
    yb = BatteryFilter(BatteryFilterConfig(sample_rate_hz=500.0, divider_ratio=1.0)).process(t_b, u(t_b))
    np.testing.assert_allclose(yb, ya[::2], atol=2e-6)
    # reusing the 1 kHz coefficients at 500 Hz (the mistake the rediscretisation avoids) is far off
    b, a = discretise(PAPER_FILTER_TAU_S, 1000.0)
    wrong, _ = signal.lfilter(b, a, np.where(t2 > 0, 1.0, 0.0), zi=[0.0])
    assert np.max(np.abs(wrong - y2)) > 0.1


def test_irregular_samples_use_their_own_dt():
    # samples at 1 kHz config but actually every 2 ms: time-aware steps give the 500 Hz answer
    t = np.arange(0, 4.0, 2e-3)
    x = np.where(t > 0, 1.0, 0.0)
    f = BatteryFilter(BatteryFilterConfig(sample_rate_hz=1000.0, divider_ratio=1.0))
    y = f.process(t, x)
    ref = BatteryFilter(BatteryFilterConfig(sample_rate_hz=500.0, divider_ratio=1.0)).process(t, x)
    np.testing.assert_allclose(y, ref, atol=1e-12)
    assert f.irregular_steps == len(t) - 1


def test_rejects_bad_samples_without_touching_state():
    f = BatteryFilter()
    f.update(0.0, 5.0)
    v = f.update(0.001, 5.5)
    state = (f._t, f._x, f._y)
    for t, x in ((0.002, math.nan), (0.002, math.inf), (0.002, -0.1), (0.002, 10.5), (math.nan, 5.0),
                 (0.001, 5.0), (0.0005, 5.0)):
        assert f.update(t, x) is None
        assert (f._t, f._x, f._y) == state
        assert f.voltage == v
    assert f.rejected_nonfinite == 3 and f.rejected_range == 2 and f.rejected_time == 2
    st = f.status()[0]
    assert st.level == WARN and "rejected" in st.message
    assert st.values["rejected_out_of_range"] == "2"
    assert f.status()[0].level == OK  # nothing new since the last report


def test_gap_resets_to_new_sample():
    f = BatteryFilter(BatteryFilterConfig(max_gap_s=0.5))
    for k in range(100):
        f.update(k * 1e-3, 5.0)
    assert f.update(0.099 + 0.6, 6.0) == pytest.approx(1.999 * 6.0)
    assert f.resets == 1
    f.update(0.7, 5.0)  # within the gap limit: filtered, not reset
    assert f.resets == 1


def test_first_sample_starts_in_steady_state_and_status():
    f = BatteryFilter()
    assert f.status()[0].level == WARN  # nothing yet
    assert f.update(10.0, 5.6) == pytest.approx(1.999 * 5.6)
    st = f.status()[0]
    assert st.level == OK and st.name == "battery filter"
    assert all(isinstance(v, str) for v in st.values.values())


@pytest.mark.parametrize("kw", [{"sample_rate_hz": 0.0}, {"divider_ratio": -1.0}, {"max_gap_s": 0.0},
                                {"min_adc_v": 5.0, "max_adc_v": 1.0}, {"tau_s": math.nan}])
def test_bad_config(kw):
    with pytest.raises(BadInputError):
        BatteryFilterConfig(**kw)


def test_throughput():
    t, adc = modulated_adc(200000)
    f = BatteryFilter()
    t0 = time.perf_counter()
    f.process(t, adc)
    batch_rate = len(t) / (time.perf_counter() - t0)
    g = BatteryFilter()
    t0 = time.perf_counter()
    for ti, xi in zip(t[:20000].tolist(), adc[:20000].tolist(), strict=True):
        g.update(ti, xi)
    stream_rate = 20000 / (time.perf_counter() - t0)
    print(f"battery filter: batch {batch_rate:.3g} samples/s, streaming {stream_rate:.3g} samples/s")
    assert batch_rate > 1e6 and stream_rate > 2e4  # a 1 kHz stream is trivial either way
