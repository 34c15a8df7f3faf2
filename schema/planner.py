"""The internal contract between the command service and the planner service.

The command service owns the state machine, the settings and the motion queue:
it checks state (servo on, alarms, speed ratio, queue capacity) and hands each
accepted-by-state motion to the planner with a snapshot of the settings. The
planner checks geometry (limits, reachability, speed, arcs), plans it from the
end of the previous queued motion, queues it, and streams it to the servo in
order. Everything here lives under ``JARA_ARM/<arm>/Planner/``.

* ``Planner/plan`` (queryable): ``MotionRequest`` -> ``PlanReply``.
* ``Planner/control`` (queryable): ``ControlRequest`` -> ``{id, comment}``.
* ``Planner/progress`` (publisher, on every change and at 10 Hz): ``PlannerProgress``.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

from . import wire_types as w
from .types import CartesianSpeed, HgMatrix, JointPos, LimitValue, Time
from .wire_types import Member, StructType


@dataclasses.dataclass(frozen=True)
class MotionSettings:
    """The command service's settings that shape a motion, as they were at acceptance."""

    spdRatioJoint: int  # [%] 1..100 (0 is refused before planning)
    spdRatioCartesian: int  # [%]
    maxSpeedJoint: tuple[float, ...]  # [rad/s or m/s] per arm axis
    maxSpeedCartesian: CartesianSpeed
    accelTimeJoint: float  # [s] rest to commanded speed
    accelTimeCartesian: float  # [s]
    softLimitJoint: tuple[LimitValue, ...]  # per arm axis
    softLimitCartesian: tuple[LimitValue, ...]  # x, y, z [m] in the robot frame
    baseOffset: HgMatrix  # robot frame seen from the arm frame
    controlPointOffset: HgMatrix  # control point in the flange frame
    home: JointPos  # [rad or m] per arm axis


@dataclasses.dataclass(frozen=True)
class MotionRequest:
    """One motion: ``op`` is the IDL operation name, ``args`` its decoded ``in`` parameters."""

    motion: int  # id given by the command service, increasing
    op: str
    args: dict[str, Any]  # wire form (maps, lists), already checked by the codec
    settings: MotionSettings


@dataclasses.dataclass(frozen=True)
class PlanReply:
    """``id``/``comment`` as RETURN_ID (a refusal is passed to the client as is)."""

    id: int
    comment: str
    endJoints: JointPos  # [rad or m] where this motion ends (arm axes + gripper)
    duration: float  # [s]


class ControlAction(enum.StrEnum):
    PAUSE = "pause"  # decelerate along the path and hold
    RESUME = "resume"  # continue the same path
    STOP = "stop"  # decelerate along the path, discard the queue
    ABORT = "abort"  # the servo is off or faulted: forget everything, send nothing more


@dataclasses.dataclass(frozen=True)
class ControlRequest:
    action: str  # a ControlAction value


@dataclasses.dataclass(frozen=True)
class PlannerProgress:
    """What the planner is doing; motions complete strictly in queue order."""

    tm: Time
    running: int  # motion id being streamed, 0 when none
    queued: tuple[int, ...]  # motion ids accepted and not finished, running one first
    lastDone: int  # id of the last motion that reached its end, 0 when none
    lastDiscarded: int  # highest id discarded by stop/abort/a servo fault, 0 when none
    paused: bool
    streaming: bool  # position commands are being sent


def _seq(item: w.WireType, name: str) -> w.SeqType:
    return w.SeqType(name, item)


MOTION_SETTINGS = StructType(MotionSettings, (
    Member("spdRatioJoint", w.ULONG, "%"), Member("spdRatioCartesian", w.ULONG, "%"),
    Member("maxSpeedJoint", w.DOUBLE_SEQ, "rad/s or m/s"),
    Member("maxSpeedCartesian", w.CARTESIAN_SPEED),
    Member("accelTimeJoint", w.DOUBLE, "s"), Member("accelTimeCartesian", w.DOUBLE, "s"),
    Member("softLimitJoint", w.LIMIT_SEQ, "rad or m"),
    Member("softLimitCartesian", w.LIMIT_SEQ, "m", "x, y, z in the robot frame"),
    Member("baseOffset", w.HG_MATRIX), Member("controlPointOffset", w.HG_MATRIX),
    Member("home", w.JOINT_POS, "rad or m"),
), doc="Internal: the settings a motion was accepted with.")


class _ArgsType(w.WireType[dict]):
    """The ``in`` parameters of ``MotionRequest.op``, kept in wire form (checked by the codec)."""

    name = "MotionArgs"

    def decode(self, value: Any, path: str) -> dict:
        if not isinstance(value, dict):
            raise w.WireError(path, "expected a map of the operation's in parameters")
        return value

    def encode(self, value: dict) -> dict:
        return dict(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "object", "description": "the IDL in parameters of `op`, in wire form"}


MOTION_REQUEST = StructType(MotionRequest, (
    Member("motion", w.ULONG), Member("op", w.STRING), Member("args", _ArgsType()),
    Member("settings", MOTION_SETTINGS),
), doc="Internal: command -> planner, Planner/plan.")
PLAN_REPLY = StructType(PlanReply, (
    Member("id", w.LONG), Member("comment", w.STRING),
    Member("endJoints", w.JOINT_POS, "rad or m"), Member("duration", w.DOUBLE, "s"),
), strict=False, doc="Internal: planner -> command, reply to Planner/plan.")
CONTROL_REQUEST = StructType(ControlRequest, (
    Member("action", w.STRING, doc=" | ".join(a.value for a in ControlAction)),
), doc="Internal: command -> planner, Planner/control.")
PLANNER_PROGRESS = StructType(PlannerProgress, (
    Member("tm", w.TIME), Member("running", w.ULONG), Member("queued", _seq(w.ULONG, "ULONGSeq")),
    Member("lastDone", w.ULONG), Member("lastDiscarded", w.ULONG), Member("paused", w.BOOLEAN),
    Member("streaming", w.BOOLEAN),
), strict=False, doc="Internal: planner -> everyone, Planner/progress.")

MESSAGES: tuple[StructType, ...] = (MOTION_SETTINGS, MOTION_REQUEST, PLAN_REPLY, CONTROL_REQUEST,
                                    PLANNER_PROGRESS)
