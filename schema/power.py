"""The internal contract of the servo's power state, which the servo alone owns.

* ``Servo/power`` (queryable): ``PowerRequest`` -> ``PowerReply``.

The command service switches the servo on and off through it, and clears the
alarms through it when the monitor does not answer the command. The reply
carries the servo's status made after the action, numbered as every status the
servo makes (``ServoStatus.started``, ``seq``): the caller adopts it at once,
and a ``Servo/status`` publication still on its way, older by its number,
changes nothing (``schema.messages.is_newer``). Nobody waits for a publication
to see the change.

The request carries the alarm monitor's newest list that the caller holds: the
servo adopts it first if it is newer than its own (as it adopts the monitor's
publications), so that a switch-on after a clear is not refused for alarms the
monitor no longer lists but whose publication has not reached the servo yet.
"""

from __future__ import annotations

import dataclasses
import enum
from typing import Any

from . import wire_types as w
from .alarms import ALARM_LIST, NO_LIST, AlarmList
from .messages import SERVO_STATUS, ServoStatus
from .wire_types import StructType, struct, wire


class PowerAction(enum.StrEnum):
    """``PowerRequest.action``; each adopts ``PowerRequest.alarms`` first."""

    ON = "on"  # servo on (Common servoON): refused STATUS_ERR while an alarm is active
    OFF = "off"  # servo off (Common servoOFF): buffered motions discarded, the arm brakes
    CLEAR = "clear"  # clearAlarms as Servo/Common's: the monitor's, or without one the servo's own whose cause has gone
    SYNC = "sync"  # nothing more: the servo now follows the list, and the reply says how it stands


@dataclasses.dataclass(frozen=True)
class PowerRequest:
    """Adopt ``alarms`` if newer than the servo's list, then ``action``: ``on``, ``off``, ``clear`` (the command's
    clearAlarms when its monitor did not answer) or ``sync`` (no more than the adoption; :class:`PowerAction`)."""

    action: str = wire(w.STRING, doc=" | ".join(a.value for a in PowerAction))
    alarms: AlarmList = wire(ALARM_LIST, doc="the alarm monitor's newest list the caller holds; one with "
                             "started (0, 0) when it holds none", default=NO_LIST)


@dataclasses.dataclass(frozen=True)
class PowerReply:
    """``id``/``comment`` as RETURN_ID (those of Common servoON, servoOFF, clearAlarms); ``status`` in any case."""

    id: int = wire(w.LONG)
    comment: str = wire(w.STRING)
    status: ServoStatus = wire(SERVO_STATUS)  # made after the action, numbered: newer than any status before it


POWER_REQUEST = struct(PowerRequest, doc="Internal: command -> servo, Servo/power.")
POWER_REPLY = struct(PowerReply, strict=False, doc="Internal: servo -> command, the reply to Servo/power.")

MESSAGES: tuple[StructType[Any], ...] = (POWER_REQUEST, POWER_REPLY)
