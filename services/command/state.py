"""The command service's state bits (``getState``) and their publication on ``JARA_ARM/<arm>/state``.

The command owns none of the facts it reports; it reads each from its owner:

* 0x01 servo on: the servo's ``Servo/status`` says so, and it spoke within
  ``stale_after``, the system's hung bound (``Health.hung_after``: 1.5 s on
  one host, 5 s on a LAN); a servo silent longer counts as off (a real drive
  that stops talking faults), at the moment the alarm monitor judges it hung
  (0x410), not before: a shorter silence is a stall, and the state of a servo
  that is on does not flicker off without an alarm.
* 0x02 moving: the servo moves, or the planner's queue holds motions
  (running, waiting or paused: the arm is not done with them).
* 0x04 alarm: the alarm monitor's list (``Monitor/alarms``, while the monitor
  is up) is not empty, or the servo reports an active alarm (its own latches
  and the monitor's list, which it keeps while the monitor restarts).
* 0x08 queue full: the planner's queue holds its ``capacity`` motions (both in its progress).
* 0x10 paused: the planner says so.

The planner's queue and pause (and the servo's speed override, which
``Ext/getSpeedOverride`` reads) come in its ``PlannerProgress``, by publication
and in the reply to every plan and control call; the newest one by its number
wins (``schema.planner.is_newer``), so a publication that arrives after a
reply it predates changes nothing. The servo's ``ServoStatus`` likewise, by
``Servo/status`` and in the reply to every ``Servo/power`` call
(``schema.messages.is_newer``): the bits read after a servoON or servoOFF reply
show it, with no wait for a publication. A planner or monitor that went away takes
its facts with it: its later messages, still on their way, are ignored.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable

from jara_arm.schema import alarms as alarm_lists
from jara_arm.schema import messages as servo_statuses
from jara_arm.schema import planner as planner_progress
from jara_arm.schema.alarms import AlarmList
from jara_arm.schema.codes import AlarmType, StateBit
from jara_arm.schema.messages import ServoStatus
from jara_arm.schema.planner import QUEUE_CAPACITY, PlannerProgress
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.timing import ARRIVAL_LISTEN, SAME_HOST

log = logging.getLogger(__name__)

#: Without a ``Servo/status`` for this long the servo counts as gone [s] unless the service says otherwise:
#: the same-host hung bound (the servo publishes every 10 cycles moving, every 100 at rest). It was 1.0 s,
#: shorter than the hung bound: an 8-arm soak on 2 cores published 0x02 (moving, servo off) for a servo
#: that was on and raised nothing (a bus held up 1.2 s), and on a LAN cell (hung after 5 s) every network
#: hiccup over 1 s did the same.
STATUS_STALE_AFTER = SAME_HOST.hung_after


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

    def __init__(self, publish: Publish, stale_after: float = STATUS_STALE_AFTER) -> None:
        """``stale_after`` [s]: a servo silent this long counts as off (the service passes its hung bound)."""
        self._publish = publish
        self._stale_after = stale_after
        self._cond = threading.Condition()
        self._status: ServoStatus | None = None
        self._status_at = -float("inf")  # [s] monotonic time the newest ServoStatus arrived
        self._progress: PlannerProgress | None = None  # the planner's newest, None while it is away
        self._done_at = -float("inf")  # [s, wall] ``tm`` of the progress that said a motion done first
        self._planner_gone_at = -float("inf")  # ``started`` [s] of the last planner that went away
        self._alarms: AlarmList | None = None  # the monitor's newest list, None while it is away
        self._monitor_gone_at = -float("inf")  # ``started`` [s] of the last monitor that went away
        self._published: tuple[int, int] | None = None
        #: Takes in what arrived and was not read yet (``Watcher.drain``); called by :meth:`view`.
        self.catch_up: Callable[[], None] | None = None

    # -- reading ------------------------------------------------------------------
    def view(self, listen: float = 0.0) -> StateView:
        """The state now, after taking in what already arrived and was not read yet (``catch_up``): a
        client that learnt from ``Planner/progress`` that its motion ended must not read MOVING from a report
        this service had not read yet, and a command service held up without a CPU (a busy machine) has
        statuses waiting, where "no status" must mean none came, not none was read (8 arms on 2 cores: 13
        moves refused in 2 minutes for it). If there is still none, the view waits up to ``listen`` [s] for
        one (``timing.STATUS_LISTEN`` for a motion request)."""
        self._catch_up_while(lambda: time.monotonic() - self._status_at > self._stale_after, listen)
        with self._cond:
            return self._view()

    def _view(self) -> StateView:
        heard = self._status is not None and time.monotonic() - self._status_at <= self._stale_after
        st = self._status if heard else None
        progress = self._progress
        queued = len(progress.queued) if progress is not None else 0
        # The planner's (it owns the queue and refuses the motion that does not fit); its default until heard.
        capacity = progress.capacity if progress is not None and progress.capacity > 0 else QUEUE_CAPACITY
        # A FAULT switches the servo off (SPEC.md §4): with one listed, no servo-on bit, even before the
        # servo's own status says so (what getActiveAlarm answered and getState must agree).
        fault = bool(self._alarms and any(a.type is AlarmType.FAULT for a in self._alarms.alarms))
        return StateView(
            servo_heard=heard,
            servo_on=bool(st and st.servoOn) and not fault,
            moving=bool(st and st.moving) or queued > 0,
            alarm=bool(st and st.alarm) or bool(self._alarms and self._alarms.alarms),
            full=queued >= capacity,
            paused=bool(progress and progress.paused),
            queue_length=queued,
            capacity=capacity,
        )

    def measured_joints(self) -> tuple[tuple[float, ...], float] | None:
        """The joints [rad or m] of the newest Servo/status and its age [s]; None before the first.

        What arrived and was not read yet is taken in first (``catch_up``): a client that learnt from
        ``Planner/progress`` that its motion ended reads the pose it ended at, not an older one this service
        had not read yet (its watcher held up on a busy machine: the demo said a resumed LIN arrived 1 mm
        short, two test workers beside two busy loops)."""
        # A status the servo made before the planner said the motion done may be the newest here while those
        # after it are still on their way (the progress and the statuses take different paths): one stamped
        # then or later is waited for, a moment (the demo read a goHome 0.0032 rad short, three test workers
        # beside a busy loop per core).
        self._catch_up_while(self._before_done, ARRIVAL_LISTEN)
        st, at = self._status, self._status_at  # one read each: the watcher replaces them
        if st is None or not st.pos:
            return None
        return st.pos, time.monotonic() - at

    def _catch_up_while(self, pending: Callable[[], bool], seconds: float) -> None:
        """Take in what arrived (``catch_up``), then, while ``pending()``, wait up to ``seconds`` [s] for more
        (woken by ``on_status``, or every 20 ms to drain what came meanwhile). Without a watcher: nothing."""
        if (catch_up := self.catch_up) is None:
            return
        catch_up()
        deadline = time.monotonic() + seconds
        while pending() and time.monotonic() < deadline:
            with self._cond:
                self._cond.wait(min(0.02, max(0.0, deadline - time.monotonic())))
            catch_up()

    def _before_done(self) -> bool:
        """The newest status was stamped before the planner's word that the last motion was done."""
        st = self._status
        return st is not None and st.tm.to_seconds() < self._done_at

    def servo_status(self) -> ServoStatus | None:
        """The servo's newest status (by its number); None before the first one."""
        return self._status  # one read: the inputs replace it whole

    def alarm_list(self) -> AlarmList | None:
        """The monitor's newest list; None before the first one and while the monitor is away."""
        return self._alarms  # one read: the inputs replace it whole

    def planner_progress(self) -> PlannerProgress | None:
        """The planner's newest ``PlannerProgress``; None before the first one and while the planner is away."""
        return self._progress  # one read: the inputs replace it whole

    @property
    def soft_limit_joint(self) -> tuple[LimitValue, ...]:
        """The servo's joint soft limits from its newest status; () before the first one."""
        st = self._status
        return tuple(st.softLimitJoint) if st is not None else ()

    # -- inputs -----------------------------------------------------------------------
    def on_status(self, status: ServoStatus | None) -> None:
        """A ``ServoStatus``, published or in a ``Servo/power`` reply (None: the servo did not answer)."""
        with self._cond:
            if status is None:
                return
            # Older by its number: made before the one held, and on its way meanwhile. Once the one held is stale,
            # a status of another servo process counts whatever its number (one restarted after the wall clock
            # stepped back); of the same process, never an older one (this process's threads were held up).
            held = self._status
            stale = time.monotonic() - self._status_at > self._stale_after
            if not servo_statuses.is_newer(status, held) and not (
                    stale and held is not None and status.started != held.started):
                return
            self._status = status
            self._status_at = time.monotonic()
            self._cond.notify_all()
            self._changed()

    def on_progress(self, progress: PlannerProgress | None) -> None:
        """A ``PlannerProgress``, published or in a reply (None: the planner did not answer)."""
        with self._cond:
            if (progress is None or progress.started.to_seconds() <= self._planner_gone_at
                    or not planner_progress.is_newer(progress, self._progress)):
                return
            if progress.lastDone > (self._progress.lastDone if self._progress is not None else 0):
                self._done_at = progress.tm.to_seconds()
            self._progress = progress
            self._changed()

    def on_planner_gone(self) -> None:
        """The planner's liveliness token went away: its queue and pause went with it."""
        with self._cond:
            if self._progress is not None:
                self._planner_gone_at = self._progress.started.to_seconds()
            self._progress = None
            self._changed()

    def on_alarms(self, alarms: AlarmList) -> None:
        """The alarm monitor's list: bit 0x04 follows it."""
        with self._cond:
            if (alarms.started.to_seconds() <= self._monitor_gone_at
                    or not alarm_lists.is_newer(alarms, self._alarms)):
                return
            self._alarms = alarms
            self._changed()

    def on_monitor_gone(self) -> None:
        """The monitor's liveliness token went away: the servo holds its list until a new one takes over."""
        with self._cond:
            if self._alarms is not None:
                self._monitor_gone_at = self._alarms.started.to_seconds()
            self._alarms = None
            self._changed()

    def tick(self) -> None:
        """The watcher's drain has taken in what was waiting: judge the state, a servo that fell silent included."""
        with self._cond:
            self._changed(drained=True)

    # -- publication ------------------------------------------------------------------
    def _changed(self, drained: bool = False) -> None:
        """Publish the view if its bits or queue length changed (called with the lock held). A servo heard before
        and now silent is said off only once the watcher has drained what was waiting (``drained``): a command
        held up past the staleness window finds the planner's progress and the servo's newer statuses waiting
        together, and judged on the progress alone (or a call's reply) the state said a moving arm's servo was
        off (0x02, published in an 8-arm soak on 2 cores)."""
        view = self._view()
        if not drained and self.catch_up is not None and self._status is not None and not view.servo_heard:
            return  # the watcher's drain takes them in and publishes
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
