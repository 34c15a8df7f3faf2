"""An estimate of how many of our position commands wait in the servo's SyncFIFO.

The servo takes one command per cycle while its FIFO is not empty and reports
the FIFO depth in ``ServoStatus`` every 10 cycles, stamped with the wall-clock
time its cycle stands for (the cycle's deadline; a late loop catches up by
running its cycles back to back). Between reports the depth is extrapolated:
+1 per command sent, -1 per servo period elapsed, never below 0.

A report re-anchors it, erring on the low side (a low estimate only sends a
little more; a high one lets the FIFO run dry): the reported depth, plus the
commands sent in the last moments (surely not in the FIFO when it was counted),
minus one command per period since the stamp -- the servo either consumed them
since, or will consume them as it catches up its lateness.

Error: about one command low when the report arrives promptly; under delivery
delays, low by the commands sent meanwhile (the FIFO then holds more than
``lead``, never less).
"""

from __future__ import annotations

#: A report stamped further in the past than this, or in the future, is timed by its arrival [s].
_MAX_REPORT_AGE = 0.2
#: Commands sent this recently had not reached the FIFO when the report was taken [s].
_TRANSIT = 0.0005


class FifoEstimate:
    """Depth of the servo FIFO [commands], from what we sent and what the servo reported."""

    def __init__(self, period: float) -> None:
        self.period = period  # [s] servo cycle
        self._depth = 0.0
        self._t = 0.0
        self._recent: list[tuple[float, int]] = []  # (send time [s], count) within _TRANSIT

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
        self._recent = [(t, c) for t, c in self._recent if t > now - _TRANSIT]
        self._recent.append((now, count))

    def report(self, fifo_depth: int, stamp: float, now: float) -> None:
        """The servo counted ``fifo_depth`` for its cycle at ``stamp`` [s, Unix time]; received ``now``."""
        if not now - _MAX_REPORT_AGE <= stamp <= now + 0.001:
            stamp = now  # clocks disagree (another machine) or a very late report: trust arrival
        recent = sum(c for t, c in self._recent if t > now - _TRANSIT)
        self._depth = max(0.0, fifo_depth + recent - max(0.0, now - stamp) / self.period)
        self._t = now
