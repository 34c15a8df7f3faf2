"""Real-time scheduling (SCHED_FIFO) for the threads that must run within milliseconds.

Needs CAP_SYS_NICE (or an RLIMIT_RTPRIO); without it the threads stay normal
ones and the service says so once. Priorities of this project: servo clock 40 (its
other threads 39), the launcher's router 35, the planner 29 (its planning child
normal); the alarm monitor, the command and the client gateway run under the
normal scheduler (``docs/timing.md``, "Real-time budget": every real-time
thread of the machine shares one budget, and the kernel stops them all once it is spent).
"""

from __future__ import annotations

import ctypes
import logging
import os
import threading

log = logging.getLogger(__name__)


_PR_SET_TIMERSLACK = 29

def realtime_thread(priority: int, what: str) -> bool:
    """The calling thread: 1 us timer slack (sleeps end close to their deadline) and
    SCHED_FIFO at ``priority`` (0: leave the scheduler alone). Returns whether it is real-time."""
    try:
        ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    except (OSError, AttributeError):
        pass
    if priority <= 0:
        return False
    if _set_fifo(0, priority):
        log.info("%s runs with SCHED_FIFO priority %d", what, priority)
        return True
    log.warning("%s without real-time priority (no permission?): expect more jitter", what)
    return False


def _set_fifo(tid: int, priority: int) -> bool:
    try:
        os.sched_setscheduler(tid, os.SCHED_FIFO, os.sched_param(priority))
        return True
    except (OSError, AttributeError):
        return False


def realtime_process(priority: int, what: str, *, skip_caller: bool = False) -> int:
    """SCHED_FIFO at ``priority`` for every thread of this process under the normal scheduler.

    Zenoh's threads (that receive and send) included: a safety path is only as
    fast as its slowest thread. Call it once every thread is started. Returns
    how many threads were set; 0 with ``priority`` 0 or without permission.
    """
    if priority <= 0:
        return 0
    try:
        tids = [int(t) for t in os.listdir("/proc/self/task")]
    except OSError:  # not Linux
        return 0
    if skip_caller:  # e.g. a thread that starts child processes: they would inherit SCHED_FIFO
        tids = [t for t in tids if t != threading.get_native_id()]
    tried = count = 0
    for tid in tids:
        try:
            if os.sched_getscheduler(tid) != os.SCHED_OTHER:
                continue  # set before (e.g. the service's own call in its start): nothing to say again
            tried += 1
            count += _set_fifo(tid, priority)
        except OSError:  # the thread ended meanwhile
            continue
    if count:
        log.info("%s: %d threads run with SCHED_FIFO priority %d", what, count, priority)
    elif tried:
        log.warning("%s without real-time priority (no permission?): expect more latency", what)
    return count
