"""A servo and a planner process, the test session a peer of both (``test_planner_service.py``,
``test_early.py``).

Motions go to ``Planner/plan`` as the command service would send them (``MotionRequest`` with a
settings snapshot); the commands the servo followed (``Servo/posTarget``), its feedback and its
statuses are recorded.
"""

from __future__ import annotations

import dataclasses
import time
from collections.abc import Iterator
from typing import Any

import numpy as np
import zenoh

from jara_arm.schema import codec, messages
from jara_arm.schema.codec import Reply
from jara_arm.schema.codes import ReturnCode, StateBit
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import OP
from jara_arm.schema.planner import (
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    PLANNER_PROGRESS,
    ControlAction,
    ControlRequest,
    MotionRequest,
    MotionSettings,
    PlannerProgress,
    PlanReply,
)
from jara_arm.services.runtime.zenoh_args import zenoh_config

from .harness import Newest, Processes, Recorder, RecordingArm, StatusLog
from .support import Proc, endpoint, free_port, motion_settings, service_argv, wait_alive, wait_until


@dataclasses.dataclass(frozen=True)
class Answer:
    """A ``PlanReply`` and the id of the motion it answers."""

    motion: int
    id: int
    comment: str
    endJoints: tuple[float, ...]
    duration: float


@dataclasses.dataclass
class Recorded:
    """What was seen on the wire since the last drain."""

    cmd_t: np.ndarray  # [s] the time each followed command's cycle stands for (Servo/posTarget's tm)
    cmd: np.ndarray  # (N, dof) position commands
    fb: np.ndarray  # (M, dof) feedback
    fb_tm: np.ndarray  # (M,) [s] the time each feedback sample stands for (a lost one leaves a gap)
    status: list[messages.ServoStatus]


def _progress(sample: zenoh.Sample) -> PlannerProgress:
    progress: PlannerProgress = codec.decode_message(PLANNER_PROGRESS, sample.payload.to_bytes())
    return progress


