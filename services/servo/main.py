"""The servo service (low-level ACT): PyBullet arm, fixed-period loop, ``Servo/Common``.

``python -m jara_arm.services.servo --arm arm0 --robot iiwa --listen tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import threading
from collections.abc import Sequence

import zenoh

from jara_arm.robots import DEFAULT_ROBOT, Obstacle, RobotModel, RobotModelError
from jara_arm.robots import robot as robot_model
from jara_arm.schema.codec import Reply
from jara_arm.schema.alarms import format_code
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import JaraArmError, WireError
from jara_arm.schema.keys import ArmKeys, Service, check_arm
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.heartbeat import Heartbeat
from jara_arm.services.runtime.monitor_link import MonitorLink, clear_reply
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.rpc import InterfaceServer, ok, refuse
from jara_arm.services.runtime.timing import SAME_HOST, Health
from jara_arm.services.runtime.service import announce, depart, run_service, service_session

from .clock import DEFAULT_RT_PRIORITY, ServoClock
from .loop import ServoLoop

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


@dataclasses.dataclass
class _ArmServo:
    """One arm's part of the servo process: its loop, heartbeat, interface and token."""

    keys: ArmKeys
    loop: ServoLoop
    heartbeat: Heartbeat
    server: InterfaceServer | None = None
    token: zenoh.LivelinessToken | None = None


def main(conf: zenoh.Config, arm: str, robot: RobotModel, stop: threading.Event,
         health: Health = SAME_HOST, realtime_priority: int = DEFAULT_RT_PRIORITY,
         obstacle: Sequence[Obstacle] | None = None,
         with_arm: Sequence[tuple[str, RobotModel]] | None = None) -> None:
    """The servo of ``arm`` and of every ``with_arm``: one process, one real-time clock thread."""
    arms = [(arm, robot), *(with_arm or ())]
    ids = [a for a, _ in arms]
    if len(set(ids)) != len(ids):
        raise ValueError(f"an arm is given twice: {', '.join(ids)}")
    with service_session(conf, arm, Service.SERVO, also=tuple(ids)) as (session, _):
        parts = []
        for arm_id, model in arms:
            keys = ArmKeys(arm_id)
            heartbeat = Heartbeat(session, keys, Service.SERVO, max(0, realtime_priority - 1), health)
            loop = ServoLoop(model, session, keys, tuple(obstacle or ()), heartbeat.pulse("the servo loop"),
                             health)
            parts.append(_ArmServo(keys, loop, heartbeat))
        clock = ServoClock([p.loop for p in parts], realtime_priority)
        clock.start()
        for p in parts:
            p.heartbeat.start()
            common = ServoCommon(p.loop, MonitorLink(session, p.keys))
            p.server = InterfaceServer(session, p.keys.servo_common(), COMMON, common,
                                       f"servo-rpc-{p.keys.arm}")
            if common.refresh():  # a restarted servo knows the active alarms before it says it is up
                log.info("active alarms from the alarm monitor: %s",
                         ", ".join(format_code(a.code) for a in p.loop.monitor_alarms) or "none",
                         extra={"arm": p.keys.arm})
            p.token = announce(session, p.keys, Service.SERVO)
        # Zenoh's receive threads feed the FIFO: starved, they make it run dry.
        realtime_process(max(0, realtime_priority - 1), "servo")
        for p in parts:
            m = p.loop.model
            log.info("servo up: arm %s, robot %s (%d axes%s), cycle %d ms%s", p.keys.arm, m.name, m.axis_num,
                     " + gripper" if m.has_gripper else "", m.cmd_cycle_ms,
                     f"; one clock for arms {', '.join(ids)}" if len(ids) > 1 else "", extra={"arm": p.keys.arm})
            for box in p.loop.world.obstacles:
                log.info("obstacle: box at %s m, half extents %s m", box.position, box.half_extents,
                         extra={"arm": p.keys.arm})
        try:
            while not stop.wait(0.2):
                if not clock.alive:
                    raise RuntimeError("the servo clock thread died") from clock.failed
        finally:
            for p in parts:
                if p.token is not None:
                    depart(stop, p.heartbeat, p.token)
            for p in parts:
                p.heartbeat.close()
                if p.server is not None:
                    p.server.close()
            clock.stop()
            for p in parts:
                p.loop.close()
            log.info("servo down")
    for p in parts:
        if p.server is not None:
            p.server.join()


def arm_argument(text: str) -> tuple[str, RobotModel]:
    """argparse type of ``--with-arm``: ``ID:ROBOT``."""
    arm, sep, name = text.partition(":")
    try:
        check_arm(arm)
        return arm, robot_model(name if sep else DEFAULT_ROBOT)
    except JaraArmError as exc:
        raise argparse.ArgumentTypeError(f"{text}: {exc}") from None


def obstacle_argument(text: str) -> Obstacle:
    """argparse type of ``--obstacle``: ``x,y,z,hx,hy,hz`` [m]."""
    try:
        return Obstacle.parse(text)
    except RobotModelError as exc:
        raise argparse.ArgumentTypeError(str(exc)) from None


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--realtime-priority", type=int, default=DEFAULT_RT_PRIORITY,
                        metavar="N", help="SCHED_FIFO priority of the clock thread, 1..99; 0 for "
                        f"normal scheduling (default: {DEFAULT_RT_PRIORITY})")
    parser.add_argument("--with-arm", type=arm_argument, action="append", metavar="ID:ROBOT",
                        help="another arm this process serves, on the same real-time clock thread "
                        "(repeatable; what `jara-arm up` does with several arms)")
    parser.add_argument("--obstacle", type=obstacle_argument, action="append", metavar="X,Y,Z,HX,HY,HZ",
                        help="a fixed box in the simulated world: centre and half extents [m] in the "
                        "world frame (repeatable; added to the robot model's own obstacles)")


def run(argv: Sequence[str] | None = None) -> int:
    return run_service(Service.SERVO, __doc__.splitlines()[0], main, argv, add_arguments)
