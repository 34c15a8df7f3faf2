"""``ManipulatorCommonInterface_Common`` of the middle level, one method per IDL operation.

Everything the low level owns (servo power, joint soft limits, manipulator
information) is passed through to the servo, so that the two levels never
disagree: the reply is the servo's, decoded and re-encoded through the schema.
Servo power goes to ``Servo/power``, whose reply carries the servo's status
after the action, numbered: the state takes it in at once, so the bits read
after the reply show the change (no wait for a publication); the rest to
``Servo/Common/<op>``. The joint feedback is the newest one the servo
published in its status (``feedback.py``), as for ``getFeedbackPosCartesian``:
clients may ask it as fast as they can, and the servo process, whose clock
shares one GIL with its query thread, must not pay for that. The alarms are the alarm
monitor's: ``getActiveAlarm`` and ``clearAlarms`` go to ``Monitor/Common/<op>``
(as the servo's own do), and to the servo when the monitor does not answer.
``getState`` is the command's own (``state.py``): it adds the queue and the
pause to the servo's bits, and the monitor's list to the alarm bit.
"""

from __future__ import annotations

import logging

from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import ControlAction
from jara_arm.schema.power import PowerAction
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.rpc import ok

from .core import Core, with_note
from .feedback import JointFeedback

log = logging.getLogger(__name__)


class CommandCommon:
    """The Common interface at ``JARA_ARM/<arm>/Common/<op>``."""

    def __init__(self, core: Core, feedback: JointFeedback) -> None:
        self.core = core
        self._feedback = feedback

    def clearAlarms(self) -> Reply:
        core = self.core
        with core.serial:
            reply = core.monitor.call(OP.clearAlarms)
            if reply is None:  # no monitor answered us: the servo asks it too, else clears its own (and says so)
                return self._power(PowerAction.CLEAR)
            alarms = core.monitor.alarm_list()  # the bit read next shows the clear at once...
            if alarms is not None:
                core.state.on_alarms(alarms)
            # ...and the servo's too: it follows the cleared list before the reply. A silent servo's status
            # counts for nothing (state.py): not asked, no SERVO_TIMEOUT to wait.
            if core.state.view().servo_heard:
                self._power(PowerAction.SYNC)
            return reply

    def getActiveAlarm(self) -> Reply:
        """The monitor's numbered list, adopted before it is answered: a ``getState`` after this reply has
        bit 0x04 for what it lists (and no servo-on bit for a FAULT), whatever the publications' delay."""
        alarms = self.core.monitor.alarm_list()
        if alarms is not None:
            self.core.state.on_alarms(alarms)
            return ok(alarms=alarms.alarms)
        # The monitor did not answer within MONITOR_TIMEOUT: not asked again (its Common getActiveAlarm would
        # keep the client waiting as long once more); the servo answers and says so (architecture.md, case 2).
        return self.core.servo.call(OP.getActiveAlarm)

    def getFeedbackPosJoint(self) -> Reply:
        return self._feedback.joints()

    def getManipInfo(self) -> Reply:
        return self.core.servo.call(OP.getManipInfo)

    def getSoftLimitJoint(self) -> Reply:
        return self.core.servo.call(OP.getSoftLimitJoint)

    def getState(self) -> Reply:
        return ok(state=self.core.state.view().bits)

    def servoOFF(self) -> Reply:
        """Servo off first (the brakes hold at once), then the planner forgets its queue."""
        core = self.core
        with core.serial:
            reply = self._power(PowerAction.OFF)
            # Abort even if the servo did not answer: no buffered motion may run once it is back.
            abort = core.planner.control(ControlAction.ABORT)
            core.state.on_progress(abort.progress)
            if reply.ok:
                log.info("servo off; motion queue discarded")
            if not abort.reply.ok:
                # The servo is off, which is what was asked; a missing planner has nothing queued.
                return with_note(reply, f"planner abort not confirmed: {abort.reply.comment}")
            return reply

    def servoON(self) -> Reply:
        with self.core.serial:
            reply = self._power(PowerAction.ON)
            if reply.ok:
                log.info("servo on")
            return reply

    def _power(self, action: PowerAction) -> Reply:
        """The servo's reply to ``action``, its status taken in: the bits read next show what it did. The
        servo first adopts the monitor's newest list held here (a clear it has not heard of yet)."""
        core = self.core
        answer = core.servo.power(action, core.state.alarm_list())
        if answer.status is not None and answer.status.seq:  # seq 0: the servo could not say
            core.state.on_status(answer.status)
        return answer.reply

    def setSoftLimitJoint(self, softLimit: tuple[LimitValue, ...]) -> Reply:
        """Refused while moving (servo or queue) or alarmed; the servo checks the values."""
        core = self.core
        with core.serial:
            view = core.state.view()
            if view.moving:
                why = (f"{view.queue_length} motion(s) queued" if view.queue_length
                       else "the arm is moving")
                raise Refusal(ReturnCode.STATUS_ERR, f"{OP.setSoftLimitJoint} refused while moving: {why}")
            if view.alarm:
                raise Refusal(ReturnCode.STATUS_ERR, f"{OP.setSoftLimitJoint} refused: an alarm is active "
                              f"({OP.getActiveAlarm}, {OP.clearAlarms})")
            return core.servo.call(OP.setSoftLimitJoint, {"softLimit": softLimit})