class PlannerRig(RecordingArm):
    """The rig's client: motions planned and controlled as the command would, the servo's followed commands,
    feedback and statuses recorded, the planner's newest progress. ``proc`` is the planner."""

    BLOCKS = False  # no gateway: the test is a peer of the servo (RecordingArm.BLOCKS)

    def __init__(self, session: zenoh.Session, robot_name: str, servo: Proc, planner: Proc) -> None:
        super().__init__(session, robot_name, proc=planner)
        self.servo_proc, self.planner_proc = servo, planner
        self.targets = Recorder(session, self.keys.pos_target, explain=self.log_tail)
        self.statuses = StatusLog(session, self.keys, explain=self.log_tail)
        self._progress = Newest(session, self.keys.planner_progress, _progress)
        self.last_motion = 0  # id of the last motion accepted

    def common(self, name: str, args: dict | None = None) -> Reply:
        """No command service here: the Common interface is the servo's own."""
        return self.servo(name, args)

    # -- calls ------------------------------------------------------------------------
    def settings(self, **changes: Any) -> MotionSettings:
        return motion_settings(self.model, **changes)

    def plan(self, op: str, args: dict | None = None, **settings: Any) -> Answer:
        req = MotionRequest(op, args or {}, self.settings(**settings))
        replies = list(self.session.get(self.keys.planner_plan, payload=codec.encode_message(
            MOTION_REQUEST, req), timeout=20.0))
        assert len(replies) == 1 and replies[0].ok is not None, replies
        reply: PlanReply = codec.decode_message(PLAN_REPLY, replies[0].ok.payload.to_bytes())
        if reply.id == ReturnCode.OK:  # the reply shows the queue it left: the motion in it, or done (one sample)
            p = reply.progress
            assert reply.motion > 0 and (p.queued[-1:] == (reply.motion,) or p.lastDone >= reply.motion), (
                reply.motion, reply.duration, p)
        return Answer(reply.motion, reply.id, reply.comment, reply.endJoints, reply.duration)

    def plan_ok(self, op: str, args: dict | None = None, **settings: Any) -> Answer:
        """A motion planned, which must be accepted."""
        reply = self.plan(op, args, **settings)
        self.last_motion = reply.motion
        assert reply.id == ReturnCode.OK, reply
        return reply

    def control(self, action: ControlAction, ratio: float = 100.0) -> dict:
        replies = list(self.session.get(self.keys.planner_control, payload=codec.encode_message(
            CONTROL_REQUEST, ControlRequest(action.value, ratio)), timeout=10.0))
        assert len(replies) == 1 and replies[0].ok is not None, replies
        return codec.loads(replies[0].ok.payload.to_bytes())

    def progress(self) -> PlannerProgress:
        """The newest ``Planner/progress``."""
        p = self._progress.current()
        assert p is not None
        return p

    # -- waiting and recording --------------------------------------------------------
    def wait_along(self, a: np.ndarray, b: np.ndarray, fraction: float, timeout: float = 10.0) -> None:
        """Until the servo's target puts the control point ``fraction`` of the way from ``a`` to ``b``."""
        d = b - a
        self.wait_status(f"the control point {fraction:.0%} of the way",
                         lambda st: (self.fk(st.target)[:3, 3] - a) @ d / (d @ d) >= fraction, timeout)

    def wait_planner_sees_servo_on(self, timeout: float = 20.0) -> None:
        """Until the planner plans from a servo status that says servo on.

        The probe, a PTP with one joint too few, passes the planner's check of the servo
        (NOT_SV_ON_ERR while it has not seen the servo on) and is then refused by the
        planning itself (VALUE_ERR): nothing is queued either way.
        """
        probe = {"jointPoints": [0.0] * (self.n - 1)}
        replies: list[Answer] = []
        wait_until(lambda: replies.append(self.plan(OP.movePTPJointAbs, probe))
                   or replies[-1].id == ReturnCode.VALUE_ERR, timeout, 0.01,
                   "the planner to see the servo on", explain=lambda: f"last probe: {replies[-1:]}")

    def wait_progress(self, what: str, predicate, timeout: float = 10.0) -> PlannerProgress:
        """The newest ``Planner/progress`` (the last one read, if none came since) once ``predicate`` holds."""
        return wait_until(lambda: (lambda p: p if p is not None and predicate(p) else None)(self._progress.current()),
                          timeout, 0.01, what)

    def wait_idle(self, timeout: float = 15.0) -> PlannerProgress:
        """Every accepted motion done or discarded, nothing streaming, the arm at rest."""
        last = self.last_motion
        p = self.wait_progress("planner idle", lambda p: not p.queued and not p.streaming
                               and max(p.lastDone, p.lastDiscarded) >= last, timeout)
        wait_until(lambda: not self.state() & StateBit.MOVING, timeout, what="arm at rest")
        return p

    def drain(self) -> Recorded:
        """What was recorded since the last drain: the servo's applied commands (``Servo/posTarget``, one per
        cycle that followed one), its feedback and its statuses."""
        cmd_t, cmd = self.targets.timed()
        fb_tm, fb = self.recorded_timed()
        dof = self.model.dof
        return Recorded(cmd_t, cmd.reshape(-1, dof), fb.reshape(-1, dof), fb_tm, self.statuses.drain())

    def reset(self) -> None:
        """Servo on, nothing queued, arm at rest at the ready pose, recorders empty."""
        if not self.state() & StateBit.SERVO_ON:
            wait_until(lambda: not self.state() & StateBit.MOVING, 5.0, what="the arm braked")
            self.servo(OP.clearAlarms)
            assert self.servo(OP.servoON).id == ReturnCode.OK
            self.wait_planner_sees_servo_on()
        self.control(ControlAction.STOP)
        self.wait_idle()
        if np.abs(self.joints()[:self.n] - self.model.ready_pose).max() > 1e-3:
            self.plan_ok(OP.goHome, spdRatioJoint=100)
            self.wait_idle()
        self.drain()


def start_rig(robot_name: str, servo_args: tuple[str, ...] = (),
              planner_args: tuple[str, ...] = ()) -> Iterator[PlannerRig]:
    """The rig of ``robot_name``, servo on and seen on by the planner; a fixture's body (``yield from``)."""
    sp, pp = free_port(), free_port()
    with Processes() as procs:
        # Its own exit is test_servo's business.
        servo = procs.start(service_argv(Service.SERVO, sp, "arm0", robot_name, "--publish-targets", *servo_args),
                            checked=False)
        planner = procs.start(service_argv(Service.PLANNER, pp, "arm0", robot_name, "--connect", endpoint(sp),
                                           *planner_args))
        try:
            deadline = time.monotonic() + 30.0
            while True:
                try:
                    session = zenoh.open(zenoh_config("peer", connect=[endpoint(sp), endpoint(pp)]))
                    break
                except zenoh.ZError:
                    if time.monotonic() > deadline:
                        raise
                    time.sleep(0.2)
            with session:
                wait_alive(session, "arm0", [Service.SERVO, Service.PLANNER], timeout=60.0)
                rig = PlannerRig(session, robot_name, servo, planner)
                assert rig.servo(OP.servoON).id == ReturnCode.OK
                rig.wait_planner_sees_servo_on()
                yield rig
        finally:
            print("\n".join(line for line in planner.lines if "WARNING" in line or "ERROR" in line))
