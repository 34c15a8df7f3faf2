"""Following accepted motions on ``Planner/progress``: :class:`Motion`, the handle a move returns.

Motions complete strictly in the order they were accepted, and a discard (``stop``, an alarm, a lost
service) takes the running motion and every one queued behind it. So the fate of a motion is told by
the first progress report without it: discarded if that report's ``lastDiscarded`` reached it, done if
its ``lastDone`` did. A restarted planner (a newer ``started``) lost its queue: every motion still
followed was discarded. How far the running one has come is the servo's own count of its samples passed
(``runningShare``), never a clock of the client's.
"""

from __future__ import annotations

import collections
import enum
import threading
import time
from collections.abc import Callable

import zenoh

from jara_arm.schema.keys import ArmKeys
from jara_arm.schema.motion import refreshes
from jara_arm.schema.planner import PLANNER_PROGRESS, PlannerProgress, is_newer
from jara_arm.services.runtime.wire import decode_sample

from .errors import MotionFailed, NoAnswer

#: Reports held while the tracker's thread is busy: the planner publishes on every change and every 0.1 s.
_FIFO = 4096


class Fate(enum.Enum):
    """Where a motion is: ``waiting`` (accepted, no report names it yet), ``queued``, ``running``, and at
    its end ``done`` or ``discarded``."""

    WAITING = "waiting"
    QUEUED = "queued"
    RUNNING = "running"
    DONE = "done"
    DISCARDED = "discarded"

    @property
    def ended(self) -> bool:
        return self in (Fate.DONE, Fate.DISCARDED)


class ProgressBook:
    """The fates of the motions followed, from the ``Planner/progress`` reports :meth:`offer` is given (no I/O:
    :class:`Tracker` feeds it from the network; a test by hand), and the share of its samples each one had
    passed when last reported running. Thread-safe.

    A motion is judged on each change of state the reports show (its end is read from the counters
    ``lastDone``/``lastDiscarded`` as they move). The last ``HISTORY`` changes are kept, and a motion
    followed after its reports came (a move's reply arrives after the first report naming it) is judged
    on them too."""

    #: The changes of state kept for a motion followed late: at 10 or more reports a second, seconds of them.
    HISTORY = 256

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._last: PlannerProgress | None = None
        self._changes: collections.deque[tuple[PlannerProgress | None, PlannerProgress]] = collections.deque(
            maxlen=self.HISTORY)
        self._fates: dict[int, Fate] = {}
        self._shares: dict[int, float] = {}  # [-] per motion followed: its runningShare when last reported running

    def follow(self, motion: int) -> None:
        with self._lock:
            if motion in self._fates:
                return
            fate = Fate.WAITING
            for old, new in self._changes:
                fate = _judged(motion, fate, old, new)
                if fate is Fate.RUNNING and new.running == motion:
                    self._shares[motion] = min(1.0, max(0.0, new.runningShare))
            self._fates[motion] = fate
            if self._last is not None:
                self._note_share(self._last)

    def offer(self, report: PlannerProgress) -> None:
        """Take ``report`` if it is the newest yet (or the newest state reported again later)."""
        with self._lock:
            self._offer(report)

    def fate(self, motion: int) -> Fate:
        """Where ``motion`` is now, from every report received so far."""
        with self._lock:
            return self._fates[motion]

    def progress(self, motion: int) -> float:
        """[-] 0 .. 1: 1.0 once ``motion`` is done, else the share it had run when last reported running
        (0.0 before it ran)."""
        with self._lock:
            if self._fates[motion] is Fate.DONE:
                return 1.0
            return self._shares.get(motion, 0.0)

    def newest(self) -> PlannerProgress | None:
        with self._lock:
            return self._last

    def _offer(self, report: PlannerProgress) -> None:
        """(lock held) A newer state goes through :meth:`_take`; the same one reported later (``seq`` does
        not count ``runningShare``) only renews the running motion's share."""
        if is_newer(report, self._last):
            self._take(report)
        elif refreshes(report, self._last):
            self._last = report
            self._note_share(report)

    def _take(self, new: PlannerProgress) -> None:
        old, self._last = self._last, new
        self._changes.append((old, new))
        for motion, fate in self._fates.items():
            self._fates[motion] = _judged(motion, fate, old, new)
        self._note_share(new)

    def _note_share(self, report: PlannerProgress) -> None:
        """Keep the running motion's share if it is followed and not ended (lock held)."""
        motion = report.running
        if motion and self._fates.get(motion) is Fate.RUNNING:
            self._shares[motion] = min(1.0, max(0.0, report.runningShare))

    def wait(self, motion: int, timeout: float | None) -> Fate:
        """Until ``motion`` has ended or ``timeout`` [s] (None: no end) passed; its fate then."""
        deadline = None if timeout is None else time.monotonic() + timeout
        while True:
            fate = self.fate(motion)
            if fate.ended:
                return fate
            if deadline is not None and time.monotonic() >= deadline:
                return fate
            time.sleep(0.005)  # the reports come in a channel: a short poll, no callback work


