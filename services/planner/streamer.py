"""The execution engine: queued motions -> ``Servo/posBlock``, with pause, resume, stop, abort.

One thread (:meth:`Streamer.run`) publishes the samples of the queued motions,
in order, keeping a small lead over the servo: about ``lead`` seconds of
commands wait in the servo's SyncFIFO (:class:`FifoEstimate`), topped up every
``timing.STREAM_BLOCK`` with one ``PositionBlock`` message, enough that the
FIFO never runs dry while moving and little enough that a pause or stop takes
effect within ``lead`` plus one cycle of its reply.

* Motions follow each other with no gap: each one ends at rest, and the next
  one's first sample (its start, equal to the previous end) is skipped.
* ``pause``: from the state of the last sample sent, a braking profile along
  the same path (``PathProfile.stop_at``); then nothing is sent (the servo
  holds at rest). ``resume``: the same path from where it stopped to the same
  end (``PathProfile.resume``). Commands accepted while paused are queued.
* ``stop``: the same braking, then the whole queue is discarded.
* Blends (``blend.py``, blend distance > 0): a queued motion may carry a blend
  of the corner with the motion before it. When that motion runs its nominal
  profile, it is left at the blend's cut (the motion counts as done there), the
  blend's joint-space samples follow, then the next motion from the rejoin on,
  with no stop. A pause or stop in the blend brakes with a joint-space Ruckig
  stop; a resume from there goes back to the rejoin point at rest and on along
  the path. A motion paused before its cut ends at rest at its end as usual,
  and the next one then runs its exact-stop samples.
* ``abort`` (and the servo going off, raising an alarm, or running dry during a
  motion): nothing more is sent; everything is discarded.
* Early start (``start_early``): with nothing queued, sent or paused, the
  checked first samples of a LIN / CIRC still being planned (its head,
  ``planning.Head``) go out at once. ``confirm_early`` hands the accepted
  whole over (the same samples on; slowed down: a continuation from the state
  sent); ``cancel_early`` (refused) brakes on the head and discards it. A head
  that runs out first brakes on itself and holds until one of the two. A
  pause brakes it as any motion; a stop or abort discards it (the planner
  then plans the motion again from where the arm stopped, as for any motion
  being planned when the queue stops).

Control calls compute the braking profile and install it before they return,
so their reply means "the deceleration is queued for sending".

Thread safety: every public method takes the engine's lock; only the engine
thread publishes.
"""

from __future__ import annotations

import collections
import dataclasses
import enum
import logging
import threading
import time
from collections.abc import Callable

import numpy as np

from jara_arm.schema import messages
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.messages import ServoStatus
from jara_arm.schema.planner import ControlAction, PlannerProgress
from jara_arm.schema.types import Time
from jara_arm.services.runtime.heartbeat import Pulse
from jara_arm.services.runtime.realtime import realtime_thread
from jara_arm.services.runtime.timing import SAME_HOST, STREAM_BLOCK, STREAM_LEAD, STREAMER_IDLE

from .blend import Blend, JointTrajectory, joint_move, joint_stop
from .planning import PlanRefused
from .profile import PathProfile, continue_profile, resume_profile
from .servo_fifo import FifoEstimate
from .trajectory import UNQUEUED, Joints, PlannedMotion

log = logging.getLogger(__name__)

#: Commands kept ahead of the servo [s] (``timing.STREAM_LEAD``).
DEFAULT_LEAD = STREAM_LEAD
#: SCHED_FIFO priority of the engine thread: below the servo loop's 40 (0: normal scheduling).
DEFAULT_RT_PRIORITY = 30
#: Without a servo status for this long while streaming, the servo is taken as gone [s].
STATUS_TIMEOUT = 0.5
#: A motion starting from rest must start within this of the servo's held target [rad or m].
START_TOLERANCE = 1e-4
#: After the last command is due, the servo's status is trusted for the start joints after this [s].
SETTLE = 0.03
PROGRESS_PERIOD = 0.1  # [s] progress is published at least this often
_LOW_DEPTH = 2.0  # [commands] an estimated FIFO depth this low while streaming is worth a warning


