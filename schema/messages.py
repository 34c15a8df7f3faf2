"""Published messages: the public topics of WIRE.md and the internal ones.

Messages are relaxed structs: a reader ignores members it does not know, so a
publisher may add fields without breaking older subscribers.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import msgpack

from . import wire_types as w
from .errors import WireError
from .types import Alarm, LimitValue, Time, TimedJointPos
from .wire_types import StructType, struct, wire


class _WireMap(w.WireType[dict[str, Any]]):
    """A map kept in its wire form (what a call carried), not checked here: the operation's codec checks it."""

    name = "WireMap"

    def decode(self, value: Any, path: str) -> dict[str, Any]:
        if not isinstance(value, dict):
            raise WireError(path, f"expected a map, got {type(value).__name__}")
        return value

    def encode(self, value: dict[str, Any]) -> dict[str, Any]:
        return dict(value)

    def json_schema(self) -> dict[str, Any]:
        return {"type": "object"}


#: Lower edges of the ``LoopHealth.latenessHist`` bins [s]; the last bin is open-ended.
LATENESS_BIN_EDGES: tuple[float, ...] = (0.0, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3)
_SEQ = w.DOUBLE_SEQ


@dataclasses.dataclass(frozen=True)
class StateMessage:
    """``JARA_ARM/<arm>/state``: the state bits, on every change."""

    state: int = wire(w.ULONG)


@dataclasses.dataclass(frozen=True)
class AlarmEvent:
    """``JARA_ARM/<arm>/alarm``: an alarm raised or cleared."""

    event: str = wire(w.STRING, doc='"raised" or "cleared"')
    alarm: Alarm = wire(w.ALARM)


@dataclasses.dataclass(frozen=True)
class LogRecord:
    """``JARA_ARM/<arm>/log/<service>``: one Python logging record."""

    t: float = wire(w.DOUBLE, "s", "Unix time")
    level: str = wire(w.STRING)  # DEBUG, INFO, WARNING, ERROR, CRITICAL
    service: str = wire(w.STRING)
    msg: str = wire(w.STRING)
    logger: str = wire(w.STRING)


@dataclasses.dataclass(frozen=True)
class ServoLatch:
    """An alarm the servo detected itself and holds (``ServoStatus.latches``) until the monitor clears it."""

    alarm: Alarm = wire(w.ALARM)
    present: bool = wire(w.BOOLEAN, doc="its cause is still there (an e-stop's while the arm brakes): "
                         "clearAlarms keeps it")
    # A status made before a clear still carries the latch it cleared: the monitor tells it from a new one by this.
    latched: Time = wire(w.TIME, doc="when the servo latched it: the same in every status, a later latch's later")


SERVO_LATCH = struct(ServoLatch, strict=False, doc="Internal: an alarm the servo latched itself, in ServoStatus.")


@dataclasses.dataclass(frozen=True)
class ServoStatus:
    """``Servo/status``: what the planner and the alarm monitor need from the servo loop."""

    tm: Time = wire(w.TIME)
    servoOn: bool = wire(w.BOOLEAN)
    moving: bool = wire(w.BOOLEAN)
    alarm: bool = wire(w.BOOLEAN)
    fifoDepth: int = wire(w.ULONG)  # commands waiting in the SyncFIFO
    consumed: int = wire(w.ULONG)  # commands taken from the FIFO since the servo started
    received: int = wire(w.ULONG)  # commands received since the servo started
    underruns: int = wire(w.ULONG)  # cycles the FIFO was empty while the arm was moving, since start
    vel: tuple[float, ...] = wire(_SEQ, "rad/s or m/s")  # measured joint velocities
    effort: tuple[float, ...] = wire(_SEQ, "N m or N")  # measured joint efforts
    target: tuple[float, ...] = wire(_SEQ, "rad or m")  # joint target applied this cycle
    softLimitJoint: tuple[LimitValue, ...] = wire(w.LIMIT_SEQ, "rad or m", "the joint soft limits in force, "
                                                  "per arm axis", default=())
    pos: tuple[float, ...] = wire(_SEQ, "rad or m", "measured joints this cycle", default=())
    #: A restarted servo's statuses are newer than the old one's (``is_newer``); (0, 0): not said.
    started: Time = wire(w.TIME, doc="start of the servo process", default=Time(0, 0))
    #: Every status the servo makes counts, published on ``Servo/status`` or carried in a ``PowerReply``.
    seq: int = wire(w.ULONG, doc="counts the statuses of this servo process from 1; 0: not numbered",
                    default=0)
    #: The servo's own alarms, all of them in every status: the monitor adopts them as the servo's evidence.
    latches: tuple[ServoLatch, ...] = wire(w.SeqType("ServoLatchSeq", SERVO_LATCH), doc="the alarms the servo "
                                           "latched itself and holds, oldest first", default=())


