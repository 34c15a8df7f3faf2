"""``Ext``: the command service's model-specific operations, outside the JARA_ARM IDL.

Served at ``JARA_ARM/<arm>/Ext/<op>`` with the IDL's reply rules (``RETURN_ID``,
``VALUE_ERR`` naming the field). The jogs go to the planner (``Planner/jog``), which owns the queue
and the lease (``services/planner/jog.py``); the command checks the state first, as for a motion. The
blend distance lives in the same
:class:`Settings` as the Middle ones (``CommandMiddle`` owns them), so that
every motion's ``MotionSettings`` snapshot carries it. The speed override is
not a setting of the command: the servo holds it and applies it to the motion
in progress, so it goes there through the planner's control (as ``pause``
does), and is read back from the planner's newest progress.
"""

from __future__ import annotations

import time
from pathlib import Path
from typing import Any

from jara_arm.schema.codec import Reply, encode_args
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import Refusal, WireError
from jara_arm.schema.messages import NO_STATUS
from jara_arm.schema.operations import EXT, MAX_SPEED_OVERRIDE, OP
from jara_arm.schema.planner import ControlAction, MotionRequest
from jara_arm.schema.program import NAME, teach
from jara_arm.schema.types import LimitValue
from jara_arm.services.runtime.rpc import ok

from .feedback import JointFeedback
from .middle import CommandMiddle, refuse_unless_ready

#: ``teach`` waits this long for a moving arm to come to rest before it refuses [s]: the end of a motion the
#: caller saw complete reaches this service's state a few ms later, and the arm settles after its last sample.
TEACH_SETTLE = 1.0


class CommandExt:
    """The Ext interface; runs on its own RPC thread, changing the settings through ``middle``
    and reaching the planner and the state through ``middle.core``."""

    def __init__(self, middle: CommandMiddle, feedback: JointFeedback | None = None,
                 program: Path | None = None) -> None:
        """``feedback``: the joints ``teach`` stores; ``program``: the file it writes them to (``--program``)."""
        self._middle = middle  # its core is read per call: the settings-only tests build it without one
        self._feedback = feedback
        self._program = program

    def setBlendDistance(self, distance: float) -> Reply:
        """For the motions accepted from now on; queued ones keep the distance they were accepted with."""
        self._middle.change_settings(lambda s: s.with_blend_distance(distance))
        return ok()

    def getBlendDistance(self) -> Reply:
        return ok(distance=self._middle.settings.blend_distance)

    def setSpeedOverride(self, ratio: float) -> Reply:
        """Forwarded to the servo (through the planner), which applies it to the motion in progress too.

        Accepted in any state: the servo keeps it while off or alarmed, for the
        motions to come. Not under ``core.serial``: a speed override must act at
        once, not wait while Middle's thread plans a motion, and it checks no state
        that a motion, pause or stop could change meanwhile.
        """
        if not 0.0 <= ratio <= MAX_SPEED_OVERRIDE:  # NaN fails too (the codec already refuses it)
            raise WireError("ratio", f"the speed override is 0 .. {MAX_SPEED_OVERRIDE:g} %, got {ratio}")
        core = self._middle.core
        answer = core.planner.control(ControlAction.OVERRIDE, ratio)
        core.state.on_progress(answer.progress)  # getSpeedOverride read next shows it
        return answer.reply

    def getSpeedOverride(self) -> Reply:
        """The servo's override as the planner's newest progress (published or in a reply) reports it."""
        progress = self._middle.core.state.planner_progress()
        if progress is None:
            # The servo's word comes only through the planner: without it there is nothing to say (NG, as
            # every planner call without a planner, naming the missing service).
            raise Refusal(ReturnCode.NG, f"{OP.getSpeedOverride}: no Planner/progress from the "
                          "planner service: is it running?")
        return ok(ratio=progress.override)

    # -- jogging (services/planner/jog.py) --------------------------------------------------
    def jogJoint(self, axis: int, speedRatio: float, leaseMs: int) -> Reply:
        """Start or renew a joint jog. Not under ``core.serial``: a renewal must not wait while Middle's
        thread plans a motion (the planner refuses a jog's start beside one)."""
        return self._jog(OP.jogJoint, axis=axis, speedRatio=speedRatio, leaseMs=leaseMs)

    def jogCartesian(self, frame: str, axis: str, speedRatio: float, leaseMs: int) -> Reply:
        """Start or renew a Cartesian jog (as :meth:`jogJoint`)."""
        return self._jog(OP.jogCartesian, frame=frame, axis=axis, speedRatio=speedRatio, leaseMs=leaseMs)

    def jogStop(self) -> Reply:
        """End the jog: the arm brakes on its path. Accepted in any state (nothing to stop: says so)."""
        return self._forward(OP.jogStop, {}, soft_limits=())  # a stop plans nothing: no limits to ask the servo

    def _jog(self, name: str, **args: Any) -> Reply:
        core = self._middle.core
        view = core.state.view()
        # State first, values last (DECISIONS.md), as for a motion; the values are the planner's to check.
        refuse_unless_ready(view, name)
        if view.paused:
            raise Refusal(ReturnCode.STATUS_ERR, f"{name} refused: paused ({OP.resume} or {OP.stop} first)")
        return self._forward(name, args)

    def _forward(self, name: str, args: dict[str, Any], soft_limits: tuple[LimitValue, ...] | None = None) -> Reply:
        core = self._middle.core
        if soft_limits is None:
            limits = core.servo.call(OP.getSoftLimitJoint)  # the servo's, as they are now
            if not limits.ok:
                raise Refusal(ReturnCode.NG, f"{name} refused: joint soft limits unavailable: {limits.comment}")
            soft_limits = limits["softLimit"]
        request = MotionRequest(name, encode_args(EXT[name], args), self._middle.settings.snapshot(soft_limits),
                                core.state.servo_status() or NO_STATUS)
        answer = core.planner.jog(request)
        if answer.progress is not None:
            core.state.on_progress(answer.progress)  # getState read next shows the jog moving
        return answer.reply

    # -- teaching (schema/program.py) -------------------------------------------------------
    def teach(self, name: str) -> Reply:
        """Where the arm is, as feedback says, into the program file under ``name``."""
        if not NAME.match(name):
            raise WireError("name", f"letters, digits, _ and -, not starting with a digit, got {name!r}")
        if self._program is None or self._feedback is None:
            raise Refusal(ReturnCode.NG, f"{OP.teach}: this command service has no program file (--program)")
        # A motion that just ended may still settle, or its end not have reached this service: a moment's grace.
        deadline = time.monotonic() + TEACH_SETTLE
        while self._middle.core.state.view().moving:
            if time.monotonic() > deadline:
                raise Refusal(ReturnCode.STATUS_ERR, f"{OP.teach} refused: the arm moves; teach where it holds")
            time.sleep(0.01)
        joints = self._feedback.joints()
        pose = self._middle.getFeedbackPosCartesian()
        if not joints.ok or not pose.ok:
            bad = joints if not joints.ok else pose
            raise Refusal(ReturnCode(bad.id), f"{OP.teach}: {bad.comment}")
        car = pose["pos"]
        n = self._middle.core.robot.axis_num
        try:
            teach(self._program, name, joints["pos"][:n], car.carPos, car.elbow, car.structFlag)
        except (OSError, ValueError) as exc:
            raise Refusal(ReturnCode.NG, f"{OP.teach}: cannot write {self._program}: {exc}") from None
        return ok(f"OK: taught {name} into {self._program}", jointPoint=joints["pos"], carPoint=car)
