"""Tachometer decoder against a synthetic phototransistor signal with a known rotor angle.

"Truth" for a speed estimate: the estimate at edge k is 2 pi / (t_k - t_{k-4}), the mean speed
over the revolution that ends at that edge, so it is compared with the true mean speed over
the same window, (theta(t_k) - theta(t_{k-4})) / (t_k - t_{k-4}). The sensor lag delays both
ends of the window by the same amount, so it does not bias the estimate.
"""

from __future__ import annotations

import array
import math
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from _tachsignal import first_order_steps, make_signal  # noqa: E402
from bldc_propulsion.core.status import OK, WARN  # noqa: E402
from bldc_propulsion.core.tachometer import (  # noqa: E402
    BLOCKED,
    NO_EDGES,
    SPINNING,
    STARTING,
    STOPPED,
    STUCK,
    TachometerConfig,
    TachometerDecoder,
)
from bldc_propulsion.core.tachometer_parts import EdgeDetector  # noqa: E402
from bldc_propulsion.errors import BadInputError  # noqa: E402

FS = 20000.0


def window_truth(sig, res, edges_per_rev=4):
    """True mean speed over the revolution each estimate spans."""
    idx = np.searchsorted(res.all_edge_t, res.edge_t)
    assert np.all(res.all_edge_t[idx] == res.edge_t)
    assert np.all(idx >= edges_per_rev)
    ta = res.all_edge_t[idx - edges_per_rev]
    return sig.mean_speed(ta, res.edge_t)


def rel_rms(est, truth):
    return float(np.sqrt(np.mean(((est - truth) / truth) ** 2)))


@pytest.mark.parametrize("speed", [110.0, 300.0, 650.0, 1200.0])
def test_steady_speed_rms_error_below_half_percent(speed):
    sig = make_signal(speed, 1.0, seed=int(speed))
    res = TachometerDecoder().process(0.0, sig.x, batch_size=200)
    assert len(res.speed) >= 0.8 * speed / (2 * np.pi) * 4 * 1.0 - 8
    assert rel_rms(res.speed, window_truth(sig, res)) < 0.005
    # steady speed: each estimate is the speed itself
    assert rel_rms(res.speed, np.full(len(res.speed), speed)) < 0.005


def test_speed_steps_rms_error_below_two_percent():
    f = first_order_steps(150.0, [(0.3, 700.0), (0.7, 250.0), (1.1, 1100.0), (1.5, 400.0)], tau_s=0.08)
    sig = make_signal(f, 1.9, seed=3)
    res = TachometerDecoder().process(0.0, sig.x, batch_size=200)
    truth = window_truth(sig, res)
    assert rel_rms(res.speed, truth) < 0.02
    assert np.max(np.abs(res.speed - truth) / truth) < 0.05
    # the estimates do follow the steps (not smoothed away)
    assert res.speed.max() > 1000.0 and res.speed.min() < 200.0


def test_spin_up_from_standstill():
    def f(t):
        return np.where(t < 0.2, 0.0, 800.0 * (1.0 - np.exp(-np.clip(t - 0.2, 0, None) / 0.15)))

    sig = make_signal(f, 1.0, seed=5)
    dec = TachometerDecoder()
    before = dec.process(0.0, sig.x[:4000], batch_size=200)  # 0.2 s standing still, beam clear
    assert len(before.all_edge_t) == 0 and before.speed_now == 0.0 and not before.signal_ok
    res = dec.process(0.2, sig.x[4000:], batch_size=200)
    # first speed exactly at the 5th edge, nothing earlier
    assert len(res.all_edge_t) > 5
    assert res.edge_t[0] == res.all_edge_t[4]
    truth = window_truth(sig, res)
    assert rel_rms(res.speed, truth) < 0.02
    assert dec.signal_ok and dec.state == SPINNING
    assert dec.speed_now == pytest.approx(800.0, rel=0.02)


def test_first_speed_needs_edges_per_rev_plus_one_edges_and_states():
    sig = make_signal(300.0, 0.2, seed=6)
    dec = TachometerDecoder()
    seen_starting = False
    for a in range(0, len(sig.x), 20):
        r = dec.process_batch((a + 19) / FS, sig.x[a:a + 20])
        n_edges = dec.edges
        if 0 < n_edges < 5:
            assert r.speed_now == 0.0 and not r.signal_ok and r.state == STARTING
            seen_starting = True
        if n_edges >= 5:
            assert r.signal_ok and r.state == SPINNING
    assert seen_starting


