"""The path of a jog and the speed along it (``services/planner/jog.py`` runs them).

A jog's path is a function of one parameter ``s`` [rad or m]: a joint jog moves one joint ``s`` along its
axis (:class:`JointPath`); a Cartesian jog moves the control point ``s`` along or about one axis
(:class:`CartesianPath`), each sample solved from the one before by one damped least squares step
(Chiaverini's damping, growing near a singularity), so that near one the jog slows down instead of asking the
joints for speeds they do not have, and a jog the other way backs out. The speed along ``s`` follows a
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

#: Damped least squares: below this manipulability ``sqrt(det(J Jᵀ))`` the damping grows to ``DAMPING`` at 0.
MANIPULABILITY = 0.02
DAMPING = 0.05


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

    def stop_time(self) -> float:
        """[s] A bound on the shortest jerk-limited stop from here (:func:`stop_time`)."""
        s, sd, sdd = self.state
        return stop_time(sd, sdd, self.limits)

    def braking(self) -> NDArray[np.float64]:
        """The samples of ``s`` of the shortest jerk-limited stop from here (after the current one)."""
        s, sd, sdd = self.state
        return stop_profile(self.end, s, max(sd, 0.0), sdd, self.limits).sample(self.dt).s[1:]


class JointPath:
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

    def pose(self, s: float) -> pin.SE3:
        if self.rotation:
            return pin.SE3(pin.exp3(self.direction * s) @ self.x0.rotation, self.x0.translation)
        return pin.SE3(self.x0.rotation, self.x0.translation + self.direction * s)

    def _solve(self, q: Joints, rhs: NDArray[np.float64]) -> NDArray[np.float64]:
        J = self.kin.jacobian(q[:self.n], self.tool)[self.mask]
        JJt = J @ J.T
        w = math.sqrt(max(0.0, float(np.linalg.det(JJt))))
        damping = DAMPING ** 2 * (1.0 - (w / MANIPULABILITY) ** 2) if w < MANIPULABILITY else 0.0
        return J.T @ np.linalg.solve(JJt + damping * np.eye(len(J)), rhs[self.mask])

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

    def stop_time(self) -> float:
        """[s] The stop of :meth:`stop` from the step before: the slowest joint's."""
        return float(np.max(np.abs(self._dq) / (self.amax * self.dt))) + self.dt if self._dq.any() else 0.0

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


__all__ = ["CartesianPath", "DAMPING", "JointPath", "MANIPULABILITY", "Track", "speed_to_stop_within",
           "stop_time"]
