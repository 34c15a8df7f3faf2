"""The servo service (low-level ACT): PyBullet arm, fixed-period loop, ``Servo/Common``.

``python -m jara_arm.services.servo --arm arm0 --robot iiwa --listen tcp/127.0.0.1:7447``
"""

from __future__ import annotations

import argparse
import logging
from collections.abc import Callable, Sequence

from jara_arm.robots import DEFAULT_ROBOT, RobotModel
from jara_arm.robots import robot as robot_model
from jara_arm.schema.alarms import format_code
from jara_arm.schema import codec
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding, Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import JaraArmError, Refusal, WireError
from jara_arm.schema.keys import ArmKeys, Service, check_arm, encoding_of
from jara_arm.schema.motion import MOTION_CONTROL, MOTION_REPLY, TRAJECTORY, MotionAction, MotionReply
from jara_arm.schema.operations import COMMON, OP
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.arguments import obstacle_argument
from jara_arm.services.runtime.monitor_link import MonitorLink, alarm_copy_answer
from jara_arm.services.runtime.rpc import ok
from jara_arm.services.runtime.service import ArmService, ServiceContext, entry

from .clock import DEFAULT_RT_PRIORITY, ServoClock
from .loop import ServoLoop
from .power import NO_MONITOR, ServoPower
from .world_info import WORLD_PERIOD, WorldPublisher, servo_world

log = logging.getLogger("jara_arm.servo")


class ServoCommon:
    """``ManipulatorCommonInterface_Common`` of the low level, one method per IDL operation.

    ``getActiveAlarm`` and ``clearAlarms`` are the alarm monitor's (forwarded);
    without a monitor they fall back to the servo's own latches and say so.
    ``servoON``, ``servoOFF`` and ``clearAlarms`` are :class:`~.power.ServoPower`'s,
    which ``Servo/power`` shares.
    """

    def __init__(self, power: ServoPower) -> None:
        self.loop = power.loop
        self.model = power.loop.model
        self.monitor = power.monitor
        self.power = power

    def clearAlarms(self) -> Reply:
        return self.power.clear()

    def getActiveAlarm(self) -> Reply:
        # A monitor this servo knows is gone or hung is not asked (architecture.md, "Where the servo acts alone").
        reply = None if self.loop.monitor_silent else self.monitor.call(OP.getActiveAlarm)
        if reply is None:
            return ok(f"OK ({NO_MONITOR})", alarms=self.loop.alarms)
        return reply

    def getFeedbackPosJoint(self) -> Reply:
        return ok(pos=tuple(self.loop.fb_pos.tolist()))

    def getManipInfo(self) -> Reply:
        return ok(mInfo=self.model.manip_info)

    def getSoftLimitJoint(self) -> Reply:
        return ok(softLimit=self.loop.soft_limits)

    def getState(self) -> Reply:
        return ok(state=self.loop.state_bits)

    def servoOFF(self) -> Reply:
        return self.power.off()

    def servoON(self) -> Reply:
        return self.power.on()

    def setSoftLimitJoint(self, softLimit: tuple[LimitValue, ...]) -> Reply:
        check_soft_limits(softLimit, self.model)
        why = self.loop.call(lambda: self.loop.set_soft_limits_now(softLimit))
        if why:
            raise Refusal(ReturnCode.STATUS_ERR, f"setSoftLimitJoint refused: {why}")
        return ok()


class ServoMotion:
    """``Servo/trajectory`` and ``Servo/motionControl``: the planner's way into the interpolator."""

    def __init__(self, loop: ServoLoop) -> None:
        self.loop = loop

    def trajectory(self, payload: bytes, encoding: Encoding) -> bytes:
        return self._answer(payload, encoding, lambda: self.loop.submit(
            codec.decode_message(TRAJECTORY, payload, encoding)))

    def control(self, payload: bytes, encoding: Encoding) -> bytes:
        def apply() -> MotionReply:
            req = codec.decode_message(MOTION_CONTROL, payload, encoding)
            return self.loop.motion_control(w.choice(MotionAction, req.action, "action"), req.ratio)
        return self._answer(payload, encoding, apply)

    def _answer(self, payload: bytes, encoding: Encoding, apply: Callable[[], MotionReply]) -> bytes:
        try:
            reply = apply()
        except WireError as exc:
            reply = MotionReply(int(ReturnCode.VALUE_ERR), str(exc), "",
                                self.loop.call(self.loop.motion_progress_now))
        return codec.encode_message(MOTION_REPLY, reply, encoding)


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


