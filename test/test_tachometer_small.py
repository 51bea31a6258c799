"""The live nodes' per-sample decoding (``EdgeDetector.segment_small``, which skips the work of
quiet samples) against the numpy form (``segment``, SMALL_BATCH = 0) on signals made to sit
on its bounds: every batch's result, the counters and the detector's state must be identical,
to the last bit. test_core_tachometer.py compares the two on the usual signals; these are the
cases where a quiet verdict would be wrong if a bound were off: a rotor standing still (the
blocked tracker decays up to the clear level, so both trackers move every sample), a blade
parked in the beam, the contrast at min_contrast_v, a slowly rising or falling level, samples
just inside and beyond max_abs_v or NaN in a quiet stretch, and settings whose ramp is longer
than low_fraction of the contrast (no sample is quiet in the blocked state)."""

from __future__ import annotations

import array
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).parent))
from _tachsignal import make_signal  # noqa: E402
from bldc_propulsion.core.tachometer import TachometerConfig, TachometerDecoder  # noqa: E402
from bldc_propulsion.core.tachometer_parts import EdgeDetector  # noqa: E402

FS = 20000.0


def _state(d: TachometerDecoder) -> tuple:
    e = d._edges
    return (e.hi, e.lo, e.tail, e.cross, e.pending, e.state, e.r_last, e.level_now, e.known)


def same_as_numpy(x: np.ndarray, cfg: TachometerConfig | None = None, n: int = 200) -> int:
    """Decode ``x`` in batches of ``n`` as rclpy's float32 arrays (segment_small) and with numpy
    only; assert identical results, counters and state after every batch. Returns how many
    batches segment_small decoded itself (the others fell back to numpy: NaN, beyond lim)."""
    small, numpy_only = TachometerDecoder(cfg), TachometerDecoder(cfg)
    numpy_only.SMALL_BATCH = 0
    decoded = [0]
    real = EdgeDetector.segment_small

    def counted(self, *args):
        done = real(self, *args)
        decoded[0] += done
        return done
    EdgeDetector.segment_small = counted
    try:
        x32 = np.asarray(x, dtype=np.float32)
        for a in range(0, len(x32) - n + 1, n):
            t = (a + n - 1) / FS
            batch = x32[a:a + n]
            r1 = small.process_batch(t, array.array('f', batch.tobytes()))
            r2 = numpy_only.process_batch(t, batch)
            for f in ("edge_t", "speed", "all_edge_t"):
                np.testing.assert_array_equal(getattr(r1, f), getattr(r2, f))
            assert (r1.speed_now, r1.signal_ok, r1.state) == (r2.speed_now, r2.signal_ok, r2.state)
            assert small.counts == numpy_only.counts
            assert _state(small) == _state(numpy_only), f"batch at sample {a}"
    finally:
        EdgeDetector.segment_small = real
    assert small.status() == numpy_only.status()
    return decoded[0]


def test_a_rotor_standing_still_moves_both_trackers_every_sample():
    """Steady clear beam for 6 s: the blocked tracker decays up to the signal (contrast
    clamped), then the rotor starts."""
    rng = np.random.default_rng(1)
    still = 4.5 + 0.002 * rng.standard_normal(int(6.0 * FS))
    spin = make_signal(300.0, 0.5, seed=1).x
    assert same_as_numpy(np.concatenate([still, spin])) > 0


def test_a_blade_parked_in_the_beam_and_a_level_that_drifts():
    rng = np.random.default_rng(2)
    parked = 0.3 + 0.002 * rng.standard_normal(int(3.0 * FS))  # the clear tracker decays down
    t = np.arange(int(1.0 * FS)) / FS
    rising = np.where((t * 150.0) % 1.0 < 0.1, 0.3, 3.0 + 1.5 * t)  # clear level rising 1.5 V/s
    falling = np.where((t * 150.0) % 1.0 < 0.1, 0.3, 4.5 - 1.5 * t)
    spin = make_signal(500.0, 0.3, seed=2).x
    assert same_as_numpy(np.concatenate([parked, spin, rising, falling, spin])) > 0


@pytest.mark.parametrize("high_v, low_v", [(0.8, 0.45), (0.95, 0.45), (4.5, 4.0)])
def test_contrast_at_and_under_min_contrast(high_v, low_v):
    """Levels closer than min_contrast_v (0.5 V): the blocked level is clamped to the clear
    one minus 0.5 V, so the normalised level of a blade sits near the thresholds."""
    sig = make_signal(400.0, 0.6, high_v=high_v, low_v=low_v, noise_v=0.05, seed=3)
    same_as_numpy(sig.x)


def test_noise_and_spikes_on_both_levels():
    sig = make_signal(350.0, 0.8, noise_v=0.3, seed=4)
    x = sig.x.copy()
    x[2000:2002] = 0.2  # a two-sample dip in the clear beam
    x[3000] = 4.4  # a one-sample spike up
    x[7001:7003] = 6.0  # above the clear level: raises it
    x[9000:9010] = -1.0  # below the blocked level: lowers it
    same_as_numpy(x)


@pytest.mark.parametrize("bad", [np.nan, np.inf, -np.inf, 100.5, -100.5, 3e38])
@pytest.mark.parametrize("where", [0, 1, 57, 199])
def test_bad_samples_anywhere_in_a_quiet_batch_fall_back_to_numpy(bad, where):
    """A NaN, an infinity or a sample beyond max_abs_v (100 V) anywhere in a batch, first
    sample, middle or last, in a stretch where every other sample is quiet: segment_small
    refuses the batch (the numpy path drops the sample as a gap), with nothing changed."""
    x = make_signal(300.0, 0.2, seed=5).x
    hold = x[400:600].copy()
    quiet = np.full(200, 4.5)  # a quiet batch (clear beam) at samples 2000-2199
    x[2000:2200] = quiet
    x[2000 + where] = bad
    x[400:600] = hold
    decoded = same_as_numpy(x)
    assert decoded == len(x) // 200 - 1  # only the batch with the bad sample fell back


def test_samples_at_max_abs_v_are_decoded_by_the_small_form():
    x = make_signal(300.0, 0.3, high_v=99.0, low_v=-99.0, noise_v=1.5, seed=6).x
    x = np.clip(x, -100.0, 100.0)  # some samples exactly at +-max_abs_v
    assert same_as_numpy(x) == len(x) // 200


def test_a_ramp_longer_than_the_blocked_quiet_band():
    """level_decay_v_per_s so fast that a batch's ramp exceeds low_fraction of the contrast:
    no sample may be quiet in the blocked state; and a narrow hysteresis band."""
    sig = make_signal(250.0, 0.5, seed=7)
    fast = TachometerConfig(level_decay_v_per_s=10000.0, min_contrast_v=0.5)
    same_as_numpy(sig.x, fast)
    narrow = TachometerConfig(low_fraction=0.49, high_fraction=0.51)
    same_as_numpy(sig.x, narrow)
    same_as_numpy(sig.x, n=512)  # the largest batch segment_small takes
    same_as_numpy(sig.x, n=1)


def test_random_signals():
    """Random levels, contrasts, noise and speeds (seeded)."""
    rng = np.random.default_rng(8)
    for seed in range(12):
        lo = rng.uniform(-1.0, 2.0)
        hi = lo + rng.uniform(0.2, 4.0)
        sig = make_signal(rng.uniform(50.0, 1500.0), 0.15, high_v=hi, low_v=lo,
                          noise_v=rng.uniform(0.0, 0.4), seed=seed)
        n = int(rng.integers(20, 400))
        same_as_numpy(sig.x, n=n)
