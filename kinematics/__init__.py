"""Kinematics of one arm on Pinocchio, shared by the services: frames, the arm angle, FK, Jacobians, IK.

=================  ==================================================================
``errors``         :class:`KinematicsError`, the package's one error root
``frames``         poses (``pin.SE3``; 3x4 ``HgMatrix`` only at the wire: ``as_se3``, ``se3_to_hg``),
                   arm base <-> robot frame, pose error
``arm_angle``      the arm angle of a 7-axis arm, its value and gradient on Pinocchio
``ik``             task masks, :class:`IkResult`, seed table, restarts, the IK loop
``model``          :class:`Kinematics`: one arm's model, limits, FK, Jacobians, ``ik``
``posture``        posture bits (``structFlag``) of 6- and 7-axis arms: reading them, IK that holds them
=================  ==================================================================

Frames are those of DECISIONS.md "Frames" (see :mod:`.frames`). Positions are
[m], angles [rad]; joint values are [rad] (revolute) or [m] (prismatic), in the
order J1..Jn = ``RobotModel.arm_joints``.
"""

from .arm_angle import DEFAULT_ELBOW_JOINTS, arm_angle
from .errors import KinematicsError
from .frames import Pose, arm_to_robot, as_se3, hg_to_se3, pose_error, robot_to_arm, se3_to_hg
from .ik import FULL_MASK, POSITION_MASK, IkResult, Mask
from .model import Kinematics

__all__ = [
    "DEFAULT_ELBOW_JOINTS",
    "FULL_MASK",
    "POSITION_MASK",
    "IkResult",
    "Kinematics",
    "KinematicsError",
    "Mask",
    "Pose",
    "arm_angle",
    "arm_to_robot",
    "as_se3",
    "hg_to_se3",
    "pose_error",
    "robot_to_arm",
    "se3_to_hg",
]
