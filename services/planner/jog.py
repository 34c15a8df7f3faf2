"""Jogging: ``Ext/jogJoint``, ``Ext/jogCartesian`` and ``Ext/jogStop``, a motion that goes on while its lease is renewed.

A jog is one motion of the servo's interpolator that this module keeps extending: it is handed over as a head
(``final`` false, as an early start's), and every :data:`TICK` the jog thread appends the next samples at its
last one, so that about :data:`HORIZON` of path lies ahead of the servo. The two ways it ends:

* **The lease lapses, or ``jogStop``**: the servo is told to stop (``MotionAction.STOP``): it brakes on the
  buffered path, jerk-limited, and holds; the queue is discarded. A lapse is logged, not alarmed.
* **A limit ahead**: every extension is checked before it is handed over *with the braking that would follow
  it* (joint soft limits, the Cartesian soft-limit box, the obstacles): the arm can always stop from the end
  of what the servo holds. An extension that fails is replaced by that braking (``final``): the arm stops
  before the limit, never past it, and the reply to the next renewal names the limit. A joint jog runs to its
  soft limit exactly (the profile's target is the limit).

If this process stalls, the servo runs out of samples at the end of the head and slows down on it to a stop
(``interpolator.head_cap``): the dead-man holds without the planner.

The path: a joint jog moves one joint along its axis; a Cartesian jog moves the control point along or about
one axis of the robot frame or of its own frame, each sample solved from the one before by one damped least
squares step (Chiaverini's damping, growing near a singularity), so that near one the jog slows down instead
of asking the joints for speeds they do not have, and a jog the other way backs out. The speed along the
path follows a jerk-limited profile (Ruckig, one degree of freedom) within the settings' speed and
acceleration time; the speed override scales it in the servo, as any motion.

No I/O but through :class:`~.handover.Handover`; tests: ``tests/test_jog.py``.
"""

from __future__ import annotations

import dataclasses
import logging
import math
import threading
import time
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray
from ruckig import InputParameter, OutputParameter, Result, Ruckig

from jara_arm.kinematics import Kinematics
from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.operations import JOG_AXES, JOG_FRAMES, JOG_LEASE_MS, OP
from jara_arm.schema.planner import ControlAction, MotionSettings
from jara_arm.services.runtime.threads import LoopThread

from . import families
from .checks import Checks
from .collision import DEFAULT_MARGIN, PathChecker
from .frames import Frames
from .handover import Handover
from .profile import ProfileLimits, stop_profile
from .request import PlanRefused
from .sampling import BatchFk
from .trajectory import Joints

log = logging.getLogger(__name__)

#: The jog thread looks at the lease and extends the jog this often [s].
TICK = 0.01
#: Path kept buffered ahead of the servo [s of planned time]. The servo caps a head's speed so that it could
#: stop within half of what is left of it (``interpolator.head_cap``): at the scale's slowest rate (10/s) full
#: speed needs 0.18 s left; this keeps the jog at its speed with a tick or two of lateness to spare.
HORIZON = 0.3
#: A joint jog stops this far inside its soft limit [rad or m]: the servo refuses a command outside it.
LIMIT_MARGIN = 1e-6
#: A jog that could move no joint more than this before a limit is refused, naming it [rad or m]: it is there.
#: From rest a jog may creep closer than it stopped from speed (its stop is shorter), and again, each time by
#: less: below a milliradian (about a millimetre at the tool) it is refused instead.
CREEP = 1e-3
#: Damped least squares: below this manipulability ``sqrt(det(J Jᵀ))`` the damping grows to ``DAMPING`` at 0.
MANIPULABILITY = 0.02
DAMPING = 0.05
#: A Cartesian jog asks each joint for at most this share of its max speed: the rest is the margin for the
#: change of the joint rates along a sample near a singularity (the servo refuses 110 % as a jump).
JOINT_SPEED_SHARE = 0.9
#: A Cartesian jog along a straight line (or about an axis) goes at most this far [m or rad] in one go: the
#: profile's target, far enough never to be reached while jogging by hand.
CARTESIAN_REACH = 10.0


