"""The command service's state bits (``getState``) and their publication on ``JARA_ARM/<arm>/state``.

Sources: the servo's ``Servo/status`` (servo on, moving, alarm), the planner's
``Planner/progress`` (queue, paused) and the command's own acceptances and
control calls. The bits:

* 0x01 servo on: the servo says so, and it spoke within ``stale_after``; a
  silent servo counts as off (a real drive that stops talking faults).
* 0x02 moving: the servo moves, or the queue holds motions (running, waiting or
  paused: the arm is not done with them).
* 0x04 alarm: the alarm monitor's list (``Monitor/alarms``) is not empty, or
  the servo reports an active alarm (its own latches, which it keeps even
  without a monitor).
* 0x08 queue full: the queue holds ``capacity`` motions.
* 0x10 paused.

``paused`` follows the command's own successful pause/resume/stop/abort at
once, and the planner's ``paused`` flag in its first message and whenever it
changes (an edge). After the command's own pause or resume, the planner's flag
counts again only once it agrees (or after ``CONFIRM_TIMEOUT``): a progress
message published before the planner took the call, and delivered after its
reply, must not undo it.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable

from jara_arm.schema.alarms import AlarmList
from jara_arm.schema.codes import StateBit
from jara_arm.schema.messages import ServoStatus
from jara_arm.schema.planner import PlannerProgress
from jara_arm.schema.types import Alarm, LimitValue
from jara_arm.services.runtime.monitor_link import is_newer

from .queue import MotionQueue

log = logging.getLogger(__name__)

#: Without a ``Servo/status`` for this long the servo counts as gone [s]
#: (it publishes every 10 cycles, i.e. at 100 Hz with a 1 ms cycle).
STATUS_STALE_AFTER = 1.0
#: Longest wait for the first Planner/progress of a planner that just appeared [s] (it
#: publishes at 10 Hz at least).
FIRST_PROGRESS_TIMEOUT = 0.5
#: Longest time the planner's ``paused`` flag is ignored after the command's own pause or
#: resume, while it disagrees [s] (the planner publishes on every change, and at 10 Hz).
CONFIRM_TIMEOUT = 0.5


@dataclasses.dataclass(frozen=True)
class StateView:
    """One consistent reading of the state."""

    servo_heard: bool  # a Servo/status arrived within the staleness window
    servo_on: bool
    moving: bool
    alarm: bool
    full: bool
    paused: bool
    queue_length: int
    capacity: int

    @property
    def bits(self) -> int:
        return int((StateBit.SERVO_ON if self.servo_on else 0)
                   | (StateBit.MOVING if self.moving else 0)
                   | (StateBit.ALARM if self.alarm else 0)
                   | (StateBit.BUFFER_FULL if self.full else 0)
                   | (StateBit.PAUSED if self.paused else 0))


#: Called with every new view whose bits or queue length differ from the last one published.
Publish = Callable[[StateView], None]


class StateTracker:
    """Thread-safe state of the command service; publishes on every change."""

    def __init__(self, queue: MotionQueue, publish: Publish,
                 stale_after: float = STATUS_STALE_AFTER) -> None:
        self._queue = queue
        self._publish = publish
        self._stale_after = stale_after
        self._cond = threading.Condition()
        self._status: ServoStatus | None = None
        self._status_at = -float("inf")  # [s] monotonic time of the last Servo/status
        self._status_count = 0
        self._paused = False
        self._planner_paused: bool | None = None  # last value of PlannerProgress.paused
        self._confirm: tuple[bool, float] | None = None  # own pause/resume awaiting the planner's word
        self._published: tuple[int, int] | None = None
        self._planner_up = False  # its liveliness token is there
        self._progress_since_up = False  # a Planner/progress arrived since the token appeared
        self._monitor_list: AlarmList | None = None  # the newest list of the alarm monitor
        self._monitor_alarms: tuple[Alarm, ...] = ()  # its alarms (forgotten by a clear without it)

    # -- reading ------------------------------------------------------------------
    def view(self) -> StateView:
        with self._cond:
            return self._view()

    def _view(self) -> StateView:
        heard = self._status is not None and time.monotonic() - self._status_at <= self._stale_after
        st = self._status if heard else None
        q = self._queue
        return StateView(
            servo_heard=heard,
            servo_on=bool(st and st.servoOn),
            moving=bool(st and st.moving) or len(q) > 0,
            alarm=bool(st and st.alarm) or bool(self._monitor_alarms),
            full=q.full,
            paused=self._paused,
            queue_length=len(q),
            capacity=q.capacity,
        )

    def measured_joints(self) -> tuple[tuple[float, ...], float] | None:
        """The joints [rad or m] of the newest Servo/status and its age [s]; None before the first."""
        st, at = self._status, self._status_at  # one read each: the watcher replaces them
        if st is None or not st.pos:
            return None
        return st.pos, time.monotonic() - at

    # -- inputs -----------------------------------------------------------------------
    def on_status(self, status: ServoStatus) -> None:
        with self._cond:
            self._status = status
            self._status_at = time.monotonic()
            self._status_count += 1
            self._cond.notify_all()
            self._changed()

    def on_progress(self, progress: PlannerProgress) -> None:
        with self._cond:
            self._progress_since_up = True
            self._cond.notify_all()
            self._queue.update(progress)
            if self._confirm is not None:
                paused, since = self._confirm
                if progress.paused != paused and time.monotonic() - since < CONFIRM_TIMEOUT:
                    self._changed()
                    return  # sent before the planner took our call
                self._confirm = None
                self._paused = progress.paused  # it agrees, or it is the truth after all
            elif self._planner_paused is None or progress.paused != self._planner_paused:
                self._paused = progress.paused  # first message (adopt it) or an edge
            self._planner_paused = progress.paused
            self._changed()

    def on_alarms(self, alarms: AlarmList) -> None:
        """The alarm monitor's list: bit 0x04 follows it; a new alarm ends every queued motion.

        A FAULT switches the servo off and aborts the planner, a WARNING stops it:
        either way nothing queued will run (the planner's progress says so too,
        unless it is the one that failed).
        """
        with self._cond:
            if not is_newer(alarms, self._monitor_list):
                return  # published before the list already adopted
            before = {a.code for a in self._monitor_alarms}
            self._monitor_list = alarms
            self._monitor_alarms = alarms.alarms
            if any(a.code not in before for a in alarms.alarms) and len(self._queue):
                log.warning("alarm raised: the motion queue (%d) is discarded", len(self._queue))
                self._queue.discard_all()
                self._expect_paused(False)
            self._changed()

    @property
    def monitor_list(self) -> AlarmList | None:
        """The newest alarm list adopted from the monitor, less what was cleared without it (None before)."""
        with self._cond:
            if self._monitor_list is None:
                return None
            return dataclasses.replace(self._monitor_list, alarms=self._monitor_alarms)

    def forget_alarms(self) -> None:
        """clearAlarms without an alarm monitor: its (old) list no longer counts."""
        with self._cond:
            self._monitor_alarms = ()
            self._changed()

    @property
    def soft_limit_joint(self) -> tuple[LimitValue, ...]:
        """The servo's joint soft limits from its newest status; () before the first one."""
        st = self._status
        return tuple(st.softLimitJoint) if st is not None else ()

    def on_planner_up(self) -> None:
        with self._cond:
            self._planner_up = True
            self._progress_since_up = False

    def on_planner_gone(self) -> None:
        """The planner's liveliness token went away: its queue and pause went with it."""
        with self._cond:
            self._planner_up = False
            self._queue.forget()
            self._paused = False
            self._planner_paused = None
            self._confirm = None
            self._changed()

    def tick(self) -> None:
        """Re-evaluate time-dependent bits (a servo that fell silent)."""
        with self._cond:
            self._changed()

    # -- the command's own actions ------------------------------------------------------
    def allocate(self, timeout: float = FIRST_PROGRESS_TIMEOUT) -> int:
        """A new motion id, above every id the planner reported.

        A planner that outlived a previous command process reports its ids in
        its first progress message; wait for it (bounded), so that a new id is
        never one the planner already finished.
        """
        with self._cond:
            if self._planner_up and not self._progress_since_up:
                self._cond.wait_for(lambda: self._progress_since_up, timeout)
            return self._queue.allocate()

    def accepted(self, motion: int) -> None:
        with self._cond:
            self._queue.add(motion)
            self._changed()

    def discarded(self) -> None:
        """stop or abort accepted by the planner: the queue and the pause are gone."""
        with self._cond:
            self._queue.discard_all()
            self._expect_paused(False)
            self._changed()

    def set_paused(self, paused: bool) -> None:
        """The planner accepted our pause (True) or resume (False)."""
        with self._cond:
            self._expect_paused(paused)
            self._changed()

    def _expect_paused(self, paused: bool) -> None:
        self._paused = paused
        self._confirm = (paused, time.monotonic())

    def await_servo(self, done: Callable[[ServoStatus], bool] | None = None, count: int = 2,
                    timeout: float = 0.5) -> bool:
        """Wait until ``count`` more Servo/status messages arrived and the newest satisfies ``done``.

        After a servo call that changes its state, so that the bits read next
        already show the change. Two messages: the first may have been on its
        way before the servo handled the call. False on timeout.
        """
        deadline = time.monotonic() + timeout
        with self._cond:
            target = self._status_count + count
            while True:
                st = self._status
                if self._status_count >= target and st is not None and (done is None or done(st)):
                    return True
                left = deadline - time.monotonic()
                if left <= 0:
                    return False
                self._cond.wait(left)

    def await_servo_alarm(self, alarm: bool, timeout: float = 0.5) -> bool:
        """Wait until the servo's status shows ``alarm`` (it follows the monitor's list); False on timeout."""
        return self.await_servo(lambda st: st.alarm == alarm, count=1, timeout=timeout)

    # -- publication ------------------------------------------------------------------
    def _changed(self) -> None:
        """Publish the view if its bits or queue length changed (called with the lock held)."""
        view = self._view()
        key = (view.bits, view.queue_length)
        if key != self._published:
            if self._published is not None and (view.bits ^ self._published[0]):
                log.debug("state 0x%02x -> 0x%02x (queue %d)", self._published[0], view.bits,
                          view.queue_length)
            self._published = key
            try:
                self._publish(view)
            except Exception:  # a publication that fails must not break the state machine
                log.exception("could not publish the state")
