"""The internal contract of the alarm monitor, the owner of each arm's list of active alarms.

Everything here lives under ``JARA_ARM/<arm>/Monitor/``:

* ``Monitor/Common/<op>`` (queryable): ``getActiveAlarm`` and ``clearAlarms``
  of the Common table (:data:`MONITOR_OPERATIONS`); any other ``<op>`` gets
  ``NOT_IMPLEMENTED``. The Common interfaces of the servo and of the command
  service forward these two operations here, so that every interface agrees.
* ``Monitor/alarms`` (publisher, on every change and at 2 Hz; also a
  queryable that answers the current one): :class:`AlarmList`, the whole list.
* ``Servo/status`` (subscriber, ``schema.messages.ServoStatus``): what the
  servo detected itself and holds (``latches``, each with whether its cause is
  still there), in every status it makes; the monitor adopts each newer status's
  latches as the servo's evidence, and ignores a latch it has cleared
  (``ServoLatch.latched``) that a status made before the clear still carries.
* ``heartbeat/<service>`` (subscriber): :class:`Heartbeat` that every service
  publishes every ``Health.heartbeat_period`` (``services/runtime/timing.py``) from a real-time thread of its own.
  A liveliness token shows connectivity, not health: a stopped or starved
  process falls silent here while its token stays up, and a process whose
  working loop is stuck says so in ``stuck``. Either is the service's hung
  FAULT (0x410-0x412).

The public side is ``JARA_ARM/<arm>/alarm``: an ``AlarmEvent`` for every alarm
raised or cleared (``schema.messages.ALARM_EVENT``).

:data:`ALARM_TABLE` lists every code this implementation raises, with its type
and meaning (DECISIONS.md "Alarms": a FAULT switches the servo off and
discards the motion queue; a WARNING stops the motion and keeps the servo on).
"""

from __future__ import annotations

import dataclasses
import enum
from collections.abc import Mapping
from types import MappingProxyType
from typing import Any

from . import wire_types as w
from .codes import AlarmCode, AlarmType
from .operations import COMMON, OP, Operation
from .types import Alarm, Time
from .wire_types import StructType, struct, wire


class AlarmEventKind(enum.StrEnum):
    """``AlarmEvent.event``."""

    RAISED = "raised"
    CLEARED = "cleared"


@dataclasses.dataclass(frozen=True)
class AlarmInfo:
    """One row of the alarm table: what a code means and how the system reacts to it."""

    code: AlarmCode
    type: AlarmType
    meaning: str


ALARM_TABLE: tuple[AlarmInfo, ...] = (
    AlarmInfo(AlarmCode.EMERGENCY_STOP, AlarmType.FAULT,
              "emergency stop: a put on JARA_ARM/<arm>/estop"),
    AlarmInfo(AlarmCode.OVERLOAD, AlarmType.WARNING,
              "overload: a joint effort above its rating (e.g. pushing against an obstacle)"),
    AlarmInfo(AlarmCode.OVERSPEED, AlarmType.FAULT,
              "overspeed: a joint faster than its rated speed, or a position command that jumps"),
    AlarmInfo(AlarmCode.SOFT_LIMIT_JOINT, AlarmType.WARNING,
              "joint soft limit crossed during motion, or a position command beyond it"),
    AlarmInfo(AlarmCode.SOFT_LIMIT_CARTESIAN, AlarmType.WARNING,
              "Cartesian soft limit crossed by the control point during motion"),
    AlarmInfo(AlarmCode.SERVO_LOST, AlarmType.FAULT,
              "the servo service is gone (its liveliness token was deleted)"),
    AlarmInfo(AlarmCode.PLANNER_LOST, AlarmType.FAULT,
              "the planner service is gone (its liveliness token was deleted)"),
    AlarmInfo(AlarmCode.COMMAND_LOST, AlarmType.FAULT,
              "the command service is gone (its liveliness token was deleted)"),
    AlarmInfo(AlarmCode.MONITOR_LOST, AlarmType.FAULT,
              "the alarm monitor is gone (its liveliness token was deleted): detected by the servo, "
              "listed once a monitor is back"),
    AlarmInfo(AlarmCode.SERVO_HUNG, AlarmType.FAULT,
              "the servo service hangs: token up, but its heartbeat silent or a loop of it stuck"),
    AlarmInfo(AlarmCode.PLANNER_HUNG, AlarmType.FAULT,
              "the planner service hangs: token up, but its heartbeat silent or a loop of it stuck"),
    AlarmInfo(AlarmCode.COMMAND_HUNG, AlarmType.FAULT,
              "the command service hangs: token up, but its heartbeat silent or a loop of it stuck"),
    AlarmInfo(AlarmCode.MONITOR_HUNG, AlarmType.FAULT,
              "the alarm monitor hangs: token up, but its heartbeat silent or a loop of it stuck: "
              "detected by the servo"),
    AlarmInfo(AlarmCode.MOTION_NOT_COMPLETED, AlarmType.WARNING,
              "an accepted motion did not run to its end: discarded because of an alarm (the servo refusing "
              "one of its commands raises one too); names the motions and why. A client's stop and servoOFF "
              "are not alarms"),
)

