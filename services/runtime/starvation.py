"""Evidence about a silent service on this host: stopped, asleep, starved, or beating unheard?

A heartbeat that does not come says that it did not arrive, not why. On the
watcher's own host the kernel says why (``/proc/<pid>/task/<tid>``): a thread
in state ``T`` or ``t`` is stopped (SIGSTOP, a debugger); the heartbeat
thread's ``schedstat`` counts the time it was runnable but waited for a CPU
(its run delay) and how often it was given one. :class:`~.heartbeat.ServiceWatch`
asks this only during a silence longer than halfway from the heartbeat period
to the stall bound, a few file reads, never per beat; a stall that ends is
logged with what its process waited for a CPU meanwhile (:func:`stall_cause`).

* The heartbeat thread waited for a CPU for ``STARVED_SHARE`` of the silence
  or more: the service is *starved*, not hung (the machine is busy).
* It ran at least every other heartbeat period: the service *beats*, and its
  beats do not arrive (the link or the watcher's own reception stalls).
* Neither, but the process's threads together waited for a CPU for
  ``STARVED_SHARE`` of the silence: *starved* too (the heartbeat thread sleeps
  on a GIL whose holder waits for a CPU; it wakes every 5 ms to ask for it).
* None of these (every thread sleeps: blocked, deadlocked), or a thread is
  stopped: *hung*.

Starved or beating unheard, it is judged hung all the same once silent for
``STARVED_MAX``: a service that long out of sight is not doing its job
(docs/timing.md, "Starved or hung").
"""

from __future__ import annotations

import dataclasses
import os
from typing import Final

from .timing import LAN


def _read(path: str) -> str:
    try:
        with open(path, encoding="ascii", errors="replace") as f:  # a thread's name may be anything
            return f.read().strip()
    except OSError:
        return ""


def _pid_namespace() -> str:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return ""


def _this_host() -> str:
    boot, ns = _read("/proc/sys/kernel/random/boot_id"), _pid_namespace()
    return f"{boot}/{ns}" if boot and ns else ""


#: This host's boot id and PID namespace ("" where there is none): a heartbeat that carries it comes
#: from a process whose ids mean the same here (containers of one host share the boot id, not the pids).
THIS_HOST: Final[str] = _this_host()

#: The heartbeat thread waited for a CPU for at least this share of a silence [-]: starved. A thread
#: that sleeps between beats waits for almost none (it runs 10 times a second for microseconds); one
#: starved by a busy machine waits for most of it (each of three busy processes on one core: 67 %).
STARVED_SHARE: Final = 0.25
#: ... or it was given a CPU at least this share of the heartbeat periods of the silence [-]: it beats.
BEATING_SHARE: Final = 0.5
#: ... but not more than this many times per period [-]: a thread woken 200 times a second is not
#: beating but asking for a GIL that a hung thread holds (CPython asks again every 5 ms).
BEATING_MAX: Final = 4.0
#: Starved or beating unheard, a service is judged hung all the same once silent this long [s]: the
#: LAN profile's hung bound, the longest silence the system accepts for any reason.
STARVED_MAX: Final = LAN.hung_after
#: The counters are compared over at least this long [s] before a verdict other than hung.
EVIDENCE_WINDOW: Final = 0.2


@dataclasses.dataclass(frozen=True)
class ThreadSched:
    """What the kernel says about a service's heartbeat thread now."""

    stopped: bool  # a thread of its process is stopped (SIGSTOP) or stopped by a tracer (a debugger)
    run_delay: float  # [s] the thread's time runnable but waiting for a CPU, since it started
    runs: int  # times the thread was given a CPU, since it started
    process_run_delay: float  # [s] the same for every thread of its process, summed


def thread_sched(pid: int, tid: int) -> ThreadSched | None:
    """Heartbeat thread ``tid`` of process ``pid`` now, or None if it cannot be read (gone, another
    host's ids, no /proc)."""
    if pid <= 0 or tid <= 0:
        return None
    sched = _read(f"/proc/{pid}/task/{tid}/schedstat").split()
    if len(sched) < 3 or not (sched[1].isdigit() and sched[2].isdigit()):
        return None
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    stopped = False
    delay_ns = 0
    for t in tids:
        stat = _read(f"/proc/{pid}/task/{t}/stat")  # "" for a thread that ended meanwhile
        end = stat.rfind(")")
        stopped |= end > 0 and stat[end + 2:end + 3] in ("T", "t")
        other = _read(f"/proc/{pid}/task/{t}/schedstat").split()
        if len(other) >= 2 and other[1].isdigit():
            delay_ns += int(other[1])
    return ThreadSched(stopped, int(sched[1]) * 1e-9, int(sched[2]), delay_ns * 1e-9)


def judge(before: ThreadSched, now: ThreadSched, elapsed: float, period: float) -> str:
    """The verdict on a silent service from its heartbeat thread ``before`` and ``now``, ``elapsed`` [s]
    apart (its heartbeat ``period`` [s]): "stopped", "starved", "beating" (unheard) or "hung"."""
    if now.stopped:
        return "stopped"
    if elapsed < EVIDENCE_WINDOW:
        return "starved"  # too short to tell: the benefit of the doubt, for EVIDENCE_WINDOW
    if now.run_delay - before.run_delay >= STARVED_SHARE * elapsed:
        return "starved"
    if BEATING_SHARE * elapsed / period <= now.runs - before.runs <= BEATING_MAX * elapsed / period:
        return "beating"
    if now.process_run_delay - before.process_run_delay >= STARVED_SHARE * elapsed:
        return "starved"  # the heartbeat thread waits for a GIL whose holder waits for a CPU
    return "hung"


#: A stall's cause is told from at least this much of it [s]: less says nothing.
STALL_EVIDENCE_MIN: Final = 0.05


def stall_cause(before: ThreadSched, now: ThreadSched, elapsed: float) -> str:
    """Why a service was silent for a while and is back, from its heartbeat thread ``before`` and ``now``,
    ``elapsed`` [s] apart (the end of the silence): what a stall warning adds, so that a user reads whether
    the machine was busy (starved of the CPU) or the service itself stood still."""
    if now.stopped or before.stopped:
        return "its process was stopped (SIGSTOP, or held by a debugger)"
    if elapsed < STALL_EVIDENCE_MIN:
        return "cause not measured"
    waited = max(now.run_delay - before.run_delay, now.process_run_delay - before.process_run_delay)
    seen = f"its threads waited for a CPU {waited * 1e3:.0f} ms in all over the last {elapsed * 1e3:.0f} ms of it"
    if waited >= STARVED_SHARE * elapsed:
        return f"starved of the CPU: {seen}"
    return f"not starved of the CPU: {seen}"