#: A status no servo made (``seq`` 0, nothing on, nothing measured): "none held" where a field needs a value.
NO_STATUS = ServoStatus(Time(0, 0), False, False, False, 0, 0, 0, 0, (), (), ())


def is_newer(candidate: ServoStatus, current: ServoStatus | None) -> bool:
    """Whether the servo status ``candidate`` tells a later state than ``current`` (of a later servo
    process, or later in it); an unnumbered one (``seq`` 0: a sender that does not number them) always does."""
    if current is None or candidate.seq == 0:
        return True
    return (candidate.started.to_seconds(), candidate.seq) > (current.started.to_seconds(), current.seq)


@dataclasses.dataclass(frozen=True)
class LoopHealth:
    """``Servo/health``: the servo loop's timing since the previous report."""

    tm: Time = wire(w.TIME)
    cycles: int = wire(w.ULONG)  # cycles run in the window
    period: float = wire(w.DOUBLE, "s")  # nominal cycle period
    latenessP50: float = wire(w.DOUBLE, "s")  # start of cycle after its deadline
    latenessP99: float = wire(w.DOUBLE, "s")
    latenessMax: float = wire(w.DOUBLE, "s")
    lateCycles: int = wire(w.ULONG)  # cycles that started more than one period late
    overruns: int = wire(w.ULONG)  # cycles whose work took longer than one period
    fifoDepth: int = wire(w.ULONG)
    underruns: int = wire(w.ULONG)  # in the window
    latenessHist: tuple[int, ...] = wire(w.SeqType("ULONGSeq", w.ULONG),
                                         doc=f"cycles per lateness bin; bin lower edges [s]: "
                                         f"{list(LATENESS_BIN_EDGES)}")


@dataclasses.dataclass(frozen=True)
class CallTrace:
    """``trace/<served>/<op>``: one call a service answered, published only while something subscribes.

    Zenoh shows a query to no one but its queryable: this is how a recorder (or
    anyone) sees the calls of the Common and Middle interfaces and their replies.
    """

    t: float = wire(w.DOUBLE, "s", "Unix time the reply was sent")
    request: dict[str, Any] = wire(_WireMap(), doc="the in parameters as received, in wire form ({} for none); "
                                   'a payload that is not a map: {"payload": its text}')
    reply: dict[str, Any] = wire(_WireMap(), doc="the reply {id, comment, <out parameters>} in wire form")


@dataclasses.dataclass(frozen=True)
class WorldBox:
    """A fixed box of the simulated world: what the arm can run into."""

    position: tuple[float, ...] = wire(w.DOUBLE_SEQ, "m", "centre x, y, z in the world frame")
    halfExtents: tuple[float, ...] = wire(w.DOUBLE_SEQ, "m", "half the size along x, y, z")


WORLD_BOX = struct(WorldBox, strict=False)


@dataclasses.dataclass(frozen=True)
class ServoWorld:
    """``Servo/world``: the robot model the servo runs and the world around it, for viewers.

    The world frame is the simulation's; the arm frame (the URDF root) sits at
    ``basePosition`` in it. Nothing here changes while the servo runs.
    """

    robot: str = wire(w.STRING, doc="robot model name (`--robot`, jara_arm.robots)")
    basePosition: tuple[float, ...] = wire(w.DOUBLE_SEQ, "m", "the arm frame's origin in the world frame")
    obstacles: tuple[WorldBox, ...] = wire(w.SeqType("WorldBoxSeq", WORLD_BOX),
                                           doc="the model's own boxes, then the servo's --obstacle ones")


@dataclasses.dataclass(frozen=True)
class FeedbackBlock:
    """``Servo/posFeedbackBlock``: the servo's ``Servo/posFeedback`` samples of the last few cycles, oldest
    first, for the client gateway, which publishes them one by one on ``Servo/posFeedback`` to its clients
    (``launcher/up/gateway.py``): on the cell bus the 1 kHz stream costs one message per block, not per cycle."""

    samples: tuple[TimedJointPos, ...] = wire(w.SeqType("TimedJointPosSeq", w.TIMED_JOINT_POS))


