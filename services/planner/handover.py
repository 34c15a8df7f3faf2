"""The hand-over: each accepted motion goes to the servo's interpolator whole.

The planner plans; the servo executes (``services/servo/interpolator.py``,
``schema/motion.py``). This module is the planner's side of that boundary:

* :meth:`Handover.start_point`: where the next motion starts (the end of the
  last buffered motion, or where the servo holds the arm) and the servo's
  epoch it is planned in; while the servo slows down for a stop it waits, since
  where the arm stops is not known before.
* :meth:`Handover.submit`: one planned motion to ``Servo/trajectory``. A blend
  goes as a splice into the motion before it; too late for that (the servo is
  past its cut), the exact stop goes instead. A refusal as stale (the queue was
  stopped meanwhile) returns None: the caller plans again.
* Early start: :meth:`start_early` hands over a LIN / CIRC's checked head
  (``final`` false) before the whole is planned; the servo slows the head down
  if the rest is late, never stopping on it. :meth:`confirm_early` sends the
  rest, spliced at the head's last sample; :meth:`cancel_early` stops it.
* :meth:`control`: pause, resume, stop, abort, override, forwarded.
* A relay thread republishes the servo's ``Servo/motion`` as ``Planner/progress``
  (the command service's view of the queue), numbered by this process.

Nothing here is on a motion's real-time path: once buffered, a motion runs to
its end whatever this process does.
"""

from __future__ import annotations

import dataclasses
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.messages import NO_STATUS, ServoStatus, is_newer as is_newer_status
from jara_arm.schema.motion import (
    MotionAction,
    MotionControl,
    MotionProgress,
    MotionReply,
    Trajectory,
    TrajectoryRefusal,
    is_newer,
    refreshes,
)
from jara_arm.schema.planner import QUEUE_CAPACITY, ControlAction, PlannerProgress
from jara_arm.schema.types import Time
from jara_arm.services.runtime.heartbeat import Pulse
from jara_arm.services.runtime.inbox import Inbox
from jara_arm.services.runtime.threads import LoopThread
from jara_arm.services.runtime.timing import SAME_HOST, STATUS_LISTEN, STOP_WAIT, WATCHER_POLL

from .profile import continue_profile
from .request import PlanRefused
from .trajectory import Joints, PlannedMotion

log = logging.getLogger(__name__)

#: Without a servo status for this long, the servo is taken as gone [s].
STATUS_TIMEOUT = 0.5
PROGRESS_PERIOD = 0.1  # [s] Planner/progress at least this often

#: ``(trajectory) -> reply``, ``(control) -> reply``; None when the servo did not answer. The
#: ``poll_motion`` of :class:`Handover` gives the newest ``Servo/motion`` since its last call, or None.
AskTrajectory = Callable[[Trajectory], MotionReply | None]
AskControl = Callable[[MotionControl], MotionReply | None]


@dataclasses.dataclass(frozen=True)
class _Head:
    motion: int  # the id it was handed over with
    planned: PlannedMotion


