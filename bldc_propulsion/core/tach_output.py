"""Which tachometer speeds may be published: the rule the node and ``replay`` share.

The decoder always has a latest speed, but after a break in the samples (a gap, a late batch,
a publisher restart, a sample-rate mismatch, non-finite samples) that speed describes the rotor
before the break. A consumer cannot tell, so it is not published again until a full revolution
after the break gives a new one. A speed of 0 is published only when it is known: edges stopped
while batches kept coming and the signal sits at the clear-beam level (``stopped``). With no
batches, or a signal stuck low or between the levels, nothing is published and diagnostics say why.

Each value also has the instant it describes (``rotor/state``'s stamp): a speed the middle of
its revolution (:func:`revolution_middle`), a 0 the batch's last sample.
"""

from __future__ import annotations

import math

import numpy as np

from .tachometer import STOPPED, TachometerDecoder


def revolution_middle(end_t: float | np.ndarray, speed_rad_s: float | np.ndarray) -> float | np.ndarray:
    """The instant a tachometer speed describes (s): the middle of the revolution it is the
    mean over, which ends at ``end_t``, i.e. ``end_t - pi / speed``.

    The one rule for where a measured speed sits in time (the offline loader, the node's
    rotor/state stamp, replay): at the end of its revolution it lags the rotor by half a
    revolution (60 ms at 50 rad/s), a phase error a consumer comparing by time would pay.
    """
    if isinstance(end_t, float) and isinstance(speed_rad_s, float):  # a node's one speed: no numpy
        return end_t - math.pi / max(speed_rad_s, 1e-9)  # the same IEEE operations (NaN too)
    return end_t - math.pi / np.maximum(speed_rad_s, 1e-9)


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
        #: the instant (s) the value after_batch returned describes (revolution_middle, or the
        #: batch's time for a 0), and whether that value is a measurement not returned before:
        #: a stamped output publishes each measurement once (a repeat would count as new evidence)
        self.stamp_s = math.nan
        self.fresh = False
        self._speeds = decoder.speeds
        self._breaks = _breaks(decoder)

    def after_batch(self, t_last: float) -> float | None:
        """The speed (rad/s) to publish after the batch just decoded, whose last sample is at
        ``t_last`` (s), or None; sets :attr:`stamp_s` and :attr:`fresh` for it."""
        d = self.decoder
        w, edge_t, signal_ok, rate_mismatch = d.speed_report()
        breaks = _breaks(d)
        speeds = d.counts.speeds
        if speeds > self._speeds and not rate_mismatch:
            self.valid = True  # a revolution measured in this batch
        elif breaks > self._breaks:
            self.valid = False
        self._speeds, self._breaks = speeds, breaks
        if self.valid and signal_ok:
            assert edge_t is not None, "a valid speed was measured over a revolution"
            stamp = float(revolution_middle(edge_t, w))
            self.fresh = stamp != self.stamp_s
            self.stamp_s = stamp
            return w
        self.valid = False
        if d.state == STOPPED and not rate_mismatch:
            self.stamp_s, self.fresh = float(t_last), True  # known to stand still up to now
            return 0.0
        self.fresh = False
        self.withheld += 1
        return None
