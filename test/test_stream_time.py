"""Timing rules of stamp-less inputs (nodes/stream_time.py) and the output grid (core/ticker.py).

Plain Python: every fault the live tests provoke (lost batches, a stalled node, a late burst, a
restarted publisher, /clock steps) is reproduced here with exact arrival times.
"""

from __future__ import annotations

from itertools import pairwise

import pytest

from bldc_propulsion.core.ticker import Ticker
from bldc_propulsion.nodes.stream_time import (
    CONTIGUOUS,
    LATE,
    LOST,
    NEW_STREAM,
    Arrival,
    EventStream,
    LatencyFloor,
    Placement,
    SampleStream,
    arrival,
)

RATE, N = 20000.0, 200  # tachometer: 200-sample batches, 10 ms each
P = N / RATE


def feed(stream, arrivals):
    """Every message's placement, in order (a held one is settled by its successor)."""
    out = [p for k, a in enumerate(arrivals) for p, _ in stream.push(a, N, k)]
    out += [p for p, _ in stream.release_held()]
    assert len(out) == len(arrivals)
    return out


def regular(k0, k1, latency=0.0003, jitter=0.0, receipt_extra=None, t0=50.0, seq0=1):
    """Batches k0..k1-1 published at their last sample's time (+ latency on receipt)."""
    out = []
    for k in range(k0, k1):
        src = t0 + (k + 1) * P + (jitter if k % 2 else 0.0)
        rec = src + latency + (receipt_extra(k) if receipt_extra else 0.0)
        out.append(Arrival(rec, src, seq0 + k))
    return out


def test_arrival_from_message_info_and_without():
    a = arrival(3.0, {"source_timestamp": 2_500_000_000, "publication_sequence_number": 7})
    assert (a.receipt_s, a.source_s, a.seq) == (3.0, 2.5, 7)
    assert arrival(3.0, None) == Arrival(3.0)
    # rmw's "unsupported" sequence number means unknown, not 2**64 - 1 messages
    assert arrival(3.0, {"source_timestamp": 0, "publication_sequence_number": 2**64 - 1}).seq is None


def test_contiguous_batches_are_timed_by_counting_despite_jitter():
    s = SampleStream(RATE, 0.005)
    places = feed(s, regular(0, 50, jitter=0.002))
    assert places[0].event == NEW_STREAM
    assert all(p.event == CONTIGUOUS for p in places[1:])
    ts = [p.t_last for p in places]
    assert all(b - a == pytest.approx(P, abs=1e-12) for a, b in pairwise(ts))


def test_one_message_published_late_is_held_then_forgiven():
    """A busy publisher sends one batch 8 ms late (less than a batch, more than the
    tolerance): the next batch is on time, so nothing was missing."""
    s = SampleStream(RATE, 0.005)
    arr = regular(0, 20)
    a = arr[10]
    arr[10] = Arrival(a.receipt_s + 0.008, a.source_s + 0.008, a.seq)
    settled = [s.push(x, N, k) for k, x in enumerate(arr)]
    assert settled[10] == []  # held: its successor decides
    assert [k for _, k in settled[11]] == [10, 11]
    places = feed(SampleStream(RATE, 0.005), arr)
    assert all(p.event == CONTIGUOUS for p in places[1:])
    assert s.late_forgiven == 1 and s.late_breaks == 0


def test_batches_lost_in_transport_advance_time_by_their_duration():
    s = SampleStream(RATE, 0.005)
    arr = regular(0, 10) + regular(13, 20)  # sequence numbers 11..13 never arrive
    places = feed(s, arr)
    lost = places[10]
    assert lost.event == LOST and lost.lost_messages == 3
    assert lost.t_last - places[9].t_last == pytest.approx(4 * P)
    assert all(p.event == CONTIGUOUS for p in places[11:])
    assert s.lost_messages == 3


def test_a_publisher_that_skips_batches_is_caught_by_its_source_time():
    """Sequence numbers stay consecutive (the publisher never sent them): lateness tells."""
    s = SampleStream(RATE, 0.005)
    arr = regular(0, 10)
    for k in range(13, 20):  # three batches skipped at the source, numbering continues
        a = regular(k, k + 1)[0]
        arr.append(Arrival(a.receipt_s, a.source_s, k - 3 + 1))
    places = feed(s, arr)
    assert places[10].event == LATE
    assert places[10].late_s == pytest.approx(3 * P, abs=1e-9)
    assert places[10].t_last - places[9].t_last == pytest.approx(4 * P, abs=1e-9)
    assert all(p.event == CONTIGUOUS for p in places[11:])


