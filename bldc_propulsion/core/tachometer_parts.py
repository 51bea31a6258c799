"""The collaborators :class:`~bldc_propulsion.core.tachometer.TachometerDecoder` is made of.

- :class:`SampleClock`: which time each sample has (anchor, gaps, resyncs, the sample-rate check);
- :class:`EdgeDetector`: samples to edge positions (level trackers, hysteresis, midpoint-crossing
  interpolation, glitches, the edge awaiting its glitch check);
- :class:`SpeedGate`: edges to speeds (one-revolution history, overspeed, noise verification,
  timeout and signal loss);
- :class:`TachCounters`: the counters all three update (the decoder shows them as attributes);
- :class:`TachOutput`: what one batch produced so far.

The steps are described in the docstring of :mod:`bldc_propulsion.core.tachometer`. Positions
are in clock samples (float, sub-sample), times in seconds.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from typing import Protocol, cast

import numpy as np

TWO_PI = 2.0 * math.pi


class Settings(Protocol):
    """What the parts read of the decoder's configuration (``tachometer.TachometerConfig`` has
    it; the parts need these numbers, not the module that checks them)."""

    @property
    def sample_rate_hz(self) -> float: ...
    @property
    def gap_tolerance_s(self) -> float: ...
    @property
    def edges_per_rev(self) -> int: ...
    @property
    def max_speed_rad_s(self) -> float: ...
    @property
    def timeout_s(self) -> float: ...
    @property
    def min_edge_interval_s(self) -> float: ...
    @property
    def level_decay_v_per_s(self) -> float: ...
    @property
    def low_fraction(self) -> float: ...
    @property
    def high_fraction(self) -> float: ...
    @property
    def min_contrast_v(self) -> float: ...
    @property
    def initial_low_v(self) -> float: ...


@dataclass(slots=True)
class TachCounters:
    """Event counters of one decoder (kept by :meth:`TachometerDecoder.reset`)."""

    batches: int = 0
    samples: int = 0
    rejected_batches: int = 0  #: time not increasing / not finite
    gaps: int = 0  #: batches that started later than expected (missing samples)
    missing_samples: int = 0
    time_resyncs: int = 0  #: batches that overlapped the previous ones beyond tolerance
    nonfinite_samples: int = 0  #: NaN/inf samples, and samples beyond max_abs_v
    nonfinite_gaps: int = 0
    edges: int = 0
    glitches: int = 0  #: edge pairs closer than physically possible, dropped
    overspeed: int = 0  #: speeds above max_speed_rad_s, rejected
    speeds: int = 0
    signal_losses: int = 0
    history_resets: int = 0
    rate_mismatch_batches: int = 0  #: batches decoded while the sample rate disagreed
    speeds_suppressed: int = 0  #: speeds not reported because of a sample-rate mismatch
    speeds_unverified: int = 0  #: speeds withheld after noise until two consecutive agree


@dataclass(slots=True)
class TachOutput:
    """Accumulator of one batch: speeds with their edge times, and every accepted edge time."""

    edge_t: list[float] = field(default_factory=list)
    speed: list[float] = field(default_factory=list)
    all_edge_t: list[float] = field(default_factory=list)


def _median(values: deque[float]) -> float:
    """``statistics.median`` (the same arithmetic) without its generality, for a few numbers."""
    data = sorted(values)
    n = len(data)
    if n % 2 == 1:
        return data[n // 2]
    i = n // 2
    return (data[i - 1] + data[i]) / 2


class SampleClock:
    """Clock index of every sample, anchored on the batch stamps (step 5 of the decoder).

    Sample ``i`` of the current clock is at ``anchor + i * dt``; a batch that does not start
    where the previous one ended (beyond ``gap_tolerance_s``) is a gap or a resync and starts a
    new clock. Also checks the median sample rate the batch stamps imply against the parameter.
    """

    __slots__ = ("dt", "counts", "_rate_hz", "_gap_tolerance_s", "_rate_tolerance",
                 "anchor", "next_idx", "last_batch_t", "t_start", "now",
                 "rates", "rate_bad", "rate_measured")

    def __init__(self, cfg: Settings, counts: TachCounters, *, rate_batches: int,
                 rate_tolerance: float) -> None:
        self.dt = 1.0 / cfg.sample_rate_hz
        self.counts = counts
        self._rate_hz = cfg.sample_rate_hz
        self._gap_tolerance_s = cfg.gap_tolerance_s
        self._rate_tolerance = rate_tolerance
        self.anchor: float | None = None  #: time of sample index 0 of the current clock
        self.next_idx = 0  #: clock index of the next expected sample
        self.last_batch_t: float | None = None  #: stamp of the last accepted batch
        self.t_start: float | None = None  #: time of the very first sample
        self.now: float | None = None  #: latest time seen (batch or check_timeout)
        self.rates: deque[float] = deque(maxlen=rate_batches)  #: implied rate / parameter
        self.rate_bad = False  #: the median implied rate disagrees with the parameter
        self.rate_measured = math.nan  #: that median rate (samples/s), while it disagrees

    def accepts(self, t_last: float) -> bool:
        """A batch stamped ``t_last`` moves time forward (else it is counted as rejected)."""
        if not math.isfinite(t_last) or (self.last_batch_t is not None and t_last <= self.last_batch_t):
            self.counts.rejected_batches += 1
            return False
        return True

    def check_rate(self, t_last: float, n: int) -> bool:
        """Compare the samples per second the batch stamps imply with the parameter.

        True if a mismatch starts with this batch (what was measured at the wrong rate is void).
        """
        rates = self.rates
        if self.last_batch_t is not None:
            rate = n / (t_last - self.last_batch_t) / self._rate_hz
            rates.append(rate)
            if not self.rate_bad and len(rates) == rates.maxlen and rates.maxlen % 2 == 1 \
                    and abs(rate - 1.0) <= self._rate_tolerance:
                # a good median (of the full odd window, or of the one value short before it)
                # leaves at most half the window bad on either side, and a good value added in
                # place of an old one cannot make more: the verdict stays good, unsorted
                return False
        if not rates:  # the first batch: no timing to compare yet
            return False
        ratio = float(_median(rates))  # 5 numbers: faster than np.median
        bad = abs(ratio - 1.0) > self._rate_tolerance
        starts = False
        if bad:
            self.rate_measured = ratio * self._rate_hz
            self.counts.rate_mismatch_batches += 1
            starts = not self.rate_bad
        self.rate_bad = bad
        return starts

    def breaks(self, t_first: float) -> bool:
        """True if a batch whose first sample is at ``t_first`` does not continue the clock
        (gap or resync, counted); the caller then settles the old clock and calls :meth:`restart`."""
        dt, anchor = self.dt, self.anchor
        assert anchor is not None, "breaks() is asked from the second batch on"
        delta = t_first - (anchor + self.next_idx * dt)
        if abs(delta) > self._gap_tolerance_s:
            if delta > 0:
                self.counts.gaps += 1
                self.counts.missing_samples += int(round(delta / dt))
            else:
                self.counts.time_resyncs += 1
            return True
        return False

    def restart(self, t_first: float) -> None:
        """A new clock whose index 0 is at ``t_first``."""
        self.anchor, self.next_idx = t_first, 0
        if self.t_start is None:
            self.t_start = t_first

    def advance(self, t_last: float, n: int) -> int:
        """Account for a batch of n samples stamped t_last; the clock index of its first sample."""
        self.counts.batches += 1
        self.counts.samples += n
        self.last_batch_t = t_last
        i0 = self.next_idx
        self.next_idx += n
        return i0

    def last_sample_t(self) -> float:
        assert self.anchor is not None, "no sample yet"
        return self.anchor + (self.next_idx - 1) * self.dt

    def see(self, now: float) -> None:
        """Time has reached ``now`` (never goes back)."""
        if self.now is None or now > self.now:
            self.now = now


class SpeedGate:
    """Accepted edges to speeds (steps 4 and 6): one-revolution history, overspeed, noise
    verification, timeout and signal loss."""

    __slots__ = ("counts", "_clock", "_n_rev", "_max_speed", "_timeout_s", "_verify_tol",
                 "_max_accel", "hist", "last_edge_t", "lost", "edges_since_loss", "have_speed",
                 "speed_now", "verify", "candidate", "t_speed")

    def __init__(self, cfg: Settings, counts: TachCounters, clock: SampleClock, *,
                 verify_tolerance: float, max_accel: float) -> None:
        self.counts = counts
        self._clock = clock  # edge positions to times, and the sample-rate verdict
        self._n_rev = cfg.edges_per_rev
        self._max_speed = cfg.max_speed_rad_s
        self._timeout_s = cfg.timeout_s
        self._verify_tol = verify_tolerance
        self._max_accel = max_accel
        self.hist: deque[float] = deque(maxlen=self._n_rev + 1)  #: edge positions (samples)
        self.last_edge_t: float | None = None
        self.lost = True  #: no signal yet, or lost
        self.edges_since_loss = 0
        self.have_speed = False
        self.speed_now = 0.0
        self.verify = False  #: noise seen: check speeds against each other before reporting
        self.candidate: float | None = None  #: the previous speed under verification
        self.t_speed: float | None = None  #: time of the last reported speed

    def clear_history(self) -> None:
        """No speed across this point (gap, loss, rate mismatch)."""
        if self.hist:
            self.counts.history_resets += 1
        self.hist.clear()

    def void_speed(self) -> None:
        """The speed so far was measured at a wrong sample rate: forget it."""
        self.speed_now = 0.0
        self.have_speed = False
        self.clear_history()

    def noise_seen(self) -> None:
        """Evidence of noise: verify the next speeds before reporting them."""
        self.verify, self.candidate = True, None

    def declare_lost(self) -> None:
        self.lost = True
        self.counts.signal_losses += 1
        self.speed_now = 0.0
        self.have_speed = False
        self.edges_since_loss = 0
        self.clear_history()

    def check_timeout(self, now: float, t_start: float | None, t_pending: float | None) -> bool:
        """Declare the signal lost if no edge came for timeout_s before ``now``; True if so here.

        ``t_pending`` is the time of an edge still awaiting its glitch check (None if none).
        """
        ref = self.last_edge_t if self.last_edge_t is not None else t_start
        if self.lost or ref is None or now - ref <= self._timeout_s:
            return False
        if t_pending is not None and t_pending - ref <= self._timeout_s:
            return False  # an edge arrived in time, it is only awaiting its glitch check
        self.declare_lost()
        return True

    def edge(self, p: float, out: TachOutput) -> None:
        """An accepted edge at position p: history, speed, timeout bookkeeping."""
        clock = self._clock
        assert clock.anchor is not None, "an edge comes from a decoded sample"
        t = clock.anchor + p * clock.dt
        counts = self.counts
        if self.last_edge_t is not None and t - self.last_edge_t > self._timeout_s \
                and not self.lost:
            self.declare_lost()  # silence between two edges longer than the timeout
        self.lost = False
        self.edges_since_loss += 1
        counts.edges += 1
        self.last_edge_t = t
        hist = self.hist
        hist.append(p)
        out.all_edge_t.append(t)
        if len(hist) == self._n_rev + 1:
            w = TWO_PI / ((p - hist[0]) * clock.dt)
            if w > self._max_speed:
                counts.overspeed += 1
                counts.history_resets += 1
                self.verify, self.candidate = True, None
                hist.clear()
                hist.append(p)
                return
            if clock.rate_bad:  # edge times scaled by the wrong rate: not a speed
                counts.speeds_suppressed += 1
                return
            if not self._plausible(w, t):
                counts.speeds_unverified += 1
                return
            counts.speeds += 1
            self.t_speed = t
            self.speed_now = w
            self.have_speed = True
            out.edge_t.append(t)
            out.speed.append(w)

    def _plausible(self, w: float, t: float) -> bool:
        """Whether speed w at time t may be reported (the noise verification of step 4)."""
        tol = self._verify_tol
        reachable = True
        if self.t_speed is not None and self.speed_now > 0.0:
            jump = abs(w - self.speed_now)
            reachable = jump <= self._max_accel * (t - self.t_speed) + tol * self.speed_now
        if not reachable and not self.verify:
            self.verify, self.candidate = True, None
        if self.verify:  # after noise: only a plausible speed that its predecessor confirms
            prev, self.candidate = self.candidate, w
            agree = (self.t_speed is not None and self.speed_now > 0.0 and reachable
                     and abs(w / self.speed_now - 1.0) <= tol)
            if not agree and (prev is None or abs(w / prev - 1.0) > tol or not reachable):
                return False
            self.verify, self.candidate = False, None
        return True


@dataclass(slots=True)
class RowPlan:
    """Rows of :meth:`EdgeDetector.plan_rows`: per batch the clear level ``HI``, the clamped
    blocked level ``LO`` and the normalised signal ``R`` (as :meth:`EdgeDetector.segment`
    computes them), the state assumed on entry and left on exit, and the hysteresis events
    of each row: its first event (a sample beyond a threshold: column ``first_col``, -1 if
    none, and ``first_val``, True above), its last event's value, and the columns where an
    event differs from the row's previous one (``switch_cols[bounds[j]:bounds[j+1]]``)."""

    X: np.ndarray
    HI: np.ndarray
    LO: np.ndarray
    R: np.ndarray
    enter: list[tuple[float | None, float | None, float | None]]
    hi_end: list[float]
    lo_end: list[float]
    last: list[float]
    r_last: list[float]
    r_first: list[float]
    first_col: list[int]
    first_val: list[bool]
    last_val: list[bool]
    switch_cols: list[int]
    bounds: list[int]


