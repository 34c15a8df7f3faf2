"""The settings of the Middle interface: values, defaults, validation.

:class:`Settings` is a frozen value; every setter is a ``with_*`` method that
checks its argument and returns a new value, or raises :class:`WireError`
naming the offending field (the RPC layer answers ``VALUE_ERR`` with it), so a
bad value changes nothing. Every motion accepted after a setter carries the new
value in its :class:`MotionSettings` snapshot.

Defaults (DECISIONS.md, and the choices below):

* speed ratios 0 % (the specification's initial value: motions are refused
  until one is set);
* joint max speeds: the model's rated speeds, which are also their upper bound;
* Cartesian max speed: 0.25 m/s, 1.0 rad/s;
* min accel times: the model's ``min_accel_time`` / ``min_accel_time_cartesian``;
  accel times equal to them. Raising a minimum above the current accel time
  raises the accel time with it, so that "accel time >= minimum" always holds;
  lowering a minimum leaves the accel time alone;
* Cartesian soft limits: until ``setSoftLimitCartesian`` is called, the cube of
  half-size ``reach + |C.p|`` centred on the arm base origin seen in the robot
  frame (it follows the base offset B and the control point offset C), which
  holds every pose the control point can take;
* base offset and control point offset: identity;
* home: the model's ready pose; ``setHome`` must lie within the joint soft limits;
* blend distance (``Ext/setBlendDistance``, outside the IDL): 0 m, the
  specification's exact stop; at most ``MAX_BLEND_DISTANCE``.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Sequence

import numpy as np

from jara_arm.robots import RobotModel
from jara_arm.schema.errors import WireError
from jara_arm.schema.operations import MAX_BLEND_DISTANCE, OP
from jara_arm.schema.planner import MotionSettings
from jara_arm.schema.types import IDENTITY, CartesianSpeed, HgMatrix, JointPos, LimitValue

from .cartesian import reach_box

#: Initial Cartesian max speed (DECISIONS.md): the ISO 10218 collaborative reduced speed [m/s]
#: and 1 rad/s.
DEFAULT_MAX_SPEED_CARTESIAN = CartesianSpeed(0.25, 1.0)
MAX_SPEED_RATIO = 100  # [%]
#: Relative slack on "at most the rated speed", so that a rated value read back and sent
#: again is accepted whatever rounding it went through [-].
_RATED_SLACK = 1e-9

CartesianLimits = tuple[LimitValue, LimitValue, LimitValue]
_XYZ = ("xLimit", "yLimit", "zLimit")


@dataclasses.dataclass(frozen=True, eq=False)  # holds arrays: compare members, not settings
class Settings:
    """Every value the Middle (and Ext) setters change (units in brackets)."""

    axis_num: int
    rated_speed: tuple[float, ...]  # [rad/s or m/s] upper bound of max speeds, per arm axis
    prismatic: tuple[bool, ...]
    reach: float  # [m] arm reach about the arm base origin (default Cartesian limits)
    spd_ratio_joint: int = 0  # [%]
    spd_ratio_cartesian: int = 0  # [%]
    max_speed_joint: tuple[float, ...] = ()  # [rad/s or m/s]
    max_speed_cartesian: CartesianSpeed = DEFAULT_MAX_SPEED_CARTESIAN
    min_accel_time_joint: float = 0.0  # [s]
    min_accel_time_cartesian: float = 0.0  # [s]
    accel_time_joint: float = 0.0  # [s]
    accel_time_cartesian: float = 0.0  # [s]
    soft_limit_cartesian: CartesianLimits | None = None  # [m] robot frame; None: the reach box
    base_offset: HgMatrix = dataclasses.field(default_factory=lambda: IDENTITY)  # read-only
    control_point_offset: HgMatrix = dataclasses.field(default_factory=lambda: IDENTITY)
    home: JointPos = ()  # [rad or m]
    blend_distance: float = 0.0  # [m] Ext; 0: exact stop at every corner

    @classmethod
    def defaults(cls, robot: RobotModel, reach: float) -> "Settings":
        return cls(
            axis_num=robot.axis_num, rated_speed=tuple(robot.rated_speed),
            prismatic=tuple(robot.prismatic), reach=reach,
            max_speed_joint=tuple(robot.rated_speed),
            min_accel_time_joint=robot.min_accel_time,
            min_accel_time_cartesian=robot.min_accel_time_cartesian,
            accel_time_joint=robot.min_accel_time,
            accel_time_cartesian=robot.min_accel_time_cartesian,
            home=tuple(robot.ready_pose),
        )

    # -- derived ---------------------------------------------------------------------
    @property
    def cartesian_limits(self) -> CartesianLimits:
        """The Cartesian soft limits in force: the ones set, else the reach box."""
        if self.soft_limit_cartesian is not None:
            return self.soft_limit_cartesian
        tool = float(np.linalg.norm(np.asarray(self.control_point_offset)[:, 3]))
        return reach_box(self.reach + tool, self.base_offset)

    def snapshot(self, soft_limit_joint: Sequence[LimitValue]) -> MotionSettings:
        """What a motion accepted now is planned with; the joint limits come from the servo."""
        return MotionSettings(
            spdRatioJoint=self.spd_ratio_joint, spdRatioCartesian=self.spd_ratio_cartesian,
            maxSpeedJoint=self.max_speed_joint, maxSpeedCartesian=self.max_speed_cartesian,
            accelTimeJoint=self.accel_time_joint, accelTimeCartesian=self.accel_time_cartesian,
            softLimitJoint=tuple(soft_limit_joint), softLimitCartesian=self.cartesian_limits,
            baseOffset=self.base_offset, controlPointOffset=self.control_point_offset,
            home=self.home, blendDistance=self.blend_distance,
        )

    # -- setters ---------------------------------------------------------------------
    def with_speed_joint(self, spdRatio: int) -> "Settings":
        return dataclasses.replace(self, spd_ratio_joint=_ratio(spdRatio))

    def with_speed_cartesian(self, spdRatio: int) -> "Settings":
        return dataclasses.replace(self, spd_ratio_cartesian=_ratio(spdRatio))

    def with_max_speed_joint(self, speed: Sequence[float]) -> "Settings":
        self._check_length("speed", speed)
        for i, (v, rated, linear) in enumerate(zip(speed, self.rated_speed, self.prismatic)):
            unit = "m/s" if linear else "rad/s"
            if not v > 0.0:
                raise WireError(f"speed[{i}]", f"max speed of J{i + 1} must be positive, got {v} {unit}")
            if v > rated * (1.0 + _RATED_SLACK):
                raise WireError(f"speed[{i}]", f"{v} {unit} is above the rated speed {rated:.6g} {unit} "
                                f"of J{i + 1}")
        return dataclasses.replace(self, max_speed_joint=tuple(float(v) for v in speed))

    def with_max_speed_cartesian(self, speed: CartesianSpeed) -> "Settings":
        if not speed.translation > 0.0:
            raise WireError("speed.translation", f"must be positive, got {speed.translation} m/s")
        if not speed.rotation > 0.0:
            raise WireError("speed.rotation", f"must be positive, got {speed.rotation} rad/s")
        return dataclasses.replace(self, max_speed_cartesian=speed)

    def with_min_accel_time_joint(self, aclTime: float) -> "Settings":
        _positive_time(aclTime)
        return dataclasses.replace(self, min_accel_time_joint=aclTime,
                                   accel_time_joint=max(self.accel_time_joint, aclTime))

    def with_min_accel_time_cartesian(self, aclTime: float) -> "Settings":
        _positive_time(aclTime)
        return dataclasses.replace(self, min_accel_time_cartesian=aclTime,
                                   accel_time_cartesian=max(self.accel_time_cartesian, aclTime))

    def with_accel_time_joint(self, aclTime: float) -> "Settings":
        _not_below(aclTime, self.min_accel_time_joint, OP.setMinAccelTimeJoint)
        return dataclasses.replace(self, accel_time_joint=aclTime)

    def with_accel_time_cartesian(self, aclTime: float) -> "Settings":
        _not_below(aclTime, self.min_accel_time_cartesian, OP.setMinAccelTimeCartesian)
        return dataclasses.replace(self, accel_time_cartesian=aclTime)

    def with_soft_limit_cartesian(self, xLimit: LimitValue, yLimit: LimitValue,
                                  zLimit: LimitValue) -> "Settings":
        limits = (xLimit, yLimit, zLimit)
        for name, lim in zip(_XYZ, limits):
            if not lim.lower < lim.upper:
                raise WireError(name, f"lower {lim.lower} m must be below upper {lim.upper} m")
        return dataclasses.replace(self, soft_limit_cartesian=limits)

    def with_base_offset(self, offset: HgMatrix) -> "Settings":
        return dataclasses.replace(self, base_offset=offset)

    def with_control_point_offset(self, offset: HgMatrix) -> "Settings":
        return dataclasses.replace(self, control_point_offset=offset)

    def with_home(self, jointPoint: Sequence[float], soft_limit_joint: Sequence[LimitValue]) -> "Settings":
        """Home within ``soft_limit_joint`` (the servo's current joint soft limits)."""
        self._check_length("jointPoint", jointPoint)
        for i, (q, lim) in enumerate(zip(jointPoint, soft_limit_joint)):
            if not lim.lower <= q <= lim.upper:
                raise WireError(f"jointPoint[{i}]", f"J{i + 1}={q:.6g} is outside the joint soft limit "
                                f"[{lim.lower:.6g}, {lim.upper:.6g}]")
        return dataclasses.replace(self, home=tuple(float(q) for q in jointPoint))

    def with_blend_distance(self, distance: float) -> "Settings":
        """``Ext/setBlendDistance``: 0 .. ``MAX_BLEND_DISTANCE`` [m]."""
        if not math.isfinite(distance) or distance < 0.0:
            raise WireError("distance", f"must be a finite length of 0 m or more, got {distance} m")
        if distance > MAX_BLEND_DISTANCE:
            raise WireError("distance", f"{distance} m is above the largest blend distance {MAX_BLEND_DISTANCE} m")
        return dataclasses.replace(self, blend_distance=float(distance))

    def check_joint_points(self, field: str, values: Sequence[float]) -> None:
        """WireError naming ``field`` unless ``values`` has one entry per arm axis."""
        self._check_length(field, values)

    def _check_length(self, field: str, values: Sequence[float]) -> None:
        if len(values) != self.axis_num:
            raise WireError(field, f"expected {self.axis_num} values (one per arm axis, J1..J"
                            f"{self.axis_num}), got {len(values)}")


def _ratio(spdRatio: int) -> int:
    if spdRatio > MAX_SPEED_RATIO:
        raise WireError("spdRatio", f"{spdRatio} % is above {MAX_SPEED_RATIO} %")
    return spdRatio


def _positive_time(aclTime: float) -> None:
    if not aclTime > 0.0:
        raise WireError("aclTime", f"must be positive, got {aclTime} s")


def _not_below(aclTime: float, minimum: float, setter: str) -> None:
    if aclTime < minimum:
        raise WireError("aclTime", f"{aclTime} s is below the minimum acceleration time "
                        f"{minimum} s (see {setter})")
