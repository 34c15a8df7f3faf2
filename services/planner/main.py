"""The planner service (middle level): plans motions, queues them, streams them to the servo.

``python -m jara_arm.services.planner --arm arm0 --robot iiwa --connect tcp/127.0.0.1:7447``

One process with a child (``schema/planner.py`` is the contract):

* ``Planner/plan``: a worker thread decodes the ``MotionRequest``, takes the
  start joints from the streamer, has the planning process (``worker.py``)
  plan and check it, queues it and replies ``PlanReply``. Motions are planned
  one at a time, in order.
* ``Planner/control``: another worker thread (never waits for planning)
  applies pause / resume / stop / abort to the streamer and replies once any
  braking is queued for sending.
* The streamer thread (``streamer.py``) sends the position commands, watches
  ``Servo/status`` and publishes ``Planner/progress``.

Every thread of this process runs under SCHED_FIFO when allowed (the streamer
highest); the CPU-heavy planning runs in the child at normal priority.
"""

from __future__ import annotations

import argparse
import logging
import sys
import threading
import time
from collections.abc import Callable

import zenoh

from jara_arm.robots import RobotModel
from jara_arm.schema import codec, messages
from jara_arm.schema.codec import Encoding
from jara_arm.schema.codes import ReturnCode
from jara_arm.schema.errors import WireError
from jara_arm.schema.keys import ArmKeys, Service
from jara_arm.schema.planner import (
    CONTROL_REQUEST,
    MOTION_REQUEST,
    PLAN_REPLY,
    PLANNER_PROGRESS,
    ControlAction,
    PlannerProgress,
    PlanReply,
)
from jara_arm.services.runtime.heartbeat import Heartbeat
from jara_arm.services.runtime.realtime import realtime_process
from jara_arm.services.runtime.rpc import expired
from jara_arm.services.runtime.timing import SAME_HOST, Health
from jara_arm.services.runtime.service import announce, depart, run_service, service_session

from .planning import PlanRefused
from .streamer import DEFAULT_LEAD, DEFAULT_RT_PRIORITY, Streamer
from .worker import PlanningProcess

log = logging.getLogger("jara_arm.planner")

_ZENOH_ENCODING = {Encoding.JSON: zenoh.Encoding.APPLICATION_JSON,
                   Encoding.MSGPACK: zenoh.Encoding("application/msgpack")}
_CHANNEL_CAPACITY = 256
#: Times a motion is re-planned when a stop or abort moved the queue's end while it was planned.
_REPLAN = 3
#: Other threads hand the GIL to the streamer this often [s] (Python's default is 5 ms).
GIL_SWITCH_INTERVAL = 0.0005


def _worker(queryable: zenoh.Queryable, key: str, handle: Callable[[bytes, Encoding], bytes],
            name: str) -> threading.Thread:
    """A thread answering the queries of ``queryable`` one at a time, in order, on ``key``.

    ``handle(payload, encoding)`` gives the reply body; the reply names the concrete key
    (a query may use wildcards, e.g. ``JARA_ARM/*/Planner/plan``).
    """

    def serve() -> None:
        while True:
            try:
                query = queryable.recv()
            except Exception:  # the session closed: shutting down
                return
            try:
                if (late := expired(query)) is not None:
                    log.warning("dropped %s unanswered: its requester gave up %.0f ms ago (the planner "
                                "was held up, or the clocks differ)", query.key_expr, late * 1e3)
                    continue
                encoding = Encoding.of(query.encoding)
                payload = query.payload.to_bytes() if query.payload is not None else b""
                query.reply(key, handle(payload, encoding), encoding=_ZENOH_ENCODING[encoding])
            except Exception:
                log.exception("could not answer %s", query.key_expr)
            finally:
                query.drop()

    thread = threading.Thread(target=serve, name=name, daemon=True)
    thread.start()
    return thread


