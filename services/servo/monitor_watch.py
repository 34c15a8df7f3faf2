"""The servo's watch of the alarm monitor: nobody else can watch the watcher.

Without the monitor nothing watches overload, overspeed, the Cartesian box or
the other services, so the servo stops the arm when the monitor is gone
(``MONITOR_LOST``, its liveliness token deleted) or hangs (``MONITOR_HUNG``,
no heartbeat for ``Health.hung_after`` while its token is up). A shorter
silence is a stall: logged, not an alarm (``docs/timing.md``).

It runs on the servo clock's thread, once per cycle, and only polls Zenoh
channels; what it finds comes back as a :class:`Finding` for the loop to act on.
"""

from __future__ import annotations

import dataclasses
import time

import zenoh

from jara_arm.schema.codes import AlarmCode
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.services.runtime.heartbeat import ServiceWatch
from jara_arm.services.runtime.presence import Change, Presence
from jara_arm.services.runtime.timing import Health


@dataclasses.dataclass(frozen=True)
class Finding:
    """What one look at the monitor found: an alarm to raise (a FAULT), or a line to log."""

    alarm: AlarmCode | None = None
    description: str = ""
    warning: str = ""  # a stall that ended, or a malformed heartbeat
    error: str = ""


class MonitorWatch:
    """The alarm monitor's liveliness token and heartbeat, as seen from one arm's servo loop."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, health: Health) -> None:
        self.health = health
        self._watch = ServiceWatch(Service.ALARM_MONITOR, health)
        # Polled once per cycle: nothing to wake. Token and beats in one box, in arrival order.
        self._presence = Presence(session, keys, {Service.ALARM_MONITOR: self._watch})
        self._looked_at = time.monotonic()  # [s] the previous look
        self._judge_after = 0.0  # [s] monotonic: the monitor's silence counts from then on

    def look(self, hung_latched: bool) -> list[Finding]:
        """Drain what arrived; ``hung_latched``: MONITOR_HUNG is latched already (not raised again)."""
        found: list[Finding] = []
        now = time.monotonic()
        if now - self._looked_at > self.health.stall_after:
            # This loop was held up: the beats still in Zenoh's queue come first.
            self._judge_after = now + self.health.heartbeat_period
        self._looked_at = now
        watch = self._watch
        for event in self._presence.drain(now):
            if event.change in (Change.LEFT, Change.LOST):
                # Even in order: nothing would watch overload, overspeed or the other services.
                why = ("it shut down in order" if event.change is Change.LEFT
                       else "its liveliness token was deleted (process ended or unreachable)")
                found.append(Finding(AlarmCode.MONITOR_LOST, f"the alarm monitor is gone: {why}"))
            elif event.change is Change.STALL:
                found.append(Finding(warning=watch.stall_line(event.gap)))
            elif event.change is Change.MALFORMED:
                found.append(Finding(error=f"ignored a malformed heartbeat of the alarm monitor: {event.error}"))
        if now >= self._judge_after and not hung_latched and watch.hung(now):
            found.append(Finding(AlarmCode.MONITOR_HUNG,
                                 f"the alarm monitor hangs while its liveliness token is up: {watch.why_hung(now)}"))
        elif (line := watch.evidence_line(now)) is not None:
            found.append(Finding(warning=line))
        return found

    @property
    def alive(self) -> bool:
        """Its liveliness token is up."""
        return self._watch.alive

    def hung(self) -> bool:
        """Silent past the hung bound while its token is up."""
        return self._watch.hung(time.monotonic())

    def close(self) -> None:
        self._presence.close()
