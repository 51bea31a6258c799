"""Rotor speed from the phototransistor signal: edges of the blades cutting an infrared beam.

The beam is clear (high voltage) most of the time; each blade pulls the signal low while it
passes, so one revolution gives ``2 * blades`` edges. As in the paper, a speed is computed at
every edge from the edge one revolution earlier,

    w_k = 2 pi / (t_k - t_{k - edges_per_rev}),

which is the mean speed over the last revolution and cancels any blade asymmetry (spacing or
width), because both ends of the interval are the same physical edge. The first speed comes
at the (edges_per_rev + 1)-th edge; nothing is extrapolated, and after ``timeout_s`` without
an edge the speed is 0.

Decoding, streamed over batches (state carried across batch boundaries, so the edges and
speeds do not depend on how the samples are cut into batches):

1. Levels: the clear and blocked levels are tracked by peak trackers (max/min with a slow
   linear decay, ``level_decay_v_per_s``) of the 2-sample minimum (clear) and maximum
   (blocked) of the signal, so a one-sample spike does not move them. Before a blade has been
   seen, the blocked level is guessed as ``initial_low_v``; the two levels are kept at least
   ``min_contrast_v`` apart. A spike longer than one sample above the clear level raises the
   clear level until it decays (``level_decay_v_per_s``); edges may be missed meanwhile.
2. Hysteresis: the signal goes low below ``low_fraction`` and high above ``high_fraction`` of
   the way from the blocked to the clear level (noise cannot chatter between them).
3. Edge time: linear interpolation between the two samples around the crossing of the
   midpoint level that precedes the hysteresis switch (sub-sample resolution).
4. Glitches: two switches closer than the shortest physically possible edge interval
   (``min_edge_fraction`` of a revolution at ``max_speed_rad_s``) are a spike, not a blade:
   both are dropped and counted. A speed above ``max_speed_rad_s`` is rejected too.
   Noise can also make switches far enough apart to pass as edges. Evidence of noise is a
   glitch, an overspeed, or a speed that jumped more than a rotor can accelerate
   (``MAX_ACCEL_RAD_S2`` plus ``VERIFY_TOLERANCE``) from the last reported one. After such
   evidence a speed is only reported once two consecutive one-revolution speeds agree
   within ``VERIFY_TOLERANCE`` and are reachable from the last reported speed (counted as
   ``speeds_unverified`` until then), so a noise burst does not yield a made-up speed.
5. Time: sample times come from a clock anchored on the batch stamps (the stamp is the time of
   the batch's last sample). A batch starting later than expected by more than
   ``gap_tolerance_s`` means samples are missing: the edge history is reset (no speed across
   the gap). Batches that do not move forward are rejected. NaN/inf samples, and samples
   beyond ``max_abs_v`` (not an ADC reading), are dropped and treated as a gap.
   Sample rate check: each batch's sample count over the time since the previous batch's
   stamp is the rate the data really has. When the median over the last
   ``RATE_CHECK_BATCHES`` batches differs from ``sample_rate_hz`` by more than
   ``RATE_TOLERANCE`` (relative), the parameter is wrong for this data: every edge time and
   speed would be scaled by the ratio, so no speed is produced (speed 0, ``signal_ok``
   False, status ERROR naming both rates) until the batches agree with the parameter again.
   It is checked from the second batch on (the first has nothing to compare with); once a
   few batches have arrived, one late or missing batch is an outlier of the median, not a
   mismatch.
6. Silence: no edge for ``timeout_s`` gives speed 0 and ``signal_ok`` False (one signal loss
   counted). A rotor standing still also gives no edges: the signal level then tells what can
   be known: ``stopped`` (steady at the clear level: speed 0 is true), ``blocked`` (steady at the
   blocked level: a blade parked in the beam, or the emitter dark), ``stuck`` (steady between
   the levels: sensor fault), ``no_edges`` (no blade seen yet, levels unknown).
"""

from __future__ import annotations

import math
import statistics
from collections import deque
from dataclasses import dataclass, field

import numpy as np

from ..errors import BadInputError
from .status import ERROR, OK, WARN, CoreStatus, counters

