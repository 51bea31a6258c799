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

Where each step lives (:mod:`bldc_propulsion.core.tachometer_parts`): steps 1-3 and the glitch
check of step 4 in :class:`EdgeDetector` (level trackers, hysteresis state, midpoint crossing,
the edge awaiting its glitch check); the speed, overspeed and noise verification of step 4 and
the timeout and signal loss of step 6 in :class:`SpeedGate` (one-revolution edge history, last
reported speed); step 5 in :class:`SampleClock` (anchor and next sample index, gaps and resyncs,
the sample-rate median check), except the dropping of NaN/inf samples, which
:class:`TachometerDecoder` does before handing each finite run to the edge detector. The
decoder composes the three, holds the counters they update (:class:`TachCounters`) and
builds each batch's :class:`TachBatchResult` from a :class:`TachOutput`; the rotor state of
step 6 combines the gate's signal loss with the detector's levels.
"""

from __future__ import annotations

import array
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal, TypeAlias, overload

import numpy as np

from ..errors import BadInputError
from ..runs import true_runs
from .status import ERROR, OK, WARN, CoreStatus, counters
from .tachometer_parts import TWO_PI, EdgeDetector, RowPlan, SampleClock, SpeedGate, TachCounters, TachOutput

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


#: A batch of ADC samples (V): a numpy array (replay, tests), rclpy's ``array.array('f')``
#: (Float32MultiArray.data, a live node) or a list of floats.
Samples: TypeAlias = "np.ndarray | array.array[float] | Sequence[float]"


class _Counter:
    """A decoder attribute that is one field of its :class:`TachCounters` (read and write)."""

    def __set_name__(self, owner: type, name: str) -> None:
        self.name = name

    @overload
    def __get__(self, obj: None, owner: type | None = None) -> _Counter: ...
    @overload
    def __get__(self, obj: TachometerDecoder, owner: type | None = None) -> int: ...
    def __get__(self, obj: TachometerDecoder | None, owner: type | None = None) -> _Counter | int:
        if obj is None:  # the class attribute itself
            return self
        count: int = getattr(obj.counts, self.name)
        return count

    def __set__(self, obj: TachometerDecoder, value: int) -> None:
        setattr(obj.counts, self.name, value)


class TachometerDecoder:
    """Streaming decoder of phototransistor batches into edge times and speeds.

    Composes a :class:`SampleClock` (sample times), an :class:`EdgeDetector` (samples to edges)
    and a :class:`SpeedGate` (edges to speeds), which share one :class:`TachCounters`.
    """

    _CHUNK = 16384  #: long inputs are processed in slices of this size (cache, precision)
    #: array.array batches (what rclpy gives a live node) up to this size are decoded by
    #: EdgeDetector.segment_small, without numpy calls: a node waking for each batch has cold
    #: caches, where that loop costs about half of segment's numpy calls (warm, numpy is twice
    #: as fast, so numpy arrays keep it); 0 decodes every batch with numpy
    SMALL_BATCH = 512
    _PLAN_ROWS = 256  #: batches planned at a time (:meth:`expect`)
    RATE_CHECK_BATCHES = 5  #: batches whose median sample rate is compared with the parameter
    RATE_TOLERANCE = 0.2  #: relative difference of that rate from sample_rate_hz that is a mismatch
    VERIFY_TOLERANCE = 0.05  #: relative agreement of consecutive speeds that ends a noise check
    MAX_ACCEL_RAD_S2 = 20000.0  #: faster speed changes than this are noise (a 12" prop: ~5000)

    # counters (attributes of the decoder, kept in self.counts)
    batches = _Counter()
    samples = _Counter()
    rejected_batches = _Counter()  #: time not increasing / not finite
    gaps = _Counter()  #: batches that started later than expected (missing samples)
    missing_samples = _Counter()
    time_resyncs = _Counter()  #: batches that overlapped the previous ones beyond tolerance
    nonfinite_samples = _Counter()  #: NaN/inf samples, and samples beyond max_abs_v
    nonfinite_gaps = _Counter()
    edges = _Counter()
    glitches = _Counter()  #: edge pairs closer than physically possible, dropped
    overspeed = _Counter()  #: speeds above max_speed_rad_s, rejected
    speeds = _Counter()
    signal_losses = _Counter()
    history_resets = _Counter()
    rate_mismatch_batches = _Counter()  #: batches decoded while the sample rate disagreed
    speeds_suppressed = _Counter()  #: speeds not reported because of a sample-rate mismatch
    speeds_unverified = _Counter()  #: speeds withheld after noise until two consecutive agree

    def __init__(self, config: TachometerConfig | None = None) -> None:
        self.config = config or TachometerConfig()
        self.dt = 1.0 / self.config.sample_rate_hz
        self.counts = TachCounters()
        self._expected: list[np.ndarray] | None = None
        self._cursor = 0
        self._plan: RowPlan | None = None
        self._plan_start = 0
        self.planned_batches = 0  #: batches decoded through a plan (see expect)
        self._sink = TachOutput()  #: what process_batch(result=False) accumulates and drops
        self.reset()

    def reset(self) -> None:
        """Forget everything measured (counters stay)."""
        cfg, counts = self.config, self.counts
        self._clock = SampleClock(cfg, counts, rate_batches=self.RATE_CHECK_BATCHES,
                                  rate_tolerance=self.RATE_TOLERANCE)
        self._gate = SpeedGate(cfg, counts, self._clock, verify_tolerance=self.VERIFY_TOLERANCE,
                               max_accel=self.MAX_ACCEL_RAD_S2)
        self._edges = EdgeDetector(cfg, counts, self._gate)
        self._plan = None

    # --- public API --------------------------------------------------------------------------

    def expect(self, batches: Sequence[np.ndarray]) -> None:
        """Announce the batches the next :meth:`process_batch` calls receive (the same array
        objects, in order; others may come between them). Their level trackers are then
        computed many batches at a time (:meth:`EdgeDetector.plan_rows`), which is several
        times faster and gives the same state and results (each planned row is used only when
        the detector's state is the one the plan assumed). Replay knows its batches ahead."""
        self._expected = list(batches)
        self._cursor = 0
        self._plan = None

    def _planned_row(self, samples: Samples) -> tuple[RowPlan, int] | None:
        """(plan, row) for ``samples`` if they are the next expected batch and can be planned."""
        exp = self._expected
        k = self._cursor
        if exp is None or k >= len(exp) or samples is not exp[k]:
            return None
        self._cursor = k + 1
        if self._plan is not None and self._plan_start <= k < self._plan_start + len(self._plan.X):
            return self._plan, k - self._plan_start
        n = len(exp[k])
        if not 1 <= n <= self._CHUNK:
            return None
        stop = k
        while stop < min(len(exp), k + self._PLAN_ROWS) and len(exp[stop]) == n and np.ndim(exp[stop]) == 1:
            stop += 1
        X = np.asarray(np.stack(exp[k:stop]), dtype=np.float64)
        lim = self.config.max_abs_v
        bad = np.flatnonzero(~(np.abs(X) <= lim).all(axis=1))  # NaN/inf or absurd: not planned
        if len(bad):
            X = X[: bad[0]]
        if len(X) == 0:
            self._plan = None
            return None
        self._plan, self._plan_start = self._edges.plan_rows(X), k
        return self._plan, 0

    @overload
    def process_batch(self, t_last: float, samples: Samples, result: Literal[True] = True) -> TachBatchResult: ...
    @overload
    def process_batch(self, t_last: float, samples: Samples, result: bool) -> TachBatchResult | None: ...
    def process_batch(self, t_last: float, samples: Samples, result: bool = True) -> TachBatchResult | None:
        """Decode one batch of contiguous samples (V); ``t_last`` is the time (s) of the last one.
        With ``result=False`` nothing is returned (the decoder's state is all a caller needs)."""
        planned = self._planned_row(samples) if self._expected is not None else None
        small = None  # a short batch as Python floats, for EdgeDetector.segment_small
        if planned is not None:
            x = planned[0].X[planned[1]]
        elif isinstance(samples, array.array) and samples.typecode in 'fd' and len(samples) <= self.SMALL_BATCH:
            x = small = samples  # rclpy's Float32MultiArray.data: a live node's batch
        else:  # numpy arrays (replay, tests, benchmarks: warm caches, where numpy is faster)
            x = np.asarray(samples, dtype=np.float64)
            if x.ndim != 1:
                x = x.reshape(-1)
        n = len(x)
        if result:
            out = TachOutput()
        else:  # nothing is returned: the one sink, emptied (cheaper than a new TachOutput)
            out = self._sink
            out.edge_t.clear()
            out.speed.clear()
            out.all_edge_t.clear()
        if n == 0:
            return self._result(out) if result else None
        t_last = float(t_last)
        clock, edges = self._clock, self._edges
        if not clock.accepts(t_last):
            return self._result(out) if result else None
        if clock.check_rate(t_last, n):  # whatever was measured at the wrong rate is void
            self._gate.void_speed()
        t_first = t_last - (n - 1) * self.dt
        if clock.anchor is None:
            clock.restart(t_first)
        elif clock.breaks(t_first):  # samples missing, or time went back: no speed across
            edges.settle(out)
            clock.restart(t_first)
        i0 = clock.advance(t_last, n)
        if planned is not None:  # a whole finite batch: segment, through the plan when it holds
            if edges.segment_planned(planned[0], planned[1], i0, out):
                self.planned_batches += 1
            else:
                self._plan = None  # the state differs from the plan's: plan again from the next
                edges.segment(x, i0, out)
            self._check_time(clock.last_sample_t())
            return self._result(out) if result else None
        lim = self.config.max_abs_v
        if small is not None:
            if edges.segment_small(small, i0, lim, out):
                self._check_time(clock.last_sample_t())
                return self._result(out) if result else None
            x = np.asarray(x, dtype=np.float64)  # not finite or beyond lim somewhere: below
        segment, chunk = edges.segment, self._CHUNK
        if np.abs(x).max() <= lim:  # every sample finite and in range (a NaN max fails this)
            if n <= chunk:
                segment(x, i0, out)
            else:
                for a in range(0, n, chunk):
                    segment(x[a:a + chunk], i0 + a, out)
        else:  # NaN/inf or absurd values, all as NaN
            x = np.where(np.abs(x) <= lim, x, np.nan)
            fin = np.isfinite(x)
            self.counts.nonfinite_samples += int(n - np.count_nonzero(fin))
            # runs of finite samples: [starts[i], stops[i])
            starts, stops = true_runs(fin)
            if len(starts) == 0 or starts[0] > 0:
                self._nonfinite_gap(out)
            for k, (a, b) in enumerate(zip(starts.tolist(), stops.tolist(), strict=True)):
                if k > 0:
                    self._nonfinite_gap(out)
                for c in range(a, b, chunk):
                    segment(x[c:min(b, c + chunk)], i0 + c, out)
            if len(stops) and stops[-1] < n:
                self._nonfinite_gap(out)
        self._check_time(clock.last_sample_t())
        return self._result(out) if result else None

    def process(self, t0: float, samples: Samples, batch_size: int | None = None) -> TachBatchResult:
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
            return self._result(TachOutput())
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
        return self._clock.rate_bad

    def check_timeout(self, t_now: float) -> bool:
        """Apply the timeout at ``t_now`` (s) when no batch arrives; True if the signal is lost just now."""
        t_now = float(t_now)
        if not math.isfinite(t_now):
            return False
        return self._check_time(t_now)

    @property
    def speed_now(self) -> float:
        return self._gate.speed_now

    def speed_report(self) -> tuple[float, float | None, bool, bool]:
        """(speed_now, speed_edge_t, signal_ok, rate_mismatch) in one call: what a node asks
        after every batch (``tach_output.SpeedOutput``), where four properties cost four calls."""
        gate = self._gate
        return gate.speed_now, gate.t_speed, gate.have_speed and not gate.lost, self._clock.rate_bad

    @property
    def speed_edge_t(self) -> float | None:
        """Time (s) of the edge that completed the revolution ``speed_now`` was measured over
        (None before the first speed): where that revolution, and so the value, ends."""
        return self._gate.t_speed

    @property
    def signal_ok(self) -> bool:
        return self._gate.have_speed and not self._gate.lost

    @property
    def state(self) -> str:
        """What is known about the rotor: spinning, starting, stopped, blocked, stuck, no_edges."""
        gate, edges = self._gate, self._edges
        if not gate.lost:
            return SPINNING if gate.have_speed else STARTING
        if edges.known is None or not math.isfinite(edges.level_now):
            return NO_EDGES
        lo, hi = edges.known
        frac = (edges.level_now - lo) / (hi - lo)
        if frac > 0.75:
            return STOPPED
        if frac < 0.25:
            return BLOCKED
        return STUCK

    def status(self) -> list[CoreStatus]:
        """Counters and what the signal says; WARN when no speed can be measured for a bad reason."""
        state = self.state
        clock, edges = self._clock, self._edges
        level = OK if state in (SPINNING, STARTING, STOPPED) else WARN
        msg = _STATE_TEXT[state]
        if clock.rate_bad:
            level, msg = ERROR, (
                f"sample rate mismatch: batches carry {clock.rate_measured:.0f} samples/s, "
                f"sample_rate_hz is {self.config.sample_rate_hz:g}; no speed reported")
        elif clock.now is not None and clock.last_batch_t is not None \
                and clock.now - clock.last_batch_t > self.config.timeout_s:
            level, msg = WARN, f"no tachometer/adc batch for {clock.now - clock.last_batch_t:.2f} s"
        elif clock.last_batch_t is None:
            level, msg = WARN, "no tachometer/adc batch yet"
        known = edges.known or (math.nan, math.nan)
        return [CoreStatus("tachometer", level, msg, counters(
            state=state,
            speed_rad_s=self.speed_now,
            signal_ok=self.signal_ok,
            level_v=edges.level_now,
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
            rate_mismatch=clock.rate_bad,
            measured_sample_rate_hz=clock.rate_measured,
            rate_mismatch_batches=self.rate_mismatch_batches,
            speeds_suppressed=self.speeds_suppressed,
            speeds_unverified=self.speeds_unverified,
        ))]

    # --- internals ---------------------------------------------------------------------------

    def _result(self, out: TachOutput) -> TachBatchResult:
        return TachBatchResult(
            edge_t=np.asarray(out.edge_t, dtype=float) if out.edge_t else _EMPTY,
            speed=np.asarray(out.speed, dtype=float) if out.speed else _EMPTY,
            speed_now=self._gate.speed_now,
            signal_ok=self.signal_ok,
            all_edge_t=np.asarray(out.all_edge_t, dtype=float) if out.all_edge_t else _EMPTY,
            state=self.state,
        )

    def _nonfinite_gap(self, out: TachOutput) -> None:
        if self._edges.tail is not None:  # count each hole once, however it is cut into batches
            self.counts.nonfinite_gaps += 1
            self._edges.settle(out)

    def _check_time(self, now: float) -> bool:
        """Timeout bookkeeping at time ``now``; True if the signal was declared lost here."""
        clock = self._clock
        clock.see(now)
        pending = self._edges.pending
        t_pending = None if pending is None or clock.anchor is None else clock.anchor + pending[0] * clock.dt
        return self._gate.check_timeout(now, clock.t_start, t_pending)