class EdgeDetector:
    """Contiguous finite samples to edge positions (steps 1 to 4 of the decoder).

    Tracks the clear and blocked levels, applies the hysteresis, interpolates each edge at the
    midpoint crossing and holds the latest edge until no later switch can make it a glitch;
    accepted edges go to the :class:`SpeedGate`.
    """

    __slots__ = ("counts", "_gate", "_decay", "_ramp", "_ramp_list", "_min_trig", "_low_f", "_high_f",
                 "_min_contrast", "_initial_low", "hi", "lo", "level_now", "known",
                 "tail", "state", "r_last", "cross", "pending", "pending_levels")

    def __init__(self, cfg: Settings, counts: TachCounters, gate: SpeedGate) -> None:
        self.counts = counts
        self._gate = gate
        dt = 1.0 / cfg.sample_rate_hz
        self._decay = cfg.level_decay_v_per_s * dt  # volts per sample
        self._ramp = np.arange(1024, dtype=float) * self._decay
        self._ramp_list: list[float] = self._ramp.tolist()  #: the same, for segment_small
        self._min_trig = cfg.min_edge_interval_s * cfg.sample_rate_hz  # in samples
        self._low_f = cfg.low_fraction
        self._high_f = cfg.high_fraction
        self._min_contrast = cfg.min_contrast_v
        self._initial_low = cfg.initial_low_v
        self.hi: float | None = None  #: clear-level tracker (unclamped), carried across gaps
        self.lo: float | None = None  #: blocked-level tracker (unclamped), carried across gaps
        self.level_now = math.nan  #: latest sample (V)
        self.known: tuple[float, float] | None = None  #: (blocked, clear) at the last edge
        self.break_continuity()

    def break_continuity(self) -> None:
        """Samples before and after this point are not adjacent: no interpolation across."""
        self.tail: float | None = None  #: previous raw sample (spike guard of the trackers)
        self.state: bool | None = None  #: hysteresis state: True = high (beam clear)
        self.r_last: float | None = None  #: normalised level of the previous sample
        self.cross: float | None = None  #: position of the latest midpoint crossing
        self.pending: tuple[float, int] | None = None  #: (position, switch index)
        self.pending_levels = (math.nan, math.nan)  #: (blocked, clear) at the pending edge

    def settle(self, out: TachOutput) -> None:
        """Samples are missing: accept the pending edge now and forget continuity."""
        if self.pending is not None:
            self._confirm(out)
        self._gate.clear_history()
        self.break_continuity()

    def _confirm(self, out: TachOutput) -> None:
        assert self.pending is not None, "confirmed only while an edge is pending"
        self.known = self.pending_levels
        self._gate.edge(self.pending[0], out)

    def _ramp_for(self, n: int) -> np.ndarray:
        if n > len(self._ramp):
            self._ramp = np.arange(max(n, 2 * len(self._ramp)), dtype=float) * self._decay
        return self._ramp[:n]

    def segment(self, x: np.ndarray, i0: int, out: TachOutput) -> None:
        """Decode contiguous finite samples x whose first one has clock index i0."""
        n = len(x)
        c = self._decay
        x0 = x.item(0)
        if self.tail is None:
            self.tail = x0
        hi0, lo0 = self.hi, self.lo
        if hi0 is None or lo0 is None:  # the first samples: the trackers start here
            hi0, lo0 = x0 + c, min(self._initial_low, x0) - c
        # Level trackers see a 2-sample min (clear level) / max (blocked level) of the signal,
        # so a one-sample spike does not move them. Peak trackers with linear decay,
        # hi[i] = max(s[i], hi[i-1] - c), vectorised as hi[i] = max_j<=i (s[j] + c j) - c i
        # (and the same for lo with min).
        k = self._ramp[:n] if n <= len(self._ramp) else self._ramp_for(n)
        u = np.empty(n)
        np.minimum(x[:-1], x[1:], out=u[1:])
        u[0] = min(self.tail, x0)
        u += k
        if u[0] < hi0 - c:
            u[0] = hi0 - c
        np.maximum.accumulate(u, out=u)
        hi = u
        hi -= k
        v = np.empty(n)
        np.maximum(x[:-1], x[1:], out=v[1:])
        v[0] = max(self.tail, x0)
        v -= k
        if v[0] > lo0 + c:
            v[0] = lo0 + c
        np.minimum.accumulate(v, out=v)
        lo = v
        lo += k
        self.tail = self.level_now = x.item(-1)
        self.hi, self.lo = hi.item(-1), lo.item(-1)
        # clamp: keep the blocked level at least min_contrast_v under the clear level
        np.minimum(lo, hi - self._min_contrast, out=lo)
        span = hi - lo
        r = x - lo
        r /= span  # 0 = blocked level, 1 = clear level
        r_prev0 = self.r_last if self.r_last is not None else r.item(0)
        self.r_last = r.item(-1)
        low_f, high_f = self._low_f, self._high_f
        state = self.state
        if state is None:
            state = self.state = bool(r[0] >= 0.5)
        # fast path: nothing can switch
        if (r.min() >= low_f) if state else (r.max() <= high_f):
            trig = None
        else:
            # vectorised hysteresis: +1 above high, -1 below low; a switch is an event whose
            # sign differs from the previous event's
            e = (r > high_f).view(np.int8) - (r < low_f).view(np.int8)
            ev = np.flatnonzero(e)
            val = e[ev] > 0
            prev = np.empty_like(val)
            prev[0] = state
            prev[1:] = val[:-1]
            trig = ev[val != prev]
            self.state = bool(val[-1])
        self._finish_slice(r, trig.tolist() if trig is not None else (), hi, lo, r_prev0, i0, out)

    def _entry(self, tail: float | None, hi: float | None, lo: float | None, x0: float) -> tuple[float, float]:
        """The clear and blocked trackers' values at a batch's first sample x0 (k = 0), from the
        previous batch's last sample ``tail`` (the spike guard) and the levels carried in: the
        scalar chain :meth:`segment` runs, for :meth:`plan_rows` and :meth:`segment_small`."""
        c = self._decay
        if tail is None:
            tail = x0
        if hi is None or lo is None:
            hi = x0 + c
            lo = min(self._initial_low, x0) - c
        u0 = min(tail, x0) + 0.0
        if u0 < hi - c:
            u0 = hi - c
        v0 = max(tail, x0) - 0.0
        if v0 > lo + c:
            v0 = lo + c
        return u0, v0

    def segment_small(self, xs: Sequence[float], i0: int, lim: float, out: TachOutput) -> bool:
        """:meth:`segment` of a short batch of Python floats, one sample at a time, with no numpy
        call: the same arithmetic, operation for operation, so the same results to the last bit
        (tested). Why a second form: a live node wakes for each ~200-sample batch with cold
        caches, where segment's ~25 numpy calls cost about twice this loop (numpy is faster only
        when warm; replay plans its batches instead). False, with nothing changed, if a sample
        is not finite or beyond ``lim``; the caller then takes segment's NaN path.

        Most samples are quiet (:meth:`_quiet`): deep in the clear or the blocked level, where
        they cannot switch and ``_crossing`` never reads their normalised level, so only the
        trackers they can move are updated. The others go through :meth:`_loud`. A quiet
        sample's level is computed only if the next sample is loud or it is the batch's last."""
        n = len(xs)
        ks = self._ramp_list
        if n > len(ks):
            return False
        x0 = xs[0]
        if not -lim <= x0 <= lim:
            return False
        mc = self._min_contrast
        U, V = self._entry(self.tail, self.hi, self.lo, x0)
        lc = U - mc
        if V < lc:
            lc = V
        r_first = (x0 - lc) / (U - lc)
        rs: list[float | None] = [None] * n
        rs[0] = r_first
        state = self.state
        if state is None:
            state = r_first >= 0.5
        trig: list[int] = []
        his: dict[int, float] = {}
        los: dict[int, float] = {}
        if (r_first < self._low_f) if state else (r_first > self._high_f):
            trig.append(0)
            his[0], los[0] = U, lc
            state = not state
        k_max = ks[n - 1]
        # the least h - lc of the batch (trackers only widen it), and a margin far above the
        # rounding of volts within lim (~1e-16 of them) for the quiet verdicts
        span = max(mc, (U - k_max) - V - k_max)
        margin = 1e-9 * (1.0 + lim)
        if not (-lim <= V and U <= lim):  # carried trackers beyond lim: cannot happen, but _quiet
            return False  # relies on it (the caller's numpy path then gives the same result)
        samples = enumerate(xs)
        next(samples)  # sample 0: above
        while True:
            i, s, U, V = self._quiet(xs, samples, state, U, V, k_max, span, margin, lim)
            if i == 0:  # no sample left
                break
            if not -lim <= s <= lim:  # NaN or beyond lim
                return False
            U, V, state = self._loud(i, s, xs[i - 1], U, V, state, rs, trig, his, los)
        prev = xs[-1]
        last = rs[-1]
        if last is None:
            last = rs[-1] = self._level(prev, U, V, k_max)
        self.tail = self.level_now = prev
        self.hi, self.lo = U - k_max, V + k_max
        r_prev0 = self.r_last if self.r_last is not None else r_first
        self.r_last = last
        self.state = state
        # every level _finish_slice reads is set (the docstring's rule); the others stay None
        self._finish_slice(cast(list[float], rs), trig, his, los, r_prev0, i0, out)
        return True

    def _quiet(self, xs: Sequence[float], samples: Iterator[tuple[int, float]], clear: bool,
               U: float, V: float, k_max: float, span: float, margin: float,  # noqa: N803
               lim: float) -> tuple[int, float, float, float]:
        """segment_small over quiet samples: from ``samples`` (index, value: an enumerate of the
        batch ``xs`` at sample 1 or later), in the clear state if ``clear`` else the blocked one,
        with the trackers at ``U`` and ``V``. Returns (i, s, U, V) at the first sample that is
        not quiet (i = 0: none left).

        Quiet, whatever the trackers do meanwhile (h the clear level, lc the clamped blocked
        one, h - lc >= ``span``; ``margin`` covers rounding): in the clear state s >= U -
        (1 - high_fraction) span has a normalised level above high_fraction (h <= max(U, s));
        in the blocked state s <= min(U - k_max - min_contrast, V) + low_fraction span has one
        below low_fraction (lc >= min(h - min_contrast, V, s - k_max); so does a ramp k_max
        under low_fraction span). Those bounds are kept from ``u_cap`` >= U and ``v_cap`` <= V,
        moved only when a tracker passes them, so a tracker that moves every sample (a rotor
        standing still) does not recompute them every sample. A tracker is updated, with
        segment's arithmetic, only for a sample that can move it: above u_top (U - k_max) or
        below v_bot (V + k_max), bounds that move with it (or stay, in the other tracker's
        state: more samples tested, none missed); both are inside lim (segment_small's guard),
        so a sample beyond lim is caught there."""
        ks = self._ramp_list
        km = k_max + margin
        u_top, v_bot = U - km, V + km
        slack = self.QUIET_SLACK * span
        if clear:
            c1 = (1.0 - self._high_f) * span - margin
            u_cap = U + slack
            clear_from = u_cap - c1
            quiet_from = clear_from if clear_from > v_bot else v_bot  # and V stays
            for i, s in samples:
                if not s >= quiet_from:  # (not <: a NaN lands here, and is returned)
                    if not s >= clear_from or s < -lim:
                        return i, s, U, V
                    k = ks[i]  # a blocked tracker decayed up to the signal
                    prev = xs[i - 1]
                    v = prev - k if s < prev else s - k
                    if v < V:
                        V = v
                if s > u_top:
                    if s > lim:
                        return i, s, U, V
                    k = ks[i]
                    prev = xs[i - 1]
                    u = s + k if s < prev else prev + k
                    if u > U:
                        U = u
                        u_top = U - km
                        if U > u_cap:
                            u_cap = U + slack
                            clear_from = u_cap - c1
                            quiet_from = clear_from if clear_from > v_bot else v_bot
            return 0, 0.0, U, V
        low = self._low_f * span - margin
        h_floor = U - k_max - self._min_contrast
        v_cap = V - slack
        blocked_to = (h_floor if h_floor < v_cap else v_cap) + low if k_max < low else -math.inf
        quiet_to = blocked_to if blocked_to < u_top else u_top  # and U stays
        for i, s in samples:
            if not s <= quiet_to:  # (not >: a NaN lands here, and is returned)
                if not s <= blocked_to or s > lim:
                    return i, s, U, V
                k = ks[i]  # a clear tracker decayed down to the signal
                prev = xs[i - 1]
                u = s + k if s < prev else prev + k
                if u > U:
                    U = u
            if s < v_bot:
                if s < -lim:
                    return i, s, U, V
                k = ks[i]
                prev = xs[i - 1]
                v = prev - k if s < prev else s - k
                if v < V:
                    V = v
                    v_bot = V + km
                    if V < v_cap and k_max < low:
                        v_cap = V - slack
                        blocked_to = (h_floor if h_floor < v_cap else v_cap) + low
                        quiet_to = blocked_to if blocked_to < u_top else u_top
        return 0, 0.0, U, V

    def _loud(self, i: int, s: float, prev: float, U: float, V: float, state: bool,  # noqa: N803
              rs: list[float | None], trig: list[int], his: dict[int, float],
              los: dict[int, float]) -> tuple[float, float, bool]:
        """segment_small's full step for sample ``i`` (``s``, after ``prev``), which is not quiet:
        both trackers, its normalised level (and the previous sample's, if that was quiet), and
        a switch. Returns the trackers and the hysteresis state after it."""
        ks = self._ramp_list
        mc = self._min_contrast
        if rs[i - 1] is None:  # the previous sample was quiet: _crossing may read its level
            k = ks[i - 1]  # (_level, inline: one call less per edge)
            h = U - k
            lc = h - mc
            l_ = V + k
            if l_ < lc:
                lc = l_
            rs[i - 1] = (prev - lc) / (h - lc)
        k = ks[i]
        if s < prev:  # the 2-sample min feeds the clear level, the max the blocked level
            u, v = s + k, prev - k
        else:
            u, v = prev + k, s - k
        if u > U:
            U = u
        if v < V:
            V = v
        h = U - k
        lc = h - mc
        l_ = V + k
        if l_ < lc:
            lc = l_
        r = rs[i] = (s - lc) / (h - lc)
        if (r < self._low_f) if state else (r > self._high_f):
            trig.append(i)
            his[i], los[i] = h, lc
            state = not state
        return U, V, state

    def _level(self, s: float, U: float, V: float, k: float) -> float:  # noqa: N803 - as in segment_small
        """The normalised level of sample ``s`` with the trackers at ``U``, ``V`` and ramp ``k``:
        segment_small's arithmetic, operation for operation."""
        h = U - k
        lc = h - self._min_contrast
        l_ = V + k
        if l_ < lc:
            lc = l_
        return (s - lc) / (h - lc)

    #: how far past a tracker segment_small's quiet bounds are set (a fraction of the span),
    #: so that a tracker moving every sample moves them once in many samples
    QUIET_SLACK = 0.05

    # --- many batches' levels at once (the same arithmetic as segment, row by row) ----------
    def plan_rows(self, X: np.ndarray) -> RowPlan:
        """Level trackers of the batches ``X`` (rows: contiguous, finite, each a whole batch),
        computed ahead on the assumption that each row is segmented right after the previous
        one, starting from the detector's current state. :meth:`segment_planned` uses a row
        only when the state it meets is the one assumed (checked), so results are those of
        :meth:`segment` either way."""
        m, n = X.shape
        k = self._ramp[:n] if n <= len(self._ramp) else self._ramp_for(n)
        U = np.empty((m, n))
        np.minimum(X[:, :-1], X[:, 1:], out=U[:, 1:])
        U[:, 1:] += k[1:]
        V = np.empty((m, n))
        np.maximum(X[:, :-1], X[:, 1:], out=V[:, 1:])
        V[:, 1:] -= k[1:]
        u_max = U[:, 1:].max(axis=1).tolist() if n > 1 else [-math.inf] * m
        v_min = V[:, 1:].min(axis=1).tolist() if n > 1 else [math.inf] * m
        first, last = X[:, 0].tolist(), X[:, -1].tolist()
        k_end = k.item(n - 1)
        enter: list[tuple[float | None, float | None, float | None]] = []
        u0s, v0s = [], []
        tail, hi, lo = self.tail, self.hi, self.lo
        for j in range(m):  # the scalar chain segment runs at the start of each row
            enter.append((tail, hi, lo))
            u0, v0 = self._entry(tail, hi, lo, first[j])
            u0s.append(u0)
            v0s.append(v0)
            tail = last[j]
            hi = max(u0, u_max[j]) - k_end
            lo = min(v0, v_min[j]) + k_end
        U[:, 0] = u0s
        V[:, 0] = v0s
        np.maximum.accumulate(U, axis=1, out=U)
        U -= k
        np.minimum.accumulate(V, axis=1, out=V)
        V += k
        hi_end, lo_end = U[:, -1].tolist(), V[:, -1].tolist()
        np.minimum(V, U - self._min_contrast, out=V)  # clamped blocked level
        R = X - V
        R /= U - V
        low_f, high_f = self._low_f, self._high_f
        E = (R > high_f).view(np.int8) - (R < low_f).view(np.int8)
        rows, cols = np.nonzero(E)
        val = E[rows, cols] > 0
        new_row = np.ones(len(rows), dtype=bool)
        new_row[1:] = rows[1:] != rows[:-1]
        switch = ~new_row
        switch[1:] &= val[1:] != val[:-1]
        # per row: its first event (column, value), its last event's value, its inner switches
        first_col = np.full(m, -1, dtype=np.int64)
        first_val = np.zeros(m, dtype=bool)
        last_val = np.zeros(m, dtype=bool)
        starts = np.flatnonzero(new_row)
        first_col[rows[starts]] = cols[starts]
        first_val[rows[starts]] = val[starts]
        ends = np.append(starts[1:], len(rows)) - 1
        last_val[rows[ends]] = val[ends]
        sw_rows = rows[switch]
        bounds = np.searchsorted(sw_rows, np.arange(m + 1)).tolist()
        return RowPlan(X, U, V, R, enter, hi_end, lo_end, last, R[:, -1].tolist(), R[:, 0].tolist(),
                       first_col.tolist(), first_val.tolist(), last_val.tolist(),
                       cols[switch].tolist(), bounds)

    def segment_planned(self, plan: RowPlan, j: int, i0: int, out: TachOutput) -> bool:
        """:meth:`segment` of row j of ``plan`` if the state is the one the plan assumed for
        it (True); False, with nothing done, otherwise."""
        if plan.enter[j] != (self.tail, self.hi, self.lo):
            return False
        r = plan.R[j]
        self.tail = self.level_now = plan.last[j]
        self.hi, self.lo = plan.hi_end[j], plan.lo_end[j]
        r_prev0 = self.r_last if self.r_last is not None else plan.r_first[j]
        self.r_last = plan.r_last[j]
        state = self.state
        if state is None:
            state = self.state = plan.r_first[j] >= 0.5
        first = plan.first_col[j]
        if first >= 0:  # the row has hysteresis events
            trig = plan.switch_cols[plan.bounds[j]:plan.bounds[j + 1]]
            if plan.first_val[j] != state:
                trig.insert(0, first)
            self.state = plan.last_val[j]
        else:
            trig = []
        self._finish_slice(r, trig, plan.HI[j], plan.LO[j], r_prev0, i0, out)
        return True

    def _finish_slice(self, r: np.ndarray | list[float], trig: Sequence[int],
                      hi: np.ndarray | dict[int, float], lo: np.ndarray | dict[int, float],
                      r_prev0: float, i0: int, out: TachOutput) -> None:
        """The end of :meth:`segment` and :meth:`segment_planned` (one place, so the planned
        path cannot drift from the plain one; ``hi[kk]``, ``lo[kk]`` are the levels at each
        switch, arrays or dicts): the slice's switches at indices ``trig``, the
        crossing of a slice that ends inside a transition, and the pending edge's confirmation."""
        for kk in trig:
            p = self._crossing(r, kk, r_prev0, i0)
            if p is None:  # the crossing was in an earlier slice
                p = self.cross if self.cross is not None else float(i0 + kk)
            self._switch(p, i0 + kk, out, hi[kk], lo[kk])
        assert self.r_last is not None, "both callers set it first"
        if self._low_f <= self.r_last <= self._high_f:
            # the slice ends inside a transition: its switch may come in a later slice and
            # need the midpoint crossing found here
            p = self._crossing(r, len(r), r_prev0, i0)
            if p is not None:
                self.cross = p
        # a pending edge is confirmed once no later switch can be close enough to cancel it
        if self.pending is not None and (i0 + len(r) - self.pending[1]) >= self._min_trig:
            self._confirm(out)
            self.pending = None

    def _crossing(self, r: np.ndarray | list[float], kk: int, r_prev0: float, i0: int) -> float | None:
        """Position (clock samples) of the last midpoint crossing at or before index kk of the slice.

        Scans back while the signal stays in the hysteresis band (between a crossing and its
        switch it does); None if the crossing is before the slice or not there yet.
        kk == len(r) asks for the last crossing of the slice.
        """
        lo_f, hi_f = self._low_f, self._high_f
        item = r.item if isinstance(r, np.ndarray) else r.__getitem__
        i = min(kk, len(r) - 1)
        side = item(i) >= 0.5
        while True:
            rb = item(i)
            ra = item(i - 1) if i > 0 else r_prev0
            if (ra >= 0.5) != side and (rb >= 0.5) == side:
                frac = (ra - 0.5) / (ra - rb) if ra != rb else 0.0
                return i0 + i - 1 + frac
            if i == 0 or not (lo_f <= ra <= hi_f):
                return None
            i -= 1

    def _switch(self, p: float, g: int, out: TachOutput, hi: float, lo: float) -> None:
        """A hysteresis switch at clock index g, interpolated edge position p."""
        if self.pending is not None:
            if g - self.pending[1] < self._min_trig:  # a spike: drop it and its partner
                self.counts.glitches += 1
                self._gate.noise_seen()
                self.pending = None
                return
            self._confirm(out)
        self.pending = (p, g)
        self.pending_levels = (float(lo), float(hi))
