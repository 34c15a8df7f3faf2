"""An estimate of how many of our position commands wait in the servo's SyncFIFO.

The servo takes one command per cycle while its FIFO is not empty and reports
the FIFO depth in ``ServoStatus`` (every 10 cycles, stamped with wall-clock
time). Between reports the depth is extrapolated: +1 per command sent, -1 per
servo period elapsed, never below 0. A report re-anchors it: the reported
depth, plus the commands sent after the report was taken (they were not in the
FIFO yet), minus the cycles elapsed since.

Error: about one command (a command reaches the FIFO at the start of the
servo's next cycle); the report's delivery delay does not matter, as the
report's own time stamp is used when the clocks agree.
"""

from __future__ import annotations

import collections

#: A report stamped further in the past than this, or in the future, is timed by its arrival [s].
_MAX_REPORT_AGE = 0.2
#: Commands sent this long before a report had not reached the FIFO when it was taken [s].
_TRANSIT = 0.0005
_HISTORY = 1.0  # [s] send times kept for re-anchoring


class FifoEstimate:
    """Depth of the servo FIFO [commands], from what we sent and what the servo reported."""

    def __init__(self, period: float) -> None:
        self.period = period  # [s] servo cycle
        self._depth = 0.0
        self._t = 0.0
        self._sends: collections.deque[tuple[float, int]] = collections.deque()

    def depth(self, now: float) -> float:
        """Estimated depth at ``now`` [s, Unix time]."""
        if now > self._t:
            self._depth = max(0.0, self._depth - (now - self._t) / self.period)
            self._t = now
        return self._depth

    def sent(self, now: float, count: int) -> None:
        """``count`` commands were published at ``now``."""
        if count <= 0:
            return
        self.depth(now)
        self._depth += count
        self._sends.append((now, count))
        while self._sends and self._sends[0][0] < now - _HISTORY:
            self._sends.popleft()

    def report(self, fifo_depth: int, stamp: float, now: float) -> None:
        """The servo reported ``fifo_depth`` at ``stamp`` [s, Unix time]; received at ``now``."""
        if not now - _MAX_REPORT_AGE <= stamp <= now + 0.001:
            stamp = now  # clocks disagree (another machine) or a very late report: trust arrival
        later = sum(c for t, c in self._sends if t > stamp - _TRANSIT)
        self._depth = max(0.0, fifo_depth + later - max(0.0, now - stamp) / self.period)
        self._t = now
