"""Published messages: the public topics of WIRE.md and the internal ones.

Messages are relaxed structs: a reader ignores members it does not know, so a
publisher may add fields without breaking older subscribers.
"""

from __future__ import annotations

import dataclasses

import msgpack
import numpy as np

from . import wire_types as w
from .errors import WireError
from .types import Alarm, LimitValue, Time
from .wire_types import Member, StructType


@dataclasses.dataclass(frozen=True)
class StateMessage:
    """``JARA_ARM/<arm>/state``: the state bits, on every change."""

    state: int


@dataclasses.dataclass(frozen=True)
class AlarmEvent:
    """``JARA_ARM/<arm>/alarm``: an alarm raised or cleared."""

    event: str  # "raised" | "cleared"
    alarm: Alarm


@dataclasses.dataclass(frozen=True)
class LogRecord:
    """``JARA_ARM/<arm>/log/<service>``: one Python logging record."""

    t: float  # [s] Unix time
    level: str  # DEBUG, INFO, WARNING, ERROR, CRITICAL
    service: str
    msg: str
    logger: str


@dataclasses.dataclass(frozen=True)
class ServoStatus:
    """``Servo/status``: what the planner and the alarm monitor need from the servo loop."""

    tm: Time
    servoOn: bool
    moving: bool
    alarm: bool
    fifoDepth: int  # commands waiting in the SyncFIFO
    consumed: int  # commands taken from the FIFO since the servo started
    received: int  # commands received since the servo started
    underruns: int  # cycles the FIFO was empty while the arm was moving, since start
    vel: tuple[float, ...]  # [rad/s or m/s] measured joint velocities
    effort: tuple[float, ...]  # [N m or N] measured joint efforts
    target: tuple[float, ...]  # [rad or m] joint target applied this cycle
    softLimitJoint: tuple[LimitValue, ...] = ()  # [rad or m] the servo's joint soft limits, per arm axis
    pos: tuple[float, ...] = ()  # [rad or m] measured joints this cycle (as in Servo/posFeedback)


@dataclasses.dataclass(frozen=True)
class LoopHealth:
    """``Servo/health``: the servo loop's timing since the previous report."""

    tm: Time
    cycles: int  # cycles run in the window
    period: float  # [s] nominal cycle period
    latenessP50: float  # [s] start of cycle after its deadline
    latenessP99: float  # [s]
    latenessMax: float  # [s]
    lateCycles: int  # cycles that started more than one period late
    overruns: int  # cycles whose work took longer than one period
    fifoDepth: int
    underruns: int  # in the window
    latenessHist: tuple[int, ...]  # cycles per lateness bin, edges LATENESS_BIN_EDGES


@dataclasses.dataclass(frozen=True)
class PositionBlock:
    """``Servo/posBlock``: consecutive position commands for the SyncFIFO, one per cycle, in order.

    What the planner streams: one message per few cycles instead of one per
    cycle (``Servo/posCmd``) costs the planner, the router and the servo a
    fraction of the work for the same commands.
    """

    tm: Time  # when the first one is due at the servo
    pos: tuple[tuple[float, ...], ...]  # [rad or m] one JointPos per cycle


#: Lower edges of the ``LoopHealth.latenessHist`` bins [s]; the last bin is open-ended.
LATENESS_BIN_EDGES: tuple[float, ...] = (0.0, 50e-6, 100e-6, 200e-6, 500e-6, 1e-3, 2e-3, 5e-3, 10e-3)


STATE_MESSAGE = StructType(StateMessage, (Member("state", w.ULONG),), strict=False,
                           doc="State bits; extra members may follow.")
ALARM_EVENT = StructType(AlarmEvent, (
    Member("event", w.STRING, doc='"raised" or "cleared"'), Member("alarm", w.ALARM),
), strict=False)
LOG_RECORD = StructType(LogRecord, (
    Member("t", w.DOUBLE, "s", "Unix time"), Member("level", w.STRING), Member("service", w.STRING),
    Member("msg", w.STRING), Member("logger", w.STRING),
), strict=False)
_SEQ = w.DOUBLE_SEQ
SERVO_STATUS = StructType(ServoStatus, (
    Member("tm", w.TIME), Member("servoOn", w.BOOLEAN), Member("moving", w.BOOLEAN),
    Member("alarm", w.BOOLEAN), Member("fifoDepth", w.ULONG), Member("consumed", w.ULONG),
    Member("received", w.ULONG), Member("underruns", w.ULONG),
    Member("vel", _SEQ, "rad/s or m/s"), Member("effort", _SEQ, "N m or N"),
    Member("target", _SEQ, "rad or m"),
    Member("softLimitJoint", w.LIMIT_SEQ, "rad or m", "the joint soft limits in force, per arm axis"),
    Member("pos", _SEQ, "rad or m", "measured joints this cycle"),
), strict=False, doc="Internal: servo loop status, published every few cycles.")
LOOP_HEALTH = StructType(LoopHealth, (
    Member("tm", w.TIME), Member("cycles", w.ULONG), Member("period", w.DOUBLE, "s"),
    Member("latenessP50", w.DOUBLE, "s"), Member("latenessP99", w.DOUBLE, "s"),
    Member("latenessMax", w.DOUBLE, "s"), Member("lateCycles", w.ULONG),
    Member("overruns", w.ULONG), Member("fifoDepth", w.ULONG), Member("underruns", w.ULONG),
    Member("latenessHist", w.SeqType("ULONGSeq", w.ULONG),
           doc=f"cycles per lateness bin; bin lower edges [s]: {list(LATENESS_BIN_EDGES)}"),
), strict=False, doc="Internal: servo loop timing over the last window (about 1 s).")

