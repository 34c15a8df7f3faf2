"""One real-time thread that runs the cycle of every arm of the servo process, every period.

One thread for several arms, rather than one each: a 1 kHz Python loop spends
most of its time waking up and warming its caches, so four arms cost a
fraction of four threads (``docs/timing.md``, ``bench/soak.py``). The arms run
in turn, in the order given, each in its own PyBullet world.

The clock sleeps to each deadline; behind by more than a period it runs the
cycles back to back (catching up), behind by more than ``RESYNC_AFTER`` it
restarts its schedule. An arm that waits for a late command mid-motion (its
simulated time stands still) restarts the schedule too, so that it does not
then consume its commands faster than real time. While every arm rests, it
wakes once per ``REST_BATCH`` periods and runs the cycles due back to back; a
call to an arm, or the first cycle with work, returns it to one per period.

A cycle that raises ends the thread (:attr:`failed`); the service then exits
and the launcher restarts it, every arm of it.
"""

from __future__ import annotations

import collections
import gc
import logging
import sys
import threading
import time
from collections.abc import Sequence

from jara_arm.services.runtime.realtime import realtime_thread
from jara_arm.services.runtime.threads import LoopThread
from jara_arm.services.runtime.timing import RESYNC_AFTER

from .loop import ServoLoop

log = logging.getLogger(__name__)

#: SCHED_FIFO priority of the clock thread (Linux 1..99; 0 = normal scheduling).
DEFAULT_RT_PRIORITY = 40
#: Other threads of the servo process hand the GIL back to the clock this often [s]: the
#: longest the clock waits for it. 10 clients querying at 900/s (``bench/load.py``): 1.46 %
#: late cycles with 0.5 ms, 0.40 % with 0.1 ms.
GIL_SWITCH_INTERVAL = 0.0001


#: While every arm of the clock rests (:attr:`ServoLoop.resting`: its world held, nothing commanded,
#: buffered or called), the clock wakes once per this many periods and runs the cycles due back to back,
#: each stamped and published as always [cycles]. At 1 kHz the wake-up costs more than the cycle: an
#: idle iiwa's servo took 0.084 of a core waking every period, and 0.035 waking every 10 (2026-12-05).
#: A call to the loop (servoON, a motion's hand-over, pause, ...) wakes the clock at once; what arrives
#: over Zenoh at rest (a low-level client's first command, an e-stop) is taken within this many periods,
#: while nothing moves. The first cycle with work in it ends the batch: from there, one cycle per period.
REST_BATCH = 10


#: A garbage collection in the servo process longer than this is logged [s]: it holds the clock.
GC_PAUSE_LOGGED = 0.002


class GcWatch:
    """Times the process's garbage collections (``gc.callbacks``) and keeps the long ones for :meth:`say`.

    The callback itself never logs: a collection starts at any allocation, also inside a log handler
    that holds its own lock, and logging from there again deadlocked that thread (a two-arm servo's
    main thread, in ``Event.set`` of the Zenoh log handler, never declared its tokens: 3 of about 100
    two-arm starts over two sessions, 2026-11-27)."""

    def __init__(self) -> None:
        self._start = 0.0
        self.long: collections.deque[tuple[int, int, float]] = collections.deque(maxlen=16)

    def __call__(self, phase: str, info: dict[str, int]) -> None:
        if phase == "start":
            self._start = time.perf_counter()
            return
        pause = time.perf_counter() - self._start
        if pause > GC_PAUSE_LOGGED:
            self.long.append((info.get("generation", -1), info.get("collected", 0), pause))

    def say(self) -> None:
        """Log the long collections kept since the last call (from a thread of the caller's, not the callback)."""
        while self.long:
            generation, collected, pause = self.long.popleft()
            log.warning("garbage collection (generation %d, %d objects collected) held the servo "
                        "process %.1f ms", generation, collected, pause * 1e3)


class ServoClockError(ValueError):
    """The arms given cannot share one clock."""


class ServoClock:
    """Runs ``loops`` every period on one thread (see the module docstring)."""

    def __init__(self, loops: Sequence[ServoLoop], realtime_priority: int = DEFAULT_RT_PRIORITY) -> None:
        if not loops:
            raise ServoClockError("a servo clock needs at least one arm")
        periods = {loop.model.cmd_cycle_ms for loop in loops}
        if len(periods) != 1:
            raise ServoClockError("arms with different cmdCycle cannot share a servo process: "
                                  + ", ".join(f"{loop.arm} {loop.model.cmd_cycle_ms} ms" for loop in loops))
        self.loops = tuple(loops)
        self.period_ns = periods.pop() * 1_000_000
        self._rt_priority = realtime_priority
        self.failed: BaseException | None = None
        self._thread = LoopThread(self._run, "servo-clock", join_within=5.0)
        self._gc = GcWatch()
        gc.callbacks.append(self._gc)
        self._wake = threading.Event()  # set by a call to a resting loop: its cycle runs now, not at the batch's end
        for loop in self.loops:
            loop.wake = self._wake.set

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._thread.stop()

    @property
    def alive(self) -> bool:
        return self._thread.alive

    def _run(self, stop: threading.Event) -> None:
        realtime_thread(self._rt_priority, "servo clock")
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        period = self.period_ns
        next_ns = time.monotonic_ns()
        wall_offset = time.time_ns() - next_ns
        for i, loop in enumerate(self.loops):
            loop.begin(next_ns + wall_offset, i / len(self.loops))
        resting = False
        batch_end = -1  # [ns] a rest batch's wake: the cycles due by then run back to back (REST_BATCH)
        try:
            while not stop.is_set():
                now = time.monotonic_ns()
                if next_ns > batch_end:
                    wake = next_ns + (REST_BATCH - 1) * period if resting else next_ns
                    if now < wake:
                        if resting:
                            self._wake.wait((wake - now) * 1e-9)
                        else:
                            time.sleep((wake - now) * 1e-9)
                        now = time.monotonic_ns()
                    if resting:
                        self._wake.clear()  # before the cycles: a call from now on wakes the next batch
                        if now < next_ns:  # woken by a call within a period: a cycle never runs before its time
                            time.sleep((next_ns - now) * 1e-9)
                            now = time.monotonic_ns()
                        batch_end = min(now, wake)
                due = max(next_ns, batch_end)  # a batched cycle is late by its batch's wake, not by its deadline
                lateness = now - due
                if lateness > RESYNC_AFTER * 1e9:
                    log.warning("servo clock %.0f ms behind schedule; restarting it", lateness * 1e-6)
                    next_ns = due = now
                    wall_offset = time.time_ns() - now
                behind = lateness > period
                waited = False
                for loop in self.loops:
                    waited |= not loop.tick(next_ns + wall_offset, due, behind)
                if self._gc.long:
                    self._gc.say()
                was_resting, resting = resting, all(loop.resting for loop in self.loops)
                if waited or (was_resting and not resting):
                    # The late commands were not sent yet, not lost: no catching up on them. Work that ends a
                    # rest batch runs from now on, one cycle per period: the batch's rest cycles still due
                    # are not run (their feedback samples, at rest, are not sent).
                    now = time.monotonic_ns()
                    next_ns = now + period
                    wall_offset = time.time_ns() - now
                    batch_end = -1
                else:
                    next_ns += period
        except BaseException as exc:  # surfaced by main(): the service exits and is restarted
            self.failed = exc
            log.exception("servo clock failed")
