"""Evidence about a silent service on this host: stopped, or starved of the CPU?

A heartbeat that does not come says the process did not run, not why. On the
watcher's own host the kernel says why (``/proc/<pid>/task/*``): a thread in
state ``T`` or ``t`` is stopped (SIGSTOP, a debugger), and a thread's
``schedstat`` counts the time it was runnable but waited for a CPU (its run
delay). :class:`~.heartbeat.ServiceWatch` asks this only during a silence
longer than the stall bound, a few file reads, never per beat.

A service whose threads waited for a CPU for ``STARVED_SHARE`` of its silence
or more is starved, not hung: the machine is busy (docs/timing.md, "Starved or
hung"). It is judged hung once it has been silent for ``STARVED_MAX`` all the
same: a service that long without the CPU is not doing its job.
"""

from __future__ import annotations

import dataclasses
import os
from typing import Final


def _boot_id() -> str:
    try:
        with open("/proc/sys/kernel/random/boot_id", encoding="ascii") as f:
            return f.read().strip()
    except OSError:
        return ""


def _pid_namespace() -> str:
    try:
        return os.readlink("/proc/self/ns/pid")
    except OSError:
        return ""


#: This host's boot id and PID namespace ("" where there is none): a heartbeat that carries it comes
#: from a process whose pid means the same here (containers of one host share the boot id, not the pids).
THIS_HOST: Final[str] = f"{_boot_id()}/{_pid_namespace()}" if _boot_id() and _pid_namespace() else ""

#: Its threads waited for a CPU for at least this share of a silence [-]: starved. A process that
#: sleeps (blocked, deadlocked) waits for none; one starved by a busy machine waits for most of it
#: (with a busy loop on every core and 4 arms: 40-95 %, ``bench/soak.py --hog``).
STARVED_SHARE: Final = 0.25
#: A starved service is judged hung all the same once silent this long [s]: the LAN profile's
#: hung bound, the longest silence the system accepts for any reason.
STARVED_MAX: Final = 5.0
#: The run delay is compared over at least this long [s] before a starved verdict.
EVIDENCE_WINDOW: Final = 0.2


@dataclasses.dataclass(frozen=True)
class ProcessSched:
    """What the kernel says about one process now."""

    stopped: bool  # a thread of it is stopped (SIGSTOP) or stopped by a tracer (a debugger)
    run_delay: float  # [s] its threads' time runnable but waiting for a CPU, summed, since they started


def process_sched(pid: int) -> ProcessSched | None:
    """``pid``'s threads now, or None if it cannot be read (gone, another host's pid, no /proc)."""
    if pid <= 0:
        return None
    stopped = False
    delay_ns = 0
    try:
        tids = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return None
    for tid in tids:
        try:
            with open(f"/proc/{pid}/task/{tid}/stat", encoding="ascii") as f:
                stat = f.read()
            with open(f"/proc/{pid}/task/{tid}/schedstat", encoding="ascii") as f:
                sched = f.read().split()
        except OSError:
            continue  # a thread that ended meanwhile
        state = stat[stat.rfind(")") + 2:stat.rfind(")") + 3]
        stopped |= state in ("T", "t")
        if len(sched) >= 2 and sched[1].isdigit():
            delay_ns += int(sched[1])
    return ProcessSched(stopped, delay_ns * 1e-9)