#: Alarm type of every code, from :data:`ALARM_TABLE`.
ALARM_TYPE: Mapping[int, AlarmType] = MappingProxyType({int(a.code): a.type for a in ALARM_TABLE})


def make_alarm(code: AlarmCode, description: str) -> Alarm:
    """The alarm ``code`` with its type from the table and ``description``."""
    return Alarm(int(code), ALARM_TYPE[int(code)], description)


def format_code(code: int) -> str:
    """``0x01`` for the specification's codes, ``0x400`` for the model-specific ones."""
    return f"0x{code:02x}"


@dataclasses.dataclass(frozen=True)
class AlarmList:
    """``Monitor/alarms``: every active alarm of the arm, oldest first."""

    tm: Time = wire(w.TIME)  # when the monitor made this list; a later tm is a newer list
    started: Time = wire(w.TIME, doc="start of the monitor process")  # a new value means a new monitor
    alarms: tuple[Alarm, ...] = wire(w.ALARM_SEQ, doc="oldest first")


#: No time said: the times of :data:`NO_LIST`.
NO_TIME = Time(0, 0)

#: No monitor's list: what ``Monitor/copy`` answers before the servo adopted one, and what a caller of
#: ``Servo/power`` that holds none sends (never adopted: no monitor started at time 0).
NO_LIST = AlarmList(NO_TIME, NO_TIME, ())


def is_newer(candidate: AlarmList, current: AlarmList | None) -> bool:
    """Whether ``candidate`` replaces ``current``: a later monitor start, or a later list of it."""
    if current is None:
        return True
    return ((candidate.started.to_seconds(), candidate.tm.to_seconds())
            >= (current.started.to_seconds(), current.tm.to_seconds()))


@dataclasses.dataclass(frozen=True)
class Heartbeat:
    """``heartbeat/<service>``: the service's process runs; which of its working loops are stuck."""

    seq: int = wire(w.ULONG, doc="counts from 0 at the process's start")
    # e.g. "the servo loop: 130 ms"; () if none
    stuck: tuple[str, ...] = wire(w.SeqType("StringSeq", w.STRING), doc="a line per loop that missed its deadline")
    leaving: bool = wire(w.BOOLEAN, doc="the last beat of a service shutting down in order: its token "
                         "goes next, and that is not a loss", default=False)
    pid: int = wire(w.ULONG, doc="the service's process id (0: not said)", default=0)
    host: str = wire(w.STRING, doc="its host's boot id and PID namespace: a watcher with the same one may "
                     "ask this host's kernel whether a silent service is stopped or starved", default="")
    tid: int = wire(w.ULONG, doc="the heartbeat thread's id (0: not said)", default=0)


ALARM_LIST = struct(AlarmList, strict=False, doc="Internal: the alarm monitor's list of active alarms, Monitor/alarms.")
HEARTBEAT = struct(Heartbeat, strict=False, doc="Internal: every service -> the alarm monitor, heartbeat/<service>.")

#: The Common operations the alarm monitor serves at ``Monitor/Common/<op>``.
MONITOR_OPERATIONS: Mapping[str, Operation] = MappingProxyType(
    {name: COMMON[name] for name in (OP.clearAlarms, OP.getActiveAlarm)})

MESSAGES: tuple[StructType[Any], ...] = (ALARM_LIST, HEARTBEAT)
