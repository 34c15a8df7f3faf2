"""The planner service (middle level): plans motions and hands each one over to the servo whole.

``python -m jara_arm.services.planner --arm arm0 --robot iiwa --connect tcp/127.0.0.1:7447``

One process with a child (``schema/planner.py`` is the contract):

* ``Planner/plan``: a worker thread decodes the ``MotionRequest``, takes the
  start joints from the servo's progress, decodes the request's parameters
  once into a typed ``PlanRequest`` (``request.py``), has the planning process
  (``worker.py``) plan and check it, hands it to the servo's interpolator
  (``handover.py``, ``Servo/trajectory``) and replies ``PlanReply``. Motions
  are planned one at a time, in order. Meanwhile, with nothing buffered or
  moving, the worker plans a LIN / CIRC's head itself and hands it over at
  once: the early start (``docs/decisions.md``, "First command and
  acceptance"); the reply still waits for the whole.
* ``Planner/control``: another worker thread (never waits for planning)
  forwards pause / resume / stop / abort / override to the servo
  (``Servo/motionControl``), which acts on them in its next cycle.
* A relay thread republishes the servo's ``Servo/motion`` as ``Planner/progress``.

The CPU-heavy planning runs in the child at normal priority; this process's
threads run under SCHED_FIFO when allowed (``PlannerProgram.REALTIME_PRIORITY``)
for its heartbeat and the early start's head, not for the motions: a buffered
motion runs to its end whatever this process does.
"""

from __future__ import annotations

import argparse
import logging
import threading
import time

import zenoh

from jara_arm.robots import Obstacle, RobotModel
from jara_arm.schema import codec, messages
from jara_arm.schema import wire_types as w
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import Service
from jara_arm.schema.operations import EXT, OP
from jara_arm.schema.motion import (
    MOTION_CONTROL,
    MOTION_PROGRESS,
    MOTION_REPLY,
    TRAJECTORY,
    MotionControl,
    MotionProgress,
    MotionReply,
    Trajectory,
)
from jara_arm.schema.planner import (
    CONTROL_REPLY,
    CONTROL_REQUEST,
    MOTION_REQUEST,
    MotionRequest,
    PLAN_REPLY,
    PLANNED_PATH,
    PLANNER_PROGRESS,
    QUEUE_CAPACITY,
    ControlAction,
    ControlReply,
    PlannedPath,
    PlannerProgress,
    PlanReply,
    accepted_comment,
)
from jara_arm.services.runtime.arguments import non_negative_float, obstacle_argument, positive_int
from jara_arm.services.runtime.service import ArmService, ServiceContext, entry
from jara_arm.services.runtime.ask import Asker, Silence
from jara_arm.services.runtime.inbox import Inbox
from jara_arm.services.runtime.timing import CONTROL_TIMEOUT, EARLY_START, SERVO_TIMEOUT
from jara_arm.services.runtime.wire import Publication, decode_sample

from .collision import DEFAULT_MARGIN
from .handover import Handover
from .jog import Jogger
from .jog_request import JogCommand
from .planning import MotionPlanner
from .request import PlanRefused, PlanRequest
from .trajectory import Joints
from .worker import PlanningProcess

log = logging.getLogger("jara_arm.planner")

#: [s] How long a jog's start waits for the servo's word on its queue to catch up with the command's view of
#: the servo (``Servo/motion`` comes on every change and every 0.1 s).
QUEUE_NEWS = 0.25
#: Times a motion is re-planned when a stop or abort moved the queue's end while it was planned.
_REPLAN = 3