@pytest.mark.parametrize("after, state, level", [(4.5, STOPPED, OK), (0.3, BLOCKED, WARN), (2.4, STUCK, WARN)])
def test_signal_loss_gives_zero_after_timeout(after, state, level):
    sig = make_signal(500.0, 0.5, seed=7)
    rng = np.random.default_rng(1)
    tail = after + rng.normal(0.0, 0.02, int(0.6 * FS))
    x = np.concatenate([sig.x, tail])
    dec = TachometerDecoder(TachometerConfig(timeout_s=0.3))
    last_edge = None
    speeds_now = []
    for a in range(0, len(x), 200):
        t_last = (a + 199) / FS
        r = dec.process_batch(t_last, x[a:a + 200])
        if len(r.all_edge_t):
            last_edge = r.all_edge_t[-1]
        speeds_now.append((t_last, r.speed_now, r.signal_ok))
    for t, w, ok in speeds_now:
        if 0.1 < t and t - last_edge <= 0.3 - 1e-9:
            assert w > 400.0 and ok  # still the measured speed, not made up, not zeroed
        if t - last_edge > 0.3 + 200 / FS:
            assert w == 0.0 and not ok
    assert dec.signal_losses == 1
    assert dec.state == state
    st = dec.status()[0]
    assert st.level == level and st.values["signal_losses"] == "1" and st.values["state"] == state


def test_check_timeout_when_batches_stop():
    sig = make_signal(400.0, 0.3, seed=8)
    dec = TachometerDecoder(TachometerConfig(timeout_s=0.3))
    r = dec.process(0.0, sig.x, batch_size=200)
    assert r.signal_ok
    t_end = (len(sig.x) - 1) / FS
    assert dec.check_timeout(t_end + 0.1) is False
    assert dec.check_timeout(t_end + 0.5) is True  # once
    assert dec.check_timeout(t_end + 0.6) is False
    assert dec.speed_now == 0.0 and not dec.signal_ok
    assert dec.signal_losses == 1
    st = dec.status()[0]
    assert st.level == WARN and "no tachometer/adc batch" in st.message


def test_history_resets_after_loss_and_restarts_cleanly():
    a = make_signal(500.0, 0.3, seed=9)
    gap = 4.5 + np.random.default_rng(2).normal(0, 0.02, int(0.5 * FS))
    b = make_signal(300.0, 0.3, seed=10, theta0=1.0)
    x = np.concatenate([a.x, gap, b.x])
    res = TachometerDecoder().process(0.0, x, batch_size=200)
    t_restart = (len(a.x) + len(gap)) / FS
    after = res.edge_t > t_restart
    first_edges_after = res.all_edge_t[res.all_edge_t > t_restart]
    assert res.edge_t[after][0] == first_edges_after[4]  # 5 new edges before the first new speed
    assert np.allclose(res.speed[after], 300.0, rtol=0.005)
    assert np.allclose(res.speed[~after], 500.0, rtol=0.005)


def test_glitch_spikes_are_rejected():
    sig = make_signal(500.0, 1.0, seed=11, noise_v=0.01)
    x = sig.x.copy()
    rng = np.random.default_rng(3)
    clear = np.flatnonzero((x > 4.3) & (np.roll(x, 3) > 4.3) & (np.roll(x, -3) > 4.3))
    down = rng.choice(clear[5:-5], 25, replace=False)
    x[down] = 0.1  # one-sample dips to below the blocked level while the beam is clear
    blocked = np.flatnonzero((x < 0.5) & (np.roll(x, 1) < 0.5) & (np.roll(x, -1) < 0.5))
    up = rng.choice(blocked[5:-5], 10, replace=False)
    x[up] = 5.0  # one-sample spikes above the clear level while a blade blocks
    dec = TachometerDecoder()
    res = dec.process(0.0, x, batch_size=200)
    assert dec.glitches == 35
    assert dec.overspeed == 0
    clean = TachometerDecoder().process(0.0, sig.x, batch_size=200)
    assert len(res.speed) == len(clean.speed)
    assert np.max(np.abs(res.speed - 500.0)) / 500.0 < 0.005


def test_overspeed_is_rejected():
    sig = make_signal(500.0, 0.5, seed=12)
    dec = TachometerDecoder(TachometerConfig(max_speed_rad_s=300.0, min_edge_fraction=0.01))
    res = dec.process(0.0, sig.x, batch_size=200)
    assert len(res.speed) == 0 and dec.overspeed > 0 and dec.edges > 20


