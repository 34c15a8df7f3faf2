"""The list of active alarms of one arm, and what is known about their causes.

Not thread-safe: the monitor thread alone uses it (the RPC thread hands its
work to that thread).
"""

from __future__ import annotations

from collections.abc import Callable

from jara_arm.schema.alarms import AlarmReport
from jara_arm.schema.types import Alarm, Time


class AlarmBook:
    """Active alarms by code (one per code, the first description wins), oldest first.

    A code may be raised by the monitor's own detectors and reported by other
    services; its cause is present while any of them says so: the detector's
    own state (asked at clear time) or the latest report of each source.
    A source sends its reports again (a lost one must not keep an alarm), so
    the reports of a detection already cleared (``AlarmReport.latched``) are
    ignored: a copy in flight at the clear does not raise the alarm again.
    """

    def __init__(self) -> None:
        self._alarms: dict[int, Alarm] = {}
        self._reported: dict[int, dict[str, AlarmReport]] = {}  # code -> source -> its latest report
        self._cleared: dict[tuple[int, str], int] = {}  # (code, source) -> ``latched`` [ns] of the last cleared

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

    def report(self, report: AlarmReport) -> bool:
        """A service's report: its cause's presence is noted; True if the alarm is new. A report of a
        detection already cleared changes nothing (False)."""
        latched = report.latched.to_ns()
        if latched and latched <= self._cleared.get((report.alarm.code, report.source), 0):
            return False
        self._reported.setdefault(report.alarm.code, {})[report.source] = report
        return self.raise_alarm(report.alarm)

    def cause_reported(self, code: int) -> bool:
        """Whether a service's latest report on ``code`` says its cause is still present."""
        return any(r.present for r in self._reported.get(code, {}).values())

    def forget(self, source: str, since: Time) -> list[int]:
        """Drop what ``source`` reported of detections before ``since`` (a new process of it started then: what
        the old one saw of a cause is no evidence now); the codes whose dropped report said the cause present."""
        present = []
        for code, by_source in self._reported.items():
            report = by_source.get(source)
            if report is not None and report.latched.to_ns() < since.to_ns():
                del by_source[source]
                if report.present:
                    present.append(code)
        return present

    def clear(self, detected: Callable[[int], bool]) -> tuple[list[Alarm], list[Alarm]]:
        """Clear every alarm whose cause has gone; ``detected(code)``: the monitor's own view.

        Returns (cleared, kept), each oldest first.
        """
        cleared, kept = [], []
        for code, alarm in list(self._alarms.items()):
            if detected(code) or self.cause_reported(code):
                kept.append(alarm)
            else:
                cleared.append(self._alarms.pop(code))
                for source, report in self._reported.pop(code, {}).items():
                    key = (code, source)
                    self._cleared[key] = max(self._cleared.get(key, 0), report.latched.to_ns())
        return cleared, kept