class Handover:
    """The planner's side of the servo's interpolator (see the module docstring)."""

    def __init__(self, dof: int, period: float, ask_trajectory: AskTrajectory, ask_control: AskControl,
                 publish_progress: Callable[[PlannerProgress], None],
                 poll_status: Callable[[], ServoStatus | None], poll_motion: Callable[[], MotionProgress | None],
                 pulse: Pulse | None = None, capacity: int = QUEUE_CAPACITY, inbox: Inbox | None = None) -> None:
        """``inbox``: the one whose box ``poll_motion`` reads: the relay wakes when a ``Servo/motion`` comes
        (without it, only every ``PROGRESS_PERIOD``)."""
        if capacity < 1:
            raise ValueError(f"queue capacity must be at least 1, got {capacity}")
        self.dof, self.period = dof, period
        self.capacity = capacity  # [motions] accepted, not finished (the running one included)
        self._ask_trajectory, self._ask_control = ask_trajectory, ask_control
        self._publish_progress = publish_progress
        self._poll_status, self._poll_motion = poll_status, poll_motion
        self._pulse = pulse or Pulse("the progress relay", SAME_HOST.hung_after)
        self._lock = threading.Lock()
        self._news = threading.Condition(self._lock)  # a newer MotionProgress arrived
        self._motion: MotionProgress | None = None  # the servo's newest
        self._status: ServoStatus | None = None
        self._status_at = 0.0
        self._last_id = 0  # the motion ids this planner gave, increasing
        self._last: PlannedMotion | None = None  # the last motion handed over, as the servo buffers it
        self._head: _Head | None = None  # handed over early, not accepted yet
        self._started = Time.now()
        self._snapshot: PlannerProgress | None = None
        self._inbox = inbox or Inbox()
        self._loop = LoopThread(self._relay, "planner-progress", wake=self._inbox.ring)

    # ------------------------------------------------------------------ life cycle

    def start(self) -> None:
        self._loop.start()

    def close(self) -> None:
        self._loop.stop()

    @property
    def alive(self) -> bool:
        return self._loop.alive

    # ------------------------------------------------------------------ planning side

    def start_point(self, known: ServoStatus = NO_STATUS) -> tuple[Joints, int]:
        """(start joints of the next motion, the servo's epoch); raises PlanRefused if there is none.

        ``known``: the caller's newest servo status (``MotionRequest.servo``; seq 0: none), gone by where it is
        newer than the planner's own: the reply to a servoON reaches the command before the servo's publication
        reaches the planner."""
        self._refresh()
        newest = self._poll_status()
        deadline = time.monotonic() + STATUS_LISTEN
        while newest is None and time.time() - self._status_at > STATUS_TIMEOUT and time.monotonic() < deadline:
            time.sleep(0.01)  # this process's receiving threads may be the late ones: listen first
            newest = self._poll_status()
        with self._lock:
            now = time.time()
            # The planner's own receipts say the servo is heard (``_status_at``); once they are stale any of them
            # counts (a servo restarted with an earlier clock). The caller's only adds what it says, if newer.
            if newest is not None and (is_newer_status(newest, self._status) or now - self._status_at > STATUS_TIMEOUT):
                self._status, self._status_at = newest, now
            if known.seq and is_newer_status(known, self._status):
                self._status = known
            st = self._status
            if st is None or now - self._status_at > STATUS_TIMEOUT:
                raise PlanRefused(ReturnCode.STATUS_ERR, "no status from the servo: is it running?")
            if not st.servoOn:
                raise PlanRefused(ReturnCode.NOT_SV_ON_ERR, "the servo is off")
            if st.alarm:
                raise PlanRefused(ReturnCode.STATUS_ERR, "the servo has an active alarm")
            # Checked here, by the queue's owner, one request at a time: two clients cannot both take the last place.
            queued = self._queued()
            if len(queued) >= self.capacity:
                raise PlanRefused(ReturnCode.FULL_MOTION_QUEUE_ERR,
                                  f"the motion queue holds {len(queued)} of {self.capacity} motions")
            # Slowing down for a stop: where the arm ends is known once it has.
            if not self._news.wait_for(lambda: self._motion is not None and len(self._motion.tail) == self.dof,
                                       STOP_WAIT):
                raise PlanRefused(ReturnCode.STATUS_ERR, "the servo did not say where the next motion starts "
                                  f"within {STOP_WAIT:.1f} s (still stopping?)")
            m = self._motion
            assert m is not None
            return np.array(m.tail, dtype=float), m.epoch

    def heard_since(self, tm: float, timeout: float) -> bool:
        """Wait until the servo's newest word on its queue (``Servo/motion``, every change and every 0.1 s) was
        made at ``tm`` [s, the servo's clock] or later; False if none was within ``timeout`` [s]."""
        deadline = time.monotonic() + timeout
        while True:
            self._refresh()
            with self._lock:
                if self._motion is not None and self._motion.tm.to_seconds() >= tm:
                    return True
            if time.monotonic() >= deadline:
                return False
            time.sleep(0.002)

    def last_motion(self) -> PlannedMotion | None:
        """The motion handed over last if the servo still buffers it: what a blend would leave."""
        with self._lock:
            m = self._motion
            last = self._last
            if last is None or m is None or not m.queued or m.queued[-1] != last.motion or m.head:
                return None
            return last

    def submit(self, motion: PlannedMotion, epoch: int) -> tuple[int, PlannerProgress] | None:
        """Hand ``motion`` (planned from ``start_point()``) over: its id and the progress it left, or None
        if the queue moved since (plan it again). Raises PlanRefused if the servo refuses it otherwise."""
        motion_id = self._last_id + 1
        after = self._last.motion if self._last is not None else 0
        blend = motion.blend
        if blend is not None:
            q = np.concatenate([blend.trajectory.q, motion.q[blend.rejoin + 1:]])
            reply = self._hand(Trajectory(motion_id, epoch, blend.previous, blend.cut, True, self.dof,
                                          q.reshape(-1)))
            if reply.refusal == TrajectoryRefusal.LATE:
                log.info("%s: exact stop, motion %d is already past the blend's cut", motion.op, blend.previous)
                blend = None
            else:
                buffered = dataclasses.replace(
                    motion, motion=motion_id, q=q, blend=dataclasses.replace(blend, rejoin=len(blend.trajectory.q) - 1))
        if blend is None:
            buffered = dataclasses.replace(motion, motion=motion_id, blend=None)
            reply = self._hand(Trajectory(motion_id, epoch, after, -1, True, self.dof, motion.q.reshape(-1)))
        if reply.refusal == TrajectoryRefusal.STALE:
            log.info("%s: %s", motion.op, reply.comment)
            return None
        if reply.id != ReturnCode.OK:  # NOT_SV_ON_ERR for a servo off (its status said on a moment ago)
            code = ReturnCode.NOT_SV_ON_ERR if reply.id == ReturnCode.NOT_SV_ON_ERR else ReturnCode.STATUS_ERR
            raise PlanRefused(code, f"the servo did not take it: {reply.comment}")
        with self._lock:
            self._last_id, self._last = motion_id, buffered
            return motion_id, self._progress(time.time())

    def _hand(self, traj: Trajectory) -> MotionReply:
        """``Servo/trajectory``; a servo that does not answer refuses (PlanRefused)."""
        reply = self._ask_trajectory(traj)
        if reply is None:
            # It may have buffered the motion and lost only the reply: a motion refused to the client must
            # not run, so the servo stops its queue (what it already runs slows down to rest on its path).
            with self._lock:
                self._last_id = max(self._last_id, traj.motion)  # the servo may know this id: never reuse it
            stopped = self._ask_control(MotionControl(MotionAction.STOP.value))
            if stopped is not None:
                self._adopt(stopped.progress)
            raise PlanRefused(ReturnCode.STATUS_ERR, "the servo did not answer Servo/trajectory; its queue was "
                              + ("stopped" if stopped is not None else "not stopped either: it does not answer"))
        self._adopt(reply.progress)
        return reply

    def can_start_early(self) -> bool:
        """Nothing buffered, paused or stopping: a motion planned now may start before it is accepted."""
        self._refresh()
        with self._lock:
            m = self._motion
            return (self._head is None and m is not None and not m.queued and not m.paused and not m.stopping
                    and not m.moving)

    def start_early(self, head: PlannedMotion, epoch: int) -> bool:
        """Hand over ``head`` (``early.Head.motion``) before its motion is planned whole; True if the
        servo took it: :meth:`confirm_early` or :meth:`cancel_early` must follow."""
        motion_id = self._last_id + 1
        after = self._last.motion if self._last is not None else 0
        try:
            reply = self._hand(Trajectory(motion_id, epoch, after, -1, False, self.dof, head.q.reshape(-1)))
        except PlanRefused:
            return False
        if reply.id != ReturnCode.OK:
            log.info("no early start: %s", reply.comment)
            return False
        with self._lock:
            self._last_id = motion_id  # given, even if the motion is refused after all
            self._head = _Head(motion_id, head)
        return True

    def confirm_early(self, motion: PlannedMotion, epoch: int) -> tuple[int, PlannerProgress] | None:
        """The motion whose head :meth:`start_early` handed over is accepted: its rest follows the head's
        last sample (slowed down: a continuation from the head's end state). None: a stop discarded the
        head; plan it again."""
        with self._lock:
            h, self._head = self._head, None
        if h is None:  # cancelled already
            return None
        head = h.planned
        k = len(head.q) - 1
        same = (motion.profile.limits == head.profile.limits and len(motion.q) >= len(head.q)
                and np.array_equal(motion.q[:len(head.q)], head.q))
        if same:
            rest = motion.q[k:]
        else:  # slowed down: on from the head's last state within the slower limits
            s, sd, sdd = head.profile.at(k * head.dt)
            rest = motion.joints_along(continue_profile(motion.profile.length, s, sd, sdd, motion.profile.limits))
            rest[0] = head.q[k]  # the same point: the two plans' joint maps may differ by rounding
        reply = self._hand(Trajectory(h.motion, epoch, h.motion, k, True, self.dof, rest.reshape(-1)))
        if reply.id != ReturnCode.OK:
            log.info("%s: its early start is gone (%s); planning again", motion.op, reply.comment)
            return None
        buffered = dataclasses.replace(motion, motion=h.motion, q=np.concatenate([head.q[:k], rest]), blend=None)
        with self._lock:
            self._last = buffered
            log.debug("motion %d accepted %s", h.motion, "on its head" if same else "slowed down after its head")
            return h.motion, self._progress(time.time())

    def cancel_early(self) -> str:
        """The motion whose head :meth:`start_early` handed over is refused: the head slows down to rest on
        its path and is discarded. Returns what the arm did, for the refusal's comment."""
        with self._lock:
            h, self._head = self._head, None
        if h is None:
            return ""
        reply = self._ask_control(MotionControl(MotionAction.STOP.value))
        if reply is not None:
            self._adopt(reply.progress)
        log.info("the early start is refused: the arm stops on its head")
        return "it had started early and stops on its checked first samples"

    # ------------------------------------------------------------------ jogging (jog.py)

    def jog_start(self, head: Joints, epoch: int, final: bool) -> tuple[int, MotionReply]:
        """Hand over a jog's first samples (``head`` (N, dof), from where the servo holds the arm), as a head
        unless ``final``; its motion id and the servo's reply. Raises PlanRefused if the servo refuses."""
        motion_id = self._last_id + 1
        reply = self._hand(Trajectory(motion_id, epoch, 0, -1, final, self.dof, head.reshape(-1)))
        if reply.id != ReturnCode.OK:
            code = ReturnCode.NOT_SV_ON_ERR if reply.id == ReturnCode.NOT_SV_ON_ERR else ReturnCode.STATUS_ERR
            raise PlanRefused(code, f"the servo did not take the jog: {reply.comment}")
        with self._lock:
            self._last_id, self._last = motion_id, None  # a jog is no motion a blend could leave
        return motion_id, reply

    def jog_extend(self, motion: int, epoch: int, rows: Joints, final: bool, splice: int = -1) -> MotionReply:
        """The jog ``motion``'s next samples from its sample ``splice`` on, counted from its end (-1: the last;
        the servo drops a long head's passed samples, so an index from its start would not do), ``rows[0]``
        being that sample; the servo's reply (a refusal if the jog is gone: stopped, aborted, servo off; or
        ``late`` if the servo passed the splice). Raises PlanRefused if the servo does not answer (its queue
        is then stopped)."""
        return self._hand(Trajectory(motion, epoch, motion, splice, final, self.dof, rows.reshape(-1)))

    def progress(self) -> PlannerProgress:
        """The queue and the pause now."""
        self._refresh()
        with self._lock:
            return self._progress(time.time())

    # ------------------------------------------------------------------ control

    def control(self, action: ControlAction, ratio: float = 100.0) -> tuple[ReturnCode, str, PlannerProgress]:
        """Forward ``action`` to the servo; returns (code, comment, the progress it left behind)."""
        reply = self._ask_control(MotionControl(MotionAction(action.value).value, ratio))
        if reply is None:
            return ReturnCode.STATUS_ERR, f"{action.value}: the servo did not answer", self.progress()
        self._adopt(reply.progress)
        if reply.id == ReturnCode.OK and not reply.comment.startswith("OK: ignored"):
            log.info("%s %s", action.value, reply.comment[4:])
        return ReturnCode(reply.id), reply.comment, self.progress()

    # ------------------------------------------------------------------ the relay

    def _refresh(self, relay: bool = False) -> None:
        """Take the newest ``Servo/motion`` received, if any (the relay does it too, when one comes); one
        taken here, not by the relay, wakes the relay to publish it."""
        m = self._poll_motion()
        if m is not None:
            self._adopt(m)
            if not relay:
                self._inbox.ring()

    def _adopt(self, m: MotionProgress) -> bool:
        """Keep ``m`` if it is the servo's newest; True if it was. One of the same state but later (its
        ``runningShare`` newer) replaces the one kept, and wakes no one: nothing waited for changed."""
        with self._lock:
            if refreshes(m, self._motion):
                self._motion = m
                return False
            if not is_newer(m, self._motion):
                return False
            self._motion = m
            self._news.notify_all()
            return True

    def _relay(self, stop: threading.Event) -> None:
        """Relay ``Servo/motion`` to ``Planner/progress``: on every change, and every PROGRESS_PERIOD."""
        last: PlannerProgress | None = None
        last_at = 0.0
        while not stop.is_set():
            self._pulse.beat()
            try:
                self._refresh(relay=True)
                now = time.time()
                with self._lock:
                    progress = self._progress(now)
                if last is None or progress.seq != last.seq or now - last_at >= PROGRESS_PERIOD:
                    self._publish_progress(progress)
                    last, last_at = progress, now
            except Exception:  # the relay must outlive a bug: log it and go on
                log.exception("progress relay iteration failed")
            self._inbox.wait(max(0.0, last_at + PROGRESS_PERIOD - time.time()), spacing=WATCHER_POLL)

    def _queued(self) -> tuple[int, ...]:
        """The motions accepted and not finished, the running one first (lock held): a head is not accepted yet."""
        m = self._motion
        return () if m is None else tuple(i for i in m.queued if i != m.head)

    def _progress(self, now: float) -> PlannerProgress:
        """The servo's progress as the planner's, numbered: ``seq`` grows when anything but the time and
        ``runningShare`` changed (lock held)."""
        m = self._motion
        queued = self._queued()
        if m is None:
            running = done = discarded = 0
            paused = moving = False
            override, share = 100.0, 0.0
        else:
            running = m.running if m.moving and not m.stopping and m.running in queued else 0
            done, discarded, paused, moving, override = m.lastDone, m.lastDiscarded, m.paused, m.moving, m.override
            share = m.runningShare if running else 0.0
        last = self._snapshot
        seq = last.seq if last is not None else 0
        progress = PlannerProgress(Time.from_seconds(now), running, queued, done, discarded, paused, moving,
                                   self._started, seq, override, self.capacity, share)
        if last is None or dataclasses.replace(progress, tm=last.tm, runningShare=last.runningShare) != last:
            progress = dataclasses.replace(progress, seq=seq + 1)
        self._snapshot = progress
        return progress