class PlannerService:
    """``Planner/plan`` and ``Planner/control`` queryables, and the hand-over to the servo."""

    def __init__(self, ctx: ServiceContext, planner: PlanningProcess, heads: MotionPlanner, capacity: int,
                 obstacles: tuple[Obstacle, ...] = (), collision_margin: float = DEFAULT_MARGIN) -> None:
        session, keys = ctx.session, ctx.keys
        self.model = model = ctx.model
        self.planner = planner
        self.heads = heads  # the early starts' heads, planned in this process beside the child
        self._progress_pub = ctx.enter(Publication(session, keys.planner_progress))
        self._path_pub = ctx.enter(Publication(session, keys.planner_path))  # for viewers, low rate
        self._status_sub = ctx.enter(session.declare_subscriber(keys.servo_status, zenoh.handlers.RingChannel(1)))
        relay_inbox = Inbox()  # the progress relay wakes when a Servo/motion comes
        self._motion_sub = relay_inbox.box(4)
        ctx.enter(session.declare_subscriber(keys.servo_motion, self._motion_sub))
        self._trajectory = Asker(session, keys.servo_trajectory, SERVO_TIMEOUT)
        ctx.closing(self._trajectory.close)
        self._control = Asker(session, keys.servo_motion_control, CONTROL_TIMEOUT)
        ctx.closing(self._control.close)
        self.handover = Handover(model.dof, model.cmd_cycle, self._ask_trajectory, self._ask_control,
                                 self._put_progress, self._poll_status, self._poll_motion,
                                 pulse=ctx.heartbeat().pulse("the progress relay"), capacity=capacity,
                                 inbox=relay_inbox)
        self.handover.start()
        ctx.closing(self.handover.close)
        ctx.watch("the progress relay thread", lambda: self.handover.alive)
        self.jogger = Jogger(model, self.handover, obstacles, collision_margin)
        self.jogger.start()
        ctx.closing(self.jogger.close)
        ctx.watch("the jog thread", lambda: self.jogger.alive)
        # A plan and a jog's start must not both take the empty queue: whichever comes second is refused.
        self._gate = threading.Lock()
        # Planning may take a while: control queries and jogs have a worker each of their own.
        plan_key, control_key, jog_key = keys.planner_plan, keys.planner_control, keys.planner_jog
        ctx.serve_key(plan_key, lambda _k, p, e: (plan_key, self._answer_plan(p, e)), "planner-plan")
        ctx.serve_key(control_key, lambda _k, p, e: (control_key, self._answer_control(p, e)), "planner-control")
        ctx.serve_key(jog_key, lambda _k, p, e: (jog_key, self._answer_jog(p, e)), "planner-jog")

    # ------------------------------------------------------------------ the servo

    def _ask_trajectory(self, traj: Trajectory) -> MotionReply | None:
        return self._ask(self._trajectory, codec.encode_message(TRAJECTORY, traj))

    def _ask_control(self, control: MotionControl) -> MotionReply | None:
        return self._ask(self._control, codec.encode_message(MOTION_CONTROL, control))

    @staticmethod
    def _ask(asker: Asker, payload: bytes) -> MotionReply | None:
        got = asker.ask(payload)
        if isinstance(got, Silence):
            log.warning("%s", got.why)
            return None
        try:
            return codec.decode_message(MOTION_REPLY, got.payload, got.encoding)
        except WireError as exc:
            log.warning("ignored a malformed reply of %s: %s", asker.key, exc)
            return None

    def _poll_status(self) -> messages.ServoStatus | None:
        sample = self._status_sub.try_recv()
        if sample is None:
            return None
        try:
            return decode_sample(messages.SERVO_STATUS, sample)
        except WireError as exc:
            log.warning("ignored a malformed servo status: %s", exc)
            return None

    def _poll_motion(self) -> MotionProgress | None:
        """The newest ``Servo/motion`` received since the last poll, or None."""
        newest = None
        while (sample := self._motion_sub.try_recv()) is not None:
            try:
                newest = decode_sample(MOTION_PROGRESS, sample)
            except WireError as exc:
                log.warning("ignored a malformed Servo/motion: %s", exc)
        return newest

    def _put_progress(self, progress: PlannerProgress) -> None:
        self._progress_pub.put_message(PLANNER_PROGRESS, progress)

    # ------------------------------------------------------------------ queries

    def _answer_plan(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(PLAN_REPLY, self.plan(payload, encoding), encoding)

    def plan(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> PlanReply:
        """Decode, plan and queue one motion; the reply says OK (with the motion's id) or why not."""
        try:
            wire = codec.decode_message(MOTION_REQUEST, payload, encoding)
        except WireError as exc:
            log.info("motion request refused: %s", exc)
            return self._refused(ReturnCode.VALUE_ERR, str(exc))
        with self._gate:
            if self.jogger.active:
                return self._refused(ReturnCode.STATUS_ERR, f"{wire.op} refused: the arm is jogging "
                                     f"({OP.jogStop} first)")
            return self._plan(wire)

    def _plan(self, wire: MotionRequest) -> PlanReply:
        req: PlanRequest | None = None
        for _ in range(_REPLAN):
            try:
                start, epoch = self.handover.start_point(wire.servo)
                if req is None:  # its parameters, once (request.py): after the servo's state, values come last
                    req = PlanRequest.decode(wire)
            except PlanRefused as exc:
                log.info("%s refused (%s): %s", wire.op, exc.code.name, exc.comment)
                return self._refused(exc.code, exc.comment)
            reply = self._plan_from(req, start, epoch)
            if reply is not None:
                return reply
            log.info("%s: the queue was stopped or the arm held anew while planning; planning again", req.op)
        return self._refused(ReturnCode.STATUS_ERR, "the queue kept being stopped while planning")

    def _plan_from(self, req: PlanRequest, start: Joints, epoch: int) -> PlanReply | None:
        """Plan ``req`` from ``start`` (the servo's ``epoch``) in the planning process and hand it over, its head
        early if it may start so; the reply, or None if the queue moved meanwhile (plan it again)."""
        t0 = time.perf_counter()
        started = False

        def start_early() -> None:
            nonlocal started
            began = time.perf_counter()
            head = self.heads.head(req, start)
            planned = time.perf_counter()
            if head is not None and self.handover.start_early(head.motion, epoch):
                started = True
                done = time.perf_counter()
                # Where the time to the first command goes (bench/motion.py reads this line).
                log.info("%s starts early: head planned in %.1f ms (%.1f before it began, %.1f planning it, "
                         "%.1f handing it over), %d samples before acceptance, within %.2f mm of the start",
                         req.op, (done - t0) * 1e3, (began - t0) * 1e3, (planned - began) * 1e3,
                         (done - planned) * 1e3, len(head.motion.q), head.reach * 1e3)

        try:
            previous = self.handover.last_motion() if req.settings.blendDistance > 0.0 else None
            early = start_early if self.handover.can_start_early() else None
            motion = self.planner.plan(req, start, previous, early)
            if started:
                queued = self.handover.confirm_early(motion, epoch)
            else:
                queued = self.handover.submit(motion, epoch)
        except PlanRefused as exc:
            comment = exc.comment
            if started:
                moved = self.handover.cancel_early()
                comment = f"{comment}; {moved}" if moved else comment
            log.info("%s refused (%s): %s", req.op, exc.code.name, comment)
            return self._refused(exc.code, comment)
        if queued is None:
            return None
        motion_id, progress = queued
        log.info("motion %d %s accepted: %.3f s long, planned in %.0f ms", motion_id, req.op,
                 motion.duration, (time.perf_counter() - t0) * 1e3)
        # One message per motion, for viewers.
        # The preview arrives from the planning process after the motion: read it once queued.
        self._path_pub.put_message(PLANNED_PATH, PlannedPath(
            motion_id, req.op, tuple(tuple(p) for p in self.planner.preview().tolist())))
        return PlanReply(int(ReturnCode.OK), accepted_comment(motion_id), motion_id,
                         tuple(motion.end.tolist()), motion.duration, progress)

    def _answer_jog(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(CONTROL_REPLY, self.jog(payload, encoding), encoding)

    def jog(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> ControlReply:
        """``Ext/jogJoint`` / ``jogCartesian`` (start or renew) and ``Ext/jogStop`` (``jog.py``)."""
        try:
            wire = codec.decode_message(MOTION_REQUEST, payload, encoding)
            if wire.op == OP.jogStop:
                return ControlReply(int(ReturnCode.OK), self.jogger.stop(f"{OP.jogStop}"), self.handover.progress())
            if wire.op not in (OP.jogJoint, OP.jogCartesian):
                raise PlanRefused(ReturnCode.NOT_IMPLEMENTED, f"{wire.op!r} is not a jog")
            cmd = JogCommand.decode(wire.op, codec.decode_args(EXT[wire.op], wire.args), self.model.axis_num)
        except WireError as exc:
            return ControlReply(int(ReturnCode.VALUE_ERR), str(exc), self.handover.progress())
        except PlanRefused as exc:
            return ControlReply(int(exc.code), exc.comment, self.handover.progress())
        starting = not self.jogger.active  # a renewal never waits for a plan, nor takes the gate
        try:
            if starting and not self._gate.acquire(blocking=False):
                raise PlanRefused(ReturnCode.STATUS_ERR, f"{cmd.op} refused: a motion is being planned")
            try:
                code, comment = self.jogger.jog(cmd, wire.settings, lambda: self._jog_start(wire))
            finally:
                if starting:
                    self._gate.release()
        except PlanRefused as exc:
            log.info("%s refused (%s): %s", cmd.op, exc.code.name, exc.comment)
            return ControlReply(int(exc.code), exc.comment, self.handover.progress())
        return ControlReply(int(code), comment, self.handover.progress())

    def _jog_start(self, wire: MotionRequest) -> tuple[Joints, int]:
        """Where a new jog starts and the servo's epoch; refused unless nothing is queued, moving or paused."""
        start, epoch = self.handover.start_point(wire.servo)
        if not self.handover.can_start_early():
            # The command forwards a jog only when the servo's status says the arm is at rest; the servo's word on
            # its queue may not have reached this process yet (a jog that ended a moment ago, a busy machine).
            if wire.servo.seq and self.handover.heard_since(wire.servo.tm.to_seconds(), QUEUE_NEWS):
                start, epoch = self.handover.start_point(wire.servo)
        if not self.handover.can_start_early():
            raise PlanRefused(ReturnCode.STATUS_ERR, f"{wire.op} refused: a motion runs, is queued or is paused "
                              f"(wait for it, or {OP.stop} it)")
        return start, epoch

    def _refused(self, code: ReturnCode, comment: str) -> PlanReply:
        return PlanReply(int(code), comment, 0, (), 0.0, self.handover.progress())

    def _answer_control(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(CONTROL_REPLY, self.control(payload, encoding), encoding)

    def control(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> ControlReply:
        """Decode one pause / resume / stop / abort / override and have the servo apply it."""
        try:
            req = codec.decode_message(CONTROL_REQUEST, payload, encoding)
            action = w.choice(ControlAction, req.action, "action")
        except WireError as exc:
            return ControlReply(int(ReturnCode.VALUE_ERR), str(exc), self.handover.progress())
        if action is ControlAction.OVERRIDE and not 0.0 <= req.ratio <= 100.0:
            return ControlReply(int(ReturnCode.VALUE_ERR), f"ratio: the speed override is 0 .. 100 %, got "
                                f"{req.ratio}", self.handover.progress())
        code, comment, progress = self.handover.control(action, req.ratio)
        return ControlReply(int(code), comment, progress)


class PlannerProgram(ArmService):
    """Plans one arm's motions and hands them to the servo; the planning itself in a child process."""

    SERVICE = Service.PLANNER
    #: Not for the motions (a buffered motion does not need the planner) but for its evidence of health and
    #: its early starts: at normal priority, eight planners starting together starved their own heartbeats
    #: into false 0x411 FAULTs, and an early start's head (5-10 ms of planning) waited behind the child's
    #: plan of the whole. The CPU-heavy planning itself runs in the child, at normal priority.
    REALTIME_PRIORITY = 30
    REALTIME_WHAT = "the planner's threads (its planning child stays under the normal scheduler)"

    def __init__(self) -> None:
        self._planner: PlanningProcess | None = None
        self._heads: MotionPlanner | None = None

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--obstacle", type=obstacle_argument, action="append", metavar="X,Y,Z,HX,HY,HZ",
                            help="a fixed box of the world that every motion keeps clear of: centre and half "
                            "extents [m] in the world frame (repeatable; added to the robot model's own "
                            "obstacles; give it the servo's --obstacle boxes)")
        parser.add_argument("--early-start-ms", type=non_negative_float, default=EARLY_START * 1e3, metavar="MS",
                            help="how much of a LIN / CIRC from rest may run while the rest of it is still "
                            "planned [ms of motion]; a motion refused after it started has moved the arm "
                            f"along its checked first samples, 0: never (default: {EARLY_START * 1e3:.0f})")
        parser.add_argument("--queue-capacity", type=positive_int, default=QUEUE_CAPACITY, metavar="N",
                            help="motions the queue holds (the running one included) before the next is refused "
                            f"FULL_MOTION_QUEUE_ERR (default: {QUEUE_CAPACITY})")
        parser.add_argument("--collision-margin", type=non_negative_float, default=DEFAULT_MARGIN, metavar="M",
                            help="clearance every link keeps from the obstacles [m]; links only must not touch "
                            f"each other (default: {DEFAULT_MARGIN})")

    def before_session(self, model: RobotModel, options: argparse.Namespace) -> None:
        obstacles = model.obstacles + tuple(options.obstacle or ())
        self._planner = PlanningProcess(model, logging.getLevelName(logging.getLogger().level), obstacles,
                                        options.collision_margin)
        self._heads = MotionPlanner(model, obstacles=obstacles, collision_margin=options.collision_margin,
                                    early_start=options.early_start_ms * 1e-3)
        self._planner.wait_started()  # it started above: its start overlapped the heads' (0.9 s and 0.3 s here)

    def start(self, ctx: ServiceContext) -> None:
        assert self._planner is not None and self._heads is not None  # before_session() ran
        PlannerService(ctx, self._planner, self._heads, ctx.options.queue_capacity,
                       ctx.model.obstacles + tuple(ctx.options.obstacle or ()), ctx.options.collision_margin)
        m = ctx.model
        ctx.up(f"planner up: arm {ctx.keys.arm}, robot {m.name} ({m.axis_num} axes"
               f"{' + gripper' if m.has_gripper else ''}), early start {ctx.options.early_start_ms:g} ms, "
               f"queue capacity {ctx.options.queue_capacity}")

    def after_session(self) -> None:
        if self._planner is not None:
            self._planner.close()


PROGRAM = PlannerProgram
run = entry(PROGRAM)
