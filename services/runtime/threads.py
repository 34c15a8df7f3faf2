"""The services' own loops: a daemon thread each, started, watched and stopped the same way.

The alarm monitor's loop, the command's watcher and the planner's progress relay run as a
:class:`LoopThread`; the servo's real-time loop has its own (``servo/clock.py``).
"""

from __future__ import annotations

import threading
from collections.abc import Callable


class LoopThread:
    """A daemon thread running ``body(stop)``; ``body`` returns once ``stop`` is set (:meth:`stop`)."""

    def __init__(self, body: Callable[[threading.Event], None], name: str, join_within: float = 2.0) -> None:
        """``join_within`` [s]: how long :meth:`stop` waits for ``body`` to return."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=body, args=(self._stop,), name=name, daemon=True)
        self._join_within = join_within

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        """Whether ``body`` still runs (a service's heartbeat reports a dead loop as stuck)."""
        return self._thread.is_alive()

    def stop(self) -> None:
        """Ask ``body`` to return, and wait for it up to ``join_within``."""
        self._stop.set()
        self._thread.join(timeout=self._join_within)


__all__ = ["LoopThread"]
