"""The alarm monitor service: the arm's active alarms, detection across services, reactions.

``python -m jara_arm.services.alarm_monitor --arm arm0 --robot iiwa --mode client --connect tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Sequence

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema.alarms import MONITOR_OPERATIONS
from jara_arm.schema.codec import Reply
from jara_arm.schema.keys import Service
from jara_arm.services.runtime.heartbeat import Heartbeat
from jara_arm.services.runtime.monitor_link import clear_reply, newest_copy
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.rpc import InterfaceServer, ok
from jara_arm.services.runtime.timing import SAME_HOST, Health
from jara_arm.services.runtime.service import announce, depart, run_service, service_session

from .monitor import Monitor

log = logging.getLogger("jara_arm.alarm_monitor")

#: SCHED_FIFO priority of the monitor's threads; 0 (the default): the normal scheduler. Its
#: work grows with the arms and the traffic, and every real-time thread of the machine
#: shares one budget that the servo clock needs (``docs/timing.md``, "Real-time budget");
#: what must act within cycles is decided inside the servo.
DEFAULT_RT_PRIORITY = 0


class MonitorCommon:
    """``getActiveAlarm`` and ``clearAlarms`` at ``Monitor/Common/<op>``; other operations are not served."""

    def __init__(self, monitor: Monitor) -> None:
        self.monitor = monitor

    def clearAlarms(self) -> Reply:
        return clear_reply(*self.monitor.call(self.monitor.clear_now))

    def getActiveAlarm(self) -> Reply:
        return ok(alarms=self.monitor.call(lambda: self.monitor.book.alarms))


def main(conf: zenoh.Config, arm: str, robot: RobotModel, stop: threading.Event,
         health: Health = SAME_HOST, realtime_priority: int = DEFAULT_RT_PRIORITY) -> None:
    with service_session(conf, arm, Service.ALARM_MONITOR) as (session, keys):
        heartbeat = Heartbeat(session, keys, Service.ALARM_MONITOR, realtime_priority, health)
        monitor = Monitor(session, keys, robot, heartbeat.pulse("the alarm monitor loop"), health)
        monitor.take_over(newest_copy(session, keys))  # before its first (empty) list goes out
        monitor.start()
        heartbeat.start()
        server = InterfaceServer(session, keys.monitor_common(), MONITOR_OPERATIONS, MonitorCommon(monitor),
                                 "monitor-rpc")
        # Every thread of the process (Zenoh's that bring the samples in, too): an alarm
        # must not wait for the planner's or anyone's normal-priority work.
        realtime_process(realtime_priority, "alarm monitor")
        token = announce(session, keys, Service.ALARM_MONITOR)
        log.info("alarm monitor up: arm %s, robot %s", arm, robot.name)
        try:
            while not stop.wait(0.2):
                if not monitor.alive:
                    raise RuntimeError("the alarm monitor thread died")
        finally:
            depart(stop, heartbeat, token)
            heartbeat.close()
            server.close()
            monitor.stop()
            log.info("alarm monitor down")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """The monitor's own options (its thresholds are constants: ``detectors.py``)."""
    parser.add_argument("--realtime-priority", type=int, default=DEFAULT_RT_PRIORITY, metavar="N",
                        help="SCHED_FIFO priority of the monitor's threads, 1..99; 0 for normal "
                        f"scheduling (default: {DEFAULT_RT_PRIORITY})")


def run(argv: Sequence[str] | None = None) -> int:
    return run_service(Service.ALARM_MONITOR, __doc__.splitlines()[0], main, argv, add_arguments)
