"""``ManipulatorCommonInterface_Middle``, one method per IDL operation.

Settings live in a frozen :class:`Settings` value that each setter replaces
(``settings.py``: validation and defaults). Motion commands are checked against
the state here and planned by the planner service (``schema/planner.py``);
pause, resume and stop go to the planner's control.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable
from typing import Any

from jara_arm.schema.codec import Reply, encode_args
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal
from jara_arm.schema.messages import NO_STATUS
from jara_arm.schema.operations import MIDDLE, OP
from jara_arm.schema.planner import ControlAction, MotionRequest
from jara_arm.schema.types import CarPosWithElbow, CartesianSpeed, HgMatrix, JointPos, LimitValue
from jara_arm.services.runtime.rpc import ok
from jara_arm.services.runtime.timing import STATUS_LISTEN

from .cartesian import CartesianFeedback
from .core import Core
from .feedback import JointFeedback
from .settings import Settings
from .state import StateView

log = logging.getLogger(__name__)

#: LIN and CIRC move in Cartesian space and use the Cartesian speed ratio. Every other
#: motion -- PTP joint, PTP Cartesian (joint-interpolated), goHome (a joint PTP) and the
#: gripper commands (a joint axis) -- uses the joint speed ratio.
CARTESIAN_RATIO_OPS = frozenset({
    OP.moveLinearCartesianAbs, OP.moveLinearCartesianRel,
    OP.moveCircularCartesianAbs, OP.moveCircularCartesianRel,
})
#: Full opening of ``moveGripper`` [%].
MAX_GRIPPER_RATIO = 100


def refuse_unless_ready(view: StateView, name: str) -> None:
    """Raise the refusal of ``name`` (a motion or a jog) if the arm cannot move now: servo off or an alarm."""
    if not view.servo_on:
        why = ("the servo is off: call servoON first" if view.servo_heard else
               "no Servo/status from the servo service: is it running?")
        raise Refusal(ReturnCode.NOT_SV_ON_ERR, f"{name} refused: {why}")
    if view.alarm:
        raise Refusal(ReturnCode.STATUS_ERR, f"{name} refused: an alarm is active "
                      f"({OP.getActiveAlarm}, then {OP.clearAlarms} and {OP.servoON})")


class CommandMiddle:
    """The Middle interface at ``JARA_ARM/<arm>/Middle/<op>``; runs on one RPC thread."""

    def __init__(self, core: Core, settings: Settings, feedback: JointFeedback,
                 cartesian: CartesianFeedback,
                 on_settings: Callable[[Settings], None] | None = None) -> None:
        self.core = core
        self._on_settings = on_settings
        self._settings = settings
        self._settings_lock = threading.Lock()  # Ext's setters change the settings from another thread
        self._feedback = feedback
        self._cartesian = cartesian  # used on this interface's RPC thread only

    @property
    def settings(self) -> Settings:
        return self._settings

    @settings.setter
    def settings(self, value: Settings) -> None:
        """Every setter replaces the settings here; ``on_settings`` hears of each change."""
        changed = value is not self._settings
        self._settings = value
        if changed and self._on_settings is not None:
            self._on_settings(value)

    def change_settings(self, change: Callable[[Settings], Settings]) -> None:
        """``settings = change(settings)`` as one step for every thread (Middle's and Ext's setters);
        a WireError from ``change`` leaves them as they were."""
        with self._settings_lock:
            self.settings = change(self.settings)

    # -- motions ------------------------------------------------------------------
    def movePTPJointAbs(self, jointPoints: JointPos) -> Reply:
        return self._motion(OP.movePTPJointAbs, jointPoints=jointPoints)

    def movePTPJointRel(self, jointPoints: JointPos) -> Reply:
        return self._motion(OP.movePTPJointRel, jointPoints=jointPoints)

    def movePTPCartesianAbs(self, carPoint: CarPosWithElbow) -> Reply:
        return self._motion(OP.movePTPCartesianAbs, carPoint=carPoint)

    def movePTPCartesianRel(self, carPoint: CarPosWithElbow) -> Reply:
        return self._motion(OP.movePTPCartesianRel, carPoint=carPoint)

    def moveLinearCartesianAbs(self, carPoint: CarPosWithElbow) -> Reply:
        return self._motion(OP.moveLinearCartesianAbs, carPoint=carPoint)

    def moveLinearCartesianRel(self, carPoint: CarPosWithElbow) -> Reply:
        return self._motion(OP.moveLinearCartesianRel, carPoint=carPoint)

    def moveCircularCartesianAbs(self, carPointR: CarPosWithElbow, carPointT: CarPosWithElbow) -> Reply:
        return self._motion(OP.moveCircularCartesianAbs, carPointR=carPointR, carPointT=carPointT)

    def moveCircularCartesianRel(self, carPointR: CarPosWithElbow, carPointT: CarPosWithElbow) -> Reply:
        return self._motion(OP.moveCircularCartesianRel, carPointR=carPointR, carPointT=carPointT)

    def goHome(self) -> Reply:
        return self._motion(OP.goHome)

    def moveGripper(self, angleRatio: int) -> Reply:
        return self._motion(OP.moveGripper, angleRatio=angleRatio)

    def openGripper(self) -> Reply:
        return self._motion(OP.openGripper)

    def closeGripper(self) -> Reply:
        return self._motion(OP.closeGripper)

    def _motion(self, name: str, **args: Any) -> Reply:
        """Check the state, then have the planner check the geometry and queue the motion."""
        core = self.core
        op = MIDDLE[name]
        with core.serial:
            view = core.state.view(listen=STATUS_LISTEN)
            # The order of the refusals is DECISIONS.md's: state first, values last.
            refuse_unless_ready(view, name)
            # The speed ratio starts at 0 % (specification): until it is set, nothing may move.
            if name in CARTESIAN_RATIO_OPS:
                ratio, setter = self.settings.spd_ratio_cartesian, OP.setSpeedCartesian
            else:
                ratio, setter = self.settings.spd_ratio_joint, OP.setSpeedJoint
            if ratio == 0:
                raise Refusal(ReturnCode.STATUS_ERR, f"{name} refused: the speed ratio is 0 %; "
                              f"set it with {setter}")
            if view.full:
                raise Refusal(ReturnCode.FULL_MOTION_QUEUE_ERR, f"{name} refused: the motion queue "
                              f"holds {view.queue_length} of {view.capacity} motions")
            if "jointPoints" in args:
                self.settings.check_joint_points("jointPoints", args["jointPoints"])
            if "angleRatio" in args and args["angleRatio"] > MAX_GRIPPER_RATIO:
                raise Refusal(ReturnCode.VALUE_ERR, f"angleRatio: {args['angleRatio']} % is above "
                              f"{MAX_GRIPPER_RATIO} %")
            limits = core.servo.call(OP.getSoftLimitJoint)  # the servo's, as they are now
            if not limits.ok:
                raise Refusal(ReturnCode.NG, f"{name} refused: joint soft limits unavailable: "
                              f"{limits.comment}")
            # In wire form for Planner/plan (another process): the planner decodes them once (planner/request.py).
            # With the servo's newest status the command holds: the planner may not have heard of a servoON yet.
            request = MotionRequest(name, encode_args(op, args), self.settings.snapshot(limits["softLimit"]),
                                    core.state.servo_status() or NO_STATUS)
            answer = core.planner.plan(request)
            core.state.on_progress(answer.progress)  # the queue as it is now, before serial is let go
            if answer.reply.ok:
                log.debug("motion %d %s queued", answer.motion, name)
            else:
                log.info("%s refused by the planner: %s", name, answer.reply.comment)
            return answer.reply

    # -- pause, resume, stop ----------------------------------------------------------
    def pause(self) -> Reply:
        """Ignored (OK, says so) when servo off, alarmed, already paused or not moving."""
        core = self.core
        with core.serial:
            view = core.state.view()
            why = ("the servo is off" if not view.servo_on else "an alarm is active" if view.alarm
                   else "already paused" if view.paused else "not moving" if not view.moving else "")
            if why:
                return ok(f"{OP.pause} ignored: {why}")
            return self._control(ControlAction.PAUSE)

    def resume(self) -> Reply:
        """Ignored (OK, says so) unless paused."""
        core = self.core
        with core.serial:
            if not core.state.view().paused:
                return ok(f"{OP.resume} ignored: not paused")
            return self._control(ControlAction.RESUME)

    def stop(self) -> Reply:
        """Ignored (OK, says so) when servo off or alarmed; else the queue and the pause go."""
        core = self.core
        with core.serial:
            view = core.state.view()
            if not view.servo_on or view.alarm:
                why = "the servo is off" if not view.servo_on else "an alarm is active"
                return ok(f"{OP.stop} ignored: {why}")
            return self._control(ControlAction.STOP)

    def _control(self, action: ControlAction) -> Reply:
        answer = self.core.planner.control(action)
        self.core.state.on_progress(answer.progress)  # getState read next shows it
        return answer.reply

    # -- feedback -------------------------------------------------------------------------
    def getFeedbackPosCartesian(self) -> Reply:
        """Control point ``inv(B) · T_flange · C`` of the newest joint feedback."""
        joints = self._feedback.joints()
        if not joints.ok:
            return joints
        s = self.settings
        return ok(pos=self._cartesian.pose(joints["pos"], s.base_offset, s.control_point_offset))

    # -- speeds -----------------------------------------------------------------------
    def getMaxSpeedCartesian(self) -> Reply:
        return ok(speed=self.settings.max_speed_cartesian)

    def setMaxSpeedCartesian(self, speed: CartesianSpeed) -> Reply:
        self.change_settings(lambda s: s.with_max_speed_cartesian(speed))
        return ok()

    def getMaxSpeedJoint(self) -> Reply:
        return ok(speed=self.settings.max_speed_joint)

    def setMaxSpeedJoint(self, speed: tuple[float, ...]) -> Reply:
        self.change_settings(lambda s: s.with_max_speed_joint(speed))
        return ok()

    def setSpeedCartesian(self, spdRatio: int) -> Reply:
        self.change_settings(lambda s: s.with_speed_cartesian(spdRatio))
        return ok()

    def setSpeedJoint(self, spdRatio: int) -> Reply:
        self.change_settings(lambda s: s.with_speed_joint(spdRatio))
        return ok()

    # -- acceleration times -------------------------------------------------------------
    def getMinAccelTimeCartesian(self) -> Reply:
        return ok(aclTime=self.settings.min_accel_time_cartesian)

    def setMinAccelTimeCartesian(self, aclTime: float) -> Reply:
        self.change_settings(lambda s: s.with_min_accel_time_cartesian(aclTime))
        return ok()

    def getMinAccelTimeJoint(self) -> Reply:
        return ok(aclTime=self.settings.min_accel_time_joint)

    def setMinAccelTimeJoint(self, aclTime: float) -> Reply:
        self.change_settings(lambda s: s.with_min_accel_time_joint(aclTime))
        return ok()

    def setAccelTimeCartesian(self, aclTime: float) -> Reply:
        self.change_settings(lambda s: s.with_accel_time_cartesian(aclTime))
        return ok()

    def setAccelTimeJoint(self, aclTime: float) -> Reply:
        self.change_settings(lambda s: s.with_accel_time_joint(aclTime))
        return ok()

    # -- limits and frames ------------------------------------------------------------------
    def getSoftLimitCartesian(self) -> Reply:
        x, y, z = self.settings.cartesian_limits
        return ok(xLimit=x, yLimit=y, zLimit=z)

    def setSoftLimitCartesian(self, xLimit: LimitValue, yLimit: LimitValue, zLimit: LimitValue) -> Reply:
        self.change_settings(lambda s: s.with_soft_limit_cartesian(xLimit, yLimit, zLimit))
        return ok()

    def getBaseOffset(self) -> Reply:
        return ok(offset=self.settings.base_offset)

    def setBaseOffset(self, offset: HgMatrix) -> Reply:
        self.change_settings(lambda s: s.with_base_offset(offset))
        return ok()

    def setControlPointOffset(self, offset: HgMatrix) -> Reply:
        self.change_settings(lambda s: s.with_control_point_offset(offset))
        return ok()

    # -- home -------------------------------------------------------------------------------
    def getHome(self) -> Reply:
        return ok(jointPoint=self.settings.home)

    def setHome(self, jointPoint: JointPos) -> Reply:
        """Within the servo's current joint soft limits."""
        core = self.core
        self.settings.check_joint_points("jointPoint", jointPoint)
        with core.serial:  # no setSoftLimitJoint in between the check and the change
            limits = core.servo.call(OP.getSoftLimitJoint)
            if not limits.ok:
                raise Refusal(ReturnCode.NG, f"{OP.setHome} refused: joint soft limits unavailable: "
                              f"{limits.comment}")
            self.change_settings(lambda s: s.with_home(jointPoint, limits["softLimit"]))
            return ok()
