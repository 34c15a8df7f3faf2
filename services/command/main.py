"""The command service (middle level): ``Common``, ``Middle`` and ``Ext``, settings, state.

``python -m jara_arm.services.command --arm arm0 --robot iiwa --mode client --connect tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

from jara_arm.schema import codec
from jara_arm.schema.encoding import Encoding
from jara_arm.schema.keys import Service
from jara_arm.schema.messages import STATE_MESSAGE, StateMessage
from jara_arm.schema.operations import COMMON, EXT, MIDDLE, Interface
from jara_arm.services.runtime.arguments import positive_float
from jara_arm.services.runtime.monitor_link import MonitorLink
from jara_arm.services.runtime.service import ArmService, ServiceContext, entry
from jara_arm.services.runtime.wire import Publication

from .cartesian import CartesianFeedback, reach
from .common import CommandCommon
from .core import Core
from .ext import CommandExt
from .feedback import JointFeedback
from .links import CONTROL_TIMEOUT, PLAN_TIMEOUT, SERVO_TIMEOUT, PlannerLink, ServoLink
from .middle import CommandMiddle
from .settings import Settings
from .settings_publisher import SETTINGS_PERIOD, SettingsPublisher
from .state import StateTracker, StateView
from .watch import Watcher

log = logging.getLogger("jara_arm.command")


def state_payload(view: StateView, encoding: Encoding) -> bytes:
    """``StateMessage`` plus the queue length and capacity (extra members are allowed)."""
    body = STATE_MESSAGE.encode(StateMessage(view.bits))
    body.update(queueLength=view.queue_length, queueCapacity=view.capacity)
    return codec.dumps(body, encoding)


#: SCHED_FIFO priority of the heartbeat thread and Zenoh's threads, the command's own work
#: one below; 0 (the default): the normal scheduler. The command's work is what clients ask
#: for, without bound, and every real-time thread of the machine shares one budget that the
#: servo clock needs (``docs/timing.md``, "Real-time budget"). Its hung bound (1.5 s) holds
#: under the normal scheduler on a busy machine.
DEFAULT_RT_PRIORITY = 0


class CommandService(ArmService):
    """``Common``, ``Middle`` and ``Ext`` of one arm, its state and its settings."""

    SERVICE = Service.COMMAND
    REALTIME_PRIORITY = DEFAULT_RT_PRIORITY
    REALTIME_WHAT = "the heartbeat and of Zenoh's threads (the command's own work: one less)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--servo-timeout", type=positive_float, default=SERVO_TIMEOUT, metavar="S",
                            help=f"time the servo has to answer a query [s] (default: {SERVO_TIMEOUT:g})")
        parser.add_argument("--plan-timeout", type=positive_float, default=PLAN_TIMEOUT, metavar="S",
                            help=f"time the planner has to plan one motion [s] (default: {PLAN_TIMEOUT:g})")
        parser.add_argument("--program", default="{arm}.program.yaml", metavar="FILE",
                            help="the program file Ext/teach stores points in; {arm} is the arm's id "
                            "(default: {arm}.program.yaml in the working directory)")

    def start(self, ctx: ServiceContext) -> None:
        session, keys, robot, opts = ctx.session, ctx.keys, ctx.model, ctx.options
        state_pub = ctx.enter(Publication(session, keys.state))
        tracker = StateTracker(lambda v: state_pub.put(state_payload(v, state_pub.encoding)), ctx.health.hung_after)
        watcher = Watcher(session, keys, tracker, ctx.heartbeat().pulse("the state watcher"))
        watcher.start()
        ctx.closing(watcher.stop)
        ctx.watch("the state watcher thread", lambda: watcher.alive)
        servo = ServoLink(session, keys, opts.servo_timeout)
        core = Core(robot, keys, servo, PlannerLink(session, keys, opts.plan_timeout, CONTROL_TIMEOUT),
                    MonitorLink(session, keys), tracker)
        feedback = JointFeedback(tracker, servo)
        cartesian = CartesianFeedback(robot)
        settings = Settings.defaults(robot, reach(cartesian.kinematics))
        settings_pub = SettingsPublisher(session, keys, tracker, robot, settings)
        ctx.closing(settings_pub.close)
        settings_pub.republish()
        ctx.every(SETTINGS_PERIOD, settings_pub.republish)
        ctx.serve(keys.interface(Interface.COMMON), COMMON, CommandCommon(core, feedback), "command-common")
        middle = CommandMiddle(core, settings, feedback, cartesian, settings_pub.changed)
        ctx.serve(keys.interface(Interface.MIDDLE), MIDDLE, middle, "command-middle")
        program = Path(opts.program.replace("{arm}", keys.arm)).resolve()
        ctx.serve(keys.interface(Interface.EXT), EXT, CommandExt(middle, feedback, program), "command-ext")
        alarms = core.monitor.alarm_list()  # a restarted command knows the active alarms at once
        if alarms is not None:
            tracker.on_alarms(alarms)
        ctx.up(f"command up: arm {keys.arm}, robot {robot.name} ({robot.axis_num} axes), "
               f"reach {settings.reach:.3f} m")






PROGRAM = CommandService
run = entry(PROGRAM)
