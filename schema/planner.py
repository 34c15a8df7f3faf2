"""The internal contract between the command service and the planner service.

The command service owns the state machine and the settings: it checks state
(servo on, alarms, speed ratio, a full queue as last heard) and hands each
accepted-by-state motion to the planner with a snapshot of the settings. The
planner owns the motion queue, its capacity and the pause: it gives each motion its id,
checks geometry (limits, reachability, speed, arcs), plans it from the end of
the previous queued motion, and hands it to the servo's interpolator
(``schema/motion.py``), which runs the motions in order.
Everything here lives under ``JARA_ARM/<arm>/Planner/``.

* ``Planner/plan`` (queryable): ``MotionRequest`` -> ``PlanReply``.
* ``Planner/control`` (queryable): ``ControlRequest`` -> ``ControlReply``.
* ``Planner/progress`` (publisher, on every change and at 10 Hz): ``PlannerProgress``.

Every reply carries the ``PlannerProgress`` the call left behind, and every
progress message is numbered (``started``, ``seq``): a reader keeps the newest
one it received by either way (:func:`is_newer`), and needs no other rule for
a publication that arrives after a reply it already saw. ``runningShare``
changes without a new ``seq``: a report of the same number but a later ``tm``
(:func:`jara_arm.schema.motion.refreshes`) carries a newer one.
"""

from __future__ import annotations

import dataclasses
import enum
import re
from typing import Any

from . import wire_types as w
from .errors import WireError
from .messages import NO_STATUS, SERVO_STATUS, ServoStatus
from .types import CartesianSpeed, HgMatrix, JointPos, LimitValue, Time
from .wire_types import StructType, struct, wire


