"""Return codes, alarm codes and state bits of the specification (SPEC.md §4)."""

from __future__ import annotations

import enum


class ReturnCode(enum.IntEnum):
    """``RETURN_ID.id``: the outcome of every operation."""

    OK = 0
    NG = -1
    STATUS_ERR = -2
    VALUE_ERR = -3
    NOT_SV_ON_ERR = -4
    FULL_MOTION_QUEUE_ERR = -5
    NOT_IMPLEMENTED = -6


class AlarmType(enum.Enum):
    """``AlarmType``: FAULT is unrecoverable without servoON, WARNING recoverable."""

    FAULT = "FAULT"
    WARNING = "WARNING"
    UNKNOWN = "UNKNOWN"


class AlarmCode(enum.IntEnum):
    """``Alarm.code``: 0x01-0x05 from the specification, >= 0x400 model-specific.

    The model-specific codes of this implementation say which service that is
    needed to move the arm failed, and how: 0x40s = its liveliness token was
    deleted (the process is gone), 0x41s = its token is still up but its
    heartbeat went silent or names a stuck loop (the process hangs). Every one
    is a FAULT. The alarm monitor watches the servo, the planner and the
    command service; the servo watches the alarm monitor (0x403, 0x413).
    0x420 is a WARNING: an accepted motion did not run to its end.
    """

    EMERGENCY_STOP = 0x01
    OVERLOAD = 0x02
    OVERSPEED = 0x03
    SOFT_LIMIT_JOINT = 0x04
    SOFT_LIMIT_CARTESIAN = 0x05
    SERVO_LOST = 0x400  # the servo service's liveliness token was deleted
    PLANNER_LOST = 0x401  # the planner service's token was deleted
    COMMAND_LOST = 0x402  # the command service's token was deleted
    SERVO_HUNG = 0x410  # token up, but its heartbeat silent, or a loop of it stuck
    PLANNER_HUNG = 0x411  # token up, but its heartbeat silent, or a loop of it stuck
    COMMAND_HUNG = 0x412  # token up, but its heartbeat silent, or a loop of it stuck
    MONITOR_LOST = 0x403  # the alarm monitor's token was deleted (detected by the servo)
    MONITOR_HUNG = 0x413  # the alarm monitor's token up, its heartbeat silent or stuck (servo)
    #: WARNING: an accepted motion was discarded before its end by anything but a client's stop
    #: (an alarm, the servo refusing a command of it); the description names the motions and why
    MOTION_NOT_COMPLETED = 0x420


class StateBit(enum.IntFlag):
    """``getState`` bits. The IDL names 0x01-0x08; the prose adds 0x10 (paused)."""

    SERVO_ON = 0x01  # CONST_BINARY_00000001, isServoOn
    MOVING = 0x02  # CONST_BINARY_00000010, isMoving
    ALARM = 0x04  # CONST_BINARY_00000100, isAlarmed
    BUFFER_FULL = 0x08  # CONST_BINARY_00001000, isBufferFull (middle level only)
    PAUSED = 0x10  # paused (middle level only)


# The IDL constant names, so that a search for them lands here.
CONST_BINARY_00000001 = StateBit.SERVO_ON
CONST_BINARY_00000010 = StateBit.MOVING
CONST_BINARY_00000100 = StateBit.ALARM
CONST_BINARY_00001000 = StateBit.BUFFER_FULL

ULONG_MAX = 2**32 - 1