class _Kind(enum.Enum):
    RUN = "run"  # a motion, nominal or resumed
    PAUSE = "pause"  # braking along the path, then hold (resumable)
    STOP = "stop"  # braking along the path of a discarded motion


@dataclasses.dataclass
class _Segment:
    """A profile on a motion's path being sent, or a joint-space trajectory in its blend (``joint``);
    sample 0 is the state already commanded."""

    motion: PlannedMotion
    profile: PathProfile  # on the motion's path (not used while ``joint`` is set)
    q: Joints  # (N, dof) joints at the profile's samples, or ``joint.q``
    kind: _Kind
    k: int = 1  # next sample to send
    resume_after: bool = False  # PAUSE: resume as soon as the braking ends
    nominal: bool = False  # the motion's own samples (``motion.q``): a blend into the next one may cut it
    joint: JointTrajectory | None = None  # in ``motion.blend``: the blend, a braking in it, or the way back
    blend: Blend | None = None  # set with ``joint``
    #: PAUSE (or held) of an accepted early start: the run after it, known at acceptance and rebased as the
    #: motion's own, so that a next motion planned meanwhile blends into what will be streamed
    then: _Segment | None = None

    @property
    def last_sent_time(self) -> float:
        """[s] time on ``profile`` of the last sample sent."""
        return (self.k - 1) * self.motion.dt

    @property
    def duration(self) -> float:
        """[s] of the whole segment."""
        return self.joint.duration if self.joint is not None else self.profile.duration

    def brake(self, kind: _Kind) -> _Segment:
        """Braking along the path (in a blend: in joint space) from the state of the last sample sent."""
        if self.joint is not None and self.blend is not None:
            i = self.k - 1
            stop = joint_stop(self.joint.q[i], self.joint.dq[i], self.joint.ddq[i], self.blend.limits,
                              self.joint.dt)
            return _Segment(self.motion, self.profile, stop.q, kind, joint=stop, blend=self.blend)
        profile = self.profile.stop_at(self.last_sent_time)
        return _Segment(self.motion, profile, self.motion.joints_along(profile), kind)

    def resumed(self) -> _Segment:
        """From rest where this segment ended to the end of the path (in a blend: first back to the
        rejoin point, at rest)."""
        if self.joint is not None and self.blend is not None:
            back = joint_move(self.q[-1], self.blend.trajectory.q[-1], self.blend.limits, self.joint.dt)
            return _Segment(self.motion, self.profile, back.q, _Kind.RUN, joint=back, blend=self.blend)
        m = self.motion  # its own limits: an early start's head may have braked with others (slowed down since)
        profile = resume_profile(m.profile.length, self.profile.s_end, m.profile.limits)
        return _Segment(m, profile, m.joints_along(profile), _Kind.RUN)

    def rebased(self) -> _Segment:
        """This run as its motion's nominal one: the motion's profile and samples become this segment's,
        so that a blend planned after it (into the next motion) cuts into what is streamed. Only before
        anything was planned against the motion: an early start's, when it is accepted."""
        m = dataclasses.replace(self.motion, profile=self.profile, q=self.q)
        return _Segment(m, self.profile, self.q, _Kind.RUN, k=self.k, nominal=True)

    def continued(self, motion: PlannedMotion) -> _Segment:
        """``motion`` (on this segment's path, other limits) on from the state of the last sample sent."""
        s, sd, sdd = self.profile.at(self.last_sent_time)
        profile = continue_profile(motion.profile.length, s, sd, sdd, motion.profile.limits)
        return _Segment(motion, profile, motion.joints_along(profile), _Kind.RUN)

    def path_after(self) -> _Segment:
        """After the blend (or the way back onto the path): the motion's path from the rejoin point on."""
        assert self.joint is not None and self.blend is not None
        m = self.motion
        if self.joint is self.blend.trajectory:  # the blend itself: the nominal samples go on
            return _Segment(m, m.profile, m.q, _Kind.RUN, k=self.blend.rejoin + 1, nominal=True)
        profile = resume_profile(m.profile.length, self.blend.s_rejoin, m.profile.limits)
        return _Segment(m, profile, m.joints_along(profile), _Kind.RUN)