def test_batch_sizes_give_identical_results():
    f = first_order_steps(200.0, [(0.2, 900.0), (0.5, 300.0)], tau_s=0.05)
    sig = make_signal(f, 0.7, seed=13)
    x = sig.x.copy()
    x[5000:5003] = np.nan  # a hole inside the stream
    x[7001] = 0.0  # and a glitch
    ref = TachometerDecoder().process(0.0, x)
    assert len(ref.speed) > 100
    for bs in (1, 2, 3, 7, 64, 199, 200, 201, 1000):
        res = TachometerDecoder().process(0.0, x, batch_size=bs)
        assert len(res.all_edge_t) == len(ref.all_edge_t), bs
        assert len(res.speed) == len(ref.speed), bs
        np.testing.assert_allclose(res.all_edge_t, ref.all_edge_t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.edge_t, ref.edge_t, rtol=0, atol=1e-9)
        np.testing.assert_allclose(res.speed, ref.speed, rtol=0, atol=1e-9)


def test_edge_straddling_batches_found_once():
    sig = make_signal(400.0, 0.2, seed=14)
    ref = TachometerDecoder().process(0.0, sig.x)
    # cut the stream exactly in the middle of every transition
    d = np.abs(np.diff(sig.x))
    cuts = np.flatnonzero(d > 1.0) + 1
    dec = TachometerDecoder()
    got = []
    prev = 0
    for c in list(cuts) + [len(sig.x)]:
        if c > prev:
            got.append(dec.process_batch((c - 1) / FS, sig.x[prev:c]).all_edge_t)
            prev = c
    got = np.concatenate(got)
    np.testing.assert_allclose(got, ref.all_edge_t, rtol=0, atol=1e-9)


def test_blade_asymmetry_gives_no_ripple():
    sig = make_signal(600.0, 1.0, seed=15, spacing_asym=0.05, width_asym=0.05)
    res = TachometerDecoder().process(0.0, sig.x, batch_size=200)
    assert np.std(res.speed) / np.mean(res.speed) < 0.001
    assert np.mean(res.speed) == pytest.approx(600.0, rel=0.001)
    # the naive one-edge-interval estimate would ripple by far more than 5 %
    naive = (2 * np.pi / 4) / np.diff(res.all_edge_t)
    assert np.std(naive) / np.mean(naive) > 0.3


def test_missing_batch_resets_history_no_speed_across_gap():
    sig = make_signal(500.0, 0.6, seed=16)
    dec = TachometerDecoder()
    parts = []
    for k, a in enumerate(range(0, len(sig.x), 200)):
        if k == 30:  # this batch is lost
            continue
        parts.append(dec.process_batch((a + 199) / FS, sig.x[a:a + 200]))
    assert dec.gaps == 1 and dec.missing_samples == 200
    edge_t = np.concatenate([r.edge_t for r in parts])
    w = np.concatenate([r.speed for r in parts])
    all_t = np.concatenate([r.all_edge_t for r in parts])
    assert np.allclose(w, 500.0, rtol=0.005)  # a speed across the gap would be ~20 % off
    gap_end = 31 * 200 / FS
    assert edge_t[edge_t > gap_end][0] == all_t[all_t > gap_end][4]  # history restarted


def test_backwards_and_empty_batches():
    sig = make_signal(500.0, 0.2, seed=17)
    dec = TachometerDecoder()
    dec.process(0.0, sig.x[:2000], batch_size=200)
    edges = dec.edges
    r = dec.process_batch(0.05, sig.x[2000:2200])  # time went backwards
    assert dec.rejected_batches == 1 and dec.edges == edges and len(r.all_edge_t) == 0
    r = dec.process_batch((2199) / FS, np.zeros(0))  # empty: no-op
    assert dec.rejected_batches == 1 and dec.batches == 10
    dec.process_batch(1999 / FS, sig.x[:200])  # duplicate time
    assert dec.rejected_batches == 2


def test_nonfinite_samples_dropped_and_counted():
    sig = make_signal(500.0, 0.5, seed=18)
    x = sig.x.copy()
    x[3000:3010] = np.nan
    x[6000] = np.inf
    dec = TachometerDecoder()
    res = dec.process(0.0, x, batch_size=200)
    assert dec.nonfinite_samples == 11 and dec.nonfinite_gaps == 2
    assert np.allclose(res.speed, 500.0, rtol=0.005)


