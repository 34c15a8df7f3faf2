"""The thread that feeds the state tracker from the servo, the planner, the alarm monitor and their liveliness.

Zenoh only fills the boxes of an ``Inbox`` (the servo status, where the newest
value is what counts, in a box of a few; planner progress and liveliness, where
every change counts, in large ones); this one thread drains them when something
came (at most every ``timing.WATCHER_POLL``), and at least every
``timing.WATCHER_WAIT`` to notice a servo that fell silent, which no message
would announce.
"""

from __future__ import annotations

import logging
import threading

import zenoh

from jara_arm.schema import messages
from jara_arm.schema.alarms import ALARM_LIST
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.planner import PLANNER_PROGRESS
from jara_arm.services.runtime.entities import Entities
from jara_arm.services.runtime.heartbeat import Pulse
from jara_arm.services.runtime.inbox import Inbox
from jara_arm.services.runtime.threads import LoopThread
from jara_arm.services.runtime.timing import WATCHER_POLL, WATCHER_WAIT
from jara_arm.services.runtime.wire import decode_sample

from .state import StateTracker

log = logging.getLogger(__name__)

_STATUS_RING = 8  #: Servo/status messages kept between drains (100 Hz: two drains' worth and more)
_PROGRESS_FIFO = 1024  #: Planner/progress messages kept between drains
_ALARMS_FIFO = 64  #: Monitor/alarms lists kept between drains


class Watcher:
    """Subscribes to ``Servo/status``, ``Planner/progress``, ``Monitor/alarms`` and the liveliness of the
    planner and the monitor."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, tracker: StateTracker,
                 pulse: Pulse | None = None) -> None:
        self._tracker = tracker
        self._pulse = pulse or Pulse("the state watcher", 0.5)
        self._drain_lock = threading.Lock()  # the watcher's thread and a call's catch-up: one at a time, in order
        tracker.catch_up = self.drain
        self._entities = Entities()
        enter = self._entities.enter_context
        inbox = self._inbox = Inbox()
        self._status = inbox.box(_STATUS_RING)
        self._progress = inbox.box(_PROGRESS_FIFO)
        self._planner = inbox.box(64)
        self._alarms = inbox.box(_ALARMS_FIFO)
        self._monitor = inbox.box(64)
        enter(session.declare_subscriber(keys.servo_status, self._status))
        enter(session.declare_subscriber(keys.planner_progress, self._progress))
        enter(session.liveliness().declare_subscriber(keys.alive(Service.PLANNER), self._planner, history=True))
        enter(session.declare_subscriber(keys.monitor_alarms, self._alarms))
        enter(session.liveliness().declare_subscriber(keys.alive(Service.ALARM_MONITOR), self._monitor,
                                                      history=True))
        self._bad = 0  # malformed messages seen (logged once per kind)
        self._loop = LoopThread(self._run, "command-watch", wake=inbox.ring)

    def start(self) -> None:
        self._loop.start()

    @property
    def alive(self) -> bool:
        return self._loop.alive

    def stop(self) -> None:
        self._loop.stop()
        self._tracker.catch_up = None
        with self._drain_lock:  # a call's catch-up in progress ends before the subscribers close
            self._entities.close()

    def _run(self, stop: threading.Event) -> None:
        while not stop.is_set():
            self._inbox.wait(WATCHER_WAIT, spacing=WATCHER_POLL)
            self._pulse.beat()
            self.drain()

    def drain(self) -> None:
        """Everything that arrived since the last drain, in order, then the staleness check."""
        with self._drain_lock:
            self._drain()

    def _drain(self) -> None:
        while (s := self._planner.try_recv()) is not None:
            if s.kind == zenoh.SampleKind.DELETE:
                log.warning("the planner service is gone: its queue is discarded")
                self._tracker.on_planner_gone()
            else:
                log.info("the planner service is up")
        while (s := self._monitor.try_recv()) is not None:
            if s.kind == zenoh.SampleKind.DELETE:
                log.warning("the alarm monitor is gone: the servo holds its alarms")
                self._tracker.on_monitor_gone()
        while (s := self._alarms.try_recv()) is not None:
            try:
                self._tracker.on_alarms(decode_sample(ALARM_LIST, s))
            except WireError as exc:
                self._malformed("Monitor/alarms", exc)
        while (s := self._progress.try_recv()) is not None:
            try:
                self._tracker.on_progress(decode_sample(PLANNER_PROGRESS, s))
            except WireError as exc:
                self._malformed("Planner/progress", exc)
        while (s := self._status.try_recv()) is not None:
            try:
                self._tracker.on_status(decode_sample(messages.SERVO_STATUS, s))
            except WireError as exc:
                self._malformed("Servo/status", exc)
        self._tracker.tick()  # everything waiting is in: now a silent servo may be said off

    def _malformed(self, what: str, exc: WireError) -> None:
        self._bad += 1
        if self._bad in (1, 10, 100, 1000) or self._bad % 10000 == 0:
            log.error("ignored a malformed %s message (%d so far): %s", what, self._bad, exc)
