"""The Cartesian side of the command service: feedback pose and the arm's reach.

Frames as in DECISIONS.md "Frames": the control point is ``T_flange · C`` in
the arm base frame, and a pose in the robot frame is ``inv(B) · T_arm``.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import pinocchio as pin

from jara_arm.kinematics import Kinematics, arm_to_robot, as_se3, se3_to_hg
from jara_arm.kinematics.posture import Postures
from jara_arm.robots import Family, RobotModel
from jara_arm.schema.types import CarPosWithElbow, HgMatrix, LimitValue


def _about_z(r: np.ndarray) -> np.ndarray:
    """The rotation about Z (3x3) nearest to ``r``."""
    psi = float(np.arctan2(r[1, 0] - r[0, 1], r[0, 0] + r[1, 1]))
    c, s = np.cos(psi), np.sin(psi)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def reach(kinematics: Kinematics) -> float:
    """Radius [m] of a ball about the arm base origin that holds the flange in every pose.

    Walking from the flange to the base, a revolute joint keeps the distance
    between its origin and the next joint's origin, and a prismatic joint
    changes it by at most its stroke; so the sum of the fixed offsets (joint
    placements and the flange placement, read from the URDF) plus every
    prismatic stroke bounds the distance (triangle inequality).
    """
    model = kinematics.pin_model
    robot = kinematics.robot
    fid = model.getFrameId(robot.flange_frame)
    frame = model.frames[fid]
    total = float(np.linalg.norm(frame.placement.translation))
    joint = frame.parentJoint
    while joint > 0:
        total += float(np.linalg.norm(model.jointPlacements[joint].translation))
        jm = model.joints[joint]
        if jm.shortname().startswith("JointModelP"):  # prismatic: PX, PY, PZ, PrismaticUnaligned
            lo, hi = model.lowerPositionLimit[jm.idx_q], model.upperPositionLimit[jm.idx_q]
            total += float(max(abs(lo), abs(hi)))
        joint = model.parents[joint]
    return total


def reach_box(radius: float, base_offset: HgMatrix) -> tuple[LimitValue, LimitValue, LimitValue]:
    """x, y, z limits [m] in the robot frame of a cube that holds the ball of ``radius`` about the arm base.

    The arm base origin in the robot frame is ``inv(B)`` applied to the origin;
    an axis-aligned cube of half-size ``radius`` holds the ball whatever B's rotation.
    """
    x, y, z = (float(c) for c in as_se3(base_offset, "base offset").actInv(np.zeros(3)))
    return (LimitValue(x + radius, x - radius), LimitValue(y + radius, y - radius),
            LimitValue(z + radius, z - radius))


class CartesianFeedback:
    """Control-point pose of joint feedback; one instance per thread (it owns a Pinocchio work area)."""

    def __init__(self, robot: RobotModel) -> None:
        self.robot = robot
        self.kinematics = Kinematics(robot, seed_table=0)  # FK only: no IK seed table
        self.postures = Postures(self.kinematics) if robot.posture_joints is not None else None

    def pose(self, joints: Sequence[float], base_offset: HgMatrix,
             control_point_offset: HgMatrix) -> CarPosWithElbow:
        """``inv(B) · T_flange(q) · C`` and, for 7 axes, the measured arm angle [rad] (else 0).

        Per family (SPEC.md §7): a gantry reports where its carriage is (1 axis: X moves,
        Y, Z and the orientation are those of the model; 2 axes: X and Y move); a SCARA
        reports its orientation as the rotation about the robot frame's Z axis only (the
        rotation about Z nearest to the measured one: the same projection as its commands,
        so a tilted control point offset or base offset adds no X / Y rotation); articulated
        arms the full pose. ``elbow`` is the measured arm angle on 7 axes, 0 otherwise.
        ``structFlag`` is the arm's posture ``POSTURE_SET | bits`` on robots that define posture
        bits (``kinematics/posture.py``), 0 on the others.

        ``joints`` [rad or m] may include the gripper axis after the arm axes; it is ignored.
        """
        q = np.asarray(joints[: self.robot.axis_num], dtype=float)
        t_arm = self.kinematics.control_point(q, as_se3(control_point_offset, "tool"))
        hg = se3_to_hg(arm_to_robot(t_arm, as_se3(base_offset, "base offset")))
        if self.robot.family is Family.SCARA:
            hg[:, :3] = _about_z(hg[:, :3])
        # Re-orthonormalise: float error must not make the reply fail the codec's rotation check.
        hg[:, :3] = pin.Quaternion(hg[:, :3]).normalized().toRotationMatrix()
        hg.flags.writeable = False
        elbow = self.kinematics.elbow_angle(q) if self.robot.axis_num == 7 else 0.0
        posture = self.postures.of(q) if self.postures is not None else 0
        return CarPosWithElbow(hg, float(elbow), posture)
