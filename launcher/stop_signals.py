"""SIGINT/SIGTERM as events: how every long-running command of ``jara-arm`` learns it is to stop.

``up`` and ``router`` stop their children and routers in order; the client
commands close their session and exit. The handlers only set events.
"""

from __future__ import annotations

import signal
import threading


class StopSignals:
    """SIGINT/SIGTERM handlers: the first sets ``stop``, a second one also sets ``hurry``.

    Install them before starting children, from the main thread; the handlers
    only set events, the main loop does the rest.
    """

    def __init__(self) -> None:
        self.stop = threading.Event()
        self.hurry = threading.Event()
        self.name = ""  #: the signal that set ``stop``
        for signum in (signal.SIGINT, signal.SIGTERM):
            signal.signal(signum, self._handle)

    def _handle(self, signum: int, _frame: object) -> None:
        # Only set events here: logging from a handler could re-enter a stream write.
        if self.stop.is_set():
            self.hurry.set()
        else:
            self.name = signal.Signals(signum).name
            self.stop.set()
