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
        self._next: float | None = None
        #: the next grid time (inf before the grid starts): a cheap 'anything due?' test, read
        #: for every input of a node (an attribute, kept equal to _next: a property costs more
        #: than the test)
        self.next_s = math.inf

    def start(self, t: float) -> None:
        """Start the grid at ``t`` (if it has not started)."""
        if self._next is None:
            self._next = self.next_s = float(t)

    @property
    def started(self) -> bool:
        return self._next is not None

    def due(self, t: float) -> list[float]:
        """Grid times <= t not yet emitted (oldest first); a jump over max_backlog_s is skipped."""
        nxt = self._next
        if nxt is None or t < nxt:
            return []
        n = int((t - nxt) / self.period_s) + 1
        limit = max(1, int(self.max_backlog_s / self.period_s))
        if n > limit:  # a clock jump (paused or skipped bag): no burst of stale outputs
            self.skipped += n - 1
            self._next = self.next_s = nxt + n * self.period_s
            return [nxt + (n - 1) * self.period_s]
        self._next = self.next_s = nxt + n * self.period_s
        return [nxt + k * self.period_s for k in range(n)]

    def take(self, t: float) -> bool:
        """True if a grid time was passed by ``t`` (starting the grid at ``t``): decimation.
        Runs per battery sample: nothing due is answered without building ``due``'s list."""
        if self._next is None:
            self._next = self.next_s = float(t)
        elif t < self._next:
            return False
        return bool(self.due(t))