def test_a_stalled_node_loses_nothing_when_the_publisher_kept_time():
    """SIGSTOP for 300 ms: 30 batches queue up and arrive together; source times are regular."""
    s = SampleStream(RATE, 0.005)
    stall_end = 50.0 + 40 * P
    arr = regular(0, 40, receipt_extra=lambda k: max(0.0, stall_end - (50.0 + (k + 1) * P))
                  if k >= 10 else 0.0)
    places = feed(s, arr)
    assert [p.event for p in places[1:]] == [CONTIGUOUS] * 39
    assert places[-1].t_last - places[0].t_last == pytest.approx(39 * P, abs=1e-9)


def test_without_message_info_a_stall_breaks_the_stream_instead():
    s = SampleStream(RATE, 0.005)
    stall_end = 50.0 + 40 * P
    arr = [Arrival(a.receipt_s) for a in regular(
        0, 40, receipt_extra=lambda k: max(0.0, stall_end - (50.0 + (k + 1) * P)) if k >= 10 else 0.0)]
    events = [p.event for p in feed(s, arr)]
    assert events.count(LATE) == 1 and events[10] == LATE
    assert s.witness == "receipt"


def test_a_late_burst_breaks_once_then_continues():
    s = SampleStream(RATE, 0.005)
    arr = regular(0, 10)
    for k in range(10, 15):  # the publisher held 5 batches, then sent them at once
        arr.append(Arrival(50.0 + 15 * P + 0.0003, 50.0 + 15 * P, k + 1))
    arr += regular(15, 25)
    events = [p.event for p in feed(s, arr)]
    assert events[10] == LATE
    assert events[11:] == [CONTIGUOUS] * (len(events) - 11)


def test_a_restarted_publisher_starts_a_new_stream():
    s = SampleStream(RATE, 0.005)
    arr = regular(0, 20) + regular(25, 35, seq0=-24)  # numbering starts again at 1
    places = feed(s, arr)
    assert places[20].t_last == arr[20].receipt_s  # anchored on the node clock again
    assert places[20].event == NEW_STREAM and s.publisher_restarts == 1


def test_counted_time_that_drifts_from_the_node_clock_resyncs():
    s = SampleStream(RATE, 0.005, use_source=False)
    arr = [Arrival(50.0 + k * P * 0.8) for k in range(600)]  # data really 20 % faster
    places = feed(s, arr)
    assert s.resyncs >= 1
    assert all(p.t_last <= a.receipt_s + 0.1 + 1e-9 for p, a in zip(places, arr, strict=True))
    assert all(b.t_last > a.t_last or b.event == NEW_STREAM for a, b in pairwise(places))


def test_latency_floor_is_a_sliding_window_minimum():
    f = LatencyFloor(window_s=1.0)
    assert f.floor(0.0, 0.5) == 0.5
    assert f.floor(0.5, 0.2) == 0.2
    assert f.floor(1.0, 0.9) == 0.2
    assert f.floor(1.6, 0.7) == 0.7  # 0.2 left the window
    f.reset()
    assert f.peek() is None


def test_event_stream_keeps_a_queued_command_at_its_own_time():
    e = EventStream()
    offset = 1000.0  # node clock (e.g. /clock) minus the publisher's wall clock
    assert e.place(Arrival(offset + 1.0003, 1.0, 1)) == (pytest.approx(offset + 1.0003), 0)
    # received 400 ms late (node stalled): timed at publication + the latency floor
    t, lost = e.place(Arrival(offset + 1.5, 1.1, 2))
    assert t == pytest.approx(offset + 1.1003) and lost == 0
    t, lost = e.place(Arrival(offset + 1.6003, 1.6, 5))
    assert lost == 2 and e.lost_messages == 2
    assert e.place(Arrival(offset + 2.0, None, None))[0] == offset + 2.0  # no info: receipt


def test_ticker_emits_every_grid_time_a_coarse_clock_passes():
    tick = Ticker(100.0)
    assert tick.due(5.0) == []  # not started
    tick.start(5.0)
    emitted = []
    for k in range(1, 41):  # /clock at 40 Hz for one second
        emitted += tick.due(5.0 + 0.025 * k)
    assert len(emitted) == 101
    assert emitted[:3] == pytest.approx([5.0, 5.01, 5.02])
    assert all(b - a == pytest.approx(0.01) for a, b in pairwise(emitted))


