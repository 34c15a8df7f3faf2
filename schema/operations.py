"""The 44 operations of the two IDL interfaces (SPEC.md §6-7), and our extensions, as data.

``COMMON`` (9 operations, served at ``Common/<op>`` by the command service and
at ``Servo/Common/<op>`` by the servo) and ``MIDDLE`` (35 operations, served at
``Middle/<op>``) are the IDL's (``IDL``). ``EXT`` (served at ``Ext/<op>`` by the
command service) is not: model-specific operations of this implementation, with
the same reply rules (``RETURN_ID``, ``VALUE_ERR`` naming the field). Every
parameter carries its wire type and unit; services and clients look operations
up here and never spell their names by hand.
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Iterable, Mapping
from types import MappingProxyType
from typing import Final

from . import wire_types as w
from .errors import UnknownOperationError
from .wire_types import Member


class Interface(enum.Enum):
    """An interface; its value is the key-expression chunk it is served under."""

    COMMON = "Common"
    MIDDLE = "Middle"
    EXT = "Ext"  #: model-specific extensions, outside the IDL

    @property
    def idl_name(self) -> str | None:
        """``ManipulatorCommonInterface_<value>``; None for ``EXT``, which the IDL does not have."""
        return None if self is Interface.EXT else f"ManipulatorCommonInterface_{self.value}"


@dataclasses.dataclass(frozen=True)
class Operation:
    """One IDL operation: ``RETURN_ID name(in ..., out ...)``."""

    name: str
    interface: Interface
    inputs: tuple[Member, ...]
    outputs: tuple[Member, ...]
    doc: str
    #: A motion command: queued, refused while the servo is off or alarmed.
    motion: bool = False


def _op(interface: Interface, name: str, doc: str, inputs: Iterable[Member] = (),
        outputs: Iterable[Member] = (), motion: bool = False) -> Operation:
    return Operation(name, interface, tuple(inputs), tuple(outputs), doc, motion)


_C, _M, _E = Interface.COMMON, Interface.MIDDLE, Interface.EXT
_CAR = "m, rad"
_AXIS = "rad or m"

_COMMON = (
    _op(_C, "clearAlarms", "Clear the active alarms whose cause has gone."),
    _op(_C, "getActiveAlarm", "The active alarms; an empty sequence when none.",
        outputs=[Member("alarms", w.ALARM_SEQ)]),
    _op(_C, "getFeedbackPosJoint", "Joint position feedback, J1..Jn then the gripper.",
        outputs=[Member("pos", w.JOINT_POS, _AXIS)]),
    _op(_C, "getManipInfo", "Manipulator information.", outputs=[Member("mInfo", w.MANIP_INFO)]),
    _op(_C, "getSoftLimitJoint", "Joint soft limits, one per axis (gripper excluded).",
        outputs=[Member("softLimit", w.LIMIT_SEQ, _AXIS)]),
    _op(_C, "getState", "State bits: 0x01 servo on, 0x02 moving, 0x04 alarm, "
        "0x08 buffer full, 0x10 paused.", outputs=[Member("state", w.ULONG)]),
    _op(_C, "servoOFF", "All axes servo off; brakes hold the joints."),
    _op(_C, "servoON", "All axes servo on."),
    _op(_C, "setSoftLimitJoint", "Set the joint soft limits, one per axis; refused while "
        "moving or alarmed.", inputs=[Member("softLimit", w.LIMIT_SEQ, _AXIS)]),
)

_CARPOINT = [Member("carPoint", w.CAR_POS_WITH_ELBOW, _CAR)]
_CIRC = [Member("carPointR", w.CAR_POS_WITH_ELBOW, _CAR, "via point"),
         Member("carPointT", w.CAR_POS_WITH_ELBOW, _CAR, "target")]
_ACL = [Member("aclTime", w.DOUBLE, "s")]
_LIMITS = [Member(n, w.LIMIT_VALUE, "m") for n in ("xLimit", "yLimit", "zLimit")]

_MIDDLE = (
    _op(_M, "closeGripper", "Close the gripper fully.", motion=True),
    _op(_M, "getBaseOffset", "Base offset: the robot frame seen from the arm frame.",
        outputs=[Member("offset", w.HG_MATRIX, _CAR)]),
    _op(_M, "getFeedbackPosCartesian", "Control-point pose in the robot frame.",
        outputs=[Member("pos", w.CAR_POS_WITH_ELBOW, _CAR)]),
    _op(_M, "getMaxSpeedCartesian", "Cartesian max translation and rotation speed.",
        outputs=[Member("speed", w.CARTESIAN_SPEED)]),
    _op(_M, "getMaxSpeedJoint", "Per-axis max speed.",
        outputs=[Member("speed", w.DOUBLE_SEQ, "rad/s or m/s")]),
    _op(_M, "getMinAccelTimeCartesian", "Minimum time to accelerate to max speed (Cartesian).",
        outputs=_ACL),
    _op(_M, "getMinAccelTimeJoint", "Minimum time to accelerate to max speed (joint).",
        outputs=_ACL),
    _op(_M, "getSoftLimitCartesian", "Cartesian soft limits in the robot frame.",
        outputs=_LIMITS),
    _op(_M, "moveGripper", "Gripper opening: 0 % fully closed, 100 % fully open.",
        inputs=[Member("angleRatio", w.ULONG, "%")], motion=True),
    _op(_M, "moveLinearCartesianAbs", "LIN to an absolute target.", inputs=_CARPOINT, motion=True),
    _op(_M, "moveLinearCartesianRel", "LIN to a relative target.", inputs=_CARPOINT, motion=True),
    _op(_M, "movePTPCartesianAbs", "PTP (joint interpolation) to an absolute Cartesian target.",
        inputs=_CARPOINT, motion=True),
    _op(_M, "movePTPCartesianRel", "PTP (joint interpolation) to a relative Cartesian target.",
        inputs=_CARPOINT, motion=True),
    _op(_M, "movePTPJointAbs", "PTP to an absolute joint target, J1, J2, ...",
        inputs=[Member("jointPoints", w.JOINT_POS, _AXIS)], motion=True),
    _op(_M, "movePTPJointRel", "PTP to a relative joint target, J1, J2, ...",
        inputs=[Member("jointPoints", w.JOINT_POS, _AXIS)], motion=True),
    _op(_M, "openGripper", "Open the gripper fully.", motion=True),
    _op(_M, "pause", "Decelerate along the path and hold."),
    _op(_M, "resume", "Continue the paused path."),
    _op(_M, "stop", "Decelerate along the path and discard every queued motion."),
    _op(_M, "setAccelTimeCartesian", "Acceleration time of Cartesian moves; not below the "
        "minimum.", inputs=_ACL),
    _op(_M, "setAccelTimeJoint", "Acceleration time of joint moves; not below the minimum.",
        inputs=_ACL),
    _op(_M, "setBaseOffset", "Set the base offset.", inputs=[Member("offset", w.HG_MATRIX, _CAR)]),
    _op(_M, "setControlPointOffset", "Set the control point offset from the flange.",
        inputs=[Member("offset", w.HG_MATRIX, _CAR)]),
    _op(_M, "setMaxSpeedCartesian", "Set the Cartesian max speeds.",
        inputs=[Member("speed", w.CARTESIAN_SPEED)]),
    _op(_M, "setMaxSpeedJoint", "Set the per-axis max speeds.",
        inputs=[Member("speed", w.DOUBLE_SEQ, "rad/s or m/s")]),
    _op(_M, "setMinAccelTimeCartesian", "Set the Cartesian minimum acceleration time.",
        inputs=_ACL),
    _op(_M, "setMinAccelTimeJoint", "Set the joint minimum acceleration time.", inputs=_ACL),
    _op(_M, "setSoftLimitCartesian", "Set the Cartesian soft limits in the robot frame.",
        inputs=_LIMITS),
    _op(_M, "setSpeedCartesian", "Cartesian speed as % of max (0 .. 100).",
        inputs=[Member("spdRatio", w.ULONG, "%")]),
    _op(_M, "setSpeedJoint", "Joint speed as % of max (0 .. 100).",
        inputs=[Member("spdRatio", w.ULONG, "%")]),
    _op(_M, "moveCircularCartesianAbs", "CIRC through via point R to target T (absolute).",
        inputs=_CIRC, motion=True),
    _op(_M, "moveCircularCartesianRel", "CIRC through via point R to target T (relative).",
        inputs=_CIRC, motion=True),
    _op(_M, "setHome", "Set the home position (absolute joint coordinates).",
        inputs=[Member("jointPoint", w.JOINT_POS, _AXIS)]),
    _op(_M, "getHome", "The home position.", outputs=[Member("jointPoint", w.JOINT_POS, _AXIS)]),
    _op(_M, "goHome", "PTP to the home position.", motion=True),
)

#: Largest blend distance ``setBlendDistance`` takes [m]: a blend leaves the path at most this far
#: before a corner and rejoins at most this far after it; beyond ~0.1 m a blend would replace most
#: of a typical pick-and-place move, and the path it takes is no longer one a user can picture.
MAX_BLEND_DISTANCE = 0.1
#: Largest speed override ``setSpeedOverride`` takes [%]: motions as planned. Not more: a motion is
#: planned to its speed, acceleration and jerk limits, so running it faster would break them.
MAX_SPEED_OVERRIDE = 100.0
#: A jog's lease ``leaseMs`` [ms]: the jog moves while the caller renews it within this time. Below 50 ms a
#: renewal over a loaded network would lapse between two calls; above 1 s a lost client would leave the arm
#: moving for longer than a person holding a dead-man switch would accept.
JOG_LEASE_MS = (50, 1000)
#: ``jogCartesian``'s frames: the robot frame's axes, or the control point's own (tool frame).
JOG_FRAMES = ("base", "tool")
#: ``jogCartesian``'s axes: along x, y, z [m] or about them [rad].
JOG_AXES = ("x", "y", "z", "rx", "ry", "rz")
_JOG_RULES = (
    "The jog moves while the caller repeats the call within leaseMs; when the lease lapses, or on jogStop, "
    "the arm brakes on its path, jerk-limited, and holds (a lapse is logged, not alarmed). Refused while a "
    "motion runs or is queued (STATUS_ERR), while paused (STATUS_ERR), with the servo off (NOT_SV_ON_ERR) "
    "or with an alarm (STATUS_ERR). The joint and Cartesian soft limits and the obstacles stop it before "
    "it reaches them; the speed override scales it. A renewal may change the speed, not the axis or the "
    "direction (STATUS_ERR: jogStop first).")

_EXT = (
    _op(_E, "setBlendDistance", "Model-specific extension (not in the IDL): blend distance d of the motions "
        f"accepted from now on, 0 .. {MAX_BLEND_DISTANCE:g} m. With d > 0 a motion queued behind another "
        "leaves that motion's path at most d before their common corner and joins its own path at most d "
        "after it, without stopping (jerk-limited, within the joint limits, collision-checked); where no "
        "such blend exists the arm stops at the corner. 0 (the default): exact stop at every corner, "
        "as the specification says.",
        inputs=[Member("distance", w.DOUBLE, "m", "0 = exact stop")]),
    _op(_E, "getBlendDistance", "Model-specific extension (not in the IDL): the blend distance set with "
        "setBlendDistance.", outputs=[Member("distance", w.DOUBLE, "m", "0 = exact stop")]),
    _op(_E, "setSpeedOverride", "Model-specific extension (not in the IDL): speed override of every motion, "
        f"the running one included, 0 .. {MAX_SPEED_OVERRIDE:g} %. The speed starts to change within 20 ms, "
        "jerk-limited, by scaling time along the planned path, never leaving it: 0 holds the arm on its "
        "path (not a pause: setting it above 0 continues), 100 (the default) runs motions as planned. It "
        "does not change setSpeedJoint / setSpeedCartesian, which shape each motion when it is accepted; "
        "the override scales its execution (like KUKA's $OV_PRO or UR's speed slider). Held by the servo: "
        "100 % again when the servo process restarts.",
        inputs=[Member("ratio", w.DOUBLE, "%", "0 = hold on the path, 100 = as planned")]),
    _op(_E, "getSpeedOverride", "Model-specific extension (not in the IDL): the speed override set with "
        "setSpeedOverride, as the servo last reported it.",
        outputs=[Member("ratio", w.DOUBLE, "%", "0 = hold on the path, 100 = as planned")]),
    _op(_E, "jogJoint", "Model-specific extension (not in the IDL): jog one joint at speedRatio % of its max "
        "speed (setMaxSpeedJoint), the sign giving the direction. " + _JOG_RULES,
        inputs=[Member("axis", w.ULONG, "", "1 = J1"),
                Member("speedRatio", w.DOUBLE, "%", "-100 .. 100, not 0"),
                Member("leaseMs", w.ULONG, "ms", f"{JOG_LEASE_MS[0]} .. {JOG_LEASE_MS[1]}")]),
    _op(_E, "jogCartesian", "Model-specific extension (not in the IDL): jog the control point along or about "
        "one axis of the robot frame (base) or of its own frame (tool) at speedRatio % of the max Cartesian "
        "speed (setMaxSpeedCartesian: translation for x, y, z, rotation for rx, ry, rz), keeping the other "
        "five components. Near a singularity it slows down, and it can always back out. NG for a family "
        "that cannot hold that component (SPEC.md §7). " + _JOG_RULES,
        inputs=[Member("frame", w.STRING, "", " | ".join(JOG_FRAMES)),
                Member("axis", w.STRING, "", " | ".join(JOG_AXES)),
                Member("speedRatio", w.DOUBLE, "%", "-100 .. 100, not 0"),
                Member("leaseMs", w.ULONG, "ms", f"{JOG_LEASE_MS[0]} .. {JOG_LEASE_MS[1]}")]),
    _op(_E, "jogStop", "Model-specific extension (not in the IDL): end the jog now: the arm brakes on its "
        "path and holds. OK (ignored, saying so) when no jog runs."),
    _op(_E, "teach", "Model-specific extension (not in the IDL): store where the arm is now as the point "
        "`name` of the arm's program file (the command service's --program; `jara-arm up --program-dir "
        "DIR` makes it DIR/<arm>.program.yaml, the working directory by default): its joints and its control "
        "point's pose, elbow and posture, as getFeedbackPosJoint and getFeedbackPosCartesian give them. A "
        "point of that name is replaced; the rest of the file stays as it is (docs/programs.md). Refused "
        "while the arm moves (STATUS_ERR).",
        inputs=[Member("name", w.STRING, "", "letters, digits, _ and -, not starting with a digit")],
        outputs=[Member("jointPoint", w.JOINT_POS, _AXIS), Member("carPoint", w.CAR_POS_WITH_ELBOW, _CAR)]),
)

COMMON: Mapping[str, Operation] = MappingProxyType({op.name: op for op in _COMMON})
MIDDLE: Mapping[str, Operation] = MappingProxyType({op.name: op for op in _MIDDLE})
EXT: Mapping[str, Operation] = MappingProxyType({op.name: op for op in _EXT})
TABLES: Mapping[Interface, Mapping[str, Operation]] = MappingProxyType(
    {Interface.COMMON: COMMON, Interface.MIDDLE: MIDDLE, Interface.EXT: EXT}
)
#: The 44 operations of the IDL.
IDL: tuple[Operation, ...] = _COMMON + _MIDDLE
#: Every operation served: the IDL's and the extensions.
ALL: tuple[Operation, ...] = IDL + _EXT


def operation(interface: Interface, name: str) -> Operation:
    """The operation ``name`` of ``interface``; raises UnknownOperationError listing the valid ones."""
    table = TABLES[interface]
    try:
        return table[name]
    except KeyError:
        raise UnknownOperationError(interface.value, name, list(table)) from None


class OP:
    """The operation names, spelled out so that editors and type checkers follow them
    (``OP.movePTPJointAbs == "movePTPJointAbs"``); code names operations through these,
    never with string literals. Checked against the tables at import."""

    # Common
    clearAlarms: Final = "clearAlarms"
    getActiveAlarm: Final = "getActiveAlarm"
    getFeedbackPosJoint: Final = "getFeedbackPosJoint"
    getManipInfo: Final = "getManipInfo"
    getSoftLimitJoint: Final = "getSoftLimitJoint"
    getState: Final = "getState"
    servoOFF: Final = "servoOFF"
    servoON: Final = "servoON"
    setSoftLimitJoint: Final = "setSoftLimitJoint"
    # Middle
    closeGripper: Final = "closeGripper"
    getBaseOffset: Final = "getBaseOffset"
    getFeedbackPosCartesian: Final = "getFeedbackPosCartesian"
    getMaxSpeedCartesian: Final = "getMaxSpeedCartesian"
    getMaxSpeedJoint: Final = "getMaxSpeedJoint"
    getMinAccelTimeCartesian: Final = "getMinAccelTimeCartesian"
    getMinAccelTimeJoint: Final = "getMinAccelTimeJoint"
    getSoftLimitCartesian: Final = "getSoftLimitCartesian"
    moveGripper: Final = "moveGripper"
    moveLinearCartesianAbs: Final = "moveLinearCartesianAbs"
    moveLinearCartesianRel: Final = "moveLinearCartesianRel"
    movePTPCartesianAbs: Final = "movePTPCartesianAbs"
    movePTPCartesianRel: Final = "movePTPCartesianRel"
    movePTPJointAbs: Final = "movePTPJointAbs"
    movePTPJointRel: Final = "movePTPJointRel"
    openGripper: Final = "openGripper"
    pause: Final = "pause"
    resume: Final = "resume"
    stop: Final = "stop"
    setAccelTimeCartesian: Final = "setAccelTimeCartesian"
    setAccelTimeJoint: Final = "setAccelTimeJoint"
    setBaseOffset: Final = "setBaseOffset"
    setControlPointOffset: Final = "setControlPointOffset"
    setMaxSpeedCartesian: Final = "setMaxSpeedCartesian"
    setMaxSpeedJoint: Final = "setMaxSpeedJoint"
    setMinAccelTimeCartesian: Final = "setMinAccelTimeCartesian"
    setMinAccelTimeJoint: Final = "setMinAccelTimeJoint"
    setSoftLimitCartesian: Final = "setSoftLimitCartesian"
    setSpeedCartesian: Final = "setSpeedCartesian"
    setSpeedJoint: Final = "setSpeedJoint"
    moveCircularCartesianAbs: Final = "moveCircularCartesianAbs"
    moveCircularCartesianRel: Final = "moveCircularCartesianRel"
    setHome: Final = "setHome"
    getHome: Final = "getHome"
    goHome: Final = "goHome"
    # Ext (not in the IDL)
    setBlendDistance: Final = "setBlendDistance"
    getBlendDistance: Final = "getBlendDistance"
    setSpeedOverride: Final = "setSpeedOverride"
    getSpeedOverride: Final = "getSpeedOverride"
    jogJoint: Final = "jogJoint"
    jogCartesian: Final = "jogCartesian"
    jogStop: Final = "jogStop"
    teach: Final = "teach"


_spelled = {name for name in vars(OP) if not name.startswith("_")}
if _spelled != {op.name for op in ALL}:  # a table and this list disagree: fail at import
    raise ImportError(f"OP and the operation tables differ: {sorted(_spelled ^ {op.name for op in ALL})}")
