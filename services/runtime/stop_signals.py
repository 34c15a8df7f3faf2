"""SIGINT/SIGTERM as events: how every service and every long-running ``jara-arm`` command learns to stop.

The handler only puts the signal on a ``queue.SimpleQueue`` (reentrant); a thread
sets the events. A handler that set an event itself would run in the main thread
between two bytecodes, perhaps while that thread holds the event's own lock (inside
``stop.wait``), and deadlock: ``jara-arm logs`` once ignored a SIGINT so, until
it was killed.
"""

from __future__ import annotations

import queue
import signal
import threading
from collections.abc import Callable


class StopSignals:
    """SIGINT/SIGTERM handlers: the first sets ``stop``, a second one also sets ``hurry``.

    Install them from the main thread, before starting children (a signal must
    never orphan one). ``on_signal`` is called with the signal's name, from the
    watching thread, before the event is set.
    """

    def __init__(self, on_signal: Callable[[str], None] | None = None) -> None:
        self.stop = threading.Event()
        self.hurry = threading.Event()
        self.name = ""  #: the signal that set ``stop``
        self._on_signal = on_signal
        self._received: queue.SimpleQueue[int] = queue.SimpleQueue()
        threading.Thread(target=self._watch, name="signal-watch", daemon=True).start()
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._handle)

    def _handle(self, signum: int, _frame: object) -> None:
        self._received.put(signum)

    def _watch(self) -> None:
        while True:
            name = signal.Signals(self._received.get()).name
            if self._on_signal is not None:
                self._on_signal(name)
            if self.stop.is_set():
                self.hurry.set()
            else:
                self.name = name
                self.stop.set()
