"""The command service (middle level): ``Common`` and ``Middle``, settings, motion queue, state.

``python -m jara_arm.services.command --arm arm0 --robot iiwa --mode client --connect tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Sequence

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema import codec
from jara_arm.schema.keys import Service
from jara_arm.schema.messages import STATE_MESSAGE, StateMessage
from jara_arm.schema.operations import COMMON, MIDDLE, Interface
from jara_arm.services.runtime.heartbeat import Heartbeat
from jara_arm.services.runtime.monitor_link import MonitorLink
from jara_arm.services.runtime.realtime import realtime_process, realtime_thread
from jara_arm.services.runtime.rpc import InterfaceServer
from jara_arm.services.runtime.timing import SAME_HOST, Health
from jara_arm.services.runtime.service import announce, depart, run_service, service_session

from .cartesian import CartesianFeedback, reach
from .common import CommandCommon
from .core import Core
from .feedback import JointFeedback
from .settings_publisher import SETTINGS_PERIOD, SettingsPublisher
from .links import CONTROL_TIMEOUT, PLAN_TIMEOUT, SERVO_TIMEOUT, PlannerLink, ServoLink
from .middle import CommandMiddle
from .queue import DEFAULT_CAPACITY, MotionQueue
from .settings import Settings
from .state import StateTracker, StateView
from .watch import Watcher

log = logging.getLogger("jara_arm.command")


def state_payload(view: StateView) -> bytes:
    """``StateMessage`` plus the queue length and capacity (extra members are allowed)."""
    body = STATE_MESSAGE.encode(StateMessage(view.bits))
    body.update(queueLength=view.queue_length, queueCapacity=view.capacity)
    return codec.dumps(body)


#: SCHED_FIFO priority of the heartbeat thread and Zenoh's threads, the command's own work
#: one below; 0 (the default): the normal scheduler. The command's work is what clients ask
#: for, without bound, and every real-time thread of the machine shares one budget that the
#: servo clock needs (``docs/timing.md``, "Real-time budget"). Its hung bound (1.5 s) holds
#: under the normal scheduler on a busy machine.
DEFAULT_RT_PRIORITY = 0


def main(conf: zenoh.Config, arm: str, robot: RobotModel, stop: threading.Event,
         queue_capacity: int = DEFAULT_CAPACITY, servo_timeout: float = SERVO_TIMEOUT,
         plan_timeout: float = PLAN_TIMEOUT, realtime_priority: int = DEFAULT_RT_PRIORITY,
         health: Health = SAME_HOST) -> None:
    with service_session(conf, arm, Service.COMMAND) as (session, keys):
        # Only Zenoh's threads exist yet: they carry the heartbeat out; a busy machine
        # must not delay it into a hung alarm. The threads started from here on inherit
        # the main thread's priority.
        realtime_process(realtime_priority, "command (Zenoh's threads)", skip_caller=True)
        realtime_thread(max(0, realtime_priority - 1), "command (its own work)")
        heartbeat = Heartbeat(session, keys, Service.COMMAND, realtime_priority, health)
        main_pulse = heartbeat.pulse("the command's main loop")
        heartbeat.start()
        state_pub = session.declare_publisher(keys.state)
        tracker = StateTracker(MotionQueue(queue_capacity), lambda v: state_pub.put(state_payload(v)))
        watcher = Watcher(session, keys, tracker, heartbeat.pulse("the state watcher"))
        watcher.start()
        servo = ServoLink(session, keys, servo_timeout)
        core = Core(robot, keys, servo, PlannerLink(session, keys, plan_timeout, CONTROL_TIMEOUT),
                    MonitorLink(session, keys), tracker)
        feedback = JointFeedback(tracker, servo)
        cartesian = CartesianFeedback(robot)
        settings = Settings.defaults(robot, reach(cartesian.kinematics))
        settings_pub = SettingsPublisher(session, keys, tracker, robot, settings)
        settings_pub.republish()
        common = InterfaceServer(session, keys.interface(Interface.COMMON), COMMON, CommandCommon(core, feedback),
                                 "command-common")
        middle = InterfaceServer(session, keys.interface(Interface.MIDDLE), MIDDLE,
                                 CommandMiddle(core, settings, feedback, cartesian, settings_pub.changed),
                                 "command-middle")
        alarms = core.monitor.alarm_list()  # a restarted command knows the active alarms at once
        if alarms is not None:
            tracker.on_alarms(alarms)
        token = announce(session, keys, Service.COMMAND)
        log.info("command up: arm %s, robot %s (%d axes), queue capacity %d, reach %.3f m", arm,
                 robot.name, robot.axis_num, queue_capacity, settings.reach)
        try:
            while not stop.wait(SETTINGS_PERIOD):
                main_pulse.beat()
                if not watcher.alive:
                    raise RuntimeError("the state watcher thread died")
                settings_pub.republish()
        finally:
            depart(stop, heartbeat, token)
            heartbeat.close()
            common.close()
            middle.close()
            watcher.stop()
            settings_pub.close()
            state_pub.undeclare()
            log.info("command down")
    common.join()
    middle.join()


def _positive_int(text: str) -> int:
    try:
        value = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {text!r}") from None
    if value < 1:
        raise argparse.ArgumentTypeError(f"expected a positive integer, got {value}")
    return value


def _positive_seconds(text: str) -> float:
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected seconds, got {text!r}") from None
    if not value > 0.0:
        raise argparse.ArgumentTypeError(f"expected a positive number of seconds, got {value}")
    return value


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--queue-capacity", type=_positive_int, default=DEFAULT_CAPACITY, metavar="N",
                        help=f"motions the queue holds before FULL_MOTION_QUEUE_ERR "
                        f"(default: {DEFAULT_CAPACITY})")
    parser.add_argument("--servo-timeout", type=_positive_seconds, default=SERVO_TIMEOUT, metavar="S",
                        help=f"time the servo has to answer a query [s] (default: {SERVO_TIMEOUT:g})")
    parser.add_argument("--realtime-priority", type=int, default=DEFAULT_RT_PRIORITY, metavar="N",
                        help="SCHED_FIFO priority of the heartbeat and of Zenoh's threads, 1..99; 0 for "
                        f"normal scheduling (default: {DEFAULT_RT_PRIORITY})")
    parser.add_argument("--plan-timeout", type=_positive_seconds, default=PLAN_TIMEOUT, metavar="S",
                        help=f"time the planner has to plan one motion [s] (default: {PLAN_TIMEOUT:g})")


def run(argv: Sequence[str] | None = None) -> int:
    return run_service(Service.COMMAND, __doc__.splitlines()[0], main, argv, add_arguments)
