"""Every service's heartbeat: ``heartbeat/<service>`` every ``Health.heartbeat_period`` from a thread of its own.

A liveliness token shows connectivity, not health. The heartbeat shows that
the process runs: one stopped with SIGSTOP, or starved of the CPU, falls
silent while its token stays up. It also shows that the process's working
loops turn: each loop takes a :class:`Pulse` and beats it on every turn, and a
loop that has not beaten within its deadline is named in the heartbeat's
``stuck`` lines. :class:`ServiceWatch` is how a watcher judges one service by
its token and its heartbeat, with the bounds of ``timing.Health``: a silence
longer than ``stall_after`` that ends is a *stall* (logged with its length);
one longer than ``hung_after`` is a hung service (a FAULT).

The thread runs at real-time priority where the process may: a heartbeat
that is late because the machine is busy would read as a stall.

A service that shuts down in order calls :meth:`Heartbeat.leave` before it
deletes its token: its last beat says ``leaving``, so its watchers see a
departure, not a loss (no lost or hung FAULT for a launcher that stops).
"""

from __future__ import annotations

import dataclasses
import logging
import math
import os
import threading
import time

import zenoh

from jara_arm.schema import alarms
from jara_arm.schema.alarms import HEARTBEAT
from jara_arm.schema.codes import ULONG_MAX
from jara_arm.schema.keys import ArmKeys, Service

from .entities import Entities
from .realtime import realtime_thread
from .starvation import EVIDENCE_WINDOW, STARVED_MAX, STARVED_SHARE, THIS_HOST, process_sched
from .timing import SAME_HOST, Health
from .wire import Publication

log = logging.getLogger(__name__)

#: After the leaving beat, the token waits this long [s]: the beat (data) and the token's
#: deletion (a declaration) travel apart, and the beat should come first.
LEAVE_GRACE = 0.05


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
                 health: Health = SAME_HOST) -> None:
        self.service = service
        self.health = health
        self.period = health.heartbeat_period  # [s]
        self._priority = priority
        self._pulses: list[Pulse] = []
        self._entities = Entities()
        self._pub = self._entities.enter_context(Publication(session, keys.heartbeat(service)))
        self._stop = threading.Event()
        self._seq = 0
        self._left = False
        self._thread = threading.Thread(target=self._run, name=f"{service.value}-heartbeat", daemon=True)

    def pulse(self, name: str, deadline: float | None = None) -> Pulse:
        """A new loop to watch: ``name`` says which in the stuck line, e.g. "the servo loop";
        ``deadline`` [s] defaults to the hung bound (a loop that long still is hung)."""
        p = Pulse(name, self.health.hung_after if deadline is None else deadline)
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
            self._pub.put_message(HEARTBEAT, alarms.Heartbeat(self._seq, (), True, os.getpid(), THIS_HOST))
        except zenoh.ZError as exc:
            log.debug("leaving beat not sent: %s", exc)
            return
        time.sleep(LEAVE_GRACE)

    def close(self) -> None:
        self._stop_thread()
        self._entities.close()  # idempotent: the framework closes a heartbeat twice

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
        pid = os.getpid()
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
            if now - last > self.health.stall_after:  # this thread itself was held up
                steady_since = now
            last = now
            try:
                beat = alarms.Heartbeat(self._seq, self.stuck(now, steady_since), False, pid, THIS_HOST)
                self._pub.put_message(HEARTBEAT, beat)
            except zenoh.ZError as exc:  # the session is closing
                log.debug("heartbeat not sent: %s", exc)
            except Exception:  # a bug here must not silence the service: say it, beat on
                if self._seq % 1000 == 0:
                    log.exception("heartbeat %d failed", self._seq)
            self._seq = (self._seq + 1) % (ULONG_MAX + 1)


