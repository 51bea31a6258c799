"""When was a message's data taken? Timing rules for inputs whose messages carry no stamp.

``pwm``, ``battery/adc`` and ``tachometer/adc`` are Float64 / Float32MultiArray: no header.
Guessing their times from receipt alone turns a stall into a wrong number (a batch that arrives
100 ms late looks like the next one, so the edges across a hole give a speed 60 % too high).
What rclpy does give, with every executor (``common.WithInfo``), is the message info of each message:
the publisher's clock when it published (``source_timestamp``) and the publisher's sequence
number (``publication_sequence_number``). The rules (docs/ros.md, "Timing and faults"):

Fixed-rate streams (``SampleStream``: battery/adc samples, tachometer/adc batches of n samples)
are timed by counting samples: a message that follows the previous one carries the next n
samples, so its last sample is ``n / sample_rate_hz`` after the previous one's. Whether it
really follows is decided by two witnesses:

1. Sequence numbers. Consecutive: nothing was lost in transport. A jump of k: k messages were
   lost (DDS queue overflow while the node stalled, a lossy link): the time advances by k + 1
   messages, so the core sees a gap of the right length and measures nothing across it. A
   number that does not increase: the publisher restarted; the stream starts over.
2. Lateness on the publisher's clock (``source_timestamp``; receipt time on the node clock when
   the executor gives no message info). A contiguous stream is published at the rate it is
   sampled, so ``observed time - counted time`` never falls below the transport latency; its
   floor over the last ``FLOOR_WINDOW_S`` is tracked. A message later than that floor by more
   than the tolerance is held until the next one arrives. Next one late too: the publisher
   skipped data (driver overrun, a recording with a hole) or sent a late burst, and the stream
   breaks before the held one (a gap of its lateness) rather than bridging a hole it cannot
   see into; a late burst costs one revolution of output, never a wrong one. Next one on
   time: the held one was only published late (a busy publisher), and nothing breaks. A node
   that stalls while the publisher keeps going is NOT late on the publisher's clock: the queued
   messages are processed with their counted times and nothing is lost.

Event streams (``EventStream``: pwm, published on change) are timed by their source time mapped
onto the node clock through the same latency floor (so a command that sat in the queue during
a stall keeps its own time), and a jump in sequence numbers counts lost commands.

Counted time is anchored on the node clock at a stream's first message; if it runs ahead of the
node clock by more than ``AHEAD_S`` (data faster than sample_rate_hz, a bag played faster, a
clock jumping back) the stream starts over at the node clock. Everything here is plain Python so the rules are
tested without ROS; the nodes only convert rclpy's message info into :class:`Arrival`.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Mapping
from dataclasses import dataclass
from typing import Generic, NamedTuple, TypeVar

#: Window (s, on the observing clock) over which the transport latency floor is the minimum.
FLOOR_WINDOW_S = 2.0
#: Counted time this far ahead of the node clock (s) restarts the stream on the node clock: a
#: sample cannot be taken after it is received (the slack covers a /clock stepping at 40 Hz).
#: Counted time falling behind needs no rule of its own: it makes later messages late (rule 2).
AHEAD_S = 0.1

#: rmw's "no sequence number" values (RMW_MESSAGE_INFO_SEQUENCE_NUMBER_UNSUPPORTED, 0).
_NO_SEQ = (0, 2**64 - 1)

# Values of Placement.event
CONTIGUOUS = "contiguous"  #: follows the previous message
NEW_STREAM = "new_stream"  #: first message, publisher restart, or resync to the node clock
LOST = "lost"  #: messages lost in transport (sequence-number jump)
LATE = "late"  #: later than the latency floor allows: publisher skipped data or burst


class Arrival(NamedTuple):
    """One received message: node clock at receipt, and what the middleware says of it.

    Immutable; a NamedTuple rather than a frozen dataclass because one is made per message
    (0.4 us against 0.9 us here), as :class:`Placement`."""

    receipt_s: float  #: node clock when the callback ran (s): wall or /clock time
    source_s: float | None = None  #: publisher's clock at publication (s), None if not known
    seq: int | None = None  #: publisher's sequence number, None if not known


def arrival(receipt_s: float, info: Mapping[str, int] | None) -> Arrival:
    """An :class:`Arrival` from rclpy's message-info dict (None: the executor gave none)."""
    if not info:
        return Arrival(receipt_s)
    return Arrival(receipt_s, *_source_and_seq(info))


def _source_and_seq(info: Mapping[str, int]) -> tuple[float | None, int | None]:
    """(source time in s, sequence number) of a message-info dict, None where not known."""
    src = info.get("source_timestamp")
    seq = info.get("publication_sequence_number")
    return None if not src else src * 1e-9, None if seq is None or seq in _NO_SEQ else int(seq)


