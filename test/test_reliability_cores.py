"""Property tests of the three cores under any mix of bad input (hypothesis, derandomized).

For any sequence of finite, NaN, inf, negative, huge and duplicate-/backwards-timestamp
inputs: every output is finite (or the documented None/NaN for a rejected sample / a
not-ready prediction) and within physical bounds, and once the bad input stops the output
converges to what a fresh core fed only the clean input gives.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

sys.path.insert(0, str(Path(__file__).parent))
from _tachsignal import make_signal  # noqa: E402
from bldc_propulsion import contract as c  # noqa: E402
from bldc_propulsion.core.battery_filter import BatteryFilter, BatteryFilterConfig  # noqa: E402
from bldc_propulsion.core.estimator import ThrustEstimator  # noqa: E402
from bldc_propulsion.core.tachometer import TachometerConfig, TachometerDecoder  # noqa: E402
from bldc_propulsion.model import NetworkModel  # noqa: E402
from bldc_propulsion.physics.fallback import fallback_model  # noqa: E402

FAST = settings(max_examples=40, deadline=None, derandomize=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])

BAD_VALUES = [math.nan, math.inf, -math.inf, -1.0, -1e300, 1e300, 1e30, -0.0, 0.0]
#: time steps: nominal, duplicate, backwards, jitter, a gap, NaN/inf
STEPS = st.sampled_from([1e-3, 1e-3, 1e-3, 0.0, -5e-4, 1.3e-3, 0.7, math.nan, math.inf])


def values(lo: float, hi: float):
    return st.one_of(st.floats(lo, hi), st.sampled_from(BAD_VALUES),
                     st.floats(allow_nan=True, allow_infinity=True))


def times(steps: list[float]) -> list[float]:
    """Sample times from steps; a NaN/inf step yields a NaN/inf time but does not move the clock."""
    t, out = 1.0, []
    for d in steps:
        if math.isfinite(d):
            t += d
            out.append(t)
        else:
            out.append(d)
    return out


# --- battery filter ---------------------------------------------------------------------------
BF = BatteryFilterConfig()


@FAST
@given(st.lists(st.tuples(STEPS, values(-2.0, 12.0)), min_size=1, max_size=80))
def test_battery_filter_bad_input(events):
    ts = times([d for d, _ in events])
    xs = [x for _, x in events]
    lo, hi = BF.divider_ratio * BF.min_adc_v, BF.divider_ratio * BF.max_adc_v
    f = BatteryFilter(BF)
    outs = [f.update(t, x) for t, x in zip(ts, xs, strict=True)]
    for v in outs:
        assert v is None or (math.isfinite(v) and lo - 1e-9 <= v <= hi + 1e-9)
    # the batch path gives the same answers (NaN where update said None)
    g = BatteryFilter(BF)
    batch = g.process(np.array(ts), np.array(xs))
    for v, b in zip(outs, batch, strict=True):
        assert (v is None and math.isnan(b)) or (v is not None and b == pytest.approx(v, rel=1e-9, abs=1e-9))
    assert f.accepted + f.rejected == len(xs)
    st_ = f.status()[0]
    assert st_.level in (0, 1)
    # recovery: after the bad part, 20 s (10 time constants) of clean samples
    t_end = max([t for t in ts if math.isfinite(t)], default=0.0)
    tc = t_end + 1e-3 + np.arange(20000) * 1e-3
    xc = 6.0 + 0.5 * np.sin(tc)
    dirty = f.process(tc, xc)
    clean = BatteryFilter(BF).process(tc, xc)
    assert np.all(np.isfinite(dirty)) and np.all(np.isfinite(clean))
    assert abs(dirty[-1] - clean[-1]) < 1e-3
    assert f.status()[0].level in (0, 1)


# --- tachometer -------------------------------------------------------------------------------
TACH = TachometerConfig()
SIG = make_signal(400.0, 8.0, seed=9)  # 8 s of a 400 rad/s rotor at 20 kHz
BAD_PART = len(SIG.x) // 8  # bad batches use the first second of the signal
#: the level trackers forget a wrong level at level_decay_v_per_s: a -4.5 V excursion
#: (a batch of negated samples) takes ~5 s to be forgotten; the clean part is 6 s
CLEAN_FROM = len(SIG.x) // 4

BATCH_KIND = st.sampled_from(["clean", "clean", "nan", "inf", "negative", "huge", "noise", "flat"])
STAMP = st.sampled_from(["next", "next", "next", "duplicate", "backwards", "gap", "nan", "short"])


def _bad_batch(kind: str, n: int, a: int, rng: np.random.Generator) -> np.ndarray:
    if kind == "clean":
        return SIG.x[a:a + n]
    if kind == "nan":
        x = SIG.x[a:a + n].copy()
        x[rng.integers(0, n, max(1, n // 4))] = np.nan
        return x
    if kind == "inf":
        return np.full(n, np.inf)
    if kind == "negative":
        return -np.abs(SIG.x[a:a + n])
    if kind == "huge":
        return np.where(rng.random(n) < 0.5, 1e30, SIG.x[a:a + n])
    if kind == "noise":
        return rng.uniform(-1.0, 6.0, n)
    return np.full(n, 2.4)


@FAST
@given(st.lists(st.tuples(BATCH_KIND, STAMP, st.integers(1, 400)), min_size=1, max_size=40),
       st.integers(0, 2**31 - 1))
def test_tachometer_bad_input(batches, seed):
    rng = np.random.default_rng(seed)
    dec = TachometerDecoder(TACH)
    t, a = 0.0, 0
    for kind, stamp, n in batches:
        n = min(n, BAD_PART - a) or 1
        x = _bad_batch(kind, n, a, rng)
        a = (a + n) % BAD_PART
        step = {"next": n / TACH.sample_rate_hz, "duplicate": 0.0, "backwards": -0.02,
                "gap": 0.4, "nan": math.nan, "short": 1e-4}[stamp]
        stamp_t = t + step if math.isfinite(step) else math.nan
        out = dec.process_batch(stamp_t, x)
        if math.isfinite(stamp_t):
            t = max(t, stamp_t)
        for arr in (out.speed, out.edge_t, out.all_edge_t):
            assert np.all(np.isfinite(arr))
        assert np.all((out.speed >= 0.0) & (out.speed <= TACH.max_speed_rad_s))
        assert math.isfinite(out.speed_now) and 0.0 <= out.speed_now <= TACH.max_speed_rad_s
    dec.status()
    # recovery: clean batches continuing after the latest stamp; the rotor's true speed again
    t0 = t + 0.5
    res = dec.process(t0, SIG.x[CLEAN_FROM:], batch_size=200)
    ref = TachometerDecoder(TACH).process(t0, SIG.x[CLEAN_FROM:], batch_size=200)
    assert res.signal_ok and not dec.rate_mismatch
    assert res.speed_now == pytest.approx(400.0, rel=0.01)
    # the last second of speeds equals a fresh decoder's (same edges)
    late = res.edge_t > res.edge_t[-1] - 1.0
    late_ref = ref.edge_t > ref.edge_t[-1] - 1.0
    assert np.allclose(res.speed[late], ref.speed[late_ref], rtol=1e-9)
    assert dec.status()[0].level == 0


# --- thrust estimator -------------------------------------------------------------------------
def small_network() -> NetworkModel:
    rng = np.random.default_rng(1)
    return NetworkModel(
        input_names=tuple(c.DEFAULT_INPUTS), input_min=np.array([9.0, 0.05, 0.05]),
        input_max=np.array([13.0, 0.10, 0.10]), output_min=0.0, output_max=900.0,
        W1=rng.normal(0, 1.0, (5, 3)), b1=rng.normal(0, 0.3, 5), W2=rng.normal(0, 0.5, 5), b2=0.1)


def network_bound(m: NetworkModel) -> float:
    """Largest speed the network can output (tanh is bounded, inputs are clipped)."""
    s = float(np.sum(np.abs(m.W2)) + abs(m.b2))
    half = (m.output_max - m.output_min) / 2.0
    return m.output_min + half * (1.0 + s)


EST_EVENT = st.tuples(st.sampled_from(["pwm", "voltage", "predict"]), STEPS,
                      st.one_of(st.floats(0.04, 0.11), st.floats(8.0, 13.5), st.sampled_from(BAD_VALUES),
                                st.floats(allow_nan=True, allow_infinity=True)))


@pytest.mark.parametrize("which", ["network", "fallback"])
@FAST
@given(events=st.lists(EST_EVENT, min_size=1, max_size=60))
def test_thrust_estimator_bad_input(which, events):
    model = small_network() if which == "network" else fallback_model()
    bound = network_bound(model) if which == "network" else 5000.0
    est = ThrustEstimator(model)
    ts = times([d for _, d, _ in events])
    for (kind, _, v), t in zip(events, ts, strict=True):
        if kind == "pwm":
            est.update_pwm(t, v)
        elif kind == "voltage":
            est.update_voltage(t, v)
        else:
            p = est.predict(t)
            if p.ready:
                assert math.isfinite(p.speed_rad_s) and 0.0 <= p.speed_rad_s <= bound
                assert math.isfinite(p.thrust_n) and p.thrust_n >= 0.0
            else:
                assert math.isnan(p.speed_rad_s) and math.isnan(p.thrust_n)
    est.status()
    # recovery: 5 s (20 time constants of pwm_filtered) of clean inputs after the bad part
    t_end = max([t for t in ts if math.isfinite(t)], default=0.0) + 0.01
    fresh = ThrustEstimator(model)
    for k in range(250):
        tk = t_end + 0.02 * k
        pwm = 0.06 + 0.03 * (k // 50 % 2)
        for e in (est, fresh):
            assert e.update_pwm(tk, pwm)
            assert e.update_voltage(tk, 11.5)
    p, q = est.predict(t_end + 5.0), fresh.predict(t_end + 5.0)
    assert p.ready and q.ready
    assert p.speed_rad_s == pytest.approx(q.speed_rad_s, rel=1e-6, abs=1e-6)
