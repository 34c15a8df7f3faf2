"""The control law of one arm: each cycle's target, and the safety rules on every command.

No I/O: no Zenoh, no PyBullet, no clock, no logging. The law holds the
commanded state (target ``q``, its velocity ``qd`` and acceleration ``qdd``),
the SyncFIFO and any stop in progress; :meth:`ControlLaw.advance` chooses the
next target and returns what the loop must act on (a :class:`Refusal` to
raise as an alarm, :data:`RAN_DRY`, :data:`STOPPED`). ``loop.py`` does the
acting, the stepping and the publishing; ``tests/test_control.py`` checks
every rule below in microseconds.

Rules on a position command (``follow``):

* not finite, or asking an axis for more than ``OVERSPEED_MARGIN`` times its
  rated speed (a jump): refused, ``OVERSPEED`` FAULT;
* outside the joint soft limits: refused, ``SOFT_LIMIT_JOINT`` WARNING;
* heading so fast towards a soft limit that the shortest stop would pass it:
  refused, ``SOFT_LIMIT_JOINT`` WARNING (so that the stop from the last
  applied command always ends inside);
* the gripper axis is clamped into its hard limits, not refused;
* after a stream ran dry, only a stream that starts again from rest where the
  arm stopped is followed: a command within ``RESUME_TOLERANCE`` of the held
  target, then ``RESUME_CYCLES`` commands that accelerate no harder than the
  limit stop (``LIMIT_STOP_ACCEL``); a stream that goes on mid-motion through
  the held target fails the second test and stays stale.

A refused command is not applied. Stops (``brake``) are jerk-limited (Ruckig,
``braking.py``) and their targets are clamped into the soft limits, the last
line of defence.
"""

from __future__ import annotations

import collections
import dataclasses
from typing import Final

import numpy as np

from jara_arm.robots import RobotModel
from jara_arm.schema.codes import AlarmCode, AlarmType
from jara_arm.schema.types import LimitValue

from .braking import Braking, Glide

#: A command may ask for at most this multiple of an axis' rated speed [-];
#: beyond it the stream is taken as a jump: OVERSPEED fault, controlled stop.
OVERSPEED_MARGIN = 1.1
#: Jerk of a controlled stop: full deceleration is reached in this time [s].
BRAKE_JERK_TIME = 0.02
#: Below this speed an axis counts as at rest [rad/s or m/s].
REST_SPEED = 1e-3
#: A stop in front of a joint soft limit may decelerate at up to this multiple of an
#: axis' max_accel (rated speed / min accel time) [-]: the peak deceleration of the
#: planner's S-curve at the min accel time (2 v / T), so that a planned motion that
#: ends on a limit is never taken for one that would overrun it.
LIMIT_STOP_ACCEL = 2.0
#: After the stream ran dry, a command this close to the held target counts as starting
#: from rest there (e.g. a client that starts from the measured joints) [rad or m].
RESUME_TOLERANCE = 1e-4
#: ... and for this many cycles after it, each command must accelerate the arm no harder than
#: the limit stop does: a stream that merely passes the held target mid-motion would otherwise
#: step the velocity from zero to its own in one cycle (0.38 rad/s on the iiwa's J1, 375 rad/s²,
#: seen beside a busy loop per core). A real start from rest is jerk-limited: its first steps are
#: far below [cycles].
RESUME_CYCLES = 10
#: After a stop for an alarm, a target this far from the measured joints means the
#: arm is blocked (an obstacle): it is then held where it is, not pushed on [rad or m].
RELAX_TOLERANCE = 0.01
#: ... bringing the target there in this time, so that the push fades rather than drops [s].
RELAX_TIME = 0.2
#: Slack of the "stops before the soft limit" check, for rounding only [rad or m].
_LIMIT_EPS = 1e-9


@dataclasses.dataclass(frozen=True)
class Refusal:
    """A command the law did not apply, and the alarm it calls for."""

    code: AlarmCode
    kind: AlarmType
    description: str


#: :meth:`ControlLaw.advance`: the FIFO was empty while the arm moved; a controlled stop began.
RAN_DRY: Final = "ran dry"
#: :meth:`ControlLaw.advance`: a stop (or a glide) ended this cycle.
STOPPED: Final = "stopped"


