"""The frames of a Cartesian command (DECISIONS.md "Frames"), and the poses a command asks for in them.

Cartesian commands are in the robot frame. With the base offset ``B`` (robot
frame seen from the arm frame) a robot-frame pose ``T`` is ``B · T`` in the arm
frame, where kinematics works; the controlled pose is ``T_flange · C``
(``C``: control point offset). A relative target adds its translation in the
robot frame and applies its rotation about the robot frame axes
(``R_rel · R_start``). What each family ignores of a pose (``families.py``)
is applied here, to the commanded pose and to a path's poses before IK.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pinocchio as pin
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics, arm_to_robot, hg_to_se3
from jara_arm.schema.planner import MotionSettings
from jara_arm.schema.types import CarPosWithElbow

from . import families
from .families import CartesianRule, Orientation


@dataclasses.dataclass(frozen=True)
class Frames:
    """The settings' frames, decoded from the wire once per motion."""

    base: pin.SE3  # B: robot frame seen from the arm frame
    tool: pin.SE3  # C: control point in the flange frame

    @classmethod
    def of(cls, settings: MotionSettings, *, planar: bool = False) -> Frames:
        """The frames of ``settings``; ``planar`` (a family that works in the arm frame): no base offset."""
        base = pin.SE3.Identity() if planar else hg_to_se3(settings.baseOffset)
        return cls(base, hg_to_se3(settings.controlPointOffset))

    def to_robot(self, points: NDArray[np.float64]) -> NDArray[np.float64]:
        """Arm-frame points (N, 3) [m] in the robot frame: inv(B) on a batch, as an array for speed."""
        inv = self.base.inverse()
        return points @ inv.rotation.T + inv.translation


def control_pose(kin: Kinematics, q_arm: NDArray[np.float64], frames: Frames) -> pin.SE3:
    """Control point pose in the robot frame at arm joints ``q_arm`` [rad or m]."""
    return arm_to_robot(kin.control_point(q_arm, frames.tool), frames.base)


def commanded_pose(cp: CarPosWithElbow, start_pose: pin.SE3, relative: bool, rule: CartesianRule) -> pin.SE3:
    """The pose ``cp`` commands from ``start_pose`` (robot frame; arm frame for ``planar``) after the family rule."""
    cmd = hg_to_se3(cp.carPos)
    r0, p0 = start_pose.rotation, start_pose.translation
    if relative:
        # The command acts in the frame at the start point with the robot frame's axes:
        # its translation along the robot axes, its rotation about them (R_rel · R_start).
        at_start = pin.SE3(np.eye(3), p0)
        T = at_start * cmd * at_start.actInv(start_pose)
    else:
        T = cmd
    if rule.orientation is Orientation.KEEP:
        T = pin.SE3(r0, T.translation)
    elif rule.orientation is Orientation.YAW:
        T = pin.SE3(_yaw_only(T.rotation @ r0.T) @ r0, T.translation)
    if rule.planar:
        T = pin.SE3(T.rotation, np.array([*T.translation[:2], p0[2]]))
    return T


def ik_targets(kin: Kinematics, poses: NDArray[np.float64], frames: Frames,
               rule: CartesianRule) -> NDArray[np.float64]:
    """Robot-frame path poses (N, 4, 4) as IK must meet them: arm frame, family rule applied."""
    if frames.base != pin.SE3.Identity():  # B · T on the batch, as an array for speed
        poses = np.einsum("ij,njk->nik", frames.base.homogeneous, poses)
    return families.reachable(rule, kin, poses, frames.tool)


def _yaw_only(r_delta: NDArray[np.float64]) -> NDArray[np.float64]:
    """The rotation about Z nearest to ``r_delta`` (3x3)."""
    psi = math.atan2(r_delta[1, 0] - r_delta[0, 1], r_delta[0, 0] + r_delta[1, 1])
    c, s = math.cos(psi), math.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


__all__ = ["Frames", "commanded_pose", "control_pose", "ik_targets"]
