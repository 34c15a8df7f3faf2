"""The list of active alarms of one arm, and what is known about their causes.

Not thread-safe: the monitor thread alone uses it (the RPC thread hands its
work to that thread).
"""

from __future__ import annotations

from collections.abc import Callable, Iterable

from jara_arm.schema.messages import ServoLatch
from jara_arm.schema.types import Alarm


class AlarmBook:
    """Active alarms by code (one per code, the first description wins), oldest first.

    A code may be raised by the monitor's own detectors and latched by the servo
    (its status carries its latches, every one in every status); its cause is
    present while either says so: the detector's own state (asked at clear
    time) or the servo's newest status. A status made before a clear still
    carries the latch cleared, so a latch whose time (``ServoLatch.latched``) is
    not after the last one cleared of its code is ignored: it does not raise the
    alarm again.
    """

    def __init__(self) -> None:
        self._alarms: dict[int, Alarm] = {}
        self._latches: dict[int, ServoLatch] = {}  # by code: the servo's, as its newest status says
        self._cleared: dict[int, int] = {}  # by code: ``latched`` [ns] of the last servo latch cleared

    @property
    def alarms(self) -> tuple[Alarm, ...]:
        return tuple(self._alarms.values())

    def __contains__(self, code: int) -> bool:
        return code in self._alarms

    def raise_alarm(self, alarm: Alarm) -> bool:
        """Add ``alarm`` unless its code is active; True if it is new."""
        if alarm.code in self._alarms:
            return False
        self._alarms[alarm.code] = alarm
        return True

    def adopt(self, latches: Iterable[ServoLatch]) -> list[Alarm]:
        """The servo's latches now (a newer status's: what it no longer holds says nothing any more); the
        alarms they added to the list. A latch already cleared is left out."""
        self._latches = {latch.alarm.code: latch for latch in latches
                         if latch.latched.to_ns() > self._cleared.get(latch.alarm.code, 0)}
        return [latch.alarm for latch in self._latches.values() if self.raise_alarm(latch.alarm)]

    def cause_latched(self, code: int) -> bool:
        """Whether the servo's newest status says the cause of its latch ``code`` is still present."""
        latch = self._latches.get(code)
        return latch is not None and latch.present

    def clear(self, detected: Callable[[int], bool]) -> tuple[list[Alarm], list[Alarm]]:
        """Clear every alarm whose cause has gone; ``detected(code)``: the monitor's own view.

        Returns (cleared, kept), each oldest first.
        """
        cleared, kept = [], []
        for code, alarm in list(self._alarms.items()):
            if detected(code) or self.cause_latched(code):
                kept.append(alarm)
                continue
            cleared.append(self._alarms.pop(code))
            latch = self._latches.pop(code, None)
            if latch is not None:
                self._cleared[code] = max(self._cleared.get(code, 0), latch.latched.to_ns())
        return cleared, kept