class ControlLaw:
    """The commanded state of one arm and the rules that change it (see the module docstring)."""

    def __init__(self, model: RobotModel, q: np.ndarray) -> None:
        """``q``: the joints [rad or m] to hold at first, one per wire axis."""
        self.model = model
        self.dt = model.cmd_cycle
        self._per_cycle = 1.0 / self.dt  # [1/s]
        n = model.dof
        self.q = np.array(q, dtype=float)
        self.qd, self.qdd = np.zeros(n), np.zeros(n)
        self.fifo: collections.deque[np.ndarray] = collections.deque()
        self.braking: Braking | Glide | None = None  # a stop, or letting go of a push
        self.moving = False  # the commanded velocity qd is not all zero
        self.interrupted = False  # the stream ran dry mid-motion; wait for a consistent command
        self._resuming = 0  # cycles left in which a resumed stream must accelerate as from rest
        self.consumed = 0  # commands taken from the FIFO
        self.stale = 0  # commands of an interrupted stream, dropped

        self._vmax = np.array(list(model.rated_speed) + ([model.gripper_speed] if model.has_gripper else []))
        self._amax = self._vmax / model.min_accel_time
        self._jmax = self._amax / BRAKE_JERK_TIME
        self._limit_amax = self._amax * LIMIT_STOP_ACCEL
        self._limit_jmax = self._limit_amax / BRAKE_JERK_TIME
        self._step_max = self._vmax * self.dt * OVERSPEED_MARGIN  # [rad or m] per cycle
        # Stopping distance bound (overruns_soft_limit) = (v + a·T)·((v + a·T)/(2a) + 2T).
        arm_amax = self._limit_amax[:model.axis_num]
        self._reach_at = arm_amax * BRAKE_JERK_TIME
        self._reach_half_inv_a = 0.5 / arm_amax
        grip = model.gripper_limits
        self._hard = list(model.hard_limits) + ([grip] if grip else [])
        self.soft_limits = model.hard_limits

    @property
    def soft_limits(self) -> tuple[LimitValue, ...]:
        """[rad or m] the joint soft limits in force, one per arm axis."""
        return self._soft_limits

    @property
    def max_accel(self) -> np.ndarray:
        """[rad/s² or m/s²] each wire axis' rated acceleration: rated speed / min accel time."""
        return self._amax

    @soft_limits.setter
    def soft_limits(self, limits: tuple[LimitValue, ...]) -> None:
        # Kept as arrays too: every command is checked against them.
        self._soft_lower = np.array([lim.lower for lim in limits])
        self._soft_upper = np.array([lim.upper for lim in limits])
        # The same bounds for a whole command; the gripper axis is clamped, not checked.
        free = [np.inf] * (self.model.dof - len(limits))
        self._cmd_lower = np.array([lim.lower for lim in limits] + [-x for x in free])
        self._cmd_upper = np.array([lim.upper for lim in limits] + free)
        # For screen(): the gripper axis inside its hard limits, so that no clamp is left to do.
        grip = [self._hard[i] for i in range(len(limits), self.model.dof)]
        self._screen_lower = np.array([lim.lower for lim in limits] + [g.lower for g in grip])
        self._screen_upper = np.array([lim.upper for lim in limits] + [g.upper for g in grip])
        # Last: screen() runs on another thread and tags its verdict with the limits it read first.
        self._soft_limits = limits

    # -- off the real-time path -----------------------------------------------------------
    def screen(self, q: np.ndarray) -> tuple[np.ndarray, tuple[LimitValue, ...]]:
        """Which segments of samples ``q`` (N, dof) [rad or m], run at the servo cycle, need no
        check in the cycle, and the soft limits this holds for.

        Segment i (samples i to i+1) passes when any target a cycle can take in it,
        run at a time scale of at most 1 (``interpolator.py``), would pass every check
        of :meth:`follow` from the target of the cycle before: both samples inside the
        soft limits (the gripper inside its hard limits: nothing to clamp), a step of
        at most ``max(|q[i] - q[i-1]|, |q[i+1] - q[i]|)`` within the jump bound, and
        the cheap stopping-distance bound of :meth:`overruns_soft_limit` at that speed
        clear of both limits. Segment 0 never passes: the cycle before may have been
        anywhere (rest, another motion's end). A NaN fails every comparison.
        The exact check (Ruckig) stays in the cycle for the segments near a limit.
        """
        limits = self._soft_limits
        if len(q) < 3:
            return np.zeros(max(0, len(q) - 1), dtype=bool), limits
        seg = np.abs(np.diff(q, axis=0))  # (N-1, dof)
        step = seg.copy()
        step[1:] = np.maximum(seg[:-1], seg[1:])
        ok = (step <= self._step_max).all(axis=1)
        inside = ((q >= self._screen_lower) & (q <= self._screen_upper)).all(axis=1)
        ok &= inside[:-1] & inside[1:]
        n = self.model.axis_num
        va = step[:, :n] * self._per_cycle + self._reach_at
        reach = va * (va * self._reach_half_inv_a + 2 * BRAKE_JERK_TIME)
        high = np.maximum(q[:-1, :n], q[1:, :n]) + reach
        low = np.minimum(q[:-1, :n], q[1:, :n]) - reach
        ok &= ((high <= self._soft_upper) & (low >= self._soft_lower)).all(axis=1)
        ok[0] = False
        return ok, limits

    # -- each cycle ---------------------------------------------------------------------
    def advance(self, enabled: bool, screened: object = None) -> Refusal | str | None:
        """Choose this cycle's target: go on stopping, follow the FIFO, or hold.

        ``enabled``: the servo is on and no alarm is active (otherwise the FIFO is
        not followed). ``screened``: the soft limits the FIFO's next command passed
        :meth:`screen` against (the interpolator's), None if it did not; it is taken
        without the checks while they are still the limits in force. Returns a
        :class:`Refusal` (the FIFO's next command was not applied; the caller raises
        its alarm, which stops the arm), :data:`RAN_DRY` (a controlled stop began),
        :data:`STOPPED` (a stop ended) or None.
        """
        if self.braking is not None:
            q, self.qd, self.qdd, done = self.braking.next()
            self.q = self.inside_soft_limits(q)
            self.moving = not done
            if done:
                self.braking = None
                return STOPPED
            return None
        if enabled and self.fifo:
            self.consumed += 1
            cmd = self.fifo.popleft()
            if screened is not None and screened is self._soft_limits and not (self.interrupted or self._resuming):
                qd = (cmd - self.q) * self._per_cycle
                self.qdd = (qd - self.qd) * self._per_cycle
                self.q, self.qd = cmd, qd
                self.moving = True
                return None
            return self.follow(cmd)
        if self.moving and enabled and np.any(np.abs(self.qd) > REST_SPEED):
            self.interrupted = True
            self.brake()
            self.advance(enabled)  # the stop starts this cycle
            return RAN_DRY
        if self.moving:
            self._still()
            self.moving = False
        return None

    def follow(self, cmd: np.ndarray) -> Refusal | None:
        """Apply ``cmd`` [rad or m] as this cycle's target, or refuse it (see the module docstring)."""
        step = cmd - self.q
        if not self.interrupted and ((cmd >= self._cmd_lower) & (cmd <= self._cmd_upper)
                                     & (np.abs(step) <= self._step_max)).all():
            # Every check below passes (a NaN fails every comparison): the usual command, in
            # a fraction of the work. Only the stop before a soft limit is left to check.
            self._clamp_gripper(cmd)
            return self._apply(cmd, step)
        if self.interrupted:
            # Joining a moving stream halfway would step the velocity from zero to the
            # stream's in one cycle.
            if np.any(np.abs(step) > RESUME_TOLERANCE):
                self.stale += 1
                return None
            self.interrupted = False
            refusal = self._checked(cmd, step)
            if refusal is None:  # taken up at rest: the tolerance is a position correction, not a speed
                self._still()
                self._resuming = RESUME_CYCLES
            return refusal
        return self._checked(cmd, step)

    def _checked(self, cmd: np.ndarray, step: np.ndarray) -> Refusal | None:
        """``cmd`` through every check of :meth:`follow`, applied if it passes."""
        if not np.all(np.isfinite(cmd)):
            return Refusal(AlarmCode.OVERSPEED, AlarmType.FAULT, "non-finite position command")
        axis = self.model.axis_num
        outside = (cmd[:axis] < self._soft_lower) | (cmd[:axis] > self._soft_upper)
        if outside.any():
            i = int(np.argmax(outside))
            lim = self.soft_limits[i]
            return Refusal(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
                           f"position command J{i + 1}={cmd[i]:.6g} outside the joint soft limit "
                           f"[{lim.lower:.6g}, {lim.upper:.6g}]; not applied")
        self._clamp_gripper(cmd)
        if (np.abs(step) > self._step_max).any():
            i = int(np.argmax(np.abs(step) / (self._vmax * self.dt)))
            return Refusal(AlarmCode.OVERSPEED, AlarmType.FAULT,
                           f"position command asks J{i + 1} for {abs(step[i]) / self.dt:.3g} per s, "
                           f"above {OVERSPEED_MARGIN:g} x its rated {self._vmax[i]:.3g}; not applied")
        return self._apply(cmd, step)

    def _clamp_gripper(self, cmd: np.ndarray) -> None:
        if self.model.has_gripper:
            axis = self.model.axis_num
            g = self._hard[axis]
            cmd[axis] = min(max(cmd[axis], g.lower), g.upper)

    def _apply(self, cmd: np.ndarray, step: np.ndarray) -> Refusal | None:
        """Follow ``cmd``, which passed every check but the stop before a soft limit."""
        qd = step * self._per_cycle
        qdd = (qd - self.qd) * self._per_cycle
        if self._resuming:
            self._resuming -= 1
            if np.any(np.abs(qdd) > self._limit_amax):  # not a start from rest: the stream is stale still
                self._resuming = 0
                self.interrupted = True
                self.stale += 1
                self._still()
                return None
        i = self.overruns_soft_limit(cmd, qd, qdd)
        if i is not None:
            lim = self.soft_limits[i]
            return Refusal(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
                           f"position command J{i + 1}={cmd[i]:.6g} at {qd[i]:.3g} per s could not stop "
                           f"before the joint soft limit [{lim.lower:.6g}, {lim.upper:.6g}]; not applied")
        self.q, self.qd, self.qdd = cmd, qd, qdd
        self.moving = True
        return None

    def overruns_soft_limit(self, q: np.ndarray, qd: np.ndarray, qdd: np.ndarray) -> int | None:
        """The first arm axis whose shortest stop from (q, qd, qdd) would leave its soft limit.

        The exact stop (Ruckig) is computed only for the axes a cheap upper bound
        of the stopping distance brings near a limit.
        """
        n = self.model.axis_num
        lower, upper = self._soft_lower, self._soft_upper
        va = np.abs(qd[:n]) + self._reach_at
        reach = va * (va * self._reach_half_inv_a + 2 * BRAKE_JERK_TIME)
        qn = q[:n]
        close = (qn + reach > upper) | (qn - reach < lower)
        if not close.any():
            return None
        near = np.flatnonzero(close)
        # Unsynchronized: every axis stops on its own, so only the near ones need computing.
        low, high = Braking(q[near], qd[near], qdd[near], self._limit_amax[near], self._limit_jmax[near],
                            self.dt, synchronized=False).extrema()
        beyond = (high > upper[near] + _LIMIT_EPS) | (low < lower[near] - _LIMIT_EPS)
        return int(near[np.argmax(beyond)]) if beyond.any() else None

    def inside_soft_limits(self, q: np.ndarray) -> np.ndarray:
        """``q`` with the arm axes clamped into the soft limits.

        A stop that starts next to a limit may not be able to end before it;
        the limit wins over smoothness there, as it is the last line of defence.
        """
        for i, lim in enumerate(self.soft_limits):
            if q[i] > lim.upper or q[i] < lim.lower:
                q[i] = min(max(q[i], lim.lower), lim.upper)
        return q

    # -- actions ------------------------------------------------------------------------
    def brake(self, before_limit: bool = False) -> None:
        """Controlled stop from the commanded state; the FIFO is emptied.

        ``before_limit``: the shortest stop of each axis, which ends inside the
        joint soft limits (every applied command was checked for it).
        """
        self.fifo.clear()
        if self.braking is None and np.any(np.abs(self.qd) > 0.0):
            if before_limit:
                self.braking = Braking(self.q, self.qd, self.qdd, self._limit_amax, self._limit_jmax,
                                       self.dt, synchronized=False)
            else:
                self.braking = Braking(self.q, self.qd, self.qdd, self._amax, self._jmax, self.dt)

    def let_go(self, measured: np.ndarray) -> tuple[int, float] | None:
        """After a stop for an alarm: if the arm did not follow its target (blocked), glide the
        target to the ``measured`` joints in ``RELAX_TIME`` and return (axis, gap [rad or m]).

        Otherwise the drives would keep pushing the arm into whatever stopped it
        (at up to their peak effort) and an overload could never go away. The
        gripper axis keeps its target: it may be holding a part.
        """
        n = self.model.axis_num
        gap = np.abs(self.q[:n] - measured[:n])
        if not np.any(gap > RELAX_TOLERANCE):
            return None
        i = int(np.argmax(gap))
        target = self.q.copy()
        target[:n] = measured[:n]
        self.braking = Glide(self.q, target, RELAX_TIME, self.dt)
        return i, float(gap[i])

    def _still(self) -> None:
        """Zero commanded speed and acceleration (the target stays)."""
        self.qd = np.zeros_like(self.qd)
        self.qdd = np.zeros_like(self.qdd)

    def hold(self, q: np.ndarray) -> None:
        """Hold ``q`` [rad or m] at rest from now on (servo on): nothing queued, nothing stopping."""
        self.q = np.array(q, dtype=float)
        self._still()
        self.moving = False
        self.fifo.clear()
        self.interrupted = False
        self._resuming = 0
