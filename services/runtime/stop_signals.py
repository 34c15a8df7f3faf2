"""SIGINT/SIGTERM as events: how every service and every long-running ``jara-arm`` command learns to stop.

A child of ``jara-arm up`` (a service, the client gateway) also stops when the
launcher dies without a word (SIGKILL, a crash): :meth:`StopSignals.exit_with_parent`.

The handler only puts the signal on a ``queue.SimpleQueue`` (reentrant); a thread
sets the events. A handler that set an event itself would run in the main thread
between two bytecodes, perhaps while that thread holds the event's own lock (inside
``stop.wait``), and deadlock: ``jara-arm logs`` once ignored a SIGINT so, until
it was killed.
"""

from __future__ import annotations

import os
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

    def exit_with_parent(self, on_orphaned: Callable[[int], None] | None = None) -> None:
        """Set ``stop`` once this process's parent has died (checked every 0.5 s): a launcher killed with no
        chance to stop its children leaves none running (a client gateway once held its listen port for 42
        minutes so). ``on_orphaned`` gets the dead parent's pid first."""
        parent = os.getppid()

        def watch() -> None:
            while not self.stop.wait(0.5):
                if os.getppid() != parent:
                    if on_orphaned is not None:
                        on_orphaned(parent)
                    self.name = "the parent's death"
                    self.stop.set()

        threading.Thread(target=watch, name="parent-watch", daemon=True).start()

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
