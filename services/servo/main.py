"""The servo service (low-level ACT): PyBullet arm, fixed-period loop, ``Servo/Common``.

``python -m jara_arm.services.servo --arm arm0 --robot iiwa --listen tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import logging
import threading
from collections.abc import Sequence

import zenoh

from jara_arm.robots import Obstacle, RobotModel, RobotModelError
from jara_arm.schema.codec import Reply
from jara_arm.schema.alarms import format_code
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.heartbeat import Heartbeat
from jara_arm.services.runtime.monitor_link import MonitorLink, clear_reply
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.rpc import InterfaceServer, ok, refuse
from jara_arm.services.runtime.timing import SAME_HOST, Health
from jara_arm.services.runtime.service import announce, depart, run_service, service_session

from .loop import DEFAULT_RT_PRIORITY, ServoLoop

log = logging.getLogger("jara_arm.servo")


#: Comment added to replies made without the alarm monitor.
NO_MONITOR = "the alarm monitor does not answer: the servo's own alarms only"


class ServoCommon:
    """``ManipulatorCommonInterface_Common`` of the low level, one method per IDL operation.

    ``getActiveAlarm`` and ``clearAlarms`` are the alarm monitor's (forwarded);
    without a monitor they fall back to the servo's own latches and say so.
    """

    def __init__(self, loop: ServoLoop, monitor: MonitorLink) -> None:
        self.loop = loop
        self.model = loop.model
        self.monitor = monitor

    def clearAlarms(self) -> Reply:
        reply = self.monitor.call(OP.clearAlarms)
        if reply is None:
            cleared, kept = self.loop.call(self.loop.clear_alarms_now)
            fallback = clear_reply(cleared, kept)
            return Reply(fallback.id, f"{fallback.comment} ({NO_MONITOR})")
        self.refresh()  # the latches the monitor cleared are released before the reply
        return reply

    def getActiveAlarm(self) -> Reply:
        reply = self.monitor.call(OP.getActiveAlarm)
        if reply is None:
            return ok(f"OK ({NO_MONITOR})", alarms=self.loop.alarms)
        return reply

    def refresh(self) -> bool:
        """Adopt the monitor's current list now (not when its publication arrives); False if silent."""
        alarms = self.monitor.alarm_list()
        if alarms is None:
            return False
        self.loop.call(lambda: self.loop.adopt_monitor_list(alarms))
        return True

    def getFeedbackPosJoint(self) -> Reply:
        return ok(pos=tuple(self.loop.fb_pos.tolist()))

    def getManipInfo(self) -> Reply:
        return ok(mInfo=self.model.manip_info)

    def getSoftLimitJoint(self) -> Reply:
        return ok(softLimit=self.loop.soft_limits)

    def getState(self) -> Reply:
        return ok(state=self.loop.state_bits)

    def servoOFF(self) -> Reply:
        self.loop.call(self.loop.servo_off_now)
        return ok()

    def servoON(self) -> Reply:
        why = self.loop.call(self.loop.servo_on_now)
        if why and self.loop.monitor_alarms and self.refresh():
            why = self.loop.call(self.loop.servo_on_now)  # alarms just cleared through another interface
        return refuse(ReturnCode.STATUS_ERR, f"servoON refused: {why}") if why else ok()

    def setSoftLimitJoint(self, softLimit: tuple[LimitValue, ...]) -> Reply:
        check_soft_limits(softLimit, self.model)
        why = self.loop.call(lambda: self.loop.set_soft_limits_now(softLimit))
        return refuse(ReturnCode.STATUS_ERR, f"setSoftLimitJoint refused: {why}") if why else ok()


def check_soft_limits(limits: Sequence[LimitValue], model: RobotModel) -> None:
    """WireError (VALUE_ERR) unless one ``lower < upper`` per axis, inside the hard limits."""
    if len(limits) != model.axis_num:
        raise WireError("softLimit", f"expected {model.axis_num} entries (one per axis, "
                        f"gripper excluded), got {len(limits)}")
    for i, (lim, hard) in enumerate(zip(limits, model.hard_limits)):
        if not lim.lower < lim.upper:
            raise WireError(f"softLimit[{i}]", f"lower {lim.lower} must be below upper {lim.upper}")
        if lim.lower < hard.lower or lim.upper > hard.upper:
            raise WireError(f"softLimit[{i}]", f"[{lim.lower}, {lim.upper}] leaves the hard limits "
                            f"[{hard.lower}, {hard.upper}] of J{i + 1}")


def main(conf: zenoh.Config, arm: str, robot: RobotModel, stop: threading.Event,
         health: Health = SAME_HOST, realtime_priority: int = DEFAULT_RT_PRIORITY,
         obstacle: Sequence[Obstacle] | None = None) -> None:
    with service_session(conf, arm, Service.SERVO) as (session, keys):
        heartbeat = Heartbeat(session, keys, Service.SERVO, max(0, realtime_priority - 1), health)
        loop = ServoLoop(robot, session, keys, realtime_priority, tuple(obstacle or ()),
                         heartbeat.pulse("the servo loop"), health)
        loop.start()
        heartbeat.start()
        common = ServoCommon(loop, MonitorLink(session, keys))
        server = InterfaceServer(session, keys.servo_common(), COMMON, common, "servo-rpc")
        if common.refresh():  # a restarted servo knows the active alarms before it says it is up
            log.info("active alarms from the alarm monitor: %s",
                     ", ".join(format_code(a.code) for a in loop.monitor_alarms) or "none")
        token = announce(session, keys, Service.SERVO)
        # Zenoh's receive threads feed the FIFO: starved, they make it run dry.
        realtime_process(max(0, realtime_priority - 1), "servo")
        log.info("servo up: arm %s, robot %s (%d axes%s), cycle %d ms", arm, robot.name,
                 robot.axis_num, " + gripper" if robot.has_gripper else "", robot.cmd_cycle_ms)
        for box in loop.world.obstacles:
            log.info("obstacle: box at %s m, half extents %s m", box.position, box.half_extents)
        try:
            while not stop.wait(0.2):
                if not loop.alive:
                    raise RuntimeError("the servo loop thread died")
        finally:
            depart(stop, heartbeat, token)
            heartbeat.close()
            server.close()
            loop.stop()
            log.info("servo down")
    server.join()


def obstacle_argument(text: str) -> Obstacle:
    """argparse type of ``--obstacle``: ``x,y,z,hx,hy,hz`` [m]."""
    try:
        return Obstacle.parse(text)
    except RobotModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--realtime-priority", type=int, default=DEFAULT_RT_PRIORITY,
                        metavar="N", help="SCHED_FIFO priority of the loop thread, 1..99; 0 for "
                        f"normal scheduling (default: {DEFAULT_RT_PRIORITY})")
    parser.add_argument("--obstacle", type=obstacle_argument, action="append", metavar="X,Y,Z,HX,HY,HZ",
                        help="a fixed box in the simulated world: centre and half extents [m] in the "
                        "world frame (repeatable; added to the robot model's own obstacles)")


def run(argv: Sequence[str] | None = None) -> int:
    return run_service(Service.SERVO, __doc__.splitlines()[0], main, argv, add_arguments)
