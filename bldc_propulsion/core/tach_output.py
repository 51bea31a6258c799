"""Which tachometer speeds may be published: the rule the node and ``replay`` share.

The decoder always has a latest speed, but after a break in the samples (a gap, a late batch,
a publisher restart, a sample-rate mismatch, non-finite samples) that speed describes the rotor
before the break. A consumer cannot tell, so it is not published again until a full revolution
after the break gives a new one. A speed of 0 is published only when it is known: edges stopped
while batches kept coming and the signal sits at the clear-beam level (``stopped``). With no
batches, or a signal stuck low or between the levels, nothing is published and diagnostics say why.
"""

from __future__ import annotations

from .tachometer import STOPPED, TachometerDecoder


def _breaks(d: TachometerDecoder) -> int:
    """Every counter that marks samples before and after it as not adjacent."""
    k = d.counts
    return (k.history_resets + k.gaps + k.time_resyncs + k.nonfinite_gaps + k.signal_losses
            + k.rate_mismatch_batches + k.rejected_batches)


class SpeedOutput:
    """Tracks the decoder's counters between batches and answers 'what may I publish now?'."""

    def __init__(self, decoder: TachometerDecoder) -> None:
        self.decoder = decoder
        self.valid = False
        self.withheld = 0  #: batches after which nothing was published
        self._speeds = decoder.speeds
        self._breaks = _breaks(decoder)

    def after_batch(self) -> float | None:
        """The speed (rad/s) to publish after the batch just decoded, or None."""
        d = self.decoder
        breaks = _breaks(d)
        speeds = d.counts.speeds
        if speeds > self._speeds and not d.rate_mismatch:
            self.valid = True  # a revolution measured in this batch
        elif breaks > self._breaks:
            self.valid = False
        self._speeds, self._breaks = speeds, breaks
        if self.valid and d.signal_ok:
            return d.speed_now
        self.valid = False
        if d.state == STOPPED and not d.rate_mismatch:
            return 0.0
        self.withheld += 1
        return None
