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
departure, not a loss (no lost or hung FAULT for a launcher that stops);
``presence.py`` takes the two in the order they arrived.
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
from .starvation import EVIDENCE_WINDOW, STARVED_MAX, THIS_HOST, ThreadSched, judge, stall_cause, thread_sched
from .threads import LoopThread
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
        self._seq = 0
        self._left = False
        self._thread = LoopThread(self._run, f"{service.value}-heartbeat", join_within=1.0)

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
        self._thread.stop()
        if self._left:
            return
        self._left = True
        try:
            self._pub.put_message(HEARTBEAT, alarms.Heartbeat(self._seq, (), True, os.getpid(), THIS_HOST,
                                                              self._thread.native_id))
        except zenoh.ZError as exc:
            log.debug("leaving beat not sent: %s", exc)
            return
        time.sleep(LEAVE_GRACE)

    def close(self) -> None:
        self._thread.stop()
        self._entities.close()  # idempotent: the framework closes a heartbeat twice

    def stuck(self, now: float, steady_since: float = -math.inf) -> tuple[str, ...]:
        """A line per pulse silent beyond its deadline, counting only from ``steady_since`` [s]."""
        return tuple(f"{p.name} has not turned for {p.silence(now) * 1e3:.0f} ms (deadline "
                     f"{p.deadline * 1e3:.0f} ms)"
                     for p in self._pulses if now - max(p.at, steady_since) > p.deadline)

    def _run(self, stop: threading.Event) -> None:
        realtime_thread(self._priority, f"{self.service.value} heartbeat")
        pid, tid = os.getpid(), threading.get_native_id()
        last = steady_since = time.monotonic()
        due = last
        while True:
            due += self.period
            now = time.monotonic()
            if due < now:  # behind: beat now, no burst to catch up
                due = now
            if stop.wait(due - now):
                return
            now = time.monotonic()
            if now - last > self.health.stall_after:  # this thread itself was held up
                steady_since = now
            last = now
            try:
                beat = alarms.Heartbeat(self._seq, self.stuck(now, steady_since), False, pid, THIS_HOST, tid)
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
    pid: int = 0  # its process and heartbeat thread, if its heartbeat says it runs on this host
    tid: int = 0
    # During a silence (starvation.py): the heartbeat thread when the silence passed _evidence_after()
    # (time [s], its counters), the newest verdict (time [s], verdict: "hung", "starved", "beating"
    # or "stopped") and whether a verdict other than hung was logged.
    _base: tuple[float, ThreadSched] | None = None
    _verdict: tuple[float, str] | None = None
    _said: bool = False
    _stall_cause: str = ""  # of the newest stall that ended (stall_line)

    def token(self, up: bool, now: float) -> bool:
        """A liveliness change; True if the service was alive and is now gone (``leaving`` says
        whether it announced that)."""
        was = self.alive
        self.alive = up
        if up and not was:
            self.up_at = now
            self.stuck = ()
            self.leaving = False
            self.pid = self.tid = 0  # a new process: evidence from its own first beat on
            self._base = self._verdict = None
            self._said = False
        return was and not up

    def heard(self, now: float, stuck: tuple[str, ...] = (), leaving: bool = False, pid: int = 0,
              host: str = "", tid: int = 0) -> float | None:
        """A heartbeat arrived at ``now`` (from thread ``tid`` of process ``pid`` of ``host``, if it
        says); returns the silence it ended [s] if that was a stall."""
        gap = now - self.heard_at if self.heard_at >= self.up_at else 0.0
        self._stall_cause = ""
        if gap > self.health.stall_after and self._base is not None and self.pid:
            sched = thread_sched(self.pid, self.tid)
            t0, before = self._base
            self._stall_cause = stall_cause(before, sched, now - t0) if sched is not None else ""
        self.heard_at = now
        self.stuck = stuck
        self.leaving = leaving
        local = bool(host) and host == THIS_HOST and pid > 0 and tid > 0
        self.pid, self.tid = (pid, tid) if local else (0, 0)
        self._base = self._verdict = None
        self._said = False
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
        """Token up, heartbeat silent for longer than :meth:`limit`, unless this host's kernel shows it
        starved or beating unheard (``starvation.py``) and the silence is shorter than ``STARVED_MAX``."""
        if not self.alive:
            return False
        silence = self.silence(now)
        if silence <= self.limit():
            if self.pid and silence > self._evidence_after() and self._base is None:
                sched = thread_sched(self.pid, self.tid)
                self._base = (now, sched) if sched is not None else None
            return False
        return not self.pid or silence > self._starved_limit() or self.verdict(now) in ("hung", "stopped")

    def _evidence_after(self) -> float:
        """[s] the silence from which the heartbeat thread's counters are kept as evidence: halfway from the
        heartbeat period (a beat a little late) to the stall bound, so that a stall that ends has some."""
        return (self.health.heartbeat_period + self.health.stall_after) / 2

    def _starved_limit(self) -> float:
        """[s] the silence that makes it hung even when starved or beating unheard."""
        return max(STARVED_MAX, self.limit())

    def verdict(self, now: float) -> str:
        """During a silence: "stopped", "starved", "beating" (unheard) or "hung" (see ``starvation.py``)."""
        if self._verdict is not None and now - self._verdict[0] < EVIDENCE_WINDOW / 2:
            return self._verdict[1]
        sched = thread_sched(self.pid, self.tid) if self.pid else None
        if sched is None:
            verdict = "hung"  # gone, or nothing to read: no evidence
        else:
            if self._base is None:  # the watcher itself missed the start: evidence from now on
                self._base = (now, sched)
            t0, before = self._base
            verdict = judge(before, sched, now - t0, self.health.heartbeat_period)
        self._verdict = (now, verdict)
        return verdict

    def evidence_line(self, now: float) -> str | None:
        """Once per silence past the hung bound judged starved or beating unheard, its warning; else None."""
        if self._said or self._verdict is None or self._verdict[1] not in ("starved", "beating") \
                or self.silence(now) <= self.limit():
            return None
        self._said = True
        why = ("it is starved of the CPU (its heartbeat thread waits for one)" if self._verdict[1] == "starved"
               else "it beats (its heartbeat thread runs), and its beats do not arrive: the link or this "
                    "watcher's reception stalls")
        return (f"the {self.service.value} service has been silent for {self.silence(now) * 1e3:.0f} ms, past "
                f"its hung bound of {self.limit() * 1e3:.0f} ms, but {why}: judged hung only if still silent "
                f"after {self._starved_limit() * 1e3:.0f} ms")

    def hung(self, now: float) -> bool:
        """Silent (see :meth:`stale`), or a loop of it stuck; never once it said it is leaving."""
        return self.alive and not self.leaving and (bool(self.stuck) or self.stale(now))

    def why_hung(self, now: float) -> str:
        """What makes it hung, for the alarm's description."""
        if self.stuck:
            return "; ".join(self.stuck)
        verdict = self._verdict[1] if self._verdict is not None else None
        why = {"stopped": "its process is stopped (SIGSTOP, or held by a debugger)",
               "starved": "starved of the CPU all that time",
               "beating": "it beat all that time, and its beats did not arrive",
               "hung": "its heartbeat thread neither ran nor waited for a CPU, or ran without beating"}.get(verdict or "", "")
        if not self.pid or not why:
            why = "stopped, or starved of the CPU"
        return (f"no heartbeat for {self.silence(now) * 1e3:.0f} ms (bound {self.limit() * 1e3:.0f} ms, "
                f"timing profile {self.health.name}; {why})")

    def stall_line(self, gap: float) -> str:
        """The warning for a stall that ended [s], with its cause where this host's kernel kept evidence of it
        (a service on this host, the stall watched from ``_evidence_after()``)."""
        cause = f"; {self._stall_cause}" if self._stall_cause else ""
        return (f"the {self.service.value} service was silent for {gap * 1e3:.0f} ms and is back (stall "
                f"{self.stalls}; warned above {self.health.stall_after * 1e3:.0f} ms, hung above "
                f"{self.health.hung_after * 1e3:.0f} ms{cause})")