def test_ticker_skips_a_clock_jump_instead_of_a_burst_of_stale_outputs():
    tick = Ticker(100.0, max_backlog_s=1.0)
    tick.start(0.0)
    assert len(tick.due(0.5)) == 51
    jump = tick.due(60.0)
    assert len(jump) == 1 and jump[0] == pytest.approx(60.0, abs=0.01)
    assert tick.skipped > 5000


def test_ticker_take_decimates_samples_by_time():
    tick = Ticker(50.0)
    taken = [k for k in range(1000) if tick.take(k * 0.001)]
    assert len(taken) == 50 and taken[:3] == [0, 20, 40]


def _stream_state(s: SampleStream) -> tuple:
    return (s.messages, s.streams, s.publisher_restarts, s.resyncs, s.lost_messages, s.late_breaks,
            s.late_forgiven, s.witness, s._t, s._seq, s._held is None, s._floor.value,
            list(s._floor._q))


def _faulty_arrivals(rng_seed: int) -> list[tuple[float, dict | None]]:
    """(receipt time, message info) of a stream with every fault the rules handle: jitter, a
    stall, losses, a late burst, a restarted publisher, a clock running ahead, no info."""
    import random

    rng = random.Random(rng_seed)
    out: list[tuple[float, dict | None]] = []
    seq, src = 1, 50.0
    for k in range(400):
        src += P
        rec = src + 0.0003 + rng.uniform(0.0, 0.002)
        if 100 <= k < 110:
            rec += 0.05  # a stall: queued, on time on the publisher's clock
        if k in (150, 151, 152):
            seq += 1  # lost in transport
        if k == 200:
            src += 0.03  # the publisher skipped data: late on its own clock
        if k == 250:
            seq = 1  # restarted publisher
        if k == 300:
            rec -= 0.5  # counted time ahead of the node clock: resync
        info = None if 350 <= k < 355 else {
            "source_timestamp": int(round(src * 1e9)), "publication_sequence_number": seq}
        out.append((rec, info))
        seq += 1
    return out


@pytest.mark.parametrize("use_source", [True, False])
def test_follow_places_the_usual_message_exactly_as_push(use_source):
    """The nodes place a message with follow() and fall back to push() when it returns None:
    every placement, counter and internal state equals push() alone, through every fault."""
    for seed in range(3):
        a, b = SampleStream(RATE, 0.005, use_source), SampleStream(RATE, 0.005, use_source)
        followed = 0
        for k, (rec, info) in enumerate(_faulty_arrivals(seed)):
            expected = [(p, v) for p, v in a.push(arrival(rec, info), N, k)]
            t = b.follow(rec, info, N)
            if t is not None:
                followed += 1
                got = [(Placement(t, CONTIGUOUS), k)]
            else:
                got = b.push(arrival(rec, info), N, k)
            assert got == expected, k
            assert _stream_state(a) == _stream_state(b), k
        assert 300 < followed < 400  # the usual message, and only it, takes the short way


def test_follow_leaves_nothing_changed_when_it_declines():
    s = SampleStream(RATE, 0.005)
    assert s.follow(50.0, {"source_timestamp": 50_000_000_000, "publication_sequence_number": 1}, N) is None
    assert s.messages == 0  # the first message: push starts the stream
    s.push(arrival(50.0003, {"source_timestamp": 50_000_000_000, "publication_sequence_number": 1}), N, 0)
    before = _stream_state(s)
    info = {"source_timestamp": int((50.0 + P) * 1e9), "publication_sequence_number": 3}
    assert s.follow(50.0003 + P, info, N) is None  # a sequence jump: push's rule
    assert _stream_state(s) == before


def test_event_stream_place_info_equals_place_of_the_arrival():
    a, b = EventStream(), EventStream()
    for rec, info in _faulty_arrivals(4):
        assert a.place(arrival(rec, info)) == b.place_info(rec, info)
    assert (a.messages, a.lost_messages, a.publisher_restarts, a._floor.value) == (
        b.messages, b.lost_messages, b.publisher_restarts, b._floor.value)


def test_ticker_next_s_follows_start_due_and_take():
    tick = Ticker(100.0)
    assert tick.next_s == float("inf") and not tick.started
    assert tick.take(-1.0)  # starts the grid at -1.0 and takes that grid time
    assert tick.started and tick.next_s == pytest.approx(-0.99)
    assert not tick.take(-0.995)  # nothing due: answered from next_s
    tick.due(0.5)
    assert tick.next_s == pytest.approx(0.51)
    other = Ticker(100.0)
    other.start(2.0)
    assert other.next_s == 2.0 and other.due(1.0) == [] and other.next_s == 2.0
