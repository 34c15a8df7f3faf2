"""The servo's power state, which it alone owns: servo on and off, and the alarms that keep it off cleared.

Two ways in, one function each: ``Servo/Common``'s ``servoON``, ``servoOFF`` and
``clearAlarms`` (the IDL's: for generic tools, and the alarm monitor's reaction
to a FAULT) and ``Servo/power`` (the command service's, ``schema/power.py``),
whose reply carries the servo's status made after the action, numbered, so that
the caller knows the new state at once instead of waiting for a publication.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.alarms import NO_LIST, AlarmList
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal
from jara_arm.schema.messages import NO_STATUS
from jara_arm.schema.operations import OP
from jara_arm.schema.power import POWER_REPLY, POWER_REQUEST, PowerAction, PowerReply
from jara_arm.services.runtime.monitor_link import MonitorLink, clear_reply
from jara_arm.services.runtime.rpc import ok

from .loop import ServoLoop

log = logging.getLogger(__name__)

#: Comment added to replies made without the alarm monitor.
NO_MONITOR = "the alarm monitor does not answer: the servo's own alarms only"


class ServoPower:
    """Servo on, off, and the alarms cleared (the monitor's, or without one the servo's own), for ``Servo/Common``
    and ``Servo/power``."""

    def __init__(self, loop: ServoLoop, monitor: MonitorLink) -> None:
        self.loop = loop
        self.monitor = monitor
        self._actions: dict[PowerAction, Callable[[], Reply]] = {
            PowerAction.ON: self.on, PowerAction.OFF: self.off, PowerAction.CLEAR: self.clear,
            PowerAction.SYNC: ok}

    def adopt(self, alarms: AlarmList) -> None:
        """Follow ``alarms``, the monitor's, now if it is newer than the list the loop holds (as a publication)."""
        self.loop.call(lambda: self.loop.adopt_monitor_list(alarms))

    def refresh(self) -> bool:
        """Adopt the monitor's current list now (not when its publication arrives); False if silent."""
        alarms = self.monitor.alarm_list()
        if alarms is None:
            return False
        self.adopt(alarms)
        return True

    def on(self) -> Reply:
        """Servo on; Refusal STATUS_ERR saying why not (an alarm active, the arm still stopping)."""
        loop = self.loop
        why = loop.call(loop.servo_on_now)
        if why and loop.alarm_state.monitor_alarms and self.refresh():
            why = loop.call(loop.servo_on_now)  # alarms just cleared through another interface
        if why:
            raise Refusal(ReturnCode.STATUS_ERR, f"servoON refused: {why}")
        return ok()

    def off(self) -> Reply:
        """Servo off: buffered motions discarded, the arm brakes."""
        self.loop.call(self.loop.servo_off_now)
        return ok()

    def clear(self) -> Reply:
        """``clearAlarms``: the alarm monitor's reply, its list followed at once; without a monitor, the servo's own
        alarms whose cause has gone cleared and the monitor's list forgotten (Refusal STATUS_ERR naming what stayed)."""
        reply = self.monitor.call(OP.clearAlarms)
        if reply is None:
            cleared, kept = self.loop.call(self.loop.clear_alarms_now)
            return clear_reply(cleared, kept, NO_MONITOR)
        self.refresh()  # the latches the monitor cleared are released before the reply
        return reply

    def answer(self, key: str, payload: bytes, encoding: Encoding) -> tuple[str, bytes]:
        """``Servo/power`` (a ``QueryServer``'s answer): adopt the request's list, act, and reply on ``key`` with
        the status after it. A malformed request changes nothing: VALUE_ERR naming the field."""
        try:
            req = codec.decode_message(POWER_REQUEST, payload, encoding)
            act = self._actions[w.choice(PowerAction, req.action, "action")]
            if req.alarms.started != NO_LIST.started:  # started at time 0: the caller holds no monitor's list
                self.adopt(req.alarms)
            reply = act()
        except Refusal as exc:  # a WireError too
            reply = Reply(exc.code, exc.comment)
        except Exception as exc:  # the loop did not take the call in time (a starved host): NG now, not silence
            log.warning("Servo/power: %s", exc)
            reply = Reply(ReturnCode.NG, f"the servo could not act: {exc}")
        try:
            status = self.loop.call(self.loop.status_now)
        except Exception:  # NO_STATUS (seq 0) says none: the caller keeps what it had
            status = NO_STATUS
        return key, codec.encode_message(POWER_REPLY, PowerReply(int(reply.id), reply.comment, status), encoding)
