"""Output times on a fixed grid, shared by the nodes and ``replay`` so both publish alike.

A ROS timer fires at most once per step of the clock it runs on: under ``ros2 bag play
--clock`` (40 Hz by default) a 100 Hz output would fall to 40 Hz. Driving outputs from a grid
instead (every grid time the clock has passed is emitted, in order) keeps the rate whatever the
clock's step, and makes the node's outputs the same as ``replay``'s.
"""

from __future__ import annotations

import math


class Ticker:
    """Grid times ``start + k / rate_hz``; :meth:`due` returns those not yet emitted."""

    def __init__(self, rate_hz: float, max_backlog_s: float = 1.0) -> None:
        if not (math.isfinite(rate_hz) and rate_hz > 0):
            raise ValueError(f"rate_hz must be > 0, got {rate_hz!r}")
        self.period_s = 1.0 / rate_hz
        self.max_backlog_s = max_backlog_s
        self.skipped = 0  #: grid times dropped after the clock jumped more than max_backlog_s
        #: the next grid time, inf before the grid starts: also the cheap 'anything due?' test a
        #: node makes for every input (an attribute: a property costs more than the test)
        self.next_s = math.inf

    def start(self, t: float) -> None:
        """Start the grid at ``t`` (if it has not started)."""
        if not self.started:
            self.next_s = float(t)

    @property
    def started(self) -> bool:
        return self.next_s != math.inf

    def due(self, t: float) -> list[float]:
        """Grid times <= t not yet emitted (oldest first); a jump over max_backlog_s is skipped."""
        nxt = self.next_s
        if not t >= nxt:  # (before the start, next_s is inf)
            return []
        n = int((t - nxt) / self.period_s) + 1
        limit = max(1, int(self.max_backlog_s / self.period_s))
        if n > limit:  # a clock jump (paused or skipped bag): no burst of stale outputs
            self.skipped += n - 1
            self.next_s = nxt + n * self.period_s
            return [nxt + (n - 1) * self.period_s]
        self.next_s = nxt + n * self.period_s
        return [nxt + k * self.period_s for k in range(n)]

    def take(self, t: float) -> bool:
        """True if a grid time was passed by ``t`` (starting the grid at ``t``): decimation.
        Runs per battery sample: nothing due is answered without building ``due``'s list, and
        without ``start``'s call and property (the same test, inline)."""
        if self.next_s == math.inf:
            self.next_s = float(t)
        return t >= self.next_s and bool(self.due(t))
