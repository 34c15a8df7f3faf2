"""The arm angle ("elbow") of a 7-axis arm in a Cartesian command: its start and target, and its rate limit on a
LIN / CIRC (DECISIONS.md "Frames": the arm angle, "elbow").

A command's ``elbow`` is the target arm angle [rad]; a relative command adds it
to the start's. The target is taken the short way round from the start's, and
only where the family keeps the arm angle (``families.py``) on an arm that has
one.

A LIN or CIRC moves the arm angle linearly along its path (``sampling.py``),
so the angle is a third part of the path beside translation and rotation, and
it needs its own speed limit: without one, a move whose translation and
rotation are (nearly) zero would squeeze its elbow change into (nearly) no time.

The limit [rad/s] is derived from the joint speed limits, not set per robot:
turning the arm angle with the control point held is the arm's self-motion,
whose joint rates are ``dq/dψ`` times the angle's rate, with ``dq/dψ`` solving
``J · dq = 0`` (the constrained task rows) and ``∂ψ/∂q · dq = 1``. The angle
may turn at most as fast as brings the first joint to its max speed at the
start joints, and no faster than the Cartesian rotation limit (the arm angle is
a rotation of the commanded pose). ``dq/dψ`` changes along the path, so this is
the first guess of the profile's speed; the planner's check of every sample
against the joint speed limits (slowing the profile down) has the last word.
"""

from __future__ import annotations

import math

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics, Mask
from jara_arm.schema.types import CarPosWithElbow

from .families import CartesianRule

__all__ = ["elbow_speed_limit", "elbow_targets", "self_motion"]

#: Residual of ``∂ψ/∂q · dq = 1`` above which the arm angle cannot turn with the control point held (the
#: shoulder, elbow and wrist in a line, or a singular task Jacobian) [-].
_SELF_MOTION_RESIDUAL = 1e-6


def self_motion(kin: Kinematics, q: NDArray[np.float64], tool: pin.SE3 | None,
                mask: Mask) -> NDArray[np.float64] | None:
    """``dq/dψ`` (n,) [rad/rad] at arm joints ``q``: the joint rates that turn the arm angle by 1 rad/s with
    the ``mask`` rows of the control point held; None where the arm angle cannot turn so."""
    J = kin.jacobian(q, tool)[np.flatnonzero(np.array(mask))]
    A = np.vstack([J, kin.elbow_jacobian(q)])
    b = np.zeros(A.shape[0])
    b[-1] = 1.0
    dq: NDArray[np.float64] = np.linalg.lstsq(A, b, rcond=None)[0]  # least-norm if rows are masked
    if not np.all(np.isfinite(dq)) or np.abs(A @ dq - b).max() > _SELF_MOTION_RESIDUAL:
        return None
    return dq


def elbow_speed_limit(kin: Kinematics, q: NDArray[np.float64], tool: pin.SE3 | None, mask: Mask,
                      max_joint_speed: NDArray[np.float64], max_rotation_speed: float) -> float:
    """[rad/s] The arm angle's max rate at 100 % speed from arm joints ``q`` (module docstring).

    ``max_joint_speed`` [rad/s or m/s per arm axis], ``max_rotation_speed`` [rad/s]: the Cartesian
    rotation limit, which alone sets it where the arm angle cannot turn with the control point held.
    """
    dq = self_motion(kin, q, tool, mask)
    if dq is None:
        return max_rotation_speed
    moving = np.abs(dq) > 0.0
    joints = float(np.min(max_joint_speed[moving] / np.abs(dq[moving]))) if moving.any() else math.inf
    return min(joints, max_rotation_speed)


def elbow_targets(kin: Kinematics, cp: CarPosWithElbow, start_arm: NDArray[np.float64], relative: bool,
                  rule: CartesianRule) -> tuple[float | None, float | None]:
    """(start, target) arm angle [rad] of a 7-axis arm at arm joints ``start_arm`` commanded ``cp``,
    (None, None) when not commanded (module docstring)."""
    if not (rule.elbow and kin.has_elbow):
        return None, None
    e0 = kin.elbow_angle(start_arm)
    e1 = e0 + cp.elbow if relative else cp.elbow
    return e0, e0 + math.remainder(e1 - e0, 2.0 * math.pi)