def timed_joint_pos_payload(time_ns: int, pos: list[float]) -> bytes:
    """MessagePack ``TimedJointPos`` for the servo's 1 kHz feedback, without the generic
    encoder's per-member work; tested to equal ``encode_message(TIMED_JOINT_POS, ...)``."""
    return msgpack.packb({"tm": {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000},
                          "pos": pos})



def servo_status_payload(status: ServoStatus) -> bytes:
    """MessagePack ``ServoStatus`` without the generic encoder's per-member work (100 a second
    per moving arm); tested to equal ``encode_message(SERVO_STATUS, status)``."""
    return msgpack.packb({
        "tm": {"sec": status.tm.sec, "nsec": status.tm.nsec}, "servoOn": status.servoOn,
        "moving": status.moving, "alarm": status.alarm, "fifoDepth": status.fifoDepth,
        "consumed": status.consumed, "received": status.received, "underruns": status.underruns,
        "vel": list(status.vel), "effort": list(status.effort), "target": list(status.target),
        "softLimitJoint": [{"upper": lim.upper, "lower": lim.lower} for lim in status.softLimitJoint],
        "pos": list(status.pos)})

POSITION_BLOCK = StructType(PositionBlock, (
    Member("tm", w.TIME, doc="when the first command is due at the servo"),
    Member("pos", w.SeqType("JointPosSeq", w.JOINT_POS), "rad or m", "one JointPos per cycle, in order"),
), strict=False, doc="Internal: consecutive position commands for the servo's SyncFIFO, one per cycle.")


def position_block_payload(due: float, rows: list[list[float]]) -> bytes:
    """MessagePack ``PositionBlock`` (``due`` [s] Unix time) without the generic encoder's
    per-member work; tested to decode as ``POSITION_BLOCK``."""
    sec = int(due // 1)
    nsec = int(round((due - sec) * 1e9))  # the fraction alone: due * 1e9 would lose 100 ns
    if nsec >= 1_000_000_000:
        sec, nsec = sec + 1, nsec - 1_000_000_000
    return msgpack.packb({"tm": {"sec": sec, "nsec": nsec}, "pos": rows})



def position_block_rows(payload: bytes, dof: int) -> np.ndarray:
    """The ``pos`` rows [rad or m] of a MessagePack ``PositionBlock`` as an (n, ``dof``) array,
    checked as ``POSITION_BLOCK`` checks them (finite numbers, ``dof`` per row) without its
    per-number work: the servo reads 250 of these a second per arm. Raises WireError."""
    try:
        msg = msgpack.unpackb(payload, raw=False, strict_map_key=True)
    except Exception as exc:  # every parser error is the sender's
        raise WireError("payload", f"not valid MSGPACK: {exc}") from None
    if not isinstance(msg, dict):
        raise WireError("", "expected a map (PositionBlock)")
    POSITION_BLOCK.members[0].type.decode(msg.get("tm"), "tm")
    pos = msg.get("pos")
    if not isinstance(pos, list) or not all(isinstance(row, list) for row in pos):
        raise WireError("pos", "expected a list of lists of numbers (JointPosSeq)")
    for row in pos:
        if len(row) != dof:
            raise WireError("pos", f"expected rows of {dof} axes, got {len(row)}")
    try:
        rows = np.array(pos, dtype=float).reshape(len(pos), dof)
    except (TypeError, ValueError) as exc:
        raise WireError("pos", f"expected rows of numbers: {exc}") from None
    if any(isinstance(x, bool) for row in pos for x in row):
        raise WireError("pos", "expected numbers, got a boolean")
    if not np.isfinite(rows).all():
        raise WireError("pos", "must be finite")
    return rows

#: Every message type, for the generated JSON Schema.
MESSAGES: tuple[StructType, ...] = (
    w.TIMED_JOINT_POS, STATE_MESSAGE, ALARM_EVENT, LOG_RECORD, SERVO_STATUS, LOOP_HEALTH, POSITION_BLOCK,
)
