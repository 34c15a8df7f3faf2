"""The path of a jog and the speed along it (``services/planner/jog.py`` runs them).

A jog's path is a function of one parameter ``s`` [rad or m]: a joint jog moves one joint ``s`` along its
axis (:class:`JointPath`); a Cartesian jog moves the control point ``s`` along or about one axis
(:class:`CartesianPath`), each sample solved from the one before by one least squares step (a 7-axis arm
also holds its arm angle), damped only within :data:`SINGULAR` of a singularity (Nakamura and Hanafusa's
damping, growing as the smallest singular value falls). Near one the jog slows down within the joints' speeds
and accelerations, and ``jog.py`` stops it at :data:`SINGULAR` (the arm keeps to its line and its posture,
and a jog the other way backs out). The speed along ``s`` follows a
jerk-limited profile (:class:`Track`: Ruckig, one degree of freedom, one sample at a time).

The stop of a jog is planned before the jog goes on: :func:`stop_time` bounds it, :func:`speed_to_stop_within`
inverts the bound (the fastest a jog may go that still stops in a given time).
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray
from ruckig import InputParameter, OutputParameter, Result, Ruckig

from .checks import Checks
from .frames import Frames
from .profile import ProfileLimits, stop_profile
from .trajectory import Joints

#: [m/rad or rad/rad] The smallest singular value of the Jacobian's held rows (and the arm angle's, 7 axes)
#: below which a Cartesian jog does not go deeper (``jog.py``), and the least squares step is damped
#: (λ² = SINGULAR² - σ²). The iiwa's elbow at 1.7 degrees from stretched (about 2 mm short of its reach), a
#: wrist at a third of a degree; 2-4 % of random poses of the articulated arms are below it. Deeper, a line
#: needs joint rates that change faster than the joints can follow: with no such stop (and the step before
#: this one) the iiwa left its line by 40 mm, its elbow went through the singularity and the tool moved against
#: the jog.
SINGULAR = 0.005
#: A Cartesian jog asks each joint for at most this share of its max speed: the rest is the margin for the
#: change of the joint rates along a sample near a singularity (the servo refuses 110 % as a jump).
JOINT_SPEED_SHARE = 0.9
#: A Cartesian jog's speed changes with at most this share of each joint's acceleration: the rest is for the
#: change of the joint rates along the line (large near a singularity: the iiwa's joints then lagged its line
#: by 3.0 mm, 1.8 mm with this share).
JOINT_ACCEL_SHARE = 0.5
#: A Cartesian jog's nearness to a singularity is looked at every this many samples, and at the last: it
#: changes little in 10 ms.
SINGULAR_STRIDE = 10


def stop_time(speed: float, accel: float, limits: ProfileLimits) -> float:
    """[s] A bound on the shortest stop from ``speed`` [per s] and ``accel`` [per s²] within ``limits``.

    The stop it bounds is one that could be made: the acceleration ramps down to 0 first (``accel / jerk``,
    the speed growing by ``accel² / 2 jerk``), then the time-optimal stop from rest acceleration (two jerk
    ramps, ``2 sqrt(v / jerk)``, or with a constant-deceleration phase ``v / a + a / jerk``). The optimal stop
    (Ruckig's) is never longer.
    """
    a, j = limits.acceleration, limits.jerk
    up = max(accel, 0.0)
    v = max(speed, 0.0) + up * up / (2.0 * j)
    ramp = 2.0 * math.sqrt(v / j) if v <= a * a / j else v / a + a / j
    return up / j + ramp


def speed_to_stop_within(seconds: float, limits: ProfileLimits) -> float:
    """[per s] The highest speed (cruising, no acceleration) whose stop takes at most ``seconds`` (the inverse
    of :func:`stop_time`); 0 for no time."""
    a, j = limits.acceleration, limits.jerk
    t = max(seconds, 0.0)
    return j * t * t / 4.0 if t <= 2.0 * a / j else a * (t - a / j)


class Track:
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

    def step(self, speed: float, accel: float = math.inf) -> float:
        """The next sample's ``s``, at most ``speed`` [per s] and ``accel`` [per s²] (and the track's limits)."""
        self._inp.max_velocity = [max(speed, 1e-9)]
        self._inp.max_acceleration = [max(min(self.limits.acceleration, accel), 1e-6)]
        result = self._otg.update(self._inp, self._out)
        if result not in (Result.Working, Result.Finished):  # never on valid limits: stay where it is
            self.finished = True
            return self._inp.current_position[0]
        self._out.pass_to_input(self._inp)
        self.finished = result == Result.Finished
        return self._out.new_position[0]

    def stop_time(self) -> float:
        """[s] A bound on the shortest jerk-limited stop from here (:func:`stop_time`)."""
        s, sd, sdd = self.state
        return stop_time(sd, sdd, self.limits)

    def braking(self) -> NDArray[np.float64]:
        """The samples of ``s`` of the shortest jerk-limited stop from here (after the current one)."""
        s, sd, sdd = self.state
        # Ruckig lands on the end up to rounding: 7e-18 past it made stop_profile refuse, and the held jog of a
        # pendant stopped as failed (fresh-clone run 151, 2026-12-05).
        s = min(max(s, 0.0), self.end)
        return stop_profile(self.end, s, max(sd, 0.0), sdd, self.limits).sample(self.dt).s[1:]


class JointPath:
    """A joint jog: joint ``joint`` moves ``sign * s`` from ``q0``."""

    def __init__(self, q0: Joints, joint: int, sign: float) -> None:
        self.q0, self.joint, self.sign = q0.copy(), joint, sign

    def at(self, q: Joints, s: float) -> Joints:
        out = q.copy()
        out[self.joint] = self.q0[self.joint] + self.sign * s
        return out

    def limits(self, q: Joints, speed: float) -> tuple[float, float]:
        """The speed [rad/s or m/s] and acceleration [per s²] along ``s`` at ``q``: the jog's ``speed``."""
        return speed, math.inf

    def rate(self, q: Joints) -> Joints:
        """d q / d s at ``q`` (joints per unit of ``s``)."""
        g = np.zeros_like(q)
        g[self.joint] = self.sign
        return g

    def stop_time(self) -> float:
        return 0.0  # its stop is the track's

    def state(self) -> object:
        return None  # each sample is a function of s alone

    def restore(self, state: object) -> None:
        pass


