"""Joint traces of an arm over a time window: positions, velocities and accelerations, with the limits.

The numeric core of ``jara-arm plot``, on plain arrays (no Zenoh, no files).
Velocities and accelerations are finite differences over the real spacing of
the samples' own timestamps (``TimedJointPos.tm``); a difference is taken only
between neighbours one servo cycle apart (within a quarter cycle, the rule of
``tests/test_servo.py``): a lost sample leaves a gap, and a difference across
it would not be the arm's, so it is NaN (a break in the drawn line, not a spike).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from jara_arm.kinematics import Kinematics
from jara_arm.robots import RobotModel
from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.types import LimitValue

#: A neighbour counts as the next sample if its spacing is within this fraction of a cycle of one cycle.
CYCLE_TOLERANCE = 0.25


class TraceError(JaraArmError, ValueError):
    """Samples that cannot make a trace: too few in the window, or not one row per time."""


@dataclasses.dataclass(frozen=True)
class JointLimits:
    """What is drawn with the traces, per arm axis J1..Jn."""

    hard: tuple[LimitValue, ...]  # [rad or m] the robot model's (URDF)
    soft: tuple[LimitValue, ...] | None  # [rad or m] the arm's soft limits, None if not known
    speed: tuple[float, ...]  # [rad/s or m/s] rated speed
    accel: tuple[float, ...]  # [rad/s² or m/s²] rated speed over the minimum acceleration time

    @classmethod
    def of(cls, model: RobotModel, soft: tuple[LimitValue, ...] | None = None) -> "JointLimits":
        return cls(model.hard_limits, soft, model.rated_speed, model.max_accel)

    @property
    def axes(self) -> int:
        return len(self.hard)


@dataclasses.dataclass(frozen=True)
class Traces:
    """Positions and their differences; times [s] from the first sample (of the data, not of the window).

    ``vel[i]`` is between samples ``i`` and ``i + 1`` (at ``t_vel[i]``, their midpoint) and
    ``acc[i]`` between ``vel[i]`` and ``vel[i + 1]`` (at ``t_acc[i]``, the midpoint of theirs); NaN next to a gap.
    """

    t: np.ndarray  # (N,) [s]
    q: np.ndarray  # (N, n) [rad or m]
    t_vel: np.ndarray  # (N - 1,) [s]
    vel: np.ndarray  # (N - 1, n) [rad/s or m/s]
    t_acc: np.ndarray  # (N - 2,) [s]
    acc: np.ndarray  # (N - 2, n) [rad/s² or m/s²]
    gaps: int  # spacings that are not one cycle (lost, repeated or late samples)

    @property
    def axes(self) -> int:
        return int(self.q.shape[1])


def differences(tm: npt.ArrayLike, q: npt.ArrayLike, cycle: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Velocity and acceleration by finite differences over the samples' spacing.

    ``tm`` (N,) [s] sample times, increasing; ``q`` (N, n) or (N,) positions; ``cycle`` [s]
    the servo period. Returns ``(one, vel, acc)``: ``one`` (N - 1,) whether each spacing
    is one cycle, ``vel`` (N - 1, ...) and ``acc`` (N - 2, ...), NaN where a difference
    would span a gap. ``acc`` divides by the distance of the two velocities' midpoints.
    """
    dt = np.diff(np.asarray(tm, dtype=float))
    joints = np.asarray(q, dtype=float)
    one = np.abs(dt - cycle) < CYCLE_TOLERANCE * cycle
    shape = (-1,) + (1,) * (joints.ndim - 1)  # broadcast the spacing over the axes
    with np.errstate(divide="ignore", invalid="ignore"):  # a zero spacing is a gap: its quotient is dropped
        vel = np.where(one.reshape(shape), np.diff(joints, axis=0) / dt.reshape(shape), np.nan)
        mid = 0.5 * (dt[:-1] + dt[1:])
        acc = np.diff(vel, axis=0) / mid.reshape(shape)  # NaN next to a gap, as vel is
    return one, vel, acc


def traces(tm: npt.ArrayLike, q: npt.ArrayLike, cycle: float, start: float = 0.0,
           end: float | None = None) -> Traces:
    """The traces of the samples between ``start`` and ``end`` [s] after the first sample.

    ``tm`` (N,) [s] sample times in any order (sorted here; a repeated time is a gap),
    ``q`` (N, n) [rad or m]. TraceError if fewer than 3 samples are in the window.
    """
    times = np.asarray(tm, dtype=float)
    joints = np.asarray(q, dtype=float)
    if joints.ndim != 2 or times.shape != (joints.shape[0],):
        raise TraceError(f"expected N times and N rows of joint values, got {times.shape} and {joints.shape}")
    if len(times) == 0:
        raise TraceError("no samples")
    order = np.argsort(times, kind="stable")  # a subscriber may see samples out of order
    times, joints = times[order], joints[order]
    t = times - times[0]
    inside = (t >= start) & (t <= (np.inf if end is None else end))
    t, joints = t[inside], joints[inside]
    if len(t) < 3:
        window = f"{start:g} .. {'end' if end is None else f'{end:g}'} s"
        raise TraceError(f"{len(t)} sample(s) in the window {window} of the {times[-1] - times[0]:.3f} s "
                         "of samples: 3 at least are needed")
    one, vel, acc = differences(t, joints, cycle)
    t_vel = 0.5 * (t[:-1] + t[1:])
    return Traces(t, joints, t_vel, vel, 0.5 * (t_vel[:-1] + t_vel[1:]), acc, int(np.count_nonzero(~one)))


def cartesian_path(kinematics: Kinematics, q: npt.ArrayLike, tool: pin.SE3 | None = None,
                   most: int = 4000) -> np.ndarray:
    """(M, 3) [m] the control point in the arm base frame at ``q`` (N, n) [rad or m], at most
    ``most`` evenly spread samples, the first and the last always among them (FK of every sample
    of a long 1 kHz run would cost seconds and draw no better)."""
    joints = np.asarray(q, dtype=float)
    if len(joints) == 0:
        return np.empty((0, 3))
    rows = np.unique(np.linspace(0, len(joints) - 1, min(len(joints), most)).round().astype(int))
    return np.array([kinematics.control_point(joints[i], tool).translation for i in rows])