class ServoService(ArmService):
    """The servo process: one real-time clock thread for every arm it serves, each arm with its
    loop, ``Servo/Common``, heartbeat and token."""

    SERVICE = Service.SERVO
    REALTIME_PRIORITY = DEFAULT_RT_PRIORITY
    REALTIME_WHAT = "the clock thread (the process's other threads: one less)"

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--with-arm", type=arm_argument, action="append", metavar="ID:ROBOT",
                            help="another arm this process serves, on the same real-time clock thread "
                            "(repeatable; what `jara-arm up` does with several arms)")
        parser.add_argument("--publish-targets", action="store_true",
                            help="publish Servo/posTarget (the command followed each cycle, 1 kHz while the arm "
                            "moves) while someone subscribes: for tests and benches; off, a JARA_ARM/** recorder "
                            "takes the feedback alone")
        parser.add_argument("--obstacle", type=obstacle_argument, action="append", metavar="X,Y,Z,HX,HY,HZ",
                            help="a fixed box in the simulated world: centre and half extents [m] in the "
                            "world frame (repeatable; added to the robot model's own obstacles)")

    def arms(self, arm: str, model: RobotModel, options: argparse.Namespace) -> list[tuple[str, RobotModel]]:
        arms = [(arm, model), *(options.with_arm or ())]
        ids = [a for a, _ in arms]
        if len(set(ids)) != len(ids):
            raise ValueError(f"an arm is given twice: {', '.join(ids)}")
        return arms

    def start(self, ctx: ServiceContext) -> None:
        obstacles = tuple(ctx.options.obstacle or ())
        loops = []
        for arm, model in ctx.arms:
            loop = ServoLoop(model, ctx.session, ArmKeys(arm), obstacles,
                             ctx.heartbeat(arm).pulse("the servo loop"), ctx.health, ctx.options.publish_targets)
            ctx.closing(loop.close)
            loops.append(loop)
        clock = ServoClock(loops, ctx.realtime_priority)
        clock.start()
        ctx.closing(clock.stop)  # stopped before the loops close (the reverse order)
        ctx.watch("the servo clock thread", lambda: clock.alive, lambda: clock.failed)
        ids = [a for a, _ in ctx.arms]
        for loop in loops:
            keys = ArmKeys(loop.arm)
            power = ServoPower(loop, MonitorLink(ctx.session, keys))
            ctx.serve(keys.servo_common(), COMMON, ServoCommon(power), f"servo-rpc-{keys.arm}")
            ctx.serve_key(keys.servo_power, power.answer, f"servo-power-{keys.arm}")
            motion = ServoMotion(loop)
            traj_key, control_key = keys.servo_trajectory, keys.servo_motion_control
            # Control has a worker of its own: a pause never waits behind a long trajectory's decoding.
            ctx.serve_key(traj_key, lambda _k, p, e, k=traj_key, m=motion: (k, m.trajectory(p, e)),
                          f"servo-trajectory-{keys.arm}")
            ctx.serve_key(control_key, lambda _k, p, e, k=control_key, m=motion: (k, m.control(p, e)),
                          f"servo-motion-control-{keys.arm}")
            world = WorldPublisher(ctx.session, keys, servo_world(loop.model, loop.world.obstacles))
            ctx.closing(world.close)
            ctx.serve_key(keys.servo_world, world.answer, f"servo-world-{keys.arm}")
            # Read on the loop's thread, which owns the list; answered by a worker, never by the loop.
            ctx.serve_key(keys.alarm_copy, alarm_copy_answer(lambda lp=loop: lp.call(lp.alarm_state.held_list)),
                          f"servo-alarm-copy-{keys.arm}", encoding_of(keys.alarm_copy))
            ctx.every(WORLD_PERIOD, world.publish)
            if power.refresh():  # a restarted servo knows the active alarms before it says it is up
                log.info("active alarms from the alarm monitor: %s",
                         ", ".join(format_code(a.code) for a in loop.alarm_state.monitor_alarms) or "none",
                         extra={"arm": keys.arm})
            m = loop.model
            ctx.up(f"servo up: arm {keys.arm}, robot {m.name} ({m.axis_num} axes"
                   f"{' + gripper' if m.has_gripper else ''}), cycle {m.cmd_cycle_ms} ms"
                   + (f"; one clock for arms {', '.join(ids)}" if len(ids) > 1 else ""), keys.arm)
            for box in loop.world.obstacles:
                ctx.up(f"obstacle: box at {box.position} m, half extents {box.half_extents} m", keys.arm)


def arm_argument(text: str) -> tuple[str, RobotModel]:
    """argparse type of ``--with-arm``: ``ID:ROBOT``."""
    arm, sep, name = text.partition(":")
    try:
        check_arm(arm)
        return arm, robot_model(name if sep else DEFAULT_ROBOT)
    except JaraArmError as exc:
        raise argparse.ArgumentTypeError(f"{text}: {exc}") from None


PROGRAM = ServoService
run = entry(PROGRAM)