@dataclasses.dataclass(frozen=True)
class JogCommand:
    """One jog call, decoded once (:meth:`decode`)."""

    op: str  # OP.jogJoint or OP.jogCartesian
    joint: int  # jogJoint: the joint's index (0 = J1); -1 for a Cartesian jog
    frame: str  # jogCartesian: "base" or "tool"; "" for a joint jog
    axis: int  # jogCartesian: 0..5 = x, y, z, rx, ry, rz; -1 for a joint jog
    sign: float  # +1 or -1: the direction
    ratio: float  # (0, 1]: the share of the max speed
    lease: float  # [s]

    @classmethod
    def decode(cls, op: str, args: Mapping[str, Any], axis_num: int) -> JogCommand:
        """The jog ``args`` of ``op`` ask for; raises WireError naming the field."""
        ratio = float(args["speedRatio"])
        if not (math.isfinite(ratio) and 0.0 < abs(ratio) <= 100.0):
            raise WireError("speedRatio", f"-100 .. 100 %, not 0 (jogStop ends a jog), got {ratio}")
        lease = int(args["leaseMs"])
        if not JOG_LEASE_MS[0] <= lease <= JOG_LEASE_MS[1]:
            raise WireError("leaseMs", f"{JOG_LEASE_MS[0]} .. {JOG_LEASE_MS[1]} ms, got {lease}")
        sign, share, seconds = math.copysign(1.0, ratio), abs(ratio) / 100.0, lease / 1000.0
        if op == OP.jogJoint:
            axis = int(args["axis"])
            if not 1 <= axis <= axis_num:
                raise WireError("axis", f"1 .. {axis_num} (J1 .. J{axis_num}), got {axis}")
            return cls(op, axis - 1, "", -1, sign, share, seconds)
        if op == OP.jogCartesian:
            frame, name = str(args["frame"]), str(args["axis"])
            if frame not in JOG_FRAMES:
                raise WireError("frame", f"one of {', '.join(JOG_FRAMES)}, got {frame!r}")
            if name not in JOG_AXES:
                raise WireError("axis", f"one of {', '.join(JOG_AXES)}, got {name!r}")
            return cls(op, -1, frame, JOG_AXES.index(name), sign, share, seconds)
        raise WireError("op", f"not a jog: {op!r}")  # pragma: no cover - the service routes only jogs here

    def same_jog(self, other: JogCommand) -> bool:
        """Whether ``other`` renews this jog (the same axis and direction; the speed may differ)."""
        return (self.op, self.joint, self.frame, self.axis, self.sign) == (
            other.op, other.joint, other.frame, other.axis, other.sign)

    def describe(self) -> str:
        sign = "+" if self.sign > 0 else "-"
        if self.joint >= 0:
            return f"J{self.joint + 1} {sign}"
        return f"{self.frame} {JOG_AXES[self.axis]} {sign}"


class _Track:
    """The distance along the jog ``s`` [rad or m], its speed and acceleration, one sample at a time (Ruckig,
    position interface towards ``end``: a joint jog stops on its soft limit exactly)."""

    def __init__(self, dt: float, end: float, limits: ProfileLimits) -> None:
        self.dt, self.end, self.limits = dt, end, limits
        self._otg = Ruckig(1, dt)
        self._inp = InputParameter(1)
        self._out = OutputParameter(1)
        self._inp.current_position, self._inp.current_velocity, self._inp.current_acceleration = [0.0], [0.0], [0.0]
        self._inp.target_position, self._inp.target_velocity, self._inp.target_acceleration = [end], [0.0], [0.0]
        self._inp.max_acceleration, self._inp.max_jerk = [limits.acceleration], [limits.jerk]
        self.finished = False

    @property
    def state(self) -> tuple[float, float, float]:
        inp = self._inp
        return inp.current_position[0], inp.current_velocity[0], inp.current_acceleration[0]

    def restore(self, state: tuple[float, float, float]) -> None:
        self._inp.current_position, self._inp.current_velocity, self._inp.current_acceleration = (
            [state[0]], [state[1]], [state[2]])
        self.finished = False

    def step(self, speed: float) -> float:
        """The next sample's ``s``, at most ``speed`` [per s]."""
        self._inp.max_velocity = [max(speed, 1e-9)]
        result = self._otg.update(self._inp, self._out)
        if result not in (Result.Working, Result.Finished):  # never on valid limits: stay where it is
            self.finished = True
            return self._inp.current_position[0]
        self._out.pass_to_input(self._inp)
        self.finished = result == Result.Finished
        return self._out.new_position[0]

    def braking(self) -> NDArray[np.float64]:
        """The samples of ``s`` of the shortest jerk-limited stop from here (after the current one)."""
        s, sd, sdd = self.state
        return stop_profile(self.end, s, max(sd, 0.0), sdd, self.limits).sample(self.dt).s[1:]