def test_epoch_timestamps_keep_precision():
    sig = make_signal(700.0, 0.5, seed=19)
    t0 = 1.7e9
    res = TachometerDecoder().process(t0, sig.x, batch_size=200)
    assert np.allclose(res.speed, 700.0, rtol=0.005)
    assert res.edge_t[0] > t0


def test_starts_with_blade_in_beam():
    sig = make_signal(400.0, 0.4, seed=20, theta0=0.0)  # blade 1 centred on the beam
    res = TachometerDecoder().process(0.0, sig.x, batch_size=200)
    assert np.allclose(res.speed, 400.0, rtol=0.005)


def test_no_edges_state_before_any_blade():
    dec = TachometerDecoder()
    r = dec.process_batch(0.5, np.full(10000, 4.5))
    assert r.state == NO_EDGES and r.speed_now == 0.0 and not r.signal_ok
    assert dec.status()[0].level == WARN
    assert dec.signal_losses == 0


def test_other_blade_counts():
    sig = make_signal(400.0, 0.5, seed=21, blades=3, blade_width=0.04)
    res = TachometerDecoder(TachometerConfig(blades=3)).process(0.0, sig.x, batch_size=200)
    assert np.allclose(res.speed, 400.0, rtol=0.005)
    assert res.edge_t[0] == res.all_edge_t[6]


def test_status_counters():
    dec = TachometerDecoder()
    dec.process(0.0, make_signal(300.0, 0.3, seed=22).x, batch_size=200)
    st = dec.status()
    assert len(st) == 1 and st[0].name == "tachometer" and st[0].level == OK
    for key in ("edges", "speeds", "signal_losses", "glitches_rejected", "gaps", "rejected_batches",
                "nonfinite_samples", "overspeed_rejected", "history_resets", "state"):
        assert key in st[0].values
    assert all(isinstance(v, str) for v in st[0].values.values())


@pytest.mark.parametrize("kw", [
    {"sample_rate_hz": 0.0}, {"blades": 0}, {"blades": 2.5}, {"timeout_s": -1.0},
    {"low_fraction": 0.6}, {"high_fraction": 0.4}, {"max_speed_rad_s": math.nan},
])
def test_bad_config(kw):
    with pytest.raises(BadInputError):
        TachometerConfig(**kw)


def test_against_simulator_truth():
    from bldc_propulsion.sim.bench import simulate

    # a command that steps through the range (0.5 s at standstill first)
    t_cmd = np.arange(0.0, 6.0, 0.02)
    level = np.select([t_cmd < 0.5, t_cmd < 2.0, t_cmd < 3.5, t_cmd < 4.5], [0.05, 0.075, 0.095, 0.065], 0.085)
    res = simulate("custom", 6.0, seed=1, effects=None, soc=1.0, pwm=(t_cmd, level))
    dec = TachometerDecoder(TachometerConfig(sample_rate_hz=res.tach_rate_hz))
    out = dec.process(res.tach_t0, res.tach, batch_size=200)
    assert len(out.speed) > 50
    # truth: mean of the simulated speed over the revolution each estimate spans
    idx = np.searchsorted(out.all_edge_t, out.edge_t)
    ta = out.all_edge_t[idx - 4]
    tt, w = np.asarray(res.truth_t), np.asarray(res.truth_speed)
    theta = np.concatenate(([0.0], np.cumsum(0.5 * (w[1:] + w[:-1]) * np.diff(tt))))
    truth = (np.interp(out.edge_t, tt, theta) - np.interp(ta, tt, theta)) / (out.edge_t - ta)
    fast = truth > 100.0
    assert fast.sum() > 20
    assert rel_rms(out.speed[fast], truth[fast]) < 0.01


def _state(d: TachometerDecoder) -> tuple:
    e = d._edges
    return (e.hi, e.lo, e.tail, e.cross, e.pending, e.state, e.r_last, e.level_now)


