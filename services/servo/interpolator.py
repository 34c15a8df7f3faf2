"""The servo's interpolator: buffered trajectories, executed with a time scale.

The planner hands over each accepted motion whole (``schema/motion.py``): joint
samples at the servo's cycle, the first being where it takes over. The
interpolator keeps them in order and gives the control law one target per
cycle, at a position ``tau`` [samples] along the running one that advances by
the *scale* each cycle (1: as planned). Pause, resume, stop and the speed
override only change the scale's target; the scale follows it jerk-limited
(Ruckig, one degree of freedom), so the arm slows down and speeds up on the
planned path, never off it. This is how industrial controllers do it (KUKA's
``$OV_PRO``, the speed sliders of ABB and UR): the path is planned once, the
real-time part scales time along it.

* Rate of the scale [1/s]: slowing along a path adds ``|dq/dtau| * d(scale)/dt``
  to each axis' acceleration, so per trajectory the rate is the largest that
  keeps this within each axis' rated acceleration (rated speed / min accel
  time) at the trajectory's peak speed; ``RATE_MAX`` where it barely moves.
* Motions follow each other with no gap (each one's first sample is the
  previous one's last) and complete in order; a blend replaces the tail of the
  motion before it from a future sample on (its *splice*), refused
  (``TrajectoryRefusal.LATE``) once ``tau`` has passed that sample.
* A head (``final`` false: an early start whose rest is still being planned)
  is run with the scale capped so that it could still slow to 0 before its
  last sample (:func:`head_cap`): a late rest slows the arm down, it never
  brakes it to a stop on the head and starts it again. The rest splices onto
  the head.
* ``stop``: the scale goes to 0, then every buffered motion is discarded; the
  epoch changes at once, so a trajectory planned against the old queue is
  refused (``TrajectoryRefusal.STALE``). ``abort``: everything is discarded at once (the
  control law then brakes the arm off the path, within its limits).

No I/O, no clock, no logging: :class:`~.loop.ServoLoop` drives it once per cycle
and publishes what it says; ``tests/test_interpolator.py`` checks it in
microseconds. Nothing here raises on the real-time path: a trajectory is
checked (:func:`prepare`) before it reaches the cycle.
"""

from __future__ import annotations

import collections
import dataclasses
import math

import numpy as np
from ruckig import InputParameter, OutputParameter, Result, Ruckig

from jara_arm.schema.motion import MotionAction, MotionProgress, TrajectoryRefusal
from jara_arm.schema.types import Time

#: Fastest change of the scale [1/s]: 0 to 1 in 50 ms where the arm barely moves.
RATE_MAX = 20.0
#: The scale's acceleration reaches its limit in this time [s]: the jerk of the change
#: (the control law's braking uses the same, ``control.BRAKE_JERK_TIME``).
JERK_TIME = 0.02
#: A trajectory must start this close to where it takes over [rad or m]: the planner
#: plans from the exact samples the servo holds, so this is rounding only. From rest,
#: one that starts further from the held target was planned from an older hold (a
#: servoON holds the arm where the brakes left it): it is stale, planned again, never
#: joined by a step of the command.
START_TOLERANCE = 1e-6
#: A head keeps this share of the stopping distance it has left as margin [-]: the scale
#: follows a cap that falls every cycle, with a lag.
HEAD_MARGIN = 0.5
#: A head whose rest arrives after this many samples passed drops them [samples]: only a jog's, which is
#: extended for as long as it is held; an early start's head is 30 samples, and keeps its share of its motion.
TRIM_AFTER = 2000


