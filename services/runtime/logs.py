"""Python logging to stderr and to ``JARA_ARM/<arm>/log/<service>``.

``emit`` only puts the record on a ``queue.SimpleQueue``; a thread of its own
publishes, so that a log call never blocks a Zenoh callback or the servo loop.
``SimpleQueue.put`` is reentrant: a log call from code that interrupts ``emit``
in the same thread (a signal handler, a ``gc`` callback) cannot deadlock it,
as the servo's main thread once did on a ``threading.Event``'s lock. The records are JSON
(``schema/keys.py``): any Zenoh tool prints them.
"""

from __future__ import annotations

import logging
import queue
import sys
import threading

import zenoh

from jara_arm.schema import messages
from jara_arm.schema.keys import ArmKeys, Service

from .entities import Entities
from .wire import Publication

FORMAT = "%(asctime)s %(levelname)-7s %(name)s: %(message)s"
_QUEUE_LIMIT = 10_000  # records kept while Zenoh is slow; newer ones are dropped


def setup_stderr(level: str = "INFO") -> None:
    """Log to stderr at ``level`` (the service's own stderr, always on)."""
    root = logging.getLogger()
    root.setLevel(level.upper())
    if not any(getattr(h, "_jara_stderr", False) for h in root.handlers):
        h = logging.StreamHandler(sys.stderr)
        h.setFormatter(logging.Formatter(FORMAT))
        h._jara_stderr = True  # type: ignore[attr-defined]
        root.addHandler(h)


class ZenohLogHandler(logging.Handler):
    """Publishes every record as a ``LogRecord`` message on the service's log key.

    A process that serves several arms (``also``) publishes a record on the key
    of the arm it names (``extra={"arm": ...}``, e.g. through a ``LoggerAdapter``),
    and the process's own records on the first arm's key.
    """

    def __init__(self, session: zenoh.Session, keys: ArmKeys, service: Service,
                 also: tuple[ArmKeys, ...] = ()) -> None:
        super().__init__()
        self._service = service
        # What close() needs exists before the first declaration: logging.shutdown() at exit
        # closes a handler whose __init__ failed too.
        self._entities = Entities()
        self._pending: queue.SimpleQueue[logging.LogRecord | None] = queue.SimpleQueue()  # None: closed
        self._thread = threading.Thread(target=self._run, name="log-publisher", daemon=True)
        # looked up by a record's arm, None when it names none (then the main publisher)
        self._by_arm: dict[str | None, Publication] = {
            k.arm: self._entities.enter_context(Publication(session, k.log(service)))
            for k in also if k.arm != keys.arm}
        self._publisher = self._entities.enter_context(Publication(session, keys.log(service)))
        self._thread.start()

    def emit(self, record: logging.LogRecord) -> None:
        if self._pending.qsize() < _QUEUE_LIMIT:
            self._pending.put(record)

    def _run(self) -> None:
        while (record := self._pending.get()) is not None:
            self._publish(record)

    def _publish(self, record: logging.LogRecord) -> None:
        try:
            msg = record.getMessage()
            if record.exc_info:
                msg += "\n" + logging.Formatter().formatException(record.exc_info)
            self._by_arm.get(getattr(record, "arm", None), self._publisher).put_message(
                messages.LOG_RECORD, messages.LogRecord(record.created, record.levelname, self._service.value, msg,
                                                        record.name))
        except Exception:  # a log that cannot be published must not take the service down
            pass

    def close(self) -> None:
        self._pending.put(None)
        if self._thread.is_alive():  # not started if __init__ failed
            self._thread.join(timeout=2.0)
        self._entities.close()
        super().close()