class _JointPath:
    """A joint jog: joint ``joint`` moves ``sign * s`` from ``q0``."""

    def __init__(self, q0: Joints, joint: int, sign: float) -> None:
        self.q0, self.joint, self.sign = q0.copy(), joint, sign

    def at(self, q: Joints, s: float) -> Joints:
        out = q.copy()
        out[self.joint] = self.q0[self.joint] + self.sign * s
        return out

    def rate(self, q: Joints) -> Joints:
        """d q / d s at ``q`` (joints per unit of ``s``)."""
        g = np.zeros_like(q)
        g[self.joint] = self.sign
        return g

    def state(self) -> object:
        return None  # each sample is a function of s alone

    def restore(self, state: object) -> None:
        pass


class _CartesianPath:
    """A Cartesian jog: the control point's pose at ``s`` is the start pose moved ``sign * s`` along or about
    one axis; each sample's joints come from the sample before by one damped least squares step."""

    def __init__(self, checks: Checks, fk_frames: Frames, q0: Joints, cmd: JogCommand, vmax: Joints,
                 dt: float, accel_time: float) -> None:
        """``vmax`` [rad/s or m/s]: the joints' speeds; ``accel_time`` [s]: rest to ``vmax`` (the settings')."""
        kin = checks.kin
        self.kin, self.n, self.tool, self.dt = kin, checks.n, fk_frames.tool, dt
        self.vmax = vmax[:self.n]
        self.amax = self.vmax / accel_time  # [rad/s² or m/s²]
        self._dq = np.zeros(self.n)  # the step before [rad or m]
        x0 = kin.control_point(q0[:self.n], self.tool)  # the arm frame, where kinematics works
        axis = np.zeros(3)
        axis[cmd.axis % 3] = cmd.sign
        self.rotation = cmd.axis >= 3
        # The direction along the arm frame's axes: a robot-frame axis turned by the base offset, or the
        # control point's own axis turned by its orientation at the start (the tool frame moves with it,
        # but along a straight line its orientation stays the start's).
        turn = fk_frames.base.rotation if cmd.frame == "base" else x0.rotation
        self.direction = turn @ axis
        self.x0 = x0

    def pose(self, s: float) -> pin.SE3:
        if self.rotation:
            return pin.SE3(pin.exp3(self.direction * s) @ self.x0.rotation, self.x0.translation)
        return pin.SE3(self.x0.rotation, self.x0.translation + self.direction * s)

    def _solve(self, q: Joints, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        J = self.kin.jacobian(q[:self.n], self.tool)
        JJt = J @ J.T
        w = math.sqrt(max(0.0, float(np.linalg.det(JJt))))
        damping = DAMPING ** 2 * (1.0 - (w / MANIPULABILITY) ** 2) if w < MANIPULABILITY else 0.0
        return J.T @ np.linalg.solve(JJt + damping * np.eye(6), rhs)

    def at(self, q: Joints, s: float) -> Joints:
        target = self.pose(s)
        now = self.kin.control_point(q[:self.n], self.tool)
        err = np.concatenate([target.translation - now.translation, pin.log3(target.rotation @ now.rotation.T)])
        dq = self._solve(q, err)
        # A step never asks a joint for more than its speed, nor changes it faster than its acceleration: near a
        # singularity the joint rates a straight line needs change fast (an effort of twice J2's rating was
        # measured before this); the arm then lags behind the line and the next steps close on it.
        step = self.amax * self.dt * self.dt
        dq = np.clip(dq, self._dq - step, self._dq + step)
        over = np.max(np.abs(dq) / (self.vmax * self.dt))
        if over > 1.0:
            dq /= over
        self._dq = dq
        out = q.copy()
        out[:self.n] += dq
        return out

    def stop(self, q: Joints) -> NDArray[np.float64]:
        """The samples of a stop from ``q`` moving by the step before: each joint slows down on its own at its
        acceleration (the arm leaves the line a little; the stop is what the checks assumed, joint by joint)."""
        rows = []
        dq = self._dq.copy()
        step = self.amax * self.dt * self.dt
        while np.any(dq != 0.0):
            dq = np.sign(dq) * np.maximum(np.abs(dq) - step, 0.0)
            q = q.copy()
            q[:self.n] += dq
            rows.append(q)
        self._dq = dq
        return np.array(rows) if rows else q[None, :].copy()

    def state(self) -> object:
        return self._dq.copy()

    def restore(self, state: object) -> None:
        self._dq = np.array(state, dtype=float)

    def rate(self, q: Joints) -> Joints:
        """d q / d s at ``q``: the joint rates of a unit speed along the jog."""
        twist = np.concatenate([np.zeros(3), self.direction] if self.rotation else [self.direction, np.zeros(3)])
        g = np.zeros_like(q)
        g[:self.n] = self._solve(q, twist)
        return g


@dataclasses.dataclass
class _Jog:
    """The jog that runs: what was asked, its path, where its buffered samples end."""

    cmd: JogCommand
    settings: MotionSettings
    path: _JointPath | _CartesianPath
    track: _Track
    speed: float  # [rad/s or m/s] the commanded speed along s (the ratio of the max speed)
    motion: int  # the servo's motion id
    epoch: int
    q_end: Joints  # the last buffered sample
    lease_until: float  # [monotonic s]
    left: float = 0.0  # [samples] the servo had left of it when it last said (``MotionProgress.runningLeft``)
    left_at: float = 0.0  # [monotonic s] when it said it
    ended: str = ""  # why the last extension was the end (a limit ahead), "" while it goes on


class Jogger:
    """The jog of one arm (module docstring): requests from ``Planner/jog``, extensions on a thread of its own."""

    def __init__(self, model: RobotModel, handover: Handover, obstacles: tuple[Obstacle, ...] = (),
                 collision_margin: float = DEFAULT_MARGIN) -> None:
        self.model = model
        self.dt = model.cmd_cycle
        self.handover = handover
        self._obstacles, self._margin = obstacles, collision_margin
        self._tools: tuple[Checks, PathChecker, BatchFk] | None = None  # built by the jog thread as it starts
        self._lock = threading.RLock()
        self._jog: _Jog | None = None
        #: The last jog that stopped by itself before a limit, why, and its motion: renewals of it while that
        #: motion still brakes are refused naming the limit.
        self._ended: tuple[JogCommand, str, int] | None = None
        self._loop = LoopThread(self._run, "planner-jog")

    # ------------------------------------------------------------------ life cycle
    def start(self) -> None:
        self._loop.start()

    def close(self) -> None:
        self._loop.stop()

    @property
    def alive(self) -> bool:
        return self._loop.alive

    @property
    def active(self) -> bool:
        """A jog runs (its motion may still be braking in the servo after that)."""
        return self._jog is not None

    def _kit(self) -> tuple[Checks, PathChecker, BatchFk]:
        if self._tools is None:
            kin = Kinematics(self.model)
            fk = BatchFk(kin)
            # A work area of its own: the plan worker's thread uses the heads' (kinematics are not thread-safe).
            self._tools = (Checks(self.model, kin, fk), PathChecker(self.model, self._obstacles, self._margin), fk)
        return self._tools

    # ------------------------------------------------------------------ requests
    def jog(self, cmd: JogCommand, settings: MotionSettings, start: Callable[[], tuple[Joints, int]]
            ) -> tuple[ReturnCode, str]:
        """Start ``cmd``, or renew the jog it continues; ``start()`` gives where a new one starts and the
        servo's epoch (raising PlanRefused). Raises PlanRefused."""
        with self._lock:
            jog = self._jog
            if jog is not None:
                if not jog.cmd.same_jog(cmd):
                    raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: jogging {jog.cmd.describe()}; "
                                      f"{OP.jogStop} first (or let its lease lapse)")
                now = time.monotonic()
                if now > jog.lease_until:  # lapsed: the jog thread is stopping it, a late call does not revive it
                    raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: the lease of jog "
                                      f"{jog.cmd.describe()} lapsed {(now - jog.lease_until) * 1e3:.0f} ms ago: "
                                      "it brakes; call again once it holds")
                jog.cmd, jog.lease_until = cmd, now + cmd.lease
                jog.speed = cmd.ratio * self._top(cmd, jog.settings)
                return ReturnCode.OK, f"OK: jogging {cmd.describe()} at {cmd.ratio * 100:.0f} %"
            ended = self._ended
            if ended is not None and ended[0].same_jog(cmd) and ended[2] in self.handover.progress().queued:
                raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: stopping before the limit: {ended[1]}")
            checks, _, _ = self._kit()
            try:
                checks.settings(settings)
            except WireError as exc:
                raise PlanRefused(ReturnCode.VALUE_ERR, str(exc)) from None
            q0, epoch = start()
            jog = self._begin(cmd, settings, q0, epoch)
            if jog.ended:  # the head already brakes before a limit: nothing to renew
                self._ended = (cmd, jog.ended, jog.motion)
                log.info("jog %s: stopping before the limit: %s", cmd.describe(), jog.ended)
                return ReturnCode.OK, f"OK: jogging {cmd.describe()}, stopping before the limit: {jog.ended}"
            self._jog = jog
            log.info("jog %s at %.0f %% started (motion %d, lease %.0f ms)", cmd.describe(), cmd.ratio * 100,
                     jog.motion, cmd.lease * 1e3)
            return ReturnCode.OK, f"OK: jogging {cmd.describe()} at {cmd.ratio * 100:.0f} % (motion {jog.motion})"

    def stop(self, why: str) -> str:
        """End the jog now: the servo brakes on its path. What it did, for the reply."""
        with self._lock:
            jog, self._jog = self._jog, None
        if jog is None:
            return f"OK: {OP.jogStop} ignored: no jog runs"
        code, comment, _ = self.handover.control(ControlAction.STOP)
        log.info("jog %s: %s: %s", jog.cmd.describe(), why, comment)
        return f"OK: {why}: braking" if code == ReturnCode.OK else f"{why}: {comment}"

    def _top(self, cmd: JogCommand, s: MotionSettings) -> float:
        """The max speed along a jog of ``cmd``'s kind [rad/s or m/s]: the joint's, or the Cartesian one."""
        if cmd.joint >= 0:
            checks, _, _ = self._kit()
            return float(checks.vmax(s)[cmd.joint])
        return s.maxSpeedCartesian.rotation if cmd.axis >= 3 else s.maxSpeedCartesian.translation

    def _begin(self, cmd: JogCommand, s: MotionSettings, q0: Joints, epoch: int) -> _Jog:
        checks, _, _ = self._kit()
        top = self._top(cmd, s)
        if cmd.joint >= 0:
            lo, hi = checks.soft_limits(s)
            i = cmd.joint
            room = (hi[i] - LIMIT_MARGIN - q0[i]) if cmd.sign > 0 else (q0[i] - lo[i] - LIMIT_MARGIN)
            if room <= 1e-6:
                bound = f"upper {hi[i]:.6g}" if cmd.sign > 0 else f"lower {lo[i]:.6g}"
                raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: J{i + 1} is at its joint soft limit "
                                  f"({bound}): jog the other way")
            limits = ProfileLimits.from_accel_time(top, s.accelTimeJoint)
            path: _JointPath | _CartesianPath = _JointPath(q0, i, cmd.sign)
            end = room
        else:
            rule = families.rule(self.model, families.CartesianKind.LINEAR)
            if isinstance(rule, families.Refused) or not all(rule.mask) \
                    or rule.orientation is not families.Orientation.FULL:
                why = rule.why if isinstance(rule, families.Refused) else (
                    f"a {self.model.axis_num}-axis {self.model.family.value} arm cannot hold all six components "
                    "of the pose (a Cartesian jog keeps the five it does not move)")
                raise PlanRefused(ReturnCode.NG, f"{cmd.op} refused: {why}")
            limits = ProfileLimits.from_accel_time(top, s.accelTimeCartesian)
            path = _CartesianPath(checks, Frames.of(s), q0, cmd, checks.vmax(s), self.dt, s.accelTimeJoint)
            end = CARTESIAN_REACH
        jog = _Jog(cmd, s, path, _Track(self.dt, end, limits), cmd.ratio * top, 0, epoch, q0.copy(),
                   time.monotonic() + cmd.lease)
        rows, ended = self._extend(jog, int(round(HORIZON / self.dt)))
        if ended and np.abs(rows[-1] - q0).max() < CREEP:  # at the limit already: nothing left to jog
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{cmd.op} refused: {ended}")
        head = np.vstack([q0[None, :], rows])
        jog.motion, reply = self.handover.jog_start(head, epoch, final=bool(ended))
        jog.left, jog.left_at = len(head) - 1.0, time.monotonic()
        jog.ended = ended
        return jog

    # ------------------------------------------------------------------ extensions
    def _extend(self, jog: _Jog, count: int) -> tuple[NDArray[np.float64], str]:
        """The next ``count`` samples after ``jog.q_end`` (advancing its track and ``q_end``), checked with the
        braking that would follow them. If that fails: the longest of their first samples that still passes,
        then the braking (the jog ends there), and why."""
        before_q, before_s, before_p = jog.q_end.copy(), jog.track.state, jog.path.state()
        chunk, why = self._try(jog, count)
        if not why:
            jog.q_end = chunk[-1]
            if jog.track.finished and jog.cmd.joint >= 0:
                lim = "upper" if jog.cmd.sign > 0 else "lower"
                return chunk, f"J{jog.cmd.joint + 1} reached its joint soft limit ({lim})"
            return chunk, ""
        # A limit ahead: bisect for the last sample from which the arm still stops in time (the samples before
        # the one that fails are checked in order: a limit comes nearer along the jog). The braking from
        # where the servo holds was checked with the extension before, so none passing still has one.
        good, bad = 0, len(chunk)
        best: tuple[NDArray[np.float64], tuple[float, float, float], object] | None = None
        while bad - good > 1:
            mid = (good + bad) // 2
            jog.track.restore(before_s)
            jog.path.restore(before_p)
            trial, failed = self._try(jog, mid)
            if failed:
                bad = mid
            else:
                good, best = mid, (trial, jog.track.state, jog.path.state())
        jog.track.restore(best[1] if best is not None else before_s)
        jog.path.restore(best[2] if best is not None else before_p)
        start = best[0][-1] if best is not None else before_q
        brake = self._braking(jog, start)
        parts = [p for p in (best[0] if best is not None else None, brake) if p is not None and len(p)]
        rows = np.vstack(parts) if parts else before_q[None, :]
        jog.q_end = rows[-1]
        return rows, why

    def _try(self, jog: _Jog, count: int) -> tuple[NDArray[np.float64], str]:
        """``count`` samples on from ``jog.q_end`` (advancing the track), and why they fail ("" if they do not)."""
        checks, collisions, fk = self._kit()
        rows = []
        q = jog.q_end
        for _ in range(count):
            q = jog.path.at(q, jog.track.step(jog.speed if jog.cmd.joint >= 0 else self._cap(jog, q)))
            rows.append(q)
            if jog.track.finished:
                break
        chunk = np.array(rows)
        return chunk, self._check(jog, chunk, checks, collisions, fk)

    def _cap(self, jog: _Jog, q: Joints) -> float:
        """A Cartesian jog's speed at ``q``: the one asked for, or less where a joint would be too fast."""
        g = np.abs(jog.path.rate(q)[:self.model.axis_num])
        checks, _, _ = self._kit()
        top = checks.vmax(jog.settings)[:self.model.axis_num] * JOINT_SPEED_SHARE
        moving = g > 1e-12
        allowed = float(np.min(top[moving] / g[moving])) if moving.any() else jog.speed
        return min(jog.speed, allowed)

    def _braking(self, jog: _Jog, q: Joints) -> NDArray[np.float64]:
        if isinstance(jog.path, _CartesianPath):
            return jog.path.stop(q)
        rows = []
        for s in jog.track.braking():
            q = jog.path.at(q, float(s))
            rows.append(q)
        return np.array(rows)

    def _check(self, jog: _Jog, chunk: NDArray[np.float64], checks: Checks, collisions: PathChecker,
               fk: BatchFk) -> str:
        """Why ``chunk`` and the braking after it would not do ("" if they would)."""
        s0, sd, _ = jog.track.state
        stop = jog.track.braking()
        ds = float(stop[-1] - s0) if len(stop) else 0.0
        last = chunk[-1]
        ahead = np.vstack([chunk, last + jog.path.rate(last) * ds]) if ds > 0.0 else chunk
        n = self.model.axis_num
        lo, hi = checks.soft_limits(jog.settings)
        if isinstance(jog.path, _CartesianPath) and len(chunk) >= 2:
            # Each joint must also be able to stop on its own at its acceleration: near a singularity the joints
            # lag the line, and a wrist axis spun fast stops further than the line's stop says.
            # Every sample's (the servo checks every command so).
            v = np.diff(chunk[:, :n], axis=0) / self.dt
            reach = chunk[1:, :n] + np.sign(v) * v * v / (2.0 * jog.path.amax)
            ahead = np.vstack([ahead, np.hstack([reach, chunk[1:, n:]])])
        bad = np.argwhere((ahead[:, :n] < lo - 1e-9) | (ahead[:, :n] > hi + 1e-9))
        if bad.size:
            i = int(bad[0][1])
            return f"J{i + 1} would pass its joint soft limit [{lo[i]:.6g}, {hi[i]:.6g}]"
        frames = Frames.of(jog.settings)
        positions = frames.to_robot(fk.run(ahead[:, :n], frames.tool)[0])
        try:
            checks.box(jog.settings, positions, jog.cmd.op)
        except PlanRefused as exc:
            return exc.comment.split(": ", 1)[-1]
        contact = collisions.check(np.vstack([jog.q_end[None, :], ahead]))
        if contact is not None:
            return f"it would come too close to an obstacle: {contact.describe()}"
        return ""

    # ------------------------------------------------------------------ the thread
    def _run(self, stop: threading.Event) -> None:
        with self._lock:  # built here, not at the first jog (0.25 s) nor in the service's start
            self._kit()
        while not stop.wait(TICK):
            try:
                self._tick()
            except Exception:  # a jog that cannot go on stops; the thread goes on for the next one
                log.exception("jog: extension failed; stopping the jog")
                self.stop("the jog failed")

    def _tick(self) -> None:
        with self._lock:
            jog = self._jog
            if jog is None:
                return
            now = time.monotonic()
            if now > jog.lease_until:
                silent = now - jog.lease_until + jog.cmd.lease
                lapsed = True
            else:
                lapsed = False
                want = int(round(HORIZON / self.dt)) - self._ahead(jog, now)
                if want >= int(round(TICK / self.dt)):
                    self._extend_jog(jog, want)
        if lapsed:
            self.stop(f"the lease lapsed ({silent * 1e3:.0f} ms without a renewal)")

    def _extend_jog(self, jog: _Jog, count: int) -> None:
        held = jog.q_end.copy()
        rows, ended = self._extend(jog, count)
        # Each extension starts on the last sample the servo holds (the splice point), repeated.
        reply = self.handover.jog_extend(jog.motion, jog.epoch, np.vstack([held, rows]), final=bool(ended))
        if reply.id != ReturnCode.OK:
            log.info("jog %s ended: the servo did not take its extension: %s", jog.cmd.describe(), reply.comment)
            self._jog = None
            return
        p = reply.progress
        if p.running == jog.motion:
            jog.left, jog.left_at = p.runningLeft, time.monotonic()
        if ended:  # the braking before a limit is buffered: the jog is over, its motion ends at rest
            self._jog = None
            self._ended = (jog.cmd, ended, jog.motion)
            log.info("jog %s: stopping before the limit: %s", jog.cmd.describe(), ended)

    def _ahead(self, jog: _Jog, now: float) -> int:
        """Samples buffered ahead of the servo: from its last word, at full speed since (an override or a pause
        only makes it more)."""
        return max(0, int(jog.left - (now - jog.left_at) / self.dt))


__all__ = ["HORIZON", "JogCommand", "Jogger", "TICK"]