class CartesianPath:
    """A Cartesian jog: the control point's pose at ``s`` is the start pose moved ``sign * s`` along or about
    one axis; each sample's joints come from the sample before by one damped least squares step."""

    def __init__(self, checks: Checks, fk_frames: Frames, q0: Joints, frame: str, axis: int, sign: float,
                 vmax: Joints, dt: float, accel_time: float, mask: NDArray[np.bool_] | None = None) -> None:
        """``frame`` "base" or "tool", ``axis`` 0..5 (x, y, z, rx, ry, rz), ``sign`` ±1: the jog;
        ``vmax`` [rad/s or m/s]: the joints' speeds; ``accel_time`` [s]: rest to ``vmax`` (the settings');
        ``mask``: the pose components (x .. rz, arm base frame) the arm holds, all six if None (a SCARA
        moves x, y, z and rz, a gantry its axes: the others it cannot change, nor hold)."""
        kin = checks.kin
        self.kin, self.n, self.tool, self.dt = kin, checks.n, fk_frames.tool, dt
        self.vmax = vmax[:self.n]
        self.amax = self.vmax / accel_time  # [rad/s² or m/s²]
        self._dq = np.zeros(self.n)  # the step before [rad or m]
        self.mask = np.ones(6, dtype=bool) if mask is None else np.asarray(mask, dtype=bool)
        x0 = kin.control_point(q0[:self.n], self.tool)  # the arm frame, where kinematics works
        unit = np.zeros(3)
        unit[axis % 3] = sign
        self.rotation = axis >= 3
        # The direction along the arm frame's axes: a robot-frame axis turned by the base offset, or the
        # control point's own axis turned by its orientation at the start (the tool frame moves with it,
        # but along a straight line its orientation stays the start's).
        turn = fk_frames.base.rotation if frame == "base" else x0.rotation
        self.direction = turn @ unit
        self.x0 = x0
        # A 7-axis arm holds its arm angle too, as a LIN does (DECISIONS.md "Frames"): the least norm step
        # let the iiwa's J1 and J5 turn by 0.9 and 1.1 rad of self-motion while its tool crept 6 mm.
        self.elbow = kin.elbow_angle(q0[:self.n]) if kin.has_elbow and self.mask.all() else None
        self._last: tuple[bytes, tuple[NDArray[np.float64], ...]] = (b"", ())

    def pose(self, s: float) -> pin.SE3:
        if self.rotation:
            return pin.SE3(pin.exp3(self.direction * s) @ self.x0.rotation, self.x0.translation)
        return pin.SE3(self.x0.rotation, self.x0.translation + self.direction * s)

    def _jacobian(self, q: Joints) -> NDArray[np.float64]:
        """The held rows of the Jacobian at ``q``, and the arm angle's gradient on a 7-axis arm."""
        J = self.kin.jacobian(q[:self.n], self.tool)[self.mask]
        return J if self.elbow is None else np.vstack([J, self.kin.elbow_jacobian(q[:self.n])])

    def _svd(self, q: Joints) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]]:
        """The singular value decomposition of :meth:`_jacobian` at ``q``; the last one is kept: a sample's
        speed (:meth:`rate`) and its step (:meth:`at`) are solved at the same joints."""
        key = q[:self.n].tobytes()
        if self._last[0] != key:
            self._last = key, np.linalg.svd(self._jacobian(q), full_matrices=False)
        return self._last[1]

    def _solve(self, q: Joints, rhs: NDArray[np.float64], elbow: float = 0.0) -> NDArray[np.float64]:
        """The joint step for the pose change ``rhs`` (x .. rz) and the arm angle change ``elbow`` [rad]."""
        U, sigma, Vt = self._svd(q)
        damping = SINGULAR ** 2 - sigma[-1] ** 2 if sigma[-1] < SINGULAR else 0.0
        task = rhs[self.mask] if self.elbow is None else np.append(rhs[self.mask], elbow)
        return Vt.T @ (sigma / (sigma * sigma + damping) * (U.T @ task))

    def singular(self, q: Joints) -> float:
        """[m/rad or rad/rad] The smallest singular value of the Jacobian (held rows, arm angle) at ``q``: 0 at
        a singularity."""
        return float(self._svd(q)[1][-1])

    def too_singular(self, start: Joints, line: NDArray[np.float64]) -> str:
        """Why the samples of ``line`` (on from ``start``) come too close to a singularity, "" if they do not:
        below :data:`SINGULAR` and nearer than ``start`` (a jog that starts nearer may leave)."""
        rows = np.vstack([line[:-1:SINGULAR_STRIDE], line[-1:]])
        sigma = min(self.singular(q) for q in rows)
        if sigma >= SINGULAR or sigma >= self.singular(start):
            return ""
        return (f"it would come too close to a singularity (the smallest singular value of its Jacobian would "
                f"fall to {sigma:.4f}, below {SINGULAR}): jog the other way, or jog the joints")

    def at(self, q: Joints, s: float) -> Joints:
        target = self.pose(s)
        now = self.kin.control_point(q[:self.n], self.tool)
        err = np.concatenate([target.translation - now.translation, pin.log3(target.rotation @ now.rotation.T)])
        turn = 0.0 if self.elbow is None else math.remainder(self.elbow - self.kin.elbow_angle(q[:self.n]), math.tau)
        dq = self._solve(q, err, turn)
        # A step never asks a joint for more than its speed, nor changes it faster than its acceleration: near a
        # singularity the joint rates a straight line needs change fast (an effort of twice J2's rating was
        # measured before this); the arm then lags behind the line and the next steps close on it. The change
        # is scaled as a whole: clipped joint by joint it turned the step off the line (40 mm, offline, near the
        # iiwa's stretched elbow).
        step = self.amax * self.dt * self.dt
        change = dq - self._dq
        dq = self._dq + change * min(1.0, float(np.min(step / np.maximum(np.abs(change), 1e-15))))
        over = np.max(np.abs(dq) / (self.vmax * self.dt))
        if over > 1.0:
            dq /= over
        self._dq = dq
        out = q.copy()
        out[:self.n] += dq
        return out

    def stop(self, q: Joints) -> NDArray[np.float64]:
        """The samples of a stop from ``q`` moving by the step before: the joints slow down together, in the time
        the slowest needs at its acceleration, so that the step keeps its direction (the arm stays on the line's
        tangent: each joint braking on its own left the line by 1.4 mm and 5 mrad near a singularity). Pure: the
        path's state is left as it is (the jogger asks for the stop after each extension, then goes on)."""
        dq = self._dq
        count = math.ceil(float(np.max(np.abs(dq) / (self.amax * self.dt * self.dt)))) if dq.any() else 0
        rows = []
        for k in range(1, count + 1):
            q = q.copy()
            q[:self.n] += dq * ((count - k) / count)
            rows.append(q)
        return np.array(rows) if rows else q[None, :].copy()

    def stop_time(self) -> float:
        """[s] The stop of :meth:`stop` from the step before: the slowest joint's."""
        return float(np.max(np.abs(self._dq) / (self.amax * self.dt))) + self.dt if self._dq.any() else 0.0

    def state(self) -> object:
        return self._dq.copy()

    def restore(self, state: object) -> None:
        self._dq = np.array(state, dtype=float)

    def limits(self, q: Joints, speed: float) -> tuple[float, float]:
        """The speed [m/s or rad/s] along ``s`` at ``q``, ``speed`` or less where a joint would be too fast, and
        the acceleration [per s²] where a joint would accelerate too fast."""
        g = np.abs(self.rate(q)[:self.n])
        moving = g > 1e-12
        if not moving.any():
            return speed, math.inf
        top = float(np.min(self.vmax[moving] * JOINT_SPEED_SHARE / g[moving]))
        return min(speed, top), float(np.min(self.amax[moving] * JOINT_ACCEL_SHARE / g[moving]))

    def rate(self, q: Joints) -> Joints:
        """d q / d s at ``q``: the joint rates of a unit speed along the jog."""
        twist = np.concatenate([np.zeros(3), self.direction] if self.rotation else [self.direction, np.zeros(3)])
        g = np.zeros_like(q)
        g[:self.n] = self._solve(q, twist)
        return g


__all__ = ["CartesianPath", "JOINT_ACCEL_SHARE", "JOINT_SPEED_SHARE", "JointPath", "SINGULAR", "SINGULAR_STRIDE",
           "Track", "speed_to_stop_within", "stop_time"]