TWO_PI = 2.0 * math.pi

#: Values of :attr:`TachBatchResult.state`.
SPINNING = "spinning"
STARTING = "starting"  #: edges seen, not yet a full revolution since start/loss
STOPPED = "stopped"
BLOCKED = "blocked"
STUCK = "stuck"
NO_EDGES = "no_edges"

_STATE_TEXT = {
    SPINNING: "spinning",
    STARTING: "edges arriving, first revolution not complete",
    STOPPED: "no edges: signal steady at the clear-beam level (rotor standing still or < timeout speed)",
    BLOCKED: "no edges: signal stuck at the blocked level (blade parked in the beam, or emitter dark)",
    STUCK: "no edges: signal stuck between the clear and blocked levels (sensor fault?)",
    NO_EDGES: "no blade edge seen yet (levels unknown)",
}


@dataclass(frozen=True)
class TachometerConfig:
    """Parameters of :class:`TachometerDecoder` (SI units, volts at the ADC)."""

    sample_rate_hz: float = 20000.0
    blades: int = 2
    max_speed_rad_s: float = 2000.0
    timeout_s: float = 0.3  #: ~ a revolution at 5 rad/s with 2 blades
    #: shortest angle between two edges, as a fraction of a revolution (narrowest blade or gap)
    min_edge_fraction: float = 0.02
    low_fraction: float = 0.35
    high_fraction: float = 0.65
    min_contrast_v: float = 0.5  #: least clear-minus-blocked difference that is a real signal
    level_decay_v_per_s: float = 1.0  #: how fast a level tracker forgets a peak
    initial_low_v: float = 0.0  #: guess of the blocked level before a blade has been seen
    gap_tolerance_s: float = 0.005  #: batch-time slack before a gap (missing samples) is declared
    #: samples beyond +-max_abs_v are not ADC readings (corrupt data): dropped like NaN, so
    #: one absurd value cannot drive the level trackers out of range for hours
    max_abs_v: float = 100.0

    def __post_init__(self) -> None:
        for name in ("sample_rate_hz", "max_speed_rad_s", "timeout_s", "min_edge_fraction",
                     "min_contrast_v", "level_decay_v_per_s", "gap_tolerance_s", "max_abs_v"):
            v = getattr(self, name)
            if not (isinstance(v, (int, float)) and math.isfinite(v) and v > 0):
                raise BadInputError(f"tachometer: {name} must be > 0, got {v!r}")
        if isinstance(self.blades, bool) or not isinstance(self.blades, int) or self.blades < 1:
            raise BadInputError(f"tachometer: blades must be an integer >= 1, got {self.blades!r}")
        if not (0.0 < self.low_fraction < 0.5 < self.high_fraction < 1.0):
            raise BadInputError(
                "tachometer: need 0 < low_fraction < 0.5 < high_fraction < 1, got "
                f"{self.low_fraction!r}, {self.high_fraction!r}")
        if not (self.min_edge_fraction < 1.0 / (2 * self.blades)):
            raise BadInputError(f"tachometer: min_edge_fraction {self.min_edge_fraction!r} too large")
        if not math.isfinite(self.initial_low_v):
            raise BadInputError("tachometer: initial_low_v must be finite")

    @property
    def edges_per_rev(self) -> int:
        return 2 * self.blades

    @property
    def min_edge_interval_s(self) -> float:
        """Shortest physically possible time between two edges."""
        return self.min_edge_fraction * TWO_PI / self.max_speed_rad_s


@dataclass(frozen=True)
class TachBatchResult:
    """What one batch produced.

    ``edge_t[i]`` and ``speed[i]`` belong together: the time (s) of an edge that completed a
    revolution, and the mean speed (rad/s) over that revolution. ``all_edge_t`` lists every
    accepted edge, including those without a speed (start-up, after a reset).
    """

    edge_t: np.ndarray
    speed: np.ndarray
    speed_now: float  #: latest speed (rad/s); 0.0 after a signal loss / before the first speed
    signal_ok: bool  #: a speed has been measured within timeout_s
    all_edge_t: np.ndarray = field(default_factory=lambda: np.zeros(0))
    state: str = NO_EDGES  #: one of spinning, starting, stopped, blocked, stuck, no_edges


