"""Blending (approximate positioning) of a corner between two consecutive queued motions.

An extension outside the JARA_ARM IDL (``Ext/setBlendDistance``); blend distance
``d`` = 0 is the specification's exact stop. With ``d`` > 0 the arm leaves the
previous motion's path where its control point comes within ``d`` of the corner
(the cut, a sample of that motion), and rejoins the next motion's path at its
last sample still within ``d`` of the corner (the rejoin). In between it follows
one jerk-limited joint-space Ruckig trajectory from the state (q, dq, ddq) at
the cut to the state at the rejoin, within every axis' speed, acceleration and
jerk limit: it never stops at the corner.

The planner (``corners.py``) checks the blend's control point stays within
``d`` of the corner, its joints within the soft limits, and the whole blend
clear of collisions; any failure keeps the exact stop for that corner. The
servo (``servo/interpolator.py``) runs the previous motion up to the cut, the
blend, then the next motion from the rejoin, as one buffered path: a pause or
stop in the blend slows down on the blend itself, and a resume goes on along it.
A blend that reaches the servo after it has passed the cut is handed over as
the exact stop (``planner/handover.py``).

Samples are ``dt`` apart (the servo period); every trajectory here lasts a whole
number of periods so that its last sample is its target exactly.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import ruckig
from numpy.typing import NDArray

from .profile import ProfileError, ProfileLimits, calculate

Joints = NDArray[np.float64]

#: Ops never blended: the gripper moves alone while the arm holds.
UNBLENDED_OPS = frozenset({"moveGripper", "openGripper", "closeGripper"})


class BlendError(Exception):
    """No blend for this corner (the planner then keeps the exact stop)."""


@dataclass(frozen=True, eq=False)
class JointLimits:
    """Per-axis limits of a joint-space trajectory (arm axes)."""

    velocity: Joints  # [rad/s or m/s]
    acceleration: Joints  # [rad/s² or m/s²]
    jerk: Joints  # [rad/s³ or m/s³]

    @classmethod
    def from_accel_time(cls, velocity: Joints, accel_time: float) -> JointLimits:
        """Each axis as a PTP drives it at full speed: rest to ``velocity`` in ``accel_time`` [s] (S-curve)."""
        lims = [ProfileLimits.from_accel_time(float(v), accel_time) for v in velocity]
        return cls(np.asarray(velocity, dtype=float), np.array([lim.acceleration for lim in lims]),
                   np.array([lim.jerk for lim in lims]))


@dataclass(frozen=True, eq=False)
class JointTrajectory:
    """A joint-space trajectory sampled every ``dt``: row 0 is its start state, the last row its end."""

    q: Joints  # (M, n)
    dq: Joints  # (M, n)
    ddq: Joints  # (M, n)
    dt: float  # [s]

    @property
    def duration(self) -> float:
        """[s]"""
        return (len(self.q) - 1) * self.dt


@dataclass(frozen=True, eq=False)
class Blend:
    """The blend that replaces the end of motion ``previous`` and the start of the motion carrying it."""

    previous: int  # the id of the motion it leaves
    cut: int  # sample of the previous motion where it leaves (the blend's row 0, already commanded)
    rejoin: int  # sample of this motion where it rejoins (the blend's last row)
    s_rejoin: float  # this motion's path parameter at the rejoin
    trajectory: JointTrajectory  # the wire axes (arm, then gripper held); q[0] = previous.q[cut]
    limits: JointLimits  # of the arm axes: what braking in the blend keeps to
    distance: float  # [m] the blend distance d it was planned with
    deviation: float  # [m] the largest distance of its control point from the corner


def state_at(q: Joints, i: int, dt: float) -> tuple[Joints, Joints, Joints]:
    """(q, dq, ddq) at sample ``i`` (1 <= i <= len - 2) of samples ``q`` ``dt`` apart, by central differences."""
    return q[i], (q[i + 1] - q[i - 1]) / (2.0 * dt), (q[i + 1] - 2.0 * q[i] + q[i - 1]) / dt**2


def _input(q: Joints, dq: Joints, ddq: Joints, limits: JointLimits) -> ruckig.InputParameter:
    n = len(q)
    inp = ruckig.InputParameter(n)
    inp.current_position = q.tolist()
    inp.current_velocity = dq.tolist()
    inp.current_acceleration = ddq.tolist()
    inp.max_velocity = limits.velocity.tolist()
    inp.max_acceleration = limits.acceleration.tolist()
    inp.max_jerk = limits.jerk.tolist()
    return inp


def _calculate(inp: ruckig.InputParameter) -> ruckig.Trajectory:
    try:
        return calculate(inp)
    except ProfileError as exc:
        raise BlendError(str(exc)) from None


def _whole_periods(inp: ruckig.InputParameter, dt: float) -> ruckig.Trajectory:
    """The time-optimal trajectory stretched to a whole number of periods (its last sample is its target)."""
    traj = _calculate(inp)
    periods = math.ceil(traj.duration / dt - 1e-9)
    if abs(periods * dt - traj.duration) > 1e-12:
        inp.minimum_duration = periods * dt
        traj = _calculate(inp)
        if abs(traj.duration - periods * dt) > 1e-9:
            raise BlendError(f"Ruckig could not stretch {traj.duration:.6f} s to {periods * dt:.6f} s")
    return traj


def _sample(traj: ruckig.Trajectory, dt: float, end: tuple[Joints, Joints, Joints]) -> JointTrajectory:
    m = round(traj.duration / dt)
    rows = [traj.at_time(k * dt) for k in range(m)]
    q = np.array([r[0] for r in rows] + [end[0]]).reshape(m + 1, -1)
    dq = np.array([r[1] for r in rows] + [end[1]]).reshape(m + 1, -1)
    ddq = np.array([r[2] for r in rows] + [end[2]]).reshape(m + 1, -1)
    return JointTrajectory(q, dq, ddq, dt)


def joint_blend(start: tuple[Joints, Joints, Joints], end: tuple[Joints, Joints, Joints], limits: JointLimits,
                dt: float) -> JointTrajectory:
    """From state ``start`` to state ``end`` (q, dq, ddq, moving), time-optimal within ``limits``,
    time-synchronised; raises BlendError when Ruckig finds none."""
    inp = _input(*start, limits)
    inp.target_position = end[0].tolist()
    inp.target_velocity = end[1].tolist()
    inp.target_acceleration = end[2].tolist()
    return _sample(_whole_periods(inp, dt), dt, end)


def cut_points(previous: NDArray[np.float64], following: NDArray[np.float64], radius: float) -> tuple[int, int]:
    """(cut, rejoin): the first sample of ``previous`` (control points (N, 3) [m], ending at the corner)
    from which on it stays within ``radius`` of the corner, and the last sample of ``following``
    (starting at the corner) up to which it does; raises BlendError if either motion is too short."""
    corner = previous[-1]
    far = np.flatnonzero(np.linalg.norm(previous - corner, axis=1) > radius)
    cut = int(far[-1]) + 1 if far.size else 1
    far = np.flatnonzero(np.linalg.norm(following - corner, axis=1) > radius)
    rejoin = int(far[0]) - 1 if far.size else len(following) - 2
    if not 1 <= cut <= len(previous) - 2 or not 1 <= rejoin <= len(following) - 2:
        raise BlendError("a motion at the corner is too short to cut")
    return cut, rejoin


__all__ = ["Blend", "BlendError", "JointLimits", "JointTrajectory", "UNBLENDED_OPS", "cut_points",
           "joint_blend", "state_at"]