@dataclasses.dataclass
class Buffered:
    """One motion's samples as the interpolator runs them."""

    motion: int
    q: np.ndarray  # (N, dof); row 0 is where it takes over; its tail may be replaced by a splice
    final: bool
    rate: float  # [1/s] fastest change of the scale along it
    #: The samples and their screen before a splice cut them (restored if the splice is discarded).
    full: tuple[np.ndarray, np.ndarray | None] | None = None
    #: Per segment (samples i to i+1): every target a cycle can take in it passes the control law's
    #: checks against the soft limits ``limits`` (``ControlLaw.screen``); None: not screened.
    screened: np.ndarray | None = None
    limits: object = None
    #: Its last two samples are the same: it ends at rest. A head that does (a jog's, which ends in its
    #: stop) needs no cap: the arm stops on its samples, and holding at its end is no late rest.
    rests: bool = False

    @property
    def end(self) -> int:
        return len(self.q) - 1

    def screen(self, screened: np.ndarray, limits: object) -> None:
        """Attach ``ControlLaw.screen``'s verdict (off the real-time path, before :meth:`Interpolator.submit`)."""
        self.screened, self.limits = screened, limits

    def screened_at(self, i: int) -> object:
        """The limits segment ``i`` was screened against, or None if a cycle in it needs every check."""
        s = self.screened
        return self.limits if s is not None and 0 <= i < len(s) and s[i] else None


def scale_rate(q: np.ndarray, dt: float, max_accel: np.ndarray) -> float:
    """[1/s] the fastest change of the scale along samples ``q`` (see the module docstring)."""
    if len(q) < 2:
        return RATE_MAX
    speed = np.abs(np.diff(q, axis=0)).max(axis=0) / dt  # [rad/s or m/s] peak per axis
    moving = speed > 1e-9
    if not moving.any():
        return RATE_MAX
    return float(min(RATE_MAX, np.min(max_accel[moving] / speed[moving])))


def prepare(motion: int, rows: np.ndarray, final: bool, dt: float, max_accel: np.ndarray) -> Buffered:
    """A trajectory ready to hand to :meth:`Interpolator.submit` (off the real-time path)."""
    q = np.array(rows, dtype=float)
    rests = len(q) >= 2 and bool(np.array_equal(q[-1], q[-2]))
    return Buffered(motion, q, final, scale_rate(q, dt, max_accel), rests=rests)


def head_cap(remaining: float, rate: float) -> float:
    """The highest scale from which the scale can still reach 0 within ``remaining`` [s of
    planned time] (with ``HEAD_MARGIN``), at ``rate`` [1/s] and the jerk of ``JERK_TIME``.

    Slowing from ``r`` at ``rate`` covers ``r**2 / (2 rate)`` of planned time, plus about
    ``2 r JERK_TIME`` while the rate ramps in.
    """
    budget = max(0.0, remaining) * HEAD_MARGIN
    t = 2.0 * JERK_TIME
    return rate * (-t + math.sqrt(t * t + 2.0 * budget / rate))