class LatencyFloor:
    """Least ``observed - true`` time offset over a sliding window: transport latency floor.

    A monotonic deque keeps the window minimum in O(1) per update; the window slides on the
    observing clock, so a permanent change of offset (a clock jump) is adopted after the window.
    """

    def __init__(self, window_s: float = FLOOR_WINDOW_S) -> None:
        self.window_s = float(window_s)
        self._q: deque[tuple[float, float]] = deque()  # (observed time, offset), offsets rising
        #: the floor now (None: no observation): :meth:`peek` as an attribute, read per message
        self.value: float | None = None

    def reset(self) -> None:
        self._q.clear()
        self.value = None

    def floor(self, observed_s: float, offset_s: float) -> float:
        """Add one observation; the floor including it."""
        q = self._q
        while q and q[-1][1] >= offset_s:
            q.pop()
        q.append((observed_s, offset_s))
        while q[0][0] < observed_s - self.window_s:
            q.popleft()
        self.value = q[0][1]
        return self.value

    def peek(self) -> float | None:
        return self.value


class Placement(NamedTuple):
    """Where a fixed-rate message goes on the node clock, and why."""

    t_last: float  #: time (s, node clock) of the message's last sample
    event: str  #: CONTIGUOUS, NEW_STREAM, LOST or LATE
    lost_messages: int = 0  #: messages known lost in transport before this one
    late_s: float = 0.0  #: lateness beyond the floor that broke the stream (LATE)


#: What a message carries to its placement (a node's samples), handed back as it was given.
PayloadT = TypeVar("PayloadT")


@dataclass
class _Suspect(Generic[PayloadT]):
    """A message later than the floor allows, held until the next one says why."""

    arrival: Arrival
    observed: float
    payload: PayloadT
    t_contiguous: float  #: its time if nothing is missing before it
    excess: float  #: its lateness beyond the floor (s)


class SampleStream(Generic[PayloadT]):
    """Times of a fixed-rate sampled stream (module docstring, rules 1-2).

    A message later than the latency floor by more than the tolerance is *held* until the next
    one arrives: if that one is late too, data is missing before the held one (a hole: the
    stream breaks there); if it is back on time, the held one was only published late (jitter
    of a busy publisher: no break). So the tolerance can sit below one message's duration and
    still not mistake scheduling jitter for a hole. ``release_held`` lets a node settle a held
    message when no next one comes (conservatively: as a break).
    """

    def __init__(self, sample_rate_hz: float, tolerance_s: float, use_source: bool = True) -> None:
        self.period_s = 1.0 / float(sample_rate_hz)
        self.tolerance_s = float(tolerance_s)
        self.use_source = bool(use_source)
        self.messages = 0
        self.streams = 0  #: new streams started (the first one included)
        self.publisher_restarts = 0
        self.resyncs = 0
        self.lost_messages = 0  #: known lost in transport (sequence numbers)
        self.late_breaks = 0  #: breaks because data came too late on the publisher's clock
        self.late_forgiven = 0  #: late messages the next one showed were only published late
        self.witness = "none yet"  #: which clock judged lateness last: source or receipt
        self._floor = LatencyFloor()
        self._t: float | None = None
        self._seq: int | None = None
        self._held: _Suspect[PayloadT] | None = None

    def push(self, a: Arrival, n: int, payload: PayloadT) -> list[tuple[Placement, PayloadT]]:
        """Place message ``a`` of ``n`` samples; returns the (placement, payload) pairs that are
        settled now, in order: none while the message is held, two when a held one is settled."""
        self.messages += 1
        duration = n * self.period_s
        source = a.source_s if self.use_source else None
        observed = source if source is not None else a.receipt_s
        self.witness = "source" if source is not None else "receipt"
        out: list[tuple[Placement, PayloadT]] = []
        restart = a.seq is not None and self._seq is not None and a.seq <= self._seq
        if self._t is None or restart:
            out += self.release_held()
            self.publisher_restarts += restart
            out.append((self._start(a, observed), payload))
            return out
        lost = 0
        if a.seq is not None and self._seq is not None:
            lost = a.seq - self._seq - 1
        self._seq = a.seq
        held = self._held
        if held is not None:  # does this message say the held one followed its predecessor?
            self._held = None
            t_if = held.t_contiguous + duration * (1 + lost)
            floor = self._floor.peek()
            still_late = floor is not None and (observed - t_if) - floor > self.tolerance_s
            out.append(self._settle(held, late=still_late))
        t = self._t + duration * (1 + lost)  # lost messages assumed of the same size
        if t > a.receipt_s + AHEAD_S:
            self.resyncs += 1
            out.append((self._start(a, observed), payload))
            return out
        floor = self._floor.peek()
        excess = 0.0 if floor is None else (observed - t) - floor
        if lost > 0:
            self.lost_messages += lost
            self._t = t
            self._floor.floor(observed, observed - t)
            out.append((Placement(t, LOST, lost_messages=lost), payload))
        elif excess > self.tolerance_s:
            self._held = _Suspect(a, observed, payload, t, excess)
        else:
            self._t = t
            self._floor.floor(observed, observed - t)
            out.append((Placement(t, CONTIGUOUS), payload))
        return out

    def follow(self, receipt_s: float, info: Mapping[str, int] | None, n: int) -> float | None:
        """Place a message of ``n`` samples received at ``receipt_s`` with message info
        ``info`` if it simply continues the stream: the time of its last sample, with the state
        :meth:`push` would leave for ``arrival(receipt_s, info)`` (a CONTIGUOUS placement).
        None, with nothing changed, whenever another rule may apply (first message, a sequence
        number that is not the next, a message held or to hold, a resync): then call push.

        Why a second way in: it runs for every message (battery/adc at 1 kHz), and the usual
        message needs neither an Arrival nor a Placement, each of which costs as much as the
        rest of this method."""
        t_last = self._t
        if t_last is None or self._held is not None:
            return None
        source: float | None = None
        seq: int | None = None
        if info:  # _source_and_seq, inline
            src = info.get("source_timestamp")
            seq = info.get("publication_sequence_number")
            source = None if not src else src * 1e-9
            seq = None if seq is None or seq in _NO_SEQ else int(seq)
        if seq is not None and self._seq is not None and seq != self._seq + 1:
            return None  # lost messages or a restarted publisher
        t = t_last + n * self.period_s  # push's arithmetic for a message with none lost
        if t > receipt_s + AHEAD_S:
            return None
        if not self.use_source:
            source = None
        observed = source if source is not None else receipt_s
        floor = self._floor.value
        excess = 0.0 if floor is None else (observed - t) - floor
        if excess > self.tolerance_s:
            return None
        self.messages += 1
        self.witness = "source" if source is not None else "receipt"
        self._seq = seq
        self._t = t
        self._floor.floor(observed, observed - t)
        return t

    def counted_t(self, k: int, n: int) -> float | None:
        """The time :meth:`follow` would give the ``k``-th message of ``n`` samples after the
        last one placed, if those k follow it with none lost, held or resynced; None while no
        message is placed or one is held. Lets a node tell that no output can fall due before
        it places them (``battery_filter_node``)."""
        if self._t is None or self._held is not None:
            return None
        return self._t + k * n * self.period_s

    def release_held(self) -> list[tuple[Placement, PayloadT]]:
        """Settle a held message with no successor to judge it: as a break (nothing bridged)."""
        if self._held is None:
            return []
        held, self._held = self._held, None
        return [self._settle(held, late=True)]

    @property
    def holding(self) -> Arrival | None:
        return None if self._held is None else self._held.arrival

    def _settle(self, held: _Suspect[PayloadT], late: bool) -> tuple[Placement, PayloadT]:
        if late:  # data missing before it: break, with the gap its lateness shows
            self.late_breaks += 1
            self._t = held.t_contiguous + held.excess
            self._floor.reset()
            self._floor.floor(held.observed, held.observed - self._t)
            return Placement(self._t, LATE, late_s=held.excess), held.payload
        self.late_forgiven += 1
        self._t = held.t_contiguous
        self._floor.floor(held.observed, held.observed - self._t)
        return Placement(self._t, CONTIGUOUS), held.payload

    def _start(self, a: Arrival, observed: float) -> Placement:
        """Anchor a new stream on the node clock at receipt (it may be earlier than the old
        stream's last time: the caller restarts its core on every NEW_STREAM but the first)."""
        self.streams += 1
        self._seq = a.seq
        t = a.receipt_s
        self._t = t
        self._floor.reset()
        self._floor.floor(observed, observed - t)
        return Placement(t, NEW_STREAM)

    def counters(self) -> dict[str, str | int]:
        """For diagnostics: what the timing rules saw."""
        return {
            "timing_witness": self.witness,
            "publisher_restarts": self.publisher_restarts,
            "lost_in_transport": self.lost_messages,
            "late_breaks": self.late_breaks,
            "late_forgiven": self.late_forgiven,
            "clock_resyncs": self.resyncs,
        }