class _ArgsType(w.WireType[dict[str, Any]]):
    """The ``in`` parameters of ``MotionRequest.op``, kept in wire form (checked by the codec)."""

    name = "MotionArgs"

    def decode(self, value: Any, path: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise WireError(path, "expected a map of the operation's in parameters")
        return value

    def encode(self, value: dict[str, Any]) -> dict[str, Any]:
        return dict(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "object", "description": "the IDL in parameters of `op`, in wire form"}


@dataclasses.dataclass(frozen=True)
class MotionSettings:
    """The command service's settings that shape a motion, as they were at acceptance."""

    spdRatioJoint: int = wire(w.ULONG, "%")  # 1..100 (0 is refused before planning)
    spdRatioCartesian: int = wire(w.ULONG, "%")
    maxSpeedJoint: tuple[float, ...] = wire(w.DOUBLE_SEQ, "rad/s or m/s")  # per arm axis
    maxSpeedCartesian: CartesianSpeed = wire(w.CARTESIAN_SPEED)
    accelTimeJoint: float = wire(w.DOUBLE, "s")  # rest to commanded speed
    accelTimeCartesian: float = wire(w.DOUBLE, "s")
    softLimitJoint: tuple[LimitValue, ...] = wire(w.LIMIT_SEQ, "rad or m")  # per arm axis
    softLimitCartesian: tuple[LimitValue, ...] = wire(w.LIMIT_SEQ, "m", "x, y, z in the robot frame")
    baseOffset: HgMatrix = wire(w.HG_MATRIX)  # robot frame seen from the arm frame
    controlPointOffset: HgMatrix = wire(w.HG_MATRIX)  # control point in the flange frame
    home: JointPos = wire(w.JOINT_POS, "rad or m")  # per arm axis
    #: Extension (model-specific, outside the IDL; ``Ext/setBlendDistance``): how far before and after a
    #: corner between queued motions the arm may leave the path; 0 = exact stop (the specification's)
    blendDistance: float = wire(w.DOUBLE, "m", default=0.0)


MOTION_SETTINGS = struct(MotionSettings, doc="Internal: the settings a motion was accepted with.")


@dataclasses.dataclass(frozen=True)
class MotionRequest:
    """One motion: ``op`` is the IDL operation name, ``args`` its decoded ``in`` parameters."""

    op: str = wire(w.STRING)
    args: dict[str, Any] = wire(_ArgsType())  # wire form (maps, lists), already checked by the codec
    settings: MotionSettings = wire(MOTION_SETTINGS)
    #: The caller's newest servo status: a servoON's reply reaches the command before the servo's publication
    #: reaches the planner, which goes by the newer of the two (``messages.is_newer``).
    servo: ServoStatus = wire(SERVO_STATUS, doc="the servo's newest status the caller holds (seq 0: none); the "
                              "planner goes by it where it is newer than its own", default=NO_STATUS)


class ControlAction(enum.StrEnum):
    PAUSE = "pause"  # decelerate along the path and hold
    RESUME = "resume"  # continue the same path
    STOP = "stop"  # decelerate along the path, discard the queue
    ABORT = "abort"  # the servo is off or faulted: forget everything, send nothing more
    OVERRIDE = "override"  # Ext/setSpeedOverride: scale the speed of every motion, the running one too


@dataclasses.dataclass(frozen=True)
class ControlRequest:
    action: str = wire(w.STRING, doc=" | ".join(a.value for a in ControlAction))
    #: OVERRIDE only: the speed override, 0 (hold on the path) .. 100 (as planned)
    ratio: float = wire(w.DOUBLE, "%", default=100.0)


@dataclasses.dataclass(frozen=True)
class PlannerProgress:
    """What the planner is doing; motions complete strictly in queue order."""

    tm: Time = wire(w.TIME)
    running: int = wire(w.ULONG)  # motion id the servo runs, 0 when none (or holding paused)
    queued: tuple[int, ...] = wire(w.SeqType("ULONGSeq", w.ULONG))  # accepted, not finished, running one first
    lastDone: int = wire(w.ULONG)  # id of the last motion that reached its end, 0 when none
    lastDiscarded: int = wire(w.ULONG)  # highest id discarded by stop/abort/a servo fault, 0 when none
    paused: bool = wire(w.BOOLEAN)
    streaming: bool = wire(w.BOOLEAN)  # the servo's interpolator commands the arm (the name is older)
    started: Time = wire(w.TIME)  # when this planner process started: a restarted planner is newer
    seq: int = wire(w.ULONG)  # grows with every change of the other members but ``tm``, ``runningShare``
    override: float = wire(w.DOUBLE, "%", "the servo's speed override (Ext/setSpeedOverride)", default=100.0)
    capacity: int = wire(w.ULONG, "motions", "the queue holds at most this many; the next motion is refused "
                         "FULL_MOTION_QUEUE_ERR (planner --queue-capacity)", default=0)
    runningShare: float = wire(w.DOUBLE, "", "0 .. 1: the share of the running motion's samples the servo has "
                               "passed (of its planned time, not of its length; MotionProgress.runningShare), 0 "
                               "when none runs; not counted in seq", default=0.0)


PLANNER_PROGRESS = struct(PlannerProgress, strict=False, doc="Internal: planner -> everyone, Planner/progress.")


#: Motions the planner's queue holds by default (DECISIONS.md "Motion commands"; planner ``--queue-capacity``).
QUEUE_CAPACITY = 32


def accepted_comment(motion: int) -> str:
    """The comment of a motion operation's OK reply: it names the id under which ``Planner/progress``
    reports the motion (``queued``, ``running``, ``lastDone``, ``lastDiscarded``)."""
    return f"OK: motion {motion} queued"


_ACCEPTED = re.compile(r"\bmotion (\d+) queued\b")


def accepted_motion(comment: str) -> int | None:
    """The motion id an OK reply's comment names (:func:`accepted_comment`); None if it names none."""
    found = _ACCEPTED.search(comment)
    return int(found.group(1)) if found else None


def is_newer(candidate: PlannerProgress, current: PlannerProgress | None) -> bool:
    """Whether ``candidate`` tells a later state than ``current`` (of a later planner, or later in it)."""
    if current is None:
        return True
    return ((candidate.started.to_seconds(), candidate.seq)
            > (current.started.to_seconds(), current.seq))


@dataclasses.dataclass(frozen=True)
class PlanReply:
    """``id``/``comment`` as RETURN_ID (a refusal is passed to the client as is)."""

    id: int = wire(w.LONG)
    comment: str = wire(w.STRING)
    motion: int = wire(w.ULONG)  # the id the planner gave the motion, 0 when refused
    endJoints: JointPos = wire(w.JOINT_POS, "rad or m")  # where this motion ends (arm axes + gripper)
    duration: float = wire(w.DOUBLE, "s")
    progress: PlannerProgress = wire(PLANNER_PROGRESS)  # the queue as this call left it


@dataclasses.dataclass(frozen=True)
class ControlReply:
    """``id``/``comment`` as RETURN_ID, and the queue and pause as the call left them."""

    id: int = wire(w.LONG)
    comment: str = wire(w.STRING)
    progress: PlannerProgress = wire(PLANNER_PROGRESS)


@dataclasses.dataclass(frozen=True)
class PlannedPath:
    """``Planner/path``: where the control point of an accepted motion goes, for viewers.

    Published once when the motion is accepted (queued); a viewer draws the one
    whose ``motion`` is ``PlannerProgress.running``.
    """

    motion: int = wire(w.ULONG)  # the id the planner gave the motion
    op: str = wire(w.STRING)  # IDL operation name
    points: tuple[tuple[float, ...], ...] = wire(w.SeqType("PointSeq", w.DOUBLE_SEQ), "m",
                                                 "control point x, y, z in the arm frame, start to end, "
                                                 "a polyline of at most a few hundred points")


MOTION_REQUEST = struct(MotionRequest, doc="Internal: command -> planner, Planner/plan.")
PLAN_REPLY = struct(PlanReply, strict=False, doc="Internal: planner -> command, reply to Planner/plan.")
CONTROL_REQUEST = struct(ControlRequest, doc="Internal: command -> planner, Planner/control.")
CONTROL_REPLY = struct(ControlReply, strict=False, doc="Internal: planner -> command, reply to Planner/control.")

PLANNED_PATH = struct(PlannedPath, strict=False, doc="Internal: planner -> viewers, Planner/path.")

MESSAGES: tuple[StructType[Any], ...] = (MOTION_SETTINGS, MOTION_REQUEST, PLAN_REPLY, CONTROL_REQUEST,
                                         CONTROL_REPLY, PLANNER_PROGRESS, PLANNED_PATH)