class Interpolator:
    """The buffered motions of one arm and the scale they run at (see the module docstring)."""

    def __init__(self, dof: int, dt: float) -> None:
        self.dof, self.dt = dof, dt
        self.queue: collections.deque[Buffered] = collections.deque()
        self.tau = 0.0  # [samples] along queue[0]
        self.scale = 1.0  # [-] samples per cycle
        self._scale_v = 0.0  # [1/s]
        self._scale_a = 0.0  # [1/s²]
        self.override = 1.0  # [-]
        self.paused = False
        self.stopping = False
        self.epoch = 1
        self.last_done = 0
        self.last_discarded = 0
        self.ran_out = 0  # cycles a head held at its last sample, waiting for its rest
        self.done: list[int] = []  # motions completed since the caller last emptied it
        #: The soft limits the target :meth:`next` gave last was screened against (``Buffered.screen``),
        #: or None: the control law checks it in full.
        self.screened: object = None
        self._state_key: tuple[object, ...] = ()
        self._state_samples: object = None
        self._state: tuple[object, ...] = ()
        self._otg = Ruckig(1, dt)
        self._inp = InputParameter(1)
        self._out = OutputParameter(1)
        self._inp.target_velocity = [0.0]
        self._inp.target_acceleration = [0.0]

    def release(self) -> None:
        """Free Ruckig's objects now (at exit, nanobind reports the ones still alive as leaks)."""
        del self._otg, self._inp, self._out

    # -- state --------------------------------------------------------------------------
    @property
    def active(self) -> bool:
        """It has motions: it gives the target every cycle."""
        return bool(self.queue)

    @property
    def holding(self) -> bool:
        """Paused and at rest on the path: nothing changes until a resume, stop or abort."""
        return self.paused and self.scale == 0.0 and self._scale_v == 0.0

    @property
    def running(self) -> int:
        return self.queue[0].motion if self.queue else 0

    @property
    def head(self) -> int:
        """The last buffered motion if it is a head waiting for its rest, else 0."""
        return self.queue[-1].motion if self.queue and not self.queue[-1].final else 0

    def tail(self, held: np.ndarray) -> np.ndarray | None:
        """Where the next motion starts: the end of the last buffered one, or ``held`` (the target
        the servo holds) when none; None while stopping or while a head is last."""
        if self.stopping or self.head:
            return None
        return self.queue[-1].q[-1] if self.queue else held

    def state(self, held: np.ndarray) -> tuple[object, ...]:
        """What ``Servo/motion`` says but its time and the scale (``held``: the target the servo holds):
        a new value is a new ``seq``."""
        queue = self.queue
        # Every cycle: built again only when what it is made of changed (a splice replaces q; the
        # held target is replaced, never changed in place).
        samples = queue[-1].q if queue else held
        key = (self.epoch, len(queue), queue[-1].final if queue else True,
               self.last_done, self.last_discarded, self.paused, self.holding, self.stopping, self.override)
        if key == self._state_key and samples is self._state_samples:
            return self._state
        tail = self.tail(held)
        self._state_key, self._state_samples = key, samples
        self._state = (self.epoch, tuple(b.motion for b in queue), self.head, self.last_done, self.last_discarded,
                       self.paused, self.active and not self.holding, self.stopping, self.override,
                       () if tail is None else tuple(tail.tolist()))
        return self._state

    def progress(self, state: tuple[object, ...], started: Time, seq: int) -> MotionProgress:
        """``Servo/motion`` from :meth:`state`, of the servo process ``started``, numbered ``seq``; its
        ``runningShare`` is ``tau`` over the running motion's last sample index (a head's known so far)."""
        epoch, queued, head, done, discarded, paused, moving, stopping, override, tail = state
        end = self.queue[0].end if self.queue else 0
        share = self.tau / end if end > 0 else 0.0
        return MotionProgress(Time.now(), epoch, self.running, queued, head, done, discarded, paused,
                              moving, stopping, override * 100.0, self.scale, tail, started, seq, share,
                              max(0.0, end - self.tau))

    # -- from the planner (called on the loop's thread, between cycles) ------------------
    def submit(self, traj: Buffered, epoch: int, after: int, splice: int, held: np.ndarray,
               at_rest: bool) -> tuple[TrajectoryRefusal | None, str]:
        """Buffer ``traj`` behind ``after`` (see ``schema/motion.Trajectory``); ``held``: the target
        the servo holds, ``at_rest``: nothing else moves the arm. Returns (refusal or None, why)."""
        if epoch != self.epoch:
            return TrajectoryRefusal.STALE, f"planned in epoch {epoch}, the servo is in epoch {self.epoch} (stopped since)"
        if self.stopping:
            return TrajectoryRefusal.STALE, "the servo is stopping the queue"
        last = self.queue[-1] if self.queue else None
        if last is not None and after == last.motion:
            return self._splice(traj, last, splice)
        if last is not None:
            return TrajectoryRefusal.STALE, f"motion {after} is not the last buffered one ({last.motion} is)"
        if splice >= 0 and after != 0:
            return TrajectoryRefusal.LATE, f"motion {after} has ended: too late for a splice into it"
        if not at_rest:
            return TrajectoryRefusal.STATE, "the arm is moving (a low-level client's stream, or a stop)"
        gap = float(np.max(np.abs(traj.q[0] - held)))
        if gap > START_TOLERANCE:
            return TrajectoryRefusal.STALE, (f"it starts {gap:.3g} away from where the servo holds the arm "
                                             "(planned from an older hold)")
        self.queue.append(traj)
        self.tau = 0.0
        # From rest the speed is 0: the scale may take its value at once.
        self.scale = min(self._target(), self._cap(traj, 0.0))
        self._scale_v = self._scale_a = 0.0
        return None, "buffered"

    def _splice(self, traj: Buffered, last: Buffered, splice: int) -> tuple[TrajectoryRefusal | None, str]:
        k = last.end + 1 + splice if splice < 0 else splice  # negative: counted from the end (-1: the last)
        if not 0 <= k <= last.end:
            return TrajectoryRefusal.START, f"splice {splice} is outside motion {last.motion}'s samples 0..{last.end}"
        if len(self.queue) == 1 and self.tau > k:
            return TrajectoryRefusal.LATE, f"motion {last.motion} is past sample {k}"
        gap = float(np.max(np.abs(traj.q[0] - last.q[k])))
        if gap > START_TOLERANCE:
            return TrajectoryRefusal.START, f"it starts {gap:.3g} away from sample {k} of motion {last.motion}"
        if traj.motion == last.motion:  # the rest of a head
            # A jog's head is extended for as long as it runs: the samples the servo has passed go, so that an
            # extension costs the same after a minute as after a second (not an early start's short head).
            cut = int(self.tau) if len(self.queue) == 1 and self.tau >= TRIM_AFTER else 0
            last.q = np.concatenate([last.q[cut:k], traj.q])
            self.tau -= cut
            last.final, last.rate, last.full, last.rests = traj.final, min(last.rate, traj.rate), None, traj.rests
            if last.screened is not None and traj.screened is not None and traj.limits is last.limits and k > cut:
                # The segment into the joint ends on the rest's first sample, not the head's: checked in full.
                last.screened = np.concatenate([last.screened[cut:k - 1], [False], traj.screened])
            else:
                last.screened = None
            return None, "joined to its head"
        if not last.final:
            return TrajectoryRefusal.STATE, f"motion {last.motion} is a head still waiting for its rest"
        if k < last.end:
            last.full = last.q, last.screened
            last.q = last.q[:k + 1]
            last.screened = None if last.screened is None else last.screened[:k]
        self.queue.append(traj)
        return None, "buffered" if splice < 0 else f"spliced into motion {last.motion} at sample {k}"

    def control(self, action: MotionAction, ratio: float = 1.0) -> str:
        """Apply a pause, resume, stop or override (``ratio`` [-], 0..1); returns what it did."""
        if action is MotionAction.OVERRIDE:
            self.override = ratio
            if not self.queue:
                self.scale, self._scale_v, self._scale_a = ratio, 0.0, 0.0
            return f"OK: speed override {ratio * 100:.0f} %"
        if action is MotionAction.ABORT:
            ids = self.discard()
            return f"OK: motions {ids} discarded" if ids else "OK: nothing to abort"
        if action is MotionAction.PAUSE:
            if self.paused:
                return "OK: ignored, already paused"
            if self.stopping:
                return "OK: ignored, stopping"
            if not self.queue:
                return "OK: ignored, not moving"
            self.paused = True
            return f"OK: pausing, decelerating along the path in {self._time_to(0.0):.3f} s"
        if action is MotionAction.RESUME:
            if not self.paused:
                return "OK: ignored, not paused"
            self.paused = False
            return "OK: resumed"
        if action is MotionAction.STOP:
            if not self.queue:
                self.paused = False
                return "OK: ignored, not moving"
            # Only the running motion is left to slow down on: its own samples, to its end at rest.
            dropped = [b.motion for b in list(self.queue)[1:]]
            while len(self.queue) > 1:
                self.queue.pop()
            first = self.queue[0]
            if first.full is not None:
                (first.q, first.screened), first.full = first.full, None
            if dropped:
                self.last_discarded = max(self.last_discarded, max(dropped))
            self.stopping, self.paused = True, False
            self.epoch += 1
            return (f"OK: stopping in {self._time_to(0.0):.3f} s, "
                    f"{len(dropped) + 1} motions discarded")
        raise ValueError(f"unknown action {action!r}")  # pragma: no cover - MotionAction is closed

    def discard(self) -> list[int]:
        """Forget every buffered motion now; a new epoch. Returns their ids."""
        ids = [b.motion for b in self.queue]
        self.queue.clear()
        if ids:
            self.last_discarded = max(self.last_discarded, max(ids))
        self.tau = 0.0
        self.paused = self.stopping = False
        self.scale, self._scale_v, self._scale_a = self.override, 0.0, 0.0
        self.epoch += 1
        return ids

    # -- each cycle ------------------------------------------------------------------------
    def next(self) -> np.ndarray | None:
        """This cycle's target [rad or m], or None when nothing is buffered."""
        if not self.queue:
            return None
        cur = self.queue[0]
        target = min(self._target(), self._cap(cur, self.tau))
        self._follow(target, cur.rate)
        tau = self.tau + self.scale
        while tau >= cur.end:
            if not cur.final:  # a head at its last sample: hold there until its rest comes
                tau = float(cur.end)
                if self.scale > 0.0 and not cur.rests:
                    self.ran_out += 1
                self.scale, self._scale_v, self._scale_a = 0.0, 0.0, 0.0
                break
            if len(self.queue) == 1 or self.stopping:
                self.queue.popleft()
                self._completed(cur)
                if self.stopping:
                    self._stopped()
                self.tau = 0.0
                self.screened = cur.screened_at(cur.end - 1)  # the end of the last segment
                return cur.q[-1].copy()
            tau -= cur.end
            self.queue.popleft()
            self._completed(cur)
            cur = self.queue[0]
        self.tau = tau
        # The segment whose end the cycle before may have been at too: tau in (i, i + 1] is segment i.
        self.screened = cur.screened_at(min(max(0, math.ceil(tau) - 1), cur.end - 1))
        if self.stopping and self.scale == 0.0 and self._scale_v == 0.0:
            q = self._at(cur, tau)
            ids = [b.motion for b in self.queue]
            self.queue.clear()
            self.last_discarded = max(self.last_discarded, max(ids))
            self._stopped()
            return q
        return self._at(cur, tau)

    def _completed(self, b: Buffered) -> None:
        self.last_done = b.motion
        self.done.append(b.motion)

    def _stopped(self) -> None:
        self.stopping = False
        self.tau = 0.0
        self.scale, self._scale_v, self._scale_a = self.override, 0.0, 0.0

    @staticmethod
    def _at(b: Buffered, tau: float) -> np.ndarray:
        i = min(int(tau), b.end - 1)
        f = tau - i
        return b.q[i] + f * (b.q[i + 1] - b.q[i])

    def _target(self) -> float:
        return 0.0 if (self.paused or self.stopping) else self.override

    def _cap(self, b: Buffered, tau: float) -> float:
        if b.final or b.rests:
            return 1.0
        return head_cap((b.end - tau) * self.dt, b.rate)

    def _follow(self, target: float, rate: float) -> None:
        """Move the scale one cycle towards ``target``, jerk-limited (Ruckig)."""
        if self.scale == target and self._scale_v == 0.0 and self._scale_a == 0.0:
            return
        inp = self._inp
        inp.current_position = [self.scale]
        inp.current_velocity = [self._scale_v]
        inp.current_acceleration = [self._scale_a]
        inp.target_position = [target]
        inp.max_velocity = [rate]
        inp.max_acceleration = [rate / JERK_TIME]
        inp.max_jerk = [rate / JERK_TIME ** 2]
        result = self._otg.update(inp, self._out)
        if result == Result.Finished:
            self.scale, self._scale_v, self._scale_a = target, 0.0, 0.0
        elif result == Result.Working:
            self.scale = min(1.0, max(0.0, self._out.new_position[0]))
            self._scale_v, self._scale_a = self._out.new_velocity[0], self._out.new_acceleration[0]
        else:  # never on valid limits; hold the target rather than leave the arm without one
            self.scale, self._scale_v, self._scale_a = target, 0.0, 0.0

    def _time_to(self, target: float) -> float:
        """[s] for the scale to reach ``target`` from where it is (for the replies)."""
        rate = self.queue[0].rate if self.queue else RATE_MAX
        return abs(self.scale - target) / rate + abs(self._scale_v) / (rate / JERK_TIME) + JERK_TIME