class EventStream:
    """Times of messages published on change (pwm): source time on the node clock, losses."""

    def __init__(self, use_source: bool = True) -> None:
        self.use_source = bool(use_source)
        self.messages = 0
        self.lost_messages = 0
        self.publisher_restarts = 0
        self._floor = LatencyFloor()
        self._seq: int | None = None

    def place(self, a: Arrival) -> tuple[float, int]:
        """(time on the node clock, messages lost just before this one)."""
        return self._place(a.receipt_s, a.source_s, a.seq)

    def place_info(self, receipt_s: float, info: Mapping[str, int] | None) -> tuple[float, int]:
        """:meth:`place` of ``arrival(receipt_s, info)``, without building the Arrival (it runs
        for every message)."""
        source, seq = _source_and_seq(info) if info else (None, None)
        return self._place(receipt_s, source, seq)

    def _place(self, receipt_s: float, source_s: float | None, seq: int | None) -> tuple[float, int]:
        self.messages += 1
        lost = 0
        if seq is not None:
            if self._seq is not None and seq <= self._seq:
                self.publisher_restarts += 1
                self._floor.reset()
            elif self._seq is not None:
                lost = seq - self._seq - 1
            self._seq = seq
        self.lost_messages += lost
        if not self.use_source or source_s is None:
            return receipt_s, lost
        # receipt = source + offset + queueing; the least offset is the clocks' difference
        floor = self._floor.floor(source_s, receipt_s - source_s)
        t = source_s + floor
        return (t if math.isfinite(t) and t <= receipt_s else receipt_s), lost
