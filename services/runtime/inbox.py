"""Zenoh inputs that wake the one thread reading them: a service's loop sleeps while nothing arrives.

A Zenoh channel (``FifoChannel``, ``RingChannel``) cannot wake a thread that reads several of them, so the
alarm monitor, the command's state watcher and the planner's progress relay polled theirs every 10 ms:
100 wakes a second each, 0.03-0.045 of a core per service with the arm at rest (``bench/cpu.py``). An
:class:`Inbox` gives each input a :class:`Box` whose Zenoh callback only appends the sample and rings a
bell; the loop waits on the bell and drains every box, so it runs when something came, and otherwise
only as often as its own timers need.
"""

from __future__ import annotations

import collections
import threading
import time
from typing import Any


class Box:
    """One input's samples, oldest first, filled by its Zenoh callback (pass the box as the handler).

    Full at ``capacity``: the oldest sample is dropped for the newest (counted in :attr:`dropped`), as a
    ``RingChannel`` does; a ``FifoChannel`` would hold up Zenoh's receiving thread instead.
    """

    def __init__(self, bell: threading.Event, capacity: int) -> None:
        self._bell = bell
        self._samples: collections.deque[Any] = collections.deque(maxlen=capacity)
        self.dropped = 0

    def __call__(self, sample: Any) -> None:
        # On Zenoh's thread: no work but this (deque.append is atomic, Event.set does not block).
        if len(self._samples) == self._samples.maxlen:
            self.dropped += 1
        self._samples.append(sample)
        self._bell.set()

    def try_recv(self) -> Any | None:
        """The oldest sample not taken yet, or None (as a Zenoh channel's ``try_recv``)."""
        try:
            return self._samples.popleft()
        except IndexError:
            return None


class Inbox:
    """The inputs of one thread: :meth:`box` for each, then :meth:`wait` between drains."""

    def __init__(self) -> None:
        self._bell = threading.Event()
        self._woke = -float("inf")  # [s] monotonic: the last return of :meth:`wait`

    def box(self, capacity: int) -> Box:
        """A new input of this inbox holding up to ``capacity`` samples."""
        return Box(self._bell, capacity)

    def ring(self) -> None:
        """Wake the waiting thread (its stop, or work handed to it outside the boxes)."""
        self._bell.set()

    def wait(self, timeout: float, spacing: float = 0.0) -> bool:
        """Until something arrives or ``timeout`` [s] passes; True if something arrived (or :meth:`ring`).

        ``spacing`` [s]: at most one return per ``spacing``; what arrives sooner than that after the last
        return waits for the rest of it, and is drained in one batch (a 100 Hz stream plus heartbeats cost
        no more wakes than the poll they replace).
        """
        rang = self._bell.wait(timeout)
        self._bell.clear()  # before the drain: what comes during it rings again
        if spacing > 0.0:
            rest = self._woke + spacing - time.monotonic()
            if rest > 0.0:
                time.sleep(rest)
        self._woke = time.monotonic()
        return rang


__all__ = ["Box", "Inbox"]