STATE_MESSAGE = struct(StateMessage, strict=False, doc="State bits; extra members may follow.")
ALARM_EVENT = struct(AlarmEvent, strict=False)
LOG_RECORD = struct(LogRecord, strict=False)
SERVO_STATUS = struct(ServoStatus, strict=False, doc="Internal: servo loop status, published every few cycles.")
LOOP_HEALTH = struct(LoopHealth, strict=False, doc="Internal: servo loop timing over the last window (about 1 s).")
FEEDBACK_BLOCK = struct(FeedbackBlock, strict=False, doc="Internal: consecutive Servo/posFeedback samples, oldest "
                        "first, for the client gateway.")
CALL_TRACE = struct(CallTrace, strict=False, doc="A call answered on Common, Middle, Servo/Common or Monitor/Common "
                    "and its reply, as the serving service saw them.")
SERVO_WORLD = struct(ServoWorld, strict=False, doc="Internal: the servo's robot model and obstacles, Servo/world.")


def _timed_joint_pos(time_ns: int, pos: list[float]) -> dict[str, Any]:
    """``TimedJointPos`` in its wire form, built directly (the fast paths below)."""
    return {"tm": {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}, "pos": pos}


def timed_joint_pos_payload(time_ns: int, pos: list[float]) -> bytes:
    """MessagePack ``TimedJointPos`` for the servo's 1 kHz feedback, without the generic
    encoder's per-member work; tested to equal ``encode_message(TIMED_JOINT_POS, ...)``."""
    payload: bytes = msgpack.packb(_timed_joint_pos(time_ns, pos))
    return payload



def feedback_block_payload(samples: list[tuple[int, list[float]]]) -> bytes:
    """MessagePack ``FeedbackBlock`` of ``(time [ns], pos)`` samples, as :func:`timed_joint_pos_payload`
    builds each; tested to equal ``encode_message(FEEDBACK_BLOCK, ...)``."""
    payload: bytes = msgpack.packb({"samples": [_timed_joint_pos(ns, pos) for ns, pos in samples]})
    return payload


def feedback_block_samples(payload: bytes) -> list[bytes]:
    """The MessagePack ``TimedJointPos`` of each sample of a ``FeedbackBlock``, oldest first: byte for byte
    what :func:`timed_joint_pos_payload` gives for it. Raises WireError for anything else."""
    try:
        samples = msgpack.unpackb(payload)["samples"]
        return [msgpack.packb(w.TIMED_JOINT_POS.encode(w.TIMED_JOINT_POS.decode(s, "samples[]"))) for s in samples]
    except WireError:
        raise
    except Exception as exc:  # not MessagePack, not a map, no samples
        raise WireError("samples", f"not a FeedbackBlock: {exc}") from None


def servo_status_payload(status: ServoStatus) -> bytes:
    """MessagePack ``ServoStatus`` without the generic encoder's per-member work (100 a second
    per moving arm); tested to equal ``encode_message(SERVO_STATUS, status)``."""
    payload: bytes = msgpack.packb({
        "tm": {"sec": status.tm.sec, "nsec": status.tm.nsec}, "servoOn": status.servoOn,
        "moving": status.moving, "alarm": status.alarm, "fifoDepth": status.fifoDepth,
        "consumed": status.consumed, "received": status.received, "underruns": status.underruns,
        "vel": list(status.vel), "effort": list(status.effort), "target": list(status.target),
        "softLimitJoint": [{"upper": lim.upper, "lower": lim.lower} for lim in status.softLimitJoint],
        "pos": list(status.pos), "started": {"sec": status.started.sec, "nsec": status.started.nsec},
        "seq": status.seq, "latches": [SERVO_LATCH.encode(x) for x in status.latches]})  # rare: the generic way
    return payload


#: Every message type, for the generated JSON Schema.
MESSAGES: tuple[StructType[Any], ...] = (
    w.TIMED_JOINT_POS, STATE_MESSAGE, ALARM_EVENT, LOG_RECORD, SERVO_LATCH, SERVO_STATUS, LOOP_HEALTH, CALL_TRACE,
    WORLD_BOX, SERVO_WORLD, FEEDBACK_BLOCK,
)
