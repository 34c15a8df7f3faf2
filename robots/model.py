"""A robot model: what every service needs to know about one kind of arm."""

from __future__ import annotations

import dataclasses
import enum
import math
import xml.etree.ElementTree as ET
from functools import cached_property
from pathlib import Path

from jara_arm.schema.errors import JaraArmError
from jara_arm.schema.types import LimitValue, ManipInfo


class RobotModelError(JaraArmError, ValueError):
    """A robot model whose configuration does not hold together."""


class Family(enum.Enum):
    """Robot families of the specification (SPEC.md §7, "Per-family rules")."""

    CARTESIAN = "cartesian"  # 1-3 axis gantry
    SCARA = "scara"  # 4-axis horizontal articulated
    ARTICULATED = "articulated"  # 5-7 axis vertical articulated


@dataclasses.dataclass(frozen=True)
class Obstacle:
    """A fixed box in the simulated world, for the arm to run into (overload for real)."""

    position: tuple[float, float, float]  # [m] centre, in the world frame (the arm base at base_position)
    half_extents: tuple[float, float, float]  # [m] half the box's size along x, y, z

    def __post_init__(self) -> None:
        if len(self.position) != 3 or len(self.half_extents) != 3:
            raise RobotModelError("an obstacle needs 3 position and 3 half-extent values")
        if not all(math.isfinite(v) for v in self.position + self.half_extents):
            raise RobotModelError("obstacle values must be finite numbers")
        if not all(h > 0.0 for h in self.half_extents):
            raise RobotModelError(f"obstacle half extents must be positive, got {self.half_extents}")

    @classmethod
    def parse(cls, text: str) -> "Obstacle":
        """``x,y,z,hx,hy,hz`` [m]: centre and half extents; RobotModelError if malformed."""
        parts = [p.strip() for p in text.split(",")]
        if len(parts) != 6:
            raise RobotModelError(f"obstacle {text!r}: expected x,y,z,hx,hy,hz (6 numbers in m)")
        try:
            v = [float(p) for p in parts]
        except ValueError:
            raise RobotModelError(f"obstacle {text!r}: expected x,y,z,hx,hy,hz (6 numbers in m)") from None
        return cls((v[0], v[1], v[2]), (v[3], v[4], v[5]))

    def argument(self) -> str:
        """The ``x,y,z,hx,hy,hz`` form, for a command line."""
        return ",".join(f"{v:g}" for v in self.position + self.half_extents)


@dataclasses.dataclass(frozen=True)
class RobotModel:
    """One robot model: its URDF, its joints, its ratings and its defaults.

    Joint values are [rad] for revolute and [m] for prismatic joints. The
    gripper, if fitted, is ONE axis after the arm axes; all its URDF joints
    are driven to the same value.
    """

    name: str  # the name on the command line (``--robot``)
    manufacturer: str
    type: str
    family: Family
    urdf: Path
    arm_joints: tuple[str, ...]  # URDF joint names, J1..Jn
    flange_frame: str  # URDF link of the flange
    rated_speed: tuple[float, ...]  # [rad/s or m/s] per arm axis
    rated_effort: tuple[float, ...]  # [N m or N] per arm axis
    min_accel_time: float  # [s] joint moves, rest to max speed
    min_accel_time_cartesian: float  # [s]
    ready_pose: tuple[float, ...]  # [rad or m] home position
    gripper_joints: tuple[str, ...] = ()  # URDF joints moved together as the gripper axis
    gripper_speed: float = 0.0  # [m/s or rad/s] of the gripper axis
    gripper_effort: float = 0.0  # [N or N m]
    cmd_cycle_ms: int = 1  # [ms] servo period
    base_position: tuple[float, float, float] = (0.0, 0.0, 0.0)  # [m] in the simulated world
    obstacles: tuple[Obstacle, ...] = ()  # fixed boxes in the simulated world
    # Posture bits (structFlag, kinematics/posture.py): zero-based shoulder, elbow, wrist joints S, E, W;
    # None: the robot defines none and structFlag must be 0.
    posture_joints: tuple[int, int, int] | None = None

    def __post_init__(self) -> None:
        n = len(self.arm_joints)
        if not 1 <= n <= 7:
            raise RobotModelError(f"{self.name}: 1 to 7 arm axes, got {n}")
        for field in ("rated_speed", "rated_effort", "ready_pose"):
            if len(getattr(self, field)) != n:
                raise RobotModelError(f"{self.name}: {field} needs {n} values (one per arm axis)")
        if not self.urdf.is_file():
            raise RobotModelError(f"{self.name}: URDF not found: {self.urdf}")
        if self.cmd_cycle_ms < 1:
            raise RobotModelError(f"{self.name}: cmd_cycle_ms must be >= 1")
        pj = self.posture_joints
        if pj is not None and (n not in (6, 7) or not 0 <= pj[0] < pj[1] < pj[2] < n):
            raise RobotModelError(f"{self.name}: posture_joints need 6 or 7 axes and three increasing "
                                  f"axis indices, got {pj}")
        limits = self.hard_limits
        for i, (q, lim) in enumerate(zip(self.ready_pose, limits)):
            if not lim.lower <= q <= lim.upper:
                raise RobotModelError(f"{self.name}: ready_pose[{i}]={q} outside {lim}")

    @property
    def axis_num(self) -> int:
        """``axisNum``: arm axes without the gripper."""
        return len(self.arm_joints)

    @property
    def has_gripper(self) -> bool:
        return bool(self.gripper_joints)

    @property
    def dof(self) -> int:
        """Length of a ``JointPos`` on the wire: arm axes, plus one gripper axis if fitted."""
        return self.axis_num + (1 if self.has_gripper else 0)

    @property
    def cmd_cycle(self) -> float:
        """Servo period [s]."""
        return self.cmd_cycle_ms * 1e-3

    @property
    def manip_info(self) -> ManipInfo:
        return ManipInfo(self.manufacturer, self.type, self.axis_num, self.cmd_cycle_ms,
                         self.has_gripper)

    @cached_property
    def _urdf_limits(self) -> dict[str, tuple[str, LimitValue, float, float]]:
        """URDF joint name -> (type, limits, velocity, effort)."""
        out = {}
        for j in ET.parse(self.urdf).getroot().iter("joint"):
            lim = j.find("limit")
            if lim is None:
                continue
            out[j.get("name")] = (
                j.get("type"),
                LimitValue(float(lim.get("upper", 0)), float(lim.get("lower", 0))),
                float(lim.get("velocity", 0)),
                float(lim.get("effort", 0)),
            )
        for name in self.arm_joints + self.gripper_joints:
            if name not in out:
                raise RobotModelError(f"{self.name}: joint {name!r} has no <limit> in {self.urdf}")
        return out

    @property
    def hard_limits(self) -> tuple[LimitValue, ...]:
        """Per arm axis [rad or m], from the URDF."""
        return tuple(self._urdf_limits[j][1] for j in self.arm_joints)

    @property
    def gripper_limits(self) -> LimitValue | None:
        """The gripper axis range: ``lower`` fully closed, ``upper`` fully open."""
        return self._urdf_limits[self.gripper_joints[0]][1] if self.has_gripper else None

    @property
    def prismatic(self) -> tuple[bool, ...]:
        """Per arm axis: True for a prismatic (linear) axis."""
        return tuple(self._urdf_limits[j][0] == "prismatic" for j in self.arm_joints)

    @property
    def max_accel(self) -> tuple[float, ...]:
        """Per arm axis [rad/s^2 or m/s^2]: rated speed reached in the min accel time."""
        return tuple(v / self.min_accel_time for v in self.rated_speed)
