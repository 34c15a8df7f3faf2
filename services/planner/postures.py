"""The posture a Cartesian command asks for: its ``structFlag``.

``structFlag`` 0 takes the IK solution nearest to the start joints. On robots
with posture bits (``arm6``, ``iiwa``, ``panda``: ``kinematics/posture.py``) a
non-zero ``structFlag`` is ``POSTURE_SET | bits``: a PTP reaches the pose in
that posture (VALUE_ERR naming it if the pose has none within the joint soft
limits); a LIN / CIRC must keep the start's posture (a posture change needs a
PTP), and its target's structFlag, if non-zero, must be that posture; a CIRC's
via point's structFlag is only checked for form. Other robots refuse a
non-zero ``structFlag``.
"""

from __future__ import annotations

import pinocchio as pin

from jara_arm.kinematics.posture import BITS, POSTURE_SET, Postures, describe
from jara_arm.robots import RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.types import CarPosWithElbow

from .checks import IK_TOLERANCE
from .families import CartesianRule
from .frames import Frames
from .request import PlanRefused
from .trajectory import Joints


class PostureRule:
    """The ``structFlag`` rules of one robot model; ``postures`` None: it defines no posture bits."""

    def __init__(self, model: RobotModel, postures: Postures | None) -> None:
        self.model = model
        self.postures = postures

    def flag(self, cp: CarPosWithElbow) -> int:
        """``cp.structFlag`` checked: 0 (nearest) or, on a robot with posture bits, ``POSTURE_SET | bits``."""
        flag = cp.structFlag
        if flag == 0:
            return 0
        if self.postures is None:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"structFlag {flag}: {self.model.name} defines no posture flags; "
                              "use 0 (the IK solution nearest to the start joints)")
        if flag & ~(POSTURE_SET | BITS) or not flag & POSTURE_SET:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"structFlag {flag:#x}: {self.model.name}'s posture flags are {POSTURE_SET:#x} | "
                              f"bits (0x1 shoulder back, 0x2 elbow down, 0x4 wrist flipped), or 0 (nearest)")
        return flag

    def ik(self, op: str, flag: int, target: pin.SE3, start_arm: Joints, frames: Frames, elbow: float | None,
           rule: CartesianRule, lo: Joints, hi: Joints) -> Joints:
        """Arm joints [rad or m] that reach ``target`` (arm frame) in posture ``flag`` (non-zero) within the joint
        soft limits ``lo`` .. ``hi`` (and at arm angle ``elbow`` [rad] if given), nearest to ``start_arm``."""
        assert self.postures is not None  # flag() let no non-zero flag through without posture bits
        found = self.postures.ik(flag, target, [start_arm], tool=frames.tool, elbow=elbow, mask=rule.mask,
                                 tol_pos=IK_TOLERANCE, tol_rot=IK_TOLERANCE, lower=lo, upper=hi)
        if found is None:
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"{op}: the target pose has no IK solution with posture {describe(flag)}"
                              + (" at this arm angle" if elbow is not None else "")
                              + " within the joint soft limits")
        q: Joints = found.q
        return q

    def keep_at_start(self, op: str, flag: int, start_arm: Joints) -> None:
        """A LIN / CIRC whose target posture is ``flag`` (0: any): refused unless the start is in it."""
        if not flag or self.postures is None:
            return
        at_start = self.postures.of(start_arm)
        if flag != at_start:
            raise _differs(op, flag, at_start)

    def keep_at_end(self, op: str, flag: int, end_arm: Joints) -> None:
        """The same LIN / CIRC planned: refused unless its end is in posture ``flag`` too (0: any)."""
        if not flag or self.postures is None:
            return
        at_end = self.postures.of(end_arm)
        if at_end != flag:  # the path ends in another posture: no path keeps this one
            raise _differs(op, at_end, flag)


def _differs(op: str, target: int, start: int) -> PlanRefused:
    return PlanRefused(ReturnCode.VALUE_ERR,
                       f"{op}: the target posture {describe(target)} differs from the start's "
                       f"{describe(start)}: a posture change needs a PTP (movePTPCartesianAbs / Rel)")


__all__ = ["PostureRule"]