@dataclasses.dataclass
class ServiceWatch:
    """Liveliness and heartbeat of one service, judged with the bounds of ``health``."""

    service: Service
    health: Health = SAME_HOST
    alive: bool = False
    up_at: float = -float("inf")  # [s] monotonic time its token appeared
    heard_at: float = -float("inf")  # [s] monotonic time of its newest heartbeat
    stuck: tuple[str, ...] = ()  # the newest heartbeat's stuck loops
    leaving: bool = False  # its newest heartbeat said it shuts down in order
    stalls: int = 0  # silences longer than health.stall_after that ended (the service beat again)
    pid: int = 0  # its process, if its heartbeat says it runs on this host (starvation.THIS_HOST)
    # During a silence (starvation.py): (time [s], run delay [s]) when it passed stall_after, the
    # newest verdict (time [s], starved, stopped), and whether the starved verdict was logged.
    _base: tuple[float, float] | None = None
    _verdict: tuple[float, bool, bool] | None = None
    _starved_said: bool = False

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

    def heard(self, now: float, stuck: tuple[str, ...] = (), leaving: bool = False, pid: int = 0,
              host: str = "") -> float | None:
        """A heartbeat arrived at ``now`` (from process ``pid`` of ``host``, if it says); returns the
        silence it ended [s] if that was a stall."""
        gap = now - self.heard_at if self.heard_at >= self.up_at else 0.0
        self.heard_at = now
        self.stuck = stuck
        self.leaving = leaving
        self.pid = pid if host and host == THIS_HOST else 0
        self._base = self._verdict = None
        self._starved_said = False
        if gap > self.health.stall_after:
            self.stalls += 1
            return gap
        return None

    def silence(self, now: float) -> float:
        """[s] since the newest heartbeat (or since the token appeared, if later)."""
        return now - max(self.heard_at, self.up_at)

    def limit(self) -> float:
        """[s] the silence that makes it hung: ``hung_after``, or ``first_beat_grace`` while no
        beat came since its token appeared (a service just up, or a watcher just started)."""
        settled = self.heard_at >= self.up_at
        return self.health.hung_after if settled else max(self.health.hung_after, self.health.first_beat_grace)

    def stale(self, now: float) -> bool:
        """Token up, heartbeat silent for longer than :meth:`limit`, and not starved of the CPU on
        the evidence of this host's kernel (``starvation.py``) for less than ``STARVED_MAX``."""
        if not self.alive:
            return False
        silence = self.silence(now)
        if silence <= self.limit():
            if self.pid and silence > self.health.stall_after and self._base is None:
                sched = process_sched(self.pid)
                self._base = (now, sched.run_delay) if sched is not None else None
            return False
        return not self.pid or silence > max(STARVED_MAX, self.limit()) or not self.starved(now)

    def starved(self, now: float) -> bool:
        """During a silence: its process is runnable and waits for a CPU (see ``starvation.py``);
        False if it is stopped, sleeps, is gone or is not on this host."""
        if self._verdict is not None and now - self._verdict[0] < EVIDENCE_WINDOW / 2:
            return self._verdict[1]
        sched = process_sched(self.pid) if self.pid else None
        stopped = sched is not None and sched.stopped
        if sched is None or stopped:
            starved = False
        elif self._base is None:  # the watcher itself missed the start: evidence from now on
            self._base = (now, sched.run_delay)
            starved = True
        else:
            t0, d0 = self._base
            starved = now - t0 < EVIDENCE_WINDOW or sched.run_delay - d0 >= STARVED_SHARE * (now - t0)
        self._verdict = (now, starved, stopped)
        return starved

    def starved_line(self, now: float) -> str | None:
        """Once per silence, the warning that it is judged starved rather than hung; else None."""
        if self._starved_said or self._verdict is None or not self._verdict[1] or self.silence(now) <= self.limit():
            return None
        self._starved_said = True
        waited = ""
        if self._base is not None and (sched := process_sched(self.pid)) is not None:
            waited = f" (its threads waited {(sched.run_delay - self._base[1]) * 1e3:.0f} ms for one since)"
        return (f"the {self.service.value} service has been silent for {self.silence(now) * 1e3:.0f} ms, "
                f"past its hung bound of {self.limit() * 1e3:.0f} ms, but it is starved of the CPU{waited}: "
                f"judged hung only if still silent after {max(STARVED_MAX, self.limit()) * 1e3:.0f} ms")

    def hung(self, now: float) -> bool:
        """Silent (see :meth:`stale`), or a loop of it stuck; never once it said it is leaving."""
        return self.alive and not self.leaving and (bool(self.stuck) or self.stale(now))

    def why_hung(self, now: float) -> str:
        """What makes it hung, for the alarm's description."""
        if self.stuck:
            return "; ".join(self.stuck)
        if self._verdict is not None and self._verdict[2]:
            why = "its process is stopped (SIGSTOP, or held by a debugger)"
        elif self._verdict is not None and self._verdict[1]:
            why = "starved of the CPU all that time"
        elif self.pid:
            why = "its process neither ran nor waited for a CPU"
        else:
            why = "stopped, or starved of the CPU"
        return (f"no heartbeat for {self.silence(now) * 1e3:.0f} ms (bound {self.limit() * 1e3:.0f} ms, "
                f"timing profile {self.health.name}; {why})")

    def stall_line(self, gap: float) -> str:
        """The warning for a stall that ended [s]."""
        return (f"the {self.service.value} service was silent for {gap * 1e3:.0f} ms and is back (stall "
                f"{self.stalls}; warned above {self.health.stall_after * 1e3:.0f} ms, hung above "
                f"{self.health.hung_after * 1e3:.0f} ms)")
