"""One arm's alarms as its servo acts on them: what it detected itself (latches), and the alarm monitor's list.

The alarm monitor owns the arm's list (``schema/alarms.py``). What the servo
detects itself (an e-stop put, a command that jumps or leaves the joint soft
limits) it acts on in the same cycle (``loop.py``) and keeps as a *latch*. The
servo's status (``Servo/status``, ``ServoStatus.latches``) carries every latch
it holds, with whether its cause is still there and when it latched: a status
goes out at once when a latch or its cause comes or goes, and at least every
0.1 s besides, so a status lost on the ``drop`` key, or one a restarting monitor
missed, is replaced by the next one; nothing is reported twice. The monitor
adopts the latches of each newer status and ignores a latch it has cleared
that a status made before the clear still carries (``latched``). The servo
follows the monitor's ``Monitor/alarms``: an alarm that appears there stops the
arm (a FAULT also switches the servo off), and a latch is released once the
monitor that listed it no longer does. While any latch or any listed alarm is
active, position commands are dropped.

:class:`AlarmState` is the bookkeeping of that: which alarms are active, and
what the status says of them. Stopping the arm, and whether a cause is still
there, are the loop's: it passes them in. Loop thread only, as the rest of the
loop's state.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable

from jara_arm.schema.alarms import AlarmList, format_code, is_newer
from jara_arm.schema.codes import AlarmCode, AlarmType
from jara_arm.schema.messages import ServoLatch
from jara_arm.schema.types import Alarm, Time

@dataclasses.dataclass
class Latch:
    """An alarm the servo detected itself; it keeps the arm stopped until the monitor clears it."""

    status: ServoLatch  # as every status carries it: its cause's presence when last looked at (every cycle)
    acked: Time | None = None  # ``started`` of the monitor whose list held it; None: not listed yet


class AlarmState:
    """The active alarms of one arm's servo (module docstring)."""

    def __init__(self, log: logging.LoggerAdapter[logging.Logger], cause_present: Callable[[int], bool]) -> None:
        """``cause_present(code)``: whether the cause of the servo's own alarm ``code`` is still there (the
        loop's state says)."""
        self.latches: dict[int, Latch] = {}  # by code: what the servo detected itself
        self.monitor_alarms: tuple[Alarm, ...] = ()  # the alarm monitor's newest list
        #: A latch, or its cause, came or went since the last status: the next one goes out at once.
        self.changed = False
        self._monitor_list: AlarmList | None = None
        self._log = log
        self._cause_present = cause_present
        self._latched_ns = 0  # the last latch's time [ns]: strictly increasing (ServoLatch.latched)

    def latch(self, code: AlarmCode, kind: AlarmType, description: str) -> None:
        """Latch the servo's own alarm ``code`` (the first of a code stands)."""
        if int(code) not in self.latches:
            alarm = Alarm(int(code), kind, description)
            self.latches[int(code)] = Latch(ServoLatch(alarm, self._cause_present(int(code)), self._now()))
            self.changed = True
            self._log.error("alarm %s %s: %s", format_code(code), kind.value, description)

    def not_completed(self, motions: list[int], why: str) -> None:
        """The WARNING that accepted motions were discarded before their end (0x420)."""
        description = f"motions {motions} discarded before their end: {why}"
        code = int(AlarmCode.MOTION_NOT_COMPLETED)
        if code in self.latches:  # one latch per code: the first one stands until cleared
            self._log.warning("%s (alarm %s already active)", description, format_code(code))
            return
        self.latches[code] = Latch(ServoLatch(Alarm(code, AlarmType.WARNING, description), False, self._now()))
        self.changed = True
        self._log.warning("alarm %s %s: %s", format_code(code), AlarmType.WARNING.value, description)

    def _now(self) -> Time:
        """A latch's time: now, later than any latch before it (a wall clock may stand or step back)."""
        self._latched_ns = max(time.time_ns(), self._latched_ns + 1)
        return Time.from_ns(self._latched_ns)

    def look(self) -> None:
        """Note whether each latch's cause is still there (every cycle while one is held)."""
        for code, latch in self.latches.items():
            present = self._cause_present(code)
            if present != latch.status.present:
                latch.status = dataclasses.replace(latch.status, present=present)
                self.changed = True

    def snapshot(self) -> tuple[ServoLatch, ...]:
        """Every latch as the status carries it (``ServoStatus.latches``), oldest first."""
        return tuple(latch.status for latch in self.latches.values())

    def held_list(self) -> AlarmList | None:
        """The monitor's newest list less what was cleared without it: what this servo acts on."""
        if self._monitor_list is None:
            return None
        return dataclasses.replace(self._monitor_list, alarms=self.monitor_alarms)

    def adopt(self, alarms: AlarmList, stop: Callable[[Alarm], None]) -> None:
        """Follow the monitor's list: ``stop`` for each alarm new there (not latched here), release the latches
        it cleared (once listed by it: a latch the list does not hold yet is one it has not heard of yet)."""
        if not is_newer(alarms, self._monitor_list):
            return  # published before the one already adopted
        self._monitor_list = alarms
        listed = {a.code for a in alarms.alarms}
        for code, latch in list(self.latches.items()):
            if code not in listed and latch.acked == alarms.started:
                del self.latches[code]
                self.changed = True
                self._log.info("alarm %s released: the alarm monitor cleared it", format_code(code))
                continue
            latch.acked = alarms.started if code in listed else None  # listed by a monitor before: not by this one
        before = {a.code for a in self.monitor_alarms}
        self.monitor_alarms = alarms.alarms
        for alarm in alarms.alarms:
            if alarm.code not in before and alarm.code not in self.latches:  # a stop may have latched 0x420
                self._log.warning("alarm %s %s from the alarm monitor: stopping the arm (%s)",
                                  format_code(alarm.code), alarm.type.value, alarm.description)
                stop(alarm)

    def clear(self) -> tuple[list[Alarm], list[Alarm]]:
        """Without an alarm monitor: clear the latches whose cause has gone, forget the monitor's list.

        Returns (cleared, still active).
        """
        cleared, kept = list(self.monitor_alarms), []
        self.monitor_alarms = ()
        for code, latch in list(self.latches.items()):
            if self._cause_present(code):
                kept.append(latch.status.alarm)
            else:
                cleared.append(self.latches.pop(code).status.alarm)
                self.changed = True
                self._log.info("alarm %s cleared", format_code(code))
        return cleared, kept


__all__ = ["AlarmState", "Latch"]
