"""One arm's alarms as its servo acts on them: what it detected itself (latches), and the alarm monitor's list.

The alarm monitor owns the arm's list (``schema/alarms.py``). What the servo
detects itself (an e-stop put, a command that jumps or leaves the joint soft
limits) it acts on in the same cycle (``loop.py``) and keeps as a *latch*,
reported to the monitor on ``Monitor/report`` (again when its cause comes or
goes, and again on each list of the monitor's, whether it holds the latch or
not yet: the monitor publishes its list on every change and every
``LIST_PERIOD``, so a report lost on the ``drop`` key, or while the monitor was
down or restarting, is made again on its evidence, not on a timer). Each
latch's reports carry the time it latched: the monitor ignores those of a latch
it has cleared, so a copy still in flight after a clear raises nothing. The servo follows
the monitor's ``Monitor/alarms``: an alarm that appears there stops the arm (a
FAULT also switches the servo off), and a latch is released once the monitor
that listed it no longer does. While any latch or any listed alarm is active,
position commands are dropped.

:class:`AlarmState` is the bookkeeping of that: which alarms are active, and
what the monitor is told. Stopping the arm, and whether a cause is still
there, are the loop's: it passes them in. Loop thread only, as the rest of the
loop's state.
"""

from __future__ import annotations

import dataclasses
import logging
import time
from collections.abc import Callable

from jara_arm.schema.alarms import ALARM_REPORT, AlarmList, AlarmReport, format_code, is_newer
from jara_arm.schema.codes import AlarmCode, AlarmType
from jara_arm.schema.keys import Service
from jara_arm.schema.types import Alarm, Time
from jara_arm.services.runtime.wire import Publication

@dataclasses.dataclass
class Latch:
    """An alarm the servo detected itself; it keeps the arm stopped until the monitor clears it."""

    alarm: Alarm
    present: bool  # the cause was present when last reported
    latched: Time  # when: this latch's reports carry it (AlarmReport.latched), a later latch's is later
    acked: Time | None = None  # ``started`` of the monitor whose list held it; None: not listed yet


class AlarmState:
    """The active alarms of one arm's servo (module docstring)."""

    def __init__(self, report_pub: Publication, log: logging.LoggerAdapter[logging.Logger],
                 cause_present: Callable[[int], bool]) -> None:
        """``report_pub``: ``Monitor/report``; ``cause_present(code)``: whether the cause of the servo's own
        alarm ``code`` is still there (the loop's state says)."""
        self.latches: dict[int, Latch] = {}  # by code: what the servo detected itself
        self.monitor_alarms: tuple[Alarm, ...] = ()  # the alarm monitor's newest list
        self._monitor_list: AlarmList | None = None
        self._report_pub = report_pub
        self._log = log
        self._cause_present = cause_present
        self._latched_ns = 0  # the last latch's time [ns]: strictly increasing (AlarmReport.latched)

    def latch(self, code: AlarmCode, kind: AlarmType, description: str) -> None:
        """Latch the servo's own alarm ``code`` (the first of a code stands) and report it to the monitor."""
        if int(code) not in self.latches:
            latch = Latch(Alarm(int(code), kind, description), self._cause_present(int(code)), self._now())
            self.latches[int(code)] = latch
            self._log.error("alarm %s %s: %s", format_code(code), kind.value, description)
            self._report(latch)

    def not_completed(self, motions: list[int], why: str) -> None:
        """The WARNING that accepted motions were discarded before their end (0x420)."""
        description = f"motions {motions} discarded before their end: {why}"
        code = int(AlarmCode.MOTION_NOT_COMPLETED)
        if code in self.latches:  # one latch per code: the first one stands until cleared
            self._log.warning("%s (alarm %s already active)", description, format_code(code))
            return
        latch = Latch(Alarm(code, AlarmType.WARNING, description), False, self._now())
        self.latches[code] = latch
        self._log.warning("alarm %s %s: %s", format_code(code), AlarmType.WARNING.value, description)
        self._report(latch)

    def _now(self) -> Time:
        """A latch's time: now, later than any latch before it (a wall clock may stand or step back)."""
        self._latched_ns = max(time.time_ns(), self._latched_ns + 1)
        return Time.from_ns(self._latched_ns)

    def _report(self, latch: Latch) -> None:
        report = AlarmReport(latch.alarm, latch.present, Service.SERVO.value, latch.latched)
        try:
            self._report_pub.put_message(ALARM_REPORT, report)
        except Exception as exc:  # a report that cannot be sent is sent again later
            self._log.warning("could not report alarm %s to the monitor: %s", format_code(latch.alarm.code), exc)

    def report_latches(self) -> None:
        """Report every latch whose cause came or went."""
        for code, latch in list(self.latches.items()):
            present = self._cause_present(code)
            if present != latch.present:
                latch.present = present
                self._report(latch)

    def held_list(self) -> AlarmList | None:
        """The monitor's newest list less what was cleared without it: what this servo acts on."""
        if self._monitor_list is None:
            return None
        return dataclasses.replace(self._monitor_list, alarms=self.monitor_alarms)

    def adopt(self, alarms: AlarmList, stop: Callable[[Alarm], None]) -> None:
        """Follow the monitor's list: ``stop`` for each alarm new there (not latched here), release the latches
        it cleared, report every other latch again: one it does not hold yet (it lost the report, or the list
        crossed it), one it holds with the cause's presence now (a lost "cause gone" would keep it from a
        clear)."""
        if not is_newer(alarms, self._monitor_list):
            return  # published before the one already adopted
        self._monitor_list = alarms
        listed = {a.code for a in alarms.alarms}
        for code, latch in list(self.latches.items()):
            if code not in listed and latch.acked == alarms.started:
                del self.latches[code]
                self._log.info("alarm %s released: the alarm monitor cleared it", format_code(code))
                continue
            # Not listed yet, or by a monitor before this one: tell this one; listed: its cause's presence now.
            latch.acked = alarms.started if code in listed else None
            latch.present = self._cause_present(code)
            self._report(latch)
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
                kept.append(latch.alarm)
            else:
                cleared.append(self.latches.pop(code).alarm)
                self._log.info("alarm %s cleared", format_code(code))
        return cleared, kept


__all__ = ["AlarmState", "Latch"]
