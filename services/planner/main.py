"""The planner service (middle level): plans motions, queues them, streams them to the servo.

``python -m jara_arm.services.planner --arm arm0 --robot iiwa --connect tcp/127.0.0.1:7447``

One process with a child (``schema/planner.py`` is the contract):

* ``Planner/plan``: a worker thread decodes the ``MotionRequest``, takes the
  start joints from the streamer, has the planning process (``worker.py``)
  plan and check it, queues it and replies ``PlanReply``. Motions are planned
  one at a time, in order. Meanwhile, with nothing queued or moving, the
  worker plans a LIN / CIRC's head itself and streams it: the early start
  (``docs/decisions.md``, "First command and acceptance"); the reply still
  waits for the whole.
* ``Planner/control``: another worker thread (never waits for planning)
  applies pause / resume / stop / abort to the streamer and replies once any
  braking is queued for sending.
* The streamer thread (``streamer.py``) sends the position commands, watches
  ``Servo/status`` and publishes ``Planner/progress``.

Every thread of this process runs under SCHED_FIFO when allowed (the streamer
highest); the CPU-heavy planning runs in the child at normal priority. A
head (about 2 ms) is planned here: only while the streamer has nothing to send.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema import codec, messages
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import Service
from jara_arm.schema.planner import (
    CONTROL_REPLY,
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    PLANNED_PATH,
    PLANNER_PROGRESS,
    ControlAction,
    ControlReply,
    PlannedPath,
    PlannerProgress,
    PlanReply,
)
from jara_arm.services.runtime.arguments import non_negative_float, obstacle_argument
from jara_arm.services.runtime.service import ArmService, ServiceContext, entry
from jara_arm.services.runtime.timing import EARLY_START
from jara_arm.services.runtime.wire import Publication, decode_sample

from .collision import DEFAULT_MARGIN
from .planning import MotionPlanner, PlanRefused
from .streamer import DEFAULT_LEAD, DEFAULT_RT_PRIORITY, Streamer
from .worker import PlanningProcess

log = logging.getLogger("jara_arm.planner")

#: Times a motion is re-planned when a stop or abort moved the queue's end while it was planned.
_REPLAN = 3
#: Other threads hand the GIL to the streamer this often [s] (Python's default is 5 ms).
GIL_SWITCH_INTERVAL = 0.0005


class PlannerService:
    """``Planner/plan`` and ``Planner/control`` queryables, the status watch and the streamer."""

    def __init__(self, ctx: ServiceContext, planner: PlanningProcess, heads: MotionPlanner, lead: float) -> None:
        session, keys = ctx.session, ctx.keys
        self.model = model = ctx.model
        self.planner = planner
        self.heads = heads  # the early starts' heads, planned in this process beside the child
        # Every command counts (SyncFIFO): its traffic class (stream) blocks rather than drops, on the
        # cell bus only. The blocks are MessagePack built by hand (messages.position_block_payload), fast.
        self._cmd_pub = ctx.enter(Publication(session, keys.pos_block, Encoding.MSGPACK))
        self._progress_pub = ctx.enter(Publication(session, keys.planner_progress))
        self._path_pub = ctx.enter(Publication(session, keys.planner_path))  # for viewers, low rate
        self._status_sub = ctx.enter(session.declare_subscriber(keys.servo_status, zenoh.handlers.RingChannel(1)))
        self.streamer = Streamer(model.dof, model.cmd_cycle, self._cmd_pub.put, self._put_progress,
                                 self._poll_status, lead=lead, realtime_priority=ctx.realtime_priority,
                                 pulse=ctx.heartbeat().pulse("the streamer loop"))
        self.streamer.start()
        ctx.closing(self.streamer.close)
        ctx.watch("the streamer thread", lambda: self.streamer.alive)
        # Planning may take a while: control queries have a worker of their own.
        plan_key, control_key = keys.planner_plan, keys.planner_control
        ctx.serve_key(plan_key, lambda _k, p, e: (plan_key, self._answer_plan(p, e)), "planner-plan")
        ctx.serve_key(control_key, lambda _k, p, e: (control_key, self._answer_control(p, e)), "planner-control")

    # ------------------------------------------------------------------ servo status

    def _poll_status(self) -> messages.ServoStatus | None:
        sample = self._status_sub.try_recv()
        if sample is None:
            return None
        try:
            return decode_sample(messages.SERVO_STATUS, sample)
        except WireError as exc:
            log.warning("ignored a malformed servo status: %s", exc)
            return None

    def _put_progress(self, progress: PlannerProgress) -> None:
        self._progress_pub.put_message(PLANNER_PROGRESS, progress)

    # ------------------------------------------------------------------ queries

    def _answer_plan(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(PLAN_REPLY, self.plan(payload, encoding), encoding)

    def plan(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> PlanReply:
        """Decode, plan and queue one motion; the reply says OK (with the motion's id) or why not."""
        try:
            req = codec.decode_message(MOTION_REQUEST, payload, encoding)
        except WireError as exc:
            log.info("motion request refused: %s", exc)
            return self._refused(ReturnCode.VALUE_ERR, str(exc))
        for _ in range(_REPLAN):
            started = False

            def start_early() -> None:
                nonlocal started
                head = self.heads.head(req, start)
                if head is not None and self.streamer.start_early(head.motion, generation):
                    started = True
                    log.info("%s starts early: head planned in %.1f ms, %d samples before acceptance, within "
                             "%.2f mm of the start", req.op, (time.perf_counter() - t0) * 1e3, len(head.motion.q),
                             head.reach * 1e3)

            try:
                start, generation = self.streamer.start_point()
                t0 = time.perf_counter()
                previous = self.streamer.last_motion() if req.settings.blendDistance > 0.0 else None
                early = start_early if self.streamer.can_start_early() else None
                motion = self.planner.plan(req, start, previous, early)
            except PlanRefused as exc:
                comment = exc.comment
                if started:
                    moved = self.streamer.cancel_early()
                    comment = f"{comment}; {moved}" if moved else comment
                log.info("%s refused (%s): %s", req.op, exc.code.name, comment)
                return self._refused(exc.code, comment)
            if started:
                queued = self.streamer.confirm_early(motion, generation)
            else:
                queued = self.streamer.submit(motion, generation)
            if queued is not None:
                motion_id, progress = queued
                log.info("motion %d %s accepted: %.3f s long, planned in %.0f ms", motion_id, req.op,
                         motion.duration, (time.perf_counter() - t0) * 1e3)
                # On the plan worker (not the streamer): one message per motion, for viewers.
                # The preview arrives from the planning process after the motion: read it once queued.
                self._path_pub.put_message(PLANNED_PATH, PlannedPath(
                    motion_id, req.op, tuple(tuple(p) for p in self.planner.preview().tolist())))
                return PlanReply(int(ReturnCode.OK), "OK", motion_id, tuple(motion.end.tolist()),
                                 motion.duration, progress)
            log.info("%s: the queue was stopped while planning; planning again", req.op)
        return self._refused(ReturnCode.STATUS_ERR, "the queue kept being stopped while planning")

    def _refused(self, code: ReturnCode, comment: str) -> PlanReply:
        return PlanReply(int(code), comment, 0, (), 0.0, self.streamer.progress())

    def _answer_control(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(CONTROL_REPLY, self.control(payload, encoding), encoding)

    def control(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> ControlReply:
        """Decode and apply one pause / resume / stop / abort."""
        try:
            req = codec.decode_message(CONTROL_REQUEST, payload, encoding)
            action = ControlAction(req.action)
        except WireError as exc:
            return ControlReply(int(ReturnCode.VALUE_ERR), str(exc), self.streamer.progress())
        except ValueError:
            return ControlReply(int(ReturnCode.VALUE_ERR), f"action: unknown {req.action!r}; valid: "
                                + ", ".join(a.value for a in ControlAction), self.streamer.progress())
        code, comment, progress = self.streamer.control(action)
        return ControlReply(int(code), comment, progress)

class PlannerProgram(ArmService):
    """Plans, queues and streams one arm's motions; the planning itself in a child process."""

    SERVICE = Service.PLANNER
    REALTIME_PRIORITY = DEFAULT_RT_PRIORITY
    REALTIME_WHAT = "the streamer thread (the process's other threads: one less)"

    def __init__(self) -> None:
        self._planner: PlanningProcess | None = None
        self._heads: MotionPlanner | None = None

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        parser.add_argument("--lead-ms", type=float, default=DEFAULT_LEAD * 1e3, metavar="MS",
                            help="position commands kept ahead of the servo [ms]: the pause/stop latency "
                            f"(default: {DEFAULT_LEAD * 1e3:.0f})")
        parser.add_argument("--obstacle", type=obstacle_argument, action="append", metavar="X,Y,Z,HX,HY,HZ",
                            help="a fixed box of the world that every motion keeps clear of: centre and half "
                            "extents [m] in the world frame (repeatable; added to the robot model's own "
                            "obstacles; give it the servo's --obstacle boxes)")
        parser.add_argument("--early-start-ms", type=non_negative_float, default=EARLY_START * 1e3, metavar="MS",
                            help="how much of a LIN / CIRC from rest may stream while the rest of it is still "
                            "planned [ms of motion]; a motion refused after it started has moved the arm "
                            f"along its checked first samples, 0: never (default: {EARLY_START * 1e3:.0f})")
        parser.add_argument("--collision-margin", type=non_negative_float, default=DEFAULT_MARGIN, metavar="M",
                            help="clearance every link keeps from the obstacles [m]; links only must not touch "
                            f"each other (default: {DEFAULT_MARGIN})")

    def before_session(self, model: RobotModel, options: argparse.Namespace) -> None:
        sys.setswitchinterval(GIL_SWITCH_INTERVAL)
        obstacles = model.obstacles + tuple(options.obstacle or ())
        self._planner = PlanningProcess(model, logging.getLevelName(logging.getLogger().level), obstacles,
                                        options.collision_margin)
        self._heads = MotionPlanner(model, obstacles=obstacles, collision_margin=options.collision_margin,
                                    early_start=options.early_start_ms * 1e-3)

    def start(self, ctx: ServiceContext) -> None:
        assert self._planner is not None and self._heads is not None  # before_session() ran
        lead_ms = ctx.options.lead_ms
        PlannerService(ctx, self._planner, self._heads, lead_ms * 1e-3)
        m = ctx.model
        ctx.up(f"planner up: arm {ctx.keys.arm}, robot {m.name} ({m.axis_num} axes"
               f"{' + gripper' if m.has_gripper else ''}), lead {lead_ms:.0f} ms")

    def after_session(self) -> None:
        if self._planner is not None:
            self._planner.close()


PROGRAM = PlannerProgram
run = entry(PROGRAM)
