"""Poses and frames (DECISIONS.md "Frames").

* **Arm base frame** -- the frame of the URDF root link; forward and inverse
  kinematics work in it.
* **Flange** -- the URDF link ``RobotModel.flange_frame``.
* **Control point** -- ``T_cp = T_flange · C``, where ``C`` (the control point
  offset, the ``tool`` argument) is the pose of the control point in the flange
  frame; identity when not given.
* **Robot (reference) frame** -- ``T_robot = inv(B) · T_arm``, where the base
  offset ``B`` is the pose of the robot frame seen from the arm base frame:
  :func:`arm_to_robot` / :func:`robot_to_arm`.

A single pose is a ``pin.SE3``, in this package's API and inside the services;
compose poses with SE3 operations (``*``, ``inverse()``, ``act``, ``actInv``).
Arrays appear only at the wire, where a 3x4 ``HgMatrix`` enters or leaves
(:func:`hg_to_se3`, :func:`as_se3` -- the one place that checks a rotation --
and :func:`se3_to_hg`), and in vectorised batches of N poses or points (the
planner's sampled paths), which stay (N, 4, 4) / (N, 3) arrays for speed.
Positions are [m], angles [rad].
"""

from __future__ import annotations

from typing import Union

import numpy as np
import numpy.typing as npt
import pinocchio as pin

from .errors import KinematicsError

__all__ = ["Pose", "arm_to_robot", "as_se3", "hg_to_se3", "pose_error", "robot_to_arm", "se3_to_hg"]

Pose = Union[npt.ArrayLike, pin.SE3]  # Union[]: `|` on a runtime alias needs both sides to support it
"""A pose as :func:`as_se3` accepts it: a 4x4 homogeneous matrix, a 3x4 ``HgMatrix`` or a ``pin.SE3``."""

_ROTATION_TOL = 1e-6  # on det - 1 and on each entry of R^T R - I


def as_se3(pose: Pose, what: str = "pose") -> pin.SE3:
    """A ``pin.SE3`` from a 4x4 homogeneous matrix or a 3x4 ``HgMatrix`` (p in [m]), or the SE3 itself.

    The 3x3 block must be a proper rotation (orthonormal, det +1, within 1e-6);
    ``what`` names the pose in the error.
    """
    if isinstance(pose, pin.SE3):
        return pose
    a = np.asarray(pose, dtype=float)
    if a.shape != (4, 4) and a.shape != (3, 4):
        raise KinematicsError(f"{what}: expected a 4x4 or 3x4 matrix, got shape {a.shape}")
    # Scalar arithmetic: faster than numpy on one 3x3 block, and IK checks every target.
    (r00, r01, r02), (r10, r11, r12), (r20, r21, r22) = a[:3, :3].tolist()
    det = r00 * (r11 * r22 - r12 * r21) - r01 * (r10 * r22 - r12 * r20) + r02 * (r10 * r21 - r11 * r20)
    tol = _ROTATION_TOL
    if not (abs(det - 1.0) < tol
            and abs(r00 * r00 + r10 * r10 + r20 * r20 - 1.0) < tol
            and abs(r01 * r01 + r11 * r11 + r21 * r21 - 1.0) < tol
            and abs(r00 * r01 + r10 * r11 + r20 * r21) < tol
            and abs(r00 * r02 + r10 * r12 + r20 * r22) < tol
            and abs(r01 * r02 + r11 * r12 + r21 * r22) < tol):
        raise KinematicsError(f"{what}: the 3x3 block is not a rotation matrix (orthonormal, det +1)")
    return pin.SE3(a[:3, :3], a[:3, 3])


def hg_to_se3(hg: npt.ArrayLike) -> pin.SE3:
    """The pose of a 3x4 ``HgMatrix`` ([R | p], p in [m]); the rotation is not checked (:func:`as_se3` does)."""
    a = np.asarray(hg, dtype=float)
    if a.shape != (3, 4):
        raise KinematicsError(f"HgMatrix: expected shape (3, 4), got {a.shape}")
    return pin.SE3(a[:, :3], a[:, 3])


def se3_to_hg(pose: pin.SE3) -> np.ndarray:
    """3x4 ``HgMatrix`` ([R | p], p in [m]) of a pose, for the wire; a new array."""
    if not isinstance(pose, pin.SE3):
        raise KinematicsError(f"pose: expected a pin.SE3, got {type(pose).__name__}")
    return pose.homogeneous[:3].copy()


def arm_to_robot(pose_arm: pin.SE3, base: pin.SE3 | None = None) -> pin.SE3:
    """Pose in the robot frame, ``inv(B) · T_arm``; ``base`` = B, identity if None. A new SE3."""
    return pose_arm.copy() if base is None else base.actInv(pose_arm)


def robot_to_arm(pose_robot: pin.SE3, base: pin.SE3 | None = None) -> pin.SE3:
    """Pose in the arm base frame, ``B · T_robot``; ``base`` = B, identity if None. A new SE3."""
    return pose_robot.copy() if base is None else base * pose_robot


def pose_error(a: pin.SE3, b: pin.SE3) -> tuple[float, float]:
    """(position error [m], rotation angle [rad]) between two poses."""
    return (float(np.linalg.norm(a.translation - b.translation)),
            float(np.linalg.norm(pin.log3(a.rotation.T @ b.rotation))))