def _judged(motion: int, fate: Fate, old: PlannerProgress | None, new: PlannerProgress) -> Fate:
    """``motion``'s fate after the change of state from ``old`` to ``new`` (``fate``: before it)."""
    if fate.ended:
        return fate
    if old is not None and new.started != old.started and fate is not Fate.WAITING:
        return Fate.DISCARDED  # a new planner: what the one before had queued is gone
    if new.running == motion:
        return Fate.RUNNING
    if motion in new.queued:
        return Fate.QUEUED
    if motion > max((new.running, new.lastDone, new.lastDiscarded, *new.queued), default=0):
        return fate  # accepted, not reported yet
    if new.lastDiscarded >= motion and (old is None or old.lastDiscarded < motion):
        return Fate.DISCARDED
    if new.lastDone >= motion:
        return Fate.DONE
    return Fate.DISCARDED


class Tracker(ProgressBook):
    """The arm's ``Planner/progress``, taken by a thread of its own as it comes; the fates of the motions
    handed out as :class:`Motion`. Thread-safe.

    The thread keeps the channel empty: a full ``FifoChannel`` blocks the session's own thread, and with it
    every reply to this client (an arm left open, not moving, stopped answering after 4,096 reports: 7 min)."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys) -> None:
        super().__init__()
        self._sub = session.declare_subscriber(keys.planner_progress, zenoh.handlers.FifoChannel(_FIFO))
        self._thread = threading.Thread(target=self._take_reports, name=f"progress-{keys.arm}", daemon=True)
        self._thread.start()

    def close(self) -> None:
        self._sub.undeclare()  # ends the thread's iteration
        self._thread.join(timeout=2.0)

    def _take_reports(self) -> None:
        try:
            for sample in self._sub:
                try:
                    report = decode_sample(PLANNER_PROGRESS, sample)
                except Exception:  # a malformed report says nothing about our motions
                    continue
                self.offer(report)
        except Exception:  # the subscriber undeclared, the session closed: nothing more comes
            return


class Motion:
    """An accepted motion: :meth:`wait` for its end, :attr:`fate`, :attr:`progress` and :attr:`done` meanwhile."""

    def __init__(self, tracker: ProgressBook, motion: int, op: str, explain: Callable[[], tuple[str, ...]]) -> None:
        """``explain``: the arm's active alarms as text, asked when the motion turns out discarded."""
        self.id = motion
        self.op = op
        self._tracker = tracker
        self._explain = explain
        tracker.follow(motion)

    @property
    def fate(self) -> Fate:
        return self._tracker.fate(self.id)

    @property
    def progress(self) -> float:
        """[-] 0.0 .. 1.0, the share of the motion done, as the servo's interpolator reports it (at least every
        0.1 s, relayed on ``Planner/progress``): 0.0 while waiting or queued, while running the share of its
        samples passed (of its planned time, not of its length: a move's slow start and end cover less path
        per sample), 1.0 once done. Paused (its fate is queued again) or discarded (a stop, an alarm), it
        stays at the share it had reached when last reported running."""
        return self._tracker.progress(self.id)

    @property
    def done(self) -> bool:
        """It reached its end (False while it runs, and when it was discarded)."""
        return self.fate is Fate.DONE

    def wait(self, timeout: float | None = None) -> None:
        """Block until the motion reached its end; MotionFailed (with the active alarms) if it was discarded,
        NoAnswer if ``timeout`` [s] passed first."""
        fate = self._tracker.wait(self.id, timeout)
        if fate is Fate.DONE:
            return
        if fate is Fate.DISCARDED:
            alarms = self._explain()
            raise MotionFailed(f"motion {self.id} ({self.op}) was discarded before its end"
                               + (f": {'; '.join(alarms)}" if alarms else " (a stop, or a lost service)"),
                               self.id, alarms)
        raise NoAnswer(f"motion {self.id} ({self.op}) is still {fate.value} after {timeout:g} s")

    def __repr__(self) -> str:
        return f"Motion({self.id}, {self.op}, {self.fate.value})"


__all__ = ["Fate", "Motion", "ProgressBook", "Tracker"]