_EMPTY = np.zeros(0)


class TachometerDecoder:
    """Streaming decoder of phototransistor batches into edge times and speeds."""

    _CHUNK = 16384  #: long inputs are processed in slices of this size (cache, precision)
    RATE_CHECK_BATCHES = 5  #: batches whose median sample rate is compared with the parameter
    RATE_TOLERANCE = 0.2  #: relative difference of that rate from sample_rate_hz that is a mismatch
    VERIFY_TOLERANCE = 0.05  #: relative agreement of consecutive speeds that ends a noise check
    MAX_ACCEL_RAD_S2 = 20000.0  #: faster speed changes than this are noise (a 12" prop: ~5000)

    def __init__(self, config: TachometerConfig | None = None) -> None:
        self.config = config or TachometerConfig()
        cfg = self.config
        self.dt = 1.0 / cfg.sample_rate_hz
        self._n_rev = cfg.edges_per_rev
        self._min_trig = cfg.min_edge_interval_s * cfg.sample_rate_hz  # in samples
        self._decay = cfg.level_decay_v_per_s * self.dt  # volts per sample
        self._ramp = np.arange(1024, dtype=float) * self._decay
        # counters
        self.batches = 0
        self.samples = 0
        self.rejected_batches = 0  #: time not increasing / not finite
        self.gaps = 0  #: batches that started later than expected (missing samples)
        self.missing_samples = 0
        self.time_resyncs = 0  #: batches that overlapped the previous ones beyond tolerance
        self.nonfinite_samples = 0  #: NaN/inf samples, and samples beyond max_abs_v
        self.nonfinite_gaps = 0
        self.edges = 0
        self.glitches = 0  #: edge pairs closer than physically possible, dropped
        self.overspeed = 0  #: speeds above max_speed_rad_s, rejected
        self.speeds = 0
        self.signal_losses = 0
        self.history_resets = 0
        self.rate_mismatch_batches = 0  #: batches decoded while the sample rate disagreed
        self.speeds_suppressed = 0  #: speeds not reported because of a sample-rate mismatch
        self.speeds_unverified = 0  #: speeds withheld after noise until two consecutive agree
        self.reset()

    def reset(self) -> None:
        """Forget everything measured (counters stay)."""
        self._anchor: float | None = None  # time of sample index 0 of the current clock
        self._next_idx = 0  # clock index of the next expected sample
        self._last_batch_t: float | None = None
        self._t_start: float | None = None
        self._now: float | None = None
        self._hi: float | None = None  # level trackers (unclamped), carried across gaps
        self._lo: float | None = None
        self._level_now = math.nan
        self._known: tuple[float, float] | None = None  # (blocked, clear) at the last edge
        self._hist: deque[float] = deque(maxlen=self._n_rev + 1)  # edge positions (samples)
        self._last_edge_t: float | None = None
        self._lost = True  # no signal yet
        self._edges_since_loss = 0
        self._have_speed = False
        self._speed_now = 0.0
        self._rates: deque[float] = deque(maxlen=self.RATE_CHECK_BATCHES)  # implied rate / parameter
        self._rate_bad = False
        self._rate_measured = math.nan
        self._verify = False  # noise seen: check speeds against each other before reporting
        self._candidate: float | None = None
        self._t_speed: float | None = None  # time of the last reported speed
        self._break_continuity()

    def _break_continuity(self) -> None:
        """Samples before and after this point are not adjacent: no interpolation across."""
        self._tail: float | None = None  # previous raw sample (spike guard of the trackers)
        self._state: bool | None = None  # hysteresis state: True = high (beam clear)
        self._r_last: float | None = None  # normalised level of the previous sample
        self._cross: float | None = None  # position of the latest midpoint crossing
        self._pending: tuple[float, int] | None = None  # (position, switch index)
        self._pending_levels = (math.nan, math.nan)

    # --- public API --------------------------------------------------------------------------

    def process_batch(self, t_last: float, samples) -> TachBatchResult:
        """Decode one batch of contiguous samples (V); ``t_last`` is the time (s) of the last one."""
        x = np.asarray(samples, dtype=np.float64)
        if x.ndim != 1:
            x = x.reshape(-1)
        n = len(x)
        if n == 0:
            return self._result([], [], [])
        t_last = float(t_last)
        if not math.isfinite(t_last) or (self._last_batch_t is not None and t_last <= self._last_batch_t):
            self.rejected_batches += 1
            return self._result([], [], [])
        dt = self.dt
        edge_t: list[float] = []
        speed: list[float] = []
        all_t: list[float] = []
        out = (edge_t, speed, all_t)
        self._check_rate(t_last, n)
        t_first = t_last - (n - 1) * dt
        if self._anchor is None:
            self._anchor, self._next_idx = t_first, 0
            if self._t_start is None:
                self._t_start = t_first
        else:
            delta = t_first - (self._anchor + self._next_idx * dt)
            if abs(delta) > self.config.gap_tolerance_s:
                if delta > 0:
                    self.gaps += 1
                    self.missing_samples += int(round(delta / dt))
                else:
                    self.time_resyncs += 1
                self._restart_history(out)
                self._anchor, self._next_idx = t_first, 0
        self.batches += 1
        self.samples += n
        self._last_batch_t = t_last
        i0 = self._next_idx
        self._next_idx += n
        lim = self.config.max_abs_v
        if not (x.max() <= lim and x.min() >= -lim):  # NaN/inf or absurd values: all as NaN
            x = np.where(np.abs(x) <= lim, x, np.nan)
        if math.isfinite(x.sum()):  # no NaN/inf (the sum of volts cannot overflow)
            if n <= self._CHUNK:
                self._segment(x, i0, out)
            else:
                for a in range(0, n, self._CHUNK):
                    self._segment(x[a:a + self._CHUNK], i0 + a, out)
        else:
            fin = np.isfinite(x)
            self.nonfinite_samples += int(n - np.count_nonzero(fin))
            # runs of finite samples: [starts[i], stops[i])
            d = np.diff(np.concatenate(([0], fin.astype(np.int8), [0])))
            starts, stops = np.flatnonzero(d == 1), np.flatnonzero(d == -1)
            if len(starts) == 0 or starts[0] > 0:
                self._nonfinite_gap(out)
            for k, (a, b) in enumerate(zip(starts.tolist(), stops.tolist())):
                if k > 0:
                    self._nonfinite_gap(out)
                for c in range(a, b, self._CHUNK):
                    self._segment(x[c:min(b, c + self._CHUNK)], i0 + c, out)
            if len(stops) and stops[-1] < n:
                self._nonfinite_gap(out)
        self._check_time(self._anchor + (self._next_idx - 1) * dt)
        return self._result(edge_t, speed, all_t)

    def process(self, t0: float, samples, batch_size: int | None = None) -> TachBatchResult:
        """Decode a flat array whose first sample is at ``t0`` (s), in batches of ``batch_size``.

        Same state and results as feeding the batches to :meth:`process_batch` (the default,
        None, feeds everything as one batch). Returns all edges and speeds concatenated.
        """
        x = np.asarray(samples, dtype=np.float64).reshape(-1)
        n = len(x)
        bs = max(n, 1) if batch_size is None else int(batch_size)
        if bs < 1:
            raise BadInputError(f"tachometer: batch_size must be >= 1, got {batch_size!r}")
        parts: list[TachBatchResult] = []
        for a in range(0, n, bs):
            b = min(n, a + bs)
            parts.append(self.process_batch(t0 + (b - 1) * self.dt, x[a:b]))
        if not parts:  # empty input
            return self._result([], [], [])
        return TachBatchResult(
            edge_t=np.concatenate([p.edge_t for p in parts]),
            speed=np.concatenate([p.speed for p in parts]),
            speed_now=parts[-1].speed_now,
            signal_ok=parts[-1].signal_ok,
            all_edge_t=np.concatenate([p.all_edge_t for p in parts]),
            state=parts[-1].state,
        )

    @property
    def rate_mismatch(self) -> bool:
        """True while the batches' timing says the data is not at ``sample_rate_hz``."""
        return self._rate_bad

    def _check_rate(self, t_last: float, n: int) -> None:
        """Compare the samples per second the batch stamps imply with the parameter."""
        if self._last_batch_t is not None:
            self._rates.append(n / (t_last - self._last_batch_t) / self.config.sample_rate_hz)
        if not self._rates:  # the first batch: no timing to compare yet
            return
        ratio = float(statistics.median(self._rates))  # 5 numbers: faster than np.median
        bad = abs(ratio - 1.0) > self.RATE_TOLERANCE
        if bad:
            self._rate_measured = ratio * self.config.sample_rate_hz
            self.rate_mismatch_batches += 1
            if not self._rate_bad:  # whatever was measured at the wrong rate is void
                self._speed_now = 0.0
                self._have_speed = False
                if self._hist:
                    self.history_resets += 1
                self._hist.clear()
        self._rate_bad = bad

    def check_timeout(self, t_now: float) -> bool:
        """Apply the timeout at ``t_now`` (s) when no batch arrives; True if the signal is lost just now."""
        t_now = float(t_now)
        if not math.isfinite(t_now):
            return False
        return self._check_time(t_now)

    @property
    def speed_now(self) -> float:
        return self._speed_now

    @property
    def signal_ok(self) -> bool:
        return self._have_speed and not self._lost

    @property
    def state(self) -> str:
        """What is known about the rotor: spinning, starting, stopped, blocked, stuck, no_edges."""
        if not self._lost:
            return SPINNING if self._have_speed else STARTING
        if self._known is None or not math.isfinite(self._level_now):
            return NO_EDGES
        lo, hi = self._known
        frac = (self._level_now - lo) / (hi - lo)
        if frac > 0.75:
            return STOPPED
        if frac < 0.25:
            return BLOCKED
        return STUCK

    def status(self) -> list[CoreStatus]:
        """Counters and what the signal says; WARN when no speed can be measured for a bad reason."""
        state = self.state
        level = OK if state in (SPINNING, STARTING, STOPPED) else WARN
        msg = _STATE_TEXT[state]
        if self._rate_bad:
            level, msg = ERROR, (
                f"sample rate mismatch: batches carry {self._rate_measured:.0f} samples/s, "
                f"sample_rate_hz is {self.config.sample_rate_hz:g}; no speed reported")
        elif self._now is not None and self._last_batch_t is not None \
                and self._now - self._last_batch_t > self.config.timeout_s:
            level, msg = WARN, f"no tachometer/adc batch for {self._now - self._last_batch_t:.2f} s"
        elif self._last_batch_t is None:
            level, msg = WARN, "no tachometer/adc batch yet"
        known = self._known or (math.nan, math.nan)
        return [CoreStatus("tachometer", level, msg, counters(
            state=state,
            speed_rad_s=self._speed_now,
            signal_ok=self.signal_ok,
            level_v=self._level_now,
            clear_level_v=known[1],
            blocked_level_v=known[0],
            batches=self.batches,
            samples=self.samples,
            edges=self.edges,
            speeds=self.speeds,
            signal_losses=self.signal_losses,
            glitches_rejected=self.glitches,
            overspeed_rejected=self.overspeed,
            history_resets=self.history_resets,
            rejected_batches=self.rejected_batches,
            gaps=self.gaps,
            missing_samples=self.missing_samples,
            time_resyncs=self.time_resyncs,
            nonfinite_samples=self.nonfinite_samples,
            rate_mismatch=self._rate_bad,
            measured_sample_rate_hz=self._rate_measured,
            rate_mismatch_batches=self.rate_mismatch_batches,
            speeds_suppressed=self.speeds_suppressed,
            speeds_unverified=self.speeds_unverified,
        ))]

    # --- internals ---------------------------------------------------------------------------

    def _result(self, edge_t, speed, all_t) -> TachBatchResult:
        return TachBatchResult(
            edge_t=np.asarray(edge_t, dtype=float) if edge_t else _EMPTY,
            speed=np.asarray(speed, dtype=float) if speed else _EMPTY,
            speed_now=self._speed_now,
            signal_ok=self.signal_ok,
            all_edge_t=np.asarray(all_t, dtype=float) if all_t else _EMPTY,
            state=self.state,
        )

    def _nonfinite_gap(self, out) -> None:
        if self._tail is not None:  # count each hole once, however it is cut into batches
            self.nonfinite_gaps += 1
            self._restart_history(out)

    def _restart_history(self, out) -> None:
        """Samples are missing: settle the pending edge, forget the edge history and continuity."""
        if self._pending is not None:
            self._confirm(self._pending[0], out)
        if self._hist:
            self.history_resets += 1
        self._hist.clear()
        self._break_continuity()

    def _check_time(self, now: float) -> bool:
        """Timeout bookkeeping at time ``now``; True if the signal was declared lost here."""
        if self._now is None or now > self._now:
            self._now = now
        ref = self._last_edge_t if self._last_edge_t is not None else self._t_start
        if self._lost or ref is None or now - ref <= self.config.timeout_s:
            return False
        if self._pending is not None and self._pos_time(self._pending[0]) - ref <= self.config.timeout_s:
            return False  # an edge arrived in time, it is only awaiting its glitch check
        self._declare_lost()
        return True

    def _declare_lost(self) -> None:
        self._lost = True
        self.signal_losses += 1
        self._speed_now = 0.0
        self._have_speed = False
        self._edges_since_loss = 0
        if self._hist:
            self.history_resets += 1
        self._hist.clear()

    def _ramp_for(self, n: int) -> np.ndarray:
        if n > len(self._ramp):
            self._ramp = np.arange(max(n, 2 * len(self._ramp)), dtype=float) * self._decay
        return self._ramp[:n]

    def _segment(self, x: np.ndarray, i0: int, out) -> None:
        """Decode contiguous finite samples x whose first one has clock index i0."""
        n = len(x)
        cfg = self.config
        c = self._decay
        x0 = x.item(0)
        if self._tail is None:
            self._tail = x0
        if self._hi is None:
            self._hi = x0 + c
            self._lo = min(cfg.initial_low_v, x0) - c
        # Level trackers see a 2-sample min (clear level) / max (blocked level) of the signal,
        # so a one-sample spike does not move them. Peak trackers with linear decay,
        # hi[i] = max(s[i], hi[i-1] - c), vectorised as hi[i] = max_j<=i (s[j] + c j) - c i
        # (and the same for lo with min).
        k = self._ramp[:n] if n <= len(self._ramp) else self._ramp_for(n)
        u = np.empty(n)
        np.minimum(x[:-1], x[1:], out=u[1:])
        u[0] = min(self._tail, x0)
        u += k
        if u[0] < self._hi - c:
            u[0] = self._hi - c
        np.maximum.accumulate(u, out=u)
        hi = u
        hi -= k
        v = np.empty(n)
        np.maximum(x[:-1], x[1:], out=v[1:])
        v[0] = max(self._tail, x0)
        v -= k
        if v[0] > self._lo + c:
            v[0] = self._lo + c
        np.minimum.accumulate(v, out=v)
        lo = v
        lo += k
        self._tail = self._level_now = x.item(-1)
        self._hi, self._lo = hi.item(-1), lo.item(-1)
        # clamp: keep the blocked level at least min_contrast_v under the clear level
        np.minimum(lo, hi - cfg.min_contrast_v, out=lo)
        span = hi - lo
        r = x - lo
        r /= span  # 0 = blocked level, 1 = clear level
        r_prev0 = self._r_last if self._r_last is not None else r.item(0)
        self._r_last = r.item(-1)
        state = self._state
        if state is None:
            state = self._state = bool(r[0] >= 0.5)
        # fast path: nothing can switch
        if (r.min() >= cfg.low_fraction) if state else (r.max() <= cfg.high_fraction):
            trig = None
        else:
            # vectorised hysteresis: +1 above high, -1 below low; a switch is an event whose
            # sign differs from the previous event's
            e = (r > cfg.high_fraction).view(np.int8) - (r < cfg.low_fraction).view(np.int8)
            ev = np.flatnonzero(e)
            val = e[ev] > 0
            prev = np.empty_like(val)
            prev[0] = state
            prev[1:] = val[:-1]
            trig = ev[val != prev]
            self._state = bool(val[-1])
        if trig is not None:
            for kk in trig.tolist():
                p = self._crossing(r, kk, r_prev0, i0)
                if p is None:  # the crossing was in an earlier slice
                    p = self._cross if self._cross is not None else float(i0 + kk)
                self._switch(p, i0 + kk, out, float(hi[kk]), float(lo[kk]))
        if cfg.low_fraction <= self._r_last <= cfg.high_fraction:
            # the slice ends inside a transition: its switch may come in a later slice and
            # need the midpoint crossing found here
            p = self._crossing(r, n, r_prev0, i0)
            if p is not None:
                self._cross = p
        # a pending edge is confirmed once no later switch can be close enough to cancel it
        if self._pending is not None and (i0 + n - self._pending[1]) >= self._min_trig:
            self._confirm(self._pending[0], out)
            self._pending = None

    def _crossing(self, r: np.ndarray, kk: int, r_prev0: float, i0: int) -> float | None:
        """Position (clock samples) of the last midpoint crossing at or before index kk of the slice.

        Scans back while the signal stays in the hysteresis band (between a crossing and its
        switch it does); None if the crossing is before the slice or not there yet.
        kk == len(r) asks for the last crossing of the slice.
        """
        lo_f, hi_f = self.config.low_fraction, self.config.high_fraction
        item = r.item
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

    def _switch(self, p: float, g: int, out, hi: float, lo: float) -> None:
        """A hysteresis switch at clock index g, interpolated edge position p."""
        if self._pending is not None:
            if g - self._pending[1] < self._min_trig:  # a spike: drop it and its partner
                self.glitches += 1
                self._verify, self._candidate = True, None
                self._pending = None
                return
            self._confirm(self._pending[0], out)
        self._pending = (p, g)
        self._pending_levels = (float(lo), float(hi))

    def _pos_time(self, p: float) -> float:
        return self._anchor + p * self.dt

    def _confirm(self, p: float, out) -> None:
        """An accepted edge at position p: history, speed, timeout bookkeeping."""
        t = self._pos_time(p)
        if self._last_edge_t is not None and t - self._last_edge_t > self.config.timeout_s \
                and not self._lost:
            self._declare_lost()  # silence between two edges longer than the timeout
        self._lost = False
        self._edges_since_loss += 1
        self.edges += 1
        self._last_edge_t = t
        self._known = self._pending_levels
        hist = self._hist
        hist.append(p)
        if out is not None:
            out[2].append(t)
        if len(hist) == self._n_rev + 1:
            w = TWO_PI / ((p - hist[0]) * self.dt)
            if w > self.config.max_speed_rad_s:
                self.overspeed += 1
                self.history_resets += 1
                self._verify, self._candidate = True, None
                hist.clear()
                hist.append(p)
                return
            if self._rate_bad:  # edge times scaled by the wrong rate: not a speed
                self.speeds_suppressed += 1
                return
            tol = self.VERIFY_TOLERANCE
            reachable = True
            if self._t_speed is not None and self._speed_now > 0.0:
                jump = abs(w - self._speed_now)
                reachable = jump <= self.MAX_ACCEL_RAD_S2 * (t - self._t_speed) + tol * self._speed_now
            if not reachable and not self._verify:
                self._verify, self._candidate = True, None
            if self._verify:  # after noise: only a plausible speed that its predecessor confirms
                prev, self._candidate = self._candidate, w
                agree = (self._t_speed is not None and self._speed_now > 0.0 and reachable
                         and abs(w / self._speed_now - 1.0) <= tol)
                if not agree and (prev is None or abs(w / prev - 1.0) > tol or not reachable):
                    self.speeds_unverified += 1
                    return
                self._verify, self._candidate = False, None
            self.speeds += 1
            self._t_speed = t
            self._speed_now = w
            self._have_speed = True
            if out is not None:
                out[0].append(t)
                out[1].append(w)
