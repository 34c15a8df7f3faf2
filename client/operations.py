"""Every operation of the arm as a typed method, by its IDL name (generated: do not edit).

``python -m jara_arm.client.generate`` writes this file from ``jara_arm.schema.operations``. A method
returns the operation's out parameters (None, the one, or a tuple in IDL order) and raises
:class:`~jara_arm.client.errors.Refused` for any RETURN_ID but OK; a motion returns its
:class:`~jara_arm.client.motion.Motion`, after its end with ``wait=True`` (the default).
"""

from __future__ import annotations

import abc
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from jara_arm.schema.operations import OP, Interface
from jara_arm.schema.types import Alarm, CarPosWithElbow, CartesianSpeed, LimitValue, ManipInfo

from .motion import Motion


class Operations(abc.ABC):
    """The operations of ``Common``, ``Middle`` and ``Ext``; :class:`~jara_arm.client.Arm` carries them."""

    @abc.abstractmethod
    def _call(self, interface: Interface, name: str, args: Mapping[str, Any]) -> tuple[Any, ...]:
        """The out parameters of one call, in IDL order; raises for anything but OK."""

    @abc.abstractmethod
    def _move(self, interface: Interface, name: str, args: Mapping[str, Any], wait: bool,
              timeout: float | None) -> Motion:
        """One motion operation: its handle, after its end if ``wait``."""

    def clearAlarms(self) -> None:
        """Clear the active alarms whose cause has gone."""
        args: dict[str, Any] = {}
        self._call(Interface.COMMON, OP.clearAlarms, args)

    def getActiveAlarm(self) -> tuple[Alarm, ...]:
        """The active alarms; an empty sequence when none."""
        args: dict[str, Any] = {}
        result: tuple[Alarm, ...] = self._call(Interface.COMMON, OP.getActiveAlarm, args)[0]
        return result

    def getFeedbackPosJoint(self) -> tuple[float, ...]:
        """Joint position feedback, J1..Jn then the gripper."""
        args: dict[str, Any] = {}
        result: tuple[float, ...] = self._call(Interface.COMMON, OP.getFeedbackPosJoint, args)[0]
        return result

    def getManipInfo(self) -> ManipInfo:
        """Manipulator information."""
        args: dict[str, Any] = {}
        result: ManipInfo = self._call(Interface.COMMON, OP.getManipInfo, args)[0]
        return result

    def getSoftLimitJoint(self) -> tuple[LimitValue, ...]:
        """Joint soft limits, one per axis (gripper excluded)."""
        args: dict[str, Any] = {}
        result: tuple[LimitValue, ...] = self._call(Interface.COMMON, OP.getSoftLimitJoint, args)[0]
        return result

    def getState(self) -> int:
        """State bits: 0x01 servo on, 0x02 moving, 0x04 alarm, 0x08 buffer full, 0x10 paused."""
        args: dict[str, Any] = {}
        result: int = self._call(Interface.COMMON, OP.getState, args)[0]
        return result

    def servoOFF(self) -> None:
        """All axes servo off; brakes hold the joints."""
        args: dict[str, Any] = {}
        self._call(Interface.COMMON, OP.servoOFF, args)

    def servoON(self) -> None:
        """All axes servo on."""
        args: dict[str, Any] = {}
        self._call(Interface.COMMON, OP.servoON, args)

    def setSoftLimitJoint(self, softLimit: Sequence[LimitValue]) -> None:
        """Set the joint soft limits, one per axis; refused while moving or alarmed. ``softLimit`` [rad or
        m]."""
        args: dict[str, Any] = {"softLimit": softLimit}
        self._call(Interface.COMMON, OP.setSoftLimitJoint, args)

    def closeGripper(self, *, wait: bool = True, timeout: float | None = None) -> Motion:
        """Close the gripper fully."""
        args: dict[str, Any] = {}
        return self._move(Interface.MIDDLE, OP.closeGripper, args, wait, timeout)

    def getBaseOffset(self) -> NDArray[np.float64]:
        """Base offset: the robot frame seen from the arm frame."""
        args: dict[str, Any] = {}
        result: NDArray[np.float64] = self._call(Interface.MIDDLE, OP.getBaseOffset, args)[0]
        return result

    def getFeedbackPosCartesian(self) -> CarPosWithElbow:
        """Control-point pose in the robot frame."""
        args: dict[str, Any] = {}
        result: CarPosWithElbow = self._call(Interface.MIDDLE, OP.getFeedbackPosCartesian, args)[0]
        return result

    def getMaxSpeedCartesian(self) -> CartesianSpeed:
        """Cartesian max translation and rotation speed."""
        args: dict[str, Any] = {}
        result: CartesianSpeed = self._call(Interface.MIDDLE, OP.getMaxSpeedCartesian, args)[0]
        return result

    def getMaxSpeedJoint(self) -> tuple[float, ...]:
        """Per-axis max speed."""
        args: dict[str, Any] = {}
        result: tuple[float, ...] = self._call(Interface.MIDDLE, OP.getMaxSpeedJoint, args)[0]
        return result

    def getMinAccelTimeCartesian(self) -> float:
        """Minimum time to accelerate to max speed (Cartesian)."""
        args: dict[str, Any] = {}
        result: float = self._call(Interface.MIDDLE, OP.getMinAccelTimeCartesian, args)[0]
        return result

    def getMinAccelTimeJoint(self) -> float:
        """Minimum time to accelerate to max speed (joint)."""
        args: dict[str, Any] = {}
        result: float = self._call(Interface.MIDDLE, OP.getMinAccelTimeJoint, args)[0]
        return result

    def getSoftLimitCartesian(self) -> tuple[LimitValue, LimitValue, LimitValue]:
        """Cartesian soft limits in the robot frame."""
        args: dict[str, Any] = {}
        out = self._call(Interface.MIDDLE, OP.getSoftLimitCartesian, args)
        return (out[0], out[1], out[2])

    def moveGripper(self, angleRatio: int, *, wait: bool = True, timeout: float | None = None) -> Motion:
        """Gripper opening: 0 % fully closed, 100 % fully open. ``angleRatio`` [%]."""
        args: dict[str, Any] = {"angleRatio": angleRatio}
        return self._move(Interface.MIDDLE, OP.moveGripper, args, wait, timeout)

    def moveLinearCartesianAbs(
            self,
            carPoint: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """LIN to an absolute target. ``carPoint`` [m, rad]."""
        args: dict[str, Any] = {"carPoint": carPoint}
        return self._move(Interface.MIDDLE, OP.moveLinearCartesianAbs, args, wait, timeout)

    def moveLinearCartesianRel(
            self,
            carPoint: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """LIN to a relative target. ``carPoint`` [m, rad]."""
        args: dict[str, Any] = {"carPoint": carPoint}
        return self._move(Interface.MIDDLE, OP.moveLinearCartesianRel, args, wait, timeout)

    def movePTPCartesianAbs(
            self,
            carPoint: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """PTP (joint interpolation) to an absolute Cartesian target. ``carPoint`` [m, rad]."""
        args: dict[str, Any] = {"carPoint": carPoint}
        return self._move(Interface.MIDDLE, OP.movePTPCartesianAbs, args, wait, timeout)

    def movePTPCartesianRel(
            self,
            carPoint: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """PTP (joint interpolation) to a relative Cartesian target. ``carPoint`` [m, rad]."""
        args: dict[str, Any] = {"carPoint": carPoint}
        return self._move(Interface.MIDDLE, OP.movePTPCartesianRel, args, wait, timeout)

    def movePTPJointAbs(
            self,
            jointPoints: Sequence[float],
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """PTP to an absolute joint target, J1, J2, ... ``jointPoints`` [rad or m]."""
        args: dict[str, Any] = {"jointPoints": jointPoints}
        return self._move(Interface.MIDDLE, OP.movePTPJointAbs, args, wait, timeout)

    def movePTPJointRel(
            self,
            jointPoints: Sequence[float],
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """PTP to a relative joint target, J1, J2, ... ``jointPoints`` [rad or m]."""
        args: dict[str, Any] = {"jointPoints": jointPoints}
        return self._move(Interface.MIDDLE, OP.movePTPJointRel, args, wait, timeout)

    def openGripper(self, *, wait: bool = True, timeout: float | None = None) -> Motion:
        """Open the gripper fully."""
        args: dict[str, Any] = {}
        return self._move(Interface.MIDDLE, OP.openGripper, args, wait, timeout)

    def pause(self) -> None:
        """Decelerate along the path and hold."""
        args: dict[str, Any] = {}
        self._call(Interface.MIDDLE, OP.pause, args)

    def resume(self) -> None:
        """Continue the paused path."""
        args: dict[str, Any] = {}
        self._call(Interface.MIDDLE, OP.resume, args)

    def stop(self) -> None:
        """Decelerate along the path and discard every queued motion."""
        args: dict[str, Any] = {}
        self._call(Interface.MIDDLE, OP.stop, args)

    def setAccelTimeCartesian(self, aclTime: float) -> None:
        """Acceleration time of Cartesian moves; not below the minimum. ``aclTime`` [s]."""
        args: dict[str, Any] = {"aclTime": aclTime}
        self._call(Interface.MIDDLE, OP.setAccelTimeCartesian, args)

    def setAccelTimeJoint(self, aclTime: float) -> None:
        """Acceleration time of joint moves; not below the minimum. ``aclTime`` [s]."""
        args: dict[str, Any] = {"aclTime": aclTime}
        self._call(Interface.MIDDLE, OP.setAccelTimeJoint, args)

    def setBaseOffset(self, offset: ArrayLike) -> None:
        """Set the base offset. ``offset`` [m, rad]."""
        args: dict[str, Any] = {"offset": offset}
        self._call(Interface.MIDDLE, OP.setBaseOffset, args)

    def setControlPointOffset(self, offset: ArrayLike) -> None:
        """Set the control point offset from the flange. ``offset`` [m, rad]."""
        args: dict[str, Any] = {"offset": offset}
        self._call(Interface.MIDDLE, OP.setControlPointOffset, args)

    def setMaxSpeedCartesian(self, speed: CartesianSpeed) -> None:
        """Set the Cartesian max speeds. ``speed``."""
        args: dict[str, Any] = {"speed": speed}
        self._call(Interface.MIDDLE, OP.setMaxSpeedCartesian, args)

    def setMaxSpeedJoint(self, speed: Sequence[float]) -> None:
        """Set the per-axis max speeds. ``speed`` [rad/s or m/s]."""
        args: dict[str, Any] = {"speed": speed}
        self._call(Interface.MIDDLE, OP.setMaxSpeedJoint, args)

    def setMinAccelTimeCartesian(self, aclTime: float) -> None:
        """Set the Cartesian minimum acceleration time. ``aclTime`` [s]."""
        args: dict[str, Any] = {"aclTime": aclTime}
        self._call(Interface.MIDDLE, OP.setMinAccelTimeCartesian, args)

    def setMinAccelTimeJoint(self, aclTime: float) -> None:
        """Set the joint minimum acceleration time. ``aclTime`` [s]."""
        args: dict[str, Any] = {"aclTime": aclTime}
        self._call(Interface.MIDDLE, OP.setMinAccelTimeJoint, args)

    def setSoftLimitCartesian(self, xLimit: LimitValue, yLimit: LimitValue, zLimit: LimitValue) -> None:
        """Set the Cartesian soft limits in the robot frame. ``xLimit`` [m]. ``yLimit`` [m]. ``zLimit``
        [m]."""
        args: dict[str, Any] = {"xLimit": xLimit, "yLimit": yLimit, "zLimit": zLimit}
        self._call(Interface.MIDDLE, OP.setSoftLimitCartesian, args)

    def setSpeedCartesian(self, spdRatio: int) -> None:
        """Cartesian speed as % of max (0 .. 100). ``spdRatio`` [%]."""
        args: dict[str, Any] = {"spdRatio": spdRatio}
        self._call(Interface.MIDDLE, OP.setSpeedCartesian, args)

    def setSpeedJoint(self, spdRatio: int) -> None:
        """Joint speed as % of max (0 .. 100). ``spdRatio`` [%]."""
        args: dict[str, Any] = {"spdRatio": spdRatio}
        self._call(Interface.MIDDLE, OP.setSpeedJoint, args)

    def moveCircularCartesianAbs(
            self,
            carPointR: CarPosWithElbow,
            carPointT: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """CIRC through via point R to target T (absolute). ``carPointR`` [m, rad]: via point. ``carPointT``
        [m, rad]: target."""
        args: dict[str, Any] = {"carPointR": carPointR, "carPointT": carPointT}
        return self._move(Interface.MIDDLE, OP.moveCircularCartesianAbs, args, wait, timeout)

    def moveCircularCartesianRel(
            self,
            carPointR: CarPosWithElbow,
            carPointT: CarPosWithElbow,
            *,
            wait: bool = True,
            timeout: float | None = None,
    ) -> Motion:
        """CIRC through via point R to target T (relative). ``carPointR`` [m, rad]: via point. ``carPointT``
        [m, rad]: target."""
        args: dict[str, Any] = {"carPointR": carPointR, "carPointT": carPointT}
        return self._move(Interface.MIDDLE, OP.moveCircularCartesianRel, args, wait, timeout)

    def setHome(self, jointPoint: Sequence[float]) -> None:
        """Set the home position (absolute joint coordinates). ``jointPoint`` [rad or m]."""
        args: dict[str, Any] = {"jointPoint": jointPoint}
        self._call(Interface.MIDDLE, OP.setHome, args)

    def getHome(self) -> tuple[float, ...]:
        """The home position."""
        args: dict[str, Any] = {}
        result: tuple[float, ...] = self._call(Interface.MIDDLE, OP.getHome, args)[0]
        return result

    def goHome(self, *, wait: bool = True, timeout: float | None = None) -> Motion:
        """PTP to the home position."""
        args: dict[str, Any] = {}
        return self._move(Interface.MIDDLE, OP.goHome, args, wait, timeout)

    def setBlendDistance(self, distance: float) -> None:
        """blend distance d of the motions accepted from now on, 0 .. 0.1 m. With d > 0 a motion queued
        behind another leaves that motion's path at most d before their common corner and joins its own path
        at most d after it, without stopping (jerk-limited, within the joint limits, collision-checked);
        where no such blend exists the arm stops at the corner. 0 (the default): exact stop at every corner,
        as the specification says. ``distance`` [m]: 0 = exact stop. A model-specific extension (``Ext``),
        not in the IDL."""
        args: dict[str, Any] = {"distance": distance}
        self._call(Interface.EXT, OP.setBlendDistance, args)

    def getBlendDistance(self) -> float:
        """the blend distance set with setBlendDistance. A model-specific extension (``Ext``), not in the
        IDL."""
        args: dict[str, Any] = {}
        result: float = self._call(Interface.EXT, OP.getBlendDistance, args)[0]
        return result

    def setSpeedOverride(self, ratio: float) -> None:
        """speed override of every motion, the running one included, 0 .. 100 %. The speed starts to change
        within 20 ms, jerk-limited, by scaling time along the planned path, never leaving it: 0 holds the
        arm on its path (not a pause: setting it above 0 continues), 100 (the default) runs motions as
        planned. It does not change setSpeedJoint / setSpeedCartesian, which shape each motion when it is
        accepted; the override scales its execution (like KUKA's $OV_PRO or UR's speed slider). Held by the
        servo: 100 % again when the servo process restarts. ``ratio`` [%]: 0 = hold on the path, 100 = as
        planned. A model-specific extension (``Ext``), not in the IDL."""
        args: dict[str, Any] = {"ratio": ratio}
        self._call(Interface.EXT, OP.setSpeedOverride, args)

    def getSpeedOverride(self) -> float:
        """the speed override set with setSpeedOverride, as the servo last reported it. A model-specific
        extension (``Ext``), not in the IDL."""
        args: dict[str, Any] = {}
        result: float = self._call(Interface.EXT, OP.getSpeedOverride, args)[0]
        return result

    def jogJoint(self, axis: int, speedRatio: float, leaseMs: int) -> None:
        """jog one joint at speedRatio % of its max speed (setMaxSpeedJoint), the sign giving the direction.
        The jog moves while the caller repeats the call within leaseMs; when the lease lapses, or on
        jogStop, the arm brakes on its path, jerk-limited, and holds (a lapse is logged, not alarmed).
        Refused while a motion runs or is queued (STATUS_ERR), while paused (STATUS_ERR), with the servo off
        (NOT_SV_ON_ERR) or with an alarm (STATUS_ERR). The joint and Cartesian soft limits and the obstacles
        stop it before it reaches them; the speed override scales it. A renewal may change the speed, not
        the axis or the direction (STATUS_ERR: jogStop first). ``axis``: 1 = J1. ``speedRatio`` [%]: -100 ..
        100, not 0. ``leaseMs`` [ms]: 50 .. 1000. A model-specific extension (``Ext``), not in the IDL."""
        args: dict[str, Any] = {"axis": axis, "speedRatio": speedRatio, "leaseMs": leaseMs}
        self._call(Interface.EXT, OP.jogJoint, args)

    def jogCartesian(self, frame: str, axis: str, speedRatio: float, leaseMs: int) -> None:
        """jog the control point along or about one axis of the robot frame (base) or of its own frame
        (tool) at speedRatio % of the max Cartesian speed (setMaxSpeedCartesian: translation for x, y, z,
        rotation for rx, ry, rz), keeping the other five components. Near a singularity it slows down, and
        it can always back out. NG for a family that cannot hold that component (SPEC.md §7). The jog moves
        while the caller repeats the call within leaseMs; when the lease lapses, or on jogStop, the arm
        brakes on its path, jerk-limited, and holds (a lapse is logged, not alarmed). Refused while a motion
        runs or is queued (STATUS_ERR), while paused (STATUS_ERR), with the servo off (NOT_SV_ON_ERR) or
        with an alarm (STATUS_ERR). The joint and Cartesian soft limits and the obstacles stop it before it
        reaches them; the speed override scales it. A renewal may change the speed, not the axis or the
        direction (STATUS_ERR: jogStop first). ``frame``: base | tool. ``axis``: x | y | z | rx | ry | rz.
        ``speedRatio`` [%]: -100 .. 100, not 0. ``leaseMs`` [ms]: 50 .. 1000. A model-specific extension
        (``Ext``), not in the IDL."""
        args: dict[str, Any] = {"frame": frame, "axis": axis, "speedRatio": speedRatio, "leaseMs": leaseMs}
        self._call(Interface.EXT, OP.jogCartesian, args)

    def jogStop(self) -> None:
        """end the jog now: the arm brakes on its path and holds. OK (ignored, saying so) when no jog runs.
        A model-specific extension (``Ext``), not in the IDL."""
        args: dict[str, Any] = {}
        self._call(Interface.EXT, OP.jogStop, args)

    def teach(self, name: str) -> tuple[tuple[float, ...], CarPosWithElbow]:
        """store where the arm is now as the point `name` of the arm's program file (the command service's
        --program; `jara-arm up --program-dir DIR` makes it DIR/<arm>.program.yaml, the working directory by
        default): its joints and its control point's pose, elbow and posture, as getFeedbackPosJoint and
        getFeedbackPosCartesian give them. A point of that name is replaced; the rest of the file stays as
        it is (docs/programs.md). Refused while the arm moves (STATUS_ERR). ``name``: letters, digits, _ and
        -, not starting with a digit. A model-specific extension (``Ext``), not in the IDL."""
        args: dict[str, Any] = {"name": name}
        out = self._call(Interface.EXT, OP.teach, args)
        return (out[0], out[1])


__all__ = ["Operations"]
