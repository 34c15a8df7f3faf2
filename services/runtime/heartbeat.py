"""Every service's heartbeat: ``heartbeat/<service>`` every ``HEARTBEAT_PERIOD`` from a thread of its own.

A liveliness token shows connectivity, not health. The heartbeat shows that
the process runs: one stopped with SIGSTOP, or starved of the CPU, falls
silent within a few periods while its token stays up. It also shows that the
process's working loops turn: each loop takes a :class:`Pulse` and beats it
on every turn, and a loop that has not beaten within its deadline is named in
the heartbeat's ``stuck`` lines. The alarm monitor raises the service's hung
FAULT (0x410-0x412) on either (``services/alarm_monitor/detectors.py``).

The thread runs at real-time priority where the process may: a heartbeat
that is late because the machine is busy would read as a hung service.
"""

from __future__ import annotations

import logging
import math
import threading
import time

import zenoh

from jara_arm.schema import codec
from jara_arm.schema import alarms
from jara_arm.schema.alarms import HEARTBEAT, HEARTBEAT_PERIOD
from jara_arm.schema.codes import ULONG_MAX
from jara_arm.schema.keys import ArmKeys, Service

from .realtime import realtime_thread

log = logging.getLogger(__name__)

#: The heartbeat thread itself held up this long [s] (the whole process or machine
#: stalled): a loop's silence over that time says nothing about the loop.
_SELF_STALL = 4 * HEARTBEAT_PERIOD


class Pulse:
    """One working loop's proof of life: :meth:`beat` on every turn, from that loop's thread."""

    __slots__ = ("name", "deadline", "at")

    def __init__(self, name: str, deadline: float) -> None:
        if not deadline > 0.0:
            raise ValueError(f"a pulse deadline must be a positive number of seconds, got {deadline!r}")
        self.name = name
        self.deadline = deadline  # [s] longest time between two beats of a healthy loop
        self.at = math.inf  # [s] monotonic time of the last beat; inf: not yet started, never stuck

    def beat(self) -> None:
        self.at = time.monotonic()  # one float store: atomic under the GIL, no lock needed

    def silence(self, now: float) -> float:
        """[s] since the last beat (0 before the first)."""
        return max(0.0, now - self.at)


class Heartbeat:
    """Publishes this service's ``schema.alarms.Heartbeat`` every ``period`` until :meth:`close`."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, service: Service, priority: int = 0,
                 period: float = HEARTBEAT_PERIOD) -> None:
        self.service = service
        self.period = period  # [s]
        self._priority = priority
        self._pulses: list[Pulse] = []
        self._pub = session.declare_publisher(keys.heartbeat(service), express=True)
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name=f"{service.value}-heartbeat", daemon=True)

    def pulse(self, name: str, deadline: float) -> Pulse:
        """A new loop to watch: ``name`` says which in the stuck line, e.g. "the servo loop" [s]."""
        p = Pulse(name, deadline)
        self._pulses = [*self._pulses, p]  # replaced, never mutated: the thread reads it lock-free
        return p

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)
        try:
            self._pub.undeclare()
        except Exception:
            pass

    def stuck(self, now: float, steady_since: float = -math.inf) -> tuple[str, ...]:
        """A line per pulse silent beyond its deadline, counting only from ``steady_since`` [s]."""
        return tuple(f"{p.name} has not turned for {p.silence(now) * 1e3:.0f} ms (deadline "
                     f"{p.deadline * 1e3:.0f} ms)"
                     for p in self._pulses if now - max(p.at, steady_since) > p.deadline)

    def _run(self) -> None:
        realtime_thread(self._priority, f"{self.service.value} heartbeat")
        seq = 0
        last = steady_since = time.monotonic()
        due = last
        while True:
            due += self.period
            now = time.monotonic()
            if due < now:  # behind: beat now, no burst to catch up
                due = now
            if self._stop.wait(due - now):
                return
            now = time.monotonic()
            if now - last > _SELF_STALL:
                steady_since = now
            last = now
            try:
                beat = alarms.Heartbeat(seq, self.stuck(now, steady_since))
                self._pub.put(codec.encode_message(HEARTBEAT, beat))
            except zenoh.ZError as exc:  # the session is closing
                log.debug("heartbeat not sent: %s", exc)
            except Exception:  # a bug here must not silence the service: say it, beat on
                if seq % 1000 == 0:
                    log.exception("heartbeat %d failed", seq)
            seq = (seq + 1) % (ULONG_MAX + 1)
