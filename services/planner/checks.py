"""The checks of a motion against its settings and the robot model, before and after it is shaped.

* The settings snapshot (``MotionSettings``): one entry per arm axis, positive
  max speeds and acceleration times, speed ratios at most 100 %; a defect is
  the request's (``WireError``: VALUE_ERR naming the field), as is a joint
  target without one value per arm axis.
* A Cartesian command needs its family's support (``families.py``): NG if the
  robot cannot do it.
* Joint targets stay within the joint soft limits, and every control point
  position of a motion within the Cartesian soft limits (robot frame).
* Joint speed limits are ``maxSpeedJoint`` capped at the model's rated speeds
  (the servo refuses anything faster as an overspeed fault).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from jara_arm.kinematics import Kinematics
from jara_arm.robots import RobotModel
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.planner import MotionSettings

from . import families
from .families import CartesianKind, CartesianRule
from .frames import Frames
from .request import PlanRefused
from .sampling import BatchFk
from .trajectory import Joints

#: IK tolerance at LIN / CIRC knots and for PTP-Cartesian targets [m] and [rad]: a target is reached within it.
IK_TOLERANCE = 1e-7


class Checks:
    """The checks of one robot model; every one raises PlanRefused (or WireError, the request's defect)."""

    def __init__(self, model: RobotModel, kin: Kinematics, fk: BatchFk) -> None:
        self.model = model
        self.kin = kin
        self.n = model.axis_num
        self._fk = fk
        self._rated = np.array(model.rated_speed)

    def settings(self, s: MotionSettings) -> None:
        """The settings snapshot fits the model; raises WireError naming the field."""
        n = self.n
        for field, value, size in (("maxSpeedJoint", s.maxSpeedJoint, n),
                                   ("softLimitJoint", s.softLimitJoint, n),
                                   ("softLimitCartesian", s.softLimitCartesian, 3), ("home", s.home, n)):
            if len(value) != size:
                raise WireError(f"settings.{field}", f"expected {size} entries, got {len(value)}")
        if any(v <= 0.0 for v in s.maxSpeedJoint):
            raise WireError("settings.maxSpeedJoint", "every max speed must be positive")
        if s.maxSpeedCartesian.translation <= 0.0 or s.maxSpeedCartesian.rotation <= 0.0:
            raise WireError("settings.maxSpeedCartesian", "max speeds must be positive")
        for field in ("accelTimeJoint", "accelTimeCartesian"):
            if getattr(s, field) <= 0.0:
                raise WireError(f"settings.{field}", "acceleration time must be positive")
        for field in ("spdRatioJoint", "spdRatioCartesian"):
            if getattr(s, field) > 100:
                raise WireError(f"settings.{field}", "speed ratio above 100 %")

    def joint_arg(self, points: tuple[float, ...]) -> Joints:
        """``jointPoints`` [rad or m] as arm joints; raises WireError unless one value per arm axis."""
        if len(points) != self.n:
            raise WireError("jointPoints", f"expected {self.n} values (one per arm axis, gripper "
                            f"excluded), got {len(points)}")
        return np.array(points, dtype=float)

    def rule(self, kind: CartesianKind, op: str) -> CartesianRule:
        """What the model's family keeps of a Cartesian command of ``kind``; NG if it cannot do one."""
        r = families.rule(self.model, kind)
        if isinstance(r, families.Refused):
            raise PlanRefused(ReturnCode.NG, f"{op}: {r.why}")
        return r

    def soft_limits(self, s: MotionSettings) -> tuple[Joints, Joints]:
        """Joint soft limits [rad or m], clamped into the hard limits (IK insists on that)."""
        lo = np.maximum([lim.lower for lim in s.softLimitJoint], self.kin.lower)
        hi = np.minimum([lim.upper for lim in s.softLimitJoint], self.kin.upper)
        return lo, hi

    def joint_target(self, s: MotionSettings, target: Joints, what: str) -> None:
        """Refuse arm joints ``target`` [rad or m] outside the joint soft limits."""
        for i, (q, lim) in enumerate(zip(target, s.softLimitJoint)):
            if not lim.lower <= q <= lim.upper:
                raise PlanRefused(ReturnCode.VALUE_ERR,
                                  f"{what}: J{i + 1} = {q:.6g} is outside its joint soft limit "
                                  f"[{lim.lower:.6g}, {lim.upper:.6g}]")

    @staticmethod
    def box(s: MotionSettings, positions: NDArray[np.float64], what: str) -> None:
        """Refuse if any control-point position (N, 3) [m, robot frame] leaves the Cartesian soft limits."""
        lo = np.array([lim.lower for lim in s.softLimitCartesian])
        hi = np.array([lim.upper for lim in s.softLimitCartesian])
        bad = np.flatnonzero(np.any((positions < lo) | (positions > hi), axis=1))
        if bad.size:
            k = int(bad[0])
            p = positions[k]
            axis = int(np.flatnonzero((p < lo) | (p > hi))[0])
            last = len(positions) - 1
            where = "target" if k == last else f"path at {100.0 * k / max(1, last):.0f} %"
            raise PlanRefused(ReturnCode.VALUE_ERR,
                              f"{what}: the control point leaves the Cartesian soft limits ({where}): "
                              f"{'xyz'[axis]} = {p[axis]:.6g} m outside [{lo[axis]:.6g}, {hi[axis]:.6g}] "
                              f"(robot frame)")

    def path_box(self, s: MotionSettings, q: Joints, frames: Frames, what: str) -> None:
        """Cartesian soft-limit check of a joint-space path (wire joints (N, dof)), at every sample."""
        if np.all(q[0, :self.n] == q[-1, :self.n]):
            return  # the arm does not move (gripper only, or already there)
        self.box(s, frames.to_robot(self._fk.run(q[:, :self.n], frames.tool)[0]), what)

    def vmax(self, s: MotionSettings) -> Joints:
        """Joint speed limits of the wire axes [rad/s or m/s]: settings capped at the rated speeds."""
        v = np.minimum(np.array(s.maxSpeedJoint, dtype=float), self._rated)
        if self.model.has_gripper:
            v = np.append(v, self.model.gripper_speed)
        return v


__all__ = ["Checks", "IK_TOLERANCE"]