class PlannerService:
    """``Planner/plan`` and ``Planner/control`` queryables, the status watch and the streamer."""

    def __init__(self, session: zenoh.Session, keys: ArmKeys, model: RobotModel, planner: PlanningProcess,
                 lead: float, realtime_priority: int, health: Health = SAME_HOST) -> None:
        self.model = model
        self.planner = planner
        # Every command counts (SyncFIFO): block rather than drop when the link is congested.
        self._cmd_pub = session.declare_publisher(keys.pos_block, express=True,
                                                  congestion_control=zenoh.CongestionControl.BLOCK,
                                                  priority=zenoh.Priority.REAL_TIME)
        self._progress_pub = session.declare_publisher(keys.planner_progress, express=True)
        self._status_sub = session.declare_subscriber(keys.servo_status, zenoh.handlers.RingChannel(1))
        self.heartbeat = Heartbeat(session, keys, Service.PLANNER, max(0, realtime_priority - 1), health)
        self.streamer = Streamer(model.dof, model.cmd_cycle, self._cmd_pub.put, self._put_progress,
                                 self._poll_status, lead=lead, realtime_priority=realtime_priority,
                                 pulse=self.heartbeat.pulse("the streamer loop"))
        self.streamer.start()
        self.heartbeat.start()
        self._plan_q = session.declare_queryable(keys.planner_plan,
                                                 zenoh.handlers.FifoChannel(_CHANNEL_CAPACITY))
        self._control_q = session.declare_queryable(keys.planner_control,
                                                    zenoh.handlers.FifoChannel(_CHANNEL_CAPACITY))
        # Planning may take a while: control queries have a thread of their own.
        self._threads = [
            _worker(self._plan_q, keys.planner_plan, self._answer_plan, "planner-plan"),
            _worker(self._control_q, keys.planner_control, self._answer_control, "planner-control")]
        # Every other thread just below the streamer: Zenoh's carry the commands, and a Python
        # thread preempted while holding the GIL would hold the streamer back with it.
        realtime_process(max(0, realtime_priority - 1), "planner")

    # ------------------------------------------------------------------ servo status

    def _poll_status(self) -> messages.ServoStatus | None:
        sample = self._status_sub.try_recv()
        if sample is None:
            return None
        try:
            return codec.decode_message(messages.SERVO_STATUS, sample.payload.to_bytes())
        except WireError as exc:
            log.warning("ignored a malformed servo status: %s", exc)
            return None

    def _put_progress(self, progress: PlannerProgress) -> None:
        self._progress_pub.put(codec.encode_message(PLANNER_PROGRESS, progress))

    # ------------------------------------------------------------------ queries

    def _answer_plan(self, payload: bytes, encoding: Encoding) -> bytes:
        return codec.encode_message(PLAN_REPLY, self.plan(payload, encoding), encoding)

    def plan(self, payload: bytes, encoding: Encoding = Encoding.MSGPACK) -> PlanReply:
        """Decode, plan and queue one motion; the reply says OK or why not."""
        try:
            req = codec.decode_message(MOTION_REQUEST, payload, encoding)
        except WireError as exc:
            log.info("motion request refused: %s", exc)
            return PlanReply(int(ReturnCode.VALUE_ERR), str(exc), (), 0.0)
        for _ in range(_REPLAN):
            try:
                start, generation = self.streamer.start_point()
                t0 = time.perf_counter()
                motion = self.planner.plan(req, start)
            except PlanRefused as exc:
                log.info("motion %d %s refused (%s): %s", req.motion, req.op, exc.code.name, exc.comment)
                return PlanReply(int(exc.code), exc.comment, (), 0.0)
            if self.streamer.submit(motion, generation):
                log.info("motion %d %s accepted: %.3f s long, planned in %.0f ms", req.motion, req.op,
                         motion.duration, (time.perf_counter() - t0) * 1e3)
                return PlanReply(int(ReturnCode.OK), "OK", tuple(motion.end.tolist()), motion.duration)
            log.info("motion %d %s: the queue was stopped while planning; planning again",
                     req.motion, req.op)
        return PlanReply(int(ReturnCode.STATUS_ERR), "the queue kept being stopped while planning", (), 0.0)

    def _answer_control(self, payload: bytes, encoding: Encoding) -> bytes:
        try:
            req = codec.decode_message(CONTROL_REQUEST, payload, encoding)
            action = ControlAction(req.action)
        except WireError as exc:
            code, comment = ReturnCode.VALUE_ERR, str(exc)
        except ValueError:
            code, comment = ReturnCode.VALUE_ERR, (f"action: unknown {req.action!r}; valid: "
                                                  + ", ".join(a.value for a in ControlAction))
        else:
            code, comment = self.streamer.control(action)
        return codec.dumps({"id": int(code), "comment": comment}, encoding)

    # ------------------------------------------------------------------ life cycle

    @property
    def alive(self) -> bool:
        return self.streamer.alive

    def close(self) -> None:
        self.heartbeat.close()
        for entity in (self._plan_q, self._control_q):
            try:
                entity.undeclare()
            except Exception:
                pass
        self.streamer.close()
        for entity in (self._status_sub, self._cmd_pub, self._progress_pub):
            try:
                entity.undeclare()
            except Exception:
                pass

    def join(self, timeout: float) -> None:
        """Wait for the query workers; call it once the session is closed (that ends their recv()).

        A thread still inside recv() when the interpreter exits would abort the process.
        """
        for t in self._threads:
            t.join(timeout)
            if t.is_alive():
                log.warning("query worker %s did not end", t.name)


def main(conf: zenoh.Config, arm: str, robot: RobotModel, stop: threading.Event,
         health: Health = SAME_HOST, lead_ms: float = DEFAULT_LEAD * 1e3,
         realtime_priority: int = DEFAULT_RT_PRIORITY) -> None:
    sys.setswitchinterval(GIL_SWITCH_INTERVAL)
    planner = PlanningProcess(robot, logging.getLevelName(logging.getLogger().level))
    service: PlannerService | None = None
    try:
        with service_session(conf, arm, Service.PLANNER) as (session, keys):
            service = PlannerService(session, keys, robot, planner, lead_ms * 1e-3, realtime_priority, health)
            token = announce(session, keys, Service.PLANNER)
            log.info("planner up: arm %s, robot %s (%d axes%s), lead %.0f ms", arm, robot.name,
                     robot.axis_num, " + gripper" if robot.has_gripper else "", lead_ms)
            try:
                while not stop.wait(0.2):
                    if not service.alive:
                        raise RuntimeError("the streamer thread died")
            finally:
                depart(stop, service.heartbeat, token)
                service.close()
                log.info("planner down")
    finally:
        if service is not None:
            service.join(2.0)
        planner.close()


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--lead-ms", type=float, default=DEFAULT_LEAD * 1e3, metavar="MS",
                        help="position commands kept ahead of the servo [ms]: the pause/stop latency "
                        f"(default: {DEFAULT_LEAD * 1e3:.0f})")
    parser.add_argument("--realtime-priority", type=int, default=DEFAULT_RT_PRIORITY, metavar="N",
                        help="SCHED_FIFO priority of the streamer thread, 1..99; 0 for normal "
                        f"scheduling (default: {DEFAULT_RT_PRIORITY})")


def run(argv: list[str] | None = None) -> int:
    return run_service(Service.PLANNER, __doc__.splitlines()[0], main, argv, add_arguments)