class Streamer:
    """Queue and stream planned motions to the servo (see module docstring)."""

    def __init__(self, dof: int, period: float, publish: Callable[[bytes], None],
                 publish_progress: Callable[[PlannerProgress], None],
                 poll_status: Callable[[], ServoStatus | None], *, lead: float = DEFAULT_LEAD,
                 realtime_priority: int = DEFAULT_RT_PRIORITY, pulse: Pulse | None = None) -> None:
        self.dof = dof
        self._pulse = pulse or Pulse("the streamer loop", SAME_HOST.hung_after)
        self.period = period  # [s] servo cycle
        self.lead = lead  # [s]
        self._publish = publish
        self._publish_progress = publish_progress
        self._poll_status = poll_status
        self._rt_priority = realtime_priority
        self._lock = threading.Lock()
        self._wake = threading.Event()
        self._stop_event = threading.Event()
        self._fifo = FifoEstimate(period)

        self._queue: collections.deque[PlannedMotion] = collections.deque()
        self._active: _Segment | None = None
        self._held: _Segment | None = None  # paused at rest mid-path
        self._early: PlannedMotion | None = None  # the head streaming before its motion is accepted
        self._inflight: collections.deque[tuple[int, float]] = collections.deque()  # (id, due [s])
        self._paused = False
        self._tail: Joints | None = None  # where the last queued motion (or braking) ends
        self._last_sent: Joints | None = None
        self._busy_until = 0.0  # [s] when the last command sent is due at the servo
        self._generation = 0  # changes when the queue's end moves other than by submit()
        self._last_done = 0
        self._last_discarded = 0
        self._last_id = 0  # the motion ids this planner gave, increasing
        self._started = Time.from_seconds(time.time())
        self._snapshot: PlannerProgress | None = None  # the newest progress, numbered by its seq
        self._status: ServoStatus | None = None
        self._status_at = 0.0  # [s] arrival of the last status
        self._underruns: int | None = None
        self._thread = threading.Thread(target=self.run, name="planner-streamer", daemon=True)

    # ------------------------------------------------------------------ life cycle

    def start(self) -> None:
        self._thread.start()

    def close(self) -> None:
        self._stop_event.set()
        self._wake.set()
        self._thread.join(timeout=2.0)

    @property
    def alive(self) -> bool:
        return self._thread.is_alive()

    # ------------------------------------------------------------------ planning side

    def start_point(self) -> tuple[Joints, int]:
        """(start joints of the next motion, generation); raises PlanRefused if there is none.

        The end of the last queued motion; when nothing is queued or running,
        the servo's held target (or our own last end if the servo holds there).
        """
        newest = self._poll_status()  # not the engine's last poll: up to STREAMER_IDLE old
        with self._lock:
            now = time.time()
            if newest is not None:
                self._on_status(newest, now)
            st = self._status
            if st is None or now - self._status_at > STATUS_TIMEOUT:
                raise PlanRefused(ReturnCode.STATUS_ERR, "no status from the servo: is it running?")
            if not st.servoOn:
                raise PlanRefused(ReturnCode.NOT_SV_ON_ERR, "the servo is off")
            if st.alarm:
                raise PlanRefused(ReturnCode.STATUS_ERR, "the servo has an active alarm")
            if self._tail is not None and not self._idle(now, SETTLE):
                return self._tail.copy(), self._generation
            target = np.array(st.target, dtype=float)
            if target.shape != (self.dof,):
                raise PlanRefused(ReturnCode.STATUS_ERR, f"the servo reports {target.size} axes, "
                                  f"the robot has {self.dof}")
            if self._tail is not None and np.max(np.abs(target - self._tail)) < START_TOLERANCE:
                return self._tail.copy(), self._generation  # exactly where we left it
            return target, self._generation

    def last_motion(self) -> PlannedMotion | None:
        """The motion queued last if it is still queued or running: what a blend would leave."""
        with self._lock:
            if self._queue:
                return self._queue[-1]
            seg = self._next_run()
            return seg.motion if seg is not None and seg.kind is _Kind.RUN else None

    def _next_run(self) -> _Segment | None:
        """The active segment, or the run that follows a braking by itself (an accepted early start's)."""
        seg = self._active
        if seg is not None and seg.kind is _Kind.PAUSE and seg.resume_after and seg.then is not None:
            return seg.then
        return seg

    def submit(self, motion: PlannedMotion, generation: int) -> tuple[int, PlannerProgress] | None:
        """Queue ``motion`` planned from ``start_point()``: its id and the progress it left
        behind, or None (nothing queued) if the queue's end moved since. Its blend is dropped
        (exact stop) if the motion it leaves is no longer last or already past the cut."""
        with self._lock:
            if generation != self._generation:
                return None
            if motion.blend is not None and not self._blendable(motion.blend):
                log.info("%s: exact stop, motion %d is already past the blend's cut", motion.op,
                         motion.blend.previous)
                motion = dataclasses.replace(motion, blend=None)
            self._last_id += 1
            motion = dataclasses.replace(motion, motion=self._last_id)
            self._queue.append(motion)
            self._tail = motion.end.copy()
            progress = self._progress(time.time())
        self._wake.set()
        return motion.motion, progress

    def can_start_early(self) -> bool:
        """Nothing queued, sent or paused: a motion planned now may start before it is accepted."""
        with self._lock:
            return self._early is None and not self._paused and self._idle(time.time(), SETTLE)

    def start_early(self, head: PlannedMotion, generation: int) -> bool:
        """Stream ``head`` (``planning.Head.motion``) if :meth:`can_start_early` still holds, the queue's end
        has not moved and the servo holds the arm at its start; :meth:`confirm_early` or :meth:`cancel_early`
        must follow a True."""
        with self._lock:
            st = self._status
            if (generation != self._generation or self._early is not None or self._paused
                    or not self._idle(time.time(), SETTLE) or st is None or len(st.target) != self.dof
                    or float(np.max(np.abs(np.array(st.target) - head.start))) > START_TOLERANCE):
                return False
            self._early = head
            self._active = _Segment(head, head.profile, head.q, _Kind.RUN)
            self._tail = None
        self._wake.set()
        return True

    def confirm_early(self, motion: PlannedMotion, generation: int) -> tuple[int, PlannerProgress] | None:
        """The motion whose head :meth:`start_early` streams is accepted: as :meth:`submit`, and it goes on
        from wherever its head is (None: a stop or abort discarded the head; plan it again)."""
        with self._lock:
            head, self._early = self._early, None
            if head is None or generation != self._generation:
                return None
            self._last_id += 1
            motion = dataclasses.replace(motion, motion=self._last_id)
            same = (motion.profile.limits == head.profile.limits and len(motion.q) >= len(head.q)
                    and np.array_equal(motion.q[:len(head.q)], head.q))
            seg = self._active if self._active is not None and self._active.motion is head else None
            if seg is not None and seg.kind is _Kind.RUN:
                if same:  # the whole motion's samples begin with the head's, bit for bit
                    seg.motion, seg.q, seg.nominal = motion, motion.q, True
                else:  # slowed down: on from the state sent, within the slower limits
                    self._active = seg.continued(motion).rebased()
            elif seg is not None:  # braking on the head (it ran out, or a pause)
                seg.motion, seg.resume_after = motion, not self._paused
                seg.then = seg.resumed().rebased()
            elif self._held is not None and self._held.motion is head:
                held = self._held
                held.motion = motion
                held.then = held.resumed().rebased()
                if not self._paused:
                    self._active, self._held = held.then, None
            else:  # pragma: no cover - a head is active or held until confirmed, cancelled or discarded
                raise AssertionError("the early start's head is neither streaming nor held")
            self._tail = motion.end.copy()
            log.debug("motion %d accepted %s", motion.motion,
                      "on its head" if same else "slowed down: continuing from its head")
            progress = self._progress(time.time())
        self._wake.set()
        return motion.motion, progress

    def cancel_early(self) -> str:
        """The motion whose head :meth:`start_early` streams is refused: the head brakes (on itself) and is
        discarded. Returns what the arm did, for the refusal's comment ("" if the head is gone already)."""
        with self._lock:
            head, self._early = self._early, None
            if head is None:
                return ""
            seg = self._active if self._active is not None and self._active.motion is head else None
            if seg is not None and seg.kind is _Kind.RUN:
                self._active = seg = seg.brake(_Kind.STOP)
            elif seg is not None:
                seg.kind, seg.resume_after = _Kind.STOP, False
            held = self._held is not None and self._held.motion is head
            if held:
                seg, self._held = self._held, None
            assert seg is not None
            self._tail = seg.q[-1].copy()
            moved = float(np.max(np.abs(seg.q[-1] - head.start)))
            log.info("the early start is refused: the arm %s %.3g rad / m from the start",
                     "stopped" if held else "stops", moved)
        self._wake.set()
        return (f"it had started early and {'stopped' if held else 'stops'} on its checked first samples, "
                f"joints at most {moved:.2g} rad from the start")

    def _blendable(self, blend: Blend) -> bool:
        """Whether ``blend`` can still leave the motion it starts from (lock held)."""
        if self._queue:
            return self._queue[-1].motion == blend.previous
        seg = self._next_run()
        if seg is None or seg.kind is not _Kind.RUN or seg.motion.motion != blend.previous:
            return False
        return seg.joint is not None or (seg.nominal and seg.k <= blend.cut + 1)

    def progress(self) -> PlannerProgress:
        """The queue and the pause now."""
        with self._lock:
            return self._progress(time.time())

    # ------------------------------------------------------------------ control

    def control(self, action: ControlAction) -> tuple[ReturnCode, str, PlannerProgress]:
        """Apply ``action``; returns (code, comment, the progress it left behind) once any
        braking is queued for sending."""
        with self._lock:
            now = time.time()
            if action is ControlAction.PAUSE:
                result = self._pause(now)
            elif action is ControlAction.RESUME:
                result = self._resume()
            elif action is ControlAction.STOP:
                result = self._stop(now)
            else:
                self._abort("abort requested")
                result = "OK: motion aborted, queue discarded"
            progress = self._progress(now)
        self._wake.set()
        if result.startswith("OK: ignored"):
            log.info("%s %s", action.value, result[4:])
        return ReturnCode.OK, result, progress

    def _pause(self, now: float) -> str:
        if self._paused:
            return "OK: ignored, already paused"
        seg = self._active
        if seg is not None and seg.kind is _Kind.STOP:
            return "OK: ignored, stopping"
        if seg is None and not self._queue and self._idle(now):
            return "OK: ignored, not moving"
        self._paused = True
        if seg is not None:
            self._active = seg.brake(_Kind.PAUSE)
            where = "in the blend" if seg.joint is not None else "along the path"
            log.info("pause: motion %d decelerates %s in %.3f s", seg.motion.motion, where, self._active.duration)
            return f"OK: pausing, decelerating {where} in {self._active.duration:.3f} s"
        log.info("pause: between motions, %d queued", len(self._queue))
        return "OK: paused"

    def _resume(self) -> str:
        if not self._paused:
            return "OK: ignored, not paused"
        self._paused = False
        seg = self._active
        if seg is not None and seg.kind is _Kind.PAUSE:
            seg.resume_after = True
            log.info("resume: motion %d continues once its deceleration ends", seg.motion.motion)
            return "OK: resuming once the deceleration ends"
        if self._held is not None and self._held.motion is self._early:
            log.info("resume: the early start goes on once its motion is planned")
            return "OK: resumed"
        if self._held is not None:
            held, self._held = self._held, None
            self._active = held.then or held.resumed()
            log.info("resume: motion %d continues, %.3f s to its end", held.motion.motion,
                     self._active.duration)
            return "OK: resumed"
        log.info("resume: %d queued motions go on", len(self._queue))
        return "OK: resumed"

    def _stop(self, now: float) -> str:
        seg = self._active
        if seg is None and not self._queue and self._held is None and self._idle(now):
            return "OK: ignored, not moving"
        discarded = [m.motion for m in self._queue]
        if self._held is not None:
            discarded.append(self._held.motion.motion)
        if seg is not None and seg.kind is not _Kind.STOP:
            discarded.append(seg.motion.motion)
            if seg.kind is _Kind.RUN:
                self._active = seg = seg.brake(_Kind.STOP)
            else:  # already braking for a pause: keep braking, do not resume
                seg.kind, seg.resume_after = _Kind.STOP, False
        self._queue.clear()
        self._held = None
        self._paused = False
        self._early = None  # the motion being planned is planned again from where the arm stops
        self._generation += 1
        self._tail = seg.q[-1].copy() if seg is not None else self._last_sent
        discarded = [i for i in discarded if i != UNQUEUED]
        if discarded:
            self._last_discarded = max(self._last_discarded, max(discarded))
        duration = seg.duration if seg is not None else 0.0
        log.info("stop: decelerating in %.3f s; discarded motions %s", duration, discarded or "none")
        return f"OK: stopping in {duration:.3f} s, {len(discarded)} motions discarded"

    def _abort(self, why: str) -> None:
        """Send nothing more, discard everything (lock held)."""
        discarded = [i for i, _ in self._inflight] + [m.motion for m in self._queue]
        if self._held is not None:
            discarded.append(self._held.motion.motion)
        if self._active is not None and self._active.kind is not _Kind.STOP:
            discarded.append(self._active.motion.motion)
        busy = bool(discarded) or self._active is not None
        discarded = [i for i in discarded if i != UNQUEUED]
        self._queue.clear()
        self._inflight.clear()
        self._active = self._held = self._early = None
        self._paused = False
        self._tail = self._last_sent = None
        self._generation += 1
        self._busy_until = 0.0
        if discarded:
            self._last_discarded = max(self._last_discarded, max(discarded))
        if busy:
            log.warning("abort (%s): discarded motions %s", why, discarded or "none")

    # ------------------------------------------------------------------ state

    def _idle(self, now: float, settle: float = 0.0) -> bool:
        """Nothing queued, sent or due (lock held)."""
        return (self._active is None and self._held is None and not self._queue and not self._inflight
                and now >= self._busy_until + settle)

    def _progress(self, now: float) -> PlannerProgress:
        """The progress now, numbered: ``seq`` grows when anything but the time changed (lock held)."""
        ids = [i for i, _ in self._inflight]
        seg = self._active
        if seg is not None and seg.kind is not _Kind.STOP and seg.motion is not self._early:
            ids.append(seg.motion.motion)
        if self._held is not None and self._held.motion is not self._early:
            ids.append(self._held.motion.motion)
        ids += [m.motion for m in self._queue]
        moving = bool(self._inflight) or (seg is not None and seg.kind is not _Kind.STOP)
        running = ids[0] if moving and ids else 0  # 0 while paused at rest, stopping, about to start or early
        streaming = seg is not None or now < self._busy_until
        last = self._snapshot
        seq = last.seq if last is not None else 0
        progress = PlannerProgress(Time.from_seconds(now), running, tuple(ids), self._last_done,
                                   self._last_discarded, self._paused, streaming, self._started, seq)
        if last is None or dataclasses.replace(progress, tm=last.tm) != last:
            progress = dataclasses.replace(progress, seq=seq + 1)
        self._snapshot = progress
        return progress

    # ------------------------------------------------------------------ engine thread

    def run(self) -> None:
        realtime_thread(self._rt_priority, "streamer")
        last_progress: PlannerProgress | None = None
        last_progress_at = 0.0
        last_now = last_late_log = time.time()
        marks = [time.perf_counter()] * 7  # the previous round: woke, polled, locked, filled, published, done, slept
        asked = 0.0  # [s] the sleep it asked for
        while not self._stop_event.is_set():
            self._pulse.beat()
            woke = time.perf_counter()
            try:
                status = self._poll_status()
                now = time.time()
                gap, last_now = now - last_now, now
                polled = time.perf_counter()
                with self._lock:
                    locked = time.perf_counter()
                    if status is not None:
                        self._on_status(status, now)
                    elif self._has_work(now) and now - self._status_at > STATUS_TIMEOUT:
                        self._abort(f"no status from the servo for {STATUS_TIMEOUT:.1f} s")
                    depth = self._fifo.depth(now)
                    low = self._active is not None and self._active.k > 1 and depth < _LOW_DEPTH
                    out = self._fill(now)
                    while self._inflight and self._inflight[0][1] <= now:
                        self._last_done = self._inflight.popleft()[0]
                    progress = self._progress(now)
                    busy = self._active is not None or (self._queue and not self._paused)
                filled = time.perf_counter()
                if out is not None:
                    self._publish(out)
                published = time.perf_counter()
                if low and now - last_late_log > 1.0:
                    # Where the time went (a late round is what runs the servo dry): the previous round's
                    # phases, its sleep against the one asked for, and this round's start [ms].
                    ms = [1e3 * (b - a) for a, b in zip(marks, marks[1:])]
                    log.warning("servo FIFO nearly empty mid-motion (%.1f commands estimated, %.1f ms since the "
                                "streamer's previous round: poll %.1f, lock %.1f, fill %.1f, publish %.1f, progress "
                                "%.1f, then slept %.1f (asked %.1f); this round: poll %.1f, lock %.1f)", depth,
                                gap * 1e3, *ms[:5], ms[5], asked * 1e3, 1e3 * (polled - woke), 1e3 * (locked - polled))
                    last_late_log = now
                if (last_progress is None or progress.seq != last_progress.seq
                        or now - last_progress_at >= PROGRESS_PERIOD):
                    self._publish_progress(progress)
                    last_progress, last_progress_at = progress, now
                marks = [woke, polled, locked, filled, published, time.perf_counter(), 0.0]
            except Exception:  # the engine must outlive a bug: log it, drop the motions, go on
                log.exception("streamer iteration failed; aborting the queue")
                with self._lock:
                    self._abort("internal error")
                busy = False
                marks = [woke] * 7
            asked = STREAM_BLOCK if busy else STREAMER_IDLE  # a control call or new work wakes it early
            self._wake.wait(asked)
            self._wake.clear()
            marks[6] = time.perf_counter()

    def _has_work(self, now: float) -> bool:
        return not self._idle(now)

    def _on_status(self, st: ServoStatus, now: float) -> None:
        """Track the servo: FIFO depth, and the reasons to abort (lock held)."""
        self._status, self._status_at = st, now
        self._fifo.report(st.fifoDepth, st.tm.to_seconds(), now)
        moving = self._active is not None or bool(self._inflight) or now < self._busy_until
        if not st.servoOn and self._has_work(now):
            self._abort("the servo is off")
        elif st.alarm and self._has_work(now):
            self._abort("the servo raised an alarm")
        elif self._underruns is not None and st.underruns > self._underruns and moving:
            self._abort(f"the servo ran out of position commands ({st.underruns - self._underruns} "
                        f"underruns; {self._fifo.depth(now):.0f} estimated in its FIFO, status "
                        f"{(now - st.tm.to_seconds()) * 1e3:.1f} ms old)")
        self._underruns = st.underruns

    def _fill(self, now: float) -> bytes | None:
        """The commands to send now to keep ``lead`` of them in the servo FIFO, as one
        ``PositionBlock`` (lock held); None if there is nothing to send."""
        depth = self._fifo.depth(now)
        want = int(round(self.lead / self.period)) - int(depth)
        rows: list[list[float]] = []
        while len(rows) < want:
            q = self._next_sample(now)
            if q is None:
                break
            self._busy_until = now + (depth + len(rows)) * self.period
            rows.append(q.tolist())
        self._fifo.sent(now, len(rows))
        return messages.position_block_payload(now + depth * self.period, rows) if rows else None

    def _next_sample(self, now: float) -> Joints | None:
        """The next command, advancing through segments and the queue; None when there is none."""
        while True:
            seg = self._active
            if seg is None:
                if self._paused or not self._queue:
                    return None
                motion = self._queue.popleft()
                if self._idle(now) and not self._starts_at_servo(motion):
                    return None
                self._active = seg = _Segment(motion, motion.profile, motion.q, _Kind.RUN, nominal=True)
                log.debug("motion %d starts (%.3f s)", motion.motion, motion.duration)
            blend = self._queue[0].blend if seg.nominal and self._queue else None
            if (blend is not None and seg.kind is _Kind.RUN and blend.previous == seg.motion.motion
                    and seg.k == blend.cut + 1):  # the cut is sent: the blend into the next motion takes over
                self._segment_done(seg, max(now, self._busy_until))
                motion = self._queue.popleft()
                self._active = _Segment(motion, motion.profile, blend.trajectory.q, _Kind.RUN,
                                        joint=blend.trajectory, blend=blend)
                log.debug("motion %d starts in its blend (%.3f s)", motion.motion, blend.trajectory.duration)
                continue
            if seg.k < len(seg.q):
                q = seg.q[seg.k]
                seg.k += 1
                self._last_sent = q
                return q
            if seg.kind is _Kind.RUN and seg.motion is self._early:  # not accepted yet: brake on the head
                log.warning("the early start's head ran out before its motion was planned: braking on it")
                self._active = seg.brake(_Kind.PAUSE)
                continue
            self._segment_done(seg, max(now, self._busy_until))

    def _starts_at_servo(self, motion: PlannedMotion) -> bool:
        """False (and abort) if the servo does not hold the arm where ``motion`` starts."""
        st = self._status
        if st is None or len(st.target) != self.dof:
            return True
        gap = float(np.max(np.abs(np.array(st.target) - motion.start)))
        if gap <= START_TOLERANCE:
            return True
        self._queue.appendleft(motion)
        self._abort(f"the servo holds the arm {gap:.3g} away from where motion {motion.motion} starts")
        return False

    def _segment_done(self, seg: _Segment, due: float) -> None:
        """Every sample of ``seg`` has been sent; ``due`` is when the last one is consumed."""
        self._active = None
        if seg.kind is _Kind.RUN:
            if seg.joint is not None:  # the blend, or the way back onto the path: the path follows
                self._active = seg.path_after()
            else:
                self._inflight.append((seg.motion.motion, due))
        elif seg.kind is _Kind.PAUSE:
            if seg.joint is None and seg.profile.finished_at_end:  # it could only stop at the end: the motion is done
                self._inflight.append((seg.motion.motion, due))
            elif seg.resume_after and seg.motion is not self._early:
                self._active = seg.then or seg.resumed()
            else:
                self._held = seg
                if seg.motion is self._early:
                    log.info("the early start holds on its head until its motion is planned")
                elif seg.joint is not None:
                    log.info("paused: motion %d holds in its blend", seg.motion.motion)
                else:
                    log.info("paused: motion %d holds at %.1f %% of its path", seg.motion.motion,
                             100.0 * seg.profile.s_end / seg.profile.length)
