"""The alarm monitor service: the arm's active alarms, detection across services, reactions.

``python -m jara_arm.services.alarm_monitor --arm arm0 --robot iiwa --mode client --connect tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import logging

from jara_arm.schema import codec
from jara_arm.schema.alarms import ALARM_LIST, MONITOR_OPERATIONS
from jara_arm.schema.codec import Reply
from jara_arm.schema.keys import Service, encoding_of
from jara_arm.services.runtime.monitor_link import clear_reply, servo_copy
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.rpc import ok
from jara_arm.services.runtime.service import ArmService, ServiceContext, entry

from .monitor import Monitor

log = logging.getLogger("jara_arm.alarm_monitor")

#: SCHED_FIFO priority of the monitor's threads (0: the normal scheduler): below the servo clock
#: (40), the cell bus (35) and the planner (29). Under the normal scheduler, with a busy loop on every
#: core and 4 arms, the real-time threads left the monitors without a CPU for up to 12 s (their
#: loops stood still, overload and overspeed unwatched); at 20 its longest pause was under 1 s and
#: the servo's late cycles fell too (``docs/timing.md``, "Real-time budget"). Its work is bounded
#: by the arm's own traffic (100 statuses a second), not by clients: nothing a client sends reaches it.
DEFAULT_RT_PRIORITY = 20


class MonitorCommon:
    """``getActiveAlarm`` and ``clearAlarms`` at ``Monitor/Common/<op>``; other operations are not served."""

    def __init__(self, monitor: Monitor) -> None:
        self.monitor = monitor

    def clearAlarms(self) -> Reply:
        return clear_reply(*self.monitor.call(self.monitor.clear_now))

    def getActiveAlarm(self) -> Reply:
        return ok(alarms=self.monitor.call(lambda: self.monitor.book.alarms))


class AlarmMonitorService(ArmService):
    """The arm's active alarms: detection across services, reactions, ``Monitor/Common``."""

    SERVICE = Service.ALARM_MONITOR
    REALTIME_PRIORITY = DEFAULT_RT_PRIORITY
    REALTIME_WHAT = "the monitor's threads (its thresholds are constants: detectors.py)"

    def start(self, ctx: ServiceContext) -> None:
        monitor = Monitor(ctx.session, ctx.keys, ctx.model, ctx.heartbeat().pulse("the alarm monitor loop"),
                          ctx.health)
        monitor.take_over(servo_copy(ctx.session, ctx.keys))  # before its first (empty) list goes out
        monitor.start()
        ctx.closing(monitor.stop)
        ctx.watch("the alarm monitor thread", lambda: monitor.alive)
        ctx.serve(ctx.keys.monitor_common(), MONITOR_OPERATIONS, MonitorCommon(monitor), "monitor-rpc")
        # Made on the monitor's thread, after the reports that came before the query (Monitor.call).
        ctx.serve_key(ctx.keys.monitor_alarms, lambda key, _p, encoding: (
            key, codec.encode_message(ALARM_LIST, monitor.call(monitor.alarm_list), encoding)), "monitor-alarms",
            encoding_of(ctx.keys.monitor_alarms))
        # Every thread of the process (Zenoh's that bring the samples in, too) at the monitor's
        # priority: an alarm must not wait for the planner's or anyone's normal-priority work.
        realtime_process(ctx.realtime_priority, "alarm monitor")
        ctx.up(f"alarm monitor up: arm {ctx.keys.arm}, robot {ctx.model.name}")


PROGRAM = AlarmMonitorService
run = entry(PROGRAM)
