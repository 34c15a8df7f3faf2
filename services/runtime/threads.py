"""The services' own loops: a daemon thread each, started, watched and stopped the same way.

The alarm monitor's loop, the command's watcher, the planner's progress relay, every
service's heartbeat and the servo's real-time clock run as a :class:`LoopThread`.
"""

from __future__ import annotations

import threading
from collections.abc import Callable


class LoopThread:
    """A daemon thread running ``body(stop)``; ``body`` returns once ``stop`` is set (:meth:`stop`)."""

    def __init__(self, body: Callable[[threading.Event], None], name: str, join_within: float = 2.0,
                 wake: Callable[[], None] | None = None) -> None:
        """``join_within`` [s]: how long :meth:`stop` waits for ``body`` to return; ``wake``: how :meth:`stop`
        wakes a ``body`` that waits on something else than ``stop`` (an ``Inbox``'s ``ring``)."""
        self._stop = threading.Event()
        self._thread = threading.Thread(target=body, args=(self._stop,), name=name, daemon=True)
        self._join_within = join_within
        self._wake = wake

    def start(self) -> None:
        self._thread.start()

    @property
    def alive(self) -> bool:
        """Whether ``body`` still runs (a service's heartbeat reports a dead loop as stuck)."""
        return self._thread.is_alive()

    @property
    def native_id(self) -> int:
        """The kernel's id of the thread (0 before it started)."""
        return self._thread.native_id or 0

    def stop(self) -> None:
        """Ask ``body`` to return, and wait for it up to ``join_within`` (if it was started)."""
        self._stop.set()
        if self._wake is not None:
            self._wake()
        if self._thread.is_alive():
            self._thread.join(timeout=self._join_within)


__all__ = ["LoopThread"]