def _planned_vs_plain(batches: list[tuple[float, np.ndarray]], cfg=None) -> int:
    """Feed the batches to a decoder told them in advance (expect), to one that is not and gets
    them as rclpy's array.array (short batches go through segment_small) and to one that
    decodes everything with numpy (SMALL_BATCH = 0): every batch's result, the state and the
    diagnostics must be identical. Returns how many batches went through a plan."""
    plain = TachometerDecoder(cfg)
    planned = TachometerDecoder(cfg)
    numpy_only = TachometerDecoder(cfg)
    numpy_only.SMALL_BATCH = 0
    planned.expect([x for _, x in batches])
    for k, (t, x) in enumerate(batches):
        a = plain.process_batch(t, array.array('f', x.tolist()))
        b = planned.process_batch(t, x)
        c = numpy_only.process_batch(t, x)
        for f in ("edge_t", "speed", "all_edge_t"):
            np.testing.assert_array_equal(getattr(a, f), getattr(b, f))
            np.testing.assert_array_equal(getattr(a, f), getattr(c, f))
        assert (a.speed_now, a.signal_ok, a.state) == (b.speed_now, b.signal_ok, b.state)
        assert (a.speed_now, a.signal_ok, a.state) == (c.speed_now, c.signal_ok, c.state)
        assert plain.counts == planned.counts == numpy_only.counts
        assert _state(plain) == _state(planned) == _state(numpy_only)
        if k == len(batches) // 2:  # a diagnostics timeout check between two batches
            assert (plain.check_timeout(t + 0.5) == planned.check_timeout(t + 0.5)
                    == numpy_only.check_timeout(t + 0.5))
    assert plain.status() == planned.status() == numpy_only.status()
    return planned.planned_batches


def _cut(x: np.ndarray, n: int = 200, t0: float = 0.0, rate: float = 20000.0):
    return [(t0 + (a + n - 1) / rate, x[a:a + n].astype(np.float32)) for a in range(0, len(x) - n + 1, n)]


def test_planned_batches_equal_plain_ones(monkeypatch):
    """TachometerDecoder.expect (replay's planned level trackers) and the live nodes' per-sample
    form of short batches (EdgeDetector.segment_small) change nothing: clean
    signal, steps, noise and glitches, NaN and absurd samples, gaps, late and repeated
    batches, a weak signal, a sample-rate mismatch, short batches."""
    small = [0, 0]  # segment_small calls: [all, decoded]
    real_small = EdgeDetector.segment_small

    def counted(self, *args):
        done = real_small(self, *args)
        small[0] += 1
        small[1] += done
        return done
    monkeypatch.setattr(EdgeDetector, "segment_small", counted)
    steps = make_signal(first_order_steps(0.0, [(0.05, 600.0), (0.6, 150.0), (1.1, 0.0)]), 1.6, seed=2)
    batches = _cut(steps.x)
    assert _planned_vs_plain(batches) > 0.9 * len(batches)
    assert small == [len(batches), len(batches)]
    noisy = make_signal(400.0, 0.8, noise_v=0.4, seed=3)
    x = noisy.x.copy()
    x[1000:1003] = 0.2  # spikes (glitches)
    x[5000] = np.nan
    x[6000:6200] = np.nan
    x[7000] = 1e6
    batches = _cut(x)
    del batches[30:33]  # a gap
    batches[40] = (batches[39][0], batches[40][1])  # stamped like the one before: rejected
    batches[50] = (batches[50][0] + 0.02, batches[50][1])  # late
    batches.insert(60, (batches[59][0] + 0.004, batches[60][1][:80]))  # a short batch
    assert _planned_vs_plain(batches) > 0.8 * len(batches)
    assert 0 < small[1] < small[0]  # the batches with NaN or absurd samples fell back to numpy
    # a weak signal: its levels closer than min_contrast_v, so the blocked level is clamped
    weak = make_signal(300.0, 0.5, high_v=0.8, low_v=0.45, seed=5)
    assert _planned_vs_plain(_cut(weak.x)) > 0
    # batch stamps at half the rate the samples have: a sample-rate mismatch
    fast = make_signal(300.0, 0.6, seed=4)
    assert _planned_vs_plain([(t * 2, x) for t, x in _cut(fast.x)]) > 0
    # the same array objects given twice, and batches the decoder was not told about
    b = _cut(steps.x[:8000])
    plain, planned = TachometerDecoder(), TachometerDecoder()
    planned.expect([x for _, x in b])
    for k, (t, x) in enumerate(b):
        if k == 10:
            extra = (t - 0.0001, x.copy())
            plain.process_batch(*extra)
            planned.process_batch(*extra)
        assert plain.process_batch(t, x).speed.tolist() == planned.process_batch(t, x).speed.tolist()
    assert plain.counts == planned.counts and plain.status() == planned.status()
