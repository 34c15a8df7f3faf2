"""The motions planned in joint space: PTP (joint, Cartesian, goHome) and the gripper.

* PTP: a joint-space line, speed ``spdRatioJoint`` x ``maxSpeedJoint``
  synchronised to the slowest axis, ``accelTimeJoint``, every sample's control
  point within the Cartesian soft limits. A Cartesian target is solved by IK
  nearest to the start joints, or in the posture its ``structFlag`` names
  (``postures.py``).
* Gripper: the gripper axis alone, at the model's gripper speed with
  ``accelTimeJoint``; the arm holds.

Each is planned whole in one go (``profile.py``): no stages, no early start.
"""

from __future__ import annotations

from jara_arm.kinematics import Kinematics
from jara_arm.robots import RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.types import CarPosWithElbow

from . import families
from .checks import IK_TOLERANCE, Checks
from .elbow import elbow_targets
from .families import CartesianKind
from .frames import Frames, commanded_pose, control_pose
from .postures import PostureRule
from .profile import PathMotion, plan_joint_ptp
from .request import PlanRefused, PlanRequest
from .trajectory import UNQUEUED, Joints, LineMap, PlannedMotion


class JointMotions:
    """Plans the joint-space motions of one robot model."""

    def __init__(self, model: RobotModel, kin: Kinematics, checks: Checks, postures: PostureRule) -> None:
        self.model = model
        self.kin = kin
        self.checks = checks
        self.postures = postures
        self.n = model.axis_num
        self.dt = model.cmd_cycle

    def joint(self, req: PlanRequest, start: Joints, target: Joints, what: str = "target") -> PlannedMotion:
        """A PTP from wire joints ``start`` to arm joints ``target`` [rad or m] (``what`` names it in a refusal)."""
        s = req.settings
        self.checks.joint_target(s, target, f"{req.op} {what}")
        if s.spdRatioJoint == 0:
            raise PlanRefused(ReturnCode.STATUS_ERR, "joint speed ratio is 0 %: call setSpeedJoint first")
        q1 = start.copy()
        q1[:self.n] = target
        planned = self._motion(req, plan_joint_ptp(start, q1, self.checks.vmax(s), s.spdRatioJoint / 100.0,
                                                   s.accelTimeJoint))
        self.checks.path_box(s, planned.q, Frames.of(s), req.op)
        return planned

    def cartesian(self, req: PlanRequest, start: Joints, cp: CarPosWithElbow, relative: bool) -> PlannedMotion:
        """A PTP to the pose ``cp`` commands (robot frame; ``relative``: from the start pose)."""
        s = req.settings
        rule = self.checks.rule(CartesianKind.LINEAR, req.op)
        frames = Frames.of(s, planar=rule.planar)
        T0 = control_pose(self.kin, start[:self.n], frames)
        flag = self.postures.flag(cp)
        T1 = commanded_pose(cp, T0, relative, rule)
        self.checks.box(s, T1.translation[None], req.op)
        _, elbow = elbow_targets(self.kin, cp, start[:self.n], relative, rule)
        lo, hi = self.checks.soft_limits(s)
        target = families.reachable_pose(rule, self.kin, frames.base * T1, frames.tool)
        if flag:
            return self.joint(req, start, self.postures.ik(req.op, flag, target, start[:self.n], frames, elbow,
                                                           rule, lo, hi))
        res = self.kin.ik(target, start[:self.n], tool=frames.tool, elbow=elbow,
                          mask=rule.mask, tol_pos=IK_TOLERANCE, tol_rot=IK_TOLERANCE, lower=lo, upper=hi)
        if not res.success:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"{req.op}: target pose unreachable within the joint soft limits "
                              f"(best IK residual {res.pos_err:.3g} m, {res.rot_err:.3g} rad"
                              + (f", arm angle {res.elbow_err:.3g} rad)" if elbow is not None else ")"))
        return self.joint(req, start, res.q)

    def gripper(self, req: PlanRequest, start: Joints, ratio: int) -> PlannedMotion:
        """The gripper to ``ratio`` [%] of its opening (0 closed, 100 open)."""
        lim = self.model.gripper_limits
        if lim is None:
            raise PlanRefused(ReturnCode.NG, f"{req.op}: this robot has no gripper")
        if ratio > 100:
            raise PlanRefused(ReturnCode.VALUE_ERR, f"{req.op}: angleRatio {ratio} % is above 100 %")
        q1 = start.copy()
        q1[self.n] = lim.lower + ratio / 100.0 * (lim.upper - lim.lower)
        return self._motion(req, plan_joint_ptp(start, q1, self.checks.vmax(req.settings), 1.0,
                                                req.settings.accelTimeJoint))

    def _motion(self, req: PlanRequest, motion: PathMotion) -> PlannedMotion:
        _, q = motion.sample(self.dt)
        return PlannedMotion(UNQUEUED, req.op, LineMap(motion.path), motion.profile, q, self.dt)


__all__ = ["JointMotions"]
