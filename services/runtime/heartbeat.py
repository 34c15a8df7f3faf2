"""Every service's heartbeat: ``heartbeat/<service>`` every ``HEARTBEAT_PERIOD`` from a thread of its own.

A liveliness token shows connectivity, not health. The heartbeat shows that
the process runs: one stopped with SIGSTOP, or starved of the CPU, falls
silent within a few periods while its token stays up. It also shows that the
process's working loops turn: each loop takes a :class:`Pulse` and beats it
on every turn, and a loop that has not beaten within its deadline is named in
the heartbeat's ``stuck`` lines. The alarm monitor raises the service's hung
FAULT (0x410-0x412) on either; :class:`ServiceWatch` is how a watcher judges
one service by its liveliness token and its heartbeat.

The thread runs at real-time priority where the process may: a heartbeat
that is late because the machine is busy would read as a hung service.

A service that shuts down in order calls :meth:`Heartbeat.leave` before it
deletes its token: its last beat says ``leaving``, so its watchers see a
departure, not a loss (no lost or hung FAULT for a launcher that stops).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Sequence

import zenoh

from jara_arm.schema import codec
from jara_arm.schema import alarms
from jara_arm.schema.alarms import HEARTBEAT, HEARTBEAT_PERIOD
from jara_arm.schema.codes import ULONG_MAX
from jara_arm.schema.keys import ArmKeys, Service

from .realtime import realtime_thread

log = logging.getLogger(__name__)

#: A service whose heartbeat has been silent this long while its token is up hangs [s]:
#: six heartbeat periods, so that detection stays within 50 ms of the cause (at most
#: 30 ms + one monitor poll + the transport) while five lost beats in a row are tolerated.
HUNG_AFTER = 0.03
#: ... provided another service's heartbeat arrived this recently [s] (three periods).
CORROBORATE = 0.015
#: Every heartbeat silent at once: each service hangs after this long [s].
ALL_SILENT_AFTER = 0.5

#: After the leaving beat, the token waits this long [s]: the beat (data) and the token's
#: deletion (a declaration) travel apart, and the beat should come first.
LEAVE_GRACE = 4 * HEARTBEAT_PERIOD

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
        self._seq = 0
        self._left = False
        self._thread = threading.Thread(target=self._run, name=f"{service.value}-heartbeat", daemon=True)

    def pulse(self, name: str, deadline: float) -> Pulse:
        """A new loop to watch: ``name`` says which in the stuck line, e.g. "the servo loop" [s]."""
        p = Pulse(name, deadline)
        self._pulses = [*self._pulses, p]  # replaced, never mutated: the thread reads it lock-free
        return p

    def start(self) -> None:
        self._thread.start()

    def leave(self) -> None:
        """Beat no more, send the last beat (``leaving``) and give it a head start on the token."""
        self._stop_thread()
        if self._left:
            return
        self._left = True
        try:
            self._pub.put(codec.encode_message(HEARTBEAT, alarms.Heartbeat(self._seq, (), leaving=True)))
        except zenoh.ZError as exc:
            log.debug("leaving beat not sent: %s", exc)
            return
        time.sleep(LEAVE_GRACE)

    def close(self) -> None:
        self._stop_thread()
        try:
            self._pub.undeclare()
        except Exception:
            pass

    def _stop_thread(self) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=1.0)

    def stuck(self, now: float, steady_since: float = -math.inf) -> tuple[str, ...]:
        """A line per pulse silent beyond its deadline, counting only from ``steady_since`` [s]."""
        return tuple(f"{p.name} has not turned for {p.silence(now) * 1e3:.0f} ms (deadline "
                     f"{p.deadline * 1e3:.0f} ms)"
                     for p in self._pulses if now - max(p.at, steady_since) > p.deadline)

    def _run(self) -> None:
        realtime_thread(self._priority, f"{self.service.value} heartbeat")
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
                beat = alarms.Heartbeat(self._seq, self.stuck(now, steady_since))
                self._pub.put(codec.encode_message(HEARTBEAT, beat))
            except zenoh.ZError as exc:  # the session is closing
                log.debug("heartbeat not sent: %s", exc)
            except Exception:  # a bug here must not silence the service: say it, beat on
                if self._seq % 1000 == 0:
                    log.exception("heartbeat %d failed", self._seq)
            self._seq = (self._seq + 1) % (ULONG_MAX + 1)


@dataclasses.dataclass
class ServiceWatch:
    """Liveliness and heartbeat of one service that is needed to move the arm."""

    service: Service
    stale_after: float = HUNG_AFTER  # [s]
    alive: bool = False
    up_at: float = -float("inf")  # [s] monotonic time its token appeared
    heard_at: float = -float("inf")  # [s] monotonic time of its newest heartbeat
    stuck: tuple[str, ...] = ()  # the newest heartbeat's stuck loops
    leaving: bool = False  # its newest heartbeat said it shuts down in order

    def token(self, up: bool, now: float) -> bool:
        """A liveliness change; True if the service was alive and is now gone (``leaving`` says
        whether it announced that)."""
        was = self.alive
        self.alive = up
        if up and not was:
            self.up_at = now
            self.stuck = ()
            self.leaving = False
        return was and not up

    def heard(self, now: float, stuck: tuple[str, ...] = (), leaving: bool = False) -> None:
        self.heard_at = now
        self.stuck = stuck
        self.leaving = leaving

    def silence(self, now: float) -> float:
        """[s] since the newest heartbeat (or since the token appeared, if later)."""
        return now - max(self.heard_at, self.up_at)

    def stale(self, now: float, corroborated: bool = True) -> bool:
        """Token up, heartbeat silent for longer than ``stale_after``; ``ALL_SILENT_AFTER`` if
        nothing shows that the heartbeat could have come, or none came since the token appeared
        (a watcher that just started, or subscriptions still settling through the router, hear
        the services' first beats at different times)."""
        settled = corroborated and self.heard_at >= self.up_at
        limit = self.stale_after if settled else max(self.stale_after, ALL_SILENT_AFTER)
        return self.alive and self.silence(now) > limit

    def hung(self, now: float, corroborated: bool = True) -> bool:
        """Silent (see :meth:`stale`), or a loop of it stuck; never once it said it is leaving."""
        return self.alive and not self.leaving and (bool(self.stuck) or self.stale(now, corroborated))


def corroborated(watches: Sequence[ServiceWatch], service: Service, now: float) -> bool:
    """Whether another watched service's heartbeat arrived within ``CORROBORATE`` of ``now``."""
    return any(now - w.heard_at <= CORROBORATE for w in watches if w.service != service and w.alive)
